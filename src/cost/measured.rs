//! Measured close calls: when the policy's best predictions lie close together, the closest structures built and a
//! whole frame of the view's rays traced through each, a few times, and the cheapest measured taken.
//!
//! The cost model and the timed probes ([`super::timed`]) leave their worst choices where two structures are
//! predicted within a few tens of percent of each other: the probes' sample is a 64 x 64 image traced on one
//! thread, the model's errors are of that size, and the oracle's truth is a whole frame on the tracer's pool. A
//! close call is settled here by measuring as the oracle measures: each structure whose predicted total lies
//! within [`CLOSE_CALL_MARGIN`] of the least is built (timed) and traced over a whole frame of rays of the
//! workload's kind (timed, on rayon's pool, as the oracle's tracer; the rays made as the workloads make theirs, the
//! diffuse directions from this module's own seed), [`MEASURED_REPEATS`] times after [`MEASURED_WARMUP`] untimed
//! rounds, interleaved across the structures
//! so that drift hits them alike; each repeat's total is its build times the builds plus its trace times the frames,
//! and the median of those totals decides ([`FrameTiming::total_ms`]).
//!
//! This costs what it measures: [`MEASURED_WARMUP`] + [`MEASURED_REPEATS`] builds and frames of every structure
//! measured (on the scene families, 2.3 structures where there is a close call, each about 1.2x the best one's
//! frame: some 11 frames of the best structure; `docs/results/2026-12-06-cost-model-measured-close-calls.md`). It pays where the
//! structure is kept for many frames, or built once for a long run; it is off by default and bounded by a budget
//! the caller gives ([`crate::select::Selector`], level 3).

use crate::accel::{AccelStructure, StructureName};
use crate::geom::{Camera, Ray, TraceCounters, WorkloadKind};
use crate::mesh::Mesh;
use rayon::prelude::*;
use std::time::Instant;

/// Untimed rounds (every structure built and traced once) before the timed repeats: the first builds of a process
/// pay for fresh memory (the allocator maps and faults the pages a build's arrays take; a later build reuses
/// them): at 200K triangles a first build took 1.5-2.5x the third (the particle soup's grid 27.7 ms -> 11.3 ms, its
/// LBVH 45.8 ms -> 19.2 ms), where the oracle's medians of many repeats are warm.
pub const MEASURED_WARMUP: usize = 1;

/// Structures whose predicted total lies within this fraction above the least predicted total are a close call
/// and measured (`close_calls`). Chosen on the scene families (held out by family, one-shot measurements of
/// three repeats against the precise oracle's records): 0.1 measured 33 of 252 records, 0.2 measured 75 and
/// lowered the mean regret most, 0.3 and above measured more and chose no better (`docs/cost-model.md`).
pub const CLOSE_CALL_MARGIN: f64 = 0.2;

/// How many times each structure of a close call is built and traced, after [`MEASURED_WARMUP`]; the median total
/// decides. One repeat chose worse than the timed probes alone for primary rays on the scene families (a cold build
/// can take 1.5x a warm one); five chose no better than three in one run.
pub const MEASURED_REPEATS: usize = 3;

/// The most rays one measured frame may hold (`resolution^2`, 4096 x 4096): `measure_frames` measures nothing
/// beyond, so that a caller's resolution never sizes an unbounded allocation (at the cap, shadow or diffuse rays
/// hold the primary rays and their own, 512 MiB each, and each trace writes 320 MiB of hits, beside the structure).
pub const MAX_MEASURED_RAYS: u64 = 1 << 24;

/// The most a measured close call may take by the predictions unless the caller says otherwise, ms
/// (`measuring_cost_ms`; `select::MeasureBudget::DEFAULT_MAX_MS`, `--measure-max-ms`): 2 s.
pub const DEFAULT_MAX_MS: f64 = 2000.0;

