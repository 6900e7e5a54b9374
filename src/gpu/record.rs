use super::context::Inner;
use super::shaders::PushConstants;
use super::{vk_check, Buffer, Context, Kernel, Result};
use ash::vk;
use std::sync::Arc;

/// The kind of work on either side of a dependency ([`Recorder::dependency`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pass {
    /// Compute-shader dispatches (writes: `SHADER_WRITE`; reads: `SHADER_READ | SHADER_WRITE`, since kernels also
    /// update in place and use atomics).
    Compute,
    /// Transfers: fills and copies (writes: `TRANSFER_WRITE`; reads: `TRANSFER_READ | TRANSFER_WRITE`).
    Transfer,
}

impl Pass {
    fn stage(self) -> vk::PipelineStageFlags {
        match self {
            Pass::Compute => vk::PipelineStageFlags::COMPUTE_SHADER,
            Pass::Transfer => vk::PipelineStageFlags::TRANSFER,
        }
    }
    fn writes(self) -> vk::AccessFlags {
        match self {
            Pass::Compute => vk::AccessFlags::SHADER_WRITE,
            Pass::Transfer => vk::AccessFlags::TRANSFER_WRITE,
        }
    }
    fn accesses(self) -> vk::AccessFlags {
        match self {
            Pass::Compute => vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE,
            Pass::Transfer => vk::AccessFlags::TRANSFER_READ | vk::AccessFlags::TRANSFER_WRITE,
        }
    }
}

/// Records the engine's passes into a command buffer: one the caller owns ([`Recorder::new`], `unsafe`) or one of
/// [`Context::submit_and_wait`].
///
/// # The unsafe contract
///
/// Recording is where memory safety is decided, so it is where `unsafe` sits: wrapping a raw command buffer
/// ([`Recorder::new`]) and dispatching a kernel with raw device addresses (`Recorder::dispatch`) are `unsafe`;
/// the crate's operations (characterization, features, BVH builds, refit, sort, bounds) record through a
/// `Recorder` from safe methods, because they build their push constants from buffers and views whose ranges they
/// checked. Whoever made the recorder keeps every buffer used alive until the command buffer completes.
///
/// Synchronization is explicit: [`Recorder::dependency`] orders one kind of work before another (compute or
/// transfer, naming only those stages and accesses), [`Recorder::barrier`] is the full compute-and-transfer
/// barrier, and each multi-pass operation documents its first and last access to every buffer it touches.
pub struct Recorder<'a> {
    ctx: &'a Context,
    cmd: vk::CommandBuffer,
}

impl<'a> Recorder<'a> {
    /// Wraps a command buffer that the caller owns.
    ///
    /// # Safety
    ///
    /// - `cmd` is in the recording state, was allocated from a pool of a queue family with compute support on the
    ///   context's device, and is externally synchronized (no other thread records into it or its pool while the
    ///   recorder lives).
    /// - The caller submits it, and keeps every buffer, kernel, timer and view recorded into it alive (and the
    ///   buffers' memory bound) until the command buffer has completed; it does not reset or free the command
    ///   buffer while the device may still execute it.
    pub unsafe fn new(ctx: &'a Context, cmd: vk::CommandBuffer) -> Self {
        Recorder { ctx, cmd }
    }

    /// The command buffer.
    pub fn command_buffer(&self) -> vk::CommandBuffer {
        self.cmd
    }

