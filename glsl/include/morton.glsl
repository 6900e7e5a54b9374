// Morton codes of docs/spec.md step 4: bit i of x to bit 3i+2, of y to 3i+1, of z to 3i (same as keys::morton).
uint spread10(uint v) {
    uint x = v & 0x3ffu;
    x = (x | (x << 16)) & 0x030000ffu;
    x = (x | (x << 8)) & 0x0300f00fu;
    x = (x | (x << 4)) & 0x030c30c3u;
    x = (x | (x << 2)) & 0x09249249u;
    return x;
}
uint64_t spread21(uint v) {
    uint64_t x = uint64_t(v & 0x1fffffu);
    x = (x | (x << 32)) & 0x001f00000000fffful;
    x = (x | (x << 16)) & 0x001f0000ff0000fful;
    x = (x | (x << 8)) & 0x100f00f00f00f00ful;
    x = (x | (x << 4)) & 0x10c30c30c30c30c3ul;
    x = (x | (x << 2)) & 0x1249249249249249ul;
    return x;
}
uint morton30(uvec3 q) { return (spread10(q.x) << 2) | (spread10(q.y) << 1) | spread10(q.z); }
uint64_t morton63(uvec3 q) { return (spread21(q.x) << 2) | (spread21(q.y) << 1) | spread21(q.z); }
