//! The overlap floor: box crossings of the mesh and of a view, the boxes entered before the first hit, and the
//! rays that leave at once, against what every structure counts.

use meshchar::accel::StructureName;
use meshchar::characterize::{cpu, features_cpu, Params};
use meshchar::cost::CostModel;
use meshchar::geom::{Aabb, Camera, WorkloadKind};
use meshchar::mesh::{generate, Mesh};
use meshchar::select::{Budget, BuildBounds, PolicyKind, TargetWorkload};

use super::budget::*;
use super::budget_probes::*;

#[test]
fn box_crossings_are_projected_areas_and_count_coincident_copies_once_for_the_bvh() {
    use glam::Vec3;
    use meshchar::cost::Crossings;
    // One triangle filling the face z = 0 of its box: the box is the scene's, so every line meeting the scene meets
    // it, from any direction.
    let one = Mesh::new("one", vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]).unwrap();
    let c = Crossings::of_mesh(&one);
    assert_eq!((c.mean(), c.along(Vec3::Z), c.along(Vec3::new(1.0, 2.0, 3.0))), (1.0, (1.0, 1.0), (1.0, 1.0)));
    // Two unit triangles in opposite corners of a 2x2x1 box (`two_triangles`): boxes of face areas [0, 0, 1] each,
    // the scene's [2, 2, 4]. Cauchy-Crofton: 2 / 8; along z: 2 / 4; along x: no triangle box has area across x.
    let c = Crossings::of_mesh(&generate::two_triangles());
    assert_eq!((c.mean(), c.along(Vec3::Z).0, c.along(Vec3::X).0), (0.25, 0.5, 0.0));
    // A fan over three points: ceil(n / 3) copies of one index triple and zero-area legs; the distinct triples are
    // three, whatever n.
    let c = Crossings::of_mesh(&generate::fan_polygon(3000));
    let (all, distinct) = c.along(Vec3::Z);
    assert!(c.mean() > 900.0 && all > 900.0 && distinct < 3.0, "{c:?}");
    // Copies with their own vertices are distinct triples: all-equal counts every copy for the BVH too.
    let c = Crossings::of_mesh(&generate::all_equal(100));
    assert_eq!((c.mean(), c.along(Vec3::Z)), (100.0, (100.0, 100.0)));
    // Below Crossings::DISTINCT_FROM the distinct count is not taken apart.
    let c = Crossings::of_mesh(&generate::random_soup(1000, 3));
    assert!(c.mean() < Crossings::DISTINCT_FROM && c.distinct_faces == c.faces, "{c:?}");
    // Per ray of a camera: the crossings along its forward direction times the share of its rays on the box.
    let b = scene_box(&one);
    let (lo, hi) = (b.min.to_array(), b.max.to_array());
    let cam = meshchar::geom::Camera::frame(&b);
    // Without a view counted on the image (the parallel estimate):
    let parallel = Crossings { view: None, ..Crossings::of_mesh(&one) };
    let r = parallel.per_ray(Some(&cam), lo, hi);
    // No camera: the framing camera of the box, which `cam` is.
    assert_eq!(parallel.per_ray(None, lo, hi), r);
    let cover = meshchar::cost::ViewFeatures::of(&cam, lo, hi).coverage;
    assert!(r.all > 0.0 && (r.all - cover).abs() < 1e-12 && r.distinct == r.all, "{r:?} {cover}");
    // With the framing camera's view (what of_mesh counts): its count on the image, for that camera only.
    let viewed = Crossings::of_mesh(&one);
    let v = viewed.view.expect("a view");
    assert!(v.framing && v.camera == cam, "{v:?}");
    let boxes = [meshchar::geom::Aabb::of_triangle(&one.triangle(0))];
    assert_eq!(v.all, meshchar::cost::screen_crossings(&boxes, &cam));
    assert_eq!(viewed.per_ray(None, lo, hi).all, v.all);
    assert_eq!(viewed.per_ray(Some(&cam), lo, hi).all, v.all);
    let other = meshchar::geom::Camera { eye: cam.eye * 2.0, ..cam };
    assert_eq!(viewed.per_ray(Some(&other), lo, hi), parallel.per_ray(Some(&other), lo, hi));
    // Zero-area triangles: the lattice's 400 collinear ones along its diagonal are all of its crossings along z
    // but the squares', and none of the non-degenerate ones (what the kd-tree holds as boxes).
    let lat = Crossings::of_mesh(&generate::lattice_with_diagonal(30, 400));
    let w = |f: [f64; 3]| f[2] / lat.scene[2];
    assert!((w(lat.faces) - 402.0).abs() < 1e-9 && (w(lat.nondegenerate_faces) - 2.0).abs() < 1e-9, "{lat:?}");
    // The distinct triples are counted apart whenever some direction could see many boxes, even where the mean over
    // all directions is small: a box 100 long in x and 1 x 1 across (spanned by a zero-area segment) holding 30
    // copies of one triangle that fills its cross-section. Along x: 31 boxes, 2 distinct; the mean is 231 / 201.
    let mut pos = vec![[0.0, 0.0, 0.0], [100.0, 1.0, 1.0]];
    pos.extend([[50.0, 0.0, 0.0], [50.0, 1.0, 0.0], [50.0, 0.0, 1.0]]);
    let mut tris = vec![[0u32, 1, 0]];
    tris.extend(std::iter::repeat_n([2u32, 3, 4], 30));
    let thin = Crossings::of_mesh(&Mesh::new("copies", pos, tris).unwrap());
    assert!(thin.mean() < Crossings::DISTINCT_FROM && thin.most() >= Crossings::DISTINCT_FROM, "{thin:?}");
    assert_eq!(thin.along(Vec3::X), (31.0, 2.0), "{thin:?}");
    // Merged bounds of several frames keep the first frame's crossings (the policy floors the first frame), with
    // the box marked as moving where the frames' boxes differ.
    let (a, b) = (generate::fan_polygon(300), generate::random_soup(300, 1));
    let merged = BuildBounds::of_frames(&[a.clone(), b.clone()]).unwrap().unwrap();
    assert_eq!(merged.box_crossings, Some(Crossings::of_mesh(&a).over_frames(&Crossings::of_mesh(&b))));
    assert_eq!(
        merged.box_crossings.map(|c| (c.faces, c.distinct_faces, c.view.is_some())),
        Some((Crossings::of_mesh(&a).faces, Crossings::of_mesh(&a).distinct_faces, true))
    );
    // The mesh bounds carry the crossings; feature bounds cannot.
    let fan = generate::fan_polygon(3000);
    assert_eq!(BuildBounds::of_mesh(&fan).unwrap().box_crossings, Some(Crossings::of_mesh(&fan)));
    let f = features_cpu(&fan, &Params::default()).unwrap();
    assert_eq!(BuildBounds::of_features(&f).box_crossings, None);
}

