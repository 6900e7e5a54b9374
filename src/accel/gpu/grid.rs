//! The uniform grid built on the device: the host grid's cell lists ([`crate::accel::grid`], "Build"), cell for
//! cell and in the same order, from an engine's geometry view, with a bounded reference array.
//!
//! # Passes
//!
//! All kernels run the host's cell rule (`glsl/include/grid.glsl`: the box cells in f32, the slab-and-row clipping
//! in f64, operation for operation; the frame, [`GridFrame`], is computed once on the host from the scene box).
//!
//! 1. `grid_count` (`glsl/grid_cells.comp`, MODE 0): per triangle, its record (the [`TriRecord`] the traversal
//!    reads, mesh order) and its number of cells, also added to a 64-bit reference total.
//! 2. `grid_scan`: the exclusive prefix sums of the counts (`RadixSort::record_exclusive_scan`): where each
//!    triangle's references begin.
//! 3. `grid_emit` (MODE 1): per triangle, its cells as sort keys with the triangle as payload, from its offset on:
//!    the references in triangle order.
//! 4. `grid_sort`: the stable radix sort ([`RadixSort`]) of the (cell, triangle) pairs by cell, so every cell's
//!    triangles stay in triangle order, the host grid's order.
//! 5. `grid_starts` (`glsl/grid_starts.comp`): per cell, the first sorted position of its cell (a binary search):
//!    the cell starts; the sorted payload is the reference array.
//!
//! Passes 3 to 5 do nothing when the total of pass 1 exceeds the limit (the reference budget, the bytes budget or
//! the reference array's capacity): the build then fails with the count it needed, without writing the cells.
//! Every pass is a whole-device pass over triangles or cells: no invocation waits for another, and an invocation's
//! work is one triangle's (or one cell's). lavapipe stops a subgroup's loop after 65,535 iterations (gallivm's loop
//! limiter), invisibly to the kernel's code. Two checks turn that into an error ([`GridBuildError::LoopLimit`]):
//! on CPU drivers the per-triangle kernel counts its subgroup's loop iterations and flags 65,000 or more, and after
//! the lists the host compares the last cell start (the references the sort found) with the count. Only triangles
//! over very many cells reach the limit (a floor of half a million cells does; no shared mesh does).
//!
//! # Budget and capacity
//!
//! The budgets are the host grid's ([`GridOptions::reference_budget`], [`GridOptions::max_bytes`]); past them
//! [`GpuGrid::finish`] reports [`AccelError::OverBudget`] with the total the triangles need (the host reports the
//! prefix at the first triangle that crosses the budget: the same error, a larger count). A recorded build
//! ([`GridBuilder::record`]) writes into a reference array of [`GridPlan::capacity`] entries (default
//! [`GridPlan::DEFAULT_CAPACITY_PER_TRIANGLE`] per triangle, within the budget); a grid that needs more fails with
//! [`GridBuildError::Capacity`], which says how many, so that the engine records the next build with room enough.
//! [`GridBuilder::build`] submits twice instead: the count, then (after reading the total) the lists into arrays of
//! exactly the size needed. Device memory: 4 bytes per cell and per triangle, 48 per triangle record, and 16 bytes
//! per reference of capacity (keys and payloads, twice for the sort) plus the sort's scratch.
//!
//! # Arithmetic
//!
//! The f64 operations are assumed correctly rounded (IEEE 754), as lavapipe's (LLVM) and current GPUs' f64 units
//! compute them; Vulkan itself promises no more than f32 accuracy for f64 division and square root. The tests
//! compare every cell list with the host grid's on the shared meshes and degenerate scenes, and the oracle compares
//! the lists of every grid it builds on the device with the host's.
//!
//! # Result
//!
//! [`GpuGrid`] keeps the grid on the device: [`GpuGrid::cell_start`] (`cells + 1` `u32`: cell `c`'s list is
//! `refs[cell_start[c] .. cell_start[c + 1]]`, cell `(x, y, z)` is `x + res_x (y + res_y z)`), [`GpuGrid::refs`]
//! (triangle indices) and [`GpuGrid::records`] (one [`TriRecord`] per triangle, mesh order): the layout of
//! [`crate::accel::device_trace::DeviceLayout::Grid`], which [`GpuGrid::into_device_structure`] hands to the traversal
//! kernel without a read-back.

