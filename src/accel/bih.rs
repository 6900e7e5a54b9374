//! Bounding interval hierarchy (Wächter and Keller 2006): two clip planes per node and the global spatial-median
//! heuristic.
//!
//! # Build
//!
//! The split candidates come from a *candidate box* that starts as the scene box and is halved at its spatial
//! median along its longest axis, independently of the triangles (the global heuristic of Wächter and Keller).
//! Triangles go left when the centre of their box lies below the plane. When both sides are non-empty a node is
//! made: the left clip plane is the largest maximum of the left triangles along the axis, the right clip plane the
//! smallest minimum of the right ones, and each child continues with its half of the candidate box. When one side
//! is empty, the candidate box is replaced by the half that holds the triangles, and where the triangles do not
//! reach into the other half at all, a node cuts that empty space off (its other child is an empty leaf, its clip
//! plane at the triangles' extent; the "empty space cutting" of Wächter and Keller). Leaves hold at
//! most [`BihOptions::max_leaf`] triangles; where halving stops separating the triangles (all centres in one point,
//! or 64 halvings without progress, counted across the empty-space cuts in between) the node is split at the object
//! median instead, and so is every node below it: the count of halvings without progress only starts afresh below
//! a halving that separates. A path thus has at most 64 nodes that separate nothing (zero-area triangles in a
//! coordinate plane would otherwise be cut off again at every halving towards the plane, down to the smallest f32,
//! after every object-median split: 165 levels on a fan of a polygon over three points). Subtrees over
//! [`BihOptions::parallel_threshold`] triangles are built in parallel.
//!
//! # Layout ([`BihNode`], 12 bytes)
//!
//! `flags & 3` is the axis (0, 1, 2) or 3 for a leaf. An internal node's children are adjacent: left at
//! `flags >> 2`, right at `(flags >> 2) + 1`; `clip = [left max, right min]`. A leaf covers triangle records
//! `flags >> 2 .. (flags >> 2) + count` with `count = clip[0].to_bits()`. Node 0 is the root.
//!
//! # Traversal
//!
//! Interval traversal with a stack of `(node, t_entry, t_exit)`: the near child is entered up to its clip plane, the
//! far child from its clip plane (distances widened by a relative `2e-6`), a stacked node is skipped once its entry
//! lies beyond the best hit. `box_tests` counts visited nodes (one test against the scene box first).

use super::bvh::partition;
use super::{
    bytes_of, check_permutation, prepare, sah_cost, triangle_in_box, AccelError, AccelStats, AccelStructure,
    StructureName, TraversalStack, Validation,
};
use crate::accel::copies::record_bits;
use crate::geom::{closer_hit, cull_bound, tie_margin, Hit, Ray, RayInv, TraceCounters};
use crate::geom::{Aabb, Triangle};
use crate::mesh::Mesh;
use glam::Vec3;

/// One BIH node (see the module docs): generated from `struct BihNode` of `glsl/include/trace.glsl`, its one
/// definition, which the device traversal reads; the methods are here.
pub use crate::gpu::shaders::BihNode;

const _: () = assert!(std::mem::size_of::<BihNode>() == 12);

const LEAF: u32 = 3;

impl BihNode {
    /// Whether this is a leaf.
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.flags & 3 == LEAF
    }
    /// Triangle count of a leaf.
    #[inline]
    pub fn count(&self) -> u32 {
        self.clip[0].to_bits()
    }
}

/// Options of the BIH builder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BihOptions {
    /// Largest leaf.
    pub max_leaf: usize,
    /// Subtrees with at least this many triangles are built in parallel.
    pub parallel_threshold: usize,
}

impl Default for BihOptions {
    fn default() -> Self {
        BihOptions { max_leaf: 4, parallel_threshold: 8192 }
    }
}

/// The bounding interval hierarchy (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct Bih {
    nodes: Vec<BihNode>,
    tris: Vec<Triangle>,
    ids: Vec<u32>,
    bounds: Aabb,
    /// Records in no leaf (after every leaf's), copies of another record (`crate::accel::copies`), as
    /// `(record, record kept)`.
    copies: Vec<(u32, u32)>,
}

#[derive(Clone, Copy, Debug)]
struct BRef {
    min: Vec3,
    idx: u32,
    max: Vec3,
}

impl BRef {
    #[inline]
    fn center(&self, a: usize) -> f32 {
        (self.min[a] + self.max[a]) * 0.5
    }
}

/// Subtree: nodes with child indices relative to the subtree's first node, leaves relative to its first record.
struct Sub {
    nodes: Vec<BihNode>,
}

