//! Features, the cost model's fit and its files.

use super::common;
use super::cost_policy::plain_build;

use meshchar::accel::StructureName;
use meshchar::characterize::features::{exponent, SIZE_BINS};
use meshchar::characterize::{features_cpu, Features, Params};
use meshchar::cost::ViewFeatures;
use meshchar::cost::{
    phi, price_outside_ln_n, price_row, CostModel, Workload, COST_MODEL_VERSION, FEATURE_NAMES, PRICE_NAMES,
};
use meshchar::eval::fit::{Measured, Sample};
use meshchar::geom::WorkloadKind;
use meshchar::mesh::{generate, Mesh};

/// An 8 x 8 x 8 lattice (spacing 1) of small right triangles with legs 0.125 along x and y.
fn lattice() -> Mesh {
    let h = 0.125f32;
    let mut tris = Vec::new();
    for i in 0..8 {
        for j in 0..8 {
            for k in 0..8 {
                let p = glam::Vec3::new(i as f32, j as f32, k as f32);
                tris.push([p, p + glam::Vec3::new(h, 0.0, 0.0), p + glam::Vec3::new(0.0, h, 0.0)]);
            }
        }
    }
    Mesh::from_triangles("lattice", &tris).unwrap()
}

#[test]
fn features_of_one_triangle() {
    let f = features_cpu(&generate::single_triangle(), &Params::default()).unwrap();
    assert_eq!(f.triangles, 1);
    assert_eq!(f.occupied_cells, vec![1; 7]);
    // The triangle's largest extent is the scene's: exponent difference 0.
    assert_eq!(f.size_histogram[0], 1);
    assert_eq!(f.size_histogram.iter().sum::<u64>(), 1);
    assert_eq!(f.zero_extent, 0);
}

#[test]
fn features_of_a_lattice_are_exact() {
    let f = features_cpu(&lattice(), &Params::default()).unwrap();
    assert_eq!(f.triangles, 512);
    // Keys span 3 * 7 = 21 per axis; lattice index i lands in depth-d cell floor(i * 2^d / 7) (7 -> the last): 2, 4, 8
    // distinct cells per axis at depths 1, 2, 3, then every triangle alone.
    assert_eq!(f.occupied_cells, vec![8, 64, 512, 512, 512, 512, 512]);
    // Scene extent 7.125 (exponent 2), triangle extent 0.125 (exponent -3): k = 5 for all.
    assert_eq!(f.size_histogram[5], 512);
    assert_eq!(f.extent_exponents, [2, 2, 2]);
    let d = f.derived();
    assert_eq!(d.size_mean, 5.0);
    assert_eq!(d.size_spread, 0.0);
    assert_eq!(d.aspect_log2, 0.0);
    assert_eq!(d.empty_d3, 0.0);
    // 512 triangles fill their 512 cells at depth 3 exactly.
    assert!((d.fill_at_n - 1.0).abs() < 1e-12, "{}", d.fill_at_n);
}

#[test]
fn features_of_a_flat_scene() {
    let f = features_cpu(&generate::flat(1000, 7), &Params::default()).unwrap();
    let flat_axes = f.extent_exponents.iter().filter(|&&e| e == i32::MIN).count();
    assert_eq!(flat_axes, 1, "{:?}", f.extent_exponents);
    assert_eq!(f.derived().aspect_log2, 24.0);
    // A plane cannot occupy more than 4 of the 8 octants' worth of cells per level beyond the first: at depth d at
    // most 4^d cells.
    for d in 1..=7 {
        assert!(f.occupied(d) <= 4u64.pow(d as u32), "depth {d}: {}", f.occupied(d));
    }
    assert_eq!(f.size_histogram.len(), SIZE_BINS);
}

#[test]
fn exponent_reads_the_bits() {
    assert_eq!(exponent(1.0), Some(0));
    assert_eq!(exponent(0.75), Some(-1));
    assert_eq!(exponent(1024.5), Some(10));
    assert_eq!(exponent(0.0), None);
    assert_eq!(exponent(f32::MIN_POSITIVE / 2.0), None);
}

