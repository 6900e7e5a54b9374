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

/// Items per invocation of the per-element kernels.
const ITEMS: u32 = 8;
/// Largest cluster width the GPU HLBVH accepts: its cluster table has `2^cluster_bits` entries (64 MiB at 24).
pub const MAX_GPU_CLUSTER_BITS: u32 = 24;

pub use crate::gpu::shaders::bvh_collapse_cost::Push as CollapseCostPush;
pub use crate::gpu::shaders::bvh_compact::Push as CompactPush;
pub use crate::gpu::shaders::bvh_fit::Push as FitPush;
pub use crate::gpu::shaders::bvh_leaves::Push as LeavesPush;
pub use crate::gpu::shaders::bvh_parents::Push as ParentsPush;
pub use crate::gpu::shaders::hlbvh_heads::Push as HeadsPush;
pub use crate::gpu::shaders::hlbvh_roots::Push as RootsPush;
pub use crate::gpu::shaders::hlbvh_scan::Push as ScanPush;
pub use crate::gpu::shaders::hlbvh_top::Push as TopPush;
pub use crate::gpu::shaders::lbvh_codes::Push as CodesPush;
pub use crate::gpu::shaders::lbvh_karras::Push as KarrasPush;

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
/// left after the last round is built serially too.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct TopPlan {
    task_min: u32,
    rounds: u32,
    groups: u32,
}

impl TopPlan {
    fn new(l: u64, nb: usize, cpu: bool) -> Self {
        let task_min = (2048 / nb.max(1) as u32).clamp(16, 128);
        let big = l.div_ceil(task_min as u64).max(1);
        let rounds = 64 - (big - 1).leading_zeros() + 1 + 8;
        let groups = if cpu { big.div_ceil(128).clamp(2, 128) } else { big.min(128) };
        TopPlan { task_min, rounds, groups: groups as u32 }
    }
}

/// Words of the device top level's scratch for at most `l` clusters (list, partition scratch, stack, header, tasks
/// and three queues: the layout of `glsl/hlbvh_top.comp`).
fn top_work_words(l: u64) -> u64 {
    5 * l + 8 + 12 * (l / 2 + 1)
}

/// Word of the top level's error flags in its scratch.
fn top_error_word(l: u64) -> u64 {
    5 * l + 1
}

