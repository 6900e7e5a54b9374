#version 460
// HLBVH clusters, step 2, one workgroup: numbers the present table entries in prefix order. Writes
// starts = [C, s_0, s_1, ..., s_{C-1}, n], replaces each present table entry by its cluster index, and zeroes the
// C - 1 top nodes (filled later by the host's SAH over the clusters).
#include "common.glsl"
#include "bvh.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t table;   // Address of the cluster table.
    uint64_t starts;  // Address of the starts (`C`, the starts, `n`).
    uint64_t nodes;   // Address of the nodes.
    uint64_t entries; // Entries of the table.
    uint count;       // Number of positions.
    uint pad;         // Padding.
} pc;

shared uint s_count[1024];
shared uint s_total;

void main() {
    uint lid = gl_LocalInvocationIndex;
    uint w = gl_WorkGroupSize.x;
    uint64_t chunk = (pc.entries + uint64_t(w) - 1ul) / uint64_t(w);
    uint64_t b = uint64_t(lid) * chunk;
    uint64_t e = min(b + chunk, pc.entries);
    uint c = 0u;
    for (uint64_t p = b; p < e; ++p) {
        if (ld_u32(pc.table, p) != 0xffffffffu) ++c;
    }
    s_count[lid] = c;
    barrier();
    if (lid == 0u) {
        uint acc = 0u;
        for (uint k = 0u; k < w; ++k) {
            uint x = s_count[k];
            s_count[k] = acc;
            acc += x;
        }
        s_total = acc;
        st_u32(pc.starts, 0ul, acc);
        st_u32(pc.starts, 1ul + uint64_t(acc), pc.count);
    }
    barrier();
    c = s_count[lid];
    for (uint64_t p = b; p < e; ++p) {
        uint s = ld_u32(pc.table, p);
        if (s != 0xffffffffu) {
            st_u32(pc.starts, 1ul + uint64_t(c), s);
            st_u32(pc.table, p, c);
            ++c;
        }
    }
    uint top = s_total - 1u;
    for (uint k = lid; k < top; k += w) {
        BvhNodeRef r = bvh_node(pc.nodes, k);
        r.node.min = vec3(0.0);
        r.node.left_or_first = 0u;
        r.node.max = vec3(0.0);
        r.node.right_or_count = 0u;
    }
}
