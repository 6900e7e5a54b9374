//! Device traversal (`glsl/trace.comp`) against the CPU tracer, ray by ray: for every structure (BVH, kd-tree, grid,
//! BIH, LBVH, HLBVH), every ray's hit triangle, `t`, `u` and `v` bits and its box and triangle test counts equal what
//! `AccelStructure::intersect` / `occluded` give for the same ray, on every shared static mesh, the first frame of
//! three BART animations, the degenerate generators and random rays (zero and negative-zero direction components,
//! origins inside and outside).
//! With the validation layer on; every GPU test fails (never skips) under `REQUIRE_GPU=1`.

use crate::common;
use crate::gpu_support;

use glam::Vec3;
use meshchar::accel::device_trace::{DeviceLayout, DeviceStructure, DeviceTracer, TraceRay};
use meshchar::accel::{build_structure, AccelStructure, StructureName};
use meshchar::geom::Camera;
use meshchar::geom::{Ray, TraceCounters, WorkloadKind};
use meshchar::gpu::Context;
use meshchar::mesh::{generate, load::load_mesh, Mesh};
use meshchar::rng::SplitMix64;
use meshchar::trace::workload::{build_workload, mesh_bounds};

/// Traces `rays` on the device through `accel` and compares every ray with the CPU. Returns the rays that hit.
fn check(
    ctx: &Context,
    tracer: &DeviceTracer,
    what: &str,
    accel: &dyn AccelStructure,
    rays: &[Ray],
    any: bool,
) -> usize {
    let layout = accel.device_layout().expect("every structure but brute force has a device layout");
    let mut s = DeviceStructure::upload(ctx, &layout).unwrap_or_else(|e| panic!("{what}: upload: {e}"));
    let dev_rays: Vec<TraceRay> = rays.iter().map(TraceRay::from).collect();
    let out = tracer.trace(ctx, &mut s, &dev_rays, any).unwrap_or_else(|e| panic!("{what}: trace: {e}"));
    assert_eq!(out.hits.len(), rays.len());
    let mut hits = 0;
    for (i, (r, g)) in rays.iter().zip(&out.hits).enumerate() {
        let mut c = TraceCounters::default();
        let (cpu, gpu) = if any {
            let occ = accel.occluded(r, &mut c);
            (occ.then_some(()).map(|_| 0u32), g.hit().map(|_| 0u32))
        } else {
            let h = accel.intersect(r, &mut c);
            let g = g.hit();
            if let (Some(h), Some(gh)) = (h, g) {
                assert!(
                    h.triangle == gh.triangle
                        && h.t.to_bits() == gh.t.to_bits()
                        && h.u.to_bits() == gh.u.to_bits()
                        && h.v.to_bits() == gh.v.to_bits(),
                    "{what}: ray {i} {r:?}: CPU {h:?}, device {gh:?}"
                );
            }
            (h.map(|h| h.triangle), g.map(|h| h.triangle))
        };
        assert_eq!(cpu, gpu, "{what}: ray {i} {r:?}: hit (CPU, device)");
        assert_eq!(
            (c.box_tests, c.prim_tests),
            (g.box_tests as u64, g.prim_tests as u64),
            "{what}: ray {i} {r:?}: (box, triangle) tests (CPU, device)"
        );
        hits += cpu.is_some() as usize;
    }
    hits
}

/// Primary, shadow and diffuse rays of the framing camera at `res x res`.
fn workloads(mesh: &Mesh, res: u32) -> Vec<(WorkloadKind, Vec<Ray>, bool)> {
    let camera = Camera::frame(&mesh_bounds(mesh));
    let reference = build_structure(StructureName::Bvh, mesh).expect("reference BVH");
    [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse]
        .into_iter()
        .map(|k| {
            let set = build_workload(k, mesh, &camera, res, reference.as_ref());
            (k, set.rays, set.any_hit)
        })
        .collect()
}

