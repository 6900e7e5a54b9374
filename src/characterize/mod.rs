//! The characterization of `docs/spec.md`: bounds, Morton codes, moments, Doane's class count, the class histogram,
//! chi-square, concentration and empty classes, and the scene features; on the CPU (naive and rayon) and on the device.
//!
//! # How the backends stay bit-identical
//!
//! Every backend (the naive CPU reference, the rayon CPU fast path, Vulkan) computes only *exact* quantities on the
//! data: f32 keys and bounds (correctly rounded add/sub/mul, reduced in a total order), integer Morton codes, the
//! smallest and largest code, the exact integer power sums `S1 = sum m`, `S2 = sum m^2`, `S3 = sum m^3`
//! ([`CodeStats`]), per-triangle classes, and the integer histogram. Everything that needs a transcendental function
//! or a rounding choice (mean, standard deviation, skewness, `k`, chi-square, p-value) is computed once, on the host,
//! by the functions of this module from those exact values. So the three backends agree on every reported bit, and
//! the moments are within rounding of the exact real values (much closer than the 1e-9 of an f64 two-pass).

pub mod cpu;
pub mod features;
pub(crate) mod finalize;
pub(crate) mod gpu;
pub mod plan;
#[cfg(test)]
mod tests;
pub mod vulkan;

pub use crate::keys::{KeyBounds, KeyError, MortonBits, Quantizer};
pub use features::{features_cpu, Features};
pub(crate) use finalize::{class_thresholds, moments};
// The selection's unit tests read the histogram statistics of hand-made histograms.
#[cfg(test)]
pub(crate) use finalize::histogram_stats;

use crate::mesh::{Animation, Mesh, MeshError};
use num_bigint::BigUint;

/// Everything that can stop a characterization. Nothing is computed on invalid input.
#[derive(Debug, thiserror::Error)]
pub enum CharError {
    /// The mesh is invalid (a NaN or infinite coordinate, an index out of range ...); the error names the mesh and
    /// the vertex or triangle.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// There is nothing to characterize (no triangles, or none in the sample).
    #[error("{mesh}: no triangles to characterize")]
    Empty {
        /// The mesh name.
        mesh: String,
    },
    /// The input cannot be characterized for another reason (reported by a backend).
    #[error("{mesh}: {reason}")]
    Input {
        /// The mesh name.
        mesh: String,
        /// Why.
        reason: String,
    },
    /// A centroid key `(v0 + v1) + v2` overflows f32 (coordinates above about 1e38).
    #[error(
        "{mesh}: triangle {triangle}: centroid key (v0 + v1) + v2 = {key:?} overflows f32 (coordinates too large)"
    )]
    KeyOverflow {
        /// The mesh name.
        mesh: String,
        /// The triangle.
        triangle: usize,
        /// The key as computed.
        key: [f32; 3],
    },
    /// The bounds cannot be quantized in f32: `hi - lo` overflows, or `2^b / (hi - lo)` does (an extent below about
    /// 1e-36).
    #[error("{mesh}: bounds lo {lo:?} hi {hi:?} cannot be quantized in f32: {reason}")]
    Extent {
        /// The mesh name.
        mesh: String,
        /// `lo` of step 2.
        lo: [f32; 3],
        /// `hi` of step 2.
        hi: [f32; 3],
        /// What overflowed.
        reason: String,
    },
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    InvalidParams(String),
    /// The GPU path failed or is not available.
    #[error("Vulkan backend: {0}")]
    Gpu(String),
}

impl CharError {
    /// The characterization's error for a [`KeyError`] over the sample of `mesh` (key `j` is triangle
    /// `j * sample_stride`).
    pub(crate) fn of_keys(mesh: &str, sample_stride: usize, e: KeyError) -> CharError {
        let mesh = mesh.to_string();
        match e {
            KeyError::Empty => CharError::Empty { mesh },
            KeyError::Overflow { index, key } => CharError::KeyOverflow { mesh, triangle: index * sample_stride, key },
            KeyError::Extent { lo, hi, reason } => CharError::Extent { mesh, lo, hi, reason: reason.to_string() },
        }
    }
}

