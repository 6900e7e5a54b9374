//! Uniform grid with 3D-DDA traversal (Amanatides and Woo 1987) and per-ray mailboxing.
//!
//! # Resolution heuristic
//!
//! Cells proportional to the triangle count (the density rule of Cleary and Wyvill 1988): with scene extent
//! `e = (e_x, e_y, e_z)`, volume `V` and `N` triangles, the grid has `n_i = round(e_i * cbrt(lambda N / V))` cells
//! along axis `i`, clamped to `1 ..= max_resolution`, with `lambda = `[`GridOptions::density`] (default 4 cells per
//! triangle). A zero extent (flat scene) is padded to `1e-3` of the largest one (to `1` when the scene is a point)
//! so that the volume is never zero; when the product exceeds [`GridOptions::max_cells`] the density is lowered until
//! it fits.
//!
//! # Build
//!
//! A triangle is stored in the cells it touches: every cell of its bounding box (widened by `1e-4` of a cell) whose
//! box, widened by `w`, the triangle overlaps. The cells are found exactly, in f64, by clipping (Sutherland-Hodgman)
//! the triangle to each slab of cells across the box's shortest side, then each clipped polygon to each row of cells
//! within the slab, whose extent along the remaining axis gives a run of cells; so a long thin triangle costs the
//! cells along it, not the cells of its box, and a triangle costs one clip per slab and per row it meets. The
//! widening `w` is `1e-4` of a cell, eight f32 ulps of the scene's coordinates (the traversal computes cell
//! boundaries in f32), and a pad for the f32 rounding of the ray-triangle test, which can report a hit slightly
//! outside a thin triangle: `16 eps (|bounds| + extent) / sin(alpha)`, with `alpha` the angle of the record's edges
//! at `v0` (a few millionths of the scene for a well-shaped triangle; the whole box when the f32 edges are
//! parallel). A zero-area triangle, which is never hit, is stored once, in the cell of its box centre: it belongs to
//! the grid and counts as a reference at no cost to traversal.
//!
//! Each triangle's cells are counted, then written in triangle order into one array (in parallel, every triangle in
//! its own range; in one pass, chunk by chunk, where even the triangles' box cells fit the budgets below), and a
//! counting sort by cell turns that into the cells' lists, each in triangle order: no shared
//! counters (which copies of one triangle would all contend for), and the same grid on every thread count. Storage
//! is compressed rows: `cell_start[c] .. cell_start[c + 1]` indexes the reference array.
//!
//! Coincident copies (triangles whose positions are bit-identical, `crate::accel::copies`) are stored once, as the
//! smallest index of their group: the others are in no cell and listed apart, so that 50,000 copies of one triangle
//! cost one triangle's references, not 50,000 times them. The frame and the budget still count every triangle.
//!
//! The device builder ([`crate::accel::gpu::grid`]) makes the same cell lists from the same [`GridFrame`] (the
//! frame's constants are computed once, in [`GridFrame::new`], for both), given the copies' flags ([`copy_flags`],
//! `GridBuilder::build_with_copies`); without them it stores every copy.
//!
//! # Budget
//!
//! The cell references are bounded by [`GridOptions::reference_budget`] (64 per triangle, at least `2^25`) and the
//! grid's bytes by [`GridOptions::max_bytes`]: a scene of many large overlapping triangles (copies of one triangle,
//! a fan of a polygon over three points) needs `O(n)` references per triangle, `O(n^2)` in all. When the sum of the
//! triangles' box cells exceeds the budget, the triangles' exact cell counts are summed in index order (in parallel
//! chunks, each count capped where it would cross the budget) and the build fails with [`AccelError::OverBudget`]
//! at the first triangle that crosses it: the same error, with the same count, on every run and thread count. No
//! shared mesh or BART frame comes within a tenth of it (at most 5.0 references per triangle, the teapot).
//!
//! # Traversal
//!
//! The ray is clipped to the grid box, the entry cell found from the entry point, and cells visited in order of the
//! next boundary crossing, each crossing distance computed directly from the cell index (no accumulated error).
//! A hit anywhere on the ray is kept; traversal stops once the best hit lies before the current cell's exit
//! (widened by a relative `1e-5`). Mailboxing: a 16-entry direct-mapped table per ray of triangles already tested
//! (indexed by the low bits of the triangle index), so a triangle spanning several cells is usually tested once.
//! `box_tests` counts cells visited (plus the test against the grid box).

