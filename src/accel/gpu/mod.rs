//! GPU builders of the LBVH (Karras 2012) and the HLBVH (Pantaleoni and Luebke 2010, with the SAH top of Garanzha
//! et al. 2011), and refit, producing exactly the trees of the CPU references [`crate::accel::lbvh`] and
//! [`crate::accel::hlbvh`] (their module docs define them), in the shared [`BvhNode`] layout.
//!
//! # Passes
//!
//! 1. `keys_bounds` (`glsl/keys_bounds.comp`, shared with the characterization): centroid keys and their bounds.
//!    The host reads the bounds back and computes the quantization scale (docs/spec.md forbids device division).
//! 2. `codes` (`glsl/lbvh_codes.comp`): Morton code of every key (30-bit in `u32`, 63-bit in `u64`) and the
//!    identity payload.
//! 3. `sort` ([`RadixSort`], stable): codes with their triangle indices, i.e. the `(code, index)` order.
//! 4. HLBVH only: `hlbvh_heads`, `hlbvh_scan` (one workgroup): the clusters (runs of equal top
//!    [`HlbvhOptions::cluster_bits`]) and their first positions.
//! 5. `karras` (`glsl/lbvh_karras.comp`): the radix tree, one invocation per sorted position, writing children,
//!    leaves and parent links; no invocation depends on another.
//! 6. `leaves` (`glsl/bvh_leaves.comp`): every leaf's box from the mesh vertices.
//! 7. `fit` (`glsl/bvh_fit.comp`): internal boxes bottom-up with one atomic arrival counter per node; the second
//!    arrival computes the union, nobody waits.
//! 8. HLBVH only: `hlbvh_roots` gathers the cluster roots (at most `2^cluster_bits` clusters, at most n); the
//!    binned-SAH top over them, `C - 1` nodes with the parent links of their children (so refit walks through the
//!    top as well), is built either on the host ([`BvhBuilder::build_hlbvh`]: readback, the CPU reference's
//!    function, upload, `bvh_parents`) or on the device ([`BvhBuilder::record_hlbvh`]: `hlbvh_top`, below).
//! 9. With the SAH leaf collapse (`max_leaf > 1`: the HLBVH's default, an option of the LBVH; defined in
//!    [`crate::accel::lbvh`], step 7): `collapse_cost` (`glsl/bvh_collapse_cost.comp`), bottom-up with the arrival
//!    counters of `fit`, computes every node's record range, cost, kept size and collapse flag; `compact`
//!    (`glsl/bvh_compact.comp`) has every node walk up to the root to find whether it is kept and its depth-first
//!    index, and writes the collapsed tree and its parent links (O(depth) per node, no invocation waits). The host
//!    reads back the kept node count.
//!
//! # The HLBVH's top level
//!
//! [`BvhBuilder::build_hlbvh`] (two submissions and a third after the host step) builds the top level on the host
//! with the CPU reference's function over the cluster boxes (tens of thousands with the default 21 cluster bits on
//! meshes of 10^5 triangles); its cost is reported in [`GpuBvh::timings`] as `top_cpu` (with the readback of the
//! cluster roots and the upload of the top nodes) beside the GPU passes.
//!
//! [`BvhBuilder::record_hlbvh`] records the whole build, the top level included, into one command buffer:
//! `hlbvh_top` (`glsl/hlbvh_top.comp`) runs the same binned SAH with the same f32 operations in the same order
//! (`precise`, the bin scale's quotient correctly rounded in integer arithmetic), so its nodes are bit for bit the
//! reference's. Ranges of at least `task_min` clusters (128 with 16 bins) are split by whole workgroups in rounds
//! (a workgroup goes on with the larger child, so about `log2(C / task_min)` rounds reach every range); smaller
//! subtrees are built serially, one invocation each. Its passes are timed as `top_rounds` and `top_tasks`.
//!
//! Measured on lavapipe (Mesa 22.3, two shared cores, load average 2.4, three runs): the device top
//! (`top_rounds` + `top_tasks`) costs 125 to 135 ms for 19,892 clusters (a soup of 20,000 triangles), 215 ms for
//! 20,888 (sponza), 340 to 360 ms for 45,056 (bunny), 610 to 780 ms for 72,263 (dragon res2) and 670 to 710 ms for
//! 97,655 (a soup of 100,000), against 11 to 14, 18 to 42, 24 to 45, 43 to 125 and 53 to 56 ms of `top_cpu` for the
//! host top with its transfers: lavapipe runs the kernel on the same two cores, a workgroup barrier switches
//! between all its invocations, and each serial subtree is one SIMD lane. The staged build therefore keeps the
//! host top. No discrete GPU was available to measure the device top on one.
//!
//! lavapipe also stops every loop of an invocation after 65,535 iterations in all (gallivm's loop limiter); the
//! kernel keeps its loops far below that up to about 2^21 clusters and reports a cut loop as an error
//! ([`GpuBvh::finish`]), never a wrong tree.
//!
//! # Result
//!
//! [`GpuBvh`] keeps the tree on the device: [`GpuBvh::nodes`] ([`GpuBvh::node_count`] [`BvhNode`]s: `2n - 1`, fewer
//! after the collapse, whose leaves hold up to `max_leaf` records; root at 0, the layout
//! documented in [`crate::accel::bvh`] and mirrored in `glsl/include/bvh.glsl` for engines' shaders) and
//! [`GpuBvh::ids`] (`n` `u32`: record `r` of a leaf is triangle `ids[r]`), both with device addresses.
//! [`GpuBvh::read_back`] copies them to a [`BvhTree`], so [`BvhTree::validate`] and [`BvhTree::sah_cost`] apply.
//!
//! # Refit
//!
//! [`BvhBuilder::refit`] recomputes every box of an existing tree for new vertex positions (the next frame of an
//! animation: same triangles, same topology): `leaves`, counters reset, `fit`. The result equals a fresh
//! leaves-and-fit pass over the same topology.
//!
//! # Recording
//!
//! [`BvhBuilder::build_lbvh`] and [`BvhBuilder::build_hlbvh`] submit and wait (the host reads the bounds back to
//! make the quantizer). [`BvhBuilder::record_lbvh`] records the whole LBVH build into a caller's command buffer with
//! a quantizer given in advance (the planned characterization's: [`crate::characterize::plan::Plan`]), and
//! [`BvhBuilder::record_refit`] a refit; [`GpuBvh::finish`] completes a recorded tree once its command buffer has
//! completed. Every builder reads geometry through a [`GeometryView`].
//!
//! An empty mesh is an error ([`InputError::Empty`]): a tree on the device needs at least one node.
//!
//! ```no_run
//! use meshchar::gpu::{Context, ContextDesc};
//! use meshchar::gpu::MeshBuffers;
//! use meshchar::accel::gpu::BvhBuilder;
//! use meshchar::accel::lbvh::LbvhOptions;
//! let ctx = Context::new(&ContextDesc::default())?;
//! let mesh = meshchar::mesh::generate::random_soup(1000, 1);
//! let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices)?;
//! let mut builder = BvhBuilder::new(&ctx)?;
//! let bvh = builder.build_lbvh(&buffers.view(), &LbvhOptions::default())?;
//! println!("nodes at 0x{:x}", bvh.nodes().address());
//! let tree = bvh.read_back(&ctx, &buffers)?;
//! tree.validate("lbvh")?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::accel::bvh::{BvhNode, BvhTree};
use crate::accel::hlbvh::HlbvhOptions;
use crate::accel::lbvh::{LbvhOptions, MAX_COLLAPSE_LEAF};
use crate::accel::MAX_TRIANGLES;
use crate::geom::{Aabb, Triangle};
use crate::gpu::shaders::layout::{BOUNDS_HI, BOUNDS_LO, BOUNDS_WORDS, COLLAPSE_SIZE, COLLAPSE_WORDS};
use crate::gpu::sort::{KeyBits, RadixSort, SortConfig, SortStorage, SortedIn};
use crate::gpu::{
    bounds_read_back, geometry_push, shaders, Buffer, CompletionFlag, Context, DeviceType, GeometryView, GpuError,
    InputError, Kernel, KernelDesc, KeysPush, MemoryKind, MeshBuffers, Pass, Recorder, Result, RunError, Timer,
};
use crate::keys::{MortonBits, Quantizer};
use glam::Vec3;
use std::sync::Arc;

