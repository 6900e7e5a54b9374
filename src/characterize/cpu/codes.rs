//! Pass 2 of [`super::fast`]: the Morton codes of the sample, stored, with their range and their exact power sums in
//! fixed-width integers folded into big integers once per task.

use super::*;

/// A 256-bit unsigned value (`hi * 2^128 + lo`).
#[derive(Clone, Copy, Default)]
pub(super) struct U256 {
    pub(super) lo: u128,
    pub(super) hi: u128,
}

impl U256 {
    pub(super) fn to_big(self) -> BigUint {
        (BigUint::from(self.hi) << 128u32) + BigUint::from(self.lo)
    }
}

/// Steps 3 and 4 in the form of the inner loop of [`fast`]; the same codes as [`Quantizer::code`].
#[derive(Clone, Copy)]
pub(super) struct Cells {
    pub(super) lo: [f32; 3],
    pub(super) scale: [f32; 3],
    /// `2^b - 1`.
    pub(super) top: f32,
}

impl Cells {
    pub(super) fn of(q: &Quantizer) -> Cells {
        Cells { lo: q.lo(), scale: q.scale(), top: ((1u32 << q.bits().per_axis()) - 1) as f32 }
    }

    /// `min(floor((s - lo) * scale), 2^b - 1)` on axis `a`, as [`keys::quantize`] computes it, in operations that
    /// vectorize without SSE4.1 (no `roundps`, and `as i32` is scalarized by its saturation).
    ///
    /// `d = (s - lo) * scale` is finite (the quantizer checked the bounds) and not negative (`s >= lo`), so
    /// `v = min(d, 2^b - 1)` lies in `[0, 2^b - 1]`, and `floor(v) = min(floor(d), 2^b - 1)` (`2^b - 1` is an
    /// integer). `t = v + 2^23` lies in `[2^23, 2^24)`, where f32 values are the integers, so `t = 2^23 + r` with `r`
    /// the integer nearest `v` (exact: `|r - v| <= 1/2`), `r` is the mantissa field of `t`, and `t - 2^23 = r` is
    /// exact. `floor(v)` is `r` when `r <= v` and `r - 1` when `r > v`.
    #[inline(always)]
    pub(super) fn cell(&self, s: f32, a: usize) -> u32 {
        const MAGIC: f32 = 8_388_608.0; // 2^23
        let d = (s - self.lo[a]) * self.scale[a];
        let v = if d < self.top { d } else { self.top };
        let t = v + MAGIC;
        let r = t.to_bits() & 0x007f_ffff;
        r - u32::from(t - MAGIC > v)
    }

    /// Step 3 for the keys `x`, `y`, `z` (at most [`BLOCK`], equally many): their cells into `b.cx`, `b.cy`,
    /// `b.cz`, in a vectorized loop.
    #[inline(always)]
    pub(super) fn cells(&self, (x, y, z): (&[f32], &[f32], &[f32]), b: &mut Block) {
        for (c, &s) in b.cx.iter_mut().zip(x) {
            *c = self.cell(s, 0);
        }
        for (c, &s) in b.cy.iter_mut().zip(y) {
            *c = self.cell(s, 1);
        }
        for (c, &s) in b.cz.iter_mut().zip(z) {
            *c = self.cell(s, 2);
        }
    }
}

/// `SPREAD[v]`: bit `i` of `v` moved to bit `3 i`, for `v < 2^11` (as [`keys::spread10`] for `v < 2^10`). A lookup
/// costs one load where the shifts and masks of the definition cost a dozen operations (and without SSE4.1 the
/// compiler turns their vector form into emulated 32-bit multiplications).
pub(super) static SPREAD: [u32; 1 << 11] = spread_table();

pub(super) const fn spread_table() -> [u32; 1 << 11] {
    let mut t = [0u32; 1 << 11];
    let mut v = 0;
    while v < t.len() {
        let mut i = 0;
        while i < 11 {
            t[v] |= ((v as u32 >> i) & 1) << (3 * i);
            i += 1;
        }
        v += 1;
    }
    t
}

/// [`keys::spread10`] for a cell `v < 2^10` (the mask only shows the compiler the bound).
#[inline(always)]
pub(super) fn spread10(v: u32) -> u32 {
    SPREAD[(v & 0x7ff) as usize]
}

/// [`keys::spread21`] for a cell `v < 2^21`: its low 11 bits and its high 10 bits, spread by the table.
#[inline(always)]
pub(super) fn spread21(v: u32) -> u64 {
    u64::from(SPREAD[(v & 0x7ff) as usize]) | (u64::from(SPREAD[((v >> 11) & 0x7ff) as usize]) << 33)
}

/// How [`fast`] stores the codes between its passes: `u32` for 30-bit codes that are not returned, `u64` otherwise.
pub(super) trait Code: Copy + Default + Send + Sync {
    /// From a 30-bit code.
    fn from_code30(m: u32) -> Self;
    /// The code.
    fn code(self) -> u64;
}

