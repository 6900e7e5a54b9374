//! Binned-SAH BVH (Wald 2007), built in parallel with rayon.
//!
//! Binned SAH after Wald 2007: centroids binned into [`BvhOptions::bins`] bins per axis on the centroid bounds,
//! all three axes evaluated, the plane of least `K_T * A + K_I * (A_L N_L + A_R N_R)` taken when it beats a leaf
//! (`K_I * A * N`) or when the node holds more than [`BvhOptions::max_leaf`] triangles. Nodes whose centroids
//! coincide, or deeper than 64 levels, are split at the object median. A node whose centroids coincide and that
//! holds copies of one triangle (the same three vertex indices in the same order, as a polygon face over few
//! points loads to) keeps only the copy of the smallest index: under the tie rule no other copy can be the closest
//! hit (its record, `t`, `u` and `v` are the same bits) nor change an any-hit answer, and every ray that reaches them
//! would otherwise test them all. The copies stay among the triangle records (so a refit, which keeps the vertex
//! indices, keeps them copies) in no leaf; [`super::BvhTree::copies`] lists them. Subtrees above
//! [`BvhOptions::parallel_threshold`] triangles are built in parallel (`rayon::join`), and the binning of large
//! nodes is parallel too; every subtree writes into its own slice of a preallocated array (a subtree of `k`
//! triangles owns `2k - 1` slots), which a final pass compacts with siblings adjacent. The result does not depend on
//! the number of threads.

use super::{BvhNode, BvhTree};
use crate::accel::{
    prepare, AccelError, AccelStats, AccelStructure, StructureName, SAH_INTERSECTION_COST, SAH_TRAVERSAL_COST,
};
use crate::geom::Aabb;
use crate::mesh::Mesh;
use glam::Vec4;
use rayon::prelude::*;

/// Options of the binned-SAH builder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BvhOptions {
    /// Bins per axis (2 to 16).
    pub bins: usize,
    /// Largest leaf; nodes above it are always split.
    pub max_leaf: usize,
    /// Subtrees with at least this many triangles are built in parallel.
    pub parallel_threshold: usize,
}

impl Default for BvhOptions {
    fn default() -> Self {
        BvhOptions { bins: 16, max_leaf: 8, parallel_threshold: 4096 }
    }
}

const MAX_BINS: usize = 16;
const MAX_SAH_DEPTH: u32 = 64;
const PAR_BIN_THRESHOLD: usize = 65_536;

/// A box in SIMD registers for the builder (`w` lanes are ignored).
#[derive(Clone, Copy, Debug)]
struct B4 {
    min: Vec4,
    max: Vec4,
}

impl B4 {
    const EMPTY: B4 = B4 { min: Vec4::splat(f32::INFINITY), max: Vec4::splat(f32::NEG_INFINITY) };
    #[inline]
    fn union(self, o: B4) -> B4 {
        B4 { min: self.min.min(o.min), max: self.max.max(o.max) }
    }
    #[inline]
    fn grow(&mut self, p: Vec4) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    #[inline]
    fn half_area(&self) -> f32 {
        let e = self.max - self.min;
        if e.x < 0.0 {
            return 0.0;
        }
        e.x * e.y + e.y * e.z + e.z * e.x
    }
    fn aabb(&self) -> Aabb {
        Aabb::new(self.min.truncate(), self.max.truncate())
    }
}

/// A triangle reference during the build: its box, with the triangle index in the bits of `min.w`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Ref {
    b: B4,
}

impl Ref {
    fn new(b: &Aabb, idx: u32) -> Self {
        Ref { b: B4 { min: b.min.extend(f32::from_bits(idx)), max: b.max.extend(0.0) } }
    }
    #[inline]
    fn idx(&self) -> u32 {
        self.b.min.w.to_bits()
    }
    /// For a copy dropped from the leaves ([`dedup_copies`]): the triangle index of the copy kept, plus one (0: not
    /// a dropped copy).
    #[inline]
    fn kept_plus_one(&self) -> u32 {
        self.b.max.w.to_bits()
    }
    /// Twice the box centre.
    #[inline]
    fn c2(&self) -> Vec4 {
        self.b.min + self.b.max
    }
}

#[derive(Clone, Copy)]
struct Bin {
    b: B4,
    n: u32,
}

const EMPTY_BIN: Bin = Bin { b: B4::EMPTY, n: 0 };

type Bins = [[Bin; MAX_BINS]; 3];

