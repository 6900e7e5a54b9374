#version 460
// Radix sort, pass 3 of 3 per digit: every key (and its payload) moves to its place for this digit, stably.
//
// The workgroup takes the same blocks as the count pass (block b: keys from b * gl_WorkGroupSize.x * KPT). Inside a
// block, subgroup s owns a contiguous run of n_s * KPT keys (n_s: its active lanes) and walks it in KPT rounds of
// n_s consecutive keys, so subgroups and rounds are in key order:
//   1. each subgroup counts its run's digits into its own row of s_off (MAX_SUBGROUPS x 256 counters);
//   2. for every digit, the counters become first positions: the block's scanned count for the digit (from the scan
//      pass) plus the counts of the same digit in lower subgroups;
//   3. each subgroup replays its rounds: the lanes holding the same digit find each other with eight ballots, rank
//      themselves in lane order, and the lowest of them reads and advances the subgroup's counter for the digit.
// Keys are read from memory once (kept in registers between 1 and 3); there is no waiting between workgroups.
#include "common.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint KPT = 16u;
layout(constant_id = 2) const uint MAX_SUBGROUPS = 32u;
layout(constant_id = 3) const uint KEY64 = 0u;
#include "sort.glsl"

layout(push_constant) uniform Push {
    uint64_t keys_in;  // Address of the input keys.
    uint64_t keys_out; // Address of the output keys.
    uint64_t vals_in;  // Address of the input payloads (0: none).
    uint64_t vals_out; // Address of the output payloads.
    uint64_t counts;   // Address of the scanned counts.
    uint64_t count;    // Number of keys.
    uint blocks;       // Number of blocks.
    uint shift;        // Bit offset of the digit.
} pc;

shared uint s_off[MAX_SUBGROUPS * 256u];

uint64_t load_key(uint64_t i) { return KEY64 != 0u ? ld_u64(pc.keys_in, i) : uint64_t(ld_u32(pc.keys_in, i)); }
uint digit_of(uint64_t key) { return uint(key >> pc.shift) & 0xffu; }

void main() {
    uint lid = gl_LocalInvocationIndex;
    uint first, n_lanes, lane;
    subgroup_layout(first, n_lanes, lane);
    uint sg = gl_SubgroupID;
    uint nsg = gl_NumSubgroups;
    uint row = sg * 256u;
    uint block_keys = gl_WorkGroupSize.x * KPT;
    uint64_t key[KPT];
    for (uint b = gl_WorkGroupID.x; b < pc.blocks; b += gl_NumWorkGroups.x) {
        for (uint e = lid; e < nsg * 256u; e += gl_WorkGroupSize.x) s_off[e] = 0u;
        barrier();
        // This subgroup's run: round j holds keys run + j * n_lanes + lane.
        uint64_t run = uint64_t(b) * uint64_t(block_keys) + uint64_t(first) * uint64_t(KPT) + uint64_t(lane);
        for (uint j = 0u; j < KPT; ++j) {
            uint64_t i = run + uint64_t(j * n_lanes);
            key[j] = 0ul;
            if (i < pc.count) {
                key[j] = load_key(i);
                atomicAdd(s_off[row + digit_of(key[j])], 1u);
            }
        }
        barrier();
        for (uint d = lid; d < 256u; d += gl_WorkGroupSize.x) {
            uint pos = ld_u32(pc.counts, uint64_t(d) * uint64_t(pc.blocks) + uint64_t(b));
            for (uint s = 0u; s < nsg; ++s) {
                uint c = s_off[s * 256u + d];
                s_off[s * 256u + d] = pos;
                pos += c;
            }
        }
        barrier();
        for (uint j = 0u; j < KPT; ++j) {
            uint64_t i = run + uint64_t(j * n_lanes);
            bool valid = i < pc.count;
            uint d = digit_of(key[j]);
            uvec4 peers = match_digit(d, valid);
            uint rank = subgroupBallotExclusiveBitCount(peers);
            uint same = subgroupBallotBitCount(peers);
            // Lanes without a key have no peers: they read their own (unused) value.
            uint leader = valid ? subgroupBallotFindLSB(peers) : gl_SubgroupInvocationID;
            uint pos = 0u;
            if (valid && gl_SubgroupInvocationID == leader) {
                pos = s_off[row + d];
                s_off[row + d] = pos + same;
            }
            pos = subgroupShuffle(pos, leader) + rank;
            if (valid) {
                if (KEY64 != 0u) st_u64(pc.keys_out, uint64_t(pos), key[j]);
                else st_u32(pc.keys_out, uint64_t(pos), uint(key[j]));
                if (pc.vals_in != 0ul) st_u32(pc.vals_out, uint64_t(pos), ld_u32(pc.vals_in, i));
            }
            // The next round's leader for a digit may be another lane: order this round's counter update before it.
            subgroupMemoryBarrierShared();
            subgroupBarrier();
        }
        barrier();
    }
}