/// Random rays: origins in and around the scene box, directions with some components exactly `0.0` or `-0.0`, a
/// few with a positive `tmin` and a finite `tmax`.
fn random_rays(mesh: &Mesh, n: usize, seed: u64) -> Vec<Ray> {
    let b = mesh_bounds(mesh);
    let (lo, hi) = if b.is_empty() { (Vec3::splat(-1.0), Vec3::splat(1.0)) } else { (b.min, b.max) };
    let ext = (hi - lo).max(Vec3::splat(1e-3));
    let mut g = SplitMix64::new(seed);
    let c = |g: &mut SplitMix64| g.range(-0.5, 1.5) as f32;
    (0..n)
        .map(|i| {
            let o = lo + ext * Vec3::new(c(&mut g), c(&mut g), c(&mut g));
            let target = lo + ext * Vec3::new(g.next_f32(), g.next_f32(), g.next_f32());
            let mut d = target - o;
            for a in 0..3 {
                match g.below(8) {
                    0 => d[a] = 0.0,
                    1 => d[a] = -0.0,
                    _ => {}
                }
            }
            if d == Vec3::ZERO {
                d = Vec3::X;
            }
            let mut r = Ray::new(o, d);
            if i % 7 == 0 {
                r.tmin = 1e-3;
                r.tmax = 0.75;
            }
            r
        })
        .collect()
}

fn check_mesh(ctx: &Context, tracer: &DeviceTracer, name: &str, mesh: &Mesh, res: u32, random: usize) {
    let loads = workloads(mesh, res);
    let random = random_rays(mesh, random, 0x7261_7973 ^ mesh.triangle_count() as u64);
    for s in StructureName::ALL {
        let accel = match build_structure(s, mesh) {
            Ok(a) => a,
            // A structure over its reference budget is reported by the oracle; nothing to trace.
            Err(meshchar::accel::AccelError::OverBudget { .. }) => continue,
            Err(e) => panic!("{name}: {s:?}: {e}"),
        };
        for (k, rays, any) in &loads {
            check(ctx, tracer, &format!("{name} {s:?} {k:?}"), accel.as_ref(), rays, *any);
        }
        check(ctx, tracer, &format!("{name} {s:?} random"), accel.as_ref(), &random, false);
        check(ctx, tracer, &format!("{name} {s:?} random any"), accel.as_ref(), &random, true);
    }
}

