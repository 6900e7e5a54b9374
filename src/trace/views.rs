//! Named camera presets for a scene's bounds: several views of one scene, so that workloads are not all seen from
//! the framing camera.
//!
//! | preset | [`View`] | camera |
//! |---|---|---|
//! | `framing` | [`View::Framing`] | [`Camera::frame`]: outside, the whole scene in view |
//! | `inside` | [`View::Inside`] | the eye inside the bounds, at `lo + (0.37, 0.42, 0.41) * extent` (off the planes of symmetry where walls of regular layouts lie), looking horizontally along the longest horizontal axis, 70 degree field of view: a player's view of an interior |
//! | `close-up` | [`View::CloseUp`] | looking at the centre from [`crate::geom::camera::AUTO_VIEW_DIRECTION`] at a fifth of the bounding radius, 30 degree field of view: a detail fills the image |
//! | `grazing` | [`View::Grazing`] | from outside along the longest axis, nearly parallel to the dominant plane (the one across the smallest extent): 2% of the bounding radius above the scene's top in that direction, looking at a point a tenth of the smallest extent above the centre |
//!
//! The presets depend on the bounds only. An empty or point-like box is treated as the unit cube around its centre
//! (the origin when empty), so every preset gives a camera with finite vectors for any finite box.

use crate::geom::Aabb;
use crate::geom::Camera;
use glam::Vec3;

/// A camera preset (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum View {
    /// The whole scene from outside ([`Camera::frame`]).
    Framing,
    /// The eye inside the bounds.
    Inside,
    /// Close to the centre, narrow field of view.
    CloseUp,
    /// Nearly parallel to the dominant plane.
    Grazing,
}

impl View {
    /// Every preset, in the order of the module docs.
    pub const ALL: [View; 4] = [View::Framing, View::Inside, View::CloseUp, View::Grazing];

    /// `framing`, `inside`, `close-up` or `grazing`.
    pub fn name(self) -> &'static str {
        match self {
            View::Framing => "framing",
            View::Inside => "inside",
            View::CloseUp => "close-up",
            View::Grazing => "grazing",
        }
    }

    /// Parses a name of [`View::name`] (case-insensitive; `closeup` and `close_up` are accepted too).
    pub fn from_name(s: &str) -> Option<View> {
        let s = s.trim().to_ascii_lowercase().replace('_', "-");
        if s == "closeup" {
            return Some(View::CloseUp);
        }
        View::ALL.into_iter().find(|v| v.name() == s)
    }

    /// The camera of this preset for `bounds` (see the module docs).
    pub fn camera(self, bounds: &Aabb) -> Camera {
        let b = usable(bounds);
        let (center, ext) = (b.center(), b.extent());
        let radius = (ext.length() * 0.5).max(f32::MIN_POSITIVE);
        match self {
            View::Framing => Camera::frame(&b),
            View::Inside => {
                let eye = b.min + ext * Vec3::new(0.37, 0.42, 0.41);
                let dir = if ext.x >= ext.z { Vec3::new(1.0, 0.0, 0.25) } else { Vec3::new(0.25, 0.0, 1.0) };
                look(eye, eye + dir * radius, Vec3::Y, 70.0)
            }
            View::CloseUp => {
                let dir = Vec3::from_array(crate::geom::camera::AUTO_VIEW_DIRECTION).normalize();
                look(center + dir * (0.2 * radius), center, Vec3::Y, 30.0)
            }
            View::Grazing => {
                // The dominant plane is across the smallest extent; the view runs along the longest axis.
                let thin = (0..3).min_by(|&a, &b| ext[a].total_cmp(&ext[b])).unwrap_or(1);
                let long = (0..3).filter(|&a| a != thin).max_by(|&a, &b| ext[a].total_cmp(&ext[b])).unwrap_or(0);
                let (mut n, mut l) = (Vec3::ZERO, Vec3::ZERO);
                n[thin] = 1.0;
                l[long] = 1.0;
                let target = center + n * (0.1 * ext[thin]);
                let eye = center - l * (0.5 * ext[long] + radius) + n * (0.5 * ext[thin] + 0.02 * radius);
                look(eye, target, n, 45.0)
            }
        }
    }
}

impl std::fmt::Display for View {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for View {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        View::from_name(s).ok_or_else(|| format!("unknown view {s:?} (framing, inside, close-up, grazing)"))
    }
}

/// Every preset's camera for `bounds`, in [`View::ALL`] order.
pub fn presets(bounds: &Aabb) -> Vec<(View, Camera)> {
    View::ALL.into_iter().map(|v| (v, v.camera(bounds))).collect()
}

/// The box the presets work on: `bounds` itself, or the unit cube around its centre when it is empty, a point, or
/// not finite.
fn usable(bounds: &Aabb) -> Aabb {
    let finite = bounds.min.is_finite() && bounds.max.is_finite();
    if bounds.is_empty() || !finite {
        return Aabb::new(Vec3::splat(-0.5), Vec3::splat(0.5));
    }
    let e = bounds.extent();
    if e.max_element() > 0.0 && e.is_finite() {
        *bounds
    } else {
        let c = bounds.center();
        Aabb::new(c - 0.5, c + 0.5)
    }
}

/// [`Camera::look_at`], falling back to a camera looking along the view direction with any perpendicular up when
/// the given up is parallel to it (never for the presets' directions, but the fallback keeps this total).
fn look(eye: Vec3, target: Vec3, up: Vec3, fov: f32) -> Camera {
    Camera::look_at(eye, target, up, fov)
        .or_else(|| Camera::look_at(eye, target, up.any_orthonormal_vector(), fov))
        .unwrap_or_else(|| Camera::frame(&Aabb::new(eye - 0.5, eye + 0.5)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for v in View::ALL {
            assert_eq!(View::from_name(v.name()), Some(v));
            assert_eq!(v.name().to_uppercase().parse::<View>(), Ok(v));
        }
        assert_eq!(View::from_name("closeup"), Some(View::CloseUp));
        assert_eq!(View::from_name("close_up"), Some(View::CloseUp));
        assert!("top".parse::<View>().is_err());
    }

    #[test]
    fn every_preset_is_finite_on_odd_boxes_and_inside_is_inside() {
        let boxes = [
            Aabb::new(Vec3::ZERO, Vec3::ONE),
            Aabb::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 1.0)),
            Aabb::new(Vec3::new(-1e4, -1e4, -1e4), Vec3::new(1e4, 1e4, 1e4)),
            Aabb::new(Vec3::splat(3.0), Vec3::splat(3.0)),
            Aabb::EMPTY,
        ];
        for b in boxes {
            for (v, c) in presets(&b) {
                assert!(c.eye.is_finite() && c.forward.is_finite() && c.up.is_finite(), "{v} on {b:?}: {c:?}");
                assert!((c.forward.length() - 1.0).abs() < 1e-4, "{v} on {b:?}");
                if v == View::Inside {
                    let u = usable(&b);
                    assert!(c.eye.cmpge(u.min).all() && c.eye.cmple(u.max).all(), "{v} on {b:?}: {}", c.eye);
                }
            }
        }
        // Grazing on a flat box: the view is nearly parallel to the plane, from above it.
        let flat = Aabb::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(10.0, 0.5, 8.0));
        let g = View::Grazing.camera(&flat);
        assert!(g.forward.y.abs() < 0.1 && g.forward.x > 0.9, "{g:?}");
        assert!(g.eye.y > 0.5, "{g:?}");
    }
}
