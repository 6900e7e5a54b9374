//! Device traversal of every structure: the layouts the kernels read, their upload, and the traversal kernel
//! (`glsl/trace.comp`).
//!
//! # Layouts
//!
//! One definition, in `glsl/include/trace.glsl` (and `glsl/include/bvh.glsl` for [`BvhNode`]); the Rust types here
//! are generated from its reflection. An engine can traverse an uploaded structure in its own shaders by including
//! those two files:
//!
//! | structure | nodes | records |
//! |---|---|---|
//! | BVH, LBVH, HLBVH | [`BvhNode`] (32 bytes), root 0 | [`TriRecord`] in leaf order |
//! | kd-tree | [`KdNode`] (8 bytes), root 0, children `k + 1` and `k + offset` | [`TriRecord`] in mesh order, leaves list references (`u32`) |
//! | grid | `cells + 1` cell starts (`u32`) into the references | [`TriRecord`] in mesh order, references are mesh indices |
//! | BIH | [`BihNode`] (12 bytes), root 0, children `c` and `c + 1` | [`TriRecord`] in leaf order |
//!
//! Each structure also has a [`TraceScene`] header (scene box, grid resolution and cell size).
//!
//! # Exactness
//!
//! The kernel repeats the CPU tracer's arithmetic operation for operation (`precise`, no contraction; divisions and
//! square roots correctly rounded through f64), its tie rule and its traversal order, so each ray's hit triangle,
//! `t` bits and box and triangle test counts equal [`crate::accel::AccelStructure::intersect`]'s. It needs
//! `shaderFloat64` ([`DeviceTracer::new`] says so when the device lacks it) and a device that does not flush f32
//! denormals in the few places they can occur (a determinant or a distance below 2^-126).
//!
//! # Stack
//!
//! Each invocation keeps its stack in device memory, sized from the tree's depth ([`DeviceStructure::stack_entries`]),
//! and traces rays `g, g + G, ...`; the number of invocations `G` is chosen so that all stacks fit
//! [`STACK_BUDGET_BYTES`]. No tree is too deep for it; a ray whose stack would still overflow reports
//! [`TraceStatus::StackFull`] instead of a wrong hit.

use super::{AccelError, StructureName};
use crate::geom::{Aabb, Hit, Ray, Triangle};
use crate::gpu::shaders::layout::{TRACE_MISS, TRACE_OK, TRACE_STACK_ENTRY_BYTES, TRACE_STACK_FULL, TRACE_STEP_LIMIT};
use crate::gpu::{shaders, Buffer, Context, GpuError, Kernel, KernelDesc, MemoryKind, Pass, Recorder, Timer};
use glam::Vec3;

pub use crate::gpu::shaders::trace::Push as TracePush;
pub use crate::gpu::shaders::trace_rays::Push as TraceRaysPush;
pub use crate::gpu::shaders::trace_records::Push as TraceRecordsPush;
pub use crate::gpu::shaders::trace_secondary::Push as TraceSecondaryPush;
pub use crate::gpu::shaders::{BihNode, BvhNode, KdNode, TraceHit, TraceRay, TraceScene, TriRecord};

/// The most bytes of traversal stacks one dispatch uses (all invocations together): 64 MiB, or less where the
/// device's `maxMemoryAllocationSize` is smaller.
pub const STACK_BUDGET_BYTES: u64 = 64 << 20;

/// Where rays are traced: the oracle's `--trace-backend`, and the tracer a calibration describes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TraceBackend {
    /// The counting CPU tracer ([`crate::trace::trace`], rayon over rays); trace time is host wall time.
    #[default]
    Cpu,
    /// The device traversal kernel ([`crate::accel::device`]); trace time is the kernel's GPU timestamps.
    Vulkan,
}

impl TraceBackend {
    /// `cpu` or `vulkan`.
    pub fn as_str(self) -> &'static str {
        match self {
            TraceBackend::Cpu => "cpu",
            TraceBackend::Vulkan => "vulkan",
        }
    }
}

