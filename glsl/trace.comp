#version 460
// Traversal of one structure for a set of rays: closest hit, or any hit (shadow rays), with each ray's box (node,
// cell) and triangle test counts. The same arithmetic, tie rule and traversal order as the CPU tracer
// (src/accel/{bvh/mod,kdtree,grid,bih}.rs), so the hit triangle, the `t` bits and the counts equal the host's.
//
// STRUCTURE selects the layout (include/trace.glsl): 0 BVH2 (binned-SAH BVH, LBVH, HLBVH), 1 kd-tree, 2 uniform
// grid, 3 BIH. Invocation g traces rays g, g + G, g + 2G, ... (G invocations in the dispatch) and keeps its stack of
// `stack_entries` entries at stack + g * stack_entries * TRACE_STACK_ENTRY_BYTES: the host sizes it from the tree's
// depth (a push never finds it full on a tree of that depth; if it does, the ray reports TRACE_STACK_FULL).
// Every traversal runs as steps (one node visit, one triangle test, one pop or one cell step) in two nested loops of
// at most 65,535 iterations each; a ray whose steps end before it is done reports TRACE_STEP_LIMIT: one that needs
// more than 65,535^2 steps, or one whose loops the driver cut (lavapipe stops an invocation's loops after 65,535
// iterations in all). An invocation whose ray loop was cut writes TRACE_STEP_LIMIT into the next ray it did not
// trace, so a cut never passes as a result.
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "common.glsl"
#include "bvh.glsl"
#include "trace.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint STRUCTURE = 0u; // 0 BVH2, 1 kd-tree, 2 grid, 3 BIH.

layout(push_constant) uniform Push {
    uint64_t rays;      // Address of the TraceRay array.
    uint64_t hits;      // Address of the TraceHit array (one per ray).
    uint64_t nodes;     // Address of the nodes (BvhNode, KdNode, BihNode) or of the grid's cell starts.
    uint64_t tris;      // Address of the TriRecord array.
    uint64_t refs;      // Address of the references (kd-tree, grid; unused otherwise).
    uint64_t scene;     // Address of the TraceScene header.
    uint64_t stack;     // Address of the stacks of every invocation.
    uint64_t count;     // Rays.
    uint stack_entries; // Stack entries per invocation.
    uint any_hit;       // 1: any hit (stop at the first hit found); 0: closest hit.
} pc;

layout(buffer_reference, std430, buffer_reference_align = 4) buffer StackRef { uint node; float a; float b; };

// One traversal in progress.
struct Walk {
    RayInv r;
    float tmin;
    float bound;    // Cull bound: nodes entered beyond it are skipped (the ray's tmax until a hit).
    float margin;   // tie_margin of the ray in the scene box.
    uint node;      // Node to visit.
    float tn;       // Entry distance of the node (kd-tree, BIH).
    float tf;       // Exit distance of the node (kd-tree, BIH).
    uint li;        // Next record (or reference) of the leaf being tested ...
    uint le;        // ... and the end of the leaf.
    uint sp;        // Stack entries in use.
    bool popping;   // The next step pops the stack.
    uint status;    // TRACE_OK or why the walk stopped short.
    TraceState st;
};

uint64_t stack_base;

// Pushes an entry; false (and TRACE_STACK_FULL) when the stack is full.
bool push(inout Walk w, uint node, float a, float b) {
    if (w.sp >= pc.stack_entries) {
        w.status = TRACE_STACK_FULL;
        return false;
    }
    StackRef e = StackRef(stack_base + TRACE_STACK_ENTRY_BYTES * uint64_t(w.sp));
    e.node = node;
    e.a = a;
    e.b = b;
    w.sp += 1u;
    return true;
}

// Tests record `rec`; true when the walk ends (any hit found).
bool test_record(inout Walk w, TriRecord rec) {
    if (closer_hit(rec, w.r.o, w.r.d, w.tmin, w.st)) {
        w.bound = cull_bound(w.st.best_t, w.margin);
        if (pc.any_hit != 0u) return true;
    }
    return false;
}

Walk start(TraceRay ray) {
    Walk w;
    w.r = ray_inv(ray);
    w.tmin = ray.tmin;
    w.bound = ray.tmax;
    w.margin = 0.0;
    w.node = 0u;
    w.tn = 0.0;
    w.tf = 0.0;
    w.li = 0u;
    w.le = 0u;
    w.sp = 0u;
    w.popping = false;
    w.status = TRACE_OK;
    w.st.best_t = ray.tmax;
    w.st.best_id = TRACE_MISS;
    w.st.best_u = 0.0;
    w.st.best_v = 0.0;
    w.st.boxes = 0u;
    w.st.prims = 0u;
    return w;
}

