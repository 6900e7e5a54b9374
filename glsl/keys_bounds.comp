#version 460
// docs/spec.md steps 1-2: centroid key s = (v0 + v1) + v2 of every sampled triangle (no FMA, left to right), and the
// per-axis min and max of the keys in IEEE total order.
// keys: vec3 per sampled triangle (tightly packed f32). result: uint[6], filled by the host with ~0 x3, 0 x3.
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
    uint64_t keys;      // Address of the output keys (f32 xyz per sampled triangle).
    uint64_t result;    // Address of the `uint[6]` bounds.
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
                vec3 v0 = geometry_vertex(tri.x);
                vec3 v1 = geometry_vertex(tri.y);
                vec3 v2 = geometry_vertex(tri.z);
                precise vec3 s = (v0 + v1) + v2;
                st_vec3(pc.keys, i, s);
                uvec3 o = uvec3(ordered_bits(s.x), ordered_bits(s.y), ordered_bits(s.z));
                lo = min(lo, o);
                hi = max(hi, o);
            }
        }
    }
    reduce_bounds_to_global(lo, hi, pc.result);
}
