//! The CPU paths of `docs/spec.md`: [`naive`], a single-threaded transcription of the steps (the reference, and the
//! thesis's "naive implementation" of Table 5.3), and [`fast`], over rayon in three passes (the bounds; the codes
//! with their exact power sums; the histogram over the stored codes) with fixed-width integer accumulators. [`naive`]
//! takes keys, bounds and codes from [`crate::keys`] (the definitions the LBVH and the feature pass use too); [`fast`]
//! computes the same values in vectorizable forms whose equality with those definitions its tests check. Both finish
//! with [`super::finalize`] and produce the same [`Characterization`] bit for bit (timings, backend and device
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

/// A 256-bit unsigned value (`hi * 2^128 + lo`).
#[derive(Clone, Copy, Default)]
struct U256 {
    lo: u128,
    hi: u128,
}

impl U256 {
    fn to_big(self) -> BigUint {
        (BigUint::from(self.hi) << 128u32) + BigUint::from(self.lo)
    }
}

// ---------------------------------------------------------------------------------------------------------------
// The fused rayon path.

/// Sampled triangles per rayon task of [`fast`]. A task's index triples (12 bytes each) and codes stay in the
/// core's cache while it runs, and the dragon makes 54 tasks, enough to balance two to eight threads.
const TASK: usize = 1 << 14;

/// Triangles per block inside a task: their keys are gathered into three arrays of this length (3 KiB, in L1), which
/// the vectorized loops then read.
const BLOCK: usize = 256;

// The fixed-width sums of a task are exact for tasks of up to 2^32 codes (see `Sums30`, `Sums63`), and a task's
// histogram counts are `u32`.
const _: () = assert!(TASK <= 1 << 32 && TASK % BLOCK == 0);

/// The cells of one block of keys inside a task, by axis.
struct Block {
    cx: [u32; BLOCK],
    cy: [u32; BLOCK],
    cz: [u32; BLOCK],
}

impl Block {
    fn new() -> Box<Block> {
        Box::new(Block { cx: [0; BLOCK], cy: [0; BLOCK], cz: [0; BLOCK] })
    }
}

/// The centroid keys of the sample, by axis (`x[j]` of sampled triangle `j`): pass 1 of [`fast_with`] writes them
/// as it bounds them, and pass 2 reads them in order instead of gathering the vertices again.
#[derive(Default)]
struct SampleKeys {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
}

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
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.keys.x.capacity() + self.keys.y.capacity() + self.keys.z.capacity() + self.codes30.capacity())
            + 8 * self.codes63.capacity()
    }
}

/// `v` with `n` elements, its memory reused: no write when it had as many (the caller overwrites them).
fn sized<T: Copy + Default>(v: &mut Vec<T>, n: usize) -> &mut [T] {
    if v.len() < n {
        v.resize(n, T::default());
    }
    &mut v[..n]
}

/// One block of keys gathered from the vertices (where the sample's keys are not kept).
struct KeyBuf {
    x: [f32; BLOCK],
    y: [f32; BLOCK],
    z: [f32; BLOCK],
}

impl KeyBuf {
    fn new() -> Box<KeyBuf> {
        Box::new(KeyBuf { x: [0.0; BLOCK], y: [0.0; BLOCK], z: [0.0; BLOCK] })
    }
    fn slices(&mut self) -> (&mut [f32], &mut [f32], &mut [f32]) {
        (&mut self.x, &mut self.y, &mut self.z)
    }
}

/// Where pass 2 of [`fast_with`] finds a task's keys: stored by pass 1, or gathered again from the vertices of the
/// task's triangles.
#[derive(Clone, Copy)]
enum TaskKeys<'a> {
    Stored(&'a [f32], &'a [f32], &'a [f32]),
    Gather { tris: &'a [[u32; 3]], stride: usize, p: &'a [[f32; 3]] },
}

impl<'a> TaskKeys<'a> {
    /// The keys of the task's block `j` of `len` sampled triangles (gathered into `buf` when not stored).
    #[inline(always)]
    fn block<'b>(&self, j: usize, len: usize, buf: &'b mut KeyBuf) -> (&'b [f32], &'b [f32], &'b [f32])
    where
        'a: 'b,
    {
        match *self {
            TaskKeys::Stored(x, y, z) => {
                let r = j * BLOCK..j * BLOCK + len;
                (&x[r.clone()], &y[r.clone()], &z[r])
            }
            TaskKeys::Gather { tris, stride, p } => {
                let from = (j * BLOCK * stride).min(tris.len());
                let to = ((j * BLOCK + len) * stride).min(tris.len());
                gather_sampled(&tris[from..to], stride, p, buf.slices());
                (&buf.x[..len], &buf.y[..len], &buf.z[..len])
            }
        }
    }
}

