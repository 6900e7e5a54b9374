#version 460
// docs/spec.md steps 3-5 on the device: quantize each key (f32, no division, no FMA), its Morton code (30 or 63 bits), the
// smallest and largest code, and the exact sums of m, m^2, m^3 in 24-bit limbs (see wide.glsl).
// result: uint64[2 + NLIMBS] = min code, max code, limbs of S1, S2, S3; the host fills it with ~0, 0, 0 ... first.
#include "common.glsl"
#include "morton.glsl"
#include "wide.glsl"
#include "layout.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;
layout(constant_id = 2) const uint BITS63 = 0u;

layout(push_constant) uniform Push {
    uint64_t keys;   // Address of the keys.
    uint64_t codes;  // Address of the output codes (u32 for 30-bit, u64 for 63-bit codes).
    uint64_t result; // Address of the `uint64[2 + 21]` result.
    uint64_t count;  // Number of keys.
    float lo_x;      // `lo.x`.
    float lo_y;      // `lo.y`.
    float lo_z;      // `lo.z`.
    float scale_x;   // `scale.x`.
    float scale_y;   // `scale.y`.
    float scale_z;   // `scale.z`.
} pc;

// Room for 64 subgroups per workgroup (the host keeps workgroup size / smallest subgroup size <= 64).
shared uint s_limbs[NLIMBS][64];
shared uint64_t s_min[64];
shared uint64_t s_max[64];

void main() {
    const float top = BITS63 != 0u ? 2097151.0 : 1023.0;
    vec3 lo = vec3(pc.lo_x, pc.lo_y, pc.lo_z);
    vec3 scale = vec3(pc.scale_x, pc.scale_y, pc.scale_z);
    Wide w;
    wide_clear(w);
    uint64_t cmin = 0xfffffffffffffffful;
    uint64_t cmax = 0ul;
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
                uint64_t m;
                if (BITS63 != 0u) {
                    m = morton63(q);
                    st_u64(pc.codes, i, m);
                } else {
                    uint m32 = morton30(q);
                    st_u32(pc.codes, i, m32);
                    m = uint64_t(m32);
                }
                cmin = min(cmin, m);
                cmax = max(cmax, m);
                wide_add(w, m);
            }
        }
        wide_normalize(w);
    }

    // Subgroup reduction of the limbs (each < 2^24, so sums < 2^31) and of min/max as (high, low) word pairs.
    uint sg = gl_SubgroupID;
    for (int l = 0; l < NLIMBS; ++l) {
        uint s = subgroupAdd(wide_limb(w, l));
        if (subgroupElect()) s_limbs[l][sg] = s;
    }
    uint hmin = subgroupMin(uint(cmin >> 32));
    uint lmin = subgroupMin(uint(cmin >> 32) == hmin ? uint(cmin) : 0xffffffffu);
    uint hmax = subgroupMax(uint(cmax >> 32));
    uint lmax = subgroupMax(uint(cmax >> 32) == hmax ? uint(cmax) : 0u);
    if (subgroupElect()) {
        s_min[sg] = (uint64_t(hmin) << 32) | uint64_t(lmin);
        s_max[sg] = (uint64_t(hmax) << 32) | uint64_t(lmax);
    }
    barrier();
    uint lid = gl_LocalInvocationIndex;
    if (lid < uint(NLIMBS)) {
        uint64_t total = 0ul;
        for (uint k = 0u; k < gl_NumSubgroups; ++k) total += uint64_t(s_limbs[lid][k]);
        if (total != 0ul) atomicAdd(U64Ref(pc.result + 8ul * (MOMENTS_LIMBS + lid)).v, total);
    } else if (lid == uint(NLIMBS)) {
        uint64_t a = 0xfffffffffffffffful;
        uint64_t b = 0ul;
        for (uint k = 0u; k < gl_NumSubgroups; ++k) {
            a = min(a, s_min[k]);
            b = max(b, s_max[k]);
        }
        if (a <= b) {
            atomicMin(U64Ref(pc.result).v, a); // MOMENTS_CODE_MIN is 0
            atomicMax(U64Ref(pc.result + 8ul * MOMENTS_CODE_MAX).v, b);
        }
    }
}
