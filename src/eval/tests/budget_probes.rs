//! The ladder's upper levels: count probes, timed probes, measured close calls, and the size rung below level 0.

use meshchar::accel::StructureName;
use meshchar::characterize::{cpu, features_cpu, Params};
use meshchar::cost::CostModel;
use meshchar::geom::{Aabb, Camera, WorkloadKind};
use meshchar::mesh::{generate, Mesh};
use meshchar::select::budget::{grid_count_threshold, Bound};
use meshchar::select::{
    Budget, BuildBounds, Decision, Inquiry, Level, PolicyKind, ReasonKind, Scene, Selection, Selector, Structure,
    TargetWorkload,
};

use super::budget::*;

/// The sentence of the first reason of `d` that starts with `prefix`.
fn reason_line<'a>(d: &'a Decision, prefix: &str) -> Option<&'a str> {
    d.selection.reasons.iter().map(|r| r.text.as_str()).find(|r| r.starts_with(prefix))
}

#[test]
fn a_probe_counts_the_structures_own_tests_on_its_sample() {
    // A probe builds the structure the oracle builds and traces the sample of `near_crossings`: on those primary
    // rays its means are the structure's own counts, exactly. Over a 128 x 128 workload of the same camera (and the
    // shadow and diffuse rays it starts, from the reference BVH's hits, with the workload's own seed) the structure's
    // counts lie within four standard errors of the probe's means (plus 2%): the sample stands for the workload.
    // Checked for each structure the policy probes.
    use meshchar::cost::overlap::NEAR_SAMPLES;
    use meshchar::cost::{near_sample_side, probe, PROBED};
    use meshchar::mesh::families::{generate as family, Family};
    use meshchar::trace::trace;
    use meshchar::trace::views::View;
    use meshchar::trace::workload::build_workload;
    assert_eq!(near_sample_side(1.0), NEAR_SAMPLES);
    assert!(near_sample_side(1e9) < NEAR_SAMPLES);
    let interior = family(Family::Interior, 2_000, 1).expect("family");
    let lattice = generate::lattice_with_diagonal(60, 20);
    let soup = generate::random_soup(2000, 3);
    let overlapping = generate::overlapping_large(2000, 1);
    let cases = [
        (View::Inside.camera(&scene_box(&interior)), interior),
        (Camera::frame(&scene_box(&lattice)), lattice),
        (Camera::frame(&scene_box(&soup)), soup),
        (Camera::frame(&scene_box(&overlapping)), overlapping),
    ];
    for ((cam, m), s) in cases.iter().flat_map(|c| PROBED.map(|s| (c, s))) {
        let sampled = probe(s, m, &scene_box(m), cam, NEAR_SAMPLES, true).expect("probe");
        // What the policy runs: the same primary counts, no secondary ray.
        let primary = probe(s, m, &scene_box(m), cam, NEAR_SAMPLES, false).expect("probe");
        assert_eq!(primary.primary, sampled.primary, "{} {s}", m.name);
        assert_eq!((primary.shadow.box_tests.rays, primary.diffuse.box_tests.rays), (0, 0), "{} {s}", m.name);
        let probe = sampled;
        let lbvh = meshchar::accel::build_structure(s, m).unwrap();
        let reference = meshchar::accel::build_structure(StructureName::Bvh, m).unwrap();
        let sample = build_workload(WorkloadKind::Primary, m, cam, NEAR_SAMPLES, reference.as_ref());
        let out = trace(lbvh.as_ref(), &sample);
        let n = sample.rays.len() as f64;
        assert_eq!(probe.primary.box_tests.rays, sample.rays.len(), "{} {s}", m.name);
        assert_eq!(probe.primary.box_tests.mean, out.counters.box_tests as f64 / n, "{} {s}", m.name);
        assert_eq!(probe.primary.prim_tests.mean, out.counters.prim_tests as f64 / n, "{} {s}", m.name);
        for kind in [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
            let rays = build_workload(kind, m, cam, 128, reference.as_ref());
            let out = trace(lbvh.as_ref(), &rays);
            let n = rays.rays.len().max(1) as f64;
            let p = probe.of_kind(kind);
            // (A sample of a few secondary rays, where few primary rays hit, stands for nothing.)
            if p.box_tests.rays < 30 {
                assert!(kind != WorkloadKind::Primary, "{}", m.name);
                continue;
            }
            for (what, sampled, full) in [
                ("box", p.box_tests, out.counters.box_tests as f64 / n),
                ("triangle", p.prim_tests, out.counters.prim_tests as f64 / n),
            ] {
                let off = (sampled.mean - full).abs();
                assert!(
                    off <= 4.0 * sampled.standard_error + 0.02 * full + 1e-9,
                    "{} {s} {kind:?} {what}: sampled {sampled:?}, {full} over {n} rays",
                    m.name
                );
            }
        }
    }
    // Nothing to trace: no probe for a zero-side sample, empty counts for a mesh without triangles.
    let (cam, m) = &cases[2];
    assert!(probe(StructureName::Lbvh, m, &scene_box(m), cam, 0, true).is_none());
    let empty = Mesh { name: "empty".into(), positions: Vec::new(), indices: Vec::new(), object_ids: None };
    let p = probe(StructureName::Lbvh, &empty, &Aabb::EMPTY, cam, 4, true).expect("an empty LBVH builds");
    assert_eq!((p.primary.box_tests.rays, p.primary.prim_tests.mean, p.shadow.box_tests.rays), (16, 0.0, 0));
}

