//! Timed probes: the candidate structures built and a sample of the view's rays traced through each, both timed on
//! this machine, and the cost model's predictions blended with what they measured.
//!
//! The count probes ([`super::probe()`]) make the policy's test counts exact on a sample; what stays predicted is
//! the time per build and per test, and those are where the held-out errors were left (on the scene families,
//! replacing the predicted builds of every structure by the measured ones took the mean regret of primary rays from
//! 3.1% to 1.8%, and the traces from 3.1% to 1.4%, `docs/results/2026-12-06-cost-model-curved-builds-incoherent-price.md`). A timed probe measures
//! them directly, at a price: every contender (`contenders`) is built once (the count probes already build five of
//! the six structures) and [`TIMED_SIDE`]`^2` rays of the workload's kind are traced through each, on one thread, a
//! few times ([`TIMED_REPEATS`], the fastest kept: interruptions only ever add time).
//!
//! A probe's times are not the oracle's: one build, cold, against the median of many; one thread against the
//! tracer's pool; a sample whose rays are fewer and less coherent than the frame's. The calibration fits, per
//! structure, the ratio of the oracle's build to the probe's and, per structure and kind of ray, of the oracle's
//! time per ray to the probe's ([`TimedRatios::fit`]: the median of the log ratios over its records). A probe is
//! noisy where the cost model is biased, so neither replaces the other: the policy takes the geometric mean of the
//! two, for the build and for the time per ray apart ([`blend`]). The weight (one half each) was not fitted.
//!
//! Timed probes are not deterministic: two runs may choose differently where two structures are close. They are
//! off by default: a caller asks for them with [`crate::select::Selector`], level 2 (or
//! `crate::select::BuildBounds::with_timed_probes`, which [`crate::select::CalibratedPolicy::timed_probes`]
//! reads); `evaluate --compare-policies --timed-probes` scores them against the deterministic policy on the same
//! records (`docs/results/2026-12-06-cost-model-timed-probes.md`).

use crate::accel::{AccelStructure, StructureName};
use crate::geom::camera::default_light;
use crate::geom::{Aabb, Camera, Ray, TraceCounters, WorkloadKind};
use crate::mesh::Mesh;
use std::time::Instant;

/// The side of the square image of primary rays a timed probe traces (and whose hits start its shadow and diffuse
/// rays): 64, 4,096 rays.
pub const TIMED_SIDE: u32 = 64;

/// The most times a timed probe traces its sample of one kind through one structure; it keeps the fastest.
pub const TIMED_REPEATS: usize = 5;

/// After this many milliseconds spent tracing one structure's sample of one kind, a timed probe stops repeating
/// (it always makes at least two traces).
pub const TIMED_TRACE_CAP_MS: f64 = 100.0;

/// The fewest rays of one kind a timed probe's time per ray is read on: fewer (a sparse view's few hits) give a
/// time dominated by the clock's own cost.
pub const TIMED_MIN_RAYS: usize = 64;

/// A structure is worth a timed probe when the model predicts its total within this factor of the least predicted
/// total (`contenders`): on the scene families (held out by family) probing only those gave the same choices as
/// probing all six, with 3.4 structures probed on average instead of 6 (1.5: 2.2 probed, primary rays' mean regret
/// 0.65% -> 0.83%); the factor was chosen on those records.
pub const CONTENDER_FACTOR: f64 = 2.0;

/// The structures of `preds` whose predicted total is finite and within [`CONTENDER_FACTOR`] of the least: the
/// ones a timed probe could make the cheapest.
pub(crate) fn contenders(preds: &[super::Prediction]) -> Vec<StructureName> {
    let least = preds.iter().map(|p| p.total_ms).filter(|t| t.is_finite()).fold(f64::INFINITY, f64::min);
    preds
        .iter()
        .filter(|p| p.total_ms.is_finite() && p.total_ms <= CONTENDER_FACTOR * least)
        .map(|p| p.structure)
        .collect()
}

/// [`blend`] with only the probes of `preds`'s `contenders` (what the policy probes,
/// [`crate::select::Selector`], level 2): the one blend of the evaluations, which are given every structure's
/// probe.
pub fn blend_contenders(
    preds: &mut [super::Prediction],
    timed: &[TimedProbe],
    ratios: &TimedRatios,
    w: &super::Workload,
) -> usize {
    let only = contenders(preds);
    let probes: Vec<TimedProbe> = timed.iter().filter(|p| only.contains(&p.structure)).copied().collect();
    blend(preds, &probes, ratios, w)
}

/// What one structure's timed probe measured.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TimedProbe {
    /// The structure.
    pub structure: StructureName,
    /// Wall time of its one build, ms.
    pub build_ms: f64,
    /// Per kind of ray (primary, shadow, diffuse: `kind_index`), the fastest time per ray over the repeats, ns,
    /// on one thread; NaN where fewer than [`TIMED_MIN_RAYS`] rays of that kind were traced.
    pub trace_ns_per_ray: [f64; 3],
    /// Per kind of ray, how many were traced.
    pub rays: [usize; 3],
}

