//! The speed/accuracy study: Pareto front, histogram distance and drift, oracle results read back, the structures
//! within noise of the best and the cheapest of them, a sweep with a pluggable policy and its least-work table, and
//! sampled / 63-bit / other-rule characterizations identical on the CPU and on Vulkan (lavapipe).

use super::common;
use super::gpu_support;

use meshchar::accel::StructureName;
use meshchar::characterize::{cpu, Backend, Characterization, Characterizer, ClassRule, MortonBits, Params};
use meshchar::eval::tradeoff::{self, drift, histogram_distance, pareto_front, GridSpec, Setting, StatsTolerance};
use meshchar::eval::{evaluate_scene, OracleConfig, OracleRecord};
use meshchar::geom::WorkloadKind;
use meshchar::mesh::{generate, load_mesh, Animation};
use meshchar::select::{Policy, SceneSummary, Selection, Structure, ThesisPolicy};

#[test]
fn pareto_front_on_hand_data() {
    // (time, regret): 0 and 3 trade off, 1 is dominated by 0, 2 by 3, 4 equals 3 (the first of equals stays),
    // 5 is not finite.
    let pts = [(1.0, 0.5), (2.0, 0.5), (5.0, 0.3), (4.0, 0.1), (4.0, 0.1), (0.5, f64::NAN), (10.0, 0.0)];
    assert_eq!(pareto_front(&pts), vec![0, 3, 6]);
    assert_eq!(pareto_front(&[]), Vec::<usize>::new());
    // Sorted by time whatever the input order.
    assert_eq!(pareto_front(&[(3.0, 0.0), (1.0, 1.0), (2.0, 0.5)]), vec![1, 2, 0]);
}

#[test]
fn histogram_distance_by_hand() {
    assert_eq!(histogram_distance(&[3, 5, 7], &[30, 50, 70]), 0.0);
    assert_eq!(histogram_distance(&[1, 0], &[0, 1]), 1.0);
    assert!((histogram_distance(&[1, 1], &[2, 0]) - 0.5).abs() < 1e-12);
    // Different k: everything in the first half against everything in the first quarter.
    assert!((histogram_distance(&[1, 0], &[1, 0, 0, 0]) - 0.5).abs() < 1e-12);
    // A uniform histogram is the same density at any k.
    assert!(histogram_distance(&[4, 4, 4], &[1, 1, 1, 1, 1, 1]).abs() < 1e-12);
    assert_eq!(histogram_distance(&[5, 2], &[2, 5]), histogram_distance(&[2, 5], &[5, 2]));
}

fn bunny() -> Animation {
    let m = load_mesh(&common::shared_mesh("small/bunny-lowres-pd.obj")).unwrap();
    Animation::new(m.name.clone(), vec![m]).unwrap()
}

#[test]
fn drift_is_zero_for_the_full_setting_and_not_for_a_coarse_one() {
    let scene = bunny();
    let mesh = &scene.frames[0];
    let full = [cpu::fast(mesh, &Params::default()).unwrap()];
    let again = [cpu::naive(mesh, &Params::default()).unwrap()];
    let d = drift(&full, &again);
    assert_eq!(d, tradeoff::Drift::default(), "the same parameters on another backend do not drift");
    assert!(StatsTolerance::default().accepts(&d));

    let coarse = [cpu::fast(mesh, &Params { sample_stride: 64, ..Params::default() }).unwrap()];
    let d = drift(&full, &coarse);
    assert!(d.k_delta < 0, "64x fewer triangles give fewer Doane classes: {d:?}");
    assert!(d.histogram > 0.0 && d.effect_size > 0.0, "{d:?}");
    assert_eq!(d.effect_size, (coarse[0].stats.cramers_v - full[0].stats.cramers_v).abs());
    assert_eq!(d.histogram, histogram_distance(&full[0].histogram, &coarse[0].histogram));
}