use crate::accel::device_trace::{DeviceStructure, TraceScene, TriRecord};
pub use crate::accel::grid_rule::{GridFrame, GridOptions};
use crate::accel::{AccelError, MAX_TRIANGLES};
use crate::geom::{Aabb, Triangle};
use crate::gpu::sort::{KeyBits, RadixSort, SortConfig, SortStorage, SortedIn};
use crate::gpu::{
    geometry_push, shaders, Buffer, CompletionFlag, Context, GeometryView, GpuError, InputError, Kernel, KernelDesc,
    MemoryKind, Pass, Recorder, Timer,
};

pub(crate) use crate::gpu::shaders::grid_cells::Push as GridCellsPush;
pub(crate) use crate::gpu::shaders::grid_starts::Push as GridStartsPush;
pub(crate) use crate::gpu::shaders::GridHeader;

/// Largest resolution along one axis the device builder takes (the host grid's default `max_resolution` is 1,024).
pub const MAX_DEVICE_RESOLUTION: u32 = 65_535;
/// Bytes of the build's info words: the reference total (u64), the cut-loop flag (u32), padding.
const INFO_BYTES: u64 = 16;

/// Errors of the device grid builder.
#[derive(Debug, thiserror::Error)]
pub enum GridBuildError {
    /// The device failed, or a limit was exceeded.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The input cannot be built: over a budget, coordinates out of range, too many cells or triangles.
    #[error(transparent)]
    Accel(#[from] AccelError),
    /// No triangles.
    #[error(transparent)]
    Input(#[from] InputError),
    /// On a CPU driver, a subgroup's loops ran 65,000 iterations or more (lavapipe stops a loop after 65,535, which
    /// the kernel cannot see): some triangle covers more cells than the device builder may visit on this driver.
    /// Nothing wrong is returned; the host grid builds the scene.
    #[error("device grid: the {pass} pass reached the driver's loop limit (lavapipe stops a loop after 65,535 iterations): a triangle covers too many cells for the device builder on this driver")]
    LoopLimit {
        /// The pass whose loop was cut (`count`, or `lists` for the emission and the cell starts).
        pass: &'static str,
    },
    /// The recorded build's reference array was too small (nothing was written to the cells).
    #[error("grid: needs {needed} cell references, the reference array holds {capacity}: record the build again with GridPlan::with_capacity({needed})")]
    Capacity {
        /// References the grid needs.
        needed: u64,
        /// The array's capacity.
        capacity: u64,
    },
}

/// The union of the boxes of `mesh`'s triangles: the scene box the host grid's frame comes from, to pass to
/// [`GridPlan::new`] or [`GridBuilder::build`] for the host grid's cells (an engine passes the box it keeps).
pub fn triangle_bounds(mesh: &crate::mesh::Mesh) -> Aabb {
    (0..mesh.triangle_count()).fold(Aabb::EMPTY, |b, i| b.union(&Aabb::of_triangle(&mesh.triangle(i))))
}

/// What a device grid build needs before it is recorded: the frame (from the scene box the caller knows), the
/// triangle count, the budgets and the reference array's capacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridPlan {
    frame: GridFrame,
    options: GridOptions,
    triangles: u64,
    budget: u64,
    max_bytes: u64,
    capacity: u64,
}

impl GridPlan {
    /// Default capacity of a recorded build's reference array, per triangle (the shared meshes need at most 5.0).
    pub const DEFAULT_CAPACITY_PER_TRIANGLE: u64 = 8;

