//! A deterministic proxy for the oracle's trace times: every structure's exact box and triangle test counts (what
//! the counting tracer records in every oracle record) times per-test prices measured in isolation on this machine
//! ([`TestPrices::measure`]). The counts carry no timing noise, so the proxy's trace times do not either; the build
//! times stay the measured medians. `evaluate --compare-policies FILE... --proxy` scores the policies against it
//! beside the measured truth and says how well the two agree ([`Agreement`]).
//!
//! What the proxy leaves out, and the agreement shows: everything a traversal does besides its box and triangle
//! tests (stack operations, a kd-tree's or BIH's plane tests counted as box tests, a grid's cell steps and mailbox,
//! the per-ray set-up), and memory: a node that misses the cache costs more than the isolated test, whose data stay
//! in the first-level cache.

use super::Measurement;
use crate::eval::fit::Sample;
use crate::geom::{closer_hit, Ray, RayInv, Triangle};
use crate::rng::SplitMix64;
use glam::Vec3;
use std::hint::black_box;
use std::time::Instant;

/// Nanoseconds per ray-box and per ray-triangle test, each measured in isolation: one thread, the data in the
/// first-level cache, the project's own tests (the slab test every hierarchy's traversal makes, and
/// `closer_hit`, Moller-Trumbore with the tie rule).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TestPrices {
    /// Nanoseconds per ray-box slab test.
    pub box_ns: f64,
    /// Nanoseconds per ray-triangle test.
    pub triangle_ns: f64,
    /// Repeats of each measurement; the prices are their medians.
    pub repeats: usize,
}

/// Boxes and triangles per measurement: 256 of each (6 KiB and 9 KiB) stay in any first-level data cache.
const ITEMS: usize = 256;
/// Rays per measurement: 64 x 256 = 16,384 tests, a few tens of microseconds.
const RAYS: usize = 64;

impl TestPrices {
    /// Measures both prices: `repeats` (at least 1) timed passes of 64 rays over 256 random boxes and 256 random
    /// triangles in the unit cube (a fixed seed), after one untimed pass; the medians. Half the tests hit, about.
    pub fn measure(repeats: usize) -> TestPrices {
        let repeats = repeats.max(1);
        let mut rng = SplitMix64::new(0x7072_6f78_7921);
        let mut point = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let boxes: Vec<([f32; 3], [f32; 3])> = (0..ITEMS)
            .map(|_| {
                let (a, b) = (point(), point());
                (a.min(b).to_array(), a.max(b).to_array())
            })
            .collect();
        let tris: Vec<Triangle> = (0..ITEMS).map(|_| Triangle::new(&[point(), point(), point()])).collect();
        let rays: Vec<Ray> = (0..RAYS)
            .map(|_| {
                let o = point() * 3.0 - Vec3::ONE;
                let to = point();
                Ray::new(o, (to - o).normalize_or(Vec3::X))
            })
            .collect();
        let inv: Vec<RayInv> = rays.iter().map(RayInv::new).collect();
        let tests = (RAYS * ITEMS) as f64;
        let box_pass = || {
            let t = Instant::now();
            let mut hits = 0u32;
            for r in black_box(&inv) {
                for (lo, hi) in black_box(&boxes) {
                    hits += r.slab(lo, hi, 0.0, f32::INFINITY).is_some() as u32;
                }
            }
            black_box(hits);
            t.elapsed().as_secs_f64() * 1e9 / tests
        };
        let triangle_pass = || {
            let t = Instant::now();
            let mut hits = 0u32;
            for r in black_box(&inv) {
                for (i, tri) in black_box(&tris).iter().enumerate() {
                    hits += closer_hit(tri, i as u32, r.o, r.d, 0.0, f32::INFINITY, &None).is_some() as u32;
                }
            }
            black_box(hits);
            t.elapsed().as_secs_f64() * 1e9 / tests
        };
        box_pass();
        triangle_pass();
        // Interleaved, so that a drift of the machine reaches both alike.
        let (b, p): (Vec<f64>, Vec<f64>) = (0..repeats).map(|_| (box_pass(), triangle_pass())).unzip();
        TestPrices { box_ns: Measurement::of(&b).median, triangle_ns: Measurement::of(&p).median, repeats }
    }