#[test]
fn grid_varies_one_knob_at_a_time() {
    let g = GridSpec::default();
    let s = g.settings();
    assert_eq!(s[0], Setting::reference());
    // 3 backends x 9 strides, 9 strides at 63 bits, 6 other rules.
    assert_eq!(s.len(), 27 + 9 + 6);
    for (i, a) in s.iter().enumerate() {
        assert!(s[i + 1..].iter().all(|b| b != a), "duplicate {}", a.label());
        let changed = [
            a.params.sample_stride != 1 || a.backend != Backend::Cpu,
            a.params.morton_bits != MortonBits::Bits30,
            a.params.class_rule != ClassRule::Doane,
        ];
        assert!(!(changed[2] && (changed[0] || changed[1])), "{}: a rule change comes alone", a.label());
    }
    assert_eq!(s[1].label(), "cpu/30/doane/1:2");
}

/// Selects a grid when at least `min` triangles were looked at, else a BVH: a policy whose answer depends on the
/// sample size, to exercise the pluggable policy and the least-work table.
struct CountPolicy {
    min: u64,
}

impl Policy for CountPolicy {
    fn name(&self) -> &str {
        "count"
    }
    fn select(&self, scene: &SceneSummary<'_>) -> Selection {
        let n = scene.frames.first().map_or(0, |f| f.triangles);
        Selection::new(if n >= self.min { Structure::Grid } else { Structure::Bvh }, Vec::new())
    }
}

#[test]
fn sweep_with_a_pluggable_policy_and_the_least_work_table() {
    let scene = bunny();
    let n = scene.frames[0].triangle_count() as u64;
    let grid = GridSpec {
        backends: vec![Backend::Cpu, Backend::Naive],
        strides: vec![1, 2, 4, 8, 16],
        bits: vec![MortonBits::Bits30],
        rules: vec![ClassRule::Doane, ClassRule::Fixed(16), ClassRule::Fixed(4)],
    };
    let settings = grid.settings();
    // A grid for n / 4 triangles and more: strides 1, 2, 4 agree with the full computation, 8 does not.
    let policy = CountPolicy { min: n.div_ceil(4) };
    let scenes = [scene];
    // An oracle where the grid is best and the BVH is 50% slower, out of noise.
    let oracle_line = serde_json::json!({
        "mesh": scenes[0].name, "workload": "primary", "resolution": 8,
        "structures": [
            {"name": "grid", "total_ms": 10.0, "total_ms_spread": 0.5, "build_ms": 1.0, "memory_bytes": 10,
             "valid": true, "hits_agree": true},
            {"name": "bvh", "total_ms": 15.0, "total_ms_spread": 0.5, "build_ms": 2.0, "memory_bytes": 10,
             "valid": true, "hits_agree": true},
        ]
    });
    let oracle = vec![OracleRecord::from_json(&oracle_line).unwrap()];
    let workloads = vec!["primary".to_string()];
    let mut engine_for = |b: Backend| Characterizer::new(Some(b));
    let study = tradeoff::Study {
        scenes: &scenes,
        settings: &settings,
        policy: tradeoff::Selector::Policy(&policy),
        oracle: &oracle,
        workloads: &workloads,
        repeats: 1,
    };
    let results = tradeoff::sweep(&study, &mut engine_for, &|_| {}).unwrap();
    assert_eq!(results.len(), settings.len());
    for r in &results {
        let s = &r.scenes[0];
        let expect_grid = n.div_ceil(r.sample_stride as u64) >= policy.min;
        assert_eq!(s.selected, if expect_grid { "grid" } else { "bvh" }, "{}", r.label);
        assert_eq!(s.same_selection, expect_grid, "{}", r.label);
        let a = r.accuracy("primary").unwrap();
        assert_eq!(a.scenes, 1);
        if expect_grid {
            assert_eq!((a.agree_best, a.mean_regret), (1.0, 0.0), "{}", r.label);
        } else {
            assert_eq!((a.agree_best, a.agree_within_noise), (0.0, 0.0), "{}", r.label);
            assert!((a.mean_regret - 0.5).abs() < 1e-12 && (a.worst_regret - 0.5).abs() < 1e-12, "{}", r.label);
        }
        // One timed run per setting and scene (repeats: 1, the untimed warm-up apart): a single sample, which took
        // time; the setting's time is the sum over its one scene.
        let t = &r.scenes[0].time_ms;
        assert!(t.median > 0.0 && (t.min, t.max, t.spread) == (t.median, t.median, 0.0), "{}: {t:?}", r.label);
        assert_eq!(r.time_ms, t.median, "{}", r.label);
        // Sampled settings are also read with the full computation's k.
        match (&s.same_k, r.sample_stride, r.class_rule.as_str()) {
            (Some(x), stride, "doane") if stride > 1 => assert_eq!(x.drift.k_delta, 0, "{}", r.label),
            (None, 1, _) | (None, _, "16") | (None, _, "4") => {}
            other => panic!("{}: unexpected same-k result {other:?}", r.label),
        }
    }
    // Both backends compute the same numbers for the same parameters.
    let by = |label: &str| results.iter().find(|r| r.label == label).unwrap();
    assert_eq!(by("cpu/30/doane/1:8").scenes[0].drift, by("naive/30/doane/1:8").scenes[0].drift);
    assert_eq!(by("cpu/30/doane/1:1").scenes[0].drift, tradeoff::Drift::default());

    let suff = tradeoff::sufficiency(&results, &StatsTolerance::default());
    assert_eq!(suff.len(), 1);
    assert_eq!(suff[0].stride_selection, Some(4));
    assert!(suff[0].stride_statistics.is_some_and(|s| s <= 4));
    assert!(suff[0].stride_same_k.is_some_and(|s| s <= 4), "the count policy still flips at 1/8");
    // Every triangle is looked at with a fixed k, so the count policy keeps its answer.
    assert_eq!(suff[0].fixed_k_selection, Some(4));
    assert_eq!(suff[0].rules_with_same_selection, vec!["16".to_string(), "4".to_string()]);
    assert!(suff[0].bits30_enough, "no other bit depth was tried");

    let md = tradeoff::markdown(&results, &workloads, &suff);
    assert!(md.contains("| cpu/30/doane/1:16 |") && md.contains("| 1/4 |"), "{md}");
    let charts = tradeoff::charts(&results, &workloads);
    let names: Vec<&str> = charts.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["tradeoff-primary.svg", "tradeoff-statistics.svg"]);
    // The front of the regret chart: the fastest setting with regret 0 and anything faster with regret 0.5.
    assert!(!charts[0].1.front.is_empty());
}