/// The cluster count and the top level's error flags, copied to `readback` at the end of an HLBVH build with the
/// device top level: the count, or [`GpuError::Buffer`] when the flags are set or the count is out of range.
fn read_top_status(readback: &Buffer, limit: u64) -> Result<u64> {
    let w: Vec<u32> = readback.read(0, 2)?;
    if w[1] != 0 {
        return Err(GpuError::Buffer(format!("hlbvh top level: error flags {:#x}", w[1])));
    }
    let c = w[0] as u64;
    if c == 0 || c > limit {
        return Err(GpuError::Buffer(format!("hlbvh: {c} clusters read back")));
    }
    Ok(c)
}

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

    /// Builds the LBVH of the geometry on the device (two submissions: the bounds, then the tree).
    pub fn build_lbvh(&mut self, mesh: &GeometryView<'_>, o: &LbvhOptions) -> std::result::Result<GpuBvh, RunError> {
        self.build(mesh, o.bits, None, o.max_leaf)
    }

    /// Builds the HLBVH of the geometry: everything but the top level over the clusters on the device (see the
    /// module docs). `cluster_bits` above [`MAX_GPU_CLUSTER_BITS`] gives [`GpuError::Limit`].
    pub fn build_hlbvh(&mut self, mesh: &GeometryView<'_>, o: &HlbvhOptions) -> std::result::Result<GpuBvh, RunError> {
        let cb = gpu_cluster_bits(o)?;
        self.build(mesh, o.bits, Some((cb, o.bins)), o.max_leaf)
    }

    /// Records a whole HLBVH build into `rec` with a quantizer given in advance: keys, codes, sort, clusters, the
    /// cluster trees and their boxes, the cluster roots, the top level on the device (`glsl/hlbvh_top.comp`, the
    /// binned SAH of the CPU reference, node for node), the parent links and the SAH collapse, with no host
    /// round trip; then [`GpuBvh::finish`] once the command buffer has completed (it reads the cluster count into
    /// [`GpuBvh::kind`], which says 0 clusters before). With the quantizer of the geometry's own bounds the tree
    /// equals [`BvhBuilder::build_hlbvh`]'s and the CPU reference's ([`crate::accel::hlbvh::Hlbvh::build_with`]).
    ///
    /// The recording contract is [`BvhBuilder::record_lbvh`]'s (the first geometry access a compute-shader read,
    /// the last accesses compute-shader writes to the tree's buffers and transfer writes to readback buffers of the
    /// tree's own; the caller records a barrier before reading the tree; tree and builder alive until the command
    /// buffer completes). Errors: [`InputError::Plan`] when the quantizer's code width is not the options',
    /// [`GpuError::Limit`] above [`MAX_GPU_CLUSTER_BITS`], [`InputError::Empty`] for no triangles.
    pub fn record_hlbvh(
        &mut self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        quantizer: &Quantizer,
        o: &HlbvhOptions,
    ) -> std::result::Result<GpuBvh, RunError> {
        check_quantizer(quantizer, o.bits)?;
        let cb = gpu_cluster_bits(o)?;
        let b = self.prepare(mesh, o.bits, Some((cb, o.bins)), o.max_leaf, true)?;
        self.record_pending(rec, mesh, quantizer, b)
    }

    /// Records an LBVH build into `rec` with a quantizer given in advance (no host round trip: in an animation, the
    /// quantizer of the previous frame's bounds, or of a characterization recorded before), then
    /// [`GpuBvh::finish`] once the command buffer has completed. A key outside the quantizer's bounds gets the code
    /// of the nearest cell (docs/spec.md, "Planned characterization"); with the quantizer of the geometry's own
    /// bounds the tree equals [`BvhBuilder::build_lbvh`]'s and the CPU reference's.
    ///
    /// Recording contract: the first access to the geometry is a compute-shader read (`keys_bounds`, `leaves`),
    /// the caller records a barrier before that makes its geometry writes visible to compute-shader reads; the
    /// last accesses are compute-shader writes to [`GpuBvh::nodes`], [`GpuBvh::parents`] and [`GpuBvh::ids`]
    /// (and, after the collapse, a transfer write of the node count to a readback buffer of the tree's own); the
    /// caller records a barrier before reading the tree. The tree and the builder must stay alive until the
    /// command buffer completes.
    pub fn record_lbvh(
        &mut self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        quantizer: &Quantizer,
        o: &LbvhOptions,
    ) -> std::result::Result<GpuBvh, RunError> {
        check_quantizer(quantizer, o.bits)?;
        let b = self.prepare(mesh, o.bits, None, o.max_leaf, false)?;
        self.record_pending(rec, mesh, quantizer, b)
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

    /// Divides `a / b` for every pair on the device with the correctly rounded division of the HLBVH's top level
    /// (`div_rn` in `glsl/hlbvh_top.comp`, integer arithmetic, round to nearest even), which gives the bin scales
    /// their host values: a check of the kernel's arithmetic against the host's `/`. Every `a` is positive and
    /// finite, every `b` positive (finite, subnormal or infinite); other pairs, or more than 2^28 of them, give
    /// [`GpuError::Buffer`].
    pub fn device_divide(&self, pairs: &[(f32, f32)]) -> Result<Vec<f32>> {
        if pairs.is_empty() {
            return Ok(Vec::new());
        }
        if pairs.len() > 1 << 28 {
            return Err(GpuError::Buffer(format!("device_divide: {} pairs (at most 2^28)", pairs.len())));
        }
        if let Some(&(a, b)) = pairs.iter().find(|&&(a, b)| !(a > 0.0 && a.is_finite() && b > 0.0)) {
            return Err(GpuError::Buffer(format!("device_divide: {a} / {b} is outside the division's domain")));
        }
        let l = pairs.len() as u64;
        let mut words: Vec<u32> = pairs.iter().flat_map(|&(a, b)| [a.to_bits(), b.to_bits()]).collect();
        words.resize(3 * pairs.len(), 0);
        let work = self.ctx.upload("hlbvh top division", &words)?;
        let push = TopPush { work: work.address(), limit: l as u32, bins: 2, phase: 3, ..TopPush::default() };
        self.ctx.submit_and_wait(|rec| {
            rec.barrier();
            // SAFETY: phase 3 reads 2 l words of `work` and writes l more after them (3 l in all); it touches no
            // other address.
            unsafe { rec.dispatch(&self.top, &push, rec.groups_for(l, self.top.workgroup_size() as u64)) };
            rec.barrier();
            Ok(())
        })?;
        let q: Vec<u32> = self.ctx.read_buffer(&work, 8 * l, pairs.len())?;
        Ok(q.into_iter().map(f32::from_bits).collect())
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

    fn build(
        &mut self,
        mesh: &GeometryView<'_>,
        bits: MortonBits,
        hl: Option<(u32, usize)>,
        max_leaf: u32,
    ) -> std::result::Result<GpuBvh, RunError> {
        let b = self.prepare(mesh, bits, hl, max_leaf, false)?;
        let ctx = self.ctx.clone();
        let mut timer_owned = Timer::new(&ctx, 32)?;
        let timer = &mut timer_owned;
        let scratch = b.scratch.clone();

        // Submission 1: keys and their bounds.
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(timer);
            self.record_keys(rec, mesh, &b, timer);
            rec.dependency(Pass::Compute, Pass::Transfer);
            rec.copy(&scratch.bounds, 0, &scratch.bounds_readback, 0, 4 * BOUNDS_WORDS as u64);
            rec.host_read_barrier();
            Ok(())
        })?;
        let q = Quantizer::new(&bounds_read_back(&scratch.bounds_readback, 0)?, bits).map_err(InputError::from)?;

        // Submission 2: codes, sort, (clusters), tree, boxes.
        ctx.submit_and_wait(|rec| self.record_tree(rec, mesh, &b, q.lo(), q.scale(), timer))?;
        let BuildBuffers {
            n,
            total,
            max_leaf,
            collapsed,
            max_clusters,
            readback,
            bvh_nodes,
            bvh_ids,
            parents,
            counters,
            ..
        } = b;
        let mut timings: Vec<(String, f64)> = timer_owned.read()?;
        let kind = match hl {
            None => GpuBvhKind::Lbvh,
            Some((_, bins)) => {
                let t0 = std::time::Instant::now();
                let c: Vec<u32> = readback.read(0, 1)?;
                let c = c[0] as u64;
                if c == 0 || c > max_clusters {
                    return Err(GpuError::Buffer(format!("hlbvh: {c} clusters read back")).into());
                }
                let mut timer2 = Timer::new(&ctx, 8)?;
                if c > 1 {
                    let starts_host: Vec<u32> = readback.read(4, c as usize)?;
                    let root_nodes: Vec<BvhNode> = readback.read(4 * (max_clusters + 2), c as usize)?;
                    let root_ids: Vec<u32> =
                        starts_host.iter().enumerate().map(|(k, &s)| (c as u32 - 1) + 2 * s - k as u32).collect();
                    let boxes: Vec<Aabb> = root_nodes.iter().map(|nd| nd.aabb()).collect();
                    let mut list: Vec<u32> = (0..c as u32).collect();
                    let mut top = Vec::with_capacity(c as usize - 1);
                    crate::accel::hlbvh::top_tree(&mut list, &root_ids, &boxes, bins, &mut top);
                    let mut staging = ctx.create_buffer("hlbvh top", 32 * top.len() as u64, MemoryKind::Upload)?;
                    staging.write(0, &top)?;
                    ctx.submit_and_wait(|rec| {
                        rec.copy(&staging, 0, &bvh_nodes, 0, 32 * top.len() as u64);
                        rec.barrier();
                        let push = ParentsPush { nodes: bvh_nodes.address(), parents: parents.address(), count: c - 1 };
                        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
                        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
                        unsafe {
                            rec.dispatch(
                                &self.parents,
                                &push,
                                rec.groups_for(c - 1, self.parents.workgroup_size() as u64),
                            )
                        };
                        if let Some(cl) = &collapsed {
                            rec.reset_timer(&mut timer2);
                            rec.timestamp_start(&mut timer2);
                            self.record_collapse(
                                rec,
                                &bvh_nodes,
                                &parents,
                                &counters,
                                total,
                                cl,
                                max_leaf,
                                &mut timer2,
                            );
                        }
                        Ok(())
                    })?;
                } else if let Some(cl) = &collapsed {
                    ctx.submit_and_wait(|rec| {
                        rec.reset_timer(&mut timer2);
                        rec.timestamp_start(&mut timer2);
                        self.record_collapse(rec, &bvh_nodes, &parents, &counters, total, cl, max_leaf, &mut timer2);
                        Ok(())
                    })?;
                }
                let host_ms = t0.elapsed().as_secs_f64() * 1e3;
                let collapse_ms: Vec<(String, f64)> = if collapsed.is_some() { timer2.read()? } else { Vec::new() };
                let device_ms: f64 = collapse_ms.iter().map(|t| t.1).sum();
                timings.push(("top_cpu".into(), host_ms - device_ms));
                timings.extend(collapse_ms);
                GpuBvhKind::Hlbvh { clusters: c as u32 }
            }
        };
        let (nodes, parents, node_count) = match collapsed {
            Some((out_nodes, out_parents, _, readback)) => {
                let size: Vec<u32> = readback.read(0, 1)?;
                let size = size[0] as u64;
                if size == 0 || size > total {
                    return Err(GpuError::Buffer(format!("collapse: {size} nodes read back")).into());
                }
                (out_nodes, out_parents, size)
            }
            None => (bvh_nodes, parents, total),
        };
        Ok(GpuBvh { kind, triangles: n, node_count, nodes, ids: bvh_ids, parents, counters, timings, pending: None })
    }

    /// Records codes, sort, (clusters), tree, boxes (and the collapse of an LBVH; the cluster roots' readback of an
    /// HLBVH) with the quantizer `lo`, `scale`.
    fn record_tree(
        &self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        b: &BuildBuffers,
        lo: [f32; 3],
        scale: [f32; 3],
        timer: &mut Timer,
    ) -> Result<()> {
        let BuildBuffers {
            n,
            total,
            bits,
            hl,
            max_leaf,
            ref scratch,
            ref bvh_nodes,
            ref bvh_ids,
            ref parents,
            ref counters,
            ref collapsed,
            table_entries,
            max_clusters,
            ref table,
            ref starts,
            ref roots,
            ref top_work,
            device_top,
            ref readback,
        } = *b;
        let per_group = self.keys.workgroup_size() as u64 * ITEMS as u64;
        let b63 = usize::from(bits == MortonBits::Bits63);
        let shift = hl.map_or(0, |(cb, _)| bits.total() - cb);
        let key_bits = if b63 == 1 { KeyBits::U64 } else { KeyBits::U32 };
        rec.timestamp_start(timer);
        let (codes_buf, ids_buf) = match &scratch.sort.payload {
            Some((p, _)) => (&scratch.sort.keys, p),
            None => return Err(GpuError::Buffer("sort payload".into())),
        };
        let push = CodesPush {
            keys: scratch.keys.address(),
            codes: codes_buf.address(),
            ids: ids_buf.address(),
            count: n,
            lo_x: lo[0],
            lo_y: lo[1],
            lo_z: lo[2],
            scale_x: scale[0],
            scale_y: scale[1],
            scale_z: scale[2],
        };
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.codes[b63], &push, rec.groups_for(n, per_group)) };
        rec.timestamp(timer, "codes");
        let sorted_in = self.sort.record(rec, &scratch.sort.buffers(), n, key_bits)?;
        let (codes_buf, ids_buf) = match scratch.sort.result(sorted_in) {
            (k, Some(p)) => (k, p),
            (_, None) => return Err(GpuError::Buffer("sort payload".into())),
        };
        debug_assert_eq!(sorted_in, SortedIn::Input);
        rec.barrier();
        rec.timestamp(timer, "sort");
        if hl.is_some() {
            rec.fill(table, 0, None, u32::MAX);
            rec.barrier();
            let push = HeadsPush { codes: codes_buf.address(), table: table.address(), count: n, shift, pad: 0 };
            // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
            // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
            unsafe {
                rec.dispatch(&self.heads[b63], &push, rec.groups_for(n, self.heads[b63].workgroup_size() as u64))
            };
            rec.barrier();
            let push = ScanPush {
                table: table.address(),
                starts: starts.address(),
                nodes: bvh_nodes.address(),
                entries: table_entries,
                count: n as u32,
                pad: 0,
            };
            // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
            // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
            unsafe { rec.dispatch(&self.scan, &push, 1) };
            rec.timestamp(timer, "clusters");
        }
        rec.fill(parents, 0, None, u32::MAX);
        rec.barrier();
        let push = KarrasPush {
            codes: codes_buf.address(),
            ids: ids_buf.address(),
            nodes: bvh_nodes.address(),
            parents: parents.address(),
            table: table.address(),
            starts: starts.address(),
            count: n,
            shift,
            pad: 0,
        };
        let h = usize::from(hl.is_some());
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.karras[b63][h], &push, rec.groups_for(n, per_group)) };
        rec.timestamp(timer, "karras");
        rec.barrier();
        rec.copy(ids_buf, 0, bvh_ids, 0, 4 * n);
        self.record_boxes(rec, mesh, ids_buf, bvh_nodes, parents, counters, total, Some(timer));
        if let (None, Some(cl)) = (hl, &collapsed) {
            self.record_collapse(rec, bvh_nodes, parents, counters, total, cl, max_leaf, timer);
        }
        if hl.is_some() {
            rec.barrier();
            let push = RootsPush {
                starts: starts.address(),
                nodes: bvh_nodes.address(),
                roots: roots.address(),
                limit: max_clusters,
            };
            // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
            // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
            unsafe {
                rec.dispatch(&self.roots, &push, rec.groups_for(max_clusters, self.roots.workgroup_size() as u64))
            };
            rec.timestamp(timer, "roots");
            rec.barrier();
            if device_top {
                self.record_top(rec, b, timer);
                if let Some(cl) = &collapsed {
                    self.record_collapse(rec, bvh_nodes, parents, counters, total, cl, max_leaf, timer);
                }
                rec.barrier();
                rec.copy(starts, 0, readback, 0, 4);
                rec.copy(top_work, 4 * top_error_word(max_clusters), readback, 4, 4);
                rec.host_read_barrier();
            } else {
                rec.copy(starts, 0, readback, 0, 4 * (max_clusters + 2));
                rec.copy(roots, 0, readback, 4 * (max_clusters + 2), 32 * max_clusters);
                rec.host_read_barrier();
            }
        }
        Ok(())
    }

    /// Records the device top level of an HLBVH (`glsl/hlbvh_top.comp`: its phase 0, the rounds of phase 1, phase 2
    /// over the serial subtrees), which writes the `C - 1` top nodes and their children's parent links. Begins after
    /// the barrier that follows `hlbvh_roots`; ends with the shader writes of phase 2 and no barrier after them.
    fn record_top(&self, rec: &mut Recorder<'_>, b: &BuildBuffers, timer: &mut Timer) {
        let bins = b.hl.map_or(2, |(_, bins)| bins);
        let (nb, factor) = crate::accel::hlbvh::top_bins(bins);
        let plan = TopPlan::new(b.max_clusters, nb, self.ctx.caps().device_type == DeviceType::Cpu);
        let wg = self.top.workgroup_size() as u64;
        let mut push = TopPush {
            starts: b.starts.address(),
            roots: b.roots.address(),
            nodes: b.bvh_nodes.address(),
            parents: b.parents.address(),
            work: b.top_work.address(),
            limit: b.max_clusters as u32,
            bins: nb as u32,
            factor,
            task_min: plan.task_min,
            phase: 0,
            round: 0,
        };
        // SAFETY: starts holds max_clusters + 2 words and roots max_clusters nodes (written by hlbvh_scan and
        // hlbvh_roots), nodes and parents 2n - 1 entries (the top nodes and every cluster root are among them), and
        // the work buffer top_work_words(max_clusters) words, the layout the kernel indexes with `limit`.
        unsafe { rec.dispatch(&self.top, &push, rec.groups_for(b.max_clusters, wg)) };
        rec.barrier();
        push.phase = 1;
        for round in 0..plan.rounds {
            push.round = round;
            // SAFETY: as above.
            unsafe { rec.dispatch(&self.top, &push, plan.groups) };
            rec.barrier();
        }
        rec.timestamp(timer, "top_rounds");
        push.phase = 2;
        push.round = plan.rounds;
        // SAFETY: as above.
        unsafe { rec.dispatch(&self.top, &push, rec.groups_for(b.max_clusters / 2 + 1, wg)) };
        rec.timestamp(timer, "top_tasks");
    }

    /// Records the SAH collapse (`bvh_collapse_cost`, `bvh_compact`) of the `count` nodes of a fitted tree with
    /// one record per leaf into `out = (nodes, parents, info, readback)`, and copies the root's surviving node
    /// count to `readback` (begins with the barrier it needs after the fit).
    #[allow(clippy::too_many_arguments)]
    fn record_collapse(
        &self,
        rec: &mut Recorder<'_>,
        nodes: &Buffer,
        parents: &Buffer,
        counters: &Buffer,
        count: u64,
        out: &(Buffer, Buffer, Buffer, Buffer),
        max_leaf: u32,
        timer: &mut Timer,
    ) {
        let (out_nodes, out_parents, info, readback) = out;
        rec.barrier();
        rec.fill(counters, 0, Some(4 * count), 0);
        rec.barrier();
        let push = CollapseCostPush {
            nodes: nodes.address(),
            parents: parents.address(),
            counters: counters.address(),
            info: info.address(),
            count,
            max_leaf,
            pad: 0,
        };
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe {
            rec.dispatch(&self.collapse_cost, &push, rec.groups_for(count, self.collapse_cost.workgroup_size() as u64))
        };
        rec.timestamp(timer, "collapse_cost");
        rec.barrier();
        let push = CompactPush {
            nodes: nodes.address(),
            parents: parents.address(),
            info: info.address(),
            out_nodes: out_nodes.address(),
            out_parents: out_parents.address(),
            count,
        };
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.compact, &push, rec.groups_for(count, self.compact.workgroup_size() as u64)) };
        rec.timestamp(timer, "compact");
        rec.barrier();
        rec.copy(info, 4 * COLLAPSE_SIZE as u64, readback, 0, 4);
        rec.host_read_barrier();
    }

    /// Records the leaf boxes and the bottom-up fit of `count` nodes (begins with the barrier it needs after the
    /// tree's topology was written).
    #[allow(clippy::too_many_arguments)]
    fn record_boxes(
        &self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        ids: &Buffer,
        nodes: &Buffer,
        parents: &Buffer,
        counters: &Buffer,
        count: u64,
        mut timer: Option<&mut Timer>,
    ) {
        let per_group = self.leaves.workgroup_size() as u64 * ITEMS as u64;
        rec.fill(counters, 0, Some(4 * count), 0);
        rec.barrier();
        let push = geometry_push!(LeavesPush, mesh, { ids: ids.address(), nodes: nodes.address(), count: count });
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.leaves, &push, rec.groups_for(count, per_group)) };
        if let Some(t) = timer.as_deref_mut() {
            rec.timestamp(t, "leaves");
        }
        rec.barrier();
        let push = FitPush { nodes: nodes.address(), parents: parents.address(), counters: counters.address(), count };
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.fit, &push, rec.groups_for(count, self.fit.workgroup_size() as u64)) };
        if let Some(t) = timer {
            rec.timestamp(t, "fit");
        }
    }

    /// Records a refit of `bvh` for the positions now in `mesh` (same triangles as at build): leaf boxes, counters
    /// reset, bottom-up fit. A recorded build may be refitted before it is finished (in a later command buffer or
    /// later in the same one), unless it has the SAH collapse, whose node count is known only then.
    ///
    /// Synchronization: begins with [`Recorder::barrier`] (the new positions, written by a transfer or a kernel
    /// before, are visible); ends with the fit's shader writes to [`GpuBvh::nodes`] and no barrier after it: the
    /// caller records one before reading the nodes. `mesh` and `bvh` must stay alive until the command buffer
    /// completes.
    pub fn record_refit(&self, rec: &mut Recorder<'_>, mesh: &GeometryView<'_>, bvh: &GpuBvh) -> Result<()> {
        check_refit(mesh, bvh)?;
        rec.barrier();
        self.record_boxes(rec, mesh, &bvh.ids, &bvh.nodes, &bvh.parents, &bvh.counters, bvh.node_count(), None);
        Ok(())
    }

    /// Refits `bvh` for the positions now in `mesh` (see [`BvhBuilder::record_refit`]); submits and waits, and
    /// stores the pass times in [`GpuBvh::timings`].
    pub fn refit(&self, mesh: &GeometryView<'_>, bvh: &mut GpuBvh) -> Result<()> {
        check_refit(mesh, bvh)?;
        let ctx = self.ctx.clone();
        let mut timer = Timer::new(&ctx, 4)?;
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut timer);
            rec.barrier();
            rec.timestamp_start(&mut timer);
            self.record_boxes(
                rec,
                mesh,
                &bvh.ids,
                &bvh.nodes,
                &bvh.parents,
                &bvh.counters,
                bvh.node_count(),
                Some(&mut timer),
            );
            Ok(())
        })?;
        bvh.timings = timer.read()?;
        Ok(())
    }
}

