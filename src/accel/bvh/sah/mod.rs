//! Binned-SAH BVH (Wald 2007), built in parallel with rayon.
//!
//! Binned SAH after Wald 2007: centroids binned into [`BvhOptions::bins`] bins per axis on the centroid bounds,
//! all three axes evaluated, the plane of least `K_T * A + K_I * (A_L N_L + A_R N_R)` taken when it beats a leaf
//! (`K_I * A * N`) or when the node holds more than [`BvhOptions::max_leaf`] triangles. Nodes whose centroids
//! coincide, or deeper than 64 levels, are split at the object median. A node whose centroids coincide and that
//! holds copies of one triangle (the same three vertex positions, bit for bit and in the same order, as a polygon
//! face over few points loads to, or an OBJ whose groups repeat a face with vertices of their own) keeps only the
//! copy of the smallest index: under the tie rule no other copy can be the closest hit (its record, `t`, `u` and `v`
//! are the same bits) nor change an any-hit answer, and every ray that reaches them would otherwise test them all.
//! The copies stay among the triangle records in no leaf; [`super::BvhTree::copies`] lists them, and a refit that
//! moves a copy off its kept triangle fails (rebuild).  Copies in another vertex order are left alone: their `t`
//! may differ in the last bit. Subtrees above
//! [`BvhOptions::parallel_threshold`] triangles are built in parallel (`rayon::join`), and the binning of large
//! nodes is parallel too; every subtree writes into its own slice of a preallocated array (a subtree of `k`
//! triangles owns `2k - 1` slots), which a final pass compacts with siblings adjacent. Subtrees of at most 8
//! triangles are split by an exact sweep instead of bins, from a small stack rather than by recursion. The result
//! does not depend on the number of threads.
//!
//! A reinsertion pass ([`BvhOptions::reinsertion`], `reinsert.rs`) then moves subtrees of the built tree to where
//! they cost less; it changes internal nodes only, never the leaves.
//!
//! Speed: each reference's box sits in two SIMD registers whose `w` lanes carry the triangle index as normal floats
//! (`index_lane`); raw index bits there would be subnormal floats, which made every box operation take x86's slow
//! path (3-4x the build time on the bunny).

use super::{BvhNode, BvhTree};
use crate::accel::copies::position_bits;
use crate::accel::{
    prepare, AccelError, AccelStats, AccelStructure, StructureName, SAH_INTERSECTION_COST, SAH_TRAVERSAL_COST,
};
use crate::geom::Aabb;
use crate::mesh::Mesh;
use glam::Vec4;
use rayon::prelude::*;

mod binning;

pub(crate) use binning::sweep_bins;
use binning::*;

/// Options of the binned-SAH builder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BvhOptions {
    /// Bins per axis (2 to 32) of nodes under 2,048 references; larger nodes get at least 32.
    pub bins: usize,
    /// Largest leaf; nodes above it are always split.
    pub max_leaf: usize,
    /// Subtrees with at least this many triangles are built in parallel.
    pub parallel_threshold: usize,
    /// Share of the nodes (those with the largest boxes) that the reinsertion pass after the build tries to move to
    /// a cheaper place, per round; 0 turns the pass off. The pass lowers the SAH cost of scenes with large,
    /// overlapping triangles (architecture: Sponza 69 to 60, the conference room 37 to 31) and stops early where
    /// nothing moves (scans).
    pub reinsertion: f32,
}

impl Default for BvhOptions {
    fn default() -> Self {
        BvhOptions { bins: 16, max_leaf: 8, parallel_threshold: 4096, reinsertion: 0.02 }
    }
}

/// Bins per axis at most (a power of two: bin indices are masked into the arrays).
const MAX_BINS: usize = 32;
const MAX_SAH_DEPTH: u32 = 64;
/// Rounds of the reinsertion pass at most.
const REINSERTION_ROUNDS: usize = 2;
const PAR_BIN_THRESHOLD: usize = 65_536;

