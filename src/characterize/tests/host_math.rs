//! An independent reference for the host math every backend shares (docs/spec.md steps 3, 5c, 6, 9 and 10): the
//! three backends agree bit for bit because they feed the same integers to the same host code, which proves that
//! the integers agree, not that the figures are right. Here the figures are recomputed in exact rational
//! arithmetic (num-rational over num-bigint) from the exact inputs, by another route than `finalize` takes, and
//! compared with the f64 results at the accuracy docs/spec.md states:
//!
//! | figure | reference | tolerance |
//! |---|---|---|
//! | `scale_a` | `2^b / E_a` (`E_a = hi_a ⊖ lo_a`) | correctly rounded to f32 |
//! | `mean` | `S1 / n` | correctly rounded (ties to even) |
//! | `std_dev` | `sqrt(mu2)`, `mu2 = S2/n - mean^2` | 1 ulp (two roundings: `< 1.5 * 2^-53` relative) |
//! | `skewness` | `mu3 / mu2^1.5`, `mu3 = S3/n - 3 mean S2/n + 2 mean^3` | 4 ulp (four roundings: `< 3.5 * 2^-53`) |
//! | `k` (Doane) | least `k` with `2^(k-1) >= n (1 + |g1| / sigma_g1)`, decided exactly | equal, unless the exact argument lies within `1e-12` of a power of two |
//! | `k` (Sturges, sqrt) | least `k` with `2^(k-1) >= n`, with `k^2 >= n` | equal |
//! | `chi_square` | `T / (n k)`, `T = sum (k O_i - n)^2` | correctly rounded |
//! | `cramers_v` | `min(1, sqrt(T / (n^2 k (k - 1))))` | 1 ulp |
//! | `concentrated_share` | `C / n` | correctly rounded |
//!
//! The ulp bounds of `std_dev` and `skewness` are decided exactly (by squaring both ends of the interval), and the
//! largest error found in each figure is printed (`cargo test --lib host_math -- --nocapture`). Inputs: real
//! meshes from `../shared/meshes` at both code widths and a sampled stride (the power sums recomputed from the
//! codes), and edge cases: `n = 1, 2`, all codes equal, two values, codes near `2^63`, random 63-bit codes, huge
//! histogram counts.

use super::exact::{
    correctly_rounded, correctly_rounded32, histogram_exact, rat, rat32, ratio, sqrt, sqrt_within, ulps,
};
use crate::characterize::finalize::{class_count, histogram_stats, moments};
use crate::characterize::{cpu, ClassRule, CodeStats, HistogramStats, Moments, Params, MAX_CLASSES};
use crate::keys::{quantization_scale, MortonBits};
use crate::mesh::load_mesh;
use crate::mesh::testing as common;
use crate::rng::SplitMix64;
use num_bigint::{BigInt, BigUint};
use num_rational::BigRational;
use num_traits::{One, Signed, Zero};

/// The largest error found per figure, in ulps of the reported value.
#[derive(Default, Debug)]
struct Worst {
    mean: f64,
    std_dev: f64,
    skewness: f64,
    chi_square: f64,
    cramers_v: f64,
    concentrated_share: f64,
    cases: usize,
}

impl Worst {
    fn print(&self, what: &str) {
        eprintln!(
            "{what}: {} cases; largest error in ulps: mean {:.3}, std_dev {:.3}, skewness {:.3}, chi_square {:.3}, \
             cramers_v {:.3}, concentrated_share {:.3}",
            self.cases,
            self.mean,
            self.std_dev,
            self.skewness,
            self.chi_square,
            self.cramers_v,
            self.concentrated_share
        );
    }
}

/// The exact power sums of `codes`.
fn power_sums(codes: &[u64]) -> CodeStats {
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
        s.s2 += &c * &c;
        s.s3 += &c * &c * &c;
        s.s1 += c;
    }
    s
}