impl TimedProbe {
    /// The time per ray of `kind`, when measured on enough rays.
    pub(crate) fn ns_per_ray(&self, kind: WorkloadKind) -> Option<f64> {
        let i = kind_index(kind);
        let t = self.trace_ns_per_ray[i];
        (self.rays[i] >= TIMED_MIN_RAYS && t.is_finite() && t > 0.0).then_some(t)
    }

    /// The build time, when measured.
    pub fn build(&self) -> Option<f64> {
        (self.build_ms.is_finite() && self.build_ms > 0.0).then_some(self.build_ms)
    }
}

/// The index of a kind of ray in [`TimedProbe::trace_ns_per_ray`] and [`StructureRatios::trace`]: primary 0, shadow 1,
/// diffuse 2.
pub(crate) fn kind_index(kind: WorkloadKind) -> usize {
    match kind {
        WorkloadKind::Primary => 0,
        WorkloadKind::Shadow => 1,
        WorkloadKind::Diffuse => 2,
    }
}

/// Builds each of `structures` over `mesh` and times its build, then traces through each a sample of `kinds` rays
/// of `camera` ([`TIMED_SIDE`] squared primary rays through the pixel centres; the shadow and diffuse rays their
/// hits start, as the workloads start theirs), on this thread, and keeps the
/// fastest of up to [`TIMED_REPEATS`] traces per kind. A structure that does not build (or a grid past the
/// probes' budget, [`super::probe::PROBE_GRID_BUDGET`]) has no probe. Every structure traces the same rays: the
/// secondary rays start at the first built structure's hits.
pub(crate) fn time_probes(
    mesh: &Mesh,
    camera: &Camera,
    structures: &[StructureName],
    kinds: &[WorkloadKind],
) -> Vec<TimedProbe> {
    // One structure at a time (built, timed, dropped), so that at most one is held beside the mesh; the first one
    // built makes the sample's rays.
    let mut sets: Option<Vec<(usize, RaySample)>> = None;
    let mut out = Vec::new();
    for &s in structures {
        let t = Instant::now();
        let Some(accel) = super::probe::build_probed(s, mesh) else { continue };
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let sets = sets.get_or_insert_with(|| {
            kinds.iter().map(|&k| (kind_index(k), view_rays(k, mesh, camera, accel.as_ref(), TIMED_SIDE))).collect()
        });
        let mut p = TimedProbe { structure: s, build_ms: ms, trace_ns_per_ray: [f64::NAN; 3], rays: [0; 3] };
        for (i, set) in sets.iter() {
            p.rays[*i] = set.rays.len();
            if set.rays.len() >= TIMED_MIN_RAYS {
                p.trace_ns_per_ray[*i] = fastest_trace(accel.as_ref(), set);
            }
        }
        out.push(p);
    }
    out
}

/// A timed probe's (or a measured frame's) rays of one kind, and whether they are any-hit (shadow) queries.
pub(crate) struct RaySample {
    pub(crate) rays: Vec<Ray>,
    pub(crate) any_hit: bool,
}

/// Seed of a timed probe's diffuse bounces (per ray, mixed with the primary ray's index as the workloads mix theirs).
const TIMED_SEED: u64 = 0x7469_6d65_645f_7072;

/// The box of a mesh's triangles (empty without triangles).
pub(crate) fn mesh_box(mesh: &Mesh) -> Aabb {
    let mut b = Aabb::EMPTY;
    for p in mesh.indices.iter().flatten().filter_map(|&i| mesh.positions.get(i as usize)) {
        b.grow(glam::Vec3::from_array(*p));
    }
    b
}

/// The `side`^2 primary rays of `camera` through the pixel centres (row by row), or for shadow and diffuse rays
/// the rays their hits in `reference` start, as the workloads start theirs (`geom::camera::secondary_start`, the
/// scene's default light, `accel::bounce::diffuse_direction`).
pub(crate) fn view_rays(
    kind: WorkloadKind,
    mesh: &Mesh,
    camera: &Camera,
    reference: &dyn AccelStructure,
    side: u32,
) -> RaySample {
    let s = side;
    let primary: Vec<Ray> = (0..s * s).map(|k| camera.ray(k % s, k / s, s, s)).collect();
    if kind == WorkloadKind::Primary {
        return RaySample { rays: primary, any_hit: false };
    }
    let bounds = mesh_box(mesh);
    let light = default_light(&bounds);
    // The hits on the pool (a measured frame's primary rays are many), the rays from them in order.
    let hits: Vec<Option<crate::geom::Hit>> = {
        use rayon::prelude::*;
        let mut out = Vec::new();
        primary.par_iter().map(|r| reference.intersect(r, &mut TraceCounters::default())).collect_into_vec(&mut out);
        out
    };
    let rays = crate::accel::bounce::secondary_from_hits(kind, mesh, &primary, &hits, &bounds, light, TIMED_SEED);
    RaySample { rays, any_hit: kind == WorkloadKind::Shadow }
}

