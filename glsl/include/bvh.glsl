// The BVH node shared by the host (src/accel/bvh.rs, BvhNode: #[repr(C)], 32 bytes) and the kernels. Engines that
// traverse the crate's BVHs in their own shaders can include this file as is. std430 places the members at the same
// byte offsets as the Rust struct (a test compares them through reflection):
//   0  vec3 min            box lower corner
//   12 uint left_or_first  internal: left child node; leaf: first triangle record
//   16 vec3 max            box upper corner
//   28 uint right_or_count internal: right child node (bit 31 clear); leaf: BVH_LEAF_FLAG | record count
// The root is node 0. Record r of a leaf is triangle ids[r] of the mesh. A leaf may hold several records (the
// binned-SAH BVH, and the LBVH/HLBVH after their SAH leaf collapse: up to max_leaf, 8 by default for the HLBVH):
// loop over first .. first + count.
struct BvhNode {
    vec3 min;
    uint left_or_first;
    vec3 max;
    uint right_or_count;
};

#define BVH_LEAF_FLAG 0x80000000u
#define BVH_NONE 0xffffffffu

// `coherent`: the bottom-up fit reads boxes that other invocations wrote during the same dispatch.
layout(buffer_reference, std430, buffer_reference_align = 16) coherent buffer BvhNodeRef { BvhNode node; };

BvhNodeRef bvh_node(uint64_t nodes, uint k) { return BvhNodeRef(nodes + 32ul * uint64_t(k)); }
