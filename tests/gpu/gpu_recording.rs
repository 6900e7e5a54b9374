//! Recording into a command buffer the caller owns, over geometry the caller laid out: interleaved vertices
//! (position, normal, uv; 32-byte stride), two meshes in one vertex buffer and one index buffer, 16-bit indices for
//! the small one and 32-bit with a base vertex for the large one. Characterization (planned), scene features, LBVH
//! and refit are recorded into ONE command buffer, submitted and waited for by the test, and each result is
//! checked against the CPU reference: the planned characterization with its own plan equals the staged CPU report,
//! with another frame's plan it equals `plan::reference`; the features equal `features_cpu`; the LBVH equals the
//! CPU LBVH node for node; the refit equals a fresh build's boxes. No host wait happens inside the recording and
//! the validation layer stays silent.

use crate::gpu_support;

use meshchar::accel::bvh::BvhTree;
use meshchar::accel::gpu::BvhBuilder;
use meshchar::accel::lbvh::{Lbvh, LbvhOptions};
use meshchar::characterize::plan::{reference, Plan};
use meshchar::characterize::vulkan::VulkanBackend;
use meshchar::characterize::{cpu, features_cpu, Characterization, Params};
use meshchar::characterize::{KeyBounds, Quantizer};
use meshchar::gpu::{Buffer, Context, GeometryView, IndexType, Indices, MemoryKind, Pass, Vertices};
use meshchar::mesh::{generate, Mesh};

const STRIDE: u32 = 32;

/// Both meshes in one interleaved vertex buffer (mesh `a` first, then `b` after `gap` unused vertices) and one
/// index buffer (`a`'s 16-bit indices, padded to 4 bytes, then `b`'s 32-bit ones, relative to `b`'s first vertex
/// minus `base`).
struct Layout {
    vertices: Buffer,
    indices: Buffer,
    a_vertex_offset: u64,
    b_vertex_offset: u64,
    b_index_offset: u64,
}

const GAP: u64 = 3;
const BASE: u32 = 5;

fn interleave(ctx: &Context, a: &Mesh, b: &Mesh) -> Layout {
    let words_per_vertex = (STRIDE / 4) as usize;
    let total = 1 + a.positions.len() + GAP as usize + BASE as usize + b.positions.len();
    let mut v = vec![0f32; total * words_per_vertex];
    let mut put = |at: usize, p: [f32; 3]| {
        let w = &mut v[at * words_per_vertex..(at + 1) * words_per_vertex];
        w[..3].copy_from_slice(&p);
        // A normal and a uv that no kernel may read as a position.
        w[3..8].copy_from_slice(&[f32::NAN, 7.0, -7.0, 0.25, 0.75]);
    };
    // Vertex 0 is unused: mesh a starts one vertex in.
    put(0, [1e30; 3]);
    for (i, p) in a.positions.iter().enumerate() {
        put(1 + i, *p);
    }
    let b_first = 1 + a.positions.len() + GAP as usize;
    for (i, p) in b.positions.iter().enumerate() {
        put(b_first + BASE as usize + i, *p);
    }
    let mut idx: Vec<u8> = Vec::new();
    for t in &a.indices {
        for &i in t {
            idx.extend_from_slice(&(i as u16).to_le_bytes());
        }
    }
    while idx.len() % 4 != 0 {
        idx.push(0);
    }
    let b_index_offset = idx.len() as u64;
    for t in &b.indices {
        for &i in t {
            idx.extend_from_slice(&i.to_le_bytes());
        }
    }
    let vertices = ctx.create_buffer("engine vertices", 4 * v.len() as u64, MemoryKind::DeviceLocal).unwrap();
    ctx.write_buffer(&vertices, 0, &v).unwrap();
    let indices = ctx.create_buffer("engine indices", idx.len() as u64, MemoryKind::DeviceLocal).unwrap();
    ctx.write_buffer(&indices, 0, &idx).unwrap();
    Layout {
        vertices,
        indices,
        a_vertex_offset: STRIDE as u64,
        b_vertex_offset: STRIDE as u64 * b_first as u64,
        b_index_offset,
    }
}

fn view_a<'a>(l: &'a Layout, a: &Mesh) -> GeometryView<'a> {
    GeometryView::new(
        Vertices { buffer: &l.vertices, offset: l.a_vertex_offset, stride: STRIDE, count: a.positions.len() as u64 },
        Some(Indices { buffer: &l.indices, offset: 0, index_type: IndexType::U16, base_vertex: 0 }),
        a.triangle_count() as u64,
    )
    .unwrap()
}

fn view_b<'a>(l: &'a Layout, b: &Mesh) -> GeometryView<'a> {
    GeometryView::new(
        Vertices {
            buffer: &l.vertices,
            offset: l.b_vertex_offset,
            stride: STRIDE,
            count: BASE as u64 + b.positions.len() as u64,
        },
        Some(Indices { buffer: &l.indices, offset: l.b_index_offset, index_type: IndexType::U32, base_vertex: BASE }),
        b.triangle_count() as u64,
    )
    .unwrap()
}

