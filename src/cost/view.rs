//! View features: what the camera adds to the characterization, for the calibrated policy.
//!
//! An engine knows its camera. Seen from outside, a scene's primary rays start far from every triangle and many
//! miss the bounds; with the eye inside (a player in a room, a street), every ray starts among the geometry and
//! hits near. The test counts per ray of the structures differ between the two (a grid walks few cells to a near
//! hit; a BVH still descends from its root), so the choice can differ for one mesh. [`ViewFeatures::of`] reduces
//! a camera and the scene's bounds to three numbers ([`VIEW_FEATURE_NAMES`]):
//!
//! * `eye_inside`: 1 when the eye lies in the bounds (inclusive), else 0;
//! * `ln_coverage`: the natural log of the share of a [`COVERAGE_GRID`] x [`COVERAGE_GRID`] grid of the camera's
//!   primary rays (pixel centres, square image) that enter the bounds, at least `1 / COVERAGE_GRID^2`;
//! * `ln_distance`: the natural log of the eye's distance from the centre of the bounds over half their diagonal,
//!   clamped to `[-10, 10]` (a point-like box counts as a unit one).
//!
//! The cost is `COVERAGE_GRID^2` (1,024) ray-box slab tests: microseconds, against milliseconds for the
//! characterization. Without a camera the policy uses the framing camera of the bounds ([`Camera::frame`], the
//! oracle's default), so a model fitted with view features predicts, for a call without a view, exactly what it
//! predicts for the framing view; a calibration fitted without them (no `view_box_coef`) ignores the view.

use crate::geom::Aabb;
use crate::geom::Camera;
use glam::Vec3;

/// Names of the view features, in the order of [`ViewFeatures::row`].
pub const VIEW_FEATURE_NAMES: [&str; 3] = ["eye_inside", "ln_coverage", "ln_distance"];

/// Side of the grid of primary rays that measures the coverage.
pub const COVERAGE_GRID: u32 = 32;

/// A camera reduced to what the cost model reads (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ViewFeatures {
    /// The eye lies in the bounds.
    pub eye_inside: bool,
    /// Share of the grid's primary rays that enter the bounds, in `[1 / COVERAGE_GRID^2, 1]`.
    pub coverage: f64,
    /// Distance of the eye from the centre over half the diagonal.
    pub distance: f64,
}

/// The camera the policy assumes without a view: [`Camera::frame`] of the box `lo`..`hi`.
pub(crate) fn framing_camera(lo: [f32; 3], hi: [f32; 3]) -> Camera {
    Camera::frame(&Aabb { min: Vec3::from_array(lo), max: Vec3::from_array(hi) })
}

impl ViewFeatures {
    /// The features of `camera` over the box `lo`..`hi` (an empty or non-finite box is the unit cube at the origin).
    pub fn of(camera: &Camera, lo: [f32; 3], hi: [f32; 3]) -> Self {
        let mut b = Aabb { min: Vec3::from_array(lo), max: Vec3::from_array(hi) };
        if b.is_empty() || !b.min.is_finite() || !b.max.is_finite() {
            b = Aabb { min: Vec3::splat(-0.5), max: Vec3::splat(0.5) };
        }
        let e = camera.eye;
        let eye_inside = e.cmpge(b.min).all() && e.cmple(b.max).all();
        let g = COVERAGE_GRID;
        let (min, max) = (b.min.to_array(), b.max.to_array());
        let mut hit = 0u32;
        for y in 0..g {
            for x in 0..g {
                let r = camera.ray(x, y, g, g);
                hit += crate::geom::RayInv::new(&r).slab(&min, &max, 0.0, f32::INFINITY).is_some() as u32;
            }
        }
        let floor = 1.0 / (g * g) as f64;
        let half = (b.extent().length() as f64 * 0.5).max(f64::MIN_POSITIVE);
        let half = if half.is_finite() && half > 0.0 { half } else { 1.0 };
        let d = (e - b.center()).length() as f64 / half;
        ViewFeatures {
            eye_inside,
            coverage: (hit as f64 / (g * g) as f64).max(floor),
            distance: if d.is_finite() { d } else { 1.0 },
        }
    }

    /// The framing camera's features for the box ([`Camera::frame`]): what the policy assumes without a view.
    pub fn framing(lo: [f32; 3], hi: [f32; 3]) -> Self {
        Self::of(&framing_camera(lo, hi), lo, hi)
    }

    /// The model's row, in [`VIEW_FEATURE_NAMES`] order.
    pub fn row(&self) -> [f64; 3] {
        [
            self.eye_inside as u8 as f64,
            self.coverage.max(1.0 / (COVERAGE_GRID * COVERAGE_GRID) as f64).ln(),
            self.distance.max(f64::MIN_POSITIVE).ln().clamp(-10.0, 10.0),
        ]
    }
}
