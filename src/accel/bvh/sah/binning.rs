//! The binning of the SAH builder: reference boxes in SIMD registers, bins per axis, the plane of least SAH cost,
//! and the sweep over bins that the HLBVH's top level shares.

use super::*;

/// A box in SIMD registers for the builder (`w` lanes are ignored).
#[derive(Clone, Copy, Debug)]
pub(super) struct B4 {
    pub(super) min: Vec4,
    pub(super) max: Vec4,
}

impl B4 {
    pub(super) const EMPTY: B4 = B4 { min: Vec4::splat(f32::INFINITY), max: Vec4::splat(f32::NEG_INFINITY) };
    #[inline]
    pub(super) fn union(self, o: B4) -> B4 {
        B4 { min: self.min.min(o.min), max: self.max.max(o.max) }
    }
    #[inline]
    pub(super) fn grow(&mut self, p: Vec4) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    #[inline]
    pub(super) fn half_area(&self) -> f32 {
        let e = self.max - self.min;
        if e.x < 0.0 {
            return 0.0;
        }
        e.x * e.y + e.y * e.z + e.z * e.x
    }
    pub(super) fn aabb(&self) -> Aabb {
        Aabb::new(self.min.truncate(), self.max.truncate())
    }
}

/// A triangle reference during the build: its box, with the triangle index in the `w` lanes, 16 bits in each
/// ([`index_lane`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Ref {
    pub(super) b: B4,
}

/// Sixteen bits of a triangle index as the `w` lane of a reference's box: the float of bits
/// `0x3F80_0000 | k << 7`, in `[1, 2)`. The lanes go through every box operation (unions, differences, products),
/// so they must be normal numbers: x86 processors take a slow path, tens of times slower, for arithmetic on
/// subnormal operands, which the raw index bits would be.
#[inline]
pub(super) fn index_lane(k: u32) -> f32 {
    f32::from_bits(0x3F80_0000 | (k & 0xFFFF) << 7)
}

impl Ref {
    pub(super) fn new(b: &Aabb, idx: u32) -> Self {
        Ref { b: B4 { min: b.min.extend(index_lane(idx)), max: b.max.extend(index_lane(idx >> 16)) } }
    }
    #[inline]
    pub(super) fn idx(&self) -> u32 {
        let lane = |x: f32| (x.to_bits() >> 7) & 0xFFFF;
        lane(self.b.min.w) | lane(self.b.max.w) << 16
    }
    /// Twice the box centre.
    #[inline]
    pub(super) fn c2(&self) -> Vec4 {
        self.b.min + self.b.max
    }
}

/// Per axis and bin: the union of the boxes of the references binned there, and their count. One scratch per
/// thread of the build, reset for the bins a node uses.
#[derive(Clone)]
pub(super) struct Bins {
    pub(super) min: [[Vec4; MAX_BINS]; 3],
    pub(super) max: [[Vec4; MAX_BINS]; 3],
    pub(super) n: [[u32; MAX_BINS]; 3],
}

impl Bins {
    pub(super) fn new() -> Box<Bins> {
        Box::new(Bins {
            min: [[B4::EMPTY.min; MAX_BINS]; 3],
            max: [[B4::EMPTY.max; MAX_BINS]; 3],
            n: [[0; MAX_BINS]; 3],
        })
    }
    pub(super) fn reset(&mut self, nb: usize) {
        for a in 0..3 {
            self.min[a][..nb].fill(B4::EMPTY.min);
            self.max[a][..nb].fill(B4::EMPTY.max);
            self.n[a][..nb].fill(0);
        }
    }
    #[inline]
    pub(super) fn add(&mut self, refs: &[Ref], g: &Binning) {
        for r in refs {
            let bins = g.bins(r.c2());
            for (a, &i) in bins.iter().enumerate() {
                self.min[a][i] = self.min[a][i].min(r.b.min);
                self.max[a][i] = self.max[a][i].max(r.b.max);
                self.n[a][i] += 1;
            }
        }
    }
    pub(super) fn merge(mut self: Box<Self>, o: Box<Self>, nb: usize) -> Box<Self> {
        for a in 0..3 {
            for i in 0..nb {
                self.min[a][i] = self.min[a][i].min(o.min[a][i]);
                self.max[a][i] = self.max[a][i].max(o.max[a][i]);
                self.n[a][i] += o.n[a][i];
            }
        }
        self
    }
    /// The union of bins `range` of axis `a`.
    pub(super) fn union(&self, a: usize, range: std::ops::Range<usize>) -> B4 {
        let mut b = B4::EMPTY;
        for i in range {
            b = b.union(B4 { min: self.min[a][i], max: self.max[a][i] });
        }
        b
    }
}

