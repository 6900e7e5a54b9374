//! The chi-square distribution: upper-tail probability and critical values (docs/spec.md step 9), on the `statrs` crate.
//!
//! `P(X >= x)` for `X ~ chi-square(dof)` is the regularized upper incomplete gamma function `Q(dof / 2, x / 2)`,
//! which [`chi2_sf`] takes from [`statrs::function::gamma::checked_gamma_ur`] (Cephes' `igamc`: the power series
//! for `P = 1 - Q` below the mean, a continued fraction above it). [`chi2_critical`] finds the `x` with
//! `chi2_sf(x, dof) = alpha` by Newton steps on `ln Q` from the Wilson and Hilferty (1931) cube-root normal start
//! (the normal quantile from [`statrs::function::erf::erfc_inv`]), inside a bracket that bisection keeps valid.
//!
//! Accuracy, measured against 40-digit mpmath values for `dof` in `1..=4095` (`MAX_CLASSES - 1`) with `x` from the
//! lower tail through the critical region to p-values of 1e-300:
//!
//! * p-value: within 2e-13 relative for `dof <= 100`; the error grows with `dof` because statrs forms the factor
//!   `y^a e^-y / Gamma(a)` (`a = dof / 2`, `y = x / 2`) as `exp(a ln y - y - ln Gamma(a))`, whose terms, of size
//!   `a ln y`, cancel: up to 6e-13 at `dof` 1000 and 3.5e-12 at `dof` 2000 to 4095.
//! * critical value: within 6.1e-14 relative for `alpha` in `[1e-100, 0.99]`, 2e-14 at the usual 0.05, 0.01 and
//!   0.005 (the quantile is well conditioned: a relative error `e` of the tail moves `x` by `e Q / (x pdf(x))`).
//!   At `alpha = 0.999` and `dof == 1` (`x = 1.6e-6`), 1.1e-13: `Q = 0.999` carries that error in `P` itself.
//!
//! The home-made implementation this replaced (Loader's form of the factor, Lanczos `ln Gamma`) was within 2e-13
//! for p-values and 1e-14 for critical values (1.1e-15 at the usual `alpha`), so results differ in their last
//! bits: on the shared meshes by up to 44 ulps for critical values and 648 ulps for the nonzero p-values, with no
//! `uniform` decision changed.
//!
//! Where statrs falls short, and what this module does there:
//!
//! * Tiny `x`: statrs rounds `P(a, y)` to 0 for `y <= 1.11e-15` (an absolute tolerance), so it returns `Q = 1`
//!   where `dof == 1` has `Q = 1 - 2 sqrt(y / pi)` (3.8e-8 off at `y = 1.1e-15`). For `y < 1e-14`, [`chi2_sf`]
//!   uses the series' leading term, `Q = 1 - y^a / Gamma(a + 1)` (relative error of `P` below `a y / (a + 1)`,
//!   under 1e-14), with `ln Gamma` from statrs. Only `dof` 1 and 2 see a difference in f64.
//! * Underflow: statrs returns 0 once `a ln y - y - ln Gamma(a) < -709.78`, where that factor leaves f64's normal
//!   range: p-values below about 1e-308 (the last nonzero ones lie between 5e-311 and 2.2e-308, depending on
//!   `dof`) are 0. The former home-made code returned subnormal values down to 4.9e-324 there, with fewer
//!   significant bits. The report keeps statrs's 0, which reads "below f64's normal range": no decision depends
//!   on it (`uniform` compares the chi-square with the critical value), and tails that small already were 0
//!   below 4.9e-324.
//! * Quantile: statrs's `inverse_cdf` works on the lower tail at `p = 1 - alpha`, whose rounding costs the
//!   digits of small `alpha` (2e-8 relative at `alpha = 1e-10`, 1e-3 at `1e-15`, infinite below `1.1e-16`), stops
//!   its Newton steps at 1e-10 relative, and in statrs 0.18 gives NaN for `dof == 1` at `alpha >= 0.99` and 3e-3
//!   errors at `dof` 255 and 256, where its density overflows. Hence the short root finder of [`chi2_critical`],
//!   which evaluates every tail and density with statrs. It keeps the accuracy above down to `alpha = 1e-310`; for
//!   smaller `alpha` the root is where statrs's tail reaches 0, up to 4% below the true critical value (1.2% at
//!   `alpha = 1e-315`), and a chi-square between the two has a reported p-value of 0 and is rejected,
//!   consistently with that p-value.
//!
//! No function here panics, or returns NaN for a finite, non-negative `x` and `dof >= 1`.

