//! GPU LBVH and HLBVH against the CPU references, node for node, on every static shared mesh and on degenerate
//! meshes, with and without the SAH leaf collapse; the HLBVH's SAH cost against the CPU binned-SAH BVH; refit after
//! a BART frame change against a fresh fit; recorded HLBVH builds (the top level on the device) in command buffers of
//! the test's own, alone and beside recorded LBVH builds; the top level's correctly rounded division.
//!
//! Nodes are compared field by field with floats compared as values (so `-0.0 == +0.0`: `min` of signed zeros may
//! pick either on the device), and the triangle id order exactly. The collapse decisions compare f32 costs that
//! both sides compute with the same operations in the same order (see `accel::lbvh`, step 7), so they are compared
//! exactly too.

use crate::common;
use crate::gpu_support;

use ash::vk;
use glam::Vec3;
use meshchar::accel::bvh::{Bvh, BvhNode, BvhOptions, BvhTree};
use meshchar::accel::gpu::{BvhBuilder, GpuBvh, GpuBvhKind};
use meshchar::accel::hlbvh::{Hlbvh, HlbvhOptions};
use meshchar::accel::lbvh::{Lbvh, LbvhOptions};
use meshchar::accel::AccelStructure;
use meshchar::characterize::{MortonBits, Quantizer};
use meshchar::gpu::MeshBuffers;
use meshchar::gpu::{Context, Recorder};
use meshchar::mesh::{generate, load::load_mesh, Mesh};

fn same_nodes(what: &str, gpu: &[BvhNode], cpu: &[BvhNode]) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: node count");
    for (k, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        let ok = g.min == c.min
            && g.max == c.max
            && g.left_or_first == c.left_or_first
            && g.right_or_count == c.right_or_count;
        assert!(ok, "{what}: node {k} differs: GPU {g:?}, CPU {c:?}");
    }
}

fn same_tree(what: &str, gpu: &BvhTree, cpu: &BvhTree) {
    assert_eq!(gpu.triangle_ids(), cpu.triangle_ids(), "{what}: triangle id order");
    same_nodes(what, gpu.nodes(), cpu.nodes());
}

fn check_lbvh(ctx: &Context, builder: &mut BvhBuilder, mesh: &Mesh, bits: MortonBits, max_leaf: u32) {
    let what = format!("{} ({bits:?}, max_leaf {max_leaf})", mesh.name);
    let buffers = MeshBuffers::upload(ctx, &mesh.positions, &mesh.indices).unwrap();
    let o = LbvhOptions { bits, max_leaf };
    let gpu = builder.build_lbvh(&buffers.view(), &o).unwrap();
    assert_eq!(gpu.kind(), GpuBvhKind::Lbvh);
    let tree = gpu.read_back(ctx, &buffers).unwrap();
    let cpu = Lbvh::build_with(mesh, &o).unwrap();
    same_tree(&what, &tree, cpu.tree());
    tree.validate("lbvh").unwrap();
    cpu.validate().unwrap();
    let n = mesh.triangle_count();
    if max_leaf > 1 && n >= 100 {
        assert!(tree.nodes().len() < 2 * n - 1, "{what}: the collapse removed no node");
        assert!(tree.nodes().iter().all(|nd| !nd.is_leaf() || nd.count() <= max_leaf), "{what}: leaf above the cap");
    }
}

fn static_meshes() -> Vec<&'static str> {
    let mut v = vec![
        "stanford-bunny/bun_zipper.ply",
        "stanford-bunny/bun_zipper_res2.ply",
        "stanford-bunny/bun_zipper_res3.ply",
        "stanford-bunny/bun_zipper_res4.ply",
        "stanford-dragon/dragon_vrip.ply",
        "stanford-dragon/dragon_vrip_res2.ply",
        "stanford-dragon/dragon_vrip_res3.ply",
        "stanford-dragon/dragon_vrip_res4.ply",
        "dabrovic-sponza/sponza.obj",
        "sibenik/sibenik.obj",
        "conference/conference.obj",
    ];
    for dir in ["scans", "small"] {
        let mut files: Vec<String> = std::fs::read_dir(common::shared_meshes().join(dir))
            .unwrap()
            .flatten()
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|f| f.ends_with(".obj") || f.ends_with(".ply"))
            .map(|f| format!("{dir}/{f}"))
            .collect();
        files.sort();
        v.extend(files.into_iter().map(|s| &*Box::leak(s.into_boxed_str())));
    }
    v
}

