//! Pass 1 of [`super::fast`]: the sample's centroid keys gathered in blocks, the mesh validated on the way, and the
//! keys' bounds in the total order of the float bits, from which the quantizer follows.

use super::*;

/// Sampled triangles per rayon task of [`fast`]. A task's index triples (12 bytes each) and codes stay in the
/// core's cache while it runs, and the dragon makes 54 tasks, enough to balance two to eight threads.
pub(super) const TASK: usize = 1 << 14;

/// Triangles per block inside a task: their keys are gathered into three arrays of this length (3 KiB, in L1), which
/// the vectorized loops then read.
pub(super) const BLOCK: usize = 256;

// The fixed-width sums of a task are exact for tasks of up to 2^32 codes (see `Sums30`, `Sums63`), and a task's
// histogram counts are `u32`.
const _: () = assert!(TASK <= 1 << 32 && TASK % BLOCK == 0);

/// The cells of one block of keys inside a task, by axis.
pub(super) struct Block {
    pub(super) cx: [u32; BLOCK],
    pub(super) cy: [u32; BLOCK],
    pub(super) cz: [u32; BLOCK],
}

impl Block {
    pub(super) fn new() -> Box<Block> {
        Box::new(Block { cx: [0; BLOCK], cy: [0; BLOCK], cz: [0; BLOCK] })
    }
}

/// The centroid keys of the sample, by axis (`x[j]` of sampled triangle `j`): pass 1 of [`fast_with`] writes them
/// as it bounds them, and pass 2 reads them in order instead of gathering the vertices again.
#[derive(Default)]
pub(super) struct SampleKeys {
    pub(super) x: Vec<f32>,
    pub(super) y: Vec<f32>,
    pub(super) z: Vec<f32>,
}

/// `v` with `n` elements, its memory reused: no write when it had as many (the caller overwrites them).
pub(super) fn sized<T: Copy + Default>(v: &mut Vec<T>, n: usize) -> &mut [T] {
    if v.len() < n {
        v.resize(n, T::default());
    }
    &mut v[..n]
}

/// One block of keys gathered from the vertices (where the sample's keys are not kept).
pub(super) struct KeyBuf {
    pub(super) x: [f32; BLOCK],
    pub(super) y: [f32; BLOCK],
    pub(super) z: [f32; BLOCK],
}

impl KeyBuf {
    pub(super) fn new() -> Box<KeyBuf> {
        Box::new(KeyBuf { x: [0.0; BLOCK], y: [0.0; BLOCK], z: [0.0; BLOCK] })
    }
    pub(super) fn slices(&mut self) -> (&mut [f32], &mut [f32], &mut [f32]) {
        (&mut self.x, &mut self.y, &mut self.z)
    }
}

/// Where pass 2 of [`fast_with`] finds a task's keys: stored by pass 1, or gathered again from the vertices of the
/// task's triangles.
#[derive(Clone, Copy)]
pub(super) enum TaskKeys<'a> {
    Stored(&'a [f32], &'a [f32], &'a [f32]),
    Gather { tris: &'a [[u32; 3]], stride: usize, p: &'a [[f32; 3]] },
}

impl<'a> TaskKeys<'a> {
    /// The keys of the task's block `j` of `len` sampled triangles (gathered into `buf` when not stored).
    #[inline(always)]
    pub(super) fn block<'b>(&self, j: usize, len: usize, buf: &'b mut KeyBuf) -> (&'b [f32], &'b [f32], &'b [f32])
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
pub(super) fn gather<'a>(
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
pub(super) fn gather_sampled(
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
pub(super) fn all_finite(v: &[[f32; 3]]) -> bool {
    v.as_flattened().iter().fold(true, |ok, x| ok & x.is_finite())
}

/// Whether every index is below `nv`, in a loop the compiler vectorizes.
pub(super) fn all_below(tris: &[[u32; 3]], nv: usize) -> bool {
    match u32::try_from(nv) {
        Ok(nv) => tris.as_flattened().iter().fold(true, |ok, &i| ok & (i < nv)),
        Err(_) => true, // more vertices than a u32 index can name
    }
}

/// [`keys::ordered_bits`] without a branch: the sign bit, spread over the word by the arithmetic shift, flips every
/// bit of a negative float, and the top bit is set for a positive one.
#[inline(always)]
pub(super) fn ordered(x: f32) -> u32 {
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
pub(super) fn ordered_range(v: &[f32], lo: &mut u32, hi: &mut u32) {
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
pub(super) struct TaskBounds {
    /// `[lo_x, lo_y, lo_z, hi_x, hi_y, hi_z]` of the task's keys in ordered-bits form.
    pub(super) bounds: [u32; 6],
    /// The task's part of the validation passed: its triangles' indices (all of them, sampled or not) and its share
    /// of the vertices.
    pub(super) valid: bool,
}

/// Pass 1 of [`fast`] for one task: validation of the task's triangles `tris` (those from its first sampled
/// triangle to the next task's, sampled or not) and of the vertices `verts`, and steps 1 and 2 for the sampled
/// triangles, whose keys go to `keys` when given (one per sampled triangle of the task), block by block so that each
/// block's keys are still in L1 when they are bounded. With `stride == 1` the indices are checked as the keys are
/// gathered.
#[inline(never)]
pub(super) fn task_bounds(
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
pub(super) fn sample_quantizer(
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