use statrs::function::erf::erfc_inv;
use statrs::function::gamma::{checked_gamma_ur, ln_gamma};
use std::f64::consts::{LN_2, SQRT_2};

/// Below this `y = x / 2`, [`chi2_sf`] takes `P(a, y)` from its leading term (statrs rounds it to 0 below 1.11e-15).
const SMALL_Y: f64 = 1e-14;

/// Upper tail `P(X >= x)` of the chi-square distribution with `dof` degrees of freedom (1 for `dof == 0` or
/// `x <= 0`; 0 where it falls below f64's normal range, about 1e-308, or `x` is infinite).
pub(crate) fn chi2_sf(x: f64, dof: u32) -> f64 {
    if dof == 0 || x.is_nan() || x <= 0.0 {
        return 1.0;
    }
    if x == f64::INFINITY {
        return 0.0;
    }
    let a = 0.5 * f64::from(dof);
    let y = 0.5 * x;
    if y < SMALL_Y {
        // P(a, y) = y^a / Gamma(a + 1) * (1 - a y / (a + 1) + ...); y == 0 (x subnormal) gives P = 0.
        return 1.0 - (a * y.ln() - ln_gamma(a + 1.0)).exp();
    }
    // statrs errs only for y <= 0 or y infinite, both excluded above.
    checked_gamma_ur(a, y).unwrap_or(0.0)
}

/// `ln` of the chi-square density at `x > 0`: `(a - 1) ln x - x / 2 - a ln 2 - ln Gamma(a)`, `a = dof / 2`.
fn chi2_ln_pdf(x: f64, dof: u32) -> f64 {
    let a = 0.5 * f64::from(dof);
    (a - 1.0) * x.ln() - 0.5 * x - a * LN_2 - ln_gamma(a)
}

