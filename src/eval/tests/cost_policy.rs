//! The calibrated policy against its reference rule, held-out scores on the family records, the proxy, and the
//! BVH refit.

use meshchar::accel::lbvh::Lbvh;
use meshchar::accel::{AccelStructure, StructureName};
use meshchar::characterize::{cpu, features_cpu, Features, Params};
use meshchar::cost::{CostModel, Prediction, StructureModel, Workload};
use meshchar::eval::compare::compare;
use meshchar::eval::fit::Sample;
use meshchar::eval::OracleRecord;
use meshchar::geom::WorkloadKind;
use meshchar::mesh::generate;
use meshchar::select::choose;
use meshchar::select::CalibratedPolicy;
use meshchar::select::{Policy, ReasonKind, SceneSummary};

use super::cost::{known_samples, known_samples_with_rays};

fn pred(s: StructureName, build: f64, total: f64) -> Prediction {
    Prediction {
        structure: s,
        build_ms_per_build: build,
        build_ms: build,
        box_tests_per_ray: 1.0,
        prim_tests_per_ray: 1.0,
        trace_ns_per_ray: 1.0,
        trace_ms: total - build,
        total_ms: total,
    }
}

#[test]
fn choose_takes_the_smallest_total_then_the_cheaper_build_within_the_margin() {
    let p = vec![
        pred(StructureName::Bvh, 40.0, 100.0),
        pred(StructureName::Lbvh, 10.0, 103.0),
        pred(StructureName::Grid, 5.0, 200.0),
    ];
    assert_eq!(choose(&p, 0.0), Some(StructureName::Bvh));
    assert_eq!(choose(&p, 0.05), Some(StructureName::Lbvh));
    assert_eq!(choose(&p, 0.02), Some(StructureName::Bvh));
    assert_eq!(choose(&[], 0.05), None);
}

/// The module docs' formulas written out again, apart from `CostModel::predict`: phi by feature name (so a
/// reordered `phi` shows), the counts, the price by price name, and per structure the build ms and the total ms of
/// the workload.
fn reference_totals(model: &CostModel, f: &Features, w: &Workload) -> Vec<(StructureName, f64, f64)> {
    let d = f.derived();
    let feature = |name: &str| match name {
        "intercept" => 1.0,
        "shadow" => f64::from(u8::from(w.kind == WorkloadKind::Shadow)),
        "diffuse" => f64::from(u8::from(w.kind == WorkloadKind::Diffuse)),
        "ln_n" => d.ln_n,
        "ln_tris_per_cell" => d.ln_tris_per_cell,
        "fill_at_n" => d.fill_at_n,
        "empty_d3" => d.empty_d3,
        "size_mean" => d.size_mean,
        "size_spread" => d.size_spread,
        "aspect_log2" => d.aspect_log2,
        other => panic!("unknown feature {other}"),
    };
    let x: Vec<f64> = model.feature_names.iter().map(|n| feature(n)).collect();
    let n = f.total_triangles.max(f.triangles) as f64;
    model
        .structures
        .iter()
        .map(|sm| {
            // The geometric features after ln_n are clamped into the range the calibration was fitted on.
            let x: Vec<f64> = x
                .iter()
                .zip(&model.feature_names)
                .enumerate()
                .map(|(j, (&v, name))| match sm.feature_range.get(j) {
                    Some(&[lo, hi]) if !matches!(name.as_str(), "intercept" | "shadow" | "diffuse" | "ln_n") => {
                        v.clamp(lo, hi)
                    }
                    _ => v,
                })
                .collect();
            let count = |theta: &[f64]| theta.iter().zip(&x).map(|(t, x)| t * x).sum::<f64>().clamp(-30.0, 30.0).exp();
            // Nothing known of the scene beyond its features (no crossings, no probe): the prior's laws, where the
            // file has them.
            let (bc, pc) = sm.prior.as_ref().map_or((&sm.box_coef, &sm.prim_coef), |p| (&p.box_coef, &p.prim_coef));
            let (bx, pr) = (count(bc), count(pc));
            let price = |name: &str| sm.trace_price[model.price_names.iter().position(|p| p == name).unwrap()];
            let ray = match w.kind {
                WorkloadKind::Primary => price("ray_primary"),
                WorkloadKind::Shadow => price("ray_shadow"),
                WorkloadKind::Diffuse => price("ray_diffuse"),
            };
            let mut ns = ray + price("box") * bx + price("prim") * pr;
            if w.kind != WorkloadKind::Primary {
                ns += price("box_incoherent") * bx + price("prim_incoherent") * pr;
                ns += price("test_incoherent_log") * (bx + pr) * (1.0 + bx + pr).ln();
            }
            if w.kind == WorkloadKind::Diffuse {
                ns += price("test_diffuse") * (bx + pr);
            }
            let build = plain_build(sm, n);
            let total = w.builds as f64 * build + (w.frames * w.rays_per_frame) as f64 * ns * 1e-6;
            (sm.structure, w.builds as f64 * build, total)
        })
        .collect()
}