/// Step 1 for the triangles of `tris`: their keys into `x`, `y`, `z` (as many as the shortest of the four).
/// Returns how many, and whether every index was below `p.len()` (the key of a triangle with an index out of range
/// is left as 0; the caller reports the mesh invalid).
#[inline(always)]
fn gather<'a>(
    tris: impl Iterator<Item = &'a [u32; 3]>,
    p: &[[f32; 3]],
    x: &mut [f32],
    y: &mut [f32],
    z: &mut [f32],
) -> (usize, bool) {
    let mut len = 0;
    let mut ok = true;
    for (t, ((x, y), z)) in tris.zip(x.iter_mut().zip(y.iter_mut()).zip(z.iter_mut())) {
        let k = match (p.get(t[0] as usize), p.get(t[1] as usize), p.get(t[2] as usize)) {
            (Some(&a), Some(&b), Some(&c)) => keys::centroid_key(a, b, c),
            _ => {
                ok = false;
                [0.0; 3]
            }
        };
        (*x, *y, *z) = (k[0], k[1], k[2]);
        len += 1;
    }
    (len, ok)
}

/// [`gather`] for the sampled triangles of `tris`: every one (`stride == 1`) or every `stride`-th.
#[inline(always)]
fn gather_sampled(
    tris: &[[u32; 3]],
    stride: usize,
    p: &[[f32; 3]],
    (x, y, z): (&mut [f32], &mut [f32], &mut [f32]),
) -> (usize, bool) {
    if stride == 1 {
        gather(tris.iter(), p, x, y, z)
    } else {
        gather(tris.iter().step_by(stride), p, x, y, z)
    }
}

/// Whether every coordinate is finite, in a loop the compiler vectorizes.
fn all_finite(v: &[[f32; 3]]) -> bool {
    v.as_flattened().iter().fold(true, |ok, x| ok & x.is_finite())
}

/// Whether every index is below `nv`, in a loop the compiler vectorizes.
fn all_below(tris: &[[u32; 3]], nv: usize) -> bool {
    match u32::try_from(nv) {
        Ok(nv) => tris.as_flattened().iter().fold(true, |ok, &i| ok & (i < nv)),
        Err(_) => true, // more vertices than a u32 index can name
    }
}

/// [`keys::ordered_bits`] without a branch: the sign bit, spread over the word by the arithmetic shift, flips every
/// bit of a negative float, and the top bit is set for a positive one.
#[inline(always)]
fn ordered(x: f32) -> u32 {
    let b = x.to_bits();
    b ^ ((((b as i32) >> 31) as u32) | 0x8000_0000)
}

/// Minimum and maximum of `ordered(x)` over `x` in `v` (finite or infinite keys), merged into `lo` and `hi`.
///
/// In the f32 order, with the lanes of vector `minps` and `maxps` (the comparison form of the minimum is that
/// instruction), noting apart whether `-0.0` and `+0.0` occur: the f32 minimum is the total-order minimum except
/// that `-0.0` and `+0.0` compare equal, so when it is a zero it is `-0.0` if `-0.0` occurs and `+0.0` otherwise;
/// likewise the maximum, a zero, is `+0.0` if `+0.0` occurs.
#[inline(always)]
fn ordered_range(v: &[f32], lo: &mut u32, hi: &mut u32) {
    const L: usize = 8;
    let (mut l, mut h) = ([f32::INFINITY; L], [f32::NEG_INFINITY; L]);
    let mut chunks = v.chunks_exact(L);
    for c in &mut chunks {
        let Ok(c) = <&[f32; L]>::try_from(c) else { continue }; // always a full chunk
        for i in 0..L {
            l[i] = if c[i] < l[i] { c[i] } else { l[i] };
            h[i] = if c[i] > h[i] { c[i] } else { h[i] };
        }
    }
    for &x in chunks.remainder() {
        l[0] = if x < l[0] { x } else { l[0] };
        h[0] = if x > h[0] { x } else { h[0] };
    }
    let (neg0, pos0) = v
        .iter()
        .fold((0u32, 0u32), |(n, p), &x| (n | u32::from(x.to_bits() == 0x8000_0000), p | u32::from(x.to_bits() == 0)));
    let (neg0, pos0) = (neg0 != 0, pos0 != 0);
    let min = l.iter().fold(f32::INFINITY, |a, &b| if b < a { b } else { a });
    let max = h.iter().fold(f32::NEG_INFINITY, |a, &b| if b > a { b } else { a });
    let min = if min == 0.0 && neg0 {
        -0.0
    } else if min == 0.0 {
        0.0
    } else {
        min
    };
    let max = if max == 0.0 && pos0 {
        0.0
    } else if max == 0.0 {
        -0.0
    } else {
        max
    };
    (*lo, *hi) = ((*lo).min(ordered(min)), (*hi).max(ordered(max)));
}

