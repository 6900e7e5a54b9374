//! Workloads: primary rays at a given resolution (1024 x 1024 in the thesis), shadow rays to a point light, and
//! diffuse (incoherent) bounce rays.
//!
//! Shadow and diffuse rays start at the hit points of the primary rays; primary rays that miss spawn nothing. The
//! hit points come from a reference structure before any timing, so every structure traces the same rays.

use super::trace;
use crate::accel::AccelStructure;
use crate::geom::Camera;
use crate::geom::{Aabb, Hit, Ray, WorkloadKind};
use crate::mesh::Mesh;
use glam::Vec3;

/// A set of rays to trace, and whether they are any-hit (shadow) queries.
#[derive(Clone, Debug)]
pub struct RaySet {
    /// What kind of rays.
    pub kind: WorkloadKind,
    /// The rays.
    pub rays: Vec<Ray>,
    /// Any-hit (occlusion) queries instead of closest hit.
    pub any_hit: bool,
}

/// Bounding box of a mesh's triangles (empty for a mesh without triangles).
pub fn mesh_bounds(mesh: &Mesh) -> Aabb {
    let mut b = Aabb::EMPTY;
    for t in &mesh.indices {
        for &i in t {
            if let Some(p) = mesh.positions.get(i as usize) {
                b.grow(Vec3::from_array(*p));
            }
        }
    }
    b
}

/// Primary rays of `camera` for a `width x height` image, row by row.
pub fn primary_rays(camera: &Camera, width: u32, height: u32) -> Vec<Ray> {
    let mut rays = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height {
        for x in 0..width {
            rays.push(camera.ray(x, y, width, height));
        }
    }
    rays
}

pub use crate::geom::camera::default_light;

pub use crate::rng::SplitMix64;

/// Secondary rays from the hits of `primary`: shadow rays to `light` (any hit, `tmax` just short of the light) or
/// diffuse rays (closest hit). Deterministic for a given `seed`.
pub fn secondary_rays(
    kind: WorkloadKind,
    mesh: &Mesh,
    primary: &[Ray],
    hits: &[Option<Hit>],
    light: Vec3,
    seed: u64,
) -> RaySet {
    let rays = crate::accel::bounce::secondary_from_hits(kind, mesh, primary, hits, &mesh_bounds(mesh), light, seed);
    RaySet { kind, rays, any_hit: kind == WorkloadKind::Shadow }
}

/// Seed of the diffuse rays of [`build_workload`] (the device makes the same rays from it).
pub const WORKLOAD_SEED: u64 = 0x6d65_7368_6368_6172;

/// The rays of a workload for one frame: primary rays of `camera` at `resolution x resolution`, or secondary rays
/// from their hits in `reference` (traced here, before any timing).
pub fn build_workload(
    kind: WorkloadKind,
    mesh: &Mesh,
    camera: &Camera,
    resolution: u32,
    reference: &dyn AccelStructure,
) -> RaySet {
    let primary =
        RaySet { kind: WorkloadKind::Primary, rays: primary_rays(camera, resolution, resolution), any_hit: false };
    if kind == WorkloadKind::Primary {
        return primary;
    }
    let out = trace(reference, &primary);
    let light = default_light(&mesh_bounds(mesh));
    secondary_rays(kind, mesh, &primary.rays, &out.hits, light, WORKLOAD_SEED)
}

/// The largest side of the sample of primary rays [`estimate_secondary_rays`] traces by default: 128 x 128 = 16,384
/// rays, the whole image at 128 x 128 and below.
pub const SECONDARY_SAMPLE_SIDE: u32 = 128;

/// The most [`estimate_secondary_rays`] samples whatever it is asked: 1024 x 1024 primary rays (about 100 MiB at
/// most: the primary rays, their hits and the secondary rays they make, 32 MiB each, beside the reference LBVH).
pub const MAX_SECONDARY_SAMPLE_SIDE: u32 = 1024;

/// Why [`estimate_secondary_rays`] gave no estimate.
#[derive(Debug, thiserror::Error)]
pub enum SecondaryEstimateError {
    /// The reference LBVH did not build.
    #[error("the reference LBVH: {0}")]
    Build(#[from] crate::accel::AccelError),
    /// The sample's rays would make more tests each than the trace budget allows
    /// ([`super::check_trace_budget`], [`super::DEFAULT_MAX_TESTS_PER_RAY`]): the reason.
    #[error("{0}")]
    OverBudget(String),
}

/// How many secondary rays a frame makes, estimated from a sample of its primary rays ([`estimate_secondary_rays`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SecondaryRayEstimate {
    /// The estimate: secondary rays of one frame at the full resolution.
    pub rays: u64,
    /// Side of the sample: `side x side` primary rays were traced, spread evenly over the image.
    pub side: u32,
    /// Secondary rays the sample made (a primary ray that hits makes at most one).
    pub made: u64,
    /// Wall time of the estimate (a reference LBVH built over the mesh, the sample traced), ms.
    pub ms: f64,
}

