// Exact wide-integer sums of m, m^2 and m^3 for codes m < 2^63, in 24-bit limbs.
//
// Each invocation keeps its sums as arrays of uint64 limbs of 24 bits (limb j weighs 2^(24 j)). Per item, products
// of 24-bit limbs (< 2^48, at most three per output limb) are added without carrying; after each tile the limbs are
// normalized (carries moved up), so no uint64 ever overflows. Normalized limbs are below 2^24, so a subgroupAdd over
// at most 128 invocations stays below 2^31 and fits a uint. Sums hold S1 < 2^95 (4 limbs), S2 < 2^158 (7 limbs),
// S3 < 2^221 (10 limbs) for n < 2^32, with room to spare.
#define L1 4
#define L2 7
#define L3 10
#define NLIMBS (L1 + L2 + L3)
#define LIMB_MASK 0xfffffful

struct Wide {
    uint64_t s1[L1];
    uint64_t s2[L2];
    uint64_t s3[L3];
};

void wide_clear(inout Wide w) {
    for (int i = 0; i < L1; ++i) w.s1[i] = 0ul;
    for (int i = 0; i < L2; ++i) w.s2[i] = 0ul;
    for (int i = 0; i < L3; ++i) w.s3[i] = 0ul;
}

void wide_add(inout Wide w, uint64_t m) {
    uint64_t a[3] = uint64_t[3](m & LIMB_MASK, (m >> 24) & LIMB_MASK, m >> 48);
    // m^2 as 5 unnormalized limbs, then normalized to 6 limbs b for the cube.
    uint64_t c[5] = uint64_t[5](a[0] * a[0], 2ul * a[0] * a[1], 2ul * a[0] * a[2] + a[1] * a[1], 2ul * a[1] * a[2], a[2] * a[2]);
    uint64_t b[6];
    uint64_t carry = 0ul;
    for (int i = 0; i < 5; ++i) {
        uint64_t t = c[i] + carry;
        b[i] = t & LIMB_MASK;
        carry = t >> 24;
    }
    b[5] = carry;
    for (int i = 0; i < 3; ++i) w.s1[i] += a[i];
    for (int i = 0; i < 5; ++i) w.s2[i] += c[i];
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 3; ++j) w.s3[i + j] += b[i] * a[j];
    }
}

void wide_normalize(inout Wide w) {
    uint64_t carry = 0ul;
    for (int i = 0; i < L1; ++i) { uint64_t t = w.s1[i] + carry; w.s1[i] = t & LIMB_MASK; carry = t >> 24; }
    w.s1[L1 - 1] += carry << 24;
    carry = 0ul;
    for (int i = 0; i < L2; ++i) { uint64_t t = w.s2[i] + carry; w.s2[i] = t & LIMB_MASK; carry = t >> 24; }
    w.s2[L2 - 1] += carry << 24;
    carry = 0ul;
    for (int i = 0; i < L3; ++i) { uint64_t t = w.s3[i] + carry; w.s3[i] = t & LIMB_MASK; carry = t >> 24; }
    w.s3[L3 - 1] += carry << 24;
}

uint wide_limb(Wide w, int j) {
    if (j < L1) return uint(w.s1[j]);
    if (j < L1 + L2) return uint(w.s2[j - L1]);
    return uint(w.s3[j - L1 - L2]);
}
