//! The split search of the kd-tree builder: binned SAH over the three axes with empty-space cut-offs, the plane
//! sweep four candidates at a time.

use super::*;

pub(super) const MAX_BINS: usize = 64;

/// The best plane of a node over `refs` in `voxel`, `(axis, plane, cost)`; `keep_all`: whether a plane that leaves
/// one side with every reference (and the other with some) is a candidate.
///
/// Of candidates of equal cost the first wins, in the order: per axis x, y, z, the two empty-space cut-offs, then
/// the bin boundaries from low to high.
pub(super) fn find_split(refs: &[KRef], voxel: &Aabb, o: &KdOptions, keep_all: bool) -> Option<(usize, f32, f32)> {
    // Small nodes get about one bin per reference (at least 4): the same quality for much less sweeping. The bin
    // arrays are sized to the next power of two, so that small nodes (most of them) clear little.
    let nb = o.bins.clamp(2, MAX_BINS).min(refs.len().max(4));
    match nb {
        0..=8 => find_split_in::<8>(refs, voxel, o, keep_all, nb),
        9..=16 => find_split_in::<16>(refs, voxel, o, keep_all, nb),
        17..=32 => find_split_in::<32>(refs, voxel, o, keep_all, nb),
        _ => find_split_in::<MAX_BINS>(refs, voxel, o, keep_all, nb),
    }
}

/// One axis of a node's plane sweep: the voxel's interval on it and the terms of the cost.
#[derive(Clone, Copy, Debug)]
pub(super) struct SweepAxis {
    /// The voxel's lower and upper bound on the axis.
    pub(super) v0: f32,
    pub(super) v1: f32,
    /// Its extent on the axis.
    pub(super) e: f32,
    /// Half area of a child of length `len` along the axis: `len * sm + cr`.
    pub(super) sm: f32,
    pub(super) cr: f32,
    pub(super) kt: f32,
    pub(super) ki: f32,
    /// `1 - empty_bonus`.
    pub(super) empty: f32,
    /// 1 / the voxel's half area.
    pub(super) inv_sa: f32,
    /// The node's references.
    pub(super) n: u32,
    /// Whether a plane that keeps every reference on one side and some on the other is a candidate.
    pub(super) keep_all: bool,
}

impl SweepAxis {
    /// The cost of a plane at `p` with `nl`, `nr` references, infinite when it is no candidate: outside the voxel's
    /// interior, or one that keeps every reference on one side and some on the other at the end of a chain of them.
    #[inline]
    pub(super) fn cost(&self, p: f32, nl: u32, nr: u32) -> f32 {
        let n = self.n;
        let duplicates = !self.keep_all & ((nl == n) & (nr > 0) | (nr == n) & (nl > 0));
        let inside = (p > self.v0) & (p < self.v1);
        let al = (p - self.v0) * self.sm + self.cr;
        let ar = (self.v1 - p) * self.sm + self.cr;
        let bonus = if (nl == 0) | (nr == 0) { self.empty } else { 1.0 };
        let cost = self.kt + self.ki * bonus * (al * nl as f32 + ar * nr as f32) * self.inv_sa;
        if inside & !duplicates {
            cost
        } else {
            f32::INFINITY
        }
    }

    /// The plane of bin boundary `j` of `nb`.
    #[inline]
    pub(super) fn plane(&self, j: usize, nb: usize) -> f32 {
        self.v0 + self.e * (j as f32 / nb as f32)
    }

    /// `costs[j]` = [`SweepAxis::cost`] of bin boundary `j` in `1..nb` from the bins' start and end counts;
    /// `costs[0]` and any entry past `nb - 1` that is written are infinite, the others are left as they are. Four candidates at a time (`glam::Vec4`, SSE or NEON where there is one) when the
    /// counts are exact in f32 (below 2^24 references), one at a time otherwise; the same arithmetic in the same
    /// order either way, so the same costs to the bit (tested).
    pub(super) fn bin_costs<const B: usize>(&self, start: &[u32; B], end: &[u32; B], nb: usize, costs: &mut [f32; B]) {
        let (mut nl, mut nr) = (0u32, self.n);
        if self.n >= 1 << 24 {
            for j in 1..nb {
                nl += start[j - 1];
                nr -= end[j - 1];
                costs[j] = self.cost(self.plane(j, nb), nl, nr);
            }
            return;
        }
        let (mut lf, mut rf) = ([0f32; B], [0f32; B]);
        for j in 1..nb {
            nl += start[j - 1];
            nr -= end[j - 1];
            lf[j] = nl as f32;
            rf[j] = nr as f32;
        }
        let nf = Vec4::splat(self.n as f32);
        let (v0, v1) = (Vec4::splat(self.v0), Vec4::splat(self.v1));
        let (zero, nbf) = (Vec4::ZERO, Vec4::splat(nb as f32));
        for c in (0..nb).step_by(4) {
            let j = Vec4::new(c as f32, (c + 1) as f32, (c + 2) as f32, (c + 3) as f32);
            let (l, r) = (Vec4::from_slice(&lf[c..c + 4]), Vec4::from_slice(&rf[c..c + 4]));
            let p = v0 + self.e * (j / nbf);
            let duplicates = if self.keep_all {
                BVec4A::splat(false)
            } else {
                (l.cmpeq(nf) & r.cmpgt(zero)) | (r.cmpeq(nf) & l.cmpgt(zero))
            };
            let inside = p.cmpgt(v0) & p.cmplt(v1);
            let al = (p - v0) * self.sm + self.cr;
            let ar = (v1 - p) * self.sm + self.cr;
            let bonus = Vec4::select(l.cmpeq(zero) | r.cmpeq(zero), Vec4::splat(self.empty), Vec4::ONE);
            let cost = self.kt + self.ki * bonus * (al * l + ar * r) * self.inv_sa;
            let real = j.cmpge(Vec4::ONE) & j.cmplt(nbf);
            let cost = Vec4::select(inside & !duplicates & real, cost, Vec4::INFINITY);
            cost.write_to_slice(&mut costs[c..c + 4]);
        }
    }
}

