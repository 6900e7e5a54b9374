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

/// The next representable `f32` above `t` (`t` finite).
#[inline]
fn next_up(t: f32) -> f32 {
    if t.is_nan() || t == f32::INFINITY {
        t
    } else if t == 0.0 {
        f32::from_bits(1)
    } else if t > 0.0 {
        f32::from_bits(t.to_bits() + 1)
    } else {
        f32::from_bits(t.to_bits() - 1)
    }
}

/// One step of closest-hit search under the crate's **tie rule**: of two triangles hit at exactly the same `t`, the
/// one with the smaller mesh index is the closest hit. `best` is the closest hit found so far and `best_t` its
/// distance (the ray's `tmax` while there is none). Tests triangle record `tri` (mesh index `id`) and returns the
/// hit when it is closer than `best`, or as close with a smaller index. One ray-triangle test either way.
///
/// Every structure calls this for every candidate, and culls a node or cell only when it begins strictly beyond
/// `best_t` (a tied triangle may lie at its entry), so every structure returns the same triangle and the same `t`
/// bits as the brute-force reference, which tests triangles in mesh order.
#[inline]
pub(crate) fn closer_hit(
    tri: &Triangle,
    id: u32,
    origin: Vec3,
    dir: Vec3,
    tmin: f32,
    best_t: f32,
    best: &Option<Hit>,
) -> Option<Hit> {
    let may_tie = best.is_some_and(|b| id < b.triangle);
    let limit = if may_tie { next_up(best_t) } else { best_t };
    let (t, u, v) = intersect_triangle(tri, origin, dir, tmin, limit)?;
    Some(Hit { t, triangle: id, u, v })
}

/// Margin, in units of the ray's `t`, by which the computed distance of a triangle hit may fall short of the true
/// distance, for a ray from `origin` along `dir` in a scene inside `scene`. Möller-Trumbore's `t` carries an absolute
/// error of a few ulps of the coordinates involved (origin and vertices), divided by the direction's length along the
/// triangle's normal; this bound takes 64 ulps of the largest coordinate over the largest direction component (it
/// covers rays down to about 1/16 of normal incidence; closer to grazing, a tie between overlapping coplanar
/// triangles can still be missed). Zero for an empty scene or a zero direction.
#[inline]
pub(crate) fn tie_margin(origin: Vec3, dir: Vec3, scene: &crate::geom::Aabb) -> f32 {
    let d = dir.abs().max_element();
    if scene.is_empty() || d.is_nan() || d <= 0.0 {
        return 0.0;
    }
    let coords = origin.abs().max_element() + scene.min.abs().max(scene.max.abs()).max_element();
    64.0 * f32::EPSILON * coords / d
}

/// The distance up to which traversal must still visit nodes and cells when the closest hit so far is at `best_t`
/// (`margin` from [`tie_margin`]): `best_t` enlarged by `1 + 2 gamma(3)` (as the slab test enlarges its exit
/// distance) plus `margin`, so that no node or cell that may hold a triangle whose computed distance is at most
/// `best_t` is culled: the tie rule of [`closer_hit`] needs every such triangle tested.
#[inline]
pub(crate) fn cull_bound(best_t: f32, margin: f32) -> f32 {
    let r = super::ray::SLAB_ROBUST;
    (if best_t >= 0.0 { best_t * r } else { best_t / r }) + margin
}

/// Whether two closest-hit results agree: both miss, or both hit the same triangle at the same `t` bits. Every
/// structure shares one triangle test and the tie rule of `closer_hit`, so anything else is a lost or wrong hit.
pub fn hits_agree(a: &Option<Hit>, b: &Option<Hit>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => a.triangle == b.triangle && a.t.to_bits() == b.t.to_bits(),
        _ => false,
    }
}
