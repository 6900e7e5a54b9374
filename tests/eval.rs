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
            assert!(s.total_ms.median > 0.0 && s.build_ms.median >= 0.0);
            assert!(s.total_ms.min >= s.trace_ms.min && s.total_ms.max >= s.build_ms.min);
            assert!(s.box_tests_per_ray > 0.0);
            assert!(s.memory_bytes > 0);
        }
        let best = e.oracle_best.unwrap();
        let best_total = e.get(best).unwrap().total_ms.median;
        assert!(e.structures.iter().all(|s| s.total_ms.median >= best_total));
        assert!(e.get(best).unwrap().within_noise_of_best);
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
    assert!(r >= 0.0);
    assert_eq!(e.regret_within_noise, Some(e.get(StructureName::Grid).unwrap().within_noise_of_best));
    assert_eq!(e.to_json()["selected"], "grid");
}

#[test]
fn static_totals_add_build_and_trace_for_both_policies() {
    let anim = Animation::new("static", vec![scene(200, 0.0)]).unwrap();
    let mut c = config(WorkloadKind::Primary);
    c.structures = vec![StructureName::Bvh];
    c.frames = Some(10);
    c.repeats = 1;
    let once = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    let s = &once.structures[0];
    assert_eq!(once.frames, 10);
    assert!((s.total_ms.median - (s.build_ms.median + s.trace_ms.median)).abs() < 1e-9);
    c.rebuild = Rebuild::PerFrame;
    let every = evaluate_scene(&anim, &c, None, &|_| {}).unwrap();
    let s = &every.structures[0];
    assert!((s.total_ms.median - (s.build_ms.median + s.trace_ms.median)).abs() < 1e-9);
    assert_eq!(every.rebuild, Rebuild::PerFrame);
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
