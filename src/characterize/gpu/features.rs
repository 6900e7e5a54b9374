//! The scene-feature pass on the GPU: one more cheap pass after the characterization, over the codes it left on the
//! device. It produces the exact integers that [`crate::characterize::features`] defines: a mask of occupied
//! Morton cells at the deepest counted depth (the host counts set bits per depth), the histogram of triangle-size
//! exponents, and the vertex bounds of the sampled triangles.
//!
//! Two dispatches: `features_bounds` (vertex bounds in IEEE total order), then `features` (mask bits by atomic OR,
//! size histogram privatized in shared memory), which reads the bounds from device memory, so no host round trip
//! separates them and the whole pass records into a caller's command buffer ([`FeaturesGpu::record`], read with
//! [`FeaturesGpu::finish`]) as well as it submits ([`FeaturesGpu::run`]).
//!
//! # Recording contract ([`FeaturesGpu::record`])
//!
//! | buffer | first access | last access |
//! |---|---|---|
//! | geometry (the [`GeometryView`]) | compute-shader read | compute-shader read |
//! | `codes` | compute-shader read (`features`) | compute-shader read |
//! | the pass's result buffer | transfer write (fill) | transfer read (copy to the readback) |
//! | the pass's readback buffer | transfer write (copy) | host read, after the recorded host barrier |
//!
//! The caller records, before, a barrier that makes the geometry and the codes visible to compute-shader reads
//! (after a characterization recorded just before: [`Recorder::dependency`] from compute to compute).

use crate::gpu::shaders::layout::{BOUNDS_HI, BOUNDS_LO, BOUNDS_WORDS};
use crate::gpu::{
    geometry_push, shaders, Buffer, CompletionFlag, Context, GeometryView, GpuError, Kernel, KernelDesc, MemoryKind,
    Pass, Recorder, Result, Timer,
};
use crate::keys::{from_ordered_bits, MortonBits};

const ITEMS: u32 = 8;
/// Bits of the occupancy mask index: the top `MASK_LOG2` bits of a code (depth 7, `2^21` cells).
pub(crate) const MASK_LOG2: u32 = 21;
const MASK_WORDS: u64 = 1 << (MASK_LOG2 - 5);

pub(crate) use crate::gpu::shaders::features::Push as FeaturesPush;
pub(crate) use crate::gpu::shaders::features_bounds::Push as FeatureBoundsPush;

/// What the feature pass read back.
#[derive(Clone, Debug, PartialEq)]
pub struct GpuFeatures {
    /// The `2^21`-bit mask of occupied depth-7 cells, as u64 words (bit `b` of word `w` is cell `64 w + b`).
    pub mask: Vec<u64>,
    /// Size histogram, `size_bins` bins.
    pub size_histogram: Vec<u64>,
    /// Triangles whose largest extent (or the scene's) is zero, subnormal or infinite.
    pub zero_extent: u64,
    /// Vertex bounds of the sampled triangles.
    pub lo: [f32; 3],
    /// Vertex bounds of the sampled triangles.
    pub hi: [f32; 3],
    /// GPU time of the pass (ms), from timestamps.
    pub timings: Vec<(String, f64)>,
}

/// The feature pipelines and their buffers.
pub(crate) struct FeaturesGpu {
    ctx: Context,
    kernels: std::sync::Arc<Kernels>,
    size_bins: u32,
    result: Buffer,
    readback: Buffer,
    timer: Timer,
    done: CompletionFlag,
    pending: bool,
}

/// The pipelines of the pass (shared by the [`FeaturesGpu::sharing_pipelines`] copies).
struct Kernels {
    bounds: Kernel<FeatureBoundsPush>,
    features: [Kernel<FeaturesPush>; 2],
}

impl FeaturesGpu {
    /// Builds the pipelines for a histogram of `size_bins` bins (at least 1).
    pub(crate) fn new(ctx: &Context, size_bins: u32) -> Result<Self> {
        let size_bins = size_bins.max(1);
        let mk = |b63: u32| {
            Kernel::new(
                ctx,
                &KernelDesc::new(&shaders::features::INFO)
                    .constant("ITEMS", ITEMS)
                    .constant("BITS63", b63)
                    .constant("SIZE_BINS", size_bins),
            )
        };
        let kernels = Kernels {
            bounds: Kernel::new(ctx, &KernelDesc::new(&shaders::features_bounds::INFO).constant("ITEMS", ITEMS))?,
            features: [mk(0)?, mk(1)?],
        };
        Self::with_kernels(ctx, std::sync::Arc::new(kernels), size_bins)
    }

    fn with_kernels(ctx: &Context, kernels: std::sync::Arc<Kernels>, size_bins: u32) -> Result<Self> {
        let bytes = Self::result_bytes(size_bins);
        Ok(FeaturesGpu {
            ctx: ctx.clone(),
            kernels,
            size_bins,
            result: ctx.create_buffer("features result", bytes, MemoryKind::DeviceLocal)?,
            readback: ctx.create_buffer("features readback", bytes, MemoryKind::Readback)?,
            timer: Timer::new(ctx, 4)?,
            done: CompletionFlag::new(ctx)?,
            pending: false,
        })
    }

    /// A second pass object with buffers of its own and the same pipelines (already compiled and warmed when this
    /// one is): one per run that may be in flight at once.
    pub(crate) fn sharing_pipelines(&self) -> Result<Self> {
        Self::with_kernels(&self.ctx, self.kernels.clone(), self.size_bins)
    }