/// The module docs' plain build law written out again: `exp(a) n^b exp(d q)`, `q` = `(ln n - 10)^2` over the
/// fitted sizes and along its tangent beyond them.
pub(super) fn plain_build(sm: &StructureModel, n: f64) -> f64 {
    let q = match sm.build_ln_n_range[..] {
        [lo, hi] => {
            let x = n.ln();
            let edge = x.clamp(lo, hi);
            (edge - 10.0).powi(2) + 2.0 * (edge - 10.0) * (x - edge)
        }
        _ => 0.0,
    };
    sm.build_ln_a.exp() * n.powf(sm.build_exponent) * (sm.build_curvature * q).exp()
}

/// The selection rule of the docs, on reference totals: the smallest total; within `margin` of it, the cheapest
/// build.
fn reference_choice(totals: &[(StructureName, f64, f64)], margin: f64) -> StructureName {
    let best = totals.iter().map(|t| t.2).fold(f64::INFINITY, f64::min);
    let mut near: Vec<_> = totals.iter().filter(|t| t.2 <= best * (1.0 + margin)).collect();
    near.sort_by(|a, b| a.1.total_cmp(&b.1));
    near[0].0
}

#[test]
fn the_calibrated_policy_picks_the_cheapest_prediction() {
    let mesh = generate::clustered(3000, 4, 5);
    let params = Params::default();
    let chars = vec![cpu::fast(&mesh, &params).unwrap()];
    let feats = vec![features_cpu(&mesh, &params).unwrap()];
    let summary = SceneSummary::new("clustered", &chars).with_features(&feats);
    let mut chosen = Vec::new();
    for (kind, rays) in [(WorkloadKind::Primary, 1u64 << 20), (WorkloadKind::Shadow, 1000), (WorkloadKind::Diffuse, 1)]
    {
        for margin in [0.0, 0.05, 0.5] {
            let mut policy = CalibratedPolicy::new(CostModel::shipped().unwrap(), kind, rays, 7);
            policy.tie_margin = margin;
            let w = Workload { kind, rays_per_frame: rays, frames: 7, builds: 1, view: None };
            assert_eq!(policy.workload(1), w);
            let want = reference_totals(&policy.model, &feats[0], &w);
            let preds = policy.predictions(&summary).unwrap();
            assert_eq!(preds.len(), 6);
            for (p, (s, build, total)) in preds.iter().zip(&want) {
                assert_eq!(p.structure, *s);
                assert!((p.build_ms - build).abs() <= 1e-12 * build, "{s} {kind:?}: build {} vs {build}", p.build_ms);
                assert!((p.total_ms - total).abs() <= 1e-12 * total, "{s} {kind:?}: total {} vs {total}", p.total_ms);
            }
            let expect = reference_choice(&want, margin);
            let sel = policy.select(&summary);
            assert_eq!(sel.structure.name(), expect.as_str(), "{kind:?} x {rays}, margin {margin}: {want:?}");
            chosen.push(expect);
            // One reason per structure with its numbers, plus the verdict and the margin to the next structure.
            assert_eq!(sel.reasons.len(), 8, "{:?}", sel.reasons);
            assert!(sel.reasons.iter().any(|r| r.text.starts_with(&format!("{expect}: predicted build"))));
            let chosen_total = want.iter().find(|t| t.0 == expect).unwrap().2;
            let next = want.iter().filter(|t| t.0 != expect).min_by(|a, b| a.2.total_cmp(&b.2)).unwrap();
            let margin_line = format!(
                "margin: the next, {}, is predicted {:.2}x the {expect}'s total",
                next.0,
                next.2 / chosen_total
            );
            assert!(sel.reasons[1].text.starts_with(&margin_line), "{margin_line} in {:?}", sel.reasons);
            let errors = [expect, next.0].map(|s| policy.model.get(s).unwrap().fit.total);
            let close = (next.2 / chosen_total).ln().abs() < errors.iter().map(|e| e * e).sum::<f64>().sqrt();
            assert_eq!(sel.reasons[1].text.contains("a close call"), close, "{}", sel.reasons[1]);
            // The same, as typed data: the choice first, the margin second, one prediction per structure.
            assert_eq!(sel.reasons[0].kind, ReasonKind::Choice { structure: sel.structure });
            let ReasonKind::Margin { runner_up, ratio, close_call } = sel.reasons[1].kind else {
                panic!("no margin second: {:?}", sel.reasons[1])
            };
            assert_eq!((runner_up, close_call), (next.0, close));
            assert!((ratio - next.2 / chosen_total).abs() <= 1e-12 * ratio, "{ratio}");
            let predicted: Vec<_> = sel
                .reasons
                .iter()
                .filter_map(|r| match r.kind {
                    ReasonKind::Prediction { structure, total_ms } => Some((structure, total_ms)),
                    _ => None,
                })
                .collect();
            assert_eq!(predicted.len(), 6, "{:?}", sel.reasons);
            assert!(predicted.windows(2).all(|w| w[0].1 <= w[1].1), "not cheapest first: {predicted:?}");
            // The JSON holds the sentences, as before the reasons were typed.
            let json = serde_json::to_value(&sel).unwrap();
            let texts: Vec<&str> = sel.reasons.iter().map(|r| r.text.as_str()).collect();
            assert_eq!(json["reasons"], serde_json::json!(texts));
        }
    }
    chosen.sort();
    chosen.dedup();
    assert!(chosen.len() > 1, "the workloads and margins should not all select the same structure: {chosen:?}");
    // Without features the thesis policy decides, and says so.
    let bare = SceneSummary::new("clustered", &chars);
    let policy = CalibratedPolicy::new(CostModel::shipped().unwrap(), WorkloadKind::Primary, 1 << 20, 1);
    let sel = policy.select(&bare);
    assert!(sel.reasons[0].text.contains("thesis policy decides"));
    assert_eq!(sel.reasons[0].kind, ReasonKind::Fallback);
    assert!(sel.reasons[1..].iter().all(|r| matches!(r.kind, ReasonKind::Rule | ReasonKind::Excluded)));
}