/// In-place partition; returns the number of elements for which `left` holds (they come first).
#[cfg(feature = "eval")]
pub(crate) fn partition<T>(v: &mut [T], mut left: impl FnMut(&T) -> bool) -> usize {
    let mut i = 0;
    let mut j = v.len();
    while i < j {
        if left(&v[i]) {
            i += 1;
        } else {
            j -= 1;
            v.swap(i, j);
        }
    }
    i
}

/// Partitions `v` on the bin of each reference's centroid on `axis` (the bin the split was found with): left
/// (bins below `bin`) first, in input order, then right. Branch-free: every reference is written to the next slot
/// of its side in `tmp` (left from the front, right from the back), then copied back while the centroid boxes (of
/// `min + max`) of both sides are taken. Returns the size of the left side and the two centroid boxes.
fn partition_split(v: &mut [Ref], tmp: &mut [Ref], g: &Binning, axis: usize, bin: usize) -> (usize, B4, B4) {
    let n = v.len();
    let tmp = &mut tmp[..n];
    let (mut l, mut r) = (0usize, n);
    for x in v.iter() {
        let left = g.bins(x.c2())[axis] < bin;
        let at = if left { l } else { r - 1 };
        tmp[at] = *x;
        l += left as usize;
        r -= (!left) as usize;
    }
    let (mut lcb, mut rcb) = (B4::EMPTY, B4::EMPTY);
    for (d, s) in v[..l].iter_mut().zip(&tmp[..l]) {
        *d = *s;
        lcb.grow(s.c2());
    }
    for (d, s) in v[l..].iter_mut().zip(tmp[l..].iter().rev()) {
        *d = *s;
        rcb.grow(s.c2());
    }
    (l, lcb, rcb)
}

/// Nodes of at most this many references are split by an exact sweep ([`exact_split`]) instead of binning.
const EXACT_MAX: usize = 8;

/// The exact SAH sweep of a small node: on each axis the references sorted by centroid (then index), every
/// position between two of them a candidate, `A_L N_L + A_R N_R` from prefix and suffix boxes (ties: the more
/// balanced, then the lower axis and position). Reorders `refs` by the chosen axis and returns `(cost, left size,
/// left box, right box)`; `None` for fewer than two references.
fn exact_split(refs: &mut [Ref]) -> Option<(f32, usize, B4, B4)> {
    let n = refs.len();
    if !(2..=EXACT_MAX).contains(&n) {
        return None;
    }
    if n == 2 {
        // Every axis gives the same two sides; the order is by centroid on the first axis that separates them.
        let (c0, c1) = (refs[0].c2(), refs[1].c2());
        let swap = (0..3).find(|&a| c0[a] != c1[a]).map_or(refs[1].idx() < refs[0].idx(), |a| c1[a] < c0[a]);
        if swap {
            refs.swap(0, 1);
        }
        let cost = refs[0].b.half_area() + refs[1].b.half_area();
        return Some((cost, 1, refs[0].b, refs[1].b));
    }
    let mut boxes = [B4::EMPTY; EXACT_MAX];
    let mut c = [[0u64; EXACT_MAX]; 3];
    for (i, r) in refs.iter().enumerate() {
        boxes[i] = r.b;
        let (c2, id) = (r.c2(), u64::from(r.idx()));
        for (a, ca) in c.iter_mut().enumerate() {
            // `+ 0.0` folds -0.0 into +0.0: equal centroids tie, and the index decides, as `<` on floats would.
            ca[i] = u64::from(crate::keys::ordered_bits(c2[a] + 0.0)) << 32 | id;
        }
    }
    // (cost, imbalance, axis, left size); the order of the best axis is recomputed at the end.
    let mut best: Option<(f32, usize, usize, usize)> = None;
    let mut order = [0usize; EXACT_MAX];
    for (a, ca) in c.iter().enumerate() {
        ranks_into(&ca[..n], &mut order);
        let mut right_area = [0.0f32; EXACT_MAX];
        let mut acc = B4::EMPTY;
        for i in (1..n).rev() {
            acc = acc.union(boxes[order[i]]);
            right_area[i] = acc.half_area();
        }
        let mut acc = B4::EMPTY;
        for i in 1..n {
            acc = acc.union(boxes[order[i - 1]]);
            let cost = acc.half_area() * i as f32 + right_area[i] * (n - i) as f32;
            let imbalance = (2 * i).abs_diff(n);
            let better = match best {
                None => true,
                Some((bc, bi, _, _)) => cost < bc || (cost == bc && imbalance < bi),
            };
            if better {
                best = Some((cost, imbalance, a, i));
            }
        }
    }
    let (cost, _, axis, m) = best?;
    ranks_into(&c[axis][..n], &mut order);
    let mut sorted = [refs[0]; EXACT_MAX];
    for (k, &i) in order[..n].iter().enumerate() {
        sorted[k] = refs[i];
    }
    refs.copy_from_slice(&sorted[..n]);
    let (mut lb, mut rb) = (B4::EMPTY, B4::EMPTY);
    for (k, r) in refs.iter().enumerate() {
        if k < m {
            lb = lb.union(r.b);
        } else {
            rb = rb.union(r.b);
        }
    }
    Some((cost, m, lb, rb))
}