impl std::str::FromStr for TraceBackend {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "cpu" => Ok(TraceBackend::Cpu),
            "vulkan" => Ok(TraceBackend::Vulkan),
            other => Err(format!("unknown trace backend {other:?} (cpu, vulkan)")),
        }
    }
}

/// The device a device oracle ran on, as its records name it.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeviceRecord {
    /// Device name.
    pub name: String,
    /// Device type (`cpu`, `discrete`, ...).
    #[serde(default)]
    pub device_type: String,
    /// Driver name and version.
    #[serde(default)]
    pub driver: String,
    /// Raw driver version.
    #[serde(default)]
    pub driver_version: u32,
    /// `deviceUUID`, 32 hex digits.
    #[serde(default)]
    pub device_uuid: String,
}

impl DeviceRecord {
    /// The record of a context's device.
    pub fn of(ctx: &crate::gpu::Context) -> Self {
        let c = ctx.caps();
        DeviceRecord {
            name: c.name.clone(),
            device_type: c.device_type.as_str().to_string(),
            driver: c.driver.clone(),
            driver_version: c.driver_version,
            device_uuid: c.device_uuid.clone(),
        }
    }
}

/// How a structure is laid out for the traversal kernel (its `STRUCTURE` constant).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TraversalKind {
    /// Binary BVH of [`BvhNode`]s (binned-SAH BVH, LBVH, HLBVH).
    Bvh,
    /// kd-tree of [`KdNode`]s.
    KdTree,
    /// Uniform grid.
    Grid,
    /// Bounding interval hierarchy of [`BihNode`]s.
    Bih,
}

impl TraversalKind {
    /// The four kinds, in the order of the kernel's `STRUCTURE` constant.
    pub const ALL: [TraversalKind; 4] =
        [TraversalKind::Bvh, TraversalKind::KdTree, TraversalKind::Grid, TraversalKind::Bih];

    fn constant(self) -> u32 {
        self as u32
    }
}

/// A structure's arrays as the traversal kernel reads them, borrowed from a CPU structure
/// ([`crate::accel::AccelStructure::device_layout`]) or put together by an engine. [`DeviceStructure::upload`]
/// checks every index before anything reaches the device.
#[derive(Clone, Copy, Debug)]
pub enum DeviceLayout<'a> {
    /// A binary BVH: nodes (root 0), triangle records in leaf order and the mesh index of each.
    Bvh {
        /// The nodes.
        nodes: &'a [BvhNode],
        /// Triangle records in leaf order.
        tris: &'a [Triangle],
        /// Mesh index of each record.
        ids: &'a [u32],
    },
    /// A kd-tree: nodes (root 0), leaf references into the records, records and mesh indices, the scene box.
    KdTree {
        /// The nodes.
        nodes: &'a [KdNode],
        /// Leaf references (indices into `tris`).
        refs: &'a [u32],
        /// Triangle records.
        tris: &'a [Triangle],
        /// Mesh index of each record.
        ids: &'a [u32],
        /// The scene box the traversal clips the ray to.
        bounds: Aabb,
    },
    /// A uniform grid: cell starts into the references (mesh indices), records in mesh order.
    Grid {
        /// The grid's box.
        bounds: Aabb,
        /// Cells per axis.
        res: [u32; 3],
        /// Cell size.
        cell_size: Vec3,
        /// Inverse cell size, as the traversal uses it.
        inv_cell: Vec3,
        /// `cells + 1` starts into `refs`; cell `(x, y, z)` is `x + res[0] * (y + res[1] * z)`.
        cell_start: &'a [u32],
        /// References: mesh indices.
        refs: &'a [u32],
        /// Triangle records in mesh order.
        tris: &'a [Triangle],
    },
    /// A bounding interval hierarchy: nodes (root 0), records in leaf order and their mesh indices, the scene box.
    Bih {
        /// The nodes.
        nodes: &'a [BihNode],
        /// Triangle records in leaf order.
        tris: &'a [Triangle],
        /// Mesh index of each record.
        ids: &'a [u32],
        /// The scene box.
        bounds: Aabb,
    },
}