    /// The plan of a grid over `triangles` triangles whose boxes' union is `scene` (the host grid's scene box:
    /// with another box the frame, and so the cells, differ from the host grid's), with options `o`.
    ///
    /// # Errors
    ///
    /// [`InputError::Empty`] for no triangles; [`AccelError::TooLarge`] past [`MAX_TRIANGLES`] triangles or
    /// `2^32 - 1` cells; [`AccelError::CoordinateRange`] for a scene box that is not finite; [`GpuError::Limit`]
    /// for a resolution above [`MAX_DEVICE_RESOLUTION`] along an axis.
    pub fn new(scene: &Aabb, triangles: u64, o: &GridOptions) -> Result<Self, GridBuildError> {
        if triangles == 0 {
            return Err(InputError::Empty.into());
        }
        if triangles > MAX_TRIANGLES as u64 {
            let (count, limit) = (triangles as usize, MAX_TRIANGLES);
            return Err(AccelError::TooLarge { structure: "grid", what: "triangles", count, limit }.into());
        }
        if !(scene.max - scene.min).is_finite() {
            return Err(AccelError::CoordinateRange {
                structure: "grid",
                lo: scene.min.to_array(),
                hi: scene.max.to_array(),
            }
            .into());
        }
        let frame = GridFrame::new(scene, triangles as usize, o);
        if let Some(&r) = frame.res.iter().find(|&&r| r > MAX_DEVICE_RESOLUTION) {
            return Err(GpuError::Limit {
                what: "device grid: cells along one axis".into(),
                requested: u64::from(r),
                limit: u64::from(MAX_DEVICE_RESOLUTION),
            }
            .into());
        }
        if frame.cells() >= u64::from(u32::MAX) {
            let limit = u32::MAX as usize;
            return Err(AccelError::TooLarge {
                structure: "grid",
                what: "cells",
                count: frame.cells() as usize,
                limit,
            }
            .into());
        }
        let budget = o.reference_budget(triangles as usize) as u64;
        let capacity = budget.min(Self::DEFAULT_CAPACITY_PER_TRIANGLE.saturating_mul(triangles)).max(1);
        Ok(GridPlan { frame, options: *o, triangles, budget, max_bytes: o.max_bytes as u64, capacity })
    }

    /// The plan with a reference array of `references` entries (at least 1).
    pub fn with_capacity(mut self, references: u64) -> Self {
        self.capacity = references.max(1);
        self
    }

    /// The grid's frame (bounds, resolution, cell size, widening).
    pub fn frame(&self) -> &GridFrame {
        &self.frame
    }
    /// Triangles.
    pub fn triangles(&self) -> u64 {
        self.triangles
    }
    /// The reference budget ([`GridOptions::reference_budget`]).
    pub fn budget(&self) -> u64 {
        self.budget
    }
    /// Entries of a recorded build's reference array.
    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Bytes of the grid with `total` references, as [`crate::accel::AccelStructure::memory_bytes`] counts the
    /// host grid's (cell starts, references, host triangle records).
    fn bytes(&self, total: u64) -> u64 {
        4 * (self.frame.cells() + 1) + 4 * total + self.triangles * std::mem::size_of::<Triangle>() as u64
    }

    /// The largest total the list passes work on: within the budget, the bytes budget, `capacity` and `u32`.
    fn limit(&self, capacity: u64) -> u64 {
        let by_bytes = self.max_bytes.saturating_sub(self.bytes(0)) / 4;
        self.budget.min(by_bytes).min(capacity).min(u64::from(u32::MAX) - 1)
    }

    /// The build's error for a total of `total` references into an array of `capacity`, if any, in the host
    /// grid's order (references, count, bytes), then the capacity.
    fn check(&self, total: u64, capacity: u64) -> Result<(), GridBuildError> {
        let n = self.triangles as usize;
        if total > self.budget {
            return Err(self.options.over_references(n, total as usize).into());
        }
        if total >= u64::from(u32::MAX) {
            let limit = u32::MAX as usize;
            return Err(
                AccelError::TooLarge { structure: "grid", what: "references", count: total as usize, limit }.into()
            );
        }
        let bytes = self.bytes(total);
        if bytes > self.max_bytes {
            return Err(AccelError::OverBudget {
                structure: "grid",
                what: "bytes",
                needed: bytes as usize,
                budget: self.max_bytes as usize,
                rule: format!("GridOptions::max_bytes, for {} cells and {total} cell references", self.frame.cells()),
            }
            .into());
        }
        if total > capacity {
            return Err(GridBuildError::Capacity { needed: total, capacity });
        }
        Ok(())
    }

