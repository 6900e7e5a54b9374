#version 460
// Radix sort, pass 1 of 3 per digit: the 256-bin histogram of one 8-bit digit in each block of keys.
// Block b holds keys [b * block_keys, min((b + 1) * block_keys, count)); its histogram goes to
// counts[digit * blocks + b] (digit-major, so that one exclusive sum of the whole array gives every block's first
// output position for every digit). Workgroups loop over blocks, so any number of blocks is covered.
#include "common.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint KEY64 = 0u;

layout(push_constant) uniform Push {
    uint64_t keys;   // Address of the keys.
    uint64_t counts; // Address of the `uint[256 * blocks]` counts.
    uint64_t count;  // Number of keys.
    uint blocks;     // Number of blocks.
    uint block_keys; // Keys per block.
    uint shift;      // Bit offset of the digit.
    uint pad;        // Padding.
} pc;

shared uint s_hist[256];

void main() {
    uint lid = gl_LocalInvocationIndex;
    for (uint b = gl_WorkGroupID.x; b < pc.blocks; b += gl_NumWorkGroups.x) {
        for (uint d = lid; d < 256u; d += gl_WorkGroupSize.x) s_hist[d] = 0u;
        barrier();
        uint64_t start = uint64_t(b) * uint64_t(pc.block_keys);
        uint64_t end = min(start + uint64_t(pc.block_keys), pc.count);
        for (uint64_t i = start + lid; i < end; i += gl_WorkGroupSize.x) {
            uint64_t key = KEY64 != 0u ? ld_u64(pc.keys, i) : uint64_t(ld_u32(pc.keys, i));
            atomicAdd(s_hist[uint(key >> pc.shift) & 0xffu], 1u);
        }
        barrier();
        for (uint d = lid; d < 256u; d += gl_WorkGroupSize.x) {
            st_u32(pc.counts, uint64_t(d) * uint64_t(pc.blocks) + uint64_t(b), s_hist[d]);
        }
        barrier();
    }
}
