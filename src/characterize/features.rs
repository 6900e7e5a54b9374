//! Scene features for the cost model ([`crate::cost`]): cheap (O(n)) integer summaries of a mesh, defined so that a
//! GPU pass can reproduce them bit for bit.
//!
//! Every quantity is an exact integer computed from IEEE f32 operations that a GPU kernel performs identically
//! (subtraction, min/max, bit extraction; no division, no logarithm, no fused multiply-add):
//!
//! - **Counts**: triangles (sampled, as in the characterization) and the mesh's total.
//! - **Occupancy of Morton cells**: for depth `d = 1 ..= OCCUPANCY_DEPTHS`, the number of distinct prefixes of
//!   `3 d` bits among the docs/spec.md Morton codes (steps 1 to 4, the codes the characterization already computes).
//!   Depth `d` splits the key bounds into `2^d` cells per axis; the count says how much of space is occupied at that
//!   scale (`8^d` cells in all, at most `n` occupied). A GPU pass sets one bit per code in a `2^21`-bit mask of the
//!   depth-7 prefixes (atomic OR) and counts set bits of the mask and of its 8-way ORs.
//! - **Triangle sizes**: for every triangle, its largest box extent `t = max_a (max_v p_a - min_v p_a)` (f32), and
//!   the histogram of `k = e(S) - e(t)`, where `e(x)` is the unbiased f32 exponent read from the bits (`floor(log2
//!   x)` for normal numbers) and `S` the largest extent of the vertex bounds of the sampled triangles. Bin `k` for
//!   `0 <= k < SIZE_BINS - 1`; the last bin collects `k >= SIZE_BINS - 1` (tiny triangles); zero-extent triangles
//!   (all three vertices equal) and subnormal extents are counted apart in `zero_extent`. So a triangle in bin `k`
//!   spans between `2^-(k+1)` and `2^-(k-1)` of the scene.
//! - **Aspect**: the exponents `e(extent_a)` of the three vertex-bound extents (`i32::MIN` for a zero extent); the
//!   aspect is `2^(max - min)` within a factor of 2.
//!
//! Derived real-valued quantities for models ([`Features::derived`]) are computed from these integers on the host.

use super::{CharError, Params};
use crate::keys::{self, Quantizer};
use crate::mesh::Mesh;
use rayon::prelude::*;

/// Deepest Morton-prefix depth counted (`3 * 7 = 21` bits, a `2^21`-bit mask).
pub const OCCUPANCY_DEPTHS: usize = 7;
/// Triangles per task of the CPU pass.
const CHUNK: usize = 16 * 1024;
/// Bins of the triangle size histogram (the last one is open-ended).
pub const SIZE_BINS: usize = 24;

/// Integer features of one mesh (one frame). See the module docs for the definitions.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Features {
    /// Triangles characterized (after sampling).
    pub triangles: u64,
    /// Triangles of the mesh.
    pub total_triangles: u64,
    /// Bits of the Morton codes (30 or 63).
    pub morton_bits: u32,
    /// `occupied_cells[d - 1]`: distinct `3 d`-bit prefixes of the codes, `d = 1 ..= OCCUPANCY_DEPTHS`.
    pub occupied_cells: Vec<u64>,
    /// Triangle size histogram over `k = e(S) - e(t)` (see the module docs), `SIZE_BINS` bins.
    pub size_histogram: Vec<u64>,
    /// Triangles whose largest extent is zero or subnormal.
    pub zero_extent: u64,
    /// Unbiased f32 exponents of the vertex-bound extents per axis (`i32::MIN` where the extent is zero or
    /// subnormal).
    pub extent_exponents: [i32; 3],
    /// Lower corner of the vertex bounds of the sampled triangles.
    pub lo: [f32; 3],
    /// Upper corner of the vertex bounds.
    pub hi: [f32; 3],
}

/// Unbiased exponent of a positive normal f32 (`floor(log2 x)`), `None` for zero, subnormals, infinities and NaN.
#[inline]
pub fn exponent(x: f32) -> Option<i32> {
    let e = ((x.to_bits() >> 23) & 0xff) as i32;
    if e == 0 || e == 0xff {
        None
    } else {
        Some(e - 127)
    }
}

