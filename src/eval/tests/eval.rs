//! The oracle on small generated scenes: totals, best, regret, noise, JSON fields and refused configurations.

use glam::Vec3;
use meshchar::accel::StructureName;
use meshchar::eval::{evaluate_scene, Measurement, OracleConfig, Rebuild};
use meshchar::geom::WorkloadKind;
use meshchar::mesh::{Animation, Mesh};

fn scene(n: usize, shift: f32) -> Mesh {
    let tris: Vec<[Vec3; 3]> = (0..n)
        .map(|i| {
            let x = (i % 20) as f32 * 0.1 + shift;
            let z = (i / 20) as f32 * 0.1;
            [Vec3::new(x, 0.0, z), Vec3::new(x + 0.08, 0.02, z), Vec3::new(x, 0.05, z + 0.08)]
        })
        .collect();
    Mesh::from_triangles(format!("gen{shift}"), &tris).unwrap()
}

fn config(workload: WorkloadKind) -> OracleConfig {
    OracleConfig { workload, resolution: 24, repeats: 3, ..Default::default() }
}

#[test]
fn oracle_measures_every_structure_and_picks_the_least_total() {
    let anim = Animation::new("static", vec![scene(400, 0.0)]).unwrap();
    for w in [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
        let e = evaluate_scene(&anim, &config(w), None, &|_| {}).unwrap();
        assert_eq!(e.structures.len(), 6);
        assert_eq!(e.triangles, 400);
        assert!(e.rays_per_frame > 0, "{w:?}");
        for s in &e.structures {
            assert!(s.valid && s.hits_agree, "{w:?} {:?}: {:?}", s.name, s.error);
            // A build and a trace take time, and a repeat's total is its build plus its trace (one frame): the
            // totals lie between the sums of the smallest and of the largest builds and traces. A total that left
            // out the build or the trace falls below the lower sum.
            assert!(s.build_ms.min > 0.0 && s.trace_ms.min > 0.0, "{w:?} {:?}", s.name);
            let (lo, hi) = (s.build_ms.min + s.trace_ms.min, s.build_ms.max + s.trace_ms.max);
            for t in [s.total_ms.min, s.total_ms.median, s.total_ms.max] {
                assert!(lo <= t && t <= hi, "{w:?} {:?}: total {t} outside [{lo}, {hi}]", s.name);
            }
            assert_eq!(s.rays, e.rays_per_frame as u64, "{w:?} {:?}: one frame traced", s.name);
            assert!(s.box_tests_per_ray > 0.0);
            assert!(s.memory_bytes > 0);
        }
        // The best, by hand: the smallest median total (all six are valid and agree with the reference hits).
        let by_hand = e.structures.iter().min_by(|a, b| a.total_ms.median.total_cmp(&b.total_ms.median)).unwrap();
        assert_eq!(e.oracle_best, by_hand.name, "{w:?}");
        let bt = &by_hand.total_ms;
        // Within noise of the best: the two medians at most the sum of the two half-ranges apart.
        for s in &e.structures {
            let near = (s.total_ms.median - bt.median).abs() <= s.total_ms.spread + bt.spread;
            assert_eq!(s.within_noise_of_best, near, "{w:?} {:?}", s.name);
        }
        let near: Vec<StructureName> =
            e.structures.iter().filter(|s| s.within_noise_of_best).filter_map(|s| s.name).collect();
        assert_eq!(e.oracle_within_noise, near, "{w:?}");
        assert!(near.contains(&by_hand.name.unwrap()));
        // No selection given: no regret.
        assert_eq!((e.selected, e.regret), (None, None));
        let j = e.to_json();
        for k in ["mesh", "triangles", "selected", "oracle_best", "regret", "structures"] {
            assert!(j.get(k).is_some(), "{k}");
        }
        assert!(j["selected"].is_null() && j["regret"].is_null());
        let names: Vec<&str> =
            j["structures"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap()).collect();
        assert_eq!(names, ["bvh", "kdtree", "grid", "bih", "lbvh", "hlbvh"]);
        for s in j["structures"].as_array().unwrap() {
            for k in [
                "build_ms",
                "trace_ms",
                "mrays_per_s",
                "box_tests_per_ray",
                "prim_tests_per_ray",
                "memory_bytes",
                "sah_cost",
                "valid",
                "hits_agree",
            ] {
                assert!(s.get(k).is_some(), "{k}");
            }
        }
        assert!(j["structures"][2]["sah_cost"].is_null(), "the grid has no SAH cost");
    }
}