/// What pass 1 of [`fast`] learns from one task.
struct TaskBounds {
    /// `[lo_x, lo_y, lo_z, hi_x, hi_y, hi_z]` of the task's keys in ordered-bits form.
    bounds: [u32; 6],
    /// The task's part of the validation passed: its triangles' indices (all of them, sampled or not) and its share
    /// of the vertices.
    valid: bool,
}

/// Pass 1 of [`fast`] for one task: validation of the task's triangles `tris` (those from its first sampled
/// triangle to the next task's, sampled or not) and of the vertices `verts`, and steps 1 and 2 for the sampled
/// triangles, whose keys go to `keys` when given (one per sampled triangle of the task), block by block so that each
/// block's keys are still in L1 when they are bounded. With `stride == 1` the indices are checked as the keys are
/// gathered.
#[inline(never)]
fn task_bounds(
    tris: &[[u32; 3]],
    stride: usize,
    verts: &[[f32; 3]],
    p: &[[f32; 3]],
    keys: Option<(&mut [f32], &mut [f32], &mut [f32])>,
) -> TaskBounds {
    let mut valid = all_finite(verts) && (stride == 1 || all_below(tris, p.len()));
    let mut lo = [u32::MAX; 3];
    let mut hi = [0u32; 3];
    let mut bound = |block: &[[u32; 3]], (x, y, z): (&mut [f32], &mut [f32], &mut [f32])| {
        let (len, ok) = gather_sampled(block, stride, p, (x, y, z));
        valid &= ok;
        ordered_range(&x[..len], &mut lo[0], &mut hi[0]);
        ordered_range(&y[..len], &mut lo[1], &mut hi[1]);
        ordered_range(&z[..len], &mut lo[2], &mut hi[2]);
    };
    match keys {
        Some((x, y, z)) => {
            let out = x.chunks_mut(BLOCK).zip(y.chunks_mut(BLOCK)).zip(z.chunks_mut(BLOCK));
            for (block, ((x, y), z)) in tris.chunks(BLOCK * stride).zip(out) {
                bound(block, (x, y, z));
            }
        }
        None => {
            let mut buf = KeyBuf::new();
            for block in tris.chunks(BLOCK * stride) {
                bound(block, buf.slices());
            }
        }
    }
    TaskBounds { bounds: [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]], valid }
}

