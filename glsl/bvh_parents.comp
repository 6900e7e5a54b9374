#version 460
// Parent links of nodes 0 .. count-1 of a BVH in the crate's layout: parents[child] = node for both children of
// every internal node among them (the HLBVH's top nodes, built on the host, so that refit walks through them).
#include "common.glsl"
#include "bvh.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t nodes;   // Address of the nodes.
    uint64_t parents; // Address of the parent links.
    uint64_t count;   // Nodes whose children get links.
} pc;

void main() {
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    for (uint64_t k = gl_GlobalInvocationID.x; k < pc.count; k += stride) {
        BvhNodeRef r = bvh_node(pc.nodes, uint(k));
        uint rc = r.node.right_or_count;
        if ((rc & BVH_LEAF_FLAG) != 0u) continue;
        st_u32(pc.parents, uint64_t(r.node.left_or_first), uint(k));
        st_u32(pc.parents, uint64_t(rc), uint(k));
    }
}
