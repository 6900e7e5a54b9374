#version 460
// docs/spec.md steps 1-2: centroid key s = (v0 + v1) + v2 of every sampled triangle (no FMA, left to right), and the
// per-axis min and max of the keys in IEEE total order.
// keys: vec3 per sampled triangle (tightly packed f32). result: uint[6], filled by the host with ~0 x3, 0 x3.
#include "common.glsl"
#include "bounds.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;

layout(push_constant) uniform Push {
    uint64_t positions; // Address of the vertex positions (f32 xyz).
    uint64_t indices;   // Address of the triangle indices (u32 triples).
    uint64_t keys;      // Address of the output keys (f32 xyz per sampled triangle).
    uint64_t result;    // Address of the `uint[6]` bounds.
    uint64_t count;     // Sampled triangles.
    uint64_t stride;    // Sample stride.
} pc;

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
                uvec3 tri = ld_uvec3(pc.indices, i * pc.stride);
                vec3 v0 = ld_vec3(pc.positions, tri.x);
                vec3 v1 = ld_vec3(pc.positions, tri.y);
                vec3 v2 = ld_vec3(pc.positions, tri.z);
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