// ---- BVH2 ------------------------------------------------------------------------------------------------------

bool bvh_step(inout Walk w) {
    if (w.li < w.le) {
        TriRecord rec = tri_record(pc.tris, w.li);
        w.li += 1u;
        return test_record(w, rec);
    }
    if (w.popping) {
        if (w.sp == 0u) return true;
        w.sp -= 1u;
        StackRef e = StackRef(stack_base + TRACE_STACK_ENTRY_BYTES * uint64_t(w.sp));
        if (e.a <= w.bound) {
            w.node = e.node;
            w.popping = false;
        }
        return false;
    }
    BvhNode n = bvh_node(pc.nodes, w.node).node;
    if ((n.right_or_count & BVH_LEAF_FLAG) != 0u) {
        w.li = n.left_or_first;
        w.le = n.left_or_first + (n.right_or_count & ~BVH_LEAF_FLAG);
        w.popping = true;
        return false;
    }
    uint l = n.left_or_first;
    uint rr = n.right_or_count;
    BvhNode nl = bvh_node(pc.nodes, l).node;
    BvhNode nr = bvh_node(pc.nodes, rr).node;
    w.st.boxes += 2u;
    float a, b;
    bool hl = slab(w.r, nl.min, nl.max, w.tmin, w.bound, a);
    bool hr = slab(w.r, nr.min, nr.max, w.tmin, w.bound, b);
    if (hl && hr) {
        if (a <= b) {
            if (!push(w, rr, b, 0.0)) return true;
            w.node = l;
        } else {
            if (!push(w, l, a, 0.0)) return true;
            w.node = rr;
        }
    } else if (hl) {
        w.node = l;
    } else if (hr) {
        w.node = rr;
    } else {
        w.popping = true;
    }
    return false;
}

// False when the ray misses the structure at once.
bool bvh_start(inout Walk w, TraceScene sc) {
    if (sc.nodes == 0u) return false;
    w.st.boxes = 1u;
    BvhNode root = bvh_node(pc.nodes, 0u).node;
    float near;
    if (!slab(w.r, root.min, root.max, w.tmin, w.st.best_t, near)) return false;
    w.margin = tie_margin(w.r.o, w.r.d, root.min, root.max);
    return true;
}

// ---- kd-tree ---------------------------------------------------------------------------------------------------

bool kd_step(inout Walk w) {
    if (w.li < w.le) {
        uint id = ld_u32(pc.refs, uint64_t(w.li));
        w.li += 1u;
        return test_record(w, tri_record(pc.tris, id));
    }
    if (w.popping) {
        if (w.sp == 0u) return true;
        w.sp -= 1u;
        StackRef e = StackRef(stack_base + TRACE_STACK_ENTRY_BYTES * uint64_t(w.sp));
        w.node = e.node;
        w.tn = e.a;
        w.tf = e.b;
        w.popping = false;
        return false;
    }
    if (!(w.tn <= w.bound)) {
        w.popping = true;
        return false;
    }
    KdNode nd = KdNodeRef(pc.nodes + 8ul * uint64_t(w.node)).node;
    if ((nd.flags & 3u) == 3u) {
        w.li = nd.flags >> 2;
        w.le = w.li + nd.split_or_count;
        w.popping = true;
        return false;
    }
    w.st.boxes += 1u;
    uint a = nd.flags & 3u;
    float p = uintBitsToFloat(nd.split_or_count);
    float oa = w.r.o[a];
    float da = w.r.d[a];
    float ts = f_mul(f_sub(p, oa), w.r.inv[a]);
    bool below_first = oa < p || (oa == p && da <= 0.0);
    uint right = w.node + (nd.flags >> 2);
    uint near = below_first ? w.node + 1u : right;
    uint far = below_first ? right : w.node + 1u;
    if (ts < 0.0) {
        w.node = near;
        return false;
    }
    if (ts == 0.0) {
        if (!push(w, far, w.tn, w.tf)) return true;
        w.node = near;
        return false;
    }
    float e = f_mul(ts, uintBitsToFloat(TRACE_KD_WIDEN_BITS));
    float hi = f_add(ts, e);
    float lo = f_sub(ts, e);
    bool near_ok = w.tn <= hi;
    bool far_ok = lo <= w.tf;
    if (near_ok && far_ok) {
        if (!push(w, far, max(w.tn, lo), w.tf)) return true;
        w.node = near;
        w.tf = min(w.tf, hi);
    } else if (near_ok) {
        w.node = near;
    } else if (far_ok) {
        w.node = far;
    } else {
        w.popping = true;
    }
    return false;
}

