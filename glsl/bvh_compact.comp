#version 460
// SAH leaf collapse, step 2: writes the surviving nodes in depth-first order (a node's left child right after it,
// its right child after the left subtree). Every node walks up to the root through the parent links, summing its
// depth-first index (1 for a left child, 1 + size(left sibling) for a right child) and dying if an ancestor
// collapsed; no invocation depends on another. A collapsed node becomes the leaf of its record range. Also writes
// the new parent links (BVH_NONE for the root), for refit.
#include "common.glsl"
#include "bvh.glsl"
#include "layout.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t nodes;       // Address of the nodes before the collapse.
    uint64_t parents;     // Address of their parent links.
    uint64_t info;        // Address of the per-node results of the cost pass.
    uint64_t out_nodes;   // Address of the output nodes.
    uint64_t out_parents; // Address of the output parent links.
    uint64_t count;       // Number of nodes before the collapse.
} pc;

// Field `field` (COLLAPSE_*) of node k's collapse record.
uint info_at(uint k, uint field) { return ld_u32(pc.info, uint64_t(COLLAPSE_WORDS) * uint64_t(k) + uint64_t(field)); }

void main() {
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    for (uint64_t k = gl_GlobalInvocationID.x; k < pc.count; k += stride) {
        uint idx = 0u;
        uint up = BVH_NONE; // the parent's offset from this node, once known
        bool alive = true;
        uint c = uint(k);
        uint p = ld_u32(pc.parents, k);
        while (p != BVH_NONE) {
            if (info_at(p, COLLAPSE_LEAF) != 0u) {
                alive = false;
                break;
            }
            uint l = bvh_node(pc.nodes, p).node.left_or_first;
            uint d = c == l ? 1u : 1u + info_at(l, COLLAPSE_SIZE);
            if (up == BVH_NONE) up = d;
            idx += d;
            c = p;
            p = ld_u32(pc.parents, uint64_t(p));
        }
        if (!alive) continue;
        BvhNodeRef src = bvh_node(pc.nodes, uint(k));
        BvhNodeRef dst = bvh_node(pc.out_nodes, idx);
        dst.node.min = src.node.min;
        dst.node.max = src.node.max;
        uint rc = src.node.right_or_count;
        if ((rc & BVH_LEAF_FLAG) != 0u || info_at(uint(k), COLLAPSE_LEAF) != 0u) {
            dst.node.left_or_first = info_at(uint(k), COLLAPSE_FIRST);
            dst.node.right_or_count = BVH_LEAF_FLAG | info_at(uint(k), COLLAPSE_COUNT);
        } else {
            uint l = src.node.left_or_first;
            dst.node.left_or_first = idx + 1u;
            dst.node.right_or_count = idx + 1u + info_at(l, COLLAPSE_SIZE);
        }
        st_u32(pc.out_parents, uint64_t(idx), up == BVH_NONE ? BVH_NONE : idx - up);
    }
}
