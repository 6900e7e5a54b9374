//! The GPU characterization passes against a direct CPU computation of the same exact quantities (docs/spec.md steps 1-10
//! as integers): bounds, every code, the code range, the exact power sums, every class, the histogram and the
//! chi-square numerator. Any subgroup size and count: edge counts, a sample stride, 63-bit codes, and a mesh whose
//! arrays exceed one storage-buffer binding.

use crate::characterize::gpu::passes::{CharacterizeGpu, ClassPlan, CodeSums};
use crate::gpu::testing as gpu_support;
use crate::gpu::MeshBuffers;
use crate::keys::{centroid_key, max_total, min_total, morton, quantization_scale, quantize, MortonBits};
use crate::rng::SplitMix64 as Rng;

/// The thresholds of docs/spec.md step 7 for `k` classes, computed with u128.
fn thresholds(min: u64, max: u64, k: u32) -> Vec<u64> {
    let d = (max - min) as u128;
    (1..k as u128).map(|j| (j * d).div_ceil(k as u128) as u64).collect()
}

fn limbs_value(limbs: &[u64]) -> Vec<u64> {
    // Exact value as base-2^32 digits (little endian), from 24-bit-weighted limbs.
    let mut out = vec![0u64; 12];
    for (j, &l) in limbs.iter().enumerate() {
        let bit = 24 * j;
        let (w, s) = (bit / 32, bit % 32);
        let v = (l as u128) << s;
        let mut carry = 0u128;
        for (i, part) in [
            (v & 0xffff_ffff) as u64,
            ((v >> 32) & 0xffff_ffff) as u64,
            ((v >> 64) & 0xffff_ffff) as u64,
            (v >> 96) as u64,
        ]
        .into_iter()
        .enumerate()
        {
            let t = out[w + i] as u128 + part as u128 + carry;
            out[w + i] = (t & 0xffff_ffff) as u64;
            carry = t >> 32;
        }
        let mut i = w + 4;
        while carry > 0 {
            let t = out[i] as u128 + carry;
            out[i] = (t & 0xffff_ffff) as u64;
            carry = t >> 32;
            i += 1;
        }
    }
    out
}

#[allow(clippy::needless_range_loop)]
fn digits_of_sum(values: impl Iterator<Item = (u128, u128)>) -> Vec<u64> {
    // Sum of (hi, lo) 256-bit values given as two u128 halves, returned as base-2^32 digits.
    let mut out = vec![0u64; 12];
    for (hi, lo) in values {
        let mut carry = 0u128;
        for i in 0..8 {
            let part = if i < 4 { (lo >> (32 * i)) & 0xffff_ffff } else { (hi >> (32 * (i - 4))) & 0xffff_ffff };
            let t = out[i] as u128 + part + carry;
            out[i] = (t & 0xffff_ffff) as u64;
            carry = t >> 32;
        }
        let mut i = 8;
        while carry > 0 {
            let t = out[i] as u128 + carry;
            out[i] = (t & 0xffff_ffff) as u64;
            carry = t >> 32;
            i += 1;
        }
    }
    out
}

/// m^p for m < 2^63 as a 256-bit (hi, lo) pair.
fn pow256(m: u64, p: u32) -> (u128, u128) {
    let m = m as u128;
    match p {
        1 => (0, m),
        2 => (0, m * m),
        _ => {
            // m^2 < 2^126 fits u128; m^3 = m^2 * m with m^2 split in 64-bit halves a 2^64 + b.
            let sq = m * m;
            let (a, b) = (sq >> 64, sq & u64::MAX as u128);
            let (bm, am) = (b * m, a * m);
            let (lo, carry) = bm.overflowing_add(am << 64);
            ((am >> 64) + u128::from(carry), lo)
        }
    }
}

struct Expected {
    lo: [f32; 3],
    hi: [f32; 3],
    codes: Vec<u64>,
}

