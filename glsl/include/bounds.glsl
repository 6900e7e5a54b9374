// Workgroup reduction of per-invocation bounds (in ordered-bit form) into a global uint[BOUNDS_WORDS] (min xyz at
// BOUNDS_LO, max xyz at BOUNDS_HI; include/layout.glsl) with one atomic per value per workgroup: subgroup min/max,
// then shared-memory atomics across subgroups. Correct for any subgroup size and any number of subgroups per
// workgroup. Call from uniform control flow.
#include "layout.glsl"

shared uint s_bounds[6];

void reduce_bounds_to_global(uvec3 lo, uvec3 hi, uint64_t result) {
    if (gl_LocalInvocationIndex == 0u) {
        s_bounds[0] = 0xffffffffu; s_bounds[1] = 0xffffffffu; s_bounds[2] = 0xffffffffu;
        s_bounds[3] = 0u; s_bounds[4] = 0u; s_bounds[5] = 0u;
    }
    barrier();
    uvec3 slo = uvec3(subgroupMin(lo.x), subgroupMin(lo.y), subgroupMin(lo.z));
    uvec3 shi = uvec3(subgroupMax(hi.x), subgroupMax(hi.y), subgroupMax(hi.z));
    if (subgroupElect()) {
        atomicMin(s_bounds[0], slo.x); atomicMin(s_bounds[1], slo.y); atomicMin(s_bounds[2], slo.z);
        atomicMax(s_bounds[3], shi.x); atomicMax(s_bounds[4], shi.y); atomicMax(s_bounds[5], shi.z);
    }
    barrier();
    if (gl_LocalInvocationIndex < 3u) {
        uint a = gl_LocalInvocationIndex;
        if (s_bounds[a] != 0xffffffffu) atomicMin(U32Ref(result + 4ul * a).v, s_bounds[a]); // BOUNDS_LO is 0
        if (s_bounds[3u + a] != 0u) atomicMax(U32Ref(result + 4ul * (BOUNDS_HI + a)).v, s_bounds[3u + a]);
    }
}
