#version 460
// Radix sort, pass 2 (up-sweep of the reduce-then-scan): the sum of every tile of `tile = gl_WorkGroupSize.x * ITEMS`
// elements of `src` (n elements) goes to dst[tile index]. The host recurses on dst until one tile remains; no
// workgroup ever waits for another.
#include "common.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8u;
layout(constant_id = 2) const uint MAX_SUBGROUPS = 32u;
#include "sort.glsl"

layout(push_constant) uniform Push {
    uint64_t src; // Address of the `n` input elements.
    uint64_t dst; // Address of the tile sums.
    uint64_t n;   // Number of input elements.
} pc;

void main() {
    uint lid = gl_LocalInvocationIndex;
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.n, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t base = uint64_t(t) * uint64_t(tile) + lid;
        uint sum = 0u;
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t i = base + uint64_t(j * gl_WorkGroupSize.x);
            if (i < pc.n) sum += ld_u32(pc.src, i);
        }
        sum = workgroup_add(sum);
        if (lid == 0u) st_u32(pc.dst, uint64_t(t), sum);
    }
}
