//! The driver's own acceleration structures (`VK_KHR_acceleration_structure`) as candidates: a bottom-level
//! structure over an engine's geometry view with one of the build-flag choices an engine faces, and a top-level
//! structure of one instance over it, built from device buffers and recorded into the caller's command buffer.
//!
//! # Candidates
//!
//! | name | build flags | per frame of an animation |
//! |---|---|---|
//! | `rt_fast_trace` | `PREFER_FAST_TRACE` | rebuild |
//! | `rt_fast_build` | `PREFER_FAST_BUILD` | rebuild |
//! | `rt_update` | `PREFER_FAST_TRACE \| ALLOW_UPDATE` | update (`MODE_UPDATE`, in place) |
//! | `rt_fast_trace_compact` | `PREFER_FAST_TRACE \| ALLOW_COMPACTION` | rebuild, then compact |
//!
//! Drivers choose different builders behind these flags (Mesa's shared builder, for one, runs LBVH for fast-build
//! and updatable structures and PLOC otherwise), which is why they are measured, not assumed.
//!
//! # Building
//!
//! Sizes come from `vkGetAccelerationStructureBuildSizesKHR`; the structure and scratch buffers are the
//! context's device-local buffers (scratch aligned to `minAccelerationStructureScratchOffsetAlignment`). The
//! geometry is read straight from the view (`R32G32B32_SFLOAT` positions at the view's stride, 16- or 32-bit
//! indices or none, the base vertex as `firstVertex`, every triangle opaque); unlike the project's kernels the
//! driver does not clamp an index past the view's vertices, so every index must be valid (the meshes this crate
//! loads are checked). The top level holds one instance with the identity transform.
//!
//! [`DriverBuilder::record_build`] records both builds and their barriers into the caller's command buffer,
//! between timestamps; [`DriverBuilder::build`] submits and waits and, for `rt_fast_trace_compact`, then queries
//! the compacted size, copies into a structure of that size (a second submission: the size is known only on the
//! host) and rebuilds the top level over it. [`DriverBuilder::update`] refits an `rt_update` structure to new
//! vertex positions (same topology).
//!
//! The driver exposes no box or triangle test counts: a [`DriverStructure`] reports its build time (GPU
//! timestamps), its memory and its compacted size.
//!
//! Needs [`crate::gpu::DeviceCaps::ray_query`] (lavapipe from Mesa 24.1 on, current NVIDIA and AMD drivers); an
//! owned context enables it where supported, an engine sets [`crate::gpu::RawDevice::ray_query_enabled`].

use crate::accel::device_trace::{TraceHit, TraceRay};
use crate::gpu::{shaders, Buffer, Context, GeometryView, GpuError, IndexType, Kernel, KernelDesc, MemoryKind};
use crate::gpu::{Recorder, Timer};
use ash::vk;

pub(crate) use crate::gpu::shaders::trace_rq::Push as TraceRqPush;

/// One of the driver structures' build-flag choices (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DriverFlags {
    /// `PREFER_FAST_TRACE`, rebuilt per frame.
    FastTrace,
    /// `PREFER_FAST_BUILD`, rebuilt per frame.
    FastBuild,
    /// `PREFER_FAST_TRACE | ALLOW_UPDATE`, updated per frame.
    Update,
    /// `PREFER_FAST_TRACE | ALLOW_COMPACTION`, compacted after each build.
    FastTraceCompact,
}

impl DriverFlags {
    /// Every choice.
    pub const ALL: [DriverFlags; 4] =
        [DriverFlags::FastTrace, DriverFlags::FastBuild, DriverFlags::Update, DriverFlags::FastTraceCompact];

    /// The candidate's name (`rt_fast_trace`, `rt_fast_build`, `rt_update`, `rt_fast_trace_compact`).
    pub fn name(self) -> &'static str {
        match self {
            DriverFlags::FastTrace => "rt_fast_trace",
            DriverFlags::FastBuild => "rt_fast_build",
            DriverFlags::Update => "rt_update",
            DriverFlags::FastTraceCompact => "rt_fast_trace_compact",
        }
    }

    /// The choice named `name` (see [`DriverFlags::name`]).
    pub fn parse(name: &str) -> Option<Self> {
        DriverFlags::ALL.into_iter().find(|f| f.name() == name)
    }

    /// The Vulkan build flags.
    pub fn build_flags(self) -> vk::BuildAccelerationStructureFlagsKHR {
        use vk::BuildAccelerationStructureFlagsKHR as F;
        match self {
            DriverFlags::FastTrace => F::PREFER_FAST_TRACE,
            DriverFlags::FastBuild => F::PREFER_FAST_BUILD,
            DriverFlags::Update => F::PREFER_FAST_TRACE | F::ALLOW_UPDATE,
            DriverFlags::FastTraceCompact => F::PREFER_FAST_TRACE | F::ALLOW_COMPACTION,
        }
    }

    /// Whether the structure is compacted after its build.
    pub fn compacts(self) -> bool {
        self == DriverFlags::FastTraceCompact
    }
}

