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
use meshchar::select::budget::{grid_count_threshold, Bound, GridRule};
use meshchar::select::{
    Budget, BuildBounds, Decision, Inquiry, Level, PolicyKind, Scene, Selector, Structure, TargetWorkload,
};

/// The selector's decision for the one-frame scene `m` under `policy`, `w`, `budget` and `inquiry`, the mesh handed
/// over with `with_mesh` (its bounds and probes then computed from it; without, the features' bounds alone), for
/// frames of `resolution` squared rays where a close call is measured; `max_ms` caps a fixed level's predicted cost.
#[allow(clippy::too_many_arguments)]
pub(super) fn decide(
    m: &Mesh,
    frames: &[meshchar::characterize::Characterization],
    features: &[meshchar::characterize::Features],
    model: &CostModel,
    policy: PolicyKind,
    w: TargetWorkload,
    inquiry: Inquiry,
    budget: Budget,
    with_mesh: bool,
) -> Decision {
    let mut s = Selector::new(model, w);
    s.policy = policy;
    s.budget = budget;
    s.inquiry = inquiry;
    s.resolution = 64;
    let meshes = std::slice::from_ref(m);
    s.select(&Scene {
        name: &m.name,
        characterizations: frames,
        features,
        meshes: if with_mesh { meshes } else { &[] },
    })
}

/// The prior's decision (features alone) and the count probes' (the mesh's bounds and probes).
const PRIOR: Inquiry = Inquiry::Fixed(Level::Prior);
pub(super) const COUNTED: Inquiry = Inquiry::Fixed(Level::Counted);

/// The degenerate generators of the failure study, at sizes a test builds in well under a second (a grid over
/// 3000 copies of one triangle takes 44 s to fail at 2^22 references).
/// `n` near copies of the unit triangle: triangle `i`'s third vertex at `y = 1 + i 2^-20`, so that no two share
/// their positions (which the grid and the kd-tree would store once) and each covers about as many grid cells.
pub(super) fn near_copies(n: usize) -> Mesh {
    let positions = (0..n).flat_map(|i| [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0 + i as f32 / 1_048_576.0, 0.0]]);
    let indices = (0..n as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
    Mesh::new(format!("near copies n={n}"), positions.collect(), indices).expect("mesh")
}

pub(super) fn degenerate() -> Vec<Mesh> {
    vec![
        near_copies(300),
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
pub(super) fn tight() -> (Budget, GridOptions, KdOptions) {
    let budget =
        Budget { references_per_triangle: 64.0, min_references: 1 << 16, ..Budget::BUILDERS }.same_for_the_grid();
    let grid = GridOptions { min_reference_budget: 1 << 16, ..GridOptions::default() };
    let kd = KdOptions { min_reference_budget: 1 << 16, ..KdOptions::default() };
    (budget, grid, kd)
}

pub(super) fn grid_refs(mesh: &Mesh, o: &GridOptions) -> Result<usize, AccelError> {
    Grid::build_with(mesh, o).and_then(|g| g.validate()).map(|s| s.references)
}

pub(super) fn kd_refs(mesh: &Mesh, o: &KdOptions) -> Result<usize, AccelError> {
    KdTree::build_with(mesh, o).and_then(|g| g.validate()).map(|s| s.references)
}

pub(super) fn scene_box(mesh: &Mesh) -> Aabb {
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
    let mut exact = 0;
    for m in &meshes {
        let b = BuildBounds::of_mesh(m).expect("bounds");
        // Exact where the slab bound exceeds the count threshold (and the count stays within the builders'
        // budget), an upper bound otherwise.
        assert_ne!(b.grid_bound, Bound::Estimate, "{}", m.name);
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
                if b.grid_bound == Bound::Exact {
                    exact += 1;
                    assert_eq!(b.grid_references, actual as u64, "{}: the exact count", m.name);
                } else {
                    assert!(
                        b.grid_references <= grid_count_threshold(m.triangle_count() as u64)
                            || b.grid_references > Budget::BUILDERS.references(m.triangle_count() as u64),
                        "{}: an upper bound {} where the count is exact below the builders' budget",
                        m.name,
                        b.grid_references
                    );
                }
                assert!(bf.grid_references >= actual as u64, "{}: features bound below actual {actual}", m.name);
            }
            Err(AccelError::OverBudget { needed, .. }) => {
                println!("{:<40} {:>12} {:>12}", m.name, b.grid_references, format!(">{needed}"));
                assert!(b.grid_references >= needed as u64, "{}: bound {} < {needed}", m.name, b.grid_references);
            }
            Err(e) => panic!("{}: {e}", m.name),
        }
    }
    println!("{exact} counted exactly");
}