/// Critical value of the chi-square test: the `x` with `P(X >= x) = alpha` for `X ~ chi-square(dof)`.
///
/// Returns 0 for `dof == 0` or `alpha >= 1`, and `f64::INFINITY` for `alpha <= 0` (no finite value rejects nothing);
/// NaN `alpha` is treated as 0.
pub(crate) fn chi2_critical(alpha: f64, dof: u32) -> f64 {
    if dof == 0 || alpha >= 1.0 {
        return 0.0;
    }
    if alpha.is_nan() || alpha <= 0.0 {
        return f64::INFINITY;
    }
    let k = f64::from(dof);
    // Wilson-Hilferty: X ~ k (1 - 2/(9k) + z sqrt(2/(9k)))^3 with P(Z >= z) = alpha, z = sqrt(2) erfc^-1(2 alpha).
    let z = SQRT_2 * erfc_inv(2.0 * alpha);
    let c = 2.0 / (9.0 * k);
    let mut x = k * (1.0 - c + z * c.sqrt()).powi(3);
    if !(x.is_finite() && x > 0.0) {
        x = k;
    }
    // Bracket [lo, hi] with sf(lo) > alpha >= sf(hi).
    let mut lo = 0.0f64;
    let mut hi = x;
    while chi2_sf(hi, dof) > alpha {
        lo = hi;
        hi = hi * 2.0 + 1.0;
        if !hi.is_finite() {
            return f64::MAX;
        }
    }
    let ln_alpha = alpha.ln();
    let mut x = hi.min(x.max(lo));
    for _ in 0..200 {
        let q = chi2_sf(x, dof);
        if q > alpha {
            lo = lo.max(x);
        } else {
            hi = hi.min(x);
        }
        // Newton on g(x) = ln Q(x) - ln alpha, g'(x) = -pdf / Q.
        let mut next = if q > 0.0 {
            let ln_q = q.ln();
            x + (ln_q - ln_alpha) * (ln_q - chi2_ln_pdf(x, dof)).exp()
        } else {
            f64::NAN
        };
        if !(next > lo && next < hi) {
            next = 0.5 * (lo + hi);
        }
        if (next - x).abs() <= 4.0 * f64::EPSILON * x || hi - lo <= 4.0 * f64::EPSILON * hi {
            return next;
        }
        x = next;
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rel(a: f64, b: f64) -> f64 {
        ((a - b) / b).abs()
    }

    /// `P(X >= x)` for even `dof = 2m` in closed form: `e^(-x/2) sum_{i<m} (x/2)^i / i!` (a Poisson tail), summed
    /// with a running scale so that nothing overflows. Independent of statrs.
    fn sf_even(x: f64, dof: u32) -> f64 {
        let m = dof / 2;
        let lam = 0.5 * x;
        // Sum terms t_i = lam^i / i!, tracking ln of a common scale.
        let mut ln_scale = 0.0f64;
        let mut term = 1.0f64;
        let mut sum = 1.0f64;
        for i in 1..m {
            term *= lam / i as f64;
            sum += term;
            if sum > 1e200 {
                ln_scale += sum.ln();
                term /= sum;
                sum = 1.0;
            }
        }
        (ln_scale + sum.ln() - lam).exp()
    }

    #[test]
    fn critical_values_match_tables() {
        // Values computed with 40-digit arithmetic (mpmath: regularized incomplete gamma and bisection), rounded
        // to 16 digits; the first three agree with printed chi-square tables to the digits those give
        // (7.879, 25.188, 43.773).
        let cases = [
            (0.005, 1, 7.879_438_576_622_417),
            (0.005, 10, 25.188_179_571_971_17),
            (0.05, 30, 43.772_971_825_742_19),
            (0.05, 1, 3.841_458_820_694_126),
            (0.005, 2, 10.596_634_733_096_07),
            (0.005, 100, 140.169_489_442_313_6),
            (0.005, 4095, 4_331.864_243_631_73),
            (0.05, 4095, 4_244.985_307_925_45),
            (1e-10, 7, 60.895_195_364_670_25),
            (0.5, 3, 2.365_973_884_375_338),
            (0.995, 50, 27.990_748_866_373_33),
            // Also mpmath, 40 digits: where statrs's own inverse_cdf fails (3e-3 off at dof 255 and 256, infinite
            // for alpha below 1.1e-16, NaN for dof 1 at alpha >= 0.99), and the characterization's usual range.
            (0.005, 20, 39.996_846_312_938_64),
            (0.005, 30, 53.671_961_930_240_59),
            (0.005, 255, 316.919_385_263_474_7),
            (0.05, 256, 294.320_668_884_306_4),
            (0.01, 3000, 3_183.133_916_725_153),
            (1e-20, 4095, 4_990.625_421_225_187),
            (1e-100, 7, 485.596_843_285_696_8),
            (1e-100, 1000, 2_273.136_053_854_158),
            (0.99, 1, 1.570_878_579_097_022_4e-4),
        ];
        for (alpha, dof, want) in cases {
            let got = chi2_critical(alpha, dof);
            // Measured: within 6.1e-14 over dof 1..=4095 and alpha in [1e-100, 0.99].
            assert!(rel(got, want) < 1e-13, "alpha {alpha} dof {dof}: {got} vs {want}");
        }
        // alpha = 0.999, dof 1: x = 1.57e-6 where Q = 1 - 0.001 carries 1.1e-13 relative error in P itself.
        assert!(rel(chi2_critical(0.999, 1), 1.570_797_149_262_492_7e-6) < 1e-12);
    }

    #[test]
    fn p_values_match_reference() {
        // 40-digit mpmath values of gammainc(dof/2, x/2, inf, regularized=True).
        let cases = [
            (3.84146, 1, 0.049_999_964_833_747_42),
            (1e-3, 1, 0.974_772_879_369_960_4),
            (10.0, 3, 0.018_566_135_463_043_23),
            (100.0, 50, 3.454_931_382_984_864e-5),
            (4000.0, 4095, 0.853_276_085_402_379_7),
            (5000.0, 4095, 4.252_884_110_956_223e-21),
            (1000.0, 10, 1.870_290_720_915_95e-208),
            // Also mpmath, 40 digits: the critical region at large dof (where statrs is least precise, 3.5e-12),
            // far tails, and tiny x (below y = x/2 = 1.1e-15 statrs rounds P to 0; see the module docs).
            (3_203.277_864_864_396, 3000, 0.005_000_000_000_000_471),
            (1400.0, 1000, 7.032_145_641_828_589e-16),
            (8000.0, 4095, 3.107_121_925_728_467_5e-255),
            (1e-12, 1, 0.999_999_202_115_439_2),
            (1e-15, 1, 0.999_999_974_768_674_8),
            (1e-20, 1, 0.999_999_999_920_211_5),
            (2e-15, 2, 0.999_999_999_999_999),
        ];
        for (x, dof, want) in cases {
            let got = chi2_sf(x, dof);
            // Measured: within 3.5e-12 over dof 1..=4095 where the p-value is at least 1e-300.
            assert!(rel(got, want) < 1e-11, "x {x} dof {dof}: {got} vs {want}");
        }
    }

    #[test]
    fn p_values_below_normal_range_are_zero() {
        // mpmath: Q = 4.27e-315 (dof 1, x 1440), 2.52e-316 (dof 10, x 1500), 2.82e-321 (dof 4095, x 8600). statrs
        // flushes once its factor y^a e^-y / Gamma(a) leaves f64's normal range; no NaN, no negative zero.
        for (x, dof) in [(1440.0, 1), (1500.0, 10), (8600.0, 4095)] {
            assert_eq!(chi2_sf(x, dof).to_bits(), 0, "x {x} dof {dof}");
        }
        // The smallest nonzero p-values stay within a few decades of f64::MIN_POSITIVE.
        for dof in [1u32, 2, 10, 100, 1000, 4095] {
            let x = chi2_critical(1e-300, dof);
            let mut q = chi2_sf(x, dof);
            assert!(rel(q, 1e-300) < 1e-10, "dof {dof}: {q}");
            let mut y = x;
            while q > 0.0 {
                y += 0.25;
                let next = chi2_sf(y, dof);
                assert!(next <= q, "dof {dof}: tail rises at {y}");
                q = next;
                assert!(q == 0.0 || q > 1e-312, "dof {dof}: {q} at {y}");
            }
        }
    }

    #[test]
    fn tiny_alpha_critical_values_stay_finite() {
        for dof in [1u32, 2, 50, 4095] {
            for alpha in [1e-300, f64::MIN_POSITIVE, 1e-320, f64::from_bits(1)] {
                let x = chi2_critical(alpha, dof);
                assert!(x.is_finite() && x > 0.0, "dof {dof} alpha {alpha}: {x}");
                assert!(chi2_sf(x, dof) <= alpha.max(f64::MIN_POSITIVE) * 1.000_001, "dof {dof} alpha {alpha}");
            }
        }
    }

    #[test]
    fn even_dof_matches_poisson_sum() {
        for dof in [2u32, 4, 6, 10, 50, 100, 1000, 4094] {
            let k = dof as f64;
            for f in [0.05, 0.5, 0.9, 1.0, 1.1, 1.3, 2.0, 4.0] {
                let x = k * f;
                let got = chi2_sf(x, dof);
                let want = sf_even(x, dof);
                if want > 1e-300 {
                    assert!(rel(got, want) < 1e-10, "x {x} dof {dof}: {got} vs {want}");
                }
            }
            // dof 2 has Q = exp(-x/2), so the critical value is -2 ln alpha.
            if dof == 2 {
                for alpha in [0.5, 0.05, 0.005, 1e-9] {
                    assert!(rel(chi2_critical(alpha, 2), -2.0 * f64::ln(alpha)) < 1e-13);
                }
            }
        }
    }

    #[test]
    fn quantile_inverts_tail_over_range() {
        for dof in [1u32, 2, 3, 5, 17, 63, 255, 1000, 4095, 8190] {
            for alpha in [0.999, 0.5, 0.05, 0.005, 1e-6, 1e-30] {
                let x = chi2_critical(alpha, dof);
                assert!(x.is_finite() && x > 0.0);
                let back = chi2_sf(x, dof);
                assert!(rel(back, alpha) < 1e-10, "dof {dof} alpha {alpha}: x {x} sf {back}");
            }
        }
    }

    #[test]
    fn extremes_are_clean() {
        assert_eq!(chi2_sf(1e300, 5), 0.0);
        assert_eq!(chi2_sf(f64::INFINITY, 5), 0.0);
        assert_eq!(chi2_sf(0.0, 5), 1.0);
        assert_eq!(chi2_sf(3.0, 0), 1.0);
        assert_eq!(chi2_sf(1e7, 4095), 0.0);
        assert_eq!(chi2_critical(0.005, 0), 0.0);
        assert!(chi2_sf(1e-300, 1) <= 1.0);
        assert_eq!(chi2_sf(f64::from_bits(1), 1), 1.0);
        assert_eq!(chi2_sf(f64::MAX, 4095), 0.0);
        for dof in (1..100).chain((100..=4096).step_by(37)) {
            for x in [1e-300, 1e-200, 1e-15, 1e-10, 0.3, 3.0, 30.0, 300.0, 3e3, 3e4, 3e5, 1e300] {
                let q = chi2_sf(x, dof);
                assert!((0.0..=1.0).contains(&q), "x {x} dof {dof}: {q}");
            }
        }
    }
}
