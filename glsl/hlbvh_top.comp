#version 460
// HLBVH top level on the device: the binned SAH over the cluster root boxes of step 4 of the CPU reference
// (src/accel/hlbvh.rs: top_tree, top_node, top_split, and sweep_bins of src/accel/bvh/sah.rs), node for node and bit
// for bit. The C - 1 top nodes go to nodes 0 .. C - 2 in depth-first order (the node over list[s, e) at index p has
// its left subtree from p + 1 and its right one from p + m, m the clusters of its left side), with the parent links
// of their children. C and the cluster starts come from hlbvh_scan (starts = [C, s_0, ..., s_{C-1}, n]), the cluster
// root boxes from hlbvh_roots (roots[c]); cluster c's root is node C - 1 + 2 s_c - c.
//
// Every split is the reference's computation in the reference's order: the node box and the centroid bounds (centres
// (min + max) * 0.5); per axis with extent > 0 the scale `factor / extent` (factor = bins * (1 - 1e-6) in f32 from
// the host; the quotient correctly rounded in integer arithmetic, div_rn, since a device division need not be); the
// bin of every cluster (truncation of (centre - min) * scale, 0 * inf = NaN to 0, at most bins - 1); the bins' boxes
// and counts; the sweep (right sides backwards, left sides forwards, cost half_area(L) * N_L + half_area(R) * N_R,
// half_area = (e.x e.y + e.y e.z) + e.z e.x), axes in order, the least cost taken strictly (ties: lower axis, then
// lower plane); a stable partition of the cluster list; the middle of the list when no axis has a plane. Float
// arithmetic is `precise` (no fused multiply-adds). Boxes and bounds are unions (min and max), exact in any order up
// to the sign of zero, so they may be accumulated in parallel. Centre coordinates must not overflow f32 (|x| below
// 1.7e38), as for the quantizer, so costs are never NaN. A device that flushes subnormal results to zero computes
// extents and half areas below 2^-126 (boxes about 1e-19 wide) as zero where the host does not: such inputs are
// outside the bit-for-bit claim there.
//
// Dispatches (the host records them in this order, with a barrier after each):
//   phase 0, any size: list[i] = i for i < C; the header; the root range into queue 0 (C >= task_min) or the tasks.
//   phase 1, rounds 0 .. R - 1, G workgroups: every range of queue `round % 3` (ranges of at least task_min
//     clusters) is split by one workgroup cooperating (bounds, binning with shared atomics, a stable partition
//     with a prefix sum); children of at least task_min clusters go to queue (round + 1) % 3, smaller ones of at
//     least two clusters to the tasks. A workgroup goes on with the larger child itself while its work in this
//     dispatch stays under CHAIN_BUDGET, so a range reaches the queue only as the smaller side of a split (or when
//     the budget is spent): ceil(log2(C / task_min)) + 1 rounds suffice without budget stops.
//   phase 2, any size: every task, and every range left in queue `round % 3` (round = R), built serially by one
//     invocation (its stack in the stack entries of its own list range: a subtree of m clusters never holds more
//     than m / 2 ranges).
//   phase 3 (tests only): work[2L + i] = div_rn(work[2i], work[2i + 1]) for i < L.
//
// Loop budget: a driver may cap the loop iterations one invocation executes (lavapipe's gallivm stops every loop
// after 65,535 iterations in all). The host sizes task_min and the rounds so that realistic inputs stay far below
// it, and every loop whose completion matters is checked afterwards: a cut loop sets ERR_LOOP, never a wrong tree.
//
// work (uints, L = pc.limit >= C, Q = L / 2 + 1): list [0, L), partition scratch [L, 2L), stack [2L, 5L) (3 uints
// per entry: begin, end, node), header [5L, 5L + 8) (task count, error flags, counts of queues 0, 1, 2, three
// unused), tasks [5L + 8, 5L + 8 + 3Q), queue k at 5L + 8 + 3Q (k + 1) (3 uints per range). The error flags
// (ERR_*) are nonzero when an invariant failed; the host reports them as an error instead of returning the tree.
#include "common.glsl"
#include "bvh.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t starts;  // Address of the starts (`C`, the cluster starts, `n`).
    uint64_t roots;   // Address of the cluster root nodes (boxes of the clusters).
    uint64_t nodes;   // Address of the tree's nodes (the top nodes are written at 0 .. C - 2).
    uint64_t parents; // Address of the parent links.
    uint64_t work;    // Address of the scratch words (layout above).
    uint limit;       // Largest cluster count L the work buffer holds.
    uint bins;        // Bins per axis (2 to 64).
    float factor;     // `bins as f32 * (1.0 - 1e-6)`, computed by the host as the reference does.
    uint task_min;    // Ranges of fewer clusters are tasks of phase 2 (at least 2).
    uint phase;       // 0 to 3 (see above).
    uint round;       // Phase 1: the round; phase 2: the number of rounds recorded.
} pc;

