#version 460
// Per-axis min and max of a point set (tightly packed f32 xyz), reduced in IEEE total order.
// result: uint[6] = ordered bits of min x, y, z, max x, y, z; the host fills it with 0xffffffff x3, 0 x3 first.
#include "common.glsl"
#include "bounds.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;

layout(push_constant) uniform Push {
    uint64_t points; // Device address of `count` tightly packed f32 xyz points.
    uint64_t result; // Device address of the `uint[6]` result (ordered bits of min xyz, max xyz).
    uint64_t count;  // Number of points.
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
                vec3 p = ld_vec3(pc.points, i);
                uvec3 o = uvec3(ordered_bits(p.x), ordered_bits(p.y), ordered_bits(p.z));
                lo = min(lo, o);
                hi = max(hi, o);
            }
        }
    }
    reduce_bounds_to_global(lo, hi, pc.result);
}
