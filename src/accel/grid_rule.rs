//! The uniform grid's resolution rule, shared by the grid (`accel::grid`, with the `eval` feature) and the
//! selection's bound of its references (`select::budget`, always built).

use super::AccelError;
use crate::geom::Aabb;
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
pub fn resolution(bounds: &Aabb, n: usize, density: f32, max_resolution: u32, max_cells: usize) -> (Aabb, [u32; 3]) {
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
pub const WIDEN: f32 = 1e-4;

/// Everything the grid's cell rule needs besides the triangle: the padded bounds, the resolution, the cell size and
/// its inverse (f32, as the traversal uses them), and the two constants of the widening of a triangle's cells
/// (`crate::accel::grid`'s module docs): `widen = cell_size * WIDEN + max(|min|, |max|) * 8 eps` per axis (f64) and
/// `pad_scale = 16 eps (max(|min|, |max|) + largest extent)`, which the pad of a triangle multiplies by
/// `|e1| |e2| / |e1 x e2|`. The host grid and the device grid builder (`crate::accel::gpu_grid`) compute their
/// cells from one `GridFrame`, so both follow the same rule bit for bit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridFrame {
    /// The scene box, a zero extent padded (see [`resolution`]).
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
