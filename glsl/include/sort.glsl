// Shared GLSL of the radix-sort kernels: the order in which a workgroup's invocations take their work, and a
// workgroup-wide exclusive sum in that order.
//
// The Vulkan specification does not tie gl_LocalInvocationIndex to (gl_SubgroupID, gl_SubgroupInvocationID), nor
// promise that every subgroup is full. The sort kernels therefore never assume either: an invocation's *ordinal* is
// the number of active invocations in lower subgroups plus its rank among the active lanes of its own subgroup, so
// ordinals are 0 .. gl_WorkGroupSize.x - 1 in (subgroup, lane) order whatever the subgroup size (4 to 128) and
// however the driver fills subgroups. Subgroup operations (ballots, inclusive sums) follow the same lane order, which
// is what makes the ranks stable.
//
// The including shader declares `MAX_SUBGROUPS` (a specialization constant: the most subgroups a workgroup can have,
// gl_WorkGroupSize.x divided by the device's smallest subgroup size, rounded up) before including this file. That
// bound is the one assumption on the driver: gl_NumSubgroups <= MAX_SUBGROUPS, i.e. no subgroup holds fewer lanes
// than minSubgroupSize except for a remainder. lavapipe breaks it only when LP_NATIVE_VECTOR_WIDTH exceeds the 512 bits
// it can execute (see tests/gpu_sort.rs).
#extension GL_KHR_shader_subgroup_shuffle : require

shared uint s_subgroup_n[MAX_SUBGROUPS];

// Layout of this invocation's subgroup: `first` is the ordinal of its first lane, `n` its active lanes, `lane` this
// invocation's rank among them. Contains a workgroup barrier: call once, from uniform control flow.
void subgroup_layout(out uint first, out uint n, out uint lane) {
    uvec4 lanes = subgroupBallot(true);
    n = subgroupBallotBitCount(lanes);
    lane = subgroupBallotExclusiveBitCount(lanes);
    if (subgroupElect()) s_subgroup_n[gl_SubgroupID] = n;
    barrier();
    first = 0u;
    for (uint s = 0u; s < gl_SubgroupID; ++s) first += s_subgroup_n[s];
}

shared uint s_subgroup_sum[MAX_SUBGROUPS];

// Exclusive sum of `x` over the workgroup in ordinal order; `total` receives the sum of all. Two workgroup barriers:
// call from uniform control flow.
uint workgroup_exclusive_add(uint x, out uint total) {
    uint inclusive = subgroupInclusiveAdd(x);
    uint sum = subgroupAdd(x);
    if (subgroupElect()) s_subgroup_sum[gl_SubgroupID] = sum;
    barrier();
    uint before = 0u;
    total = 0u;
    for (uint s = 0u; s < gl_NumSubgroups; ++s) {
        uint v = s_subgroup_sum[s];
        before += s < gl_SubgroupID ? v : 0u;
        total += v;
    }
    barrier();
    return before + inclusive - x;
}

// Sum of `x` over the workgroup, valid in every invocation. Two workgroup barriers: call from uniform control flow.
uint workgroup_add(uint x) {
    uint total;
    workgroup_exclusive_add(x, total);
    return total;
}

// The lanes of this subgroup whose `digit` (8 bits) equals this lane's, among the lanes where `valid` holds: eight
// ballots, one per bit. uvec4 ballots cover subgroups of up to 128 lanes.
uvec4 match_digit(uint digit, bool valid) {
    uvec4 peers = subgroupBallot(valid);
    for (uint b = 0u; b < 8u; ++b) {
        bool bit = ((digit >> b) & 1u) != 0u;
        uvec4 m = subgroupBallot(bit);
        peers &= bit ? m : ~m;
    }
    return peers;
}
