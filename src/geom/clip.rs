//! Sutherland-Hodgman clipping of a triangle by axis-aligned slabs, in f64: the grid's cell assignment
//! (`accel::grid`) and the selection's bound of it (`select::budget`) clip the same way with this one type.

use glam::DVec3;

/// A convex polygon of at most 8 corners in f64: a triangle clipped by up to four axis-aligned planes.
#[derive(Clone, Copy)]
pub(crate) struct Polygon {
    pub(crate) v: [DVec3; 8],
    pub(crate) len: usize,
}

impl Polygon {
    /// The part of the polygon with `lo <= p[axis] <= hi` (Sutherland-Hodgman, one slab).
    pub(crate) fn clip(&self, axis: usize, lo: f64, hi: f64) -> Polygon {
        self.clip_half(axis, lo, 1.0).clip_half(axis, hi, -1.0)
    }

    /// The part with `sign * (p[axis] - c) >= 0`.
    fn clip_half(&self, axis: usize, c: f64, sign: f64) -> Polygon {
        let mut out = Polygon { v: [DVec3::ZERO; 8], len: 0 };
        for k in 0..self.len {
            let (p, q) = (self.v[k], self.v[(k + 1) % self.len]);
            let (dp, dq) = (sign * (p[axis] - c), sign * (q[axis] - c));
            if dp >= 0.0 {
                out.push(p);
            }
            if (dp >= 0.0) != (dq >= 0.0) {
                let mut x = p + (q - p) * (dp / (dp - dq));
                x[axis] = c;
                out.push(x);
            }
        }
        out
    }

    fn push(&mut self, p: DVec3) {
        if self.len < self.v.len() {
            self.v[self.len] = p;
            self.len += 1;
        }
    }

    /// Smallest and largest coordinate along `axis` (`None` for an empty polygon).
    pub(crate) fn range(&self, axis: usize) -> Option<(f64, f64)> {
        let vs = &self.v[..self.len];
        let lo = vs.iter().map(|p| p[axis]).reduce(f64::min)?;
        let hi = vs.iter().map(|p| p[axis]).reduce(f64::max)?;
        Some((lo, hi))
    }
}