/// The exact power sums of `count` codes of `value`, for each `(value, count)`: large `n` without the codes.
fn power_sums_of_counts(values: &[(u64, u64)]) -> CodeStats {
    let mut s = CodeStats {
        n: values.iter().map(|v| v.1).sum(),
        code_min: values.iter().map(|v| v.0).min().unwrap_or(0),
        code_max: values.iter().map(|v| v.0).max().unwrap_or(0),
        s1: BigUint::zero(),
        s2: BigUint::zero(),
        s3: BigUint::zero(),
    };
    for &(v, count) in values {
        let c = BigUint::from(v);
        s.s1 += &c * count;
        s.s2 += &c * &c * count;
        s.s3 += &c * &c * &c * count;
    }
    s
}

/// The exact mean, second and third central moments from the power sums, as rationals:
/// `mean = S1/n`, `mu2 = S2/n - mean^2`, `mu3 = S3/n - 3 mean S2/n + 2 mean^3`.
fn exact_moments(s: &CodeStats) -> (BigRational, BigRational, BigRational) {
    let n = BigInt::from(s.n);
    let r = |x: &BigUint| ratio(BigInt::from(x.clone()), n.clone());
    let (e1, e2, e3) = (r(&s.s1), r(&s.s2), r(&s.s3));
    let three = BigRational::from_integer(BigInt::from(3));
    let two = BigRational::from_integer(BigInt::from(2));
    let mu2 = &e2 - &e1 * &e1;
    let mu3 = &e3 - &three * &e1 * &e2 + &two * &e1 * &e1 * &e1;
    (e1, mu2, mu3)
}

/// Checks step 5c against the exact moments and returns `g1^2` (0 when `mu2 == 0`).
fn check_moments(s: &CodeStats, m: &Moments, what: &str, worst: &mut Worst) -> BigRational {
    worst.cases += 1;
    let (mean, mu2, mu3) = exact_moments(s);
    assert!(correctly_rounded(m.mean, &mean), "{what}: mean {} is not S1/n = {mean} rounded", m.mean);
    worst.mean = worst.mean.max(ulps(m.mean, &mean));
    assert!(!mu2.is_negative(), "{what}");
    if mu2.is_zero() {
        assert_eq!((m.std_dev, m.skewness), (0.0, 0.0), "{what}: all codes equal");
        assert!(mu3.is_zero(), "{what}");
        return BigRational::zero();
    }
    assert!(sqrt_within(m.std_dev, false, &mu2, 1.0), "{what}: std_dev {} not within 1 ulp", m.std_dev);
    worst.std_dev = worst.std_dev.max(ulps(m.std_dev, &sqrt(&mu2)));
    let g1sq = &mu3 * &mu3 / (&mu2 * &mu2 * &mu2);
    if mu3.is_zero() {
        assert_eq!(m.skewness, 0.0, "{what}: symmetric");
    } else {
        assert!(
            sqrt_within(m.skewness, mu3.is_negative(), &g1sq, 4.0),
            "{what}: skewness {} not within 4 ulp",
            m.skewness
        );
        let g1 = if mu3.is_negative() { -sqrt(&g1sq) } else { sqrt(&g1sq) };
        worst.skewness = worst.skewness.max(ulps(m.skewness, &g1));
    }
    g1sq
}

/// The least `k >= 1` with `2^(k-1) >= f n (1 + sqrt(r))`, clamped to `MAX_CLASSES`: for `t = 2^(k-1) / (f n) - 1`,
/// `t >= 0` and `t^2 >= r`, all in exact rationals.
fn least_k(n: u64, r: &BigRational, f: &BigRational) -> u32 {
    let fn_ = f * BigRational::from_integer(BigInt::from(n));
    for k in 1..=MAX_CLASSES {
        let t = BigRational::from_integer(BigInt::one() << (k - 1)) / &fn_ - BigRational::one();
        if !t.is_negative() && &t * &t >= *r {
            return k;
        }
    }
    MAX_CLASSES
}