#[test]
fn leave_one_out_scores_held_out_scenes() {
    // 10^3 to 10^9 rays per frame: few rays, the grid's cheaper build wins; many, the BVH's cheaper trace.
    let (mut samples, _) = known_samples_with_rays(24, |i| 10u64.pow(3 + (i % 7) as u32));
    // The baseline always says grid; the exact model knows better wherever grid is not the best.
    for s in samples.iter_mut() {
        s.baseline = Some(StructureName::Grid);
    }
    // By hand from the measured totals: the best of the two, and the grid's regret.
    let total = |s: &Sample, st| s.get(st).unwrap().total_ms;
    let (bvh, grid) = (StructureName::Bvh, StructureName::Grid);
    let best: Vec<StructureName> =
        samples.iter().map(|s| if total(s, bvh) < total(s, grid) { bvh } else { grid }).collect();
    let grid_regret: Vec<f64> =
        samples.iter().map(|s| total(s, grid) / total(s, bvh).min(total(s, grid)) - 1.0).collect();
    let grid_best = best.iter().filter(|&&b| b == grid).count();
    assert!(grid_best > 0 && grid_best < 24, "both structures are best somewhere: {best:?}");
    // Every sample is decided by more than 5%, far above the ridge fit's error (< 1%): nothing is a near tie.
    for s in &samples {
        let gap = (total(s, bvh) / total(s, grid)).ln().abs();
        assert!(gap > 0.05, "{}: bvh and grid within {gap}", s.scene);
    }
    let c = compare(&samples, 0.0, "test").unwrap();
    assert_eq!(c.rows.len(), 24);
    assert_eq!(c.baseline.scored, 24);
    assert_eq!(c.baseline.accuracy, grid_best as f64 / 24.0);
    let mean: f64 = grid_regret.iter().sum::<f64>() / 24.0;
    assert!(mean > 0.0);
    assert!((c.baseline.mean_regret - mean).abs() <= 1e-12 * mean, "{} vs {mean}", c.baseline.mean_regret);
    // Exact synthetic data and no near tie: every one of the 24 held-out selections is the best, so no regret.
    let held = &c.calibrated_held_out;
    assert_eq!((held.scored, held.accuracy, held.mean_regret), (24, 1.0, 0.0), "{held:?}");
    let ins = &c.calibrated_in_sample;
    assert_eq!((ins.scored, ins.accuracy, ins.mean_regret), (24, 1.0, 0.0), "{ins:?}");
    for (i, r) in c.rows.iter().enumerate() {
        assert_eq!(r.scene, samples[i].scene);
        assert_eq!(r.oracle_best, Some(best[i]), "{}", r.scene);
        assert_eq!(r.calibrated_held_out, Some(best[i]), "{}", r.scene);
        assert_eq!(r.calibrated_held_out_regret, Some(0.0), "{}", r.scene);
        let br = r.baseline_regret.unwrap();
        assert!(
            (br - grid_regret[i]).abs() <= 1e-12 * grid_regret[i].max(1.0),
            "{}: {br} vs {}",
            r.scene,
            grid_regret[i]
        );
    }
}