    fn header(&self) -> GridHeader {
        let f = &self.frame;
        GridHeader {
            widen_x: f.widen.x,
            widen_y: f.widen.y,
            widen_z: f.widen.z,
            pad_scale: f.pad_scale,
            lo: f.bounds.min.to_array(),
            res_x: f.res[0],
            cell_size: f.cell_size.to_array(),
            res_y: f.res[1],
            inv_cell: f.inv_cell.to_array(),
            res_z: f.res[2],
        }
    }
}

/// A grid built (or being built) on the device; see the module docs.
pub struct GpuGrid {
    plan: GridPlan,
    cell_start: Buffer,
    records: Buffer,
    header: Buffer,
    counts: Buffer,
    scan_scratch: Buffer,
    info: Buffer,
    info_readback: Buffer,
    sort: Option<SortStorage>,
    sorted_in: SortedIn,
    capacity: u64,
    pending: Option<(Timer, CompletionFlag)>,
    references: Option<u64>,
    timings: Vec<(String, f64)>,
    /// Address of the copy flags the build skips (0: none; [`GridBuilder::build_with_copies`]).
    copies: u64,
}

impl std::fmt::Debug for GpuGrid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuGrid")
            .field("res", &self.plan.frame.res)
            .field("triangles", &self.plan.triangles)
            .field("references", &self.references)
            .finish()
    }
}

impl GpuGrid {
    /// Completes a recorded build once its command buffer has completed: reads the reference total, the cut-loop
    /// flag and the pass times, and reports an overrun.
    ///
    /// # Errors
    ///
    /// [`GpuError::NotReady`] before the command buffer has completed; [`AccelError::OverBudget`] /
    /// [`AccelError::TooLarge`] past the host grid's budgets; [`GridBuildError::Capacity`] when the reference
    /// array was too small; [`GridBuildError::LoopLimit`] when the driver cut a loop (the cells are then not valid).
    pub fn finish(&mut self) -> Result<(), GridBuildError> {
        if let Some((timer, done)) = &self.pending {
            done.check("device grid build")?;
            let timings = timer.read()?;
            self.timings.extend(timings);
            self.pending = None;
        }
        self.references = None;
        let total = self.read_info("lists")?;
        self.plan.check(total, self.capacity)?;
        self.references = Some(total);
        Ok(())
    }

    /// The reference total of the readback words, or the loop-limit error of `pass` when the flag is set.
    fn read_info(&self, pass: &'static str) -> Result<u64, GridBuildError> {
        let words: Vec<u32> = self.info_readback.read(0, 4)?;
        if words[2] != 0 {
            return Err(GridBuildError::LoopLimit { pass });
        }
        let total = u64::from(words[0]) | (u64::from(words[1]) << 32);
        // After the lists: the last cell start is the number of references the sort found, which a loop the
        // driver cut leaves short of the count.
        if pass == "lists" && total <= self.plan.limit(self.capacity) && u64::from(words[3]) != total {
            return Err(GridBuildError::LoopLimit { pass });
        }
        Ok(total)
    }

    /// Whether a recorded build has not been finished yet.
    pub fn is_pending(&self) -> bool {
        self.pending.is_some()
    }
    /// The plan it was built with.
    pub fn plan(&self) -> &GridPlan {
        &self.plan
    }
    /// Cell references, once finished without error.
    pub fn reference_count(&self) -> Option<u64> {
        self.references
    }
    /// `(pass, GPU milliseconds)` of the build's passes (both submissions of [`GridBuilder::build`]).
    pub fn timings(&self) -> &[(String, f64)] {
        &self.timings
    }
    /// GPU milliseconds of all passes.
    pub fn gpu_ms(&self) -> f64 {
        self.timings.iter().map(|(_, ms)| ms).sum()
    }
    /// The cell starts (`cells + 1` `u32`).
    pub fn cell_start(&self) -> &Buffer {
        &self.cell_start
    }
    /// The references (triangle indices, [`GpuGrid::reference_count`] of them valid).
    pub fn refs(&self) -> Option<&Buffer> {
        let s = self.sort.as_ref()?;
        s.result(self.sorted_in).1
    }
    /// The triangle records, mesh order.
    pub fn records(&self) -> &Buffer {
        &self.records
    }