/// Doane's `k` in exact arithmetic from `g1^2` (docs/spec.md step 6); `Err` with the two neighbours when the exact
/// argument lies within `1e-12` (relative) of a power of two, where an f64 evaluation may round either way.
fn doane_exact(n: u64, g1sq: &BigRational) -> Result<u32, (u32, u32)> {
    if n <= 2 || g1sq.is_negative() {
        return Ok(1);
    }
    let nb = BigInt::from(n);
    // |g1| / sigma_g1 squared: g1^2 (n + 1)(n + 3) / (6 (n - 2)).
    let r = g1sq * ratio((&nb + 1) * (&nb + 3), BigInt::from(6) * (&nb - 2));
    let k = least_k(n, &r, &BigRational::one());
    let below = least_k(n, &r, &ratio(999_999_999_999i64, 1_000_000_000_000i64));
    let above = least_k(n, &r, &ratio(1_000_000_000_001i64, 1_000_000_000_000i64));
    if below == above {
        Ok(k)
    } else {
        Err((below, above))
    }
}

/// Checks step 6 (Doane) against [`doane_exact`]; returns whether the case was a near tie.
fn check_doane(n: u64, all_equal: bool, m: &Moments, g1sq: &BigRational, k: u32, what: &str) -> bool {
    assert_eq!(k, class_count(ClassRule::Doane, n, m, all_equal), "{what}: reported k");
    if all_equal || m.std_dev == 0.0 {
        assert_eq!(k, 1, "{what}");
        return false;
    }
    match doane_exact(n, g1sq) {
        Ok(want) => {
            assert_eq!(k, want, "{what}: Doane k");
            false
        }
        Err((a, b)) => {
            assert!(k == a || k == b, "{what}: Doane k {k} near a tie of {a} and {b}");
            true
        }
    }
}

/// Checks steps 9 and 10 against the histogram's exact `T`, `C` and empty classes.
fn check_histogram_stats(hist: &[u64], n: u64, st: &HistogramStats, what: &str, worst: &mut Worst) {
    let k = hist.len() as u64;
    assert_eq!(hist.iter().map(|&o| o as u128).sum::<u128>(), n as u128, "{what}: histogram total");
    let x = histogram_exact(hist, n);
    assert_eq!(st.empty_classes as usize, x.empty_classes, "{what}: empty classes");
    if k <= 1 {
        assert_eq!((st.chi_square, st.dof, st.cramers_v, st.concentrated_share), (0.0, 0, 0.0, 0.0), "{what}");
        assert!(st.uniform && st.p_value == 1.0 && st.concentrated_classes == 0, "{what}");
        return;
    }
    assert_eq!(st.dof as u64, k - 1, "{what}");
    let chi = &x.chi_square;
    assert!(
        correctly_rounded(st.chi_square, chi),
        "{what}: chi_square {} is not T/(nk) = {chi} rounded",
        st.chi_square
    );
    if !chi.is_zero() {
        worst.chi_square = worst.chi_square.max(ulps(st.chi_square, chi));
    }
    if x.v_squared >= BigRational::one() {
        assert_eq!(st.cramers_v, 1.0, "{what}: V");
    } else {
        assert!(sqrt_within(st.cramers_v, false, &x.v_squared, 1.0), "{what}: V {} not within 1 ulp", st.cramers_v);
        if !x.v_squared.is_zero() {
            worst.cramers_v = worst.cramers_v.max(ulps(st.cramers_v, &sqrt(&x.v_squared)));
        }
    }
    assert_eq!(st.concentrated_classes as usize, x.concentrated_classes, "{what}: concentrated classes");
    let share = &x.concentrated_share;
    assert!(correctly_rounded(st.concentrated_share, share), "{what}: share {} vs {share}", st.concentrated_share);
    if !share.is_zero() {
        worst.concentrated_share = worst.concentrated_share.max(ulps(st.concentrated_share, share));
    }
}

