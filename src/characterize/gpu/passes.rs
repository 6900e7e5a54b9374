//! The characterization passes of `docs/spec.md` on the GPU, producing only exact quantities (bounds, codes, their
//! minimum, maximum and exact power sums, classes, the histogram and the exact chi-square numerator). The host-side
//! meaning of those numbers (moments, `k`, p-values) lives in [`crate::characterize`].
//!
//! Two ways to run them:
//!
//! - **Staged** ([`CharacterizeGpu::run`]): three submissions with a host wait after each, because the host
//!   computes what the next pass needs: the quantization scale after the bounds (docs/spec.md step 3 forbids device
//!   division), and `k` with its class thresholds after the moments. Bit-identical to the CPU backends.
//! - **Planned** ([`CharacterizeGpu::record`], then [`CharacterizeGpu::finish`]): every pass recorded at once into
//!   a command buffer the caller owns, with the host decisions fixed in advance by a [`PassPlan`] (in an animation,
//!   the plan that the previous frame's report gives: docs/spec.md, "Planned characterization"). Nothing waits;
//!   the results are read when the caller has seen the command buffer complete, one or more frames later. Equal to
//!   the CPU reference of the same plan ([`crate::characterize::plan`]).
//!
//! # Recording contract ([`CharacterizeGpu::record`])
//!
//! | buffer | first access | last access |
//! |---|---|---|
//! | geometry (the [`GeometryView`]) | compute-shader read (`keys_bounds`) | compute-shader read (`keys_bounds`) |
//! | the slot's result buffer | transfer write (fill) | transfer read (copy to the readback) |
//! | the slot's keys, codes, classes | compute-shader write | compute-shader read/write (classes) |
//! | the slot's readback buffer | transfer write (copy) | host read, after the recorded host barrier |
//!
//! The caller records, before, a barrier that makes its geometry writes visible to compute-shader reads, and reads
//! the codes or classes of the slot ([`CharacterizeGpu::device_arrays`]) after a barrier from compute-shader writes.

use crate::gpu::shaders::layout::{
    BOUNDS_HI, BOUNDS_LO, BOUNDS_WORDS, CHI_CONCENTRATED, CHI_CONCENTRATED_TRIANGLES, CHI_EMPTY, CHI_T_HI, CHI_T_LO,
    CHI_WORDS, MOMENTS_CODE_MAX, MOMENTS_CODE_MIN, MOMENTS_LIMBS,
};
use crate::gpu::{
    bounds_read_back, geometry_push, shaders, Buffer, CompletionFlag, Context, GeometryView, GpuError, InputError,
    Kernel, KernelDesc, KeysPush, MemoryKind, Pass, Recorder, Result, RunError, Timer,
};
use crate::keys::{MortonBits, Quantizer};

/// Items per invocation and tile in the per-triangle passes.
const ITEMS: u32 = 8;
/// Limbs of the exact sums: 4 for S1, 7 for S2, 10 for S3 (see `glsl/include/wide.glsl`).
pub(crate) const LIMBS: [usize; 3] = [4, 7, 10];
const NLIMBS: usize = 21;
/// Largest class count the histogram kernel privatizes in shared memory.
pub(crate) const MAX_GPU_CLASSES: u32 = 4096;

// Byte offsets inside the small result buffer (the layouts of its parts are in `glsl/include/layout.glsl`).
const OFF_BOUNDS: u64 = 0; // uint[BOUNDS_WORDS]
const OFF_MORTON: u64 = 64; // uint64[MOMENTS_WORDS]
const MOMENTS_WORDS: usize = MOMENTS_LIMBS as usize + NLIMBS;
const OFF_CHI: u64 = OFF_MORTON + 8 * MOMENTS_WORDS as u64; // uint64[CHI_WORDS]
const OFF_HIST: u64 = OFF_CHI + 64; // uint[k]
const RESULT_BYTES: u64 = OFF_HIST + 4 * MAX_GPU_CLASSES as u64;

pub(crate) use crate::gpu::shaders::chi_square::Push as ChiPush;
pub(crate) use crate::gpu::shaders::classes_histogram::Push as ClassesPush;
pub(crate) use crate::gpu::shaders::morton_moments::Push as MortonPush;

