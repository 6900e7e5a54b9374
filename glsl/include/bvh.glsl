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
    vec3 min;            // Lower corner of the box.
    uint left_or_first;  // Left child (internal) or first triangle record (leaf).
    vec3 max;            // Upper corner of the box.
    uint right_or_count; // Right child (internal) or `BVH_LEAF_FLAG | count` (leaf).
};

#define BVH_LEAF_FLAG 0x80000000u // Bit 31 of `right_or_count` marks a leaf.
#define BVH_NONE 0xffffffffu      // No node: the parent link of a root.

// Byte offsets of the members of BvhNode and its size, for address arithmetic (the build checks them against the
// reflected struct, and the Rust mirror against them).
#define BVH_NODE_MIN 0ul             // BvhNode: byte offset of `min`.
#define BVH_NODE_LEFT_OR_FIRST 12ul  // BvhNode: byte offset of `left_or_first`.
#define BVH_NODE_MAX 16ul            // BvhNode: byte offset of `max`.
#define BVH_NODE_RIGHT_OR_COUNT 28ul // BvhNode: byte offset of `right_or_count`.
#define BVH_NODE_BYTES 32ul          // BvhNode: size in bytes.

// `coherent`: the bottom-up fit reads boxes that other invocations wrote during the same dispatch.
layout(buffer_reference, std430, buffer_reference_align = 16) coherent buffer BvhNodeRef { BvhNode node; };

BvhNodeRef bvh_node(uint64_t nodes, uint k) { return BvhNodeRef(nodes + BVH_NODE_BYTES * uint64_t(k)); }
