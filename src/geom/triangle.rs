//! Triangle records, the ray-triangle test and the hit-agreement rule.

use super::Hit;
use glam::Vec3;

/// A triangle as the intersection test wants it: a vertex and two edges.
///
/// Zero-area triangles (cross product of the edges exactly zero in f64) are stored with zero edges, so that the
/// Möller-Trumbore determinant is exactly zero and they are never hit.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Triangle {
    /// First vertex.
    pub v0: Vec3,
    /// `v1 - v0` (zero for a zero-area triangle).
    pub e1: Vec3,
    /// `v2 - v0` (zero for a zero-area triangle).
    pub e2: Vec3,
}

impl Triangle {
    /// Precomputes the record of a triangle.
    pub fn new(v: &[Vec3; 3]) -> Self {
        let (a, b, c) = (v[0].as_dvec3(), v[1].as_dvec3(), v[2].as_dvec3());
        if (b - a).cross(c - a).length_squared() == 0.0 {
            Triangle { v0: v[0], e1: Vec3::ZERO, e2: Vec3::ZERO }
        } else {
            Triangle { v0: v[0], e1: v[1] - v[0], e2: v[2] - v[0] }
        }
    }

    /// Whether the triangle has zero area (and is never hit).
    pub fn is_degenerate(&self) -> bool {
        self.e1 == Vec3::ZERO && self.e2 == Vec3::ZERO
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