pub mod grid;
mod hlbvh;
mod lbvh;
mod refit;
#[cfg(test)]
mod tests;

use hlbvh::{read_top_status, top_work_words};

/// Items per invocation of the per-element kernels.
const ITEMS: u32 = 8;
/// Largest cluster width the GPU HLBVH accepts: its cluster table has `2^cluster_bits` entries (64 MiB at 24).
pub const MAX_GPU_CLUSTER_BITS: u32 = 24;

pub(crate) use crate::gpu::shaders::bvh_collapse_cost::Push as CollapseCostPush;
pub(crate) use crate::gpu::shaders::bvh_compact::Push as CompactPush;
pub(crate) use crate::gpu::shaders::bvh_fit::Push as FitPush;
pub(crate) use crate::gpu::shaders::bvh_leaves::Push as LeavesPush;
pub(crate) use crate::gpu::shaders::bvh_parents::Push as ParentsPush;
pub(crate) use crate::gpu::shaders::hlbvh_heads::Push as HeadsPush;
pub(crate) use crate::gpu::shaders::hlbvh_roots::Push as RootsPush;
pub(crate) use crate::gpu::shaders::hlbvh_scan::Push as ScanPush;
pub(crate) use crate::gpu::shaders::hlbvh_top::Push as TopPush;
pub(crate) use crate::gpu::shaders::lbvh_codes::Push as CodesPush;
pub(crate) use crate::gpu::shaders::lbvh_karras::Push as KarrasPush;

