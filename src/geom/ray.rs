//! Rays, their inverse directions, the slab test, closest hits, work counters and the kinds of ray sets.

use glam::{Vec3, Vec3A};

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
    #[cfg_attr(not(feature = "eval"), allow(dead_code))]
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
    /// SIMD: the slab distances never involve NaN (the inverse direction is finite), so SSE min/max are exact, and
    /// the clamps to `tmin` and `tmax` are plain comparisons (`f32::max`'s NaN handling cost 11-20% of a BVH
    /// traversal on cheap rays). A NaN `tmin` or `tmax`, with which no triangle can be hit, misses every box.
    #[inline]
    pub(crate) fn slab(&self, min: &[f32; 3], max: &[f32; 3], tmin: f32, tmax: f32) -> Option<f32> {
        let t0 = (Vec3A::from_array(*min) - self.oa) * self.inva;
        let t1 = (Vec3A::from_array(*max) - self.oa) * self.inva;
        let near = t0.min(t1).max_element();
        let near = if near > tmin { near } else { tmin };
        let far = t0.max(t1).min_element() * SLAB_ROBUST;
        let far = if far < tmax { far } else { tmax };
        if near <= far {
            Some(near)
        } else {
            None
        }
    }

    /// Slab test returning the clipped interval `(entry, exit)`.
    #[inline]
    #[cfg(feature = "eval")]
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

/// Kind of rays of a workload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WorkloadKind {
    /// Camera rays, one per pixel, closest hit.
    Primary,
    /// From each primary hit to the point light, any hit.
    Shadow,
    /// From each primary hit in a cosine-distributed random direction about the normal, closest hit.
    Diffuse,
}

impl WorkloadKind {
    /// Lowercase name.
    pub fn as_str(self) -> &'static str {
        match self {
            WorkloadKind::Primary => "primary",
            WorkloadKind::Shadow => "shadow",
            WorkloadKind::Diffuse => "diffuse",
        }
    }
}

impl std::str::FromStr for WorkloadKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "primary" => Ok(WorkloadKind::Primary),
            "shadow" => Ok(WorkloadKind::Shadow),
            "diffuse" => Ok(WorkloadKind::Diffuse),
            other => Err(format!("unknown workload {other:?} (primary, shadow, diffuse)")),
        }
    }
}
