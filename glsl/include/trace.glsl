// Device layouts of every structure the crate traces, and the ray-triangle and slab arithmetic of the CPU tracer
// (src/geom/ray.rs, src/geom/triangle.rs), operation for operation, so that a device traversal returns the same
// triangle, the same `t` bits and the same test counts as the host. Engines that traverse the crate's structures in
// their own shaders can include this file (with common.glsl before it) as is.
//
// Layouts (std430; the Rust mirrors are generated from the reflection, a test compares every member):
//   TriRecord  48 bytes: a triangle as the intersection test wants it (v0 and the edges v1 - v0, v2 - v0, zero edges
//              for a zero-area triangle) and its mesh index.
//   KdNode      8 bytes: `split_or_count` (f32 bits of the plane, or a leaf's reference count) and `flags`
//              (`axis | right_offset << 2`, or `3 | first_reference << 2` for a leaf). Node 0 is the root; an
//              internal node's children are node + 1 and node + right_offset.
//   BihNode    12 bytes: `clip` (the left child's upper and the right child's lower plane along the axis; a leaf keeps
//              its record count's bits in clip[0]) and `flags` (`axis | children << 2`: children at children and
//              children + 1, or `3 | first_record << 2` for a leaf).
//   BvhNode    (bvh.glsl) for the binned-SAH BVH, LBVH and HLBVH.
//   Grid       a TraceScene header (bounds, resolution, cell size and its inverse), `cells` (ncells + 1 starts into
//              `refs`, cell (x, y, z) is x + res.x * (y + res.y * z)) and `refs` (mesh indices; records in mesh order).
// TraceRay is a ray (origin, tmin, dir, tmax); TraceHit is what a traversal returns for it.
#ifndef MESHCHAR_TRACE_GLSL
#define MESHCHAR_TRACE_GLSL

struct TriRecord {
    vec3 v0;     // First vertex.
    uint id;     // Mesh index of the triangle.
    vec3 e1;     // v1 - v0 (zero for a zero-area triangle).
    uint pad_a;  // Unused (zero).
    vec3 e2;     // v2 - v0 (zero for a zero-area triangle).
    uint pad_b;  // Unused (zero).
};

struct KdNode {
    uint split_or_count; // f32 bits of the split plane (internal) or reference count (leaf).
    uint flags;          // `axis | right_offset << 2` (internal) or `3 | first << 2` (leaf).
};

struct BihNode {
    float clip[2]; // The left child's upper and the right child's lower plane (internal); a leaf's count bits in the first.
    uint flags;    // `axis | children << 2` (internal) or `3 | first << 2` (leaf).
};

struct TraceScene {
    vec3 lo;         // Lower corner of the scene box (kd-tree, BIH, grid).
    uint res_x;      // Grid cells along x.
    vec3 hi;         // Upper corner of the scene box.
    uint res_y;      // Grid cells along y.
    vec3 cell_size;  // Grid cell size.
    uint res_z;      // Grid cells along z.
    vec3 inv_cell;   // Inverse grid cell size, as the host computed it.
    uint nodes;      // Nodes (BVH, kd-tree, BIH) or triangle records (grid); 0 for an empty structure.
};

struct TraceRay {
    vec3 origin; // Origin.
    float tmin;  // Smallest accepted distance (exclusive).
    vec3 dir;    // Direction (need not be unit).
    float tmax;  // Largest accepted distance (exclusive).
};

struct TraceHit {
    float t;         // Distance of the hit (closest hit), in units of dir; 0 for a miss.
    uint triangle;   // Mesh index of the hit triangle, TRACE_MISS for none (any hit: any occluder's index).
    float u;         // Barycentric coordinate of v1.
    float v;         // Barycentric coordinate of v2.
    uint box_tests;  // Box tests (BVH), node visits (kd-tree, BIH) or cells visited (grid), this ray.
    uint prim_tests; // Ray-triangle tests, this ray.
    uint status;     // TRACE_OK, or why the traversal stopped short (TRACE_STACK_FULL, TRACE_STEP_LIMIT).
    uint pad;        // Unused (zero).
};