fn leaf_node(first: usize, count: usize) -> BihNode {
    BihNode { clip: [f32::from_bits(count as u32), 0.0], flags: LEAF | ((first as u32) << 2) }
}

/// Halvings of the candidate box without a separating split after which a node is split at the object median.
const MAX_STALL: u32 = 64;

/// Per axis, the least and greatest centre and the least minimum and greatest maximum of a node's triangle boxes:
/// what the halvings of [`build_rec`] read once one has not separated, taken in one pass.
#[derive(Clone, Copy)]
struct Extents {
    centre: [[f32; 3]; 2],
    bounds: [[f32; 3]; 2],
}

impl Extents {
    fn of(refs: &[BRef]) -> Extents {
        let (lo, hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        let mut e = Extents { centre: [lo, hi], bounds: [lo, hi] };
        for r in refs {
            for a in 0..3 {
                let c = r.center(a);
                e.centre[0][a] = e.centre[0][a].min(c);
                e.centre[1][a] = e.centre[1][a].max(c);
                e.bounds[0][a] = e.bounds[0][a].min(r.min[a]);
                e.bounds[1][a] = e.bounds[1][a].max(r.max[a]);
            }
        }
        e
    }
}

/// Builds the subtree over `refs` (records `first ..`), candidate box `cand`, into `out` (root at `out[0]`; child
/// indices relative to `out[0]`). `stall` counts the halvings since the last separating split above; `known` are
/// the extents of `refs` when the caller has them.
///
/// Once a halving has left every centre on one side, the following ones are decided from the extents of `refs`
/// (taken then, in the one pass the empty-space test made before) without a partition or a fold over the triangles
/// each (a memmove where the partition would have rotated the records): a scene
/// of a small object in a vast box halves its candidate box dozens of times before one separates (the stadium
/// family: a path of 73 nodes against 28 for a city). The records are reordered exactly as a partition with every
/// centre on its right side reorders them (a rotation by one), so the tree and its record order are those of a
/// partition at every halving.
fn build_rec(
    refs: &mut [BRef],
    first: usize,
    mut cand: Aabb,
    mut stall: u32,
    o: &BihOptions,
    known: Option<Extents>,
    coincident: &std::sync::atomic::AtomicBool,
) -> Sub {
    let n = refs.len();
    if n <= o.max_leaf.max(1) {
        return Sub { nodes: vec![leaf_node(first, n)] };
    }
    let mut ext = known;
    let mut split = None;
    while stall < MAX_STALL {
        stall += 1;
        let axis = cand.longest_axis();
        let p = (cand.min[axis] + cand.max[axis]) * 0.5;
        if !(p > cand.min[axis] && p < cand.max[axis]) {
            break;
        }
        // No centre below the plane (`m == 0`), every centre below it (`m == n`), or a separating split.
        let m = match ext {
            Some(e) if e.centre[0][axis] >= p => {
                refs.rotate_left(1);
                0
            }
            Some(e) if e.centre[1][axis] < p => n,
            _ => partition(refs, |r| r.center(axis) < p),
        };
        if m > 0 && m < n {
            split = Some((axis, m, p));
            break;
        }
        let e = *ext.get_or_insert_with(|| Extents::of(refs));
        // All centres on one side: continue with that half of the candidate box. When the triangles do not even
        // reach into the other half, cut that empty space off with a node whose other child is an empty leaf.
        if m == 0 {
            cand.min[axis] = p;
            let lo = e.bounds[0][axis];
            if lo > p {
                let r = build_rec(refs, first, cand, stall, o, ext, coincident);
                return combine(axis, [f32::NEG_INFINITY, lo], Sub { nodes: vec![leaf_node(first, 0)] }, r);
            }
        } else {
            cand.max[axis] = p;
            let hi = e.bounds[1][axis];
            if hi < p {
                let l = build_rec(refs, first, cand, stall, o, ext, coincident);
                return combine(axis, [hi, f32::INFINITY], l, Sub { nodes: vec![leaf_node(first + n, 0)] });
            }
        }
    }
    // A separating halving starts the children's count afresh; below an object-median split it goes on (the
    // candidate box has stopped separating anything there).
    let (axis, m, lc, rc, stall) = match split {
        Some((axis, m, p)) => {
            let mut lc = cand;
            lc.max[axis] = p;
            let mut rc = cand;
            rc.min[axis] = p;
            (axis, m, lc, rc, 0)
        }
        None => {
            // Object median along the longest axis of the centres.
            let mut cb = Aabb::EMPTY;
            for r in refs.iter() {
                cb.grow((r.min + r.max) * 0.5);
            }
            if cb.min == cb.max {
                // Every centre in one point: copies of one triangle, perhaps (`Bih::build_with` then looks).
                coincident.store(true, std::sync::atomic::Ordering::Relaxed);
            }
            let axis = cb.longest_axis();
            let m = n / 2;
            refs.select_nth_unstable_by(m, |a, b| a.center(axis).total_cmp(&b.center(axis)).then(a.idx.cmp(&b.idx)));
            let p = refs[m].center(axis);
            let mut lc = cand;
            lc.max[axis] = p.clamp(cand.min[axis], cand.max[axis]);
            let mut rc = cand;
            rc.min[axis] = lc.max[axis];
            (axis, m, lc, rc, stall)
        }
    };
    let (lr, rr) = refs.split_at_mut(m);
    let left_clip = lr.iter().fold(f32::NEG_INFINITY, |a, r| a.max(r.max[axis]));
    let right_clip = rr.iter().fold(f32::INFINITY, |a, r| a.min(r.min[axis]));
    let (l, r) = if n >= o.parallel_threshold {
        rayon::join(
            || build_rec(lr, first, lc, stall, o, None, coincident),
            || build_rec(rr, first + m, rc, stall, o, None, coincident),
        )
    } else {
        (build_rec(lr, first, lc, stall, o, None, coincident), build_rec(rr, first + m, rc, stall, o, None, coincident))
    };
    combine(axis, [left_clip, right_clip], l, r)
}

/// A node over two subtrees. Layout: `[this, left root, right root, left rest..., right rest...]`.
fn combine(axis: usize, clip: [f32; 2], l: Sub, r: Sub) -> Sub {
    let mut nodes = Vec::with_capacity(1 + l.nodes.len() + r.nodes.len());
    nodes.push(BihNode { clip, flags: axis as u32 | (1 << 2) });
    let l_rest = 3; // where left's node 1.. go
    let r_rest = 3 + l.nodes.len() - 1;
    let relocate = |nd: &BihNode, own_rest: usize| -> BihNode {
        if nd.is_leaf() {
            *nd
        } else {
            // Child index k (relative to the subtree root) maps to own_rest + k - 1.
            let k = (nd.flags >> 2) as usize;
            BihNode { clip: nd.clip, flags: (nd.flags & 3) | (((own_rest + k - 1) as u32) << 2) }
        }
    };
    nodes.push(relocate(&l.nodes[0], l_rest));
    nodes.push(relocate(&r.nodes[0], r_rest));
    nodes.extend(l.nodes[1..].iter().map(|nd| relocate(nd, l_rest)));
    nodes.extend(r.nodes[1..].iter().map(|nd| relocate(nd, r_rest)));
    Sub { nodes }
}

impl Bih {
    /// Builds with explicit options.
    pub fn build_with(mesh: &Mesh, o: &BihOptions) -> Result<Self, AccelError> {
        crate::in_pool(|| Self::build_here(mesh, o))
    }

