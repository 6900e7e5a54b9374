//! Acceleration-structure benches.
//!
//! * `build/<scene>/<structure>`: build time of every structure on bunny (69K), dragon (871K) and sponza (66K);
//!   criterion's throughput is triangles per second.
//! * `trace/<scene>/<structure>`: primary rays at 256 x 256 through every structure (throughput: rays/s).
//! * `crates/<scene>/...`: the same build and trace with the crates a Rust user would pick instead (`bvh` 0.13 with
//!   its rayon build, `obvhs` 0.4 BVH2 with the `medium_build` preset).
//! * `side_by_side`: one run that prints, per scene (the three above and four scans the builders were never tuned
//!   on), build Mtris/s, trace Mrays/s (medians of 9), SAH cost (`K_T = K_I = 1`, see `meshchar::accel::sah_cost`)
//!   and hit agreement with our BVH, for our six structures, `bvh` 0.13 and `obvhs` 0.4 (medium and fastest
//!   presets), then the ratios: our binned-SAH BVH against obvhs's medium preset, our LBVH against its fastest
//!   (PLOC). Each ratio is measured twice: with ours and obvhs's alternating (19 builds, 27 traces of each, medians;
//!   the headline) and, in parentheses, from the two blocks of 9 timed one after the other. The kd-tree's SAH column is its own cost (voxel areas over the root's, `K_T = K_I = 1`), not
//!   comparable with the BVHs'; the BIH's is over its nodes' boxes; the grid prints none.
//!
//! * `screen_crossings/<scene>`: the overlap floor's count of triangle boxes on a camera's image
//!   (`meshchar::cost::screen_crossings`, framing camera), the boxes its sample rays enter before their first hits
//!   (`meshchar::cost::near_crossings`, `near`), each structure the policy probes built and traced on the same
//!   sample and the shadow and diffuse rays its hits start, as the policy probes (`meshchar::cost::probe`,
//!   `probe_<structure>`), and the whole `BuildBounds::of_mesh_viewed` pass all are
//!   part of, on the three scenes above and the generated engineering family at 200K triangles seen close up.
//!
//! Scenes come from `../shared/meshes`; the bench fails naming the path when they are missing.
//! Run: `cargo bench --bench accel` (filter with e.g. `-- side_by_side` or `-- build/bunny`).

mod common;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use meshchar::accel::{build_structure, StructureName};
use meshchar::geom::Camera;
use meshchar::geom::Ray;
use meshchar::geom::WorkloadKind;
use meshchar::mesh::Mesh;
use meshchar::trace::workload::{mesh_bounds, primary_rays};
use meshchar::trace::{trace, RaySet};
use rayon::prelude::*;
use std::time::{Duration, Instant};

const SCENES: [(&str, &str); 3] = [
    ("bunny", "stanford-bunny/bun_zipper.ply"),
    ("dragon", "stanford-dragon/dragon_vrip.ply"),
    ("sponza", "dabrovic-sponza/sponza.obj"),
];

const RES: u32 = 256;

fn scenes() -> Vec<(&'static str, Mesh)> {
    SCENES.iter().map(|(name, rel)| (*name, common::load_shared(rel))).collect()
}

fn rays_for(mesh: &Mesh) -> RaySet {
    let cam = Camera::frame(&mesh_bounds(mesh));
    RaySet { kind: WorkloadKind::Primary, rays: primary_rays(&cam, RES, RES), any_hit: false }
}

// ---------------------------------------------------------------------------------------------------------------
// The `bvh` crate.

mod bvh_crate {
    use super::*;
    use bvh::aabb::{Aabb, Bounded};
    use bvh::bounding_hierarchy::{BHShape, BoundingHierarchy};
    use bvh::bvh::{Bvh, BvhNode};
    use nalgebra::{Point3, Vector3};

    pub struct Tri {
        pub v: [Point3<f32>; 3],
        pub idx: usize,
        pub node: usize,
    }