/// Validation and pass 1 of [`fast`]: the mesh checked as [`Mesh::validate`] checks it (each task checks its
/// triangles and a share of the vertices, in vectorized loops; on failure the error is the one `Mesh::validate`
/// returns, naming the first offending vertex or triangle), then the quantizer of the sample, with the first
/// overflowing key named as [`Quantizer::of_keys`] does it; and the keys of the sample into `keys` when given.
fn sample_quantizer(
    mesh: &Mesh,
    stride: usize,
    n: usize,
    bits: MortonBits,
    keys: Option<&mut SampleKeys>,
) -> Result<Quantizer, CharError> {
    let p = &mesh.positions[..];
    let total = mesh.triangle_count();
    let tasks = n.div_ceil(TASK);
    let verts_per_task = p.len().div_ceil(tasks.max(1));
    type Out<'k> = Option<(&'k mut [f32], &'k mut [f32], &'k mut [f32])>;
    let outs: Vec<Out<'_>> = match keys {
        Some(k) => {
            let (x, y, z) = (sized(&mut k.x, n), sized(&mut k.y, n), sized(&mut k.z, n));
            x.chunks_mut(TASK)
                .zip(y.chunks_mut(TASK))
                .zip(z.chunks_mut(TASK))
                .map(|((x, y), z)| Some((x, y, z)))
                .collect()
        }
        None => (0..tasks).map(|_| None).collect(),
    };
    let r = outs
        .into_par_iter()
        .enumerate()
        .map(|(t, out)| {
            let tris = task_tris(mesh, stride, t, TASK.min(n - t * TASK));
            let v0 = (t * verts_per_task).min(p.len());
            let verts = &p[v0..(v0 + verts_per_task).min(p.len())];
            task_bounds(tris, stride, verts, p, out)
        })
        .reduce(
            || TaskBounds { bounds: [u32::MAX, u32::MAX, u32::MAX, 0, 0, 0], valid: true },
            |a, b| TaskBounds {
                bounds: std::array::from_fn(|i| {
                    if i < 3 {
                        a.bounds[i].min(b.bounds[i])
                    } else {
                        a.bounds[i].max(b.bounds[i])
                    }
                }),
                valid: a.valid & b.valid,
            },
        );
    let ids = mesh.object_ids.as_ref().is_none_or(|ids| ids.len() == total);
    if !(r.valid && ids) {
        mesh.validate()?;
        // Not reached: both check the same conditions.
        return Err(CharError::Input { mesh: mesh.name.clone(), reason: "the mesh failed validation".into() });
    }
    let b = KeyBounds::from_ordered_bits(r.bounds);
    let finite = b.lo().iter().chain(&b.hi()).all(|c| c.is_finite());
    let q = match Quantizer::new(&b, bits) {
        // A bound is infinite: some key overflowed; name the first one.
        Err(KeyError::Extent { .. }) if !finite => {
            let first = (0..n)
                .into_par_iter()
                .map(|j| (j, key_of(mesh, j * stride)))
                .find_first(|(_, k)| !k.iter().all(|c| c.is_finite()));
            match first {
                Some((index, key)) => Err(KeyError::Overflow { index, key }),
                None => Quantizer::new(&b, bits),
            }
        }
        q => q,
    };
    q.map_err(|e| CharError::of_keys(&mesh.name, stride, e))
}

/// Steps 3 and 4 in the form of the inner loop of [`fast`]; the same codes as [`Quantizer::code`].
#[derive(Clone, Copy)]
struct Cells {
    lo: [f32; 3],
    scale: [f32; 3],
    /// `2^b - 1`.
    top: f32,
}

impl Cells {
    fn of(q: &Quantizer) -> Cells {
        Cells { lo: q.lo(), scale: q.scale(), top: ((1u32 << q.bits().per_axis()) - 1) as f32 }
    }

    /// `min(floor((s - lo) * scale), 2^b - 1)` on axis `a`, as [`keys::quantize`] computes it, in operations that
    /// vectorize without SSE4.1 (no `roundps`, and `as i32` is scalarized by its saturation).
    ///
    /// `d = (s - lo) * scale` is finite (the quantizer checked the bounds) and not negative (`s >= lo`), so
    /// `v = min(d, 2^b - 1)` lies in `[0, 2^b - 1]`, and `floor(v) = min(floor(d), 2^b - 1)` (`2^b - 1` is an
    /// integer). `t = v + 2^23` lies in `[2^23, 2^24)`, where f32 values are the integers, so `t = 2^23 + r` with `r`
    /// the integer nearest `v` (exact: `|r - v| <= 1/2`), `r` is the mantissa field of `t`, and `t - 2^23 = r` is
    /// exact. `floor(v)` is `r` when `r <= v` and `r - 1` when `r > v`.
    #[inline(always)]
    fn cell(&self, s: f32, a: usize) -> u32 {
        const MAGIC: f32 = 8_388_608.0; // 2^23
        let d = (s - self.lo[a]) * self.scale[a];
        let v = if d < self.top { d } else { self.top };
        let t = v + MAGIC;
        let r = t.to_bits() & 0x007f_ffff;
        r - u32::from(t - MAGIC > v)
    }