#[test]
fn screen_crossings_count_each_box_by_its_share_of_the_image() {
    use meshchar::cost::screen_crossings;
    use meshchar::geom::Aabb;
    let v = glam::Vec3::new;
    // At the origin looking down -z with a 90-degree field of view: the image spans x / depth and y / depth in
    // [-1, 1].
    let cam = meshchar::geom::Camera {
        eye: v(0.0, 0.0, 0.0),
        forward: v(0.0, 0.0, -1.0),
        right: v(1.0, 0.0, 0.0),
        up: v(0.0, 1.0, 0.0),
        tan_half_fov: 1.0,
    };
    let b = |lo: [f32; 3], hi: [f32; 3]| Aabb { min: glam::Vec3::from(lo), max: glam::Vec3::from(hi) };
    let share = |x: Aabb| screen_crossings(&[x], &cam);
    // Filling the image, a quarter of it, clipped to it, behind the eye, holding the eye.
    assert_eq!(share(b([-1.0, -1.0, -2.0], [1.0, 1.0, -1.0])), 1.0);
    assert_eq!(share(b([0.0, 0.0, -1.0], [1.0, 1.0, -1.0])), 0.25);
    assert_eq!(share(b([0.0, 0.0, -1.0], [2.0, 1.0, -1.0])), 0.25);
    assert_eq!(share(b([-1.0, -1.0, 1.0], [1.0, 1.0, 2.0])), 0.0);
    assert_eq!(share(b([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])), 1.0);
    // Straddling the eye's plane: the part in front, cut at the near plane, projects towards the image's edge.
    assert_eq!(share(b([1.0, -0.5, -1.0], [2.0, 0.5, 1.0])), 0.0, "beside the view");
    let s = share(b([-0.5, 0.1, -1.0], [0.5, 0.5, 1.0]));
    assert!((s - 0.45).abs() < 1e-6, "above the eye, in view: {s}");
    // Boxes add up; non-finite coordinates count nothing; the order of the boxes does not change the sum's bits.
    let many: Vec<Aabb> = (0..10_000).map(|i| b([0.0, 0.0, -1.0 - i as f32], [1.0, 1.0, -1.0 - i as f32])).collect();
    let sum = screen_crossings(&many, &cam);
    assert!((sum - many.iter().map(|x| share(*x)).sum::<f64>()).abs() < 1e-9, "{sum}");
    assert_eq!(screen_crossings(&many, &cam), sum);
    assert_eq!(share(b([0.0, 0.0, -1.0], [f32::INFINITY, 1.0, -1.0])), 0.0);
    assert_eq!(screen_crossings(&[], &cam), 0.0);
    // A close camera looking into dense geometry sees far more than the parallel estimate: the engineering
    // family's fans of slivers from its close-up preset.
    let m =
        meshchar::mesh::families::generate(meshchar::mesh::families::Family::Engineering, 20_000, 1).expect("family");
    let bx = scene_box(&m);
    let close = meshchar::trace::views::View::CloseUp.camera(&bx);
    let c = meshchar::cost::Crossings::of_mesh_viewed(&m, Some(&close));
    let (lo, hi) = (bx.min.to_array(), bx.max.to_array());
    let counted = c.per_ray(Some(&close), lo, hi).all;
    let parallel = meshchar::cost::Crossings { view: None, ..c }.per_ray(Some(&close), lo, hi).all;
    assert!(counted > 3.0 * parallel, "counted {counted}, parallel {parallel}");
}