#[test]
fn past_the_default_budget_the_grids_references_are_counted_exactly() {
    // 20,000 large overlapping triangles: a slab bound of about 39 million references, four times the grid's count.
    let m = generate::overlapping_large(20_000, 1);
    let b = BuildBounds::of_mesh(&m).expect("bounds");
    assert_eq!(b.grid_bound, Bound::Exact);
    assert_eq!(b.grid_references, grid_refs(&m, &GridOptions::default()).expect("grid") as u64);
    assert!(b.grid_references > grid_count_threshold(20_000), "{b:?}");
    // The default budget keeps the grid (within its builder's limit), whose build the policy prices by the count;
    // a budget with the kd-tree's limits for the grid too excludes it, saying the count is exact.
    assert_eq!(b.grid_build_work(), Some(b.grid_references as f64));
    assert!(Budget::default().check(&b).iter().all(|e| e.structure != StructureName::Grid), "{b:?}");
    let out = Budget::default().same_for_the_grid().check(&b);
    assert!(out.iter().any(|e| e.structure == StructureName::Grid && e.reason.contains("exactly")), "{out:?}");
    // A count that passes the grid builder's own budget stops there: an upper bound, at least what the builder
    // counts before it gives up (near copies of one triangle, each over half the cells).
    let m = near_copies(3000);
    let b = BuildBounds::of_mesh(&m).expect("bounds");
    assert_eq!(b.grid_bound, Bound::Upper);
    match grid_refs(&m, &GridOptions::default()) {
        Err(AccelError::OverBudget { needed, .. }) => assert!(b.grid_references >= needed as u64, "{b:?} {needed}"),
        other => panic!("the grid should exceed its builder's budget: {other:?}"),
    }
    assert!(b.grid_references > Budget::BUILDERS.references(3000), "{b:?}");
}

