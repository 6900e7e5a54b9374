//! No catastrophe (`select::budget`): the grid's reference bound is never below the grid's actual references, the
//! bound follows the grid's own resolution rule, and no selection picks a structure whose build fails with
//! `OverBudget`, on the degenerate generators.

use meshchar::accel::grid::{grid_resolution, Grid, GridOptions};
use meshchar::accel::kdtree::{KdOptions, KdTree};
use meshchar::accel::{AccelError, AccelStructure, StructureName};
use meshchar::characterize::{cpu, features_cpu, Params};
use meshchar::cost::CostModel;
use meshchar::geom::{Aabb, WorkloadKind};
use meshchar::mesh::{generate, Mesh};
use meshchar::select::budget::{Bound, GridRule};
use meshchar::select::{
    select_for_scene, select_for_scene_within, Budget, BuildBounds, PolicyChoice, Structure, TargetWorkload,
};

/// The degenerate generators of the failure study, at sizes a test builds in well under a second (a grid over
/// 3000 copies of one triangle takes 44 s to fail at 2^22 references).
fn degenerate() -> Vec<Mesh> {
    vec![
        generate::lattice_with_diagonal(100, 400),
        generate::fan_polygon(900),
        generate::overlapping_large(3000, 1),
        generate::zero_area(3000, 2),
        generate::long_thin_triangle(),
        generate::teapot_in_stadium(3),
        generate::all_equal(300),
    ]
}

/// A budget and the builder options that enforce the same one: small enough that several generators exceed it.
fn tight() -> (Budget, GridOptions, KdOptions) {
    let budget = Budget { references_per_triangle: 64.0, min_references: 1 << 16, max_bytes: 4 << 30 };
    let grid = GridOptions { min_reference_budget: 1 << 16, ..GridOptions::default() };
    let kd = KdOptions { min_reference_budget: 1 << 16, ..KdOptions::default() };
    (budget, grid, kd)
}

fn grid_refs(mesh: &Mesh, o: &GridOptions) -> Result<usize, AccelError> {
    Grid::build_with(mesh, o).and_then(|g| g.validate()).map(|s| s.references)
}

fn kd_refs(mesh: &Mesh, o: &KdOptions) -> Result<usize, AccelError> {
    KdTree::build_with(mesh, o).and_then(|g| g.validate()).map(|s| s.references)
}

fn scene_box(mesh: &Mesh) -> Aabb {
    (0..mesh.triangle_count()).fold(Aabb::EMPTY, |b, i| b.union(&Aabb::of_triangle(&mesh.triangle(i))))
}

#[test]
fn the_resolution_rule_is_the_grids() {
    let mut meshes = degenerate();
    meshes.push(generate::random_soup(5000, 4));
    meshes.push(generate::flat(2000, 5));
    meshes.push(generate::single_triangle());
    for f in generate::Family::ALL {
        meshes.push(generate::generate(f, 4000, 6).expect("family"));
    }
    let o = GridOptions::default();
    for m in &meshes {
        let b = scene_box(m);
        let n = m.triangle_count();
        let (ours, theirs) = (GridRule::from(&o).resolution(&b, n), grid_resolution(&b, n, &o));
        assert_eq!(ours, theirs, "{}", m.name);
        assert_eq!(
            GridRule::default().resolution(&b, n),
            theirs,
            "{}: the default rule is the default options'",
            m.name
        );
        // (copies of one triangle exceed the grid's budget: no grid to compare with)
        if let Ok(built) = Grid::build(m) {
            assert_eq!(BuildBounds::of_mesh(m).expect("bounds").grid_resolution, built.resolution(), "{}", m.name);
        }
    }
}