#[test]
fn the_overlap_floor_bounds_the_hierarchies_of_every_workload() {
    use meshchar::cost::{overlap_floor, Crossings, RayCrossings};
    let c =
        Some(RayCrossings { all: 500.0, distinct: 2.0, nondegenerate: 100.0, image: 0.0, ..RayCrossings::default() });
    let f = |s, k| overlap_floor(&bounds(), s, k, c);
    let kinds = [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse];
    for s in [StructureName::Lbvh, StructureName::Hlbvh, StructureName::Bih, StructureName::KdTree] {
        // The kd-tree holds zero-area triangles as points: only the others' boxes count for it.
        let x = if s == StructureName::KdTree { 100.0 } else { 500.0 };
        for k in kinds {
            let (b, p) = bounds().tests_per_crossing(s, k);
            // Read off the records by `calibrate`; by definition the kd-tree floors no box tests.
            assert!(b >= 0.0 && p >= 0.0 && (s != StructureName::KdTree || b == 0.0), "{s} {k:?}: {b} {p}");
            assert!(k != WorkloadKind::Primary || (p > 0.0 && (b > 0.0) == (s != StructureName::KdTree)), "{s}");
            assert_eq!(f(s, k).box_tests, x * b, "{s} {k:?}");
            assert_eq!(f(s, k).prim_tests, x * p, "{s} {k:?}");
        }
    }
    // The BVH and the grid count distinct triangles; a kd-tree floors no node visits; the grid floors the triangle
    // tests of primary rays only, with the least factor of all.
    for k in kinds {
        let (b, p) = bounds().tests_per_crossing(StructureName::Bvh, k);
        assert_eq!(f(StructureName::Bvh, k).prim_tests, 2.0 * p);
        assert_eq!(f(StructureName::Bvh, k).box_tests, 2.0 * b);
        assert_eq!(f(StructureName::KdTree, k).box_tests, 0.0);
        let (gb, gp) = bounds().tests_per_crossing(StructureName::Grid, k);
        assert_eq!((gb, gp > 0.0), (0.0, k == WorkloadKind::Primary), "{k:?}: {gb} {gp}");
        let g = f(StructureName::Grid, k);
        assert_eq!((g.box_tests, g.prim_tests), (0.0, 2.0 * gp), "{k:?}");
        let least =
            [StructureName::Bvh, StructureName::KdTree, StructureName::Bih, StructureName::Lbvh, StructureName::Hlbvh]
                .into_iter()
                .map(|s| bounds().tests_per_crossing(s, k).1)
                .fold(f64::INFINITY, f64::min);
        assert!(gp <= least, "{k:?}: grid {gp}, least of the others {least}");
        assert_eq!(overlap_floor(&bounds(), StructureName::Lbvh, k, None), Default::default());
    }
    // Secondary rays are given the crossings over every direction; primary rays those along the camera.
    let m = generate::overlapping_large(2000, 1);
    let b = scene_box(&m);
    let cr = Crossings::of_mesh(&m);
    let (lo, hi) = (b.min.to_array(), b.max.to_array());
    let cam = meshchar::geom::Camera::frame(&b);
    assert_eq!(cr.for_workload(WorkloadKind::Primary, Some(&cam), lo, hi), cr.per_ray(Some(&cam), lo, hi));
    for k in [WorkloadKind::Shadow, WorkloadKind::Diffuse] {
        let r = cr.for_workload(k, Some(&cam), lo, hi);
        // (They also get the boxes holding the diffuse origins, or crossed by unoccluded shadow rays, counted on the
        // camera's sample, and the probed structures' counts on the secondary rays of that sample.)
        assert_eq!(
            RayCrossings { image: 0.0, near: None, probes: Default::default(), probe_work: Default::default(), ..r },
            cr.isotropic()
        );
        let probed = cr.view.expect("framing view").probes.map(|p| p.map(|p| *p.of_kind(k)));
        assert!(r.near.is_some() && r.probes == probed, "{k:?}");
        assert!(r.probes.iter().all(|p| p.is_some_and(|p| p.box_tests.rays > 0)), "{k:?}: {:?}", r.probes);
    }
    assert_eq!(cr.isotropic().all, cr.mean());
    // Secondary rays also get the camera's count on its image, when the view is of that camera.
    assert_eq!(cr.for_workload(WorkloadKind::Primary, None, lo, hi).image, 0.0);
    assert_eq!(cr.for_workload(WorkloadKind::Shadow, None, lo, hi).image, cr.view.expect("framing view").all);
    assert_eq!(cr.for_workload(WorkloadKind::Diffuse, Some(&cam), lo, hi).image, cr.view.unwrap().all);
    let elsewhere = meshchar::geom::Camera { eye: cam.eye * 3.0, ..cam };
    assert_eq!(cr.for_workload(WorkloadKind::Diffuse, Some(&elsewhere), lo, hi).image, 0.0);
    // The secondary floor is the larger of the isotropic one and the image's, scaled by the distinct share.
    let with_image =
        RayCrossings { all: 500.0, distinct: 2.0, nondegenerate: 100.0, image: 1000.0, ..RayCrossings::default() };
    for k in [WorkloadKind::Shadow, WorkloadKind::Diffuse] {
        for s in StructureName::ALL {
            let fl = overlap_floor(&bounds(), s, k, Some(with_image));
            let base = overlap_floor(&bounds(), s, k, c);
            let x = match s {
                StructureName::Bvh => 2.0,
                StructureName::KdTree => 100.0,
                _ => 500.0,
            };
            let (bi, pi) = bounds().tests_per_image_crossing(s, k);
            assert_eq!(fl.box_tests, base.box_tests.max(bi * (1000.0 * x / 500.0)), "{s} {k:?}");
            assert_eq!(fl.prim_tests, base.prim_tests.max(pi * (1000.0 * x / 500.0)), "{s} {k:?}");
            assert_eq!(
                (bi > 0.0, pi > 0.0),
                (!matches!(s, StructureName::Grid | StructureName::KdTree), s != StructureName::Grid),
                "{s}"
            );
        }
        assert_eq!(bounds().tests_per_image_crossing(StructureName::Bvh, WorkloadKind::Primary), (0.0, 0.0));
    }
    assert!(cr.isotropic().all > 100.0, "{:?}", cr.isotropic());
    // The model's predictions take the floor: counts at least it, and a trace no cheaper than without it.
    let model = CostModel::shipped().expect("shipped model");
    let feats = features_cpu(&m, &Params::default()).unwrap();
    let w = meshchar::cost::Workload {
        kind: WorkloadKind::Primary,
        rays_per_frame: 65536,
        frames: 1,
        builds: 1,
        view: None,
    };
    let rc = Some(cr.per_ray(Some(&cam), feats.lo, feats.hi));
    let plain = laws(&model, &feats, &w);
    let floored = model.predict_floored(&feats, &w, &|s| overlap_floor(&bounds(), s, WorkloadKind::Primary, rc));
    // The probed structures' corrections (the count held at `PROBE_BAND` over the floored law, whatever band held
    // the structure's own count), which the unprobed hierarchies share.
    let (mut lb, mut lp, mut k) = (0.0f64, 0.0f64, 0.0f64);
    let n = feats.total_triangles.max(feats.triangles);
    for p in &plain {
        let fl = overlap_floor(&bounds(), p.structure, WorkloadKind::Primary, rc);
        // The grid's own count is held to its sample, but its ratio is not shared (`SHARES_PROBES`).
        if fl.sampled.is_some() && p.structure != StructureName::Grid {
            let (bx, pr) = (p.box_tests_per_ray.max(fl.box_tests), p.prim_tests_per_ray.max(fl.prim_tests));
            let q = model.get(p.structure).expect("calibrated").predict_floored(&feats.derived(), n, &w, fl);
            lb += (q.box_tests_per_ray / bx).ln();
            lp += (q.prim_tests_per_ray / pr).ln();
            k += 1.0;
        }
    }
    // The LBVH, the BVH, the BIH and the HLBVH: every probed structure but the grid.
    assert_eq!(k, (meshchar::cost::PROBED.len() - 1) as f64, "every probed hierarchy built");
    let (gb, gp) = ((lb / k).exp(), (lp / k).exp());
    assert!(gb != 1.0, "the held counts move the shared box tests ({gb})");
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
    for (p, q) in plain.iter().zip(&floored) {
        let fl = overlap_floor(&bounds(), p.structure, WorkloadKind::Primary, rc);
        let (bx, pr) = (p.box_tests_per_ray.max(fl.box_tests), p.prim_tests_per_ray.max(fl.prim_tests));
        match fl.sampled {
            // A probed structure's own counts on the camera's sample (`cost::probe`): the shipped file was traced
            // on the CPU, so they are held there wherever the floored law lies (`OWN_PROBE_BAND_CPU`).
            Some(s) => {
                assert!(meshchar::cost::PROBED.contains(&p.structure), "{}", p.structure);
                let b = &s.box_tests;
                assert_eq!(q.box_tests_per_ray, bx.clamp(b.lower_bound(), b.upper_bound()), "{}", p.structure);
                let t = &s.prim_tests;
                assert_eq!(q.prim_tests_per_ray, pr.clamp(t.lower_bound(), t.upper_bound()), "{}", p.structure);
            }
            None if meshchar::cost::SHARES_PROBES.contains(&p.structure) => {
                // The law corrected, then its own floor.
                let (cb, cp) =
                    ((p.box_tests_per_ray * gb).max(fl.box_tests), (p.prim_tests_per_ray * gp).max(fl.prim_tests));
                assert!(close(q.box_tests_per_ray, cb), "{}: {} vs {cb}", p.structure, q.box_tests_per_ray);
                assert!(close(q.prim_tests_per_ray, cp), "{}: {} vs {cp}", p.structure, q.prim_tests_per_ray);
            }
            None => {
                assert_eq!(q.box_tests_per_ray, bx, "{}", p.structure);
                assert_eq!(q.prim_tests_per_ray, pr, "{}", p.structure);
                assert!(q.trace_ms >= p.trace_ms, "{}", p.structure);
            }
        }
        // The build: by the law in `n`, or, where the probe built the structure and the model has a work law, by
        // the probe's build work (`StructureModel::build_work_coef`).
        let sm = model.get(p.structure).expect("calibrated");
        assert_eq!(q.build_ms, sm.build_ms(n, fl.build_work) * w.builds as f64, "{}", p.structure);
        if fl.build_work == 0.0 || sm.build_work_coef.is_empty() {
            assert_eq!(q.build_ms, p.build_ms, "{}", p.structure);
        }
    }
    assert!(floored.iter().zip(&plain).any(|(q, p)| q.trace_ms > 2.0 * p.trace_ms), "the floor changed nothing");
    // Every probed structure that built reports its build's work, the grid's its references.
    for s in meshchar::cost::PROBED {
        let fl = overlap_floor(&bounds(), s, WorkloadKind::Primary, rc);
        let built = meshchar::accel::build_structure(s, &m).expect("builds");
        assert_eq!(Some(fl.build_work), built.build_work(), "{s}");
    }
}