impl Code for u32 {
    #[inline(always)]
    fn from_code30(m: u32) -> u32 {
        m
    }
    #[inline(always)]
    fn code(self) -> u64 {
        u64::from(self)
    }
}

impl Code for u64 {
    #[inline(always)]
    fn from_code30(m: u32) -> u64 {
        u64::from(m)
    }
    #[inline(always)]
    fn code(self) -> u64 {
        self
    }
}

/// The extremes and exact power sums of one task's codes, in fixed width: `S1 = s1`, `S2 = s2`,
/// `S3 = s3_lo + 2^64 s3_hi`.
#[derive(Clone, Copy)]
pub(super) struct TaskSums {
    pub(super) min: u64,
    pub(super) max: u64,
    pub(super) s1: u128,
    pub(super) s2: U256,
    pub(super) s3_lo: U256,
    pub(super) s3_hi: U256,
}

/// The range and the power sums of a task's 30-bit codes, added one code at a time.
///
/// Exact for up to 2^32 codes: `m < 2^30`, so `m^2 < 2^60`, `m^3 < 2^90`, and with `L <= 2^32` codes `S1 < 2^62`
/// fits `u64`, `S2 < 2^92` and `S3 < 2^122` fit `u128`. One 64 x 64 -> 128-bit product per code.
#[derive(Default)]
pub(super) struct Sums30 {
    pub(super) min: u32,
    pub(super) max: u32,
    pub(super) s1: u64,
    pub(super) s2: u128,
    pub(super) s3: u128,
}

impl Sums30 {
    pub(super) fn new() -> Sums30 {
        Sums30 { min: u32::MAX, ..Sums30::default() }
    }

    /// Adds code `m`.
    #[inline(always)]
    pub(super) fn add(&mut self, m: u32) {
        (self.min, self.max) = (self.min.min(m), self.max.max(m));
        let m = u64::from(m);
        let m2 = m * m;
        self.s1 += m;
        self.s2 += u128::from(m2);
        self.s3 += u128::from(m2) * u128::from(m);
    }

    pub(super) fn finish(self) -> TaskSums {
        let z = U256::default();
        TaskSums {
            min: self.min.into(),
            max: self.max.into(),
            s1: self.s1.into(),
            s2: U256 { lo: self.s2, hi: 0 },
            s3_lo: U256 { lo: self.s3, hi: 0 },
            s3_hi: z,
        }
    }
}

/// The range and the power sums of a task's 63-bit codes, added one code at a time.
///
/// Exact for up to 2^32 codes: `S1 < 2^95` fits `u128`; `m^2 < 2^126` is added to a `u128` whose carries are counted
/// (at most one per code), so `S2 = s2 + 2^128 c2`; `m^3 = p0 + 2^64 p1` with `p0 = lo64(m^2) m < 2^127` and
/// `p1 = hi64(m^2) m < 2^125`, each summed the same way. Three 64 x 64 -> 128-bit products per code.
#[derive(Default)]
pub(super) struct Sums63 {
    pub(super) min: u64,
    pub(super) max: u64,
    pub(super) s1: u128,
    pub(super) s2: u128,
    pub(super) c2: u128,
    pub(super) a: u128,
    pub(super) ca: u128,
    pub(super) b: u128,
    pub(super) cb: u128,
}

impl Sums63 {
    pub(super) fn new() -> Sums63 {
        Sums63 { min: u64::MAX, ..Sums63::default() }
    }

    /// Adds code `m`.
    #[inline(always)]
    pub(super) fn add(&mut self, m: u64) {
        let s = self;
        (s.min, s.max) = (s.min.min(m), s.max.max(m));
        let m = u128::from(m);
        let m2 = m * m;
        s.s1 += m;
        let (v, c) = s.s2.overflowing_add(m2);
        (s.s2, s.c2) = (v, s.c2 + u128::from(c));
        let p0 = (m2 as u64 as u128) * m;
        let p1 = (m2 >> 64) * m;
        let (v, c) = s.a.overflowing_add(p0);
        (s.a, s.ca) = (v, s.ca + u128::from(c));
        let (v, c) = s.b.overflowing_add(p1);
        (s.b, s.cb) = (v, s.cb + u128::from(c));
    }

    pub(super) fn finish(self) -> TaskSums {
        TaskSums {
            min: self.min,
            max: self.max,
            s1: self.s1,
            s2: U256 { lo: self.s2, hi: self.c2 },
            s3_lo: U256 { lo: self.a, hi: self.ca },
            s3_hi: U256 { lo: self.b, hi: self.cb },
        }
    }
}