impl Params {
    /// Checks the parameters: `alpha` in `(0, 1)`, `sample_stride >= 1`, a fixed class count `>= 1`.
    pub fn validate(&self) -> Result<(), CharError> {
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            return Err(CharError::InvalidParams(format!("alpha must be in (0, 1), got {}", self.alpha)));
        }
        if self.sample_stride == 0 {
            return Err(CharError::InvalidParams("sample stride must be at least 1".into()));
        }
        if self.class_rule == ClassRule::Fixed(0) {
            return Err(CharError::InvalidParams("a fixed class count must be at least 1".into()));
        }
        Ok(())
    }
}

impl ClassRule {
    /// The rule's name in reports: `doane`, `sturges`, `sqrt` or the fixed count.
    pub fn name(&self) -> String {
        match self {
            ClassRule::Doane => "doane".into(),
            ClassRule::Sturges => "sturges".into(),
            ClassRule::Sqrt => "sqrt".into(),
            ClassRule::Fixed(k) => k.to_string(),
        }
    }
}

impl std::str::FromStr for ClassRule {
    type Err = CharError;
    /// Parses `doane`, `sturges`, `sqrt` or a positive count.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "doane" => Ok(ClassRule::Doane),
            "sturges" => Ok(ClassRule::Sturges),
            "sqrt" => Ok(ClassRule::Sqrt),
            _ => match s.parse::<u32>() {
                Ok(k) if k >= 1 => Ok(ClassRule::Fixed(k)),
                _ => Err(CharError::InvalidParams(format!(
                    "class rule must be doane, sturges, sqrt or a positive count, got {s:?}"
                ))),
            },
        }
    }
}

/// Which path computes a characterization.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Backend {
    /// Vulkan compute.
    Vulkan,
    /// The rayon CPU path ([`cpu::fast`]), the default.
    #[default]
    Cpu,
    /// The single-threaded reference ([`cpu::naive`]).
    Naive,
}

impl Backend {
    /// `vulkan`, `cpu` or `naive`.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Vulkan => "vulkan",
            Backend::Cpu => "cpu",
            Backend::Naive => "naive",
        }
    }
}

impl std::str::FromStr for Backend {
    type Err = CharError;
    /// Parses `vulkan`, `cpu` or `naive`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "vulkan" => Ok(Backend::Vulkan),
            "cpu" => Ok(Backend::Cpu),
            "naive" => Ok(Backend::Naive),
            _ => Err(CharError::InvalidParams(format!("backend must be vulkan, cpu or naive, got {s:?}"))),
        }
    }
}

/// Characterizes `mesh` on `backend` (one-shot: the Vulkan backend creates its device and pipelines for this call;
/// use a [`Characterizer`] to characterize several meshes or frames).
pub fn run(mesh: &Mesh, params: &Params, backend: Backend) -> Result<Characterization, CharError> {
    Characterizer::new(Some(backend))?.characterize(mesh, params)
}

/// Characterizes meshes and animations on one backend, keeping the Vulkan device, pipelines and buffers between
/// calls.
pub struct Characterizer {
    backend: Backend,
    vulkan: Option<vulkan::VulkanBackend>,
    note: Option<String>,
    /// The CPU fast path's working memory, kept from one call to the next ([`cpu::Scratch`]).
    scratch: cpu::Scratch,
}