/// What the host decides between the moment pass and the class pass: the class count and its thresholds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ClassPlan {
    /// `k`.
    pub k: u32,
    /// `t_j = ceil(j (m_max - m_min) / k)` for `j = 1 .. k - 1`.
    pub thresholds: Vec<u64>,
}

/// The host decisions of one run, fixed before it is recorded: the quantizer of steps 2-3 (`lo`, `scale`) and the
/// class plan of steps 6-7 (`code_min`, `k`, thresholds). In the staged mode each comes from the run's own data;
/// in the planned mode the caller gives all of them (see [`crate::characterize::plan::Plan`]).
#[derive(Clone, Debug, PartialEq)]
pub struct PassPlan {
    /// `lo` of the quantizer.
    pub lo: [f32; 3],
    /// `scale` of the quantizer.
    pub scale: [f32; 3],
    /// `m_min` of the class rule (codes below it are in class 0).
    pub code_min: u64,
    /// `k` and the thresholds over `m - m_min`.
    pub classes: ClassPlan,
}

/// Exact results of the moment pass.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct CodeSums {
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
pub(crate) struct GpuCharacterization {
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
    /// The plan of a planned run (`None` for a staged one).
    pub plan_used: Option<PassPlan>,
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

/// What a recorded run needs to be finished.
struct Pending {
    n: u64,
    plan: PassPlan,
}

/// The per-run resources: one per run that may be in flight at once.
struct Slot {
    result: Buffer,
    thresholds: Buffer,
    readback: Buffer,
    scratch: Option<Scratch>,
    timer: Timer,
    done: CompletionFlag,
    pending: Option<Pending>,
}

impl Slot {
    fn new(ctx: &Context, max_k: u32) -> Result<Self> {
        Ok(Slot {
            result: ctx.create_buffer("characterize result", RESULT_BYTES, MemoryKind::DeviceLocal)?,
            thresholds: ctx.create_buffer("class thresholds", 8 * max_k as u64, MemoryKind::Upload)?,
            readback: ctx.create_buffer("characterize readback", RESULT_BYTES, MemoryKind::Readback)?,
            scratch: None,
            timer: Timer::new(ctx, 16)?,
            done: CompletionFlag::new(ctx)?,
            pending: None,
        })
    }

    fn scratch(&mut self, ctx: &Context, n: u64) -> Result<&Scratch> {
        if self.scratch.as_ref().is_none_or(|s| s.capacity < n) {
            self.scratch = None; // free the old buffers first
            self.scratch = Some(Scratch {
                capacity: n,
                keys: ctx.create_buffer("keys", 12 * n, MemoryKind::DeviceLocal)?,
                codes: ctx.create_buffer("codes", 8 * n, MemoryKind::DeviceLocal)?,
                classes: ctx.create_buffer("classes", 4 * n, MemoryKind::DeviceLocal)?,
            });
        }
        self.scratch.as_ref().ok_or_else(|| GpuError::Buffer("scratch".into()))
    }
}

/// The characterization pipelines and their buffers, reused across meshes and frames (buffers grow when needed),
/// with one set of per-run buffers ("slot") per run that may be in flight at once.
pub(crate) struct CharacterizeGpu {
    ctx: Context,
    k: Kernels,
    slots: Vec<Slot>,
}

/// The pipelines.
struct Kernels {
    keys: Kernel<KeysPush>,
    morton: [Kernel<MortonPush>; 2],
    classes: [Kernel<ClassesPush>; 2],
    chi: Kernel<ChiPush>,
    max_k: u32,
}

impl Kernels {
    /// Clears the slot's result buffer (bounds, code range, sums, histogram) and makes the fills visible to the
    /// kernels.
    fn record_fills(&self, rec: &mut Recorder<'_>, slot: &Slot) {
        let result = &slot.result;
        rec.fill(result, OFF_BOUNDS + 4 * BOUNDS_LO as u64, Some(12), u32::MAX);
        rec.fill(result, OFF_BOUNDS + 4 * BOUNDS_HI as u64, Some(12), 0);
        rec.fill(result, OFF_MORTON + 8 * MOMENTS_CODE_MIN as u64, Some(8), u32::MAX);
        rec.fill(result, OFF_MORTON + 8 * MOMENTS_CODE_MAX as u64, Some(8), 0);
        rec.fill(result, OFF_MORTON + 8 * MOMENTS_LIMBS as u64, Some(8 * NLIMBS as u64), 0);
        rec.fill(result, OFF_HIST, Some(4 * self.max_k as u64), 0);
        rec.dependency(Pass::Transfer, Pass::Compute);
    }