    fn build_here(mesh: &Mesh, o: &BihOptions) -> Result<Self, AccelError> {
        let (tris, boxes) = prepare(mesh, "bih")?;
        if tris.is_empty() {
            return Ok(Bih::default());
        }
        let bounds = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        let coincident = std::sync::atomic::AtomicBool::new(false);
        let first = Bih::build_without(&tris, &boxes, bounds, o, &[], &coincident);
        // Coincident copies cannot be split apart: they show as a node whose centres all lie in one point. Only then
        // are they looked for (a pass and a sort, a quarter of a build), and the tree rebuilt over the smallest index
        // of each group, the copies after the leaves' records.
        if !coincident.load(std::sync::atomic::Ordering::Relaxed) {
            return Ok(first);
        }
        let copies = super::copies::position_copies(mesh, &tris);
        if copies.is_empty() {
            return Ok(first);
        }
        Ok(Bih::build_without(&tris, &boxes, bounds, o, &copies, &coincident))
    }

    /// The tree over every triangle but the copies of `copies` (`(copy, kept)` mesh indices), which follow the
    /// leaves' records.
    fn build_without(
        tris: &[Triangle],
        boxes: &[Aabb],
        bounds: Aabb,
        o: &BihOptions,
        copies: &[(u32, u32)],
        coincident: &std::sync::atomic::AtomicBool,
    ) -> Bih {
        let is_copy = super::copies::copy_mask(boxes.len(), copies);
        let mut refs: Vec<BRef> = boxes
            .iter()
            .enumerate()
            .filter(|&(i, _)| !is_copy[i])
            .map(|(i, b)| BRef { min: b.min, idx: i as u32, max: b.max })
            .collect();
        let sub = build_rec(&mut refs, 0, bounds, 0, o, None, coincident);
        let mut ids: Vec<u32> = refs.iter().map(|r| r.idx).collect();
        ids.extend(copies.iter().map(|&(c, _)| c));
        let mut record = vec![0u32; ids.len()];
        for (r, &i) in ids.iter().enumerate() {
            record[i as usize] = r as u32;
        }
        let copies = copies.iter().map(|&(c, k)| (record[c as usize], record[k as usize])).collect();
        let tris = ids.iter().map(|&i| tris[i as usize]).collect();
        Bih { nodes: sub.nodes, tris, ids, bounds, copies }
    }