fn expected(pos: &[[f32; 3]], idx: &[[u32; 3]], stride: usize, bits: MortonBits) -> Expected {
    let keys: Vec<[f32; 3]> = idx
        .iter()
        .step_by(stride)
        .map(|t| centroid_key(pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]))
        .collect();
    let (mut lo, mut hi) = (keys[0], keys[0]);
    for k in &keys {
        for a in 0..3 {
            lo[a] = min_total(lo[a], k[a]);
            hi[a] = max_total(hi[a], k[a]);
        }
    }
    let scale = quantization_scale(lo, hi, bits).expect("finite");
    let codes = keys.iter().map(|&s| morton(quantize(s, lo, scale, bits), bits)).collect();
    Expected { lo, hi, codes }
}

fn check(
    gpu: &mut CharacterizeGpu,
    ctx: &crate::gpu::Context,
    pos: &[[f32; 3]],
    idx: &[[u32; 3]],
    stride: usize,
    bits: MortonBits,
    k: u32,
) {
    let want = expected(pos, idx, stride, bits);
    let mesh = MeshBuffers::upload(ctx, pos, idx).expect("upload");
    let plan = move |s: &CodeSums| -> Result<ClassPlan, String> {
        let k = if s.code_min == s.code_max { 1 } else { k };
        Ok(ClassPlan { k, thresholds: thresholds(s.code_min, s.code_max, k) })
    };
    let start = std::time::Instant::now();
    let got = gpu.run(&mesh.view(), bits, stride as u64, &plan, true).expect("run");
    let wall_ms = start.elapsed().as_secs_f64() * 1e3;
    let n = want.codes.len();
    let what = format!("n = {n}, stride {stride}, {bits:?}");
    assert_eq!(got.n, n as u64, "{what}");
    assert_eq!(got.lo.map(f32::to_bits), want.lo.map(f32::to_bits), "{what}");
    assert_eq!(got.hi.map(f32::to_bits), want.hi.map(f32::to_bits), "{what}");
    let (codes, classes) = got.per_triangle.as_ref().expect("read back");
    assert_eq!(codes, &want.codes, "{what}");
    let (cmin, cmax) = (*want.codes.iter().min().expect("n > 0"), *want.codes.iter().max().expect("n > 0"));
    assert_eq!((got.sums.code_min, got.sums.code_max), (cmin, cmax), "{what}");
    for (p, limbs) in got.sums.limbs.iter().enumerate() {
        let exact = digits_of_sum(want.codes.iter().map(|&m| pow256(m, p as u32 + 1)));
        assert_eq!(limbs_value(limbs), exact, "S{} {what}", p + 1);
    }
    let k = got.plan.k;
    let mut hist = vec![0u64; k as usize];
    for (i, &m) in want.codes.iter().enumerate() {
        let c = if cmax == cmin {
            0
        } else {
            (((m - cmin) as u128 * k as u128) / (cmax - cmin) as u128).min(k as u128 - 1) as u32
        };
        assert_eq!(classes[i], c, "class of triangle {i}, {what}");
        hist[c as usize] += 1;
    }
    assert_eq!(got.histogram, hist, "{what}");
    let t: u128 = hist.iter().map(|&o| ((k as i128 * o as i128 - n as i128).unsigned_abs()).pow(2)).sum();
    assert_eq!(got.chi_numerator, t, "{what}");
    assert_eq!(got.empty_classes as usize, hist.iter().filter(|&&o| o == 0).count(), "{what}");
    let conc: Vec<u64> = hist.iter().copied().filter(|&o| k as u64 * o > n as u64).collect();
    assert_eq!(got.concentrated_classes as usize, conc.len(), "{what}");
    assert_eq!(got.concentrated_triangles, conc.iter().sum::<u64>(), "{what}");
    let names: Vec<&str> = got.timings.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["keys_bounds", "morton_moments", "classes_histogram", "chi_square"]);
    // Device timestamps of passes recorded one after the other inside this call: each is a duration and their sum
    // fits in the call's wall time (a wrong timestamp period or reversed pair would not).
    let sum: f64 = got.timings.iter().map(|(_, ms)| ms).sum();
    assert!(got.timings.iter().all(|(_, ms)| *ms >= 0.0) && sum <= wall_ms, "{:?} in {wall_ms} ms", got.timings);
}

