#version 460
// Scene features, pass 2 (definitions in src/characterize/features.rs):
// - occupancy: bit (code >> shift) of a 2^21-bit mask set for every sampled triangle's Morton code (atomic OR; the
//   host counts set bits per depth);
// - triangle sizes: histogram of k = e(S) - e(t), where t is the largest box extent of the triangle, S the largest
//   extent of the vertex bounds (read from pass 1's result on the device), e() the unbiased f32 exponent from the
//   bits; k clamped to [0, SIZE_BINS - 1]; triangles whose t or S is zero, subnormal or infinite go to
//   hist[SIZE_BINS]. Only exact operations: min/max on ordered bits, one correctly rounded subtraction per axis.
// mask: uint[2^21 / 32] and hist: uint[SIZE_BINS + 1], zeroed by the host.
#include "common.glsl"
#include "layout.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;
layout(constant_id = 2) const uint BITS63 = 0u;
layout(constant_id = 3) const uint SIZE_BINS = 24u;

layout(push_constant) uniform Push {
    uint64_t positions;    // Address of the position of vertex 0 (include/geometry.glsl).
    uint64_t indices;      // Address of the first index (include/geometry.glsl).
    uint64_t vertex_count; // Vertices of the view (include/geometry.glsl).
    uint vertex_stride;    // Bytes between vertices (include/geometry.glsl).
    uint index_type;       // GEOMETRY_INDEX_* (include/geometry.glsl).
    uint base_vertex;      // Added to every index (include/geometry.glsl).
    uint geometry_pad;     // Padding.
    uint64_t codes;     // Address of the Morton codes of the sampled triangles (u32 or u64).
    uint64_t mask;      // Address of the `uint[2^21 / 32]` occupancy mask.
    uint64_t hist;      // Address of the `uint[size_bins + 1]` size histogram (last entry: zero or non-normal extents).
    uint64_t bounds;    // Address of the `uint[6]` vertex bounds written by the first dispatch.
    uint64_t count;     // Sampled triangles.
    uint64_t stride;    // Sample stride.
    uint shift;         // `bits - 21`: the shift that leaves a code's depth-7 prefix.
    uint pad;           // Padding.
} pc;

#include "geometry.glsl"

shared uint s_hist[SIZE_BINS + 1u];

float from_ordered_bits(uint b) {
    return uintBitsToFloat((b & 0x80000000u) != 0u ? (b & 0x7fffffffu) : ~b);
}

// Unbiased exponent of a positive normal float; -1000 for zero, subnormals, infinities and NaN.
int exponent_of(float x) {
    int e = int((floatBitsToUint(x) >> 23) & 0xffu);
    return (e == 0 || e == 255) ? -1000 : e - 127;
}

// Largest of the three extents hi - lo, starting from +0 (the host's fold order).
float largest_extent(vec3 lo, vec3 hi) {
    precise vec3 d = hi - lo;
    float m = 0.0;
    m = max(m, d.x);
    m = max(m, d.y);
    m = max(m, d.z);
    return m;
}

void main() {
    uint lid = gl_LocalInvocationIndex;
    for (uint c = lid; c <= SIZE_BINS; c += gl_WorkGroupSize.x) s_hist[c] = 0u;
    barrier();
    vec3 slo = vec3(from_ordered_bits(ld_u32(pc.bounds, BOUNDS_LO)),
                    from_ordered_bits(ld_u32(pc.bounds, BOUNDS_LO + 1u)),
                    from_ordered_bits(ld_u32(pc.bounds, BOUNDS_LO + 2u)));
    vec3 shi = vec3(from_ordered_bits(ld_u32(pc.bounds, BOUNDS_HI)),
                    from_ordered_bits(ld_u32(pc.bounds, BOUNDS_HI + 1u)),
                    from_ordered_bits(ld_u32(pc.bounds, BOUNDS_HI + 2u)));
    int se = exponent_of(largest_extent(slo, shi));
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.count, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t base = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t i = base + uint64_t(j * gl_WorkGroupSize.x);
            if (i < pc.count) {
                uint64_t m = BITS63 != 0u ? ld_u64(pc.codes, i) : uint64_t(ld_u32(pc.codes, i));
                uint prefix = uint(m >> pc.shift);
                atomicOr(U32Ref(pc.mask + 4ul * uint64_t(prefix >> 5)).v, 1u << (prefix & 31u));
                u64vec3 tri = geometry_triangle(i * pc.stride);
                vec3 v0 = geometry_vertex(tri.x);
                vec3 v1 = geometry_vertex(tri.y);
                vec3 v2 = geometry_vertex(tri.z);
                // Triangle box from ordered bits: exact whatever the device does with signed zeros or denormals.
                uvec3 o0 = uvec3(ordered_bits(v0.x), ordered_bits(v0.y), ordered_bits(v0.z));
                uvec3 o1 = uvec3(ordered_bits(v1.x), ordered_bits(v1.y), ordered_bits(v1.z));
                uvec3 o2 = uvec3(ordered_bits(v2.x), ordered_bits(v2.y), ordered_bits(v2.z));
                uvec3 ol = min(min(o0, o1), o2);
                uvec3 oh = max(max(o0, o1), o2);
                vec3 tlo = vec3(from_ordered_bits(ol.x), from_ordered_bits(ol.y), from_ordered_bits(ol.z));
                vec3 thi = vec3(from_ordered_bits(oh.x), from_ordered_bits(oh.y), from_ordered_bits(oh.z));
                int te = exponent_of(largest_extent(tlo, thi));
                uint bin = SIZE_BINS;
                if (te != -1000 && se != -1000) bin = uint(clamp(se - te, 0, int(SIZE_BINS) - 1));
                atomicAdd(s_hist[bin], 1u);
            }
        }
    }
    barrier();
    for (uint c = lid; c <= SIZE_BINS; c += gl_WorkGroupSize.x) {
        uint h = s_hist[c];
        if (h != 0u) atomicAdd(U32Ref(pc.hist + 4ul * c).v, h);
    }
}