/// A driver acceleration structure object and the buffer that holds it.
struct Handle {
    ctx: Context,
    handle: vk::AccelerationStructureKHR,
    buffer: Buffer,
    address: u64,
}

impl Handle {
    fn new(ctx: &Context, name: &str, ty: vk::AccelerationStructureTypeKHR, size: u64) -> Result<Self, GpuError> {
        let loader = loader(ctx)?;
        let buffer = ctx.create_buffer(name, size, MemoryKind::DeviceLocal)?;
        let info = vk::AccelerationStructureCreateInfoKHR::default().buffer(buffer.handle()).size(size).ty(ty);
        // SAFETY: the buffer is alive, bound, has ACCELERATION_STRUCTURE_STORAGE usage (every buffer of a context
        // with ray queries) and holds `size` bytes from offset 0 (aligned to 256 as every buffer's start).
        let handle = crate::gpu::vk_check("vkCreateAccelerationStructureKHR", unsafe {
            loader.create_acceleration_structure(&info, ctx.inner.alloc())
        })?;
        let info = vk::AccelerationStructureDeviceAddressInfoKHR::default().acceleration_structure(handle);
        // SAFETY: a live structure of this device.
        let address = unsafe { loader.get_acceleration_structure_device_address(&info) };
        Ok(Handle { ctx: ctx.clone(), handle, buffer, address })
    }
}

impl Drop for Handle {
    fn drop(&mut self) {
        if let Some(loader) = self.ctx.inner.acceleration.as_ref() {
            // SAFETY: created by this loader's device; the owner keeps it alive until work that uses it completed.
            unsafe { loader.destroy_acceleration_structure(self.handle, self.ctx.inner.alloc()) };
        }
    }
}

fn loader(ctx: &Context) -> Result<&ash::khr::acceleration_structure::Device, GpuError> {
    ctx.inner.acceleration.as_ref().ok_or_else(|| GpuError::Unsupported {
        name: ctx.caps().name.clone(),
        missing: vec!["VK_KHR_acceleration_structure and VK_KHR_ray_query (accelerationStructure, rayQuery)".into()],
    })
}

/// A bottom-level driver structure over a geometry view and the one-instance top level over it.
pub struct DriverStructure {
    flags: DriverFlags,
    triangles: u64,
    blas: Handle,
    tlas: Handle,
    instances: Buffer,
    scratch: Buffer,
    blas_bytes: u64,
    compacted_bytes: Option<u64>,
    timings: Vec<(String, f64)>,
    pending: Option<Timer>,
    /// Timers of earlier recorded updates whose command buffers may still run (a frame updates the structure
    /// while the frame before is in flight): kept until [`DriverStructure::finish`] has seen a later one complete.
    retired: Vec<Timer>,
}

impl std::fmt::Debug for DriverStructure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DriverStructure")
            .field("flags", &self.flags.name())
            .field("triangles", &self.triangles)
            .field("blas_bytes", &self.blas_bytes)
            .field("compacted_bytes", &self.compacted_bytes)
            .finish()
    }
}