/// Why a ray's traversal stopped short (never on a structure this crate built).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TraceStatus {
    /// The traversal ran to its end.
    Ok,
    /// The stack was too small for the tree.
    StackFull,
    /// More than 65,535^2 steps.
    StepLimit,
    /// A status the kernel does not write (a corrupted result).
    Unknown(u32),
}

impl TraceStatus {
    fn of(s: u32) -> Self {
        match s {
            TRACE_OK => TraceStatus::Ok,
            TRACE_STACK_FULL => TraceStatus::StackFull,
            TRACE_STEP_LIMIT => TraceStatus::StepLimit,
            other => TraceStatus::Unknown(other),
        }
    }
}

impl TraceHit {
    /// The closest hit (closest-hit rays) or an occluder (any-hit rays), `None` for a miss.
    pub fn hit(&self) -> Option<Hit> {
        (self.triangle != TRACE_MISS).then_some(Hit { t: self.t, triangle: self.triangle, u: self.u, v: self.v })
    }
    /// Whether the traversal ran to its end.
    pub fn status(&self) -> TraceStatus {
        TraceStatus::of(self.status)
    }
}

impl From<&Ray> for TraceRay {
    fn from(r: &Ray) -> Self {
        TraceRay { origin: r.origin.to_array(), tmin: r.tmin, dir: r.dir.to_array(), tmax: r.tmax }
    }
}

fn bad(reason: String) -> AccelError {
    AccelError::Invalid { structure: "device layout", reason }
}

fn records(tris: &[Triangle], ids: impl Fn(usize) -> u32) -> Vec<TriRecord> {
    tris.iter()
        .enumerate()
        .map(|(i, t)| TriRecord {
            v0: t.v0.to_array(),
            id: ids(i),
            e1: t.e1.to_array(),
            pad_a: 0,
            e2: t.e2.to_array(),
            pad_b: 0,
        })
        .collect()
}

/// Largest depth (edges from the root) of a binary tree given as a child function, checking that the nodes form one
/// tree rooted at 0 (every node reached at most once) and every leaf range lies inside `0..leaf_limit`.
fn tree_depth(
    count: usize,
    children: impl Fn(usize) -> Option<(usize, usize)>,
    leaf: impl Fn(usize) -> (usize, usize),
    leaf_limit: usize,
) -> Result<usize, AccelError> {
    if count == 0 {
        return Ok(0);
    }
    let mut seen = vec![false; count];
    let mut stack = vec![(0usize, 0usize)];
    let mut depth = 0;
    while let Some((k, d)) = stack.pop() {
        if k >= count || std::mem::replace(&mut seen[k], true) {
            return Err(bad(format!("node {k} out of range or reached twice")));
        }
        depth = depth.max(d);
        match children(k) {
            Some((a, b)) => {
                stack.push((a, d + 1));
                stack.push((b, d + 1));
            }
            None => {
                let (first, n) = leaf(k);
                if first.checked_add(n).is_none_or(|e| e > leaf_limit) {
                    return Err(bad(format!("leaf {k}: records {first}..{first}+{n} past {leaf_limit}")));
                }
            }
        }
    }
    Ok(depth)
}

fn check_ids(ids: &[u32], tris: usize) -> Result<(), AccelError> {
    if ids.len() != tris {
        return Err(bad(format!("{} mesh indices for {tris} records", ids.len())));
    }
    match ids.iter().position(|&i| i == TRACE_MISS) {
        Some(k) => Err(bad(format!("record {k}: mesh index {TRACE_MISS:#x} is reserved for a miss"))),
        None => Ok(()),
    }
}

fn scene_header(bounds: &Aabb, nodes: usize) -> TraceScene {
    TraceScene { lo: bounds.min.to_array(), hi: bounds.max.to_array(), nodes: nodes as u32, ..TraceScene::default() }
}

/// What the upload of a [`DeviceLayout`] sends: the arrays, checked, and the header.
struct Prepared {
    kind: TraversalKind,
    nodes: Vec<u8>,
    records: Vec<TriRecord>,
    refs: Vec<u32>,
    scene: TraceScene,
    stack_entries: u32,
}