/// Box plus triangle tests per ray of `s` over the rays of `kind` from 32 x 32 primary rays of `camera` (`None`:
/// the framing camera; secondary rays from the reference BVH's hits): deterministic.
pub(super) fn tests_per_ray(s: StructureName, m: &Mesh, kind: WorkloadKind, camera: Option<&Camera>) -> Option<f64> {
    use meshchar::trace::trace;
    use meshchar::trace::workload::{build_workload, mesh_bounds};
    let accel = meshchar::accel::build_structure(s, m).ok()?;
    let reference = meshchar::accel::build_structure(StructureName::Bvh, m).ok()?;
    let cam = camera.copied().unwrap_or_else(|| Camera::frame(&mesh_bounds(m)));
    let rays = build_workload(kind, m, &cam, 32, reference.as_ref());
    let out = trace(accel.as_ref(), &rays);
    Some((out.counters.box_tests + out.counters.prim_tests) as f64 / rays.rays.len().max(1) as f64)
}

/// The calibrated policy's choice for `m` under `kind` at 256 x 256 rays from `camera` (`None`: the framing one),
/// and whether its tests per ray stay within 4 times the fewest among the structures the budget keeps (the counts,
/// for the message).
pub(super) fn choice_within_4x_of_fewest_tests(
    m: &Mesh,
    kind: WorkloadKind,
    camera: Option<&Camera>,
) -> (StructureName, bool, Vec<(StructureName, f64)>) {
    let model = CostModel::shipped().expect("shipped model");
    let params = Params::default();
    let c = cpu::fast(m, &params).expect("characterization");
    let f = features_cpu(m, &params).expect("features");
    let (frames, features) = (std::slice::from_ref(&c), std::slice::from_ref(&f));
    let w = TargetWorkload { kind, camera: camera.copied(), ..workload() };
    let sel = decide(m, frames, features, &model, PolicyKind::Calibrated, w, COUNTED, Budget::default(), true);
    let chosen = sel.selection.structure;
    let kept: Vec<StructureName> =
        StructureName::ALL.into_iter().filter(|s| !sel.selection.excluded.iter().any(|e| e.structure == *s)).collect();
    let counts: Vec<(StructureName, f64)> =
        kept.iter().filter_map(|&s| tests_per_ray(s, m, kind, camera).map(|t| (s, t))).collect();
    let least = counts.iter().map(|c| c.1).fold(f64::INFINITY, f64::min);
    let mine = counts.iter().find(|c| c.0 == chosen).map(|c| c.1).expect("the chosen structure builds");
    (chosen, mine <= 4.0 * least.max(1.0), counts)
}

#[test]
fn on_overlapping_and_coincident_triangles_the_calibrated_policy_picks_no_runaway_traversal() {
    // The three primary-ray catastrophes of docs/data/degenerate-primary.jsonl before the overlap floor: the BVH
    // at 6.9x the grid on overlapping triangles, the LBVH over the trace budget on a fan, the LBVH at 69x the grid
    // on zero-area triangles. Judged by counted tests per ray (deterministic), not by time: the chosen structure
    // makes at most 4 times the tests of the structure with the fewest among those the budget keeps.
    for m in [generate::overlapping_large(2000, 1), generate::fan_polygon(20_000), generate::zero_area(20_000, 1)] {
        let (chosen, ok, counts) = choice_within_4x_of_fewest_tests(&m, WorkloadKind::Primary, None);
        assert!(ok, "{}: chose {chosen}; tests per ray {counts:?}", m.name);
    }
}

#[test]
fn on_overlapping_triangles_the_calibrated_policy_picks_no_runaway_traversal_for_secondary_rays() {
    // The secondary-ray catastrophes of docs/data/degenerate-{shadow,diffuse}.jsonl before the floor reached them:
    // the BVH at 2.1x (shadow) and 9.8x (diffuse) the grid's total on 2,000 large overlapping triangles.
    let m = generate::overlapping_large(2000, 1);
    for kind in [WorkloadKind::Shadow, WorkloadKind::Diffuse] {
        let (chosen, ok, counts) = choice_within_4x_of_fewest_tests(&m, kind, None);
        assert!(ok, "{} {kind:?}: chose {chosen}; tests per ray {counts:?}", m.name);
    }
}

#[test]
fn seen_close_up_the_engineering_family_gets_no_runaway_traversal() {
    // The families' worst records (docs/data/families-*.jsonl): fans of long slivers seen close up, where the BVH
    // family's traversal explodes and the grid wins; the crossings counted on the camera's image see it, the
    // parallel estimate does not. Counted tests per ray, as above, for primary rays. For diffuse rays the LBVH, the
    // BIH, the HLBVH and the kd-tree make 285-414 tests per ray, the BVH 176 and the grid 41: with both of the last
    // two probed, their counts are known and their prices decide (a grid cell costs 2-4 box tests), and the
    // choice must be one of them, never a runaway (the record at 256 x 256: the BVH 37.7 ms, the grid 22.1 ms).
    let m =
        meshchar::mesh::families::generate(meshchar::mesh::families::Family::Engineering, 20_000, 1).expect("family");
    let close = meshchar::trace::views::View::CloseUp.camera(&scene_box(&m));
    let (chosen, ok, counts) = choice_within_4x_of_fewest_tests(&m, WorkloadKind::Primary, Some(&close));
    assert!(ok, "{} primary close up: chose {chosen}; tests per ray {counts:?}", m.name);
    let (chosen, _, counts) = choice_within_4x_of_fewest_tests(&m, WorkloadKind::Diffuse, Some(&close));
    let of = |s: StructureName| counts.iter().find(|c| c.0 == s).map_or(f64::INFINITY, |c| c.1);
    let fewest_hierarchy =
        counts.iter().filter(|c| c.0 != StructureName::Grid).map(|c| c.1).fold(f64::INFINITY, f64::min);
    assert!(
        chosen == StructureName::Grid || of(chosen) <= 1.1 * fewest_hierarchy,
        "{} diffuse close up: chose {chosen}; tests per ray {counts:?}",
        m.name
    );
    assert!(of(chosen) <= 0.7 * counts.iter().map(|c| c.1).fold(0.0, f64::max), "{chosen}: {counts:?}");
}