#[test]
fn regret_of_a_selection_is_its_total_over_the_best() {
    let anim = Animation::new("static", vec![scene(300, 0.0)]).unwrap();
    let e = evaluate_scene(&anim, &config(WorkloadKind::Primary), Some(StructureName::Grid), &|_| {}).unwrap();
    let best = e.get(e.oracle_best.unwrap()).unwrap().total_ms.median;
    let grid = e.get(StructureName::Grid).unwrap().total_ms.median;
    let r = e.regret.unwrap();
    assert!((r - (grid / best - 1.0)).abs() < 1e-12);
    // The best is the smallest median total, found here by hand; the regret is 0 exactly when the grid is it.
    let by_hand = e.structures.iter().min_by(|a, b| a.total_ms.median.total_cmp(&b.total_ms.median)).unwrap();
    assert_eq!(e.oracle_best, by_hand.name);
    assert_eq!(r == 0.0, grid == by_hand.total_ms.median, "regret {r}");
    assert_eq!(e.regret_within_noise, Some(e.get(StructureName::Grid).unwrap().within_noise_of_best));
    assert_eq!(e.to_json()["selected"], "grid");
}

/// The trace ms of one frame from a result's throughput (`mrays_per_s` = rays / median per-frame trace time):
/// independent of how the oracle scales the trace time to the run.
fn trace_ms_of_one_frame(s: &meshchar::eval::StructureResult) -> f64 {
    s.rays as f64 / (s.mrays_per_s * 1e3)
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * b.abs()
}

#[test]
fn static_totals_are_builds_plus_frames_times_the_trace() {
    // A static scene rendered F frames: traced once and counted F times; built once (B + F T) or every frame
    // (F B + F T).
    const F: usize = 10_000;
    let anim = Animation::new("static", vec![scene(2000, 0.0)]).unwrap();
    let mut c = config(WorkloadKind::Primary);
    c.structures = vec![StructureName::Bvh];
    c.frames = Some(F);
    let run = |c: &OracleConfig| {
        let e = evaluate_scene(&anim, c, None, &|_| {}).unwrap();
        assert_eq!((e.frames, e.frames_measured, e.rebuild), (F, 1, c.rebuild));
        assert_eq!(e.structures[0].rays, e.rays_per_frame as u64, "one frame traced");
        e.structures[0].clone()
    };
    // One repeat: the medians are the single samples, so the formulas hold exactly (up to rounding).
    c.repeats = 1;
    let once = run(&c);
    let t = trace_ms_of_one_frame(&once);
    assert!(close(once.trace_ms.median, F as f64 * t), "trace {} vs {F} x {t}", once.trace_ms.median);
    assert!(close(once.total_ms.median, once.build_ms.median + F as f64 * t), "{once:?}");
    c.rebuild = Rebuild::PerFrame;
    let every = run(&c);
    let t = trace_ms_of_one_frame(&every);
    assert!(close(every.trace_ms.median, F as f64 * t), "trace {} vs {F} x {t}", every.trace_ms.median);
    assert!(close(every.total_ms.median, every.build_ms.median + F as f64 * t), "{every:?}");
    // Five repeats: the medians of the scaled samples are the scaled medians, and the per-frame build is F builds
    // where building once is one: the ratio of the two runs' median builds is F, within timing noise (a factor of
    // 100 either way; building once counted F times, or per frame counted once, gives about 1).
    c.repeats = 5;
    c.rebuild = Rebuild::Once;
    let once = run(&c);
    assert!(close(once.trace_ms.median, F as f64 * trace_ms_of_one_frame(&once)));
    c.rebuild = Rebuild::PerFrame;
    let every = run(&c);
    assert!(close(every.trace_ms.median, F as f64 * trace_ms_of_one_frame(&every)));
    let ratio = every.build_ms.median / once.build_ms.median;
    assert!(
        ratio > F as f64 / 100.0 && ratio < F as f64 * 100.0,
        "per-frame / once build ratio {ratio}, expected ~{F}"
    );
    for s in [&once, &every] {
        let (lo, hi) = (s.build_ms.min + s.trace_ms.min, s.build_ms.max + s.trace_ms.max);
        assert!(lo <= s.total_ms.min && s.total_ms.max <= hi, "{s:?}");
    }
}

