//! The characterization passes of `docs/spec.md` on the GPU, producing only exact quantities (bounds, codes, their
//! minimum, maximum and exact power sums, classes, the histogram and the exact chi-square numerator). The host-side
//! meaning of those numbers (moments, `k`, p-values) lives in [`crate::characterize`].
//!
//! Three submissions per mesh or frame, because the host computes what the next pass needs: the quantization scale
//! after the bounds (docs/spec.md step 3 forbids device division), and `k` with its class thresholds after the moments.

use crate::gpu::shaders::layout::{
    BOUNDS_HI, BOUNDS_LO, BOUNDS_WORDS, CHI_CONCENTRATED, CHI_CONCENTRATED_TRIANGLES, CHI_EMPTY, CHI_T_HI, CHI_T_LO,
    CHI_WORDS, MOMENTS_CODE_MAX, MOMENTS_CODE_MIN, MOMENTS_LIMBS,
};
use crate::gpu::{
    bounds_read_back, shaders, Buffer, Context, GpuError, InputError, Kernel, KernelDesc, KeysPush, MemoryKind,
    MeshBuffers, Result, RunError, Timer,
};
use crate::keys::{MortonBits, Quantizer};

/// Items per invocation and tile in the per-triangle passes.
const ITEMS: u32 = 8;
/// Limbs of the exact sums: 4 for S1, 7 for S2, 10 for S3 (see `glsl/include/wide.glsl`).
pub const LIMBS: [usize; 3] = [4, 7, 10];
const NLIMBS: usize = 21;
/// Largest class count the histogram kernel privatizes in shared memory.
pub const MAX_GPU_CLASSES: u32 = 4096;

// Byte offsets inside the small result buffer (the layouts of its parts are in `glsl/include/layout.glsl`).
const OFF_BOUNDS: u64 = 0; // uint[BOUNDS_WORDS]
const OFF_MORTON: u64 = 64; // uint64[MOMENTS_WORDS]
const MOMENTS_WORDS: usize = MOMENTS_LIMBS as usize + NLIMBS;
const OFF_CHI: u64 = OFF_MORTON + 8 * MOMENTS_WORDS as u64; // uint64[CHI_WORDS]
const OFF_HIST: u64 = OFF_CHI + 64; // uint[k]
const RESULT_BYTES: u64 = OFF_HIST + 4 * MAX_GPU_CLASSES as u64;

pub use crate::gpu::shaders::chi_square::Push as ChiPush;
pub use crate::gpu::shaders::classes_histogram::Push as ClassesPush;
pub use crate::gpu::shaders::morton_moments::Push as MortonPush;

/// What the host decides between the moment pass and the class pass: the class count and its thresholds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ClassPlan {
    /// `k`.
    pub k: u32,
    /// `t_j = ceil(j (m_max - m_min) / k)` for `j = 1 .. k - 1`.
    pub thresholds: Vec<u64>,
}

/// Exact results of the moment pass.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CodeSums {
    /// Number of codes.
    pub n: u64,
    /// Smallest code.
    pub code_min: u64,
    /// Largest code.
    pub code_max: u64,
    /// `S1`, `S2`, `S3` as little-endian 24-bit limbs (each limb may exceed 24 bits; its weight is `2^(24 j)`).
    pub limbs: [Vec<u64>; 3],
}

/// Everything the GPU computed for one mesh or frame.
#[derive(Clone, Debug, PartialEq)]
pub struct GpuCharacterization {
    /// Sampled triangles `n`.
    pub n: u64,
    /// Bounds of the keys.
    pub lo: [f32; 3],
    /// Bounds of the keys.
    pub hi: [f32; 3],
    /// The moment pass.
    pub sums: CodeSums,
    /// The class plan used.
    pub plan: ClassPlan,
    /// Histogram of classes.
    pub histogram: Vec<u64>,
    /// `T = sum (k O_i - n)^2`.
    pub chi_numerator: u128,
    /// Classes with no triangle.
    pub empty_classes: u32,
    /// Classes with `k O_i > n`.
    pub concentrated_classes: u32,
    /// Triangles in concentrated classes.
    pub concentrated_triangles: u64,
    /// Codes and classes read back, when asked for.
    pub per_triangle: Option<(Vec<u64>, Vec<u32>)>,
    /// GPU time of each pass (ms), from timestamps.
    pub timings: Vec<(String, f64)>,
}