    impl Bounded<f32, 3> for Tri {
        fn aabb(&self) -> Aabb<f32, 3> {
            Aabb::empty().grow(&self.v[0]).grow(&self.v[1]).grow(&self.v[2])
        }
    }

    impl BHShape<f32, 3> for Tri {
        fn set_bh_node_index(&mut self, i: usize) {
            self.node = i;
        }
        fn bh_node_index(&self) -> usize {
            self.node
        }
    }

    pub fn shapes(mesh: &Mesh) -> Vec<Tri> {
        (0..mesh.triangle_count())
            .map(|i| {
                let t = mesh.triangle(i);
                Tri { v: t.map(|p| Point3::new(p.x, p.y, p.z)), idx: i, node: 0 }
            })
            .collect()
    }

    pub fn build(shapes: &mut [Tri]) -> Bvh<f32, 3> {
        Bvh::build_par(shapes)
    }

    /// Closest hit: shapes in near-to-far order of their boxes, stopping once a box starts beyond the best hit.
    pub fn closest(bvh: &Bvh<f32, 3>, shapes: &[Tri], r: &Ray) -> Option<(f32, usize)> {
        let o = Point3::new(r.origin.x, r.origin.y, r.origin.z);
        let d = Vector3::new(r.dir.x, r.dir.y, r.dir.z);
        let ray = bvh::ray::Ray::new(o, d);
        let mut best: Option<(f32, usize)> = None;
        for s in bvh.nearest_traverse_iterator(&ray, shapes) {
            if let (Some((t0, _)), Some((bt, _))) = (ray.intersection_slice_for_aabb(&s.aabb()), best) {
                if t0 > bt {
                    break;
                }
            }
            let hit = ray.intersects_triangle(&s.v[0], &s.v[1], &s.v[2]);
            if hit.distance.is_finite() && hit.distance > 0.0 && best.is_none_or(|(bt, _)| hit.distance < bt) {
                best = Some((hit.distance, s.idx));
            }
        }
        best
    }

    /// SAH cost with `K_T = K_I = 1` (leaves hold one shape each).
    pub fn sah(bvh: &Bvh<f32, 3>) -> f64 {
        let area = |b: &Aabb<f32, 3>| b.surface_area() as f64;
        let Some(root) = bvh.nodes.first() else { return 0.0 };
        let root_area = match root {
            BvhNode::Node { child_l_aabb, child_r_aabb, .. } => area(&child_l_aabb.join(child_r_aabb)),
            BvhNode::Leaf { .. } => return 1.0,
        };
        let mut items = vec![(root_area, false, 0)];
        for n in &bvh.nodes {
            if let BvhNode::Node { child_l_index, child_l_aabb, child_r_index, child_r_aabb, .. } = n {
                for (i, b) in [(child_l_index, child_l_aabb), (child_r_index, child_r_aabb)] {
                    let leaf = matches!(bvh.nodes[*i], BvhNode::Leaf { .. });
                    items.push((area(b), leaf, usize::from(leaf)));
                }
            }
        }
        meshchar::accel::sah_cost(root_area, items.into_iter())
    }
}

// ---------------------------------------------------------------------------------------------------------------
// The `obvhs` crate.

mod obvhs_crate {
    use super::*;
    use glam_obvhs::Vec3A;
    use obvhs::bvh2::builder::build_bvh2_from_tris;
    use obvhs::bvh2::Bvh2;
    use obvhs::ray::{Ray as ORay, RayHit};
    use obvhs::triangle::Triangle;
    use obvhs::BvhBuildParams;

    pub fn tris(mesh: &Mesh) -> Vec<Triangle> {
        (0..mesh.triangle_count())
            .map(|i| {
                let [a, b, c] = mesh.triangle(i).map(|p| Vec3A::new(p.x, p.y, p.z));
                Triangle { v0: a, v1: b, v2: c }
            })
            .collect()
    }

