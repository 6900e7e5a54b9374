//! The CPU paths of `docs/spec.md`: [`naive`], a single-threaded transcription of the steps (the reference, and the
//! thesis's "naive implementation" of Table 5.3), and [`fast`], chunked over rayon with fixed-width integer
//! accumulators. Both take keys, bounds and codes from [`crate::keys`] (the definitions the LBVH and the feature
//! pass use too) and finish with [`super::finalize`]. Both produce the same [`Characterization`] bit for bit (timings, backend and device aside).

use super::finalize::{self, class_from_thresholds, class_thresholds};
use super::{Backend, CharError, Characterization, CodeStats, Exact, Params, PassTime, PerTriangle};
use crate::keys::{self, MortonBits, Quantizer};
use crate::mesh::Mesh;
use num_bigint::BigUint;
use num_traits::Zero;
use rayon::prelude::*;
use std::time::Instant;

/// Triangles per rayon task in [`fast`].
const CHUNK: usize = 1 << 15;

/// The CPU model (from `/proc/cpuinfo` where there is one) and the number of threads used.
pub fn cpu_device_name(threads: usize) -> String {
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    format!("{model} ({threads} thread{})", if threads == 1 { "" } else { "s" })
}

/// Number of sampled triangles: those with `i % stride == 0`.
fn sample_count(total: usize, stride: usize) -> usize {
    total.div_ceil(stride)
}

/// Checks `params` and `mesh`, and returns the number of sampled triangles (at least 1).
fn check_input(mesh: &Mesh, params: &Params) -> Result<usize, CharError> {
    params.validate()?;
    mesh.validate()?;
    let n = sample_count(mesh.triangle_count(), params.sample_stride as usize);
    if n == 0 {
        return Err(CharError::Empty { mesh: mesh.name.clone() });
    }
    Ok(n)
}

/// Step 1 for triangle `i` (indices are valid: the mesh was validated).
#[inline]
fn key_of(mesh: &Mesh, i: usize) -> [f32; 3] {
    let [a, b, c] = mesh.indices[i];
    let p = &mesh.positions;
    keys::centroid_key(p[a as usize], p[b as usize], p[c as usize])
}

fn pass(name: &str, t: Instant) -> PassTime {
    PassTime { name: name.to_string(), ms: t.elapsed().as_secs_f64() * 1e3 }
}

/// The single-threaded reference: docs/spec.md steps 1 to 10 written out one element at a time on the calling thread
/// (keys, bounds and codes by the scalar definitions of [`crate::keys`], [`Quantizer::of_slice`]), power sums in
/// `BigUint`.
///
/// Errors: invalid parameters, an invalid mesh (the error names the vertex), no (sampled) triangles, a centroid key
/// that overflows f32, bounds that f32 cannot quantize.
pub fn naive(mesh: &Mesh, params: &Params) -> Result<Characterization, CharError> {
    let start = Instant::now();
    check_input(mesh, params)?;
    let stride = params.sample_stride as usize;
    let bits = params.morton_bits;
    let mut timings = Vec::new();

    // Steps 1 and 2: keys and bounds; step 3, host part: the scale.
    let t = Instant::now();
    let keys_v: Vec<[f32; 3]> = (0..mesh.triangle_count()).step_by(stride).map(|i| key_of(mesh, i)).collect();
    let q = Quantizer::of_slice(&keys_v, bits).map_err(|e| CharError::of_keys(&mesh.name, stride, e))?;
    let (lo, hi) = (q.lo(), q.hi());
    timings.push(pass("keys_bounds", t));

    // Steps 3 to 5: quantization, Morton codes, exact power sums.
    let t = Instant::now();
    let mut codes = Vec::with_capacity(keys_v.len());
    let mut s1 = BigUint::zero();
    let mut s2 = BigUint::zero();
    let mut s3 = BigUint::zero();
    for key in &keys_v {
        let code = q.code(*key);
        let m = BigUint::from(code);
        s1 += &m;
        s2 += &m * &m;
        s3 += &m * &m * &m;
        codes.push(code);
    }
    let stats = CodeStats {
        n: codes.len() as u64,
        code_min: codes.iter().copied().min().unwrap_or(0),
        code_max: codes.iter().copied().max().unwrap_or(0),
        s1,
        s2,
        s3,
    };
    let k = finalize::class_count_of(params.class_rule, &stats);
    timings.push(pass("morton_moments", t));

    // Steps 7 and 8: classes by the u128 formula, histogram by counting.
    let t = Instant::now();
    let classes: Vec<u32> = codes.iter().map(|&c| finalize::class_of(c, stats.code_min, stats.code_max, k)).collect();
    let mut histogram = vec![0u64; k as usize];
    for &c in &classes {
        histogram[c as usize] += 1;
    }
    timings.push(pass("classes_histogram", t));

    // Steps 9 and 10.
    let t = Instant::now();
    let hstats = finalize::histogram_stats(&histogram, stats.n, params.alpha);
    timings.push(pass("chi_square", t));
    timings.push(pass(PassTime::TOTAL, start));

    let per_triangle = params.keep_per_triangle.then_some(PerTriangle { codes, classes });
    let exact = Exact { lo, hi, code_stats: stats, classes: k, histogram, stats: hstats, per_triangle };
    Ok(Characterization::from_exact(mesh, params, exact, timings, Backend::Naive, cpu_device_name(1)))
}