/// Real-valued quantities derived from [`Features`] for the cost model (host side; see [`Features::derived`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Derived {
    /// `ln n`, `n` the mesh's triangle count (not the sample's; n >= 1).
    pub ln_n: f64,
    /// Share of occupied cells at the depth where `8^d` is closest to `n` (interpolated in `d`), of `min(8^d, n)`:
    /// 1 when the triangles fill space at the scale of one cell per triangle, small when space is mostly empty.
    pub fill_at_n: f64,
    /// `ln` of the triangles per occupied cell at the depth of a uniform grid with 4 cells per triangle
    /// (`8^d = 4 n`, clamped to the deepest counted depth; interpolated in `d`).
    pub ln_tris_per_cell: f64,
    /// Share of empty cells at depth 3 (512 cells), of the cells that `n` triangles could occupy.
    pub empty_d3: f64,
    /// Mean of the size exponent difference `k` (triangles are about `2^-k` of the scene).
    pub size_mean: f64,
    /// Standard deviation of `k`.
    pub size_spread: f64,
    /// `log2` of the aspect (max minus min extent exponent), capped at 24 (flat scenes).
    pub aspect_log2: f64,
}

impl Features {
    /// The scene's triangle count, `n` in every law of the cost model and the selection: the larger of the mesh's
    /// ([`Features::total_triangles`]) and the count characterized ([`Features::triangles`]).
    pub(crate) fn scene_triangles(&self) -> u64 {
        self.total_triangles.max(self.triangles)
    }

    /// Occupied cells at depth `d` (1-based), 0 outside `1 ..= OCCUPANCY_DEPTHS`.
    pub fn occupied(&self, d: usize) -> u64 {
        if d == 0 {
            return 1.min(self.triangles);
        }
        self.occupied_cells.get(d - 1).copied().unwrap_or(0)
    }

    fn occ_interp(&self, d: f64) -> f64 {
        let d = d.clamp(0.0, OCCUPANCY_DEPTHS as f64);
        let d0 = d.floor() as usize;
        let d1 = (d0 + 1).min(OCCUPANCY_DEPTHS);
        let t = d - d0 as f64;
        let a = (self.occupied(d0).max(1) as f64).ln();
        let b = (self.occupied(d1).max(1) as f64).ln();
        (a + t * (b - a)).exp()
    }

    /// The derived quantities of [`Derived`].
    pub fn derived(&self) -> Derived {
        let n = self.triangles.max(1) as f64;
        let d_n = n.ln() / 8f64.ln();
        let fill_at_n = (self.occ_interp(d_n) / n.min(8f64.powf(d_n.min(OCCUPANCY_DEPTHS as f64)))).clamp(0.0, 1.0);
        let d_grid = (4.0 * n).ln() / 8f64.ln();
        let ln_tris_per_cell = (n / self.occ_interp(d_grid).max(1.0)).ln();
        let cap3 = n.min(512.0);
        let empty_d3 = (1.0 - self.occupied(3) as f64 / cap3).clamp(0.0, 1.0);
        let total: u64 = self.size_histogram.iter().sum();
        let (mut m, mut m2) = (0.0, 0.0);
        if total > 0 {
            for (k, &c) in self.size_histogram.iter().enumerate() {
                m += k as f64 * c as f64;
                m2 += (k * k) as f64 * c as f64;
            }
            m /= total as f64;
            m2 /= total as f64;
        }
        let size_spread = (m2 - m * m).max(0.0).sqrt();
        let exps: Vec<i32> = self.extent_exponents.iter().copied().filter(|&e| e != i32::MIN).collect();
        let aspect_log2 = if exps.len() < 3 {
            24.0
        } else {
            let mx = exps.iter().max().copied().unwrap_or(0);
            let mn = exps.iter().min().copied().unwrap_or(0);
            ((mx - mn) as f64).min(24.0)
        };
        // The scene's size is the mesh's (a sample is a smaller set of the same scene); the occupancy ratios above
        // compare the sample with itself.
        let n_scene = self.scene_triangles().max(1) as f64;
        Derived { ln_n: n_scene.ln(), fill_at_n, ln_tris_per_cell, empty_d3, size_mean: m, size_spread, aspect_log2 }
    }
}

/// How much features change between two frames (for animations), from [`Features`] only.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FeatureChange {
    /// Largest `|ln occ_d(b) - ln occ_d(a)|` over the depths.
    pub occupancy: f64,
    /// Largest relative change of a vertex-bound extent, `|e_b - e_a| / max(e_a, e_b)`.
    pub bounds: f64,
    /// Change of the mean size exponent.
    pub size: f64,
}