struct Binning {
    cmin: Vec4,
    k: Vec4,
    nb: usize,
}

impl Binning {
    #[inline]
    fn bins(&self, c2: Vec4) -> [usize; 3] {
        // Clamped in f32 first: the integer conversions then need no saturation.
        let x = ((c2 - self.cmin) * self.k).clamp(Vec4::ZERO, Vec4::splat((self.nb - 1) as f32));
        [x.x as u32 as usize, x.y as u32 as usize, x.z as u32 as usize]
    }
    #[inline]
    fn bin(&self, c2: Vec4, axis: usize) -> usize {
        let x = (c2[axis] - self.cmin[axis]) * self.k[axis];
        (x as usize).min(self.nb - 1)
    }
}

fn bin_refs(refs: &[Ref], g: &Binning) -> Bins {
    let mut bins = [[EMPTY_BIN; MAX_BINS]; 3];
    bin_refs_into(refs, g, &mut bins);
    bins
}

fn bin_refs_into(refs: &[Ref], g: &Binning, bins: &mut Bins) {
    for r in refs {
        let [b0, b1, b2] = g.bins(r.c2());
        for (axis_bins, bi) in bins.iter_mut().zip([b0, b1, b2]) {
            let bin = &mut axis_bins[bi];
            bin.n += 1;
            bin.b = bin.b.union(r.b);
        }
    }
}

fn merge_bins(mut a: Bins, b: Bins) -> Bins {
    for (x, y) in a.iter_mut().zip(b.iter()) {
        for (p, q) in x.iter_mut().zip(y.iter()) {
            p.n += q.n;
            p.b = p.b.union(q.b);
        }
    }
    a
}

fn ref_bounds(refs: &[Ref]) -> (B4, B4) {
    let f = |rs: &[Ref]| {
        let mut b = B4::EMPTY;
        let mut cb = B4::EMPTY;
        for r in rs {
            b = b.union(r.b);
            cb.grow(r.c2());
        }
        (b, cb)
    };
    if refs.len() >= PAR_BIN_THRESHOLD {
        refs.par_chunks(16_384).map(f).reduce(|| (B4::EMPTY, B4::EMPTY), |x, y| (x.0.union(y.0), x.1.union(y.1)))
    } else {
        f(refs)
    }
}

/// Best binned split: `(axis, first bin of the right side, cost = A_L N_L + A_R N_R in half areas)`.
fn find_split(refs: &[Ref], cb: &B4, nb: usize) -> Option<(usize, usize, f32, Binning)> {
    let ext = cb.max - cb.min;
    let kf = |e: f32| {
        if e > 0.0 {
            nb as f32 * (1.0 - 1e-6) / e
        } else {
            0.0
        }
    };
    let g = Binning { cmin: cb.min, k: Vec4::new(kf(ext.x), kf(ext.y), kf(ext.z), 0.0), nb };
    if g.k == Vec4::ZERO {
        return None;
    }
    let mut bins = [[EMPTY_BIN; MAX_BINS]; 3];
    if refs.len() >= PAR_BIN_THRESHOLD {
        bins = refs.par_chunks(16_384).map(|c| bin_refs(c, &g)).reduce(|| [[EMPTY_BIN; MAX_BINS]; 3], merge_bins);
    } else {
        bin_refs_into(refs, &g, &mut bins);
    }
    let n = refs.len() as i64;
    let mut best: Option<(usize, usize, f32, i64)> = None;
    for (a, ab) in bins.iter().enumerate() {
        if g.k[a] == 0.0 {
            continue;
        }
        sweep_bins::<B4, MAX_BINS>(
            nb,
            |i| (ab[i].b, ab[i].n),
            |i, cost, cnt| {
                let imbalance = (2 * cnt as i64 - n).abs();
                let better = match best {
                    None => true,
                    Some((_, _, bc, bi)) => cost < bc || (cost == bc && imbalance < bi),
                };
                if better {
                    best = Some((a, i, cost, imbalance));
                }
            },
        );
    }
    best.map(|(a, i, c, _)| (a, i, c, g))
}

/// A box the SAH sweep accumulates: [`Aabb`] (the HLBVH's top level) or the builder's SIMD box.
pub(crate) trait SweepBox: Copy {
    /// The empty box.
    const EMPTY: Self;
    /// The smallest box containing both.
    fn union(self, o: Self) -> Self;
    /// Half the surface area, `e.x e.y + e.y e.z + e.z e.x` (0 for the empty box).
    fn half_area(&self) -> f32;
}