#[test]
fn animations_are_rebuilt_per_frame_and_refuse_building_once() {
    let anim = Animation::new("anim", vec![scene(200, 0.0), scene(200, 0.3), scene(200, 0.6)]).unwrap();
    let mut c = config(WorkloadKind::Primary);
    c.structures = vec![StructureName::Lbvh, StructureName::Grid];
    assert!(evaluate_scene(&anim, &c, None, &|_| {}).is_err(), "building once is refused for an animation");
    c.rebuild = Rebuild::PerFrame;
    c.frames = Some(2);
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    assert_eq!((e.frames_measured, e.frames), (2, 2));
    for s in &e.structures {
        assert!(s.valid && s.hits_agree);
        assert_eq!(s.rays as usize, 2 * 24 * 24);
    }
    let empty = Animation::new("none", vec![]).unwrap();
    assert!(evaluate_scene(&empty, &c, None, &|_| {}).is_err());
}

#[test]
fn noise_is_the_half_range_and_ties_overlap() {
    let a = Measurement::of(&[10.0, 12.0, 11.0]);
    assert_eq!((a.median, a.min, a.max, a.spread), (11.0, 10.0, 12.0, 1.0));
    let b = Measurement::of(&[12.5, 13.0, 12.0]);
    assert!(a.within_noise(&b));
    let c = Measurement::of(&[20.0, 20.5, 21.0]);
    assert!(!a.within_noise(&c));
    assert_eq!(Measurement::of(&[4.0, 2.0]).median, 3.0);
    assert_eq!(Measurement::of(&[]), Measurement::default());
}

#[test]
fn rays_that_all_miss_still_rank_the_structures_and_no_rays_name_no_best() {
    // At 1e30 the f32 ray-triangle test hits nothing (docs/failure-study.md): every primary ray is a miss, but each
    // still visits the nodes and cells on its way out, so the totals rank the structures.
    let soup = scene(200, 0.0);
    let huge = meshchar::mesh::generate::scaled(&soup, 1e30).expect("scaled");
    let anim = Animation { name: "huge".into(), frames: vec![huge] };
    let e = evaluate_scene(&anim, &config(WorkloadKind::Primary), Some(StructureName::Bvh), &|_| {}).expect("oracle");
    assert_eq!(e.reference_hits, 0);
    assert!(e.rays_per_frame > 0);
    let best = e.oracle_best.expect("misses rank the structures");
    let least =
        e.structures.iter().filter(|s| s.valid && s.hits_agree).map(|s| s.total_ms.median).fold(f64::MAX, f64::min);
    assert_eq!(e.structures.iter().find(|s| s.name == Some(best)).unwrap().total_ms.median, least);
    assert!(e.regret.is_some() && e.no_best_reason.is_none());
    let rec = e.record();
    assert!(rec.to_json_line().contains("\"reference_hits\":0"));
    assert!(!rec.to_json_line().contains("no_best_reason"));
    // Shadow rays start at the primary hits: there are none, so nothing is traced and only builds were timed.
    let e = evaluate_scene(&anim, &config(WorkloadKind::Shadow), Some(StructureName::Bvh), &|_| {}).expect("oracle");
    assert_eq!((e.rays_per_frame, e.reference_hits), (0, 0));
    assert_eq!(e.oracle_best, None);
    assert!(e.oracle_within_noise.is_empty() && e.oracle_cheapest_within_noise.is_none());
    assert_eq!((e.regret, e.regret_within_noise), (None, None));
    let why = e.no_best_reason.as_deref().expect("a reason");
    assert!(why.contains("no ray"), "{why}");
    assert_eq!(e.record().no_best_reason.as_deref(), Some(why));
    // The same soup at scale 1: hits, a best structure, no reason.
    let anim = Animation { name: "soup".into(), frames: vec![soup] };
    let e = evaluate_scene(&anim, &config(WorkloadKind::Primary), None, &|_| {}).expect("oracle");
    assert!(e.reference_hits > 0, "the soup is in view");
    assert!(e.oracle_best.is_some() && e.no_best_reason.is_none());
    assert!(!e.record().to_json_line().contains("no_best_reason"));
}

