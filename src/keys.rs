//! Centroid keys, quantization and Morton codes exactly as `docs/spec.md` steps 1 to 4 pin them.
//!
//! These are the definitions shared by the CPU characterization paths, the scene features, the BVH builders (LBVH
//! and HLBVH sort triangles by the same codes), the host side of the device passes and the tests that check the GPU:
//! the scalar steps ([`centroid_key`], [`quantization_scale`], [`quantize`], [`morton`]), the step-2 reduction
//! ([`KeyBounds`]), the quantizer of a set of keys with the one error of steps 1 to 3 ([`Quantizer`],
//! [`KeyError`], which every caller maps to its own error type) and the whole pipeline ([`morton_codes`]). Every
//! function is exact IEEE f32 or integer arithmetic, so a GPU kernel that performs the same operations (marked
//! `precise`, no fused multiply-add, no division) produces the same bits.

/// Bits per axis of the Morton code: 10 (30-bit codes, the default) or 21 (63-bit codes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize)]
pub enum MortonBits {
    /// 10 bits per axis, 30-bit codes.
    #[default]
    Bits30,
    /// 21 bits per axis, 63-bit codes.
    Bits63,
}

impl MortonBits {
    /// Bits per axis `b`.
    pub(crate) fn per_axis(self) -> u32 {
        match self {
            MortonBits::Bits30 => 10,
            MortonBits::Bits63 => 21,
        }
    }
    /// Total bits of a code, `3 b`.
    pub fn total(self) -> u32 {
        3 * self.per_axis()
    }
    /// Parses `30` or `63`.
    pub fn from_total(bits: u32) -> Option<Self> {
        match bits {
            30 => Some(MortonBits::Bits30),
            63 => Some(MortonBits::Bits63),
            _ => None,
        }
    }
}

/// Step 1: `s = (v0 + v1) + v2` per axis in f32, left to right (three times the centroid).
#[inline]
pub(crate) fn centroid_key(v0: [f32; 3], v1: [f32; 3], v2: [f32; 3]) -> [f32; 3] {
    [(v0[0] + v1[0]) + v2[0], (v0[1] + v1[1]) + v2[1], (v0[2] + v1[2]) + v2[2]]
}

/// Maps an f32 to a `u32` whose unsigned order is the IEEE total order of the float (`-0.0 < +0.0`).
///
/// Bounds are reduced in this representation on every backend, so that the minimum of `{-0.0, +0.0}` is the same
/// bit pattern everywhere.
#[inline]
pub(crate) fn ordered_bits(x: f32) -> u32 {
    let b = x.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Inverse of [`ordered_bits`].
#[inline]
pub(crate) fn from_ordered_bits(u: u32) -> f32 {
    if u & 0x8000_0000 != 0 {
        f32::from_bits(u & 0x7fff_ffff)
    } else {
        f32::from_bits(!u)
    }
}

/// Per-axis minimum in the total order of [`ordered_bits`].
#[cfg(test)]
#[inline]
pub(crate) fn min_total(a: f32, b: f32) -> f32 {
    if ordered_bits(b) < ordered_bits(a) {
        b
    } else {
        a
    }
}

/// Per-axis maximum in the total order of [`ordered_bits`].
#[cfg(test)]
#[inline]
pub(crate) fn max_total(a: f32, b: f32) -> f32 {
    if ordered_bits(b) > ordered_bits(a) {
        b
    } else {
        a
    }
}

/// Step 3, host part: `scale = 2^b / (hi - lo)` per axis in f32, `0` where `hi == lo`.
///
/// Returns `None` when `hi - lo` overflows f32 (coordinates too far apart for f32 keys, or a bound that is not
/// finite) or the scale does (a non-zero extent below about `2^b / f32::MAX`, 1e-35 for 63-bit codes): such bounds
/// cannot be quantized in f32. [`Quantizer::new`] says which.
#[cfg(test)]
pub(crate) fn quantization_scale(lo: [f32; 3], hi: [f32; 3], bits: MortonBits) -> Option<[f32; 3]> {
    checked_scale(lo, hi, bits).ok()
}

fn checked_scale(lo: [f32; 3], hi: [f32; 3], bits: MortonBits) -> Result<[f32; 3], ExtentError> {
    let cells = (1u32 << bits.per_axis()) as f32;
    if let Some(axis) = (0..3).find(|&a| !(hi[a] - lo[a]).is_finite()) {
        return Err(ExtentError::Wide { axis });
    }
    let mut scale = [0.0f32; 3];
    for a in 0..3 {
        let extent = hi[a] - lo[a];
        scale[a] = if extent == 0.0 { 0.0 } else { cells / extent };
        if !scale[a].is_finite() {
            return Err(ExtentError::Narrow { per_axis: bits.per_axis() });
        }
    }
    Ok(scale)
}

/// Why bounds cannot be quantized in f32 (step 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ExtentError {
    /// `hi - lo` is not finite on this axis (the first such axis): the keys lie too far apart for f32, or a bound
    /// is infinite.
    #[error("axis {axis}: hi - lo overflows f32")]
    Wide {
        /// The axis.
        axis: usize,
    },
    /// A non-zero extent so small that `2^b / extent` overflows f32.
    #[error("an extent is so small that 2^{per_axis} / extent overflows f32")]
    Narrow {
        /// `b`, the bits per axis.
        per_axis: u32,
    },
}