impl DeviceLayout<'_> {
    /// Which traversal the layout needs.
    pub fn kind(&self) -> TraversalKind {
        match self {
            DeviceLayout::Bvh { .. } => TraversalKind::Bvh,
            DeviceLayout::KdTree { .. } => TraversalKind::KdTree,
            DeviceLayout::Grid { .. } => TraversalKind::Grid,
            DeviceLayout::Bih { .. } => TraversalKind::Bih,
        }
    }

    fn prepare(&self) -> Result<Prepared, AccelError> {
        let too_many = |what: &'static str, count: usize| AccelError::TooLarge {
            structure: "device layout",
            what,
            count,
            limit: u32::MAX as usize - 1,
        };
        let fits = |what: &'static str, n: usize| if n >= u32::MAX as usize { Err(too_many(what, n)) } else { Ok(()) };
        Ok(match *self {
            DeviceLayout::Bvh { nodes, tris, ids } => {
                fits("nodes", nodes.len())?;
                fits("records", tris.len())?;
                check_ids(ids, tris.len())?;
                let n = nodes.len();
                let depth = tree_depth(
                    n,
                    |k| {
                        (!nodes[k].is_leaf())
                            .then(|| (nodes[k].left_or_first as usize, nodes[k].right_or_count as usize))
                    },
                    |k| (nodes[k].left_or_first as usize, nodes[k].count() as usize),
                    tris.len(),
                )?;
                Prepared {
                    kind: TraversalKind::Bvh,
                    nodes: bytemuck::cast_slice(nodes).to_vec(),
                    records: records(tris, |i| ids[i]),
                    refs: Vec::new(),
                    scene: scene_header(&Aabb::EMPTY, n),
                    stack_entries: depth as u32 + 1,
                }
            }
            DeviceLayout::KdTree { nodes, refs, tris, ids, bounds } => {
                fits("nodes", nodes.len())?;
                fits("references", refs.len())?;
                check_ids(ids, tris.len())?;
                if let Some(k) = refs.iter().position(|&r| r as usize >= tris.len()) {
                    return Err(bad(format!("kd-tree reference {k} past the {} records", tris.len())));
                }
                let n = nodes.len();
                let kd_leaf = |k: usize| nodes[k].flags & 3 == 3;
                let depth = tree_depth(
                    n,
                    |k| (!kd_leaf(k)).then(|| (k + 1, k + (nodes[k].flags >> 2) as usize)),
                    |k| ((nodes[k].flags >> 2) as usize, nodes[k].split_or_count as usize),
                    refs.len(),
                )?;
                Prepared {
                    kind: TraversalKind::KdTree,
                    nodes: bytemuck::cast_slice(nodes).to_vec(),
                    records: records(tris, |i| ids[i]),
                    refs: refs.to_vec(),
                    scene: scene_header(&bounds, n),
                    stack_entries: depth as u32 + 1,
                }
            }
            DeviceLayout::Grid { bounds, res, cell_size, inv_cell, cell_start, refs, tris } => {
                fits("records", tris.len())?;
                fits("references", refs.len())?;
                if !tris.is_empty() {
                    if !res.iter().all(|&r| r > 0 && r < (1 << 24)) {
                        return Err(bad(format!("grid: resolution {res:?}")));
                    }
                    let cells = res.iter().try_fold(1usize, |a, &r| a.checked_mul(r as usize));
                    if cells.and_then(|c| c.checked_add(1)) != Some(cell_start.len()) {
                        return Err(bad(format!("grid: {} cell starts for {res:?} cells", cell_start.len())));
                    }
                    if cell_start.windows(2).any(|w| w[0] > w[1]) || cell_start.last() != Some(&(refs.len() as u32)) {
                        return Err(bad("grid: cell starts not monotone or not ending at the references".into()));
                    }
                    if let Some(k) = refs.iter().position(|&r| r as usize >= tris.len()) {
                        return Err(bad(format!("grid reference {k} past the {} records", tris.len())));
                    }
                }
                let mut scene = scene_header(&bounds, tris.len());
                [scene.res_x, scene.res_y, scene.res_z] = res;
                scene.cell_size = cell_size.to_array();
                scene.inv_cell = inv_cell.to_array();
                Prepared {
                    kind: TraversalKind::Grid,
                    nodes: bytemuck::cast_slice(cell_start).to_vec(),
                    records: records(tris, |i| i as u32),
                    refs: refs.to_vec(),
                    scene,
                    stack_entries: 0,
                }
            }
            DeviceLayout::Bih { nodes, tris, ids, bounds } => {
                fits("nodes", nodes.len())?;
                fits("records", tris.len())?;
                check_ids(ids, tris.len())?;
                let n = nodes.len();
                let bih_leaf = |k: usize| nodes[k].flags & 3 == 3;
                let depth = tree_depth(
                    n,
                    |k| (!bih_leaf(k)).then(|| ((nodes[k].flags >> 2) as usize, (nodes[k].flags >> 2) as usize + 1)),
                    |k| ((nodes[k].flags >> 2) as usize, nodes[k].clip[0].to_bits() as usize),
                    tris.len(),
                )?;
                Prepared {
                    kind: TraversalKind::Bih,
                    nodes: bytemuck::cast_slice(nodes).to_vec(),
                    records: records(tris, |i| ids[i]),
                    refs: Vec::new(),
                    scene: scene_header(&bounds, n),
                    stack_entries: depth as u32 + 1,
                }
            }
        })
    }
}