#[test]
fn the_grid_is_probed_within_the_default_selection_budget() {
    // A probe never builds a grid past the count threshold, where the bound pass counts the references exactly
    // instead (and the policy prices the build by them): the probe's budget is that threshold, and the kd-tree's
    // default budget.
    let [per, least] = meshchar::cost::probe::PROBE_GRID_BUDGET;
    let b = Budget::default();
    assert_eq!((per as f64, least as u64), (b.references_per_triangle, b.min_references));
    assert_eq!(grid_count_threshold(20_000), b.references(20_000));
    // 20,000 large overlapping triangles need 9.8 million references (`docs/cost-model.md`): past the threshold,
    // counted exactly, no probe.
    let m = generate::overlapping_large(20_000, 1);
    let bounds = BuildBounds::of_mesh(&m).expect("bounds");
    assert_eq!(bounds.grid_bound, Bound::Exact, "{bounds:?}");
    let cam = Camera::frame(&scene_box(&m));
    assert!(meshchar::cost::probe(StructureName::Grid, &m, &scene_box(&m), &cam, 8, false).is_none());
    // The selection's bounds do not even try: the grid past the threshold has no probe, the hierarchies have theirs.
    let probes = |bounds: &BuildBounds, m: &Mesh| {
        let b = scene_box(m);
        let c = bounds.box_crossings.expect("crossings");
        let rc = c.for_workload(WorkloadKind::Primary, None, b.min.to_array(), b.max.to_array());
        (rc.probe(StructureName::Grid).is_some(), rc.probe(StructureName::Lbvh).is_some())
    };
    assert_eq!(probes(&bounds, &m), (false, true));
    // Within it, the grid is probed; under a caller's stricter budget that excludes it, it is not.
    let ok = generate::random_soup(2000, 3);
    let cam = Camera::frame(&scene_box(&ok));
    assert!(meshchar::cost::probe(StructureName::Grid, &ok, &scene_box(&ok), &cam, 8, false).is_some());
    assert_eq!(probes(&BuildBounds::of_mesh(&ok).expect("bounds"), &ok), (true, true));
    let strict = Budget { references_per_triangle: 0.5, min_references: 100, ..Budget::BUILDERS }.same_for_the_grid();
    let within = BuildBounds::of_frames_viewed_within(std::slice::from_ref(&ok), None, &strict)
        .expect("bounds")
        .expect("one frame");
    assert!(strict.check(&within).iter().any(|e| e.structure == StructureName::Grid));
    assert_eq!(probes(&within, &ok), (false, true));
}

