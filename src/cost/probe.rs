//! Probes: a structure built and a sample of a camera's rays traced through it, its box and triangle tests counted
//! ray by ray.
//!
//! The count laws of the cost model read features that describe the whole scene; where the geometry makes the
//! traversal of one view explode they can miss tenfold: in an LBVH a few large triangles whose centroids scatter
//! through the Morton order make every node above each of them as large as it; in any hierarchy, rays that can hit
//! nothing (zero-area triangles) descend every node their line crosses; a small object in a vast box lies outside
//! every calibration scene's features; and each structure's law misses in its own way where the geometry is new to
//! it (on long slivers the BIH makes twice the BVH's tests, and the grid five to ten times the triangle tests its
//! law says). For every view of a static scene it is given, the policy builds the LBVH (the cheapest hierarchy to
//! build), the binned-SAH BVH (the one it picks most), the BIH, the grid and the HLBVH ([`PROBED`]) and counts what
//! they do
//! (`Crossings::with_probes_but`): the same builders with the same options the oracle and the engine use (the
//! grid within the default selection budget), so that the counts are the structures' own on the sampled rays. The
//! primary sample is [`super::near_crossings`]'s where that pass runs (the rays through the pixel centres of a square
//! image of the camera, at most 32 x 32), the full 32 x 32 otherwise; on request, shadow and diffuse rays start at
//! their hits as the workloads start theirs (`geom::camera::secondary_start`, the shadow workload's light,
//! `accel::bounce::diffuse_direction`). Each count is a [`SampledMean`]. Each probe also reports the work its
//! build did ([`Probe::build_work`], [`crate::accel::AccelStructure::build_work`]), which prices the structure's
//! build ([`super::StructureModel::build_work_coef`]).
//!
//! How the policy uses them (`super::overlap_floor`, `super::TestFloor::sampled`,
//! `super::StructureModel::predict_floored`): for each kind of ray, where a structure's law misses its sampled
//! mean by more than its own error band (for a calibration traced on the CPU none, [`super::OWN_PROBE_BAND_CPU`]:
//! the probe traced the frame's own tree; for a device calibration [`super::PROBE_BAND`] times the fit's RMS error
//! either way, both read on `ln(1 + count)`), the count is held within two standard errors of that mean; within the
//! band the law stands. The
//! hierarchy that is not probed (the kd-tree) takes the probed hierarchies' correction
//! ([`super::SHARES_PROBES`], `super::CostModel::predict_floored`): exact counts for some structures beside others
//! whose laws miss in the same direction made the choices worse on the family records (`docs/cost-model.md`,
//! "Probes"). The grid's correction is its own and is not shared.

use super::overlap::SampledMean;
use crate::accel::bounce::diffuse_direction;
use crate::accel::StructureName;
use crate::geom::camera::{default_light, secondary_start, shadow_ray};
use crate::geom::{Aabb, Camera, Ray, TraceCounters, WorkloadKind};
use crate::mesh::Mesh;

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

/// The structures the policy probes (`Crossings::with_probes_but`): the LBVH, the binned-SAH BVH, the BIH, the
/// grid and the HLBVH. The BIH and the grid were added on 2026-12-05, once the band read
/// counts on `ln(1 + count)`: held out by family on the scene families, `calibrated_cv` 4.0% -> 2.8% (the engineering
/// family 11.5% -> 5.6%); without the BIH 4.8% (its sliver error is its own: 21% on the engineering family). The
/// HLBVH, which gained nothing on those records (2.8%), was added on 2026-12-06: on the records
/// measured again, and with the shipped calibration refitted on them, its shared correction left it 2.6-3.6x below
/// its counts where slivers or overlapping triangles make its traversal explode (the engineering family close up,
/// `overlapping:2000`: chosen there at 1.8x the best), and probed, the families read 2.4% / 3.0% -> 2.6% / 2.7% by
/// scene / by family (`docs/results/2026-12-05-cost-model-probes.md`). The BIH and the grid exist only with the `eval`
/// feature; a build that fails (or a grid past its count threshold, [`PROBE_GRID_BUDGET`]) gives no probe.
pub const PROBED: [StructureName; PROBES] =
    [StructureName::Lbvh, StructureName::Bvh, StructureName::Bih, StructureName::Grid, StructureName::Hlbvh];

/// The fewest rays of one kind a probe must have traced for the policy to read its counts
/// ([`super::RayCrossings::probe`]): 32, a 32nd of the full primary sample.
pub const MIN_PROBED_RAYS: usize = 32;

/// How many structures the policy probes ([`PROBED`]).
pub const PROBES: usize = 5;