struct Scratch {
    capacity: u64,
    keys: Buffer,
    codes: Buffer,
    classes: Buffer,
}

/// The characterization pipelines and their buffers, reused across meshes and frames (buffers grow when needed).
pub struct CharacterizeGpu {
    ctx: Context,
    keys: Kernel<KeysPush>,
    morton: [Kernel<MortonPush>; 2],
    classes: [Kernel<ClassesPush>; 2],
    chi: Kernel<ChiPush>,
    max_k: u32,
    result: Buffer,
    thresholds: Buffer,
    readback: Buffer,
    scratch: Option<Scratch>,
    timer: Timer,
}

impl CharacterizeGpu {
    /// Builds the pipelines for the context's device.
    pub fn new(ctx: &Context) -> Result<Self> {
        let caps = ctx.caps();
        // Shared memory: the histogram plus a margin for the compiler's own use.
        let max_k = MAX_GPU_CLASSES.min((caps.max_shared_memory / 4).saturating_sub(256)).max(1);
        let mk = |bits63: u32| -> Result<(Kernel<MortonPush>, Kernel<ClassesPush>)> {
            Ok((
                Kernel::new(
                    ctx,
                    &KernelDesc::new(&shaders::morton_moments::INFO)
                        .constant("ITEMS", ITEMS)
                        .constant("BITS63", bits63),
                )?,
                Kernel::new(
                    ctx,
                    &KernelDesc::new(&shaders::classes_histogram::INFO)
                        .constant("ITEMS", ITEMS)
                        .constant("BITS63", bits63)
                        .constant("MAX_K", max_k),
                )?,
            ))
        };
        let (m30, c30) = mk(0)?;
        let (m63, c63) = mk(1)?;
        Ok(CharacterizeGpu {
            ctx: ctx.clone(),
            keys: Kernel::new(ctx, &KernelDesc::new(&shaders::keys_bounds::INFO).constant("ITEMS", ITEMS))?,
            morton: [m30, m63],
            classes: [c30, c63],
            chi: Kernel::new(ctx, &KernelDesc::new(&shaders::chi_square::INFO))?,
            max_k,
            result: ctx.create_buffer("characterize result", RESULT_BYTES, MemoryKind::DeviceLocal)?,
            thresholds: ctx.create_buffer("class thresholds", 8 * max_k as u64, MemoryKind::Upload)?,
            readback: ctx.create_buffer("characterize readback", RESULT_BYTES, MemoryKind::Readback)?,
            scratch: None,
            timer: Timer::new(ctx, 16)?,
        })
    }

    /// Largest class count this device's histogram kernel accepts.
    pub fn max_classes(&self) -> u32 {
        self.max_k
    }

    fn scratch(&mut self, n: u64) -> Result<&Scratch> {
        if self.scratch.as_ref().is_none_or(|s| s.capacity < n) {
            self.scratch = None; // free the old buffers first
            let ctx = &self.ctx;
            self.scratch = Some(Scratch {
                capacity: n,
                keys: ctx.create_buffer("keys", 12 * n, MemoryKind::DeviceLocal)?,
                codes: ctx.create_buffer("codes", 8 * n, MemoryKind::DeviceLocal)?,
                classes: ctx.create_buffer("classes", 4 * n, MemoryKind::DeviceLocal)?,
            });
        }
        self.scratch.as_ref().ok_or_else(|| GpuError::Buffer("scratch".into()))
    }