impl DriverStructure {
    /// The build-flag choice.
    pub fn flags(&self) -> DriverFlags {
        self.flags
    }
    /// Triangles of the bottom level.
    pub fn triangle_count(&self) -> u64 {
        self.triangles
    }
    /// Device address of the top-level structure (what a ray query traces).
    pub fn tlas_address(&self) -> u64 {
        self.tlas.address
    }
    /// The top-level structure's handle (for the engine's descriptor sets).
    pub fn tlas(&self) -> vk::AccelerationStructureKHR {
        self.tlas.handle
    }
    /// Bytes of the bottom level as built (before any compaction: `accelerationStructureSize`).
    pub fn built_bytes(&self) -> u64 {
        self.blas_bytes
    }
    /// Bytes of the compacted bottom level (`rt_fast_trace_compact` after [`DriverBuilder::build`]).
    pub fn compacted_bytes(&self) -> Option<u64> {
        self.compacted_bytes
    }
    /// Device bytes held: both levels, the instance and the scratch kept for updates.
    pub fn memory_bytes(&self) -> u64 {
        self.blas.buffer.size() + self.tlas.buffer.size() + self.instances.size() + self.scratch.size()
    }
    /// `(pass, GPU milliseconds)` of the last build or update (`blas`, `tlas`, `compact`, `blas_update`).
    pub fn timings(&self) -> &[(String, f64)] {
        &self.timings
    }
    /// GPU milliseconds of the last build or update, all passes.
    pub fn gpu_ms(&self) -> f64 {
        self.timings.iter().map(|(_, ms)| ms).sum()
    }
    /// Reads the timestamps of a recorded build once its command buffer has completed.
    ///
    /// # Errors
    ///
    /// [`GpuError::Vk`] with `VK_NOT_READY` while the command buffer has not completed.
    pub fn finish(&mut self) -> Result<(), GpuError> {
        if let Some(timer) = &self.pending {
            self.timings = timer.try_read()?;
            self.pending = None;
            // Submitted earlier on the same queue, so completed too.
            self.retired.clear();
        }
        Ok(())
    }
}

/// Barycentric distance from an edge within which a hit may be a miss for another intersection test (see
/// [`hit_agrees`]). Measured on lavapipe: the driver hits the Stanford bunny's triangles where the project's
/// (non-watertight) test passes through the crack at barycentric distances up to `1.2e-5` from the edge.
pub const EDGE_TOLERANCE: f32 = 1e-4;

/// Whether a driver hit agrees with the CPU reference's closest hit (`None` for a miss): both miss, or the same
/// triangle, or the same `t` within `1e-4 t + 1e-6 extent` (`extent`: the scene's largest extent), which covers a
/// hit on the neighbour across a shared edge or on a coincident triangle, where the driver's intersection test and
/// its tie rule differ from the project's; or the nearer hit (or the only one) lies within [`EDGE_TOLERANCE`] of
/// its triangle's edge (smallest barycentric coordinate `min(u, v, 1 - u - v)`): a ray through a shared edge or
/// vertex that the other test sent through the crack between the two triangles, to whatever lies behind (the
/// driver's test may be watertight, the project's is not). Any-hit rays agree when both are occluded or neither is.
pub fn hit_agrees(want: Option<crate::geom::Hit>, got: Option<crate::geom::Hit>, extent: f32) -> bool {
    let at_edge = |h: crate::geom::Hit| h.u.min(h.v).min(1.0 - h.u - h.v) <= EDGE_TOLERANCE;
    match (want, got) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            a.triangle == b.triangle
                || (a.t - b.t).abs() <= 1e-4 * a.t.abs() + 1e-6 * extent
                || at_edge(if a.t < b.t { a } else { b })
        }
        (Some(h), None) | (None, Some(h)) => at_edge(h),
    }
}

/// Builds driver structures on a context with [`crate::gpu::DeviceCaps::ray_query`], and traces them with ray
/// queries (`glsl/trace_rq.comp`).
pub struct DriverBuilder {
    ctx: Context,
    query: Kernel<TraceRqPush>,
}

/// Hits of a ray-query trace.
#[derive(Clone, Debug)]
pub struct DriverTrace {
    /// One per ray, in ray order (no box or triangle counts: the driver exposes none).
    pub hits: Vec<TraceHit>,
    /// GPU milliseconds of the dispatch (timestamps).
    pub gpu_ms: f64,
}

impl std::fmt::Debug for DriverBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DriverBuilder").field("device", &self.ctx.caps().name).finish()
    }
}

/// The triangle geometry of a view, as the driver reads it. The view's base vertex is folded into the vertex
/// address (and the build ranges' `firstVertex` is 0): Vulkan adds `firstVertex` to each index, which is the same,
/// but lavapipe (Mesa 25.0.7, measured) adds it twice, offsetting the vertex address by it as well, so a view with a
/// base vertex read the wrong vertices there.
fn triangles_of<'a>(view: &GeometryView<'_>) -> vk::AccelerationStructureGeometryKHR<'a> {
    let index_type = match view.index_type() {
        IndexType::None => vk::IndexType::NONE_KHR,
        IndexType::U16 => vk::IndexType::UINT16,
        IndexType::U32 => vk::IndexType::UINT32,
    };
    let (base, stride) = (u64::from(view.base_vertex()), u64::from(view.vertex_stride()));
    let triangles = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
        .vertex_format(vk::Format::R32G32B32_SFLOAT)
        .vertex_data(vk::DeviceOrHostAddressConstKHR { device_address: view.positions() + base * stride })
        .vertex_stride(stride)
        .max_vertex(view.vertex_count().saturating_sub(base + 1).min(u64::from(u32::MAX)) as u32)
        .index_type(index_type)
        .index_data(vk::DeviceOrHostAddressConstKHR {
            device_address: if index_type == vk::IndexType::NONE_KHR { 0 } else { view.indices() },
        });
    vk::AccelerationStructureGeometryKHR::default()
        .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
        .geometry(vk::AccelerationStructureGeometryDataKHR { triangles })
        .flags(vk::GeometryFlagsKHR::OPAQUE)
}