impl FeatureChange {
    /// Change from `a` to `b`.
    pub fn between(a: &Features, b: &Features) -> FeatureChange {
        let mut occ: f64 = 0.0;
        for d in 1..=OCCUPANCY_DEPTHS {
            let x = (a.occupied(d).max(1) as f64).ln();
            let y = (b.occupied(d).max(1) as f64).ln();
            occ = occ.max((x - y).abs());
        }
        let mut bounds: f64 = 0.0;
        for ax in 0..3 {
            let ea = (a.hi[ax] - a.lo[ax]) as f64;
            let eb = (b.hi[ax] - b.lo[ax]) as f64;
            let m = ea.max(eb);
            if m > 0.0 {
                bounds = bounds.max((ea - eb).abs() / m);
            }
        }
        FeatureChange { occupancy: occ, bounds, size: (a.derived().size_mean - b.derived().size_mean).abs() }
    }
}

/// CPU reference of the features of `mesh` for `params` (`morton_bits` and `sample_stride` apply as in the
/// characterization). Exact integer arithmetic in parallel chunks (every merge is an OR, a sum, or a min or max in the
/// IEEE total order, so the result does not depend on the split); O(n) time plus a `2^21`-bit mask per chunk.
///
/// # Errors
///
/// [`CharError`] for invalid parameters, an empty sample, or bounds that cannot be quantized (as the
/// characterization).
pub fn features_cpu(mesh: &Mesh, params: &Params) -> Result<Features, CharError> {
    features_with(mesh, params, None)
}

/// [`features_cpu`] with the codes of `quantizer` where one is given (a planned run's feature pass counts the cells
/// of the plan's codes), else of the sample's own quantizer.
pub(crate) fn features_with(mesh: &Mesh, params: &Params, quantizer: Option<Quantizer>) -> Result<Features, CharError> {
    features_from(mesh, params, quantizer, None)
}