#define MAX_BINS 64u
#define MAX_WORKGROUP 1024u
// Loop iterations one workgroup may spend in a round before it stops following the larger child.
#define CHAIN_BUDGET 16384u

#define ERR_STACK 1u  // a stack, queue or task list full (cannot happen: they are sized from L)
#define ERR_SPLIT 2u  // a partition left a side empty (cannot happen)
#define ERR_LIMIT 4u  // more clusters than the work buffer holds
#define ERR_LOOP 8u   // a loop stopped before its end (the driver's loop limit)

#define INF uintBitsToFloat(0x7f800000u)

// Buffer words other invocations of the workgroup read after a barrier.
layout(buffer_reference, std430, buffer_reference_align = 4) coherent buffer CoherentU32 { uint v; };

uint L;            // pc.limit
uint Q;            // capacity of the task list and of each queue
uint C;            // number of clusters
uint nb;           // bins
uint64_t w_head;   // word index of the header

uint w_ld(uint64_t i) { return CoherentU32(pc.work + 4ul * i).v; }
void w_st(uint64_t i, uint v) { CoherentU32(pc.work + 4ul * i).v = v; }
void fail(uint e) { atomicOr(CoherentU32(pc.work + 4ul * (w_head + 1ul)).v, e); }
uint64_t w_tmp(uint i) { return uint64_t(L) + uint64_t(i); }
uint64_t w_stack(uint i) { return 2ul * uint64_t(L) + 3ul * uint64_t(i); }
uint64_t w_task(uint k) { return w_head + 8ul + 3ul * uint64_t(k); }
uint64_t w_queue(uint q, uint k) { return w_head + 8ul + 3ul * uint64_t(Q) * uint64_t(q + 1u) + 3ul * uint64_t(k); }
uint64_t w_queue_count(uint q) { return w_head + 2ul + uint64_t(q); }

bool is_inf(float x) { return (floatBitsToUint(x) & 0x7fffffffu) == 0x7f800000u; }

// ---- Correctly rounded division ----

// Number of significant bits of a nonzero 64-bit integer.
int bit_length(uint64_t m) {
    uint hi = uint(m >> 32);
    return hi != 0u ? findMSB(hi) + 33 : findMSB(uint(m)) + 1;
}

// m * 2^e (m nonzero, its lowest bit standing for any nonzero rest below it, at least two bits below the f32
// rounding position) rounded to the nearest f32, ties to even; overflow gives +inf, results below half the least
// subnormal 0.
float round_f32(uint64_t m, int e) {
    int len = bit_length(m);
    int lead = len - 1 + e;
    if (lead > 127) return INF;
    int shift = lead >= -126 ? len - 24 : -149 - e;
    if (shift >= 64) return 0.0;
    uint64_t q = m >> uint(shift);
    uint64_t rest = m & ((1ul << uint(shift)) - 1ul);
    uint64_t half_ulp = 1ul << uint(shift - 1);
    if (rest > half_ulp || (rest == half_ulp && (q & 1ul) != 0ul)) q += 1ul;
    if (lead < -126) return uintBitsToFloat(uint(q)); // subnormal (2^23 after a carry: the least normal)
    // q in [2^23, 2^24]; a carry to 2^24 moves to the next exponent, at the top to +inf.
    return uintBitsToFloat(uint(lead + 127) * 0x800000u + uint(q) - 0x800000u);
}