    fn finished_total(&self) -> Result<u64, GridBuildError> {
        if self.pending.is_some() {
            return Err(GpuError::NotReady("device grid build".into()).into());
        }
        self.references
            .ok_or_else(|| GpuError::NotReady("device grid build (not finished without error)".into()).into())
    }

    /// Reads the cell starts and the references back (for checks against the host grid).
    ///
    /// # Errors
    ///
    /// [`GpuError::NotReady`] unless [`GpuGrid::finish`] succeeded, or a device error.
    pub fn read_back(&self, ctx: &Context) -> Result<(Vec<u32>, Vec<u32>), GridBuildError> {
        let total = self.finished_total()?;
        let starts = ctx.read_buffer(&self.cell_start, 0, (self.plan.frame.cells() + 1) as usize)?;
        let refs = match self.refs() {
            Some(r) => ctx.read_buffer(r, 0, total as usize)?,
            None => Vec::new(),
        };
        Ok((starts, refs))
    }

    /// The grid as the traversal kernel's structure ([`crate::accel::device_trace::DeviceTracer`]), its buffers moved,
    /// only the 64-byte scene header uploaded (submits and waits).
    ///
    /// # Errors
    ///
    /// [`GpuError::NotReady`] unless [`GpuGrid::finish`] succeeded, or a device error.
    pub fn into_device_structure(self, ctx: &Context) -> Result<DeviceStructure, GridBuildError> {
        let start = std::time::Instant::now();
        self.finished_total()?;
        let f = &self.plan.frame;
        let scene = TraceScene {
            lo: f.bounds.min.to_array(),
            hi: f.bounds.max.to_array(),
            res_x: f.res[0],
            res_y: f.res[1],
            res_z: f.res[2],
            cell_size: f.cell_size.to_array(),
            inv_cell: f.inv_cell.to_array(),
            nodes: self.plan.triangles as u32,
        };
        let scene = ctx.upload("trace scene", std::slice::from_ref(&scene))?;
        let sort = self.sort.ok_or_else(|| GpuError::NotReady("device grid build without its lists".into()))?;
        let refs = match (self.sorted_in, sort.payload) {
            (SortedIn::Input, Some((p, _))) | (SortedIn::Alternate, Some((_, p))) => p,
            (_, None) => return Err(GpuError::Buffer("device grid: sort storage without payload".into()).into()),
        };
        Ok(DeviceStructure::from_grid_parts(self.cell_start, self.records, refs, scene, start.elapsed()))
    }
}

/// The device grid builder's pipelines.
pub struct GridBuilder {
    ctx: Context,
    cells: [Kernel<GridCellsPush>; 2],
    starts: Kernel<GridStartsPush>,
    sort: RadixSort,
}

impl std::fmt::Debug for GridBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GridBuilder").field("device", &self.ctx.caps().name).finish()
    }
}

impl GridBuilder {
    /// Builds the pipelines (the cell rule needs `shaderFloat64`).
    ///
    /// # Errors
    ///
    /// [`GpuError::Unsupported`] without `shaderFloat64`; a device error.
    pub fn new(ctx: &Context) -> Result<Self, GpuError> {
        if !ctx.caps().float64 {
            return Err(GpuError::Unsupported {
                name: ctx.caps().name.clone(),
                missing: vec!["shaderFloat64 (the device grid builder runs the host grid's f64 cell rule)".into()],
            });
        }
        // On CPU drivers (lavapipe cuts a subgroup's loops after 65,535 iterations) the kernel counts its loops.
        let check = u32::from(ctx.caps().device_type == crate::gpu::DeviceType::Cpu);
        let cells = |m: u32| {
            Kernel::new(
                ctx,
                &KernelDesc::new(&shaders::grid_cells::INFO).constant("MODE", m).constant("CHECK_LOOPS", check),
            )
        };
        Ok(GridBuilder {
            ctx: ctx.clone(),
            cells: [cells(0)?, cells(1)?],
            starts: Kernel::new(ctx, &KernelDesc::new(&shaders::grid_starts::INFO))?,
            sort: RadixSort::new(ctx, SortConfig::for_device(ctx.caps()))?,
        })
    }