/// How many `kind` rays one frame of `camera` at `resolution x resolution` makes: for primary rays the image's
/// pixels; for shadow and diffuse rays, one per primary ray that hits and starts one (as [`build_workload`] makes
/// them), estimated by tracing an evenly spread sample of at most `max_side x max_side` of the primary rays
/// (`max_side` at most [`MAX_SECONDARY_SAMPLE_SIDE`]; the pixels at the centres of the sample's cells) through a
/// reference LBVH and scaling what they make to the image.
/// When the sample is the whole image (`resolution <= max_side`) the count is the workload's own (up to ties between
/// equally close hits). An error when the LBVH does not build or the rays would make more tests each than the trace
/// budget allows ([`super::check_trace_budget`] on a sample of them). This is what the calibrated policy is to be
/// told as the rays per frame of a secondary workload when the caller does not know it; an engine that does (its
/// primary pass's hits) passes its own.
pub fn estimate_secondary_rays(
    kind: WorkloadKind,
    mesh: &Mesh,
    camera: &Camera,
    resolution: u32,
    max_side: u32,
) -> Result<SecondaryRayEstimate, SecondaryEstimateError> {
    let pixels = u64::from(resolution) * u64::from(resolution);
    if kind == WorkloadKind::Primary {
        return Ok(SecondaryRayEstimate { rays: pixels, side: resolution, made: pixels, ms: 0.0 });
    }
    let t = std::time::Instant::now();
    let side = resolution.min(max_side.clamp(1, MAX_SECONDARY_SAMPLE_SIDE));
    if side == 0 || mesh.triangle_count() == 0 {
        return Ok(SecondaryRayEstimate { rays: 0, side, made: 0, ms: 0.0 });
    }
    // The centre pixel of each of the sample's `side x side` cells (every pixel when `side == resolution`).
    let at = |i: u32| ((2 * u64::from(i) + 1) * u64::from(resolution) / (2 * u64::from(side))) as u32;
    let mut primary = Vec::with_capacity(side as usize * side as usize);
    for y in 0..side {
        for x in 0..side {
            primary.push(camera.ray(at(x), at(y), resolution, resolution));
        }
    }
    let reference = crate::accel::build_structure(crate::accel::StructureName::Lbvh, mesh)?;
    let set = RaySet { kind: WorkloadKind::Primary, rays: primary, any_hit: false };
    // Heavily overlapping or coincident triangles: refused on a sample of the rays before all of them are traced.
    super::check_trace_budget(reference.as_ref(), &set, super::DEFAULT_MAX_TESTS_PER_RAY)
        .map_err(SecondaryEstimateError::OverBudget)?;
    let hits = trace(reference.as_ref(), &set).hits;
    let bounds = mesh_bounds(mesh);
    let made = crate::accel::bounce::secondary_from_hits(
        kind,
        mesh,
        &set.rays,
        &hits,
        &bounds,
        default_light(&bounds),
        WORKLOAD_SEED,
    )
    .len() as u64;
    let sampled = u64::from(side) * u64::from(side);
    // Rounded to the nearest ray, in integers.
    let rays = ((u128::from(made) * u128::from(pixels) + u128::from(sampled / 2)) / u128::from(sampled)) as u64;
    Ok(SecondaryRayEstimate { rays, side, made, ms: t.elapsed().as_secs_f64() * 1e3 })
}

#[cfg(test)]
mod tests {
    use crate::accel::bounce::turn_sin_cos;

    #[test]
    fn turn_sin_cos_is_close_to_the_library() {
        for i in 0..=4096 {
            let u = (i as f32 / 4096.0).min(1.0 - f32::EPSILON / 2.0);
            let (s, c) = turn_sin_cos(u);
            let phi = std::f64::consts::TAU * u as f64;
            assert!((s as f64 - phi.sin()).abs() < 2e-7 && (c as f64 - phi.cos()).abs() < 2e-7, "{u}: {s} {c}");
        }
        assert_eq!(turn_sin_cos(0.0), (0.0, 1.0));
        assert_eq!(turn_sin_cos(0.25).0, 1.0);
    }
}
