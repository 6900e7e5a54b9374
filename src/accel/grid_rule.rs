//! The uniform grid's resolution rule, shared by the grid (`accel::grid`, with the `eval` feature) and the
//! selection's bound of its references (`select::budget`, always built).

use super::AccelError;
use crate::geom::{Aabb, Polygon, Triangle};
use glam::{DVec3, Vec3};

/// Options of the grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridOptions {
    /// Cells per triangle, `lambda`.
    pub density: f32,
    /// Largest number of cells along one axis.
    pub max_resolution: u32,
    /// Largest number of cells in all.
    pub max_cells: usize,
    /// Cell references allowed per triangle (default 64; the shared meshes need at most 5.0): see
    /// [`GridOptions::reference_budget`].
    pub max_references_per_triangle: usize,
    /// Cell references always allowed, however few the triangles (default `2^25`, 128 MiB of references): see
    /// [`GridOptions::reference_budget`].
    pub min_reference_budget: usize,
    /// Largest size of the grid in bytes, as [`crate::accel::AccelStructure::memory_bytes`] counts it (cell starts, references,
    /// triangle records); default 4 GiB. A larger grid fails with [`AccelError::OverBudget`] before its reference
    /// array is allocated.
    pub max_bytes: usize,
}

impl Default for GridOptions {
    fn default() -> Self {
        GridOptions {
            density: 4.0,
            max_resolution: 1024,
            max_cells: 1 << 24,
            max_references_per_triangle: 64,
            min_reference_budget: 1 << 25,
            max_bytes: 4 << 30,
        }
    }
}

impl GridOptions {
    /// The most cell references a grid over `n` triangles may hold:
    /// `max(max_references_per_triangle * n, min_reference_budget)` (saturating). A build that needs more fails
    /// with [`AccelError::OverBudget`] (see the module docs).
    pub fn reference_budget(&self, n: usize) -> usize {
        self.max_references_per_triangle.saturating_mul(n).max(self.min_reference_budget)
    }

    /// The budget error of a grid over `n` triangles that needs at least `needed` cell references.
    pub(crate) fn over_references(&self, n: usize, needed: usize) -> AccelError {
        AccelError::OverBudget {
            structure: "grid",
            what: "cell references",
            needed,
            budget: self.reference_budget(n),
            rule: format!(
                "{} per triangle for {n} triangles, at least {}",
                self.max_references_per_triangle, self.min_reference_budget
            ),
        }
    }
}

/// The padded bounds and the resolution of a grid over `n` triangles in `bounds`: the density rule of Cleary and
/// Wyvill 1988 (`n_i = round(e_i * cbrt(density * n / V))`, clamped to `1 ..= max_resolution`), a zero extent
/// padded to `1e-3` of the largest (to 1 for a point), the density lowered until the cells fit `max_cells`.
pub(crate) fn resolution(
    bounds: &Aabb,
    n: usize,
    density: f32,
    max_resolution: u32,
    max_cells: usize,
) -> (Aabb, [u32; 3]) {
    let mut b = *bounds;
    let ext = b.extent();
    let m = ext.max_element();
    let floor = if m > 0.0 { m * 1e-3 } else { 1.0 };
    for a in 0..3 {
        if ext[a] < floor {
            let c = (b.min[a] + b.max[a]) * 0.5;
            b.min[a] = c - floor * 0.5;
            b.max[a] = c + floor * 0.5;
        }
    }
    let e = (b.max - b.min).as_dvec3();
    let vol = e.x * e.y * e.z;
    let mut d = (density.max(1e-6) as f64) * n.max(1) as f64;
    loop {
        let s = (d / vol).cbrt();
        let r = |x: f64| {
            let v = (x * s).round();
            if v.is_finite() {
                v.clamp(1.0, max_resolution.max(1) as f64) as u32
            } else {
                1
            }
        };
        let res = [r(e.x), r(e.y), r(e.z)];
        let cells = res.iter().map(|&x| x as usize).product::<usize>();
        if cells <= max_cells.max(1) || res == [1, 1, 1] {
            return (b, res);
        }
        d *= 0.8 * max_cells as f64 / cells as f64;
    }
}