    // Layout: mask words, then 6 bound words (+2 padding), then the histogram.
    fn off_bounds() -> u64 {
        4 * MASK_WORDS
    }
    fn off_hist() -> u64 {
        4 * MASK_WORDS + 32
    }
    fn result_bytes(size_bins: u32) -> u64 {
        Self::off_hist() + 4 * (size_bins as u64 + 1)
    }

    /// Runs the pass over `n` sampled triangles (every `stride`-th of the view) whose `bits` Morton codes are in
    /// `codes` (as [`super::passes::CharacterizeGpu::device_arrays`] leaves them), submits and waits.
    pub(crate) fn run(
        &mut self,
        view: &GeometryView<'_>,
        codes: &Buffer,
        n: u64,
        stride: u64,
        bits: MortonBits,
    ) -> Result<GpuFeatures> {
        let ctx = self.ctx.clone();
        ctx.submit_and_wait(|rec| self.record(rec, view, codes, n, stride, bits))?;
        self.finish()
    }

    /// Records the pass (see the module docs for the recording contract); [`FeaturesGpu::finish`] reads it once
    /// the command buffer has completed. A pass recorded and not yet finished is an error.
    pub(crate) fn record(
        &mut self,
        rec: &mut Recorder<'_>,
        view: &GeometryView<'_>,
        codes: &Buffer,
        n: u64,
        stride: u64,
        bits: MortonBits,
    ) -> Result<()> {
        let stride = stride.max(1);
        if n == 0 || n > view.triangle_count().div_ceil(stride) {
            return Err(GpuError::Buffer(format!(
                "feature pass over {n} sampled triangles of a {}-triangle view (stride {stride})",
                view.triangle_count()
            )));
        }
        if self.pending {
            return Err(GpuError::Buffer("feature pass: the previous recorded pass was not finished".into()));
        }
        let b63 = usize::from(bits == MortonBits::Bits63);
        let code_bytes = if b63 == 1 { 8 } else { 4 };
        if codes.size() < n * code_bytes {
            return Err(GpuError::Buffer(format!("codes buffer of {} bytes for {n} codes", codes.size())));
        }
        let (result, readback, timer) = (&self.result, &self.readback, &mut self.timer);
        let bytes = Self::result_bytes(self.size_bins);
        let wg = self.kernels.bounds.workgroup_size() as u64;
        let per_group = wg * ITEMS as u64;
        let bounds_addr = result.address() + Self::off_bounds();
        rec.reset_timer(timer);
        rec.fill(result, 0, Some(4 * MASK_WORDS), 0);
        rec.fill(result, Self::off_bounds() + 4 * BOUNDS_LO as u64, Some(12), u32::MAX);
        rec.fill(result, Self::off_bounds() + 4 * BOUNDS_HI as u64, Some(12), 0);
        rec.fill(result, Self::off_hist(), Some(4 * (self.size_bins as u64 + 1)), 0);
        rec.dependency(Pass::Transfer, Pass::Compute);
        rec.timestamp_start(timer);
        let push = geometry_push!(FeatureBoundsPush, view, { result: bounds_addr, count: n, stride: stride });
        // SAFETY: reads n sampled triangles of the view (checked above) and writes six words of the result buffer.
        unsafe { rec.dispatch(&self.kernels.bounds, &push, rec.groups_for(n, per_group)) };
        rec.dependency(Pass::Compute, Pass::Compute);
        let push = geometry_push!(FeaturesPush, view, {
            codes: codes.address(),
            mask: result.address(),
            hist: result.address() + Self::off_hist(),
            bounds: bounds_addr,
            count: n,
            stride: stride,
            shift: bits.total() - MASK_LOG2,
            pad: 0,
        });
        // SAFETY: reads n triangles and n codes (the codes buffer holds them: checked above), writes the mask and
        // the size_bins + 1 histogram entries of the result buffer.
        unsafe { rec.dispatch(&self.kernels.features[b63], &push, rec.groups_for(n, per_group)) };
        rec.timestamp(timer, "features");
        rec.dependency(Pass::Compute, Pass::Transfer);
        rec.copy(result, 0, readback, 0, bytes);
        rec.timestamp_start(timer);
        self.done.record(rec)?;
        self.pending = true;
        Ok(())
    }

    /// The results of the recorded pass once its command buffer has completed ([`GpuError::NotReady`], and still
    /// pending, before).
    pub(crate) fn finish(&mut self) -> Result<GpuFeatures> {
        if !self.pending {
            return Err(GpuError::Buffer("feature pass: nothing recorded".into()));
        }
        self.done.check("feature pass")?;
        let timings = self.timer.try_read()?;
        self.pending = false;
        let readback = &self.readback;
        let words: Vec<u32> = readback.read(0, MASK_WORDS as usize)?;
        let mask = words.chunks(2).map(|w| w[0] as u64 | (w[1] as u64) << 32).collect();
        let b: Vec<u32> = readback.read(Self::off_bounds(), BOUNDS_WORDS as usize)?;
        let corner = |at: u32| [0, 1, 2].map(|a| from_ordered_bits(b[at as usize + a]));
        let h: Vec<u32> = readback.read(Self::off_hist(), self.size_bins as usize + 1)?;
        Ok(GpuFeatures {
            mask,
            size_histogram: h[..self.size_bins as usize].iter().map(|&x| x as u64).collect(),
            zero_extent: h[self.size_bins as usize] as u64,
            lo: corner(BOUNDS_LO),
            hi: corner(BOUNDS_HI),
            timings,
        })
    }
}