#[test]
fn the_lbvhs_sampled_counts_hold_its_primary_prediction_in_their_band() {
    use meshchar::cost::{overlap_floor, ProbeCounts, RayCrossings, SampledMean, TestFloor};
    let probe = ProbeCounts {
        box_tests: SampledMean { mean: 100.0, standard_error: 1.0, rays: 1024 },
        prim_tests: SampledMean { mean: 10.0, standard_error: 0.5, rays: 1024 },
    };
    // The LBVH is the first probed structure (`PROBED`).
    assert_eq!(meshchar::cost::PROBED[0], StructureName::Lbvh);
    let probes = std::array::from_fn(|i| (i == 0).then_some(probe));
    let c = RayCrossings { all: 5.0, distinct: 5.0, nondegenerate: 5.0, probes, ..Default::default() };
    let without = RayCrossings { probes: Default::default(), ..c };
    let p = WorkloadKind::Primary;
    // The LBVH's own counts, for the kind of rays the crossings are of (`Crossings::for_workload` gives each kind
    // its own); every other structure's floor is unchanged.
    for k in [p, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
        assert_eq!(overlap_floor(&bounds(), StructureName::Lbvh, k, Some(c)).sampled, Some(probe), "{k:?}");
        assert_eq!(
            TestFloor { sampled: None, ..overlap_floor(&bounds(), StructureName::Lbvh, k, Some(c)) },
            overlap_floor(&bounds(), StructureName::Lbvh, k, Some(without))
        );
    }
    for s in StructureName::ALL.into_iter().filter(|s| *s != StructureName::Lbvh) {
        let (with, base) = (overlap_floor(&bounds(), s, p, Some(c)), overlap_floor(&bounds(), s, p, Some(without)));
        if s == StructureName::KdTree {
            // The kd-tree, which no probe counts, makes at least `KD_TREE_PRIM_FLOOR` of the fewest triangle tests
            // the probed hierarchies make (their lower bounds: the LBVH's 10 less two standard errors).
            let floor = bounds().kd_tree_prim_floor * probe.prim_tests.lower_bound();
            assert_eq!(with.prim_tests, base.prim_tests.max(floor), "{s}");
            assert!(with.prim_tests > base.prim_tests, "{with:?}");
            assert_eq!(TestFloor { prim_tests: base.prim_tests, ..with }, base, "{s}");
            // Not where some triangles have zero area (the kd-tree stores those as points).
            let degenerate = RayCrossings { nondegenerate: 4.0, ..c };
            let without_degenerate = RayCrossings { nondegenerate: 4.0, ..without };
            assert_eq!(
                overlap_floor(&bounds(), s, p, Some(degenerate)),
                overlap_floor(&bounds(), s, p, Some(without_degenerate))
            );
            // For secondary rays the probes' means count the rays that leave the scene at once, which test no
            // triangle; the floor bounds the others (the prediction applies it to them alone).
            for k in [WorkloadKind::Shadow, WorkloadKind::Diffuse] {
                let leaving = RayCrossings { leave_share: 0.5, ..c };
                let base = overlap_floor(&bounds(), s, k, Some(RayCrossings { leave_share: 0.5, ..without }));
                assert_eq!(
                    overlap_floor(&bounds(), s, k, Some(leaving)).prim_tests,
                    base.prim_tests.max(floor / 0.5),
                    "{k:?}"
                );
            }
        } else {
            assert_eq!(with, base, "{s}");
        }
    }
    // The prediction lands in the band, from whatever the laws say.
    let model = CostModel::shipped().expect("shipped model");
    let m = generate::random_soup(2000, 3);
    let f = features_cpu(&m, &Params::default()).expect("features");
    let w = meshchar::cost::Workload { kind: p, rays_per_frame: 65_536, frames: 1, builds: 1, view: None };
    let lbvh = |c: RayCrossings| {
        let preds = model.predict_floored(&f, &w, &|s| overlap_floor(&bounds(), s, p, Some(c)));
        preds.into_iter().find(|q| q.structure == StructureName::Lbvh).expect("lbvh")
    };
    let (held, free) = (lbvh(c), lbvh(without));
    assert!((98.0..=102.0).contains(&held.box_tests_per_ray), "{held:?}");
    assert!((9.0..=11.0).contains(&held.prim_tests_per_ray), "{held:?}");
    assert!(!(98.0..=102.0).contains(&free.box_tests_per_ray), "the law already predicted the band: {free:?}");
    // Within the law's own error band about the sampled mean (`PROBE_BAND` times its fit's RMS error of
    // `ln(1 + count)`) a device calibration keeps the law: a sample 1.2 times the law's counts (the shipped file's
    // LBVH errs by more than that: RMS 0.48 and 0.30) moves nothing there. A calibration traced on the CPU holds
    // the count to the sample all the same (`OWN_PROBE_BAND_CPU`: the probe traced the frame's own tree).
    let fit = model.get(StructureName::Lbvh).expect("lbvh law").fit;
    let band = meshchar::cost::PROBE_BAND;
    assert!(band * fit.box_tests > 1.2f64.ln() && band * fit.prim_tests > 1.2f64.ln(), "{fit:?}");
    assert_eq!(model.own_probe_band(), meshchar::cost::OWN_PROBE_BAND_CPU);
    let near = ProbeCounts {
        box_tests: SampledMean { mean: 1.2 * free.box_tests_per_ray, standard_error: 0.01, rays: 1024 },
        prim_tests: SampledMean { mean: 1.2 * free.prim_tests_per_ray, standard_error: 0.01, rays: 1024 },
    };
    let inside = RayCrossings { probes: std::array::from_fn(|i| (i == 0).then_some(near)), ..c };
    let held_near = lbvh(inside);
    let within_sample = |x: f64, m: SampledMean| (x - m.mean).abs() <= 2.0 * m.standard_error + 1e-9;
    assert!(within_sample(held_near.box_tests_per_ray, near.box_tests), "{held_near:?}");
    assert!(within_sample(held_near.prim_tests_per_ray, near.prim_tests), "{held_near:?}");
    let mut device = model.clone();
    device.trace_backend = meshchar::accel::device::TraceBackend::Vulkan;
    device.trace_device = Some(meshchar::accel::device::DeviceRecord { name: "a device".into(), ..Default::default() });
    assert_eq!(device.own_probe_band(), band);
    let on_device = |c: RayCrossings| {
        let preds = device.predict_floored(&f, &w, &|s| overlap_floor(&bounds(), s, p, Some(c)));
        preds.into_iter().find(|q| q.structure == StructureName::Lbvh).expect("lbvh")
    };
    let kept = on_device(inside);
    assert_eq!((kept.box_tests_per_ray, kept.prim_tests_per_ray), (free.box_tests_per_ray, free.prim_tests_per_ray));
    // Held, the LBVH's correction is shared by the hierarchy no probe counts (`SHARES_PROBES`: the kd-tree); the
    // grid, the BIH, the BVH and the HLBVH (probed structures, not probed in this sample) keep their laws. Within
    // the band nothing moves.
    let all = |c: RayCrossings| model.predict_floored(&f, &w, &|s| overlap_floor(&bounds(), s, p, Some(c)));
    let (rb, rp) = (held.box_tests_per_ray / free.box_tests_per_ray, held.prim_tests_per_ray / free.prim_tests_per_ray);
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
    let mut shared = 0;
    for ((h, fr), law) in all(c).iter().zip(&all(without)).zip(&laws(&model, &f, &w)) {
        if meshchar::cost::SHARES_PROBES.contains(&h.structure) {
            shared += 1;
            // The law corrected, then its own floor (the same as without the probe).
            let fl = overlap_floor(&bounds(), h.structure, p, Some(without));
            let (cb, cp) =
                ((law.box_tests_per_ray * rb).max(fl.box_tests), (law.prim_tests_per_ray * rp).max(fl.prim_tests));
            assert!(close(h.box_tests_per_ray, cb), "{h:?} {fr:?}");
            assert!(close(h.prim_tests_per_ray, cp), "{h:?} {fr:?}");
            assert!(h.box_tests_per_ray > fr.box_tests_per_ray, "{h:?} {fr:?}");
            assert_eq!(h.build_ms, fr.build_ms);
        } else if h.structure != StructureName::Lbvh {
            assert_eq!(h, fr);
        }
    }
    assert_eq!(shared, 1);
    // Within the band the correction is 1: only the LBVH's own counts move (to its sample, on the CPU).
    for (a, b) in all(inside).iter().zip(&all(without)) {
        if a.structure == StructureName::Lbvh {
            assert_eq!(
                (a.box_tests_per_ray, a.prim_tests_per_ray),
                (held_near.box_tests_per_ray, held_near.prim_tests_per_ray)
            );
        } else if a.structure == StructureName::KdTree {
            // The kd-tree's triangle tests are also floored by the probed hierarchies' fewest (`kd_tree_prim_floor`).
            assert_eq!(a.box_tests_per_ray, b.box_tests_per_ray);
            assert!(a.prim_tests_per_ray >= b.prim_tests_per_ray, "{a:?} {b:?}");
        } else {
            assert_eq!(a, b);
        }
    }
}

