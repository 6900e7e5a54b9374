#version 460
// SAH leaf collapse, step 1 (src/accel/lbvh.rs, step 7 of the module docs): bottom-up over a tree whose leaves hold
// one record each, with the arrival-counter scheme of bvh_fit.comp (nobody waits). For every node it writes the
// collapse record info[k] = (first, end, count, cost bits, size, collapse, 0, 0) (the COLLAPSE_* fields of
// include/layout.glsl): the record range of its subtree (lowest first, highest end, number of records), its best
// cost in half-area units (K_T = K_I = 1), the nodes its subtree keeps after the collapse, and whether it becomes a
// leaf. A node collapses when its records are contiguious (end - first == count), count <= MAX_LEAF and the leaf
// cost h * count is at most the split cost (h + cost_left) + cost_right. The arithmetic is `precise` (no fused
// multiply-add) and flushes subnormal results to zero, so the host reference computes the same floats. counters:
// one zeroed uint per node.
#extension GL_KHR_shader_subgroup_vote : require
#include "common.glsl"
#include "bvh.glsl"
#include "layout.glsl"

layout(local_size_x_id = 0) in;
// See bvh_fit.comp: 0 on CPU drivers.
layout(constant_id = 1) const uint FENCES = 1u;

layout(push_constant) uniform Push {
    uint64_t nodes;    // Address of the nodes.
    uint64_t parents;  // Address of the parent links.
    uint64_t counters; // Address of the zeroed arrival counters.
    uint64_t info;     // Address of the per-node collapse records (`COLLAPSE_*` of include/layout.glsl).
    uint64_t count;    // Number of nodes.
    uint max_leaf;     // Largest leaf the collapse forms.
    uint pad;          // Padding.
} pc;

layout(buffer_reference, std430, buffer_reference_align = 4) coherent buffer CoherentU32 { uint v; };

uint ld_c(uint64_t a) { return atomicOr(CoherentU32(a).v, 0u); }
void st_c(uint64_t a, uint x) { atomicExchange(CoherentU32(a).v, x); }

float flush_subnormal(float x) { return x < 1.17549435e-38 ? 0.0 : x; }

// (e.x e.y + e.y e.z) + e.z e.x with e = hi - lo, as collapse_half_area in src/accel/lbvh.rs.
float half_area(uint k) {
    BvhNodeRef r = bvh_node(pc.nodes, k);
    vec3 lo = r.node.min;
    vec3 hi = r.node.max;
    precise float ex = flush_subnormal(hi.x - lo.x);
    precise float ey = flush_subnormal(hi.y - lo.y);
    precise float ez = flush_subnormal(hi.z - lo.z);
    precise float xy = flush_subnormal(ex * ey);
    precise float yz = flush_subnormal(ey * ez);
    precise float zx = flush_subnormal(ez * ex);
    precise float h = (xy + yz) + zx;
    return h;
}

void store_info(uint k, uint first, uint end, uint count, float cost, uint size, uint collapse) {
    uint64_t a = pc.info + 4ul * COLLAPSE_WORDS * uint64_t(k);
    st_c(a, first); // COLLAPSE_FIRST is 0
    st_c(a + 4ul * COLLAPSE_END, end);
    st_c(a + 4ul * COLLAPSE_COUNT, count);
    st_c(a + 4ul * COLLAPSE_COST, floatBitsToUint(cost));
    st_c(a + 4ul * COLLAPSE_SIZE, size);
    st_c(a + 4ul * COLLAPSE_LEAF, collapse);
}

void main() {
    // As in bvh_fit.comp, the walk's loop is uniform across the subgroup so that the barriers are too.
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    uint64_t first_k = uint64_t(gl_WorkGroupID.x) * uint64_t(gl_WorkGroupSize.x);
    for (uint64_t b = first_k; b < pc.count; b += stride) {
        uint64_t k = b + uint64_t(gl_LocalInvocationIndex);
        uint cur = BVH_NONE;
        if (k < pc.count) {
            BvhNodeRef r = bvh_node(pc.nodes, uint(k));
            uint rc = r.node.right_or_count;
            if ((rc & BVH_LEAF_FLAG) != 0u) {
                uint n = rc & ~BVH_LEAF_FLAG;
                uint f = r.node.left_or_first;
                precise float cost = half_area(uint(k)) * float(n);
                store_info(uint(k), f, f + n, n, cost, 1u, 0u);
                cur = ld_u32(pc.parents, k);
            }
        }
        bool walking = cur != BVH_NONE;
        while (subgroupAny(walking)) {
            if (FENCES != 0u) memoryBarrierBuffer();
            uint before = 0u;
            if (walking) before = atomicAdd(CoherentU32(pc.counters + 4ul * uint64_t(cur)).v, 1u);
            if (FENCES != 0u) memoryBarrierBuffer();
            if (walking) {
                if (before == 0u) {
                    walking = false;
                } else {
                    BvhNodeRef r = bvh_node(pc.nodes, cur);
                    uint64_t la = pc.info + 4ul * COLLAPSE_WORDS * uint64_t(r.node.left_or_first);
                    uint64_t ra = pc.info + 4ul * COLLAPSE_WORDS * uint64_t(r.node.right_or_count);
                    uint first = min(ld_c(la), ld_c(ra)); // COLLAPSE_FIRST is 0
                    uint end = max(ld_c(la + 4ul * COLLAPSE_END), ld_c(ra + 4ul * COLLAPSE_END));
                    uint count = ld_c(la + 4ul * COLLAPSE_COUNT) + ld_c(ra + 4ul * COLLAPSE_COUNT);
                    float cl = uintBitsToFloat(ld_c(la + 4ul * COLLAPSE_COST));
                    float cr = uintBitsToFloat(ld_c(ra + 4ul * COLLAPSE_COST));
                    uint size = 1u + ld_c(la + 4ul * COLLAPSE_SIZE) + ld_c(ra + 4ul * COLLAPSE_SIZE);
                    precise float h = half_area(cur);
                    precise float split = (h + cl) + cr;
                    precise float leaf = h * float(count);
                    bool collapse = count <= pc.max_leaf && end - first == count && leaf <= split;
                    store_info(cur, first, end, count, collapse ? leaf : split, collapse ? 1u : size, collapse ? 1u : 0u);
                    cur = ld_u32(pc.parents, uint64_t(cur));
                    walking = cur != BVH_NONE;
                }
            }
        }
    }
}
