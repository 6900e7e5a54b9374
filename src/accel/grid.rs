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
//! A triangle is stored in every cell of its bounding box (widened by `1e-4` of a cell) that its plane passes
//! through (plane-box overlap; zero-area triangles keep their whole box). Counting and filling run in parallel with
//! atomic counters; each cell's list is then sorted, so the result is deterministic. Storage is compressed rows:
//! `cell_start[c] .. cell_start[c + 1]` indexes the reference array.
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
use std::sync::atomic::{AtomicU32, Ordering};

/// Options of the grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridOptions {
    /// Cells per triangle, `lambda`.
    pub density: f32,
    /// Largest number of cells along one axis.
    pub max_resolution: u32,
    /// Largest number of cells in all.
    pub max_cells: usize,
}

impl Default for GridOptions {
    fn default() -> Self {
        GridOptions { density: 4.0, max_resolution: 1024, max_cells: 1 << 24 }
    }
}

/// The grid (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct Grid {
    bounds: Aabb,
    res: [u32; 3],
    cell_size: Vec3,
    inv_cell: Vec3,
    cell_start: Vec<u32>,
    refs: Vec<u32>,
    tris: Vec<Triangle>,
    boxes: Vec<Aabb>,
}

const WIDEN: f32 = 1e-4;

/// Resolution by the density heuristic, and the padded bounds.
pub fn grid_resolution(bounds: &Aabb, n: usize, o: &GridOptions) -> (Aabb, [u32; 3]) {
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
    let mut density = (o.density.max(1e-6) as f64) * n.max(1) as f64;
    loop {
        let s = (density / vol).cbrt();
        let r = |x: f64| {
            let v = (x * s).round();
            if v.is_finite() {
                v.clamp(1.0, o.max_resolution.max(1) as f64) as u32
            } else {
                1
            }
        };
        let res = [r(e.x), r(e.y), r(e.z)];
        let cells = res.iter().map(|&x| x as usize).product::<usize>();
        if cells <= o.max_cells.max(1) || res == [1, 1, 1] {
            return (b, res);
        }
        density *= 0.8 * o.max_cells as f64 / cells as f64;
    }
}