/// For a degenerate mesh seen by the framing camera, primary rays: per structure of `runaway`, its box tests per ray
/// as the shipped calibration predicts them with the probes (`Crossings::of_mesh`, `overlap_floor`) against its
/// count on 64 x 64 rays; and the calibrated policy's choice (with its reasons).
pub(super) fn probed_against_counted(
    m: &Mesh,
    runaway: &[StructureName],
) -> (Vec<(StructureName, f64, f64)>, Selection) {
    use meshchar::cost::{overlap_floor, Crossings};
    use meshchar::trace::trace;
    use meshchar::trace::workload::build_workload;
    let b = scene_box(m);
    let (lo, hi) = (b.min.to_array(), b.max.to_array());
    let c = Crossings::of_mesh(m).for_workload(WorkloadKind::Primary, None, lo, hi);
    let model = CostModel::shipped().expect("shipped model");
    let f = features_cpu(m, &Params::default()).expect("features");
    let w = meshchar::cost::Workload {
        kind: WorkloadKind::Primary,
        rays_per_frame: 65_536,
        frames: 1,
        builds: 1,
        view: None,
    };
    let preds = model.predict_floored(&f, &w, &|s| overlap_floor(&bounds(), s, WorkloadKind::Primary, Some(c)));
    let reference = meshchar::accel::build_structure(StructureName::Bvh, m).unwrap();
    let rays = build_workload(WorkloadKind::Primary, m, &Camera::frame(&b), 64, reference.as_ref());
    let counts = runaway
        .iter()
        .map(|&s| {
            assert!(c.probe(s).is_some(), "{s}: {c:?}");
            let predicted = preds.iter().find(|q| q.structure == s).expect("predicted").box_tests_per_ray;
            let accel = meshchar::accel::build_structure(s, m).unwrap();
            let counted = trace(accel.as_ref(), &rays).counters.box_tests as f64 / rays.rays.len() as f64;
            (s, predicted, counted)
        })
        .collect();
    let ch = cpu::fast(m, &Params::default()).expect("characterization");
    let (frames, features) = (std::slice::from_ref(&ch), std::slice::from_ref(&f));
    let sel = decide(m, frames, features, &model, PolicyKind::Calibrated, workload(), COUNTED, Budget::default(), true);
    (counts, sel.selection)
}

#[test]
fn on_the_lattice_with_a_diagonal_the_lbvhs_runaway_is_counted_not_predicted() {
    // The selection issue's lattice at 20,000 triangles (99 x 99 squares and 44 collinear zero-area triangles across
    // the diagonal, docs/data/degenerate-primary.jsonl): the diagonal triangles' boxes span the lattice and their
    // centroids scatter through the Morton order, so every LBVH node above one is as large as the lattice, and a
    // primary ray makes 146 box tests where the shipped laws said 15; the policy chose the LBVH at 2.3x the best
    // total. The probe counts it on the sample: the predicted count lies within 10% of the LBVH's on 64 x 64 rays,
    // and the policy picks another structure.
    let m = generate::lattice_with_diagonal(99, 44);
    let (counts, sel) = probed_against_counted(&m, &[StructureName::Lbvh]);
    for (s, predicted, counted) in counts {
        assert!(counted > 100.0, "{s}: {counted}");
        assert!((predicted / counted - 1.0).abs() < 0.1, "{s}: predicted {predicted}, counted {counted}");
    }
    assert_ne!(sel.structure, StructureName::Lbvh, "{:?}", sel.reasons);
}