/// A 256-bit unsigned accumulator (`hi * 2^128 + lo`).
#[derive(Clone, Copy, Default)]
struct U256 {
    lo: u128,
    hi: u128,
}

impl U256 {
    #[inline]
    fn add(&mut self, lo: u128, hi: u128) {
        let (l, carry) = self.lo.overflowing_add(lo);
        self.lo = l;
        self.hi = self.hi.wrapping_add(hi).wrapping_add(u128::from(carry));
    }
    fn to_big(self) -> BigUint {
        (BigUint::from(self.hi) << 128u32) + BigUint::from(self.lo)
    }
}

/// Power sums and extremes of one chunk of codes.
#[derive(Clone)]
struct ChunkSums {
    min: u64,
    max: u64,
    s1: u128,
    s2: U256,
    s3: U256,
}

impl ChunkSums {
    /// 30-bit codes: `m^3 < 2^90`, so every sum of a chunk of at most 2^32 codes fits `u128`.
    fn of_30(codes: &[u64]) -> ChunkSums {
        let (mut min, mut max) = (u64::MAX, 0u64);
        let (mut s1, mut s2, mut s3) = (0u64, 0u128, 0u128);
        for &m in codes {
            min = min.min(m);
            max = max.max(m);
            let m2 = m * m;
            s1 += m;
            s2 += u128::from(m2);
            s3 += u128::from(m2) * u128::from(m);
        }
        ChunkSums { min, max, s1: s1.into(), s2: U256 { lo: s2, hi: 0 }, s3: U256 { lo: s3, hi: 0 } }
    }

    /// 63-bit codes: `m^2 < 2^126` in `u128`, `m^3 < 2^189` as a 192-bit product, sums in 256 bits.
    fn of_63(codes: &[u64]) -> ChunkSums {
        let (mut min, mut max) = (u64::MAX, 0u64);
        let mut s1 = 0u128;
        let mut s2 = U256::default();
        let mut s3 = U256::default();
        for &m in codes {
            min = min.min(m);
            max = max.max(m);
            let mw = u128::from(m);
            let m2 = mw * mw;
            s1 += mw;
            s2.add(m2, 0);
            // m^3 = m2_lo * m + (m2_hi * m) << 64.
            let p0 = (m2 as u64 as u128) * mw;
            let p1 = ((m2 >> 64) as u64 as u128) * mw;
            let (lo, carry) = p0.overflowing_add(p1 << 64);
            s3.add(lo, (p1 >> 64) + u128::from(carry));
        }
        ChunkSums { min, max, s1, s2, s3 }
    }
}