// Significand (24 bits, leading bit set) and exponent of a positive finite float: x = m * 2^e.
void split_f32(float x, out uint m, out int e) {
    uint b = floatBitsToUint(x);
    uint be = b >> 23;
    m = b & 0x7fffffu;
    if (be == 0u) {
        int s = 23 - findMSB(m);
        m <<= uint(s);
        e = -149 - s;
    } else {
        m |= 0x800000u;
        e = int(be) - 150;
    }
}

// a / b correctly rounded (to nearest, ties to even) for finite a > 0 and b > 0 or +inf, in integer arithmetic.
float div_rn(float a, float b) {
    if (is_inf(b)) return 0.0;
    uint ma, mb;
    int ea, eb;
    split_f32(a, ma, ea);
    split_f32(b, mb, eb);
    uint64_t num = uint64_t(ma) << 40;
    uint64_t q = num / uint64_t(mb); // in (2^39, 2^41)
    uint sticky = (num - q * uint64_t(mb)) != 0ul ? 1u : 0u;
    return round_f32((q << 1) | uint64_t(sticky), ea - eb - 41);
}

// ---- The reference's arithmetic ----

vec3 box_lo(uint c) { return bvh_node(pc.roots, c).node.min; }
vec3 box_hi(uint c) { return bvh_node(pc.roots, c).node.max; }

// Aabb::center.
vec3 centre(uint c) {
    BvhNodeRef r = bvh_node(pc.roots, c);
    precise vec3 s = r.node.min + r.node.max;
    precise vec3 m = s * 0.5;
    return m;
}

// Aabb::half_area.
float half_area(vec3 lo, vec3 hi) {
    precise vec3 e = hi - lo;
    if (e.x < 0.0) return 0.0;
    precise float xy = e.x * e.y;
    precise float yz = e.y * e.z;
    precise float zx = e.z * e.x;
    precise float s = xy + yz;
    precise float a = s + zx;
    return a;
}

// top_split's bin_of: `((centre - min) * scale) as usize`, at most bins - 1 (0 * inf is NaN, which `as` maps to 0).
uint bin_of(float cv, float cmin, float scale) {
    precise float d = cv - cmin;
    if (d == 0.0 || scale == 0.0) return 0u;
    if (is_inf(d) || is_inf(scale)) return nb - 1u;
    precise float x = d * scale;
    if (x >= float(nb - 1u)) return nb - 1u;
    return uint(x);
}

// The centroid extent and the scale of every axis from the centroid bounds (the scale 0 where the extent is not
// positive: the reference skips that axis).
vec3 scales(vec3 clo, vec3 chi, out vec3 extent) {
    precise vec3 ext = chi - clo;
    extent = ext;
    vec3 scale = vec3(0.0);
    for (uint a = 0u; a < 3u; ++a) scale[a] = ext[a] > 0.0 ? div_rn(pc.factor, ext[a]) : 0.0;
    return scale;
}

uint root_id(uint c) { return C - 1u + 2u * ld_u32(pc.starts, 1ul + uint64_t(c)) - c; }

// Bins of one axis and the sweep's right sides.
vec3 bb_lo[MAX_BINS];
vec3 bb_hi[MAX_BINS];
uint bn[MAX_BINS];
float right_area[MAX_BINS];
uint right_n[MAX_BINS];

struct Best {
    bool found;
    uint axis;
    uint plane;
    float cost;
};