#[test]
fn a_structure_over_its_budget_is_reported_failed_and_the_others_are_measured() {
    // 3,000 near copies of one triangle: each fills half the grid's cells, far past the grid's reference budget.
    let mesh = super::budget::near_copies(3000);
    let anim = Animation::new("all_equal", vec![mesh]).unwrap();
    let config = OracleConfig { resolution: 16, repeats: 1, ..Default::default() };
    let e = evaluate_scene(&anim, &config, Some(StructureName::Grid), &|_| {}).unwrap();
    let grid = e.get(StructureName::Grid).unwrap();
    let err = grid.error.as_deref().unwrap_or_default();
    assert!(err.starts_with("grid: needs at least") && err.contains("over its budget of 33554432"), "{err}");
    assert!(!grid.valid && !grid.hits_agree && grid.rays == 0, "{err}");
    assert_eq!((grid.total_ms.median, grid.within_noise_of_best), (0.0, false));
    // The selection failed to build: no regret is claimed for it.
    assert_eq!((e.regret, e.regret_within_noise), (None, None));
    for s in e.structures.iter().filter(|s| s.name != Some(StructureName::Grid)) {
        assert!(s.valid && s.hits_agree && s.rays > 0, "{:?}: {:?}", s.name, s.error);
    }
    assert!(e.oracle_best.is_some_and(|b| b != StructureName::Grid), "{:?}", e.oracle_best);
    let j = e.to_json();
    let g = j["structures"].as_array().unwrap().iter().find(|s| s["name"] == "grid").unwrap();
    assert_eq!(g["error"].as_str(), Some(err));
    assert_eq!(g["valid"], false);
}

#[test]
fn a_structure_over_the_trace_budget_is_reported_failed_and_a_reference_over_it_fails_the_scene() {
    use meshchar::accel::build_structure;
    use meshchar::geom::Camera;
    use meshchar::trace::trace;
    use meshchar::trace::workload::{build_workload, mesh_bounds};
    // The fan of a polygon over three points: 1,000 copies of one triangle. The BVH and the grid keep one copy; the
    // LBVH and the HLBVH test them all on every ray that reaches them. At 32 x 32 rays the sample is every ray, so which
    // structures exceed the budget follows from their counts over all rays, computed here apart.
    let mesh = meshchar::mesh::generate::fan_polygon(3000);
    let budget = 64.0;
    let camera = Camera::frame(&mesh_bounds(&mesh));
    let reference = build_structure(StructureName::Bvh, &mesh).unwrap();
    let rays = build_workload(WorkloadKind::Primary, &mesh, &camera, 32, reference.as_ref());
    let anim = Animation::new("fan", vec![mesh.clone()]).unwrap();
    let config = OracleConfig { resolution: 32, repeats: 1, max_tests_per_ray: budget, ..Default::default() };
    let e = evaluate_scene(&anim, &config, None, &|_| {}).unwrap();
    let mut over = 0;
    for s in &e.structures {
        let name = s.name.unwrap();
        let Ok(accel) = build_structure(name, &mesh) else {
            assert!(s.error.as_deref().is_some_and(|e| e.contains("budget")), "{name}: {:?}", s.error);
            continue;
        };
        let c = trace(accel.as_ref(), &rays).counters;
        let per_ray = (c.box_tests + c.prim_tests) as f64 / rays.rays.len() as f64;
        let failed = s.error.as_deref().is_some_and(|e| e.contains("over the trace budget"));
        assert_eq!(failed, per_ray > budget, "{name}: {per_ray} tests per ray: {:?}", s.error);
        assert_eq!(s.valid, !failed, "{name}");
        over += usize::from(failed);
    }
    assert!(over >= 2, "only {over} structures over the budget");
    assert_eq!(e.oracle_best, Some(StructureName::Bvh));
    // A budget the reference itself exceeds: the scene fails, naming the reference.
    let tight = OracleConfig { max_tests_per_ray: 0.5, ..config };
    let err = evaluate_scene(&anim, &tight, None, &|_| {}).unwrap_err().to_string();
    assert!(err.contains("reference") && err.contains("over the trace budget"), "{err}");
}