#[test]
fn oracle_records_parse_into_samples() {
    let rec = serde_json::json!({
        "mesh": "m.obj", "workload": "shadow", "rebuild": "per_frame", "frames": 3, "frames_measured": 3,
        "rays_per_frame": 1000, "selected": "bvh",
        "structures": [
            {"name": "bvh", "build_ms": 30.0, "trace_ms": 6.0, "total_ms": 36.0, "mrays_per_s": 0.5,
             "box_tests_per_ray": 10.0, "prim_tests_per_ray": 2.0, "valid": true, "hits_agree": true,
             "within_noise_of_best": false},
            {"name": "grid", "build_ms": 3.0, "trace_ms": 9.0, "total_ms": 12.0, "mrays_per_s": 0.25,
             "box_tests_per_ray": 5.0, "prim_tests_per_ray": 4.0, "valid": true, "hits_agree": true,
             "within_noise_of_best": true}
        ]
    });
    let f = features_cpu(&generate::single_triangle(), &Params::default()).unwrap();
    let s = OracleRecord::from_json(&rec).unwrap().sample(f, None);
    assert_eq!(
        s.workload,
        Workload { kind: WorkloadKind::Shadow, rays_per_frame: 1000, frames: 3, builds: 3, view: None }
    );
    assert_eq!(s.baseline, Some(StructureName::Bvh));
    let bvh = s.get(StructureName::Bvh).unwrap();
    assert_eq!(bvh.build_ms_per_build, 10.0);
    assert_eq!(bvh.trace_ns_per_ray, 2000.0);
    assert_eq!(s.best().unwrap().structure, StructureName::Grid);
    assert_eq!(s.regret(StructureName::Bvh), Some(2.0));
}

