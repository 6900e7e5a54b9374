//! Pass 3 of [`super::fast`]: the class of every stored code and the histogram, from an `f32` estimate corrected by
//! the exact thresholds.

use super::*;

/// Step 7 for many codes: the class of `x = m - m_min` from an `f32` estimate of `x k / D`, corrected by the exact
/// thresholds of [`class_thresholds`], without a division.
///
/// With `u = 2^-24`, the estimate `P = rn(rn(x) rn(k / rn(D)))` has a relative error below
/// `(1 + u)^3 / (1 - u) - 1 < 4.0001 u` (four roundings; every value is normal or 0), so it is within
/// `4096 * 4.0001 * 2^-24 < 0.001` of `Q = x k / D <= k`. Then `min(P, k - 1)` is within 0.001 of `min(Q, k - 1)`,
/// whose integer part is the class `c = min(floor(Q), k - 1)`, so the nearest integer `E` of `min(P, k - 1)` is `c`
/// or `c + 1`. With `e[0] = 0` and `e[j] = t_j` (`j = 1 .. k - 1`), the class is at least `j` exactly when
/// `x >= e[j]`; so the class is `E - 1` if `x < e[E]` and `E` otherwise. (Where thresholds repeat, the classes
/// between them are empty, and the rule still gives the class of step 7.)
pub(super) struct Classifier {
    pub(super) code_min: u64,
    /// `rn(k / rn(D))`.
    pub(super) r: f32,
    /// `k - 1`.
    pub(super) top: f32,
    /// `e[0 .. k]`.
    pub(super) e: Vec<u64>,
}

impl Classifier {
    /// For `k >= 2` and `D = code_max - code_min > 0`.
    pub(super) fn new(code_min: u64, code_max: u64, k: u32) -> Classifier {
        let d = code_max - code_min;
        let mut e = Vec::with_capacity(k as usize);
        e.push(0);
        e.extend(class_thresholds(code_min, code_max, k));
        Classifier { code_min, r: k as f32 / d as f32, top: (k - 1) as f32, e }
    }

    /// The nearest integer `E` of `min(rn(x) r, k - 1)`, by the magic-number rounding of [`Cells::cell`]
    /// (`min(P, k - 1)` lies in `[0, 2^23)`).
    #[inline(always)]
    pub(super) fn estimate(&self, x: f32) -> u32 {
        const MAGIC: f32 = 8_388_608.0; // 2^23
        let p = x * self.r;
        let p = if p < self.top { p } else { self.top };
        (p + MAGIC).to_bits() & 0x007f_ffff
    }

    /// The class of `x = m - m_min` from its estimate `E` (`e` is `self.e`, here so that the caller can keep it in
    /// a register).
    #[inline(always)]
    pub(super) fn class(e: &[u64], x: u64, estimate: u32) -> u32 {
        estimate - u32::from(x < e[estimate as usize])
    }
}

/// How [`fast`] stores the codes, part 2: the offset of a code from the smallest one, exactly and as the nearest
/// `f32`.
pub(super) trait Offset: Code {
    /// `m - m_min` rounded to the nearest `f32` (`m >= m_min`).
    fn offset_f32(self, code_min: u64) -> f32;
}

impl Offset for u32 {
    /// Codes below 2^30: the offset converts through `i32` (vectorized).
    #[inline(always)]
    fn offset_f32(self, code_min: u64) -> f32 {
        (self - code_min as u32) as i32 as f32
    }
}

impl Offset for u64 {
    /// Codes below 2^63: the offset converts through `i64`.
    #[inline(always)]
    fn offset_f32(self, code_min: u64) -> f32 {
        (self - code_min) as i64 as f32
    }
}

/// Steps 7 and 8 over `codes`: the histogram of `k` classes, and the class of every code into `classes` when it is
/// not empty (then as long as `codes`).
pub(super) fn sample_histogram<C: Offset>(codes: &[C], stats: &CodeStats, k: u32, classes: &mut [u32]) -> Vec<u64> {
    let n = codes.len() as u64;
    if k <= 1 || stats.code_max <= stats.code_min {
        // One class (step 7: every code in class 0).
        let mut h = vec![0u64; k as usize];
        h[0] = n;
        return h;
    }
    let cl = Classifier::new(stats.code_min, stats.code_max, k);
    let kk = k as usize;
    let task_hist = |cs: &[C], out: &mut [u32]| -> Vec<u64> {
        let (e, code_min) = (&cl.e[..], cl.code_min);
        // Four interleaved histograms, so that neighbouring codes of one class do not wait on each other's counts.
        let mut h = vec![0u32; 4 * kk];
        let (h01, h23) = h.split_at_mut(2 * kk);
        let ((h0, h1), (h2, h3)) = (h01.split_at_mut(kk), h23.split_at_mut(kk));
        let mut est = [0u32; BLOCK];
        for (i, cs) in cs.chunks(BLOCK).enumerate() {
            let est = &mut est[..cs.len()];
            for (e, &m) in est.iter_mut().zip(cs) {
                *e = cl.estimate(m.offset_f32(code_min));
            }
            if out.is_empty() {
                let mut quads = cs.chunks_exact(4).zip(est.chunks_exact(4));
                for (m, est) in &mut quads {
                    h0[Classifier::class(e, m[0].code() - code_min, est[0]) as usize] += 1;
                    h1[Classifier::class(e, m[1].code() - code_min, est[1]) as usize] += 1;
                    h2[Classifier::class(e, m[2].code() - code_min, est[2]) as usize] += 1;
                    h3[Classifier::class(e, m[3].code() - code_min, est[3]) as usize] += 1;
                }
                let done = cs.len() / 4 * 4;
                for (&m, &est) in cs[done..].iter().zip(&est[done..]) {
                    h0[Classifier::class(e, m.code() - code_min, est) as usize] += 1;
                }
            } else {
                let out = &mut out[i * BLOCK..i * BLOCK + cs.len()];
                for ((o, &m), &est) in out.iter_mut().zip(cs).zip(est.iter()) {
                    let c = Classifier::class(e, m.code() - code_min, est);
                    *o = c;
                    h0[c as usize] += 1;
                }
            }
        }
        (0..kk).map(|c| u64::from(h0[c]) + u64::from(h1[c]) + u64::from(h2[c]) + u64::from(h3[c])).collect()
    };
    if classes.is_empty() {
        codes.par_chunks(TASK).map(|cs| task_hist(cs, &mut [])).reduce(|| vec![0u64; kk], merge_hist)
    } else {
        codes
            .par_chunks(TASK)
            .zip(classes.par_chunks_mut(TASK))
            .map(|(cs, out)| task_hist(cs, out))
            .reduce(|| vec![0u64; kk], merge_hist)
    }
}
