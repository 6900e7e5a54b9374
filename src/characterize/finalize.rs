//! Host-side math shared by every backend: from the exact quantities ([`CodeStats`], the histogram) to the reported
//! figures (docs/spec.md steps 5, 6, 7, 9, 10).
//!
//! Every function here is deterministic and takes only exact integers (or figures computed from them by this module),
//! so all backends report the same bits. Integer work is exact (`BigInt`, `u128`); each division that produces a
//! reported float is a correctly rounded quotient of two exact integers ([`ratio_to_f64`]).

use super::{ClassRule, CodeStats, HistogramStats, Moments, MAX_CLASSES};
use crate::stats;
use num_bigint::{BigInt, BigUint, Sign};
use num_traits::Zero;

/// The quotient `num / den` of two non-negative integers, correctly rounded to the nearest f64 (ties to even).
///
/// Returns 0 when `den` is zero (callers never divide by zero; this keeps the function total). Results that exceed
/// the f64 range are `f64::MAX`; results below the normal range are flushed toward 0 (only a denominator of more than
/// about 1000 bits could produce one).
pub(crate) fn ratio_to_f64(num: &BigUint, den: &BigUint) -> f64 {
    if den.is_zero() || num.is_zero() {
        return 0.0;
    }
    // Scale the numerator so that the integer quotient has at least 66 significant bits.
    let shift = (den.bits() as i64 - num.bits() as i64 + 66).max(0);
    let scaled = num << (shift as u64);
    let q = &scaled / den;
    let mut sticky = !(&scaled - &q * den).is_zero();
    let qbits = q.bits() as i64;
    // Keep the top 64 bits of q; fold every lower bit into the sticky bit.
    let drop = qbits - 64;
    let top: u64 = if drop > 0 {
        let t = &q >> (drop as u64);
        sticky |= !(&q - (&t << (drop as u64))).is_zero();
        t.iter_u64_digits().next().unwrap_or(0)
    } else {
        q.iter_u64_digits().next().unwrap_or(0)
    };
    // top has its highest bit set and 11 bits below the 53 kept by the conversion: OR-ing the sticky bit into bit 0
    // makes the u64 -> f64 conversion (round to nearest even) round exactly as the full quotient would.
    let top = top | u64::from(sticky);
    let exp = drop.max(0) - shift;
    ldexp(top as f64, exp)
}

/// `x * 2^e`, exact while the result is a normal f64; saturates to `f64::MAX` and flushes to 0 outside.
fn ldexp(x: f64, e: i64) -> f64 {
    let mut x = x;
    let mut e = e;
    while e > 0 {
        let step = e.min(1000);
        x *= f64::from_bits(((1023 + step) as u64) << 52);
        e -= step;
        if x.is_infinite() {
            return f64::MAX;
        }
    }
    while e < 0 {
        let step = (-e).min(1000);
        x /= f64::from_bits(((1023 + step) as u64) << 52);
        e += step;
    }
    x
}

/// Signed version of [`ratio_to_f64`].
fn signed_ratio_to_f64(num: &BigInt, den: &BigUint) -> f64 {
    let r = ratio_to_f64(num.magnitude(), den);
    if num.sign() == Sign::Minus {
        -r
    } else {
        r
    }
}

/// Exact central moments of the codes, scaled to integers: `M2n = n S2 - S1^2 = n sum (m - mu)^2` (never
/// negative) and `M3n = n^2 S3 - 3 n S1 S2 + 2 S1^3 = n^2 sum (m - mu)^3` (signed).
pub(crate) fn central_moments(s: &CodeStats) -> (BigUint, BigInt) {
    let n = BigInt::from(s.n);
    let s1 = BigInt::from(s.s1.clone());
    let s2 = BigInt::from(s.s2.clone());
    let s3 = BigInt::from(s.s3.clone());
    let m2 = &n * &s2 - &s1 * &s1;
    let m3 = &n * &n * &s3 - BigInt::from(3u32) * &n * &s1 * &s2 + BigInt::from(2u32) * &s1 * &s1 * &s1;
    // m2 >= 0 by Cauchy-Schwarz for any consistent CodeStats; clamp anyway so inconsistent input cannot go negative.
    let m2 = m2.to_biguint().unwrap_or_default();
    (m2, m3)
}