use super::{bytes_of, invalid, prepare, AccelError, AccelStats, AccelStructure, StructureName, Validation};
use crate::geom::{closer_hit, cull_bound, tie_margin, Hit, Ray, RayInv, TraceCounters};
use crate::geom::{Aabb, Triangle};
use crate::mesh::Mesh;
use glam::Vec3;
use rayon::prelude::*;

pub use super::grid_rule::{GridFrame, GridOptions};

/// The grid (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct Grid {
    frame: GridFrame,
    cell_start: Vec<u32>,
    refs: Vec<u32>,
    tris: Vec<Triangle>,
    boxes: Vec<Aabb>,
    /// Triangles in no cell, coincident copies of another (`crate::accel::copies`), as `(copy, kept)`.
    copies: Vec<(u32, u32)>,
    /// Whether each triangle is one of `copies`.
    is_copy: Vec<bool>,
}

use super::grid_rule::WIDEN;

/// Resolution by the density heuristic, and the padded bounds.
pub fn grid_resolution(bounds: &Aabb, n: usize, o: &GridOptions) -> (Aabb, [u32; 3]) {
    super::grid_rule::resolution(bounds, n, o.density, o.max_resolution, o.max_cells)
}

/// One `u32` per triangle of `mesh`, 1 for a coincident copy of a triangle of smaller index (bit-identical
/// positions), 0 otherwise: the grid stores such copies once, and [`crate::accel::gpu::grid::GridBuilder::build_with_copies`]
/// takes these flags to build the same lists on the device.
///
/// # Errors
///
/// [`AccelError`] for a mesh the grid cannot be built over.
pub fn copy_flags(mesh: &Mesh) -> Result<Vec<u32>, AccelError> {
    let (tris, _) = prepare(mesh, "grid")?;
    let copies = super::copies::position_copies(mesh, &tris);
    Ok(super::copies::copy_mask(tris.len(), &copies).into_iter().map(u32::from).collect())
}

impl Grid {
    /// Builds with explicit options.
    pub fn build_with(mesh: &Mesh, o: &GridOptions) -> Result<Self, AccelError> {
        crate::in_pool(|| Self::build_here(mesh, o))
    }