/// The one instance of the top level over the bottom level at `blas`: identity transform, mask 0xff, opaque.
fn instance_words(blas: u64) -> [u32; 16] {
    let mut w = [0u32; 16];
    for (r, c) in [(0usize, 0usize), (1, 1), (2, 2)] {
        w[r * 4 + c] = 1.0f32.to_bits();
    }
    w[12] = 0xff << 24;
    w[13] = vk::GeometryInstanceFlagsKHR::FORCE_OPAQUE.as_raw() << 24;
    w[14] = blas as u32;
    w[15] = (blas >> 32) as u32;
    w
}

/// The top level's one geometry: the instance array in `instances`.
fn instances_geometry<'a>(instances: &Buffer) -> vk::AccelerationStructureGeometryKHR<'a> {
    vk::AccelerationStructureGeometryKHR::default().geometry_type(vk::GeometryTypeKHR::INSTANCES).geometry(
        vk::AccelerationStructureGeometryDataKHR {
            instances: vk::AccelerationStructureGeometryInstancesDataKHR::default()
                .array_of_pointers(false)
                .data(vk::DeviceOrHostAddressConstKHR { device_address: instances.address() }),
        },
    )
}

/// The build of the one-instance top level over `geometry` (from [`instances_geometry`]) into `dst` (null: only
/// for the size query), with the scratch at `scratch`.
fn tlas_build<'a>(
    geometry: &'a [vk::AccelerationStructureGeometryKHR<'a>],
    dst: vk::AccelerationStructureKHR,
    scratch: u64,
) -> vk::AccelerationStructureBuildGeometryInfoKHR<'a> {
    vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL)
        .flags(vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE)
        .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
        .geometries(geometry)
        .dst_acceleration_structure(dst)
        .scratch_data(vk::DeviceOrHostAddressKHR { device_address: scratch })
}

/// Orders every earlier acceleration-structure build, compute-shader and transfer work before every later one and
/// makes their writes visible (the build inputs, the structures, the scratch).
fn barrier(rec: &mut Recorder<'_>) {
    let stages = vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR
        | vk::PipelineStageFlags::COMPUTE_SHADER
        | vk::PipelineStageFlags::TRANSFER;
    let mb = [vk::MemoryBarrier::default()
        .src_access_mask(
            vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR
                | vk::AccessFlags::SHADER_WRITE
                | vk::AccessFlags::TRANSFER_WRITE,
        )
        .dst_access_mask(
            vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR
                | vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR
                | vk::AccessFlags::SHADER_READ
                | vk::AccessFlags::SHADER_WRITE
                | vk::AccessFlags::TRANSFER_READ,
        )];
    // SAFETY: a command buffer in the recording state (the recorder's contract).
    unsafe {
        rec.context().device().cmd_pipeline_barrier(
            rec.command_buffer(),
            stages,
            stages,
            vk::DependencyFlags::empty(),
            &mb,
            &[],
            &[],
        )
    };
}

impl DriverBuilder {
    /// A builder on `ctx`.
    ///
    /// # Errors
    ///
    /// [`GpuError::Unsupported`] without [`crate::gpu::DeviceCaps::ray_query`].
    pub fn new(ctx: &Context) -> Result<Self, GpuError> {
        loader(ctx)?;
        let query = Kernel::new(ctx, &KernelDesc::new(&shaders::trace_rq::INFO))?;
        Ok(DriverBuilder { ctx: ctx.clone(), query })
    }

