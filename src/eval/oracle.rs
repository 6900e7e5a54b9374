//! The measurement oracle: build and trace every structure on a scene and a workload, and from the timings the
//! ground-truth best structure, each structure's total, and the regret of a selection.
//!
//! # Method
//!
//! For each frame of the scene, the rays of the workload are generated once (from a binned-SAH BVH built for that
//! frame, not timed) together with the reference hits. Then, `repeats` times, every structure is built (timed),
//! traced over the rays (timed, rayon over rays), and, in the first repeat, validated and compared with the
//! reference hits (not timed). Repeats are interleaved across structures so that slow drift of the machine affects
//! them alike. Reported times are **medians over repeats**.
//!
//! # Totals
//!
//! * A static scene (one mesh) rendered for `F` frames: `total = B + F * T` when the structure is built once,
//!   `F * (B + T)` when rebuilt every frame, with `B`, `T` the build and trace time of one frame.
//! * An animation (several meshes, one topology): frames `0 .. F` are used, each rebuilt and traced:
//!   `total = sum_f (B_f + T_f)`. Building once is refused for an animation (tracing frame `f` through frame 0's
//!   structure without an update would give wrong hits).
//! * **Refit candidates** of an animation ([`OracleConfig::refit`], `bvh_refit` and `lbvh_refit`): frame 0 built,
//!   every later frame refitted ([`crate::accel::bvh::BvhTree::refit`]) and traced, every frame's hits checked
//!   against the reference: `total = B_0 + sum_{f >= 1} R_f + sum_f T_f`. They are candidates of their own
//!   ([`SceneEvaluation::refit_structures`], named in [`SceneEvaluation::best_candidate`]), so that what refitting
//!   saves is measured rather than predicted; they are measured with `repeats` repeats (no precision target) on
//!   the CPU tracer.
//!
//! The **oracle best** is the structure with the smallest median total among those that built, validated and
//! agreed with the reference hits. The **regret** of a selection `s` is `total(s) / total(best) - 1`.
//!
//! # Noise
//!
//! Each structure's total has a spread, half the range of its totals over the repeats. Two structures are *within
//! noise* of each other when their medians differ by no more than the sum of their spreads; a regret is within
//! noise when the selection is within noise of the best. With one repeat the spread is zero and nothing is ever
//! within noise: use at least three repeats to judge.
//!
//! # The precise oracle
//!
//! With [`OracleConfig::precision`] set (0.02 for +-2%), every structure is measured `repeats` times and then in
//! further rounds, each round measuring every structure once (interleaved), until the distribution-free 95%
//! confidence interval of each structure's median total ([`median_ci95`], the sign-test interval from order
//! statistics: at least 6 repeats) lies within the target of its median, or [`OracleConfig::max_repeats`] rounds
//! are reached (more while [`OracleConfig::precision_ms`] allows); each structure's `precision_met` says whether
//! its interval met the target. Every structure takes part in every round so that the machine's drift hits all
//! alike: on the 2-core VM the same build and trace run up to 1.6x slower for seconds at a time, and when a
//! structure already precise stopped while another went on into such a stretch, the one measured on was judged
//! slower than it is (`docs/cost-model.md`, "Twelfth session"). With intervals, two totals are within noise when
//! their intervals overlap. On an animation, frame 0 decides the repeats and later frames repeat each structure as
//! often, so that every repeat's total covers every frame.
//!
//! # Trace budget
//!
//! Building is bounded by the grid's and the kd-tree's reference budgets; tracing is bounded here. Before a
//! structure's first timed trace on a frame, a sample of the rays (every `k`-th ray, [`TRACE_SAMPLE_RAYS`] of them;
//! not timed) is traced with counters; when its box and triangle tests per ray exceed
//! [`OracleConfig::max_tests_per_ray`], the structure is reported as failed for the scene, with the counts and the
//! projected total, and the others are measured. The reference is checked the same way before it makes the rays,
//! and a reference over the budget is an error for the scene. Such scenes exist: a polygon face over three points
//! loads to many coincident copies of one triangle, and under the tie rule a ray that reaches them tests every copy
//! (the binned-SAH BVH keeps one copy of a triangle whose vertex indices repeat, [`crate::accel::bvh::BvhTree::copies`],
//! the other structures test them all). On every scene of `docs/data` the most tests per ray of any structure is
//! 134 (the grid on the dragon, shadow rays), so the default of 4,096 stops only the pathological.
//!
//! # The cheapest structure within noise
//!
//! When several structures are within noise of the best, the measurement cannot tell them apart, and the one that
//! costs least to have is the better answer: [`SceneEvaluation::oracle_within_noise`] lists them (the best
//! included) and [`SceneEvaluation::oracle_cheapest_within_noise`] names the one with the least median build time,
//! then the least memory. `oracle_best` stays the structure with the smallest median total, and `regret` is still
//! measured against it; a policy (or a calibration) that wants the cheapest defensible answer targets
//! `oracle_cheapest_within_noise` instead.

use super::record::{OracleRecord, StructureRecord};
use crate::accel::device::{DeviceStructure, DeviceTraceError, DeviceTracer, TraceRay};
use crate::accel::{build_structure, AccelStats, AccelStructure, StructureName};
use crate::geom::WorkloadKind;
use crate::mesh::{Animation, Mesh};
use crate::trace::workload::{build_workload, mesh_bounds};
use crate::trace::{count_disagreements, trace, Camera, RaySet, TraceOutcome};
use std::time::Instant;

/// When structures are (re)built.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Rebuild {
    /// Built for every frame.
    PerFrame,
    /// Built once (static scenes only).
    Once,
}

pub use crate::accel::device::{DeviceRecord, TraceBackend};