#[test]
fn on_zero_area_triangles_the_bvhs_runaway_is_counted_not_predicted() {
    // 2,000 zero-area triangles (docs/data/degenerate-primary.jsonl): no ray can hit one, so every ray descends every
    // node its line crosses, and the binned-SAH BVH makes 171 box tests per primary ray where its law said 5; the
    // policy chose it at 5.7x the grid's total. The probes count it on the sample: each probed hierarchy's predicted
    // count lies within 20% of its count on 64 x 64 rays (the prediction is held at the edge of the sample's band,
    // two standard errors from its mean), and the policy picks none of them.
    // The grid, probed too, walks a few cells per ray (its count is held to its sample likewise), and is chosen.
    let m = generate::zero_area(2000, 1);
    let (counts, sel) = probed_against_counted(&m, &meshchar::cost::PROBED);
    for (s, predicted, counted) in counts {
        let runaway = s != StructureName::Grid;
        assert!(!runaway || counted > 100.0, "{s}: {counted}");
        assert!(runaway || counted < 20.0, "{s}: {counted}");
        assert!((predicted / counted - 1.0).abs() < 0.2, "{s}: predicted {predicted}, counted {counted}");
    }
    assert_eq!(sel.structure, StructureName::Grid, "{:?}", sel.reasons);
    // The shipped calibration prices the probed builds by their work, and the reasons say by how much: the grid's
    // work per triangle is its references per triangle.
    let grid = meshchar::accel::build_structure(StructureName::Grid, &m).expect("grid");
    let per = grid.build_work().expect("work") / m.triangle_count() as f64;
    let line =
        sel.reasons.iter().find(|r| r.text.starts_with("builds priced by the probes' work")).map(|r| r.text.as_str());
    assert!(line.is_some_and(|r| r.contains(&format!("grid {per:.1}"))), "{:?}", sel.reasons);
}

#[test]
fn a_sparse_view_is_probed_too_and_an_animation_is_not() {
    // A teapot in a stadium, framed: few triangle boxes cover a pixel, so the boxes-entered pass does not run, and the
    // probes trace their own 32 x 32 sample.
    let m = generate::generate(generate::Family::Stadium, 4000, 6).expect("stadium");
    let b = BuildBounds::of_mesh(&m).expect("bounds");
    let v = b.box_crossings.and_then(|c| c.view).expect("the framing view");
    assert!(v.all < meshchar::cost::Crossings::NEAR_FROM && v.near.is_none(), "{} {:?}", v.all, v.near);
    for p in v.probes {
        let p = p.expect("every probed structure builds");
        assert_eq!((p.primary.box_tests.rays, p.primary.prim_tests.rays), (1024, 1024));
        assert!(p.primary.box_tests.mean >= 1.0, "{p:?}");
        // A shadow and a diffuse ray from every hit (a shadow ray that starts at the light is not traced).
        assert!(p.diffuse.box_tests.rays > 0 && p.shadow.box_tests.rays <= p.diffuse.box_tests.rays, "{p:?}");
    }
    // An animation's first frame is not probed: the structures it would build are not the later frames'. (Checked
    // on the first frame's own crossings, before any merge of frames, which would drop probes anyway.)
    let first = meshchar::cost::Crossings::of_first_frame_viewed(&m, None, 2);
    let v = first.view.expect("the framing view");
    assert!(v.probes.iter().all(Option::is_none), "{:?}", v.probes);
    let single = meshchar::cost::Crossings::of_first_frame_viewed(&m, None, 1);
    assert!(single.view.expect("the framing view").probes.iter().all(Option::is_some));
}