#[test]
fn oracle_reports_the_cheapest_structure_within_noise() {
    // A few hundred large triangles (vertices uniform in the unit cube, so the tiny image hits them), a tiny image:
    // every structure builds in well under a millisecond, so several are within noise of each other.
    let m = generate::overlapping_large(300, 7);
    let scene = Animation::new("soup", vec![m]).unwrap();
    let config = OracleConfig { workload: WorkloadKind::Primary, resolution: 16, repeats: 3, ..Default::default() };
    let e = evaluate_scene(&scene, &config, Some(StructureName::Bvh), &|_| {}).unwrap();
    assert!(e.reference_hits > 0, "the soup is in view");
    let best = e.oracle_best.expect("a best structure");
    assert!(e.oracle_within_noise.contains(&best));
    for s in &e.structures {
        let name = s.name.unwrap();
        assert_eq!(e.oracle_within_noise.contains(&name), s.within_noise_of_best, "{name}");
    }
    let cheapest = e.oracle_cheapest_within_noise.expect("the best is within noise of itself");
    let c = e.get(cheapest).unwrap();
    for &n in &e.oracle_within_noise {
        let o = e.get(n).unwrap();
        assert!(
            c.build_ms.median < o.build_ms.median
                || (c.build_ms.median == o.build_ms.median && c.memory_bytes <= o.memory_bytes),
            "{cheapest} is not the cheapest: {n} builds in {} ms",
            o.build_ms.median
        );
    }
    // Regret is still against the best by total.
    let r = e.regret.unwrap();
    let expect = e.get(StructureName::Bvh).unwrap().total_ms.median / e.get(best).unwrap().total_ms.median - 1.0;
    assert_eq!(r, expect);
    // The JSON line carries the fields, and the study reads it back to the same answers.
    let v = e.to_json();
    assert_eq!(v["oracle_cheapest_within_noise"], serde_json::json!(cheapest.as_str()));
    assert_eq!(v["oracle_within_noise"].as_array().unwrap().len(), e.oracle_within_noise.len());
    let o = OracleRecord::from_json(&v).unwrap();
    assert_eq!(o.best().and_then(|b| b.name), Some(best));
    assert_eq!(o.within_noise(), e.oracle_within_noise);
    assert_eq!(o.cheapest_within_noise(), Some(cheapest));
    assert_eq!(o.regret(StructureName::Bvh), Some(r));
    assert_eq!(e.record().cheapest_within_noise(), Some(cheapest));
}