#[test]
fn the_grid_bound_is_never_below_the_grids_references() {
    let big = GridOptions { min_reference_budget: 1 << 22, max_references_per_triangle: 1 << 20, ..Default::default() };
    let mut meshes = degenerate();
    meshes.push(generate::random_soup(5000, 4));
    for f in generate::Family::ALL {
        meshes.push(generate::generate(f, 4000, 6).expect("family"));
    }
    println!(
        "{:<40} {:>12} {:>12} {:>7} {:>12} {:>12}",
        "mesh", "grid bound", "grid actual", "ratio", "kd est.", "kd actual"
    );
    for m in &meshes {
        let b = BuildBounds::of_mesh(m).expect("bounds");
        assert_eq!(b.grid_bound, Bound::Upper);
        let f = features_cpu(m, &Params::default()).expect("features");
        let bf = BuildBounds::of_features(&f);
        // The bound from the features (complete here) is also an upper bound, and never tighter than the mesh's.
        assert!(bf.grid_references >= b.grid_references, "{}: features {bf:?} mesh {b:?}", m.name);
        match grid_refs(m, &big) {
            Ok(actual) => {
                let kd = kd_refs(m, &KdOptions { min_reference_budget: 1 << 22, ..Default::default() });
                let kd = kd.map_or_else(|e| format!("{e}"), |k| k.to_string());
                println!(
                    "{:<40} {:>12} {:>12} {:>7.2} {:>12} {:>12}",
                    m.name,
                    b.grid_references,
                    actual,
                    b.grid_references as f64 / actual.max(1) as f64,
                    b.kdtree_references,
                    kd
                );
                assert!(
                    b.grid_references >= actual as u64,
                    "{}: bound {} < actual {actual}",
                    m.name,
                    b.grid_references
                );
                assert!(bf.grid_references >= actual as u64, "{}: features bound below actual {actual}", m.name);
            }
            Err(AccelError::OverBudget { needed, .. }) => {
                println!("{:<40} {:>12} {:>12}", m.name, b.grid_references, format!(">{needed}"));
                assert!(b.grid_references >= needed as u64, "{}: bound {} < {needed}", m.name, b.grid_references);
            }
            Err(e) => panic!("{}: {e}", m.name),
        }
    }
}

#[test]
fn an_excluded_grid_is_one_whose_build_would_fail_and_a_kept_one_builds() {
    let (budget, grid, _) = tight();
    let mut failed = 0;
    for m in degenerate() {
        let b = BuildBounds::of_mesh(&m).expect("bounds");
        let out = budget.check(&b);
        let grid_out = out.iter().any(|e| e.structure == StructureName::Grid);
        match grid_refs(&m, &grid) {
            Ok(actual) => assert!(actual as u64 <= b.grid_references, "{}", m.name),
            Err(AccelError::OverBudget { .. }) => {
                failed += 1;
                assert!(grid_out, "{}: the build fails, the budget keeps it ({b:?})", m.name);
            }
            Err(e) => panic!("{}: {e}", m.name),
        }
        if !grid_out {
            assert!(grid_refs(&m, &grid).is_ok(), "{}: kept but does not build", m.name);
        }
    }
    assert!(failed >= 2, "the tight budget should make some grid builds fail ({failed})");
}

fn workload() -> TargetWorkload {
    TargetWorkload {
        kind: WorkloadKind::Primary,
        rays_per_frame: 256 * 256,
        frames: 1,
        animation_frames: None,
        driver: false,
        camera: None,
    }
}

#[test]
fn no_selection_fails_its_build_over_budget() {
    let (budget, grid_o, kd_o) = tight();
    let model = CostModel::shipped().expect("shipped model");
    let policies = [PolicyChoice::Thesis, PolicyChoice::Calibrated { model: &model, tie_margin: 0.05 }];
    let mut excluded = 0;
    for m in degenerate() {
        let params = Params::default();
        let c = cpu::fast(&m, &params).expect("characterization");
        let f = features_cpu(&m, &params).expect("features");
        let (frames, features) = (std::slice::from_ref(&c), std::slice::from_ref(&f));
        let bounds = BuildBounds::of_mesh(&m).expect("bounds");
        for policy in policies {
            for (how, sel) in [
                (
                    "mesh bounds",
                    select_for_scene_within(
                        &m.name,
                        frames,
                        features,
                        policy,
                        &workload(),
                        Some(bounds.clone()),
                        budget,
                    ),
                ),
                (
                    "feature bounds",
                    select_for_scene_within(&m.name, frames, features, policy, &workload(), None, budget),
                ),
            ] {
                let s = sel.selection.structure;
                excluded += sel.selection.excluded.len();
                assert!(
                    !sel.selection.excluded.iter().any(|e| e.structure == s),
                    "{} ({}, {how}): selected an excluded {s}",
                    m.name,
                    policy.name()
                );
                for e in &sel.selection.excluded {
                    assert!(e.needed > e.budget, "{e:?}");
                    assert!(
                        sel.selection.reasons.iter().any(|r| r.contains(&e.reason)),
                        "{}: reason not given",
                        m.name
                    );
                }
                let built = match s {
                    Structure::Grid => grid_refs(&m, &grid_o).map(|_| ()),
                    Structure::KdTree => kd_refs(&m, &kd_o).map(|_| ()),
                    other => meshchar::accel::build_structure(other, &m).map(|_| ()),
                };
                assert!(
                    !matches!(built, Err(AccelError::OverBudget { .. })),
                    "{} ({}, {how}): selected {s}, whose build fails: {built:?}",
                    m.name,
                    policy.name()
                );
            }
        }
        // With the default budget and builders as well.
        for policy in policies {
            let sel = select_for_scene(&m.name, frames, features, policy, &workload());
            let s = sel.selection.structure;
            let built = meshchar::accel::build_structure(s, &m);
            assert!(!matches!(built, Err(AccelError::OverBudget { .. })), "{}: default {s} fails", m.name);
        }
    }
    assert!(excluded > 0, "the tight budget excluded nothing");
}