/// The fastest of up to [`TIMED_REPEATS`] single-threaded traces of `set` through `accel`, ns per ray.
fn fastest_trace(accel: &dyn AccelStructure, set: &RaySample) -> f64 {
    let mut best = f64::INFINITY;
    let mut spent = 0.0;
    for r in 0..TIMED_REPEATS {
        let t = Instant::now();
        let mut c = TraceCounters::default();
        let mut hits = 0usize;
        for ray in &set.rays {
            hits +=
                if set.any_hit { accel.occluded(ray, &mut c) } else { accel.intersect(ray, &mut c).is_some() } as usize;
        }
        std::hint::black_box((hits, c));
        let ms = t.elapsed().as_secs_f64() * 1e3;
        best = best.min(ms);
        spent += ms;
        if r >= 1 && spent > TIMED_TRACE_CAP_MS {
            break;
        }
    }
    best * 1e6 / set.rays.len().max(1) as f64
}

/// What turns a timed probe into the oracle's times, fitted per calibration ([`TimedRatios::fit`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimedRatios {
    /// Per structure with a timed probe in the calibration's records, in [`StructureName::ALL`]'s order.
    pub structures: Vec<StructureRatios>,
    /// How many records the ratios were fitted on.
    pub records: usize,
}

/// One structure's [`TimedRatios`]: each the median over the calibration's records of the records' time over the
/// probe's, as `exp(median(ln ratio))`; `None` where no record had both.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StructureRatios {
    /// The structure.
    pub structure: StructureName,
    /// Of one build.
    pub build: Option<f64>,
    /// Of the time per ray, per kind of ray (primary, shadow, diffuse: `kind_index`).
    pub trace: [Option<f64>; 3],
}

/// The range a ratio of [`TimedRatios`] must lie in for a calibration file to be valid: a probe and the oracle
/// differ by threads, caches and repeats, not by orders of magnitude.
pub const TIMED_RATIO_RANGE: [f64; 2] = [1e-3, 1e3];

impl TimedRatios {
    /// The ratios of `structure`, when fitted.
    pub fn of(&self, structure: StructureName) -> Option<&StructureRatios> {
        self.structures.iter().find(|r| r.structure == structure)
    }

    /// Checks that every ratio given is within [`TIMED_RATIO_RANGE`] and each structure appears once.
    pub fn validate(&self) -> Result<(), String> {
        for (i, r) in self.structures.iter().enumerate() {
            if self.structures[..i].iter().any(|o| o.structure == r.structure) {
                return Err(format!("{} appears twice", r.structure));
            }
            for x in std::iter::once(r.build).chain(r.trace).flatten() {
                if !(TIMED_RATIO_RANGE[0]..=TIMED_RATIO_RANGE[1]).contains(&x) {
                    return Err(format!(
                        "ratio {x} of {} outside [{}, {}]",
                        r.structure, TIMED_RATIO_RANGE[0], TIMED_RATIO_RANGE[1]
                    ));
                }
            }
        }
        Ok(())
    }
}

/// The predictions `preds` of a static scene (one build) blended with its timed probes `timed` under `ratios`: for
/// each structure with a probe and fitted ratios, the build of one build becomes the geometric mean of the
/// predicted one and the probe's times its ratio, and the time per ray likewise for the workload's kind; totals
/// follow (`build_ms` times the builds, the trace over the predicted rays). Structures without a probe, a ratio or
/// a positive prediction keep their predictions. Returns how many predictions were blended.
pub fn blend(
    preds: &mut [super::Prediction],
    timed: &[TimedProbe],
    ratios: &TimedRatios,
    w: &super::Workload,
) -> usize {
    let mut n = 0;
    for p in preds.iter_mut() {
        let (Some(t), Some(r)) = (timed.iter().find(|t| t.structure == p.structure), ratios.of(p.structure)) else {
            continue;
        };
        let mut blended = false;
        let usable = |x: f64| x.is_finite() && x > 0.0;
        if let (Some(b), Some(rb)) = (t.build(), r.build.filter(|_| usable(p.build_ms_per_build))) {
            let per = (p.build_ms_per_build * rb * b).sqrt();
            if usable(per) {
                p.build_ms = per * w.builds as f64;
                p.build_ms_per_build = per;
                blended = true;
            }
        }
        let rk = r.trace[kind_index(w.kind)];
        if let (Some(ns), Some(rk)) = (t.ns_per_ray(w.kind), rk.filter(|_| usable(p.trace_ns_per_ray))) {
            let per = (p.trace_ns_per_ray * rk * ns).sqrt();
            if usable(per) && p.trace_ms.is_finite() {
                p.trace_ms *= per / p.trace_ns_per_ray;
                p.trace_ns_per_ray = per;
                blended = true;
            }
        }
        if blended {
            p.total_ms = p.build_ms + p.trace_ms;
            n += 1;
        }
    }
    n
}

/// The median of `v` (the mean of the middle two for an even count); `None` when empty.
pub(crate) fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(v[n / 2]),
        _ => Some(0.5 * (v[n / 2 - 1] + v[n / 2])),
    }
}