/// The structures of `preds` whose predicted total is finite and within [`CLOSE_CALL_MARGIN`] of the least, the
/// least first and then in `preds`'s order; empty unless there are at least two (nothing to settle).
pub(crate) fn close_calls(preds: &[super::Prediction]) -> Vec<StructureName> {
    let Some(least) = preds.iter().filter(|p| p.total_ms.is_finite()).min_by(|a, b| a.total_ms.total_cmp(&b.total_ms))
    else {
        return Vec::new();
    };
    let mut out = vec![least.structure];
    out.extend(
        preds
            .iter()
            .filter(|p| {
                p.structure != least.structure
                    && p.total_ms.is_finite()
                    && p.total_ms <= least.total_ms * (1.0 + CLOSE_CALL_MARGIN)
            })
            .map(|p| p.structure),
    );
    if out.len() < 2 {
        out.clear();
    }
    out
}

/// What measuring one structure's frames found: per repeat, its build and its trace of one whole frame.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FrameTiming {
    /// The structure.
    pub structure: StructureName,
    /// Wall time of each repeat's build, ms.
    pub build_ms: Vec<f64>,
    /// Wall time of each repeat's trace of one frame, ms (on rayon's pool).
    pub trace_ms: Vec<f64>,
    /// Rays of one frame.
    pub rays: usize,
}

impl FrameTiming {
    /// The median over the repeats of `builds` builds and `frames` traced frames (a static scene built once:
    /// `builds` 1; rebuilt every frame: `builds == frames`), ms; `None` without a repeat.
    pub fn total_ms(&self, builds: u64, frames: u64) -> Option<f64> {
        let totals: Vec<f64> = self
            .build_ms
            .iter()
            .zip(&self.trace_ms)
            .map(|(b, t)| b * builds as f64 + t * frames as f64)
            .filter(|x| x.is_finite())
            .collect();
        super::timed::median(totals)
    }
}

/// Builds each of `structures` over `mesh` and traces through it one whole frame of `kind` rays of `camera` at
/// `resolution` x `resolution` (the primary rays through the pixel centres; for shadow and diffuse rays those their
/// hits start, as [`super::timed::time_probes`] makes them), `repeats` times (at least one) after
/// [`MEASURED_WARMUP`] untimed rounds, interleaved across the structures, each build dropped before the next. Each is built as the oracle and the engine build it
/// ([`crate::accel::build_structure`], the grid within its builder's own reference budget, not the probes': the
/// caller's budget has already excluded what it would not build); a structure that does not build has no timing,
/// and nothing is measured beyond [`MAX_MEASURED_RAYS`] primary rays. The rays are made once, from the first structure built (not timed); every
/// structure traces the same rays.
pub(crate) fn measure_frames(
    mesh: &Mesh,
    camera: &Camera,
    resolution: u32,
    kind: WorkloadKind,
    structures: &[StructureName],
    repeats: usize,
) -> Vec<FrameTiming> {
    let mut out: Vec<FrameTiming> = Vec::new();
    if u64::from(resolution) * u64::from(resolution) > MAX_MEASURED_RAYS {
        return out;
    }
    let mut failed: Vec<StructureName> = Vec::new();
    let mut rays: Option<super::timed::RaySample> = None;
    let mut unique: Vec<StructureName> = Vec::new();
    for &s in structures {
        if !unique.contains(&s) {
            unique.push(s);
        }
    }
    // The rays are made from the first structure built, in the first (untimed) round.
    for round in 0..MEASURED_WARMUP.saturating_add(repeats.max(1)) {
        for &s in &unique {
            if failed.contains(&s) {
                continue;
            }
            let t = Instant::now();
            let Ok(accel) = crate::accel::build_structure(s, mesh) else {
                failed.push(s);
                continue;
            };
            let build = t.elapsed().as_secs_f64() * 1e3;
            let set =
                rays.get_or_insert_with(|| super::timed::view_rays(kind, mesh, camera, accel.as_ref(), resolution));
            let trace = trace_frame(accel.as_ref(), &set.rays, set.any_hit);
            drop(accel);
            if round < MEASURED_WARMUP {
                continue;
            }
            let i = match out.iter().position(|f| f.structure == s) {
                Some(i) => i,
                None => {
                    out.push(FrameTiming { structure: s, build_ms: Vec::new(), trace_ms: Vec::new(), rays: 0 });
                    out.len() - 1
                }
            };
            out[i].build_ms.push(build);
            out[i].trace_ms.push(trace);
            out[i].rays = set.rays.len();
        }
    }
    out
}