    /// Builds with the `medium_build` preset and reorders the triangles by `primitive_indices`, as obvhs advises
    /// (part of the build time). Returns the tree, the reordered triangles and their mesh indices.
    pub fn build(tris: &[Triangle]) -> (Bvh2, Vec<Triangle>, Vec<u32>) {
        build_with(tris, BvhBuildParams::medium_build())
    }

    /// [`build`] with the `fastest_build` preset (PLOC).
    pub fn build_fastest(tris: &[Triangle]) -> (Bvh2, Vec<Triangle>, Vec<u32>) {
        build_with(tris, BvhBuildParams::fastest_build())
    }

    fn build_with(tris: &[Triangle], params: BvhBuildParams) -> (Bvh2, Vec<Triangle>, Vec<u32>) {
        let mut t = Duration::ZERO;
        let bvh = build_bvh2_from_tris(tris, params, &mut t);
        let ids = bvh.primitive_indices.clone();
        let ordered = ids.iter().map(|&i| tris[i as usize]).collect();
        (bvh, ordered, ids)
    }

    pub fn closest(bvh: &Bvh2, tris: &[Triangle], ids: &[u32], r: &Ray) -> Option<(f32, usize)> {
        let ray = ORay::new_inf(Vec3A::new(r.origin.x, r.origin.y, r.origin.z), Vec3A::new(r.dir.x, r.dir.y, r.dir.z));
        let mut hit = RayHit::none();
        if bvh.ray_traverse(ray, &mut hit, |ray, id| tris[id].intersect(ray)) {
            Some((hit.t, ids[hit.primitive_id as usize] as usize))
        } else {
            None
        }
    }

    pub fn sah(bvh: &Bvh2) -> f64 {
        let Some(root) = bvh.nodes.first() else { return 0.0 };
        let root_area = 2.0 * root.aabb().half_area() as f64;
        meshchar::accel::sah_cost(
            root_area,
            bvh.nodes.iter().map(|n| (2.0 * n.aabb().half_area() as f64, n.is_leaf(), n.prim_count as usize)),
        )
    }
}

// ---------------------------------------------------------------------------------------------------------------

fn bench_build(c: &mut Criterion) {
    for (scene, mesh) in scenes() {
        let mut g = c.benchmark_group(format!("build/{scene}"));
        g.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
        g.throughput(Throughput::Elements(mesh.triangle_count() as u64));
        for name in StructureName::ALL {
            g.bench_function(BenchmarkId::from_parameter(name), |b| {
                b.iter(|| build_structure(name, &mesh).unwrap_or_else(|e| panic!("{e}")))
            });
        }
        g.finish();
    }
}

fn bench_trace(c: &mut Criterion) {
    for (scene, mesh) in scenes() {
        let rays = rays_for(&mesh);
        let mut g = c.benchmark_group(format!("trace/{scene}"));
        g.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
        g.throughput(Throughput::Elements(rays.rays.len() as u64));
        for name in StructureName::ALL {
            let s = build_structure(name, &mesh).unwrap_or_else(|e| panic!("{e}"));
            g.bench_function(BenchmarkId::from_parameter(name), |b| b.iter(|| trace(s.as_ref(), &rays)));
        }
        g.finish();
    }
}

