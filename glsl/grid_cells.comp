#version 460
// Device grid builder (src/accel/gpu_grid.rs), the per-triangle passes: every triangle's cells by the host's rule
// (include/grid.glsl). MODE 0 writes the triangle records (TriRecord, mesh order), every triangle's cell count
// (counts[i]) and adds it to the 64-bit reference total (info word 0); MODE 1, after the exclusive scan of the
// counts, writes triangle i's cells as sort keys from keys[counts[i]] on, with payload i, in the host's visiting
// order. MODE 1 does nothing when the total exceeds `limit` (a budget or the key array's capacity).
//
// lavapipe stops a loop of a subgroup after 65,535 iterations (gallivm's loop limiter), which the compiled code
// cannot see. With CHECK_LOOPS (set on CPU drivers) one active lane counts every iteration of every loop of its
// subgroup, and a subgroup whose loops ran 65,000 iterations or more in all sets info word 2 to 1: such a loop may
// have been cut, and the build fails instead of returning a grid that may be wrong.
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "common.glsl"
#include "trace.glsl"
layout(constant_id = 2) const uint CHECK_LOOPS = 0; // Count loop iterations (include/grid.glsl).
#include "grid.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint MODE = 0;

layout(push_constant) uniform Push {
    uint64_t positions;    // Address of the position of vertex 0 (include/geometry.glsl).
    uint64_t indices;      // Address of the first index (include/geometry.glsl).
    uint64_t vertex_count; // Vertices of the view (include/geometry.glsl).
    uint vertex_stride;    // Bytes between vertices (include/geometry.glsl).
    uint index_type;       // GEOMETRY_INDEX_* (include/geometry.glsl).
    uint base_vertex;      // Added to every index (include/geometry.glsl).
    uint geometry_pad;     // Padding.
    uint64_t header;  // Address of the GridHeader.
    uint64_t records; // Address of the TriRecord array (MODE 0).
    uint64_t info;    // Address of the build's info: the reference total (u64), then the cut-loop flag (u32).
    uint64_t counts;  // Address of the per-triangle cell counts (MODE 0), their exclusive prefix sums (MODE 1).
    uint64_t keys;    // Address of the sort keys: the cells (MODE 1).
    uint64_t payload; // Address of the sort payload: the triangles (MODE 1).
    uint64_t count;   // Triangles.
    uint64_t limit;   // Largest total MODE 1 works on.
    uint64_t skip;    // Address of one u32 per triangle, nonzero for a coincident copy, in no cell (0: none).
} pc;

#include "geometry.glsl"

layout(buffer_reference, std430, buffer_reference_align = 16) writeonly buffer TriRecordOut { TriRecord rec; };

// The next key slot of the triangle being emitted (MODE 1).
uint64_t g_slot;

void grid_emit(uint cell, uint tri) {
    if (MODE == 1u) {
        st_u32(pc.keys, g_slot, cell);
        st_u32(pc.payload, g_slot, tri);
        g_slot += 1ul;
    }
}

double grid_edge(GridHeader g, uint axis, uint k) {
    return d_add(double(fcomp(g.lo, axis)), d_mul(double(k), double(fcomp(g.cell_size, axis))));
}

// The cells along `axis` whose widened extent meets l ..= h, within lo ..= hi (the `cells` closure of
// Grid::for_each_cell).
bool grid_cells_along(GridHeader g, uint axis, double l, double h, double w, uint lo, uint hi, out uint from,
                      out uint to) {
    double b = double(fcomp(g.lo, axis));
    double cs = double(fcomp(g.cell_size, axis));
    double f = d_max(floor(d_div(d_sub(d_sub(l, w), b), cs)), double(lo));
    double t = d_min(floor(d_div(d_sub(d_add(h, w), b), cs)), double(hi));
    if (!(f <= t)) return false;
    from = uint(f);
    to = uint(t);
    return true;
}