/// Features with pseudo-random but valid contents, `i` picks the variant.
fn synthetic_features(i: u64) -> Features {
    let mut x = i.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let n = 500 + next() % 500_000;
    let mut occ = Vec::new();
    let mut prev = 1u64;
    for d in 1..=7u32 {
        let cap = 8u64.pow(d).min(n);
        let v = (prev + next() % cap.max(1)).clamp(prev, cap);
        occ.push(v);
        prev = v;
    }
    let mut hist = vec![0u64; SIZE_BINS];
    for _ in 0..5 {
        hist[(next() % 16) as usize] += 1 + next() % 1000;
    }
    Features {
        triangles: n,
        total_triangles: n,
        morton_bits: 30,
        occupied_cells: occ,
        size_histogram: hist,
        zero_extent: 0,
        extent_exponents: [0, -((next() % 5) as i32), (next() % 3) as i32],
        lo: [0.0; 3],
        hi: [1.0; 3],
    }
}

/// A structure's true constants: name, `a`, `b`, prices.
pub(super) type Truth = (StructureName, f64, f64, Vec<f64>);

/// Samples measured exactly by a known model: build = exp(a_s) n^b_s, tests = exp(theta . phi), price row.
pub(super) fn known_samples(count: u64) -> (Vec<Sample>, Vec<Truth>) {
    known_samples_with_rays(count, |i| 10_000 + 1000 * i)
}

/// [`known_samples`] with `rays(i)` rays per frame in sample `i`.
pub(super) fn known_samples_with_rays(count: u64, rays: impl Fn(u64) -> u64) -> (Vec<Sample>, Vec<Truth>) {
    known_samples_viewed(count, rays, |_| None, [0.0, 0.0])
}

/// [`known_samples_with_rays`] seen from `view(i)` in sample `i`, the BVH's and the grid's
/// `test_outside_log_n` prices `outside`.
fn known_samples_viewed(
    count: u64,
    rays: impl Fn(u64) -> u64,
    view: impl Fn(u64) -> Option<ViewFeatures>,
    outside: [f64; 2],
) -> (Vec<Sample>, Vec<Truth>) {
    let truth: Vec<Truth> = vec![
        (StructureName::Bvh, -7.0, 1.05, vec![2.0, 1.0, 0.5, 0.0, 6.0, 0.0, 3.0, 0.0, 0.8, outside[0]]),
        (StructureName::Grid, -8.0, 0.9, vec![1.0, 20.0, 4.0, 9.0, 12.0, 1.0, 5.0, 0.7, 0.3, outside[1]]),
    ];
    let kinds = [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse];
    let mut samples = Vec::new();
    for i in 0..count {
        let f = synthetic_features(i + 1);
        let kind = kinds[(i % 3) as usize];
        let x = phi(&f.derived(), kind);
        let n = f.triangles as f64;
        let workload = Workload { kind, rays_per_frame: rays(i), frames: 1, builds: 1, view: view(i) };
        let measured = truth
            .iter()
            .enumerate()
            .map(|(si, (s, a, b, price))| {
                let bx = (1.0 + 0.2 * si as f64 + 0.1 * x[3] - 0.05 * x[4]).exp();
                let pr = (0.5 - 0.3 * si as f64 + 0.2 * x[7] * 0.1).exp();
                let build = (a + b * n.ln()).exp();
                let row = price_row(kind, bx, pr, price_outside_ln_n(&workload, f.triangles));
                let ns: f64 = price.iter().zip(row).map(|(p, r)| p * r).sum();
                let trace = ns * 1e-6 * workload.rays_per_frame as f64;
                Measured {
                    structure: *s,
                    valid: true,
                    total_ms: build + trace,
                    build_ms: build,
                    trace_ms: trace,
                    build_ms_per_build: build,
                    trace_ns_per_ray: ns,
                    box_tests_per_ray: bx,
                    prim_tests_per_ray: pr,
                    within_noise_of_best: false,
                    total_ms_ci95: None,
                    build_work: 0.0,
                }
            })
            .collect();
        samples.push(Sample {
            scene: format!("scene{i}"),
            workload,
            features: f,
            measured,
            baseline: Some(StructureName::Grid),
            driver: Vec::new(),
            frame_features: Vec::new(),
            crossings: None,
            timed: Vec::new(),
            frame_timings: Vec::new(),
            grid_build_work: 0.0,
            trace_backend: Default::default(),
            stage_ms: Default::default(),
        });
    }
    (samples, truth)
}