fn bench_screen_crossings(c: &mut Criterion) {
    use meshchar::geom::Aabb;
    let mut all = scenes();
    let family = meshchar::mesh::families::generate(meshchar::mesh::families::Family::Engineering, 200_000, 1)
        .unwrap_or_else(|e| panic!("{e}"));
    all.push(("engineering-200k", family));
    for (scene, mesh) in all {
        let (boxes, tris): (Vec<Aabb>, Vec<meshchar::geom::Triangle>) = (0..mesh.triangle_count())
            .map(|i| {
                let v = mesh.triangle(i);
                (Aabb::of_triangle(&v), meshchar::geom::Triangle::new(&v))
            })
            .unzip();
        let b = boxes.iter().fold(Aabb::EMPTY, |a, x| a.union(x));
        let camera = if scene == "engineering-200k" {
            meshchar::trace::views::View::CloseUp.camera(&b)
        } else {
            meshchar::geom::Camera::frame(&b)
        };
        let mut g = c.benchmark_group(format!("screen_crossings/{scene}"));
        g.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(2));
        g.throughput(Throughput::Elements(mesh.triangle_count() as u64));
        g.bench_function("count", |x| x.iter(|| meshchar::cost::screen_crossings(&boxes, &camera)));
        let image = meshchar::cost::screen_crossings(&boxes, &camera);
        g.bench_function("near", |x| x.iter(|| meshchar::cost::near_crossings(&boxes, &tris, &camera, image)));
        let side = meshchar::cost::near_sample_side(image);
        for s in meshchar::cost::PROBED {
            g.bench_function(format!("probe_{s}"), |x| {
                x.iter(|| meshchar::cost::probe(s, &mesh, &b, &camera, side, true))
            });
        }
        g.bench_function("build_bounds", |x| {
            x.iter(|| {
                meshchar::select::BuildBounds::of_mesh_viewed(&mesh, Some(&camera)).unwrap_or_else(|e| panic!("{e}"))
            })
        });
        g.finish();
    }
}

fn bench_crates(c: &mut Criterion) {
    for (scene, mesh) in scenes() {
        let rays = rays_for(&mesh);
        let mut g = c.benchmark_group(format!("crates/{scene}"));
        g.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
        g.throughput(Throughput::Elements(mesh.triangle_count() as u64));
        g.bench_function("build/bvh-crate", |b| {
            b.iter_batched(
                || bvh_crate::shapes(&mesh),
                |mut s| bvh_crate::build(&mut s),
                criterion::BatchSize::LargeInput,
            )
        });
        let otris = obvhs_crate::tris(&mesh);
        g.bench_function("build/obvhs", |b| b.iter(|| obvhs_crate::build(&otris)));
        g.throughput(Throughput::Elements(rays.rays.len() as u64));
        let mut shapes = bvh_crate::shapes(&mesh);
        let bvh = bvh_crate::build(&mut shapes);
        g.bench_function("trace/bvh-crate", |b| {
            b.iter(|| rays.rays.par_iter().map(|r| bvh_crate::closest(&bvh, &shapes, r)).collect::<Vec<_>>())
        });
        let (ob, ot, oid) = obvhs_crate::build(&otris);
        g.bench_function("trace/obvhs", |b| {
            b.iter(|| rays.rays.par_iter().map(|r| obvhs_crate::closest(&ob, &ot, &oid, r)).collect::<Vec<_>>())
        });
        g.finish();
    }
}

fn median_of<T>(reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..reps {
        let t = Instant::now();
        last = Some(f());
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], last.expect("at least one repeat"))
}

/// Medians of `reps` timings of `a` and of `b`, run alternately in the order a b b a a b b a ... (so that neither
/// always runs first).
fn interleaved<A, B>(reps: usize, mut a: impl FnMut() -> A, mut b: impl FnMut() -> B) -> (f64, f64) {
    let (mut ta, mut tb) = (Vec::new(), Vec::new());
    let mut time_a = |ta: &mut Vec<f64>| {
        let t = Instant::now();
        std::hint::black_box(a());
        ta.push(t.elapsed().as_secs_f64());
    };
    let mut time_b = |tb: &mut Vec<f64>| {
        let t = Instant::now();
        std::hint::black_box(b());
        tb.push(t.elapsed().as_secs_f64());
    };
    for i in 0..reps {
        if i % 2 == 0 {
            time_a(&mut ta);
            time_b(&mut tb);
        } else {
            time_b(&mut tb);
            time_a(&mut ta);
        }
    }
    ta.sort_by(f64::total_cmp);
    tb.sort_by(f64::total_cmp);
    (ta[reps / 2], tb[reps / 2])
}

