#version 460
// docs/spec.md steps 9-10 as exact integers, one workgroup: T = sum (k O_i - n)^2 (128 bits; chi2 = T / (n k) on the host),
// the number of empty classes (O_i == 0), of concentrated classes (k O_i > n, i.e. O_i > E) and the triangles in
// them. out: uint64[5] = T low, T high, empty, concentrated, triangles in concentrated classes.
#include "common.glsl"
#include "layout.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t hist;     // Address of the histogram.
    uint64_t out_addr; // Address of the `uint64[5]` output.
    uint64_t n;        // Number of codes.
    uint k;            // Class count.
    uint pad;          // Padding.
} pc;

shared uint64_t s_lo[gl_WorkGroupSize.x];
shared uint64_t s_hi[gl_WorkGroupSize.x];
shared uint s_counts[3];

void add128(inout uint64_t hi, inout uint64_t lo, uint64_t bhi, uint64_t blo) {
    uint64_t r = lo + blo;
    hi += bhi + (r < lo ? 1ul : 0ul);
    lo = r;
}

void main() {
    uint lid = gl_LocalInvocationIndex;
    if (lid == 0u) { s_counts[0] = 0u; s_counts[1] = 0u; s_counts[2] = 0u; }
    barrier();
    uint64_t hi = 0ul, lo = 0ul;
    uint empty = 0u, conc = 0u, conc_n = 0u;
    for (uint c = lid; c < pc.k; c += gl_WorkGroupSize.x) {
        uint64_t o = uint64_t(ld_u32(pc.hist, c));
        uint64_t ko = uint64_t(pc.k) * o;
        uint64_t d = ko > pc.n ? ko - pc.n : pc.n - ko;
        // d < 2^45: d^2 = dh^2 2^64 + 2 dh dl 2^32 + dl^2 with 32-bit halves dh, dl.
        uint64_t dh = d >> 32, dl = d & 0xfffffffful;
        uint64_t mid = 2ul * dh * dl;
        add128(hi, lo, dh * dh, dl * dl);
        add128(hi, lo, mid >> 32, mid << 32);
        if (o == 0ul) empty += 1u;
        if (ko > pc.n) { conc += 1u; conc_n += uint(o); }
    }
    s_lo[lid] = lo;
    s_hi[lid] = hi;
    uint e = subgroupAdd(empty), cc = subgroupAdd(conc), cn = subgroupAdd(conc_n);
    if (subgroupElect()) {
        atomicAdd(s_counts[0], e);
        atomicAdd(s_counts[1], cc);
        atomicAdd(s_counts[2], cn);
    }
    barrier();
    if (lid == 0u) {
        uint64_t th = 0ul, tl = 0ul;
        for (uint i = 0u; i < gl_WorkGroupSize.x; ++i) add128(th, tl, s_hi[i], s_lo[i]);
        st_u64(pc.out_addr, CHI_T_LO, tl);
        st_u64(pc.out_addr, CHI_T_HI, th);
        st_u64(pc.out_addr, CHI_EMPTY, uint64_t(s_counts[0]));
        st_u64(pc.out_addr, CHI_CONCENTRATED, uint64_t(s_counts[1]));
        st_u64(pc.out_addr, CHI_CONCENTRATED_TRIANGLES, uint64_t(s_counts[2]));
    }
}