/// Why a set of centroid keys has no Morton codes: the one error of steps 1 to 3, which the characterization, the
/// BVH builders and the device passes each report in their own error type.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum KeyError {
    /// There are no keys (no bounds).
    #[error("no centroid keys")]
    Empty,
    /// Key `index` (the first, in the order of the keys) is not finite: `(v0 + v1) + v2` overflows f32.
    #[error("key {index}: centroid key (v0 + v1) + v2 = {key:?} overflows f32 (coordinates too large)")]
    Overflow {
        /// Position of the key among the keys (for the characterization, of the triangle in the sample).
        index: usize,
        /// The key as computed.
        key: [f32; 3],
    },
    /// The bounds of finite keys cannot be quantized in f32.
    #[error("bounds lo {lo:?} hi {hi:?} cannot be quantized in f32: {reason}")]
    Extent {
        /// `lo` of step 2.
        lo: [f32; 3],
        /// `hi` of step 2.
        hi: [f32; 3],
        /// What overflowed.
        reason: ExtentError,
    },
}

/// Step 2: per-axis bounds of keys, reduced in the total order of `ordered_bits` (the representation every
/// backend reduces in, so that the minimum of `{-0.0, +0.0}` is the same bit pattern everywhere).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KeyBounds {
    lo: [u32; 3],
    hi: [u32; 3],
}

impl Default for KeyBounds {
    fn default() -> Self {
        KeyBounds::EMPTY
    }
}

impl KeyBounds {
    /// No key yet.
    pub const EMPTY: KeyBounds = KeyBounds { lo: [u32::MAX; 3], hi: [0; 3] };

    /// Bounds as the device reduces them: `[lo_x, lo_y, lo_z, hi_x, hi_y, hi_z]` in `ordered_bits` form.
    pub(crate) fn from_ordered_bits(u: [u32; 6]) -> KeyBounds {
        KeyBounds { lo: [u[0], u[1], u[2]], hi: [u[3], u[4], u[5]] }
    }

    /// Adds one key.
    #[inline]
    pub fn add(&mut self, key: [f32; 3]) {
        for ((lo, hi), &k) in self.lo.iter_mut().zip(&mut self.hi).zip(&key) {
            let o = ordered_bits(k);
            *lo = (*lo).min(o);
            *hi = (*hi).max(o);
        }
    }

    /// The bounds of both sets of keys.
    #[inline]
    pub(crate) fn merge(self, o: KeyBounds) -> KeyBounds {
        KeyBounds {
            lo: std::array::from_fn(|a| self.lo[a].min(o.lo[a])),
            hi: std::array::from_fn(|a| self.hi[a].max(o.hi[a])),
        }
    }

    /// Whether no key was added.
    pub fn is_empty(&self) -> bool {
        (0..3).any(|a| self.lo[a] > self.hi[a])
    }

    /// `lo`: the per-axis minimum in the total order.
    pub fn lo(&self) -> [f32; 3] {
        self.lo.map(from_ordered_bits)
    }

    /// `hi`: the per-axis maximum in the total order.
    pub fn hi(&self) -> [f32; 3] {
        self.hi.map(from_ordered_bits)
    }
}