// sweep_bins over the bins of axis a (bb_lo, bb_hi, bn), updating `best` as top_split's visit does.
void sweep(uint a, inout Best best) {
    vec3 alo = vec3(INF), ahi = vec3(-INF);
    uint cnt = 0u;
    uint i = nb - 1u;
    for (; i >= 1u; --i) {
        alo = min(alo, bb_lo[i]);
        ahi = max(ahi, bb_hi[i]);
        cnt += bn[i];
        right_area[i] = half_area(alo, ahi);
        right_n[i] = cnt;
    }
    if (i != 0u) fail(ERR_LOOP);
    alo = vec3(INF);
    ahi = vec3(-INF);
    cnt = 0u;
    for (i = 1u; i < nb; ++i) {
        alo = min(alo, bb_lo[i - 1u]);
        ahi = max(ahi, bb_hi[i - 1u]);
        cnt += bn[i - 1u];
        if (cnt == 0u || right_n[i] == 0u) continue;
        precise float left_cost = half_area(alo, ahi) * float(cnt);
        precise float right_cost = right_area[i] * float(right_n[i]);
        precise float cost = left_cost + right_cost;
        if (!best.found || cost < best.cost) {
            best.found = true;
            best.axis = a;
            best.plane = i;
            best.cost = cost;
        }
    }
    if (i != nb) fail(ERR_LOOP);
}

// Writes the top node at `pos` over list[s, e) split after m clusters, with its box, and its children's parent links.
void write_node(uint s, uint e, uint pos, uint m, vec3 lo, vec3 hi) {
    uint li = m == 1u ? root_id(w_ld(uint64_t(s))) : pos + 1u;
    uint ri = e - s - m == 1u ? root_id(w_ld(uint64_t(s + m))) : pos + m;
    BvhNodeRef r = bvh_node(pc.nodes, pos);
    r.node.min = lo;
    r.node.left_or_first = li;
    r.node.max = hi;
    r.node.right_or_count = ri;
    st_u32(pc.parents, uint64_t(li), pos);
    st_u32(pc.parents, uint64_t(ri), pos);
}

// ---- Phase 2: one invocation per subtree ----

// top_node: splits the top node over list[s, e) (at least two clusters), writes it at node `pos`, and returns the
// number of clusters of its left side.
uint serial_node(uint s, uint e, uint pos) {
    uint n = e - s;
    vec3 lo = vec3(INF), hi = vec3(-INF), clo = vec3(INF), chi = vec3(-INF);
    uint i = s;
    for (; i < e; ++i) {
        uint c = w_ld(uint64_t(i));
        lo = min(lo, box_lo(c));
        hi = max(hi, box_hi(c));
        vec3 m = centre(c);
        clo = min(clo, m);
        chi = max(chi, m);
    }
    if (i != e) fail(ERR_LOOP);
    vec3 ext;
    vec3 scale = scales(clo, chi, ext);
    Best best = Best(false, 0u, 0u, 0.0);
    for (uint a = 0u; a < 3u; ++a) {
        if (!(ext[a] > 0.0)) continue;
        for (uint b = 0u; b < nb; ++b) {
            bb_lo[b] = vec3(INF);
            bb_hi[b] = vec3(-INF);
            bn[b] = 0u;
        }
        for (i = s; i < e; ++i) {
            uint c = w_ld(uint64_t(i));
            uint b = bin_of(centre(c)[a], clo[a], scale[a]);
            bb_lo[b] = min(bb_lo[b], box_lo(c));
            bb_hi[b] = max(bb_hi[b], box_hi(c));
            bn[b] += 1u;
        }
        if (i != e) fail(ERR_LOOP);
        sweep(a, best);
    }
    uint m = n / 2u;
    if (best.found) {
        // Stable partition: the left side forwards into the scratch from s, the right side backwards from e - 1.
        uint nl = 0u, nr = 0u;
        for (i = s; i < e; ++i) {
            uint c = w_ld(uint64_t(i));
            if (bin_of(centre(c)[best.axis], clo[best.axis], scale[best.axis]) < best.plane) {
                w_st(w_tmp(s + nl), c);
                ++nl;
            } else {
                ++nr;
                w_st(w_tmp(e - nr), c);
            }
        }
        if (i != e) fail(ERR_LOOP);
        for (i = 0u; i < nl; ++i) w_st(uint64_t(s + i), w_ld(w_tmp(s + i)));
        if (i != nl) fail(ERR_LOOP);
        for (i = 0u; i < nr; ++i) w_st(uint64_t(s + nl + i), w_ld(w_tmp(e - 1u - i)));
        if (i != nr) fail(ERR_LOOP);
        m = nl;
        if (m == 0u || m >= n) {
            fail(ERR_SPLIT);
            m = n / 2u;
        }
    }
    write_node(s, e, pos, m, lo, hi);
    return m;
}