#[test]
fn refit_keeps_a_valid_tree_and_tracks_the_geometry() {
    let mesh = generate::clustered(2000, 3, 11);
    let anim = generate::explode(&mesh, 3, 4).unwrap();
    let mut tree = Lbvh::build(&anim.frames[0]).unwrap().into_tree();
    let sah0 = tree.sah_cost();
    tree.refit(&anim.frames[0]).unwrap();
    assert_eq!(tree.sah_cost(), sah0, "refitting to the same positions changes nothing");
    for frame in &anim.frames[1..] {
        tree.refit(frame).unwrap();
        tree.validate("refit").unwrap();
        // validate() checks every triangle record lies in its leaf's box and every child in its parent's.
        assert_ne!(tree.sah_cost(), sah0, "the boxes follow the moved geometry");
    }
    let other = generate::random_soup(10, 1);
    assert!(tree.refit(&other).is_err());
}

#[test]
fn the_baselines_are_scored_on_the_same_samples_by_workload_and_family() {
    use meshchar::cost::SIZE_FEATURES;
    use meshchar::eval::compare::{compare_baselines, family_of, workload_of};
    let (mut samples, _) = known_samples_with_rays(24, |i| 10u64.pow(3 + (i % 7) as u32));
    for (i, s) in samples.iter_mut().enumerate() {
        s.scene = format!("family:{}:1000:{i}", if i % 2 == 0 { "city" } else { "terrain" });
    }
    assert_eq!(family_of("family:city:1000:3"), "city");
    assert_eq!(family_of("bunny.obj"), "mesh");
    // A directory of frames is an animation wherever the command runs (the path need not exist from here).
    assert_eq!(family_of("../elsewhere/bart/kitchen"), "animation");
    assert_eq!(family_of("degenerate:fan:2000:1"), "mesh");
    assert_eq!(workload_of(&samples[1]), "shadow");
    let b = compare_baselines(&samples, 0.0, "test");
    let names: Vec<String> = b.policies.iter().map(|p| format!("{} {}", p.policy, p.holdout)).collect();
    assert_eq!(
        names,
        [
            "thesis recorded",
            "best_single hindsight",
            "size_only scene_out",
            "size_only family_out",
            "calibrated scene_out",
            "calibrated family_out",
            "calibrated_cv scene_out",
            "calibrated_cv family_out",
            "calibrated in_sample"
        ]
    );
    // The best single structure per workload, by hand: the one of least mean regret over that workload's samples.
    let (bvh, grid) = (StructureName::Bvh, StructureName::Grid);
    let single = b.get("best_single", "hindsight").unwrap();
    for kind in ["primary", "shadow", "diffuse"] {
        let of: Vec<&Sample> = samples.iter().filter(|s| s.workload.kind.as_str() == kind).collect();
        let mean = |st| of.iter().map(|s| s.regret(st).unwrap()).sum::<f64>() / of.len() as f64;
        let want = if mean(bvh) <= mean(grid) { bvh } else { grid };
        for (s, c) in samples.iter().zip(&single.choices) {
            if s.workload.kind.as_str() == kind {
                assert_eq!(*c, Some(want), "{kind}");
            }
        }
        let (_, sc) = single.by_workload.iter().find(|(k, _)| k == kind).unwrap();
        assert!((sc.mean_regret - mean(want)).abs() < 1e-12, "{kind}: {} vs {}", sc.mean_regret, mean(want));
    }
    // The thesis baseline is the recorded choice; the families are scored apart and together.
    assert!(b.get("thesis", "recorded").unwrap().choices.iter().all(|c| *c == Some(grid)));
    let cal = b.get("calibrated", "scene_out").unwrap();
    assert_eq!(
        cal.by_family.iter().map(|(k, s)| (k.as_str(), s.scored)).collect::<Vec<_>>(),
        [("city", 12), ("terrain", 12)]
    );
    assert_eq!((cal.overall.scored, cal.overall.mean_regret), (24, 0.0), "exact data: {:?}", cal.overall);
    // The size-only model sees no geometry: its test-count laws have zero geometric coefficients, and a change of
    // the geometric features alone changes none of its predictions.
    let m = CostModel::fit_size_only(&samples, "test", "size only").unwrap();
    let full = CostModel::fit(&samples, "test", "full").unwrap();
    for (sm, fm) in m.structures.iter().zip(&full.structures) {
        assert!(sm.box_coef[SIZE_FEATURES..].iter().chain(&sm.prim_coef[SIZE_FEATURES..]).all(|c| *c == 0.0));
        assert!(fm.box_coef[SIZE_FEATURES..].iter().any(|c| *c != 0.0), "the full model uses the geometry");
    }
    let mut other = samples[0].features.clone();
    other.size_histogram.rotate_left(3);
    other.occupied_cells.iter_mut().for_each(|c| *c = (*c / 2).max(1));
    let (p, q) = (m.predict(&samples[0].features, &samples[0].workload), m.predict(&other, &samples[0].workload));
    assert_eq!(p, q);
    // A selection that was not validly measured is counted as failed, not scored.
    samples[0].measured.iter_mut().for_each(|x| x.valid = x.structure != grid);
    let b = compare_baselines(&samples, 0.0, "test");
    let t = &b.get("thesis", "recorded").unwrap().overall;
    assert_eq!((t.scored, t.failed), (23, 1));
}