impl Characterizer {
    /// A characterizer on `backend`; `None` picks Vulkan when a usable device exists (see
    /// [`crate::gpu::ContextDesc::device`] and `MESHCHAR_DEVICE`), else the CPU fast path, and records why in
    /// [`Characterizer::note`]. Asking for Vulkan without a usable device is an error.
    pub fn new(backend: Option<Backend>) -> Result<Self, CharError> {
        let want_vulkan = matches!(backend, None | Some(Backend::Vulkan));
        if !want_vulkan {
            return Ok(Characterizer {
                backend: backend.unwrap_or_default(),
                vulkan: None,
                note: None,
                scratch: cpu::Scratch::default(),
            });
        }
        let made = crate::gpu::Context::new(&crate::gpu::ContextDesc::default())
            .map_err(|e| CharError::Gpu(e.to_string()))
            .and_then(|ctx| vulkan::VulkanBackend::new(&ctx));
        match (made, backend) {
            (Ok(vk), _) => Ok(Characterizer {
                backend: Backend::Vulkan,
                vulkan: Some(vk),
                note: None,
                scratch: cpu::Scratch::default(),
            }),
            (Err(e), Some(_)) => Err(e),
            (Err(e), None) => Ok(Characterizer {
                backend: Backend::Cpu,
                vulkan: None,
                note: Some(format!("no usable Vulkan device ({e}); using the CPU path")),
                scratch: cpu::Scratch::default(),
            }),
        }
    }

    /// A Vulkan characterizer on an existing context (a host engine's device, say).
    pub fn with_context(ctx: &crate::gpu::Context) -> Result<Self, CharError> {
        Ok(Characterizer {
            backend: Backend::Vulkan,
            vulkan: Some(vulkan::VulkanBackend::new(ctx)?),
            note: None,
            scratch: cpu::Scratch::default(),
        })
    }

    /// The backend in use.
    pub fn backend(&self) -> Backend {
        self.backend
    }

    /// Why the automatic choice fell back to the CPU, if it did.
    pub fn note(&self) -> Option<&str> {
        self.note.as_deref()
    }

    /// Characterizes one mesh.
    pub fn characterize(&mut self, mesh: &Mesh, params: &Params) -> Result<Characterization, CharError> {
        match (&mut self.vulkan, self.backend) {
            (Some(vk), _) => vk.characterize(mesh, params),
            (None, Backend::Naive) => cpu::naive(mesh, params),
            (None, _) => cpu::fast_with(mesh, params, &mut self.scratch),
        }
    }

    /// Characterizes every frame of an animation (on Vulkan, the topology is uploaded once).
    pub fn characterize_animation(
        &mut self,
        anim: &Animation,
        params: &Params,
    ) -> Result<Vec<Characterization>, CharError> {
        match &mut self.vulkan {
            Some(vk) => vk.characterize_animation(anim, params),
            None => anim.frames.iter().map(|f| self.characterize(f, params)).collect(),
        }
    }
}

impl Characterizer {
    /// Characterizes one mesh and measures its scene features ([`features`]): on Vulkan with one more GPU pass over
    /// the codes already on the device, on the CPU paths with [`features_cpu`]. Both give the same integers.
    pub fn characterize_with_features(
        &mut self,
        mesh: &Mesh,
        params: &Params,
    ) -> Result<(Characterization, Features), CharError> {
        match (&mut self.vulkan, self.backend) {
            (Some(vk), _) => vk.characterize_with_features(mesh, params),
            (None, Backend::Naive) => Ok((cpu::naive(mesh, params)?, features_cpu(mesh, params)?)),
            // The fast path's codes, kept in its working memory or returned per triangle, feed the feature pass.
            (None, _) => {
                let c = cpu::fast_with(mesh, params, &mut self.scratch)?;
                let n = c.triangles as usize;
                let codes = match &c.per_triangle {
                    Some(p) => Some(features::SampleCodes::Wide(&p.codes)),
                    None => self.scratch.sample_codes(n, params.morton_bits),
                };
                let f = match codes {
                    Some(codes) => features::features_of_codes(mesh, params, codes)?,
                    None => features_cpu(mesh, params)?,
                };
                Ok((c, f))
            }
        }
    }

