//! The traversal kernel (`glsl/trace.comp`) and its companions: primary rays from a camera
//! (`glsl/trace_rays.comp`), shadow and diffuse rays from the primary hits (`glsl/trace_secondary.comp`), and the
//! triangle records of a device-built BVH (`glsl/trace_records.comp`).

use super::layout::scene_header;
use super::*;

/// The traversal kernel, one pipeline per [`TraversalKind`], and the kernel that makes the triangle records of a
/// device-built BVH.
pub struct DeviceTracer {
    kernels: Vec<Kernel<TracePush>>,
    records: Kernel<TraceRecordsPush>,
    rays: Kernel<TraceRaysPush>,
    secondary: Kernel<TraceSecondaryPush>,
}

/// Primary rays per invocation of the secondary-ray kernel.
const SECONDARY_CHUNK: u32 = 64;

/// What the secondary rays of a primary pass are made from ([`DeviceTracer::record_secondary_rays`]).
#[derive(Clone, Copy, Debug)]
pub struct SecondaryInputs<'a> {
    /// Shadow or diffuse rays (`Primary` is refused).
    pub kind: crate::geom::WorkloadKind,
    /// Seed of the diffuse rays' generator (`trace::workload::build_workload` uses `0x6d65_7368_6368_6172`).
    pub seed: u64,
    /// The mesh the hits refer to.
    pub view: &'a crate::gpu::GeometryView<'a>,
    /// The primary rays ([`TraceRay`]s).
    pub primary: &'a Buffer,
    /// Their closest hits ([`TraceHit`]s), one per primary ray.
    pub hits: &'a Buffer,
    /// Primary rays.
    pub count: u64,
    /// The point light (`trace::workload::default_light` of the scene box for the oracle's workloads).
    pub light: Vec3,
    /// The scene box (`trace::workload::mesh_bounds`): the surface offset is `1e-5` of its diagonal plus `1e-6` of
    /// the point's largest coordinate.
    pub bounds: Aabb,
}

/// Items per invocation of the records kernel.
const RECORD_ITEMS: u32 = 4;

/// Stack entries a device-built BVH starts with: its depth is not known without reading the tree back, so a trace
/// that finds the stack full ([`TraceStatus::StackFull`]) is run again with twice as many ([`DeviceTracer::trace`]).
pub const DEVICE_BUILT_STACK_ENTRIES: u32 = 96;

impl std::fmt::Debug for DeviceTracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceTracer").finish()
    }
}

/// The buffers of one recorded trace ([`DeviceTracer::record`]).
#[derive(Clone, Copy, Debug)]
pub struct TraceBuffers<'a> {
    /// The rays, [`TraceRay`]s.
    pub rays: &'a Buffer,
    /// How many rays.
    pub count: u64,
    /// One [`TraceHit`] per ray, written by the trace.
    pub hits: &'a Buffer,
    /// The invocations' stacks ([`DeviceTracer::stack_layout`]).
    pub stack: &'a Buffer,
}

/// Rays traced on the device: one [`TraceHit`] per ray and the kernel's GPU time.
#[derive(Clone, Debug)]
pub struct DeviceTrace {
    /// One result per ray, in ray order.
    pub hits: Vec<TraceHit>,
    /// GPU milliseconds of the traversal dispatch (timestamps).
    pub gpu_ms: f64,
    /// Invocations the dispatch ran (each traced every `invocations`-th ray).
    pub invocations: u64,
}

impl DeviceTrace {
    /// Box (node, cell) and triangle tests summed over all rays.
    pub fn counters(&self) -> crate::geom::TraceCounters {
        let mut c = crate::geom::TraceCounters::default();
        for h in &self.hits {
            c.box_tests += h.box_tests as u64;
            c.prim_tests += h.prim_tests as u64;
        }
        c
    }
}

impl DeviceTracer {
    /// Builds the four pipelines.
    ///
    /// # Errors
    ///
    /// [`GpuError::Unsupported`] without `shaderFloat64` (the exact division needs it), or a pipeline error.
    pub fn new(ctx: &Context) -> Result<Self, GpuError> {
        if !ctx.caps().float64 {
            return Err(GpuError::Unsupported {
                name: ctx.caps().name.clone(),
                missing: vec!["shaderFloat64 (device traversal rounds its divisions correctly through f64)".into()],
            });
        }
        let kernels = TraversalKind::ALL
            .iter()
            .map(|k| Kernel::new(ctx, &KernelDesc::new(&shaders::trace::INFO).constant("STRUCTURE", k.constant())))
            .collect::<Result<Vec<_>, _>>()?;
        let records =
            Kernel::new(ctx, &KernelDesc::new(&shaders::trace_records::INFO).constant("ITEMS", RECORD_ITEMS))?;
        let rays = Kernel::new(ctx, &KernelDesc::new(&shaders::trace_rays::INFO))?;
        let secondary = Kernel::new(ctx, &KernelDesc::new(&shaders::trace_secondary::INFO))?;
        Ok(DeviceTracer { kernels, records, rays, secondary })
    }