#[test]
fn view_features_tell_inside_from_outside_and_a_view_enters_only_a_model_fitted_with_views() {
    use glam::Vec3;
    use meshchar::cost::ViewFeatures;
    use meshchar::geom::Camera;
    let (lo, hi) = ([0.0f32; 3], [1.0f32; 3]);
    let b = meshchar::geom::Aabb { min: Vec3::ZERO, max: Vec3::ONE };
    // Framing: outside, about 1.05 / sin(22.5 deg) half-diagonals away, the box on part of the image.
    let framing = ViewFeatures::framing(lo, hi);
    assert!(!framing.eye_inside);
    assert!((framing.distance - 1.05 / (22.5f64.to_radians()).sin()).abs() < 1e-3, "{framing:?}");
    assert!(framing.coverage > 0.1 && framing.coverage < 1.0, "{framing:?}");
    assert_eq!(framing, ViewFeatures::of(&Camera::frame(&b), lo, hi));
    // Inside: every ray starts in the box.
    let inside = Camera::look_at(Vec3::splat(0.5), Vec3::new(1.0, 0.5, 0.5), Vec3::Y, 60.0).unwrap();
    let v = ViewFeatures::of(&inside, lo, hi);
    assert!(v.eye_inside && v.coverage == 1.0 && v.distance < 1e-6, "{v:?}");
    // Looking away: no ray enters; the coverage is floored.
    let away = Camera::look_at(Vec3::new(0.5, 0.5, 3.0), Vec3::new(0.5, 0.5, 6.0), Vec3::Y, 30.0).unwrap();
    let v = ViewFeatures::of(&away, lo, hi);
    assert!(!v.eye_inside && v.coverage == 1.0 / 1024.0, "{v:?}");
    assert!(v.row().iter().all(|x| x.is_finite()));
    // An empty box counts as the unit cube: finite features.
    assert!(ViewFeatures::of(&away, [1.0; 3], [0.0; 3]).row().iter().all(|x| x.is_finite()));

    // Samples where the eye inside halves the box tests of the grid and doubles the BVH's.
    let (mut samples, _) = known_samples_with_rays(48, |i| 10u64.pow(3 + (i % 5) as u32));
    for (i, s) in samples.iter_mut().enumerate() {
        let cam = if i % 2 == 0 { Camera::frame(&b) } else { inside };
        s.features.lo = lo;
        s.features.hi = hi;
        let v = ViewFeatures::of(&cam, lo, hi);
        s.workload.view = Some(v);
        for m in s.measured.iter_mut() {
            let k: f64 = match (v.eye_inside, m.structure) {
                (true, StructureName::Grid) => 0.5,
                (true, _) => 2.0,
                _ => 1.0,
            };
            m.box_tests_per_ray *= k;
        }
    }
    let m = CostModel::fit(&samples, "test", "views").unwrap();
    assert!(m.structures.iter().all(|s| s.view_box_coef.len() == 3 && s.view_prim_coef.len() == 3));
    let grid = m.get(StructureName::Grid).unwrap();
    let bvh = m.get(StructureName::Bvh).unwrap();
    // eye_inside's coefficient carries ln 0.5 and ln 2 (the other view features are constant within each group).
    let d = |s: &meshchar::cost::StructureModel, w: &Workload| {
        s.predict(&samples[0].features.derived(), samples[0].features.triangles, w).box_tests_per_ray
    };
    let w_out = Workload { view: Some(framing), ..samples[0].workload };
    let w_in = Workload { view: Some(ViewFeatures::of(&inside, lo, hi)), ..samples[0].workload };
    assert!((d(grid, &w_in) / d(grid, &w_out) - 0.5).abs() < 0.05, "{} {}", d(grid, &w_in), d(grid, &w_out));
    assert!((d(bvh, &w_in) / d(bvh, &w_out) - 2.0).abs() < 0.1, "{} {}", d(bvh, &w_in), d(bvh, &w_out));
    // Without a view, the prediction is the framing camera's.
    let none = Workload { view: None, ..samples[0].workload };
    assert_eq!(m.predict(&samples[0].features, &none), m.predict(&samples[0].features, &w_out));
    // The model round-trips through its file with the view coefficients.
    let back = CostModel::from_json(&m.to_json()).unwrap();
    assert_eq!(back.structures, m.structures);
    // Samples without views fit no view coefficient, and such a model (the shipped one too) ignores the camera.
    for s in samples.iter_mut() {
        s.workload.view = None;
    }
    let plain = CostModel::fit(&samples, "test", "no views").unwrap();
    assert!(plain.structures.iter().all(|s| s.view_box_coef.is_empty()));
    // Nor do samples that record the framing camera itself (as evaluate's records do since they carry the camera).
    let mut framed = samples.clone();
    for s in framed.iter_mut() {
        s.workload.view = Some(ViewFeatures::framing(s.features.lo, s.features.hi));
    }
    let framed = CostModel::fit(&framed, "test", "framing views").unwrap();
    assert_eq!(framed.structures, plain.structures);
    let shipped = CostModel::shipped().unwrap();
    for model in [&plain, &shipped] {
        assert_eq!(model.predict(&samples[0].features, &w_in), model.predict(&samples[0].features, &w_out));
    }
}

