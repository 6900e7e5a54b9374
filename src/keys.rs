//! Centroid keys, quantization and Morton codes exactly as `docs/spec.md` steps 1 to 4 pin them.
//!
//! These are the scalar definitions shared by the CPU paths, the tests that check the GPU, and the BVH builders
//! (LBVH and HLBVH sort triangles by the same codes). Every function is exact IEEE f32 or integer arithmetic, so a
//! GPU kernel that performs the same operations (marked `precise`, no fused multiply-add, no division) produces the
//! same bits.

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
    pub fn per_axis(self) -> u32 {
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
pub fn centroid_key(v0: [f32; 3], v1: [f32; 3], v2: [f32; 3]) -> [f32; 3] {
    [(v0[0] + v1[0]) + v2[0], (v0[1] + v1[1]) + v2[1], (v0[2] + v1[2]) + v2[2]]
}

/// Maps an f32 to a `u32` whose unsigned order is the IEEE total order of the float (`-0.0 < +0.0`).
///
/// Bounds are reduced in this representation on every backend, so that the minimum of `{-0.0, +0.0}` is the same
/// bit pattern everywhere.
#[inline]
pub fn ordered_bits(x: f32) -> u32 {
    let b = x.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Inverse of [`ordered_bits`].
#[inline]
pub fn from_ordered_bits(u: u32) -> f32 {
    if u & 0x8000_0000 != 0 {
        f32::from_bits(u & 0x7fff_ffff)
    } else {
        f32::from_bits(!u)
    }
}

/// Per-axis minimum in the total order of [`ordered_bits`].
#[inline]
pub fn min_total(a: f32, b: f32) -> f32 {
    if ordered_bits(b) < ordered_bits(a) {
        b
    } else {
        a
    }
}

/// Per-axis maximum in the total order of [`ordered_bits`].
#[inline]
pub fn max_total(a: f32, b: f32) -> f32 {
    if ordered_bits(b) > ordered_bits(a) {
        b
    } else {
        a
    }
}

/// Step 3, host part: `scale = 2^b / (hi - lo)` per axis in f32, `0` where `hi == lo`.
///
/// Returns `None` when `hi - lo` overflows f32 (coordinates too far apart for f32 keys) or the scale does (a
/// non-zero extent below about `2^b / f32::MAX`, 1e-35 for 63-bit codes): such bounds cannot be quantized in f32.
pub fn quantization_scale(lo: [f32; 3], hi: [f32; 3], bits: MortonBits) -> Option<[f32; 3]> {
    let cells = (1u32 << bits.per_axis()) as f32;
    let mut scale = [0.0f32; 3];
    for a in 0..3 {
        let extent = hi[a] - lo[a];
        if !extent.is_finite() {
            return None;
        }
        scale[a] = if extent == 0.0 { 0.0 } else { cells / extent };
        if !scale[a].is_finite() {
            return None;
        }
    }
    Some(scale)
}

/// Step 3, per triangle: `q = min(floor((s - lo) * scale), 2^b - 1)` in f32, then to an unsigned integer.
#[inline]
pub fn quantize(s: [f32; 3], lo: [f32; 3], scale: [f32; 3], bits: MortonBits) -> [u32; 3] {
    let top = ((1u32 << bits.per_axis()) - 1) as f32;
    let mut q = [0u32; 3];
    for a in 0..3 {
        let v = ((s[a] - lo[a]) * scale[a]).floor().min(top);
        // v is in [0, 2^b - 1]: (s - lo) >= 0 and scale >= 0, and both are finite for validated input.
        q[a] = v as u32;
    }
    q
}

/// Spreads the low 10 bits of `v` so that bit `i` lands on bit `3 i`.
#[inline]
pub fn spread10(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x | (x << 16)) & 0x0300_00ff;
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    x = (x | (x << 2)) & 0x0924_9249;
    x
}

/// Spreads the low 21 bits of `v` so that bit `i` lands on bit `3 i`.
#[inline]
pub fn spread21(v: u32) -> u64 {
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
pub fn morton(q: [u32; 3], bits: MortonBits) -> u64 {
    match bits {
        MortonBits::Bits30 => ((spread10(q[0]) << 2) | (spread10(q[1]) << 1) | spread10(q[2])) as u64,
        MortonBits::Bits63 => (spread21(q[0]) << 2) | (spread21(q[1]) << 1) | spread21(q[2]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