#[test]
fn device_traversal_equals_cpu_on_shared_meshes() {
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    for (rel, res) in [
        ("small/bunny-lowres-pd.obj", 48),
        ("small/teapot-pd.obj", 48),
        ("small/suzanne.obj", 48),
        ("small/cow.obj", 48),
        ("small/fandisk.obj", 48),
        ("small/homer.obj", 48),
        ("small/spot.obj", 48),
        ("small/rocker-arm.obj", 48),
        ("stanford-bunny/bun_zipper.ply", 64),
        ("dabrovic-sponza/sponza.obj", 64),
        ("sibenik/sibenik.obj", 64),
        ("conference/conference.obj", 64),
        ("bart/robots/robots_f0000.obj", 64),
    ] {
        let mesh = load_mesh(&common::shared_mesh(rel)).unwrap();
        check_mesh(&ctx, &tracer, rel, &mesh, res, 1024);
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn device_traversal_equals_cpu_on_every_other_shared_mesh() {
    // The scans, the lower resolutions of the bunny and the dragon, and the first frame of every BART animation
    // (the meshes of the test above and the full dragon, below, aside), at fewer rays.
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    let root = common::shared_meshes();
    let listed = |d: &str| -> Vec<std::path::PathBuf> {
        let mut v: Vec<_> =
            std::fs::read_dir(root.join(d)).expect("mesh folder").map(|e| e.expect("entry").path()).collect();
        v.sort();
        v
    };
    let mut files: Vec<std::path::PathBuf> = listed("scans");
    files.extend(listed("stanford-bunny").into_iter().filter(|p| p.to_string_lossy().contains("_res")));
    files.extend(listed("stanford-dragon").into_iter().filter(|p| p.to_string_lossy().contains("_res")));
    for anim in ["kitchen", "museum5", "robots"] {
        files.extend(
            listed(&format!("bart/{anim}")).into_iter().filter(|p| p.extension().is_some_and(|e| e == "obj")).take(1),
        );
    }
    let files: Vec<_> = files.into_iter().filter(|p| p.extension().is_some_and(|e| e == "obj" || e == "ply")).collect();
    assert!(files.len() >= 15, "only {} meshes found", files.len());
    for f in &files {
        let mesh = load_mesh(f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        check_mesh(&ctx, &tracer, &f.display().to_string(), &mesh, 32, 256);
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn device_traversal_equals_cpu_on_the_dragon() {
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    let mesh = load_mesh(&common::shared_mesh("stanford-dragon/dragon_vrip.ply")).unwrap();
    check_mesh(&ctx, &tracer, "dragon", &mesh, 32, 256);
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn device_traversal_equals_cpu_on_degenerate_meshes() {
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    let mut cases: Vec<(&str, Mesh)> = vec![("empty", Mesh::new("empty", vec![], vec![]).unwrap())];
    cases.extend(common::degenerate_scenes());
    for (name, mesh) in &cases {
        check_mesh(&ctx, &tracer, name, mesh, 24, 512);
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn device_traversal_equals_cpu_on_the_failure_study_scenes() {
    // The failure study's generated scenes (flat, collinear, all equal, 1e30 and 1e-30, slivers, overlapping, ...),
    // two frames of each, smaller than the study's own.
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    let cases = meshchar::eval::failure_study::generated_cases(2000).expect("cases");
    assert!(cases.len() >= 10, "only {} cases", cases.len());
    for case in &cases {
        for (f, frame) in case.frames.iter().take(2).enumerate() {
            check_mesh(&ctx, &tracer, &format!("{} frame {f}", case.name), frame, 24, 256);
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// A hand-made BVH 300 levels deep (a chain: each internal node holds a leaf and the rest of the chain) is traced
/// with a stack sized from its depth: every ray finds the triangle the brute force finds.
#[test]
fn deep_chain_bvh_uses_a_stack_sized_from_its_depth() {
    use meshchar::accel::bvh::BvhNode;
    use meshchar::geom::{Aabb, Triangle};
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    let depth = 300usize;
    // Triangle k lies in the plane z = k, over [0, 1]^2; node 2k is internal (children 2k + 1: leaf of triangle k,
    // 2k + 2: the rest), the last node is the leaf of the last triangle.
    let verts: Vec<[Vec3; 3]> = (0..=depth)
        .map(|k| {
            let z = k as f32;
            [Vec3::new(0.0, 0.0, z), Vec3::new(1.0, 0.0, z), Vec3::new(0.0, 1.0, z)]
        })
        .collect();
    let tris: Vec<Triangle> = verts.iter().map(Triangle::new).collect();
    let ids: Vec<u32> = (0..=depth as u32).collect();
    let boxed = |from: usize| Aabb::new(Vec3::new(0.0, 0.0, from as f32), Vec3::new(1.0, 1.0, depth as f32));
    let mut nodes = Vec::new();
    for k in 0..depth {
        let here = nodes.len() as u32;
        nodes.push(BvhNode::internal(&boxed(k), here + 1, here + 2));
        nodes.push(BvhNode::leaf(
            &Aabb::new(Vec3::new(0.0, 0.0, k as f32), Vec3::new(1.0, 1.0, k as f32)),
            k as u32,
            1,
        ));
    }
    nodes.push(BvhNode::leaf(&boxed(depth), depth as u32, 1));
    let layout = DeviceLayout::Bvh { nodes: &nodes, tris: &tris, ids: &ids };
    let mut s = DeviceStructure::upload(&ctx, &layout).expect("upload");
    assert_eq!(s.stack_entries(), depth as u32 + 1);
    // Rays from below (+z) and from above (-z): the closest hits are triangle 0 and triangle `depth`.
    let rays: Vec<TraceRay> = (0..64)
        .map(|i| {
            let x = 0.05 + (i % 8) as f32 * 0.05;
            let y = 0.05 + (i / 8) as f32 * 0.05;
            let up = i % 2 == 0;
            let o = Vec3::new(x, y, if up { -1.0 } else { depth as f32 + 1.0 });
            TraceRay::from(&Ray::new(o, Vec3::new(0.0, 0.0, if up { 1.0 } else { -1.0 })))
        })
        .collect();
    let out = tracer.trace(&ctx, &mut s, &rays, false).expect("trace");
    for (i, h) in out.hits.iter().enumerate() {
        let want = if i % 2 == 0 { 0 } else { depth as u32 };
        assert_eq!(h.hit().map(|h| h.triangle), Some(want), "ray {i}");
    }
    // A stack far too small (as a device-built tree of unknown depth may start with) fills, and the trace grows it
    // and runs again: the same hits and counts.
    s.set_stack_entries(4);
    let again = tracer.trace(&ctx, &mut s, &rays, false).expect("trace with a growing stack");
    assert!(s.stack_entries() > depth as u32, "stack grew to {}", s.stack_entries());
    for (a, b) in out.hits.iter().zip(&again.hits) {
        assert_eq!(
            (a.triangle, a.t.to_bits(), a.box_tests, a.prim_tests),
            (b.triangle, b.t.to_bits(), b.box_tests, b.prim_tests)
        );
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// Layouts that are not one tree, or whose indices leave their arrays, are refused before anything is uploaded.
#[test]
fn malformed_layouts_are_refused() {
    use meshchar::accel::bvh::BvhNode;
    use meshchar::accel::device_trace::{BihNode, KdNode};
    use meshchar::geom::{Aabb, Triangle};
    let Some(ctx) = gpu_support::context() else { return };
    let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
    let tris = vec![Triangle::new(&[Vec3::ZERO, Vec3::X, Vec3::Y]); 2];
    let ids = vec![0u32, 1];
    let cycle = [BvhNode::internal(&b, 0, 1), BvhNode::leaf(&b, 0, 2)];
    let past = [BvhNode::internal(&b, 1, 2), BvhNode::leaf(&b, 0, 2), BvhNode::leaf(&b, 1, 2)];
    let child = [BvhNode::internal(&b, 1, 7), BvhNode::leaf(&b, 0, 1)];
    for nodes in [&cycle[..], &past[..], &child[..]] {
        let l = DeviceLayout::Bvh { nodes, tris: &tris, ids: &ids };
        assert!(DeviceStructure::upload(&ctx, &l).is_err(), "{nodes:?}");
    }
    let l = DeviceLayout::Bvh { nodes: &past[1..2], tris: &tris, ids: &ids[..1] };
    assert!(DeviceStructure::upload(&ctx, &l).is_err(), "ids of another length");
    let kd = [KdNode { split_or_count: 0, flags: 40 << 2 }];
    let l = DeviceLayout::KdTree { nodes: &kd, refs: &[], tris: &tris, ids: &ids, bounds: b };
    assert!(DeviceStructure::upload(&ctx, &l).is_err(), "kd child out of range");
    let kd = [KdNode { split_or_count: 1, flags: 3 }];
    let l = DeviceLayout::KdTree { nodes: &kd, refs: &[5], tris: &tris, ids: &ids, bounds: b };
    assert!(DeviceStructure::upload(&ctx, &l).is_err(), "kd reference out of range");
    let bih = [BihNode { clip: [f32::from_bits(3), 0.0], flags: 3 }];
    let l = DeviceLayout::Bih { nodes: &bih, tris: &tris, ids: &ids, bounds: b };
    assert!(DeviceStructure::upload(&ctx, &l).is_err(), "BIH leaf past the records");
    let grid = |starts: &'static [u32], refs: &'static [u32]| DeviceLayout::Grid {
        bounds: b,
        res: [1, 1, 1],
        cell_size: Vec3::ONE,
        inv_cell: Vec3::ONE,
        cell_start: starts,
        refs,
        tris: &tris,
    };
    assert!(DeviceStructure::upload(&ctx, &grid(&[0, 1], &[9])).is_err(), "grid reference out of range");
    assert!(DeviceStructure::upload(&ctx, &grid(&[0, 2], &[0])).is_err(), "grid starts past the references");
    assert!(DeviceStructure::upload(&ctx, &grid(&[0], &[])).is_err(), "grid starts of another count");
    assert!(DeviceStructure::upload(&ctx, &grid(&[0, 1], &[1])).is_ok(), "a good grid");
    gpu_support::assert_no_validation_messages(&ctx);
}

/// LBVH and HLBVH built on the device and traced there without a read-back ([`DeviceTracer::structure_of`]): every
/// ray equals the CPU tree's traversal (the device trees equal the CPU builders' node for node), counts included.
#[test]
fn device_built_trees_trace_like_the_cpu_trees() {
    use meshchar::accel::gpu::BvhBuilder;
    use meshchar::accel::hlbvh::Hlbvh;
    use meshchar::accel::lbvh::Lbvh;
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    let mut builder = BvhBuilder::new(&ctx).expect("builder");
    for rel in ["stanford-bunny/bun_zipper.ply", "dabrovic-sponza/sponza.obj", "small/fandisk.obj"] {
        let mesh = load_mesh(&common::shared_mesh(rel)).unwrap();
        let buffers = meshchar::gpu::MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
        let view = buffers.view();
        let cpu_l = Lbvh::build(&mesh).unwrap();
        let cpu_h = Hlbvh::build(&mesh).unwrap();
        let gpu_l = builder.build_lbvh(&view, &Default::default()).unwrap();
        let gpu_h = builder.build_hlbvh(&view, &Default::default()).unwrap();
        let mut rays = workloads(&mesh, 48);
        rays.push((WorkloadKind::Primary, random_rays(&mesh, 1024, 11), false));
        for (what, cpu, gpu) in [("lbvh", &cpu_l as &dyn AccelStructure, &gpu_l), ("hlbvh", &cpu_h, &gpu_h)] {
            let (mut s, ms) = tracer.structure_of(&ctx, gpu, &view).unwrap();
            assert!(ms >= 0.0);
            for (k, rays, any) in &rays {
                let dev: Vec<TraceRay> = rays.iter().map(TraceRay::from).collect();
                let out = tracer.trace(&ctx, &mut s, &dev, *any).unwrap();
                for (i, (r, g)) in rays.iter().zip(&out.hits).enumerate() {
                    let mut c = TraceCounters::default();
                    let want = if *any {
                        cpu.occluded(r, &mut c).then_some(u32::MAX)
                    } else {
                        cpu.intersect(r, &mut c).map(|h| h.triangle)
                    };
                    let got = g.hit().map(|h| if *any { u32::MAX } else { h.triangle });
                    assert_eq!(want, got, "{rel} {what} {k:?} ray {i}");
                    assert_eq!(
                        (c.box_tests, c.prim_tests),
                        (g.box_tests as u64, g.prim_tests as u64),
                        "{rel} {what} {k:?} ray {i}"
                    );
                }
            }
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// Primary rays made on the device equal `Camera::ray` bit for bit (origin, direction, tmin, tmax), for framing
/// cameras of several scenes, explicit cameras, square and non-square images and a one-pixel image; traced from the
/// device buffer they give the CPU tracer's hits and counts.
#[test]
fn primary_rays_on_the_device_equal_the_host_rays() {
    use meshchar::accel::device_trace::Pinhole;
    use meshchar::trace::workload::primary_rays;
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    let bunny = load_mesh(&common::shared_mesh("stanford-bunny/bun_zipper.ply")).unwrap();
    let mut cams =
        vec![Camera::frame(&mesh_bounds(&bunny)), Camera::frame(&mesh_bounds(&generate::teapot_in_stadium(2)))];
    cams.push(Camera::look_at(Vec3::new(1e4, -3.0, 0.25), Vec3::new(-2.0, 5.0, 1e-3), Vec3::Y, 97.0).unwrap());
    cams.push(Camera::look_at(Vec3::new(0.0, 0.1, 0.3), Vec3::ZERO, Vec3::Z, 5.0).unwrap());
    for (ci, cam) in cams.iter().enumerate() {
        for (w, h) in [(64u32, 64u32), (97, 31), (1, 1), (3, 200)] {
            let host = primary_rays(cam, w, h);
            let buf = tracer.primary_rays(&ctx, &Pinhole::from(cam), w, h).unwrap();
            let dev: Vec<TraceRay> = ctx.read_buffer(&buf, 0, host.len()).unwrap();
            for (i, (a, b)) in host.iter().zip(&dev).enumerate() {
                let bits = |v: [f32; 3]| v.map(f32::to_bits);
                assert_eq!(
                    (bits(a.origin.to_array()), bits(a.dir.to_array()), a.tmin.to_bits(), a.tmax.to_bits()),
                    (bits(b.origin), bits(b.dir), b.tmin.to_bits(), b.tmax.to_bits()),
                    "camera {ci} {w}x{h} pixel {i}"
                );
            }
        }
    }
    // Traced straight from the device buffer.
    let accel = build_structure(StructureName::Bvh, &bunny).unwrap();
    let mut s = DeviceStructure::upload(&ctx, &accel.device_layout().unwrap()).unwrap();
    let host = primary_rays(&cams[0], 40, 40);
    let buf = tracer.primary_rays(&ctx, &Pinhole::from(&cams[0]), 40, 40).unwrap();
    let out = tracer.trace_buffer(&ctx, &mut s, &buf, host.len() as u64, false).unwrap();
    for (i, (r, g)) in host.iter().zip(&out.hits).enumerate() {
        let mut c = TraceCounters::default();
        let h = accel.intersect(r, &mut c);
        assert_eq!(h.map(|h| (h.triangle, h.t.to_bits())), g.hit().map(|h| (h.triangle, h.t.to_bits())), "ray {i}");
        assert_eq!((c.box_tests, c.prim_tests), (g.box_tests as u64, g.prim_tests as u64), "ray {i}");
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// Shadow and diffuse rays made on the device from the primary hits equal `secondary_rays` bit for bit and in
/// order (misses spawn none), on a scan, a teapot in a stadium, and a zero-area scene (no hit, no ray).
#[test]
fn secondary_rays_on_the_device_equal_the_host_rays() {
    use meshchar::accel::device_trace::{Pinhole, SecondaryInputs};
    use meshchar::trace::workload::{default_light, primary_rays, secondary_rays, WORKLOAD_SEED};
    let Some(ctx) = gpu_support::context() else { return };
    let tracer = DeviceTracer::new(&ctx).expect("tracer");
    let bunny = load_mesh(&common::shared_mesh("stanford-bunny/bun_zipper_res3.ply")).unwrap();
    for (name, mesh) in
        [("bunny", bunny), ("zero area", generate::zero_area(500, 9)), ("stadium", generate::teapot_in_stadium(4))]
    {
        let bounds = mesh_bounds(&mesh);
        let cam = Camera::frame(&bounds);
        let (w, h) = (61u32, 47u32);
        let primary = primary_rays(&cam, w, h);
        let bvh = build_structure(StructureName::Bvh, &mesh).unwrap();
        let cpu_hits: Vec<_> = primary.iter().map(|r| bvh.intersect(r, &mut TraceCounters::default())).collect();
        let light = default_light(&bounds);
        for kind in [WorkloadKind::Shadow, WorkloadKind::Diffuse] {
            let want = secondary_rays(kind, &mesh, &primary, &cpu_hits, light, WORKLOAD_SEED);
            let mut s = DeviceStructure::upload(&ctx, &bvh.device_layout().unwrap()).unwrap();
            let prim_buf = tracer.primary_rays(&ctx, &Pinhole::from(&cam), w, h).unwrap();
            let traced = tracer.trace_buffer(&ctx, &mut s, &prim_buf, primary.len() as u64, false).unwrap();
            let hits_buf = ctx.upload("hits", &traced.hits).unwrap();
            let mb = meshchar::gpu::MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
            let view = mb.view();
            let inputs = SecondaryInputs {
                kind,
                seed: WORKLOAD_SEED,
                view: &view,
                primary: &prim_buf,
                hits: &hits_buf,
                count: primary.len() as u64,
                light,
                bounds,
            };
            let (buf, n) = tracer.secondary_rays(&ctx, &inputs).unwrap();
            assert_eq!(n as usize, want.rays.len(), "{name} {kind:?}: ray count");
            // The zero-area scene is never hit: no shadow ray at all; the others have hits and misses.
            if name != "zero area" {
                assert!(n > 0 && (n as usize) < primary.len(), "{name}: {n} of {} (hits and misses)", primary.len());
            }
            let got: Vec<TraceRay> = ctx.read_buffer(&buf, 0, n as usize).unwrap();
            for (i, (a, b)) in want.rays.iter().zip(&got).enumerate() {
                assert_eq!(
                    bytemuck::bytes_of(&TraceRay::from(a)),
                    bytemuck::bytes_of(b),
                    "{name} {kind:?}: ray {i}: {a:?} vs {b:?}"
                );
            }
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}
