//! Every structure returns the same closest hit (triangle and `t` bits, under the tie rule of
//! `geom::closer_hit`) and the same occlusion as the brute-force reference, on the failure study's degenerate scenes
//! (flat, collinear, all equal, huge, tiny, slivers, overlapping, zero-area, duplicated), and the same as the
//! binned-SAH BVH on every shared static mesh and a BART frame, for primary, shadow and diffuse rays; and on the flat
//! lattice with zero-area triangles along its diagonal, where the grid's cells and budget are put to the test.
use crate::common;

use meshchar::accel::{build_structure, AccelStructure, StructureName};
use meshchar::eval::failure_study::generated_cases;
use meshchar::geom::Camera;
use meshchar::geom::{hits_agree, WorkloadKind};
use meshchar::mesh::Mesh;
use meshchar::trace::trace;
use meshchar::trace::workload::{build_workload, mesh_bounds};

/// Traces the three workloads (`resolution`^2 primary rays, and the shadow and diffuse rays from their hits) through
/// every structure and `reference`, and returns one line per disagreement (at most 3 per structure and workload)
/// and the number of rays that hit in the reference (summed over the workloads).
fn disagreements(mesh: &Mesh, reference: &dyn AccelStructure, resolution: u32) -> (Vec<String>, usize) {
    let camera = Camera::frame(&mesh_bounds(mesh));
    let mut out = Vec::new();
    let mut hits = 0;
    for kind in [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
        let rays = build_workload(kind, mesh, &camera, resolution, reference);
        let want = trace(reference, &rays);
        hits += want.hits.iter().filter(|h| h.is_some()).count() + want.occluded.iter().filter(|&&o| o).count();
        for s in StructureName::ALL {
            let accel = build_structure(s, mesh).unwrap_or_else(|e| panic!("{}: {s}: {e}", mesh.name));
            let got = trace(accel.as_ref(), &rays);
            assert_eq!(got.rays(), want.rays(), "{}: {s}: ray count", mesh.name);
            let mut bad = 0;
            for i in 0..want.rays() {
                let same = if rays.any_hit {
                    want.occluded[i] == got.occluded[i]
                } else {
                    hits_agree(&want.hits[i], &got.hits[i])
                };
                if !same {
                    bad += 1;
                    if bad <= 3 {
                        out.push(format!(
                            "{} {} {s}: ray {i} {:?}: reference {:?} {:?}, got {:?} {:?}",
                            mesh.name,
                            kind.as_str(),
                            rays.rays[i],
                            want.hits.get(i),
                            want.occluded.get(i),
                            got.hits.get(i),
                            got.occluded.get(i)
                        ));
                    }
                }
            }
            if bad > 3 {
                out.push(format!("{} {} {s}: {bad} rays disagree in all", mesh.name, kind.as_str()));
            }
        }
    }
    (out, hits)
}

#[test]
fn every_structure_equals_brute_force_on_the_degenerate_scenes() {
    let mut all = Vec::new();
    let mut checked = 0;
    for case in generated_cases(20_000).expect("cases") {
        for frame in case.frames.iter().take(2) {
            let brute = build_structure(StructureName::Brute, frame).expect("brute force");
            let (bad, hits) = disagreements(frame, brute.as_ref(), 48);
            all.extend(bad.into_iter().map(|b| format!("{}: {b}", case.name)));
            // A scene that the camera sees must produce hits, or the comparison proves nothing. Exceptions: the 1e30
            // soup (the f32 ray-triangle test hits nothing there, see docs/failure-study.md), zero-area triangles
            // (never hit), the 1e-30 soup (its edge products underflow f32), and one to ten small random triangles,
            // which a 48 x 48 image may miss.
            let exempt = ["huge", "zero_area", "tiny"];
            if !exempt.iter().any(|e| case.name.starts_with(e)) {
                assert!(hits > 0, "{}: no ray hits anything", case.name);
            }
            checked += 1;
        }
    }
    assert!(checked >= 20, "only {checked} scenes checked");
    assert!(all.is_empty(), "{} disagreements:\n{}", all.len(), all.join("\n"));
}