/// Which tree a [`GpuBvh`] holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpuBvhKind {
    /// LBVH (Karras numbering).
    Lbvh,
    /// HLBVH with this many clusters.
    Hlbvh {
        /// Number of Morton clusters.
        clusters: u32,
    },
}

/// A BVH on the device (see the module docs).
#[derive(Debug)]
pub struct GpuBvh {
    kind: GpuBvhKind,
    triangles: u64,
    node_count: u64,
    nodes: Buffer,
    ids: Buffer,
    parents: Buffer,
    counters: Buffer,
    timings: Vec<(String, f64)>,
    /// A recorded build not yet finished: what [`GpuBvh::finish`] reads.
    pending: Option<PendingBuild>,
}

/// What a recorded build keeps until [`GpuBvh::finish`]: its timer, the readback of the collapsed node count (and
/// of an HLBVH's cluster count), the builder's scratch buffers it used, and the build's other buffers (alive until
/// the tree is finished or dropped, even if the builder moves on to larger ones).
#[derive(Debug)]
struct PendingBuild {
    timer: Timer,
    done: CompletionFlag,
    collapsed_count: Option<Buffer>,
    /// HLBVH: the readback of the cluster count and the top level's error flags, and the largest cluster count.
    clusters: Option<(Buffer, u64)>,
    _scratch: Arc<Scratch>,
    /// The other buffers of the build the command buffer uses (see [`BvhBuilder::record_lbvh`]).
    _buffers: Vec<Buffer>,
}

impl GpuBvh {
    /// LBVH or HLBVH (a recorded HLBVH says 0 clusters until [`GpuBvh::finish`] has read the count).
    pub fn kind(&self) -> GpuBvhKind {
        self.kind
    }
    /// Triangles (`n`).
    pub fn triangle_count(&self) -> u64 {
        self.triangles
    }
    /// Nodes: `2n - 1`, or fewer after the SAH collapse (for a recorded build with the collapse, known only once
    /// [`GpuBvh::finish`] has read it: `2n - 1` before).
    pub fn node_count(&self) -> u64 {
        self.node_count
    }