    /// [`Characterizer::characterize_with_features`] for every frame of an animation.
    pub fn characterize_animation_with_features(
        &mut self,
        anim: &Animation,
        params: &Params,
    ) -> Result<(Vec<Characterization>, Vec<Features>), CharError> {
        let mut chars = Vec::with_capacity(anim.frames.len());
        let mut feats = Vec::with_capacity(anim.frames.len());
        for frame in &anim.frames {
            let (c, f) = self.characterize_with_features(frame, params)?;
            chars.push(c);
            feats.push(f);
        }
        Ok((chars, feats))
    }
}

/// The largest class count any rule may produce (the GPU privatizes the histogram in shared memory of this size).
pub const MAX_CLASSES: u32 = 4096;

/// Rule for the number of classes `k`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum ClassRule {
    /// Doane (docs/spec.md step 6), the thesis's rule and the default.
    #[default]
    Doane,
    /// Sturges: `ceil(1 + log2 n)`.
    Sturges,
    /// Square root: `ceil(sqrt n)`.
    Sqrt,
    /// A fixed count (clamped to `1..=MAX_CLASSES`).
    Fixed(u32),
}

/// Knobs of a characterization.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// 30-bit (default) or 63-bit codes.
    pub morton_bits: MortonBits,
    /// Significance of the chi-square test (default 0.005, as the thesis).
    pub alpha: f64,
    /// Look at every `sample_stride`-th triangle only (1 = all, the default). Triangle `i` is in the sample iff
    /// `i % sample_stride == 0`.
    pub sample_stride: u32,
    /// Class-count rule.
    pub class_rule: ClassRule,
    /// Keep the per-triangle codes and classes in the result (they always stay on the device for the Vulkan path).
    pub keep_per_triangle: bool,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            morton_bits: MortonBits::Bits30,
            alpha: 0.005,
            sample_stride: 1,
            class_rule: ClassRule::Doane,
            keep_per_triangle: false,
        }
    }
}

/// Exact statistics of the Morton codes: what every backend's second pass produces.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CodeStats {
    /// Number of codes `n`.
    pub n: u64,
    /// Smallest code.
    pub code_min: u64,
    /// Largest code.
    pub code_max: u64,
    /// `sum m`.
    pub s1: BigUint,
    /// `sum m^2`.
    pub s2: BigUint,
    /// `sum m^3`.
    pub s3: BigUint,
}

/// Mean, population standard deviation and population skewness of the codes (docs/spec.md step 5).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Moments {
    /// `mu`.
    pub mean: f64,
    /// `sigma`.
    pub std_dev: f64,
    /// `g1` (0 when `sigma == 0`).
    pub skewness: f64,
}

/// Chi-square test, effect size, concentration and empty classes of a histogram (docs/spec.md steps 9 and 10).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct HistogramStats {
    /// `sum (O_i - E)^2 / E`.
    pub chi_square: f64,
    /// `k - 1`.
    pub dof: u32,
    /// `P(X >= chi2)`, `X ~ chi-square(dof)` (1 when `dof == 0`).
    pub p_value: f64,
    /// Critical value at `alpha` (0 when `dof == 0`).
    pub critical_value: f64,
    /// `chi_square <= critical_value`.
    pub uniform: bool,
    /// Cramér's `V = sqrt(chi2 / (n (k - 1)))` (0 when `k == 1`).
    pub cramers_v: f64,
    /// Classes with `O_i == 0`.
    pub empty_classes: u32,
    /// Classes with `O_i > E`.
    pub concentrated_classes: u32,
    /// Share of triangles in concentrated classes.
    pub concentrated_share: f64,
}

/// GPU (or CPU) time of one pass.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PassTime {
    /// Pass name (`keys_bounds`, `morton_moments`, `classes_histogram`, `chi_square`, ..., [`PassTime::TOTAL`]).
    pub name: String,
    /// Milliseconds.
    pub ms: f64,
}

impl PassTime {
    /// The name of the last entry of every backend's timings: the whole characterization.
    pub const TOTAL: &'static str = "total";
}

/// Codes and classes of every sampled triangle, in sample order.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct PerTriangle {
    /// Morton code of each sampled triangle.
    pub codes: Vec<u64>,
    /// Class of each sampled triangle.
    pub classes: Vec<u32>,
}

