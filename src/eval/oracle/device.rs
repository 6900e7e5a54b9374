//! The oracle on the device: structures traced by the traversal kernel, the LBVH, HLBVH and grid built by the
//! device builders, primary and secondary rays made on the device ([`DeviceOracle`]), and the driver's
//! acceleration structures measured beside them.

use super::measure::Frame;
use super::DriverResult;
use super::Measurement;
use crate::accel::device_trace::{DeviceStructure, DeviceTraceError, DeviceTracer, TraceRay};
use crate::accel::{build_structure, AccelStructure, StructureName};
use crate::geom::Camera;
use crate::geom::WorkloadKind;
use crate::mesh::Mesh;
use crate::trace::workload::mesh_bounds;
use crate::trace::{RaySet, TraceOutcome};

/// The device side of the oracle: a context and the traversal kernel, its four pipelines already run once (some
/// drivers compile a pipeline at its first dispatch, inside the timestamps: lavapipe does, with LLVM).
///
/// The LBVH and the HLBVH are built on the device ([`crate::accel::gpu::BvhBuilder`], default options, the trees
/// of the CPU builders node for node) and traced without a read-back; so is the grid
/// ([`crate::accel::gpu::grid::GridBuilder`], default options), whose cell lists are compared with the host grid's
/// on every build (a difference is an error); where the driver cuts the device grid builder's loops (lavapipe, on
/// triangles over very many cells) the grid is built on the host and uploaded instead, and its `build_backend`
/// says `host`. The other structures are built on the host and uploaded.
pub struct DeviceOracle<'a> {
    pub(super) ctx: &'a crate::gpu::Context,
    tracer: DeviceTracer,
    builder: std::cell::RefCell<crate::accel::gpu::BvhBuilder>,
    grids: crate::accel::gpu::grid::GridBuilder,
    driver: Option<crate::accel::driver::DriverBuilder>,
}

impl<'a> DeviceOracle<'a> {
    /// Builds the kernel and warms it on a one-triangle scene of every structure.
    ///
    /// # Errors
    ///
    /// The device lacks what the kernel needs ([`DeviceTracer::new`]), or a warm-up failed.
    pub fn new(ctx: &'a crate::gpu::Context) -> Result<Self, DeviceTraceError> {
        let tracer = DeviceTracer::new(ctx)?;
        let mesh = crate::mesh::generate::single_triangle();
        let ray = [TraceRay::from(&crate::geom::Ray::new(glam::Vec3::new(0.2, 0.2, -1.0), glam::Vec3::Z))];
        for name in StructureName::ALL {
            let s = build_structure(name, &mesh)?;
            let layout = s.device_layout().ok_or(DeviceTraceError::NoLayout(name))?;
            let mut d = DeviceStructure::upload(ctx, &layout)?;
            tracer.trace(ctx, &mut d, &ray, false)?;
        }
        let builder = std::cell::RefCell::new(crate::accel::gpu::BvhBuilder::new(ctx)?);
        let grids = crate::accel::gpu::grid::GridBuilder::new(ctx)?;
        let driver = match ctx.caps().ray_query {
            true => Some(crate::accel::driver::DriverBuilder::new(ctx)?),
            false => None,
        };
        let o = DeviceOracle { ctx, tracer, builder, grids, driver };
        // The device builders' pipelines run once too.
        let buffers = crate::gpu::MeshBuffers::upload(ctx, &mesh.positions, &mesh.indices)?;
        for name in [StructureName::Lbvh, StructureName::Hlbvh, StructureName::Grid] {
            let host = build_structure(name, &mesh)?;
            o.run_device_built(
                name,
                &buffers,
                &RaySet { kind: WorkloadKind::Primary, rays: vec![], any_hit: false },
                None,
                (host.as_ref(), &mesh),
            )?
            .ok_or(DeviceTraceError::NoLayout(name))?;
        }
        // The ray-query pipeline compiles at its first dispatch on some drivers.
        if let Some(b) = &o.driver {
            let s = b.build(&buffers.view(), crate::accel::driver::DriverFlags::FastTrace)?;
            b.trace(&s, &ray, false)?;
        }
        Ok(o)
    }

