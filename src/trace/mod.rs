//! Rays, the ray-triangle test, cameras, workloads and a counting parallel tracer.
//!
//! The ray-triangle test is Möller and Trumbore 1997 in f32 on precomputed edges ([`crate::accel::Triangle`]).
//! It is not watertight: a ray through a shared edge may report either neighbour (both at the same `t`), and in
//! rare cases neither. All structures use this one test, so they agree triangle for triangle; a ray is counted as
//! a hit when `tmin < t < tmax`, `u >= 0`, `v >= 0`, `u + v <= 1` and the determinant is non-zero and finite.
//! Zero-area triangles have zero edges, a zero determinant, and are never hit.
//!
//! Ray-box tests are slab tests (Kay and Kajiya 1986) with the exit distance scaled by `1 + 2 gamma(3)` as Ize 2013
//! recommends, so that rounding never culls a box a ray really touches. A zero direction component gets an inverse
//! of `f32::MAX` instead of infinity, so that no slab test ever computes `0 * inf`.

pub mod camera;
pub mod workload;

pub use camera::Camera;
pub use workload::{RaySet, WorkloadKind};

use crate::accel::{AccelStructure, Triangle};
use glam::{Vec3, Vec3A};
use rayon::prelude::*;

/// A ray `origin + t * dir` for `tmin < t < tmax`. `dir` need not be normalized.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin.
    pub origin: Vec3,
    /// Direction.
    pub dir: Vec3,
    /// Smallest accepted distance (exclusive).
    pub tmin: f32,
    /// Largest accepted distance (exclusive).
    pub tmax: f32,
}

impl Ray {
    /// A ray from `origin` along `dir` with `tmin = 0`, `tmax = inf`.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir, tmin: 0.0, tmax: f32::INFINITY }
    }
}

/// The closest hit of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the ray, in units of `dir`.
    pub t: f32,
    /// Index of the triangle in the mesh.
    pub triangle: u32,
    /// Barycentric coordinate of `v1`.
    pub u: f32,
    /// Barycentric coordinate of `v2`.
    pub v: f32,
}

/// Work counters of tracing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TraceCounters {
    /// Box tests (BVH-like structures), node visits (kd-tree, BIH), cells visited (grid).
    pub box_tests: u64,
    /// Ray-triangle tests.
    pub prim_tests: u64,
}

impl TraceCounters {
    /// Sum of two counters.
    pub fn add(&mut self, o: &TraceCounters) {
        self.box_tests += o.box_tests;
        self.prim_tests += o.prim_tests;
    }
}

/// `1 + 2 gamma(3)`, the factor that makes a slab test conservative (Ize 2013).
pub(crate) const SLAB_ROBUST: f32 = 1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// A ray with its inverse direction, as traversal wants it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RayInv {
    pub(crate) o: Vec3,
    pub(crate) d: Vec3,
    pub(crate) inv: Vec3,
    oa: Vec3A,
    inva: Vec3A,
}

impl RayInv {
    #[inline]
    pub(crate) fn new(r: &Ray) -> Self {
        let f = |x: f32| if x == 0.0 { f32::MAX } else { 1.0 / x };
        let inv = Vec3::new(f(r.dir.x), f(r.dir.y), f(r.dir.z));
        RayInv { o: r.origin, d: r.dir, inv, oa: r.origin.into(), inva: inv.into() }
    }

    /// Slab test against `[min, max]` (as stored in nodes) within `(tmin, tmax)`: the entry distance, or `None`.
    /// SIMD: the slab distances never involve NaN (the inverse direction is finite), so SSE min/max are exact.
    #[inline]
    pub(crate) fn slab(&self, min: &[f32; 3], max: &[f32; 3], tmin: f32, tmax: f32) -> Option<f32> {
        let t0 = (Vec3A::from_array(*min) - self.oa) * self.inva;
        let t1 = (Vec3A::from_array(*max) - self.oa) * self.inva;
        let near = t0.min(t1).max_element().max(tmin);
        let far = t0.max(t1).min_element() * SLAB_ROBUST;
        if near <= far.min(tmax) {
            Some(near)
        } else {
            None
        }
    }

    /// Slab test returning the clipped interval `(entry, exit)`.
    #[inline]
    pub(crate) fn slab_interval(&self, min: Vec3, max: Vec3, tmin: f32, tmax: f32) -> Option<(f32, f32)> {
        let t0 = (min - self.o) * self.inv;
        let t1 = (max - self.o) * self.inv;
        let near = t0.min(t1).max_element().max(tmin);
        let far = (t0.max(t1).min_element() * SLAB_ROBUST).min(tmax);
        if near <= far {
            Some((near, far))
        } else {
            None
        }
    }
}

/// Möller-Trumbore ray-triangle test: `(t, u, v)` when `tmin < t < tmax`.
#[inline]
pub fn intersect_triangle(tri: &Triangle, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
    let p = dir.cross(tri.e2);
    let det = tri.e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - tri.v0;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(tri.e1);
    let v = dir.dot(q) * inv;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    let t = tri.e2.dot(q) * inv;
    if t > tmin && t < tmax {
        Some((t, u, v))
    } else {
        None
    }
}

/// Tolerance of hit comparison: two hits agree when they name the same triangle, or when their distances differ by
/// at most `HIT_T_EPSILON * max(1, |t|)` (a tie: two triangles hit at the same distance). Structures share one
/// triangle test, so the same triangle gives the same `t` bit for bit; the tolerance only admits ties.
pub const HIT_T_EPSILON: f32 = 1e-5;

/// Whether two closest-hit results agree (see [`HIT_T_EPSILON`]).
pub fn hits_agree(a: &Option<Hit>, b: &Option<Hit>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => a.triangle == b.triangle || (a.t - b.t).abs() <= HIT_T_EPSILON * a.t.abs().max(1.0),
        _ => false,
    }
}

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