    /// Whether the tree comes from a recorded build that [`GpuBvh::finish`] has not read yet.
    pub fn is_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// Completes a recorded build ([`BvhBuilder::record_lbvh`], [`BvhBuilder::record_hlbvh`]) once its command
    /// buffer has completed and the caller has seen it complete: reads the pass times, after the SAH collapse the
    /// node count, and for an HLBVH the cluster count ([`GpuBvh::kind`]) and the top level's error flags.
    /// [`GpuError::NotReady`] (the build stays pending) before the command buffer has completed;
    /// [`GpuError::Buffer`] (the build stays pending) when a count read back is out of range or the top level
    /// reports an error. Finishing a tree that is not pending does nothing.
    pub fn finish(&mut self) -> Result<()> {
        let Some(p) = &self.pending else { return Ok(()) };
        p.done.check("recorded BVH build")?;
        let timings = p.timer.try_read()?;
        let kind = match &p.clusters {
            Some((readback, limit)) => GpuBvhKind::Hlbvh { clusters: read_top_status(readback, *limit)? as u32 },
            None => self.kind,
        };
        if let Some(readback) = &p.collapsed_count {
            let size: Vec<u32> = readback.read(0, 1)?;
            let size = size[0] as u64;
            if size == 0 || size > 2 * self.triangles - 1 {
                return Err(GpuError::Buffer(format!("collapse: {size} nodes read back")));
            }
            self.node_count = size;
        }
        self.kind = kind;
        self.timings = timings;
        self.pending = None;
        Ok(())
    }
    /// The nodes ([`BvhNode`], 32 bytes each, root at 0; the first [`GpuBvh::node_count`] are the tree, the buffer
    /// holds `2n - 1`).
    pub fn nodes(&self) -> &Buffer {
        &self.nodes
    }
    /// The triangle ids of the records (`u32`, `n`).
    pub fn ids(&self) -> &Buffer {
        &self.ids
    }
    /// Parent node of every node (`u32`, `BVH_NONE` = `u32::MAX` for the root), used by refit.
    pub fn parents(&self) -> &Buffer {
        &self.parents
    }
    /// Milliseconds of each pass of the last build or refit (GPU timestamps; `top_cpu` is host time).
    pub fn timings(&self) -> &[(String, f64)] {
        &self.timings
    }

    /// Copies the nodes and ids to the host, with the triangle records from `mesh` (the host copy of the geometry
    /// the tree was built or refitted for).
    pub fn read_back_with(&self, ctx: &Context, mesh: &crate::mesh::Mesh) -> Result<BvhTree> {
        self.read_back_from(ctx, &mesh.positions, &mesh.indices)
    }

    /// Copies the nodes and ids to the host, with the triangle records from the mesh on the device (the same mesh
    /// the tree was built or refitted for).
    pub fn read_back(&self, ctx: &Context, mesh: &MeshBuffers) -> Result<BvhTree> {
        let positions: Vec<[f32; 3]> = ctx.read_buffer(&mesh.positions, 0, mesh.vertices as usize)?;
        let indices: Vec<[u32; 3]> = ctx.read_buffer(&mesh.indices, 0, mesh.triangles as usize)?;
        self.read_back_from(ctx, &positions, &indices)
    }

    fn read_back_from(&self, ctx: &Context, positions: &[[f32; 3]], indices: &[[u32; 3]]) -> Result<BvhTree> {
        if self.is_pending() {
            return Err(GpuError::Buffer("read back of a recorded build not yet finished (GpuBvh::finish)".into()));
        }
        let n = self.triangles as usize;
        let nodes: Vec<BvhNode> = ctx.read_buffer(&self.nodes, 0, self.node_count as usize)?;
        let ids: Vec<u32> = ctx.read_buffer(&self.ids, 0, n)?;
        let mut tris = Vec::with_capacity(n);
        for &id in &ids {
            let t =
                indices.get(id as usize).ok_or_else(|| GpuError::Buffer(format!("triangle id {id} out of range")))?;
            let v = |k: u32| positions.get(k as usize).map(|p| Vec3::from_array(*p));
            match (v(t[0]), v(t[1]), v(t[2])) {
                (Some(a), Some(b), Some(c)) => tris.push(Triangle::new(&[a, b, c])),
                _ => return Err(GpuError::Buffer(format!("triangle {id}: vertex index out of range"))),
            }
        }
        Ok(BvhTree { nodes, tris, ids, copies: Vec::new() })
    }
}

#[derive(Debug)]
struct Scratch {
    capacity: u64,
    keys: Buffer,
    bounds: Buffer,
    bounds_readback: Buffer,
    sort: SortStorage,
}