    /// The buffers of a build of `plan` over `view`, without the lists' (see [`GridBuilder::allocate_lists`]).
    fn allocate(
        &self,
        view: &GeometryView<'_>,
        plan: &GridPlan,
        copies: Option<&Buffer>,
    ) -> Result<GpuGrid, GridBuildError> {
        if view.triangle_count() != plan.triangles {
            return Err(GpuError::Buffer(format!(
                "device grid: the view has {} triangles, the plan {}",
                view.triangle_count(),
                plan.triangles
            ))
            .into());
        }
        if let Some(c) = copies.filter(|c| c.size() < 4 * plan.triangles) {
            return Err(GpuError::Buffer(format!(
                "device grid: the copy flags hold {} bytes, {} triangles need {}",
                c.size(),
                plan.triangles,
                4 * plan.triangles
            ))
            .into());
        }
        let ctx = &self.ctx;
        let n = plan.triangles;
        let dev = |name: &str, bytes: u64| ctx.create_buffer(name, bytes, MemoryKind::DeviceLocal);
        Ok(GpuGrid {
            plan: *plan,
            cell_start: dev("grid cell starts", 4 * (plan.frame.cells() + 1))?,
            records: dev("grid records", n * std::mem::size_of::<TriRecord>() as u64)?,
            header: ctx.upload("grid header", std::slice::from_ref(&plan.header()))?,
            counts: dev("grid counts", 4 * (n + 1))?,
            scan_scratch: dev("grid scan scratch", self.sort.scan_scratch_bytes(n + 1))?,
            info: dev("grid info", INFO_BYTES)?,
            info_readback: ctx.create_buffer("grid info readback", INFO_BYTES, MemoryKind::Readback)?,
            sort: None,
            sorted_in: SortedIn::Input,
            capacity: 0,
            pending: None,
            references: None,
            timings: Vec::new(),
            copies: copies.map_or(0, Buffer::address),
        })
    }

    /// The sort's buffers for `capacity` references.
    fn allocate_lists(&self, g: &mut GpuGrid, capacity: u64) -> Result<(), GridBuildError> {
        let capacity = capacity.max(1);
        if capacity > self.sort.max_count() {
            let limit = self.sort.max_count();
            return Err(GpuError::Limit { what: "device grid references".into(), requested: capacity, limit }.into());
        }
        let mem = self.sort.memory_requirements(capacity, KeyBits::U32);
        g.sort = Some(SortStorage::new(&self.ctx, &mem, true)?);
        g.capacity = capacity;
        Ok(())
    }

    fn cells_push(&self, view: &GeometryView<'_>, g: &GpuGrid, limit: u64) -> GridCellsPush {
        let (keys, payload) = match &g.sort {
            Some(s) => (s.keys.address(), s.payload.as_ref().map_or(0, |p| p.0.address())),
            None => (0, 0),
        };
        geometry_push!(GridCellsPush, view, {
            header: g.header.address(),
            records: g.records.address(),
            info: g.info.address(),
            counts: g.counts.address(),
            keys: keys,
            payload: payload,
            count: g.plan.triangles,
            limit: limit,
            skip: g.copies,
        })
    }