/// The rayon path: bounds in the total order of [`keys::ordered_bits`] and codes by [`Quantizer`],
/// power sums in fixed-width integers (`u128`, 256 bits for 63-bit codes) combined exactly, classes by `u64`
/// division where `(m_max - m_min) k < 2^64` and by [`class_thresholds`] otherwise, per-chunk histograms merged.
///
/// Same errors as [`naive`]; the same triangle is named when several keys overflow (the first one).
pub fn fast(mesh: &Mesh, params: &Params) -> Result<Characterization, CharError> {
    let start = Instant::now();
    let n = check_input(mesh, params)?;
    let stride = params.sample_stride;
    let bits = params.morton_bits;
    let mut timings = Vec::new();
    let tri = |j: usize| j * stride as usize;

    // Steps 1 and 2: bounds in parallel, in ordered-bits form; the first overflowing key, if any; step 3, host
    // part: the scale.
    let t = Instant::now();
    let q = Quantizer::of_keys(n, |j| key_of(mesh, tri(j)), bits)
        .map_err(|e| CharError::of_keys(&mesh.name, stride as usize, e))?;
    let (lo, hi) = (q.lo(), q.hi());
    timings.push(pass("keys_bounds", t));

    // Steps 3 to 5.
    let t = Instant::now();
    let mut codes = vec![0u64; n];
    let sums: Vec<ChunkSums> = codes
        .par_chunks_mut(CHUNK)
        .enumerate()
        .map(|(c, out)| {
            let base = c * CHUNK;
            for (o, j) in out.iter_mut().zip(base..) {
                *o = q.code(key_of(mesh, tri(j)));
            }
            match bits {
                MortonBits::Bits30 => ChunkSums::of_30(out),
                MortonBits::Bits63 => ChunkSums::of_63(out),
            }
        })
        .collect();
    let mut stats = CodeStats {
        n: n as u64,
        code_min: u64::MAX,
        code_max: 0,
        s1: BigUint::zero(),
        s2: BigUint::zero(),
        s3: BigUint::zero(),
    };
    for s in sums {
        stats.code_min = stats.code_min.min(s.min);
        stats.code_max = stats.code_max.max(s.max);
        stats.s1 += BigUint::from(s.s1);
        stats.s2 += s.s2.to_big();
        stats.s3 += s.s3.to_big();
    }
    let k = finalize::class_count_of(params.class_rule, &stats);
    timings.push(pass("morton_moments", t));

    // Steps 7 and 8.
    let t = Instant::now();
    let (cmin, d) = (stats.code_min, stats.code_max - stats.code_min);
    let thresholds = class_thresholds(stats.code_min, stats.code_max, k);
    let use_div = k > 1 && d > 0 && (d as u128) * (k as u128) <= u64::MAX as u128;
    let k64 = u64::from(k);
    let class = |m: u64| -> u32 {
        if k <= 1 || d == 0 {
            0
        } else if use_div {
            // (m - m_min) k <= D k < 2^64: the u128 formula of step 7 in u64.
            (((m - cmin) * k64) / d).min(k64 - 1) as u32
        } else {
            class_from_thresholds(m - cmin, &thresholds)
        }
    };
    let kk = k as usize;
    let mut classes_out = if params.keep_per_triangle { vec![0u32; n] } else { Vec::new() };
    let histogram: Vec<u64> = if params.keep_per_triangle {
        codes
            .par_chunks(CHUNK)
            .zip(classes_out.par_chunks_mut(CHUNK))
            .map(|(cs, out)| {
                let mut h = vec![0u64; kk];
                for (o, &m) in out.iter_mut().zip(cs) {
                    let c = class(m);
                    *o = c;
                    h[c as usize] += 1;
                }
                h
            })
            .reduce(|| vec![0u64; kk], merge_hist)
    } else {
        codes
            .par_chunks(CHUNK)
            .map(|cs| {
                let mut h = vec![0u64; kk];
                for &m in cs {
                    h[class(m) as usize] += 1;
                }
                h
            })
            .reduce(|| vec![0u64; kk], merge_hist)
    };
    timings.push(pass("classes_histogram", t));

    // Steps 9 and 10.
    let t = Instant::now();
    let hstats = finalize::histogram_stats(&histogram, stats.n, params.alpha);
    timings.push(pass("chi_square", t));
    timings.push(pass(PassTime::TOTAL, start));

    let per_triangle = params.keep_per_triangle.then_some(PerTriangle { codes, classes: classes_out });
    let exact = Exact { lo, hi, code_stats: stats, classes: k, histogram, stats: hstats, per_triangle };
    let device = cpu_device_name(rayon::current_num_threads());
    Ok(Characterization::from_exact(mesh, params, exact, timings, Backend::Cpu, device))
}

fn merge_hist(mut a: Vec<u64>, b: Vec<u64>) -> Vec<u64> {
    for (x, y) in a.iter_mut().zip(b) {
        *x += y;
    }
    a
}

/// Number of sampled triangles (`i % sample_stride == 0`) whose area is exactly zero, by the test of
/// [`Mesh::zero_area_count`] (f64 cross product of the f32 edges), in parallel. Indices must be valid
/// (validated mesh); `sample_stride` 0 is treated as 1.
pub fn zero_area_triangles(mesh: &Mesh, sample_stride: u32) -> u64 {
    let stride = sample_stride.max(1) as usize;
    let n = sample_count(mesh.triangle_count(), stride);
    let nv = mesh.positions.len();
    (0..n)
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&j| {
            let [a, b, c] = mesh.indices[j * stride];
            if a as usize >= nv || b as usize >= nv || c as usize >= nv {
                return false;
            }
            let [a, b, c] = mesh.triangle(j * stride);
            let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
            (b - a).cross(c - a).length_squared() == 0.0
        })
        .count() as u64
}