/// The device side of the oracle: a context and the traversal kernel, its four pipelines already run once (some
/// drivers compile a pipeline at its first dispatch, inside the timestamps: lavapipe does, with LLVM).
///
/// The LBVH and the HLBVH are built on the device ([`crate::accel::gpu::BvhBuilder`], default options, the trees
/// of the CPU builders node for node) and traced without a read-back; so is the grid
/// ([`crate::accel::gpu_grid::GridBuilder`], default options), whose cell lists are compared with the host grid's
/// on every build (a difference is an error); where the driver cuts the device grid builder's loops (lavapipe, on
/// triangles over very many cells) the grid is built on the host and uploaded instead, and its `build_backend`
/// says `host`. The other structures are built on the host and uploaded.
pub struct DeviceOracle<'a> {
    ctx: &'a crate::gpu::Context,
    tracer: DeviceTracer,
    builder: std::cell::RefCell<crate::accel::gpu::BvhBuilder>,
    grids: crate::accel::gpu_grid::GridBuilder,
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
        let grids = crate::accel::gpu_grid::GridBuilder::new(ctx)?;
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
    fn primary_rays(&self, camera: &Camera, res: u32, want: &[crate::geom::Ray]) -> Result<crate::gpu::Buffer, String> {
        let pin = crate::accel::device::Pinhole::from(camera);
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
    fn secondary_rays(
        &self,
        kind: WorkloadKind,
        camera: &Camera,
        res: u32,
        mesh: &Mesh,
        want: &[crate::geom::Ray],
    ) -> Result<crate::gpu::Buffer, String> {
        use crate::accel::device::{SecondaryInputs, TraceBuffers, TraceHit};
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
        let pin = crate::accel::device::Pinhole::from(camera);
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
    fn run_device_built(
        &self,
        name: StructureName,
        mesh: &crate::gpu::MeshBuffers,
        rays: &RaySet,
        on_device: Option<&crate::gpu::Buffer>,
        host: (&dyn AccelStructure, &Mesh),
    ) -> Result<Option<(f64, TraceOutcome)>, DeviceTraceError> {
        let view = mesh.view();
        if name == StructureName::Grid {
            use crate::accel::gpu_grid::GridBuildError;
            let bad = |reason: String| {
                DeviceTraceError::Layout(crate::accel::AccelError::Invalid { structure: "grid", reason })
            };
            let scene = crate::accel::gpu_grid::triangle_bounds(host.1);
            let g = match self.grids.build(&view, &scene, &Default::default()) {
                Ok(g) => g,
                Err(GridBuildError::LoopLimit { .. }) => return Ok(None),
                Err(GridBuildError::Gpu(e)) => return Err(DeviceTraceError::Gpu(e)),
                Err(e) => return Err(bad(e.to_string())),
            };
            let (starts, refs) = g.read_back(self.ctx).map_err(|e| bad(e.to_string()))?;
            match host.0.device_layout() {
                Some(crate::accel::device::DeviceLayout::Grid { cell_start, refs: want, .. })
                    if cell_start == starts.as_slice() && want == refs.as_slice() => {}
                _ => return Err(bad("the device-built grid's cell lists differ from the host grid's".into())),
            }
            let build_ms = g.gpu_ms();
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
    fn run(
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

/// A workload for the oracle.
#[derive(Clone, Debug)]
pub struct OracleConfig {
    /// Kind of rays.
    pub workload: WorkloadKind,
    /// Image side: `resolution x resolution` primary rays per frame (1024 in the thesis).
    pub resolution: u32,
    /// Frames: how many times a static scene is rendered, or how many frames of an animation are used
    /// (`None`: 1 for a static scene, all for an animation).
    pub frames: Option<usize>,
    /// When structures are built.
    pub rebuild: Rebuild,
    /// Repeats of every measurement (medians are reported).
    pub repeats: usize,
    /// Structures to compare.
    pub structures: Vec<StructureName>,
    /// Camera; `None` frames the scene automatically ([`Camera::frame`] on the bounds of all frames).
    pub camera: Option<Camera>,
    /// The driver's acceleration structures to measure beside `structures` (device backend with ray queries).
    pub driver: Vec<crate::accel::driver::DriverFlags>,
    /// The trace budget: most box and triangle tests per ray (mean over a sample of the rays) before a structure
    /// is reported as failed instead of traced (see the module docs).
    pub max_tests_per_ray: f64,
    /// The precise oracle: when set (a fraction, 0.02 for +-2%), every structure is measured at least `repeats`
    /// times and then in further rounds of all of them (interleaved), until the 95% confidence interval of each
    /// one's median total ([`median_ci95`]) lies within this fraction of its median, or `max_repeats` rounds are
    /// reached (see `precision_ms`; a structure whose interval is still wider has `precision_met` `false`).
    /// `None`: exactly `repeats` repeats.
    pub precision: Option<f64>,
    /// The most repeats of one structure under `precision`, unless `precision_ms` allows more.
    pub max_repeats: usize,
    /// Under `precision`, the rounds go on past `max_repeats` (up to [`MAX_PRECISION_REPEATS`]) while a structure
    /// is still short of the target and the record's frame-0 builds and traces so far (the times measured: a static
    /// scene's one frame, not the `frames` it stands for; on the device the traces' timestamps) sum to less than
    /// this many milliseconds: cheap records are repeated until precise, costly ones stop at `max_repeats`. 0: no
    /// rounds past `max_repeats`.
    pub precision_ms: f64,
    /// Refit candidates to measure on an animation beside the rebuilt structures ([`RefitCandidate`]): frame 0
    /// built, every later frame refitted. Ignored for a static scene; measured on the CPU tracer only.
    pub refit: Vec<RefitCandidate>,
}

/// A candidate that builds frame 0 of an animation and refits the tree to every later frame
/// ([`crate::accel::bvh::BvhTree::refit`]) instead of rebuilding it: what an engine does with a deforming mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RefitCandidate {
    /// The binned-SAH BVH, refitted: `bvh_refit`.
    #[serde(rename = "bvh_refit")]
    Bvh,
    /// The LBVH, refitted: `lbvh_refit`.
    #[serde(rename = "lbvh_refit")]
    Lbvh,
}

impl RefitCandidate {
    /// Every refit candidate.
    pub const ALL: [RefitCandidate; 2] = [RefitCandidate::Bvh, RefitCandidate::Lbvh];

    /// `bvh_refit` or `lbvh_refit`.
    pub fn name(self) -> &'static str {
        match self {
            RefitCandidate::Bvh => "bvh_refit",
            RefitCandidate::Lbvh => "lbvh_refit",
        }
    }

    /// Parses [`RefitCandidate::name`].
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == s)
    }

    /// The structure it builds on frame 0.
    pub fn structure(self) -> StructureName {
        match self {
            RefitCandidate::Bvh => StructureName::Bvh,
            RefitCandidate::Lbvh => StructureName::Lbvh,
        }
    }

    fn build(self, mesh: &Mesh) -> Result<Refitted, crate::accel::AccelError> {
        Ok(match self {
            RefitCandidate::Bvh => Refitted::Bvh(crate::accel::bvh::Bvh::build(mesh)?),
            RefitCandidate::Lbvh => Refitted::Lbvh(crate::accel::lbvh::Lbvh::build(mesh)?),
        })
    }
}

/// A tree that is refitted frame after frame.
enum Refitted {
    Bvh(crate::accel::bvh::Bvh),
    Lbvh(crate::accel::lbvh::Lbvh),
}

impl Refitted {
    fn accel(&self) -> &dyn AccelStructure {
        match self {
            Refitted::Bvh(b) => b,
            Refitted::Lbvh(l) => l,
        }
    }

    fn refit(&mut self, mesh: &Mesh) -> Result<(), crate::accel::AccelError> {
        match self {
            Refitted::Bvh(b) => b.refit(mesh),
            Refitted::Lbvh(l) => l.refit(mesh),
        }
    }
}

/// What the oracle measured for one refit candidate on an animation.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RefitResult {
    /// `bvh_refit` or `lbvh_refit`.
    pub name: String,
    /// Median build of frame 0, ms.
    pub build_ms: f64,
    /// Median of the refits of frames 1 and later, summed, ms.
    pub refit_ms: f64,
    /// Median trace time over every frame, ms.
    pub trace_ms: f64,
    /// Median total (build, refits and traces of every frame), ms.
    pub total_ms: f64,
    /// Half the range of the totals over the repeats, ms.
    pub total_ms_spread: f64,
    /// Rays traced per repeat (over all measured frames).
    pub rays: u64,
    /// Box tests per ray over every frame.
    pub box_tests_per_ray: f64,
    /// Triangle tests per ray over every frame.
    pub prim_tests_per_ray: f64,
    /// SAH cost of frame 0's tree and of the last frame's refitted tree.
    pub sah_first_last: Option<[f64; 2]>,
    /// Memory of the tree, bytes.
    pub memory_bytes: usize,
    /// Every refitted tree validated.
    pub valid: bool,
    /// Every hit agreed with the reference on every frame.
    pub hits_agree: bool,
    /// Rays that disagreed with the reference.
    pub disagreements: usize,
    /// The build, refit or validation error, if any.
    pub error: Option<String>,
    /// Per frame: the median build (frame 0) or refit (later frames), ms.
    pub frame_update_ms: Vec<f64>,
    /// Per frame: the median trace, ms.
    pub frame_trace_ms: Vec<f64>,
}