    fn build_here(mesh: &Mesh, o: &GridOptions) -> Result<Self, AccelError> {
        let (tris, boxes) = prepare(mesh, "grid")?;
        let n = tris.len();
        if n == 0 {
            return Ok(Grid::default());
        }
        let scene = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        if !(scene.max - scene.min).is_finite() {
            return Err(AccelError::CoordinateRange {
                structure: "grid",
                lo: scene.min.to_array(),
                hi: scene.max.to_array(),
            });
        }
        let frame = GridFrame::new(&scene, n, o);
        let res = frame.res;
        // Coincident copies are stored once, as the smallest index of their group: every copy would cover the
        // same cells, and a ray would test them all (the frame and the budget still count every triangle, as the
        // device builder's do).
        let copies = super::copies::position_copies(mesh, &tris);
        let is_copy = super::copies::copy_mask(n, &copies);
        let mut g = Grid { frame, cell_start: Vec::new(), refs: Vec::new(), tris, boxes, copies, is_copy };
        let ncells = res.iter().map(|&x| x as usize).product::<usize>();
        if ncells >= u32::MAX as usize {
            let limit = u32::MAX as usize;
            return Err(AccelError::TooLarge { structure: "grid", what: "cells", count: ncells, limit });
        }
        // Cells per triangle, then every triangle's cells in triangle order (no shared counters: copies of one
        // triangle would all contend for the same ones), then a counting sort by cell, which leaves every cell's
        // list in triangle order.
        let (counts, written) = g.cell_counts(o)?;
        let mut offsets = Vec::with_capacity(n + 1);
        let mut total = 0u64;
        for &c in &counts {
            offsets.push(total as usize);
            total += u64::from(c);
        }
        offsets.push(total as usize);
        if total >= u32::MAX as u64 {
            return Err(AccelError::TooLarge {
                structure: "grid",
                what: "references",
                count: total as usize,
                limit: u32::MAX as usize,
            });
        }
        let total = total as usize;
        let bytes = 4 * (ncells + 1) + 4 * total + bytes_of(&g.tris);
        if bytes > o.max_bytes {
            return Err(AccelError::OverBudget {
                structure: "grid",
                what: "bytes",
                needed: bytes,
                budget: o.max_bytes,
                rule: format!("GridOptions::max_bytes, for {ncells} cells and {total} cell references"),
            });
        }
        let cells = if let Some(cells) = written {
            cells
        } else {
            let mut cells = vec![0u32; total];
            let mut parts: Vec<(usize, &mut [u32])> = Vec::with_capacity(n);
            let mut rest: &mut [u32] = &mut cells;
            for i in 0..n {
                let (a, b) = rest.split_at_mut(offsets[i + 1] - offsets[i]);
                parts.push((i, a));
                rest = b;
            }
            parts.into_par_iter().with_min_len(256).for_each(|(i, out)| {
                let mut k = 0;
                g.for_each_cell(i, |c| {
                    out[k] = c as u32;
                    k += 1;
                    k < out.len()
                });
            });
            cells
        };
        let mut start = vec![0u32; ncells + 1];
        for &c in &cells {
            start[c as usize + 1] += 1;
        }
        for c in 0..ncells {
            start[c + 1] += start[c];
        }
        let mut cursor = start[..ncells].to_vec();
        let mut refs = vec![0u32; total];
        for i in 0..n {
            for &c in &cells[offsets[i]..offsets[i + 1]] {
                let pos = &mut cursor[c as usize];
                refs[*pos as usize] = i as u32;
                *pos += 1;
            }
        }
        g.cell_start = start;
        g.refs = refs;
        Ok(g)
    }

    /// Cells along x, y, z.
    pub fn resolution(&self) -> [u32; 3] {
        // An empty grid has no cells (its frame's one cell is a placeholder).
        if self.tris.is_empty() {
            [0; 3]
        } else {
            self.frame.res
        }
    }

    #[inline]
    fn cell_index(&self, x: u32, y: u32, z: u32) -> usize {
        x as usize + self.frame.res[0] as usize * (y as usize + self.frame.res[1] as usize * z as usize)
    }

    #[inline]
    fn cell_box(&self, x: u32, y: u32, z: u32) -> Aabb {
        let lo = self.frame.bounds.min + Vec3::new(x as f32, y as f32, z as f32) * self.frame.cell_size;
        Aabb::new(lo, lo + self.frame.cell_size)
    }

    /// An upper bound of the cells triangle `i` is stored in: its box's cells (1 for a zero-area triangle).
    fn box_cell_count(&self, i: usize) -> u64 {
        if self.is_copy.get(i) == Some(&true) {
            return 0;
        }
        if self.tris[i].is_degenerate() {
            return 1;
        }
        let (lo, hi) = self.frame.box_cells(&self.boxes[i]);
        (0..3).map(|a| u64::from(hi[a] - lo[a] + 1)).product()
    }

    /// Calls `f` with every cell triangle `i` is stored in (the rule of the module docs,
    /// [`GridFrame::for_each_run`]), slab by slab, row by row, until `f` returns `false`.
    fn for_each_cell(&self, i: usize, mut f: impl FnMut(usize) -> bool) {
        if self.is_copy.get(i) == Some(&true) {
            return;
        }
        self.frame.for_each_run(&self.tris[i], &self.boxes[i], |run| {
            (run.from..=run.to).all(|k| {
                let [x, y, z] = run.cell(k);
                f(self.cell_index(x, y, z))
            })
        });
    }