    /// The primary rays of `camera` at `res x res` made on the device, checked against the host's `want`.
    pub(super) fn primary_rays(
        &self,
        camera: &Camera,
        res: u32,
        want: &[crate::geom::Ray],
    ) -> Result<crate::gpu::Buffer, String> {
        let pin = crate::accel::device_trace::Pinhole::from(camera);
        let buf = self.tracer.primary_rays(self.ctx, &pin, res, res).map_err(|e| e.to_string())?;
        let got: Vec<TraceRay> = self.ctx.read_buffer(&buf, 0, want.len()).map_err(|e| e.to_string())?;
        if let Some(i) =
            want.iter().zip(&got).position(|(a, b)| bytemuck::bytes_of(&TraceRay::from(a)) != bytemuck::bytes_of(b))
        {
            return Err(format!("device primary ray {i} differs from the host's: {:?} vs {:?}", got[i], want[i]));
        }
        Ok(buf)
    }

    /// The shadow or diffuse workload of `camera` at `res x res` over `mesh` made on the device (primary rays, their
    /// closest hits in a binned-SAH BVH, the secondary rays, in one submission), checked against the host's `want`.
    pub(super) fn secondary_rays(
        &self,
        kind: WorkloadKind,
        camera: &Camera,
        res: u32,
        mesh: &Mesh,
        want: &[crate::geom::Ray],
    ) -> Result<crate::gpu::Buffer, String> {
        use crate::accel::device_trace::{SecondaryInputs, TraceBuffers, TraceHit};
        use crate::gpu::MemoryKind;
        let e = |x: &dyn std::fmt::Display| x.to_string();
        let ctx = self.ctx;
        let reference = crate::accel::bvh::Bvh::build(mesh).map_err(|x| e(&x))?;
        let layout = reference.device_layout().ok_or("no device layout for the reference BVH")?;
        let s = DeviceStructure::upload(ctx, &layout).map_err(|x| e(&x))?;
        let n = res as u64 * res as u64;
        let bounds = mesh_bounds(mesh);
        let buffers = crate::gpu::MeshBuffers::upload(ctx, &mesh.positions, &mesh.indices).map_err(|x| e(&x))?;
        let view = buffers.view();
        let mk = |name: &str, bytes: u64| ctx.create_buffer(name, bytes, MemoryKind::DeviceLocal).map_err(|x| e(&x));
        let primary = mk("primary rays", n * std::mem::size_of::<TraceRay>() as u64)?;
        let hits = mk("primary hits", n * std::mem::size_of::<TraceHit>() as u64)?;
        let (_, stack_bytes) = self.tracer.stack_layout(ctx, &s, n);
        let stack = mk("stacks", stack_bytes)?;
        let out = mk("shadow rays", n * std::mem::size_of::<TraceRay>() as u64)?;
        let counts = mk("shadow counts", DeviceTracer::secondary_counts_bytes(n))?;
        let pin = crate::accel::device_trace::Pinhole::from(camera);
        let inputs = SecondaryInputs {
            kind,
            seed: crate::trace::workload::WORKLOAD_SEED,
            view: &view,
            primary: &primary,
            hits: &hits,
            count: n,
            light: crate::trace::workload::default_light(&bounds),
            bounds,
        };
        ctx.submit_and_wait(|rec| {
            self.tracer.record_primary_rays(rec, &pin, res, res, &primary)?;
            rec.dependency(crate::gpu::Pass::Compute, crate::gpu::Pass::Compute);
            let io = TraceBuffers { rays: &primary, count: n, hits: &hits, stack: &stack };
            self.tracer.record(rec, &s, &io, false)?;
            rec.dependency(crate::gpu::Pass::Compute, crate::gpu::Pass::Compute);
            self.tracer.record_secondary_rays(rec, &inputs, &out, &counts)
        })
        .map_err(|x| e(&x))?;
        let total: Vec<u32> =
            ctx.read_buffer(&counts, DeviceTracer::secondary_total_offset(n), 1).map_err(|x| e(&x))?;
        if total[0] as usize != want.len() {
            return Err(format!("the device made {} secondary rays, the host {}", total[0], want.len()));
        }
        let got: Vec<TraceRay> = ctx.read_buffer(&out, 0, want.len()).map_err(|x| e(&x))?;
        if let Some(i) =
            want.iter().zip(&got).position(|(a, b)| bytemuck::bytes_of(&TraceRay::from(a)) != bytemuck::bytes_of(b))
        {
            return Err(format!("device secondary ray {i} differs from the host's: {:?} vs {:?}", got[i], want[i]));
        }
        Ok(out)
    }