/// Steps 3 and 4 for one set of keys: their bounds and the scale that map a key to its Morton code.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quantizer {
    lo: [f32; 3],
    hi: [f32; 3],
    scale: [f32; 3],
    bits: MortonBits,
}

impl Quantizer {
    /// The quantizer of keys with these bounds (`quantization_scale`).
    ///
    /// Errors: [`KeyError::Empty`] for empty bounds, [`KeyError::Extent`] when the bounds cannot be quantized in
    /// f32 (which includes bounds that are not finite: a caller that can name the overflowing key reports
    /// [`KeyError::Overflow`] instead, as `Quantizer::of_keys` does).
    pub fn new(bounds: &KeyBounds, bits: MortonBits) -> Result<Quantizer, KeyError> {
        if bounds.is_empty() {
            return Err(KeyError::Empty);
        }
        let (lo, hi) = (bounds.lo(), bounds.hi());
        let scale = checked_scale(lo, hi, bits).map_err(|reason| KeyError::Extent { lo, hi, reason })?;
        Ok(Quantizer { lo, hi, scale, bits })
    }

    /// Steps 1 to 3 over `key(j)` for `j` in `0 .. n`, in parallel: the bounds and the quantizer. When a key is
    /// not finite the error is [`KeyError::Overflow`] naming the first such `j`; a set of finite keys whose bounds
    /// cannot be quantized gives [`KeyError::Extent`].
    pub(crate) fn of_keys(
        n: usize,
        key: impl Fn(usize) -> [f32; 3] + Sync,
        bits: MortonBits,
    ) -> Result<Quantizer, KeyError> {
        use rayon::prelude::*;
        let bounds = (0..n)
            .into_par_iter()
            .with_min_len(4096)
            .fold(KeyBounds::default, |mut b, j| {
                b.add(key(j));
                b
            })
            .reduce(KeyBounds::default, KeyBounds::merge);
        Quantizer::finish(&bounds, bits, || {
            (0..n).into_par_iter().map(|j| (j, key(j))).find_first(|(_, k)| !k.iter().all(|c| c.is_finite()))
        })
    }

    /// [`Quantizer::of_keys`] over a slice of keys, one key at a time on the calling thread.
    pub(crate) fn of_slice(keys: &[[f32; 3]], bits: MortonBits) -> Result<Quantizer, KeyError> {
        let mut bounds = KeyBounds::EMPTY;
        for &k in keys {
            bounds.add(k);
        }
        Quantizer::finish(&bounds, bits, || {
            keys.iter().copied().enumerate().find(|(_, k)| !k.iter().all(|c| c.is_finite()))
        })
    }

    /// A quantizer from its parts, as a plan records them (no check: `scale` is what [`Quantizer::new`] computed for
    /// bounds `lo`, `hi`).
    pub(crate) fn from_parts(lo: [f32; 3], hi: [f32; 3], scale: [f32; 3], bits: MortonBits) -> Quantizer {
        Quantizer { lo, hi, scale, bits }
    }

    /// The quantizer of `bounds`, or the first overflowing key (found by `first_overflow`) when a bound is not
    /// finite.
    fn finish(
        bounds: &KeyBounds,
        bits: MortonBits,
        first_overflow: impl FnOnce() -> Option<(usize, [f32; 3])>,
    ) -> Result<Quantizer, KeyError> {
        let q = Quantizer::new(bounds, bits);
        let finite = bounds.lo().iter().chain(&bounds.hi()).all(|c| c.is_finite());
        match q {
            Err(KeyError::Extent { .. }) if !finite => match first_overflow() {
                Some((index, key)) => Err(KeyError::Overflow { index, key }),
                None => q,
            },
            _ => q,
        }
    }

    /// `lo` of step 2.
    pub fn lo(&self) -> [f32; 3] {
        self.lo
    }

    /// `hi` of step 2.
    pub fn hi(&self) -> [f32; 3] {
        self.hi
    }

    /// `scale` of step 3.
    pub fn scale(&self) -> [f32; 3] {
        self.scale
    }

    /// The code width.
    pub fn bits(&self) -> MortonBits {
        self.bits
    }

    /// Steps 3 and 4 for one key: `morton(quantize(key, lo, scale, bits), bits)`.
    #[inline]
    pub fn code(&self, key: [f32; 3]) -> u64 {
        morton(quantize(key, self.lo, self.scale, self.bits), self.bits)
    }
}