/// What a backend measures on the data: only exact quantities (see the module docs). [`Characterization::from_exact`]
/// turns them into the result; every backend goes through it, so no backend computes a reported float itself.
pub(crate) struct Exact {
    /// `lo` of step 2.
    pub(crate) lo: [f32; 3],
    /// `hi` of step 2.
    pub(crate) hi: [f32; 3],
    /// Exact code statistics of step 5 (`n` is the number of sampled triangles).
    pub(crate) code_stats: CodeStats,
    /// `k`.
    pub(crate) classes: u32,
    /// `O_0 .. O_{k-1}`.
    pub(crate) histogram: Vec<u64>,
    /// Steps 9 and 10, by [`histogram_stats`] or [`histogram_stats_exact`].
    pub(crate) stats: HistogramStats,
    /// Per-triangle codes and classes, when kept.
    pub(crate) per_triangle: Option<PerTriangle>,
}

impl Characterization {
    /// The result of `backend` on `device` for a mesh of `total_triangles` triangles with `params`: the exact quantities, the moments computed from
    /// them by [`moments`], and the pass timings.
    pub(crate) fn from_exact(
        mesh: &Mesh,
        params: &Params,
        exact: Exact,
        timings: Vec<PassTime>,
        backend: Backend,
        device: String,
    ) -> Characterization {
        Self::from_exact_total(mesh.triangle_count() as u64, params, exact, timings, backend, device)
    }

    /// [`Characterization::from_exact`] for a mesh of `total_triangles` triangles (a device view).
    pub(crate) fn from_exact_total(
        total_triangles: u64,
        params: &Params,
        exact: Exact,
        timings: Vec<PassTime>,
        backend: Backend,
        device: String,
    ) -> Characterization {
        let Exact { lo, hi, code_stats, classes, histogram, stats, per_triangle } = exact;
        Characterization {
            total_triangles,
            triangles: code_stats.n,
            params: params.clone(),
            lo,
            hi,
            moments: moments(&code_stats),
            code_stats,
            classes,
            histogram,
            stats,
            per_triangle,
            timings,
            backend: backend.name().into(),
            device,
        }
    }
}

/// The result of characterizing one mesh (or one frame) on one backend.
#[derive(Clone, Debug, PartialEq)]
pub struct Characterization {
    /// Triangles in the mesh.
    pub total_triangles: u64,
    /// Triangles looked at (`n`; equal to `total_triangles` when `sample_stride == 1`).
    pub triangles: u64,
    /// Parameters used.
    pub params: Params,
    /// `lo` of step 2.
    pub lo: [f32; 3],
    /// `hi` of step 2.
    pub hi: [f32; 3],
    /// Exact code statistics of step 5.
    pub code_stats: CodeStats,
    /// Moments of step 5.
    pub moments: Moments,
    /// `k`.
    pub classes: u32,
    /// `O_0 .. O_{k-1}`.
    pub histogram: Vec<u64>,
    /// Steps 9 and 10.
    pub stats: HistogramStats,
    /// Per-triangle codes and classes, when `params.keep_per_triangle`.
    pub per_triangle: Option<PerTriangle>,
    /// Time of each pass.
    pub timings: Vec<PassTime>,
    /// `naive`, `cpu` or `vulkan`.
    pub backend: String,
    /// The device (GPU name, or the CPU and thread count).
    pub device: String,
}

impl Characterization {
    /// Whether `other` reports the same characterization: every field but the pass timings, the backend and the
    /// device, which differ between runs and backends by design. The CPU reference and a device run of the same mesh
    /// and parameters compare equal (the backends are bit-identical); so does a planned run's report with the report of
    /// its CPU reference ([`plan::reference`]).
    pub fn same_result(&self, other: &Characterization) -> bool {
        let strip = |c: &Characterization| Characterization {
            timings: Vec::new(),
            backend: String::new(),
            device: String::new(),
            ..c.clone()
        };
        strip(self) == strip(other)
    }
}