// kd-tree and BIH: the scene box test. False when the ray misses the structure at once.
bool interval_start(inout Walk w, TraceScene sc) {
    if (sc.nodes == 0u) return false;
    w.st.boxes = 1u;
    if (!slab_interval(w.r, sc.lo, sc.hi, w.tmin, w.st.best_t, w.tn, w.tf)) return false;
    w.margin = tie_margin(w.r.o, w.r.d, sc.lo, sc.hi);
    return true;
}

// ---- BIH -------------------------------------------------------------------------------------------------------

bool bih_step(inout Walk w) {
    if (w.li < w.le) {
        TriRecord rec = tri_record(pc.tris, w.li);
        w.li += 1u;
        return test_record(w, rec);
    }
    if (w.popping) {
        if (w.sp == 0u) return true;
        w.sp -= 1u;
        StackRef e = StackRef(stack_base + TRACE_STACK_ENTRY_BYTES * uint64_t(w.sp));
        w.node = e.node;
        w.tn = e.a;
        w.tf = e.b;
        w.popping = false;
        return false;
    }
    if (!(w.tn <= w.bound)) {
        w.popping = true;
        return false;
    }
    BihNode nd = BihNodeRef(pc.nodes + 12ul * uint64_t(w.node)).node;
    if ((nd.flags & 3u) == 3u) {
        w.li = nd.flags >> 2;
        w.le = w.li + floatBitsToUint(nd.clip[0]);
        w.popping = true;
        return false;
    }
    w.st.boxes += 1u;
    uint a = nd.flags & 3u;
    uint ch = nd.flags >> 2;
    const float E = uintBitsToFloat(TRACE_BIH_WIDEN_BITS);
    float oa = w.r.o[a];
    float ia = w.r.inv[a];
    float tl = f_mul(f_sub(nd.clip[0], oa), ia);
    float tr = f_mul(f_sub(nd.clip[1], oa), ia);
    uint near, far;
    float near_end, far_start;
    if (ia > 0.0) {
        near = ch;
        near_end = f_add(tl, f_mul(abs(tl), E));
        far = ch + 1u;
        far_start = f_sub(tr, f_mul(abs(tr), E));
    } else {
        near = ch + 1u;
        near_end = f_add(tr, f_mul(abs(tr), E));
        far = ch;
        far_start = f_sub(tl, f_mul(abs(tl), E));
    }
    bool near_ok = w.tn <= near_end;
    bool far_ok = far_start <= w.tf;
    if (near_ok && far_ok) {
        if (!push(w, far, max(w.tn, far_start), w.tf)) return true;
        w.node = near;
        w.tf = min(w.tf, near_end);
    } else if (near_ok) {
        w.node = near;
        w.tf = min(w.tf, near_end);
    } else if (far_ok) {
        w.node = far;
        w.tn = max(w.tn, far_start);
    } else {
        w.popping = true;
    }
    return false;
}

// ---- grid ------------------------------------------------------------------------------------------------------

// 3D-DDA state of a grid walk.
int g_cell[3];
int g_step[3];
int g_res[3];
float g_next[3];
float g_t1;
uint g_mailbox[16];
bool g_entering;

float grid_next_t(TraceScene sc, RayInv r, uint a) {
    if (g_step[a] == 0) return uintBitsToFloat(0x7f800000u);
    int k = g_step[a] > 0 ? g_cell[a] + 1 : g_cell[a];
    float plane = f_add(sc.lo[a], f_mul(float(k), sc.cell_size[a]));
    return div_rn(f_sub(plane, r.o[a]), r.d[a]);
}

bool grid_start(inout Walk w, TraceScene sc) {
    if (sc.nodes == 0u) return false;
    w.st.boxes = 1u;
    float t0;
    if (!slab_interval(w.r, sc.lo, sc.hi, w.tmin, w.st.best_t, t0, g_t1)) return false;
    vec3 p = v_add(w.r.o, v_scale(w.r.d, t0));
    vec3 f = floor(v_mul(v_sub(p, sc.lo), sc.inv_cell));
    g_res[0] = int(sc.res_x);
    g_res[1] = int(sc.res_y);
    g_res[2] = int(sc.res_z);
    for (uint a = 0u; a < 3u; a++) {
        g_cell[a] = int(min(max(f[a], 0.0), float(g_res[a] - 1)));
        float d = w.r.d[a];
        g_step[a] = d > 0.0 ? 1 : (d < 0.0 ? -1 : 0);
    }
    for (uint a = 0u; a < 3u; a++) g_next[a] = grid_next_t(sc, w.r, a);
    for (uint s = 0u; s < 16u; s++) g_mailbox[s] = 0xffffffffu;
    w.margin = tie_margin(w.r.o, w.r.d, sc.lo, sc.hi);
    g_entering = true;
    return true;
}