/// Mean, population standard deviation and population skewness of the codes (docs/spec.md step 5), from the exact power
/// sums.
///
/// * `mean = S1 / n`, correctly rounded;
/// * `std_dev = sqrt(M2n / n^2)`: the quotient correctly rounded, then one correctly rounded `sqrt` (within 1 ulp);
/// * `skewness = (sum (m - mu)^3 / n) / sigma^3 = M3n / M2n^1.5` as `(M3n / M2n) / sqrt(M2n)`: a correctly rounded
///   quotient, the f64 of `M2n` correctly rounded, a square root and one division (within a few ulp).
///
/// So each figure is within a few units in the last place of the exact real value: the relative errors add up to
/// below `1.5 * 2^-53` for `std_dev` (1 ulp) and `3.5 * 2^-53` for `skewness` (4 ulp); `src/characterize/tests/host_math.rs` checks
/// all three against exact rationals. `n == 0` gives all zeros;
/// `M2n == 0` (all codes equal, `n == 1`) gives `std_dev = skewness = 0`. Never NaN or infinite.
pub(crate) fn moments(s: &CodeStats) -> Moments {
    if s.n == 0 {
        return Moments { mean: 0.0, std_dev: 0.0, skewness: 0.0 };
    }
    let n = BigUint::from(s.n);
    let mean = ratio_to_f64(&s.s1, &n);
    let (m2, m3) = central_moments(s);
    if m2.is_zero() {
        return Moments { mean, std_dev: 0.0, skewness: 0.0 };
    }
    let std_dev = ratio_to_f64(&m2, &(&n * &n)).sqrt();
    let a = signed_ratio_to_f64(&m3, &m2);
    let m2f = ratio_to_f64(&m2, &BigUint::from(1u32));
    let skewness = a / m2f.sqrt();
    Moments { mean, std_dev, skewness: if skewness.is_finite() { skewness } else { 0.0 } }
}

/// Number of classes `k` (docs/spec.md step 6 for [`ClassRule::Doane`]), clamped to `1..=MAX_CLASSES`.
///
/// * Doane: `sigma_g1 = sqrt(6 (n - 2) / ((n + 1)(n + 3)))`, `k = ceil(1 + log2 n + log2(1 + |g1| / sigma_g1))`;
///   `k = 1` when `n <= 2`, `std_dev == 0` or `all_equal` (every code the same).
/// * Sturges: `ceil(1 + log2 n)`. Sqrt: `ceil(sqrt n)`. Fixed: the given count.
///
/// For every rule `k = 1` when `n == 0` or `all_equal`: a single code value has a single class (and step 7 puts
/// every triangle in class 0 anyway).
pub(crate) fn class_count(rule: ClassRule, n: u64, m: &Moments, all_equal: bool) -> u32 {
    if n == 0 || all_equal {
        return 1;
    }
    let nf = n as f64;
    let k = match rule {
        ClassRule::Doane => {
            if n <= 2 || m.std_dev == 0.0 {
                return 1;
            }
            let sigma_g1 = (6.0 * (nf - 2.0) / ((nf + 1.0) * (nf + 3.0))).sqrt();
            (1.0 + nf.log2() + (1.0 + m.skewness.abs() / sigma_g1).log2()).ceil()
        }
        ClassRule::Sturges => (1.0 + nf.log2()).ceil(),
        ClassRule::Sqrt => nf.sqrt().ceil(),
        ClassRule::Fixed(k) => k as f64,
    };
    if k.is_nan() {
        return 1;
    }
    k.clamp(1.0, MAX_CLASSES as f64) as u32
}

/// The class count of step 6 for the codes of `s`: [`class_count`] with the [`moments`] of `s` (every code equal when
/// `code_min == code_max`). What every backend plans its classes with.
pub(crate) fn class_count_of(rule: ClassRule, s: &CodeStats) -> u32 {
    class_count(rule, s.n, &moments(s), s.code_min == s.code_max)
}

/// Class of a code (docs/spec.md step 7): `min(((m - m_min) k) div (m_max - m_min), k - 1)`, exact in `u128`; 0 when
/// `m_max == m_min` or `k <= 1`. Codes outside `[m_min, m_max]` are clamped to the nearest end.
#[inline]
pub(crate) fn class_of(code: u64, code_min: u64, code_max: u64, k: u32) -> u32 {
    if code_max <= code_min || k <= 1 {
        return 0;
    }
    let x = code.clamp(code_min, code_max) - code_min;
    let d = code_max - code_min;
    let c = (x as u128 * k as u128) / d as u128;
    c.min(k as u128 - 1) as u32
}