    fn record_keys(&self, rec: &mut Recorder<'_>, slot: &Slot, view: &GeometryView<'_>, n: u64, stride: u64) {
        let (Some(scratch), result) = (&slot.scratch, &slot.result) else { return };
        let push = geometry_push!(KeysPush, view, {
            keys: scratch.keys.address(),
            result: result.address() + OFF_BOUNDS,
            count: n,
            stride: stride,
        });
        let groups = rec.groups_for(n, self.keys.workgroup_size() as u64 * ITEMS as u64);
        // SAFETY: the kernel reads `n` sampled triangles of the view (valid per its constructor) and writes `n` keys
        // into the slot's scratch (capacity >= n) and the bounds into the result buffer.
        unsafe { rec.dispatch(&self.keys, &push, groups) };
    }

    fn record_morton(&self, rec: &mut Recorder<'_>, slot: &Slot, n: u64, b63: usize, lo: [f32; 3], scale: [f32; 3]) {
        let (Some(scratch), result) = (&slot.scratch, &slot.result) else { return };
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
        let groups = rec.groups_for(n, self.keys.workgroup_size() as u64 * ITEMS as u64);
        // SAFETY: reads the n keys and writes n codes (8 bytes each at most) of the slot's scratch, and the moments
        // of the result buffer.
        unsafe { rec.dispatch(&self.morton[b63], &push, groups) };
    }

    fn record_classes(&self, rec: &mut Recorder<'_>, slot: &mut Slot, n: u64, b63: usize, code_min: u64, k: u32) {
        let (Some(scratch), result, thresholds, timer) =
            (&slot.scratch, &slot.result, &slot.thresholds, &mut slot.timer)
        else {
            return;
        };
        let push = ClassesPush {
            codes: scratch.codes.address(),
            classes: scratch.classes.address(),
            thresholds: thresholds.address(),
            hist: result.address() + OFF_HIST,
            count: n,
            code_min,
            k,
            pad: 0,
        };
        let groups = rec.groups_for(n, self.keys.workgroup_size() as u64 * ITEMS as u64);
        // SAFETY: reads n codes and k - 1 thresholds (k <= max_k, the thresholds buffer's capacity), writes n
        // classes and k histogram entries (k <= MAX_GPU_CLASSES, inside the result buffer).
        unsafe { rec.dispatch(&self.classes[b63], &push, groups) };
        rec.timestamp(timer, "classes_histogram");
        rec.dependency(Pass::Compute, Pass::Compute);
        let push = ChiPush { hist: result.address() + OFF_HIST, out_addr: result.address() + OFF_CHI, n, k, pad: 0 };
        // SAFETY: one workgroup reading the k histogram entries and writing CHI_WORDS words of the result buffer.
        unsafe { rec.dispatch(&self.chi, &push, 1) };
        rec.timestamp(timer, "chi_square");
    }

    fn check_plan(&self, classes: &ClassPlan) -> std::result::Result<(), RunError> {
        let k = classes.k;
        if k == 0 || k > self.max_k || classes.thresholds.len() != k as usize - 1 {
            return Err(InputError::Plan(format!(
                "k = {k} with {} thresholds (this device supports k <= {})",
                classes.thresholds.len(),
                self.max_k
            ))
            .into());
        }
        Ok(())
    }
}

fn slot_of(slots: &mut [Slot], slot: usize) -> Result<&mut Slot> {
    let n = slots.len();
    slots.get_mut(slot).ok_or_else(|| GpuError::Buffer(format!("characterization slot {slot} of {n}")))
}

/// Checks the sample of a run: `n` sampled triangles of the view.
fn sample_count(view: &GeometryView<'_>, stride: u64) -> std::result::Result<u64, RunError> {
    let n = view.triangle_count().div_ceil(stride.max(1));
    if n == 0 {
        return Err(InputError::Empty.into());
    }
    if n > u32::MAX as u64 {
        return Err(InputError::TooMany(n).into());
    }
    Ok(n)
}

impl CharacterizeGpu {
    /// Builds the pipelines for the context's device, with one slot.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn new(ctx: &Context) -> Result<Self> {
        Self::with_slots(ctx, 1)
    }