#[test]
fn the_report_lists_the_exclusions() {
    let m = generate::all_equal(30_000);
    let params = Params::default();
    let c = cpu::fast(&m, &params).expect("characterization");
    let f = features_cpu(&m, &params).expect("features");
    let sel = select_for_scene(
        &m.name,
        std::slice::from_ref(&c),
        std::slice::from_ref(&f),
        PolicyChoice::Thesis,
        &workload(),
    );
    assert!(sel.selection.excluded.iter().any(|e| e.structure == Structure::Grid), "{:?}", sel.selection);
    let r = meshchar::select::Report::new(&m.name, &c).selection(sel.kind, sel.policy, &sel.selection);
    let v: serde_json::Value = serde_json::from_str(&r.to_json()).expect("json");
    let ex = v["excluded"].as_array().expect("excluded array");
    assert_eq!(ex[0]["structure"], "grid");
    assert_eq!(ex[0]["what"], "references");
    assert!(ex[0]["needed"].as_u64() > ex[0]["budget"].as_u64());
    assert!(v.get("reasons").is_some() && v.get("selected").is_some());
    assert!(r.to_text().contains("excluded"));
}

/// The bounds of an animation are the largest over its frames; no frame, no bounds.
#[test]
fn bounds_of_frames_are_the_largest_frame_bounds() {
    let a = generate::fan_polygon(300);
    let b = generate::random_soup(2000, 3);
    let both = meshchar::select::BuildBounds::of_frames(&[a.clone(), b.clone()]).unwrap().unwrap();
    let want =
        meshchar::select::BuildBounds::of_mesh(&a).unwrap().max(&meshchar::select::BuildBounds::of_mesh(&b).unwrap());
    assert_eq!(both, want);
    assert!(both.grid_references >= meshchar::select::BuildBounds::of_mesh(&a).unwrap().grid_references);
    assert_eq!(meshchar::select::BuildBounds::of_frames(&[]).unwrap(), None);
}

#[test]
fn the_decision_cost_is_weighed_against_the_chosen_frame() {
    use meshchar::select::SelectionCost;
    let p = meshchar::cost::Prediction {
        structure: meshchar::accel::StructureName::Bvh,
        build_ms_per_build: 10.0,
        build_ms: 10.0,
        box_tests_per_ray: 1.0,
        prim_tests_per_ray: 1.0,
        trace_ns_per_ray: 1.0,
        trace_ms: 990.0,
        total_ms: 1000.0,
    };
    // A static scene over 10 frames: 100 ms a frame; a decision of 0.5 + 0.4 ms is 0.9% of it.
    let c = SelectionCost::new(0.5, 0.4, 1, Some(&p), 10);
    assert_eq!(c.predicted_frame_ms, Some(100.0));
    assert!((c.share.unwrap() - 0.009).abs() < 1e-12 && c.within_goal == Some(true), "{c:?}");
    // An animation of 4 frames, each characterized: the decision per frame is a quarter of the whole.
    let c = SelectionCost::new(8.0, 4.0, 4, Some(&p), 4);
    assert_eq!((c.per_frame_ms, c.predicted_frame_ms), (3.0, Some(250.0)));
    assert_eq!(c.within_goal, Some(false));
    // Without predictions (the thesis policy) there is nothing to weigh against.
    let c = SelectionCost::new(1.0, 1.0, 1, None, 1);
    assert_eq!((c.share, c.within_goal), (None, None));
}