/// A model fitted on samples all traced on a device is a device model (its backend, a device named by the fit's
/// `device`), which keeps a law within one RMS of a probe's sample; one fitted on CPU samples holds every probed
/// count to its sample (`CostModel::own_probe_band`).
#[test]
fn a_fit_on_device_samples_is_a_device_model_and_keeps_the_probe_band() {
    use meshchar::accel::device::TraceBackend;
    let (samples, _) = known_samples(40);
    let cpu = CostModel::fit(&samples, "test", "synthetic").unwrap();
    assert_eq!((cpu.trace_backend, cpu.trace_device.as_ref()), (TraceBackend::Cpu, None));
    assert_eq!(cpu.own_probe_band(), meshchar::cost::OWN_PROBE_BAND_CPU);
    let on_device: Vec<Sample> =
        samples.iter().map(|s| Sample { trace_backend: TraceBackend::Vulkan, ..s.clone() }).collect();
    let dev = CostModel::fit(&on_device, "a device", "synthetic").unwrap();
    assert_eq!(dev.trace_backend, TraceBackend::Vulkan);
    assert_eq!(dev.trace_device.as_ref().map(|d| d.name.as_str()), Some("a device"));
    assert_eq!(dev.own_probe_band(), meshchar::cost::PROBE_BAND);
    dev.validate().expect("a device model a file can hold");
    // One CPU sample among them keeps the model a CPU one.
    let mut mixed = on_device.clone();
    mixed[0].trace_backend = TraceBackend::Cpu;
    assert_eq!(CostModel::fit(&mixed, "a device", "synthetic").unwrap().trace_backend, TraceBackend::Cpu);
}

#[test]
fn the_fitter_recovers_known_constants() {
    let (samples, truth) = known_samples(40);
    let m = CostModel::fit(&samples, "test", "synthetic").unwrap();
    assert_eq!(m.structures.len(), 2);
    for (s, a, b, price) in &truth {
        let sm = m.get(*s).unwrap();
        assert!((sm.build_ln_a - a).abs() < 1e-6, "{s}: a {} vs {a}", sm.build_ln_a);
        assert!((sm.build_exponent - b).abs() < 1e-6, "{s}: b {} vs {b}", sm.build_exponent);
        assert_eq!(sm.trace_price.len(), PRICE_NAMES.len());
        for (got, want) in sm.trace_price.iter().zip(price) {
            assert!((got - want).abs() < 1e-6 * want.max(1.0), "{s}: price {:?} vs {price:?}", sm.trace_price);
        }
        // The counts are log-linear in phi: the ridge fit reproduces them closely.
        assert!(sm.fit.box_tests < 0.05 && sm.fit.prim_tests < 0.05, "{s}: {:?}", sm.fit);
        assert!(sm.fit.total < 0.05, "{s}: {:?}", sm.fit);
    }
}

