//! The LBVH probe: the LBVH built and a sample of a camera's rays traced through it, its box and triangle tests
//! counted ray by ray.
//!
//! The count laws of the cost model read features that describe the whole scene; where the geometry makes the
//! traversal of one view explode (large triangles whose centroids scatter through the Morton order, so that every
//! node above one is as large as it), they can miss tenfold. The LBVH is the cheapest hierarchy to build (a Morton
//! sort and one pass), so the policy can afford to build it and count what it does: the same builder with the same
//! options the oracle and the engine use, so that the counts are the LBVH's own on the sampled rays. The primary
//! sample is [`super::near_crossings`]'s (the rays through the pixel centres of a square image of the camera, at
//! most 32 x 32); on request, shadow and diffuse rays start at their hits as the workloads start theirs
//! (`geom::camera::secondary_start`, the shadow workload's light, cosine-distributed bounces). Each count is a
//! [`SampledMean`].
//!
//! How the policy uses it ([`super::overlap_floor`], [`super::TestFloor::sampled`],
//! [`super::StructureModel::predict_floored`]): for primary rays, where the LBVH law's count lies outside its own
//! error band about the sampled mean (twice the fit's RMS log error either way), the count is held within two
//! standard errors of that mean. Within the band the law stands, and secondary rays keep their laws: giving the
//! LBVH exact counts where the other structures' laws miss in the same direction made the choices worse on the
//! family records (`docs/cost-model.md`, "The LBVH probe").

use super::overlap::SampledMean;
use crate::accel::bounce::cosine_direction;
use crate::geom::camera::{default_light, secondary_start, shadow_ray};
use crate::geom::{Aabb, Camera, Ray, TraceCounters, WorkloadKind};
use crate::mesh::Mesh;
use crate::rng::SplitMix64;

/// A structure's tests per ray, counted on a sample of rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ProbeCounts {
    /// Box tests per ray.
    pub box_tests: SampledMean,
    /// Triangle tests per ray.
    pub prim_tests: SampledMean,
}

impl ProbeCounts {
    fn of(counters: &[TraceCounters]) -> ProbeCounts {
        let sat = |x: u64| u32::try_from(x).unwrap_or(u32::MAX);
        let b: Vec<u32> = counters.iter().map(|c| sat(c.box_tests)).collect();
        let p: Vec<u32> = counters.iter().map(|c| sat(c.prim_tests)).collect();
        ProbeCounts { box_tests: SampledMean::of(&b), prim_tests: SampledMean::of(&p) }
    }
}

/// What [`lbvh_probe`] counts: the LBVH's tests per ray of each workload on the sample of one camera's rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct LbvhProbe {
    /// The primary rays of the sample.
    pub primary: ProbeCounts,
    /// The shadow rays their hits start (to [`default_light`] of the scene's box), when traced.
    pub shadow: ProbeCounts,
    /// The diffuse rays their hits start, when traced.
    pub diffuse: ProbeCounts,
}

impl LbvhProbe {
    /// The counts of one kind of ray.
    pub fn of_kind(&self, kind: WorkloadKind) -> &ProbeCounts {
        match kind {
            WorkloadKind::Primary => &self.primary,
            WorkloadKind::Shadow => &self.shadow,
            WorkloadKind::Diffuse => &self.diffuse,
        }
    }
}

/// Seed of the probe's diffuse bounces (per ray, mixed with the ray's index as the diffuse workload mixes its own).
const PROBE_SEED: u64 = 0x7072_6f62_655f_6c62;

/// Builds the LBVH of `mesh` (default options: what the oracle and the engine build) and traces the `side x side`
/// rays of `camera` through the pixel centres, then, with `secondary`, a shadow and a diffuse ray from each hit,
/// counting the tests of each ray ([`LbvhProbe`]; without `secondary` its shadow and diffuse counts are empty, no
/// ray); `bounds` is the box of the mesh's triangles (where the secondary rays' offsets and the light come from).
/// The policy traces primary rays alone ([`super::Crossings::with_lbvh_probe`]): it uses no secondary count.
/// `None` when the LBVH cannot be built (an invalid mesh, too many triangles) or for `side` 0. Deterministic: the
/// counts are integers and each ray is traced alone.
pub fn lbvh_probe(mesh: &Mesh, bounds: &Aabb, camera: &Camera, side: u32, secondary: bool) -> Option<LbvhProbe> {
    use crate::accel::AccelStructure;
    use rayon::prelude::*;
    if side == 0 {
        return None;
    }
    let lbvh = crate::accel::lbvh::Lbvh::build(mesh).ok()?;
    let light = default_light(bounds);
    let s = side as usize;
    type Traced = (TraceCounters, Option<(Option<TraceCounters>, TraceCounters)>);
    let traced: Vec<Traced> = crate::in_pool(|| {
        (0..s * s)
            .into_par_iter()
            .map(|k| {
                let ray = camera.ray((k % s) as u32, (k / s) as u32, side, side);
                let mut c = TraceCounters::default();
                let hit = lbvh.intersect(&ray, &mut c);
                let second = hit.filter(|_| secondary).and_then(|h| {
                    let i = h.triangle as usize;
                    if i >= mesh.triangle_count() {
                        return None;
                    }
                    let tri = crate::geom::Triangle::new(&mesh.triangle(i));
                    let (origin, n) = secondary_start(&tri, ray.origin + ray.dir * h.t, ray.dir, bounds)?;
                    // A shadow ray whose origin is the light itself is not traced by the workload either.
                    let sc = shadow_ray(origin, light).map(|shadow| {
                        let mut sc = TraceCounters::default();
                        lbvh.occluded(&shadow, &mut sc);
                        sc
                    });
                    let mut rng = SplitMix64(PROBE_SEED ^ (k as u64).wrapping_mul(0x2545_f491_4f6c_dd1d));
                    let mut dc = TraceCounters::default();
                    lbvh.intersect(&Ray::new(origin, cosine_direction(n, &mut rng)), &mut dc);
                    Some((sc, dc))
                });
                (c, second)
            })
            .collect()
    });
    let primary: Vec<TraceCounters> = traced.iter().map(|t| t.0).collect();
    let shadow: Vec<TraceCounters> = traced.iter().filter_map(|t| t.1.and_then(|s| s.0)).collect();
    let diffuse: Vec<TraceCounters> = traced.iter().filter_map(|t| t.1.map(|s| s.1)).collect();
    Some(LbvhProbe {
        primary: ProbeCounts::of(&primary),
        shadow: ProbeCounts::of(&shadow),
        diffuse: ProbeCounts::of(&diffuse),
    })
}