#[test]
fn the_grids_primary_floor_sees_triangles_crowded_into_one_cell() {
    // A fan of 2,000 slivers around one vertex (the failure study's generator): the structures that do not keep one
    // of coincident copies (the LBVH here) test a hundred or more triangles per primary ray near the hub. A
    // calibration fitted on the shared meshes and the families together predicted the grid cheapest there without a
    // floor under its triangle tests, and picked it at 145x the best total, before the grid merged copies; the
    // grid's floor now counts each group of copies once, as the BVH's does, and stays below what it tests.
    use meshchar::cost::{overlap_floor, Crossings};
    use meshchar::trace::workload::{build_workload, mesh_bounds};
    let m = meshchar::eval::load_scene(std::path::Path::new("degenerate:fan:2000:1")).unwrap().frames.remove(0);
    let cam = Camera::frame(&mesh_bounds(&m));
    let b = scene_box(&m);
    let rc = Crossings::of_mesh(&m).for_workload(WorkloadKind::Primary, Some(&cam), b.min.to_array(), b.max.to_array());
    let floor = |s| overlap_floor(&bounds(), s, WorkloadKind::Primary, Some(rc)).prim_tests;
    let reference = meshchar::accel::build_structure(StructureName::Bvh, &m).unwrap();
    let rays = build_workload(WorkloadKind::Primary, &m, &cam, 64, reference.as_ref());
    let prim = |s| {
        let a = meshchar::accel::build_structure(s, &m).unwrap();
        meshchar::trace::trace(a.as_ref(), &rays).counters.prim_tests as f64 / rays.rays.len() as f64
    };
    let (grid, lbvh, bvh) = (prim(StructureName::Grid), prim(StructureName::Lbvh), prim(StructureName::Bvh));
    // A floor: below what each does; and one that parts the LBVH from the BVH by far.
    let (fg, fl) = (floor(StructureName::Grid), floor(StructureName::Lbvh));
    assert!(fg <= grid, "floor {fg}, grid {grid} triangle tests per ray");
    assert!(fl <= lbvh, "floor {fl}, LBVH {lbvh} triangle tests per ray");
    assert!(fl > 5.0 * bvh.max(1.0), "floor {fl}, BVH {bvh} triangle tests per ray");
}

#[test]
fn the_mesh_bounds_are_the_same_on_any_number_of_threads() {
    // The pass runs in parallel; its sums that round stay in mesh order, so one thread and three give the same bits,
    // with the distinct copies counted (the overlapping soup crosses many boxes) and without.
    for mesh in [
        generate::overlapping_large(3000, 2),
        meshchar::eval::load_scene(std::path::Path::new("family:city:2k:1")).unwrap().frames.remove(0),
    ] {
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| BuildBounds::of_mesh_viewed(&mesh, None).unwrap())
        };
        let one = on(1);
        assert!(one.box_crossings.is_some());
        assert_eq!(one, on(3));
        assert_eq!(one, BuildBounds::of_mesh_viewed(&mesh, None).unwrap());
    }
}

/// Box and triangle tests per ray of `s`, apart, over the rays of `kind` from 32 x 32 primary rays of the framing
/// camera (secondary rays from the reference BVH's hits), and how many rays there were.
pub(super) fn counts_per_ray(s: StructureName, m: &Mesh, kind: WorkloadKind) -> (f64, f64, usize) {
    use meshchar::trace::trace;
    use meshchar::trace::workload::{build_workload, mesh_bounds};
    let accel = meshchar::accel::build_structure(s, m).expect("build");
    let reference = meshchar::accel::build_structure(StructureName::Bvh, m).expect("reference");
    let cam = Camera::frame(&mesh_bounds(m));
    let rays = build_workload(kind, m, &cam, 32, reference.as_ref());
    let out = trace(accel.as_ref(), &rays);
    let n = rays.rays.len().max(1) as f64;
    (out.counters.box_tests as f64 / n, out.counters.prim_tests as f64 / n, rays.rays.len())
}

#[test]
fn secondary_rays_leaving_a_flat_scene_test_each_hierarchys_root_once_as_predicted() {
    use meshchar::cost::overlap::{overlap_floor, secondary_rays_leave_the_plane};
    use meshchar::cost::Crossings;
    let hierarchies =
        [StructureName::Bvh, StructureName::KdTree, StructureName::Bih, StructureName::Lbvh, StructureName::Hlbvh];
    for m in [
        generate::all_equal(300),
        generate::fan_polygon(900),
        generate::flat(2000, 1),
        generate::lattice_with_diagonal(40, 20),
    ] {
        let b = scene_box(&m);
        let (lo, hi) = (b.min.to_array(), b.max.to_array());
        let cr = Crossings::of_mesh(&m);
        for kind in [WorkloadKind::Shadow, WorkloadKind::Diffuse] {
            assert!(secondary_rays_leave_the_plane(kind, None, lo, hi), "{}: {kind:?}", m.name);
            let c = cr.for_workload(kind, None, lo, hi);
            assert!(c.leave_flat_scene, "{}: {c:?}", m.name);
            for s in hierarchies {
                // What the model is told is what the traversal does, ray for ray.
                let (bx, pr, rays) = counts_per_ray(s, &m, kind);
                assert!(rays > 0, "{}: no {kind:?} rays", m.name);
                assert_eq!((bx, pr), (1.0, 0.0), "{}: {s:?} {kind:?}", m.name);
                let f = overlap_floor(&bounds(), s, kind, Some(c));
                assert_eq!((f.box_tests, f.prim_tests, f.box_tests_most, f.prim_tests_most), (1.0, 0.0, 1.0, 0.0));
                let model = CostModel::shipped().expect("shipped model");
                let d = features_cpu(&m, &Params::default()).expect("features").derived();
                let w = meshchar::cost::Workload { kind, rays_per_frame: 1000, frames: 1, builds: 1, view: None };
                let p = model.get(s).expect("calibrated").predict_floored(&d, m.triangle_count() as u64, &w, f);
                assert_eq!((p.box_tests_per_ray, p.prim_tests_per_ray), (1.0, 0.0), "{}: {s:?}", m.name);
            }
            // The grid still steps through the cells at the rays' origins: no bound.
            assert_eq!(overlap_floor(&bounds(), StructureName::Grid, kind, Some(c)).box_tests_most, f64::INFINITY);
        }
        // Primary rays, and a camera in the plane, keep the counts.
        assert!(!secondary_rays_leave_the_plane(WorkloadKind::Primary, None, lo, hi));
        let axis = (0..3).find(|&a| lo[a] == hi[a]).expect("flat");
        let mut in_plane = Camera::frame(&b);
        in_plane.eye[axis] = lo[axis];
        assert!(!secondary_rays_leave_the_plane(WorkloadKind::Diffuse, Some(&in_plane), lo, hi));
        // Shadow rays toward a light across the plane cross it: the camera on the other side keeps the counts.
        let mut across = Camera::frame(&b);
        across.eye[axis] = 2.0 * lo[axis] - across.eye[axis];
        assert!(!secondary_rays_leave_the_plane(WorkloadKind::Shadow, Some(&across), lo, hi), "{}", m.name);
        assert!(secondary_rays_leave_the_plane(WorkloadKind::Diffuse, Some(&across), lo, hi), "{}", m.name);
    }
    // A box with extent along every axis is not flat.
    let m = generate::overlapping_large(200, 1);
    let b = scene_box(&m);
    assert!(!secondary_rays_leave_the_plane(WorkloadKind::Diffuse, None, b.min.to_array(), b.max.to_array()));
}