/// The bin indices of lanes already clamped to `[0, nb - 1]`: truncated toward zero, a NaN lane to a value whose
/// low bits are 0 (the bin of a NaN is 0 either way). One SSE2 conversion on x86-64, lane by lane elsewhere.
#[inline(always)]
pub(super) fn bins(v: Vec3A) -> [u32; 4] {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: SSE2 is part of every x86-64 target; the intrinsic only converts a register.
        bytemuck::cast(unsafe { std::arch::x86_64::_mm_cvttps_epi32(v.into()) })
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        [v.x as u32, v.y as u32, v.z as u32, 0]
    }
}

/// [`find_split`] with `nb <= B` bins (`B` a power of two, at least 4).
#[inline(always)]
pub(super) fn find_split_in<const B: usize>(
    refs: &[KRef],
    voxel: &Aabb,
    o: &KdOptions,
    keep_all: bool,
    nb: usize,
) -> Option<(usize, f32, f32)> {
    let sa = voxel.half_area();
    if sa.is_nan() || sa <= 0.0 {
        return None;
    }
    let n = refs.len();
    let ext = voxel.max - voxel.min;
    // One pass over the references bins all three axes (SIMD), with the references' extent for the cut-offs.
    let kf = |e: f32| if e > 0.0 { nb as f32 / e } else { 0.0 };
    let kv = Vec3A::new(kf(ext.x), kf(ext.y), kf(ext.z));
    let vmin = Vec3A::from(voxel.min);
    let top = Vec3A::splat((nb - 1) as f32);
    let mut start = [[0u32; B]; 3];
    let mut end = [[0u32; B]; 3];
    let (mut lo, mut hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
    for r in refs {
        let (mn, mx) = (Vec3A::from(r.min), Vec3A::from(r.max));
        let b0 = ((mn - vmin) * kv).clamp(Vec3A::ZERO, top);
        let b1 = ((mx - vmin) * kv).clamp(Vec3A::ZERO, top);
        let (i0, i1) = (bins(b0), bins(b1));
        for a in 0..3 {
            // The bins lie in [0, nb - 1] after the clamp; the mask only spares the bounds check.
            start[a][i0[a] as usize & (B - 1)] += 1;
            end[a][i1[a] as usize & (B - 1)] += 1;
        }
        lo = lo.min(mn);
        hi = hi.max(mx);
    }
    let mut best: Option<(usize, f32, f32)> = None;
    let mut best_cost = f32::INFINITY;
    // Half area of a child along `axis` with length `len`: len * (e_b + e_c) + e_b * e_c.
    let sums = [ext.y + ext.z, ext.x + ext.z, ext.x + ext.y];
    let crosses = [ext.y * ext.z, ext.x * ext.z, ext.x * ext.y];
    for axis in 0..3 {
        if ext[axis].is_nan() || ext[axis] <= 0.0 {
            continue;
        }
        let sweep = SweepAxis {
            v0: voxel.min[axis],
            v1: voxel.max[axis],
            e: ext[axis],
            sm: sums[axis],
            cr: crosses[axis],
            kt: o.traversal_cost,
            ki: o.intersection_cost,
            empty: 1.0 - o.empty_bonus,
            inv_sa: 1.0 / sa,
            n: n as u32,
            keep_all,
        };
        // Empty-space cut-offs exactly at the references' extent, then the bin boundaries.
        for (p, nl, nr) in [(lo[axis], 0, n as u32), (hi[axis], n as u32, 0)] {
            let c = sweep.cost(p, nl, nr);
            if c < best_cost {
                best_cost = c;
                best = Some((axis, p, c));
            }
        }
        let mut costs = [f32::INFINITY; B];
        sweep.bin_costs(&start[axis], &end[axis], nb, &mut costs);
        let mut bj = 0;
        for (j, &c) in costs.iter().enumerate().take(nb).skip(1) {
            if c < best_cost {
                best_cost = c;
                bj = j;
            }
        }
        if bj > 0 {
            best = Some((axis, sweep.plane(bj, nb), best_cost));
        }
    }
    best
}