#[test]
fn a_static_sample_stands_for_more_frames_with_the_same_build_and_trace() {
    use meshchar::eval::compare::with_frames;
    let (mut samples, _) = known_samples(3);
    samples[2].workload.frames = 5;
    samples[2].workload.builds = 5;
    let out = with_frames(&samples, &[1, 10, 1000]);
    assert_eq!(out.len(), 2 * 3 + 1, "two static one-frame samples swept, the per-frame one kept once");
    for (k, f) in [1u64, 10, 1000].into_iter().enumerate() {
        let (a, d) = (&samples[0], &out[k]);
        assert_eq!((d.workload.frames, d.workload.builds), (f, 1));
        for (m, n) in a.measured.iter().zip(&d.measured) {
            let want = m.build_ms + f as f64 * m.trace_ms;
            assert!((n.total_ms - want).abs() <= 1e-12 * want, "{f}: {} vs {want}", n.total_ms);
            assert_eq!(n.trace_ns_per_ray, m.trace_ns_per_ray);
        }
    }
    assert_eq!(out[6], samples[2]);
}

#[test]
fn the_proxy_replaces_every_trace_by_counted_tests_times_the_prices() {
    use meshchar::eval::proxy::{agreement, proxied, TestPrices};
    let (samples, _) = known_samples(12);
    let prices = TestPrices { box_ns: 2.0, triangle_ns: 5.0, repeats: 1 };
    let p = proxied(&samples, &prices, 0.02);
    assert_eq!(p.len(), samples.len());
    for (s, q) in samples.iter().zip(&p) {
        let rays = s.workload.rays_per_frame as f64;
        for (m, n) in s.measured.iter().zip(&q.measured) {
            let ns = 2.0 * m.box_tests_per_ray + 5.0 * m.prim_tests_per_ray;
            assert_eq!(n.trace_ns_per_ray, ns);
            assert_eq!(n.trace_ms, ns * rays * 1e-6);
            assert_eq!(
                (n.build_ms, n.box_tests_per_ray, n.prim_tests_per_ray),
                (m.build_ms, m.box_tests_per_ray, m.prim_tests_per_ray)
            );
            assert_eq!(n.total_ms, m.build_ms + n.trace_ms);
        }
        // Within noise under the proxy: within 2% of the best total, the best included.
        let best = q.best().unwrap().total_ms;
        for n in &q.measured {
            assert_eq!(n.within_noise_of_best, n.total_ms <= best * 1.02, "{}", n.structure);
        }
    }
    // Samples compared with themselves agree exactly.
    let same = agreement(&samples, &samples);
    assert_eq!(
        (same.samples, same.same_best, same.best_within_noise, same.mean_regret_of_proxy_best),
        (12, 1.0, 1.0, 0.0)
    );
    assert!(
        same.trace_ratio.iter().all(|(_, n, med, rms)| *n == 12 && *med == 1.0 && *rms == 0.0),
        "{:?}",
        same.trace_ratio
    );
    let a = agreement(&samples, &p);
    assert_eq!(a.samples, 12);
    for (name, n, med, _) in &a.trace_ratio {
        assert_eq!(*n, 12, "{name}");
        assert!(med.is_finite() && *med > 0.0, "{name}: {med}");
    }
    // The proxy's best judged by the measurement: its regret is the measured regret of that structure.
    let expect: f64 =
        samples.iter().zip(&p).map(|(s, q)| s.regret(q.best().unwrap().structure).unwrap()).sum::<f64>() / 12.0;
    assert!((a.mean_regret_of_proxy_best - expect).abs() < 1e-12);
}

