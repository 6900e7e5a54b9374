#version 460
// Scene features, pass 1: per-axis min and max (IEEE total order) of the vertices of every sampled triangle: the
// vertex bounds whose largest extent scales the triangle-size histogram (see src/characterize/features.rs).
// result: uint[6] in ordered-bit form, filled by the host with ~0 x3, 0 x3.
#include "common.glsl"
#include "bounds.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;

layout(push_constant) uniform Push {
    uint64_t positions;    // Address of the position of vertex 0 (include/geometry.glsl).
    uint64_t indices;      // Address of the first index (include/geometry.glsl).
    uint64_t vertex_count; // Vertices of the view (include/geometry.glsl).
    uint vertex_stride;    // Bytes between vertices (include/geometry.glsl).
    uint index_type;       // GEOMETRY_INDEX_* (include/geometry.glsl).
    uint base_vertex;      // Added to every index (include/geometry.glsl).
    uint geometry_pad;     // Padding.
    uint64_t result;    // Address of the `uint[6]` bounds (ordered bits).
    uint64_t count;     // Sampled triangles.
    uint64_t stride;    // Sample stride.
} pc;

#include "geometry.glsl"

void main() {
    uvec3 lo = uvec3(0xffffffffu);
    uvec3 hi = uvec3(0u);
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.count, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t base = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t i = base + uint64_t(j * gl_WorkGroupSize.x);
            if (i < pc.count) {
                u64vec3 tri = geometry_triangle(i * pc.stride);
                for (uint v = 0u; v < 3u; ++v) {
                    vec3 p = geometry_vertex(tri[v]);
                    uvec3 o = uvec3(ordered_bits(p.x), ordered_bits(p.y), ordered_bits(p.z));
                    lo = min(lo, o);
                    hi = max(hi, o);
                }
            }
        }
    }
    reduce_bounds_to_global(lo, hi, pc.result);
}
