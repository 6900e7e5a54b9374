#version 460
// LBVH step 1 on the device: the Morton code of every centroid key (docs/spec.md steps 3-4, the same quantization as
// morton_moments.comp) and the identity payload, ready for the stable radix sort (which yields the (code, index)
// order). codes: u32 (30-bit) or u64 (63-bit); ids: u32.
#include "common.glsl"
#include "morton.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;
layout(constant_id = 2) const uint BITS63 = 0u;

layout(push_constant) uniform Push {
    uint64_t keys;  // Address of the keys (f32 xyz).
    uint64_t codes; // Address of the output codes.
    uint64_t ids;   // Address of the output ids.
    uint64_t count; // Number of keys.
    float lo_x;     // `lo.x`.
    float lo_y;     // `lo.y`.
    float lo_z;     // `lo.z`.
    float scale_x;  // `scale.x`.
    float scale_y;  // `scale.y`.
    float scale_z;  // `scale.z`.
} pc;

void main() {
    const float top = BITS63 != 0u ? 2097151.0 : 1023.0;
    vec3 lo = vec3(pc.lo_x, pc.lo_y, pc.lo_z);
    vec3 scale = vec3(pc.scale_x, pc.scale_y, pc.scale_z);
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.count, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t base = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t i = base + uint64_t(j * gl_WorkGroupSize.x);
            if (i < pc.count) {
                vec3 s = ld_vec3(pc.keys, i);
                precise vec3 d = (s - lo) * scale;
                uvec3 q = uvec3(clamp(floor(d), vec3(0.0), vec3(top))); // below 0 only for a planned quantizer
                if (BITS63 != 0u) {
                    st_u64(pc.codes, i, morton63(q));
                } else {
                    st_u32(pc.codes, i, morton30(q));
                }
                st_u32(pc.ids, i, uint(i));
            }
        }
    }
}