    /// Records ray queries of `count` rays at `rays` (TraceRay) against `s`, writing `count` TraceHit records to
    /// `hits`. Recording contract: the rays and the structure must be visible to compute-shader reads (the build's
    /// own closing barrier covers the structure); ends with the kernel's writes to `hits`.
    ///
    /// # Errors
    ///
    /// [`GpuError::Buffer`] when a buffer is too small for `count`.
    pub fn record_trace(
        &self,
        rec: &mut Recorder<'_>,
        s: &DriverStructure,
        rays: &Buffer,
        hits: &Buffer,
        count: u64,
        any_hit: bool,
    ) -> Result<(), GpuError> {
        if count == 0 {
            return Ok(());
        }
        let (rb, hb) = (std::mem::size_of::<TraceRay>() as u64, std::mem::size_of::<TraceHit>() as u64);
        if rays.size() < count * rb || hits.size() < count * hb {
            return Err(GpuError::Buffer(format!(
                "ray query: {count} rays need {} and {} bytes",
                count * rb,
                count * hb
            )));
        }
        let push = TraceRqPush {
            rays: rays.address(),
            hits: hits.address(),
            tlas: s.tlas.address,
            count,
            any_hit: u32::from(any_hit),
            pad: 0,
        };
        let wg = self.query.workgroup_size() as u64;
        // SAFETY: `count` rays and hits fit their buffers (checked); the structure is alive and built.
        unsafe { rec.dispatch(&self.query, &push, rec.groups_for(count, wg)) };
        Ok(())
    }

