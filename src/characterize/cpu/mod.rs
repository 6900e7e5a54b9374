//! The CPU paths of `docs/spec.md`: [`naive`], a single-threaded transcription of the steps (the reference, and the
//! thesis's "naive implementation" of Table 5.3), and [`fast`], over rayon in three passes (the bounds; the codes
//! with their exact power sums; the histogram over the stored codes) with fixed-width integer accumulators. [`naive`]
//! takes keys, bounds and codes from `crate::keys` (the definitions the LBVH and the feature pass use too); [`fast`]
//! computes the same values in vectorizable forms whose equality with those definitions its tests check. Both finish
//! with `super::finalize` and produce the same [`Characterization`] bit for bit (timings, backend and device
//! aside).

use super::finalize::{self, class_thresholds};
use super::{Backend, CharError, Characterization, CodeStats, Exact, Params, PassTime, PerTriangle};
use crate::keys::{self, KeyBounds, KeyError, MortonBits, Quantizer};
use crate::mesh::Mesh;
use num_bigint::BigUint;
use num_traits::Zero;
use rayon::prelude::*;
use std::time::Instant;

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
/// (keys, bounds and codes by the scalar definitions of `crate::keys`, `Quantizer::of_slice`), power sums in
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

mod bounds;
mod classes;
mod codes;

use bounds::*;
use classes::*;
use codes::*;

/// The working memory of [`fast_with`], kept between calls: the sample's centroid keys (12 bytes per sampled
/// triangle) and its Morton codes (4 bytes per sampled triangle for 30-bit codes, 8 for 63-bit ones), as large as
/// the largest sample characterized with it. With the keys kept, pass 2 reads them in order instead of gathering
/// every triangle's vertices a second time. Fresh memory is expensive, though: on the 2-core development VM the
/// first write to the 14 MB that the dragon (871,414 triangles) needs costs about 6 ms in page faults, as much as
/// the characterization itself, so [`fast`], which has no memory to keep, gathers twice and allocates only the
/// codes, and a caller that characterizes every frame keeps one `Scratch` (as [`super::Characterizer`] does) and
/// pays for it once.
#[derive(Default)]
pub struct Scratch {
    keys: SampleKeys,
    codes30: Vec<u32>,
    codes63: Vec<u64>,
}

impl Scratch {
    /// The codes of the last [`fast_with`] run's `n` sampled triangles with `bits` codes, when it kept them here (it
    /// returns them per triangle under `keep_per_triangle` instead).
    pub(crate) fn sample_codes(
        &self,
        n: usize,
        bits: MortonBits,
    ) -> Option<crate::characterize::features::SampleCodes<'_>> {
        use crate::characterize::features::SampleCodes;
        match bits {
            MortonBits::Bits30 => self.codes30.get(..n).map(SampleCodes::Bits30),
            MortonBits::Bits63 => self.codes63.get(..n).map(SampleCodes::Wide),
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.keys.x.capacity() + self.keys.y.capacity() + self.keys.z.capacity() + self.codes30.capacity())
            + 8 * self.codes63.capacity()
    }
}

/// The rayon path, in three passes over the sample, each in tasks of `TASK` sampled triangles: the validation of
/// the mesh and the key bounds; then, fused, the codes (stored, `u32` where they fit), their range and their power
/// sums, in fixed-width integers that are folded into big integers once per task; then the classes and the histogram
/// over the stored codes alone, from an `f32` estimate corrected by the exact thresholds (no division). The inner
/// loops are written so that the compiler vectorizes them with the baseline x86-64 instruction set (SSE2). The same
/// result as [`naive`] bit for bit (timings, backend and device aside).
///
/// Same errors as [`naive`]; the same triangle is named when several keys overflow (the first one).
pub fn fast(mesh: &Mesh, params: &Params) -> Result<Characterization, CharError> {
    run_fast(mesh, params, None)
}

