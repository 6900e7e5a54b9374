//! The first kernel end to end: bounds of point sets on the GPU equal the CPU's exactly; and every push-constant
//! mirror against its shader's reflection.

use super::testing as gpu_support;
use super::PointBounds;
use super::{shaders, Context};
use crate::keys::{max_total, min_total};
use crate::rng::SplitMix64 as Rng;

fn cpu_bounds(p: &[[f32; 3]]) -> Option<([f32; 3], [f32; 3])> {
    let first = *p.first()?;
    let (mut lo, mut hi) = (first, first);
    for q in p {
        for a in 0..3 {
            lo[a] = min_total(lo[a], q[a]);
            hi[a] = max_total(hi[a], q[a]);
        }
    }
    Some((lo, hi))
}

fn gpu_bounds(ctx: &Context, op: &PointBounds, p: &[[f32; 3]]) -> Option<([f32; 3], [f32; 3])> {
    let buf = ctx.upload("points", if p.is_empty() { &[[0.0f32; 3]][..] } else { p }).expect("upload");
    op.run(ctx, &buf, p.len() as u64).expect("bounds")
}

fn bits(b: Option<([f32; 3], [f32; 3])>) -> Option<([u32; 3], [u32; 3])> {
    b.map(|(lo, hi)| (lo.map(f32::to_bits), hi.map(f32::to_bits)))
}

/// Finite floats of every magnitude and sign, zeros of both signs included.
fn finite_f32(rng: &mut Rng) -> f32 {
    loop {
        let x = f32::from_bits(rng.next_u64() as u32);
        if x.is_finite() {
            return x;
        }
    }
}

