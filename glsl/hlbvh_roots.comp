#version 460
// HLBVH clusters, step 3: gathers every cluster's root node (node C - 1 + 2 s_c - c) into roots[c], for the host's
// SAH over the clusters.
#include "common.glsl"
#include "bvh.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t starts; // Address of the starts.
    uint64_t nodes;  // Address of the nodes.
    uint64_t roots;  // Address of the gathered roots.
    uint64_t limit;  // Largest cluster count the roots buffer holds.
} pc;

void main() {
    uint clusters = ld_u32(pc.starts, 0ul);
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    for (uint64_t c = gl_GlobalInvocationID.x; c < min(pc.limit, uint64_t(clusters)); c += stride) {
        uint s = ld_u32(pc.starts, 1ul + c);
        uint root = clusters - 1u + 2u * s - uint(c);
        BvhNodeRef src = bvh_node(pc.nodes, root);
        BvhNodeRef dst = bvh_node(pc.roots, uint(c));
        dst.node = src.node;
    }
}