/// Steps 1 to 4 over `key(j)` for `j` in `0 .. n`, in parallel: the quantizer and the code of every key, in order.
/// Errors as [`Quantizer::of_keys`].
pub(crate) fn morton_codes(
    n: usize,
    key: impl Fn(usize) -> [f32; 3] + Sync,
    bits: MortonBits,
) -> Result<(Quantizer, Vec<u64>), KeyError> {
    use rayon::prelude::*;
    let q = Quantizer::of_keys(n, &key, bits)?;
    let codes = (0..n).into_par_iter().with_min_len(4096).map(|j| q.code(key(j))).collect();
    Ok((q, codes))
}

/// Step 3, per triangle: `q = min(floor((s - lo) * scale), 2^b - 1)` in f32, then to an unsigned integer.
#[inline]
pub(crate) fn quantize(s: [f32; 3], lo: [f32; 3], scale: [f32; 3], bits: MortonBits) -> [u32; 3] {
    let top = ((1u32 << bits.per_axis()) - 1) as f32;
    let mut q = [0u32; 3];
    for a in 0..3 {
        // `(x).min(top) as u32` is `floor(x).min(top) as u32` for every x: the cast truncates towards zero, which is
        // the floor for x >= 0, and saturates at 0 below 1 where the floor's result would too (a NaN gives `top`
        // both ways, through `min`). It spares the floor, a library call on x86-64 without SSE4.1 (an eighth of the
        // Morton codes' time). x is in [0, 2^b - 1] anyway: (s - lo) >= 0, scale >= 0, finite for validated input.
        q[a] = ((s[a] - lo[a]) * scale[a]).min(top) as u32;
    }
    q
}

/// Spreads the low 10 bits of `v` so that bit `i` lands on bit `3 i`.
#[inline]
pub(crate) fn spread10(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x | (x << 16)) & 0x0300_00ff;
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    x = (x | (x << 2)) & 0x0924_9249;
    x
}