/// The mapping of twice a centroid to a bin on each axis: `floor((c2 - cmin) * k)`, clamped to the bins.
pub(super) struct Binning {
    pub(super) cmin: Vec4,
    pub(super) k: Vec4,
    pub(super) top: Vec4,
}

impl Binning {
    pub(super) fn new(cb: &B4, nb: usize) -> Binning {
        let ext = cb.max - cb.min;
        let kf = |e: f32| {
            if e > 0.0 {
                nb as f32 * (1.0 - 1e-6) / e
            } else {
                0.0
            }
        };
        Binning { cmin: cb.min, k: Vec4::new(kf(ext.x), kf(ext.y), kf(ext.z), 0.0), top: Vec4::splat((nb - 1) as f32) }
    }
    /// The bin of `c2` on each axis. Clamped in f32 (a NaN lane, which only a sum overflowing to infinity can
    /// make, lands in bin 0), truncated on all lanes at once, and masked into the bin arrays.
    #[inline]
    pub(super) fn bins(&self, c2: Vec4) -> [usize; 3] {
        let x = ((c2 - self.cmin) * self.k).max(Vec4::ZERO).min(self.top);
        let i = truncate(x);
        [i[0] as usize & (MAX_BINS - 1), i[1] as usize & (MAX_BINS - 1), i[2] as usize & (MAX_BINS - 1)]
    }
}

/// The lanes of `x` (each in `0 ..= MAX_BINS - 1`) truncated to integers, in one instruction where SSE2 exists.
#[cfg(target_arch = "x86_64")]
#[inline]
pub(super) fn truncate(x: Vec4) -> [u32; 4] {
    use std::arch::x86_64::{__m128, __m128i, _mm_cvttps_epi32};
    let v: __m128 = x.into();
    // SAFETY: SSE2 is part of every x86_64 target; __m128i and [u32; 4] are 16 plain bytes, every bit pattern a
    // valid [u32; 4].
    unsafe {
        let i: __m128i = _mm_cvttps_epi32(v);
        std::mem::transmute::<__m128i, [u32; 4]>(i)
    }
}

#[cfg(not(target_arch = "x86_64"))]
#[inline]
pub(super) fn truncate(x: Vec4) -> [u32; 4] {
    [x.x as u32, x.y as u32, x.z as u32, 0]
}

pub(super) fn ref_bounds(refs: &[Ref]) -> (B4, B4) {
    let f = |rs: &[Ref]| {
        let mut b = B4::EMPTY;
        let mut cb = B4::EMPTY;
        for r in rs {
            b = b.union(r.b);
            cb.grow(r.c2());
        }
        (b, cb)
    };
    if refs.len() >= PAR_BIN_THRESHOLD {
        refs.par_chunks(16_384).map(f).reduce(|| (B4::EMPTY, B4::EMPTY), |x, y| (x.0.union(y.0), x.1.union(y.1)))
    } else {
        f(refs)
    }
}

/// The best binned split of a node.
pub(super) struct Split {
    pub(super) axis: usize,
    /// First bin of the right side.
    pub(super) bin: usize,
    /// `A_L N_L + A_R N_R` in half areas.
    pub(super) cost: f32,
    /// Boxes of the two sides (unions of their bins).
    pub(super) left: B4,
    pub(super) right: B4,
    pub(super) g: Binning,
}