    /// The number of cells of every triangle, checked against [`GridOptions::reference_budget`] before anything
    /// is allocated for the references (see the module docs): in one parallel pass when the triangles' box cells
    /// fit the budget, else in index order, chunk by chunk, failing at the first triangle that crosses it. Where
    /// the box cells fit the budget and the bytes they would take fit [`GridOptions::max_bytes`], the same pass
    /// also writes every triangle's cells, in triangle order (the second value), so that the caller need not clip
    /// each triangle again to fill them.
    fn cell_counts(&self, o: &GridOptions) -> Result<(Vec<u32>, Option<Vec<u32>>), AccelError> {
        let n = self.tris.len();
        let budget = o.reference_budget(n) as u64;
        let count = |i: usize, cap: u64| {
            let mut c = 0u64;
            self.for_each_cell(i, |_| {
                c += 1;
                c < cap
            });
            c
        };
        let upper: Vec<u64> = (0..n).into_par_iter().map(|i| self.box_cell_count(i)).collect();
        let boxed = upper.iter().sum::<u64>();
        if boxed <= budget {
            let ncells = self.frame.res.iter().map(|&x| x as u64).product::<u64>();
            let most_bytes = 4 * (ncells + 1) + 4 * boxed + bytes_of(&self.tris) as u64;
            if most_bytes <= o.max_bytes as u64 {
                // Even every box cell fits the bytes: the cells are written as they are counted, one pass over
                // each triangle's clipping instead of two (chunks in parallel, joined in triangle order).
                const CHUNK: usize = 2048;
                let parts: Vec<(Vec<u32>, Vec<u32>)> = (0..n.div_ceil(CHUNK))
                    .into_par_iter()
                    .map(|c| {
                        let (a, b) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
                        let (mut counts, mut cells) = (Vec::with_capacity(b - a), Vec::with_capacity(4 * (b - a)));
                        for i in a..b {
                            let before = cells.len();
                            self.for_each_cell(i, |cell| {
                                cells.push(cell as u32);
                                true
                            });
                            counts.push((cells.len() - before) as u32);
                        }
                        (counts, cells)
                    })
                    .collect();
                let counts = parts.iter().flat_map(|p| p.0.iter().copied()).collect();
                let cells = parts.iter().flat_map(|p| p.1.iter().copied()).collect();
                return Ok((counts, Some(cells)));
            }
            return Ok(((0..n).into_par_iter().map(|i| count(i, u64::MAX) as u32).collect(), None));
        }
        // A chunk holds triangles whose box cells, each capped at what would cross the budget, sum to no more than
        // that, so no chunk counts much past the budget; a count stops at the cap, where it crosses anyway.
        let mut counts = Vec::with_capacity(n);
        let mut prefix = 0u64;
        let mut i = 0;
        while i < n {
            let cap = budget + 1 - prefix;
            let (mut j, mut acc) = (i, 0u64);
            while j < n && j - i < 65_536 {
                let u = upper[j].min(cap);
                if j > i && acc + u > cap {
                    break;
                }
                acc += u;
                j += 1;
            }
            let chunk: Vec<u64> = (i..j).into_par_iter().map(|k| count(k, cap)).collect();
            for c in chunk {
                prefix += c;
                if prefix > budget {
                    return Err(o.over_references(n, prefix as usize));
                }
                counts.push(c as u32);
            }
            i = j;
        }
        Ok((counts, None))
    }