    /// Whether the oracle builds `name` on the device (the LBVH, the HLBVH and the grid).
    pub fn builds_on_device(name: StructureName) -> bool {
        matches!(name, StructureName::Lbvh | StructureName::Hlbvh | StructureName::Grid)
    }

    /// Builds `name` (LBVH, HLBVH or grid) on the device from `mesh` and traces `rays` through it: the build's GPU
    /// milliseconds (its passes' timestamps, the HLBVH's host top level included, plus the triangle-records pass)
    /// and the outcome; `None` when the driver cut the device grid builder's loops (the caller builds on the
    /// host). `host` is the host's structure of the same frame (and the frame): the device grid's cell lists must
    /// equal its lists.
    pub(super) fn run_device_built(
        &self,
        name: StructureName,
        mesh: &crate::gpu::MeshBuffers,
        rays: &RaySet,
        on_device: Option<&crate::gpu::Buffer>,
        host: (&dyn AccelStructure, &Mesh),
    ) -> Result<Option<(f64, TraceOutcome)>, DeviceTraceError> {
        let view = mesh.view();
        if name == StructureName::Grid {
            use crate::accel::gpu::grid::GridBuildError;
            let bad = |reason: String| {
                DeviceTraceError::Layout(crate::accel::AccelError::Invalid { structure: "grid", reason })
            };
            let scene = crate::accel::gpu::grid::triangle_bounds(host.1);
            // The coincident copies are found on the host (as the host grid finds them) and skipped on the device;
            // the host pass counts in the build.
            let t = std::time::Instant::now();
            let flags = crate::accel::grid::copy_flags(host.1).map_err(|e| bad(e.to_string()))?;
            let copies = match flags.contains(&1) {
                true => Some(self.ctx.upload("grid copy flags", &flags).map_err(DeviceTraceError::Gpu)?),
                false => None,
            };
            let flags_ms = t.elapsed().as_secs_f64() * 1e3;
            let built = match &copies {
                Some(c) => self.grids.build_with_copies(&view, &scene, &Default::default(), c),
                None => self.grids.build(&view, &scene, &Default::default()),
            };
            let g = match built {
                Ok(g) => g,
                Err(GridBuildError::LoopLimit { .. }) => return Ok(None),
                Err(GridBuildError::Gpu(e)) => return Err(DeviceTraceError::Gpu(e)),
                Err(e) => return Err(bad(e.to_string())),
            };
            let (starts, refs) = g.read_back(self.ctx).map_err(|e| bad(e.to_string()))?;
            match host.0.device_layout() {
                Some(crate::accel::device_trace::DeviceLayout::Grid { cell_start, refs: want, .. })
                    if cell_start == starts.as_slice() && want == refs.as_slice() => {}
                _ => return Err(bad("the device-built grid's cell lists differ from the host grid's".into())),
            }
            let build_ms = g.gpu_ms() + flags_ms;
            let mut d = g.into_device_structure(self.ctx).map_err(|e| bad(e.to_string()))?;
            return Ok(Some((build_ms, self.trace_on(&mut d, rays, on_device)?)));
        }
        let run = |e: crate::gpu::RunError| match e {
            crate::gpu::RunError::Gpu(g) => DeviceTraceError::Gpu(g),
            other => DeviceTraceError::Layout(crate::accel::AccelError::Invalid {
                structure: name.as_str(),
                reason: other.to_string(),
            }),
        };
        let bvh = {
            let mut b = self.builder.borrow_mut();
            match name {
                StructureName::Hlbvh => b.build_hlbvh(&view, &Default::default()).map_err(run)?,
                _ => b.build_lbvh(&view, &Default::default()).map_err(run)?,
            }
        };
        let build_ms: f64 = bvh.timings().iter().map(|(_, ms)| ms).sum();
        let (mut d, records_ms) = self.tracer.structure_of(self.ctx, &bvh, &view)?;
        let out = self.trace_on(&mut d, rays, on_device)?;
        Ok(Some((build_ms + records_ms, out)))
    }