/// The buffers of one build.
struct BuildBuffers {
    n: u64,
    total: u64,
    bits: MortonBits,
    hl: Option<(u32, usize)>,
    max_leaf: u32,
    scratch: Arc<Scratch>,
    bvh_nodes: Buffer,
    bvh_ids: Buffer,
    parents: Buffer,
    counters: Buffer,
    collapsed: Option<(Buffer, Buffer, Buffer, Buffer)>,
    table_entries: u64,
    max_clusters: u64,
    table: Buffer,
    starts: Buffer,
    roots: Buffer,
    /// HLBVH with the device top level: the scratch of `glsl/hlbvh_top.comp` (one word otherwise).
    top_work: Buffer,
    /// Whether the top level runs on the device (`hlbvh_top`) or on the host (the staged build's choice).
    device_top: bool,
    readback: Buffer,
}

/// The device top level's plan for at most `l` clusters and `nb` bins per axis: subtrees of fewer than `task_min`
/// clusters are built serially by one invocation each, larger ranges by workgroups over `rounds` rounds of `groups`
/// workgroups (see `glsl/hlbvh_top.comp`).
///
/// Serial subtrees stay small enough that one invocation runs well under 2^16 loop iterations (lavapipe stops every
/// loop of an invocation after 65,535 iterations in all; the kernel reports a cut loop as an error): about
/// `6 m log2 m + 9 nb m` for `m` clusters, so `task_min` is 2048 / `nb` within 16 ..= 128. Without chain stops,
/// `ceil(log2(l / task_min)) + 1` rounds reach every range; 8 more absorb the stops of unbalanced trees, and what is
/// The LBVH and HLBVH pipelines of one device, with scratch buffers reused across builds.
pub struct BvhBuilder {
    ctx: Context,
    keys: Kernel<KeysPush>,
    codes: [Kernel<CodesPush>; 2],
    karras: [[Kernel<KarrasPush>; 2]; 2],
    leaves: Kernel<LeavesPush>,
    fit: Kernel<FitPush>,
    parents: Kernel<ParentsPush>,
    heads: [Kernel<HeadsPush>; 2],
    scan: Kernel<ScanPush>,
    roots: Kernel<RootsPush>,
    top: Kernel<TopPush>,
    collapse_cost: Kernel<CollapseCostPush>,
    compact: Kernel<CompactPush>,
    sort: RadixSort,
    scratch: Option<Arc<Scratch>>,
}

impl std::fmt::Debug for BvhBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BvhBuilder").field("device", &self.ctx.caps().name).finish()
    }
}

impl BvhBuilder {
    /// Builds the pipelines on the context's device (workgroup sizes and sort tuning from its limits).
    pub fn new(ctx: &Context) -> Result<Self> {
        let items = |info| KernelDesc::new(info).constant("ITEMS", ITEMS);
        let codes = |b: u32| Kernel::new(ctx, &items(&shaders::lbvh_codes::INFO).constant("BITS63", b));
        let karras = |b: u32, h: u32| {
            Kernel::new(ctx, &items(&shaders::lbvh_karras::INFO).constant("BITS63", b).constant("HLBVH", h))
        };
        let heads = |b: u32| Kernel::new(ctx, &KernelDesc::new(&shaders::hlbvh_heads::INFO).constant("BITS63", b));
        let mut scan_desc = KernelDesc::new(&shaders::hlbvh_scan::INFO);
        // The scan kernel keeps one shared counter per invocation, 1,024 at most.
        scan_desc.workgroup_size = Some(ctx.caps().workgroup_size().min(1024));
        // The top level's workgroups keep one shared prefix-sum slot per invocation, 1,024 at most.
        let mut top_desc = KernelDesc::new(&shaders::hlbvh_top::INFO);
        top_desc.workgroup_size = Some(ctx.caps().workgroup_size().min(1024));
        Ok(BvhBuilder {
            ctx: ctx.clone(),
            keys: Kernel::new(ctx, &items(&shaders::keys_bounds::INFO))?,
            codes: [codes(0)?, codes(1)?],
            karras: [[karras(0, 0)?, karras(0, 1)?], [karras(1, 0)?, karras(1, 1)?]],
            leaves: Kernel::new(ctx, &items(&shaders::bvh_leaves::INFO))?,
            // See glsl/bvh_fit.comp: no explicit barriers on CPU drivers, where they break the walk.
            fit: Kernel::new(
                ctx,
                &KernelDesc::new(&shaders::bvh_fit::INFO)
                    .constant("FENCES", u32::from(ctx.caps().device_type != DeviceType::Cpu)),
            )?,
            parents: Kernel::new(ctx, &KernelDesc::new(&shaders::bvh_parents::INFO))?,
            heads: [heads(0)?, heads(1)?],
            scan: Kernel::new(ctx, &scan_desc)?,
            roots: Kernel::new(ctx, &KernelDesc::new(&shaders::hlbvh_roots::INFO))?,
            top: Kernel::new(ctx, &top_desc)?,
            collapse_cost: Kernel::new(
                ctx,
                &KernelDesc::new(&shaders::bvh_collapse_cost::INFO)
                    .constant("FENCES", u32::from(ctx.caps().device_type != DeviceType::Cpu)),
            )?,
            compact: Kernel::new(ctx, &KernelDesc::new(&shaders::bvh_compact::INFO))?,
            sort: RadixSort::new(ctx, SortConfig::for_device(ctx.caps()))?,
            scratch: None,
        })
    }