/// The calibrated policy blends timed probes in only where it is given them and its model has their ratios, and says
/// so in its reasons either way.
#[test]
fn timed_probes_are_blended_into_a_static_scenes_predictions_when_the_model_has_ratios() {
    let model = CostModel::shipped().expect("shipped model");
    assert!(model.timed.is_some(), "the shipped CPU calibration has timed-probe ratios");
    let without_ratios = CostModel { timed: None, ..model.clone() };
    let m = generate::teapot_in_stadium(5);
    let params = Params::default();
    let c = cpu::fast(&m, &params).expect("characterization");
    let f = features_cpu(&m, &params).expect("features");
    let (frames, features) = (std::slice::from_ref(&c), std::slice::from_ref(&f));
    let budget = Budget::default();
    let bounds = BuildBounds::of_mesh(&m).expect("bounds");
    let timed = bounds.clone().with_timed_probes(&m, None, WorkloadKind::Primary, &StructureName::ALL, &budget);
    assert_eq!(timed.timed.len(), StructureName::ALL.len(), "every structure within the default budget: {timed:?}");
    assert!(timed.timed.iter().all(|p| p.build().is_some() && p.ns_per_ray(WorkloadKind::Primary).is_some()));
    // An animation's frames get none.
    let two = [m.clone(), m.clone()];
    let b = BuildBounds::of_frames_viewed_within(&two, None, &budget).expect("bounds").expect("some");
    assert!(b.timed.is_empty());
    let run = |model: &CostModel, policy: PolicyKind, level: Level, with_mesh: bool| {
        let w = workload();
        decide(&m, frames, features, model, policy, w, Inquiry::Fixed(level), budget, with_mesh)
    };
    let reason = |s: &Decision, what: &str| s.selection.reasons.iter().any(|r| r.text.contains(what));
    let plain = run(&model, PolicyKind::Calibrated, Level::Counted, true);
    let blended = run(&model, PolicyKind::Calibrated, Level::Timed, true);
    let unblended = run(&without_ratios, PolicyKind::Calibrated, Level::Timed, true);
    assert!(!reason(&plain, "timed probes"), "{:?}", plain.selection.reasons);
    assert!(reason(&blended, "timed probes (one build each"), "{:?}", blended.selection.reasons);
    assert_eq!(blended.level, Level::Timed);
    let decided = blended.selection.reasons.iter().find(|r| matches!(r.kind, ReasonKind::Decided { .. }));
    assert_eq!(decided.map(|r| r.kind), Some(ReasonKind::Decided { level: Level::Timed }), "{:?}", blended.selection);
    let taken = |s: &Decision, level: Level| {
        s.selection.reasons.iter().any(|r| r.kind == ReasonKind::Inquiry { level, taken: true })
    };
    assert!(taken(&blended, Level::Timed) && !taken(&plain, Level::Timed), "{:?}", plain.selection.reasons);
    let (p, b, u) =
        (plain.predicted.unwrap(), blended.predicted.clone().unwrap(), unblended.predicted.clone().unwrap());
    assert_eq!(p, u, "no ratios: the predictions are the model's");
    // The flow probes the contenders of the count probes' predictions only, and says which; those are blended.
    let only = meshchar::cost::timed::contenders(&p);
    assert!(!only.is_empty() && only.len() <= p.len());
    let line = reason_line(&blended, "timed probes (").expect("timed probes");
    for st in StructureName::ALL {
        assert_eq!(line.contains(&format!(" {st} ")), only.contains(&st), "{st}: {line}");
    }
    for (x, y) in p.iter().zip(&b) {
        assert_eq!(x.structure, y.structure);
        assert!(y.total_ms.is_finite() && y.total_ms > 0.0, "{y:?}");
        assert_eq!(only.contains(&x.structure), x.total_ms != y.total_ms, "{} blended: {x:?} {y:?}", x.structure);
        assert_eq!(x.box_tests_per_ray, y.box_tests_per_ray, "the counts are the model's");
    }
    // The model alone is deterministic.
    let again = run(&model, PolicyKind::Calibrated, Level::Counted, true);
    assert_eq!(again.selection.structure, plain.selection.structure);
    // With no mesh (nothing to probe with), the thesis policy, a calibration without ratios or an animation: no
    // timed probe, and a reason saying why.
    let none_taken = |s: &Decision, why: &str| {
        let r: Vec<&str> =
            s.selection.reasons.iter().map(|r| r.text.as_str()).filter(|r| r.starts_with("timed probes")).collect();
        assert!(r.len() == 1 && r[0].starts_with("timed probes: none taken: ") && r[0].contains(why), "{r:?}");
    };
    none_taken(&run(&model, PolicyKind::Calibrated, Level::Timed, false), "no mesh");
    none_taken(&run(&model, PolicyKind::Thesis, Level::Timed, true), "thesis");
    none_taken(&unblended, "no timed-probe ratios");
    let (two_c, two_f) = ([c.clone(), c.clone()], [f.clone(), f.clone()]);
    let mut sel = Selector::new(&model, workload());
    sel.inquiry = Inquiry::Fixed(Level::Timed);
    let anim = sel.select(&Scene { name: &m.name, characterizations: &two_c, features: &two_f, meshes: &two });
    none_taken(&anim, "animation");
}

/// The selector for a one-frame scene asked to measure its close call over frames of `resolution` squared rays,
/// within `max_ms` by the predictions.
#[allow(clippy::too_many_arguments)]
pub(super) fn measured(
    m: &Mesh,
    frames: &[meshchar::characterize::Characterization],
    features: &[meshchar::characterize::Features],
    model: &CostModel,
    policy: PolicyKind,
    w: TargetWorkload,
    resolution: u32,
    max_ms: f64,
) -> Decision {
    let mut s = Selector::new(model, w);
    s.policy = policy;
    s.inquiry = Inquiry::Fixed(Level::Measured);
    s.resolution = resolution;
    s.max_inquiry_ms = max_ms;
    s.select(&Scene { name: &m.name, characterizations: frames, features, meshes: std::slice::from_ref(m) })
}

