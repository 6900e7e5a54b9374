//! The uniform grid's resolution rule, shared by the grid (`accel::grid`, with the `eval` feature) and the
//! selection's bound of its references (`select::budget`, always built).

use crate::geom::Aabb;

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