/// The order of `keys` (distinct): `order[rank] = i`, the rank of `i` counted branch-free.
#[inline]
fn ranks_into(keys: &[u64], order: &mut [usize; EXACT_MAX]) {
    for (i, &ki) in keys.iter().enumerate() {
        let rank: usize = keys.iter().map(|&kj| (kj < ki) as usize).sum();
        order[rank] = i;
    }
}

/// Sorts `refs` (whose centroids coincide) by the vertex positions of `same`'s triangles and moves every copy of a
/// triangle (bit-identical positions in the same order, larger triangle index) to the end, adding (copy, kept)
/// triangle indices to `pairs`; returns the number of triangles kept (they come first, in position order).
fn dedup_copies(refs: &mut [Ref], same: &Mesh, pairs: &mut Vec<(u32, u32)>) -> usize {
    let key = |r: &Ref| position_bits(same, r.idx());
    refs.sort_unstable_by(|a, b| key(a).cmp(&key(b)).then(a.idx().cmp(&b.idx())));
    let mut kept: Vec<Ref> = Vec::with_capacity(refs.len());
    let mut copies: Vec<Ref> = Vec::new();
    for r in refs.iter() {
        match kept.last() {
            Some(k) if key(k) == key(r) => {
                pairs.push((r.idx(), k.idx()));
                copies.push(*r);
            }
            _ => kept.push(*r),
        }
    }
    let u = kept.len();
    refs[..u].copy_from_slice(&kept);
    refs[u..].copy_from_slice(&copies);
    u
}

/// Whether a split of cost `A_L N_L + A_R N_R` (in half areas) beats a leaf for a node of `n` references in
/// `bounds`.
#[inline]
fn split_worth(bounds: &B4, n: usize, cost: f32) -> bool {
    let area = f64::from(bounds.half_area());
    SAH_TRAVERSAL_COST * area + SAH_INTERSECTION_COST * f64::from(cost) < SAH_INTERSECTION_COST * area * n as f64
}