    /// A device-built LBVH or HLBVH ([`crate::accel::gpu::BvhBuilder`]) made traceable on the device, without a
    /// read-back: its nodes copied and its triangle records made from `view` by a kernel (the records
    /// [`crate::geom::Triangle::new`] makes on the host, bit for bit). Submits and waits; returns the structure and
    /// the GPU milliseconds of the copy and the records pass.
    ///
    /// `view` must be the geometry the tree was built from (or refitted to); its stack starts at
    /// [`DEVICE_BUILT_STACK_ENTRIES`] entries.
    ///
    /// # Errors
    ///
    /// [`GpuError::NotReady`] for a recorded build not yet finished, [`GpuError::Buffer`] when `view` has another
    /// triangle count, or a device error.
    pub fn structure_of(
        &self,
        ctx: &Context,
        bvh: &crate::accel::gpu::GpuBvh,
        view: &crate::gpu::GeometryView<'_>,
    ) -> Result<(DeviceStructure, f64), GpuError> {
        if bvh.is_pending() {
            return Err(GpuError::NotReady("device structure of a recorded BVH build".into()));
        }
        let n = bvh.triangle_count();
        if view.triangle_count() != n {
            return Err(GpuError::Buffer(format!(
                "device structure: the view has {} triangles, the tree {n}",
                view.triangle_count()
            )));
        }
        let start = std::time::Instant::now();
        let node_bytes = bvh.node_count() * std::mem::size_of::<BvhNode>() as u64;
        let nodes = ctx.create_buffer("trace nodes", node_bytes, MemoryKind::DeviceLocal)?;
        let records = ctx.create_buffer("trace records", n * 48, MemoryKind::DeviceLocal)?;
        let refs = ctx.create_buffer("trace references", 4, MemoryKind::DeviceLocal)?;
        let header = scene_header(&Aabb::EMPTY, bvh.node_count() as usize);
        let scene = ctx.upload("trace scene", std::slice::from_ref(&header))?;
        let mut timer = Timer::new(ctx, 3)?;
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut timer);
            rec.timestamp_start(&mut timer);
            rec.copy(bvh.nodes(), 0, &nodes, 0, node_bytes);
            rec.timestamp(&mut timer, "copy nodes");
            if n > 0 {
                let push = crate::gpu::geometry_push!(TraceRecordsPush, view, {
                    ids: bvh.ids().address(),
                    records: records.address(),
                    count: n,
                });
                let per_group = self.records.workgroup_size() as u64 * RECORD_ITEMS as u64;
                // SAFETY: reads n ids of the tree and the view's n triangles (valid per its constructor), writes n
                // records into a buffer of n * 48 bytes.
                unsafe { rec.dispatch(&self.records, &push, rec.groups_for(n, per_group)) };
            }
            rec.timestamp(&mut timer, "records");
            Ok(())
        })?;
        let gpu_ms = timer.read()?.iter().map(|(_, ms)| ms).sum();
        let bytes = nodes.size() + records.size() + refs.size() + scene.size();
        let s = DeviceStructure {
            kind: TraversalKind::Bvh,
            nodes,
            records,
            refs,
            scene,
            stack_entries: DEVICE_BUILT_STACK_ENTRIES,
            bytes,
            upload_seconds: start.elapsed().as_secs_f64(),
        };
        Ok((s, gpu_ms))
    }

    /// Invocations and stack bytes a dispatch over `rays` rays of `s` uses: as many invocations as rays, up to
    /// the dispatch limit and [`STACK_BUDGET_BYTES`] of stacks (a whole number of workgroups, at least one).
    pub fn stack_layout(&self, ctx: &Context, s: &DeviceStructure, rays: u64) -> (u64, u64) {
        let caps = ctx.caps();
        let wg = self.kernels[0].workgroup_size().max(1) as u64;
        let per = s.stack_entries as u64 * TRACE_STACK_ENTRY_BYTES;
        let budget = STACK_BUDGET_BYTES.min(caps.max_memory_allocation_size / 2).max(per * wg);
        let by_stack = budget.checked_div(per).unwrap_or(u64::MAX);
        let groups = rays.div_ceil(wg).min(by_stack / wg).min(caps.max_workgroup_count[0] as u64).max(1);
        (groups * wg, groups * wg * per)
    }

    /// Records the traversal of `io.count` rays ([`TraceRay`]s in `io.rays`) through `s`, writing one
    /// [`TraceHit`] per ray to `io.hits`, with `io.stack` as the invocations' stacks (at least
    /// [`DeviceTracer::stack_layout`]'s bytes). Records no barrier before or after: the caller orders the writes of
    /// the rays before and the reads of the hits after ([`Recorder::dependency`]).
    ///
    /// # Errors
    ///
    /// [`GpuError::Buffer`] when a buffer is too small.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        s: &DeviceStructure,
        io: &TraceBuffers<'_>,
        any_hit: bool,
    ) -> Result<(), GpuError> {
        let TraceBuffers { rays, count, hits, stack } = *io;
        if count == 0 {
            return Ok(());
        }
        let (invocations, stack_bytes) = self.stack_layout(rec.context(), s, count);
        let ray_bytes = std::mem::size_of::<TraceRay>() as u64;
        let hit_bytes = std::mem::size_of::<TraceHit>() as u64;
        if rays.size() < count * ray_bytes || hits.size() < count * hit_bytes || stack.size() < stack_bytes {
            return Err(GpuError::Buffer(format!(
                "trace: {count} rays need {} bytes of rays, {} of hits and {stack_bytes} of stack",
                count * ray_bytes,
                count * hit_bytes
            )));
        }
        let kernel = &self.kernels[s.kind.constant() as usize];
        let push = TracePush {
            rays: rays.address(),
            hits: hits.address(),
            nodes: s.nodes.address(),
            tris: s.records.address(),
            refs: s.refs.address(),
            scene: s.scene.address(),
            stack: stack.address(),
            count,
            stack_entries: s.stack_entries,
            any_hit: any_hit as u32,
        };
        let groups = (invocations / kernel.workgroup_size().max(1) as u64) as u32;
        // SAFETY: every array the kernel reads was checked at upload (indices in range, one tree); the ray, hit and
        // stack buffers are large enough (checked above).
        unsafe { rec.dispatch(kernel, &push, groups) };
        Ok(())
    }

    /// Traces `rays` through `s` (uploads, dispatches between two timestamps, reads back; submits and waits). A
    /// device-built tree whose stack turns out too small gets twice the entries and is traced again (the GPU time
    /// is the last run's).
    ///
    /// # Errors
    ///
    /// [`DeviceTraceError::Gpu`] when the device fails, [`DeviceTraceError::Incomplete`] when a ray stopped short.
    pub fn trace(
        &self,
        ctx: &Context,
        s: &mut DeviceStructure,
        rays: &[TraceRay],
        any_hit: bool,
    ) -> Result<DeviceTrace, DeviceTraceError> {
        if rays.is_empty() {
            return Ok(DeviceTrace { hits: Vec::new(), gpu_ms: 0.0, invocations: 0 });
        }
        let ray_buf = ctx.upload("trace rays", rays)?;
        self.trace_buffer(ctx, s, &ray_buf, rays.len() as u64, any_hit)
    }

    /// [`DeviceTracer::trace`] of `count` rays already on the device (`rays`, [`TraceRay`]s: made by
    /// [`DeviceTracer::record_primary_rays`], or an engine's own).
    ///
    /// # Errors
    ///
    /// As [`DeviceTracer::trace`]; [`GpuError::Buffer`] when `rays` is smaller than `count` rays.
    pub fn trace_buffer(
        &self,
        ctx: &Context,
        s: &mut DeviceStructure,
        rays: &Buffer,
        count: u64,
        any_hit: bool,
    ) -> Result<DeviceTrace, DeviceTraceError> {
        loop {
            match self.trace_buffer_once(ctx, s, rays, count, any_hit) {
                // Only a tree whose depth was not known (a device-built one) can fill its stack: grow it and retry.
                Err(DeviceTraceError::Incomplete { status: TraceStatus::StackFull, .. })
                    if s.stack_entries < (1 << 20) =>
                {
                    s.stack_entries *= 2;
                }
                other => return other,
            }
        }
    }

    fn trace_buffer_once(
        &self,
        ctx: &Context,
        s: &DeviceStructure,
        ray_buf: &Buffer,
        count: u64,
        any_hit: bool,
    ) -> Result<DeviceTrace, DeviceTraceError> {
        if count == 0 {
            return Ok(DeviceTrace { hits: Vec::new(), gpu_ms: 0.0, invocations: 0 });
        }
        let (invocations, stack_bytes) = self.stack_layout(ctx, s, count);
        let hit_bytes = count * std::mem::size_of::<TraceHit>() as u64;
        let hits = ctx.create_buffer("trace hits", hit_bytes, MemoryKind::DeviceLocal)?;
        let stack = ctx.create_buffer("trace stacks", stack_bytes, MemoryKind::DeviceLocal)?;
        let readback = ctx.create_buffer("trace hits readback", hit_bytes, MemoryKind::Readback)?;
        let mut timer = Timer::new(ctx, 2)?;
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut timer);
            rec.timestamp_start(&mut timer);
            self.record(rec, s, &TraceBuffers { rays: ray_buf, count, hits: &hits, stack: &stack }, any_hit)?;
            rec.timestamp(&mut timer, "trace");
            rec.dependency(Pass::Compute, Pass::Transfer);
            rec.copy(&hits, 0, &readback, 0, hit_bytes);
            rec.host_read_barrier();
            Ok(())
        })?;
        let out: Vec<TraceHit> = readback.read(0, count as usize)?;
        let gpu_ms = timer.read()?.iter().map(|(_, ms)| ms).sum();
        let bad: Vec<usize> = out.iter().enumerate().filter(|(_, h)| h.status != TRACE_OK).map(|(i, _)| i).collect();
        if let Some(&first) = bad.first() {
            return Err(DeviceTraceError::Incomplete { count: bad.len(), first, status: out[first].status() });
        }
        Ok(DeviceTrace { hits: out, gpu_ms, invocations })
    }

    /// Records the primary rays of a pinhole camera for a `width x height` image into `rays` (at least
    /// `width * height` [`TraceRay`]s, row by row): bit for bit the rays of `geom::Camera::ray`, so a primary
    /// workload never crosses the bus. No barrier before or after (the caller orders the trace after it).
    ///
    /// # Errors
    ///
    /// [`GpuError::Buffer`] when `rays` is too small.
    pub fn record_primary_rays(
        &self,
        rec: &mut Recorder<'_>,
        camera: &Pinhole,
        width: u32,
        height: u32,
        rays: &Buffer,
    ) -> Result<(), GpuError> {
        let count = width as u64 * height as u64;
        let bytes = count * std::mem::size_of::<TraceRay>() as u64;
        if rays.size() < bytes {
            return Err(GpuError::Buffer(format!("primary rays: {width}x{height} need {bytes} bytes")));
        }
        if count == 0 {
            return Ok(());
        }
        let v4 = |v: Vec3, w: f32| [v.x, v.y, v.z, w];
        let push = TraceRaysPush {
            eye: v4(camera.eye, camera.tan_half_fov),
            forward: v4(camera.forward, 0.0),
            right: v4(camera.right, 0.0),
            up: v4(camera.up, 0.0),
            rays: rays.address(),
            width,
            height,
        };
        let groups = rec.groups_for(count, self.rays.workgroup_size() as u64);
        // SAFETY: writes `count` rays into a buffer of at least that many (checked above).
        unsafe { rec.dispatch(&self.rays, &push, groups) };
        Ok(())
    }

    /// The primary rays of `camera` made on the device (submits and waits): a buffer of `width * height`
    /// [`TraceRay`]s for [`DeviceTracer::trace_buffer`].
    ///
    /// # Errors
    ///
    /// A device error.
    pub fn primary_rays(&self, ctx: &Context, camera: &Pinhole, width: u32, height: u32) -> Result<Buffer, GpuError> {
        let bytes = width as u64 * height as u64 * std::mem::size_of::<TraceRay>() as u64;
        let rays = ctx.create_buffer("primary rays", bytes, MemoryKind::DeviceLocal)?;
        ctx.submit_and_wait(|rec| self.record_primary_rays(rec, camera, width, height, &rays))?;
        Ok(rays)
    }
}

