// The uniform grid's cell rule on the device (src/accel/grid.rs, "Build"; src/accel/grid_rule.rs, GridFrame): the
// cells a triangle is stored in, found by the same f32 and f64 operations in the same order as the host's
// Grid::for_each_cell, so the device grid builder (glsl/grid_cells.comp, src/accel/gpu_grid.rs) makes the host's
// cell lists exactly. The f64 operations (add, subtract, multiply, divide, square root, floor) are assumed to be
// IEEE-754 correctly rounded, as lavapipe (LLVM) and the f64 units of current GPUs compute them; Vulkan itself only
// promises f32 accuracy for them, so the builder's tests compare every cell list with the host's.
#ifndef MESHCHAR_GRID_GLSL
#define MESHCHAR_GRID_GLSL

#define GRID_WIDEN_BITS 0x38d1b717u // 1e-4f: the widening of a triangle's box cells, in cells (grid_rule::WIDEN).
#define GRID_MAX_CORNERS 8          // Corners of a clipped polygon (geom::clip::Polygon).

// The frame of a grid (grid_rule::GridFrame), as the host computed it.
struct GridHeader {
    double widen_x;   // The widening common to every triangle along x: cell_size * WIDEN + |bounds| * 8 eps.
    double widen_y;   // The widening along y.
    double widen_z;   // The widening along z.
    double pad_scale; // 16 eps (|bounds| + largest extent): the pad's factor of |e1| |e2| / |e1 x e2|.
    vec3 lo;          // Lower corner of the padded scene box.
    uint res_x;       // Cells along x.
    vec3 cell_size;   // Size of a cell (f32).
    uint res_y;       // Cells along y.
    vec3 inv_cell;    // 1 / cell_size (f32).
    uint res_z;       // Cells along z.
};

layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer GridHeaderRef { GridHeader h; };

// Loop iterations of this subgroup, counted once per iteration by one active lane (see glsl/grid_cells.comp):
// CHECK_LOOPS (a specialization constant of the including kernel) turns the count on.
uint g_loops;
void loop_tick() {
    if (CHECK_LOOPS != 0u && subgroupElect()) g_loops += 1u;
}

// Single f64 operations without contraction.
double d_add(double a, double b) {
    precise double r = a + b;
    return r;
}
double d_sub(double a, double b) {
    precise double r = a - b;
    return r;
}
double d_mul(double a, double b) {
    precise double r = a * b;
    return r;
}
double d_div(double a, double b) {
    precise double r = a / b;
    return r;
}
// Rust's f64::max and f64::min: a NaN operand gives the other one.
double d_max(double a, double b) { return isnan(a) ? b : (isnan(b) ? a : max(a, b)); }
double d_min(double a, double b) { return isnan(a) ? b : (isnan(b) ? a : min(a, b)); }
// glam's DVec3::length: sqrt((x * x + y * y) + z * z).
double d_length(dvec3 v) { return sqrt(d_add(d_add(d_mul(v.x, v.x), d_mul(v.y, v.y)), d_mul(v.z, v.z))); }

// Component `a` of a vector, and a copy of it with component `a` replaced (no dynamic indexing, which CPU drivers
// turn into memory accesses per lane).
double dcomp(dvec3 v, uint a) { return a == 0u ? v.x : (a == 1u ? v.y : v.z); }
dvec3 dwith(dvec3 v, uint a, double x) { return dvec3(a == 0u ? x : v.x, a == 1u ? x : v.y, a == 2u ? x : v.z); }
float fcomp(vec3 v, uint a) { return a == 0u ? v.x : (a == 1u ? v.y : v.z); }
uint ucomp(uvec3 v, uint a) { return a == 0u ? v.x : (a == 1u ? v.y : v.z); }


// Rust's `v.clamp(0.0, hi) as u32` for an integral v (a NaN gives 0).
uint grid_clamp_cell(float v, uint res) {
    if (isnan(v)) return 0u;
    return uint(clamp(v, 0.0, float(res - 1u)));
}