#[test]
fn the_grids_own_budget_holds_only_where_its_build_is_priced() {
    // 20,000 large overlapping triangles: 9.7 million references, past the count threshold, within the builder's.
    let m = generate::overlapping_large(20_000, 1);
    let exact = BuildBounds::of_mesh(&m).expect("bounds");
    let threshold = grid_count_threshold(20_000);
    assert!(exact.grid_build_work().is_some() && exact.grid_references > threshold, "{exact:?}");
    let grid_out = |out: Vec<meshchar::select::Exclusion>| out.into_iter().find(|e| e.structure == StructureName::Grid);
    // Counted exactly: the calibrated policy prices the build, the grid's own limit holds.
    assert_eq!(grid_out(Budget::default().check(&exact)), None);
    // A policy that prices no build (the thesis policy) holds the grid to the kd-tree's limits (by default the
    // threshold).
    let e = grid_out(Budget::default().check_unpriced(&exact)).expect("excluded unpriced");
    assert_eq!((e.needed, e.budget, e.bound), (exact.grid_references, threshold, Bound::Exact));
    let c = cpu::fast(&m, &Params::default()).expect("characterization");
    let f = features_cpu(&m, &Params::default()).expect("features");
    let (frames, features) = (std::slice::from_ref(&c), std::slice::from_ref(&f));
    let model = CostModel::shipped().expect("shipped model");
    let sel = decide(&m, frames, features, &model, PolicyKind::Thesis, workload(), COUNTED, Budget::default(), true);
    let out = &sel.selection.excluded;
    assert!(out.iter().any(|e| e.structure == StructureName::Grid), "{out:?}");
    // Bounds from the features alone are never priced: held to the kd-tree's limits too (the threshold, by default).
    let from_features = BuildBounds::of_features(&f);
    assert!(from_features.grid_build_work().is_none() && from_features.grid_references > threshold);
    let e = grid_out(Budget::default().check(&from_features)).expect("excluded from features");
    assert_eq!(e.budget, threshold);
    // A caller's grid limit below the threshold holds either way.
    let strict = Budget { grid_references_per_triangle: 1.0, grid_min_references: 1000, ..Budget::default() };
    assert_eq!(grid_out(strict.check(&exact)).map(|e| e.budget), Some(20_000));
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

pub(super) fn workload() -> TargetWorkload {
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
    let policies = [PolicyKind::Thesis, PolicyKind::Calibrated];
    let mut excluded = 0;
    for m in degenerate() {
        let params = Params::default();
        let c = cpu::fast(&m, &params).expect("characterization");
        let f = features_cpu(&m, &params).expect("features");
        let (frames, features) = (std::slice::from_ref(&c), std::slice::from_ref(&f));
        for policy in policies {
            for (how, sel) in [
                ("mesh bounds", decide(&m, frames, features, &model, policy, workload(), COUNTED, budget, true)),
                ("feature bounds", decide(&m, frames, features, &model, policy, workload(), PRIOR, budget, false)),
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
                        sel.selection.reasons.iter().any(|r| r.text.contains(&e.reason)),
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
            let sel = decide(&m, frames, features, &model, policy, workload(), Inquiry::Auto, Budget::default(), true);
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
    let model = CostModel::shipped().expect("shipped model");
    let (frames, features) = (std::slice::from_ref(&c), std::slice::from_ref(&f));
    let sel = decide(&m, frames, features, &model, PolicyKind::Thesis, workload(), PRIOR, Budget::default(), false);
    assert!(sel.selection.excluded.iter().any(|e| e.structure == Structure::Grid), "{:?}", sel.selection);
    let r = meshchar::select::Report::new(&m.name, &c).selection(sel.kind, sel.policy.name(), &sel.selection);
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
    // A static scene over 10 frames: 100 ms a frame; a decision of 0.5 + 0.4 ms, once per build, is 0.09 ms per
    // frame, 0.09% of it; over one frame of the same total it would be 0.09%, over 100 frames a tenth of that.
    let c = SelectionCost::new(0.5, 0.4, 1, Some(&p), 10);
    assert_eq!((c.predicted_frame_ms, c.counted), (Some(100.0), "once per build"));
    assert!((c.per_frame_ms - 0.09).abs() < 1e-12, "{c:?}");
    assert!((c.share.unwrap() - 0.0009).abs() < 1e-12 && c.within_goal == Some(true), "{c:?}");
    let p100 = meshchar::cost::Prediction { trace_ms: 9990.0, total_ms: 10000.0, ..p };
    let c100 = SelectionCost::new(0.5, 0.4, 1, Some(&p100), 100);
    assert!(c100.share.unwrap() < c.share.unwrap(), "{c100:?} {c:?}");
    // An animation of 4 frames, each characterized: the decision per frame is a quarter of the whole.
    let c = SelectionCost::new(8.0, 4.0, 4, Some(&p), 4);
    assert_eq!((c.per_frame_ms, c.predicted_frame_ms, c.counted), (3.0, Some(250.0), "per frame"));
    assert_eq!(c.within_goal, Some(false));
    // Without predictions (the thesis policy) there is nothing to weigh against.
    let c = SelectionCost::new(1.0, 1.0, 1, None, 1);
    assert_eq!((c.share, c.within_goal), (None, None));
}