/// The Morton codes of a mesh's sample, in sample order, as a characterization computed them.
#[derive(Clone, Copy, Debug)]
pub(crate) enum SampleCodes<'a> {
    /// 30-bit codes.
    Bits30(&'a [u32]),
    /// Codes of any width, in `u64`.
    Wide(&'a [u64]),
}

/// [`features_cpu`] from the sample's codes computed already by a characterization of `mesh` with `params` that
/// succeeded (so the mesh is valid, and is not checked again): no key pass, and the triangles are read once. The
/// same features. Codes of another length than the sample's are ignored (the codes are then computed).
pub(crate) fn features_of_codes(mesh: &Mesh, params: &Params, codes: SampleCodes<'_>) -> Result<Features, CharError> {
    features_from(mesh, params, None, Some(codes))
}

/// Where the feature pass takes the sample's codes from.
enum CodeSource<'a> {
    /// A characterization's.
    Given(SampleCodes<'a>),
    /// Computed from the keys by this quantizer.
    Quantized(Quantizer),
}

/// Biased f32 exponent fields: the triangles' extents are counted by this field in one pass, and binned once the
/// scene's exponent is known.
const EXPONENT_FIELDS: usize = 256;

/// What one pass over a run of the sample gathers: the vertex bounds as [`keys::ordered_bits`] (whose unsigned
/// minimum and maximum are those of the IEEE total order), the extents' exponent fields, the occupied depth-7
/// cells.
struct Partial {
    lo: [u32; 3],
    hi: [u32; 3],
    fields: Vec<u64>,
    mask: Vec<u64>,
}

impl Partial {
    fn new(words: usize) -> Self {
        Partial { lo: [u32::MAX; 3], hi: [0; 3], fields: vec![0; EXPONENT_FIELDS], mask: vec![0; words] }
    }

    fn merge(mut self, o: Partial) -> Partial {
        for a in 0..3 {
            self.lo[a] = self.lo[a].min(o.lo[a]);
            self.hi[a] = self.hi[a].max(o.hi[a]);
        }
        self.fields.iter_mut().zip(&o.fields).for_each(|(x, y)| *x += y);
        self.mask.iter_mut().zip(&o.mask).for_each(|(x, y)| *x |= y);
        self
    }
}

/// Triangles per block of the feature pass: their vertices are gathered by axis into arrays of this length.
const BLOCK: usize = 256;

/// [`keys::ordered_bits`] without a branch.
#[inline]
fn ordered(x: f32) -> u32 {
    let b = x.to_bits();
    b ^ (((b as i32) >> 31) as u32 | 0x8000_0000)
}

/// The largest of the three extents `hi - lo` (f32), `0` when all are zero.
fn largest_extent(lo: &[f32; 3], hi: &[f32; 3]) -> f32 {
    let mut m = 0.0f32;
    for a in 0..3 {
        m = m.max(hi[a] - lo[a]);
    }
    m
}

fn features_from(
    mesh: &Mesh,
    params: &Params,
    quantizer: Option<Quantizer>,
    codes: Option<SampleCodes<'_>>,
) -> Result<Features, CharError> {
    params.validate()?;
    let stride = params.sample_stride.max(1) as usize;
    let total = mesh.triangle_count();
    let n = total.div_ceil(stride);
    let bits = params.morton_bits;
    let codes = codes.filter(|c| match c {
        SampleCodes::Bits30(c) => c.len() == n && bits == keys::MortonBits::Bits30,
        SampleCodes::Wide(c) => c.len() == n,
    });
    // Codes come from a characterization of this mesh, which validated it.
    if codes.is_none() {
        mesh.validate()?;
    }
    if n == 0 {
        return Err(CharError::Empty { mesh: mesh.name.clone() });
    }
    let p = &mesh.positions;
    let tri = |j: usize| {
        let [a, b, c] = mesh.indices[j * stride];
        [p[a as usize], p[b as usize], p[c as usize]]
    };
    // Key bounds and scale (docs/spec.md steps 1-3), as the characterization, unless its codes are at hand.
    let source = match (quantizer, codes) {
        (Some(q), _) => CodeSource::Quantized(q),
        (None, Some(c)) => CodeSource::Given(c),
        (None, None) => CodeSource::Quantized(
            Quantizer::of_keys(
                n,
                |j| {
                    let [v0, v1, v2] = tri(j);
                    keys::centroid_key(v0, v1, v2)
                },
                bits,
            )
            .map_err(|e| CharError::of_keys(&mesh.name, stride, e))?,
        ),
    };
    let shift = bits.total() - 3 * OCCUPANCY_DEPTHS as u32;
    // One pass: the vertex bounds, the extents' exponent fields and the occupied cells, per run of the sample. Every
    // merge is a minimum, a maximum, a sum or an OR of integers, so the split does not change the result.
    let words = (1usize << (3 * OCCUPANCY_DEPTHS)) / 64;
    let run = CHUNK.max(n.div_ceil(rayon::current_num_threads().max(1)));
    let gather = |r: usize| {
        let mut out = Partial::new(words);
        // Blocks of triangles gathered by axis (`v[3 k + a]`: vertex `k`, axis `a`), so that the loops over a block
        // vectorize.
        let mut v = Box::new([[0f32; BLOCK]; 9]);
        let mut extent = [0f32; BLOCK];
        let (first, end) = (r * run, ((r + 1) * run).min(n));
        for j0 in (first..end).step_by(BLOCK) {
            let len = BLOCK.min(end - j0);
            for k in 0..len {
                let t = tri(j0 + k);
                for (c, vertex) in t.iter().enumerate() {
                    for a in 0..3 {
                        v[3 * c + a][k] = vertex[a];
                    }
                }
            }
            extent[..len].fill(0.0);
            for a in 0..3 {
                let (x0, x1, x2) = (&v[a][..len], &v[3 + a][..len], &v[6 + a][..len]);
                let (mut lo, mut hi) = (out.lo[a], out.hi[a]);
                for k in 0..len {
                    let (o0, o1, o2) = (ordered(x0[k]), ordered(x1[k]), ordered(x2[k]));
                    lo = lo.min(o0.min(o1).min(o2));
                    hi = hi.max(o0.max(o1).max(o2));
                    // The triangle's box extent along `a`, as `largest_extent` computes it.
                    let e = x0[k].max(x1[k]).max(x2[k]) - x0[k].min(x1[k]).min(x2[k]);
                    extent[k] = extent[k].max(e);
                }
                (out.lo[a], out.hi[a]) = (lo, hi);
            }
            for &e in &extent[..len] {
                out.fields[((e.to_bits() >> 23) & 0xff) as usize] += 1;
            }
            for k in 0..len {
                let j = j0 + k;
                let code = match &source {
                    CodeSource::Given(SampleCodes::Bits30(c)) => u64::from(c[j]),
                    CodeSource::Given(SampleCodes::Wide(c)) => c[j],
                    CodeSource::Quantized(q) => {
                        let at = |c: usize| [v[3 * c][k], v[3 * c + 1][k], v[3 * c + 2][k]];
                        q.code(keys::centroid_key(at(0), at(1), at(2)))
                    }
                };
                let prefix = (code >> shift) as usize;
                out.mask[prefix / 64] |= 1u64 << (prefix % 64);
            }
        }
        out
    };
    let part = crate::in_pool(|| {
        (0..n.div_ceil(run))
            .into_par_iter()
            .map(gather)
            .reduce_with(Partial::merge)
            .unwrap_or_else(|| Partial::new(words))
    });
    let vlo = part.lo.map(keys::from_ordered_bits);
    let vhi = part.hi.map(keys::from_ordered_bits);
    // The size histogram: bin `e(S) - e(t)` of every normal extent `t`; zero and subnormal extents (fields 0 and
    // 255, which the vertices' finiteness leaves to zero and subnormal ones), and every extent of a scene whose own
    // extent is not normal, apart.
    let mut size_histogram = vec![0u64; SIZE_BINS];
    let mut zero_extent = 0u64;
    let scene_exp = exponent(largest_extent(&vlo, &vhi));
    for (field, &count) in part.fields.iter().enumerate() {
        match (field, scene_exp) {
            (1..=254, Some(s)) => {
                let t = field as i32 - 127;
                size_histogram[((s - t).max(0) as usize).min(SIZE_BINS - 1)] += count;
            }
            _ => zero_extent += count,
        }
    }
    Ok(Features {
        triangles: n as u64,
        total_triangles: total as u64,
        morton_bits: bits.total(),
        occupied_cells: occupancy_from_mask(&part.mask),
        size_histogram,
        zero_extent,
        extent_exponents: extent_exponents(&vlo, &vhi),
        lo: vlo,
        hi: vhi,
    })
}

/// Occupied cells per depth `1 ..= OCCUPANCY_DEPTHS` from the mask of occupied deepest cells (`2^(3
/// OCCUPANCY_DEPTHS)` bits as u64 words, bit `b` of word `w` being cell `64 w + b`): the set bits, then 8-way ORs
/// down to depth 1. Shared by the CPU reference and the GPU pass, which produce the same mask.
pub(crate) fn occupancy_from_mask(mask: &[u64]) -> Vec<u64> {
    let mut occupied_cells = vec![0u64; OCCUPANCY_DEPTHS];
    // `level` holds `8^d` bits, 64 to a word (the last word partly used below depth 2).
    let mut level: Vec<u64> = mask.to_vec();
    for d in (1..=OCCUPANCY_DEPTHS).rev() {
        occupied_cells[d - 1] = level.iter().map(|w| u64::from(w.count_ones())).sum();
        // One bit per group of 8: bit `b` of the next level is set when byte `b` of this one is not zero.
        let mut next = vec![0u64; level.len().div_ceil(8)];
        for (k, w) in level.iter().enumerate() {
            let mut bits = 0u64;
            for byte in 0..8 {
                bits |= u64::from((w >> (8 * byte)) & 0xff != 0) << byte;
            }
            next[k / 8] |= bits << (8 * (k % 8));
        }
        level = next;
    }
    occupied_cells
}

/// Unbiased exponents of the extents `hi - lo` per axis, `i32::MIN` where zero or not normal.
pub(crate) fn extent_exponents(lo: &[f32; 3], hi: &[f32; 3]) -> [i32; 3] {
    std::array::from_fn(|a| exponent(hi[a] - lo[a]).unwrap_or(i32::MIN))
}

/// The features from the GPU pass's integers (`crate::characterize::gpu::features::FeaturesGpu`) for `triangles` sampled
/// triangles of a `total_triangles`-triangle mesh with `bits` codes.
pub(crate) fn features_from_gpu(
    g: &super::gpu::features::GpuFeatures,
    triangles: u64,
    total_triangles: u64,
    bits: keys::MortonBits,
) -> Features {
    Features {
        triangles,
        total_triangles,
        morton_bits: bits.total(),
        occupied_cells: occupancy_from_mask(&g.mask),
        size_histogram: g.size_histogram.clone(),
        zero_extent: g.zero_extent,
        extent_exponents: extent_exponents(&g.lo, &g.hi),
        lo: g.lo,
        hi: g.hi,
    }
}