/// Checks step 3's scale: `rn32(2^b / (hi ⊖ lo))`, 0 for a zero extent, `None` when the extent or the scale is not
/// a finite f32.
fn check_scale(lo: [f32; 3], hi: [f32; 3], bits: MortonBits, what: &str) {
    let got = quantization_scale(lo, hi, bits);
    let cells = BigRational::from_integer(BigInt::one() << bits.per_axis());
    // A quotient at or above 2^128 - 2^103, halfway from f32::MAX to 2^128, rounds to infinity.
    let overflow = BigRational::from_integer((BigInt::one() << 128) - (BigInt::one() << 103));
    let mut want_none = false;
    for a in 0..3 {
        let e = hi[a] - lo[a];
        if !e.is_finite() || (e != 0.0 && cells.clone() / rat32(e) >= overflow) {
            want_none = true;
        }
    }
    if want_none {
        assert_eq!(got, None, "{what}: {lo:?} {hi:?}");
        return;
    }
    let s = got.unwrap_or_else(|| panic!("{what}: no scale for {lo:?} {hi:?}"));
    for a in 0..3 {
        let e = hi[a] - lo[a];
        if e == 0.0 {
            assert_eq!(s[a], 0.0, "{what}: axis {a}");
        } else {
            let q = cells.clone() / rat32(e);
            assert!(correctly_rounded32(s[a], &q), "{what}: axis {a}: scale {} is not 2^b / {e} = {q} rounded", s[a]);
        }
    }
}

const MESHES: [&str; 6] = [
    "small/bunny-lowres-pd.obj",
    "small/cow.obj",
    "small/fandisk.obj",
    "small/suzanne.obj",
    "stanford-bunny/bun_zipper_res2.ply",
    "scans/horse.obj",
];

#[test]
fn real_meshes_match_the_exact_reference() {
    let mut worst = Worst::default();
    let mut near_ties = 0;
    for rel in MESHES {
        let mesh = load_mesh(&common::shared_mesh(rel)).unwrap();
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            for stride in [1u32, 3] {
                let params =
                    Params { morton_bits: bits, sample_stride: stride, keep_per_triangle: true, ..Params::default() };
                let what = format!("{rel} {bits:?} 1:{stride}");
                let c = cpu::fast(&mesh, &params).unwrap();
                let codes = &c.per_triangle.as_ref().expect("kept").codes;
                // The power sums from the codes, independently of the backend's accumulation.
                let s = power_sums(codes);
                assert_eq!(s, c.code_stats, "{what}: power sums");
                check_scale(c.lo, c.hi, bits, &what);
                let g1sq = check_moments(&s, &c.moments, &what, &mut worst);
                assert_eq!(c.moments, moments(&s), "{what}");
                near_ties +=
                    usize::from(check_doane(s.n, s.code_min == s.code_max, &c.moments, &g1sq, c.classes, &what));
                // The histogram from the codes by the exact class formula of step 7.
                let k = c.classes as u128;
                let d = (s.code_max - s.code_min) as u128;
                let mut hist = vec![0u64; c.classes as usize];
                for &m in codes {
                    let i = ((m - s.code_min) as u128 * k).checked_div(d).map_or(0, |c| c.min(k - 1));
                    hist[i as usize] += 1;
                }
                assert_eq!(hist, c.histogram, "{what}: histogram");
                check_histogram_stats(&hist, s.n, &c.stats, &what, &mut worst);
            }
        }
    }
    worst.print("real meshes");
    eprintln!("real meshes: {near_ties} Doane near ties");
    assert_eq!(worst.cases, MESHES.len() * 4);
}

/// Step 5c, 6 and the histogram figures of a list of codes (all in one class count from Doane).
fn check_codes(codes: &[u64], what: &str, worst: &mut Worst) {
    let s = power_sums(codes);
    let m = moments(&s);
    let g1sq = check_moments(&s, &m, what, worst);
    let all_equal = s.code_min == s.code_max;
    let k = class_count(ClassRule::Doane, s.n, &m, all_equal);
    check_doane(s.n, all_equal, &m, &g1sq, k, what);
}

/// `2^53 + 1`: the midpoint between the f64 neighbours `2^53` and `2^53 + 2`.
const TIE: u64 = (1 << 53) + 1;