#[test]
fn oracle_files_are_read_and_bad_lines_are_named() {
    let dir = common::temp_dir("oracle");
    let good = serde_json::json!({"mesh": "a.obj", "workload": "shadow", "resolution": 4, "structures": [
        {"name": "lbvh", "total_ms": 2.0, "total_ms_spread": 0.1, "build_ms": 1.0, "memory_bytes": 5,
         "valid": true, "hits_agree": true},
        {"name": "kdtree", "total_ms": 1.0, "total_ms_spread": 0.1, "build_ms": 0.5, "memory_bytes": 5,
         "valid": true, "hits_agree": false},
        {"name": "bih", "total_ms": 2.15, "total_ms_spread": 0.1, "build_ms": 0.2, "memory_bytes": 9,
         "valid": true, "hits_agree": true},
        {"name": "grid", "total_ms": 2.25, "total_ms_spread": 0.1, "build_ms": 0.1, "memory_bytes": 1,
         "valid": true, "hits_agree": true}]});
    let p = dir.join("o.jsonl");
    std::fs::write(&p, format!("{good}\n\n{good}\n")).unwrap();
    let v = meshchar::eval::record::read_jsonl(&p).unwrap();
    assert_eq!(v.len(), 2);
    // The kd-tree disagreed with the reference hits: it cannot be the best.
    assert_eq!(v[0].best().and_then(|b| b.name), Some(StructureName::Lbvh));
    assert_eq!(v[0].regret(StructureName::KdTree), None);
    // bih (2.15 +- 0.1) is within noise of lbvh (2.0 +- 0.1) and builds faster; grid (2.25) is not within noise.
    assert_eq!(v[0].within_noise(), vec![StructureName::Lbvh, StructureName::Bih]);
    assert_eq!(v[0].cheapest_within_noise(), Some(StructureName::Bih));
    assert!((v[0].regret(StructureName::Bih).unwrap() - 0.075).abs() < 1e-12);
    let md = tradeoff::structures_markdown(&v, &["shadow".to_string()]);
    assert!(md.contains("| shadow | a.obj | lbvh | lbvh, bih | bih (cheaper than the best) |"), "{md}");
    assert!(md.contains("shadow: 2 of 2 scenes"), "{md}");
    std::fs::write(&p, format!("{good}\n{{\"mesh\": 1}}\n")).unwrap();
    let err = meshchar::eval::record::read_jsonl(&p).unwrap_err().to_string();
    assert!(err.contains("o.jsonl:2"), "{err}");
    assert!(meshchar::eval::record::read_jsonl(&dir.join("missing.jsonl")).is_err());
}

fn assert_same(a: &Characterization, b: &Characterization, what: &str) {
    assert_eq!(a.triangles, b.triangles, "{what}: n");
    assert_eq!(a.code_stats, b.code_stats, "{what}: code sums");
    assert_eq!(a.classes, b.classes, "{what}: k");
    assert_eq!(a.histogram, b.histogram, "{what}: histogram");
    assert_eq!(a.moments.skewness.to_bits(), b.moments.skewness.to_bits(), "{what}: skewness");
    assert_eq!(a.stats.cramers_v.to_bits(), b.stats.cramers_v.to_bits(), "{what}: V");
    assert_eq!(a.stats.chi_square.to_bits(), b.stats.chi_square.to_bits(), "{what}: chi2");
    assert_eq!(a.stats.empty_classes, b.stats.empty_classes, "{what}: empty");
    assert_eq!(a.stats.concentrated_share.to_bits(), b.stats.concentrated_share.to_bits(), "{what}: share");
}