impl DeviceTracer {
    /// Bytes of the counts buffer [`DeviceTracer::record_secondary_rays`] needs for `count` primary rays.
    pub fn secondary_counts_bytes(count: u64) -> u64 {
        Self::secondary_total_offset(count) + 4
    }

    /// Byte offset, in the counts buffer of [`DeviceTracer::record_secondary_rays`], of the word that holds the number
    /// of shadow rays made from `count` primary rays.
    pub fn secondary_total_offset(count: u64) -> u64 {
        4 * count.div_ceil(SECONDARY_CHUNK as u64)
    }

    /// Records the shadow or diffuse rays of a primary pass into `out` (room for `inputs.count` rays): from every
    /// closest hit, the ray of `trace::workload::secondary_rays`, bit for bit and in the same order (misses and
    /// zero-area triangles spawn none; diffuse directions from the same SplitMix64 stream per primary ray), so a
    /// secondary workload never crosses the bus. `counts` (at least
    /// [`DeviceTracer::secondary_counts_bytes`]) ends with the number of rays made in its last word. Three dispatches
    /// with barriers between them; none before (the caller orders the primary trace's writes before it) or after.
    ///
    /// # Errors
    ///
    /// [`GpuError::Buffer`] when a buffer is too small.
    pub fn record_secondary_rays(
        &self,
        rec: &mut Recorder<'_>,
        inputs: &SecondaryInputs<'_>,
        out: &Buffer,
        counts: &Buffer,
    ) -> Result<(), GpuError> {
        let n = inputs.count;
        let ray_bytes = n * std::mem::size_of::<TraceRay>() as u64;
        if inputs.primary.size() < ray_bytes
            || inputs.hits.size() < n * std::mem::size_of::<TraceHit>() as u64
            || out.size() < ray_bytes
            || counts.size() < Self::secondary_counts_bytes(n)
        {
            return Err(GpuError::Buffer(format!("secondary rays: buffers too small for {n} primary rays")));
        }
        let kind = match inputs.kind {
            crate::geom::WorkloadKind::Shadow => 0,
            crate::geom::WorkloadKind::Diffuse => 1,
            crate::geom::WorkloadKind::Primary => {
                return Err(GpuError::Buffer("secondary rays: primary is not a secondary workload".into()))
            }
        };
        let chunks = n.div_ceil(SECONDARY_CHUNK as u64);
        let offset = 1e-5 * inputs.bounds.extent().length();
        let l = inputs.light;
        let push = |phase: u32| {
            crate::gpu::geometry_push!(TraceSecondaryPush, inputs.view, {
                light_x: l.x,
                light_y: l.y,
                light_z: l.z,
                offset: offset,
                primary: inputs.primary.address(),
                hits: inputs.hits.address(),
                counts: counts.address(),
                out_rays: out.address(),
                count: n,
                triangles: inputs.view.triangle_count(),
                chunk: SECONDARY_CHUNK,
                phase: phase,
                tmax_scale: 1.0 - 1e-5,
                kind: kind,
                seed: inputs.seed,
            })
        };
        let groups = rec.groups_for(chunks, self.secondary.workgroup_size() as u64);
        // SAFETY: reads `n` primary rays and hits and the view's triangles by index (checked against its count in
        // the kernel), writes at most `n` rays and `chunks + 1` counts, all inside the buffers checked above.
        unsafe { rec.dispatch(&self.secondary, &push(0), groups) };
        rec.dependency(Pass::Compute, Pass::Compute);
        // SAFETY: as above (one invocation scans the counts).
        unsafe { rec.dispatch(&self.secondary, &push(1), 1) };
        rec.dependency(Pass::Compute, Pass::Compute);
        // SAFETY: as above.
        unsafe { rec.dispatch(&self.secondary, &push(2), groups) };
        Ok(())
    }

    /// The shadow rays of a primary pass made on the device (submits and waits): the buffer and how many rays it
    /// holds (one word read back).
    ///
    /// # Errors
    ///
    /// A device error, or [`GpuError::Buffer`] as [`DeviceTracer::record_secondary_rays`].
    pub fn secondary_rays(&self, ctx: &Context, inputs: &SecondaryInputs<'_>) -> Result<(Buffer, u64), GpuError> {
        let n = inputs.count;
        let out =
            ctx.create_buffer("shadow rays", n * std::mem::size_of::<TraceRay>() as u64, MemoryKind::DeviceLocal)?;
        let counts = ctx.create_buffer("shadow counts", Self::secondary_counts_bytes(n), MemoryKind::DeviceLocal)?;
        if n == 0 {
            return Ok((out, 0));
        }
        ctx.submit_and_wait(|rec| self.record_secondary_rays(rec, inputs, &out, &counts))?;
        let total: Vec<u32> = ctx.read_buffer(&counts, Self::secondary_total_offset(n), 1)?;
        Ok((out, total[0] as u64))
    }
}