    /// Step 3 for the keys `x`, `y`, `z` (at most [`BLOCK`], equally many): their cells into `b.cx`, `b.cy`,
    /// `b.cz`, in a vectorized loop.
    #[inline(always)]
    fn cells(&self, (x, y, z): (&[f32], &[f32], &[f32]), b: &mut Block) {
        for (c, &s) in b.cx.iter_mut().zip(x) {
            *c = self.cell(s, 0);
        }
        for (c, &s) in b.cy.iter_mut().zip(y) {
            *c = self.cell(s, 1);
        }
        for (c, &s) in b.cz.iter_mut().zip(z) {
            *c = self.cell(s, 2);
        }
    }
}

/// `SPREAD[v]`: bit `i` of `v` moved to bit `3 i`, for `v < 2^11` (as [`keys::spread10`] for `v < 2^10`). A lookup
/// costs one load where the shifts and masks of the definition cost a dozen operations (and without SSE4.1 the
/// compiler turns their vector form into emulated 32-bit multiplications).
static SPREAD: [u32; 1 << 11] = spread_table();

const fn spread_table() -> [u32; 1 << 11] {
    let mut t = [0u32; 1 << 11];
    let mut v = 0;
    while v < t.len() {
        let mut i = 0;
        while i < 11 {
            t[v] |= ((v as u32 >> i) & 1) << (3 * i);
            i += 1;
        }
        v += 1;
    }
    t
}

/// [`keys::spread10`] for a cell `v < 2^10` (the mask only shows the compiler the bound).
#[inline(always)]
fn spread10(v: u32) -> u32 {
    SPREAD[(v & 0x7ff) as usize]
}

/// [`keys::spread21`] for a cell `v < 2^21`: its low 11 bits and its high 10 bits, spread by the table.
#[inline(always)]
fn spread21(v: u32) -> u64 {
    u64::from(SPREAD[(v & 0x7ff) as usize]) | (u64::from(SPREAD[((v >> 11) & 0x7ff) as usize]) << 33)
}

/// How [`fast`] stores the codes between its passes: `u32` for 30-bit codes that are not returned, `u64` otherwise.
trait Code: Copy + Default + Send + Sync {
    /// From a 30-bit code.
    fn from_code30(m: u32) -> Self;
    /// The code.
    fn code(self) -> u64;
}

impl Code for u32 {
    #[inline(always)]
    fn from_code30(m: u32) -> u32 {
        m
    }
    #[inline(always)]
    fn code(self) -> u64 {
        u64::from(self)
    }
}

impl Code for u64 {
    #[inline(always)]
    fn from_code30(m: u32) -> u64 {
        u64::from(m)
    }
    #[inline(always)]
    fn code(self) -> u64 {
        self
    }
}

/// The extremes and exact power sums of one task's codes, in fixed width: `S1 = s1`, `S2 = s2`,
/// `S3 = s3_lo + 2^64 s3_hi`.
#[derive(Clone, Copy)]
struct TaskSums {
    min: u64,
    max: u64,
    s1: u128,
    s2: U256,
    s3_lo: U256,
    s3_hi: U256,
}

/// The range and the power sums of a task's 30-bit codes, added one code at a time.
///
/// Exact for up to 2^32 codes: `m < 2^30`, so `m^2 < 2^60`, `m^3 < 2^90`, and with `L <= 2^32` codes `S1 < 2^62`
/// fits `u64`, `S2 < 2^92` and `S3 < 2^122` fit `u128`. One 64 x 64 -> 128-bit product per code.
#[derive(Default)]
struct Sums30 {
    min: u32,
    max: u32,
    s1: u64,
    s2: u128,
    s3: u128,
}

impl Sums30 {
    fn new() -> Sums30 {
        Sums30 { min: u32::MAX, ..Sums30::default() }
    }

    /// Adds code `m`.
    #[inline(always)]
    fn add(&mut self, m: u32) {
        (self.min, self.max) = (self.min.min(m), self.max.max(m));
        let m = u64::from(m);
        let m2 = m * m;
        self.s1 += m;
        self.s2 += u128::from(m2);
        self.s3 += u128::from(m2) * u128::from(m);
    }

    fn finish(self) -> TaskSums {
        let z = U256::default();
        TaskSums {
            min: self.min.into(),
            max: self.max.into(),
            s1: self.s1.into(),
            s2: U256 { lo: self.s2, hi: 0 },
            s3_lo: U256 { lo: self.s3, hi: 0 },
            s3_hi: z,
        }
    }
}