#[test]
fn sampled_settings_characterize_identically_on_cpu_and_vulkan() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut vk = Characterizer::with_context(&ctx).unwrap();
    let meshes = [
        load_mesh(&common::shared_mesh("small/bunny-lowres-pd.obj")).unwrap(),
        load_mesh(&common::shared_mesh("stanford-bunny/bun_zipper_res2.ply")).unwrap(),
    ];
    let mut settings = GridSpec::default().settings();
    settings.retain(|s| s.backend == Backend::Cpu);
    // Also a few combinations beyond one knob at a time.
    for (stride, rule) in [(16, ClassRule::Sqrt), (3, ClassRule::Sturges), (7, ClassRule::Fixed(100))] {
        settings.push(Setting {
            backend: Backend::Cpu,
            params: Params {
                sample_stride: stride,
                class_rule: rule,
                morton_bits: MortonBits::Bits63,
                ..Params::default()
            },
        });
    }
    for mesh in &meshes {
        for s in &settings {
            let what = format!("{} {}", mesh.name, s.label());
            let c = cpu::fast(mesh, &s.params).unwrap();
            let g = vk.characterize(mesh, &s.params).unwrap();
            assert_eq!(g.backend, "vulkan");
            assert_same(&g, &c, &what);
            let pol = ThesisPolicy::default();
            assert_eq!(
                pol.select(&SceneSummary::new("m", std::slice::from_ref(&g))).structure,
                pol.select(&SceneSummary::new("m", std::slice::from_ref(&c))).structure,
                "{what}"
            );
        }
    }
    drop(vk);
    gpu_support::assert_no_validation_messages(&ctx);
}

/// A cost model small enough to predict on paper: every test-count coefficient 0 (one box and one triangle test per
/// ray, both free), a linear build `exp(a) n` and one price per ray, the same for every kind of ray.
fn paper_model() -> meshchar::cost::CostModel {
    use meshchar::cost::{CostModel, FitError, StructureModel, COST_MODEL_VERSION, FEATURE_NAMES, PRICE_NAMES};
    let structure = |s: StructureName, build_ms_per_triangle: f64, ns_per_ray: f64| StructureModel {
        structure: s,
        build_ln_a: f64::ln(build_ms_per_triangle),
        build_exponent: 1.0,
        box_coef: vec![0.0; FEATURE_NAMES.len()],
        prim_coef: vec![0.0; FEATURE_NAMES.len()],
        trace_price: {
            let mut p = vec![0.0; PRICE_NAMES.len()];
            p[..3].fill(ns_per_ray);
            p
        },
        view_box_coef: Vec::new(),
        view_prim_coef: Vec::new(),
        crossing_coef: Vec::new(),
        crossing_mean: Vec::new(),
        feature_range: Vec::new(),
        build_work_coef: Vec::new(),
        build_curvature: 0.0,
        build_ln_n_range: Vec::new(),
        prior: None,
        size: None,
        fit: FitError::default(),
    };
    let m = CostModel {
        version: COST_MODEL_VERSION,
        device: "paper".into(),
        source: "src/eval/tests/tradeoff.rs".into(),
        scenes: Vec::new(),
        feature_names: FEATURE_NAMES.iter().map(|s| s.to_string()).collect(),
        price_names: PRICE_NAMES.iter().map(|s| s.to_string()).collect(),
        structures: vec![
            structure(StructureName::Grid, 1e-4, 1000.0),
            structure(StructureName::Bvh, 1e-3, 10.0),
            structure(StructureName::Lbvh, 5e-4, 115.0),
        ],
        total_rms_log: 0.0,
        refit: None,
        trace_backend: Default::default(),
        trace_device: None,
        driver: Vec::new(),
        timed: None,
        count_bounds: Default::default(),
        uncertainty: None,
        inquiry_costs: Vec::new(),
        chosen_as: None,
    };
    m.validate().unwrap();
    m
}