    /// Builds the pipelines with `slots` slots (at least 1): as many planned runs as may be in flight at once.
    pub(crate) fn with_slots(ctx: &Context, slots: usize) -> Result<Self> {
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
            k: Kernels {
                keys: Kernel::new(ctx, &KernelDesc::new(&shaders::keys_bounds::INFO).constant("ITEMS", ITEMS))?,
                morton: [m30, m63],
                classes: [c30, c63],
                chi: Kernel::new(ctx, &KernelDesc::new(&shaders::chi_square::INFO))?,
                max_k,
            },
            slots: (0..slots.max(1)).map(|_| Slot::new(ctx, max_k)).collect::<Result<_>>()?,
        })
    }

    /// Largest class count this device's histogram kernel accepts.
    pub(crate) fn max_classes(&self) -> u32 {
        self.k.max_k
    }

    fn slot(&mut self, slot: usize) -> Result<&mut Slot> {
        slot_of(&mut self.slots, slot)
    }

    /// The device buffers of slot 0's last run: keys (f32 xyz), codes (u32 or u64) and classes (u32), for later
    /// passes (a BVH builder, a renderer of classes). `None` before the first run.
    pub(crate) fn device_arrays(&self) -> Option<(&Buffer, &Buffer, &Buffer)> {
        self.slot_arrays(0)
    }

    /// The device buffers of a slot's last run (see [`CharacterizeGpu::device_arrays`]).
    pub(crate) fn slot_arrays(&self, slot: usize) -> Option<(&Buffer, &Buffer, &Buffer)> {
        self.slots.get(slot)?.scratch.as_ref().map(|s| (&s.keys, &s.codes, &s.classes))
    }

    /// Records a planned run into `rec` (see the module docs for the recording contract): keys and bounds, codes
    /// and moments with `plan`'s quantizer, classes, histogram and chi-square with its class plan, and the copy of
    /// the results to the slot's readback buffer. Nothing is submitted and nothing waits. [`CharacterizeGpu::finish`]
    /// reads the results once the command buffer has completed.
    ///
    /// The slot must not be in use: its previous run finished ([`CharacterizeGpu::finish`]) or never recorded; a
    /// slot with a run not yet finished is an error (its buffers may still be in flight).
    pub(crate) fn record(
        &mut self,
        rec: &mut Recorder<'_>,
        slot: usize,
        view: &GeometryView<'_>,
        bits: MortonBits,
        stride: u64,
        plan: &PassPlan,
    ) -> std::result::Result<(), RunError> {
        let stride = stride.max(1);
        let n = sample_count(view, stride)?;
        let k = &self.k;
        k.check_plan(&plan.classes)?;
        let b63 = usize::from(bits == MortonBits::Bits63);
        let s = slot_of(&mut self.slots, slot)?;
        if s.pending.is_some() {
            return Err(GpuError::Buffer(format!("characterization slot {slot} still holds an unfinished run")).into());
        }
        s.scratch(&self.ctx, n)?;
        s.thresholds.write(0, &plan.classes.thresholds)?;
        rec.reset_timer(&mut s.timer);
        k.record_fills(rec, s);
        rec.timestamp_start(&mut s.timer);
        k.record_keys(rec, s, view, n, stride);
        rec.timestamp(&mut s.timer, "keys_bounds");
        rec.dependency(Pass::Compute, Pass::Compute);
        k.record_morton(rec, s, n, b63, plan.lo, plan.scale);
        rec.timestamp(&mut s.timer, "morton_moments");
        rec.dependency(Pass::Compute, Pass::Compute);
        k.record_classes(rec, s, n, b63, plan.code_min, plan.classes.k);
        rec.dependency(Pass::Compute, Pass::Transfer);
        rec.copy(&s.result, 0, &s.readback, 0, OFF_HIST + 4 * plan.classes.k as u64);
        rec.timestamp_start(&mut s.timer);
        s.done.record(rec)?;
        s.pending = Some(Pending { n, plan: plan.clone() });
        Ok(())
    }

    /// The results of the run recorded into `slot`, once its command buffer has completed and the caller has seen
    /// it complete (its fence signalled). A run that has not completed gives [`GpuError::NotReady`] and stays
    /// pending; any other outcome frees the slot. Errors about the
    /// input (a frame whose own bounds overflow) are [`RunError::Input`].
    pub(crate) fn finish(&mut self, slot: usize) -> std::result::Result<GpuCharacterization, RunError> {
        let s = self.slot(slot)?;
        if s.pending.is_some() {
            s.done.check(&format!("characterization slot {slot}"))?;
        }
        let timings = s.timer.try_read()?;
        let Some(Pending { n, plan }) = s.pending.take() else {
            return Err(GpuError::Buffer(format!("characterization slot {slot} has no recorded run")).into());
        };
        let bounds = bounds_read_back(&s.readback, OFF_BOUNDS)?;
        if bounds.is_empty() || !bounds.lo().iter().chain(&bounds.hi()).all(|c| c.is_finite()) {
            return Err(InputError::Overflow { lo: bounds.lo(), hi: bounds.hi() }.into());
        }
        let sums = read_sums(&s.readback, n)?;
        let (chi, hist) = read_histogram(&s.readback, plan.classes.k)?;
        Ok(assemble(n, bounds.lo(), bounds.hi(), sums, plan.classes.clone(), chi, hist, None, timings, Some(plan)))
    }

    /// Characterizes the geometry on the device in the staged mode (see the module docs): every `stride`-th
    /// triangle, `bits` Morton codes; `plan` turns the exact code sums into the class count and thresholds (see
    /// [`crate::characterize`]). With `read_back`, the codes and classes are copied to the host too. Uses slot 0.
    pub(crate) fn run(
        &mut self,
        view: &GeometryView<'_>,
        bits: MortonBits,
        stride: u64,
        plan: &dyn Fn(&CodeSums) -> std::result::Result<ClassPlan, String>,
        read_back: bool,
    ) -> std::result::Result<GpuCharacterization, RunError> {
        let stride = stride.max(1);
        let n = sample_count(view, stride)?;
        let b63 = usize::from(bits == MortonBits::Bits63);
        let ctx = self.ctx.clone();
        let s = slot_of(&mut self.slots, 0)?;
        self.k.run_staged(&ctx, s, view, n, stride, bits, b63, plan, read_back)
    }
}