/// The widening of a triangle's box cells, in cells (`1e-4`): see [`GridFrame`].
pub(crate) const WIDEN: f32 = 1e-4;

/// Everything the grid's cell rule needs besides the triangle: the padded bounds, the resolution, the cell size and
/// its inverse (f32, as the traversal uses them), and the two constants of the widening of a triangle's cells
/// (`crate::accel::grid`'s module docs): `widen = cell_size * WIDEN + max(|min|, |max|) * 8 eps` per axis (f64) and
/// `pad_scale = 16 eps (max(|min|, |max|) + largest extent)`, which the pad of a triangle multiplies by
/// `|e1| |e2| / |e1 x e2|`. The host grid and the device grid builder (`crate::accel::gpu::grid`) compute their
/// cells from one `GridFrame`, so both follow the same rule bit for bit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridFrame {
    /// The scene box, a zero extent padded (see `resolution`).
    pub bounds: Aabb,
    /// Cells along x, y, z.
    pub res: [u32; 3],
    /// Size of a cell, `(max - min) / res` in f32.
    pub cell_size: Vec3,
    /// `1 / cell_size` in f32.
    pub inv_cell: Vec3,
    /// The widening common to every triangle, per axis.
    pub widen: DVec3,
    /// The pad's factor of `|e1| |e2| / |e1 x e2|`.
    pub pad_scale: f64,
}

impl GridFrame {
    /// The frame of a grid over `n` triangles whose boxes' union is `scene`, with options `o`.
    pub fn new(scene: &Aabb, n: usize, o: &GridOptions) -> Self {
        let (bounds, res) = resolution(scene, n, o.density, o.max_resolution, o.max_cells);
        let cell_size = (bounds.max - bounds.min) / Vec3::new(res[0] as f32, res[1] as f32, res[2] as f32);
        let mag = bounds.min.abs().max(bounds.max.abs()).as_dvec3();
        let scale = mag.max_element() + bounds.extent().max_element() as f64;
        GridFrame {
            bounds,
            res,
            cell_size,
            inv_cell: Vec3::ONE / cell_size,
            widen: cell_size.as_dvec3() * WIDEN as f64 + mag * (8.0 * f32::EPSILON as f64),
            pad_scale: 16.0 * f32::EPSILON as f64 * scale,
        }
    }

    /// Cells in all (`res_x * res_y * res_z`).
    pub fn cells(&self) -> u64 {
        self.res.iter().map(|&r| u64::from(r)).product()
    }
}

impl Default for GridFrame {
    /// The frame of an empty grid: one cell over the empty box.
    fn default() -> Self {
        GridFrame {
            bounds: Aabb::default(),
            res: [1; 3],
            cell_size: Vec3::ONE,
            inv_cell: Vec3::ONE,
            widen: DVec3::ZERO,
            pad_scale: 0.0,
        }
    }
}

/// One row of the cells a triangle is stored in: cells `from ..= to` along axis `axes[2]`, in slab `slab` along
/// `axes[0]` and row `row` along `axes[1]` ([`GridFrame::for_each_run`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellRun {
    /// The axes of the slabs, the rows and the runs: the triangle's box's shortest side first, its longest last.
    pub axes: [usize; 3],
    /// The slab's cell index along `axes[0]`.
    pub slab: u32,
    /// The row's cell index along `axes[1]`.
    pub row: u32,
    /// The first cell of the run along `axes[2]`.
    pub from: u32,
    /// The last cell of the run along `axes[2]` (inclusive).
    pub to: u32,
}

impl CellRun {
    /// Cells in the run.
    pub fn len(&self) -> u64 {
        u64::from(self.to - self.from) + 1
    }

    /// The cell (x, y, z) of the run's `k`-th cell along `axes[2]` (`from <= k <= to`).
    #[cfg(feature = "eval")]
    pub(crate) fn cell(&self, k: u32) -> [u32; 3] {
        let mut c = [0u32; 3];
        (c[self.axes[0]], c[self.axes[1]], c[self.axes[2]]) = (self.slab, self.row, k);
        c
    }
}