#[test]
fn secondary_rays_from_a_closed_scene_seen_from_outside_leave_it_at_once_as_predicted() {
    use meshchar::cost::{overlap_floor, Crossings};
    use meshchar::mesh::families::{generate as family, Family};
    // Closed rooms whose outer walls lie on the scene box's faces, seen by the framing camera from outside.
    let m = family(Family::Interior, 20_000, 1).expect("family");
    let b = scene_box(&m);
    let (lo, hi) = (b.min.to_array(), b.max.to_array());
    let c = Crossings::of_mesh(&m);
    assert!(c.boundary_fill.iter().all(|&f| f > 0.95), "walls on every face: {:?}", c.boundary_fill);
    let share = c.leave_share(WorkloadKind::Diffuse, None);
    assert!(share > 0.95, "share {share}");
    // What the traversals do: every diffuse ray tests the root box and nothing else, in every structure.
    for s in StructureName::ALL {
        let (bx, pr, rays) = counts_per_ray(s, &m, WorkloadKind::Diffuse);
        assert!(rays > 0);
        assert_eq!((bx, pr), (1.0, 0.0), "{s:?}");
    }
    // What the model is told: the share's rays make one box test and none of the others' triangle tests.
    let r = c.for_workload(WorkloadKind::Diffuse, None, lo, hi);
    assert_eq!(r.leave_share, share);
    let model = CostModel::shipped().expect("shipped model");
    let d = features_cpu(&m, &Params::default()).expect("features").derived();
    let w = meshchar::cost::Workload {
        kind: WorkloadKind::Diffuse,
        rays_per_frame: 1000,
        frames: 1,
        builds: 1,
        view: None,
    };
    for s in StructureName::ALL {
        let f = overlap_floor(&bounds(), s, WorkloadKind::Diffuse, Some(r));
        let p = model.get(s).expect("calibrated").predict_floored(&d, m.triangle_count() as u64, &w, f);
        let plain = model.get(s).unwrap().predict_floored(&d, m.triangle_count() as u64, &w, Default::default());
        assert!((p.box_tests_per_ray - 1.0).abs() < 0.1 * plain.box_tests_per_ray.max(1.0), "{s:?}: {p:?}");
        assert!(p.prim_tests_per_ray <= (1.0 - share) * plain.prim_tests_per_ray.max(f.prim_tests) + 1e-12, "{s:?}");
    }
    // The same camera's primary rays, a camera inside the box, and a scene with nothing on its faces: no share.
    assert_eq!(c.leave_share(WorkloadKind::Primary, None), 0.0);
    let inside = Camera { eye: b.center(), ..Camera::frame(&b) };
    assert_eq!(c.leave_share(WorkloadKind::Diffuse, Some(&inside)), 0.0);
    let soup = generate::overlapping_large(500, 1);
    let sc = Crossings::of_mesh(&soup);
    assert_eq!(sc.boundary_fill, [0.0; 6]);
    assert_eq!(sc.leave_share(WorkloadKind::Diffuse, None), 0.0);
}

#[test]
fn the_rays_leaving_at_once_follow_the_box_of_every_frame_and_any_axis() {
    use meshchar::cost::overlap::secondary_rays_leave_the_plane;
    use meshchar::cost::Crossings;
    use meshchar::mesh::families::{generate as family, Family};
    // A flat scene in the plane y = 5 (a floor away from the origin), seen from the framing camera.
    let mut floor = generate::flat(2000, 1);
    floor.positions.iter_mut().for_each(|p| *p = [p[0], 5.0, p[1]]);
    let b = scene_box(&floor);
    let (lo, hi) = (b.min.to_array(), b.max.to_array());
    assert!(secondary_rays_leave_the_plane(WorkloadKind::Diffuse, None, lo, hi));
    for kind in [WorkloadKind::Shadow, WorkloadKind::Diffuse] {
        if !secondary_rays_leave_the_plane(kind, None, lo, hi) {
            continue;
        }
        for s in [StructureName::Bvh, StructureName::Bih, StructureName::Lbvh] {
            let (bx, pr, rays) = counts_per_ray(s, &floor, kind);
            assert!(rays > 0);
            assert_eq!((bx, pr), (1.0, 0.0), "{s:?} {kind:?}");
        }
    }
    // An animation whose box moves after the first frame: no frame's rays are taken to leave at once.
    let room = family(Family::Interior, 2_000, 1).expect("family");
    let mut moved = room.clone();
    moved.positions[0][0] += 1.0e3;
    let first = Crossings::of_mesh(&room);
    assert!(first.leave_share(WorkloadKind::Diffuse, None) > 0.5);
    let both = first.over_frames(&Crossings::of_mesh(&moved));
    assert!(both.box_moves);
    assert_eq!(both.leave_share(WorkloadKind::Diffuse, None), 0.0);
    assert!(!both.for_workload(WorkloadKind::Diffuse, None, lo, hi).leave_flat_scene);
    // The same box in every frame keeps the least fill of the frames.
    let same = first.over_frames(&first);
    assert!(!same.box_moves && same.boundary_fill == first.boundary_fill);
    let flat = Crossings::of_mesh(&floor);
    let flat_twice = flat.over_frames(&flat);
    assert!(flat_twice.for_workload(WorkloadKind::Diffuse, None, lo, hi).leave_flat_scene);
    // Through the selection's bounds of an animation: the frames' crossings combine the same way.
    let bounds = BuildBounds::of_frames_viewed(&[room.clone(), moved], None).expect("bounds").expect("frames");
    assert!(bounds.box_crossings.expect("crossings").box_moves);
    let still = BuildBounds::of_frames_viewed(&[room.clone(), room], None).expect("bounds").expect("frames");
    assert!(!still.box_crossings.expect("crossings").box_moves);
}

/// The triangles' boxes and records of a mesh, in mesh order.
pub(super) fn boxes_and_triangles(m: &Mesh) -> (Vec<Aabb>, Vec<meshchar::geom::Triangle>) {
    (0..m.triangle_count())
        .map(|i| {
            let v = m.triangle(i);
            (Aabb::of_triangle(&v), meshchar::geom::Triangle::new(&v))
        })
        .unzip()
}