#[test]
fn edge_cases_match_the_exact_reference() {
    let mut worst = Worst::default();
    let top = (1u64 << 63) - 1;
    let cases: Vec<(&str, Vec<u64>)> = vec![
        ("n = 1", vec![12345]),
        ("n = 1 at 2^63 - 1", vec![top]),
        ("n = 2", vec![3, 10]),
        ("n = 2 extremes", vec![0, top]),
        ("all equal", vec![777; 9]),
        ("all equal near 2^63", vec![top - 5; 1000]),
        ("two values, 1 and 3", vec![0, 5, 5, 5]),
        ("two values near 2^63", vec![top, top - 1, top, top, top - 1, top]),
        ("two values at the ends", vec![0, top, top, top, top, top, top, top]),
        ("three values", vec![0, 0, 3]),
        ("symmetric", vec![1, 5, 9]),
        ("codes near 2^63", (0..500).map(|i| top - (i * i) % 1009).collect()),
        ("one outlier", (0..1000).map(|i| if i == 0 { top } else { i }).collect()),
    ];
    for (what, codes) in &cases {
        check_codes(codes, what, &mut worst);
    }
    let mut g = SplitMix64(2024);
    for n in [3usize, 4, 7, 100, 4097] {
        for bits in [8u32, 30, 63] {
            let codes: Vec<u64> = (0..n).map(|_| g.next_u64() >> (64 - bits)).collect();
            check_codes(&codes, &format!("random n = {n}, {bits} bits"), &mut worst);
            // Skewed: squares of uniform codes pile up near 0.
            let skewed: Vec<u64> = codes.iter().map(|&c| ((c as u128 * c as u128) >> bits) as u64).collect();
            check_codes(&skewed, &format!("skewed n = {n}, {bits} bits"), &mut worst);
        }
    }
    // Power sums of 2^32 - 1 codes of 2^63 - 1 (S3 near 2^221, the spec's bound), without the codes.
    let n = u32::MAX as u64;
    let many = [
        ("2^32 - 1 codes of 2^63 - 1", vec![(top, n)]),
        ("two halves at the ends", vec![(0, n / 2), (top, n / 2)]),
        ("one at the top among 2^32 - 2 zeros", vec![(0, n - 1), (top, 1)]),
        ("one at 0 among 2^32 - 2 at the top", vec![(0, 1), (top, n - 1)]),
        // S1 / n = 2^53 + 1 + 2^-20, just above the tie between 2^53 and 2^53 + 2: rounds up, which needs the
        // bits far below the 64 the quotient keeps (the sticky bit).
        ("mean just above a tie", vec![(TIE, (1 << 20) - 1), (TIE + 1, 1)]),
        ("mean just below a tie", vec![(TIE, (1 << 20) - 1), (TIE - 1, 1)]),
        ("mean exactly a tie", vec![(TIE - 1, 1), (TIE + 1, 1)]),
    ];
    for (what, values) in many {
        let s = power_sums_of_counts(&values);
        let m = moments(&s);
        let g1sq = check_moments(&s, &m, what, &mut worst);
        let all_equal = s.code_min == s.code_max;
        check_doane(s.n, all_equal, &m, &g1sq, class_count(ClassRule::Doane, s.n, &m, all_equal), what);
    }
    let tie = |values: &[(u64, u64)]| moments(&power_sums_of_counts(values)).mean;
    assert_eq!(tie(&[(TIE, (1 << 20) - 1), (TIE + 1, 1)]), (TIE + 1) as f64);
    assert_eq!(tie(&[(TIE, (1 << 20) - 1), (TIE - 1, 1)]), (TIE - 1) as f64);
    assert_eq!(tie(&[(TIE - 1, 1), (TIE + 1, 1)]), (TIE - 1) as f64, "ties to even");
    assert_eq!(moments(&power_sums_of_counts(&[(0, n / 2), (top, n / 2)])).skewness, 0.0);
    worst.print("edge cases");
}

#[test]
fn histogram_figures_match_the_exact_reference() {
    let mut worst = Worst::default();
    let mut check = |hist: &[u64], what: &str| {
        let n: u64 = hist.iter().sum();
        check_histogram_stats(hist, n, &histogram_stats(hist, n, 0.005), what, &mut worst);
    };
    check(&[5], "k = 1");
    check(&[7, 7, 7], "uniform");
    check(&[3, 3, 4], "E not an integer");
    check(&[0, 0, 9, 0], "one class");
    check(&[1, 0], "n = 1, k = 2");
    check(&[10, 0, 25, 5], "by hand");
    let mut g = SplitMix64(77);
    for k in [2usize, 3, 17, 255, 4096] {
        for scale in [10u64, 1000, 1 << 40] {
            let hist: Vec<u64> = (0..k).map(|_| g.next_u64() % scale).collect();
            check(&hist, &format!("random k = {k}, counts below {scale}"));
        }
    }
    // Counts near 2^64 / k: k O - n needs more than 64 bits and T more than 128 (the big-integer path).
    let per = u64::MAX / 4096;
    let mut hist = vec![per; 4096];
    hist[0] = per / 3;
    hist[4095] = per - 12345;
    check(&hist, "k = 4096, counts near 2^64 / k");
    let two = [u64::MAX / 2, 0];
    check(&two, "half of 2^64 in one of two classes");
    worst.print("histograms");
}