    /// The nodes (root first).
    pub fn nodes(&self) -> &[BihNode] {
        &self.nodes
    }

    /// The arrays the device traversal reads (see [`crate::accel::device_trace`]).
    pub fn device_layout(&self) -> crate::accel::device_trace::DeviceLayout<'_> {
        crate::accel::device_trace::DeviceLayout::Bih {
            nodes: &self.nodes,
            tris: &self.tris,
            ids: &self.ids,
            bounds: self.bounds,
        }
    }

    fn traverse(&self, ray: &Ray, any: bool, c: &mut TraceCounters) -> Option<Hit> {
        if self.nodes.is_empty() {
            return None;
        }
        let r = RayInv::new(ray);
        c.box_tests += 1;
        let (mut tn, mut tf) = r.slab_interval(self.bounds.min, self.bounds.max, ray.tmin, ray.tmax)?;
        let mut best_t = ray.tmax;
        let mut bound = ray.tmax;
        let margin = tie_margin(ray.origin, ray.dir, &self.bounds);
        let mut best = None;
        let mut stack: TraversalStack<(u32, f32, f32)> = TraversalStack::new();
        let mut node = 0usize;
        const E: f32 = 2e-6;
        loop {
            if tn <= bound {
                let nd = self.nodes[node];
                if nd.is_leaf() {
                    let first = (nd.flags >> 2) as usize;
                    for i in first..first + nd.count() as usize {
                        c.prim_tests += 1;
                        if let Some(h) = closer_hit(&self.tris[i], self.ids[i], r.o, r.d, ray.tmin, best_t, &best) {
                            best_t = h.t;
                            bound = cull_bound(h.t, margin);
                            best = Some(h);
                            if any {
                                return best;
                            }
                        }
                    }
                } else {
                    c.box_tests += 1;
                    let a = (nd.flags & 3) as usize;
                    let ch = (nd.flags >> 2) as usize;
                    let tl = (nd.clip[0] - r.o[a]) * r.inv[a];
                    let tr = (nd.clip[1] - r.o[a]) * r.inv[a];
                    let (tl, tr) = (tl + tl.abs() * E, tr - tr.abs() * E);
                    // Positive (or zero) direction: left is near; it spans t <= tl, right spans t >= tr.
                    let ((near, near_end), (far, far_start)) = if r.inv[a] > 0.0 {
                        ((ch, tl), (ch + 1, tr))
                    } else {
                        // Negative direction: the right child spans t <= t(clip[1]), the left t >= t(clip[0]).
                        let tl2 = (nd.clip[0] - r.o[a]) * r.inv[a];
                        let tr2 = (nd.clip[1] - r.o[a]) * r.inv[a];
                        ((ch + 1, tr2 + tr2.abs() * E), (ch, tl2 - tl2.abs() * E))
                    };
                    let near_ok = tn <= near_end;
                    let far_ok = far_start <= tf;
                    match (near_ok, far_ok) {
                        (true, true) => {
                            stack.push((far as u32, tn.max(far_start), tf));
                            node = near;
                            tf = tf.min(near_end);
                            continue;
                        }
                        (true, false) => {
                            node = near;
                            tf = tf.min(near_end);
                            continue;
                        }
                        (false, true) => {
                            node = far;
                            tn = tn.max(far_start);
                            continue;
                        }
                        (false, false) => {}
                    }
                }
            }
            match stack.pop() {
                None => return best,
                Some((nd, a, b)) => {
                    node = nd as usize;
                    tn = a;
                    tf = b;
                }
            }
        }
    }