    /// The proxy's trace nanoseconds per ray for these counts.
    pub fn ns_per_ray(&self, box_tests_per_ray: f64, prim_tests_per_ray: f64) -> f64 {
        box_tests_per_ray * self.box_ns + prim_tests_per_ray * self.triangle_ns
    }
}

/// The samples with every structure's trace replaced by the proxy's (counts times `prices`; the build kept):
/// `trace_ns_per_ray`, `trace_ms` (rays per frame x frames traced) and `total_ms` follow, and "within noise of the
/// best" becomes "within `tie` of the best total" (the proxy has no intervals; 0.02 is the precise oracle's
/// target). The driver's structures, which have no counts, are dropped.
pub fn proxied(samples: &[Sample], prices: &TestPrices, tie: f64) -> Vec<Sample> {
    samples
        .iter()
        .map(|s| {
            let mut s = s.clone();
            let rays = s.workload.rays_per_frame as f64 * s.workload.frames.max(1) as f64;
            for m in &mut s.measured {
                m.trace_ns_per_ray = prices.ns_per_ray(m.box_tests_per_ray, m.prim_tests_per_ray);
                m.trace_ms = m.trace_ns_per_ray * rays * 1e-6;
                m.total_ms = m.build_ms + m.trace_ms;
                // The measured intervals are not the proxy's: it has none (it is exact).
                m.total_ms_ci95 = None;
            }
            let best = s.best().map(|b| b.total_ms);
            for m in &mut s.measured {
                m.within_noise_of_best = best.is_some_and(|b| m.valid && m.total_ms <= b * (1.0 + tie.max(0.0)));
            }
            s.driver.clear();
            s
        })
        .collect()
}

/// How the proxy agrees with the measured truth over the same samples ([`agreement`]).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Agreement {
    /// Samples with a best structure under both truths.
    pub samples: usize,
    /// Share of them whose proxy best is the measured best.
    pub same_best: f64,
    /// Share whose proxy best is the measured best or within the measured noise of it.
    pub best_within_noise: f64,
    /// Mean over samples of the measured total of the proxy's best over the measured best, minus 1: the regret of
    /// choosing by the proxy, judged by the measurement.
    pub mean_regret_of_proxy_best: f64,
    /// Per structure: `(name, traces compared, median of measured / proxy trace time, RMS of its natural log)`.
    pub trace_ratio: Vec<(String, usize, f64, f64)>,
}

/// Compares `proxy` (from [`proxied`]) with the measured `samples` it was made from, pairwise.
pub fn agreement(samples: &[Sample], proxy: &[Sample]) -> Agreement {
    let mut a = Agreement::default();
    let (mut same, mut near, mut regret) = (0usize, 0usize, 0.0);
    let mut ratios: Vec<(crate::accel::StructureName, Vec<f64>)> =
        crate::accel::StructureName::ALL.iter().map(|&s| (s, Vec::new())).collect();
    for (m, p) in samples.iter().zip(proxy) {
        for (x, y) in m.measured.iter().zip(&p.measured) {
            if x.valid && x.trace_ms > 0.0 && y.trace_ms > 0.0 {
                if let Some(r) = ratios.iter_mut().find(|r| r.0 == x.structure) {
                    r.1.push((x.trace_ms / y.trace_ms).ln());
                }
            }
        }
        let (Some(mb), Some(pb)) = (m.best(), p.best()) else { continue };
        a.samples += 1;
        let chosen = m.get(pb.structure);
        same += (pb.structure == mb.structure) as usize;
        near += chosen.is_some_and(|c| c.structure == mb.structure || c.within_noise_of_best) as usize;
        regret += m.regret(pb.structure).unwrap_or(0.0);
    }
    if a.samples > 0 {
        let n = a.samples as f64;
        (a.same_best, a.best_within_noise, a.mean_regret_of_proxy_best) =
            (same as f64 / n, near as f64 / n, regret / n);
    }
    a.trace_ratio = ratios
        .into_iter()
        .filter(|r| !r.1.is_empty())
        .map(|(s, l)| {
            let rms = (l.iter().map(|x| x * x).sum::<f64>() / l.len() as f64).sqrt();
            (s.as_str().to_string(), l.len(), Measurement::of(&l).median.exp(), rms)
        })
        .collect();
    a
}
