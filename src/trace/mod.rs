//! Cameras, workloads (primary, shadow and diffuse ray sets) and a counting parallel tracer over any structure.
//!
//! Rays, hits, cameras, the ray-triangle and slab tests live in [`crate::geom`].

pub mod views;
pub mod workload;

pub use workload::RaySet;

use crate::accel::AccelStructure;
use crate::geom::{hits_agree, Hit, TraceCounters};
use rayon::prelude::*;

/// Result of tracing a ray set.
#[derive(Clone, Debug, Default)]
pub struct TraceOutcome {
    /// Closest hits (closest-hit workloads), one per ray; empty for any-hit workloads.
    pub hits: Vec<Option<Hit>>,
    /// Occlusion (any-hit workloads), one per ray; empty for closest-hit workloads.
    pub occluded: Vec<bool>,
    /// Tests summed over all rays.
    pub counters: TraceCounters,
    /// Wall-clock seconds of the trace.
    pub seconds: f64,
}

impl TraceOutcome {
    /// Number of rays traced.
    pub fn rays(&self) -> usize {
        self.hits.len().max(self.occluded.len())
    }
}

/// Traces every ray of `rays` through `accel` in parallel (rayon over rays) and times it.
pub fn trace(accel: &dyn AccelStructure, rays: &RaySet) -> TraceOutcome {
    let start = std::time::Instant::now();
    let mut out = TraceOutcome::default();
    out.counters = if rays.any_hit {
        trace_into(&rays.rays, &mut out.occluded, |r, c| accel.occluded(r, c))
    } else {
        trace_into(&rays.rays, &mut out.hits, |r, c| accel.intersect(r, c))
    };
    out.seconds = start.elapsed().as_secs_f64();
    out
}

/// Counters of one rayon piece of the trace, added to the total when the piece ends.
struct PieceCounters<'a> {
    counters: TraceCounters,
    total: &'a std::sync::Mutex<TraceCounters>,
}

impl Drop for PieceCounters<'_> {
    fn drop(&mut self) {
        // A poisoned lock means another piece panicked; that panic is what propagates, so its counters do not matter.
        if let Ok(mut t) = self.total.lock() {
            t.add(&self.counters);
        }
    }
}

/// `out = rays.map(f)` in parallel, the counters summed.
///
/// The results are collected straight into `out` (rayon writes each piece in place, with no initialisation pass
/// and no per-piece vectors), and the counters are kept per rayon piece and summed once per piece. On cheap rays
/// (the conference room at 256x256, two threads, medians of 61) writing chunks of 1,024 rays into a vector filled
/// beforehand took 1.53-1.63 ms; this takes 1.32-1.37 ms (README, "side by side").
fn trace_into<T: Send>(
    rays: &[crate::geom::Ray],
    out: &mut Vec<T>,
    f: impl Fn(&crate::geom::Ray, &mut TraceCounters) -> T + Sync,
) -> TraceCounters {
    let total = std::sync::Mutex::new(TraceCounters::default());
    rays.par_iter()
        .map_init(
            || PieceCounters { counters: TraceCounters::default(), total: &total },
            |piece, r| f(r, &mut piece.counters),
        )
        .collect_into_vec(out);
    total.into_inner().unwrap_or_else(|e| e.into_inner())
}

/// Number of rays on which two outcomes of the same ray set disagree (see [`hits_agree`]; occlusion must be equal).
pub fn count_disagreements(a: &TraceOutcome, b: &TraceOutcome) -> usize {
    let h = a.hits.iter().zip(&b.hits).filter(|(x, y)| !hits_agree(x, y)).count();
    let o = a.occluded.iter().zip(&b.occluded).filter(|(x, y)| x != y).count();
    h + o + a.hits.len().abs_diff(b.hits.len()) + a.occluded.len().abs_diff(b.occluded.len())
}

/// Rays the trace-budget check ([`check_trace_budget`]) traces per structure and frame (fewer when the workload has
/// fewer).
pub const TRACE_SAMPLE_RAYS: usize = 1024;

/// The default trace budget: most box and triangle tests per ray (mean over a sample of the rays) before a structure
/// is reported as failed instead of traced (the oracle's `--max-tests-per-ray`; the secondary-ray estimate's too).
pub const DEFAULT_MAX_TESTS_PER_RAY: f64 = 4096.0;

/// [`TRACE_SAMPLE_RAYS`] of `rays` (all when there are fewer), spread over the whole set: ray
/// `floor(frac(i * phi) * len)` for `i` in `0 .. TRACE_SAMPLE_RAYS`, the golden-ratio sequence, so that a sample
/// of an image's rays (row by row) covers its columns as well as its rows (a stride equal to the image width
/// would sample one column).
fn sample_rays(rays: &[crate::geom::Ray]) -> Vec<crate::geom::Ray> {
    if rays.len() <= TRACE_SAMPLE_RAYS {
        return rays.to_vec();
    }
    const PHI_FRAC: f64 = 0.618_033_988_749_894_8;
    (0..TRACE_SAMPLE_RAYS)
        .map(|i| rays[(((i as f64 * PHI_FRAC).fract() * rays.len() as f64) as usize).min(rays.len() - 1)])
        .collect()
}

/// Traces a sample of `rays` ([`TRACE_SAMPLE_RAYS`] of them, spread over the set) through `s` with counters (not
/// part of any timing) and fails with the reason when the tests per ray exceed `max_tests_per_ray`.
pub fn check_trace_budget(s: &dyn AccelStructure, rays: &RaySet, max_tests_per_ray: f64) -> Result<(), String> {
    if rays.rays.is_empty() {
        return Ok(());
    }
    let sample = RaySet { kind: rays.kind, rays: sample_rays(&rays.rays), any_hit: rays.any_hit };
    let out = trace(s, &sample);
    let k = sample.rays.len() as f64;
    let per_ray = (out.counters.box_tests + out.counters.prim_tests) as f64 / k;
    if per_ray > max_tests_per_ray {
        return Err(format!(
            "{}: over the trace budget: a sample of {} rays needs {:.0} tests per ray ({:.0} box, {:.0} triangle), \
             about {:.2e} for the {} rays, over the budget of {max_tests_per_ray} per ray (--max-tests-per-ray); \
             coincident or heavily overlapping triangles make every ray test them all",
            s.name(),
            sample.rays.len(),
            per_ray,
            out.counters.box_tests as f64 / k,
            out.counters.prim_tests as f64 / k,
            per_ray * rays.rays.len() as f64,
            rays.rays.len()
        ));
    }
    Ok(())
}