/// The view's price (`test_outside_log_n`) is fitted where the samples hold eyes both inside and outside the
/// bounds, and held at 0 where every eye is outside: there it could only stand for `ln n`, and would vanish from
/// every prediction for an eye inside.
#[test]
fn an_eye_outside_is_priced_only_where_the_samples_hold_both() {
    let inside = ViewFeatures { eye_inside: true, coverage: 1.0, distance: 0.5 };
    let outside = ViewFeatures { eye_inside: false, coverage: 0.4, distance: 3.0 };
    let view = |i: u64| Some(if (i / 3) % 2 == 0 { outside } else { inside });
    let (samples, truth) = known_samples_viewed(60, |i| 10_000 + 1000 * i, view, [0.05, 0.3]);
    let m = CostModel::fit(&samples, "test", "synthetic").unwrap();
    for (s, _, _, price) in &truth {
        let got = &m.get(*s).unwrap().trace_price;
        for (g, want) in got.iter().zip(price) {
            assert!((g - want).abs() < 1e-6 * want.max(1.0), "{s}: {got:?} vs {price:?}");
        }
        assert!(got[PRICE_NAMES.len() - 1] > 0.0, "{s}: {got:?}");
    }
    // The same records with every eye outside: the price is held at 0, and the trace time per ray it stood for
    // falls to the others.
    let (samples, _) = known_samples_viewed(60, |i| 10_000 + 1000 * i, |_| Some(outside), [0.05, 0.3]);
    let m = CostModel::fit(&samples, "test", "synthetic").unwrap();
    for sm in &m.structures {
        assert_eq!(sm.trace_price[PRICE_NAMES.len() - 1], 0.0, "{}: {:?}", sm.structure, sm.trace_price);
    }
    // An eye inside is not priced by it; no view is priced as the framing camera's, whose eye is outside.
    let w = Workload { kind: WorkloadKind::Primary, rays_per_frame: 1, frames: 1, builds: 1, view: Some(inside) };
    assert_eq!(price_outside_ln_n(&w, 1000), 0.0);
    assert_eq!(price_outside_ln_n(&Workload { view: None, ..w }, 1000), 1000f64.ln());
    assert_eq!(price_outside_ln_n(&Workload { view: Some(outside), ..w }, 1000), 1000f64.ln());
}

/// [`known_samples`] whose builds follow the work law `exp(a) n^b (work / n)^c` for each structure's `c` (the
/// BVH's 0.8, the grid's -0.5: a law in which more work builds faster), with the work per triangle varying
/// from sample to sample apart from `n`.
fn samples_with_work() -> Vec<Sample> {
    let (mut samples, truth) = known_samples(40);
    for (i, smp) in samples.iter_mut().enumerate() {
        let n = smp.features.triangles as f64;
        let per = 4.0 + ((i * 7) % 23) as f64;
        for (m, (_, a, b, _)) in smp.measured.iter_mut().zip(&truth) {
            let c = if m.structure == StructureName::Bvh { 0.8 } else { -0.5 };
            m.build_work = n * per;
            m.build_ms_per_build = (a + b * n.ln() + c * per.ln()).exp();
            m.build_ms = m.build_ms_per_build;
            m.total_ms = m.build_ms + m.trace_ms;
        }
    }
    samples
}

#[test]
fn the_work_law_prices_a_probed_build_by_its_work_and_never_makes_work_cheaper() {
    let samples = samples_with_work();
    let m = CostModel::fit(&samples, "test", "synthetic").unwrap();
    let bvh = m.get(StructureName::Bvh).unwrap();
    let [a, b, c, ref d @ ..] = bvh.build_work_coef[..] else { panic!("no work law: {:?}", bvh.build_work_coef) };
    assert!((a + 7.0).abs() < 1e-5 && (b - 1.05).abs() < 1e-5 && (c - 0.8).abs() < 1e-5, "{a} {b} {c}");
    // Builds without curvature: none fitted (or a negligible one).
    assert!(d.iter().all(|d| d.abs() < 1e-6), "{d:?}");
    assert!(bvh.fit.build_work < 1e-6, "{:?}", bvh.fit);
    // The plain law, fitted on n alone, misses what the work adds.
    assert!(bvh.fit.build > 0.1, "{:?}", bvh.fit);
    // A prediction reads the work where a probe gives it, the plain law otherwise.
    let smp = &samples[5];
    let meas = smp.get(StructureName::Bvh).unwrap();
    let n = smp.features.triangles;
    let floor = meshchar::cost::TestFloor { build_work: meas.build_work, ..Default::default() };
    let with = bvh.predict_floored(&smp.features.derived(), n, &smp.workload, floor);
    assert!((with.build_ms_per_build / meas.build_ms_per_build - 1.0).abs() < 1e-5, "{with:?}");
    let without = bvh.predict(&smp.features.derived(), n, &smp.workload);
    let plain = plain_build(bvh, n as f64);
    assert!((without.build_ms_per_build / plain - 1.0).abs() < 1e-12, "{without:?}");
    // The grid's builds get faster with more work: its exponent is held at 0, the law in n refitted.
    let grid = m.get(StructureName::Grid).unwrap();
    assert!(matches!(grid.build_work_coef.len(), 3 | 4), "{:?}", grid.build_work_coef);
    assert_eq!(grid.build_work_coef[2], 0.0, "{:?}", grid.build_work_coef);
    // Without counted work (records written before it), no work law.
    let (plain_samples, _) = known_samples(40);
    let m = CostModel::fit(&plain_samples, "test", "synthetic").unwrap();
    assert!(m.structures.iter().all(|s| s.build_work_coef.is_empty() && s.fit.build_work == 0.0));
}