/// The grid's cell-reference budget in a probe, `[per triangle, at least]`: 16 and `2^22`, the threshold past which
/// the selection's bound pass counts the grid's references exactly and prices its build by them instead
/// (`select::budget::grid_count_threshold`; also the kd-tree's default budget, `src/eval/tests/budget.rs` checks that they
/// agree), instead of the grid builder's own (64, at least `2^25`), so that a probe never spends the seconds a grid
/// of many large overlapping triangles can take: such a build fails at the budget after counting, and the grid gets
/// no probe.
pub const PROBE_GRID_BUDGET: [usize; 2] = [16, 1 << 22];

/// Builds a probed structure with the options the oracle and the engine use, the grid within [`PROBE_GRID_BUDGET`].
pub(crate) fn build_probed(structure: StructureName, mesh: &Mesh) -> Option<Box<dyn crate::accel::AccelStructure>> {
    #[cfg(feature = "eval")]
    if structure == StructureName::Grid {
        let o = crate::accel::grid::GridOptions {
            max_references_per_triangle: PROBE_GRID_BUDGET[0],
            min_reference_budget: PROBE_GRID_BUDGET[1],
            ..Default::default()
        };
        return crate::accel::grid::Grid::build_with(mesh, &o).ok().map(|g| Box::new(g) as _);
    }
    crate::accel::build_structure(structure, mesh).ok()
}

/// What [`probe`] counts: a structure's tests per ray of each workload on the sample of one camera's rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Probe {
    /// The primary rays of the sample.
    pub primary: ProbeCounts,
    /// The shadow rays their hits start (to [`default_light`] of the scene's box), when traced.
    pub shadow: ProbeCounts,
    /// The diffuse rays their hits start, when traced.
    pub diffuse: ProbeCounts,
    /// The work of the probe's build ([`crate::accel::AccelStructure::build_work`] of the built structure), which
    /// the build law reads ([`super::StructureModel::build_work_coef`]); 0 when unknown (an empty structure).
    pub build_work: f64,
}

impl Probe {
    /// The counts of one kind of ray.
    pub(crate) fn of_kind(&self, kind: WorkloadKind) -> &ProbeCounts {
        match kind {
            WorkloadKind::Primary => &self.primary,
            WorkloadKind::Shadow => &self.shadow,
            WorkloadKind::Diffuse => &self.diffuse,
        }
    }
}

/// Seed of the probe's diffuse bounces (per ray, mixed with the ray's index as the diffuse workload mixes its own).
const PROBE_SEED: u64 = 0x7072_6f62_655f_6c62;

/// Builds `structure` over `mesh` (default options: what the oracle and the engine build; the grid within
/// [`PROBE_GRID_BUDGET`], whatever budget the caller's policy uses) and traces the
/// `side x side` rays of `camera` through the pixel centres, then, with `secondary`, a shadow and a diffuse ray from
/// each hit, counting the tests of each ray ([`Probe`]; without `secondary` its shadow and diffuse counts are empty,
/// no ray); `bounds` is the box of the mesh's triangles (where the secondary rays' offsets and the light come from).
/// The policy traces all three (`Crossings::with_probes_but`). `None` when the structure cannot be built (an
/// invalid mesh, too many triangles, a structure this build lacks) or for `side` 0. Deterministic: the counts are
/// integers and each ray is traced alone.
pub fn probe(
    structure: StructureName,
    mesh: &Mesh,
    bounds: &Aabb,
    camera: &Camera,
    side: u32,
    secondary: bool,
) -> Option<Probe> {
    use rayon::prelude::*;
    if side == 0 {
        return None;
    }
    let built = build_probed(structure, mesh)?;
    let accel = built.as_ref();
    let light = default_light(bounds);
    let s = side as usize;
    type Traced = (TraceCounters, Option<(Option<TraceCounters>, TraceCounters)>);
    let traced: Vec<Traced> = crate::in_pool(|| {
        (0..s * s)
            .into_par_iter()
            .map(|k| {
                let ray = camera.ray((k % s) as u32, (k / s) as u32, side, side);
                let mut c = TraceCounters::default();
                let hit = accel.intersect(&ray, &mut c);
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
                        accel.occluded(&shadow, &mut sc);
                        sc
                    });
                    let mut dc = TraceCounters::default();
                    accel.intersect(&Ray::new(origin, diffuse_direction(n, PROBE_SEED, k)), &mut dc);
                    Some((sc, dc))
                });
                (c, second)
            })
            .collect()
    });
    let primary: Vec<TraceCounters> = traced.iter().map(|t| t.0).collect();
    let shadow: Vec<TraceCounters> = traced.iter().filter_map(|t| t.1.and_then(|s| s.0)).collect();
    let diffuse: Vec<TraceCounters> = traced.iter().filter_map(|t| t.1.map(|s| s.1)).collect();
    Some(Probe {
        primary: ProbeCounts::of(&primary),
        shadow: ProbeCounts::of(&shadow),
        diffuse: ProbeCounts::of(&diffuse),
        build_work: accel.build_work().unwrap_or(0.0),
    })
}