/// A triangle's clipping against a frame's cells (the rule of `accel::grid`'s module docs): its box's cells, the
/// widening of its cells and the axes of its slabs, rows and runs.
struct Clipper {
    lo: [u32; 3],
    hi: [u32; 3],
    bmin: DVec3,
    cs: DVec3,
    w: DVec3,
    tri: Polygon,
    axes: [usize; 3],
    /// The f32 edges are parallel (`e1 x e2 = 0`): the triangle is stored in its whole box.
    all: bool,
}

impl Clipper {
    /// The cells along `axis` whose widened extent meets `lo ..= hi`, within the box's cells.
    fn cells(&self, axis: usize, (l, h): (f64, f64)) -> Option<(u32, u32)> {
        let from = ((l - self.w[axis] - self.bmin[axis]) / self.cs[axis]).floor().max(self.lo[axis] as f64);
        let to = ((h + self.w[axis] - self.bmin[axis]) / self.cs[axis]).floor().min(self.hi[axis] as f64);
        (from <= to).then_some((from as u32, to as u32))
    }

    /// The part of `p` within cell `k` along `axis`, widened.
    fn clip(&self, p: &Polygon, axis: usize, k: u32) -> Polygon {
        let edge = |k: u32| self.bmin[axis] + k as f64 * self.cs[axis];
        p.clip(axis, edge(k) - self.w[axis], edge(k + 1) + self.w[axis])
    }

    /// The triangle's part in slab `o` (the whole triangle when it is stored in its whole box).
    fn slab(&self, o: u32) -> Polygon {
        if self.all {
            self.tri
        } else {
            self.clip(&self.tri, self.axes[0], o)
        }
    }

    /// The cells along `axis` (`axes[1]` or `axes[2]`) that `part` meets.
    fn range(&self, part: &Polygon, axis: usize) -> Option<(u32, u32)> {
        if self.all {
            Some((self.lo[axis], self.hi[axis]))
        } else {
            part.range(axis).and_then(|r| self.cells(axis, r))
        }
    }
}

impl GridFrame {
    /// The cells of box `b` widened by `WIDEN` of a cell (f32): inclusive index ranges per axis.
    pub(crate) fn box_cells(&self, b: &Aabb) -> ([u32; 3], [u32; 3]) {
        let lo = ((b.min - self.bounds.min) * self.inv_cell - WIDEN).floor();
        let hi = ((b.max - self.bounds.min) * self.inv_cell + WIDEN).floor();
        let cl = |v: f32, a: usize| v.clamp(0.0, (self.res[a] - 1) as f32) as u32;
        ([cl(lo.x, 0), cl(lo.y, 1), cl(lo.z, 2)], [cl(hi.x, 0), cl(hi.y, 1), cl(hi.z, 2)])
    }

    /// The cell of the centre of box `b`, clamped into its cells `lo ..= hi` (NaN and overflow included): where a
    /// zero-area triangle, or one its clipping misses, is stored.
    fn centre_cell(&self, b: &Aabb, lo: [u32; 3], hi: [u32; 3]) -> [u32; 3] {
        let c = ((b.center() - self.bounds.min) * self.inv_cell).floor();
        let at = |a: usize| (c[a].max(0.0) as u32).clamp(lo[a], hi[a]);
        [at(0), at(1), at(2)]
    }

    /// The clipping of triangle `t` (box `b`), `None` for a triangle of zero extent (stored in one cell).
    fn clipper(&self, t: &Triangle, lo: [u32; 3], hi: [u32; 3]) -> Option<Clipper> {
        if t.is_degenerate() {
            return None;
        }
        let (v0, e1, e2) = (t.v0.as_dvec3(), t.e1.as_dvec3(), t.e2.as_dvec3());
        let normal_len = e1.cross(e2).length();
        let all = normal_len == 0.0;
        // The widening of every cell (see the type's docs) and the triangle's pad, `pad_scale / sin(alpha)` with
        // `1 / sin(alpha)` = `|e1| |e2| / |e1 x e2|`.
        let pad = if all { 0.0 } else { self.pad_scale * (e1.length() * e2.length() / normal_len) };
        let mut axes = [0usize, 1, 2];
        axes.sort_by_key(|&a| hi[a] - lo[a]);
        Some(Clipper {
            lo,
            hi,
            bmin: self.bounds.min.as_dvec3(),
            cs: self.cell_size.as_dvec3(),
            w: self.widen + pad,
            tri: Polygon {
                v: [v0, v0 + e1, v0 + e2, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO],
                len: 3,
            },
            axes,
            all,
        })
    }