// The cells of a box widened by WIDEN of a cell (Grid::box_cells), inclusive per axis, in f32.
void grid_box_cells(GridHeader g, vec3 bmin, vec3 bmax, out uvec3 lo, out uvec3 hi) {
    float widen = uintBitsToFloat(GRID_WIDEN_BITS);
    vec3 l = floor(v_sub(v_mul(v_sub(bmin, g.lo), g.inv_cell), vec3(widen)));
    vec3 h = floor(v_add(v_mul(v_sub(bmax, g.lo), g.inv_cell), vec3(widen)));
    lo = uvec3(grid_clamp_cell(l.x, g.res_x), grid_clamp_cell(l.y, g.res_y), grid_clamp_cell(l.z, g.res_z));
    hi = uvec3(grid_clamp_cell(h.x, g.res_x), grid_clamp_cell(h.y, g.res_y), grid_clamp_cell(h.z, g.res_z));
}

uint grid_cell_index(GridHeader g, uvec3 c) { return c.x + g.res_x * (c.y + g.res_y * c.z); }

// Rust's `(c.max(0.0) as u32).clamp(lo, hi)` (a saturating conversion).
uint grid_centre_axis(float c, uint lo, uint hi) {
    float m = isnan(c) ? 0.0 : max(c, 0.0);
    uint u = m >= 4294967296.0 ? 0xffffffffu : uint(m);
    return clamp(u, lo, hi);
}

// The cell of the box centre clamped into the box's cells (Grid::centre_cell).
uint grid_centre_cell(GridHeader g, vec3 bmin, vec3 bmax, uvec3 lo, uvec3 hi) {
    vec3 centre = v_scale(v_add(bmin, bmax), 0.5);
    vec3 c = floor(v_mul(v_sub(centre, g.lo), g.inv_cell));
    uvec3 at = uvec3(grid_centre_axis(c.x, lo.x, hi.x), grid_centre_axis(c.y, lo.y, hi.y),
                     grid_centre_axis(c.z, lo.z, hi.z));
    return grid_cell_index(g, at);
}

// A convex polygon of at most GRID_MAX_CORNERS corners (geom::clip::Polygon).
struct GridPolygon {
    dvec3 v[GRID_MAX_CORNERS];
    uint len;
};

void grid_push(inout GridPolygon p, dvec3 x) {
    if (p.len < uint(GRID_MAX_CORNERS)) {
        p.v[p.len] = x;
        p.len += 1u;
    }
}

// x + (q - p) * s per component, as glam's DVec3 evaluates it.
dvec3 grid_lerp(dvec3 p, dvec3 q, double s) {
    return dvec3(d_add(p.x, d_mul(d_sub(q.x, p.x), s)), d_add(p.y, d_mul(d_sub(q.y, p.y), s)),
                 d_add(p.z, d_mul(d_sub(q.z, p.z), s)));
}

// The part with sign * (p[axis] - c) >= 0 (Polygon::clip_half).
GridPolygon grid_clip_half(GridPolygon poly, uint axis, double c, double sign) {
    GridPolygon o;
    o.len = 0u;
    for (uint k = 0u; k < poly.len; ++k) {
        loop_tick();
        dvec3 p = poly.v[k];
        dvec3 q = poly.v[(k + 1u) % poly.len];
        double dp = d_mul(sign, d_sub(dcomp(p, axis), c));
        double dq = d_mul(sign, d_sub(dcomp(q, axis), c));
        if (dp >= 0.0lf) grid_push(o, p);
        if ((dp >= 0.0lf) != (dq >= 0.0lf)) {
            grid_push(o, dwith(grid_lerp(p, q, d_div(dp, d_sub(dp, dq))), axis, c));
        }
    }
    return o;
}

GridPolygon grid_clip(GridPolygon poly, uint axis, double lo, double hi) {
    return grid_clip_half(grid_clip_half(poly, axis, lo, 1.0lf), axis, hi, -1.0lf);
}

// Smallest and largest coordinate along `axis`; false for an empty polygon (Polygon::range).
bool grid_range(GridPolygon poly, uint axis, out double lo, out double hi) {
    if (poly.len == 0u) return false;
    lo = dcomp(poly.v[0], axis);
    hi = lo;
    for (uint k = 1u; k < poly.len; ++k) {
        loop_tick();
        lo = d_min(lo, dcomp(poly.v[k], axis));
        hi = d_max(hi, dcomp(poly.v[k], axis));
    }
    return true;
}

#endif
