// Layouts that kernels and host code share beyond the push constants: the record of the SAH leaf collapse and the
// slots of the small result buffers. The host reads these names from `gpu::shaders::layout`, generated from this
// file by build.rs (every integer #define here and in bvh.glsl becomes a Rust constant of the same name and type:
// `u` is u32, `ul` u64). Where an offset is 0, kernels write the bare base address (`a`, not `a + 4ul * X`):
// adding a zero constant would change the SPIR-V.
#ifndef MESHCHAR_LAYOUT_GLSL
#define MESHCHAR_LAYOUT_GLSL

// Collapse record, written by bvh_collapse_cost.comp and read by bvh_compact.comp: COLLAPSE_WORDS uints per node,
// with these fields (uint indices).
#define COLLAPSE_FIRST 0u  // Collapse record: first record of the subtree (the lowest).
#define COLLAPSE_END 1u    // Collapse record: end of the subtree's records (the highest first + count).
#define COLLAPSE_COUNT 2u  // Collapse record: number of records of the subtree.
#define COLLAPSE_COST 3u   // Collapse record: bits of the subtree's best SAH cost (half-area units, K_T = K_I = 1).
#define COLLAPSE_SIZE 4u   // Collapse record: nodes the subtree keeps after the collapse.
#define COLLAPSE_LEAF 5u   // Collapse record: 1 when the node becomes a leaf, 0 otherwise.
#define COLLAPSE_WORDS 8u  // Collapse record: uints per node (the last two unused).

// Bounds result of include/bounds.glsl (bounds.comp, keys_bounds.comp, features_bounds.comp; read by features.comp):
// BOUNDS_WORDS uints, the ordered bits of the lower corner xyz, then of the upper corner xyz.
#define BOUNDS_LO 0u     // Bounds result: uint index of the lower corner's x (y, z follow).
#define BOUNDS_HI 3u     // Bounds result: uint index of the upper corner's x (y, z follow).
#define BOUNDS_WORDS 6u  // Bounds result: uints in all.

// Result of morton_moments.comp: uint64_t words, the smallest and largest code, then the NLIMBS limbs of the exact
// power sums S1, S2, S3 (include/wide.glsl).
#define MOMENTS_CODE_MIN 0u  // Moments result: uint64_t index of the smallest code.
#define MOMENTS_CODE_MAX 1u  // Moments result: uint64_t index of the largest code.
#define MOMENTS_LIMBS 2u     // Moments result: uint64_t index of the first of the NLIMBS limbs (S1, S2, S3).

// Result of chi_square.comp: CHI_WORDS uint64_t words.
#define CHI_T_LO 0ul                    // Chi-square result: low word of the numerator T = sum (k O_i - n)^2.
#define CHI_T_HI 1ul                    // Chi-square result: high word of T.
#define CHI_EMPTY 2ul                   // Chi-square result: classes with no triangle.
#define CHI_CONCENTRATED 3ul            // Chi-square result: classes with k O_i > n.
#define CHI_CONCENTRATED_TRIANGLES 4ul  // Chi-square result: triangles in concentrated classes.
#define CHI_WORDS 5ul                   // Chi-square result: uint64_t words in all.

#endif