/// [`fast`] in the working memory `scratch`, kept for the next call (see [`Scratch`]): pass 1 keeps the sample's
/// keys there, and pass 2 reads them instead of gathering the vertices again. The same result.
pub fn fast_with(mesh: &Mesh, params: &Params, scratch: &mut Scratch) -> Result<Characterization, CharError> {
    run_fast(mesh, params, Some(scratch))
}

/// [`fast`] and [`fast_with`], as one job of the thread pool ([`crate::in_pool`]).
/// The total time counts from the call, the hand-over to the pool included.
fn run_fast(mesh: &Mesh, params: &Params, scratch: Option<&mut Scratch>) -> Result<Characterization, CharError> {
    let start = Instant::now();
    crate::in_pool(|| run_fast_here(mesh, params, scratch, start))
}

fn run_fast_here(
    mesh: &Mesh,
    params: &Params,
    scratch: Option<&mut Scratch>,
    start: Instant,
) -> Result<Characterization, CharError> {
    params.validate()?;
    let stride = params.sample_stride as usize;
    let n = sample_count(mesh.triangle_count(), stride);
    if n == 0 {
        mesh.validate()?;
        return Err(CharError::Empty { mesh: mesh.name.clone() });
    }
    let bits = params.morton_bits;
    let mut timings = Vec::new();

    // Validation; steps 1 and 2, and step 3's host part.
    let t = Instant::now();
    let (keys, codes30, codes63) = match scratch {
        Some(Scratch { keys, codes30, codes63 }) => (Some(keys), Some(codes30), Some(codes63)),
        None => (None, None, None),
    };
    let mut keys = keys;
    let q = sample_quantizer(mesh, stride, n, bits, keys.as_deref_mut())?;
    let source = match keys.as_deref() {
        Some(k) => SampleSource::Stored(k),
        None => SampleSource::Gather(mesh, stride),
    };
    timings.push(pass("keys_bounds", t));

    // Steps 3 to 6, then 7 and 8.
    let keep = params.keep_per_triangle;
    let (stats, k, histogram, per_triangle) = if bits == MortonBits::Bits30 && !keep {
        let t = Instant::now();
        let mut fresh: Vec<u32>;
        let codes = match codes30 {
            Some(v) => sized(v, n),
            None => {
                fresh = vec![0u32; n];
                &mut fresh[..]
            }
        };
        let stats = sample_codes30(source, &q, codes);
        let k = finalize::class_count_of(params.class_rule, &stats);
        timings.push(pass("morton_moments", t));
        let t = Instant::now();
        let histogram = sample_histogram(codes, &stats, k, &mut []);
        timings.push(pass("classes_histogram", t));
        (stats, k, histogram, None)
    } else {
        let t = Instant::now();
        // The codes returned per triangle are the caller's; others stay in the scratch.
        let mut owned = Vec::new();
        let codes = match codes63 {
            Some(v) if !keep => sized(v, n),
            _ => {
                owned = vec![0u64; n];
                &mut owned[..]
            }
        };
        let stats = match bits {
            MortonBits::Bits30 => sample_codes30(source, &q, codes),
            MortonBits::Bits63 => sample_codes63(source, &q, codes),
        };
        let k = finalize::class_count_of(params.class_rule, &stats);
        timings.push(pass("morton_moments", t));
        let t = Instant::now();
        let mut classes = if keep { vec![0u32; n] } else { Vec::new() };
        let histogram = sample_histogram(codes, &stats, k, &mut classes);
        timings.push(pass("classes_histogram", t));
        (stats, k, histogram, keep.then_some(PerTriangle { codes: owned, classes }))
    };

    // Steps 9 and 10.
    let t = Instant::now();
    let hstats = finalize::histogram_stats(&histogram, stats.n, params.alpha);
    timings.push(pass("chi_square", t));
    timings.push(pass(PassTime::TOTAL, start));

    let exact = Exact { lo: q.lo(), hi: q.hi(), code_stats: stats, classes: k, histogram, stats: hstats, per_triangle };
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::characterize::ClassRule;
    use crate::mesh::generate;
    use crate::rng::SplitMix64 as Rng;

    /// Floats of every kind but NaN: zeros of both signs, subnormals, normals, infinities, random bit patterns.
    fn floats(g: &mut Rng, count: usize) -> Vec<f32> {
        let mut v = vec![0.0, -0.0, f32::MIN_POSITIVE, -f32::MIN_POSITIVE, 1e-45, -1e-45, 1.0, -1.0, f32::MAX];
        v.extend([f32::MIN, f32::INFINITY, f32::NEG_INFINITY]);
        while v.len() < count {
            let x = f32::from_bits(g.next_u64() as u32);
            if !x.is_nan() {
                v.push(x);
            }
        }
        v
    }

    #[test]
    fn ordered_is_ordered_bits() {
        let mut g = Rng(1);
        for x in floats(&mut g, 100_000) {
            assert_eq!(ordered(x), keys::ordered_bits(x), "{x:e}");
        }
    }

    #[test]
    fn ordered_range_is_the_total_order_range() {
        let mut g = Rng(2);
        let all = floats(&mut g, 4000);
        let zeros = [0.0f32, -0.0];
        let mut sets: Vec<Vec<f32>> =
            vec![vec![0.0], vec![-0.0], vec![0.0, -0.0], vec![-0.0, 0.0, 1.0], vec![-1.0, -0.0]];
        sets.push(vec![-1.0, 0.0, -0.0, -3.0]);
        for len in [1usize, 2, 7, 8, 9, 17, 255, 256] {
            for s in 0..20u64 {
                let mut v: Vec<f32> = (0..len).map(|_| all[g.below(all.len() as u64) as usize]).collect();
                if s % 3 == 0 {
                    // Mostly zeros of both signs, with small values of either sign.
                    for x in v.iter_mut() {
                        *x = match g.below(4) {
                            0 => 1e-3,
                            1 => -1e-3,
                            z => zeros[(z & 1) as usize],
                        };
                    }
                }
                sets.push(v);
            }
        }
        for v in sets {
            let (mut lo, mut hi) = (u32::MAX, 0);
            ordered_range(&v, &mut lo, &mut hi);
            let want =
                v.iter().fold((u32::MAX, 0), |(l, h), &x| (l.min(keys::ordered_bits(x)), h.max(keys::ordered_bits(x))));
            assert_eq!((lo, hi), want, "{v:?}");
        }
    }

    #[test]
    fn spread_table_is_the_definition() {
        for v in 0..1u32 << 10 {
            assert_eq!(spread10(v), keys::spread10(v));
        }
        for v in 0..1u32 << 21 {
            assert_eq!(spread21(v), keys::spread21(v), "{v}");
        }
    }

    #[test]
    fn cells_are_keys_quantize() {
        let mut g = Rng(3);
        let mut checked = 0;
        for bits in [MortonBits::Bits30, MortonBits::Bits63] {
            for case in 0..200 {
                // Keys on a random box (sometimes flat on one axis, sometimes straddling 0, sometimes tiny).
                let scale = [1e-30f32, 1e-3, 1.0, 1e3, 1e30][case % 5];
                let mut keys: Vec<[f32; 3]> = (0..64)
                    .map(|_| std::array::from_fn(|a| if case % 7 == a { 2.5 } else { (g.next_f32() - 0.3) * scale }))
                    .collect();
                keys.push([-0.0, 0.0, -0.0]);
                let Ok(q) = Quantizer::of_slice(&keys, bits) else { continue };
                let cells = Cells::of(&q);
                // The keys, the bounds and their neighbours within the box.
                let mut probe = keys.clone();
                probe.push(q.lo());
                probe.push(q.hi());
                probe.push(std::array::from_fn(|a| f32::from_bits(q.hi()[a].to_bits().wrapping_sub(1)).max(q.lo()[a])));
                for k in probe {
                    let want = keys::quantize(k, q.lo(), q.scale(), bits);
                    let got: [u32; 3] = std::array::from_fn(|a| cells.cell(k[a], a));
                    assert_eq!(got, want, "{k:?} in {:?} {:?} ({bits:?})", q.lo(), q.hi());
                }
                checked += 1;
            }
        }
        assert!(checked >= 390, "{checked} boxes");
    }

    #[test]
    fn classifier_is_class_of() {
        let mut g = Rng(4);
        let mut cases: Vec<(u64, u64, u32)> = vec![(0, 1, 2), (5, 6, 4096), (0, 1023, 4096), (0, (1 << 30) - 1, 4096)];
        cases.extend([(7, (1 << 63) - 1, 4096), (0, (1 << 63) - 1, 2), (1 << 62, (1 << 62) + 3, 7), (0, 4095, 4096)]);
        for _ in 0..300 {
            let width = [3u32, 10, 20, 30, 40, 63][g.below(6) as usize];
            let a = g.next_u64() >> (64 - width);
            let b = g.next_u64() >> (64 - width);
            let k = [2u32, 3, 23, 100, 4095, 4096][g.below(6) as usize];
            if a != b {
                cases.push((a.min(b), a.max(b), k));
            }
        }
        for (lo, hi, k) in cases {
            let cl = Classifier::new(lo, hi, k);
            let d = hi - lo;
            let mut xs: Vec<u64> = vec![0, d, d / 2, d.saturating_sub(1)];
            for t in class_thresholds(lo, hi, k) {
                xs.extend([t.saturating_sub(1), t, (t + 1).min(d)]);
            }
            xs.extend((0..200).map(|_| g.next_u64() % (d + 1)));
            for x in xs {
                let m = lo + x;
                let want = finalize::class_of(m, lo, hi, k);
                let e = m.offset_f32(lo);
                if hi < 1 << 30 {
                    assert_eq!((m as u32).offset_f32(lo), e);
                }
                assert_eq!(Classifier::class(&cl.e, x, cl.estimate(e)), want, "m {m} in [{lo}, {hi}], k {k}");
            }
        }
    }

    /// The exact sums of `codes`.
    fn big_sums(codes: &[u64]) -> (BigUint, BigUint, BigUint) {
        let mut s = (BigUint::zero(), BigUint::zero(), BigUint::zero());
        for &m in codes {
            let m = BigUint::from(m);
            s.0 += &m;
            s.1 += &m * &m;
            s.2 += &m * &m * &m;
        }
        s
    }

    #[test]
    fn task_sums_are_exact_at_the_largest_codes() {
        let mut g = Rng(5);
        let top30 = (1u64 << 30) - 1;
        let top63 = (1u64 << 63) - 1;
        for codes in [vec![top30; TASK], (0..TASK).map(|_| g.next_u64() >> 34).collect()] {
            let mut s = Sums30::new();
            for &m in &codes {
                s.add(m as u32);
            }
            let st = fold_sums(codes.len(), vec![s.finish()]);
            assert_eq!((st.s1, st.s2, st.s3), big_sums(&codes));
        }
        for codes in [vec![top63; TASK], (0..TASK).map(|_| g.next_u64() >> 1).collect(), vec![top63, 0, 1, top63 - 1]] {
            let mut s = Sums63::new();
            for &m in &codes {
                s.add(m);
            }
            let st = fold_sums(codes.len(), vec![s.finish()]);
            assert_eq!((st.code_min, st.code_max), (*codes.iter().min().unwrap(), *codes.iter().max().unwrap()));
            assert_eq!((st.s1, st.s2, st.s3), big_sums(&codes));
        }
    }

    /// `fast`, `fast_with` (in `scratch`, which earlier calls on other meshes have used) and `naive` give the same
    /// result (timings aside), with and without per-triangle data.
    fn assert_same(mesh: &Mesh, p: &Params, scratch: &mut Scratch) {
        let strip = |mut c: Characterization| {
            c.timings.clear();
            c.backend.clear();
            c.device.clear();
            c
        };
        let a = strip(fast(mesh, p).unwrap_or_else(|e| panic!("{}: {e}", mesh.name)));
        assert_eq!(a, strip(naive(mesh, p).unwrap()), "{} {p:?}", mesh.name);
        assert_eq!(a, strip(fast_with(mesh, p, scratch).unwrap()), "{} {p:?}: with a scratch", mesh.name);
        let kept = Params { keep_per_triangle: !p.keep_per_triangle, ..p.clone() };
        let c = strip(fast(mesh, &kept).unwrap());
        assert_eq!((&a.code_stats, &a.histogram, a.classes), (&c.code_stats, &c.histogram, c.classes));
    }

    #[test]
    fn fast_equals_naive() {
        let big = generate::random_soup(2 * TASK + 77, 6);
        let meshes = [
            generate::random_soup(3000, 7),
            generate::random_soup(TASK + 5, 12),
            generate::clustered(5000, 4, 8),
            generate::flat(999, 9),
            generate::all_equal(300),
            generate::single_triangle(),
            generate::two_triangles(),
            generate::collinear_centroids(257),
            generate::zero_area(600, 10),
            generate::random_soup(TASK, 11),
            big,
        ];
        let rules =
            [ClassRule::Doane, ClassRule::Sturges, ClassRule::Sqrt, ClassRule::Fixed(4096), ClassRule::Fixed(2)];
        // One scratch for all: meshes larger and smaller than the one before, so that it holds stale keys and codes
        // past the current sample.
        let mut scratch = Scratch::default();
        for mesh in &meshes {
            for bits in [MortonBits::Bits30, MortonBits::Bits63] {
                for (i, stride) in [1u32, 2, 3, 7].into_iter().enumerate() {
                    let p = Params {
                        morton_bits: bits,
                        sample_stride: stride,
                        class_rule: rules[(i + bits.total() as usize) % rules.len()],
                        keep_per_triangle: i % 2 == 1,
                        ..Params::default()
                    };
                    assert_same(mesh, &p, &mut scratch);
                }
            }
            assert_same(mesh, &Params { class_rule: ClassRule::Fixed(4096), ..Params::default() }, &mut scratch);
        }
    }

    #[test]
    fn invalid_meshes_give_the_validation_error() {
        let good = generate::random_soup(3 * TASK, 12);
        let mut bad_vertex = good.clone();
        bad_vertex.positions.push([0.0, f32::NAN, 0.0]); // no triangle uses it
        let mut bad_index = good.clone();
        bad_index.indices[2 * TASK + 1][2] = bad_index.positions.len() as u32; // not sampled with stride 2
        let mut bad_ids = good.clone();
        bad_ids.object_ids = Some(vec![0; 5]);
        let mut both = bad_index.clone();
        both.positions[7][0] = f32::INFINITY;
        for mesh in [&bad_vertex, &bad_index, &bad_ids, &both] {
            let want = mesh.validate().unwrap_err().to_string();
            for stride in [1, 2, 5] {
                let p = Params { sample_stride: stride, ..Params::default() };
                let e = fast(mesh, &p).unwrap_err();
                assert!(matches!(e, CharError::Mesh(_)), "{e}");
                assert_eq!(e.to_string(), want);
            }
        }
        let mut empty = good.clone();
        empty.indices.clear();
        assert!(matches!(fast(&empty, &Params::default()), Err(CharError::Empty { .. })));
        empty.positions[0][1] = f32::NAN;
        assert!(matches!(fast(&empty, &Params::default()), Err(CharError::Mesh(_))));
    }
}