    fn trace_on(
        &self,
        d: &mut DeviceStructure,
        rays: &RaySet,
        on_device: Option<&crate::gpu::Buffer>,
    ) -> Result<TraceOutcome, DeviceTraceError> {
        let out = match on_device {
            Some(buf) => self.tracer.trace_buffer(self.ctx, d, buf, rays.rays.len() as u64, rays.any_hit)?,
            None => {
                let dev_rays: Vec<TraceRay> = rays.rays.iter().map(TraceRay::from).collect();
                self.tracer.trace(self.ctx, d, &dev_rays, rays.any_hit)?
            }
        };
        let counters = out.counters();
        let mut o = TraceOutcome { counters, seconds: out.gpu_ms * 1e-3, ..Default::default() };
        if rays.any_hit {
            o.occluded = out.hits.iter().map(|h| h.hit().is_some()).collect();
        } else {
            o.hits = out.hits.iter().map(|h| h.hit()).collect();
        }
        Ok(o)
    }

    /// The context.
    pub fn context(&self) -> &crate::gpu::Context {
        self.ctx
    }

    /// Uploads `s` (timed, ms) and traces `rays` through it: the outcome (trace time from the GPU timestamps).
    pub(super) fn run(
        &self,
        s: &dyn AccelStructure,
        rays: &RaySet,
        on_device: Option<&crate::gpu::Buffer>,
    ) -> Result<(f64, TraceOutcome), DeviceTraceError> {
        let layout = s.device_layout().ok_or(DeviceTraceError::NoLayout(s.name()))?;
        let mut d = DeviceStructure::upload(self.ctx, &layout)?;
        let o = self.trace_on(&mut d, rays, on_device)?;
        Ok((d.upload_seconds() * 1e3, o))
    }
}

/// What the oracle gathers for one driver structure.
#[derive(Default)]
pub(super) struct DriverAcc {
    pub(super) build: Vec<f64>,
    pub(super) trace: Vec<f64>,
    pub(super) rays: u64,
    pub(super) memory: u64,
    pub(super) built: u64,
    pub(super) compacted: Option<u64>,
    pub(super) disagreements: usize,
    pub(super) error: Option<String>,
    pub(super) kept: Vec<Option<crate::accel::driver::DriverStructure>>,
    /// Per frame, per repeat: build and trace ms.
    pub(super) frames: Vec<(Vec<f64>, Vec<f64>)>,
}