impl Kernels {
    #[allow(clippy::too_many_arguments)]
    fn run_staged(
        &self,
        ctx: &Context,
        s: &mut Slot,
        view: &GeometryView<'_>,
        n: u64,
        stride: u64,
        bits: MortonBits,
        b63: usize,
        plan: &dyn Fn(&CodeSums) -> std::result::Result<ClassPlan, String>,
        read_back: bool,
    ) -> std::result::Result<GpuCharacterization, RunError> {
        if s.pending.is_some() {
            return Err(GpuError::Buffer("characterization slot 0 still holds an unfinished run".into()).into());
        }
        s.scratch(ctx, n)?;

        // Pass 1: keys and bounds.
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut s.timer);
            self.record_fills(rec, s);
            rec.timestamp_start(&mut s.timer);
            self.record_keys(rec, s, view, n, stride);
            rec.timestamp(&mut s.timer, "keys_bounds");
            rec.dependency(Pass::Compute, Pass::Transfer);
            rec.copy(&s.result, OFF_BOUNDS, &s.readback, OFF_BOUNDS, 4 * BOUNDS_WORDS as u64);
            rec.host_read_barrier();
            Ok(())
        })?;
        let q = Quantizer::new(&bounds_read_back(&s.readback, OFF_BOUNDS)?, bits).map_err(InputError::from)?;
        let (lo, hi, scale) = (q.lo(), q.hi(), q.scale());

        // Pass 2: codes, their range and exact power sums.
        ctx.submit_and_wait(|rec| {
            rec.timestamp_start(&mut s.timer);
            self.record_morton(rec, s, n, b63, lo, scale);
            rec.timestamp(&mut s.timer, "morton_moments");
            rec.dependency(Pass::Compute, Pass::Transfer);
            rec.copy(&s.result, OFF_MORTON, &s.readback, OFF_MORTON, 8 * MOMENTS_WORDS as u64);
            rec.host_read_barrier();
            Ok(())
        })?;
        let sums = read_sums(&s.readback, n)?;
        let class_plan = plan(&sums).map_err(InputError::Plan)?;
        self.check_plan(&class_plan)?;
        let k = class_plan.k;
        s.thresholds.write(0, &class_plan.thresholds)?;

        // Pass 3: classes, histogram, chi-square numerator.
        ctx.submit_and_wait(|rec| {
            rec.timestamp_start(&mut s.timer);
            self.record_classes(rec, s, n, b63, sums.code_min, k);
            rec.dependency(Pass::Compute, Pass::Transfer);
            rec.copy(&s.result, OFF_CHI, &s.readback, OFF_CHI, 8 * CHI_WORDS);
            rec.copy(&s.result, OFF_HIST, &s.readback, OFF_HIST, 4 * k as u64);
            rec.host_read_barrier();
            Ok(())
        })?;
        let (chi, hist) = read_histogram(&s.readback, k)?;
        let timings = s.timer.read()?;
        let per_triangle = match (read_back, &s.scratch) {
            (true, Some(scratch)) => {
                let codes: Vec<u64> = if b63 == 1 {
                    ctx.read_buffer(&scratch.codes, 0, n as usize)?
                } else {
                    ctx.read_buffer::<u32>(&scratch.codes, 0, n as usize)?.into_iter().map(u64::from).collect()
                };
                Some((codes, ctx.read_buffer(&scratch.classes, 0, n as usize)?))
            }
            _ => None,
        };
        Ok(assemble(n, lo, hi, sums, class_plan, chi, hist, per_triangle, timings, None))
    }
}