#[test]
fn the_median_interval_uses_the_sign_test_order_statistics() {
    use meshchar::eval::oracle::median_ci95;
    let sorted = |n: usize| (1..=n).map(|i| i as f64).collect::<Vec<f64>>();
    // Below 6 samples no pair of order statistics covers the median with 95%.
    for n in 0..6 {
        assert_eq!(median_ci95(&sorted(n)), None, "n = {n}");
    }
    // 6 to 8: the extremes (2 * 0.5^n <= 0.05, and 2 * P(B <= 1) > 0.05).
    for n in 6..=8 {
        assert_eq!(median_ci95(&sorted(n)), Some([1.0, n as f64]), "n = {n}");
    }
    // Table values: n = 9: x(2), x(8); n = 20: x(6), x(15); n = 100: x(40), x(61).
    assert_eq!(median_ci95(&sorted(9)), Some([2.0, 8.0]));
    assert_eq!(median_ci95(&sorted(20)), Some([6.0, 15.0]));
    assert_eq!(median_ci95(&sorted(100)), Some([40.0, 61.0]));
    // Large counts do not underflow.
    let [lo, hi] = median_ci95(&sorted(2001)).unwrap();
    assert!(lo > 900.0 && hi < 1100.0 && lo < 1001.0 && hi > 1001.0, "{lo} {hi}");
    // With intervals, "within noise" is overlap, whatever the spreads.
    let a = Measurement::of(&[10.0, 10.1, 10.2, 10.3, 10.4, 10.5, 30.0]);
    let b = Measurement::of(&[10.6, 10.7, 10.8, 10.9, 11.0, 11.1, 1.0]);
    assert_eq!((a.ci95, b.ci95), (Some([10.0, 30.0]), Some([1.0, 11.1])));
    assert!(a.within_noise(&b));
    let c = Measurement::of(&[20.0, 20.1, 20.2, 20.3, 20.4, 20.5]);
    assert!(!a.within_noise(&Measurement::of(&[40.0, 40.0, 41.0, 41.0, 42.0, 42.0])));
    assert!(c.precise_to(0.02) && !c.precise_to(0.01));
    assert!(!Measurement::of(&[1.0, 1.0, 1.0]).precise_to(0.5), "no interval below 6 samples");
}

#[test]
fn the_precise_oracle_repeats_until_the_interval_is_narrow_or_the_cap() {
    let anim = Animation::new("static", vec![scene(300, 0.0)]).unwrap();
    let mut c = config(WorkloadKind::Primary);
    c.structures = vec![StructureName::Bvh, StructureName::Grid];
    // A target every interval meets: the fewest repeats that give an interval (6), not fewer.
    c.precision = Some(1e6);
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    assert_eq!(e.precision, Some(1e6));
    for s in &e.structures {
        assert_eq!(s.total_ms.samples, 6, "{:?}", s.name);
        assert_eq!(s.precision_met, Some(true));
        let [lo, hi] = s.total_ms.ci95.expect("an interval from 6 repeats");
        assert!(lo <= s.total_ms.median && s.total_ms.median <= hi);
    }
    // The record carries the interval, the repeats and the verdict, and reads back.
    let rec = meshchar::eval::record::OracleRecord::from_json_line(&e.record().to_json_line()).unwrap();
    assert_eq!(rec.precision, Some(1e6));
    for (r, s) in rec.structures.iter().zip(&e.structures) {
        assert_eq!(r.total_ms_ci95, s.total_ms.ci95);
        assert_eq!(r.repeats_measured, Some(6));
        assert_eq!(r.precision_met, Some(true));
    }
    // A target no timing meets: the cap, reported as not met; `repeats` is still the least.
    c.precision = Some(1e-12);
    c.max_repeats = 8;
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    for s in &e.structures {
        assert_eq!(s.total_ms.samples, 8, "{:?}", s.name);
        assert_eq!(s.precision_met, Some(false));
    }
    // A cap below `repeats` does not cut them.
    c.max_repeats = 2;
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    assert!(e.structures.iter().all(|s| s.total_ms.samples == 3 && s.precision_met == Some(false)));
    // Without a target: exactly `repeats`, no verdict.
    c.precision = None;
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    assert!(e.structures.iter().all(|s| s.total_ms.samples == 3 && s.precision_met.is_none()));
}