/// Pass 2 of [`fast`] for one task, 30-bit codes: steps 3 to 5b for the task's keys `k`, block by block (cells in a
/// vectorized loop, then the codes by table into `out` and into the sums).
#[inline(never)]
pub(super) fn task_codes30<C: Code>(k: TaskKeys<'_>, cells: &Cells, out: &mut [C]) -> TaskSums {
    let (mut b, mut buf) = (Block::new(), KeyBuf::new());
    let mut s = Sums30::new();
    for (j, out) in out.chunks_mut(BLOCK).enumerate() {
        let len = out.len();
        cells.cells(k.block(j, len, &mut buf), &mut b);
        for (o, ((&x, &y), &z)) in out[..len].iter_mut().zip(b.cx[..len].iter().zip(&b.cy[..len]).zip(&b.cz[..len])) {
            let m = (spread10(x) << 2) | (spread10(y) << 1) | spread10(z);
            *o = C::from_code30(m);
            s.add(m);
        }
    }
    s.finish()
}

/// [`task_codes30`] for 63-bit codes.
#[inline(never)]
pub(super) fn task_codes63(k: TaskKeys<'_>, cells: &Cells, out: &mut [u64]) -> TaskSums {
    let (mut b, mut buf) = (Block::new(), KeyBuf::new());
    let mut s = Sums63::new();
    for (j, out) in out.chunks_mut(BLOCK).enumerate() {
        let len = out.len();
        cells.cells(k.block(j, len, &mut buf), &mut b);
        for (o, ((&x, &y), &z)) in out[..len].iter_mut().zip(b.cx[..len].iter().zip(&b.cy[..len]).zip(&b.cz[..len])) {
            let m = (spread21(x) << 2) | (spread21(y) << 1) | spread21(z);
            *o = m;
            s.add(m);
        }
    }
    s.finish()
}

/// Folds the tasks' fixed-width sums into the exact statistics, once per task.
pub(super) fn fold_sums(n: usize, sums: Vec<TaskSums>) -> CodeStats {
    let mut stats = CodeStats {
        n: n as u64,
        code_min: u64::MAX,
        code_max: 0,
        s1: BigUint::zero(),
        s2: BigUint::zero(),
        s3: BigUint::zero(),
    };
    for s in sums {
        stats.code_min = stats.code_min.min(s.min);
        stats.code_max = stats.code_max.max(s.max);
        stats.s1 += BigUint::from(s.s1);
        stats.s2 += s.s2.to_big();
        stats.s3 += s.s3_lo.to_big() + (s.s3_hi.to_big() << 64u32);
    }
    stats
}

/// The triangles of the task whose codes go to `codes[t * TASK ..]`: from the task's first sampled triangle to the
/// next task's (exclusive; for the last task, to the end).
pub(super) fn task_tris(mesh: &Mesh, stride: usize, t: usize, len: usize) -> &[[u32; 3]] {
    let j0 = t * TASK;
    let end = ((j0 + len) * stride).min(mesh.indices.len());
    &mesh.indices[j0 * stride..end]
}

/// Where pass 2 finds the sample's keys: kept by pass 1, or in the mesh (sampled every `stride`-th triangle).
#[derive(Clone, Copy)]
pub(super) enum SampleSource<'a> {
    Stored(&'a SampleKeys),
    Gather(&'a Mesh, usize),
}

impl SampleSource<'_> {
    /// The keys of task `t` (`len` of them): `TASK` from `t * TASK` on.
    pub(super) fn task(&self, t: usize, len: usize) -> TaskKeys<'_> {
        match *self {
            SampleSource::Stored(k) => {
                let r = t * TASK..t * TASK + len;
                TaskKeys::Stored(&k.x[r.clone()], &k.y[r.clone()], &k.z[r])
            }
            SampleSource::Gather(mesh, stride) => {
                TaskKeys::Gather { tris: task_tris(mesh, stride, t, len), stride, p: &mesh.positions }
            }
        }
    }
}

/// Pass 2 of [`fast`], 30-bit codes: every code into `codes` (one per sampled triangle) and the exact statistics.
pub(super) fn sample_codes30<C: Code>(keys: SampleSource<'_>, q: &Quantizer, codes: &mut [C]) -> CodeStats {
    let cells = Cells::of(q);
    let sums = codes
        .par_chunks_mut(TASK)
        .enumerate()
        .map(|(t, out)| task_codes30(keys.task(t, out.len()), &cells, out))
        .collect();
    fold_sums(codes.len(), sums)
}

/// [`sample_codes30`] for 63-bit codes.
pub(super) fn sample_codes63(keys: SampleSource<'_>, q: &Quantizer, codes: &mut [u64]) -> CodeStats {
    let cells = Cells::of(q);
    let sums = codes
        .par_chunks_mut(TASK)
        .enumerate()
        .map(|(t, out)| task_codes63(keys.task(t, out.len()), &cells, out))
        .collect();
    fold_sums(codes.len(), sums)
}