fn soup(rng: &mut Rng, n: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut pos = Vec::with_capacity(3 * n);
    let mut idx = Vec::with_capacity(n);
    for t in 0..n {
        let c = [rng.next_f32() * 100.0 - 50.0, rng.next_f32() * 10.0, rng.next_f32() * 1e-3];
        for _ in 0..3 {
            pos.push([c[0] + rng.next_f32(), c[1] + rng.next_f32(), c[2] + rng.next_f32() * 1e-4]);
        }
        idx.push([3 * t as u32, 3 * t as u32 + 1, 3 * t as u32 + 2]);
    }
    (pos, idx)
}

#[test]
fn passes_match_cpu_for_edge_counts_and_both_code_widths() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut gpu = CharacterizeGpu::new(&ctx).expect("pipelines");
    let mut rng = Rng(3);
    let wg = ctx.caps().workgroup_size() as usize;
    for &n in &[1usize, 2, 3, 7, wg - 1, wg + 1, 8 * wg + 5, 50_001] {
        let (pos, idx) = soup(&mut rng, n);
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            for k in [1u32, 2, 17, 64] {
                check(&mut gpu, &ctx, &pos, &idx, 1, bits, k);
            }
        }
        check(&mut gpu, &ctx, &pos, &idx, 3, MortonBits::Bits30, 9);
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn passes_match_cpu_on_degenerate_meshes() {
    let Some(ctx) = gpu_support::context() else { return };
    let mut gpu = CharacterizeGpu::new(&ctx).expect("pipelines");
    // All triangles equal; a flat scene; huge and tiny coordinates; shared vertices with zero-area triangles.
    let tri = vec![[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, -9.0]];
    let idx_equal: Vec<[u32; 3]> = vec![[0, 1, 2]; 1000];
    check(&mut gpu, &ctx, &tri, &idx_equal, 1, MortonBits::Bits30, 5);
    let mut rng = Rng(5);
    let (mut pos, idx) = soup(&mut rng, 5000);
    pos.iter_mut().for_each(|p| p[2] = 0.0);
    check(&mut gpu, &ctx, &pos, &idx, 1, MortonBits::Bits63, 23);
    for scale in [1e30f32, 1e-30] {
        let (pos, idx) = soup(&mut rng, 3000);
        let pos: Vec<[f32; 3]> = pos.iter().map(|p| p.map(|c| c * scale)).collect();
        check(&mut gpu, &ctx, &pos, &idx, 1, MortonBits::Bits30, 11);
    }
    let line: Vec<[f32; 3]> = (0..100).map(|i| [i as f32, 2.0 * i as f32, 0.5]).collect();
    let idx_line: Vec<[u32; 3]> = (0..2000u32).map(|i| [i % 100, (i * 7) % 100, (i * 13) % 100]).collect();
    check(&mut gpu, &ctx, &line, &idx_line, 1, MortonBits::Bits63, 31);
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn arrays_larger_than_one_storage_buffer_binding() {
    let Some(ctx) = gpu_support::context() else { return };
    let range = ctx.caps().max_storage_buffer_range as u64;
    // Index triples and keys of 12 bytes per triangle: enough triangles that both exceed one binding's range, as
    // long as the host can hold them (40M triangles: 480 MB of indices). A device whose range is larger (discrete
    // GPUs report up to 4 GiB) runs the same check at the cap; the kernels address memory through device addresses,
    // never through a binding's range, so the effect is the same code path there.
    const HOST_CAP: u64 = 40_000_000;
    let n = (range / 12 + 1000).min(HOST_CAP) as usize;
    let mut rng = Rng(9);
    let pos: Vec<[f32; 3]> = (0..4096).map(|_| [rng.next_f32(), rng.next_f32(), rng.next_f32()]).collect();
    let idx: Vec<[u32; 3]> = (0..n)
        .map(|_| [(rng.next_u64() % 4096) as u32, (rng.next_u64() % 4096) as u32, (rng.next_u64() % 4096) as u32])
        .collect();
    if 12 * (n as u64) <= range {
        eprintln!(
            "maxStorageBufferRange {range} exceeds what the test may allocate ({n} triangles): checked at the cap"
        );
    } else {
        assert!(12 * n as u64 > range);
    }
    let mut gpu = CharacterizeGpu::new(&ctx).expect("pipelines");
    check(&mut gpu, &ctx, &pos, &idx, 1, MortonBits::Bits30, 40);
    gpu_support::assert_no_validation_messages(&ctx);
}