    /// Pass 1 (records, counts, the total).
    fn record_count(&self, rec: &mut Recorder<'_>, view: &GeometryView<'_>, g: &GpuGrid, timer: &mut Timer) {
        let n = g.plan.triangles;
        rec.fill(&g.info, 0, Some(INFO_BYTES), 0);
        rec.fill(&g.counts, 4 * n, Some(4), 0);
        rec.dependency(Pass::Transfer, Pass::Compute);
        rec.timestamp_start(timer);
        let push = self.cells_push(view, g, 0);
        let wg = self.cells[0].workgroup_size() as u64;
        // SAFETY: reads the view's triangles and the header; writes n records (n * 48 bytes), n counts and the
        // info words.
        unsafe { rec.dispatch(&self.cells[0], &push, rec.groups_for(n, wg)) };
        rec.timestamp(timer, "grid_count");
    }

    /// Passes 2 to 5 into the sort storage of `g` (allocated).
    fn record_lists(
        &self,
        rec: &mut Recorder<'_>,
        view: &GeometryView<'_>,
        g: &mut GpuGrid,
        timer: &mut Timer,
    ) -> Result<(), GridBuildError> {
        let n = g.plan.triangles;
        let limit = g.plan.limit(g.capacity);
        let cells = g.plan.frame.cells();
        let sort = g.sort.as_ref().ok_or_else(|| GpuError::Buffer("device grid: lists not allocated".into()))?;
        self.sort.record_exclusive_scan(rec, &g.counts, n + 1, &g.scan_scratch)?;
        rec.timestamp(timer, "grid_scan");
        rec.fill(&sort.keys, 0, None, u32::MAX);
        rec.barrier();
        let push = self.cells_push(view, g, limit);
        let wg = self.cells[1].workgroup_size() as u64;
        // SAFETY: with a total within `limit` <= capacity, triangle i writes its count of keys and payloads from
        // its offset on, inside the total.
        unsafe { rec.dispatch(&self.cells[1], &push, rec.groups_for(n, wg)) };
        rec.timestamp(timer, "grid_emit");
        let sorted_in = self.sort.record(rec, &sort.buffers(), g.capacity, KeyBits::U32)?;
        rec.timestamp(timer, "grid_sort");
        rec.barrier();
        let (keys, _) = sort.result(sorted_in);
        let push = GridStartsPush {
            keys: keys.address(),
            starts: g.cell_start.address(),
            info: g.info.address(),
            cells,
            limit,
        };
        let wg = self.starts.workgroup_size() as u64;
        // SAFETY: reads `total` sorted keys (total <= capacity), writes cells + 1 starts.
        unsafe { rec.dispatch(&self.starts, &push, rec.groups_for(cells + 1, wg)) };
        rec.timestamp(timer, "grid_starts");
        g.sorted_in = sorted_in;
        Ok(())
    }

    /// Copies the info words (total, cut flag) and, after the lists, the last cell start to the readback words.
    fn record_info(rec: &mut Recorder<'_>, g: &GpuGrid, lists: bool) {
        rec.dependency(Pass::Compute, Pass::Transfer);
        rec.copy(&g.info, 0, &g.info_readback, 0, 12);
        if lists {
            rec.copy(&g.cell_start, 4 * g.plan.frame.cells(), &g.info_readback, 12, 4);
        }
        rec.host_read_barrier();
    }