#[test]
fn the_precise_oracle_measures_every_structure_in_every_round_and_goes_on_while_its_time_allows() {
    let anim = Animation::new("static", vec![scene(300, 0.0)]).unwrap();
    let mut c = config(WorkloadKind::Primary);
    c.structures = StructureName::ALL.to_vec();
    // A real target: structures settle at different repeats on their own; in rounds every one is measured as
    // often as the last to settle (or the cap), so that drift over the record hits all of them alike.
    c.precision = Some(0.02);
    c.max_repeats = 30;
    for _ in 0..3 {
        let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
        let n = e.structures[0].total_ms.samples;
        assert!((6..=30).contains(&n), "{n}");
        for s in &e.structures {
            assert_eq!(s.total_ms.samples, n, "{:?}: every structure in every round", s.name);
        }
        // The rounds stop at the first where every interval met the target, or at the cap.
        let all_met = e.structures.iter().all(|s| s.precision_met == Some(true));
        assert!(all_met || n == 30, "stopped at {n} with a structure short of the target");
    }
    // A target no timing meets: `max_repeats` rounds without a time allowance; with an unbounded one, on to
    // `MAX_PRECISION_REPEATS`; with a finite one, past `max_repeats` only while the record's time allows.
    c.structures = vec![StructureName::Lbvh, StructureName::Bih];
    c.precision = Some(1e-12);
    c.max_repeats = 6;
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    assert!(e.structures.iter().all(|s| s.total_ms.samples == 6 && s.precision_met == Some(false)));
    // The record says how it was measured, and reads back the same.
    let rec = e.record();
    assert_eq!((rec.precision, rec.max_repeats, rec.precision_ms), (Some(1e-12), Some(6), Some(0.0)));
    assert_eq!(rec.rounds.as_deref(), Some(meshchar::eval::oracle::ROUNDS_EVERY_STRUCTURE));
    assert_eq!(meshchar::eval::OracleRecord::from_json_line(&rec.to_json_line()).unwrap(), rec);
    c.precision_ms = f64::INFINITY;
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    assert!(e.structures.iter().all(|s| s.total_ms.samples == meshchar::eval::oracle::MAX_PRECISION_REPEATS));
    let per_round: f64 = e.structures.iter().map(|s| s.total_ms.median).sum();
    // Generous against the noise of a busy machine: the first 6 rounds would have to sum to 200 median rounds.
    c.precision_ms = 200.0 * per_round;
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    let n = e.structures[0].total_ms.samples;
    assert!(n > 6 && n < meshchar::eval::oracle::MAX_PRECISION_REPEATS, "{n} rounds for about 200 rounds' time");
    assert!(e.structures.iter().all(|s| s.total_ms.samples == n));
    // Without a target the allowance is not read, and the record carries none of the target's fields.
    c.precision = None;
    let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    assert!(e.structures.iter().all(|s| s.total_ms.samples == 3));
    let line = e.record().to_json_line();
    for field in ["\"precision\"", "\"max_repeats\"", "\"precision_ms\"", "\"rounds\""] {
        assert!(!line.contains(field), "{field} in {line}");
    }
}

#[test]
fn the_precise_oracle_repeats_every_frame_of_an_animation_as_often_as_the_first() {
    let anim = Animation::new("anim", vec![scene(200, 0.0), scene(200, 0.3)]).unwrap();
    let mut c = config(WorkloadKind::Primary);
    c.structures = vec![StructureName::Lbvh, StructureName::Bih];
    c.rebuild = Rebuild::PerFrame;
    c.precision = Some(1e-12);
    c.max_repeats = 7;
    let lines = std::sync::Mutex::new(Vec::<String>::new());
    let e = evaluate_scene(&anim, &c, None, &|l| lines.lock().unwrap().push(l.to_string())).unwrap();
    let lines = lines.into_inner().unwrap();
    for s in &e.structures {
        let name = s.name.unwrap().as_str();
        assert_eq!(s.total_ms.samples, 7);
        for frame in ["frame 1/2", "frame 2/2"] {
            let runs = lines.iter().filter(|l| l.contains(frame) && l.ends_with(&format!(": {name}"))).count();
            assert_eq!(runs, 7, "{name} on {frame}");
        }
        assert!(s.valid && s.hits_agree);
    }
}

#[test]
fn a_record_keeps_its_camera_and_its_sample_reads_the_view_from_it() {
    use meshchar::cost::ViewFeatures;
    use meshchar::eval::record::{CameraRecord, OracleRecord};
    use meshchar::geom::Camera;
    let anim = Animation::new("static", vec![scene(300, 0.0)]).unwrap();
    let mut c = config(WorkloadKind::Primary);
    c.structures = vec![StructureName::Bvh, StructureName::Grid];
    let b = meshchar::trace::workload::mesh_bounds(&anim.frames[0]);
    let inside = Camera::look_at(b.center(), b.center() + Vec3::new(1.0, -0.2, 0.3), Vec3::Y, 70.0).unwrap();
    for (camera, want_inside) in [(None, false), (Some(inside), true)] {
        c.camera = camera;
        let e = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
        let used = camera.unwrap_or_else(|| Camera::frame(&b));
        let rec = OracleRecord::from_json_line(&e.record().to_json_line()).unwrap();
        assert_eq!(rec.camera, Some(CameraRecord::from(&used)));
        assert_eq!(rec.camera.unwrap().camera(), used);
        let f = meshchar::characterize::features_cpu(&anim.frames[0], &Default::default()).unwrap();
        let smp = rec.sample(f.clone(), None);
        let v = smp.workload.view.expect("a view from the recorded camera");
        assert_eq!(v, ViewFeatures::of(&used, f.lo, f.hi));
        assert_eq!(v.eye_inside, want_inside);
    }
}