    /// Traces the `count` rays (TraceRay) at `rays` through `s` with ray queries (dispatches between timestamps,
    /// reads back; submits and waits).
    ///
    /// # Errors
    ///
    /// A device error, or a buffer too small.
    pub fn trace_buffer(
        &self,
        s: &DriverStructure,
        rays: &Buffer,
        count: u64,
        any_hit: bool,
    ) -> Result<DriverTrace, GpuError> {
        let ctx = &self.ctx;
        if count == 0 {
            return Ok(DriverTrace { hits: Vec::new(), gpu_ms: 0.0 });
        }
        let bytes = count * std::mem::size_of::<TraceHit>() as u64;
        let hits = ctx.create_buffer("ray query hits", bytes, MemoryKind::DeviceLocal)?;
        let mut timer = Timer::new(ctx, 2)?;
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut timer);
            rec.dependency(crate::gpu::Pass::Transfer, crate::gpu::Pass::Compute);
            rec.dependency(crate::gpu::Pass::Compute, crate::gpu::Pass::Compute);
            rec.timestamp_start(&mut timer);
            self.record_trace(rec, s, rays, &hits, count, any_hit)?;
            rec.timestamp(&mut timer, "ray_query");
            Ok(())
        })?;
        let gpu_ms = timer.read()?.iter().map(|(_, ms)| ms).sum();
        Ok(DriverTrace { hits: ctx.read_buffer(&hits, 0, count as usize)?, gpu_ms })
    }

    /// Traces `rays` through `s` with ray queries (uploads, dispatches between timestamps, reads back; submits and
    /// waits).
    ///
    /// # Errors
    ///
    /// A device error.
    pub fn trace(&self, s: &DriverStructure, rays: &[TraceRay], any_hit: bool) -> Result<DriverTrace, GpuError> {
        if rays.is_empty() {
            return Ok(DriverTrace { hits: Vec::new(), gpu_ms: 0.0 });
        }
        let ray_buf = self.ctx.upload("ray query rays", rays)?;
        self.trace_buffer(s, &ray_buf, rays.len() as u64, any_hit)
    }

    fn sizes(
        &self,
        info: &vk::AccelerationStructureBuildGeometryInfoKHR<'_>,
        count: u32,
    ) -> Result<vk::AccelerationStructureBuildSizesInfoKHR<'static>, GpuError> {
        let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
        // SAFETY: a valid build description with one geometry of `count` primitives.
        unsafe {
            loader(&self.ctx)?.get_acceleration_structure_build_sizes(
                vk::AccelerationStructureBuildTypeKHR::DEVICE,
                info,
                &[count],
                &mut sizes,
            )
        };
        Ok(sizes)
    }

    fn scratch_address(&self, scratch: &Buffer) -> u64 {
        let align = u64::from(self.ctx.caps().acceleration_scratch_alignment.max(1));
        scratch.address().next_multiple_of(align)
    }

    /// Records the builds of a structure over `view` with `flags` into `rec` (bottom level, then top level, each
    /// between timestamps, with the barriers between them); [`DriverStructure::finish`] reads the times once the
    /// command buffer has completed. `rt_fast_trace_compact` is built uncompacted here (compaction needs the
    /// compacted size on the host: [`DriverBuilder::build`]).
    ///
    /// Nothing is submitted or waited for (the instance record is written to host-visible memory).
    ///
    /// Recording contract: begins with a barrier that makes earlier compute and transfer writes (the geometry)
    /// visible to the build; ends with the top level's build and a barrier after it that makes it visible to
    /// compute shaders (ray queries). The structure and the view's buffers stay alive until the command buffer
    /// completes.
    ///
    /// # Errors
    ///
    /// [`GpuError::Buffer`] for a view without triangles or with more than `2^32 - 1`; a device error.
    pub fn record_build(
        &self,
        rec: &mut Recorder<'_>,
        view: &GeometryView<'_>,
        flags: DriverFlags,
    ) -> Result<DriverStructure, GpuError> {
        let ctx = &self.ctx;
        let loader = loader(ctx)?;
        let n = view.triangle_count();
        if n == 0 || n > u64::from(u32::MAX) {
            return Err(GpuError::Buffer(format!("driver structure: {n} triangles (1 to 2^32 - 1 are supported)")));
        }
        let geometry = [triangles_of(view)];
        let mut blas_info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
            .flags(flags.build_flags())
            .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
            .geometries(&geometry);
        let blas_sizes = self.sizes(&blas_info, n as u32)?;
        let blas = Handle::new(
            ctx,
            "driver blas",
            vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL,
            blas_sizes.acceleration_structure_size,
        )?;
        // The instance in host-visible memory, written directly: recording waits for nothing.
        let mut instances = ctx.create_buffer("driver instance", 64, MemoryKind::Upload)?;
        instances.write(0, &instance_words(blas.address))?;
        let inst_geometry = [instances_geometry(&instances)];
        let tlas_sizes = self.sizes(&tlas_build(&inst_geometry, vk::AccelerationStructureKHR::null(), 0), 1)?;
        let tlas = Handle::new(
            ctx,
            "driver tlas",
            vk::AccelerationStructureTypeKHR::TOP_LEVEL,
            tlas_sizes.acceleration_structure_size,
        )?;
        // One scratch for both builds (they are ordered by a barrier) and for later updates.
        let align = u64::from(ctx.caps().acceleration_scratch_alignment.max(1));
        let scratch_bytes =
            blas_sizes.build_scratch_size.max(blas_sizes.update_scratch_size).max(tlas_sizes.build_scratch_size)
                + align;
        let scratch = ctx.create_buffer("driver scratch", scratch_bytes, MemoryKind::DeviceLocal)?;
        let scratch_at = self.scratch_address(&scratch);
        let mut timer = Timer::new(ctx, 3)?;
        rec.reset_timer(&mut timer);
        barrier(rec);
        rec.timestamp_start(&mut timer);
        blas_info = blas_info
            .dst_acceleration_structure(blas.handle)
            .scratch_data(vk::DeviceOrHostAddressKHR { device_address: scratch_at });
        let blas_range = [vk::AccelerationStructureBuildRangeInfoKHR {
            primitive_count: n as u32,
            primitive_offset: 0,
            first_vertex: 0,
            transform_offset: 0,
        }];
        // SAFETY: every address points into a live buffer of this device large enough for the sizes the driver
        // reported for this geometry; the view's contract covers its vertices and indices.
        unsafe { loader.cmd_build_acceleration_structures(rec.command_buffer(), &[blas_info], &[&blas_range]) };
        rec.timestamp(&mut timer, "blas");
        barrier(rec);
        let tlas_info = tlas_build(&inst_geometry, tlas.handle, scratch_at);
        let tlas_range = [vk::AccelerationStructureBuildRangeInfoKHR { primitive_count: 1, ..Default::default() }];
        // SAFETY: as above; the instance refers to the bottom level built before the barrier.
        unsafe { loader.cmd_build_acceleration_structures(rec.command_buffer(), &[tlas_info], &[&tlas_range]) };
        rec.timestamp(&mut timer, "tlas");
        barrier(rec);
        Ok(DriverStructure {
            flags,
            triangles: n,
            blas,
            tlas,
            instances,
            scratch,
            blas_bytes: blas_sizes.acceleration_structure_size,
            compacted_bytes: None,
            timings: Vec::new(),
            pending: Some(timer),
            retired: Vec::new(),
        })
    }

    /// Builds a structure over `view` with `flags` (submits and waits); for `rt_fast_trace_compact` then compacts
    /// it (the compacted size queried, the bottom level copied into a structure of that size, the top level rebuilt
    /// over it), timed as `compact` and `tlas_compact`.
    ///
    /// # Errors
    ///
    /// Those of [`DriverBuilder::record_build`], or a device error.
    pub fn build(&self, view: &GeometryView<'_>, flags: DriverFlags) -> Result<DriverStructure, GpuError> {
        let ctx = &self.ctx;
        let mut s = ctx.submit_and_wait(|rec| self.record_build(rec, view, flags))?;
        s.finish()?;
        if flags.compacts() {
            self.compact(&mut s)?;
        }
        Ok(s)
    }

    fn compact(&self, s: &mut DriverStructure) -> Result<(), GpuError> {
        let ctx = &self.ctx;
        let loader = loader(ctx)?;
        let info = vk::QueryPoolCreateInfo::default()
            .query_type(vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR)
            .query_count(1);
        // SAFETY: a valid device.
        let pool = crate::gpu::vk_check("vkCreateQueryPool", unsafe {
            ctx.device().create_query_pool(&info, ctx.inner.alloc())
        })?;
        let result = (|| -> Result<(), GpuError> {
            ctx.submit_and_wait(|rec| {
                // SAFETY: recording command buffer; the pool has one query of the compacted-size type, reset here;
                // the structure was built with ALLOW_COMPACTION and is complete (previous submission).
                unsafe {
                    ctx.device().cmd_reset_query_pool(rec.command_buffer(), pool, 0, 1);
                    loader.cmd_write_acceleration_structures_properties(
                        rec.command_buffer(),
                        &[s.blas.handle],
                        vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR,
                        pool,
                        0,
                    );
                }
                Ok(())
            })?;
            let mut size = [0u64; 1];
            // SAFETY: the query was written by the completed submission.
            crate::gpu::vk_check("vkGetQueryPoolResults", unsafe {
                ctx.device().get_query_pool_results(
                    pool,
                    0,
                    &mut size,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
            })?;
            let compact =
                Handle::new(ctx, "driver blas compacted", vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL, size[0])?;
            let mut instances = ctx.create_buffer("driver instance", 64, MemoryKind::Upload)?;
            instances.write(0, &instance_words(compact.address))?;
            let inst_geometry = [instances_geometry(&instances)];
            let tlas_info = tlas_build(&inst_geometry, s.tlas.handle, self.scratch_address(&s.scratch));
            let mut timer = Timer::new(ctx, 3)?;
            ctx.submit_and_wait(|rec| {
                rec.reset_timer(&mut timer);
                rec.timestamp_start(&mut timer);
                let copy = vk::CopyAccelerationStructureInfoKHR::default()
                    .src(s.blas.handle)
                    .dst(compact.handle)
                    .mode(vk::CopyAccelerationStructureModeKHR::COMPACT);
                // SAFETY: source built with ALLOW_COMPACTION, destination of the queried compacted size.
                unsafe { loader.cmd_copy_acceleration_structure(rec.command_buffer(), &copy) };
                rec.timestamp(&mut timer, "compact");
                barrier(rec);
                let range = [vk::AccelerationStructureBuildRangeInfoKHR { primitive_count: 1, ..Default::default() }];
                // SAFETY: the top level is rebuilt over the compacted bottom level, with the kept scratch.
                unsafe { loader.cmd_build_acceleration_structures(rec.command_buffer(), &[tlas_info], &[&range]) };
                rec.timestamp(&mut timer, "tlas_compact");
                barrier(rec);
                Ok(())
            })?;
            s.timings.extend(timer.read()?);
            s.blas = compact;
            s.instances = instances;
            s.compacted_bytes = Some(size[0]);
            Ok(())
        })();
        // SAFETY: every submission that used the pool has completed.
        unsafe { ctx.device().destroy_query_pool(pool, ctx.inner.alloc()) };
        result
    }

    /// Records an update of `s` (an `rt_update` structure) to the vertex positions of `view` (same triangles,
    /// same topology, new positions): the bottom level in place (`MODE_UPDATE`), then the top level rebuilt, each
    /// timed (`blas_update`, `tlas`); [`DriverStructure::finish`] reads the times. The recording contract is
    /// [`DriverBuilder::record_build`]'s.
    ///
    /// # Errors
    ///
    /// [`GpuError::Buffer`] when `s` does not allow updates or `view` has another triangle count; a device error.
    pub fn record_update(
        &self,
        rec: &mut Recorder<'_>,
        view: &GeometryView<'_>,
        s: &mut DriverStructure,
    ) -> Result<(), GpuError> {
        let loader = loader(&self.ctx)?;
        if s.flags != DriverFlags::Update {
            return Err(GpuError::Buffer(format!("driver structure {}: built without ALLOW_UPDATE", s.flags.name())));
        }
        if view.triangle_count() != s.triangles {
            return Err(GpuError::Buffer(format!(
                "driver structure update: the view has {} triangles, the structure {}",
                view.triangle_count(),
                s.triangles
            )));
        }
        let geometry = [triangles_of(view)];
        let scratch_at = self.scratch_address(&s.scratch);
        let blas_info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
            .flags(s.flags.build_flags())
            .mode(vk::BuildAccelerationStructureModeKHR::UPDATE)
            .geometries(&geometry)
            .src_acceleration_structure(s.blas.handle)
            .dst_acceleration_structure(s.blas.handle)
            .scratch_data(vk::DeviceOrHostAddressKHR { device_address: scratch_at });
        let range = [vk::AccelerationStructureBuildRangeInfoKHR {
            primitive_count: s.triangles as u32,
            primitive_offset: 0,
            first_vertex: 0,
            transform_offset: 0,
        }];
        let inst_geometry = [instances_geometry(&s.instances)];
        let tlas_info = tlas_build(&inst_geometry, s.tlas.handle, scratch_at);
        let tlas_range = [vk::AccelerationStructureBuildRangeInfoKHR { primitive_count: 1, ..Default::default() }];
        let mut timer = Timer::new(&self.ctx, 3)?;
        rec.reset_timer(&mut timer);
        barrier(rec);
        rec.timestamp_start(&mut timer);
        // SAFETY: the structure was built with ALLOW_UPDATE over the same primitive count; the scratch holds the
        // update scratch size; the view's contract covers its vertices and indices.
        unsafe { loader.cmd_build_acceleration_structures(rec.command_buffer(), &[blas_info], &[&range]) };
        rec.timestamp(&mut timer, "blas_update");
        barrier(rec);
        // SAFETY: as in record_build.
        unsafe { loader.cmd_build_acceleration_structures(rec.command_buffer(), &[tlas_info], &[&tlas_range]) };
        rec.timestamp(&mut timer, "tlas");
        barrier(rec);
        if let Some(old) = s.pending.replace(timer) {
            s.retired.push(old);
        }
        Ok(())
    }

    /// [`DriverBuilder::record_update`], submitted and waited for.
    ///
    /// # Errors
    ///
    /// Those of [`DriverBuilder::record_update`].
    pub fn update(&self, view: &GeometryView<'_>, s: &mut DriverStructure) -> Result<(), GpuError> {
        self.ctx.submit_and_wait(|rec| self.record_update(rec, view, s))?;
        s.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Hit;

    fn hit(triangle: u32, t: f32, u: f32, v: f32) -> Option<Hit> {
        Some(Hit { t, triangle, u, v })
    }

    #[test]
    fn hits_agree_on_the_triangle_on_t_or_at_an_edge_only() {
        let e = 10.0;
        assert!(hit_agrees(None, None, e));
        assert!(hit_agrees(hit(3, 1.0, 0.3, 0.3), hit(3, 1.5, 0.2, 0.2), e), "same triangle");
        assert!(hit_agrees(hit(3, 1.0, 0.3, 0.3), hit(4, 1.00005, 0.3, 0.3), e), "same t within 1e-4 t + 1e-6 extent");
        assert!(!hit_agrees(hit(3, 1.0, 0.3, 0.3), hit(4, 1.01, 0.3, 0.3), e), "another triangle further on");
        // The nearer hit at an edge: the other test went through the crack to what lies behind.
        assert!(hit_agrees(hit(3, 1.5, 0.3, 0.3), hit(4, 1.0, 0.5, 0.5 - 2e-5), e));
        assert!(hit_agrees(hit(3, 1.0, 1.2e-5, 0.3), hit(4, 1.5, 0.3, 0.3), e));
        assert!(!hit_agrees(hit(3, 1.0, 0.3, 0.3), hit(4, 1.5, 1.2e-5, 0.3), e), "the farther hit at an edge");
        // A miss against a hit: only at an edge (u, v or 1 - u - v within the tolerance), either way round.
        assert!(!hit_agrees(hit(3, 1.0, 0.3, 0.3), None, e));
        assert!(!hit_agrees(None, hit(3, 1.0, 0.3, 0.3), e));
        assert!(hit_agrees(hit(3, 1.0, 0.0, 0.5), None, e), "on the edge u = 0");
        assert!(hit_agrees(None, hit(3, 1.0, 0.5, 5e-5), e), "within the tolerance of v = 0");
        assert!(hit_agrees(hit(3, 1.0, 0.5, 0.5 - 4e-5), None, e), "near the edge u + v = 1");
        assert!(!hit_agrees(hit(3, 1.0, 0.5, 0.499), None, e), "1e-3 from the edge: a real disagreement");
    }
}
