//! Exact rational arithmetic (num-rational over num-bigint) for reference values of the host math: correct
//! rounding of an f64 or f32, errors in units in the last place, square roots to 256 bits.
#![allow(dead_code)]

use num_bigint::BigInt;
use num_rational::BigRational;
use num_traits::{Signed, ToPrimitive, Zero};

/// The exact value of a finite f64.
pub(crate) fn rat(x: f64) -> BigRational {
    BigRational::from_float(x).expect("finite")
}

/// The exact value of a finite f32.
pub(crate) fn rat32(x: f32) -> BigRational {
    BigRational::from_float(x).expect("finite")
}

/// `a / b` for integers, `b != 0`.
pub(crate) fn ratio(a: impl Into<BigInt>, b: impl Into<BigInt>) -> BigRational {
    BigRational::new(a.into(), b.into())
}

/// The distance from `|x|` to the next f64 up: one unit in the last place of `x` (the smallest subnormal for 0).
pub(crate) fn ulp(x: f64) -> f64 {
    let a = x.abs();
    f64::from_bits(a.to_bits() + 1) - a
}

/// `|x - q| / ulp(x)`.
pub(crate) fn ulps(x: f64, q: &BigRational) -> f64 {
    ((rat(x) - q).abs() / rat(ulp(x))).to_f64().unwrap_or(f64::INFINITY)
}

/// Whether `x` is `q` rounded to the nearest f64, ties to even (`q` within the normal range or zero).
pub(crate) fn correctly_rounded(x: f64, q: &BigRational) -> bool {
    if q.is_zero() || x == 0.0 {
        return q.is_zero() && x == 0.0;
    }
    if (x < 0.0) != q.is_negative() {
        return false;
    }
    let a = x.abs();
    let down = f64::from_bits(a.to_bits() - 1);
    let up = f64::from_bits(a.to_bits() + 1);
    let two = BigRational::from_integer(BigInt::from(2));
    let (lo, hi) = ((rat(down) + rat(a)) / &two, (rat(a) + rat(up)) / &two);
    let qa = q.abs();
    if qa < lo || qa > hi {
        return false;
    }
    qa != lo && qa != hi || a.to_bits() & 1 == 0
}

/// Whether `x` is `q` rounded to the nearest f32, ties to even (`q > 0` within the normal range).
pub(crate) fn correctly_rounded32(x: f32, q: &BigRational) -> bool {
    if !(x > 0.0 && q.is_positive()) {
        return false;
    }
    let down = f32::from_bits(x.to_bits() - 1);
    let up = f32::from_bits(x.to_bits() + 1);
    let two = BigRational::from_integer(BigInt::from(2));
    let (lo, hi) = ((rat32(down) + rat32(x)) / &two, (rat32(x) + rat32(up)) / &two);
    if *q < lo || *q > hi {
        return false;
    }
    *q != lo && *q != hi || x.to_bits() & 1 == 0
}

/// `sqrt(q)` for `q >= 0`, truncated to at least 256 significant bits (relative error below `2^-255`): accurate
/// enough to measure an f64's error in ulps to far more digits than are reported.
pub(crate) fn sqrt(q: &BigRational) -> BigRational {
    if q.is_zero() {
        return BigRational::zero();
    }
    let (num, den) = (q.numer().magnitude(), q.denom().magnitude());
    // sqrt(num / den) 2^p with at least 256 bits: p >= 256 + (bits(den) - bits(num)) / 2 + 1.
    let p = (256 + (den.bits() as i64 - num.bits() as i64) / 2 + 2).max(0) as u64;
    let scaled = (num << (2 * p)) / den;
    BigRational::new(BigInt::from(scaled.sqrt()), BigInt::from(1) << p)
}

/// Whether `|x - r| <= k ulp(x)` for `r = sign * sqrt(r2)` (`r2 >= 0`), decided exactly by comparing squares:
/// `(|x| - k ulp)^2 <= r2 <= (|x| + k ulp)^2`, with the sign of `x` that of `r` (or `x == 0` when `r2 == 0`).
pub(crate) fn sqrt_within(x: f64, negative: bool, r2: &BigRational, k: f64) -> bool {
    if r2.is_zero() {
        return x == 0.0;
    }
    if x == 0.0 || (x < 0.0) != negative {
        return false;
    }
    let a = rat(x.abs());
    let u = rat(ulp(x)) * rat(k);
    let lo = (&a - &u).max(BigRational::zero());
    let hi = &a + &u;
    &lo * &lo <= *r2 && *r2 <= &hi * &hi
}

/// The exact figures of docs/spec.md steps 9 and 10 of a histogram of `n` codes in `k = hist.len()` classes.
pub struct HistogramExact {
    /// `T / (n k)`, `T = sum (k O_i - n)^2` (0 for `k <= 1`).
    pub chi_square: BigRational,
    /// `T / (n^2 k (k - 1))`, the square of Cramér's V before the clamp to 1 (0 for `k <= 1`).
    pub v_squared: BigRational,
    /// `C / n`, `C` the codes in classes with `k O_i > n` (0 for `k <= 1`).
    pub concentrated_share: BigRational,
    /// Classes with `k O_i > n` (0 for `k <= 1`).
    pub concentrated_classes: usize,
    /// Classes with `O_i == 0`.
    pub empty_classes: usize,
}

/// [`HistogramExact`] of `hist`, by the definitions, in big integers.
pub(crate) fn histogram_exact(hist: &[u64], n: u64) -> HistogramExact {
    let k = hist.len() as u64;
    let empty_classes = hist.iter().filter(|&&o| o == 0).count();
    if k <= 1 || n == 0 {
        let zero = BigRational::zero();
        return HistogramExact {
            chi_square: zero.clone(),
            v_squared: zero.clone(),
            concentrated_share: zero,
            concentrated_classes: 0,
            empty_classes,
        };
    }
    let (nb, kb) = (BigInt::from(n), BigInt::from(k));
    let t: BigInt = hist.iter().map(|&o| (&kb * BigInt::from(o) - &nb).pow(2)).sum();
    let conc: Vec<u64> = hist.iter().copied().filter(|&o| k as u128 * o as u128 > n as u128).collect();
    let c: BigInt = conc.iter().map(|&o| BigInt::from(o)).sum();
    HistogramExact {
        chi_square: ratio(t.clone(), &nb * &kb),
        v_squared: ratio(t, &nb * &nb * &kb * (&kb - 1)),
        concentrated_share: ratio(c, nb),
        concentrated_classes: conc.len(),
        empty_classes,
    }
}