#[test]
fn gpu_lbvh_equals_cpu_lbvh_on_shared_meshes() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut builder = BvhBuilder::new(&ctx).unwrap();
    for rel in static_meshes() {
        let mesh = load_mesh(&common::shared_mesh(rel)).unwrap();
        check_lbvh(&ctx, &mut builder, &mesh, MortonBits::Bits30, 1);
        if rel.contains("res4") || rel.starts_with("small/") || rel.contains("sponza") {
            check_lbvh(&ctx, &mut builder, &mesh, MortonBits::Bits63, 1);
            check_lbvh(&ctx, &mut builder, &mesh, MortonBits::Bits30, 8);
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn gpu_lbvh_equals_cpu_lbvh_on_degenerate_meshes() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut builder = BvhBuilder::new(&ctx).unwrap();
    let meshes = [
        generate::all_equal(1000),
        generate::single_triangle(),
        generate::two_triangles(),
        generate::flat(5000, 3),
        generate::zero_area(3000, 4),
        generate::collinear_centroids(2000),
        generate::random_soup(70_000, 5),
    ];
    for mesh in &meshes {
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            check_lbvh(&ctx, &mut builder, mesh, bits, 1);
            check_lbvh(&ctx, &mut builder, mesh, bits, 4);
        }
    }
    // An empty mesh is an error, not a panic.
    let empty = MeshBuffers::upload(&ctx, &[], &[]).unwrap();
    assert!(builder.build_lbvh(&empty.view(), &LbvhOptions::default()).is_err());
    assert!(builder.build_hlbvh(&empty.view(), &HlbvhOptions::default()).is_err());
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn gpu_hlbvh_equals_cpu_hlbvh() {
    hlbvh_on_static_meshes(false);
}

/// The bound: the GPU HLBVH (default options: 21 cluster bits, SAH leaf collapse up to 8 triangles) costs at
/// most 1.15 x the CPU binned-SAH BVH on every static shared mesh but the full dragon (which the benchmark
/// covers); prints every ratio, LBVH's beside it (`--nocapture`).
#[test]
fn gpu_hlbvh_sah_within_15_percent_of_binned_sah() {
    hlbvh_on_static_meshes(true);
}

fn hlbvh_on_static_meshes(check_sah: bool) {
    let Some(ctx) = gpu_support::context() else { return };
    let mut builder = BvhBuilder::new(&ctx).unwrap();
    let o = HlbvhOptions::default();
    let mut worst: f64 = 0.0;
    for rel in static_meshes() {
        if rel == "stanford-dragon/dragon_vrip.ply" {
            continue; // the full dragon runs once, in the LBVH test
        }
        let mesh = load_mesh(&common::shared_mesh(rel)).unwrap();
        let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
        let gpu = builder.build_hlbvh(&buffers.view(), &o).unwrap();
        let tree = gpu.read_back(&ctx, &buffers).unwrap();
        tree.validate("hlbvh").unwrap();
        let cpu = Hlbvh::build_with(&mesh, &o).unwrap();
        assert_eq!(gpu.kind(), GpuBvhKind::Hlbvh { clusters: cpu.cluster_count() as u32 }, "{rel}");
        same_tree(rel, &tree, cpu.tree());
        if !check_sah {
            continue;
        }
        // The top-down binned-SAH build that the HLBVH's top level mirrors (the BVH's reinsertion pass, which lowers
        // the cost of architecture by 10-17% more, is off: it is the BVH's own refinement, not the HLBVH's target).
        let binned = BvhOptions { reinsertion: 0.0, ..Default::default() };
        let sah = Bvh::build_with(&mesh, &binned).unwrap().sah_cost().unwrap();
        let lbvh = Lbvh::build(&mesh).unwrap().sah_cost().unwrap();
        let lbvh8 = Lbvh::build_with(&mesh, &LbvhOptions { max_leaf: 8, ..Default::default() }).unwrap();
        let ratio = tree.sah_cost() / sah;
        println!(
            "{rel:45} hlbvh/sah {ratio:.3}  lbvh/sah {:.3}  lbvh(max_leaf 8)/sah {:.3}",
            lbvh / sah,
            lbvh8.sah_cost().unwrap() / sah
        );
        worst = worst.max(ratio);
    }
    if check_sah {
        println!("worst hlbvh/sah ratio {worst:.3}");
        assert!(worst <= 1.15, "HLBVH SAH cost up to {worst:.3} x the binned SAH BVH's");
        return;
    }
    for mesh in [generate::all_equal(500), generate::single_triangle(), generate::two_triangles()] {
        let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
        let tree = builder.build_hlbvh(&buffers.view(), &o).unwrap().read_back(&ctx, &buffers).unwrap();
        same_tree(&mesh.name, &tree, Hlbvh::build_with(&mesh, &o).unwrap().tree());
    }
    // Without the collapse (one triangle per leaf, cluster blocks in the Karras numbering) and with the previous
    // 12 cluster bits.
    for rel in ["stanford-bunny/bun_zipper_res2.ply", "dabrovic-sponza/sponza.obj", "small/cow.obj"] {
        let mesh = load_mesh(&common::shared_mesh(rel)).unwrap();
        let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
        for o in [HlbvhOptions { max_leaf: 1, ..o }, HlbvhOptions { cluster_bits: 12, ..o }] {
            let tree = builder.build_hlbvh(&buffers.view(), &o).unwrap().read_back(&ctx, &buffers).unwrap();
            let cpu = Hlbvh::build_with(&mesh, &o).unwrap();
            cpu.validate().unwrap();
            same_tree(&format!("{rel} {o:?}"), &tree, cpu.tree());
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn refit_after_bart_frame_change_equals_fresh_fit() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut builder = BvhBuilder::new(&ctx).unwrap();
    let f0 = load_mesh(&common::shared_mesh("bart/robots/robots_f0000.obj")).unwrap();
    let f1 = load_mesh(&common::shared_mesh("bart/robots/robots_f0080.obj")).unwrap();
    assert_eq!(f0.indices, f1.indices);
    for hl in [false, true] {
        let buffers = MeshBuffers::upload(&ctx, &f0.positions, &f0.indices).unwrap();
        let mut bvh = if hl {
            builder.build_hlbvh(&buffers.view(), &HlbvhOptions::default()).unwrap()
        } else {
            builder.build_lbvh(&buffers.view(), &LbvhOptions::default()).unwrap()
        };
        let before = bvh.read_back(&ctx, &buffers).unwrap();
        buffers.update_positions(&ctx, &f1.positions).unwrap();
        builder.refit(&buffers.view(), &mut bvh).unwrap();
        let after = bvh.read_back(&ctx, &buffers).unwrap();
        // Same topology, ids and records order.
        assert_eq!(after.triangle_ids(), before.triangle_ids());
        for (a, b) in after.nodes().iter().zip(before.nodes()) {
            assert_eq!((a.left_or_first, a.right_or_count), (b.left_or_first, b.right_or_count));
        }
        // Boxes equal a fresh fit of that topology on the CPU over frame 80's vertices.
        let expected = fresh_fit(&f1, before.nodes(), before.triangle_ids());
        same_nodes(&format!("refit (hlbvh: {hl})"), after.nodes(), &expected);
        after.validate("refit").unwrap();
        assert_ne!(after.nodes()[0].min, before.nodes()[0].min, "frame 80 moved the scene");
        // Refitting back to frame 0 restores the built tree exactly.
        buffers.update_positions(&ctx, &f0.positions).unwrap();
        builder.refit(&buffers.view(), &mut bvh).unwrap();
        same_tree("refit back", &bvh.read_back(&ctx, &buffers).unwrap(), &before);
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// Boxes of `topology` recomputed from scratch on the host for `mesh`: leaves from their triangles, internal nodes
/// as the union of their children (recursively from the root).
fn fresh_fit(mesh: &Mesh, topology: &[BvhNode], ids: &[u32]) -> Vec<BvhNode> {
    let mut out = topology.to_vec();
    fn fit(k: usize, out: &mut [BvhNode], mesh: &Mesh, ids: &[u32]) -> ([f32; 3], [f32; 3]) {
        let nd = out[k];
        let (lo, hi) = if nd.is_leaf() {
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            for r in nd.left_or_first..nd.left_or_first + nd.count() {
                for v in mesh.triangle(ids[r as usize] as usize) {
                    for a in 0..3 {
                        lo[a] = lo[a].min(v[a]);
                        hi[a] = hi[a].max(v[a]);
                    }
                }
            }
            (lo, hi)
        } else {
            let (l0, h0) = fit(nd.left_or_first as usize, out, mesh, ids);
            let (l1, h1) = fit(nd.right_or_count as usize, out, mesh, ids);
            (std::array::from_fn(|a| l0[a].min(l1[a])), std::array::from_fn(|a| h0[a].max(h1[a])))
        };
        out[k].min = lo;
        out[k].max = hi;
        (lo, hi)
    }
    fit(0, &mut out, mesh, ids);
    out
}

/// Records `record` into a command buffer of the test's own (its own pool, the context's queue 0 of its family, as
/// an engine would), submits it and waits for it; barriers before and after make the uploads visible to the build
/// and the build's writes to the reads that follow.
fn record_own<T>(ctx: &Context, record: impl FnOnce(&mut Recorder<'_>) -> T) -> T {
    let dev = ctx.device();
    let pool_info = vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family());
    // SAFETY: valid device; the pool is destroyed below, after the fence wait.
    let pool = unsafe { dev.create_command_pool(&pool_info, None) }.expect("command pool");
    let alloc = vk::CommandBufferAllocateInfo::default()
        .command_pool(pool)
        .level(vk::CommandBufferLevel::PRIMARY)
        .command_buffer_count(1);
    // SAFETY: the pool is this test's.
    let cmd = unsafe { dev.allocate_command_buffers(&alloc) }.expect("command buffer")[0];
    let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
    // SAFETY: a fresh command buffer of our pool.
    unsafe { dev.begin_command_buffer(cmd, &begin) }.expect("begin");
    // SAFETY: `cmd` is recording, from a pool of the context's compute family that only this thread uses; the
    // buffers, views and trees recorded stay alive in the caller until after the fence wait below.
    let mut rec = unsafe { Recorder::new(ctx, cmd) };
    rec.barrier();
    let value = record(&mut rec);
    rec.barrier();
    // SAFETY: recording state.
    unsafe { dev.end_command_buffer(cmd) }.expect("end");
    // SAFETY: valid device; queue 0 of the context's family (Context::new creates one queue there), used by no
    // other thread of this test.
    let queue = unsafe { dev.get_device_queue(ctx.queue_family(), 0) };
    // SAFETY: valid device.
    let fence = unsafe { dev.create_fence(&vk::FenceCreateInfo::default(), None) }.expect("fence");
    let cmds = [cmd];
    let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
    // SAFETY: executable command buffer; fence unsignalled; the queue is externally synchronized (this thread).
    unsafe { dev.queue_submit(queue, &submit, fence) }.expect("submit");
    // SAFETY: the fence was submitted above.
    unsafe { dev.wait_for_fences(&[fence], true, u64::MAX) }.expect("wait");
    // SAFETY: the command buffer has completed; nothing of the pool is pending.
    unsafe {
        dev.destroy_fence(fence, None);
        dev.destroy_command_pool(pool, None);
    }
    value
}

/// The quantizer of the mesh's own centroid bounds (what the staged builds compute on the device).
fn own_quantizer(mesh: &Mesh, bits: MortonBits) -> Quantizer {
    let params = meshchar::characterize::Params { morton_bits: bits, ..Default::default() };
    meshchar::characterize::plan::Plan::exact(mesh, &params, u32::MAX).unwrap().quantizer()
}

/// A finished recorded HLBVH against the CPU reference: kind, node for node, ids, validity.
fn check_recorded_hlbvh(
    ctx: &Context,
    what: &str,
    mut bvh: GpuBvh,
    buffers: &MeshBuffers,
    mesh: &Mesh,
    o: &HlbvhOptions,
) {
    assert!(bvh.is_pending(), "{what}: pending before finish");
    bvh.finish().unwrap_or_else(|e| panic!("{what}: finish: {e}"));
    let cpu = Hlbvh::build_with(mesh, o).unwrap();
    assert_eq!(bvh.kind(), GpuBvhKind::Hlbvh { clusters: cpu.cluster_count() as u32 }, "{what}");
    let tree = bvh.read_back(ctx, buffers).unwrap();
    same_tree(what, &tree, cpu.tree());
    tree.validate("hlbvh").unwrap();
    cpu.validate().unwrap();
    assert!(bvh.timings().iter().any(|(n, _)| n == "top_rounds"), "{what}: {:?}", bvh.timings());
}

/// Triangles whose boxes all have the centre (0, 1.5, 0) exactly (x in [-1, 1], y in [1.5 - h, 1.5 + h], dyadic
/// coordinates), with centroids spread in x and y: every cluster root box has that centre, so every top node splits
/// its list in the middle (the fallback of step 4), on the workgroups' path (more clusters than a serial task
/// takes) and the serial one.
fn coincident_centres(pairs: usize) -> Mesh {
    let mut tris = Vec::new();
    for k in 1..=pairs {
        let h = k as f32 / 1024.0;
        let (lo, hi) = (1.5 - h, 1.5 + h);
        let t = ((k * 37) % 1024) as f32 / 512.0 - 1.0;
        let u = ((k * 101) % 1024) as f32 / 512.0 - 1.0;
        tris.push([Vec3::new(-1.0, lo, 0.0), Vec3::new(1.0, lo, 0.0), Vec3::new(t, hi, 0.0)]);
        tris.push([Vec3::new(-1.0, hi, 0.0), Vec3::new(1.0, hi, 0.0), Vec3::new(u, lo, 0.0)]);
    }
    Mesh::from_triangles(format!("coincident_centres({pairs})"), &tris).unwrap()
}

#[test]
fn recorded_hlbvh_equals_cpu_hlbvh() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut builder = BvhBuilder::new(&ctx).unwrap();
    let d = HlbvhOptions::default();
    let bunny = load_mesh(&common::shared_mesh("stanford-bunny/bun_zipper.ply")).unwrap();
    let bunny4 = load_mesh(&common::shared_mesh("stanford-bunny/bun_zipper_res4.ply")).unwrap();
    let sponza = load_mesh(&common::shared_mesh("dabrovic-sponza/sponza.obj")).unwrap();
    let cases: Vec<(Mesh, Vec<HlbvhOptions>)> = vec![
        (bunny, vec![d]),
        (sponza, vec![d]),
        (
            bunny4,
            vec![
                d,
                HlbvhOptions { max_leaf: 1, ..d },
                HlbvhOptions { bins: 64, ..d },
                HlbvhOptions { bins: 2, ..d },
                HlbvhOptions { bits: MortonBits::Bits63, ..d },
            ],
        ),
        (generate::random_soup(70_000, 11), vec![d]),
        (generate::random_soup(3000, 12), vec![d, HlbvhOptions { bins: 64, max_leaf: 1, ..d }]),
        // One cluster (no top node), two clusters (one top node).
        (
            generate::random_soup(500, 13),
            vec![HlbvhOptions { cluster_bits: 0, ..d }, HlbvhOptions { cluster_bits: 1, ..d }],
        ),
        (generate::all_equal(1000), vec![d]),
        (generate::collinear_centroids(2000), vec![d, HlbvhOptions { max_leaf: 1, ..d }]),
        (generate::flat(5000, 3), vec![d]),
        (generate::zero_area(3000, 4), vec![d]),
        (generate::single_triangle(), vec![d]),
        (generate::two_triangles(), vec![d]),
        (coincident_centres(400), vec![HlbvhOptions { max_leaf: 1, ..d }]),
    ];
    for (mesh, options) in &cases {
        let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
        for o in options {
            let what = format!("{} {o:?}", mesh.name);
            let q = own_quantizer(mesh, o.bits);
            let bvh = record_own(&ctx, |rec| builder.record_hlbvh(rec, &buffers.view(), &q, o)).unwrap();
            check_recorded_hlbvh(&ctx, &what, bvh, &buffers, mesh, o);
        }
    }
    let clusters = Hlbvh::build_with(&cases[12].0, &cases[12].1[0]).unwrap().cluster_count();
    assert!(clusters > 128, "coincident_centres: {clusters} clusters do not reach the workgroups' path");
    // Errors, not panics: the quantizer's width, too many cluster bits, no triangles.
    let mesh = &cases[4].0;
    let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
    let q30 = own_quantizer(mesh, MortonBits::Bits30);
    let o63 = HlbvhOptions { bits: MortonBits::Bits63, ..d };
    let wide = HlbvhOptions { bits: MortonBits::Bits63, cluster_bits: 25, ..d };
    let q63 = own_quantizer(mesh, MortonBits::Bits63);
    let empty = MeshBuffers::upload(&ctx, &[], &[]).unwrap();
    record_own(&ctx, |rec| {
        assert!(builder.record_hlbvh(rec, &buffers.view(), &q30, &o63).is_err());
        assert!(builder.record_hlbvh(rec, &buffers.view(), &q63, &wide).is_err());
        assert!(builder.record_hlbvh(rec, &empty.view(), &q30, &d).is_err());
    });
    gpu_support::assert_no_validation_messages(&ctx);
}

/// One command buffer: the LBVH and the HLBVH of one mesh and the HLBVH of a larger one (the builder moves to larger
/// scratch buffers; the first trees keep theirs), each equal to its CPU reference.
#[test]
fn recorded_hlbvh_and_lbvh_share_one_command_buffer() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut builder = BvhBuilder::new(&ctx).unwrap();
    let small = load_mesh(&common::shared_mesh("stanford-bunny/bun_zipper_res3.ply")).unwrap();
    let large = generate::random_soup(40_000, 21);
    let a = MeshBuffers::upload(&ctx, &small.positions, &small.indices).unwrap();
    let b = MeshBuffers::upload(&ctx, &large.positions, &large.indices).unwrap();
    let lo = LbvhOptions { max_leaf: 4, ..Default::default() };
    let ho = HlbvhOptions::default();
    let ho1 = HlbvhOptions { max_leaf: 1, ..ho };
    let (qa, qb) = (own_quantizer(&small, MortonBits::Bits30), own_quantizer(&large, MortonBits::Bits30));
    let (mut lbvh, hl_a, hl_b) = record_own(&ctx, |rec| {
        let l = builder.record_lbvh(rec, &a.view(), &qa, &lo).unwrap();
        let h = builder.record_hlbvh(rec, &a.view(), &qa, &ho).unwrap();
        let h2 = builder.record_hlbvh(rec, &b.view(), &qb, &ho1).unwrap();
        (l, h, h2)
    });
    lbvh.finish().unwrap();
    same_tree("recorded lbvh", &lbvh.read_back(&ctx, &a).unwrap(), Lbvh::build_with(&small, &lo).unwrap().tree());
    check_recorded_hlbvh(&ctx, "recorded hlbvh (small)", hl_a, &a, &small, &ho);
    check_recorded_hlbvh(&ctx, "recorded hlbvh (large)", hl_b, &b, &large, &ho1);
    gpu_support::assert_no_validation_messages(&ctx);
}