/// Builds the subtree of a node of at most [`EXACT_MAX`] references (node `base` first in its `2 n - 1` slots of
/// `nodes`) from a small explicit stack, with no call per node: every node is split by [`exact_split`] or made a
/// leaf. A node that must be split (over [`BvhOptions::max_leaf`]) whose centroids coincide first keeps one of the
/// copies of each triangle ([`dedup_copies`]), as larger nodes do.
fn build_small(refs: &mut [Ref], nodes: &mut [BvhNode], base: u32, first: u32, bounds: B4, cx: &Ctx<'_>) {
    let max_leaf = cx.o.max_leaf;
    // (first reference, count, slot in `nodes`, box); a subtree of k references holds at most k - 1 pending
    // right children.
    let mut stack = [(0usize, 0usize, 0usize, B4::EMPTY); EXACT_MAX + 1];
    let mut top = 1;
    stack[0] = (0, refs.len(), 0, bounds);
    while top > 0 {
        top -= 1;
        let (s, n, slot, b) = stack[top];
        if let (true, Some(same)) = (n > max_leaf, cx.same) {
            let r = &mut refs[s..s + n];
            let c = r[0].c2().truncate();
            if r.iter().all(|x| x.c2().truncate() == c) {
                let u = cx.keep_one_copy(r, same);
                if u < n {
                    // The same node over the triangles kept (the copies' boxes are theirs, so the box stays).
                    stack[top] = (s, u, slot, b);
                    top += 1;
                    continue;
                }
            }
        }
        let (o, aabb) = (first + s as u32, b.aabb());
        let split = match exact_split(&mut refs[s..s + n]) {
            Some((cost, m, lb, rb)) if n > max_leaf || split_worth(&b, n, cost) => Some((m, lb, rb)),
            _ => None,
        };
        match split {
            Some((m, lb, rb)) => {
                let l = base + slot as u32 + 1;
                nodes[slot] = BvhNode::internal(&aabb, l, l + 2 * m as u32 - 1);
                stack[top] = (s + m, n - m, slot + 2 * m, rb);
                stack[top + 1] = (s, m, slot + 1, lb);
                top += 2;
            }
            None => nodes[slot] = BvhNode::leaf(&aabb, o, n as u32),
        }
    }
}

/// What every node of one build reads.
struct Ctx<'a> {
    o: BvhOptions,
    same: Option<&'a Mesh>,
    /// (copy, kept) triangle indices of the copies dropped ([`dedup_copies`]).
    copies: &'a std::sync::Mutex<Vec<(u32, u32)>>,
}

impl Ctx<'_> {
    /// [`dedup_copies`] of `refs` (whose centroids coincide), the pairs added to the build's list; returns the
    /// number of triangles kept.
    fn keep_one_copy(&self, refs: &mut [Ref], same: &Mesh) -> usize {
        let mut pairs = Vec::new();
        let u = dedup_copies(refs, same, &mut pairs);
        // A poisoned lock only means another subtree panicked; its list is still whole.
        self.copies.lock().unwrap_or_else(|e| e.into_inner()).extend(pairs);
        u
    }
    /// Bins for a node of `n` references: [`TOP_BINS`] for large nodes, [`BvhOptions::bins`] below, and as many as
    /// references for small nodes (the same splits for much less sweeping).
    fn bins_for(&self, n: usize) -> usize {
        let nb = if n >= TOP_BINS_MIN_REFS { TOP_BINS.max(self.o.bins) } else { self.o.bins };
        nb.min(n).max(2)
    }
}

/// Nodes of at least this many references are binned into [`TOP_BINS`] bins: the binning pass costs the same, and
/// the planes near the root, which decide most of the SAH cost, are placed twice as finely.
const TOP_BINS_MIN_REFS: usize = 2048;
const TOP_BINS: usize = 32;