/// The range and the power sums of a task's 63-bit codes, added one code at a time.
///
/// Exact for up to 2^32 codes: `S1 < 2^95` fits `u128`; `m^2 < 2^126` is added to a `u128` whose carries are counted
/// (at most one per code), so `S2 = s2 + 2^128 c2`; `m^3 = p0 + 2^64 p1` with `p0 = lo64(m^2) m < 2^127` and
/// `p1 = hi64(m^2) m < 2^125`, each summed the same way. Three 64 x 64 -> 128-bit products per code.
#[derive(Default)]
struct Sums63 {
    min: u64,
    max: u64,
    s1: u128,
    s2: u128,
    c2: u128,
    a: u128,
    ca: u128,
    b: u128,
    cb: u128,
}

impl Sums63 {
    fn new() -> Sums63 {
        Sums63 { min: u64::MAX, ..Sums63::default() }
    }

    /// Adds code `m`.
    #[inline(always)]
    fn add(&mut self, m: u64) {
        let s = self;
        (s.min, s.max) = (s.min.min(m), s.max.max(m));
        let m = u128::from(m);
        let m2 = m * m;
        s.s1 += m;
        let (v, c) = s.s2.overflowing_add(m2);
        (s.s2, s.c2) = (v, s.c2 + u128::from(c));
        let p0 = (m2 as u64 as u128) * m;
        let p1 = (m2 >> 64) * m;
        let (v, c) = s.a.overflowing_add(p0);
        (s.a, s.ca) = (v, s.ca + u128::from(c));
        let (v, c) = s.b.overflowing_add(p1);
        (s.b, s.cb) = (v, s.cb + u128::from(c));
    }

    fn finish(self) -> TaskSums {
        TaskSums {
            min: self.min,
            max: self.max,
            s1: self.s1,
            s2: U256 { lo: self.s2, hi: self.c2 },
            s3_lo: U256 { lo: self.a, hi: self.ca },
            s3_hi: U256 { lo: self.b, hi: self.cb },
        }
    }
}

/// Pass 2 of [`fast`] for one task, 30-bit codes: steps 3 to 5b for the task's keys `k`, block by block (cells in a
/// vectorized loop, then the codes by table into `out` and into the sums).
#[inline(never)]
fn task_codes30<C: Code>(k: TaskKeys<'_>, cells: &Cells, out: &mut [C]) -> TaskSums {
    let (mut b, mut buf) = (Block::new(), KeyBuf::new());
    let mut s = Sums30::new();
    for (j, out) in out.chunks_mut(BLOCK).enumerate() {
        let len = out.len();
        cells.cells(k.block(j, len, &mut buf), &mut b);
        for (o, ((&x, &y), &z)) in out[..len].iter_mut().zip(b.cx[..len].iter().zip(&b.cy[..len]).zip(&b.cz[..len])) {
            let m = (spread10(x) << 2) | (spread10(y) << 1) | spread10(z);
            *o = C::from_code30(m);
            s.add(m);
        }
    }
    s.finish()
}

/// [`task_codes30`] for 63-bit codes.
#[inline(never)]
fn task_codes63(k: TaskKeys<'_>, cells: &Cells, out: &mut [u64]) -> TaskSums {
    let (mut b, mut buf) = (Block::new(), KeyBuf::new());
    let mut s = Sums63::new();
    for (j, out) in out.chunks_mut(BLOCK).enumerate() {
        let len = out.len();
        cells.cells(k.block(j, len, &mut buf), &mut b);
        for (o, ((&x, &y), &z)) in out[..len].iter_mut().zip(b.cx[..len].iter().zip(&b.cy[..len]).zip(&b.cz[..len])) {
            let m = (spread21(x) << 2) | (spread21(y) << 1) | spread21(z);
            *o = m;
            s.add(m);
        }
    }
    s.finish()
}

/// Folds the tasks' fixed-width sums into the exact statistics, once per task.
fn fold_sums(n: usize, sums: Vec<TaskSums>) -> CodeStats {
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
        stats.s3 += s.s3_lo.to_big() + (s.s3_hi.to_big() << 64u32);
    }
    stats
}

