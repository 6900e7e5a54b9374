#version 460
// The binary radix tree of Karras 2012 over the sorted (code, id) extended keys, one invocation per sorted position,
// no inter-invocation communication. Position i (not the last of its range) owns internal node base + i, writes
// its two children and their parent links; a child covering one position is a leaf, written here too (first
// record = that position, count 1). A range of one position writes its single leaf.
// LBVH: one range 0 .. n, base 0 (internal nodes 0 .. n-2, leaves n-1 .. 2n-2).
// HLBVH (HLBVH = 1): ranges are the Morton clusters (see hlbvh_scan.comp), delta = -1 outside a cluster; cluster
// c covering s .. e has base C - 1 + s - c, so its block of 2(e - s) - 1 nodes starts at C - 1 + 2s - c.
#include "common.glsl"
#include "bvh.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;
layout(constant_id = 2) const uint BITS63 = 0u;
layout(constant_id = 3) const uint HLBVH = 0u;

layout(push_constant) uniform Push {
    uint64_t codes;   // Address of the sorted codes.
    uint64_t ids;     // Address of the sorted ids.
    uint64_t nodes;   // Address of the nodes.
    uint64_t parents; // Address of the parent links.
    uint64_t table;   // Address of the cluster table (HLBVH).
    uint64_t starts;  // Address of the cluster starts (HLBVH).
    uint64_t count;   // Number of positions.
    uint shift;       // Code shift giving the cluster prefix (HLBVH).
    uint pad;         // Padding.
} pc;

uint64_t code_at(int64_t i) {
    return BITS63 != 0u ? ld_u64(pc.codes, uint64_t(i)) : uint64_t(ld_u32(pc.codes, uint64_t(i)));
}

int msb64(uint64_t x) {
    uint hi = uint(x >> 32);
    return hi != 0u ? 32 + findMSB(hi) : findMSB(uint(x));
}

// Common prefix length of the extended keys at i and j, -1 when j is outside s .. e.
int delta(int64_t i, int64_t j, int64_t s, int64_t e) {
    if (j < s || j >= e) return -1;
    const int bits = BITS63 != 0u ? 63 : 30;
    uint64_t a = code_at(i);
    uint64_t b = code_at(j);
    if (a != b) return bits - 1 - msb64(a ^ b);
    uint x = ld_u32(pc.ids, uint64_t(i)) ^ ld_u32(pc.ids, uint64_t(j));
    return bits + 31 - findMSB(x);
}

void write_leaf(uint node, uint p) {
    BvhNodeRef r = bvh_node(pc.nodes, node);
    r.node.left_or_first = p;
    r.node.right_or_count = BVH_LEAF_FLAG | 1u;
}

void main() {
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.count, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t tbase = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        for (uint jj = 0u; jj < ITEMS; ++jj) {
            uint64_t u = tbase + uint64_t(jj * gl_WorkGroupSize.x);
            if (u >= pc.count) continue;
            int64_t i = int64_t(u);
            int64_t s = 0l;
            int64_t e = int64_t(pc.count);
            int64_t base = 0l;
            if (HLBVH != 0u) {
                uint c = ld_u32(pc.table, code_at(i) >> pc.shift);
                uint clusters = ld_u32(pc.starts, 0ul);
                s = int64_t(ld_u32(pc.starts, 1ul + c));
                e = int64_t(ld_u32(pc.starts, 2ul + c));
                base = int64_t(clusters) - 1l + s - int64_t(c);
            }
            int64_t leaf0 = base + (e - s - 1l);
            if (e - s == 1l) {
                write_leaf(uint(leaf0 + i), uint(i));
                continue;
            }
            if (i == e - 1l) continue;
            int64_t d = delta(i, i + 1l, s, e) - delta(i, i - 1l, s, e) >= 0 ? 1l : -1l;
            int dmin = delta(i, i - d, s, e);
            int64_t lmax = 2l;
            while (delta(i, i + lmax * d, s, e) > dmin) lmax *= 2l;
            int64_t l = 0l;
            for (int64_t q = lmax / 2l; q >= 1l; q /= 2l) {
                if (delta(i, i + (l + q) * d, s, e) > dmin) l += q;
            }
            int64_t j = i + l * d;
            int dnode = delta(i, j, s, e);
            int64_t sp = 0l;
            int64_t q = l;
            for (;;) {
                q = (q + 1l) >> 1;
                if (delta(i, i + (sp + q) * d, s, e) > dnode) sp += q;
                if (q <= 1l) break;
            }
            int64_t gamma = i + sp * d + min(d, 0l);
            uint node = uint(base + i);
            uint left;
            uint right;
            if (min(i, j) == gamma) {
                left = uint(leaf0 + gamma);
                write_leaf(left, uint(gamma));
            } else {
                left = uint(base + gamma);
            }
            if (max(i, j) == gamma + 1l) {
                right = uint(leaf0 + gamma + 1l);
                write_leaf(right, uint(gamma + 1l));
            } else {
                right = uint(base + gamma + 1l);
            }
            BvhNodeRef r = bvh_node(pc.nodes, node);
            r.node.left_or_first = left;
            r.node.right_or_count = right;
            st_u32(pc.parents, uint64_t(left), node);
            st_u32(pc.parents, uint64_t(right), node);
        }
    }
}
