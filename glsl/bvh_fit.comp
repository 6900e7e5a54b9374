#version 460
// Internal boxes bottom-up (the parallel scheme of Karras 2012): from every leaf an invocation walks up the parent
// links; at each node it increments the node's arrival counter and stops if it came first, so the second arrival,
// which finds both children final, writes the union and goes on. Nobody waits for anybody. The first arrival's box
// is made visible by a buffer memory barrier before its atomic; the second arrival's barrier after the atomic orders
// its reads of the (coherent) child boxes. counters: one zeroed uint per node; parents: BVH_NONE above a root.
#extension GL_KHR_shader_subgroup_vote : require
#include "common.glsl"
#include "bvh.glsl"

layout(local_size_x_id = 0) in;
// 1: memory barriers around the arrival counter (release before, acquire after). The host sets 0 on CPU drivers:
// Mesa 22.3's lavapipe loses walks at these barriers (counters are left unincremented), while its atomics, which
// carry every box read and write here, already execute in program order on the CPU.
layout(constant_id = 1) const uint FENCES = 1u;

layout(push_constant) uniform Push {
    uint64_t nodes;    // Address of the nodes.
    uint64_t parents;  // Address of the parent links.
    uint64_t counters; // Address of the zeroed arrival counters.
    uint64_t count;    // Number of nodes.
} pc;

layout(buffer_reference, std430, buffer_reference_align = 4) coherent buffer CoherentU32 { uint v; };

// Box corners are read and written with atomics: they are the only accesses whose visibility across workgroups
// the atomic counters can order on every driver (plain loads, even of coherent memory, may be served stale).
vec3 load_box3(uint64_t a) {
    return vec3(uintBitsToFloat(atomicOr(CoherentU32(a).v, 0u)), uintBitsToFloat(atomicOr(CoherentU32(a + 4ul).v, 0u)),
                uintBitsToFloat(atomicOr(CoherentU32(a + 8ul).v, 0u)));
}
void store_box3(uint64_t a, vec3 v) {
    atomicExchange(CoherentU32(a).v, floatBitsToUint(v.x));
    atomicExchange(CoherentU32(a + 4ul).v, floatBitsToUint(v.y));
    atomicExchange(CoherentU32(a + 8ul).v, floatBitsToUint(v.z));
}

void main() {
    // Every loop here is uniform across the subgroup (the walk's loop runs while any lane walks), so the memory
    // barriers execute in uniform control flow: lavapipe loses lanes at a barrier in divergent flow.
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    uint64_t first = uint64_t(gl_WorkGroupID.x) * uint64_t(gl_WorkGroupSize.x);
    for (uint64_t b = first; b < pc.count; b += stride) {
        uint64_t k = b + uint64_t(gl_LocalInvocationIndex);
        uint cur = BVH_NONE;
        if (k < pc.count &&
            (CoherentU32(pc.nodes + BVH_NODE_BYTES * k + BVH_NODE_RIGHT_OR_COUNT).v & BVH_LEAF_FLAG) != 0u) {
            cur = CoherentU32(pc.parents + 4ul * k).v;
        }
        bool walking = cur != BVH_NONE;
        while (subgroupAny(walking)) {
            if (FENCES != 0u) memoryBarrierBuffer(); // release: the box this lane wrote is visible before its arrival is counted
            uint before = 0u;
            if (walking) before = atomicAdd(CoherentU32(pc.counters + 4ul * uint64_t(cur)).v, 1u);
            if (FENCES != 0u) memoryBarrierBuffer(); // acquire: the second arrival sees the first one's box
            if (walking) {
                if (before == 0u) {
                    walking = false;
                } else {
                    uint64_t pa = pc.nodes + BVH_NODE_BYTES * uint64_t(cur);
                    uint64_t la = pc.nodes + BVH_NODE_BYTES * uint64_t(CoherentU32(pa + BVH_NODE_LEFT_OR_FIRST).v);
                    uint64_t ra = pc.nodes + BVH_NODE_BYTES * uint64_t(CoherentU32(pa + BVH_NODE_RIGHT_OR_COUNT).v);
                    store_box3(pa, min(load_box3(la), load_box3(ra))); // BVH_NODE_MIN is 0
                    store_box3(pa + BVH_NODE_MAX, max(load_box3(la + BVH_NODE_MAX), load_box3(ra + BVH_NODE_MAX)));
                    cur = CoherentU32(pc.parents + 4ul * uint64_t(cur)).v;
                    walking = cur != BVH_NONE;
                }
            }
        }
    }
}