#[test]
fn the_proxy_prices_are_measured_positive_and_finite() {
    let p = meshchar::eval::proxy::TestPrices::measure(3);
    assert_eq!(p.repeats, 3);
    assert!(p.box_ns.is_finite() && p.box_ns > 0.0, "{p:?}");
    assert!(p.triangle_ns.is_finite() && p.triangle_ns > 0.0, "{p:?}");
    assert_eq!(p.ns_per_ray(2.0, 3.0), 2.0 * p.box_ns + 3.0 * p.triangle_ns);
}

#[test]
fn a_larger_ridge_shrinks_the_count_laws_and_a_bad_one_is_refused() {
    let (samples, _) = known_samples(40);
    let plain = CostModel::fit(&samples, "test", "synthetic").unwrap();
    let same = CostModel::fit_with_ridge(&samples, "test", "synthetic", meshchar::cost::RIDGE).unwrap();
    assert_eq!(plain.structures, same.structures);
    let norm = |m: &CostModel| -> f64 {
        m.structures.iter().map(|s| s.box_coef[1..].iter().chain(&s.prim_coef[1..]).map(|c| c * c).sum::<f64>()).sum()
    };
    let strong = CostModel::fit_with_ridge(&samples, "test", "synthetic", 100.0).unwrap();
    assert!(norm(&strong) < norm(&plain), "{} {}", norm(&strong), norm(&plain));
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        let e = CostModel::fit_with_ridge(&samples, "test", "synthetic", bad).unwrap_err().to_string();
        assert!(e.contains("ridge"), "{bad}: {e}");
    }
}