/// A measured close call builds and traces the structures predicted within the margin of the least, and selects the
/// least measured; the model's predictions (without timed-probe ratios, so deterministic) decide whether there is a
/// close call, and a reason says what was measured or why nothing was.
#[test]
fn a_close_call_is_settled_by_measuring_whole_frames_of_its_structures() {
    use meshchar::cost::measured::{close_calls, MEASURED_REPEATS};
    let shipped = CostModel::shipped().expect("shipped model");
    // No ratios: no timed probe is blended, the predictions (and the close calls) are the model's.
    let model = CostModel { timed: None, ..shipped };
    let params = Params::default();
    let mut settled = 0;
    for family in meshchar::mesh::families::Family::ALL {
        let m = meshchar::mesh::families::generate(family, 2000, 1).expect("family scene");
        let c = cpu::fast(&m, &params).expect("characterization");
        let f = features_cpu(&m, &params).expect("features");
        let (frames, features) = (std::slice::from_ref(&c), std::slice::from_ref(&f));
        let run = |res: u32, max_ms: f64| {
            measured(&m, frames, features, &model, PolicyKind::Calibrated, workload(), res, max_ms)
        };
        let s = run(64, meshchar::cost::measured::DEFAULT_MAX_MS);
        let preds = s.predicted.clone().expect("predictions");
        let allowed: Vec<_> = preds
            .iter()
            .filter(|p| !s.selection.excluded.iter().any(|e| e.structure == p.structure))
            .copied()
            .collect();
        let close = close_calls(&allowed);
        let line = reason_line(&s, "measured close call").expect("a reason");
        if close.is_empty() {
            assert!(line.contains("none: no close call"), "{line}");
            assert!(s.measured.is_empty());
            assert_eq!(Some(s.selection.structure), meshchar::select::choose(&allowed, 0.05), "the model's choice");
            continue;
        }
        settled += 1;
        let mut got: Vec<_> = s.measured.iter().map(|t| t.structure).collect();
        let mut want = close.clone();
        got.sort();
        want.sort();
        assert_eq!(got, want, "{line}");
        // The workload's frames hold 256x256 rays, the measured ones 64x64: the traces are scaled by 16.
        assert!(line.contains("traces scaled by 16.000"), "{line}");
        for t in &s.measured {
            assert_eq!(t.repeats, MEASURED_REPEATS);
            assert_eq!(t.rays, 64 * 64, "whole primary frames at the given resolution");
            assert!(t.total_ms > 0.0 && t.total_ms.is_finite() && line.contains(&format!("{} ", t.structure)));
        }
        let least = s.measured.iter().min_by(|a, b| a.total_ms.total_cmp(&b.total_ms)).expect("measured");
        assert_eq!(s.selection.structure, least.structure, "the least measured is selected: {line}");
        assert_eq!(s.level, Level::Measured);
        // Over the measuring budget: nothing measured, the predictions' choice stands, and the reason says so.
        let capped = run(64, 1e-6);
        assert!(capped.measured.is_empty());
        let why = reason_line(&capped, "measured close call").expect("reason");
        assert!(why.starts_with("measured close call: none: measuring ") && why.contains("allowed"), "{why}");
        assert_eq!(Some(capped.selection.structure), meshchar::select::choose(&allowed, 0.05));
        // No rays, or more than a measured frame may hold: nothing measured.
        for (res, why) in [(0, "no rays (resolution 0)"), (4097, "4097x4097 rays per frame, over the")] {
            let s = run(res, 1e9);
            assert!(s.measured.is_empty());
            let r = reason_line(&s, "measured close call").expect("reason");
            assert!(r.starts_with(&format!("measured close call: none: {why}")), "{r}");
        }
        // The thesis policy and an animation measure nothing.
        let thesis = measured(&m, frames, features, &model, PolicyKind::Thesis, workload(), 64, 1e9);
        assert!(thesis.measured.is_empty());
        assert!(thesis.selection.reasons.iter().any(|r| r.text.starts_with("measured close call: none: the thesis")));
        let (two_c, two_f) = ([c.clone(), c.clone()], [f.clone(), f.clone()]);
        let mut sel = Selector::new(&model, workload());
        sel.inquiry = Inquiry::Fixed(Level::Measured);
        sel.resolution = 64;
        let two = [m.clone(), m.clone()];
        let anim = sel.select(&Scene { name: &m.name, characterizations: &two_c, features: &two_f, meshes: &two });
        assert!(anim.measured.is_empty());
        assert!(anim
            .selection
            .reasons
            .iter()
            .any(|r| r.text == "measured close call: none: the scene is an animation"));
    }
    assert!(settled > 0, "some family scene at 2K triangles is a close call for the shipped model");
}

/// A measured close call of shadow or diffuse rays: the frames measured trace the secondary rays the view's hits
/// start, and their traces are scaled to the workload's rays per frame over those (not over the image's pixels):
/// told the count the frame makes (`estimate_secondary_rays` over the whole image), nothing is scaled; told
/// twice as many, every trace is scaled by 2.
#[test]
fn a_measured_close_call_of_secondary_rays_scales_its_traces_by_the_rays_it_traced() {
    use meshchar::trace::workload::estimate_secondary_rays;
    let model = CostModel { timed: None, ..CostModel::shipped().expect("shipped model") };
    let params = Params::default();
    let (mut settled, mut doubled_settled) = (0, 0);
    for family in meshchar::mesh::families::Family::ALL {
        let m = meshchar::mesh::families::generate(family, 2000, 1).expect("family scene");
        let c = cpu::fast(&m, &params).expect("characterization");
        let f = features_cpu(&m, &params).expect("features");
        let b = meshchar::trace::workload::mesh_bounds(&m);
        for (view, kind) in meshchar::trace::views::View::ALL
            .into_iter()
            .flat_map(|v| [(v, WorkloadKind::Shadow), (v, WorkloadKind::Diffuse)])
        {
            let camera = view.camera(&b);
            let made = estimate_secondary_rays(kind, &m, &camera, 64, 64).expect("estimate").rays;
            let run = |rays_per_frame: u64| {
                let w = TargetWorkload { kind, rays_per_frame, camera: Some(camera), ..workload() };
                let (frames, features) = (std::slice::from_ref(&c), std::slice::from_ref(&f));
                measured(&m, frames, features, &model, PolicyKind::Calibrated, w, 64, 1e9)
            };
            let s = run(made);
            if s.measured.is_empty() || made == 0 {
                continue;
            }
            settled += 1;
            let line = reason_line(&s, "measured close call").expect("a reason");
            assert!(s.measured.iter().all(|t| t.rays as u64 == made), "{}: {line}", m.name);
            assert!(!line.contains("traces scaled"), "{}: {line}", m.name);
            let doubled = run(2 * made);
            if !doubled.measured.is_empty() {
                doubled_settled += 1;
                let line = reason_line(&doubled, "measured close call").expect("a reason");
                assert!(line.contains("traces scaled by 2.000"), "{}: {line}", m.name);
            }
        }
    }
    assert!(settled > 0, "some family scene at 2K triangles is a close call of secondary rays");
    assert!(doubled_settled > 0, "and one still is with twice the rays");
}