/// Errors of uploading or tracing on the device.
#[derive(Debug, thiserror::Error)]
pub enum DeviceTraceError {
    /// The layout is malformed (an index out of range, nodes that are not one tree).
    #[error(transparent)]
    Layout(#[from] AccelError),
    /// The device failed or lacks what the kernel needs.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The structure has no device layout.
    #[error("{0}: no device traversal for this structure")]
    NoLayout(StructureName),
    /// Some rays stopped short (never on a structure this crate built).
    #[error("{count} rays stopped short, the first ({first}) with {status:?}")]
    Incomplete {
        /// Rays that stopped short.
        count: usize,
        /// The first of them.
        first: usize,
        /// Its status.
        status: TraceStatus,
    },
}

/// A structure uploaded for the traversal kernel.
pub struct DeviceStructure {
    kind: TraversalKind,
    nodes: Buffer,
    records: Buffer,
    refs: Buffer,
    scene: Buffer,
    stack_entries: u32,
    bytes: u64,
    upload_seconds: f64,
}

impl std::fmt::Debug for DeviceStructure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceStructure")
            .field("kind", &self.kind)
            .field("stack_entries", &self.stack_entries)
            .field("bytes", &self.bytes)
            .finish()
    }
}

impl DeviceStructure {
    /// Checks `layout` and uploads it (submits and waits).
    ///
    /// # Errors
    ///
    /// [`DeviceTraceError::Layout`] for a malformed layout, [`DeviceTraceError::Gpu`] when a buffer cannot be made.
    pub fn upload(ctx: &Context, layout: &DeviceLayout<'_>) -> Result<Self, DeviceTraceError> {
        let start = std::time::Instant::now();
        let p = layout.prepare()?;
        let nodes = ctx.upload("trace nodes", &p.nodes)?;
        let records = ctx.upload("trace records", &p.records)?;
        let refs = ctx.upload("trace references", &p.refs)?;
        let scene = ctx.upload("trace scene", std::slice::from_ref(&p.scene))?;
        let bytes = nodes.size() + records.size() + refs.size() + scene.size();
        Ok(DeviceStructure {
            kind: p.kind,
            nodes,
            records,
            refs,
            scene,
            stack_entries: p.stack_entries,
            bytes,
            upload_seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// A grid built on the device ([`crate::accel::gpu_grid::GpuGrid::into_device_structure`]): its cell starts,
    /// records and references, and the scene header.
    pub(crate) fn from_grid_parts(
        cell_start: Buffer,
        records: Buffer,
        refs: Buffer,
        scene: Buffer,
        upload: std::time::Duration,
    ) -> Self {
        let bytes = cell_start.size() + records.size() + refs.size() + scene.size();
        DeviceStructure {
            kind: TraversalKind::Grid,
            nodes: cell_start,
            records,
            refs,
            scene,
            stack_entries: 0,
            bytes,
            upload_seconds: upload.as_secs_f64(),
        }
    }

    /// Which traversal it needs.
    pub fn kind(&self) -> TraversalKind {
        self.kind
    }
    /// Stack entries each invocation needs: the tree's depth plus one (0 for the grid).
    pub fn stack_entries(&self) -> u32 {
        self.stack_entries
    }
    /// Sets the stack entries per invocation (at least 1). Fewer than the tree needs is safe: a trace that fills
    /// the stack is run again with twice as many ([`DeviceTracer::trace`]), which is how a device-built tree of
    /// unknown depth finds its size; more than it needs costs memory only.
    pub fn set_stack_entries(&mut self, entries: u32) {
        self.stack_entries = entries.max(1);
    }
    /// Device bytes of its buffers.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }
    /// Host wall seconds of [`DeviceStructure::upload`] (checks, staging, copies, waits).
    pub fn upload_seconds(&self) -> f64 {
        self.upload_seconds
    }
}

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
    /// `width * height` [`TraceRay`]s, row by row): bit for bit the rays of `trace::Camera::ray`, so a primary
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

/// A pinhole camera as the primary-ray kernel takes it (the fields of `trace::Camera`, which converts into it):
/// pixel `(x, y)` of a `w x h` image looks along `forward + right * sx + up * sy`, normalized, with
/// `sx = ((x + 0.5) / w * 2 - 1) * tan_half_fov * w / h` and `sy = (1 - (y + 0.5) / h * 2) * tan_half_fov`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pinhole {
    /// Eye position.
    pub eye: Vec3,
    /// Unit viewing direction.
    pub forward: Vec3,
    /// Unit right vector.
    pub right: Vec3,
    /// Unit up vector.
    pub up: Vec3,
    /// `tan(fov_y / 2)`.
    pub tan_half_fov: f32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::shaders::layout;

    #[test]
    fn kernel_constants_are_the_host_tracers() {
        assert_eq!(layout::TRACE_SLAB_ROBUST_BITS, crate::geom::SLAB_ROBUST.to_bits());
        assert_eq!(layout::TRACE_KD_WIDEN_BITS, 1e-5f32.to_bits());
        assert_eq!(layout::TRACE_BIH_WIDEN_BITS, 2e-6f32.to_bits());
        assert_eq!(layout::TRACE_GRID_WIDEN_BITS, 1e-5f32.to_bits());
        assert_eq!(layout::TRACE_FLT_EPSILON_BITS, f32::EPSILON.to_bits());
        assert_eq!(TRACE_STACK_ENTRY_BYTES, 12);
    }

    #[test]
    fn layouts_have_the_documented_sizes() {
        assert_eq!(std::mem::size_of::<TriRecord>(), 48);
        assert_eq!(std::mem::size_of::<KdNode>(), 8);
        assert_eq!(std::mem::size_of::<BihNode>(), 12);
        assert_eq!(std::mem::size_of::<TraceScene>(), 64);
        assert_eq!(std::mem::size_of::<TraceRay>(), 32);
        assert_eq!(std::mem::size_of::<TraceHit>(), 32);
    }

    #[test]
    fn depth_of_a_chain_and_refusal_of_a_cycle() {
        // 0 -> (1, 2), 2 -> (3, 4): depth 2.
        let kids = |k: usize| match k {
            0 => Some((1, 2)),
            2 => Some((3, 4)),
            _ => None,
        };
        assert_eq!(tree_depth(5, kids, |_| (0, 1), 1).unwrap(), 2);
        assert!(tree_depth(5, kids, |_| (0, 2), 1).is_err(), "leaf past the records");
        assert!(tree_depth(3, |k| (k == 0).then_some((1, 0)), |_| (0, 0), 0).is_err(), "cycle");
        assert!(tree_depth(2, |k| (k == 0).then_some((1, 5)), |_| (0, 0), 0).is_err(), "child out of range");
        assert_eq!(tree_depth(0, |_| None, |_| (0, 0), 0).unwrap(), 0);
    }
}