    /// The context.
    pub(crate) fn context(&self) -> &'a Context {
        self.ctx
    }

    fn dev(&self) -> &ash::Device {
        &self.ctx.inner.device
    }

    /// Dispatches `groups` workgroups of `kernel` (x only; the engine's kernels loop over tiles, so callers clamp
    /// `groups` with [`Recorder::groups_for`]).
    ///
    /// # Safety
    ///
    /// Every device address in `push` points into a live buffer of this device with room for everything the
    /// kernel reads and writes for the counts in `push` (each kernel's GLSL source documents its arrays), and the
    /// buffers stay alive until the command buffer completes.
    pub(crate) unsafe fn dispatch<P: PushConstants>(&mut self, kernel: &Kernel<P>, push: &P, groups: u32) {
        let dev = self.dev();
        // SAFETY: recording command buffer; pipeline and layout of this device; push size checked at creation.
        unsafe {
            dev.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, kernel.pipeline);
            let size = kernel.shader().push_constant_size as usize;
            if size > 0 {
                let bytes = &bytemuck::bytes_of(push)[..size];
                dev.cmd_push_constants(self.cmd, kernel.layout, vk::ShaderStageFlags::COMPUTE, 0, bytes);
            }
            dev.cmd_dispatch(self.cmd, groups.max(1), 1, 1);
        }
    }

    /// Workgroups to dispatch for `items` items at `per_group` items per workgroup, clamped to the device's
    /// `maxComputeWorkGroupCount[0]` (kernels loop over the remaining tiles).
    pub(crate) fn groups_for(&self, items: u64, per_group: u64) -> u32 {
        let needed = items.div_ceil(per_group.max(1)).max(1);
        needed.min(self.ctx.caps().max_workgroup_count[0] as u64) as u32
    }

    /// Orders every earlier `src` work before every later `dst` work and makes `src`'s writes visible to `dst`'s
    /// accesses (a global memory barrier naming only those stages and accesses).
    pub fn dependency(&mut self, src: Pass, dst: Pass) {
        let mb = [vk::MemoryBarrier::default().src_access_mask(src.writes()).dst_access_mask(dst.accesses())];
        // SAFETY: recording command buffer.
        unsafe {
            self.dev().cmd_pipeline_barrier(
                self.cmd,
                src.stage(),
                dst.stage(),
                vk::DependencyFlags::empty(),
                &mb,
                &[],
                &[],
            )
        };
    }

    /// Full compute/transfer memory barrier: every earlier shader or transfer write is visible to every later
    /// shader or transfer access.
    pub fn barrier(&mut self) {
        let mb = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(
                vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::SHADER_WRITE
                    | vk::AccessFlags::TRANSFER_READ
                    | vk::AccessFlags::TRANSFER_WRITE,
            )];
        let stages = vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER;
        // SAFETY: recording command buffer.
        unsafe {
            self.dev().cmd_pipeline_barrier(self.cmd, stages, stages, vk::DependencyFlags::empty(), &mb, &[], &[])
        };
    }

    /// Makes earlier shader and transfer writes visible to the host (after the submission's fence).
    pub fn host_read_barrier(&mut self) {
        let mb = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::HOST_READ)];
        // SAFETY: recording command buffer.
        unsafe {
            self.dev().cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::HOST,
                vk::DependencyFlags::empty(),
                &mb,
                &[],
                &[],
            )
        };
    }

    /// Fills `bytes` bytes (a multiple of 4, or `None` for the rest) of `buffer` from `offset` with `value`.
    pub fn fill(&mut self, buffer: &Buffer, offset: u64, bytes: Option<u64>, value: u32) {
        let size = bytes.unwrap_or(vk::WHOLE_SIZE);
        // SAFETY: recording command buffer; buffer has TRANSFER_DST usage.
        unsafe { self.dev().cmd_fill_buffer(self.cmd, buffer.handle(), offset, size, value) };
    }

    /// Copies `bytes` bytes from `src` at `src_offset` to `dst` at `dst_offset`.
    pub fn copy(&mut self, src: &Buffer, src_offset: u64, dst: &Buffer, dst_offset: u64, bytes: u64) {
        if bytes == 0 {
            return;
        }
        let region = [vk::BufferCopy { src_offset, dst_offset, size: bytes }];
        // SAFETY: recording command buffer; buffers with transfer usage; caller keeps ranges inside the buffers.
        unsafe { self.dev().cmd_copy_buffer(self.cmd, src.handle(), dst.handle(), &region) };
    }

    /// Resets `timer` (must be recorded before its first [`Recorder::timestamp`] in this command buffer).
    pub fn reset_timer(&mut self, timer: &mut Timer) {
        timer.names.clear();
        // SAFETY: recording command buffer; query pool of this device.
        unsafe { self.dev().cmd_reset_query_pool(self.cmd, timer.pool, 0, timer.capacity) };
    }

    /// Writes a timestamp named `name` after all earlier work completes: the end of pass `name`, timed from the
    /// timestamp before it (see [`Timer::read`]). Timestamps past the timer's capacity are dropped.
    pub fn timestamp(&mut self, timer: &mut Timer, name: &str) {
        self.write_timestamp(timer, Some(name.to_string()));
    }

    /// Writes an unnamed timestamp after all earlier work completes: it only starts the next pass (work between the
    /// timestamp before and this one, such as fills and barriers, is not reported by [`Timer::read`]).
    pub fn timestamp_start(&mut self, timer: &mut Timer) {
        self.write_timestamp(timer, None);
    }

    fn write_timestamp(&mut self, timer: &mut Timer, name: Option<String>) {
        if timer.names.len() as u32 >= timer.capacity {
            return;
        }
        let q = timer.names.len() as u32;
        timer.names.push(name);
        // SAFETY: recording command buffer; query index inside the pool, reset earlier in this command buffer.
        unsafe { self.dev().cmd_write_timestamp(self.cmd, vk::PipelineStageFlags::ALL_COMMANDS, timer.pool, q) };
    }
}

/// A pool of timestamp queries: GPU time of each pass.
pub struct Timer {
    ctx: Arc<Inner>,
    pool: vk::QueryPool,
    capacity: u32,
    names: Vec<Option<String>>,
}