    /// Calls `f` with every run of cells triangle `t` (box `b`) is stored in, slab by slab across the box's
    /// shortest side and row by row across the next, until `f` returns `false` (the rule of `accel::grid`'s module
    /// docs: one clip per slab and one per row, the runs as long as they can be). A zero-area triangle, and one
    /// whose clipping misses every cell through rounding, is stored in the cell of its box's centre.
    pub(crate) fn for_each_run(&self, t: &Triangle, b: &Aabb, mut f: impl FnMut(CellRun) -> bool) {
        let (lo, hi) = self.box_cells(b);
        if lo == hi {
            // A box in one cell: every path below stores the triangle there and only there (the runs lie in the
            // box's cells, and the centre's cell is clamped into them), so the clipping is skipped.
            f(CellRun { axes: [0, 1, 2], slab: lo[0], row: lo[1], from: lo[2], to: lo[2] });
            return;
        }
        let centre = |f: &mut dyn FnMut(CellRun) -> bool| {
            let c = self.centre_cell(b, lo, hi);
            f(CellRun { axes: [0, 1, 2], slab: c[0], row: c[1], from: c[2], to: c[2] });
        };
        let Some(cl) = self.clipper(t, lo, hi) else {
            centre(&mut f);
            return;
        };
        let [ao, am, ai] = cl.axes;
        let mut emitted = false;
        for o in lo[ao]..=hi[ao] {
            let slab = cl.slab(o);
            let Some((m0, m1)) = cl.range(&slab, am) else { continue };
            for m in m0..=m1 {
                let row = if cl.all { slab } else { cl.clip(&slab, am, m) };
                let Some((from, to)) = cl.range(&row, ai) else { continue };
                emitted = true;
                if !f(CellRun { axes: cl.axes, slab: o, row: m, from, to }) {
                    return;
                }
            }
        }
        if !emitted {
            // The triangle lies in its box's cells, so the clipping misses all of them only through rounding
            // outside anything it was built for: the cell of the box centre keeps the triangle in the grid anyway.
            centre(&mut f);
        }
    }

    /// The number of cells triangle `t` (box `b`) is stored in ([`GridFrame::for_each_run`]), counted up to `cap`
    /// (a count that reaches `cap` stops there): one clip per row.
    pub(crate) fn cell_count(&self, t: &Triangle, b: &Aabb, cap: u64) -> u64 {
        let mut c = 0u64;
        self.for_each_run(t, b, |r| {
            c = c.saturating_add(r.len());
            c < cap
        });
        c.min(cap)
    }

    /// An upper bound of [`GridFrame::cell_count`] at one clip per slab: per slab, the product of the slab's
    /// cells along the two other axes (the rows within a slab are parts of it, so their runs lie within that
    /// product); exact for a triangle one slab thick and one row wide.
    pub(crate) fn slab_bound(&self, t: &Triangle, b: &Aabb) -> u64 {
        let (lo, hi) = self.box_cells(b);
        let boxed: u64 = (0..3).map(|a| u64::from(hi[a].saturating_sub(lo[a])) + 1).product();
        let Some(cl) = self.clipper(t, lo, hi) else { return 1 };
        if cl.all || boxed <= 1 {
            return boxed;
        }
        let [ao, am, ai] = cl.axes;
        let span = |r: Option<(u32, u32)>| r.map_or(0, |(a, b)| u64::from(b - a) + 1);
        let mut total = 0u64;
        for o in lo[ao]..=hi[ao] {
            let slab = cl.slab(o);
            total = total.saturating_add(span(cl.range(&slab, am)).saturating_mul(span(cl.range(&slab, ai))));
        }
        // A triangle its clipping misses is stored in one cell anyway.
        total.clamp(1, boxed)
    }
}