/// Builds the subtree over `refs` into `nodes` (its `2 n - 1` slots, node `base` first); `first` is the position
/// of `refs[0]` among all references; `bounds` and `cb` are the box and the centroid box (of `min + max`) of
/// `refs`; `bins` is this thread's scratch.
#[allow(clippy::too_many_arguments)]
fn build_rec(
    refs: &mut [Ref],
    nodes: &mut [BvhNode],
    base: u32,
    first: u32,
    depth: u32,
    (bounds, cb): (B4, B4),
    cx: &Ctx<'_>,
    bins: &mut Bins,
    tmp: &mut [Ref],
) {
    let n = refs.len();
    let o = &cx.o;
    let leaf = |nodes: &mut [BvhNode]| nodes[0] = BvhNode::leaf(&bounds.aabb(), first, n as u32);
    if n <= 1 {
        leaf(nodes);
        return;
    }
    if n <= EXACT_MAX {
        build_small(refs, nodes, base, first, bounds, cx);
        return;
    }
    let mut split = None;
    if depth < MAX_SAH_DEPTH {
        if let Some(sp) = find_split(refs, &cb, cx.bins_for(n), bins) {
            if split_worth(&bounds, n, sp.cost) || n > o.max_leaf {
                let (m, lcb, rcb) = partition_split(refs, tmp, &sp.g, sp.axis, sp.bin);
                if m > 0 && m < n {
                    split = Some((m, [sp.left, lcb, sp.right, rcb]));
                }
            } else {
                leaf(nodes);
                return;
            }
        }
    }
    let (m, [lb, lcb, rb, rcb]) = match split {
        Some(s) => s,
        None if n > o.max_leaf || depth >= MAX_SAH_DEPTH && n > 1 => {
            // Coincident centroids: copies of one triangle keep the first (see the module docs); the boxes of the
            // copies are their kept triangle's, so the bounds stay.
            if let Some(same) = cx.same.filter(|_| cb.min.truncate() == cb.max.truncate()) {
                let u = cx.keep_one_copy(refs, same);
                if u < n {
                    let cx = Ctx { o: cx.o, same: None, copies: cx.copies };
                    build_rec(&mut refs[..u], nodes, base, first, depth, (bounds, cb), &cx, bins, tmp);
                    return;
                }
            }
            let axis = cb.aabb().longest_axis();
            let m = n / 2;
            refs.select_nth_unstable_by(m, |a, b| a.c2()[axis].total_cmp(&b.c2()[axis]).then(a.idx().cmp(&b.idx())));
            let (l, r) = (ref_bounds(&refs[..m]), ref_bounds(&refs[m..]));
            (m, [l.0, l.1, r.0, r.1])
        }
        None => {
            leaf(nodes);
            return;
        }
    };
    let m32 = m as u32;
    nodes[0] = BvhNode::internal(&bounds.aabb(), base + 1, base + 2 * m32);
    let (_, rest) = nodes.split_at_mut(1);
    let (ln, rn) = rest.split_at_mut(2 * m - 1);
    let (lr, rr) = refs.split_at_mut(m);
    let (lt, rt) = tmp.split_at_mut(m);
    if n >= o.parallel_threshold {
        rayon::join(
            || build_rec(lr, ln, base + 1, first, depth + 1, (lb, lcb), cx, bins, lt),
            || build_rec(rr, rn, base + 2 * m32, first + m32, depth + 1, (rb, rcb), cx, &mut Bins::new(), rt),
        );
    } else {
        build_rec(lr, ln, base + 1, first, depth + 1, (lb, lcb), cx, bins, lt);
        build_rec(rr, rn, base + 2 * m32, first + m32, depth + 1, (rb, rcb), cx, bins, rt);
    }
}

/// Copies the nodes reachable from node 0 of `sparse` into a compact array where the two children of every node
/// are adjacent (`right = left + 1`, one cache line for both boxes), subtrees in depth-first order.
pub(crate) fn compact_sibling_pairs(sparse: &[BvhNode]) -> Vec<BvhNode> {
    compact_sibling_pairs_from(sparse, 0)
}

/// [`compact_sibling_pairs`] of the tree rooted at node `root` of `sparse` (which comes first in the result).
pub(crate) fn compact_sibling_pairs_from(sparse: &[BvhNode], root: u32) -> Vec<BvhNode> {
    let mut out: Vec<BvhNode> = Vec::new();
    let Some(r) = sparse.get(root as usize) else { return out };
    out.push(*r);
    let mut stack = vec![(root, 0u32)];
    while let Some((old, new)) = stack.pop() {
        let node = sparse[old as usize];
        if node.is_leaf() {
            continue;
        }
        let k = out.len() as u32;
        out.push(sparse[node.left_or_first as usize]);
        out.push(sparse[node.right_or_count as usize]);
        let p = &mut out[new as usize];
        p.left_or_first = k;
        p.right_or_count = k + 1;
        stack.push((node.right_or_count, k + 1));
        stack.push((node.left_or_first, k));
    }
    out
}

