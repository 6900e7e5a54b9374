//! Workloads: primary rays at a given resolution (1024 x 1024 in the thesis), shadow rays to a point light, and
//! diffuse (incoherent) bounce rays.
//!
//! Shadow and diffuse rays start at the hit points of the primary rays; primary rays that miss spawn nothing. The
//! hit points come from a reference structure before any timing, so every structure traces the same rays.

use super::{trace, Camera};
use crate::accel::AccelStructure;
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

pub use crate::accel::bounce::{cosine_direction, diffuse_direction, turn_sin_cos};
pub use crate::geom::camera::{secondary_start, shadow_ray, surface_offset};

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

#[cfg(test)]
mod tests {
    use super::turn_sin_cos;

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
