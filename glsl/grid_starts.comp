#version 460
// Device grid builder (src/accel/gpu_grid.rs), one invocation per cell boundary: after the stable sort of the
// (cell, triangle) pairs by cell, starts[c] (c = 0 ..= cells) is the first sorted position whose cell is at least c
// (a binary search over the `total` sorted keys), so cell c's triangles are payload[starts[c] .. starts[c + 1]], in
// triangle order (a search takes at most 33 steps, far below any driver's loop limit). Does nothing when the
// reference total (info word 0) exceeds `limit`.
#include "common.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t keys;   // Address of the sorted keys (cells).
    uint64_t starts; // Address of the cell starts (u32, cells + 1).
    uint64_t info;   // Address of the build's info: the reference total (u64), then the cut-loop flag (u32).
    uint64_t cells;  // Cells.
    uint64_t limit;  // Largest total to work on.
} pc;

void main() {
    uint64_t total = ld_u64(pc.info, 0ul);
    if (total > pc.limit) return;
    uint tile = gl_WorkGroupSize.x;
    uint tiles = tile_count(pc.cells + 1ul, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t c = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        if (c > pc.cells) continue;
        uint64_t lo = 0ul;
        uint64_t hi = total;
        for (uint step = 0u; step < 64u && lo < hi; ++step) {
            uint64_t mid = lo + (hi - lo) / 2ul;
            if (uint64_t(ld_u32(pc.keys, mid)) < c) {
                lo = mid + 1ul;
            } else {
                hi = mid;
            }
        }
        st_u32(pc.starts, c, uint(lo));
    }
}