/// The cluster width of an HLBVH build on the device: [`GpuError::Limit`] above [`MAX_GPU_CLUSTER_BITS`].
fn gpu_cluster_bits(o: &HlbvhOptions) -> Result<u32> {
    let cb = o.cluster_bits.min(o.bits.total());
    if cb > MAX_GPU_CLUSTER_BITS {
        return Err(GpuError::Limit {
            what: "HLBVH cluster bits on the GPU".into(),
            requested: cb as u64,
            limit: MAX_GPU_CLUSTER_BITS as u64,
        });
    }
    Ok(cb)
}

/// A recorded build's quantizer has the options' code width ([`InputError::Plan`] otherwise).
fn check_quantizer(quantizer: &Quantizer, bits: MortonBits) -> std::result::Result<(), InputError> {
    if quantizer.bits() != bits {
        return Err(InputError::Plan(format!(
            "the quantizer has {}-bit codes, the options ask for {}",
            quantizer.bits().total(),
            bits.total()
        )));
    }
    Ok(())
}

/// A refit needs the tree's triangles, and a finished tree (a recorded build's node count is known only then).
fn check_refit(mesh: &GeometryView<'_>, bvh: &GpuBvh) -> Result<()> {
    if mesh.triangle_count() != bvh.triangles {
        return Err(GpuError::Buffer(format!(
            "refit: the geometry has {} triangles, the tree {}",
            mesh.triangle_count(),
            bvh.triangles
        )));
    }
    if bvh.pending.as_ref().is_some_and(|p| p.collapsed_count.is_some()) {
        return Err(GpuError::Buffer(
            "refit of a recorded build with the SAH collapse not yet finished (GpuBvh::finish reads its node count)"
                .into(),
        ));
    }
    Ok(())
}