    /// The device buffers of the last run's keys (f32 xyz), codes (u32 or u64) and classes (u32), for later passes
    /// (a BVH builder, a renderer of classes). `None` before the first run.
    pub fn device_arrays(&self) -> Option<(&Buffer, &Buffer, &Buffer)> {
        self.scratch.as_ref().map(|s| (&s.keys, &s.codes, &s.classes))
    }

    /// Characterizes the mesh on the device: every `stride`-th triangle, `bits` Morton codes; `plan` turns the exact
    /// code sums into the class count and thresholds (see [`crate::characterize`]). With `read_back`, the codes and
    /// classes are copied to the host too.
    pub fn run(
        &mut self,
        mesh: &MeshBuffers,
        bits: MortonBits,
        stride: u64,
        plan: &dyn Fn(&CodeSums) -> std::result::Result<ClassPlan, String>,
        read_back: bool,
    ) -> std::result::Result<GpuCharacterization, RunError> {
        let stride = stride.max(1);
        let n = mesh.triangles.div_ceil(stride);
        if n == 0 {
            return Err(InputError::Empty.into());
        }
        if n > u32::MAX as u64 {
            return Err(InputError::TooMany(n).into());
        }
        let b63 = usize::from(bits == MortonBits::Bits63);
        self.scratch(n)?;
        let ctx = self.ctx.clone();
        let (scratch, timer) = match (&self.scratch, &mut self.timer) {
            (Some(s), t) => (s, t),
            (None, _) => return Err(GpuError::Buffer("scratch".into()).into()),
        };
        let (result, readback) = (&self.result, &self.readback);
        let wg = self.keys.workgroup_size() as u64;
        let per_group = wg * ITEMS as u64;

        // Pass 1: keys and bounds.
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(timer);
            rec.fill(result, OFF_BOUNDS + 4 * BOUNDS_LO as u64, Some(12), u32::MAX);
            rec.fill(result, OFF_BOUNDS + 4 * BOUNDS_HI as u64, Some(12), 0);
            rec.barrier();
            rec.timestamp_start(timer);
            let push = KeysPush {
                positions: mesh.positions.address(),
                indices: mesh.indices.address(),
                keys: scratch.keys.address(),
                result: result.address() + OFF_BOUNDS,
                count: n,
                stride,
            };
            let groups = rec.groups_for(n, per_group);
            rec.dispatch(&self.keys, &push, groups);
            rec.timestamp(timer, "keys_bounds");
            rec.barrier();
            rec.copy(result, OFF_BOUNDS, readback, OFF_BOUNDS, 4 * BOUNDS_WORDS as u64);
            rec.host_read_barrier();
            Ok(())
        })?;
        let q = Quantizer::new(&bounds_read_back(readback, OFF_BOUNDS)?, bits).map_err(InputError::from)?;
        let (lo, hi, scale) = (q.lo(), q.hi(), q.scale());

        // Pass 2: codes, their range and exact power sums.
        ctx.submit_and_wait(|rec| {
            rec.fill(result, OFF_MORTON + 8 * MOMENTS_CODE_MIN as u64, Some(8), u32::MAX);
            rec.fill(result, OFF_MORTON + 8 * MOMENTS_CODE_MAX as u64, Some(8), 0);
            rec.fill(result, OFF_MORTON + 8 * MOMENTS_LIMBS as u64, Some(8 * NLIMBS as u64), 0);
            rec.barrier();
            rec.timestamp_start(timer);
            let push = MortonPush {
                keys: scratch.keys.address(),
                codes: scratch.codes.address(),
                result: result.address() + OFF_MORTON,
                count: n,
                lo_x: lo[0],
                lo_y: lo[1],
                lo_z: lo[2],
                scale_x: scale[0],
                scale_y: scale[1],
                scale_z: scale[2],
            };
            let groups = rec.groups_for(n, per_group);
            rec.dispatch(&self.morton[b63], &push, groups);
            rec.timestamp(timer, "morton_moments");
            rec.barrier();
            rec.copy(result, OFF_MORTON, readback, OFF_MORTON, 8 * MOMENTS_WORDS as u64);
            rec.host_read_barrier();
            Ok(())
        })?;
        let m: Vec<u64> = readback.read(OFF_MORTON, MOMENTS_WORDS)?;
        let l = MOMENTS_LIMBS as usize;
        let limbs = [
            m[l..l + LIMBS[0]].to_vec(),
            m[l + LIMBS[0]..l + LIMBS[0] + LIMBS[1]].to_vec(),
            m[l + LIMBS[0] + LIMBS[1]..l + NLIMBS].to_vec(),
        ];
        let (code_min, code_max) = (m[MOMENTS_CODE_MIN as usize], m[MOMENTS_CODE_MAX as usize]);
        let sums = CodeSums { n, code_min, code_max, limbs };
        let class_plan = plan(&sums).map_err(InputError::Plan)?;
        let k = class_plan.k;
        if k == 0 || k > self.max_k || class_plan.thresholds.len() != k as usize - 1 {
            return Err(InputError::Plan(format!(
                "k = {k} with {} thresholds (this device supports k <= {})",
                class_plan.thresholds.len(),
                self.max_k
            ))
            .into());
        }
        self.thresholds.write(0, &class_plan.thresholds)?;

        // Pass 3: classes, histogram, chi-square numerator.
        let thresholds = &self.thresholds;
        ctx.submit_and_wait(|rec| {
            rec.fill(result, OFF_HIST, Some(4 * k as u64), 0);
            rec.barrier();
            rec.timestamp_start(timer);
            let push = ClassesPush {
                codes: scratch.codes.address(),
                classes: scratch.classes.address(),
                thresholds: thresholds.address(),
                hist: result.address() + OFF_HIST,
                count: n,
                code_min: sums.code_min,
                k,
                pad: 0,
            };
            let groups = rec.groups_for(n, per_group);
            rec.dispatch(&self.classes[b63], &push, groups);
            rec.timestamp(timer, "classes_histogram");
            rec.barrier();
            let push =
                ChiPush { hist: result.address() + OFF_HIST, out_addr: result.address() + OFF_CHI, n, k, pad: 0 };
            rec.dispatch(&self.chi, &push, 1);
            rec.timestamp(timer, "chi_square");
            rec.barrier();
            rec.copy(result, OFF_CHI, readback, OFF_CHI, 8 * CHI_WORDS);
            rec.copy(result, OFF_HIST, readback, OFF_HIST, 4 * k as u64);
            rec.host_read_barrier();
            Ok(())
        })?;
        let chi: Vec<u64> = readback.read(OFF_CHI, CHI_WORDS as usize)?;
        let hist: Vec<u32> = readback.read(OFF_HIST, k as usize)?;
        let timings = timer.read()?;
        let per_triangle = if read_back {
            let codes: Vec<u64> = if b63 == 1 {
                ctx.read_buffer(&scratch.codes, 0, n as usize)?
            } else {
                ctx.read_buffer::<u32>(&scratch.codes, 0, n as usize)?.into_iter().map(u64::from).collect()
            };
            Some((codes, ctx.read_buffer(&scratch.classes, 0, n as usize)?))
        } else {
            None
        };
        Ok(GpuCharacterization {
            n,
            lo,
            hi,
            sums,
            plan: class_plan,
            histogram: hist.into_iter().map(u64::from).collect(),
            chi_numerator: (chi[CHI_T_HI as usize] as u128) << 64 | chi[CHI_T_LO as usize] as u128,
            empty_classes: chi[CHI_EMPTY as usize] as u32,
            concentrated_classes: chi[CHI_CONCENTRATED as usize] as u32,
            concentrated_triangles: chi[CHI_CONCENTRATED_TRIANGLES as usize],
            per_triangle,
            timings,
        })
    }
}