#[test]
fn every_structure_equals_the_bvh_on_every_shared_mesh() {
    let root = common::shared_meshes();
    let mut files: Vec<_> =
        ["stanford-bunny", "stanford-dragon", "dabrovic-sponza", "sibenik", "conference", "scans", "small"]
            .iter()
            .flat_map(|d| std::fs::read_dir(root.join(d)).expect("mesh folder").map(|e| e.expect("entry").path()))
            .filter(|p| p.extension().is_some_and(|e| e == "obj" || e == "ply"))
            .collect();
    files.push(
        root.join("bart/kitchen")
            .read_dir()
            .expect("kitchen")
            .map(|e| e.expect("entry").path())
            .min()
            .expect("a frame"),
    );
    files.sort();
    assert!(files.len() >= 25, "only {} shared meshes found", files.len());
    let mut all = Vec::new();
    for f in &files {
        let mesh = meshchar::mesh::load_mesh(f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        let bvh = build_structure(StructureName::Bvh, &mesh).expect("bvh");
        let (bad, hits) = disagreements(&mesh, bvh.as_ref(), 32);
        assert!(hits > 0, "{}: no ray hits anything", f.display());
        all.extend(bad);
    }
    assert!(all.is_empty(), "{} disagreements:\n{}", all.len(), all.join("\n"));
}

#[test]
fn the_lattice_with_diagonal_zero_area_triangles_fits_the_grid_and_agrees_with_brute_force() {
    use meshchar::accel::grid::{Grid, GridOptions};
    use meshchar::accel::AccelError;
    // 180,000 lattice triangles and 400 zero-area ones along the diagonal: stored in every cell of their bounding
    // boxes, the 400 would need 400 references in each of the 804,609 cells (41.6 s and 1.1 GB to build).
    let mesh = meshchar::mesh::generate::lattice_with_diagonal(300, 400);
    let n = mesh.triangle_count();
    assert_eq!((n, mesh.zero_area_count()), (180_400, 400));
    let grid = Grid::build(&mesh).expect("grid");
    let stats = grid.validate().expect("valid grid");
    let cells = grid.resolution().iter().map(|&r| r as usize).product::<usize>();
    assert!(stats.references < 16 * n && stats.references < cells * 3, "{stats:?}");
    // With a budget below what it needs, the same build stops with an error that says so.
    let tight = GridOptions { max_references_per_triangle: 4, min_reference_budget: 0, ..Default::default() };
    match Grid::build_with(&mesh, &tight) {
        Err(e @ AccelError::OverBudget { structure: "grid", .. }) => {
            let msg = e.to_string();
            assert!(msg.contains(&format!("budget of {}", 4 * n)) && msg.contains("cell references"), "{msg}");
        }
        other => panic!("a grid over a budget of 4 references per triangle: {:?}", other.map(|g| g.resolution())),
    }
    // Every structure builds, and agrees with brute force on the three workloads.
    let brute = build_structure(StructureName::Brute, &mesh).expect("brute force");
    let (bad, hits) = disagreements(&mesh, brute.as_ref(), 24);
    assert!(hits > 0, "no ray hits the lattice");
    assert!(bad.is_empty(), "{} disagreements:\n{}", bad.len(), bad.join("\n"));
}

/// `mesh` with the triangle of index `i` repeated `k` times (same vertex indices) for each `(i, k)`, the repeats
/// appended at the end.
fn with_index_copies(mesh: &Mesh, repeats: &[(usize, usize)]) -> Mesh {
    let mut out = mesh.clone();
    for &(i, k) in repeats {
        out.indices.extend(std::iter::repeat_n(mesh.indices[i], k));
    }
    out.name = format!("{} with index copies", mesh.name);
    out
}

#[test]
fn the_bvh_keeps_one_copy_of_a_triangle_and_changes_no_hit() {
    use meshchar::accel::bvh::Bvh;
    use meshchar::mesh::generate;
    // The fan of 3,000 triangles over three points: 1,000 copies each of the unit triangle and of its two zero-area
    // legs. A lattice with 100 copies of one of its triangles and 20 of another (fewer copies than a leaf holds are
    // left alone, in their leaf). Every structure still equals brute force, under the tie rule, on the three
    // workloads.
    let fan = generate::fan_polygon(3000);
    let lattice = with_index_copies(&generate::lattice_with_diagonal(20, 0), &[(17, 100), (401, 20)]);
    for (mesh, copies, kept) in [(&fan, 2997, 3), (&lattice, 120, 800)] {
        let bvh = Bvh::build(mesh).expect("bvh");
        assert_eq!(bvh.tree().copies().len(), copies, "{}", mesh.name);
        let stats = bvh.validate().expect("valid");
        assert_eq!((stats.triangles, stats.references), (mesh.triangle_count(), kept), "{}", mesh.name);
        let brute = build_structure(StructureName::Brute, mesh).expect("brute force");
        let (bad, hits) = disagreements(mesh, brute.as_ref(), 48);
        assert!(hits > 0 && bad.is_empty(), "{}: {hits} hits, disagreements:\n{}", mesh.name, bad.join("\n"));
    }
    // On the fan a ray tests one triangle instead of a thousand.
    let camera = Camera::frame(&mesh_bounds(&fan));
    let bvh = Bvh::build(&fan).expect("bvh");
    let rays = build_workload(WorkloadKind::Primary, &fan, &camera, 48, &bvh);
    let out = trace(&bvh, &rays);
    let hit = out.hits.iter().filter(|h| h.is_some()).count();
    assert!(hit > 0 && out.counters.prim_tests <= 3 * hit as u64, "{} tests, {hit} hits", out.counters.prim_tests);
    // The kept triangle is the first copy: index 0 for the unit triangle.
    assert!(out.hits.iter().flatten().all(|h| h.triangle == 0), "a hit on a later copy");
    // A refit to moved vertices keeps the copies copies: still valid, still equal to brute force.
    let mut moved = fan.clone();
    for p in moved.positions.iter_mut() {
        *p = [p[0] * 2.0 + 0.5, p[1] * 0.5 - 1.0, p[0] + p[1]];
    }
    let mut refitted = Bvh::build(&fan).expect("bvh");
    refitted.refit(&moved).expect("refit");
    refitted.validate().expect("valid after the refit");
    let brute = build_structure(StructureName::Brute, &moved).expect("brute force");
    let camera = Camera::frame(&mesh_bounds(&moved));
    for kind in [WorkloadKind::Primary, WorkloadKind::Shadow] {
        let rays = build_workload(kind, &moved, &camera, 32, brute.as_ref());
        let (want, got) = (trace(brute.as_ref(), &rays), trace(&refitted, &rays));
        assert_eq!(want.occluded, got.occluded, "{kind:?}");
        assert!(want.hits.iter().zip(&got.hits).all(|(a, b)| hits_agree(a, b)), "{kind:?}");
        assert!(want.hits.iter().chain(&got.hits).any(|h| h.is_some()) || rays.any_hit, "{kind:?}: no hit");
    }
}

/// `n` triangles with uniform random vertices in the unit square of the plane `z = 0`: their boxes overlap about a
/// quarter of the square each.
fn random_flat(n: usize, seed: u64) -> Mesh {
    let mut g = meshchar::rng::SplitMix64::new(seed);
    let positions: Vec<[f32; 3]> = (0..3 * n).map(|_| [g.next_f32(), g.next_f32(), 0.0]).collect();
    let indices = (0..n as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
    Mesh::new(format!("random flat n={n}"), positions, indices).expect("mesh")
}

#[test]
fn random_overlapping_triangles_in_one_plane_build_every_structure_and_agree() {
    use meshchar::accel::kdtree::{KdOptions, KdTree};
    // In a flat voxel the children's areas add up to their parent's, so the SAH keeps splitting however much it
    // duplicates: before the kd-tree shared its budget down the tree, 1,000 of these needed over 2^25 references.
    for (n, seed) in [(1000, 1), (300, 7)] {
        let mesh = random_flat(n, seed);
        let kd = KdTree::build(&mesh).expect("the kd-tree builds");
        let stats = kd.validate().expect("valid kd-tree");
        let budget = KdOptions::default().reference_budget(n);
        assert!(stats.references <= budget, "{}: {stats:?} over {budget}", mesh.name);
        let depth_limit = (8.0 + 1.3 * (n as f64).log2()).round() as usize;
        assert!(stats.max_depth <= depth_limit, "{}: {stats:?}", mesh.name);
        // A budget of its own is held too, however small.
        let small = KdOptions { max_references_per_triangle: 4, min_reference_budget: 0, ..Default::default() };
        let tight = KdTree::build_with(&mesh, &small).expect("a kd-tree under a small budget");
        let s = tight.validate().expect("valid under a small budget");
        assert!(s.references <= 4 * n && s.references >= n, "{}: {s:?}", mesh.name);
        let brute = build_structure(StructureName::Brute, &mesh).expect("brute force");
        let (bad, hits) = disagreements(&mesh, brute.as_ref(), 32);
        assert!(hits > 0, "{}: no ray hits the plane", mesh.name);
        assert!(bad.is_empty(), "{} disagreements:\n{}", bad.len(), bad.join("\n"));
    }
}

#[test]
fn copies_over_their_own_vertices_are_one_triangle_to_the_bvh_and_the_oracle() {
    use meshchar::accel::bvh::Bvh;
    use meshchar::eval::{evaluate_scene, OracleConfig};
    use meshchar::mesh::Animation;
    // 50,000 OBJ groups, each `f 1 2 3` over the same three vertices: the loader gives every group vertices of its
    // own, so the copies share positions, not indices.
    let dir = common::temp_dir("copies");
    let path = dir.join("copies.obj");
    let mut obj = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    for g in 0..50_000 {
        obj.push_str(&format!("g g{g}\nf 1 2 3\n"));
    }
    std::fs::write(&path, obj).expect("write the OBJ");
    let mesh = meshchar::mesh::load_mesh(&path).expect("load");
    assert_eq!(mesh.triangle_count(), 50_000);
    assert!(mesh.indices[1] != mesh.indices[0], "the loader shared the vertices; the test needs copies");
    let bvh = Bvh::build(&mesh).expect("bvh");
    assert_eq!(bvh.tree().copies().len(), 49_999);
    let stats = bvh.validate().expect("valid");
    assert_eq!((stats.triangles, stats.references), (50_000, 1));
    // Hits under the tie rule: triangle 0, as brute force finds it among the 50,000.
    let brute = build_structure(StructureName::Brute, &mesh).expect("brute force");
    let camera = Camera::frame(&mesh_bounds(&mesh));
    for kind in [WorkloadKind::Primary, WorkloadKind::Shadow] {
        let rays = build_workload(kind, &mesh, &camera, 24, brute.as_ref());
        let (want, got) = (trace(brute.as_ref(), &rays), trace(&bvh, &rays));
        assert_eq!(want.occluded, got.occluded, "{kind:?}");
        assert!(want.hits.iter().zip(&got.hits).all(|(a, b)| hits_agree(a, b)), "{kind:?}");
        assert!(got.hits.iter().flatten().all(|h| h.triangle == 0), "{kind:?}: a hit on a later copy");
        assert!(rays.any_hit || got.hits.iter().any(|h| h.is_some()), "{kind:?}: no hit");
    }
    // The oracle's reference is this BVH: the scene is measured, not refused over its trace budget.
    let scene = Animation::new("copies", vec![mesh.clone()]).expect("scene");
    let config =
        OracleConfig { resolution: 24, repeats: 1, structures: vec![StructureName::Bvh], ..Default::default() };
    let e = evaluate_scene(&scene, &config, None, &|_| {}).expect("the oracle measures the copies");
    let s = e.get(StructureName::Bvh).expect("bvh measured");
    assert!(s.valid && s.hits_agree, "{:?}", s.error);
    // A refit that moves one copy off the others fails, asking for a rebuild; one that moves all alike holds.
    let mut moved = mesh.clone();
    let v = moved.indices[7][1] as usize;
    moved.positions[v][0] += 0.25;
    let mut refitted = Bvh::build(&mesh).expect("bvh");
    let err = refitted.refit(&moved).expect_err("a refit past a separated copy");
    assert!(err.to_string().contains("rebuild"), "{err}");
    let mut shifted = mesh.clone();
    shifted.positions.iter_mut().for_each(|p| p[2] += 1.0);
    refitted = Bvh::build(&mesh).expect("bvh");
    refitted.refit(&shifted).expect("a refit that keeps the copies copies");
    refitted.validate().expect("valid after the refit");
    std::fs::remove_dir_all(&dir).ok();
}

/// 50,000 copies of one triangle, each over vertices of its own (as the OBJ loader gives 50,000 groups of `f 1 2 3`):
/// every structure builds within its default budgets, keeps one triangle of the group where it merges copies (the
/// grid: without merging, each copy would cover about half its cells, 2^25 references and more), and agrees with
/// brute force ray by ray on all three workloads.
#[test]
fn every_structure_builds_fifty_thousand_copies_and_agrees_with_brute_force() {
    let mut mesh = Mesh { name: "50,000 copies".into(), ..Default::default() };
    for k in 0..50_000u32 {
        mesh.positions.extend([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        mesh.indices.push([3 * k, 3 * k + 1, 3 * k + 2]);
    }
    for s in StructureName::ALL {
        let accel = build_structure(s, &mesh).unwrap_or_else(|e| panic!("{s}: {e}"));
        let stats = accel.validate().unwrap_or_else(|e| panic!("{s}: {e}"));
        assert_eq!(stats.triangles, 50_000, "{s}: {stats:?}");
        if s == StructureName::Grid {
            assert_eq!(stats.copies, 49_999, "{s}: {stats:?}");
        }
    }
    let brute = build_structure(StructureName::Brute, &mesh).expect("brute force");
    let (bad, hits) = disagreements(&mesh, brute.as_ref(), 12);
    assert!(hits > 0, "no ray hit the triangle");
    assert!(bad.is_empty(), "{} disagreements:\n{}", bad.len(), bad.join("\n"));
}

/// The kd-tree keeps one triangle of each group of coincident copies (bit-identical positions, each copy over
/// vertices of its own), the smallest index, and the BIH does where copies would overfill a leaf: their statistics
/// count the copies, `validate` accepts them, every structure agrees with brute force on all three workloads over a
/// soup with copies scattered through it, and on 20,000 copies of one triangle a ray tests the group once.
#[test]
fn the_kd_tree_and_the_bih_keep_one_triangle_of_each_group_of_copies() {
    // Random triangles grown 15 times about their centroids, so that they overlap and the rays hit them.
    let mut soup = meshchar::mesh::generate::random_soup(1500, 31);
    for t in soup.indices.clone() {
        let c: [f32; 3] = std::array::from_fn(|a| t.iter().map(|&v| soup.positions[v as usize][a]).sum::<f32>() / 3.0);
        for &v in &t {
            let p = &mut soup.positions[v as usize];
            *p = std::array::from_fn(|a| c[a] + 15.0 * (p[a] - c[a]));
        }
    }
    // Copies of every 7th triangle, one to three each, appended over vertices of their own, so that a group's kept
    // triangle (its smallest index) lies in the soup and its copies far later.
    let mut mesh = soup.clone();
    let mut expected = 0;
    for (i, t) in soup.indices.iter().enumerate().step_by(7) {
        for _ in 0..1 + i % 3 {
            let base = mesh.positions.len() as u32;
            mesh.positions.extend(t.iter().map(|&v| soup.positions[v as usize]));
            mesh.indices.push([base, base + 1, base + 2]);
            expected += 1;
        }
    }
    mesh.name = "soup with copies".into();
    let brute = build_structure(StructureName::Brute, &mesh).expect("brute force");
    let (bad, hits) = disagreements(&mesh, brute.as_ref(), 24);
    assert!(bad.is_empty(), "{}", bad.join("\n"));
    assert!(hits > 0, "no ray hit");
    let stats = build_structure(StructureName::KdTree, &mesh).expect("build").validate().expect("valid");
    assert_eq!((stats.triangles, stats.copies), (mesh.triangle_count(), expected));
    let stats = build_structure(StructureName::Bih, &mesh).expect("build").validate().expect("valid");
    assert!(stats.triangles == mesh.triangle_count() && stats.copies <= expected, "{stats:?}");
    // One triangle 20,000 times over vertices of its own: the group is tested once per ray.
    let mut stack = Mesh { name: "stack".into(), ..Default::default() };
    for k in 0..20_000u32 {
        stack.positions.extend([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        stack.indices.push([3 * k, 3 * k + 1, 3 * k + 2]);
    }
    let camera = Camera::frame(&mesh_bounds(&stack));
    let brute = build_structure(StructureName::Brute, &stack).expect("brute force");
    let rays = build_workload(WorkloadKind::Primary, &stack, &camera, 16, brute.as_ref());
    let want = trace(brute.as_ref(), &rays);
    for s in [StructureName::KdTree, StructureName::Bih] {
        let accel = build_structure(s, &stack).expect("build");
        assert_eq!(accel.validate().expect("valid").copies, 19_999, "{s}");
        let got = trace(accel.as_ref(), &rays);
        assert!(want.hits.iter().zip(&got.hits).all(|(a, b)| hits_agree(a, b)), "{s}");
        assert!(got.hits.iter().flatten().all(|h| h.triangle == 0), "{s}: a hit on a later copy");
        let per_ray = got.counters.prim_tests as f64 / got.rays() as f64;
        assert!(per_ray <= 2.0, "{s}: {per_ray} triangle tests per ray");
    }
}