    /// The arrays the device traversal reads (see [`crate::accel::device_trace`]).
    pub fn device_layout(&self) -> crate::accel::device_trace::DeviceLayout<'_> {
        crate::accel::device_trace::DeviceLayout::Grid {
            bounds: self.frame.bounds,
            res: self.frame.res,
            cell_size: self.frame.cell_size,
            inv_cell: self.frame.inv_cell,
            cell_start: &self.cell_start,
            refs: &self.refs,
            tris: &self.tris,
        }
    }

    fn traverse(&self, ray: &Ray, any: bool, c: &mut TraceCounters) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let r = RayInv::new(ray);
        c.box_tests += 1;
        let (t0, t1) = r.slab_interval(self.frame.bounds.min, self.frame.bounds.max, ray.tmin, ray.tmax)?;
        let p = r.o + r.d * t0;
        let f = ((p - self.frame.bounds.min) * self.frame.inv_cell).floor();
        let mut cell = [0i64; 3];
        let mut step = [0i64; 3];
        for a in 0..3 {
            cell[a] = (f[a].max(0.0) as i64).min(self.frame.res[a] as i64 - 1);
            step[a] = if r.d[a] > 0.0 {
                1
            } else if r.d[a] < 0.0 {
                -1
            } else {
                0
            };
        }
        let next_t = |cell: &[i64; 3], a: usize| -> f32 {
            if step[a] == 0 {
                return f32::INFINITY;
            }
            let k = if step[a] > 0 { cell[a] + 1 } else { cell[a] };
            (self.frame.bounds.min[a] + k as f32 * self.frame.cell_size[a] - r.o[a]) / r.d[a]
        };
        let mut tnext = [next_t(&cell, 0), next_t(&cell, 1), next_t(&cell, 2)];
        let mut mailbox = [u32::MAX; 16];
        let mut best_t = ray.tmax;
        let margin = tie_margin(ray.origin, ray.dir, &self.frame.bounds);
        let mut best = None;
        loop {
            c.box_tests += 1;
            let idx = self.cell_index(cell[0] as u32, cell[1] as u32, cell[2] as u32);
            let (s, e) = (self.cell_start[idx] as usize, self.cell_start[idx + 1] as usize);
            for &id in &self.refs[s..e] {
                let slot = (id & 15) as usize;
                if mailbox[slot] == id {
                    continue;
                }
                mailbox[slot] = id;
                c.prim_tests += 1;
                if let Some(h) = closer_hit(&self.tris[id as usize], id, r.o, r.d, ray.tmin, best_t, &best) {
                    best_t = h.t;
                    best = Some(h);
                    if any {
                        return best;
                    }
                }
            }
            let a = if tnext[0] <= tnext[1] && tnext[0] <= tnext[2] {
                0
            } else if tnext[1] <= tnext[2] {
                1
            } else {
                2
            };
            let exit = tnext[a];
            // A later cell begins at `exit`: it may hold a tied or closer hit while `exit` is within the cull bound.
            if (best.is_some() && cull_bound(best_t, margin) < exit - exit.abs() * 1e-5)
                || exit > t1
                || !exit.is_finite()
            {
                return best;
            }
            cell[a] += step[a];
            if cell[a] < 0 || cell[a] >= self.frame.res[a] as i64 {
                return best;
            }
            tnext[a] = next_t(&cell, a);
        }
    }
}

impl AccelStructure for Grid {
    fn build(mesh: &Mesh) -> Result<Self, AccelError> {
        Grid::build_with(mesh, &GridOptions::default())
    }
    fn name(&self) -> StructureName {
        StructureName::Grid
    }
    traversal_methods!();
    fn memory_bytes(&self) -> usize {
        bytes_of(&self.cell_start) + bytes_of(&self.refs) + bytes_of(&self.tris) + bytes_of(&self.copies)
    }