/// The triangles of the task whose codes go to `codes[t * TASK ..]`: from the task's first sampled triangle to the
/// next task's (exclusive; for the last task, to the end).
fn task_tris(mesh: &Mesh, stride: usize, t: usize, len: usize) -> &[[u32; 3]] {
    let j0 = t * TASK;
    let end = ((j0 + len) * stride).min(mesh.indices.len());
    &mesh.indices[j0 * stride..end]
}

/// Where pass 2 finds the sample's keys: kept by pass 1, or in the mesh (sampled every `stride`-th triangle).
#[derive(Clone, Copy)]
enum SampleSource<'a> {
    Stored(&'a SampleKeys),
    Gather(&'a Mesh, usize),
}

impl SampleSource<'_> {
    /// The keys of task `t` (`len` of them): `TASK` from `t * TASK` on.
    fn task(&self, t: usize, len: usize) -> TaskKeys<'_> {
        match *self {
            SampleSource::Stored(k) => {
                let r = t * TASK..t * TASK + len;
                TaskKeys::Stored(&k.x[r.clone()], &k.y[r.clone()], &k.z[r])
            }
            SampleSource::Gather(mesh, stride) => {
                TaskKeys::Gather { tris: task_tris(mesh, stride, t, len), stride, p: &mesh.positions }
            }
        }
    }
}

/// Pass 2 of [`fast`], 30-bit codes: every code into `codes` (one per sampled triangle) and the exact statistics.
fn sample_codes30<C: Code>(keys: SampleSource<'_>, q: &Quantizer, codes: &mut [C]) -> CodeStats {
    let cells = Cells::of(q);
    let sums = codes
        .par_chunks_mut(TASK)
        .enumerate()
        .map(|(t, out)| task_codes30(keys.task(t, out.len()), &cells, out))
        .collect();
    fold_sums(codes.len(), sums)
}

/// [`sample_codes30`] for 63-bit codes.
fn sample_codes63(keys: SampleSource<'_>, q: &Quantizer, codes: &mut [u64]) -> CodeStats {
    let cells = Cells::of(q);
    let sums = codes
        .par_chunks_mut(TASK)
        .enumerate()
        .map(|(t, out)| task_codes63(keys.task(t, out.len()), &cells, out))
        .collect();
    fold_sums(codes.len(), sums)
}

/// Step 7 for many codes: the class of `x = m - m_min` from an `f32` estimate of `x k / D`, corrected by the exact
/// thresholds of [`class_thresholds`], without a division.
///
/// With `u = 2^-24`, the estimate `P = rn(rn(x) rn(k / rn(D)))` has a relative error below
/// `(1 + u)^3 / (1 - u) - 1 < 4.0001 u` (four roundings; every value is normal or 0), so it is within
/// `4096 * 4.0001 * 2^-24 < 0.001` of `Q = x k / D <= k`. Then `min(P, k - 1)` is within 0.001 of `min(Q, k - 1)`,
/// whose integer part is the class `c = min(floor(Q), k - 1)`, so the nearest integer `E` of `min(P, k - 1)` is `c`
/// or `c + 1`. With `e[0] = 0` and `e[j] = t_j` (`j = 1 .. k - 1`), the class is at least `j` exactly when
/// `x >= e[j]`; so the class is `E - 1` if `x < e[E]` and `E` otherwise. (Where thresholds repeat, the classes
/// between them are empty, and the rule still gives the class of step 7.)
struct Classifier {
    code_min: u64,
    /// `rn(k / rn(D))`.
    r: f32,
    /// `k - 1`.
    top: f32,
    /// `e[0 .. k]`.
    e: Vec<u64>,
}

impl Classifier {
    /// For `k >= 2` and `D = code_max - code_min > 0`.
    fn new(code_min: u64, code_max: u64, k: u32) -> Classifier {
        let d = code_max - code_min;
        let mut e = Vec::with_capacity(k as usize);
        e.push(0);
        e.extend(class_thresholds(code_min, code_max, k));
        Classifier { code_min, r: k as f32 / d as f32, top: (k - 1) as f32, e }
    }

    /// The nearest integer `E` of `min(rn(x) r, k - 1)`, by the magic-number rounding of [`Cells::cell`]
    /// (`min(P, k - 1)` lies in `[0, 2^23)`).
    #[inline(always)]
    fn estimate(&self, x: f32) -> u32 {
        const MAGIC: f32 = 8_388_608.0; // 2^23
        let p = x * self.r;
        let p = if p < self.top { p } else { self.top };
        (p + MAGIC).to_bits() & 0x007f_ffff
    }