#[test]
fn refit_candidates_build_frame_0_refit_the_rest_and_agree_with_the_reference() {
    use meshchar::eval::oracle::RefitCandidate;
    let anim = Animation::new("anim", vec![scene(200, 0.0), scene(200, 0.3), scene(200, 0.6)]).unwrap();
    let mut c = config(WorkloadKind::Primary);
    c.structures = vec![StructureName::Bvh, StructureName::Lbvh];
    c.rebuild = Rebuild::PerFrame;
    c.refit = RefitCandidate::ALL.to_vec();
    let lines = std::sync::Mutex::new(Vec::<String>::new());
    let e = evaluate_scene(&anim, &c, None, &|l| lines.lock().unwrap().push(l.to_string())).unwrap();
    let names: Vec<&str> = e.refit_structures.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["bvh_refit", "lbvh_refit"]);
    for r in &e.refit_structures {
        assert!(r.valid && r.hits_agree && r.error.is_none(), "{r:?}");
        assert_eq!(r.rays as usize, 3 * 24 * 24);
        assert_eq!((r.frame_update_ms.len(), r.frame_trace_ms.len()), (3, 3));
        assert!(r.build_ms > 0.0 && r.refit_ms > 0.0 && r.trace_ms > 0.0 && r.total_ms > 0.0, "{r:?}");
        // Frame 0's tree is the rebuilt structure's: the same SAH cost.
        let rebuilt = e.get(RefitCandidate::parse(&r.name).unwrap().structure()).unwrap();
        assert_eq!(r.sah_first_last.map(|s| s[0]), rebuilt.sah_cost, "{}", r.name);
        assert_eq!(RefitCandidate::parse(&r.name).map(|c| c.name()), Some(r.name.as_str()));
        // Every frame repeated `repeats` times.
        let runs = lines.lock().unwrap().iter().filter(|l| l.ends_with(&format!(": {}", r.name))).count();
        assert_eq!(runs, 3 * 3);
    }
    // The best of every candidate is named, and the records keep the refit results.
    let best = e.best_candidate.clone().expect("a best candidate");
    let all = ["bvh", "lbvh", "bvh_refit", "lbvh_refit"];
    assert!(all.contains(&best.as_str()), "{best}");
    let least = all.iter().filter_map(|n| e.candidate_total(n)).fold(f64::INFINITY, f64::min);
    assert_eq!(e.candidate_total(&best), Some(least));
    let rec = meshchar::eval::record::OracleRecord::from_json_line(&e.record().to_json_line()).unwrap();
    assert_eq!(rec.refit_structures, e.refit_structures);
    // A static scene has nothing to refit.
    let one = Animation::new("static", vec![scene(200, 0.0)]).unwrap();
    c.rebuild = Rebuild::Once;
    let e = evaluate_scene(&one, &c, None, &|_| {}).unwrap();
    assert!(e.refit_structures.is_empty() && e.best_candidate.is_none());
}