#[test]
fn bounds_match_cpu_for_edge_counts() {
    let Some(ctx) = gpu_support::context() else { return };
    let op = PointBounds::new(&ctx).expect("pipeline");
    let mut rng = Rng(7);
    let wg = ctx.caps().workgroup_size() as usize;
    let counts = [0usize, 1, 2, 3, wg - 1, wg, wg + 1, 8 * wg - 1, 8 * wg + 1, 100_003, (1 << 20) + 3];
    for &n in &counts {
        let p: Vec<[f32; 3]> =
            (0..n).map(|_| [finite_f32(&mut rng), finite_f32(&mut rng), finite_f32(&mut rng)]).collect();
        assert_eq!(bits(gpu_bounds(&ctx, &op, &p)), bits(cpu_bounds(&p)), "n = {n}");
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn bounds_signed_zeros_and_extremes() {
    let Some(ctx) = gpu_support::context() else { return };
    let op = PointBounds::new(&ctx).expect("pipeline");
    let cases: Vec<Vec<[f32; 3]>> = vec![
        vec![[0.0, -0.0, 0.0], [-0.0, 0.0, 0.0]],
        vec![[f32::MAX, f32::MIN, f32::MIN_POSITIVE]; 5],
        vec![[1e-45, -1e-45, 0.0], [3.0e38, -3.0e38, 1e30]],
    ];
    for p in &cases {
        assert_eq!(bits(gpu_bounds(&ctx, &op, p)), bits(cpu_bounds(p)), "{p:?}");
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn bounds_more_workgroups_than_one_dispatch_dimension() {
    // Dispatches capped at TEST_DISPATCH_GROUPS workgroups: the tile loop runs on any device with little data.
    let Some(ctx) = gpu_support::capped_context() else { return };
    // One item per invocation and a tiny workgroup make (2^20 + 3) points need more workgroups than lavapipe's
    // 65,535 per dimension, which exercises the tile loop.
    let sg = ctx.caps().max_subgroup_size;
    let op = PointBounds::with_tuning(&ctx, Some(sg), 1).expect("pipeline");
    let mut rng = Rng(11);
    let n = (1usize << 20) + 3;
    let p: Vec<[f32; 3]> = (0..n).map(|_| [finite_f32(&mut rng), finite_f32(&mut rng), finite_f32(&mut rng)]).collect();
    let buf = ctx.upload("points", &p).expect("upload");
    assert_eq!(bits(op.run(&ctx, &buf, n as u64).expect("bounds")), bits(cpu_bounds(&p)));
    let tiles = (n as u64).div_ceil(sg as u64);
    let limit = ctx.caps().max_workgroup_count[0] as u64;
    eprintln!("{n} points: {tiles} tiles, dispatch limit {limit}");
    assert!(tiles > limit, "the test must need more workgroups ({tiles}) than one dispatch allows ({limit})");
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn every_push_constant_struct_matches_its_shader() {
    // The mirrors as the crate's modules name them (characterize::gpu, accel::gpu, gpu::sort re-export these).
    use super::KeysPush;
    use shaders::check_push_layout;
    use shaders::chi_square::Push as ChiPush;
    use shaders::classes_histogram::Push as ClassesPush;
    use shaders::morton_moments::Push as MortonPush;
    check_push_layout::<super::bounds::BoundsPush>(&shaders::bounds::INFO).expect("bounds");
    check_push_layout::<KeysPush>(&shaders::keys_bounds::INFO).expect("keys_bounds");
    check_push_layout::<MortonPush>(&shaders::morton_moments::INFO).expect("morton_moments");
    check_push_layout::<ClassesPush>(&shaders::classes_histogram::INFO).expect("classes_histogram");
    check_push_layout::<ChiPush>(&shaders::chi_square::INFO).expect("chi_square");
    check_push_layout::<shaders::features_bounds::Push>(&shaders::features_bounds::INFO).expect("features_bounds");
    check_push_layout::<shaders::features::Push>(&shaders::features::INFO).expect("features");
    {
        use shaders::bvh_collapse_cost::Push as CollapseCostPush;
        use shaders::bvh_compact::Push as CompactPush;
        use shaders::bvh_fit::Push as FitPush;
        use shaders::bvh_leaves::Push as LeavesPush;
        use shaders::bvh_parents::Push as ParentsPush;
        use shaders::hlbvh_heads::Push as HeadsPush;
        use shaders::hlbvh_roots::Push as RootsPush;
        use shaders::hlbvh_scan::Push as ScanPush;
        use shaders::lbvh_codes::Push as CodesPush;
        use shaders::lbvh_karras::Push as KarrasPush;
        check_push_layout::<CodesPush>(&shaders::lbvh_codes::INFO).expect("lbvh_codes");
        check_push_layout::<KarrasPush>(&shaders::lbvh_karras::INFO).expect("lbvh_karras");
        check_push_layout::<LeavesPush>(&shaders::bvh_leaves::INFO).expect("bvh_leaves");
        check_push_layout::<FitPush>(&shaders::bvh_fit::INFO).expect("bvh_fit");
        check_push_layout::<ParentsPush>(&shaders::bvh_parents::INFO).expect("bvh_parents");
        check_push_layout::<CollapseCostPush>(&shaders::bvh_collapse_cost::INFO).expect("bvh_collapse_cost");
        check_push_layout::<CompactPush>(&shaders::bvh_compact::INFO).expect("bvh_compact");
        check_push_layout::<HeadsPush>(&shaders::hlbvh_heads::INFO).expect("hlbvh_heads");
        check_push_layout::<ScanPush>(&shaders::hlbvh_scan::INFO).expect("hlbvh_scan");
        check_push_layout::<RootsPush>(&shaders::hlbvh_roots::INFO).expect("hlbvh_roots");
    }
    {
        use super::sort::*;
        check_push_layout::<SortCountPush>(&shaders::sort_count::INFO).expect("sort_count");
        check_push_layout::<SortScanReducePush>(&shaders::sort_scan_reduce::INFO).expect("sort_scan_reduce");
        check_push_layout::<SortScanDownPush>(&shaders::sort_scan_down::INFO).expect("sort_scan_down");
        check_push_layout::<SortScatterPush>(&shaders::sort_scatter::INFO).expect("sort_scatter");
    }
    // Every shader is reflected with an entry point and a local size, and ships a SPIR-V module.
    for s in shaders::ALL {
        assert_eq!(s.spirv.first(), Some(&0x0723_0203), "{}: SPIR-V magic number", s.name);
        assert_eq!(s.entry, "main", "{}", s.name);
        assert!(s.local_size_spec_ids[0].is_some(), "{} must take its workgroup size from the device", s.name);
    }
}

/// A Rust mirror with a member out of place must be rejected, both as push constants and as a struct.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Swapped {
    result: u64,
    points: u64,
    count: u64,
}
crate::push_layout!(Swapped { result, points, count });

#[test]
fn layout_mismatches_are_caught() {
    use shaders::{check_push_layout, check_struct_layout};
    let err = check_push_layout::<Swapped>(&shaders::bounds::INFO).expect_err("swapped members must not match");
    assert!(err.contains("points"), "{err}");
    assert!(check_struct_layout::<Swapped>(&shaders::bounds::INFO, "Push").is_err());
    check_struct_layout::<super::bounds::BoundsPush>(&shaders::bounds::INFO, "Push").expect("the real mirror matches");
}

/// The same names, offsets and sizes as the block of `bounds.comp`, but an `f64` where GLSL has a `uint64_t`: types
/// are compared too.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FloatCount {
    points: u64,
    result: u64,
    count: f64,
}
crate::push_layout!(FloatCount { points, result, count });

#[test]
fn type_mismatches_are_caught() {
    use shaders::{check_push_layout, check_struct_layout};
    let err = check_push_layout::<FloatCount>(&shaders::bounds::INFO).expect_err("f64 must not match uint64_t");
    // The member named `count` differs, and the message shows the types.
    assert!(err.starts_with("member count differs") && err.contains("\"f64\""), "{err}");
    assert!(check_struct_layout::<FloatCount>(&shaders::bounds::INFO, "Push").is_err());
}