impl DriverAcc {
    /// Measures the driver structure of `flags` on one frame, every repeat (an `rt_update` structure kept from the
    /// frame before is updated, the others are rebuilt); the first error ends its measurement.
    pub(super) fn measure_frame(
        &mut self,
        flags: crate::accel::driver::DriverFlags,
        f: &Frame<'_>,
        device: Option<&DeviceOracle<'_>>,
        mesh_buffers: Option<&crate::gpu::MeshBuffers>,
        device_rays: Option<&crate::gpu::Buffer>,
    ) {
        let a = self;
        let (repeats, mesh, rays, want) = (f.repeats, f.mesh, f.rays, f.want);
        if a.error.is_some() {
            return;
        }
        let (Some(d), Some(m)) = (device, mesh_buffers) else {
            a.error = Some("driver structures are traced with ray queries: needs --trace-backend vulkan".into());
            return;
        };
        let Some(builder) = &d.driver else {
            a.error = Some(format!(
                "{} has no VK_KHR_acceleration_structure / VK_KHR_ray_query (lavapipe has them from Mesa 24.1)",
                d.ctx.caps().name
            ));
            return;
        };
        let extent = mesh_bounds(mesh).extent().max_element();
        a.frames.push((vec![0.0; repeats], vec![0.0; repeats]));
        for r in 0..repeats {
            f.progress_step(r, flags.name());
            let view = m.view();
            let built = match a.kept[r].take() {
                Some(mut s) if flags == crate::accel::driver::DriverFlags::Update => {
                    builder.update(&view, &mut s).map(|_| s)
                }
                _ => builder.build(&view, flags),
            };
            let s = match built {
                Ok(s) => s,
                Err(e) => {
                    a.error = Some(format!("device: {e}"));
                    break;
                }
            };
            let traced = match device_rays {
                Some(buf) => builder.trace_buffer(&s, buf, rays.rays.len() as u64, rays.any_hit),
                None => builder.trace(&s, &rays.rays.iter().map(TraceRay::from).collect::<Vec<_>>(), rays.any_hit),
            };
            let out = match traced {
                Ok(o) => o,
                Err(e) => {
                    a.error = Some(format!("device: {e}"));
                    break;
                }
            };
            a.build[r] += s.gpu_ms();
            a.trace[r] += out.gpu_ms;
            if let Some(fr) = a.frames.last_mut() {
                fr.0[r] = s.gpu_ms();
                fr.1[r] = out.gpu_ms;
            }
            if r == 0 {
                a.rays += out.hits.len() as u64;
                a.memory = a.memory.max(s.memory_bytes());
                a.built = a.built.max(s.built_bytes());
                a.compacted = s.compacted_bytes().or(a.compacted);
                a.disagreements += out
                    .hits
                    .iter()
                    .enumerate()
                    .filter(|(i, h)| {
                        if rays.any_hit {
                            want.occluded.get(*i).copied().unwrap_or(false) != h.hit().is_some()
                        } else {
                            let w = want.hits.get(*i).copied().flatten();
                            !crate::accel::driver::hit_agrees(w, h.hit(), extent)
                        }
                    })
                    .count();
            }
            a.kept[r] = Some(s);
        }
    }

    /// The result over the run: totals per repeat scaled as the oracle's structures' are.
    pub(super) fn result(
        &self,
        flags: crate::accel::driver::DriverFlags,
        build_factor: f64,
        trace_factor: f64,
        animated: bool,
    ) -> DriverResult {
        let a = self;
        let builds: Vec<f64> = a.build.iter().map(|b| b * build_factor).collect();
        let traces: Vec<f64> = a.trace.iter().map(|t| t * trace_factor).collect();
        let totals: Vec<f64> = builds.iter().zip(&traces).map(|(b, t)| b + t).collect();
        let ok = a.error.is_none() && a.rays > 0;
        let (b, t, tot) = (Measurement::of(&builds), Measurement::of(&traces), Measurement::of(&totals));
        DriverResult {
            name: flags.name().to_string(),
            per_frame: if flags == crate::accel::driver::DriverFlags::Update { "update" } else { "rebuild" }
                .to_string(),
            build_ms: if ok { b.median } else { 0.0 },
            trace_ms: if ok { t.median } else { 0.0 },
            total_ms: if ok { tot.median } else { 0.0 },
            total_ms_spread: if ok { tot.spread } else { 0.0 },
            rays: a.rays,
            mrays_per_s: if ok && t.median > 0.0 { a.rays as f64 / (t.median * 1e3) } else { 0.0 },
            memory_bytes: a.memory,
            built_bytes: a.built,
            compacted_bytes: a.compacted,
            valid: ok,
            hits_agree: ok && a.disagreements == 0,
            disagreements: a.disagreements,
            error: a.error.clone(),
            frame_build_ms: if animated && ok {
                a.frames.iter().map(|f| Measurement::of(&f.0).median).collect()
            } else {
                Vec::new()
            },
            frame_trace_ms: if animated && ok {
                a.frames.iter().map(|f| Measurement::of(&f.1).median).collect()
            } else {
                Vec::new()
            },
        }
    }
}
