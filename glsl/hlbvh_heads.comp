#version 460
// HLBVH clusters, step 1: the first sorted position of every cluster (maximal run of equal code >> shift) is written
// to table[code >> shift]; the host fills the table with ~0 first.
#include "common.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint BITS63 = 0u;

layout(push_constant) uniform Push {
    uint64_t codes; // Address of the sorted codes.
    uint64_t table; // Address of the cluster table.
    uint64_t count; // Number of codes.
    uint shift;     // Code shift giving the cluster prefix.
    uint pad;       // Padding.
} pc;

uint64_t code_at(uint64_t i) { return BITS63 != 0u ? ld_u64(pc.codes, i) : uint64_t(ld_u32(pc.codes, i)); }

void main() {
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    for (uint64_t i = gl_GlobalInvocationID.x; i < pc.count; i += stride) {
        uint64_t p = code_at(i) >> pc.shift;
        if (i == 0ul || (code_at(i - 1ul) >> pc.shift) != p) st_u32(pc.table, p, uint(i));
    }
}