    /// The class of `x = m - m_min` from its estimate `E` (`e` is `self.e`, here so that the caller can keep it in
    /// a register).
    #[inline(always)]
    fn class(e: &[u64], x: u64, estimate: u32) -> u32 {
        estimate - u32::from(x < e[estimate as usize])
    }
}

/// How [`fast`] stores the codes, part 2: the offset of a code from the smallest one, exactly and as the nearest
/// `f32`.
trait Offset: Code {
    /// `m - m_min` rounded to the nearest `f32` (`m >= m_min`).
    fn offset_f32(self, code_min: u64) -> f32;
}

impl Offset for u32 {
    /// Codes below 2^30: the offset converts through `i32` (vectorized).
    #[inline(always)]
    fn offset_f32(self, code_min: u64) -> f32 {
        (self - code_min as u32) as i32 as f32
    }
}

impl Offset for u64 {
    /// Codes below 2^63: the offset converts through `i64`.
    #[inline(always)]
    fn offset_f32(self, code_min: u64) -> f32 {
        (self - code_min) as i64 as f32
    }
}

/// Steps 7 and 8 over `codes`: the histogram of `k` classes, and the class of every code into `classes` when it is
/// not empty (then as long as `codes`).
fn sample_histogram<C: Offset>(codes: &[C], stats: &CodeStats, k: u32, classes: &mut [u32]) -> Vec<u64> {
    let n = codes.len() as u64;
    if k <= 1 || stats.code_max <= stats.code_min {
        // One class (step 7: every code in class 0).
        let mut h = vec![0u64; k as usize];
        h[0] = n;
        return h;
    }
    let cl = Classifier::new(stats.code_min, stats.code_max, k);
    let kk = k as usize;
    let task_hist = |cs: &[C], out: &mut [u32]| -> Vec<u64> {
        let (e, code_min) = (&cl.e[..], cl.code_min);
        // Four interleaved histograms, so that neighbouring codes of one class do not wait on each other's counts.
        let mut h = vec![0u32; 4 * kk];
        let (h01, h23) = h.split_at_mut(2 * kk);
        let ((h0, h1), (h2, h3)) = (h01.split_at_mut(kk), h23.split_at_mut(kk));
        let mut est = [0u32; BLOCK];
        for (i, cs) in cs.chunks(BLOCK).enumerate() {
            let est = &mut est[..cs.len()];
            for (e, &m) in est.iter_mut().zip(cs) {
                *e = cl.estimate(m.offset_f32(code_min));
            }
            if out.is_empty() {
                let mut quads = cs.chunks_exact(4).zip(est.chunks_exact(4));
                for (m, est) in &mut quads {
                    h0[Classifier::class(e, m[0].code() - code_min, est[0]) as usize] += 1;
                    h1[Classifier::class(e, m[1].code() - code_min, est[1]) as usize] += 1;
                    h2[Classifier::class(e, m[2].code() - code_min, est[2]) as usize] += 1;
                    h3[Classifier::class(e, m[3].code() - code_min, est[3]) as usize] += 1;
                }
                let done = cs.len() / 4 * 4;
                for (&m, &est) in cs[done..].iter().zip(&est[done..]) {
                    h0[Classifier::class(e, m.code() - code_min, est) as usize] += 1;
                }
            } else {
                let out = &mut out[i * BLOCK..i * BLOCK + cs.len()];
                for ((o, &m), &est) in out.iter_mut().zip(cs).zip(est.iter()) {
                    let c = Classifier::class(e, m.code() - code_min, est);
                    *o = c;
                    h0[c as usize] += 1;
                }
            }
        }
        (0..kk).map(|c| u64::from(h0[c]) + u64::from(h1[c]) + u64::from(h2[c]) + u64::from(h3[c])).collect()
    };
    if classes.is_empty() {
        codes.par_chunks(TASK).map(|cs| task_hist(cs, &mut [])).reduce(|| vec![0u64; kk], merge_hist)
    } else {
        codes
            .par_chunks(TASK)
            .zip(classes.par_chunks_mut(TASK))
            .map(|(cs, out)| task_hist(cs, out))
            .reduce(|| vec![0u64; kk], merge_hist)
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