#[test]
fn other_class_rules_match_the_exact_reference() {
    // Sturges: the least k with 2^(k-1) >= n; sqrt: the least k with k^2 >= n; both clamped to MAX_CLASSES.
    let m = Moments { mean: 0.0, std_dev: 1.0, skewness: 0.0 };
    let mut ns: Vec<u64> = (1..=5000).collect();
    for j in 13..32 {
        for d in [-1i64, 0, 1] {
            ns.push(((1i64 << j) + d) as u64);
        }
    }
    for r in [4096u64, 65_536, 1 << 24, 4_000_000_000] {
        ns.extend([r * r - 1, r * r, r * r + 1].into_iter().filter(|&x| x < 1 << 32));
    }
    ns.push(u32::MAX as u64);
    for &n in &ns {
        let sturges = (1..=MAX_CLASSES).find(|&k| (1u128 << (k - 1)) >= n as u128).unwrap_or(MAX_CLASSES);
        let sqrt = (1..=MAX_CLASSES).find(|&k| (k as u128) * (k as u128) >= n as u128).unwrap_or(MAX_CLASSES);
        assert_eq!(class_count(ClassRule::Sturges, n, &m, false), sturges, "Sturges n = {n}");
        assert_eq!(class_count(ClassRule::Sqrt, n, &m, false), sqrt, "sqrt n = {n}");
    }
}

#[test]
fn quantization_scales_match_the_exact_reference() {
    let mut g = SplitMix64(5);
    for bits in [MortonBits::Bits30, MortonBits::Bits63] {
        for _ in 0..2000 {
            let lo = [0; 3].map(|_| (g.next_f32() - 0.5) * 2e3);
            let hi = lo.map(|l| l + g.next_f32() * 10f32.powi((g.next_u64() % 12) as i32 - 6));
            check_scale(lo, hi, bits, "random");
        }
        check_scale([0.0; 3], [0.0, 1.0, 3.0], bits, "one flat axis");
        check_scale([-1.0; 3], [1.0; 3], bits, "unit");
        check_scale([0.0; 3], [f32::MAX, 1.0, 1.0], bits, "the largest extent");
        check_scale([-f32::MAX, 0.0, 0.0], [f32::MAX, 1.0, 1.0], bits, "an infinite extent");
        check_scale([0.0; 3], [1e-30, 1e-35, 1.0], bits, "tiny extents");
        check_scale([0.0; 3], [f32::MIN_POSITIVE, 1.0, 1.0], bits, "the smallest normal extent");
        check_scale([1.0; 3], [1.0 + f32::EPSILON, 2.0, 3.0], bits, "one ulp");
    }
    // Sanity of the reference itself: 2^10 / 3 rounds to 341.33334 (f32), ties go to even.
    assert!(correctly_rounded32(1024.0 / 3.0, &ratio(1024, 3)));
    assert!(!correctly_rounded32(f32::from_bits((1024.0f32 / 3.0).to_bits() + 1), &ratio(1024, 3)));
    assert!(correctly_rounded(0.1, &ratio(1, 10)));
    assert!(!correctly_rounded(f64::from_bits(0.1f64.to_bits() + 1), &ratio(1, 10)));
    // 1 + 2^-53 is a tie between 1 and 1 + 2^-52: even is 1.
    let tie = BigRational::one() + ratio(1, BigInt::one() << 53);
    assert!(correctly_rounded(1.0, &tie) && !correctly_rounded(1.0 + f64::EPSILON, &tie));
    assert_eq!(rat(0.5), ratio(1, 2));
}