/// [`known_samples`] whose builds carry a curvature `d * (ln n - 10)^2` in the structure's law (the BVH's
/// `d_bvh`, the grid's `d_grid`), and the sizes' `ln n` restricted to `[lo, lo + span]`.
fn samples_with_curvature(d_bvh: f64, d_grid: f64, lo: f64, span: f64) -> Vec<Sample> {
    let (mut samples, truth) = known_samples(40);
    let count = samples.len();
    for (i, smp) in samples.iter_mut().enumerate() {
        let n = (lo + span * i as f64 / (count - 1) as f64).exp().round() as u64;
        smp.features.triangles = n;
        smp.features.total_triangles = n;
        let x = (n as f64).ln();
        for (m, (_, a, b, _)) in smp.measured.iter_mut().zip(&truth) {
            let d = if m.structure == StructureName::Bvh { d_bvh } else { d_grid };
            m.build_ms_per_build = (a + b * x + d * (x - 10.0).powi(2)).exp();
            m.build_ms = m.build_ms_per_build;
            m.total_ms = m.build_ms + m.trace_ms;
        }
    }
    samples
}

#[test]
fn the_build_law_bends_with_the_sizes_only_upward_and_only_where_they_span_enough() {
    // Sizes from 1K to 1M triangles (ln n 6.9 to 13.8): the BVH's U-shaped time per triangle is recovered exactly;
    // the grid's, peaked in the middle (a negative curvature), is held at 0.
    let samples = samples_with_curvature(0.05, -0.05, 6.9, 6.9);
    let m = CostModel::fit(&samples, "test", "synthetic").unwrap();
    let bvh = m.get(StructureName::Bvh).unwrap();
    assert!((bvh.build_curvature - 0.05).abs() < 1e-6, "{bvh:?}");
    assert!((bvh.build_ln_a + 7.0).abs() < 1e-5 && (bvh.build_exponent - 1.05).abs() < 1e-6, "{bvh:?}");
    assert!(bvh.fit.build < 1e-6, "{:?}", bvh.fit);
    let [lo, hi] = bvh.build_ln_n_range[..] else { panic!("no range: {bvh:?}") };
    assert!((lo - 6.9).abs() < 1e-3 && (hi - 13.8).abs() < 1e-3, "{lo} {hi}");
    let grid = m.get(StructureName::Grid).unwrap();
    assert_eq!(grid.build_curvature, 0.0, "{grid:?}");
    assert!(grid.build_ln_n_range.is_empty(), "{grid:?}");
    // Beyond the fitted sizes the law follows its tangent: at 100x the largest size, the slope of ln build in ln n
    // stays the one at the edge (b + 2 d (hi - 10)), not the parabola's steeper one.
    let d = samples[0].features.derived();
    let w = samples[0].workload;
    let at = |ln_n: f64| bvh.predict(&d, ln_n.exp() as u64, &w).build_ms_per_build.ln();
    let (x1, x2) = (hi + 1.0, hi + 4.6);
    let slope = (at(x2) - at(x1)) / (((x2.exp() as u64) as f64).ln() - ((x1.exp() as u64) as f64).ln());
    let edge = bvh.build_exponent + 2.0 * bvh.build_curvature * (hi - 10.0);
    assert!((slope - edge).abs() < 1e-6, "slope {slope} vs the edge's {edge}");
    // The term itself: continuous in value and slope at the edges, 0 for a range that is none.
    let q = |x: f64| meshchar::cost::curvature_term(x, lo, hi);
    for edge in [lo, hi] {
        assert!((q(edge + 1e-9) - q(edge - 1e-9)).abs() < 1e-6);
        let slope = |x: f64| (q(x + 1e-4) - q(x - 1e-4)) / 2e-4;
        assert!((slope(edge + 1e-3) - slope(edge - 1e-3)).abs() < 1e-2, "{edge}");
    }
    assert_eq!(meshchar::cost::curvature_term(12.0, 9.0, 7.0), 0.0);
    assert_eq!(meshchar::cost::curvature_term(12.0, f64::NAN, 7.0), 0.0);
    // Two sizes far apart (ln 6.9 and 13.8): a curvature is not identified, none is fitted.
    let mut two = samples_with_curvature(0.05, 0.05, 6.9, 6.9);
    for (k, smp) in two.iter_mut().enumerate() {
        let n = if k % 2 == 0 { 1000 } else { 1_000_000 };
        smp.features.triangles = n;
        smp.features.total_triangles = n;
    }
    let m = CostModel::fit(&two, "test", "synthetic").unwrap();
    assert!(m.structures.iter().all(|s| s.build_curvature == 0.0 && s.build_ln_n_range.is_empty()), "{m:?}");
    // Sizes within a factor of 20 (ln 3.0, under BUILD_CURVATURE_MIN_SPAN): no curvature is fitted.
    let narrow = samples_with_curvature(0.05, 0.05, 9.0, 3.0);
    let m = CostModel::fit(&narrow, "test", "synthetic").unwrap();
    assert!(m.structures.iter().all(|s| s.build_curvature == 0.0 && s.build_ln_n_range.is_empty()), "{m:?}");
}