/// Spreads the low 21 bits of `v` so that bit `i` lands on bit `3 i`.
#[inline]
pub(crate) fn spread21(v: u32) -> u64 {
    let mut x = (v as u64) & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Step 4: interleave `q` (bit `i` of x to bit `3i+2`, of y to `3i+1`, of z to `3i`).
#[inline]
pub(crate) fn morton(q: [u32; 3], bits: MortonBits) -> u64 {
    match bits {
        MortonBits::Bits30 => ((spread10(q[0]) << 2) | (spread10(q[1]) << 1) | spread10(q[2])) as u64,
        MortonBits::Bits63 => (spread21(q[0]) << 2) | (spread21(q[1]) << 1) | spread21(q[2]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_equals_the_floor_it_no_longer_calls() {
        // The saturating cast of min(x, top) is floor(x).min(top) as u32 for every x, the edges included.
        let mut xs = vec![0.0f32, -0.0, 0.5, 0.999_999_9, 1.0, 1.5, -0.5, -1.0, -1.5, -1e30, 1e30, f32::NAN];
        xs.extend([f32::INFINITY, f32::NEG_INFINITY, f32::MIN_POSITIVE, -f32::MIN_POSITIVE, 1023.5, 1024.0, 2097150.5]);
        let mut seed = 11u64;
        for _ in 0..100_000 {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            xs.push(f32::from_bits((seed >> 32) as u32));
        }
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            let t = ((1u32 << bits.per_axis()) - 1) as f32;
            for &x in &xs {
                // With lo = 0 and scale = 1 the quantizer sees x itself ((x - 0) * 1 is x, -0 included).
                let want = x.floor().min(t) as u32;
                let got = quantize([x; 3], [0.0; 3], [1.0; 3], bits);
                assert_eq!(got, [want; 3], "x {x:e} ({:#x}), {bits:?}", x.to_bits());
            }
        }
    }

    fn morton_slow(q: [u32; 3], b: u32) -> u64 {
        let mut m = 0u64;
        for i in 0..b {
            m |= (((q[0] >> i) & 1) as u64) << (3 * i + 2);
            m |= (((q[1] >> i) & 1) as u64) << (3 * i + 1);
            m |= (((q[2] >> i) & 1) as u64) << (3 * i);
        }
        m
    }

    #[test]
    fn morton_matches_bit_loop() {
        let mut x = 0x1234_5678_9abc_def0u64;
        for _ in 0..10_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let q = [(x & 0x1f_ffff) as u32, ((x >> 21) & 0x1f_ffff) as u32, ((x >> 42) & 0x1f_ffff) as u32];
            assert_eq!(morton(q, MortonBits::Bits63), morton_slow(q, 21));
            let q10 = [q[0] & 0x3ff, q[1] & 0x3ff, q[2] & 0x3ff];
            assert_eq!(morton(q10, MortonBits::Bits30), morton_slow(q10, 10));
        }
    }

    #[test]
    fn ordered_bits_is_total_order() {
        let xs = [f32::NEG_INFINITY, -1e30, -1.0, -1e-40, -0.0, 0.0, 1e-40, 1.0, 3e38, f32::INFINITY];
        for w in xs.windows(2) {
            assert!(ordered_bits(w[0]) < ordered_bits(w[1]), "{} {}", w[0], w[1]);
        }
        for &x in &xs {
            assert_eq!(from_ordered_bits(ordered_bits(x)).to_bits(), x.to_bits());
        }
    }

    #[test]
    fn quantizer_names_the_first_overflowing_key_before_the_extent() {
        let b = MortonBits::Bits30;
        let bad = [[0.0, 0.0, 0.0], [f32::INFINITY, 0.0, 0.0], [1.0, f32::NEG_INFINITY, 0.0]];
        let e = Err(KeyError::Overflow { index: 1, key: bad[1] });
        assert_eq!(Quantizer::of_slice(&bad, b), e);
        assert_eq!(Quantizer::of_keys(3, |j| bad[j], b), e);
        let wide = [[0.0, -3e38, 0.0], [0.0, 3e38, 0.0]];
        let e = Quantizer::of_keys(2, |j| wide[j], b);
        assert!(matches!(e, Err(KeyError::Extent { reason: ExtentError::Wide { axis: 1 }, .. })), "{e:?}");
        let tiny = [[0.0; 3], [1e-44; 3]];
        let e = Quantizer::of_slice(&tiny, MortonBits::Bits63);
        assert!(matches!(e, Err(KeyError::Extent { reason: ExtentError::Narrow { per_axis: 21 }, .. })), "{e:?}");
        assert_eq!(Quantizer::of_slice(&[], b), Err(KeyError::Empty));
        assert_eq!(Quantizer::of_keys(0, |_| [0.0; 3], b), Err(KeyError::Empty));
        let keys: Vec<[f32; 3]> = (0..10_000).map(|i| [i as f32, -(i as f32) * 0.5, (i % 7) as f32]).collect();
        let q = Quantizer::of_slice(&keys, b).unwrap();
        assert_eq!(Quantizer::of_keys(keys.len(), |j| keys[j], b), Ok(q));
        let (q2, codes) = morton_codes(keys.len(), |j| keys[j], b).unwrap();
        assert_eq!(q2, q);
        assert_eq!((q.lo(), q.hi()), ([0.0, -4999.5, 0.0], [9999.0, -0.0, 6.0]));
        for (k, c) in keys.iter().zip(&codes) {
            assert_eq!(*c, morton(quantize(*k, q.lo(), quantization_scale(q.lo(), q.hi(), b).unwrap(), b), b));
        }
    }

    #[test]
    fn quantize_clamps_top_and_flat_axis() {
        let lo = [0.0, 5.0, -1.0];
        let hi = [3.0, 5.0, 1.0];
        let scale = quantization_scale(lo, hi, MortonBits::Bits30).unwrap();
        assert_eq!(scale[1], 0.0);
        assert_eq!(quantize(hi, lo, scale, MortonBits::Bits30), [1023, 0, 1023]);
        assert_eq!(quantize(lo, lo, scale, MortonBits::Bits30), [0, 0, 0]);
        assert!(quantization_scale([-3e38; 3], [3e38; 3], MortonBits::Bits30).is_none());
        // A positive extent so small that 2^b / extent overflows.
        assert!(quantization_scale([0.0; 3], [1e-40; 3], MortonBits::Bits63).is_none());
        assert!(quantization_scale([0.0; 3], [1e-30; 3], MortonBits::Bits63).is_some());
    }
}