// Every cell of triangle `tri` (Grid::for_each_cell): emitted in MODE 1 and 2; returns how many.
uint grid_visit(GridHeader g, uint tri, vec3 v0f, vec3 e1f, vec3 e2f, vec3 bmin, vec3 bmax) {
    uvec3 lo, hi;
    grid_box_cells(g, bmin, bmax, lo, hi);
    if (all(equal(e1f, vec3(0.0))) && all(equal(e2f, vec3(0.0)))) {
        grid_emit(grid_centre_cell(g, bmin, bmax, lo, hi), tri);
        return 1u;
    }
    dvec3 v0 = dvec3(v0f);
    dvec3 e1 = dvec3(e1f);
    dvec3 e2 = dvec3(e2f);
    dvec3 nrm = dvec3(d_sub(d_mul(e1.y, e2.z), d_mul(e2.y, e1.z)), d_sub(d_mul(e1.z, e2.x), d_mul(e2.z, e1.x)),
                      d_sub(d_mul(e1.x, e2.y), d_mul(e2.x, e1.y)));
    double normal_len = d_length(nrm);
    bool all_cells = normal_len == 0.0lf;
    double pad = all_cells ? 0.0lf : d_mul(g.pad_scale, d_div(d_mul(d_length(e1), d_length(e2)), normal_len));
    dvec3 w = dvec3(d_add(g.widen_x, pad), d_add(g.widen_y, pad), d_add(g.widen_z, pad));
    GridPolygon poly;
    poly.len = 3u;
    poly.v[0] = v0;
    poly.v[1] = dvec3(d_add(v0.x, e1.x), d_add(v0.y, e1.y), d_add(v0.z, e1.z));
    poly.v[2] = dvec3(d_add(v0.x, e2.x), d_add(v0.y, e2.y), d_add(v0.z, e2.z));
    // Slabs across the box's shortest side, rows across the next, runs along the longest (a stable sort of the
    // axes by their cell extent).
    uvec3 ext = hi - lo;
    uint ao = 0u, am = 1u, ai = 2u;
    if (ucomp(ext, am) < ucomp(ext, ao)) { uint x = ao; ao = am; am = x; }
    if (ucomp(ext, ai) < ucomp(ext, am)) { uint x = am; am = ai; ai = x; }
    if (ucomp(ext, am) < ucomp(ext, ao)) { uint x = ao; ao = am; am = x; }
    uint lo_o = ucomp(lo, ao), hi_o = ucomp(hi, ao), lo_m = ucomp(lo, am), hi_m = ucomp(hi, am);
    uint lo_i = ucomp(lo, ai), hi_i = ucomp(hi, ai);
    double w_o = dcomp(w, ao), w_m = dcomp(w, am), w_i = dcomp(w, ai);
    uint count = 0u;
    bool emitted = false;
    for (uint o = lo_o; o <= hi_o; ++o) {
        loop_tick();
        GridPolygon slab = poly;
        uint m0 = lo_m, m1 = hi_m;
        if (!all_cells) {
            slab = grid_clip(poly, ao, d_sub(grid_edge(g, ao, o), w_o), d_add(grid_edge(g, ao, o + 1u), w_o));
            double l, h;
            if (!grid_range(slab, am, l, h)) continue;
            if (!grid_cells_along(g, am, l, h, w_m, lo_m, hi_m, m0, m1)) continue;
        }
        for (uint m = m0; m <= m1; ++m) {
            loop_tick();
            uint k0 = lo_i, k1 = hi_i;
            if (!all_cells) {
                GridPolygon row =
                    grid_clip(slab, am, d_sub(grid_edge(g, am, m), w_m), d_add(grid_edge(g, am, m + 1u), w_m));
                double l, h;
                if (!grid_range(row, ai, l, h)) continue;
                if (!grid_cells_along(g, ai, l, h, w_i, lo_i, hi_i, k0, k1)) continue;
            }
            emitted = true;
            count += k1 - k0 + 1u;
            if (MODE != 0u) {
                for (uint k = k0; k <= k1; ++k) {
                    loop_tick();
                    uvec3 c = uvec3(ao == 0u ? o : (am == 0u ? m : k), ao == 1u ? o : (am == 1u ? m : k),
                                    ao == 2u ? o : (am == 2u ? m : k));
                    grid_emit(grid_cell_index(g, c), tri);
                }
            }
        }
    }
    if (!emitted) {
        grid_emit(grid_centre_cell(g, bmin, bmax, lo, hi), tri);
        return 1u;
    }
    return count;
}

void main() {
    g_loops = 0u;
    uint64_t total = ld_u64(pc.info, 0ul);
    if (MODE != 0u && total > pc.limit) return;
    GridHeader g = GridHeaderRef(pc.header).h;
    uint tile = gl_WorkGroupSize.x;
    uint tiles = tile_count(pc.count, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        loop_tick();
        uint64_t i = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        if (i >= pc.count) continue;
        u64vec3 v = geometry_triangle(i);
        vec3 a = geometry_vertex(v.x);
        vec3 b = geometry_vertex(v.y);
        vec3 c = geometry_vertex(v.z);
        // geom::Triangle::new: both edges zero when the f64 cross product of the edges is exactly zero.
        dvec3 p = dvec3(d_sub(double(b.x), double(a.x)), d_sub(double(b.y), double(a.y)),
                        d_sub(double(b.z), double(a.z)));
        dvec3 q = dvec3(d_sub(double(c.x), double(a.x)), d_sub(double(c.y), double(a.y)),
                        d_sub(double(c.z), double(a.z)));
        dvec3 n = dvec3(d_sub(d_mul(p.y, q.z), d_mul(q.y, p.z)), d_sub(d_mul(p.z, q.x), d_mul(q.z, p.x)),
                        d_sub(d_mul(p.x, q.y), d_mul(q.x, p.y)));
        double len2 = d_add(d_add(d_mul(n.x, n.x), d_mul(n.y, n.y)), d_mul(n.z, n.z));
        vec3 e1 = len2 == 0.0lf ? vec3(0.0) : v_sub(b, a);
        vec3 e2 = len2 == 0.0lf ? vec3(0.0) : v_sub(c, a);
        vec3 bmin = min(min(a, b), c);
        vec3 bmax = max(max(a, b), c);
        if (MODE == 1u) g_slot = uint64_t(ld_u32(pc.counts, i));
        bool copy = pc.skip != 0ul && ld_u32(pc.skip, i) != 0u;
        uint cells = copy ? 0u : grid_visit(g, uint(i), a, e1, e2, bmin, bmax);
        if (MODE == 0u) {
            TriRecord r;
            r.v0 = a;
            r.id = uint(i);
            r.e1 = e1;
            r.pad_a = 0u;
            r.e2 = e2;
            r.pad_b = 0u;
            TriRecordOut(pc.records + 48ul * i).rec = r;
            st_u32(pc.counts, i, cells);
            atomicAdd(U64Ref(pc.info).v, uint64_t(cells));
        }
    }
    if (CHECK_LOOPS != 0u && subgroupAdd(g_loops) >= 65000u && subgroupElect()) atomicOr(U32Ref(pc.info + 8ul).v, 1u);
}