    /// Records the whole build into `rec` (no host round trip), then [`GpuGrid::finish`] once the command buffer
    /// has completed. The reference arrays hold [`GridPlan::capacity`] entries.
    ///
    /// Recording contract: the first access to the geometry is a compute-shader read (the caller records a
    /// barrier before that makes its geometry writes visible to compute-shader reads); the last accesses are
    /// compute-shader writes to the grid's buffers and a transfer write to a readback word of the grid's own; the
    /// caller records a barrier before reading the grid. The grid and the builder stay alive until the command
    /// buffer completes.
    ///
    /// # Errors
    ///
    /// [`GpuError::Buffer`] when the view's triangle count is not the plan's; a device error.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        view: &GeometryView<'_>,
        plan: &GridPlan,
    ) -> Result<GpuGrid, GridBuildError> {
        self.record_skipping(rec, view, plan, None)
    }

    /// [`GridBuilder::record`] with the view's coincident copies stored once, as [`GridBuilder::build_with_copies`]
    /// takes them; `copies` is read by the recorded passes and stays alive until the command buffer completes.
    ///
    /// # Errors
    ///
    /// Those of [`GridBuilder::record`], and [`GpuError::Buffer`] when `copies` holds fewer than 4 bytes per
    /// triangle.
    pub fn record_with_copies(
        &self,
        rec: &mut Recorder<'_>,
        view: &GeometryView<'_>,
        plan: &GridPlan,
        copies: &Buffer,
    ) -> Result<GpuGrid, GridBuildError> {
        self.record_skipping(rec, view, plan, Some(copies))
    }

    fn record_skipping(
        &self,
        rec: &mut Recorder<'_>,
        view: &GeometryView<'_>,
        plan: &GridPlan,
        copies: Option<&Buffer>,
    ) -> Result<GpuGrid, GridBuildError> {
        let mut g = self.allocate(view, plan, copies)?;
        self.allocate_lists(&mut g, plan.capacity)?;
        let mut timer = Timer::new(&self.ctx, 8)?;
        rec.reset_timer(&mut timer);
        self.record_count(rec, view, &g, &mut timer);
        self.record_lists(rec, view, &mut g, &mut timer)?;
        Self::record_info(rec, &g, true);
        let mut done = CompletionFlag::new(&self.ctx)?;
        done.record(rec)?;
        g.pending = Some((timer, done));
        Ok(g)
    }

    /// Builds the grid of `view` (whose triangles' boxes' union is `scene`) with options `o` in two submissions:
    /// the count, then, with arrays of exactly the total, the lists. Returns a finished grid.
    ///
    /// # Errors
    ///
    /// Those of [`GridPlan::new`] and [`GpuGrid::finish`] (never [`GridBuildError::Capacity`]), or a device error.
    pub fn build(&self, view: &GeometryView<'_>, scene: &Aabb, o: &GridOptions) -> Result<GpuGrid, GridBuildError> {
        self.build_skipping(view, scene, o, None)
    }

    /// [`GridBuilder::build`] with the view's coincident copies stored once: `copies` holds one `u32` per triangle,
    /// nonzero for a triangle that is a copy of one of smaller index (bit-identical positions, as
    /// `crate::accel::grid::copy_flags` finds them on the host), which is then in no cell. With the host grid's
    /// flags the lists are the host grid's.
    ///
    /// # Errors
    ///
    /// Those of [`GridBuilder::build`], and [`GpuError::Buffer`] when `copies` holds fewer than 4 bytes per triangle.
    pub fn build_with_copies(
        &self,
        view: &GeometryView<'_>,
        scene: &Aabb,
        o: &GridOptions,
        copies: &Buffer,
    ) -> Result<GpuGrid, GridBuildError> {
        self.build_skipping(view, scene, o, Some(copies))
    }

    fn build_skipping(
        &self,
        view: &GeometryView<'_>,
        scene: &Aabb,
        o: &GridOptions,
        copies: Option<&Buffer>,
    ) -> Result<GpuGrid, GridBuildError> {
        let plan = GridPlan::new(scene, view.triangle_count(), o)?;
        let ctx = &self.ctx;
        let mut g = self.allocate(view, &plan, copies)?;
        let mut timer = Timer::new(ctx, 4)?;
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut timer);
            self.record_count(rec, view, &g, &mut timer);
            Self::record_info(rec, &g, false);
            Ok(())
        })?;
        g.timings = timer.read()?;
        let total = g.read_info("count")?;
        plan.check(total, total)?;
        self.allocate_lists(&mut g, total)?;
        let mut timer = Timer::new(ctx, 8)?;
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut timer);
            rec.timestamp_start(&mut timer);
            self.record_lists(rec, view, &mut g, &mut timer).map_err(|e| match e {
                GridBuildError::Gpu(x) => x,
                other => GpuError::Buffer(other.to_string()),
            })?;
            Self::record_info(rec, &g, true);
            Ok(())
        })?;
        g.timings.extend(timer.read()?);
        g.finish()?;
        Ok(g)
    }
}