/// Builds a binned-SAH tree over triangle boxes; `same`, the mesh of the boxes, lets it keep one of the
/// copies of a triangle ([`dedup_copies`]). Returns the compact nodes, the order of the input boxes (the leaves'
/// entries, and the dropped copies at the places their nodes had) and, per dropped copy, its position in that
/// order and the position of the copy kept.
pub(crate) fn build_sah_tree(
    boxes: &[Aabb],
    o: &BvhOptions,
    same: Option<&Mesh>,
) -> (Vec<BvhNode>, Vec<u32>, Vec<(u32, u32)>) {
    let n = boxes.len();
    if n == 0 {
        return (Vec::new(), Vec::new(), Vec::new());
    }
    let mut refs: Vec<Ref> = boxes.par_iter().enumerate().map(|(i, b)| Ref::new(b, i as u32)).collect();
    let mut sparse = vec![BvhNode::default(); 2 * n - 1];
    let o = BvhOptions { bins: o.bins.clamp(2, MAX_BINS), max_leaf: o.max_leaf.max(1), ..*o };
    let bounds = ref_bounds(&refs);
    let mut tmp = refs.clone();
    let copies = std::sync::Mutex::new(Vec::new());
    build_rec(&mut refs, &mut sparse, 0, 0, 0, bounds, &Ctx { o, same, copies: &copies }, &mut Bins::new(), &mut tmp);
    let nodes = compact_sibling_pairs(&sparse);
    let order: Vec<u32> = refs.iter().map(|r| r.idx()).collect();
    let mut copies = copies.into_inner().unwrap_or_else(|e| e.into_inner());
    if !copies.is_empty() {
        let mut pos = vec![0u32; n];
        for (p, &id) in order.iter().enumerate() {
            pos[id as usize] = p as u32;
        }
        for c in &mut copies {
            *c = (pos[c.0 as usize], pos[c.1 as usize]);
        }
        copies.sort_unstable();
    }
    (nodes, order, copies)
}

/// Binned-SAH BVH (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    tree: BvhTree,
}

impl Bvh {
    /// Builds with explicit options.
    pub fn build_with(mesh: &Mesh, options: &BvhOptions) -> Result<Self, AccelError> {
        crate::in_pool(|| Self::build_here(mesh, options))
    }

    fn build_here(mesh: &Mesh, options: &BvhOptions) -> Result<Self, AccelError> {
        let (tris, boxes) = prepare(mesh, "bvh")?;
        let (mut nodes, order, copies) = build_sah_tree(&boxes, options, Some(mesh));
        super::reinsert::reinsert(&mut nodes, options.reinsertion, REINSERTION_ROUNDS);
        let tris = order.par_iter().map(|&i| tris[i as usize]).collect();
        Ok(Bvh { tree: BvhTree { nodes, tris, ids: order, copies } })
    }
    /// Refits the tree to the positions of `mesh` (the next frame of an animation): see [`BvhTree::refit`].
    pub fn refit(&mut self, mesh: &Mesh) -> Result<(), AccelError> {
        self.tree.refit(mesh)
    }
    /// The nodes and triangle records.
    pub fn tree(&self) -> &BvhTree {
        &self.tree
    }
}

impl AccelStructure for Bvh {
    fn build(mesh: &Mesh) -> Result<Self, AccelError> {
        Bvh::build_with(mesh, &BvhOptions::default())
    }
    fn name(&self) -> StructureName {
        StructureName::Bvh
    }
    traversal_methods!(tree);
    fn build_work(&self) -> Option<f64> {
        let nodes = self.tree.nodes.len() as f64;
        self.tree.build_work().map(|levels| levels + crate::accel::node_build_work(StructureName::Bvh) * nodes)
    }
    fn validate(&self) -> Result<AccelStats, AccelError> {
        self.tree.validate("bvh")
    }
    fn memory_bytes(&self) -> usize {
        self.tree.memory_bytes()
    }
    fn sah_cost(&self) -> Option<f64> {
        Some(self.tree.sah_cost())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate;

    /// The leaves of a tree as (first, count, box bits), sorted.
    fn leaves(t: &BvhTree) -> Vec<(u32, u32, [u32; 6])> {
        let mut v: Vec<_> = t
            .nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| {
                let b = [n.min, n.max].concat();
                (n.left_or_first, n.count(), std::array::from_fn(|i| b[i].to_bits()))
            })
            .collect();
        v.sort_unstable();
        v
    }