#define TRACE_MISS 0xffffffffu        // TraceHit.triangle of a ray that hit nothing.
#define TRACE_OK 0u                   // TraceHit.status: the traversal ran to its end.
#define TRACE_STACK_FULL 1u           // TraceHit.status: the stack was too small for the tree (a host bug).
#define TRACE_STEP_LIMIT 2u           // TraceHit.status: more than 2^32 - 2^17 steps (node visits plus tests).
#define TRACE_STACK_ENTRY_BYTES 12ul  // Bytes of one traversal stack entry (node, entry distance, exit distance).

// Bits of the f32 constants of the CPU tracer (a host test checks each against the Rust value): GLSL parses a float
// literal through double, which can round a decimal differently from Rust.
#define TRACE_SLAB_ROBUST_BITS 0x3f800003u // geom::ray::SLAB_ROBUST = 1 + 2 gamma(3).
#define TRACE_KD_WIDEN_BITS 0x3727c5acu    // 1e-5f: relative widening of kd-tree split distances.
#define TRACE_BIH_WIDEN_BITS 0x360637bdu   // 2e-6f: relative widening of BIH clip distances.
#define TRACE_GRID_WIDEN_BITS 0x3727c5acu  // 1e-5f: relative margin of the grid's cull test.
#define TRACE_FLT_EPSILON_BITS 0x34000000u // f32::EPSILON = 2^-23.

// Coefficients of turn_sin_cos (trace::workload::turn_sin_cos on the host reads these same constants): pi / 2 and
// the Taylor coefficients of sin and cos on [0, pi / 2), as f32 bits.
#define TRACE_HALF_PI_BITS 0x3fc90fdbu // pi / 2.
#define TRACE_SIN3_BITS 0xbe2aaaabu    // -1 / 3!.
#define TRACE_SIN5_BITS 0x3c088889u    // 1 / 5!.
#define TRACE_SIN7_BITS 0xb9500d01u    // -1 / 7!.
#define TRACE_SIN9_BITS 0x3638ef1du    // 1 / 9!.
#define TRACE_SIN11_BITS 0xb2d7322bu   // -1 / 11!.
#define TRACE_COS2_BITS 0xbf000000u    // -1 / 2!.
#define TRACE_COS4_BITS 0x3d2aaaabu    // 1 / 4!.
#define TRACE_COS6_BITS 0xbab60b61u    // -1 / 6!.
#define TRACE_COS8_BITS 0x37d00d01u    // 1 / 8!.
#define TRACE_COS10_BITS 0xb493f27eu   // -1 / 10!.
#define TRACE_COS12_BITS 0x310f76c7u   // 1 / 12!.

layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer TriRecordRef { TriRecord rec; };
layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer KdNodeRef { KdNode node; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer BihNodeRef { BihNode node; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer TraceSceneRef { TraceScene s; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer TraceRayRef { TraceRay ray; };
layout(buffer_reference, std430, buffer_reference_align = 16) writeonly buffer TraceHitRef { TraceHit hit; };

// Correctly rounded f32 quotient. Vulkan guarantees correct rounding for f32 addition, subtraction and
// multiplication only (division within 2.5 ulp); the f64 quotient (within a few f64 ulp) lies far closer to the
// exact value than any f32 rounding boundary can (an f32 quotient is never within 2^-49 relative of a midpoint
// unless it is one), so its conversion to f32 is the correctly rounded f32 result, as on the host.
float div_rn(float a, float b) { return float(double(a) / double(b)); }

bool is_finite_f32(float x) { return (floatBitsToUint(x) & 0x7f800000u) != 0x7f800000u; }

// glam's Vec3::dot and Vec3::cross, in their evaluation order, without contraction.
float dot3(vec3 a, vec3 b) {
    precise float r = (a.x * b.x + a.y * b.y) + a.z * b.z;
    return r;
}
vec3 cross3(vec3 a, vec3 b) {
    precise vec3 r = vec3(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
    return r;
}
// Single operations without contraction, for kernels whose own `precise` declarations would make glslang's
// no-contraction analysis run away (it follows every write of an `inout` struct).
float f_add(float a, float b) {
    precise float r = a + b;
    return r;
}
float f_sub(float a, float b) {
    precise float r = a - b;
    return r;
}
float f_mul(float a, float b) {
    precise float r = a * b;
    return r;
}
vec3 v_add(vec3 a, vec3 b) {
    precise vec3 r = a + b;
    return r;
}
vec3 v_sub(vec3 a, vec3 b) {
    precise vec3 r = a - b;
    return r;
}
vec3 v_mul(vec3 a, vec3 b) {
    precise vec3 r = a * b;
    return r;
}
vec3 v_scale(vec3 a, float b) {
    precise vec3 r = a * b;
    return r;
}
float max3(vec3 v) { return max(v.x, max(v.y, v.z)); }
float min3(vec3 v) { return min(v.x, min(v.y, v.z)); }

// The next f32 above t (geom::triangle::next_up).
float next_up(float t) {
    uint b = floatBitsToUint(t);
    if (isnan(t) || b == 0x7f800000u) return t;
    if (t == 0.0) return uintBitsToFloat(1u);
    return uintBitsToFloat(t > 0.0 ? b + 1u : b - 1u);
}

// Correctly rounded f32 square root. The f64 root is only a first guess (Mesa 25's lavapipe returns f64 roots a few
// f64 ulp off, enough to move some f32 results by one ulp): the guess is moved to the neighbour whose rounding
// interval holds the root, decided exactly in f64, where the square of an interval end (25 significant bits) is
// exact and never equals x, so no tie arises.
float sqrt_rn(float x) {
    if (!(x > 0.0) || !is_finite_f32(x)) return sqrt(x);
    float r = float(sqrt(double(x)));
    double dx = double(x);
    for (uint k = 0u; k < 2u; ++k) {
        float up = next_up(r);
        precise double hi = (double(r) + double(up)) * 0.5lf;
        if (hi * hi < dx) r = up;
    }
    for (uint k = 0u; k < 2u; ++k) {
        float down = uintBitsToFloat(floatBitsToUint(r) - 1u);
        precise double lo = (double(down) + double(r)) * 0.5lf;
        if (lo * lo > dx) r = down;
    }
    return r;
}

// A ray with its inverse direction (geom::ray::RayInv: a zero component's inverse is f32::MAX).
struct RayInv {
    vec3 o;
    vec3 d;
    vec3 inv;
};

RayInv ray_inv(TraceRay r) {
    RayInv x;
    x.o = r.origin;
    x.d = r.dir;
    const float big = uintBitsToFloat(0x7f7fffffu);
    x.inv = vec3(r.dir.x == 0.0 ? big : div_rn(1.0, r.dir.x), r.dir.y == 0.0 ? big : div_rn(1.0, r.dir.y),
                 r.dir.z == 0.0 ? big : div_rn(1.0, r.dir.z));
    return x;
}

// RayInv::slab: entry distance into [lo, hi] within (tmin, tmax), or false.
bool slab(RayInv r, vec3 lo, vec3 hi, float tmin, float tmax, out float near) {
    precise vec3 t0 = (lo - r.o) * r.inv;
    precise vec3 t1 = (hi - r.o) * r.inv;
    near = max(max3(min(t0, t1)), tmin);
    precise float far = min3(max(t0, t1)) * uintBitsToFloat(TRACE_SLAB_ROBUST_BITS);
    return near <= min(far, tmax);
}

// RayInv::slab_interval: the clipped interval (near, far), or false.
bool slab_interval(RayInv r, vec3 lo, vec3 hi, float tmin, float tmax, out float near, out float far) {
    precise vec3 t0 = (lo - r.o) * r.inv;
    precise vec3 t1 = (hi - r.o) * r.inv;
    near = max(max3(min(t0, t1)), tmin);
    precise float f = min3(max(t0, t1)) * uintBitsToFloat(TRACE_SLAB_ROBUST_BITS);
    far = min(f, tmax);
    return near <= far;
}

// geom::triangle::tie_margin for a non-empty scene box [lo, hi] (the caller passes 0 for an empty one).
float tie_margin(vec3 o, vec3 d, vec3 lo, vec3 hi) {
    float m = max3(abs(d));
    if (!(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z) || isnan(m) || m <= 0.0) return 0.0;
    precise float coords = max3(abs(o)) + max3(max(abs(lo), abs(hi)));
    precise float num = (64.0 * uintBitsToFloat(TRACE_FLT_EPSILON_BITS)) * coords;
    return div_rn(num, m);
}

// geom::triangle::cull_bound.
float cull_bound(float best_t, float margin) {
    const float r = uintBitsToFloat(TRACE_SLAB_ROBUST_BITS);
    precise float scaled = best_t >= 0.0 ? best_t * r : div_rn(best_t, r);
    precise float b = scaled + margin;
    return b;
}

// geom::triangle::intersect_triangle (Möller-Trumbore in f32).
bool intersect_triangle(TriRecord tri, vec3 o, vec3 d, float tmin, float tmax, out vec3 tuv) {
    tuv = vec3(0.0);
    precise vec3 p = cross3(d, tri.e2);
    precise float det = dot3(tri.e1, p);
    if (det == 0.0 || !is_finite_f32(det)) return false;
    float inv = div_rn(1.0, det);
    precise vec3 s = o - tri.v0;
    precise float u = dot3(s, p) * inv;
    if (!(u >= 0.0 && u <= 1.0)) return false;
    precise vec3 q = cross3(s, tri.e1);
    precise float v = dot3(d, q) * inv;
    precise float uv = u + v;
    if (!(v >= 0.0 && uv <= 1.0)) return false;
    precise float t = dot3(tri.e2, q) * inv;
    if (t > tmin && t < tmax) {
        tuv = vec3(t, u, v);
        return true;
    }
    return false;
}

// The closest hit so far of a traversal and its counters.
struct TraceState {
    float best_t;   // Distance of the closest hit so far (tmax while there is none).
    uint best_id;   // Its mesh index, TRACE_MISS while there is none.
    float best_u;
    float best_v;
    uint boxes;     // Box tests, node visits or cells (see TraceHit).
    uint prims;     // Ray-triangle tests.
};

// geom::triangle::closer_hit under the tie rule (of two hits at the same t the smaller mesh index wins); one
// ray-triangle test. Updates `st` and returns true when the record is the new closest hit.
bool closer_hit(TriRecord tri, vec3 o, vec3 d, float tmin, inout TraceState st) {
    st.prims += 1u;
    bool may_tie = st.best_id != TRACE_MISS && tri.id < st.best_id;
    float limit = may_tie ? next_up(st.best_t) : st.best_t;
    vec3 tuv;
    if (!intersect_triangle(tri, o, d, tmin, limit, tuv)) return false;
    st.best_t = tuv.x;
    st.best_id = tri.id;
    st.best_u = tuv.y;
    st.best_v = tuv.z;
    return true;
}

// sin and cos of 2 pi u for u in [0, 1), from additions and multiplications only (the host's turn_sin_cos, to the
// bit): the quadrant from 4u, then Taylor polynomials of degree 11 and 12 on [0, pi / 2) (error below 1e-7).
vec2 turn_sin_cos(float u) {
    float t = f_mul(u, 4.0);
    float q = floor(t);
    float x = f_mul(f_sub(t, q), uintBitsToFloat(TRACE_HALF_PI_BITS));
    float x2 = f_mul(x, x);
    float sp = uintBitsToFloat(TRACE_SIN11_BITS);
    sp = f_add(uintBitsToFloat(TRACE_SIN9_BITS), f_mul(x2, sp));
    sp = f_add(uintBitsToFloat(TRACE_SIN7_BITS), f_mul(x2, sp));
    sp = f_add(uintBitsToFloat(TRACE_SIN5_BITS), f_mul(x2, sp));
    sp = f_add(uintBitsToFloat(TRACE_SIN3_BITS), f_mul(x2, sp));
    float sn = f_mul(x, f_add(1.0, f_mul(x2, sp)));
    float cp = uintBitsToFloat(TRACE_COS12_BITS);
    cp = f_add(uintBitsToFloat(TRACE_COS10_BITS), f_mul(x2, cp));
    cp = f_add(uintBitsToFloat(TRACE_COS8_BITS), f_mul(x2, cp));
    cp = f_add(uintBitsToFloat(TRACE_COS6_BITS), f_mul(x2, cp));
    cp = f_add(uintBitsToFloat(TRACE_COS4_BITS), f_mul(x2, cp));
    cp = f_add(uintBitsToFloat(TRACE_COS2_BITS), f_mul(x2, cp));
    float cs = f_add(1.0, f_mul(x2, cp));
    uint k = uint(int(q)) & 3u;
    if (k == 0u) return vec2(sn, cs);
    if (k == 1u) return vec2(cs, -sn);
    if (k == 2u) return vec2(-sn, -cs);
    return vec2(-cs, sn);
}

TriRecord tri_record(uint64_t base, uint i) { return TriRecordRef(base + 48ul * uint64_t(i)).rec; }

#endif