/// The shipped CPU calibration's overlap-floor factors.
pub(super) fn bounds() -> meshchar::cost::CountBounds {
    CostModel::shipped().expect("shipped model").count_bounds
}

/// The model's fitted count laws with no floor (a caller that knows the crossings, here none: not the prior's own
/// laws, which serve a caller that knows nothing beyond the features).
pub(super) fn laws(
    model: &CostModel,
    f: &meshchar::characterize::Features,
    w: &meshchar::cost::Workload,
) -> Vec<meshchar::cost::Prediction> {
    model.predict_floored(f, w, &|_| meshchar::cost::TestFloor { crossings: 0.0, ..Default::default() })
}

/// The size rung ([`Selector::size_rung`]): the triangle count alone decides where characterizing costs more than
/// it could gain or more than the decision budget allows, and the decision says so; where the size laws are far
/// less certain than level 0 and the frames many, characterizing pays and the ladder decides as before. A fixed
/// level and a known camera never take the rung.
#[test]
fn the_size_rung_characterizes_only_where_it_pays() {
    let mesh = generate::clustered(4000, 4, 3);
    let p = Params::default();
    let frames = [cpu::fast(&mesh, &p).unwrap()];
    let feats = [features_cpu(&mesh, &p).unwrap()];
    let n = mesh.triangle_count() as u64;
    let w = |frames: u64| TargetWorkload { frames, ..TargetWorkload::default() };
    let scene = Scene { name: "clustered", characterizations: &frames, features: &feats, meshes: &[] };
    let mut model = CostModel::shipped().unwrap();
    let s = Selector::new(&model, w(1));
    let r = s.size_rung(n).expect("the shipped file has size laws, their errors and the stage laws");
    let budgeted = matches!(r.structure, Some(Structure::Grid | Structure::KdTree));
    assert_eq!(r.characterize, budgeted || (r.gain_ms > r.cost_ms && r.cost_ms <= r.allowed_ms), "{r:?}");
    let d = s.select(&scene);
    assert_eq!(d.characterized, r.characterize);
    if !r.characterize {
        assert_eq!(Some(d.structure()), r.structure);
        assert!(d.selection.reasons[0].text.contains("on the triangle count alone"), "{:?}", d.selection.reasons);
        assert!(d.selection.reasons[1].text.starts_with("margin"), "{:?}", d.selection.reasons);
    }
    // Size laws far less certain than the features': worth knowing over a million frames, not over one (where the
    // characterization is over 1% of the frame).
    for u in model.uncertainty.as_mut().unwrap().structures.iter_mut() {
        u.size = Some(2.0);
        u.prior = 0.01;
    }
    let one = Selector::new(&model, w(1)).size_rung(n).unwrap();
    assert!(!one.characterize && one.cost_ms > one.allowed_ms, "{one:?}");
    let many = Selector::new(&model, w(1_000_000));
    let r = many.size_rung(n).unwrap();
    assert!(r.characterize && r.gain_ms > r.cost_ms, "{r:?}");
    let d = many.select(&scene);
    assert!(
        d.characterized && !d.selection.reasons[0].text.contains("triangle count alone"),
        "{:?}",
        d.selection.reasons
    );
    let mut fixed = Selector::new(&model, w(1));
    fixed.inquiry = Inquiry::Fixed(Level::Prior);
    assert!(fixed.size_rung(n).is_none() && fixed.select(&scene).characterized);
    // A size choice of the grid (its laws made far cheaper here) waits for the mesh's references: it characterizes.
    let mut cheap_grid = CostModel::shipped().unwrap();
    for m in cheap_grid.structures.iter_mut().filter(|m| m.structure == StructureName::Grid) {
        m.build_ln_a -= 20.0;
        let law = m.size.as_mut().expect("size laws");
        law.box_coef[0] -= 10.0;
        law.prim_coef[0] -= 10.0;
    }
    let r = Selector::new(&cheap_grid, w(1)).size_rung(n).unwrap();
    assert!(r.structure == Some(StructureName::Grid) && r.characterize, "{r:?}");
    let camera = Camera::frame(&Aabb::new(feats[0].lo.into(), feats[0].hi.into()));
    assert!(Selector::new(&model, TargetWorkload { camera: Some(camera), ..w(1) }).size_rung(n).is_none());
}