    #[test]
    fn reinsertion_keeps_the_leaves_and_never_raises_the_sah_cost() {
        let scenes = [
            generate::overlapping_large(3_000, 7),
            generate::random_soup(5_000, 11),
            generate::teapot_in_stadium(3),
            generate::clustered(4_000, 9, 5),
            generate::flat(2_000, 2),
            generate::fan_polygon(500),
            generate::two_triangles(),
        ];
        let mut lowered = 0;
        for mesh in &scenes {
            let off = Bvh::build_with(mesh, &BvhOptions { reinsertion: 0.0, ..Default::default() }).unwrap();
            for ratio in [0.02, 0.3] {
                let on = Bvh::build_with(mesh, &BvhOptions { reinsertion: ratio, ..Default::default() }).unwrap();
                on.validate().unwrap();
                assert_eq!(leaves(&on.tree), leaves(&off.tree));
                assert_eq!(
                    (on.tree.nodes.len(), &on.tree.ids, &on.tree.copies),
                    (off.tree.nodes.len(), &off.tree.ids, &off.tree.copies)
                );
                // Every internal box is the union of its children's, siblings adjacent.
                for n in on.tree.nodes.iter().filter(|n| !n.is_leaf()) {
                    assert_eq!(n.right_or_count, n.left_or_first + 1);
                    let (l, r) = (on.tree.nodes[n.left_or_first as usize], on.tree.nodes[n.right_or_count as usize]);
                    assert_eq!(n.aabb(), Aabb::union(&l.aabb(), &r.aabb()));
                }
                let (a, b) = (on.tree.sah_cost(), off.tree.sah_cost());
                assert!(a <= b * (1.0 + 1e-9), "reinsertion raised the SAH cost from {b} to {a}");
                lowered += usize::from(a < b);
            }
        }
        // The pass does something (on these scenes a little; tests/core/accel.rs checks Sponza, its case).
        assert!(lowered >= 4, "reinsertion lowered the SAH cost of {lowered} builds");
    }

    #[test]
    fn small_nodes_keep_one_copy_of_a_triangle_too() {
        // A fan over three points: copies of three distinct triangles (vertex indices), each group with coincident
        // centroids. With one triangle per leaf every group must be split, so each keeps one copy, also in nodes of
        // at most 8 references (the small-node path split them apart before it kept copies); with the default 8 per
        // leaf only groups over 8 are.
        for (k, max_leaf, copies) in [(5, 1, 2), (8, 1, 5), (30, 1, 27), (30, 8, 27), (8, 8, 0)] {
            let mesh = generate::fan_polygon(k);
            let bvh = Bvh::build_with(&mesh, &BvhOptions { max_leaf, ..Default::default() }).unwrap();
            bvh.validate().unwrap();
            assert_eq!(bvh.tree.copies.len(), copies, "fan of {k}, max_leaf {max_leaf}");
        }
    }

    #[test]
    fn validation_refuses_a_copy_that_is_not_one() {
        let bvh = Bvh::build(&generate::fan_polygon(30)).unwrap();
        assert_eq!(bvh.tree.copies.len(), 27);
        bvh.validate().unwrap();
        // A zero-area leg listed as a copy of the unit triangle: other record bits.
        let (copy, _) = bvh.tree.copies[0];
        let other = bvh.tree.copies.iter().find(|&&(c, _)| bvh.tree.tris[c as usize] != bvh.tree.tris[copy as usize]);
        let mut bad = bvh.clone();
        bad.tree.copies[0].1 = other.unwrap().1;
        assert!(bad.validate().unwrap_err().to_string().contains("no later copy"));
        // A copy dropped from the list: an entry in no leaf.
        let mut bad = bvh.clone();
        bad.tree.copies.pop();
        assert!(bad.validate().unwrap_err().to_string().contains("in no leaf"));
        // A copy listed twice.
        let mut bad = bvh.clone();
        let first = bad.tree.copies[0];
        bad.tree.copies.push(first);
        assert!(bad.validate().is_err());
        // The kept record standing for itself (a smaller index is required).
        let mut bad = bvh;
        bad.tree.copies[0].1 = bad.tree.copies[0].0;
        assert!(bad.validate().is_err());
    }
}