    fn scratch(&mut self, n: u64) -> Result<()> {
        if self.scratch.as_ref().is_none_or(|s| s.capacity < n) {
            self.scratch = None;
            let ctx = &self.ctx;
            let sort_mem = self.sort.memory_requirements(n, KeyBits::U64);
            self.scratch = Some(Arc::new(Scratch {
                capacity: n,
                keys: ctx.create_buffer("lbvh keys", 12 * n, MemoryKind::DeviceLocal)?,
                bounds: ctx.create_buffer("lbvh bounds", 32, MemoryKind::DeviceLocal)?,
                bounds_readback: ctx.create_buffer("lbvh bounds readback", 32, MemoryKind::Readback)?,
                sort: SortStorage::new(ctx, &sort_mem, true)?,
            }));
        }
        Ok(())
    }

    /// The buffers of one build of `n` triangles.
    fn prepare(
        &mut self,
        mesh: &GeometryView<'_>,
        bits: MortonBits,
        hl: Option<(u32, usize)>,
        max_leaf: u32,
        device_top: bool,
    ) -> std::result::Result<BuildBuffers, RunError> {
        let device_top = device_top && hl.is_some();
        let max_leaf = max_leaf.min(MAX_COLLAPSE_LEAF);
        let collapse = max_leaf > 1;
        let n = mesh.triangle_count();
        if n == 0 {
            return Err(InputError::Empty.into());
        }
        if n > MAX_TRIANGLES as u64 {
            return Err(InputError::TooMany(n).into());
        }
        self.scratch(n)?;
        let ctx = self.ctx.clone();
        let Some(scratch) = self.scratch.clone() else {
            return Err(GpuError::Buffer("lbvh scratch".into()).into());
        };
        let total = 2 * n - 1;
        let dl = MemoryKind::DeviceLocal;
        // With the collapse the tree is the input of the collapse and `collapsed` the output.
        let collapsed = if collapse {
            Some((
                ctx.create_buffer("bvh collapsed nodes", 32 * total, dl)?,
                ctx.create_buffer("bvh collapsed parents", 4 * total, dl)?,
                ctx.create_buffer("bvh collapse info", 4 * COLLAPSE_WORDS as u64 * total, dl)?,
                ctx.create_buffer("bvh collapse readback", 32, MemoryKind::Readback)?,
            ))
        } else {
            None
        };
        let table_entries = hl.map_or(1, |(cb, _)| 1u64 << cb);
        let max_clusters = table_entries.min(n);
        Ok(BuildBuffers {
            n,
            total,
            bits,
            hl,
            max_leaf,
            bvh_nodes: ctx.create_buffer("bvh nodes", 32 * total, dl)?,
            bvh_ids: ctx.create_buffer("bvh ids", 4 * n, dl)?,
            parents: ctx.create_buffer("bvh parents", 4 * total, dl)?,
            counters: ctx.create_buffer("bvh counters", 4 * total, dl)?,
            collapsed,
            table_entries,
            max_clusters,
            table: ctx.create_buffer("hlbvh table", 4 * table_entries, dl)?,
            starts: ctx.create_buffer("hlbvh starts", 4 * (max_clusters + 2), dl)?,
            roots: ctx.create_buffer("hlbvh roots", 32 * max_clusters, dl)?,
            top_work: ctx.create_buffer(
                "hlbvh top work",
                if device_top { 4 * top_work_words(max_clusters) } else { 4 },
                dl,
            )?,
            device_top,
            readback: ctx.create_buffer(
                "hlbvh readback",
                if hl.is_some() && !device_top { 4 * (max_clusters + 2) + 32 * max_clusters } else { 8 },
                MemoryKind::Readback,
            )?,
            scratch,
        })
    }

