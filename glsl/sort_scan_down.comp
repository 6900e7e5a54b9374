#version 460
// Radix sort, pass 2 (down-sweep of the reduce-then-scan): replaces the n elements of `data` by their exclusive
// prefix sum. Tile t (gl_WorkGroupSize.x * ITEMS elements) adds partials[t], the exclusive sum of the tile sums
// computed by the level above; `partials == 0` means a single tile (the top level).
#include "common.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8u;
layout(constant_id = 2) const uint MAX_SUBGROUPS = 32u;
#include "sort.glsl"

layout(push_constant) uniform Push {
    uint64_t data;     // Address of the `n` elements scanned in place.
    uint64_t partials; // Address of the scanned tile sums (0 for a single tile).
    uint64_t n;        // Number of elements.
} pc;

void main() {
    uint first, n_lanes, lane;
    subgroup_layout(first, n_lanes, lane);
    uint ordinal = first + lane;
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.n, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        // Invocation `ordinal` owns ITEMS consecutive elements, so ordinal order is element order.
        uint64_t base = uint64_t(t) * uint64_t(tile) + uint64_t(ordinal * ITEMS);
        uint sum = 0u;
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t i = base + uint64_t(j);
            if (i < pc.n) sum += ld_u32(pc.data, i);
        }
        uint total;
        uint run = workgroup_exclusive_add(sum, total);
        if (pc.partials != 0ul) run += ld_u32(pc.partials, uint64_t(t));
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t i = base + uint64_t(j);
            if (i < pc.n) {
                uint v = ld_u32(pc.data, i);
                st_u32(pc.data, i, run);
                run += v;
            }
        }
    }
}
