//! The scene-feature pass on the GPU: one more cheap pass after the characterization, over the codes it left on the
//! device. It produces the exact integers that [`crate::characterize::features`] defines: a mask of occupied
//! Morton cells at the deepest counted depth (the host counts set bits per depth), the histogram of triangle-size
//! exponents, and the vertex bounds of the sampled triangles.
//!
//! Two dispatches in one submission: `features_bounds` (vertex bounds in IEEE total order), then `features` (mask
//! bits by atomic OR, size histogram privatized in shared memory), which reads the bounds from device memory, so
//! no host round trip separates them.

use crate::gpu::shaders::layout::{BOUNDS_HI, BOUNDS_LO, BOUNDS_WORDS};
use crate::gpu::{shaders, Buffer, Context, GpuError, Kernel, KernelDesc, MemoryKind, MeshBuffers, Result, Timer};
use crate::keys::{from_ordered_bits, MortonBits};

const ITEMS: u32 = 8;
/// Bits of the occupancy mask index: the top `MASK_LOG2` bits of a code (depth 7, `2^21` cells).
pub const MASK_LOG2: u32 = 21;
const MASK_WORDS: u64 = 1 << (MASK_LOG2 - 5);

pub use crate::gpu::shaders::features::Push as FeaturesPush;
pub use crate::gpu::shaders::features_bounds::Push as FeatureBoundsPush;

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
pub struct FeaturesGpu {
    ctx: Context,
    bounds: Kernel<FeatureBoundsPush>,
    features: [Kernel<FeaturesPush>; 2],
    size_bins: u32,
    result: Buffer,
    readback: Buffer,
    timer: Timer,
}

impl FeaturesGpu {
    /// Builds the pipelines for a histogram of `size_bins` bins (at least 1).
    pub fn new(ctx: &Context, size_bins: u32) -> Result<Self> {
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
        let bytes = Self::result_bytes(size_bins);
        Ok(FeaturesGpu {
            ctx: ctx.clone(),
            bounds: Kernel::new(ctx, &KernelDesc::new(&shaders::features_bounds::INFO).constant("ITEMS", ITEMS))?,
            features: [mk(0)?, mk(1)?],
            size_bins,
            result: ctx.create_buffer("features result", bytes, MemoryKind::DeviceLocal)?,
            readback: ctx.create_buffer("features readback", bytes, MemoryKind::Readback)?,
            timer: Timer::new(ctx, 4)?,
        })
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

    /// Runs the pass over `n` sampled triangles (every `stride`-th of `mesh`) whose `bits` Morton codes are in
    /// `codes` (as [`super::passes::CharacterizeGpu::device_arrays`] leaves them), submits and waits.
    pub fn run(
        &mut self,
        mesh: &MeshBuffers,
        codes: &Buffer,
        n: u64,
        stride: u64,
        bits: MortonBits,
    ) -> Result<GpuFeatures> {
        let stride = stride.max(1);
        if n == 0 || n > mesh.triangles.div_ceil(stride) {
            return Err(GpuError::Buffer(format!(
                "feature pass over {n} sampled triangles of a {}-triangle mesh (stride {stride})",
                mesh.triangles
            )));
        }
        let b63 = usize::from(bits == MortonBits::Bits63);
        let code_bytes = if b63 == 1 { 8 } else { 4 };
        if codes.size() < n * code_bytes {
            return Err(GpuError::Buffer(format!("codes buffer of {} bytes for {n} codes", codes.size())));
        }
        let ctx = self.ctx.clone();
        let (result, readback, timer) = (&self.result, &self.readback, &mut self.timer);
        let bytes = Self::result_bytes(self.size_bins);
        let wg = self.bounds.workgroup_size() as u64;
        let per_group = wg * ITEMS as u64;
        let bounds_addr = result.address() + Self::off_bounds();
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(timer);
            rec.fill(result, 0, Some(4 * MASK_WORDS), 0);
            rec.fill(result, Self::off_bounds() + 4 * BOUNDS_LO as u64, Some(12), u32::MAX);
            rec.fill(result, Self::off_bounds() + 4 * BOUNDS_HI as u64, Some(12), 0);
            rec.fill(result, Self::off_hist(), Some(4 * (self.size_bins as u64 + 1)), 0);
            rec.barrier();
            rec.timestamp_start(timer);
            let push = FeatureBoundsPush {
                positions: mesh.positions.address(),
                indices: mesh.indices.address(),
                result: bounds_addr,
                count: n,
                stride,
            };
            rec.dispatch(&self.bounds, &push, rec.groups_for(n, per_group));
            rec.barrier();
            let push = FeaturesPush {
                positions: mesh.positions.address(),
                indices: mesh.indices.address(),
                codes: codes.address(),
                mask: result.address(),
                hist: result.address() + Self::off_hist(),
                bounds: bounds_addr,
                count: n,
                stride,
                shift: bits.total() - MASK_LOG2,
                pad: 0,
            };
            rec.dispatch(&self.features[b63], &push, rec.groups_for(n, per_group));
            rec.timestamp(timer, "features");
            rec.barrier();
            rec.copy(result, 0, readback, 0, bytes);
            rec.host_read_barrier();
            Ok(())
        })?;
        let words: Vec<u32> = readback.read(0, MASK_WORDS as usize)?;
        let mask = words.chunks(2).map(|w| w[0] as u64 | (w[1] as u64) << 32).collect();
        let b: Vec<u32> = readback.read(Self::off_bounds(), BOUNDS_WORDS as usize)?;
        let corner = |at: u32| [0, 1, 2].map(|a| from_ordered_bits(b[at as usize + a]));
        let h: Vec<u32> = readback.read(Self::off_hist(), self.size_bins as usize + 1)?;
        let timings = self.timer.read()?;
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