#[test]
fn calibration_files_round_trip() {
    let (samples, _) = known_samples(12);
    let m = CostModel::fit(&samples, "test device", "synthetic").unwrap();
    assert_eq!(m.version, COST_MODEL_VERSION);
    assert_eq!(m.feature_names, FEATURE_NAMES);
    assert_eq!(m.price_names, PRICE_NAMES);
    let dir = common::temp_dir("cost");
    let path = dir.join("cal.json");
    m.save(&path).unwrap();
    // Every constant comes back (the JSON numbers are shortest round-trip forms): the whole model is equal.
    assert_eq!(CostModel::load(Some(&path)).unwrap(), m);
    // Files that cannot be used are errors, never the shipped model: src/eval/tests/cost_file.rs.
}

#[test]
fn the_fit_refuses_constants_a_calibration_file_could_not_hold() {
    // Builds of hours at any size (ms ~ 1e8): an intercept no file may hold (exp(a) at most 8 s), with the exponent
    // held in its range (a falling build time fits the exponent at 0: a_falling_build_time_fits_the_exponent_at_its_
    // bound).
    let (mut samples, _) = known_samples(12);
    for s in samples.iter_mut() {
        for m in s.measured.iter_mut() {
            m.build_ms_per_build = 1e8;
            m.build_ms = m.build_ms_per_build;
            m.total_ms = m.build_ms + m.trace_ms;
        }
    }
    let e = CostModel::fit(&samples, "test device", "synthetic").unwrap_err().to_string();
    assert!(e.contains("structures[0] (bvh).build_ln_a"), "{e}");
    assert!(CostModel::fit(&known_samples(12).0, "", "synthetic").unwrap_err().to_string().contains("device"));
}