void push(uint slot, uint s, uint e, uint pos) {
    uint64_t w = w_stack(slot);
    w_st(w, s);
    w_st(w + 1ul, e);
    w_st(w + 2ul, pos);
}

// top_sequential: the subtree over list[s0, e0) (at least two clusters) from node pos0, its stack in the stack
// entries s0 .. e0 - 1.
void subtree(uint s0, uint e0, uint pos0) {
    uint cap = e0 - s0;
    push(s0, s0, e0, pos0);
    uint sp = 1u;
    while (sp > 0u) {
        sp -= 1u;
        uint64_t w = w_stack(s0 + sp);
        uint s = w_ld(w), e = w_ld(w + 1ul), pos = w_ld(w + 2ul);
        uint m = serial_node(s, e, pos);
        if (sp + 2u > cap) {
            fail(ERR_STACK);
            return;
        }
        if (e - s - m > 1u) {
            push(s0 + sp, s + m, e, pos + m);
            sp += 1u;
        }
        if (m > 1u) {
            push(s0 + sp, s, s + m, pos + 1u);
            sp += 1u;
        }
    }
    if (sp != 0u) fail(ERR_LOOP);
}

// ---- Phase 1: one workgroup per range ----

// Minima start at ordered_bits(+inf), maxima at ordered_bits(-inf), as Aabb::EMPTY.
#define ORD_POS_INF 0xff800000u
#define ORD_NEG_INF 0x007fffffu
float from_ordered(uint u) { return uintBitsToFloat((u & 0x80000000u) != 0u ? (u & 0x7fffffffu) : ~u); }

shared uint sh_seg[4];                  // begin, end, node, whether there is a range to split
shared uint sh_box[12];                 // ordered bits: box min xyz, max xyz, centroid min xyz, max xyz
shared uint sh_bins[3u * MAX_BINS * 7u]; // per axis and bin: ordered bits of min xyz, max xyz, and the count
shared uint sh_pre[MAX_WORKGROUP];      // the partition's prefix sums (one per subgroup)
shared uint sh_total;                   // the partition's left side
shared uint sh_best[9];                 // per axis: found, plane, cost bits

vec3 sh_vec(uint k) {
    return vec3(from_ordered(sh_box[k]), from_ordered(sh_box[k + 1u]), from_ordered(sh_box[k + 2u]));
}

// Appends a child range: nothing for one cluster, a task when small, else an entry of queue q.
void add_range(uint s, uint e, uint pos, uint q) {
    uint k = e - s;
    if (k < 2u) return;
    uint64_t w;
    if (k < pc.task_min) {
        uint t = atomicAdd(CoherentU32(pc.work + 4ul * w_head).v, 1u);
        if (t >= Q) {
            fail(ERR_STACK);
            return;
        }
        w = w_task(t);
    } else {
        uint t = atomicAdd(CoherentU32(pc.work + 4ul * w_queue_count(q)).v, 1u);
        if (t >= Q) {
            fail(ERR_STACK);
            return;
        }
        w = w_queue(q, t);
    }
    w_st(w, s);
    w_st(w + 1ul, e);
    w_st(w + 2ul, pos);
}