impl SweepBox for B4 {
    const EMPTY: Self = B4::EMPTY;
    #[inline]
    fn union(self, o: Self) -> Self {
        B4::union(self, o)
    }
    #[inline]
    fn half_area(&self) -> f32 {
        B4::half_area(self)
    }
}

impl SweepBox for Aabb {
    const EMPTY: Self = Aabb::EMPTY;
    #[inline]
    fn union(self, o: Self) -> Self {
        Aabb::union(&self, &o)
    }
    #[inline]
    fn half_area(&self) -> f32 {
        Aabb::half_area(self)
    }
}

/// The binned-SAH sweep over one axis, shared by the builder and the HLBVH's top level: `bin(i)` is the box and
/// the count of bin `i` of `nb <= N`. Right sides are accumulated by a backward sweep, left sides forward (the same
/// boxes, unions being exact, as summing the bins of each side from scratch); for every plane `s` in `1 .. nb`
/// (left: bins `0 .. s`) with both sides non-empty, `visit(s, cost, n_left)` gets
/// `cost = half_area(left) * n_left + half_area(right) * n_right` in f32, evaluated in that order.
#[inline]
pub(crate) fn sweep_bins<B: SweepBox, const N: usize>(
    nb: usize,
    bin: impl Fn(usize) -> (B, u32),
    mut visit: impl FnMut(usize, f32, u32),
) {
    let nb = nb.min(N);
    let mut right_area = [0.0f32; N];
    let mut right_n = [0u32; N];
    let mut acc = B::EMPTY;
    let mut cnt = 0u32;
    for i in (1..nb).rev() {
        let (b, n) = bin(i);
        acc = acc.union(b);
        cnt += n;
        right_area[i] = acc.half_area();
        right_n[i] = cnt;
    }
    let mut acc = B::EMPTY;
    let mut cnt = 0u32;
    for i in 1..nb {
        let (b, n) = bin(i - 1);
        acc = acc.union(b);
        cnt += n;
        if cnt == 0 || right_n[i] == 0 {
            continue;
        }
        visit(i, acc.half_area() * cnt as f32 + right_area[i] * right_n[i] as f32, cnt);
    }
}

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

/// In-place partition that also returns the box and centroid box (of `min + max`) of each side.
fn partition_with_bounds(v: &mut [Ref], mut left: impl FnMut(&Ref) -> bool) -> (usize, [B4; 4]) {
    let (mut lb, mut lcb, mut rb, mut rcb) = (B4::EMPTY, B4::EMPTY, B4::EMPTY, B4::EMPTY);
    let mut i = 0;
    let mut j = v.len();
    while i < j {
        let r = v[i];
        if left(&r) {
            lb = lb.union(r.b);
            lcb.grow(r.c2());
            i += 1;
        } else {
            rb = rb.union(r.b);
            rcb.grow(r.c2());
            j -= 1;
            v.swap(i, j);
        }
    }
    (i, [lb, lcb, rb, rcb])
}

/// Sorts `refs` (whose centroids coincide) by vertex indices `same` and moves every copy of a triangle (equal
/// vertex indices, larger triangle index) to the end, marked with the index of the copy kept; returns the number
/// of triangles kept (they come first, in vertex-index order).
fn dedup_copies(refs: &mut [Ref], same: &[[u32; 3]]) -> usize {
    let key = |r: &Ref| same.get(r.idx() as usize).copied().unwrap_or([u32::MAX; 3]);
    refs.sort_unstable_by(|a, b| key(a).cmp(&key(b)).then(a.idx().cmp(&b.idx())));
    let mut kept: Vec<Ref> = Vec::with_capacity(refs.len());
    let mut copies: Vec<Ref> = Vec::new();
    for r in refs.iter() {
        match kept.last() {
            Some(k) if key(k) == key(r) => {
                let mut c = *r;
                c.b.max.w = f32::from_bits(k.idx() + 1);
                copies.push(c);
            }
            _ => kept.push(*r),
        }
    }
    let u = kept.len();
    refs[..u].copy_from_slice(&kept);
    refs[u..].copy_from_slice(&copies);
    u
}