/// The default [`OracleConfig::max_repeats`].
pub const DEFAULT_MAX_REPEATS: usize = 60;

/// The most rounds [`OracleConfig::precision_ms`] may add up to under a precision target (a larger
/// [`OracleConfig::max_repeats`] is still run in full).
pub const MAX_PRECISION_REPEATS: usize = 500;

/// The records' `rounds` under a precision target ([`crate::eval::OracleRecord::rounds`]): every structure is measured
/// in every round until all of them meet the target, as this oracle measures.
pub const ROUNDS_EVERY_STRUCTURE: &str = "every_structure";

/// The default [`OracleConfig::max_tests_per_ray`] (the trace budget's, [`crate::trace::DEFAULT_MAX_TESTS_PER_RAY`]).
pub use crate::trace::DEFAULT_MAX_TESTS_PER_RAY;

pub use crate::trace::{check_trace_budget, TRACE_SAMPLE_RAYS};

impl Default for OracleConfig {
    fn default() -> Self {
        OracleConfig {
            workload: WorkloadKind::Primary,
            resolution: 1024,
            frames: None,
            rebuild: Rebuild::Once,
            repeats: 3,
            structures: StructureName::ALL.to_vec(),
            camera: None,
            driver: Vec::new(),
            max_tests_per_ray: DEFAULT_MAX_TESTS_PER_RAY,
            precision: None,
            max_repeats: DEFAULT_MAX_REPEATS,
            precision_ms: 0.0,
            refit: Vec::new(),
        }
    }
}

/// Errors of the oracle.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The scene has no frame.
    #[error("{0}: the scene has no frame")]
    NoFrames(String),
    /// A configuration that cannot be measured.
    #[error("{scene}: {reason}")]
    Config {
        /// The scene.
        scene: String,
        /// Why.
        reason: String,
    },
    /// The reference structure could not be built.
    #[error(transparent)]
    Accel(#[from] crate::accel::AccelError),
    /// The device failed outside any one structure (the frame's upload).
    #[error("device: {0}")]
    Device(String),
}

/// Median and range of repeated measurements, in milliseconds.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Measurement {
    /// Median.
    pub median: f64,
    /// Smallest sample.
    pub min: f64,
    /// Largest sample.
    pub max: f64,
    /// Half the range, the noise estimate.
    pub spread: f64,
    /// Samples.
    pub samples: usize,
    /// The median's distribution-free 95% confidence interval ([`median_ci95`]); `None` below 6 samples, where no
    /// pair of order statistics covers the median with 95% confidence.
    pub ci95: Option<[f64; 2]>,
}

/// The distribution-free 95% confidence interval of the median of `sorted` (ascending) samples: the order
/// statistics `x_(j)` and `x_(n+1-j)` (1-based) for the largest `j` with `2 P(B <= j - 1) <= 0.05`, `B` binomial
/// with `n` trials and probability 1/2 (the sign-test interval; it assumes independent samples from one
/// distribution, nothing about its shape). `None` for fewer than 6 samples (at 5, even `[min, max]` covers the
/// median with only 93.75%).
pub fn median_ci95(sorted: &[f64]) -> Option<[f64; 2]> {
    let n = sorted.len();
    // Cumulative binomial in log space (0.5^n underflows past n = 1074).
    let ln_half_n = n as f64 * 0.5f64.ln();
    let (mut ln_pmf, mut cdf, mut j) = (ln_half_n, 0.0f64, 0usize);
    for k in 0..n / 2 {
        cdf += ln_pmf.exp();
        if 2.0 * cdf > 0.05 {
            break;
        }
        j = k + 1;
        ln_pmf += ((n - k) as f64).ln() - ((k + 1) as f64).ln();
    }
    (j >= 1).then(|| [sorted[j - 1], sorted[n - j]])
}

impl Measurement {
    /// Summary of samples (all zero when there are none).
    pub fn of(samples: &[f64]) -> Self {
        if samples.is_empty() {
            return Measurement::default();
        }
        let mut s = samples.to_vec();
        s.sort_by(f64::total_cmp);
        let k = s.len();
        let median = if k % 2 == 1 { s[k / 2] } else { 0.5 * (s[k / 2 - 1] + s[k / 2]) };
        Measurement {
            median,
            min: s[0],
            max: s[k - 1],
            spread: 0.5 * (s[k - 1] - s[0]),
            samples: k,
            ci95: median_ci95(&s),
        }
    }

    /// Whether two measurements are within noise of each other: with confidence intervals on both, when the
    /// intervals overlap; otherwise when the medians differ by no more than the sum of the spreads (see the module
    /// docs).
    pub fn within_noise(&self, o: &Measurement) -> bool {
        match (self.ci95, o.ci95) {
            (Some(a), Some(b)) => a[0] <= b[1] && b[0] <= a[1],
            _ => (self.median - o.median).abs() <= self.spread + o.spread,
        }
    }

    /// Whether the confidence interval lies within `precision` (a fraction: 0.02 is +-2%) of the median on both
    /// sides; `false` without an interval or with a median of zero.
    pub fn precise_to(&self, precision: f64) -> bool {
        match self.ci95 {
            Some([lo, hi]) if self.median > 0.0 => {
                lo >= self.median * (1.0 - precision) && hi <= self.median * (1.0 + precision)
            }
            _ => false,
        }
    }
}