/// Class thresholds `t_j = ceil(j D / k)` for `j = 1 .. k-1`, `D = m_max - m_min` (exact in `u128`).
///
/// `class_of(m) == #{ j : t_j <= m - m_min }`, because for an integer `x`, `floor(x k / D) >= j` iff
/// `x >= j D / k` iff `x >= ceil(j D / k)`. The GPU uses this form to avoid 128-bit division. The result always has
/// `k - 1` entries (none for `k <= 1`); when `D == 0` every entry is `u64::MAX`, so every code is in class 0 as
/// [`class_of`] says.
pub(crate) fn class_thresholds(code_min: u64, code_max: u64, k: u32) -> Vec<u64> {
    if k <= 1 {
        return Vec::new();
    }
    if code_max <= code_min {
        return vec![u64::MAX; (k - 1) as usize];
    }
    let d = (code_max - code_min) as u128;
    let k128 = k as u128;
    (1..k as u128).map(|j| (j * d).div_ceil(k128) as u64).collect()
}

/// Class of `x = m - m_min` from [`class_thresholds`] by binary search (equal to [`class_of`]).
#[inline]
#[cfg(test)]
pub(crate) fn class_from_thresholds(x: u64, thresholds: &[u64]) -> u32 {
    thresholds.partition_point(|&t| t <= x) as u32
}

/// `T = sum (k O_i - n)^2`, exact.
fn chi_numerator(hist: &[u64], n: u64) -> BigUint {
    let k = hist.len() as u128;
    let n128 = n as u128;
    let mut acc: Option<u128> = Some(0);
    for &o in hist {
        let ko = k.checked_mul(o as u128);
        let term = ko.map(|ko| ko.abs_diff(n128)).and_then(|d| d.checked_mul(d));
        acc = match (acc, term) {
            (Some(a), Some(t)) => a.checked_add(t),
            _ => None,
        };
        if acc.is_none() {
            break;
        }
    }
    if let Some(a) = acc {
        return BigUint::from(a);
    }
    // Astronomically large counts: the same sum with big integers.
    let kb = BigInt::from(hist.len());
    let nb = BigInt::from(n);
    hist.iter()
        .map(|&o| {
            let d = &kb * BigInt::from(o) - &nb;
            (&d * &d).magnitude().clone()
        })
        .sum()
}

/// Chi-square against uniform, p-value, critical value, Cramér's V, concentrated and empty classes (docs/spec.md steps 9
/// and 10) of a histogram of `n` codes at significance `alpha`.
///
/// Counts the exact quantities (`T = sum (k O_i - n)^2`, empty classes `O_i == 0`, concentrated classes
/// `k O_i > n` and the triangles in them) and hands them to [`histogram_stats_from`]. For `k <= 1` (or `n == 0`):
/// chi-square 0, p 1, critical value 0, uniform, V 0. Never NaN or infinite.
pub(crate) fn histogram_stats(hist: &[u64], n: u64, alpha: f64) -> HistogramStats {
    let k = hist.len() as u64;
    let empty_classes = hist.iter().filter(|&&o| o == 0).count() as u32;
    let mut concentrated_classes = 0u32;
    let mut concentrated_triangles = 0u64;
    for &o in hist {
        if (k as u128) * (o as u128) > n as u128 {
            concentrated_classes += 1;
            concentrated_triangles += o;
        }
    }
    let t = chi_numerator(hist, n);
    histogram_stats_from(&t, empty_classes, concentrated_classes, concentrated_triangles, n, k as u32, alpha)
}

/// [`histogram_stats_from`] with a `u128` chi-square numerator, as the GPU reduces it.
pub(crate) fn histogram_stats_exact(
    chi_numerator: u128,
    empty_classes: u32,
    concentrated_classes: u32,
    concentrated_triangles: u64,
    n: u64,
    k: u32,
    alpha: f64,
) -> HistogramStats {
    histogram_stats_from(
        &BigUint::from(chi_numerator),
        empty_classes,
        concentrated_classes,
        concentrated_triangles,
        n,
        k,
        alpha,
    )
}