/// The moment pass's results in a readback buffer.
fn read_sums(readback: &Buffer, n: u64) -> Result<CodeSums> {
    let m: Vec<u64> = readback.read(OFF_MORTON, MOMENTS_WORDS)?;
    let l = MOMENTS_LIMBS as usize;
    let limbs = [
        m[l..l + LIMBS[0]].to_vec(),
        m[l + LIMBS[0]..l + LIMBS[0] + LIMBS[1]].to_vec(),
        m[l + LIMBS[0] + LIMBS[1]..l + NLIMBS].to_vec(),
    ];
    Ok(CodeSums { n, code_min: m[MOMENTS_CODE_MIN as usize], code_max: m[MOMENTS_CODE_MAX as usize], limbs })
}

/// The chi-square words and the `k`-entry histogram in a readback buffer.
fn read_histogram(readback: &Buffer, k: u32) -> Result<(Vec<u64>, Vec<u32>)> {
    Ok((readback.read(OFF_CHI, CHI_WORDS as usize)?, readback.read(OFF_HIST, k as usize)?))
}

#[allow(clippy::too_many_arguments)]
fn assemble(
    n: u64,
    lo: [f32; 3],
    hi: [f32; 3],
    sums: CodeSums,
    plan: ClassPlan,
    chi: Vec<u64>,
    hist: Vec<u32>,
    per_triangle: Option<(Vec<u64>, Vec<u32>)>,
    timings: Vec<(String, f64)>,
    plan_used: Option<PassPlan>,
) -> GpuCharacterization {
    GpuCharacterization {
        n,
        lo,
        hi,
        sums,
        plan,
        histogram: hist.into_iter().map(u64::from).collect(),
        chi_numerator: (chi[CHI_T_HI as usize] as u128) << 64 | chi[CHI_T_LO as usize] as u128,
        empty_classes: chi[CHI_EMPTY as usize] as u32,
        concentrated_classes: chi[CHI_CONCENTRATED as usize] as u32,
        concentrated_triangles: chi[CHI_CONCENTRATED_TRIANGLES as usize],
        plan_used,
        per_triangle,
        timings,
    }
}