/// What the oracle measured for one structure.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StructureResult {
    /// Which structure.
    pub name: Option<StructureName>,
    /// Build time over the run (all builds of all frames), ms; with the device backend, host build plus upload.
    pub build_ms: Measurement,
    /// Upload to the device over the run (device backend, host-built structures; part of `build_ms`), ms.
    pub upload_ms: Option<Measurement>,
    /// Where it was built with the device backend: `host` (then uploaded) or `device`; `None` on the CPU backend.
    pub build_backend: Option<&'static str>,
    /// Trace time over the run (all frames), ms.
    pub trace_ms: Measurement,
    /// Total (see the module docs), ms.
    pub total_ms: Measurement,
    /// Rays traced per repeat (over all measured frames).
    pub rays: u64,
    /// Millions of rays per second, from the median trace time.
    pub mrays_per_s: f64,
    /// Box tests (or node visits, cells) per ray.
    pub box_tests_per_ray: f64,
    /// Triangle tests per ray.
    pub prim_tests_per_ray: f64,
    /// Memory of the structure (largest frame), bytes.
    pub memory_bytes: usize,
    /// SAH cost (first frame), where it applies.
    pub sah_cost: Option<f64>,
    /// Statistics of `validate()` (first frame).
    pub stats: Option<AccelStats>,
    /// Whether `validate()` passed on every frame.
    pub valid: bool,
    /// Whether every hit agreed with the reference on every frame.
    pub hits_agree: bool,
    /// Rays that disagreed with the reference.
    pub disagreements: usize,
    /// Whether its total is within noise of the best total.
    pub within_noise_of_best: bool,
    /// Under [`OracleConfig::precision`]: whether the total's confidence interval met it by the last round
    /// ([`OracleConfig::max_repeats`], or more under [`OracleConfig::precision_ms`]); `None` without a precision
    /// target.
    pub precision_met: Option<bool>,
    /// The build or validation error, if any.
    pub error: Option<String>,
}

/// The oracle's verdict on one scene and workload.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SceneEvaluation {
    /// Scene name (path).
    pub mesh: String,
    /// Triangles per frame.
    pub triangles: usize,
    /// Frames measured (distinct geometries).
    pub frames_measured: usize,
    /// Frames the totals stand for.
    pub frames: usize,
    /// Workload.
    pub workload: WorkloadKind,
    /// Image side.
    pub resolution: u32,
    /// Rebuild policy.
    pub rebuild: Rebuild,
    /// Repeats.
    pub repeats: usize,
    /// The camera the rays were made from.
    #[serde(skip)]
    pub camera: Camera,
    /// The precision target ([`OracleConfig::precision`]), when one was set.
    pub precision: Option<f64>,
    /// Under a precision target: [`OracleConfig::max_repeats`].
    pub max_repeats: Option<usize>,
    /// Under a precision target: [`OracleConfig::precision_ms`].
    pub precision_ms: Option<f64>,
    /// Rays per frame (first frame).
    pub rays_per_frame: usize,
    /// The selection passed in (from the characterization's policy), if any.
    pub selected: Option<StructureName>,
    /// The structure with the smallest median total.
    pub oracle_best: Option<StructureName>,
    /// The structures within noise of the best (see the module docs), the best included, in the order measured.
    pub oracle_within_noise: Vec<StructureName>,
    /// Among [`SceneEvaluation::oracle_within_noise`], the one with the least median build time, then the least
    /// memory: the cheapest structure the measurement cannot tell from the best.
    pub oracle_cheapest_within_noise: Option<StructureName>,
    /// `total(selected) / total(best) - 1`, when a selection was given and both were measured.
    pub regret: Option<f64>,
    /// Whether the selection is within noise of the best.
    pub regret_within_noise: Option<bool>,
    /// Rays that hit something in the reference (closest-hit workloads) or were occluded (any-hit), over every
    /// measured frame.
    pub reference_hits: u64,
    /// Why no best structure is named, when none is: the workload traces no ray (secondary rays of a camera whose
    /// primary rays all miss), so the totals are builds alone. Rays that all miss (`reference_hits` 0) still rank
    /// the structures: a miss costs every node and cell the ray visits on its way out.
    pub no_best_reason: Option<String>,
    /// Where the rays were traced.
    pub trace_backend: TraceBackend,
    /// The device (device backend).
    pub device: Option<DeviceRecord>,
    /// Per structure.
    pub structures: Vec<StructureResult>,
    /// The driver's acceleration structures, when asked for ([`OracleConfig::driver`]).
    pub driver_structures: Vec<DriverResult>,
    /// The refit candidates of an animation ([`OracleConfig::refit`]): frame 0 built, later frames refitted.
    pub refit_structures: Vec<RefitResult>,
    /// With driver structures or refit candidates measured: the candidate with the smallest median total among
    /// the project's rebuilt structures, the refitted ones and the driver's (valid and agreeing with the
    /// reference), by name; `None` without such candidates or without a best (`oracle_best` stays the best of
    /// the project's rebuilt structures).
    pub best_candidate: Option<String>,
}

/// One driver acceleration structure in the oracle ([`crate::accel::driver`]): build flags, times (GPU timestamps),
/// memory and the agreement of its ray-query hits with the CPU reference ([`crate::accel::driver::hit_agrees`]).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DriverResult {
    /// `rt_fast_trace`, `rt_fast_build`, `rt_update` or `rt_fast_trace_compact`.
    pub name: String,
    /// How it follows an animation's frames: `rebuild`, or `update` (`rt_update`: built on the first frame,
    /// updated on the next ones).
    pub per_frame: String,
    /// Median build (or update) time over the run, ms: the bottom and top levels' timestamps (and the compaction).
    pub build_ms: f64,
    /// Median trace time over the run, ms (the ray-query dispatch's timestamps).
    pub trace_ms: f64,
    /// Median total, ms.
    pub total_ms: f64,
    /// Half the range of the totals.
    pub total_ms_spread: f64,
    /// Rays traced over the measured frames (first repeat).
    pub rays: u64,
    /// Million rays per second (median trace time).
    pub mrays_per_s: f64,
    /// Device bytes held (both levels, the instance, the scratch kept for updates), largest over the frames.
    pub memory_bytes: u64,
    /// Bytes of the bottom level as built.
    pub built_bytes: u64,
    /// Bytes of the compacted bottom level (`rt_fast_trace_compact`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compacted_bytes: Option<u64>,
    /// Built and traced without error.
    pub valid: bool,
    /// Every ray agreed with the CPU reference.
    pub hits_agree: bool,
    /// Rays that did not.
    pub disagreements: usize,
    /// Why it was not measured, or what failed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Per measured frame of an animation, the median build (or update) time, ms: with `rt_update` frame 0 is the
    /// build and the others updates.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frame_build_ms: Vec<f64>,
    /// Per measured frame of an animation, the median trace time, ms: how an update's trace cost drifts from the
    /// built frame's.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frame_trace_ms: Vec<f64>,
}

/// What the oracle gathers for one refit candidate.
#[derive(Default)]
struct RefitAcc {
    kept: Vec<Option<Refitted>>,
    /// Per frame, per repeat: build or refit ms, and trace ms.
    frames: Vec<(Vec<f64>, Vec<f64>)>,
    rays: u64,
    box_tests: u64,
    prim_tests: u64,
    memory: usize,
    disagreements: usize,
    valid: bool,
    sah_first: Option<f64>,
    sah_last: Option<f64>,
    error: Option<String>,
}