// Splits the range in sh_seg with the whole workgroup (uniform control flow: every invocation calls it), writes its
// node and hands its children on; sh_seg then holds the larger child when `chain` (and it is large), else nothing.
void coop_node(bool chain, uint q_out) {
    uint lid = gl_LocalInvocationIndex;
    uint w = gl_WorkGroupSize.x;
    uint s = sh_seg[0], e = sh_seg[1], pos = sh_seg[2];
    uint n = e - s;
    uint ch = (n + w - 1u) / w;
    uint b0 = s + min(lid * ch, n);
    uint b1 = s + min(lid * ch + ch, n);
    if (lid < 12u) sh_box[lid] = (lid % 6u) < 3u ? ORD_POS_INF : ORD_NEG_INF;
    for (uint k = lid; k < 3u * nb * 7u; k += w) {
        uint f = k % 7u;
        sh_bins[k] = f < 3u ? ORD_POS_INF : (f < 6u ? ORD_NEG_INF : 0u);
    }
    barrier();
    // Bounds.
    vec3 lo = vec3(INF), hi = vec3(-INF), clo = vec3(INF), chi = vec3(-INF);
    uint i = b0;
    for (; i < b1; ++i) {
        uint c = w_ld(uint64_t(i));
        lo = min(lo, box_lo(c));
        hi = max(hi, box_hi(c));
        vec3 m = centre(c);
        clo = min(clo, m);
        chi = max(chi, m);
    }
    if (i != b1) fail(ERR_LOOP);
    if (b1 > b0) {
        for (uint a = 0u; a < 3u; ++a) {
            atomicMin(sh_box[a], ordered_bits(lo[a]));
            atomicMax(sh_box[3u + a], ordered_bits(hi[a]));
            atomicMin(sh_box[6u + a], ordered_bits(clo[a]));
            atomicMax(sh_box[9u + a], ordered_bits(chi[a]));
        }
    }
    barrier();
    lo = sh_vec(0u);
    hi = sh_vec(3u);
    clo = sh_vec(6u);
    chi = sh_vec(9u);
    vec3 ext;
    vec3 scale = scales(clo, chi, ext);
    // Bins of every axis with a positive extent.
    for (i = b0; i < b1; ++i) {
        uint c = w_ld(uint64_t(i));
        vec3 m = centre(c);
        vec3 cl = box_lo(c), chh = box_hi(c);
        for (uint a = 0u; a < 3u; ++a) {
            if (!(ext[a] > 0.0)) continue;
            uint k = (a * nb + bin_of(m[a], clo[a], scale[a])) * 7u;
            atomicMin(sh_bins[k], ordered_bits(cl.x));
            atomicMin(sh_bins[k + 1u], ordered_bits(cl.y));
            atomicMin(sh_bins[k + 2u], ordered_bits(cl.z));
            atomicMax(sh_bins[k + 3u], ordered_bits(chh.x));
            atomicMax(sh_bins[k + 4u], ordered_bits(chh.y));
            atomicMax(sh_bins[k + 5u], ordered_bits(chh.z));
            atomicAdd(sh_bins[k + 6u], 1u);
        }
    }
    if (i != b1) fail(ERR_LOOP);
    barrier();
    // The sweep of axis a on invocation a. Taking each axis' first least cost, then the axes in order with the
    // strict comparison, is the reference's single pass over the axes and planes (the costs are never NaN: the
    // extents are finite).
    if (lid < 3u) {
        uint a = lid;
        Best best = Best(false, 0u, 0u, 0.0);
        if (ext[a] > 0.0) {
            uint b = 0u;
            for (; b < nb; ++b) {
                uint k = (a * nb + b) * 7u;
                bb_lo[b] = vec3(from_ordered(sh_bins[k]), from_ordered(sh_bins[k + 1u]), from_ordered(sh_bins[k + 2u]));
                bb_hi[b] =
                    vec3(from_ordered(sh_bins[k + 3u]), from_ordered(sh_bins[k + 4u]), from_ordered(sh_bins[k + 5u]));
                bn[b] = sh_bins[k + 6u];
            }
            if (b != nb) fail(ERR_LOOP);
            sweep(a, best);
        }
        sh_best[3u * a] = best.found ? 1u : 0u;
        sh_best[3u * a + 1u] = best.plane;
        sh_best[3u * a + 2u] = floatBitsToUint(best.cost);
    }
    barrier();
    Best best = Best(false, 0u, 0u, 0.0);
    for (uint a = 0u; a < 3u; ++a) {
        float cost = uintBitsToFloat(sh_best[3u * a + 2u]);
        if (sh_best[3u * a] != 0u && (!best.found || cost < best.cost)) {
            best = Best(true, a, sh_best[3u * a + 1u], cost);
        }
    }
    uint m = n / 2u;
    if (best.found) {
        uint axis = best.axis, plane = best.plane;
        // Stable partition: each invocation's chunk keeps its order, the chunks theirs (prefix sum of the lefts).
        uint nl = 0u;
        for (i = b0; i < b1; ++i) {
            uint c = w_ld(uint64_t(i));
            if (bin_of(centre(c)[axis], clo[axis], scale[axis]) < plane) ++nl;
        }
        if (i != b1) fail(ERR_LOOP);
        // Prefix sum: within the subgroup, then over the subgroup totals (one invocation, in order).
        uint incl = subgroupInclusiveAdd(nl);
        uint sub_total = subgroupAdd(nl);
        if (gl_SubgroupInvocationID == 0u) sh_pre[gl_SubgroupID] = sub_total;
        barrier();
        if (lid == 0u) {
            uint acc = 0u;
            uint g = 0u;
            for (; g < gl_NumSubgroups; ++g) {
                uint x = sh_pre[g];
                sh_pre[g] = acc;
                acc += x;
            }
            if (g != gl_NumSubgroups) fail(ERR_LOOP);
            sh_total = acc;
        }
        barrier();
        uint left_before = sh_pre[gl_SubgroupID] + incl - nl;
        uint total_left = sh_total;
        uint right_before = (b0 - s) - left_before;
        uint kl = 0u, kr = 0u;
        for (i = b0; i < b1; ++i) {
            uint c = w_ld(uint64_t(i));
            if (bin_of(centre(c)[axis], clo[axis], scale[axis]) < plane) {
                w_st(w_tmp(s + left_before + kl), c);
                ++kl;
            } else {
                w_st(w_tmp(s + total_left + right_before + kr), c);
                ++kr;
            }
        }
        if (i != b1) fail(ERR_LOOP);
        // Every invocation has read its chunk: each copies back what it wrote.
        barrier();
        for (i = 0u; i < kl; ++i) w_st(uint64_t(s + left_before + i), w_ld(w_tmp(s + left_before + i)));
        if (i != kl) fail(ERR_LOOP);
        uint r0 = s + total_left + right_before;
        for (i = 0u; i < kr; ++i) w_st(uint64_t(r0 + i), w_ld(w_tmp(r0 + i)));
        if (i != kr) fail(ERR_LOOP);
        m = total_left;
        if (m == 0u || m >= n) {
            if (lid == 0u) fail(ERR_SPLIT);
            m = n / 2u;
        }
    }
    // The list writes are visible to the workgroup (the next range may be read by other invocations).
    memoryBarrierBuffer();
    barrier();
    if (lid == 0u) {
        write_node(s, e, pos, m, lo, hi);
        // The larger child stays here (the left one on a tie) when chaining and it is large; the rest is handed on.
        bool left_big = m >= n - m;
        uint ks = left_big ? s : s + m, ke = left_big ? s + m : e, kp = left_big ? pos + 1u : pos + m;
        uint os = left_big ? s + m : s, oe = left_big ? e : s + m, op = left_big ? pos + m : pos + 1u;
        add_range(os, oe, op, q_out);
        if (chain && ke - ks >= pc.task_min) {
            sh_seg[0] = ks;
            sh_seg[1] = ke;
            sh_seg[2] = kp;
        } else {
            add_range(ks, ke, kp, q_out);
            sh_seg[3] = 0u;
        }
    }
    memoryBarrierShared();
    barrier();
}

