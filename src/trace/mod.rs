//! Cameras, workloads (primary, shadow and diffuse ray sets) and a counting parallel tracer over any structure.
//!
//! Rays, hits, the ray-triangle and slab tests live in [`crate::geom`].

pub mod camera;
pub mod views;
pub mod workload;

pub use camera::Camera;
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

/// Rays per rayon task.
const CHUNK: usize = 1024;

/// Traces every ray of `rays` through `accel` in parallel (rayon over chunks of rays) and times it.
pub fn trace(accel: &dyn AccelStructure, rays: &RaySet) -> TraceOutcome {
    let start = std::time::Instant::now();
    let mut out = TraceOutcome::default();
    if rays.any_hit {
        let parts: Vec<(Vec<bool>, TraceCounters)> = rays
            .rays
            .par_chunks(CHUNK)
            .map(|chunk| {
                let mut c = TraceCounters::default();
                let v = chunk.iter().map(|r| accel.occluded(r, &mut c)).collect();
                (v, c)
            })
            .collect();
        out.occluded.reserve(rays.rays.len());
        for (v, c) in parts {
            out.occluded.extend(v);
            out.counters.add(&c);
        }
    } else {
        let parts: Vec<(Vec<Option<Hit>>, TraceCounters)> = rays
            .rays
            .par_chunks(CHUNK)
            .map(|chunk| {
                let mut c = TraceCounters::default();
                let v = chunk.iter().map(|r| accel.intersect(r, &mut c)).collect();
                (v, c)
            })
            .collect();
        out.hits.reserve(rays.rays.len());
        for (v, c) in parts {
            out.hits.extend(v);
            out.counters.add(&c);
        }
    }
    out.seconds = start.elapsed().as_secs_f64();
    out
}

/// Number of rays on which two outcomes of the same ray set disagree (see [`hits_agree`]; occlusion must be equal).
pub fn count_disagreements(a: &TraceOutcome, b: &TraceOutcome) -> usize {
    let h = a.hits.iter().zip(&b.hits).filter(|(x, y)| !hits_agree(x, y)).count();
    let o = a.occluded.iter().zip(&b.occluded).filter(|(x, y)| x != y).count();
    h + o + a.hits.len().abs_diff(b.hits.len()) + a.occluded.len().abs_diff(b.occluded.len())
}