impl RefitAcc {
    fn result(&self, name: &str, repeats: usize) -> RefitResult {
        let ok = self.error.is_none() && self.rays > 0;
        let per_repeat = |pick: &dyn Fn(usize) -> f64| -> Vec<f64> { (0..repeats).map(pick).collect() };
        let build = per_repeat(&|r| self.frames.first().map_or(0.0, |f| f.0[r]));
        let refit = per_repeat(&|r| self.frames.iter().skip(1).map(|f| f.0[r]).sum());
        let traces = per_repeat(&|r| self.frames.iter().map(|f| f.1[r]).sum());
        let totals: Vec<f64> = (0..repeats).map(|r| build[r] + refit[r] + traces[r]).collect();
        let per_ray = |x: u64| if self.rays > 0 { x as f64 / self.rays as f64 } else { 0.0 };
        let med = |v: &[f64]| if ok { Measurement::of(v).median } else { 0.0 };
        RefitResult {
            name: name.to_string(),
            build_ms: med(&build),
            refit_ms: med(&refit),
            trace_ms: med(&traces),
            total_ms: med(&totals),
            total_ms_spread: if ok { Measurement::of(&totals).spread } else { 0.0 },
            rays: self.rays,
            box_tests_per_ray: per_ray(self.box_tests),
            prim_tests_per_ray: per_ray(self.prim_tests),
            sah_first_last: self.sah_first.zip(self.sah_last).map(|(a, b)| [a, b]),
            memory_bytes: self.memory,
            valid: ok && self.valid,
            hits_agree: ok && self.disagreements == 0,
            disagreements: self.disagreements,
            error: self.error.clone(),
            frame_update_ms: if ok {
                self.frames.iter().map(|f| Measurement::of(&f.0).median).collect()
            } else {
                vec![]
            },
            frame_trace_ms: if ok {
                self.frames.iter().map(|f| Measurement::of(&f.1).median).collect()
            } else {
                vec![]
            },
        }
    }
}

/// What the oracle gathers for one driver structure.
#[derive(Default)]
struct DriverAcc {
    build: Vec<f64>,
    trace: Vec<f64>,
    rays: u64,
    memory: u64,
    built: u64,
    compacted: Option<u64>,
    disagreements: usize,
    error: Option<String>,
    kept: Vec<Option<crate::accel::driver::DriverStructure>>,
    /// Per frame, per repeat: build and trace ms.
    frames: Vec<(Vec<f64>, Vec<f64>)>,
}

impl SceneEvaluation {
    /// The best of all candidates (see [`SceneEvaluation::best_candidate`]).
    fn best_of_all(&self) -> Option<String> {
        if (self.driver_structures.is_empty() && self.refit_structures.is_empty()) || self.no_best_reason.is_some() {
            return None;
        }
        let ours = self
            .structures
            .iter()
            .filter(|s| s.valid && s.hits_agree)
            .filter_map(|s| s.name.map(|n| (n.as_str().to_string(), s.total_ms.median)));
        let theirs =
            self.driver_structures.iter().filter(|d| d.valid && d.hits_agree).map(|d| (d.name.clone(), d.total_ms));
        let refitted =
            self.refit_structures.iter().filter(|d| d.valid && d.hits_agree).map(|d| (d.name.clone(), d.total_ms));
        ours.chain(theirs).chain(refitted).min_by(|a, b| a.1.total_cmp(&b.1)).map(|b| b.0)
    }

    /// The median total of a candidate by name (a project structure's, `bvh`, or a driver structure's,
    /// `rt_fast_trace`), when it was measured valid and agreeing with the reference.
    pub fn candidate_total(&self, name: &str) -> Option<f64> {
        let ours = self
            .structures
            .iter()
            .find(|s| s.name.is_some_and(|n| n.as_str() == name) && s.valid && s.hits_agree)
            .map(|s| s.total_ms.median);
        ours.or_else(|| {
            self.driver_structures.iter().find(|d| d.name == name && d.valid && d.hits_agree).map(|d| d.total_ms)
        })
        .or_else(|| {
            self.refit_structures.iter().find(|d| d.name == name && d.valid && d.hits_agree).map(|d| d.total_ms)
        })
    }

    /// `total(name) / total(best of all candidates) - 1` ([`SceneEvaluation::best_candidate`]); `None` without
    /// driver structures, without a best, or when `name` was not validly measured.
    pub fn candidate_regret(&self, name: &str) -> Option<f64> {
        let best = self.candidate_total(self.best_candidate.as_deref()?)?;
        let t = self.candidate_total(name)?;
        (best > 0.0).then(|| t / best - 1.0)
    }

    /// The result of one structure.
    pub fn get(&self, name: StructureName) -> Option<&StructureResult> {
        self.structures.iter().find(|s| s.name == Some(name))
    }

    /// The record of `evaluate --json` (one per scene; see [`OracleRecord`]): `mesh`, `triangles`, `selected`,
    /// `oracle_best`, `regret`, `structures` (each with `name`, `build_ms`, `trace_ms`, `mrays_per_s`,
    /// `box_tests_per_ray`, `prim_tests_per_ray`, `memory_bytes`, `sah_cost`, `valid`, `hits_agree`, and more), plus
    /// the workload and the noise figures: `oracle_within_noise` (names) and `oracle_cheapest_within_noise`.
    pub fn record(&self) -> OracleRecord {
        OracleRecord {
            frames: self.frames,
            frames_measured: self.frames_measured,
            mesh: self.mesh.clone(),
            no_best_reason: self.no_best_reason.clone(),
            oracle_best: self.oracle_best,
            oracle_cheapest_within_noise: self.oracle_cheapest_within_noise,
            oracle_within_noise: self.oracle_within_noise.clone(),
            policy: None,
            predicted: None,
            cost_model: None,
            rays_per_frame: self.rays_per_frame,
            rebuild: self.rebuild,
            reference_hits: self.reference_hits,
            regret: self.regret,
            regret_within_noise: self.regret_within_noise,
            repeats: self.repeats,
            precision: self.precision,
            max_repeats: self.max_repeats,
            precision_ms: self.precision_ms,
            rounds: self.precision.map(|_| ROUNDS_EVERY_STRUCTURE.to_string()),
            view: None,
            camera: Some((&self.camera).into()),
            resolution: self.resolution,
            selected: self.selected,
            structures: self
                .structures
                .iter()
                .map(|s| StructureRecord {
                    box_tests_per_ray: s.box_tests_per_ray,
                    build_ms: s.build_ms.median,
                    build_ms_range: [s.build_ms.min, s.build_ms.max],
                    build_backend: s.build_backend.map(str::to_string),
                    upload_ms: s.upload_ms.as_ref().map(|m| m.median),
                    disagreements: s.disagreements,
                    error: s.error.clone(),
                    hits_agree: s.hits_agree,
                    memory_bytes: s.memory_bytes,
                    mrays_per_s: s.mrays_per_s,
                    name: s.name,
                    prim_tests_per_ray: s.prim_tests_per_ray,
                    sah_cost: s.sah_cost,
                    stats: s.stats,
                    total_ms: s.total_ms.median,
                    total_ms_spread: s.total_ms.spread,
                    total_ms_ci95: s.total_ms.ci95,
                    repeats_measured: Some(s.total_ms.samples).filter(|&k| k > 0),
                    precision_met: s.precision_met,
                    trace_ms: s.trace_ms.median,
                    trace_ms_range: [s.trace_ms.min, s.trace_ms.max],
                    valid: s.valid,
                    within_noise_of_best: s.within_noise_of_best,
                })
                .collect(),
            trace_backend: self.trace_backend,
            device: self.device.clone(),
            hits_checked: (self.trace_backend == TraceBackend::Vulkan)
                .then(|| "every ray against the CPU reference (triangle and t bits)".to_string()),
            ray_generation: (self.trace_backend == TraceBackend::Vulkan).then(|| "device".to_string()),
            triangles: self.triangles,
            workload: self.workload,
            driver_structures: self.driver_structures.clone(),
            refit_structures: self.refit_structures.clone(),
            best_candidate: self.best_candidate.clone(),
            selected_candidate: None,
            candidate_regret: None,
        }
    }