/// The report without what differs by construction between backends (timings, backend and device names).
fn comparable(mut c: Characterization) -> Characterization {
    c.timings.clear();
    c.backend.clear();
    c.device.clear();
    c
}

fn same_tree(what: &str, gpu: &BvhTree, cpu: &BvhTree) {
    assert_eq!(gpu.triangle_ids(), cpu.triangle_ids(), "{what}: triangle id order");
    assert_eq!(gpu.nodes().len(), cpu.nodes().len(), "{what}: node count");
    for (k, (g, c)) in gpu.nodes().iter().zip(cpu.nodes()).enumerate() {
        let ok = g.min == c.min
            && g.max == c.max
            && g.left_or_first == c.left_or_first
            && g.right_or_count == c.right_or_count;
        assert!(ok, "{what}: node {k} differs: GPU {g:?}, CPU {c:?}");
    }
}

fn own_quantizer(mesh: &Mesh, params: &Params) -> Quantizer {
    let c = cpu::fast(mesh, params).unwrap();
    let mut b = KeyBounds::EMPTY;
    b.add(c.lo);
    b.add(c.hi);
    Quantizer::new(&b, params.morton_bits).unwrap()
}

#[test]
fn characterization_features_lbvh_and_refit_in_one_caller_command_buffer_over_interleaved_u16_geometry() {
    let Some(ctx) = gpu_support::context() else { return };
    let a = generate::clustered(900, 7, 3);
    let b = generate::random_soup(5000, 11);
    // Mesh b one frame later: moved and stretched, so its own plan differs from the stale one used below.
    let b_stale = {
        let mut m = b.clone();
        for p in &mut m.positions {
            *p = [p[0] * 1.3 + 0.2, p[1] - 0.4, p[2] * 0.7];
        }
        m
    };
    assert!(a.positions.len() < 65536, "mesh a must fit 16-bit indices");
    let layout = interleave(&ctx, &a, &b);
    let (va, vb) = (view_a(&layout, &a), view_b(&layout, &b));
    let params = Params::default();
    let mut backend = VulkanBackend::with_slots(&ctx, 2).unwrap();
    let max_k = backend.max_classes();
    let plan_a = Plan::exact(&a, &params, max_k).unwrap();
    let plan_b = Plan::exact(&b_stale, &params, max_k).unwrap();
    assert_ne!(plan_b, Plan::exact(&b, &params, max_k).unwrap(), "the stale plan must differ from b's own");
    let mut builder = BvhBuilder::new(&ctx).unwrap();
    let lbvh_options = LbvhOptions::default();
    let qb = own_quantizer(&b, &Params { morton_bits: lbvh_options.bits, ..params.clone() });
    // A tree of mesh a built before (staged), to be refitted inside the command buffer.
    let mut refitted = builder.build_lbvh(&va, &lbvh_options).unwrap();

    let waits_before = ctx.host_waits();
    let mut lbvh_b = gpu_support::in_caller_command_buffer(&ctx, |rec| {
        backend.record_planned(rec, 0, &va, "a", &params, &plan_a, true).unwrap();
        backend.record_planned(rec, 1, &vb, "b", &params, &plan_b, false).unwrap();
        let lbvh = builder.record_lbvh(rec, &vb, &qb, &lbvh_options).unwrap();
        rec.dependency(Pass::Compute, Pass::Compute);
        builder.record_refit(rec, &va, &refitted).unwrap();
        lbvh
    });
    assert_eq!(ctx.host_waits(), waits_before, "recording must not wait on the host");

    let (got_a, features_a) = backend.finish_planned(0).unwrap();
    let want_a = cpu::fast(&a, &params).unwrap();
    assert_eq!(comparable(got_a.report), comparable(want_a), "planned run with its own plan = staged CPU report");
    assert_eq!(features_a.expect("features recorded"), features_cpu(&a, &params).unwrap());
    let own = meshchar::characterize::plan::features_reference(&a, &params, &plan_a).unwrap();
    assert_eq!(own, features_cpu(&a, &params).unwrap(), "with its own plan the planned features are the staged ones");

    let (got_b, features_b) = backend.finish_planned(1).unwrap();
    assert!(features_b.is_none());
    let want_b = reference(&b, &params, &plan_b).unwrap();
    assert_eq!(got_b.plan, want_b.plan);
    assert_eq!(comparable(got_b.report), comparable(want_b.report), "planned run with a stale plan = reference");

    lbvh_b.finish().unwrap();
    let tree = lbvh_b.read_back_with(&ctx, &b).unwrap();
    same_tree("recorded LBVH of b", &tree, Lbvh::build_with(&b, &lbvh_options).unwrap().tree());

    refitted.finish().unwrap();
    let fresh = builder.build_lbvh(&va, &lbvh_options).unwrap();
    same_tree("refit of a", &refitted.read_back_with(&ctx, &a).unwrap(), &fresh.read_back_with(&ctx, &a).unwrap());
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn planned_runs_clamp_keys_outside_the_plan_exactly_as_the_reference() {
    let Some(ctx) = gpu_support::context() else { return };
    let params = Params { morton_bits: meshchar::characterize::MortonBits::Bits63, ..Params::default() };
    let mut backend = VulkanBackend::new(&ctx).unwrap();
    let max_k = backend.max_classes();
    // The plan of a small cube, applied to a mesh that reaches far outside it on every side.
    let small = generate::random_soup(300, 2);
    let mut big = generate::random_soup(2000, 9);
    for p in &mut big.positions {
        *p = p.map(|x| 4.0 * x - 1.5);
    }
    let plan = Plan::exact(&small, &params, max_k).unwrap();
    let buffers = meshchar::gpu::MeshBuffers::upload(&ctx, &big.positions, &big.indices).unwrap();
    gpu_support::in_caller_command_buffer(&ctx, |rec| {
        backend.record_planned(rec, 0, &buffers.view(), "big", &params, &plan, true).unwrap();
    });
    let (got, features) = backend.finish_planned(0).unwrap();
    let want = reference(&big, &params, &plan).unwrap();
    // The feature pass counts the cells of the plan's codes: the planned reference, not the staged features.
    let features = features.expect("features recorded");
    let planned = meshchar::characterize::plan::features_reference(&big, &params, &plan).unwrap();
    let staged = features_cpu(&big, &params).unwrap();
    assert_eq!(features, planned, "planned features = plan::features_reference");
    assert_ne!(planned.occupied_cells, staged.occupied_cells, "the stale plan must change the counted cells");
    assert_eq!((planned.size_histogram, planned.lo, planned.hi), (staged.size_histogram, staged.lo, staged.hi));
    let top = (1u64 << 63) - 1;
    assert!(got.report.code_stats.code_min == 0 && got.report.code_stats.code_max == top, "keys must clamp");
    assert_eq!(comparable(got.report), comparable(want.report));
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn finishing_before_completion_or_recording_a_busy_slot_is_an_error() {
    let Some(ctx) = gpu_support::context() else { return };
    let params = Params::default();
    let mut backend = VulkanBackend::new(&ctx).unwrap();
    let mesh = generate::random_soup(100, 1);
    let plan = Plan::exact(&mesh, &params, backend.max_classes()).unwrap();
    let buffers = meshchar::gpu::MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
    assert!(backend.finish_planned(0).is_err(), "nothing recorded");
    gpu_support::in_caller_command_buffer(&ctx, |rec| {
        backend.record_planned(rec, 0, &buffers.view(), "m", &params, &plan, false).unwrap();
        let again = backend.record_planned(rec, 0, &buffers.view(), "m", &params, &plan, false);
        assert!(again.is_err(), "a slot with an unfinished run must refuse a second one");
        // Before submission the timestamps are not available.
        let early = backend.finish_planned(0);
        assert!(early.is_err_and(|e| e.to_string().contains("has not completed")), "finish before completion");
    });
    backend.finish_planned(0).unwrap();
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn views_reject_ranges_outside_their_buffers_and_bad_alignment() {
    let Some(ctx) = gpu_support::context() else { return };
    let v = ctx.create_buffer("v", 32 * 10, MemoryKind::DeviceLocal).unwrap();
    let i = ctx.create_buffer("i", 64, MemoryKind::DeviceLocal).unwrap();
    let vert = |offset, stride, count| Vertices { buffer: &v, offset, stride, count };
    let idx = |offset, index_type| Some(Indices { buffer: &i, offset, index_type, base_vertex: 0 });
    assert!(GeometryView::new(vert(0, 32, 10), idx(0, IndexType::U16), 10).is_ok());
    assert!(GeometryView::new(vert(0, 32, 11), idx(0, IndexType::U16), 10).is_err(), "vertices past the end");
    assert!(GeometryView::new(vert(0, 30, 10), idx(0, IndexType::U16), 10).is_err(), "stride not a multiple of 4");
    assert!(GeometryView::new(vert(2, 32, 5), idx(0, IndexType::U16), 1).is_err(), "unaligned positions");
    assert!(GeometryView::new(vert(0, 32, 10), idx(2, IndexType::U32), 1).is_err(), "unaligned 32-bit indices");
    assert!(GeometryView::new(vert(0, 32, 10), idx(0, IndexType::U32), 6).is_err(), "indices past the end");
    assert!(GeometryView::new(vert(0, 32, 10), None, 4).is_err(), "a list of 4 triangles needs 12 vertices");
    assert!(GeometryView::new(vert(0, 32, 9), None, 3).is_ok());
    assert!(GeometryView::new(vert(0, 32, 0), None, 1).is_err(), "triangles over no vertices");
    // 10 triangles of 16-bit indices end at byte 60 of 64; 11 reach 66.
    assert!(GeometryView::new(vert(0, 32, 10), idx(0, IndexType::U16), 11).is_err());
}