#[allow(clippy::too_many_arguments)]
fn build_rec(
    refs: &mut [Ref],
    nodes: &mut [BvhNode],
    base: u32,
    first: u32,
    depth: u32,
    (bounds, cb): (B4, B4),
    o: &BvhOptions,
    same: Option<&[[u32; 3]]>,
) {
    let n = refs.len();
    let leaf = |nodes: &mut [BvhNode]| nodes[0] = BvhNode::leaf(&bounds.aabb(), first, n as u32);
    if n <= 1 {
        leaf(nodes);
        return;
    }
    let mut split = None;
    if depth < MAX_SAH_DEPTH {
        // Small nodes get as many bins as references: the same splits for much less sweeping.
        if let Some((axis, bin, cost, g)) = find_split(refs, &cb, o.bins.min(n).max(2)) {
            let area = bounds.half_area() as f64;
            let split_cost = SAH_TRAVERSAL_COST * area + SAH_INTERSECTION_COST * cost as f64;
            let leaf_cost = SAH_INTERSECTION_COST * area * n as f64;
            if split_cost < leaf_cost || n > o.max_leaf {
                let (m, b) = partition_with_bounds(refs, |r| g.bin(r.c2(), axis) < bin);
                if m > 0 && m < n {
                    split = Some((m, b));
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
            if let Some(same) = same.filter(|_| cb.min.truncate() == cb.max.truncate()) {
                let u = dedup_copies(refs, same);
                if u < n {
                    build_rec(&mut refs[..u], nodes, base, first, depth, (bounds, cb), o, None);
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
    if n >= o.parallel_threshold {
        rayon::join(
            || build_rec(lr, ln, base + 1, first, depth + 1, (lb, lcb), o, same),
            || build_rec(rr, rn, base + 2 * m32, first + m32, depth + 1, (rb, rcb), o, same),
        );
    } else {
        build_rec(lr, ln, base + 1, first, depth + 1, (lb, lcb), o, same);
        build_rec(rr, rn, base + 2 * m32, first + m32, depth + 1, (rb, rcb), o, same);
    }
}

/// Copies the nodes reachable from node 0 of `sparse` into a compact array where the two children of every node
/// are adjacent (`right = left + 1`, one cache line for both boxes), subtrees in depth-first order.
pub(crate) fn compact_sibling_pairs(sparse: &[BvhNode]) -> Vec<BvhNode> {
    let mut out: Vec<BvhNode> = Vec::new();
    let Some(root) = sparse.first() else { return out };
    out.push(*root);
    let mut stack = vec![(0u32, 0u32)];
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

/// Builds a binned-SAH tree over triangle boxes; `same`, the triangles' vertex indices, lets it keep one of the
/// copies of a triangle ([`dedup_copies`]). Returns the compact nodes, the order of the input boxes (the leaves'
/// entries, and the dropped copies at the places their nodes had) and, per dropped copy, its position in that
/// order and the position of the copy kept.
pub(crate) fn build_sah_tree(
    boxes: &[Aabb],
    o: &BvhOptions,
    same: Option<&[[u32; 3]]>,
) -> (Vec<BvhNode>, Vec<u32>, Vec<(u32, u32)>) {
    let n = boxes.len();
    if n == 0 {
        return (Vec::new(), Vec::new(), Vec::new());
    }
    let mut refs: Vec<Ref> = boxes.par_iter().enumerate().map(|(i, b)| Ref::new(b, i as u32)).collect();
    let mut sparse = vec![BvhNode::default(); 2 * n - 1];
    let o = BvhOptions { bins: o.bins.clamp(2, MAX_BINS), max_leaf: o.max_leaf.max(1), ..*o };
    let bounds = ref_bounds(&refs);
    build_rec(&mut refs, &mut sparse, 0, 0, 0, bounds, &o, same);
    let nodes = compact_sibling_pairs(&sparse);
    let order: Vec<u32> = refs.iter().map(|r| r.idx()).collect();
    let mut copies = Vec::new();
    if refs.iter().any(|r| r.kept_plus_one() != 0) {
        let mut pos = vec![0u32; n];
        for (p, &id) in order.iter().enumerate() {
            pos[id as usize] = p as u32;
        }
        copies = refs
            .iter()
            .enumerate()
            .filter(|(_, r)| r.kept_plus_one() != 0)
            .map(|(p, r)| (p as u32, pos[(r.kept_plus_one() - 1) as usize]))
            .collect();
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
        let (tris, boxes) = prepare(mesh, "bvh")?;
        let (nodes, order, copies) = build_sah_tree(&boxes, options, Some(&mesh.indices));
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