impl Grid {
    /// Builds with explicit options.
    pub fn build_with(mesh: &Mesh, o: &GridOptions) -> Result<Self, AccelError> {
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
        let (bounds, res) = grid_resolution(&scene, n, o);
        let cell_size = (bounds.max - bounds.min) / Vec3::new(res[0] as f32, res[1] as f32, res[2] as f32);
        let mut g = Grid {
            bounds,
            res,
            cell_size,
            inv_cell: Vec3::ONE / cell_size,
            cell_start: Vec::new(),
            refs: Vec::new(),
            tris,
            boxes,
        };
        let ncells = res.iter().map(|&x| x as usize).product::<usize>();
        let counts: Vec<AtomicU32> = (0..ncells).map(|_| AtomicU32::new(0)).collect();
        let total: u64 = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut k = 0u64;
                g.for_each_cell(i, |c| {
                    counts[c].fetch_add(1, Ordering::Relaxed);
                    k += 1;
                });
                k
            })
            .sum();
        if total >= u32::MAX as u64 {
            return Err(AccelError::TooLarge {
                structure: "grid",
                what: "references",
                count: total as usize,
                limit: u32::MAX as usize,
            });
        }
        let mut start = Vec::with_capacity(ncells + 1);
        let mut acc = 0u32;
        for c in &counts {
            start.push(acc);
            acc += c.load(Ordering::Relaxed);
        }
        start.push(acc);
        let cursor: Vec<AtomicU32> = start[..ncells].iter().map(|&s| AtomicU32::new(s)).collect();
        let slots: Vec<AtomicU32> = (0..acc).map(|_| AtomicU32::new(0)).collect();
        (0..n).into_par_iter().for_each(|i| {
            g.for_each_cell(i, |c| {
                let pos = cursor[c].fetch_add(1, Ordering::Relaxed);
                slots[pos as usize].store(i as u32, Ordering::Relaxed);
            });
        });
        let mut refs: Vec<u32> = slots.into_iter().map(AtomicU32::into_inner).collect();
        let mut lists: Vec<&mut [u32]> = Vec::with_capacity(ncells);
        let mut rest: &mut [u32] = &mut refs;
        for c in 0..ncells {
            let (a, b) = rest.split_at_mut((start[c + 1] - start[c]) as usize);
            lists.push(a);
            rest = b;
        }
        lists.par_iter_mut().for_each(|l| l.sort_unstable());
        g.cell_start = start;
        g.refs = refs;
        Ok(g)
    }

    /// Cells along x, y, z.
    pub fn resolution(&self) -> [u32; 3] {
        self.res
    }

    #[inline]
    fn cell_index(&self, x: u32, y: u32, z: u32) -> usize {
        x as usize + self.res[0] as usize * (y as usize + self.res[1] as usize * z as usize)
    }

    #[inline]
    fn cell_box(&self, x: u32, y: u32, z: u32) -> Aabb {
        let lo = self.bounds.min + Vec3::new(x as f32, y as f32, z as f32) * self.cell_size;
        Aabb::new(lo, lo + self.cell_size)
    }

    /// Calls `f` with every cell triangle `i` is stored in.
    fn for_each_cell(&self, i: usize, mut f: impl FnMut(usize)) {
        let b = &self.boxes[i];
        let lo = ((b.min - self.bounds.min) * self.inv_cell - WIDEN).floor();
        let hi = ((b.max - self.bounds.min) * self.inv_cell + WIDEN).floor();
        let cl = |v: f32, a: usize| v.clamp(0.0, (self.res[a] - 1) as f32) as u32;
        let (x0, y0, z0) = (cl(lo.x, 0), cl(lo.y, 1), cl(lo.z, 2));
        let (x1, y1, z1) = (cl(hi.x, 0), cl(hi.y, 1), cl(hi.z, 2));
        let t = &self.tris[i];
        let normal = t.e1.cross(t.e2);
        let single = x0 == x1 && y0 == y1 && z0 == z1;
        for z in z0..=z1 {
            for y in y0..=y1 {
                for x in x0..=x1 {
                    if single || normal == Vec3::ZERO || self.plane_overlaps(t, normal, x, y, z) {
                        f(self.cell_index(x, y, z));
                    }
                }
            }
        }
    }

    /// Whether the triangle's plane passes through cell `(x, y, z)` widened by [`WIDEN`] of a cell.
    #[inline]
    fn plane_overlaps(&self, t: &Triangle, n: Vec3, x: u32, y: u32, z: u32) -> bool {
        let cb = self.cell_box(x, y, z);
        let h = (cb.max - cb.min) * (0.5 + WIDEN);
        let c = cb.center();
        let r = h.dot(n.abs());
        let s = n.dot(c - t.v0);
        s.abs() <= r * (1.0 + 1e-5)
    }

    fn traverse(&self, ray: &Ray, any: bool, c: &mut TraceCounters) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let r = RayInv::new(ray);
        c.box_tests += 1;
        let (t0, t1) = r.slab_interval(self.bounds.min, self.bounds.max, ray.tmin, ray.tmax)?;
        let p = r.o + r.d * t0;
        let f = ((p - self.bounds.min) * self.inv_cell).floor();
        let mut cell = [0i64; 3];
        let mut step = [0i64; 3];
        for a in 0..3 {
            cell[a] = (f[a].max(0.0) as i64).min(self.res[a] as i64 - 1);
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
            (self.bounds.min[a] + k as f32 * self.cell_size[a] - r.o[a]) / r.d[a]
        };
        let mut tnext = [next_t(&cell, 0), next_t(&cell, 1), next_t(&cell, 2)];
        let mut mailbox = [u32::MAX; 16];
        let mut best_t = ray.tmax;
        let margin = tie_margin(ray.origin, ray.dir, &self.bounds);
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
            if cell[a] < 0 || cell[a] >= self.res[a] as i64 {
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
        bytes_of(&self.cell_start) + bytes_of(&self.refs) + bytes_of(&self.tris)
    }

    /// Checks: row starts monotone and ending at the reference count, reference ids in range, each reference's
    /// triangle box overlapping its (widened) cell, and every triangle present in exactly the cells the build rule
    /// assigns it (so none is lost and none is stray).
    fn validate(&self) -> Result<AccelStats, AccelError> {
        let n = self.tris.len();
        let bytes = self.memory_bytes();
        if n == 0 {
            let holds = !self.refs.is_empty() || !self.cell_start.is_empty();
            return Validation::new("grid", 0, bytes, 0, 0).without_nodes(holds, "references without triangles");
        }
        let ncells = self.res.iter().map(|&x| x as usize).product::<usize>();
        if self.cell_start.len() != ncells + 1 || self.cell_start.last().copied() != Some(self.refs.len() as u32) {
            return Err(invalid("grid", "row starts do not match cells and references"));
        }
        if self.cell_start.windows(2).any(|w| w[0] > w[1]) || self.cell_start[0] != 0 {
            return Err(invalid("grid", "row starts not monotone"));
        }
        // Every cell is a leaf (depth 0) over its row of the reference array.
        let mut v = Validation::new("grid", n, bytes, ncells, self.refs.len());
        let mut seen = vec![0u32; n];
        for z in 0..self.res[2] {
            for y in 0..self.res[1] {
                for x in 0..self.res[0] {
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
            });
            if let Some(c) = lost {
                return Err(invalid("grid", format!("triangle {i} lost from cell {c}")));
            }
            if count == 0 || count != seen_i {
                return Err(invalid("grid", format!("triangle {i}: {seen_i} references, {count} expected")));
            }
        }
        // Each triangle's references are the cells the build rule gives it, so the references are all of them.
        v.finish()
    }

    fn sah_cost(&self) -> Option<f64> {
        None
    }
}