#[test]
fn calibrated_policy_selects_per_workload_and_its_regret_is_its_own() {
    use meshchar::characterize::features_cpu;
    let model = paper_model();
    let mesh = generate::random_soup(2000, 3);
    let scenes = [Animation::new("soup", vec![mesh.clone()]).unwrap()];
    // On paper, n = 2000 for both settings (a sample keeps the scene's triangle count), one frame, one build:
    // primary, 1 ray: grid 0.2 + 0.001 ms, bvh 2.0 + 0.00001, lbvh 1.0 + 0.000115: the grid.
    // shadow, 10^4 rays: grid 0.2 + 10 = 10.2 ms, bvh 2.0 + 0.1 = 2.1, lbvh 1.0 + 1.15 = 2.15: the BVH is the
    // smallest, the LBVH is within 5% of it (2.15 <= 2.205) and builds in half the time, so the 5% margin takes the
    // LBVH and no margin the BVH.
    let many = 10_000u64;
    for params in [Params::default(), Params { sample_stride: 4, ..Params::default() }] {
        let f = features_cpu(&mesh, &params).unwrap();
        assert_eq!(f.total_triangles.max(f.triangles), 2000, "stride {}", params.sample_stride);
    }
    let line = |workload: &str, rays: u64, totals: [f64; 6]| {
        let names = ["bvh", "kdtree", "grid", "bih", "lbvh", "hlbvh"];
        let structures: Vec<serde_json::Value> = names
            .iter()
            .zip(totals)
            .map(|(n, t)| {
                serde_json::json!({"name": n, "total_ms": t, "total_ms_spread": 0.01, "build_ms": t / 2.0,
                    "memory_bytes": 10, "valid": true, "hits_agree": true})
            })
            .collect();
        let v = serde_json::json!({"mesh": "soup", "workload": workload, "resolution": 1, "frames": 1,
            "rays_per_frame": rays, "structures": structures});
        OracleRecord::from_json(&v).unwrap()
    };
    // Measured: the BVH is the best on both workloads.
    let oracle = vec![
        line("primary", 1, [10.0, 17.0, 12.0, 11.0, 13.0, 15.0]),
        line("shadow", many, [20.0, 21.0, 29.0, 27.0, 23.0, 25.0]),
    ];
    assert_eq!((oracle[1].rays_per_frame, oracle[1].frames), (many as usize, 1));
    let workloads = vec!["primary".to_string(), "shadow".to_string()];
    let settings = [
        Setting::reference(),
        Setting { backend: Backend::Cpu, params: Params { sample_stride: 4, ..Params::default() } },
    ];
    let mut engine_for = |b: Backend| Characterizer::new(Some(b));
    for (margin, shadow, shadow_regret) in
        [(0.05, StructureName::Lbvh, 23.0 / 20.0 - 1.0), (0.0, StructureName::Bvh, 0.0)]
    {
        let study = tradeoff::Study {
            scenes: &scenes,
            settings: &settings,
            policy: tradeoff::Selector::Calibrated { model: &model, tie_margin: margin },
            oracle: &oracle,
            workloads: &workloads,
            repeats: 1,
        };
        let results = tradeoff::sweep(&study, &mut engine_for, &|_| {}).unwrap();
        assert_eq!(results.len(), 2);
        for r in &results {
            let run = &r.scenes[0];
            let got: Vec<Option<StructureName>> = run.per_workload.iter().map(|w| w.selected).collect();
            assert_eq!(got, [Some(StructureName::Grid), Some(shadow)], "{} margin {margin}", r.label);
            assert_eq!(run.selected, format!("primary=grid,shadow={shadow}"), "{}", r.label);
            assert!(run.same_selection, "{}", r.label);
            // The regret of the policy's own selection, against the measured best (the BVH, 10 and 20 ms).
            let primary = r.accuracy("primary").unwrap();
            assert_eq!((primary.scenes, primary.mean_regret, primary.agree_best), (1, 12.0 / 10.0 - 1.0, 0.0));
            let s = r.accuracy("shadow").unwrap();
            let agree = if shadow == StructureName::Bvh { 1.0 } else { 0.0 };
            assert_eq!((s.scenes, s.mean_regret, s.agree_best), (1, shadow_regret, agree), "{}", r.label);
        }
        // A line without rays per frame is an error for the calibrated policy, named.
        let mut bare = oracle.clone();
        bare[0].rays_per_frame = 0;
        let study = tradeoff::Study { oracle: &bare, ..study };
        let err = tradeoff::sweep(&study, &mut engine_for, &|_| {}).unwrap_err().to_string();
        assert!(err.contains("rays_per_frame"), "{err}");
    }
}