#[test]
fn the_boxes_entered_before_the_first_hit_are_counted_exactly_on_two_walls() {
    use meshchar::cost::{near_crossings, screen_crossings};
    let v = glam::Vec3::new;
    // At the origin looking down -z, 90 degrees: a wall of two triangles at z = -1 covering the whole image, and
    // the same wall at z = -2 behind it. Every ray hits the front wall and enters both of its boxes (flat, the
    // same box) no later than the hit, and neither box of the back wall: exactly 2 per ray. The image count sees
    // all four boxes.
    let cam = Camera {
        eye: v(0.0, 0.0, 0.0),
        forward: v(0.0, 0.0, -1.0),
        right: v(1.0, 0.0, 0.0),
        up: v(0.0, 1.0, 0.0),
        tan_half_fov: 1.0,
    };
    let quad = |z: f32| [[-3.0, -3.0, z], [3.0, -3.0, z], [3.0, 3.0, z], [-3.0, 3.0, z]];
    let mut pos = quad(-1.0).to_vec();
    pos.extend(quad(-2.0));
    let walls = Mesh::new("walls", pos, vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]).unwrap();
    let (boxes, tris) = boxes_and_triangles(&walls);
    let image = screen_crossings(&boxes, &cam);
    assert_eq!(image, 4.0);
    // Every ray hits; the diffuse ray each hit starts leaves the front wall towards the camera, off its flat box:
    // no box holds its origin.
    // The shadow rays to the workload's light (above, on the camera's side) leave the wall too: no box crossed.
    let both = near_crossings(&boxes, &tris, &cam, image);
    let means = |c: meshchar::cost::NearCrossings| {
        (c.entered.mean, c.holding_origin.mean, c.hit_share, c.unoccluded_shadow.mean)
    };
    assert_eq!(means(both), (2.0, 0.0, 1.0, 0.0));
    // Every ray counts the same: no spread, and the bound the floor takes is the count itself.
    assert_eq!((both.entered.standard_error, both.entered.lower_bound(), both.entered.rays), (0.0, 2.0, 1024));
    // Without the front wall every ray hits the back one: 2 again; without any wall, nothing.
    let (back_boxes, back_tris) = (&boxes[2..], &tris[2..]);
    assert_eq!(near_crossings(back_boxes, back_tris, &cam, 2.0).entered.mean, 2.0);
    assert_eq!(near_crossings(&[], &[], &cam, 0.0), Default::default());
    // Rays that hit nothing count every box they enter: the back wall seen through zero-area triangles only.
    let degenerate = [meshchar::geom::Triangle::new(&[v(0.0, 0.0, -1.0); 3]); 2];
    assert!(degenerate[0].is_degenerate());
    let missed = near_crossings(back_boxes, &degenerate, &cam, 2.0);
    assert_eq!(means(missed), (2.0, 0.0, 0.0, 0.0));
    assert_eq!((missed.holding_origin.rays, missed.unoccluded_shadow.rays), (0, 0));
    // Looking away from the walls: nothing.
    let away = Camera { forward: v(0.0, 0.0, 1.0), right: v(-1.0, 0.0, 0.0), ..cam };
    assert_eq!(near_crossings(&boxes, &tris, &away, image).entered.mean, 0.0);
    // A box around the hit point: the front wall tilted out of its plane (its two triangles now span a box of
    // depth), so every diffuse origin lies inside the boxes of the triangles around it.
    let tilted = [[-3.0, -3.0, -0.5], [3.0, -3.0, -1.5], [3.0, 3.0, -1.5], [-3.0, 3.0, -0.5]];
    let wedge = Mesh::new("tilted", tilted.to_vec(), vec![[0, 1, 2], [0, 2, 3]]).unwrap();
    let (wb, wt) = boxes_and_triangles(&wedge);
    let w = near_crossings(&wb, &wt, &cam, screen_crossings(&wb, &cam));
    assert_eq!(w.hit_share, 1.0);
    let (holding, shadow) = (w.holding_origin.mean, w.unoccluded_shadow.mean);
    assert!((1.0..=2.0).contains(&holding), "{w:?}");
    // Nothing occludes the light (on the camera's side of the plane), and a shadow ray crosses every box holding its
    // origin: both triangles have the same box.
    assert!(shadow >= holding && shadow <= 2.0, "{w:?}");
}

#[test]
fn every_hierarchy_tests_at_least_the_triangles_whose_boxes_a_ray_enters_before_its_hit() {
    // The claim behind the triangle-test floor of `overlap_floor`: a binned-SAH BVH, an LBVH, an HLBVH and a BIH
    // (every node bounds whole triangles) test, per ray, at least the triangles whose boxes the ray enters before its
    // closest hit (primary and diffuse rays) or crosses without being occluded (shadow rays). Checked on the very rays `near_crossings` samples (the pixel centres of a
    // NEAR_SAMPLES-square image of the camera), on scenes where the count is large (the engineering family seen
    // close up, 2,000 overlapping triangles), small (a closed interior from inside) and random. The argument does
    // not hold for the kd-tree and the grid, which store a triangle only in the cells it overlaps: the grid makes far
    // fewer on the engineering slivers, and neither takes this floor.
    use meshchar::cost::overlap::NEAR_SAMPLES;
    use meshchar::cost::{near_crossings, screen_crossings};
    use meshchar::mesh::families::{generate as family, Family};
    use meshchar::trace::trace;
    use meshchar::trace::views::View;
    use meshchar::trace::workload::{build_workload, mesh_bounds};
    let eng = family(Family::Engineering, 20_000, 1).expect("family");
    let interior = family(Family::Interior, 2_000, 1).expect("family");
    let cases = [
        (View::CloseUp.camera(&scene_box(&eng)), eng),
        (View::Inside.camera(&scene_box(&interior)), interior),
        (Camera::frame(&scene_box(&generate::random_soup(2000, 3))), generate::random_soup(2000, 3)),
        (Camera::frame(&scene_box(&generate::overlapping_large(2000, 1))), generate::overlapping_large(2000, 1)),
    ];
    for (cam, m) in &cases {
        let (boxes, tris) = boxes_and_triangles(m);
        let counted = near_crossings(&boxes, &tris, cam, screen_crossings(&boxes, cam));
        // The rays traced below are the very rays sampled, so the bound holds for the sample's mean exactly.
        let near = counted.entered.mean;
        let reference = meshchar::accel::build_structure(StructureName::Bvh, m).unwrap();
        let rays = build_workload(WorkloadKind::Primary, m, cam, NEAR_SAMPLES, reference.as_ref());
        assert_eq!(rays.rays.len(), (NEAR_SAMPLES * NEAR_SAMPLES) as usize);
        assert_eq!(mesh_bounds(m), scene_box(m));
        let per_ray = |s: StructureName| {
            let accel = meshchar::accel::build_structure(s, m).unwrap();
            trace(accel.as_ref(), &rays).counters.prim_tests as f64 / rays.rays.len() as f64
        };
        for s in [StructureName::Bvh, StructureName::Lbvh, StructureName::Hlbvh, StructureName::Bih] {
            let tested = per_ray(s);
            assert!(tested >= near, "{} {s}: {tested} triangle tests per ray, {near} boxes entered", m.name);
        }
        if m.name.contains("engineering") {
            assert!(near > 50.0, "{}: {near}", m.name);
            let tested = per_ray(StructureName::Grid);
            assert!(tested < near, "{} grid: {tested} triangle tests per ray, {near} boxes entered", m.name);
        }
        // The shadow rays those hits start: an unoccluded any-hit ray visits every node its segment crosses, so each
        // of the four tests at least the triangles whose boxes the unoccluded rays cross.
        let shadow = build_workload(WorkloadKind::Shadow, m, cam, NEAR_SAMPLES, reference.as_ref());
        for s in [StructureName::Bvh, StructureName::Lbvh, StructureName::Hlbvh, StructureName::Bih] {
            let accel = meshchar::accel::build_structure(s, m).unwrap();
            let tested = trace(accel.as_ref(), &shadow).counters.prim_tests as f64 / shadow.rays.len().max(1) as f64;
            let crossed = counted.unoccluded_shadow.mean;
            assert!(tested >= crossed, "{} {s} shadow: {tested} triangle tests per ray, {crossed} boxes", m.name);
        }
        assert_eq!(shadow.rays.len(), counted.unoccluded_shadow.rays, "{}: one shadow ray per hit", m.name);
        if m.name.contains("engineering") || m.name.contains("overlapping") {
            assert!(counted.unoccluded_shadow.mean > 10.0, "{}: {counted:?}", m.name);
        }
        // The diffuse rays those hits start (one per hit, from the same origins): each of the four tests at least
        // the triangles whose boxes hold the ray's origin.
        let diffuse = build_workload(WorkloadKind::Diffuse, m, cam, NEAR_SAMPLES, reference.as_ref());
        assert_eq!(diffuse.rays.len() as f64, counted.hit_share * rays.rays.len() as f64, "{}", m.name);
        for s in [StructureName::Bvh, StructureName::Lbvh, StructureName::Hlbvh, StructureName::Bih] {
            let accel = meshchar::accel::build_structure(s, m).unwrap();
            let tested = trace(accel.as_ref(), &diffuse).counters.prim_tests as f64 / diffuse.rays.len().max(1) as f64;
            let holding = counted.holding_origin.mean;
            assert!(tested >= holding, "{} {s} diffuse: {tested} triangle tests per ray, {holding} boxes", m.name);
        }
        if m.name.contains("engineering") || m.name.contains("overlapping") {
            assert!(counted.holding_origin.mean > 10.0, "{}: {counted:?}", m.name);
        }
    }
}