impl Timer {
    /// A timer with room for `capacity` timestamps.
    pub fn new(ctx: &Context, capacity: u32) -> Result<Self> {
        let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(capacity);
        // SAFETY: valid device.
        let pool = vk_check("vkCreateQueryPool", unsafe { ctx.device().create_query_pool(&info, ctx.inner.alloc()) })?;
        Ok(Timer { ctx: ctx.inner.clone(), pool, capacity, names: Vec::new() })
    }

    /// After the command buffer completed: `(name, milliseconds since the previous timestamp)` for every named
    /// timestamp but the first ([`Recorder::timestamp_start`] ones have no name). Waits for the queries if they
    /// are not available yet (callers read after waiting for the submission).
    pub fn read(&self) -> Result<Vec<(String, f64)>> {
        self.read_with(vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT)
    }

    /// [`Timer::read`] without waiting: [`GpuError::Vk`](super::GpuError::Vk) with `VK_NOT_READY` while any
    /// timestamp is not yet available (the command buffer has not completed).
    pub fn try_read(&self) -> Result<Vec<(String, f64)>> {
        self.read_with(vk::QueryResultFlags::TYPE_64)
    }

    fn read_with(&self, flags: vk::QueryResultFlags) -> Result<Vec<(String, f64)>> {
        let n = self.names.len();
        if n == 0 {
            return Ok(Vec::new());
        }
        let mut ticks = vec![0u64; n];
        // SAFETY: queries reset and written by a recorded command buffer; without WAIT an unavailable query gives
        // VK_NOT_READY and writes nothing we use.
        vk_check("vkGetQueryPoolResults", unsafe {
            self.ctx.device.get_query_pool_results(self.pool, 0, &mut ticks, flags)
        })?;
        let bits = self.ctx.caps.timestamp_valid_bits;
        let mask = if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 };
        let period = self.ctx.caps.timestamp_period as f64;
        Ok((1..n)
            .filter_map(|i| {
                let dt = (ticks[i] & mask).wrapping_sub(ticks[i - 1] & mask) & mask;
                Some((self.names[i].clone()?, dt as f64 * period * 1e-6))
            })
            .collect())
    }
}

impl std::fmt::Debug for Timer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Timer").field("capacity", &self.capacity).field("written", &self.names.len()).finish()
    }
}

impl Drop for Timer {
    fn drop(&mut self) {
        // SAFETY: query pool of this device, not in use (callers wait before dropping).
        unsafe { self.ctx.device.destroy_query_pool(self.pool, self.ctx.alloc()) };
    }
}

/// A word in host-visible memory that the device sets when a recorded operation's last command has run: how a
/// recorded operation's `finish` tells a completed run from one not yet submitted or still running (timestamp
/// availability cannot: a reused query pool still holds the previous run's results until the recorded reset runs).
/// Checking it is no substitute for synchronization: the caller reads results only after it has seen the command
/// buffer complete (its fence); the flag turns a forgotten wait into an error instead of stale numbers.
pub(crate) struct CompletionFlag {
    buffer: super::Buffer,
    serial: u32,
}

impl std::fmt::Debug for CompletionFlag {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CompletionFlag").field("serial", &self.serial).finish()
    }
}

impl CompletionFlag {
    /// A flag in a buffer of its own.
    pub(crate) fn new(ctx: &Context) -> Result<Self> {
        Ok(CompletionFlag { buffer: ctx.create_buffer("completion flag", 4, super::MemoryKind::Readback)?, serial: 0 })
    }

    /// Clears the flag on the host and records, at the current point of `rec`, the device's write of a new serial
    /// after every earlier compute and transfer command, made visible to the host. Record it last. The flag's
    /// previous run must have completed.
    pub(crate) fn record(&mut self, rec: &mut Recorder<'_>) -> Result<()> {
        self.serial = self.serial.wrapping_add(1).max(1);
        self.buffer.write(0, &[0u32])?;
        let mb = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::TRANSFER_WRITE)];
        // SAFETY: recording command buffer.
        unsafe {
            rec.dev().cmd_pipeline_barrier(
                rec.cmd,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &mb,
                &[],
                &[],
            )
        };
        rec.fill(&self.buffer, 0, Some(4), self.serial);
        rec.host_read_barrier();
        Ok(())
    }

    /// `Ok` once the device has written the serial of the last [`CompletionFlag::record`];
    /// [`GpuError::NotReady`](super::GpuError::NotReady) naming `what` before.
    pub(crate) fn check(&self, what: &str) -> Result<()> {
        let v: Vec<u32> = self.buffer.read(0, 1)?;
        if self.serial == 0 || v[0] != self.serial {
            return Err(super::GpuError::NotReady(what.to_string()));
        }
        Ok(())
    }
}