    /// Implied box of every node (parent box clipped by the node's interval), root first, with the node index.
    fn node_boxes(&self) -> Vec<(usize, Aabb, usize)> {
        let mut out = Vec::with_capacity(self.nodes.len());
        if self.nodes.is_empty() {
            return out;
        }
        let mut stack = vec![(0usize, self.bounds, 0usize)];
        while let Some((k, b, depth)) = stack.pop() {
            out.push((k, b, depth));
            let nd = self.nodes[k];
            if !nd.is_leaf() {
                let a = (nd.flags & 3) as usize;
                let ch = (nd.flags >> 2) as usize;
                let mut l = b;
                l.max[a] = l.max[a].min(nd.clip[0]);
                let mut r = b;
                r.min[a] = r.min[a].max(nd.clip[1]);
                stack.push((ch, l, depth + 1));
                stack.push((ch + 1, r, depth + 1));
            }
        }
        out
    }
}

impl AccelStructure for Bih {
    fn build(mesh: &Mesh) -> Result<Self, AccelError> {
        Bih::build_with(mesh, &BihOptions::default())
    }
    fn name(&self) -> StructureName {
        StructureName::Bih
    }
    traversal_methods!();
    fn memory_bytes(&self) -> usize {
        bytes_of(&self.nodes) + bytes_of(&self.tris) + bytes_of(&self.ids) + bytes_of(&self.copies)
    }

    fn build_work(&self) -> Option<f64> {
        super::reference_levels_of(self.nodes.len(), |k| {
            let nd = self.nodes.get(k)?;
            Some(if nd.is_leaf() {
                super::LevelNode::Leaf(nd.count() as usize)
            } else {
                let ch = (nd.flags >> 2) as usize;
                super::LevelNode::Inner(ch, ch + 1)
            })
        })
    }
    /// Checks: every node reached exactly once, children indices in range, each child's implied box inside its
    /// parent's, every triangle record in exactly one leaf and inside that leaf's implied box (so the clip planes
    /// never cut a triangle off), ids a permutation.
    fn validate(&self) -> Result<AccelStats, AccelError> {
        let n = self.tris.len();
        let mut v = Validation::new("bih", n, self.memory_bytes(), self.nodes.len(), n);
        if self.nodes.is_empty() {
            return v.without_nodes(n != 0, "no nodes for triangles");
        }
        check_permutation("bih", &self.ids, n)?;
        let mut stack = vec![(0usize, self.bounds, 0usize)];
        while let Some((k, b, depth)) = stack.pop() {
            v.visit(k, depth)?;
            let nd = self.nodes[k];
            if nd.is_leaf() {
                let first = (nd.flags >> 2) as usize;
                let count = nd.count() as usize;
                v.leaf(k, first, count)?;
                for (t, &id) in self.tris[first..first + count].iter().zip(&self.ids[first..]) {
                    if !triangle_in_box(t, &b) {
                        return Err(v.invalid(format!("triangle {id} outside leaf {k}")));
                    }
                }
            } else {
                let a = (nd.flags & 3) as usize;
                let ch = (nd.flags >> 2) as usize;
                if ch + 1 >= self.nodes.len() || ch <= k {
                    return Err(v.invalid(format!("node {k}: children {ch} out of range")));
                }
                let mut l = b;
                l.max[a] = l.max[a].min(nd.clip[0]);
                let mut r = b;
                r.min[a] = r.min[a].max(nd.clip[1]);
                if !b.contains(&l) || !b.contains(&r) {
                    return Err(v.invalid(format!("node {k}: child outside parent")));
                }
                stack.push((ch, l, depth + 1));
                stack.push((ch + 1, r, depth + 1));
            }
        }
        for &(c, k) in &self.copies {
            let same = match (self.tris.get(c as usize), self.tris.get(k as usize)) {
                (Some(tc), Some(tk)) => {
                    record_bits(tc) == record_bits(tk) && self.ids[k as usize] < self.ids[c as usize]
                }
                _ => false,
            };
            if !same {
                return Err(v.invalid(format!("record {c} is no copy of record {k} with a smaller index")));
            }
            v.copy(c as usize, k as usize)?;
        }
        v.finish()
    }

    fn sah_cost(&self) -> Option<f64> {
        let boxes = self.node_boxes();
        let root = self.bounds.surface_area();
        Some(sah_cost(
            root,
            boxes.into_iter().map(|(k, b, _)| {
                let nd = self.nodes[k];
                (b.surface_area(), nd.is_leaf(), if nd.is_leaf() { nd.count() as usize } else { 0 })
            }),
        ))
    }
}