    /// [`SceneEvaluation::record`] as a JSON value.
    pub fn to_json(&self) -> serde_json::Value {
        self.record().to_json()
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Per structure, per repeat accumulators.
#[derive(Clone, Default)]
struct Acc {
    build: Vec<f64>,
    upload: Vec<f64>,
    trace: Vec<f64>,
    rays: u64,
    box_tests: u64,
    prim_tests: u64,
    memory: usize,
    sah: Option<f64>,
    stats: Option<AccelStats>,
    valid: bool,
    disagreements: usize,
    error: Option<String>,
    /// Built on the host after the device builder hit the driver's loop limit (some frame).
    host_fallback: bool,
}

/// Runs the oracle on one scene (see the module docs). `selected` is the characterization's choice, if any: it
/// only feeds `regret`; the measurement is the same either way. `progress` receives one line per step.
pub fn evaluate_scene(
    scene: &Animation,
    config: &OracleConfig,
    selected: Option<StructureName>,
    progress: &dyn Fn(&str),
) -> Result<SceneEvaluation, EvalError> {
    evaluate_scene_on(scene, config, selected, progress, None)
}

/// [`evaluate_scene`] with the rays traced on the device when `device` is given (`trace_backend` `vulkan`): every
/// structure is built on the host (timed), uploaded (timed, reported apart as `upload_ms` and counted in the build
/// time) and traced by the device kernel (timed by GPU timestamps); every ray's hit is compared with the CPU
/// reference. Without `device`, exactly [`evaluate_scene`].
pub fn evaluate_scene_on(
    scene: &Animation,
    config: &OracleConfig,
    selected: Option<StructureName>,
    progress: &dyn Fn(&str),
    device: Option<&DeviceOracle<'_>>,
) -> Result<SceneEvaluation, EvalError> {
    let first = scene.frames.first().ok_or_else(|| EvalError::NoFrames(scene.name.clone()))?;
    let animated = scene.frames.len() > 1;
    if animated && config.rebuild == Rebuild::Once {
        return Err(EvalError::Config {
            scene: scene.name.clone(),
            reason: "building once is only meaningful for a static scene (the oracle measures no refits); use per-frame rebuilds"
                .into(),
        });
    }
    let (measured, frames): (&[Mesh], usize) = if animated {
        let f = config.frames.unwrap_or(scene.frames.len()).clamp(1, scene.frames.len());
        (&scene.frames[..f], f)
    } else {
        (&scene.frames[..1], config.frames.unwrap_or(1).max(1))
    };
    let repeats = config.repeats.max(1);
    let camera = config.camera.unwrap_or_else(|| {
        let b = measured.iter().fold(crate::geom::Aabb::EMPTY, |a, m| a.union(&mesh_bounds(m)));
        Camera::frame(&b)
    });
    let names = &config.structures;
    let mut acc: Vec<Acc> = vec![Acc { valid: true, ..Default::default() }; names.len()];
    // Totals per repeat: a static scene's frame stands for `frames` frames.
    let (build_factor, trace_factor) = if animated {
        (1.0, 1.0)
    } else {
        let f = frames as f64;
        (if config.rebuild == Rebuild::PerFrame { f } else { 1.0 }, f)
    };
    let precision = config.precision.filter(|p| p.is_finite() && *p > 0.0);
    let max_repeats = if precision.is_some() { config.max_repeats.max(repeats) } else { repeats };
    // Whether frame 0's repeats so far settle a structure's total (precise oracle).
    let settled = |a: &Acc| match precision {
        None => true,
        Some(p) => {
            let totals: Vec<f64> =
                a.build.iter().zip(&a.trace).map(|(b, t)| b * build_factor + t * trace_factor).collect();
            Measurement::of(&totals).precise_to(p)
        }
    };
    let mut dacc: Vec<DriverAcc> = config
        .driver
        .iter()
        .map(|_| DriverAcc {
            build: vec![0.0; repeats],
            trace: vec![0.0; repeats],
            kept: (0..repeats).map(|_| None).collect(),
            ..Default::default()
        })
        .collect();
    let refits: Vec<RefitCandidate> = if animated { config.refit.clone() } else { Vec::new() };
    let mut racc: Vec<RefitAcc> = refits
        .iter()
        .map(|_| RefitAcc { kept: (0..repeats).map(|_| None).collect(), valid: true, ..Default::default() })
        .collect();
    let mut rays_per_frame = 0;
    let mut reference_hits = 0u64;
    let mut rays_total = 0u64;
    for (fi, mesh) in measured.iter().enumerate() {
        progress(&format!("{}: frame {}/{}: rays and reference hits", scene.name, fi + 1, measured.len()));
        let reference = crate::accel::bvh::Bvh::build(mesh)?;
        let over =
            |reason: String| EvalError::Config { scene: scene.name.clone(), reason: format!("reference {reason}") };
        if config.workload != WorkloadKind::Primary {
            // The secondary rays start where the reference's primary rays hit.
            let primary = RaySet {
                kind: WorkloadKind::Primary,
                rays: crate::trace::workload::primary_rays(&camera, config.resolution, config.resolution),
                any_hit: false,
            };
            check_trace_budget(&reference, &primary, config.max_tests_per_ray).map_err(over)?;
        }
        let rays: RaySet = build_workload(config.workload, mesh, &camera, config.resolution, &reference);
        check_trace_budget(&reference, &rays, config.max_tests_per_ray).map_err(over)?;
        if fi == 0 {
            rays_per_frame = rays.rays.len();
        }
        let want: TraceOutcome = trace(&reference, &rays);
        drop(reference);
        reference_hits +=
            (want.hits.iter().filter(|h| h.is_some()).count() + want.occluded.iter().filter(|&&o| o).count()) as u64;
        rays_total += rays.rays.len() as u64;
        // The device builders read the frame from device memory, where an engine's geometry already is (untimed).
        let mesh_buffers = match device {
            Some(d) if names.iter().any(|&n| DeviceOracle::builds_on_device(n)) || !config.driver.is_empty() => Some(
                crate::gpu::MeshBuffers::upload(d.ctx, &mesh.positions, &mesh.indices)
                    .map_err(|e| EvalError::Device(e.to_string()))?,
            ),
            _ => None,
        };
        // Primary and shadow rays are made on the device (never uploaded), checked once against the host's, bit
        // for bit.
        let device_rays = match (device, config.workload) {
            (Some(d), WorkloadKind::Primary) => {
                Some(d.primary_rays(&camera, config.resolution, &rays.rays).map_err(EvalError::Device)?)
            }
            (Some(d), kind) => {
                Some(d.secondary_rays(kind, &camera, config.resolution, mesh, &rays.rays).map_err(EvalError::Device)?)
            }
            (None, _) => None,
        };
        // Repeats, in rounds of every structure (interleaved). On frame 0 each structure runs `repeats` times and,
        // under a precision target, further rounds of all of them follow until every total is precise enough (or
        // `max_repeats` rounds, more while `precision_ms` allows); later frames repeat each structure as often as
        // frame 0 did, so that every repeat's total covers every frame.
        let mut r = 0;
        loop {
            // Frame 0, past `repeats`: another round of every structure while one is short of the target, up to
            // `max_repeats` rounds, or past them while the record's measured time allows.
            let another_round = fi == 0 && r >= repeats && precision.is_some() && {
                let live = acc.iter().filter(|a| a.error.is_none());
                let short = live.clone().any(|a| !settled(a));
                let spent: f64 = live.flat_map(|a| a.build.iter().chain(&a.trace)).sum();
                short && (r < max_repeats || (r < MAX_PRECISION_REPEATS && spent < config.precision_ms))
            };
            let mut ran = false;
            for (si, &name) in names.iter().enumerate() {
                let a = &mut acc[si];
                if a.error.is_some() {
                    continue;
                }
                let wanted = match fi {
                    0 => r < repeats || another_round,
                    _ => r < a.build.len(),
                };
                if !wanted {
                    continue;
                }
                ran = true;
                if fi == 0 {
                    a.build.push(0.0);
                    a.upload.push(0.0);
                    a.trace.push(0.0);
                }
                let bound = match fi {
                    0 if r < max_repeats => max_repeats,
                    0 => MAX_PRECISION_REPEATS.max(r + 1),
                    _ => a.build.len(),
                };
                progress(&format!(
                    "{}: frame {}/{} repeat {}/{}{}: {name}",
                    scene.name,
                    fi + 1,
                    measured.len(),
                    r + 1,
                    if r < repeats { repeats } else { bound },
                    if r < repeats || fi > 0 { "" } else { " (precision)" },
                ));
                let t = Instant::now();
                let built = build_structure(name, mesh);
                let build_ms = ms(t);
                let s: Box<dyn AccelStructure> = match built {
                    Ok(s) => s,
                    Err(e) => {
                        a.error = Some(e.to_string());
                        a.valid = false;
                        continue;
                    }
                };
                if r == 0 {
                    if let Err(e) = check_trace_budget(s.as_ref(), &rays, config.max_tests_per_ray) {
                        a.error = Some(e);
                        a.valid = false;
                        continue;
                    }
                }
                let run = match (device, &mesh_buffers) {
                    (None, _) => Ok((build_ms, 0.0, trace(s.as_ref(), &rays))),
                    (Some(d), Some(m)) if DeviceOracle::builds_on_device(name) => {
                        match d.run_device_built(name, m, &rays, device_rays.as_ref(), (s.as_ref(), mesh)) {
                            Ok(Some((b, o))) => Ok((b, 0.0, o)),
                            // The driver cut the device builder's loops: the host build, uploaded.
                            Ok(None) => {
                                a.host_fallback = true;
                                d.run(s.as_ref(), &rays, device_rays.as_ref()).map(|(u, o)| (build_ms + u, u, o))
                            }
                            Err(e) => Err(e),
                        }
                    }
                    (Some(d), _) => d.run(s.as_ref(), &rays, device_rays.as_ref()).map(|(u, o)| (build_ms + u, u, o)),
                };
                let (build_ms, upload_ms, out) = match run {
                    Ok(x) => x,
                    Err(e) => {
                        a.error = Some(format!("device: {e}"));
                        a.valid = false;
                        continue;
                    }
                };
                a.build[r] += build_ms;
                a.upload[r] += upload_ms;
                a.trace[r] += out.seconds * 1e3;
                if r == 0 {
                    a.rays += out.rays() as u64;
                    a.box_tests += out.counters.box_tests;
                    a.prim_tests += out.counters.prim_tests;
                    a.memory = a.memory.max(s.memory_bytes());
                    a.disagreements += count_disagreements(&out, &want);
                    match s.validate() {
                        Ok(st) => {
                            if fi == 0 {
                                a.stats = Some(st);
                            }
                        }
                        Err(e) => {
                            a.valid = false;
                            a.error.get_or_insert(e.to_string());
                        }
                    }
                    if fi == 0 {
                        a.sah = s.sah_cost();
                    }
                }
            }
            if !ran {
                break;
            }
            r += 1;
        }
        for (di, &flags) in config.driver.iter().enumerate() {
            let a = &mut dacc[di];
            if a.error.is_some() {
                continue;
            }
            let (Some(d), Some(m)) = (device, &mesh_buffers) else {
                a.error = Some("driver structures are traced with ray queries: needs --trace-backend vulkan".into());
                continue;
            };
            let Some(builder) = &d.driver else {
                a.error = Some(format!(
                    "{} has no VK_KHR_acceleration_structure / VK_KHR_ray_query (lavapipe has them from Mesa 24.1)",
                    d.ctx.caps().name
                ));
                continue;
            };
            let extent = mesh_bounds(mesh).extent().max_element();
            a.frames.push((vec![0.0; repeats], vec![0.0; repeats]));
            for r in 0..repeats {
                progress(&format!(
                    "{}: frame {}/{} repeat {}/{}: {}",
                    scene.name,
                    fi + 1,
                    measured.len(),
                    r + 1,
                    repeats,
                    flags.name()
                ));
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
                let traced = match &device_rays {
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
                if let Some(f) = a.frames.last_mut() {
                    f.0[r] = s.gpu_ms();
                    f.1[r] = out.gpu_ms;
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
        for (ri, &cand) in refits.iter().enumerate() {
            let a = &mut racc[ri];
            if a.error.is_some() {
                continue;
            }
            if device.is_some() {
                a.error = Some("refit candidates are measured on the CPU tracer only (--trace-backend cpu)".into());
                continue;
            }
            a.frames.push((vec![0.0; repeats], vec![0.0; repeats]));
            for r in 0..repeats {
                progress(&format!(
                    "{}: frame {}/{} repeat {}/{}: {}",
                    scene.name,
                    fi + 1,
                    measured.len(),
                    r + 1,
                    repeats,
                    cand.name()
                ));
                let t = Instant::now();
                let updated = match a.kept[r].take() {
                    Some(mut s) => s.refit(mesh).map(|_| s),
                    None => cand.build(mesh),
                };
                let update_ms = ms(t);
                let s = match updated {
                    Ok(s) => s,
                    Err(e) => {
                        a.error = Some(e.to_string());
                        break;
                    }
                };
                if r == 0 {
                    if let Err(e) = check_trace_budget(s.accel(), &rays, config.max_tests_per_ray) {
                        a.error = Some(e);
                        break;
                    }
                }
                let out = trace(s.accel(), &rays);
                if let Some(f) = a.frames.last_mut() {
                    f.0[r] = update_ms;
                    f.1[r] = out.seconds * 1e3;
                }
                if r == 0 {
                    a.rays += out.rays() as u64;
                    a.box_tests += out.counters.box_tests;
                    a.prim_tests += out.counters.prim_tests;
                    a.memory = a.memory.max(s.accel().memory_bytes());
                    a.disagreements += count_disagreements(&out, &want);
                    if let Err(e) = s.accel().validate() {
                        a.valid = false;
                        a.error.get_or_insert(e.to_string());
                    }
                    let sah = s.accel().sah_cost();
                    if fi == 0 {
                        a.sah_first = sah;
                    }
                    a.sah_last = sah;
                }
                a.kept[r] = Some(s);
            }
        }
    }
    let mut results: Vec<StructureResult> = names
        .iter()
        .zip(&acc)
        .map(|(&name, a)| {
            let builds: Vec<f64> = a.build.iter().map(|b| b * build_factor).collect();
            let traces: Vec<f64> = a.trace.iter().map(|t| t * trace_factor).collect();
            let totals: Vec<f64> = builds.iter().zip(&traces).map(|(b, t)| b + t).collect();
            let measured_ok = a.error.is_none() || a.rays > 0;
            let trace_ms = Measurement::of(&a.trace);
            let per_ray = |x: u64| {
                if a.rays > 0 {
                    x as f64 / a.rays as f64
                } else {
                    0.0
                }
            };
            StructureResult {
                name: Some(name),
                build_ms: if measured_ok { Measurement::of(&builds) } else { Measurement::default() },
                build_backend: device.map(|_| {
                    if DeviceOracle::builds_on_device(name) && !a.host_fallback {
                        "device"
                    } else {
                        "host"
                    }
                }),
                upload_ms: device.filter(|_| !DeviceOracle::builds_on_device(name) || a.host_fallback).map(|_| {
                    let uploads: Vec<f64> = a.upload.iter().map(|u| u * build_factor).collect();
                    Measurement::of(&uploads)
                }),
                trace_ms: if measured_ok { Measurement::of(&traces) } else { Measurement::default() },
                total_ms: if measured_ok { Measurement::of(&totals) } else { Measurement::default() },
                rays: a.rays,
                mrays_per_s: if trace_ms.median > 0.0 { a.rays as f64 / (trace_ms.median * 1e3) } else { 0.0 },
                box_tests_per_ray: per_ray(a.box_tests),
                prim_tests_per_ray: per_ray(a.prim_tests),
                memory_bytes: a.memory,
                sah_cost: a.sah,
                stats: a.stats,
                valid: a.valid && a.error.is_none(),
                hits_agree: a.disagreements == 0 && a.rays > 0,
                disagreements: a.disagreements,
                within_noise_of_best: false,
                precision_met: precision.map(|p| measured_ok && Measurement::of(&totals).precise_to(p)),
                error: a.error.clone(),
            }
        })
        .collect();
    // Rays that all miss still measure work (a ray that hits nothing visits every node and cell on its way out:
    // zero-area triangles, coordinates where the f32 test finds no hit), so they rank the structures as any other
    // rays do; a workload that traces no ray at all (secondary rays of a camera that sees nothing) leaves the
    // builds alone, which rank nothing for tracing.
    let no_best_reason = (rays_total == 0).then(|| {
        "the workload traces no ray (no primary ray hits the scene, so there are no secondary rays): the totals are \
         builds alone, so no structure is named best"
            .to_string()
    });
    let best = results
        .iter()
        .filter(|_| no_best_reason.is_none())
        .filter(|s| s.valid && s.hits_agree)
        .min_by(|a, b| a.total_ms.median.total_cmp(&b.total_ms.median))
        .map(|s| (s.name, s.total_ms.clone()));
    if let Some((_, bt)) = &best {
        for s in results.iter_mut() {
            s.within_noise_of_best = s.valid && s.hits_agree && s.total_ms.within_noise(bt);
        }
    }
    let oracle_best = best.as_ref().and_then(|b| b.0);
    let near: Vec<&StructureResult> = results.iter().filter(|s| s.within_noise_of_best).collect();
    let oracle_within_noise: Vec<StructureName> = near.iter().filter_map(|s| s.name).collect();
    let oracle_cheapest_within_noise = near
        .iter()
        .min_by(|a, b| a.build_ms.median.total_cmp(&b.build_ms.median).then(a.memory_bytes.cmp(&b.memory_bytes)))
        .and_then(|s| s.name);
    let sel = selected.and_then(|n| results.iter().find(|s| s.name == Some(n)));
    let (regret, regret_within_noise) = match (sel, &best) {
        (Some(s), Some((_, bt))) if s.valid && bt.median > 0.0 => {
            (Some(s.total_ms.median / bt.median - 1.0), Some(s.within_noise_of_best))
        }
        _ => (None, None),
    };
    let mut e = SceneEvaluation {
        best_candidate: None,
        refit_structures: Vec::new(),
        mesh: scene.name.clone(),
        triangles: first.triangle_count(),
        frames_measured: measured.len(),
        frames,
        workload: config.workload,
        resolution: config.resolution,
        rebuild: config.rebuild,
        repeats,
        precision,
        max_repeats: precision.map(|_| max_repeats),
        precision_ms: precision.and(Some(config.precision_ms).filter(|x| x.is_finite()).map(|x| x.max(0.0))),
        camera,
        rays_per_frame,
        selected,
        oracle_best,
        oracle_within_noise,
        oracle_cheapest_within_noise,
        regret,
        regret_within_noise,
        reference_hits,
        no_best_reason,
        trace_backend: if device.is_some() { TraceBackend::Vulkan } else { TraceBackend::Cpu },
        device: device.map(|d| DeviceRecord::of(d.ctx)),
        structures: results,
        driver_structures: config
            .driver
            .iter()
            .zip(&dacc)
            .map(|(&flags, a)| {
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
            })
            .collect(),
    };
    e.refit_structures = refits.iter().zip(&racc).map(|(c, a)| a.result(c.name(), repeats)).collect();
    e.best_candidate = e.best_of_all();
    Ok(e)
}