/// Bins `refs` on all three axes into `nb` bins over the centroid bounds `cb` and sweeps each axis for the plane of
/// least `A_L N_L + A_R N_R` (ties: the more balanced, then the lower axis and plane). `None` when the centroids
/// coincide.
pub(super) fn find_split(refs: &[Ref], cb: &B4, nb: usize, bins: &mut Bins) -> Option<Split> {
    let g = Binning::new(cb, nb);
    if g.k == Vec4::ZERO {
        return None;
    }
    if refs.len() >= PAR_BIN_THRESHOLD {
        let merged = refs
            .par_chunks(16_384)
            .fold(
                || {
                    let mut b = Bins::new();
                    b.reset(nb);
                    b
                },
                |mut b, c| {
                    b.add(c, &g);
                    b
                },
            )
            .reduce_with(|x, y| x.merge(y, nb));
        if let Some(m) = merged {
            *bins = *m;
        }
    } else {
        bins.reset(nb);
        bins.add(refs, &g);
    }
    let n = refs.len() as i64;
    let mut best: Option<(usize, usize, f32, i64)> = None;
    for a in 0..3 {
        if g.k[a] == 0.0 {
            continue;
        }
        let (mins, maxs, counts) = (&bins.min[a], &bins.max[a], &bins.n[a]);
        sweep_bins::<B4, MAX_BINS>(
            nb,
            |i| (B4 { min: mins[i], max: maxs[i] }, counts[i]),
            |i, cost, cnt| {
                let imbalance = (2 * cnt as i64 - n).abs();
                let better = match best {
                    None => true,
                    Some((_, _, bc, bi)) => cost < bc || (cost == bc && imbalance < bi),
                };
                if better {
                    best = Some((a, i, cost, imbalance));
                }
            },
        );
    }
    best.map(|(axis, bin, cost, _)| Split {
        axis,
        bin,
        cost,
        left: bins.union(axis, 0..bin),
        right: bins.union(axis, bin..nb),
        g,
    })
}

/// A box the SAH sweep accumulates: [`Aabb`] (the HLBVH's top level) or the builder's SIMD box.
pub(crate) trait SweepBox: Copy {
    /// The empty box.
    const EMPTY: Self;
    /// The smallest box containing both.
    fn union(self, o: Self) -> Self;
    /// Half the surface area, `e.x e.y + e.y e.z + e.z e.x` (0 for the empty box).
    fn half_area(&self) -> f32;
}

impl SweepBox for B4 {
    const EMPTY: Self = B4::EMPTY;
    #[inline]
    fn union(self, o: Self) -> Self {
        B4::union(self, o)
    }
    #[inline]
    fn half_area(&self) -> f32 {
        B4::half_area(self)
    }
}

impl SweepBox for Aabb {
    const EMPTY: Self = Aabb::EMPTY;
    #[inline]
    fn union(self, o: Self) -> Self {
        Aabb::union(&self, &o)
    }
    #[inline]
    fn half_area(&self) -> f32 {
        Aabb::half_area(self)
    }
}

/// The binned-SAH sweep over one axis, shared by the builder and the HLBVH's top level: `bin(i)` is the box and
/// the count of bin `i` of `nb <= N`. Right sides are accumulated by a backward sweep, left sides forward (the same
/// boxes, unions being exact, as summing the bins of each side from scratch); for every plane `s` in `1 .. nb`
/// (left: bins `0 .. s`) with both sides non-empty, `visit(s, cost, n_left)` gets
/// `cost = half_area(left) * n_left + half_area(right) * n_right` in f32, evaluated in that order.
#[inline]
pub(crate) fn sweep_bins<B: SweepBox, const N: usize>(
    nb: usize,
    bin: impl Fn(usize) -> (B, u32),
    mut visit: impl FnMut(usize, f32, u32),
) {
    let nb = nb.min(N);
    let mut right_area = [0.0f32; N];
    let mut right_n = [0u32; N];
    let mut acc = B::EMPTY;
    let mut cnt = 0u32;
    for i in (1..nb).rev() {
        let (b, n) = bin(i);
        acc = acc.union(b);
        cnt += n;
        right_area[i] = acc.half_area();
        right_n[i] = cnt;
    }
    let mut acc = B::EMPTY;
    let mut cnt = 0u32;
    for i in 1..nb {
        let (b, n) = bin(i - 1);
        acc = acc.union(b);
        cnt += n;
        if cnt == 0 || right_n[i] == 0 {
            continue;
        }
        visit(i, acc.half_area() * cnt as f32 + right_area[i] * right_n[i] as f32, cnt);
    }
}
