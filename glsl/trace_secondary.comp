#version 460
// Secondary rays on the device: from the closest hits of primary rays, the shadow rays (KIND 0) or diffuse rays
// (KIND 1) of trace::workload::secondary_rays, bit for bit and in the same order (a primary ray that misses, or hits a
// zero-area triangle, spawns nothing), so a secondary workload is never uploaded. Diffuse directions come from the
// same SplitMix64 stream per primary ray as on the host and the host's turn_sin_cos. Three dispatches of this kernel, PHASE in the push constants:
//   0: invocation c counts the rays spawned by primary rays c * CHUNK .. (c + 1) * CHUNK into counts[c];
//   1: one invocation turns counts into exclusive offsets (counts[chunks] = the total);
//   2: invocation c writes its chunk's rays at counts[c] onward.
// The geometry view is the mesh the hits refer to (the triangle index of a hit selects its vertices).
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "common.glsl"
#include "trace.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t positions;    // Address of the position of vertex 0 (include/geometry.glsl).
    uint64_t indices;      // Address of the first index (include/geometry.glsl).
    uint64_t vertex_count; // Vertices of the view (include/geometry.glsl).
    uint vertex_stride;    // Bytes between vertices (include/geometry.glsl).
    uint index_type;       // GEOMETRY_INDEX_* (include/geometry.glsl).
    uint base_vertex;      // Added to every index (include/geometry.glsl).
    uint geometry_pad;     // Padding.
    float light_x;         // Point light, x.
    float light_y;         // Point light, y.
    float light_z;         // Point light, z.
    float offset;          // 1e-5 * the length of the scene box's extent, as the host computes it.
    uint64_t primary;      // Address of the primary TraceRay array.
    uint64_t hits;         // Address of their TraceHit array.
    uint64_t counts;       // Address of chunks + 1 uints (counts, then offsets).
    uint64_t out_rays;     // Address of the output TraceRay array (as many as primary rays, at most).
    uint64_t count;        // Primary rays.
    uint64_t triangles;    // Triangles of the view.
    uint chunk;            // Primary rays per invocation (CHUNK).
    uint phase;            // 0 count, 1 scan, 2 write.
    float tmax_scale;      // 1 - 1e-5 as the host computes it in f32.
    uint kind;             // 0: shadow rays; 1: diffuse rays.
    uint64_t seed;         // Seed of the diffuse rays' generator (the stream of primary ray k is seeded seed ^ k * M).
} pc;

#include "geometry.glsl"

layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer RayIn { TraceRay ray; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer HitIn { TraceHit hit; };
layout(buffer_reference, std430, buffer_reference_align = 16) writeonly buffer RayOut { TraceRay ray; };

// SplitMix64 (rng::SplitMix64 on the host).
uint64_t splitmix_next(inout uint64_t state) {
    state += 0x9e3779b97f4a7c15ul;
    uint64_t z = state;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ul;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebul;
    return z ^ (z >> 31);
}
float splitmix_f32(inout uint64_t state) { return f_mul(float(splitmix_next(state) >> 40), uintBitsToFloat(0x33800000u)); }

// A cosine-distributed unit direction about the unit normal n (cosine_direction on the host, glam's
// any_orthonormal_pair for the tangents).
vec3 cosine_direction(vec3 n, inout uint64_t state) {
    float u1 = splitmix_f32(state);
    float u2 = splitmix_f32(state);
    float r = sqrt_rn(u1);
    vec2 sc = turn_sin_cos(u2);
    float x = f_mul(r, sc.y);
    float y = f_mul(r, sc.x);
    float z = sqrt_rn(max(f_sub(1.0, u1), 0.0));
    float sgn = (floatBitsToUint(n.z) & 0x80000000u) != 0u ? -1.0 : 1.0;
    float a = div_rn(-1.0, f_add(sgn, n.z));
    float b = f_mul(f_mul(n.x, n.y), a);
    vec3 t = vec3(f_add(1.0, f_mul(f_mul(f_mul(sgn, n.x), n.x), a)), f_mul(sgn, b), f_mul(-sgn, n.x));
    vec3 bt = vec3(b, f_add(sgn, f_mul(f_mul(n.y, n.y), a)), -n.y);
    vec3 d = v_add(v_add(v_scale(t, x), v_scale(bt, y)), v_scale(n, z));
    float rcp = div_rn(1.0, sqrt_rn(dot3(d, d)));
    return (is_finite_f32(rcp) && rcp > 0.0) ? v_scale(d, rcp) : n;
}

// The secondary ray of primary ray k, or false.
bool shadow_ray(uint64_t k, out TraceRay s) {
    s.origin = vec3(0.0);
    s.tmin = 0.0;
    s.dir = vec3(0.0);
    s.tmax = 0.0;
    TraceHit h = HitIn(pc.hits + 32ul * k).hit;
    if (h.triangle == TRACE_MISS || uint64_t(h.triangle) >= pc.triangles) return false;
    TraceRay r = RayIn(pc.primary + 32ul * k).ray;
    u64vec3 t = geometry_triangle(uint64_t(h.triangle));
    vec3 a = geometry_vertex(t.x);
    vec3 b = geometry_vertex(t.y);
    vec3 c = geometry_vertex(t.z);
    vec3 v = cross3(v_sub(b, a), v_sub(c, a));
    float rcp = div_rn(1.0, sqrt_rn(dot3(v, v)));
    if (!(is_finite_f32(rcp) && rcp > 0.0)) return false;
    vec3 n = v_scale(v, rcp);
    if (dot3(n, r.dir) > 0.0) n = -n;
    vec3 p = v_add(r.origin, v_scale(r.dir, h.t));
    float off = f_add(pc.offset, f_mul(uintBitsToFloat(0x358637bdu), max3(abs(p)))); // 1e-6f
    vec3 o = v_add(p, v_scale(n, off));
    if (pc.kind == 1u) {
        uint64_t state = pc.seed ^ (k * 0x2545f4914f6cdd1dul);
        s.origin = o;
        s.dir = cosine_direction(n, state);
        s.tmax = uintBitsToFloat(0x7f800000u);
        return true;
    }
    vec3 to = v_sub(vec3(pc.light_x, pc.light_y, pc.light_z), o);
    float dist = sqrt_rn(dot3(to, to));
    if (!(dist > 0.0 && is_finite_f32(dist))) return false;
    s.origin = o;
    s.dir = vec3(div_rn(to.x, dist), div_rn(to.y, dist), div_rn(to.z, dist));
    s.tmax = f_mul(dist, pc.tmax_scale);
    return true;
}

void main() {
    uint64_t chunks = (pc.count + uint64_t(pc.chunk) - 1ul) / uint64_t(pc.chunk);
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    if (pc.phase == 1u) {
        if (gl_GlobalInvocationID.x != 0u) return;
        uint total = 0u;
        // Two nested loops of at most 65,535 iterations each (lavapipe cuts longer loops).
        for (uint64_t hi = 0ul; hi * 65535ul < chunks; hi++) {
            for (uint64_t lo = 0ul; lo < 65535ul && hi * 65535ul + lo < chunks; lo++) {
                uint64_t c = hi * 65535ul + lo;
                uint n = ld_u32(pc.counts, c);
                st_u32(pc.counts, c, total);
                total += n;
            }
        }
        st_u32(pc.counts, chunks, total);
        return;
    }
    for (uint64_t c = uint64_t(gl_GlobalInvocationID.x); c < chunks; c += stride) {
        uint64_t first = c * uint64_t(pc.chunk);
        uint64_t end = min(first + uint64_t(pc.chunk), pc.count);
        uint at = pc.phase == 2u ? ld_u32(pc.counts, c) : 0u;
        uint n = 0u;
        for (uint64_t k = first; k < end; k++) {
            TraceRay s;
            if (!shadow_ray(k, s)) continue;
            if (pc.phase == 2u) RayOut(pc.out_rays + 32ul * uint64_t(at + n)).ray = s;
            n += 1u;
        }
        if (pc.phase == 0u) st_u32(pc.counts, c, n);
    }
}