#[test]
fn the_boxes_entered_before_the_hit_floor_the_triangle_tests_of_the_four_hierarchies_for_every_workload() {
    use meshchar::cost::{overlap_floor, RayCrossings};
    // 40 boxes entered before the hit, 50 crossed on the image, 10 of them distinct triangles (the BVH keeps one
    // of coincident copies: 40 * 10 / 50 = 8 for it).
    let c = RayCrossings { all: 50.0, distinct: 10.0, nondegenerate: 50.0, near: Some(40.0), ..Default::default() };
    let without = RayCrossings { near: None, ..c };
    // Secondary rays that leave the scene at once cross nothing: the floor bounds the others' counts, 40 / (1 - 0.5)
    // (primary rays have no such share).
    let half = RayCrossings { leave_share: 0.5, ..c };
    let lbvh = |k, c| overlap_floor(&bounds(), StructureName::Lbvh, k, Some(c)).prim_tests;
    let d = WorkloadKind::Diffuse;
    assert_eq!(lbvh(d, half), lbvh(d, RayCrossings { near: None, ..half }).max(80.0));
    let p = WorkloadKind::Primary;
    assert_eq!(lbvh(p, half), lbvh(p, without).max(40.0));
    let leaf = |s| match s {
        StructureName::Bvh => meshchar::accel::bvh::BvhOptions::default().max_leaf as f64,
        StructureName::Lbvh => meshchar::accel::lbvh::LbvhOptions::default().max_leaf as f64,
        StructureName::Hlbvh => meshchar::accel::hlbvh::HlbvhOptions::default().max_leaf as f64,
        _ => meshchar::accel::bih::BihOptions::default().max_leaf as f64,
    };
    let kinds = [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse];
    for (s, k) in StructureName::ALL.into_iter().flat_map(|s| kinds.map(|k| (s, k))) {
        let (f, g) = (overlap_floor(&bounds(), s, k, Some(c)), overlap_floor(&bounds(), s, k, Some(without)));
        match s {
            StructureName::Bvh | StructureName::Lbvh | StructureName::Hlbvh | StructureName::Bih => {
                let near = if s == StructureName::Bvh { 8.0 } else { 40.0 };
                assert_eq!(f.prim_tests, g.prim_tests.max(near), "{s} {k:?}");
                assert_eq!(f.box_tests, g.box_tests.max(near / leaf(s)), "{s} {k:?}");
                assert!(f.prim_tests > g.prim_tests, "{s} {k:?}: the floor must bind here");
            }
            _ => assert_eq!(f, g, "{s} {k:?}: no floor from the boxes entered"),
        }
    }
    // The count travels with the camera's view: primary rays of that camera get it, another camera's do not. It is
    // counted where the image count reaches Crossings::NEAR_FROM (the engineering family close up), not below (two
    // triangles side by side, framed).
    use meshchar::cost::Crossings;
    let m = meshchar::mesh::families::generate(meshchar::mesh::families::Family::Engineering, 20_000, 1).unwrap();
    let b = scene_box(&m);
    let (lo, hi) = (b.min.to_array(), b.max.to_array());
    let close = meshchar::trace::views::View::CloseUp.camera(&b);
    let cr = Crossings::of_mesh_viewed(&m, Some(&close));
    let v = cr.view.expect("a view");
    let near = v.near.expect("counted close up");
    assert!(v.all >= Crossings::NEAR_FROM && near.entered.mean > 50.0 && near.entered.mean < v.all, "{v:?}");
    // The rays take the sampled means less two standard errors.
    let (e, h, u) = (near.entered, near.holding_origin, near.unoccluded_shadow);
    assert!(e.standard_error > 0.0 && e.lower_bound() == e.mean - 2.0 * e.standard_error, "{e:?}");
    assert_eq!(cr.per_ray(Some(&close), lo, hi).near, Some(e.lower_bound()));
    assert_eq!(cr.for_workload(WorkloadKind::Primary, Some(&close), lo, hi).near, Some(e.lower_bound()));
    assert_eq!(cr.for_workload(WorkloadKind::Diffuse, Some(&close), lo, hi).near, Some(h.lower_bound()));
    let elsewhere = Camera { eye: close.eye * 3.0, ..close };
    assert_eq!(cr.per_ray(Some(&elsewhere), lo, hi).near, None);
    assert_eq!(cr.for_workload(WorkloadKind::Diffuse, Some(&elsewhere), lo, hi).near, None);
    assert_eq!(cr.for_workload(WorkloadKind::Shadow, Some(&close), lo, hi).near, Some(u.lower_bound()));
    // An animation's frames other than the first have no such bound: combined over frames, the count is dropped.
    let merged = cr.over_frames(&cr);
    assert_eq!(merged.view.map(|v| (v.all, v.near)), Some((v.all, None)));
    // The policy's bounds of an animation skip the count (the same image count, no near); of one frame, keep it.
    let frames = [m.clone(), m.clone()];
    let crossings = |f: &[Mesh]| BuildBounds::of_frames_viewed(f, Some(&close)).unwrap().unwrap().box_crossings;
    let animated = crossings(&frames).and_then(|c| c.view).expect("a view");
    assert_eq!((animated.all, animated.near), (v.all, None));
    assert_eq!(crossings(&frames[..1]).and_then(|c| c.view).and_then(|v| v.near), Some(near));
    let first = Crossings::of_first_frame_viewed(&m, Some(&close), 2).view.expect("a view");
    assert_eq!((first.all, first.near), (v.all, None));
    // The engine core's BIH leaf is the BIH's default.
    assert_eq!(meshchar::cost::overlap::BIH_MAX_LEAF, meshchar::accel::bih::BihOptions::default().max_leaf);
    assert_eq!(cr.for_workload(WorkloadKind::Shadow, Some(&elsewhere), lo, hi).near, None);
    let framed = Crossings::of_mesh(&generate::two_triangles()).view.expect("framing view");
    assert!(framed.all < Crossings::NEAR_FROM && framed.near.is_none(), "{framed:?}");
}