/// Wall time of tracing `rays` through `accel` on rayon's pool, each ray's result written to a vector as the
/// oracle's tracer writes its hits, ms.
fn trace_frame(accel: &dyn AccelStructure, rays: &[Ray], any_hit: bool) -> f64 {
    let t = Instant::now();
    let hits = if any_hit {
        let mut out: Vec<bool> = Vec::new();
        rays.par_iter().map(|r| accel.occluded(r, &mut TraceCounters::default())).collect_into_vec(&mut out);
        out.iter().filter(|&&h| h).count()
    } else {
        let mut out = Vec::new();
        rays.par_iter().map(|r| accel.intersect(r, &mut TraceCounters::default())).collect_into_vec(&mut out);
        out.iter().filter(|h| h.is_some()).count()
    };
    let ms = t.elapsed().as_secs_f64() * 1e3;
    std::hint::black_box(hits);
    ms
}

/// What measuring `close` (a close call of `preds`) would take by the predictions, ms: [`MEASURED_WARMUP`] +
/// [`MEASURED_REPEATS`] builds and traced frames of each (a frame's trace is the predicted trace over `frames` frames
/// divided by them). An estimate: the untimed primary frame that makes shadow and diffuse rays is not counted.
pub(crate) fn measuring_cost_ms(preds: &[super::Prediction], close: &[StructureName], frames: u64) -> f64 {
    preds
        .iter()
        .filter(|p| close.contains(&p.structure))
        .map(|p| {
            (MEASURED_WARMUP + MEASURED_REPEATS) as f64 * (p.build_ms_per_build + p.trace_ms / frames.max(1) as f64)
        })
        .sum()
}

/// The choice a measured close call makes from predictions `preds` for a workload of `builds` builds and `frames`
/// frames, given the frames measured (`timings`, at least those of the close call): the close call's structure
/// with the least measured total; `None` when there is no close call (`close_calls`), when measuring it would
/// take more than `max_ms` by the predictions (`measuring_cost_ms`), or when none of it was measured.
pub fn settle(
    preds: &[super::Prediction],
    timings: &[FrameTiming],
    builds: u64,
    frames: u64,
    max_ms: f64,
) -> Option<StructureName> {
    let close = close_calls(preds);
    let cost = measuring_cost_ms(preds, &close, frames);
    if close.is_empty() || cost.is_nan() || max_ms.is_nan() || cost > max_ms {
        return None;
    }
    let measured: Vec<FrameTiming> = timings.iter().filter(|t| close.contains(&t.structure)).cloned().collect();
    cheapest(&measured, builds, frames).map(|(s, _)| s)
}

impl FrameTiming {
    /// These timings with every trace times `factor`: frames of another size than the one measured (the workload's
    /// rays per frame over the rays measured).
    pub fn scaled(&self, factor: f64) -> FrameTiming {
        FrameTiming { trace_ms: self.trace_ms.iter().map(|t| t * factor).collect(), ..self.clone() }
    }
}

/// One structure's measured total for a workload: the medians of [`FrameTiming`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MeasuredTotal {
    /// The structure.
    pub structure: StructureName,
    /// The median over the repeats of the builds and frames' total ([`FrameTiming::total_ms`]), ms.
    pub total_ms: f64,
    /// The median build, ms.
    pub build_ms: f64,
    /// The median trace of one frame, ms.
    pub trace_ms: f64,
    /// Repeats measured.
    pub repeats: usize,
    /// Rays of one frame.
    pub rays: usize,
}