/// Steps 9 and 10 from exact reductions of a histogram of `n` codes in `k` classes: `t = sum (k O_i - n)^2`, the
/// number of empty classes, of concentrated classes (`k O_i > n`) and of the triangles in them.
///
/// `chi2 = t / (n k)`, which equals `sum (O_i - E)^2 / E` with `E = n / k`, correctly rounded; Cramér's
/// `V = sqrt(t / (n^2 k (k - 1)))` likewise; the concentrated share `concentrated_triangles / n` likewise; p-value
/// and critical value from [`crate::stats`]; uniform iff `chi2 <= critical value`. For `k <= 1` or `n == 0`:
/// chi-square 0, p 1, critical value 0, uniform, V 0, no concentrated class. Never NaN or infinite.
pub(crate) fn histogram_stats_from(
    t: &BigUint,
    empty_classes: u32,
    concentrated_classes: u32,
    concentrated_triangles: u64,
    n: u64,
    k: u32,
    alpha: f64,
) -> HistogramStats {
    if k <= 1 || n == 0 {
        return HistogramStats {
            chi_square: 0.0,
            dof: 0,
            p_value: 1.0,
            critical_value: 0.0,
            uniform: true,
            cramers_v: 0.0,
            empty_classes,
            concentrated_classes: 0,
            concentrated_share: 0.0,
        };
    }
    let k = u64::from(k);
    let nb = BigUint::from(n);
    let kb = BigUint::from(k);
    let chi_square = ratio_to_f64(t, &(&nb * &kb));
    let cramers_v = ratio_to_f64(t, &(&nb * &nb * &kb * BigUint::from(k - 1))).sqrt().min(1.0);
    let dof = (k - 1) as u32;
    let p_value = stats::chi2_sf(chi_square, dof);
    let critical_value = stats::chi2_critical(alpha, dof);
    let critical_value = if critical_value.is_finite() { critical_value } else { f64::MAX };
    let concentrated_share = ratio_to_f64(&BigUint::from(concentrated_triangles), &nb);
    HistogramStats {
        chi_square,
        dof,
        p_value,
        critical_value,
        uniform: chi_square <= critical_value,
        cramers_v,
        empty_classes,
        concentrated_classes,
        concentrated_share,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64 as Rng;

    fn stats_of(codes: &[u64]) -> CodeStats {
        let mut s = CodeStats {
            n: codes.len() as u64,
            code_min: codes.iter().copied().min().unwrap_or(0),
            code_max: codes.iter().copied().max().unwrap_or(0),
            s1: BigUint::zero(),
            s2: BigUint::zero(),
            s3: BigUint::zero(),
        };
        for &c in codes {
            let c = BigUint::from(c);
            s.s1 += &c;
            s.s2 += &c * &c;
            s.s3 += &c * &c * &c;
        }
        s
    }

    #[test]
    fn ratio_is_correctly_rounded() {
        // Exactly representable quotients and ties.
        let r = |a: u128, b: u128| ratio_to_f64(&BigUint::from(a), &BigUint::from(b));
        assert_eq!(r(1, 2), 0.5);
        assert_eq!(r(10, 4), 2.5);
        assert_eq!(r(1, 3), 1.0 / 3.0);
        assert_eq!(r(2, 3), 2.0 / 3.0);
        assert_eq!(r(0, 3), 0.0);
        assert_eq!(r(5, 0), 0.0);
        // 2^53 + 1 is a tie between 2^53 and 2^53 + 2: round to even (2^53).
        assert_eq!(r((1 << 53) + 1, 1), 9007199254740992.0);
        // 2^53 + 3 ties between 2^53 + 2 and 2^53 + 4: even is 2^53 + 4.
        assert_eq!(r((1 << 53) + 3, 1), 9007199254740996.0);
        // Just above a tie rounds up.
        assert_eq!(r(((1 << 53) + 1) * 1000 + 1, 1000), 9007199254740994.0);
        // Quotients of u64 values whose f64 division is correctly rounded (both operands exact in f64).
        let mut g = Rng(99);
        for _ in 0..10_000 {
            let a = g.next_u64() >> 12;
            let b = (g.next_u64() >> 12).max(1);
            assert_eq!(r(a as u128, b as u128), a as f64 / b as f64);
        }
        // Huge values.
        let big = BigUint::from(1u32) << 1000u32;
        assert_eq!(ratio_to_f64(&big, &(BigUint::from(1u32) << 999u32)), 2.0);
        assert_eq!(ratio_to_f64(&(BigUint::from(1u32) << 1100u32), &BigUint::from(1u32)), f64::MAX);
    }

    fn two_pass(codes: &[u64]) -> (f64, f64, f64) {
        let n = codes.len() as f64;
        let mean = codes.iter().map(|&c| c as f64).sum::<f64>() / n;
        let var = codes.iter().map(|&c| (c as f64 - mean).powi(2)).sum::<f64>() / n;
        let sd = var.sqrt();
        let skew =
            if sd > 0.0 { codes.iter().map(|&c| ((c as f64 - mean) / sd).powi(3)).sum::<f64>() / n } else { 0.0 };
        (mean, sd, skew)
    }

    #[test]
    fn moments_match_two_pass() {
        let mut g = Rng(7);
        for bits in [4u32, 30, 63] {
            for n in [1usize, 2, 3, 10, 1000] {
                let codes: Vec<u64> = (0..n).map(|_| g.next_u64() >> (64 - bits)).collect();
                let m = moments(&stats_of(&codes));
                let (mean, sd, skew) = two_pass(&codes);
                assert!((m.mean - mean).abs() <= 1e-12 * mean.abs(), "{bits} {n}");
                assert!((m.std_dev - sd).abs() <= 1e-10 * sd.max(1e-300), "{bits} {n}");
                assert!((m.skewness - skew).abs() <= 1e-9 * skew.abs().max(1.0), "{bits} {n}: {} {skew}", m.skewness);
            }
        }
    }

    #[test]
    fn moments_of_small_exact_cases() {
        // {0, 0, 3}: mean 1, variance (1 + 1 + 4)/3 = 2, third moment (-1 - 1 + 8)/3 = 2, g1 = 2 / 2^1.5.
        let m = moments(&stats_of(&[0, 0, 3]));
        assert_eq!(m.mean, 1.0);
        assert_eq!(m.std_dev, 2f64.sqrt());
        assert!((m.skewness - 2.0 / 2f64.powf(1.5)).abs() < 1e-15);
        // Symmetric data: skewness exactly 0.
        let m = moments(&stats_of(&[1, 5, 9]));
        assert_eq!(m.skewness, 0.0);
        for codes in [&[][..], &[7], &[7, 7, 7]] {
            let m = moments(&stats_of(codes));
            assert_eq!((m.std_dev, m.skewness), (0.0, 0.0));
            assert!(m.mean.is_finite());
        }
        let top = (1u64 << 63) - 1;
        let m = moments(&stats_of(&[top, 0, top, top]));
        assert!(m.mean.is_finite() && m.std_dev.is_finite() && m.skewness.is_finite());
        assert!(m.skewness < 0.0);
    }

    #[test]
    fn doane_follows_the_formula() {
        let m = Moments { mean: 0.0, std_dev: 1.0, skewness: 0.0 };
        // g1 = 0: k = ceil(1 + log2 n).
        assert_eq!(class_count(ClassRule::Doane, 1024, &m, false), 11);
        assert_eq!(class_count(ClassRule::Doane, 1025, &m, false), 12);
        // n = 3: sigma_g1 = sqrt(6 / 24) = 0.5; g1 = 0.5: log2(1 + 1) = 1; k = ceil(2 + log2 3) = 4.
        let m3 = Moments { skewness: -0.5, ..m };
        assert_eq!(class_count(ClassRule::Doane, 3, &m3, false), 4);
        assert_eq!(class_count(ClassRule::Doane, 2, &m3, false), 1);
        assert_eq!(class_count(ClassRule::Doane, 1, &m3, false), 1);
        assert_eq!(class_count(ClassRule::Doane, 100, &m3, true), 1);
        let flat = Moments { std_dev: 0.0, ..m };
        assert_eq!(class_count(ClassRule::Doane, 100, &flat, false), 1);
        assert_eq!(class_count(ClassRule::Sturges, 1000, &m, false), 11);
        assert_eq!(class_count(ClassRule::Sqrt, 1000, &m, false), 32);
        assert_eq!(class_count(ClassRule::Sqrt, 1024, &m, false), 32);
        assert_eq!(class_count(ClassRule::Fixed(0), 10, &m, false), 1);
        assert_eq!(class_count(ClassRule::Fixed(99_999), 10, &m, false), MAX_CLASSES);
        assert_eq!(class_count(ClassRule::Sqrt, u64::MAX, &m, false), MAX_CLASSES);
        let wild = Moments { skewness: f64::INFINITY, ..m };
        assert_eq!(class_count(ClassRule::Doane, 10, &wild, false), MAX_CLASSES);
        let nan = Moments { skewness: f64::NAN, ..m };
        assert_eq!(class_count(ClassRule::Doane, 10, &nan, false), 1);
    }

    #[test]
    fn thresholds_equal_class_of_exhaustively_small() {
        for d in 0u64..=40 {
            for k in 1u32..=45 {
                let min = 1000;
                let th = class_thresholds(min, min + d, k);
                assert_eq!(th.len(), (k - 1) as usize);
                for x in 0..=d {
                    assert_eq!(class_from_thresholds(x, &th), class_of(min + x, min, min + d, k), "d {d} k {k} x {x}");
                }
            }
        }
    }

    #[test]
    fn thresholds_equal_class_of_random_large() {
        let mut g = Rng(12345);
        for _ in 0..200 {
            let a = g.next_u64() >> 1;
            let b = g.next_u64() >> 1;
            let (min, max) = (a.min(b), a.max(b));
            let k = (g.next_u64() % MAX_CLASSES as u64) as u32 + 1;
            let th = class_thresholds(min, max, k);
            for j in 0..200 {
                let x = match j {
                    0 => min,
                    1 => max,
                    _ => min + g.next_u64() % (max - min + 1),
                };
                assert_eq!(class_from_thresholds(x - min, &th), class_of(x, min, max, k));
            }
            // Exactly at and one below each threshold.
            for &t in th.iter().take(50) {
                for x in [t.saturating_sub(1), t] {
                    if x <= max - min {
                        assert_eq!(class_from_thresholds(x, &th), class_of(min + x, min, max, k));
                    }
                }
            }
        }
    }

    #[test]
    fn class_of_edges() {
        assert_eq!(class_of(5, 5, 5, 10), 0);
        assert_eq!(class_of(9, 0, 9, 10), 9);
        assert_eq!(class_of(u64::MAX >> 1, 0, u64::MAX >> 1, MAX_CLASSES), MAX_CLASSES - 1);
        assert_eq!(class_of(0, 0, 10, 1), 0);
        // Out-of-range codes clamp rather than panic.
        assert_eq!(class_of(0, 5, 10, 4), 0);
        assert_eq!(class_of(50, 5, 10, 4), 3);
    }

    #[test]
    fn histogram_stats_match_definitions() {
        let hist = [10u64, 0, 25, 5];
        let n = 40;
        let s = histogram_stats(&hist, n, 0.005);
        // E = 10: (0 + 100 + 225 + 25) / 10 = 35.
        assert_eq!(s.chi_square, 35.0);
        assert_eq!(s.dof, 3);
        assert_eq!(s.empty_classes, 1);
        assert_eq!(s.concentrated_classes, 1);
        assert_eq!(s.concentrated_share, 25.0 / 40.0);
        assert_eq!(s.cramers_v, (35.0f64 / (40.0 * 3.0)).sqrt());
        assert_eq!(s.critical_value, stats::chi2_critical(0.005, 3));
        assert_eq!(s.p_value, stats::chi2_sf(35.0, 3));
        assert!(!s.uniform);
        // Perfectly uniform.
        let s = histogram_stats(&[7, 7, 7], 21, 0.005);
        assert_eq!((s.chi_square, s.uniform, s.concentrated_classes, s.cramers_v), (0.0, true, 0, 0.0));
        assert_eq!(s.p_value, 1.0);
        // E not an integer: n = 10, k = 3; (3*3-10)^2 + (3*3-10)^2 + (3*4-10)^2 = 6 over 30.
        let s = histogram_stats(&[3, 3, 4], 10, 0.05);
        assert_eq!(s.chi_square, 6.0 / 30.0);
        assert_eq!(s.concentrated_classes, 1);
        // Everything in one class: V = 1.
        let s = histogram_stats(&[0, 0, 9, 0], 9, 0.005);
        assert_eq!(s.cramers_v, 1.0);
        assert_eq!(s.empty_classes, 3);
        // k = 1.
        let s = histogram_stats(&[5], 5, 0.005);
        assert_eq!(
            (s.chi_square, s.dof, s.p_value, s.critical_value, s.uniform, s.cramers_v),
            (0.0, 0, 1.0, 0.0, true, 0.0)
        );
        assert_eq!((s.empty_classes, s.concentrated_classes, s.concentrated_share), (0, 0, 0.0));
        // The GPU's entry point gives the same result from the exact reductions.
        let hist = [10u64, 0, 25, 5];
        let t: i128 = hist.iter().map(|&o| (4 * o as i128 - 40).pow(2)).sum();
        let t = t as u128;
        assert_eq!(histogram_stats_exact(t, 1, 1, 25, 40, 4, 0.005), histogram_stats(&hist, 40, 0.005));
        // Huge counts do not overflow.
        let s = histogram_stats(&[u64::MAX / 2, 0], u64::MAX / 2, 0.005);
        assert!(s.chi_square.is_finite() && s.chi_square > 0.0);
        assert_eq!(s.p_value, 0.0);
    }
}