bool grid_step(inout Walk w, TraceScene sc) {
    if (w.li < w.le) {
        uint id = ld_u32(pc.refs, uint64_t(w.li));
        w.li += 1u;
        uint slot = id & 15u;
        if (g_mailbox[slot] == id) return false;
        g_mailbox[slot] = id;
        if (closer_hit(tri_record(pc.tris, id), w.r.o, w.r.d, w.tmin, w.st)) {
            if (pc.any_hit != 0u) return true;
        }
        return false;
    }
    if (g_entering) {
        w.st.boxes += 1u;
        uint64_t idx = uint64_t(g_cell[0]) +
                       uint64_t(sc.res_x) * (uint64_t(g_cell[1]) + uint64_t(sc.res_y) * uint64_t(g_cell[2]));
        w.li = ld_u32(pc.nodes, idx);
        w.le = ld_u32(pc.nodes, idx + 1ul);
        g_entering = false;
        return false;
    }
    uint a = (g_next[0] <= g_next[1] && g_next[0] <= g_next[2]) ? 0u : (g_next[1] <= g_next[2] ? 1u : 2u);
    float exit = g_next[a];
    float widened = f_sub(exit, f_mul(abs(exit), uintBitsToFloat(TRACE_GRID_WIDEN_BITS)));
    if ((w.st.best_id != TRACE_MISS && cull_bound(w.st.best_t, w.margin) < widened) || exit > g_t1 ||
        !is_finite_f32(exit)) {
        return true;
    }
    g_cell[a] += g_step[a];
    if (g_cell[a] < 0 || g_cell[a] >= g_res[a]) return true;
    g_next[a] = grid_next_t(sc, w.r, a);
    g_entering = true;
    return false;
}

// ----------------------------------------------------------------------------------------------------------------

bool step(inout Walk w, TraceScene sc) {
    if (STRUCTURE == 0u) return bvh_step(w);
    if (STRUCTURE == 1u) return kd_step(w);
    if (STRUCTURE == 2u) return grid_step(w, sc);
    return bih_step(w);
}

bool begin(inout Walk w, TraceScene sc) {
    if (STRUCTURE == 0u) return bvh_start(w, sc);
    if (STRUCTURE == 2u) return grid_start(w, sc);
    return interval_start(w, sc);
}

void main() {
    uint64_t invocations = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    uint64_t g = uint64_t(gl_WorkGroupID.x) * uint64_t(gl_WorkGroupSize.x) + uint64_t(gl_LocalInvocationIndex);
    stack_base = pc.stack + g * uint64_t(pc.stack_entries) * TRACE_STACK_ENTRY_BYTES;
    TraceScene sc = TraceSceneRef(pc.scene).s;
    uint64_t i = g;
    for (; i < pc.count; i += invocations) {
        TraceRay ray = TraceRayRef(pc.rays + 32ul * i).ray;
        Walk w = start(ray);
        if (begin(w, sc)) {
            bool done = false;
            for (uint hi = 0u; hi < 65535u && !done; hi++) {
                for (uint lo = 0u; lo < 65535u && !done; lo++) done = step(w, sc);
            }
            if (!done) w.status = TRACE_STEP_LIMIT;
        }
        TraceHit h;
        bool hit = w.st.best_id != TRACE_MISS;
        h.t = hit ? w.st.best_t : 0.0;
        h.triangle = w.st.best_id;
        h.u = w.st.best_u;
        h.v = w.st.best_v;
        h.box_tests = w.st.boxes;
        h.prim_tests = w.st.prims;
        h.status = w.status;
        h.pad = 0u;
        TraceHitRef(pc.hits + 32ul * i).hit = h;
    }
    if (i < pc.count) {
        // The driver cut the ray loop: the rays from i on were never traced.
        TraceHit h;
        h.t = 0.0;
        h.triangle = TRACE_MISS;
        h.u = 0.0;
        h.v = 0.0;
        h.box_tests = 0u;
        h.prim_tests = 0u;
        h.status = TRACE_STEP_LIMIT;
        h.pad = 0u;
        TraceHitRef(pc.hits + 32ul * i).hit = h;
    }
}
