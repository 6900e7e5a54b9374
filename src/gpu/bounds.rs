use crate::gpu::shaders::layout::{BOUNDS_HI, BOUNDS_LO, BOUNDS_WORDS};
use crate::gpu::{shaders, Buffer, Context, GpuError, Kernel, KernelDesc, MemoryKind, Pass, Recorder, Result};
use crate::keys::from_ordered_bits;

/// Items each invocation handles per tile by default.
const ITEMS: u32 = 8;

pub(crate) use crate::gpu::shaders::bounds::Push as BoundsPush;

/// Per-axis bounds of a point set on the GPU: subgroup min/max, shared-memory atomics across subgroups, one global
/// atomic per value per workgroup. Exact (min and max in IEEE total order), for any subgroup size and any count.
pub struct PointBounds {
    kernel: Kernel<BoundsPush>,
    items: u32,
}

impl PointBounds {
    /// Builds the pipeline.
    pub fn new(ctx: &Context) -> Result<Self> {
        Self::with_tuning(ctx, None, ITEMS)
    }

    /// Builds the pipeline with a given workgroup size (`None`: the device's default) and items per invocation.
    pub(crate) fn with_tuning(ctx: &Context, workgroup_size: Option<u32>, items: u32) -> Result<Self> {
        let items = items.max(1);
        let mut desc = KernelDesc::new(&shaders::bounds::INFO).constant("ITEMS", items);
        desc.workgroup_size = workgroup_size;
        Ok(PointBounds { kernel: Kernel::new(ctx, &desc)?, items })
    }

    /// Records the reduction of `count` points at `points` into the 24-byte `result` at `result_offset`.
    ///
    /// Begins with a fill of the result (a transfer write) and a barrier; ends with the shader's atomic writes to the
    /// result, not followed by a barrier: the caller inserts one before reading it.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        points: &Buffer,
        count: u64,
        result: &Buffer,
        result_offset: u64,
    ) -> Result<()> {
        if points.size() < count * 12 || result.size() < result_offset + 24 {
            return Err(GpuError::Buffer(format!("bounds: {count} points need {} bytes, result 24", count * 12)));
        }
        rec.fill(result, result_offset + 4 * BOUNDS_LO as u64, Some(12), u32::MAX);
        rec.fill(result, result_offset + 4 * BOUNDS_HI as u64, Some(12), 0);
        rec.dependency(Pass::Transfer, Pass::Compute);
        let wg = self.kernel.workgroup_size() as u64;
        let groups = rec.groups_for(count, wg * self.items as u64);
        let push = BoundsPush { points: points.address(), result: result.address() + result_offset, count };
        // SAFETY: `points` holds `count` points (checked above) and `result` six words.
        unsafe { rec.dispatch(&self.kernel, &push, groups) };
        Ok(())
    }

    /// Bounds of `count` points in `points` (submits and waits). `None` when `count == 0`.
    pub fn run(&self, ctx: &Context, points: &Buffer, count: u64) -> Result<Option<([f32; 3], [f32; 3])>> {
        if count == 0 {
            return Ok(None);
        }
        let result = ctx.create_buffer("bounds result", 24, MemoryKind::DeviceLocal)?;
        let readback = ctx.create_buffer("bounds readback", 24, MemoryKind::Readback)?;
        ctx.submit_and_wait(|rec| {
            self.record(rec, points, count, &result, 0)?;
            rec.dependency(Pass::Compute, Pass::Transfer);
            rec.copy(&result, 0, &readback, 0, 24);
            rec.host_read_barrier();
            Ok(())
        })?;
        let u: Vec<u32> = readback.read(0, BOUNDS_WORDS as usize)?;
        let corner = |at: u32| [0, 1, 2].map(|a| from_ordered_bits(u[at as usize + a]));
        Ok(Some((corner(BOUNDS_LO), corner(BOUNDS_HI))))
    }
}
