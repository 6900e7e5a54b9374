#version 460
// docs/spec.md steps 7-8: the class of every code and the histogram of classes.
// class(m) = number of thresholds t_j <= m - m_min, where t_j = ceil(j (m_max - m_min) / k), j = 1..k-1 (computed
// exactly on the host), which equals min(((m - m_min) k) div (m_max - m_min), k - 1) without 128-bit division.
// The histogram is privatized in shared memory and merged once per workgroup with one atomic per non-empty class.
// hist: uint[k], zeroed by the host.
#include "common.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;
layout(constant_id = 2) const uint BITS63 = 0u;
layout(constant_id = 3) const uint MAX_K = 4096u;

layout(push_constant) uniform Push {
    uint64_t codes;      // Address of the codes.
    uint64_t classes;    // Address of the output classes (u32 per code).
    uint64_t thresholds; // Address of the `k - 1` thresholds (u64).
    uint64_t hist;       // Address of the `uint[k]` histogram.
    uint64_t count;      // Number of codes.
    uint64_t code_min;   // Smallest code.
    uint k;              // Class count.
    uint pad;            // Padding.
} pc;

shared uint s_hist[MAX_K];

void main() {
    uint lid = gl_LocalInvocationIndex;
    for (uint c = lid; c < pc.k; c += gl_WorkGroupSize.x) s_hist[c] = 0u;
    barrier();
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.count, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t base = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t i = base + uint64_t(j * gl_WorkGroupSize.x);
            if (i < pc.count) {
                uint64_t m = BITS63 != 0u ? ld_u64(pc.codes, i) : uint64_t(ld_u32(pc.codes, i));
                uint64_t x = m - min(m, pc.code_min); // codes below a planned code_min clamp to class 0
                // Upper bound: first j with t_j > x.
                uint a = 0u;
                uint b = pc.k - 1u;
                while (a < b) {
                    uint mid = (a + b) >> 1;
                    if (ld_u64(pc.thresholds, mid) <= x) a = mid + 1u; else b = mid;
                }
                st_u32(pc.classes, i, a);
                atomicAdd(s_hist[a], 1u);
            }
        }
    }
    barrier();
    for (uint c = lid; c < pc.k; c += gl_WorkGroupSize.x) {
        uint h = s_hist[c];
        if (h != 0u) atomicAdd(U32Ref(pc.hist + 4ul * c).v, h);
    }
}
