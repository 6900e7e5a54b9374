//! The device builders' hooks into their own kernels, checked on the device (moved from `tests/gpu/gpu_lbvh.rs` when
//! the hooks became crate-private).

use super::BvhBuilder;
use crate::accel::bvh::BvhNode;
use crate::gpu::testing as gpu_support;

#[test]
fn glsl_node_mirrors_rust_node() {
    for info in [
        &crate::gpu::shaders::bvh_leaves::INFO,
        &crate::gpu::shaders::lbvh_karras::INFO,
        &crate::gpu::shaders::hlbvh_roots::INFO,
        &crate::gpu::shaders::hlbvh_top::INFO,
    ] {
        crate::gpu::shaders::check_struct_layout::<BvhNode>(info, "BvhNode").unwrap();
    }
}

/// The top level's division is the host's `/`, bit for bit: normal, subnormal and infinite divisors, quotients that
/// overflow, underflow into the subnormals or to zero, and ties.
#[test]
fn top_level_division_is_correctly_rounded() {
    let Some(ctx) = gpu_support::context() else { return };
    let builder = BvhBuilder::new(&ctx).unwrap();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let positive = |bits: u32| f32::from_bits(bits & 0x7fff_ffff);
    let mut pairs = Vec::new();
    for _ in 0..200_000 {
        let r = next();
        let (a, b) = (positive(r as u32), positive((r >> 32) as u32));
        if a > 0.0 && a.is_finite() && b > 0.0 && !b.is_nan() {
            pairs.push((a, b));
        }
    }
    // The top level's own numerators over extents of every size, and edge cases.
    for bins in [2usize, 16, 64] {
        let factor = bins as f32 * (1.0 - 1e-6);
        for _ in 0..20_000 {
            let e = f32::from_bits((next() as u32 % 0x7f80_0000).max(1));
            pairs.push((factor, e));
        }
    }
    let min_sub = f32::from_bits(1);
    pairs.extend([
        (1.0, 3.0),
        (f32::MAX, min_sub),
        (min_sub, f32::MAX),
        (min_sub, 2.0),
        (min_sub, 1.5),
        (f32::from_bits(3), 2.0),
        (f32::MIN_POSITIVE, 3.0),
        (1.0, f32::INFINITY),
        (min_sub, min_sub),
        (f32::MAX, 0.5),
        (15.99998, 1e-38),
    ]);
    let q = builder.device_divide(&pairs).unwrap();
    let bad: Vec<String> = pairs
        .iter()
        .zip(&q)
        .filter(|(&(a, b), &g)| (a / b).to_bits() != g.to_bits())
        .take(10)
        .map(|(&(a, b), &g)| {
            format!("{a:e} / {b:e}: device {g:e} ({:#x}), host {:e} ({:#x})", g.to_bits(), a / b, (a / b).to_bits())
        })
        .collect();
    assert!(bad.is_empty(), "{} of {} quotients differ:\n{}", bad.len(), pairs.len(), bad.join("\n"));
    assert!(builder.device_divide(&[(0.0, 1.0)]).is_err());
    assert!(builder.device_divide(&[(1.0, f32::NAN)]).is_err());
    gpu_support::assert_no_validation_messages(&ctx);
}