impl MeasuredTotal {
    /// The measured total of `t` over `builds` builds and `frames` frames; `None` without a repeat.
    pub fn of(t: &FrameTiming, builds: u64, frames: u64) -> Option<MeasuredTotal> {
        Some(MeasuredTotal {
            structure: t.structure,
            total_ms: t.total_ms(builds, frames)?,
            build_ms: super::timed::median(t.build_ms.clone())?,
            trace_ms: super::timed::median(t.trace_ms.clone())?,
            repeats: t.build_ms.len(),
            rays: t.rays,
        })
    }
}

/// The cheapest of `timings` over `builds` builds and `frames` frames ([`FrameTiming::total_ms`]), with its total.
pub fn cheapest(timings: &[FrameTiming], builds: u64, frames: u64) -> Option<(StructureName, f64)> {
    timings
        .iter()
        .filter_map(|f| f.total_ms(builds, frames).map(|t| (f.structure, t)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cost::Prediction;
    use crate::mesh::generate;

    fn pred(s: StructureName, total: f64) -> Prediction {
        Prediction {
            structure: s,
            build_ms_per_build: total / 2.0,
            build_ms: total / 2.0,
            box_tests_per_ray: 1.0,
            prim_tests_per_ray: 1.0,
            trace_ns_per_ray: 1.0,
            trace_ms: total / 2.0,
            total_ms: total,
        }
    }

    #[test]
    fn close_calls_are_the_predictions_within_the_margin_of_the_least() {
        use StructureName::*;
        let preds = [pred(Bvh, 1.25), pred(Lbvh, 1.0), pred(Grid, 1.19), pred(Bih, f64::INFINITY), pred(KdTree, 3.0)];
        assert_eq!(close_calls(&preds), vec![Lbvh, Grid]);
        // One structure ahead by more than the margin: nothing to settle.
        assert!(close_calls(&[pred(Bvh, 1.0), pred(Lbvh, 1.3)]).is_empty());
        assert!(close_calls(&[pred(Bvh, 1.0)]).is_empty());
        assert!(close_calls(&[]).is_empty());
        assert!(close_calls(&[pred(Bvh, f64::NAN), pred(Lbvh, f64::INFINITY)]).is_empty());
    }

    #[test]
    fn total_is_the_median_of_the_repeats_totals() {
        let f = FrameTiming {
            structure: StructureName::Bvh,
            build_ms: vec![1.0, 9.0, 2.0],
            trace_ms: vec![1.0, 1.0, 4.0],
            rays: 10,
        };
        // Totals 2, 10, 6 for one build and one frame; 11, 19, 42 over ten frames.
        assert_eq!(f.total_ms(1, 1), Some(6.0));
        assert_eq!(f.total_ms(1, 10), Some(19.0));
        // Rebuilt every frame: 20, 100, 60.
        assert_eq!(f.total_ms(10, 10), Some(60.0));
        let none = FrameTiming { build_ms: Vec::new(), trace_ms: Vec::new(), ..f.clone() };
        assert_eq!(none.total_ms(1, 1), None);
        // A grid that builds slowly and traces fast: the BVH for one frame, the grid over a hundred (BVH totals 101,
        // 109, 402: median 109; the grid's 70).
        let g = FrameTiming {
            structure: StructureName::Grid,
            build_ms: vec![20.0; 3],
            trace_ms: vec![0.5; 3],
            ..f.clone()
        };
        let all = [g, f, none];
        assert_eq!(cheapest(&all, 1, 1), Some((StructureName::Bvh, 6.0)));
        assert_eq!(cheapest(&all, 1, 100), Some((StructureName::Grid, 70.0)));
        assert_eq!(cheapest(&[], 1, 1), None);
    }

    #[test]
    fn settle_takes_the_close_calls_least_measured_total_within_the_budget() {
        use StructureName::*;
        let t = |s, total: f64| FrameTiming { structure: s, build_ms: vec![total; 3], trace_ms: vec![0.0; 3], rays: 1 };
        let preds = [pred(Lbvh, 1.0), pred(Bvh, 1.1), pred(Grid, 5.0)];
        // The BVH measured cheaper than the LBVH; the grid, measured cheapest, is no part of the close call.
        let timings = [t(Lbvh, 2.0), t(Bvh, 1.5), t(Grid, 0.1)];
        assert_eq!(settle(&preds, &timings, 1, 1, 1e9), Some(Bvh));
        // The measurement's predicted cost: (1 + 3) builds and frames of the LBVH and the BVH.
        let cost = measuring_cost_ms(&preds, &[Lbvh, Bvh], 1);
        assert!((cost - 4.0 * 2.1).abs() < 1e-12, "{cost}");
        assert_eq!(settle(&preds, &timings, 1, 1, 8.0), None, "over the budget");
        // No close call; no timing of the close call; one structure of it unmeasured (it did not build).
        assert_eq!(settle(&[pred(Lbvh, 1.0), pred(Bvh, 1.3)], &timings, 1, 1, 1e9), None);
        assert_eq!(settle(&preds, &[t(Grid, 0.1)], 1, 1, 1e9), None);
        assert_eq!(settle(&preds, &[t(Lbvh, 2.0)], 1, 1, 1e9), Some(Lbvh));
    }

    #[test]
    fn measure_frames_times_every_repeat_of_every_structure_on_the_same_rays() {
        let mesh = generate::teapot_in_stadium(3);
        let b = super::super::timed::mesh_box(&mesh);
        let camera = crate::cost::view::framing_camera(b.min.to_array(), b.max.to_array());
        for kind in [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
            // Structures of the engine core (no `eval` feature needed), one named twice: measured once.
            let s = [StructureName::Lbvh, StructureName::Bvh, StructureName::Hlbvh];
            let asked = [s[0], s[1], s[2], s[0]];
            let t = measure_frames(&mesh, &camera, 32, kind, &asked, 2);
            assert_eq!(t.iter().map(|f| f.structure).collect::<Vec<_>>(), s.to_vec());
            for f in &t {
                assert_eq!((f.build_ms.len(), f.trace_ms.len()), (2, 2), "{f:?}");
                assert!(f.build_ms.iter().chain(&f.trace_ms).all(|x| x.is_finite() && *x >= 0.0), "{f:?}");
                assert_eq!(f.rays, t[0].rays, "every structure traces the same rays");
                assert!(f.total_ms(1, 1).is_some_and(|x| x > 0.0), "{f:?}");
            }
            // A closed stadium: every primary ray hits, and a hit starts at most one secondary ray.
            match kind {
                WorkloadKind::Primary => assert_eq!(t[0].rays, 32 * 32),
                _ => assert!(t[0].rays > 0 && t[0].rays <= 32 * 32, "{kind:?}: {}", t[0].rays),
            }
        }
        // Past the cap: nothing measured, nothing allocated.
        assert!(measure_frames(&mesh, &camera, 4097, WorkloadKind::Primary, &[StructureName::Bvh], 1).is_empty());
        // Zero repeats still measure once; an empty mesh builds and traces nothing but still times.
        let one = measure_frames(&mesh, &camera, 8, WorkloadKind::Primary, &[StructureName::Bvh], 0);
        assert_eq!(one[0].build_ms.len(), 1);
        let empty = crate::mesh::Mesh::default();
        let t = measure_frames(&empty, &camera, 8, WorkloadKind::Diffuse, &[StructureName::Bvh], 1);
        assert_eq!(t.len(), 1, "an empty BVH builds and traces");
        assert_eq!((t[0].build_ms.len(), t[0].rays), (1, 0), "no hit, no diffuse ray: {t:?}");
    }
}