/// The secondary rays of a workload, estimated from a sample of the primary rays (what `characterize` tells the
/// calibrated policy for shadow and diffuse rays): with the whole image as the sample, the count of the rays the
/// oracle traces (its reference a BVH, the estimate's an LBVH: the same primary rays hit); with a quarter of the
/// rays (every second pixel each way), within a few percent of it where the image is not too sparse; primary rays
/// are the pixels; no triangle, no ray.
#[test]
fn the_secondary_rays_estimated_from_a_sample_of_the_primary_rays_count_the_workloads_own() {
    use meshchar::geom::Camera;
    use meshchar::mesh::families::{generate, Family};
    use meshchar::trace::views::View;
    use meshchar::trace::workload::{build_workload, estimate_secondary_rays, mesh_bounds};
    let meshes = [
        generate(Family::Vegetation, 2000, 3).unwrap(),
        generate(Family::Interior, 2000, 3).unwrap(),
        generate(Family::Particles, 2000, 3).unwrap(),
        meshchar::mesh::generate::random_soup(1500, 5),
        meshchar::mesh::generate::long_thin(1000, 2),
        scene(300, 0.0),
    ];
    for m in &meshes {
        let b = mesh_bounds(m);
        let reference = meshchar::accel::build_structure(StructureName::Bvh, m).unwrap();
        for camera in [Camera::frame(&b), View::Inside.camera(&b), View::Grazing.camera(&b)] {
            for kind in [WorkloadKind::Shadow, WorkloadKind::Diffuse] {
                let res = 48;
                let want = build_workload(kind, m, &camera, res, reference.as_ref()).rays.len() as u64;
                let whole = estimate_secondary_rays(kind, m, &camera, res, 64).unwrap();
                assert_eq!((whole.side, whole.rays), (res, want), "{} {kind:?}", m.name);
                assert!(whole.ms >= 0.0 && whole.made == want);
                let half = estimate_secondary_rays(kind, m, &camera, res, res / 2).unwrap();
                assert_eq!(half.side, res / 2);
                let err = (half.rays as f64 - want as f64).abs();
                assert!(err <= 0.1 * want as f64 + 16.0, "{} {kind:?}: {} against {want}", m.name, half.rays);
            }
        }
    }
    let m = &meshes[0];
    let camera = Camera::frame(&mesh_bounds(m));
    let p = estimate_secondary_rays(WorkloadKind::Primary, m, &camera, 100, 8).unwrap();
    assert_eq!(p.rays, 10_000);
    let empty = Mesh::from_triangles("empty", &[]).unwrap();
    assert_eq!(estimate_secondary_rays(WorkloadKind::Shadow, &empty, &camera, 100, 8).unwrap().rays, 0);
    // Thousands of coincident triangles: every ray tests all of them; the trace budget refuses on a sample of the
    // rays before all of them are traced.
    let big = [Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)];
    let stack = Mesh::from_triangles("stack", &vec![big; 6000]).unwrap();
    let front = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 45.0).unwrap();
    match estimate_secondary_rays(WorkloadKind::Shadow, &stack, &front, 64, 64) {
        Err(meshchar::trace::workload::SecondaryEstimateError::OverBudget(why)) => {
            assert!(why.contains("over the trace budget"), "{why}")
        }
        other => panic!("{other:?}"),
    }
    // A sample side beyond the cap is capped (an empty mesh returns before allocating), and at least 1.
    let cap = meshchar::trace::workload::MAX_SECONDARY_SAMPLE_SIDE;
    assert_eq!(estimate_secondary_rays(WorkloadKind::Shadow, &empty, &camera, 100_000, u32::MAX).unwrap().side, cap);
    assert_eq!(estimate_secondary_rays(WorkloadKind::Shadow, m, &camera, 64, 0).unwrap().side, 1);
}

/// A record whose camera no rays can be made from (zero vectors, a zero or non-finite field of view) is refused
/// where records are read, naming the file, the line and the field; a real record's camera passes.
#[test]
fn records_with_a_camera_no_rays_can_come_from_are_refused() {
    use meshchar::eval::record::{parse_jsonl, RecordError};
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/data/families-seed2-primary.jsonl"))
        .expect("the shipped records");
    let line = text.lines().next().expect("a record");
    let good = parse_jsonl(line, "good.jsonl").expect("a real record");
    assert!(good[0].camera.is_some(), "the shipped record carries its camera");
    let mut v: serde_json::Value = serde_json::from_str(line).expect("JSON");
    let cases: [(&str, serde_json::Value, &str); 4] = [
        ("forward", serde_json::json!([0.0, 0.0, 0.0]), "camera.forward"),
        ("up", serde_json::json!([0.0, 30.0, 0.0]), "camera.up"),
        ("tan_half_fov", serde_json::json!(0.0), "camera.tan_half_fov"),
        ("tan_half_fov", serde_json::json!(-1.0), "camera.tan_half_fov"),
    ];
    for (field, value, named) in cases {
        let keep = v["camera"][field].clone();
        v["camera"][field] = value;
        match parse_jsonl(&format!("\n{v}"), "bad.jsonl") {
            Err(RecordError::Parse { place, reason }) => {
                assert_eq!(place, "bad.jsonl:2");
                assert!(reason.contains(named), "{field}: {reason}");
            }
            other => panic!("{field}: expected a parse error, got {other:?}"),
        }
        v["camera"][field] = keep;
    }
    assert!(parse_jsonl(&v.to_string(), "restored.jsonl").is_ok());
}