    /// Records the keys and their bounds (fills, keys_bounds).
    fn record_keys(&self, rec: &mut Recorder<'_>, mesh: &GeometryView<'_>, b: &BuildBuffers, timer: &mut Timer) {
        let scratch = &b.scratch;
        let n = b.n;
        rec.fill(&scratch.bounds, 4 * BOUNDS_LO as u64, Some(12), u32::MAX);
        rec.fill(&scratch.bounds, 4 * BOUNDS_HI as u64, Some(12), 0);
        rec.dependency(Pass::Transfer, Pass::Compute);
        rec.timestamp_start(timer);
        let push = geometry_push!(KeysPush, mesh, {
            keys: scratch.keys.address(),
            result: scratch.bounds.address(),
            count: n,
            stride: 1,
        });
        let per_group = self.keys.workgroup_size() as u64 * ITEMS as u64;
        // SAFETY: reads the n triangles of the view, writes n keys (scratch capacity >= n) and six bound words.
        unsafe { rec.dispatch(&self.keys, &push, rec.groups_for(n, per_group)) };
        rec.timestamp(timer, "keys_bounds");
    }

    /// Records the build of `b` (keys, then the tree) and returns the pending tree.
    fn record_pending(
        &mut self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        quantizer: &Quantizer,
        mut b: BuildBuffers,
    ) -> std::result::Result<GpuBvh, RunError> {
        let ctx = self.ctx.clone();
        let mut timer = Timer::new(&ctx, 32)?;
        rec.reset_timer(&mut timer);
        self.record_keys(rec, mesh, &b, &mut timer);
        rec.dependency(Pass::Compute, Pass::Compute);
        self.record_tree(rec, mesh, &b, quantizer.lo(), quantizer.scale(), &mut timer)?;
        rec.timestamp_start(&mut timer);
        let mut done = CompletionFlag::new(&ctx)?;
        done.record(rec)?;
        let scratch = b.scratch.clone();
        // Every buffer the command buffer uses stays alive until the build is finished or dropped: the tree's own,
        // and the rest here (the tree before the collapse, the collapse records, the cluster table, starts and
        // roots, the top level's scratch).
        let mut keep = vec![b.table, b.starts, b.roots, b.top_work];
        let collapsed_count = b.collapsed.take().map(|(out_nodes, out_parents, info, readback)| {
            keep.push(std::mem::replace(&mut b.bvh_nodes, out_nodes));
            keep.push(std::mem::replace(&mut b.parents, out_parents));
            keep.push(info);
            readback
        });
        let (kind, clusters) = match b.hl {
            Some(_) => (GpuBvhKind::Hlbvh { clusters: 0 }, Some((b.readback, b.max_clusters))),
            None => {
                keep.push(b.readback);
                (GpuBvhKind::Lbvh, None)
            }
        };
        Ok(GpuBvh {
            kind,
            triangles: b.n,
            node_count: b.total,
            nodes: b.bvh_nodes,
            ids: b.bvh_ids,
            parents: b.parents,
            counters: b.counters,
            timings: Vec::new(),
            pending: Some(PendingBuild { timer, done, collapsed_count, clusters, _scratch: scratch, _buffers: keep }),
        })
    }
}

/// A recorded build's quantizer has the options' code width ([`InputError::Plan`] otherwise).
pub(super) fn check_quantizer(quantizer: &Quantizer, bits: MortonBits) -> std::result::Result<(), InputError> {
    if quantizer.bits() != bits {
        return Err(InputError::Plan(format!(
            "the quantizer has {}-bit codes, the options ask for {}",
            quantizer.bits().total(),
            bits.total()
        )));
    }
    Ok(())
}