void main() {
    L = pc.limit;
    Q = L / 2u + 1u;
    nb = clamp(pc.bins, 2u, MAX_BINS);
    w_head = 5ul * uint64_t(L);
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    if (pc.phase == 3u) {
        for (uint64_t i = gl_GlobalInvocationID.x; i < uint64_t(L); i += stride) {
            float q = div_rn(uintBitsToFloat(w_ld(2ul * i)), uintBitsToFloat(w_ld(2ul * i + 1ul)));
            w_st(2ul * uint64_t(L) + i, floatBitsToUint(q));
        }
        return;
    }
    C = ld_u32(pc.starts, 0ul);
    if (pc.phase == 0u) {
        bool ok = C <= L && C > 0u;
        if (ok) {
            uint64_t i = gl_GlobalInvocationID.x;
            for (; i < uint64_t(C); i += stride) w_st(i, uint(i));
            if (i < uint64_t(C)) fail(ERR_LOOP);
        }
        if (gl_GlobalInvocationID.x == 0u) {
            for (uint k = 0u; k < 8u; ++k) w_st(w_head + uint64_t(k), 0u);
            if (!ok) {
                fail(ERR_LIMIT);
            } else if (C >= 2u) {
                // The root range, as add_range would (the counters are zero).
                bool task = C < pc.task_min;
                uint64_t w = task ? w_task(0u) : w_queue(0u, 0u);
                w_st(w, 0u);
                w_st(w + 1ul, C);
                w_st(w + 2ul, 0u);
                w_st(task ? w_head : w_queue_count(0u), 1u);
            }
        }
        return;
    }
    if (pc.phase == 1u) {
        uint q_in = pc.round % 3u, q_out = (pc.round + 1u) % 3u;
        // Queue (round + 2) % 3 was the input of the previous round: empty it for the next one.
        if (gl_WorkGroupID.x == 0u && gl_LocalInvocationIndex == 0u) w_st(w_queue_count((pc.round + 2u) % 3u), 0u);
        uint count = min(w_ld(w_queue_count(q_in)), Q);
        uint spent = 0u;
        uint j = gl_WorkGroupID.x;
        for (; j < count; j += gl_NumWorkGroups.x) {
            if (gl_LocalInvocationIndex == 0u) {
                uint64_t w = w_queue(q_in, j);
                sh_seg[0] = w_ld(w);
                sh_seg[1] = w_ld(w + 1ul);
                sh_seg[2] = w_ld(w + 2ul);
                sh_seg[3] = 1u;
            }
            memoryBarrierShared();
            barrier();
            while (sh_seg[3] != 0u) {
                uint n = sh_seg[1] - sh_seg[0];
                // Roughly the loop iterations of one split per invocation.
                spent += 5u * ((n + gl_WorkGroupSize.x - 1u) / gl_WorkGroupSize.x) + 8u * nb + 48u;
                coop_node(spent < CHAIN_BUDGET, q_out);
            }
            barrier();
        }
        if (j < count) fail(ERR_LOOP);
        return;
    }
    // phase 2
    if (w_ld(w_head + 1ul) != 0u) return; // an earlier phase failed
    uint tasks = min(w_ld(w_head), Q);
    uint q_left = pc.round % 3u;
    uint left = min(w_ld(w_queue_count(q_left)), Q);
    uint t = gl_GlobalInvocationID.x;
    for (; t < tasks + left; t += uint(stride)) {
        uint64_t w = t < tasks ? w_task(t) : w_queue(q_left, t - tasks);
        subtree(w_ld(w), w_ld(w + 1ul), w_ld(w + 2ul));
    }
    if (t < tasks + left) fail(ERR_LOOP);
}