    fn build_work(&self) -> Option<f64> {
        (!self.refs.is_empty()).then_some(self.refs.len() as f64)
    }
    /// Checks: row starts monotone and ending at the reference count, reference ids in range, each reference's
    /// triangle box overlapping its (widened) cell, every triangle present in exactly the cells the build rule
    /// assigns it (so none is lost and none is stray), and every listed copy in no cell, with the records' bits of
    /// a kept triangle of smaller index that is in some.
    fn validate(&self) -> Result<AccelStats, AccelError> {
        let n = self.tris.len();
        let bytes = self.memory_bytes();
        if n == 0 {
            let holds = !self.refs.is_empty() || !self.cell_start.is_empty();
            return Validation::new("grid", 0, bytes, 0, 0).without_nodes(holds, "references without triangles");
        }
        let ncells = self.frame.res.iter().map(|&x| x as usize).product::<usize>();
        if self.cell_start.len() != ncells + 1 || self.cell_start.last().copied() != Some(self.refs.len() as u32) {
            return Err(invalid("grid", "row starts do not match cells and references"));
        }
        if self.cell_start.windows(2).any(|w| w[0] > w[1]) || self.cell_start[0] != 0 {
            return Err(invalid("grid", "row starts not monotone"));
        }
        // Every cell is a leaf (depth 0) over its row of the reference array.
        let mut v = Validation::new("grid", n, bytes, ncells, self.refs.len());
        let mut seen = vec![0u32; n];
        for z in 0..self.frame.res[2] {
            for y in 0..self.frame.res[1] {
                for x in 0..self.frame.res[0] {
                    let idx = self.cell_index(x, y, z);
                    let (start, end) = (self.cell_start[idx] as usize, self.cell_start[idx + 1] as usize);
                    v.visit(idx, 0)?;
                    v.leaf(idx, start, end - start)?;
                    let cb = self.cell_box(x, y, z);
                    let w = (cb.max - cb.min) * (2.0 * WIDEN) + (cb.max.abs() + cb.min.abs()) * 1e-6;
                    let wide = Aabb::new(cb.min - w, cb.max + w);
                    for &id in &self.refs[start..end] {
                        let b = self.boxes.get(id as usize).ok_or_else(|| v.invalid(format!("reference {id}")))?;
                        if !wide.overlaps(b) {
                            return Err(v.invalid(format!("triangle {id} outside cell ({x},{y},{z})")));
                        }
                        seen[id as usize] += 1;
                    }
                }
            }
        }
        for (i, &seen_i) in seen.iter().enumerate() {
            let mut count = 0u32;
            let mut lost = None;
            self.for_each_cell(i, |c| {
                count += 1;
                let list = &self.refs[self.cell_start[c] as usize..self.cell_start[c + 1] as usize];
                if list.binary_search(&(i as u32)).is_err() {
                    lost = Some(c);
                }
                true
            });
            if let Some(c) = lost {
                return Err(invalid("grid", format!("triangle {i} lost from cell {c}")));
            }
            let copy = self.is_copy.get(i) == Some(&true);
            if (count == 0) != copy || count != seen_i {
                return Err(invalid("grid", format!("triangle {i}: {seen_i} references, {count} expected")));
            }
        }
        if self.is_copy.len() != n || self.is_copy.iter().filter(|&&c| c).count() != self.copies.len() {
            return Err(invalid("grid", "the copy flags do not match the copies"));
        }
        for &(c, k) in &self.copies {
            let (tc, tk) = match (self.tris.get(c as usize), self.tris.get(k as usize)) {
                (Some(tc), Some(tk)) if k < c => (tc, tk),
                _ => return Err(invalid("grid", format!("copy ({c}, {k}) out of range or of a larger index"))),
            };
            if super::copies::record_bits(tc) != super::copies::record_bits(tk) || self.is_copy[k as usize] {
                return Err(invalid("grid", format!("triangle {c} is no copy of a kept triangle {k}")));
            }
            if self.is_copy.get(c as usize) != Some(&true) {
                return Err(invalid("grid", format!("copy {c} not flagged")));
            }
        }
        // Each triangle's references are the cells the build rule gives it, so the references are all of them.
        let mut stats = v.finish()?;
        stats.copies = self.copies.len();
        Ok(stats)
    }

    fn sah_cost(&self) -> Option<f64> {
        None
    }
}