/// Hits that differ from ours in triangle, allowing equal distances (ties) and the rounding of other triangle tests.
fn disagreements(ours: &[Option<meshchar::geom::Hit>], theirs: &[Option<(f32, usize)>]) -> usize {
    ours.iter()
        .zip(theirs)
        .filter(|(a, b)| match (a, b) {
            (None, None) => false,
            (Some(a), Some((t, i))) => a.triangle as usize != *i && (a.t - t).abs() > 1e-4 * a.t.abs().max(1.0),
            _ => true,
        })
        .count()
}

/// Scenes of `side_by_side` beside [`SCENES`]: scans the builders were never tuned on.
const UNTUNED: [(&str, &str); 4] = [
    ("buddha", "scans/happy-buddha-100k.obj"),
    ("lucy", "scans/lucy-52k.obj"),
    ("nefertiti", "scans/nefertiti.obj"),
    ("igea", "scans/igea.ply"),
];

fn side_by_side(_: &mut Criterion) {
    // Runs when no filter is given or the filter names it (criterion's filters only apply to its own benches).
    let filters: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    if !filters.is_empty() && !filters.iter().any(|f| "side_by_side".contains(f.as_str())) {
        return;
    }
    const REPS: usize = 9;
    println!("\nside by side: primary rays {RES}x{RES}, medians of {REPS}, rayon over rays, SAH with K_T = K_I = 1");
    println!(
        "{:<8} {:<22} {:>12} {:>12} {:>10} {:>14}",
        "scene", "structure", "build Mtri/s", "trace Mray/s", "SAH", "hits differ"
    );
    let untuned = UNTUNED.iter().map(|(name, rel)| (*name, common::load_shared(rel)));
    // Per scene: (ours / obvhs medium) build and trace speed, SAH of each; (our LBVH / obvhs fastest) build speed,
    // SAH of each.
    let mut ratios = Vec::new();
    for (scene, mesh) in scenes().into_iter().chain(untuned) {
        let n = mesh.triangle_count() as f64;
        let rays = rays_for(&mesh);
        let nr = rays.rays.len() as f64;
        let mut lbvh = (0.0, 0.0);
        let (bt, ours) =
            median_of(REPS, || build_structure(StructureName::Bvh, &mesh).unwrap_or_else(|e| panic!("{e}")));
        let (tt, out) = median_of(REPS, || trace(ours.as_ref(), &rays));
        let row = |name: &str, bt: f64, tt: f64, sah: f64, bad: usize| {
            println!("{scene:<8} {name:<22} {:>12.2} {:>12.2} {:>10.1} {:>14}", n / bt / 1e6, nr / tt / 1e6, sah, bad)
        };
        row("meshchar bvh", bt, tt, ours.sah_cost().unwrap_or(f64::NAN), 0);
        for name in
            [StructureName::Lbvh, StructureName::Hlbvh, StructureName::KdTree, StructureName::Grid, StructureName::Bih]
        {
            let (b, s) = median_of(REPS, || build_structure(name, &mesh).unwrap_or_else(|e| panic!("{e}")));
            let (t, o) = median_of(REPS, || trace(s.as_ref(), &rays));
            let bad = meshchar::trace::count_disagreements(&o, &out);
            row(&format!("meshchar {name}"), b, t, s.sah_cost().unwrap_or(f64::NAN), bad);
            if name == StructureName::Lbvh {
                lbvh = (b, s.sah_cost().unwrap_or(f64::NAN));
            }
        }
        let (b, (shapes, bvh)) = median_of(REPS, || {
            let mut s = bvh_crate::shapes(&mesh);
            let b = bvh_crate::build(&mut s);
            (s, b)
        });
        let (t, hits) =
            median_of(REPS, || rays.rays.par_iter().map(|r| bvh_crate::closest(&bvh, &shapes, r)).collect::<Vec<_>>());
        row("bvh 0.13 (build_par)", b, t, bvh_crate::sah(&bvh), disagreements(&out.hits, &hits));
        let otris = obvhs_crate::tris(&mesh);
        let (b, (ob, ot, oid)) = median_of(REPS, || obvhs_crate::build(&otris));
        let (t, hits) = median_of(REPS, || {
            rays.rays.par_iter().map(|r| obvhs_crate::closest(&ob, &ot, &oid, r)).collect::<Vec<_>>()
        });
        row("obvhs 0.4 (medium)", b, t, obvhs_crate::sah(&ob), disagreements(&out.hits, &hits));
        let medium = (b, t, obvhs_crate::sah(&ob));
        // The trace ratio again with the two traces alternating, so that the machine's drift between the two
        // blocks above (ours is timed first, obvhs a few seconds later) hits both alike.
        let (ours_t, theirs_t) = interleaved(
            3 * REPS,
            || trace(ours.as_ref(), &rays),
            || rays.rays.par_iter().map(|r| obvhs_crate::closest(&ob, &ot, &oid, r)).collect::<Vec<_>>(),
        );
        let (b, (fb, ft, fid)) = median_of(REPS, || obvhs_crate::build_fastest(&otris));
        let (t, hits) = median_of(REPS, || {
            rays.rays.par_iter().map(|r| obvhs_crate::closest(&fb, &ft, &fid, r)).collect::<Vec<_>>()
        });
        row("obvhs 0.4 (fastest)", b, t, obvhs_crate::sah(&fb), disagreements(&out.hits, &hits));
        // The build ratios again with the builds alternating, as the trace's.
        let (ours_b, theirs_b) = interleaved(
            2 * REPS + 1,
            || build_structure(StructureName::Bvh, &mesh).unwrap_or_else(|e| panic!("{e}")),
            || obvhs_crate::build(&otris),
        );
        let (ours_l, theirs_f) = interleaved(
            2 * REPS + 1,
            || build_structure(StructureName::Lbvh, &mesh).unwrap_or_else(|e| panic!("{e}")),
            || obvhs_crate::build_fastest(&otris),
        );
        ratios.push(Ratios {
            scene,
            build: (theirs_b / ours_b, medium.0 / bt),
            trace: (theirs_t / ours_t, medium.1 / tt),
            sah: (ours.sah_cost().unwrap_or(f64::NAN), medium.2),
            lbvh_build: (theirs_f / ours_l, b / lbvh.0),
            lbvh_sah: (lbvh.1, obvhs_crate::sah(&fb)),
        });
    }
    println!(
        "\nratios (speed of ours / speed of obvhs, > 1 is faster; measured in this run, {} threads): each from the two \
         alternating ({} builds, {} traces of each), then in parentheses from the two blocks above",
        rayon::current_num_threads(),
        2 * REPS + 1,
        3 * REPS
    );
    println!(
        "{:<10} {:>22} {:>22} {:>18} {:>22} {:>18}",
        "scene",
        "bvh / medium build",
        "bvh / medium trace",
        "SAH bvh, medium",
        "lbvh / fastest build",
        "SAH lbvh, fastest"
    );
    let pair = |(a, b): (f64, f64)| format!("{a:.2}x ({b:.2}x)");
    for r in ratios {
        println!(
            "{:<10} {:>22} {:>22} {:>8.1}, {:>7.1} {:>22} {:>8.1}, {:>7.1}",
            r.scene,
            pair(r.build),
            pair(r.trace),
            r.sah.0,
            r.sah.1,
            pair(r.lbvh_build),
            r.lbvh_sah.0,
            r.lbvh_sah.1
        );
    }
}

/// One scene's ratios of [`side_by_side`]: speeds of ours over obvhs's, `(alternating, in sequence)`, and SAH costs
/// `(ours, obvhs's)`.
struct Ratios {
    scene: &'static str,
    build: (f64, f64),
    trace: (f64, f64),
    sah: (f64, f64),
    lbvh_build: (f64, f64),
    lbvh_sah: (f64, f64),
}

criterion_group!(benches, side_by_side, bench_build, bench_trace, bench_crates, bench_screen_crossings);
criterion_main!(benches);
