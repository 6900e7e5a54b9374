//! SAH kd-tree with binned plane candidates and empty-space cut-off (after Wald and Havran 2006, binning as in
//! Shevtsov et al. 2007), references duplicated across splits.
//!
//! # Build
//!
//! Each reference carries the triangle's bounding box clipped to the current voxel; a zero-area triangle, which is
//! never hit, carries the centre of its box instead and lands in one leaf (400 collinear ones across a flat lattice
//! would otherwise sit in every leaf). Per axis, candidate planes are
//! the boundaries of [`KdOptions::bins`] equal bins of the voxel, plus the two planes that cut off the empty space
//! on either side of the references (exactly at their smallest minimum and largest maximum). The count estimates
//! `N_L`, `N_R` come from per-bin start and end counts. The cost of a plane is
//! `K_T + K_I * (1 - b) * (SA(V_L) N_L + SA(V_R) N_R) / SA(V)`, with the empty-space bonus `b`
//! ([`KdOptions::empty_bonus`]) when one side is empty (Wald and Havran 2006). A node becomes a leaf when no plane
//! beats `K_I * N`, or at the depth limit `8 + 1.3 log2(N)` (the rule of pbrt, Pharr et al.).
//!
//! A plane that leaves one child with every reference of the node (and the other with some) duplicates all the
//! other child's references. One such split is often worth it (a wall spanning the node), but on degenerate input
//! they chain: on a fan of a polygon over three points (coincident copies of one triangle, and zero-area triangles
//! whose points lie on the sides of every voxel), every level keeps everything on the thin side down to the depth
//! limit, 18 references per triangle (135 while zero-area triangles were carried as boxes). So a node at the end of
//! [`KdOptions::max_keep_all_chain`] (6) such splits in a row, each child holding every reference of its parent,
//! gets no such plane: 5.3 references per triangle on the fan, while on the shared meshes the SAH cost moves by at
//! most 0.26% (kitchen) and the references shrink by up to 6%.
//!
//! Partition rule at plane `p` on axis `a` (reproduced exactly by `validate()`): a reference goes left when its box
//! has `min[a] < p`, right when `max[a] > p`, both when it straddles; a box lying in the plane (`min = max = p`)
//! goes left. Subtrees over [`KdOptions::parallel_threshold`] references are built in parallel.
//!
//! # Budget
//!
//! A split is taken only when its cost beats the leaf's (no bad refines by default: with pbrt's three,
//! [`KdOptions::max_bad_refines`], the SAH cost of the shared meshes rose 9-21% and their references 2-3x), and
//! only within the node's **allowance** of leaf references: the root's is [`KdOptions::reference_budget`] (64 per
//! triangle, at least `2^16`), and a split shares its node's allowance between the children in proportion to
//! their reference counts. A split whose children would hold more than the allowance is not taken; the node is a
//! leaf. So the leaves never hold more than the budget, whatever the input, and the tree depends on no thread
//! count. The rule matters where the SAH's greedy choice keeps paying: in a flat voxel the children's areas add up
//! to their parent's, so duplicating a reference costs the SAH nothing, and 1,000 random triangles in one plane,
//! whose boxes overlap about 250 deep, kept splitting to the depth limit (past 33 million references, 33,500 per
//! triangle) before the allowance; they now stop at 48 per triangle, depth 13. On the shared meshes, where a path
//! deep in a dense region may pass its share, the references fall by up to 9% (sponza 14.4 to 13.2 per
//! triangle) and the SAH cost is unchanged to four digits.
//!
//! # Layout ([`KdNode`], 8 bytes)
//!
//! Depth-first: the left child of internal node `i` is `i + 1`, the right child `i + (flags >> 2)`. `flags & 3` is
//! the split axis (0, 1, 2) or 3 for a leaf; an internal node's `split_or_count` holds the f32 bits of the plane, a
//! leaf's holds its reference count, and `flags >> 2` its first reference in [`KdTree::references`].
//!
//! # Traversal
//!
//! Front-to-back with a stack of `(node, t_entry, t_exit)` (Havran's recursive traversal in iterative form). Split
//! distances are widened by a relative `1e-5` so that rounding never skips a cell a hit lies in; hits are recorded
//! wherever they lie on the ray, and a stacked node is skipped only when its entry distance exceeds the best hit.
//! `box_tests` counts visited nodes.

use super::{
    bytes_of, invalid, prepare, sah_cost, AccelError, AccelStats, AccelStructure, StructureName, TraversalStack,
    Validation,
};
use crate::accel::copies::record_bits;
use crate::geom::{closer_hit, cull_bound, tie_margin, Hit, Ray, RayInv, TraceCounters};
use crate::geom::{Aabb, Triangle};
use crate::mesh::Mesh;
use glam::{BVec4A, Vec3, Vec3A, Vec4};

mod split;

use split::find_split;

/// One kd-tree node (see the module docs): generated from `struct KdNode` of `glsl/include/trace.glsl`, its one
/// definition, which the device traversal reads; the methods are here.
pub use crate::gpu::shaders::KdNode;

const _: () = assert!(std::mem::size_of::<KdNode>() == 8);

const LEAF: u32 = 3;
const MAX_INDEX: usize = (1 << 30) - 1;

impl KdNode {
    /// Whether this is a leaf.
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.flags & 3 == LEAF
    }
    /// Split axis of an internal node.
    #[inline]
    pub fn axis(&self) -> usize {
        (self.flags & 3) as usize
    }
    /// Split plane of an internal node.
    #[inline]
    pub fn split(&self) -> f32 {
        f32::from_bits(self.split_or_count)
    }
}

/// Options of the kd-tree builder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KdOptions {
    /// Bins per axis for plane candidates.
    pub bins: usize,
    /// Traversal cost `K_T` of the build heuristic.
    pub traversal_cost: f32,
    /// Intersection cost `K_I` of the build heuristic.
    pub intersection_cost: f32,
    /// Empty-space bonus `b` in `[0, 1)`.
    pub empty_bonus: f32,
    /// Subtrees with at least this many references are built in parallel.
    pub parallel_threshold: usize,
    /// Longest chain of splits each leaving a child with every reference of its parent, after which such planes
    /// are no candidates (default 6; see the module docs). 0 allows none.
    pub max_keep_all_chain: u32,
    /// Splits on one path from the root that may cost more than the leaf they replace (pbrt's bad refines;
    /// default 0): see the module docs.
    pub max_bad_refines: u32,
    /// Leaf references allowed per triangle (default 64; the shared meshes use at most 13.2): see
    /// [`KdOptions::reference_budget`].
    pub max_references_per_triangle: usize,
    /// Leaf references always allowed, however few the triangles (default `2^16`): see
    /// [`KdOptions::reference_budget`].
    pub min_reference_budget: usize,
}

impl Default for KdOptions {
    fn default() -> Self {
        KdOptions {
            bins: 32,
            traversal_cost: 1.0,
            intersection_cost: 1.5,
            empty_bonus: 0.2,
            parallel_threshold: 8192,
            max_keep_all_chain: 6,
            max_bad_refines: 0,
            max_references_per_triangle: 64,
            min_reference_budget: 1 << 16,
        }
    }
}

impl KdOptions {
    /// The most leaf references a kd-tree over `n` triangles may hold:
    /// `max(max_references_per_triangle * n, min_reference_budget)` (saturating): the root's allowance, shared
    /// down the tree (see the module docs). The build never passes it.
    pub fn reference_budget(&self, n: usize) -> usize {
        self.max_references_per_triangle.saturating_mul(n).max(self.min_reference_budget)
    }
}

#[derive(Clone, Copy, Debug)]
struct KRef {
    min: Vec3,
    idx: u32,
    max: Vec3,
}

/// The kd-tree (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct KdTree {
    nodes: Vec<KdNode>,
    refs: Vec<u32>,
    tris: Vec<Triangle>,
    boxes: Vec<Aabb>,
    ids: Vec<u32>,
    bounds: Aabb,
    /// Records in no leaf, copies of another record (`crate::accel::copies`), as `(record, record kept)`.
    copies: Vec<(u32, u32)>,
}

/// The box a triangle's reference starts from: its bounding box, or the centre of it for a zero-area triangle.
fn reference_box(t: &Triangle, b: &Aabb) -> Aabb {
    if t.is_degenerate() {
        Aabb::new(b.center(), b.center())
    } else {
        *b
    }
}

#[inline]
fn goes_left(min: f32, max: f32, p: f32) -> bool {
    min < p || (min == p && max == p)
}

#[inline]
fn goes_right(max: f32, p: f32) -> bool {
    max > p
}

struct Built {
    nodes: Vec<KdNode>,
    refs: Vec<u32>,
}

fn leaf(out: &mut Built, refs: &[KRef]) {
    let first = out.refs.len();
    out.refs.extend(refs.iter().map(|r| r.idx));
    out.refs[first..].sort_unstable();
    out.nodes.push(KdNode { split_or_count: refs.len() as u32, flags: LEAF | ((first as u32) << 2) });
}

/// What every subtree of one build shares: the options and the depth limit.
struct Build<'a> {
    o: &'a KdOptions,
    max_depth: u32,
}

/// Where a node sits on its path from the root: its depth, the splits in a row above it that each gave their child
/// every reference of its parent (`chain`), the splits above it that did not beat their leaf (`bad`), and the leaf
/// references its subtree may hold (`allowance`, at least its own count).
#[derive(Clone, Copy, Debug)]
struct Path {
    depth: u32,
    chain: u32,
    bad: u32,
    allowance: usize,
}

impl Path {
    /// The paths of the children of a split of a node over `n` references into `nl` and `nr`, or `None` when the
    /// children would hold more references than the node's allowance (the node is then a leaf). The allowance is
    /// shared in proportion to the children's counts, each at least its own count, so that the leaves of the whole
    /// tree never hold more than the root's.
    fn children(self, n: usize, nl: usize, nr: usize, bad: bool) -> Option<(Path, Path)> {
        let total = nl + nr;
        if total > self.allowance {
            return None;
        }
        let al = (self.allowance as u128 * nl as u128 / total.max(1) as u128) as usize;
        let child = |count: usize, allowance: usize| Path {
            depth: self.depth + 1,
            chain: if count == n { self.chain + 1 } else { 0 },
            bad: self.bad + bad as u32,
            allowance,
        };
        Some((child(nl, al), child(nr, self.allowance - al)))
    }
}

impl Build<'_> {
    /// The split of a node over `refs` in `voxel` at `path`, `(axis, plane, bad)` (`bad`: the plane does not beat
    /// the leaf's cost), or `None` for a leaf.
    fn decide(&self, refs: &[KRef], voxel: &Aabb, path: Path) -> Option<(usize, f32, bool)> {
        let n = refs.len();
        let o = self.o;
        if path.depth >= self.max_depth || n == 0 {
            return None;
        }
        let (axis, p, cost) = find_split(refs, voxel, o, path.chain < o.max_keep_all_chain)?;
        let leaf = o.intersection_cost * n as f32;
        if cost < leaf {
            return Some((axis, p, false));
        }
        // A split that does not beat the leaf may still lead to ones that do (pbrt's bad refines): a few are allowed
        // on each path, never one costing more than four leaves over a small node.
        let hopeless = cost > 4.0 * leaf && n < 16;
        (cost.is_finite() && !hopeless && path.bad < o.max_bad_refines).then_some((axis, p, true))
    }
}

/// The children's voxels of a split of `voxel` at plane `p` on `axis`.
fn child_voxels(voxel: &Aabb, axis: usize, p: f32) -> (Aabb, Aabb) {
    let (mut lv, mut rv) = (*voxel, *voxel);
    lv.max[axis] = p;
    rv.min[axis] = p;
    (lv, rv)
}

/// Builds the subtree over `refs` in `voxel` at `path` as depth-first segments (concatenated once, by
/// [`concat`]). Subtrees of at least [`KdOptions::parallel_threshold`] references split in parallel; smaller ones
/// are built by [`build_seq`] on one reference stack.
fn build_rec(refs: Vec<KRef>, voxel: Aabb, path: Path, b: &Build) -> Vec<Built> {
    let n = refs.len();
    let mut out = Built { nodes: Vec::new(), refs: Vec::new() };
    if n < b.o.parallel_threshold {
        let mut stack = refs;
        build_seq(&mut stack, 0, voxel, path, b, &mut out);
        return vec![out];
    }
    let Some((axis, p, bad)) = b.decide(&refs, &voxel, path) else {
        leaf(&mut out, &refs);
        return vec![out];
    };
    let mut left = Vec::with_capacity(n);
    let mut right = Vec::with_capacity(n);
    for r in &refs {
        if goes_left(r.min[axis], r.max[axis], p) {
            let mut c = *r;
            c.max[axis] = c.max[axis].min(p);
            left.push(c);
        }
        if goes_right(r.max[axis], p) {
            let mut c = *r;
            c.min[axis] = c.min[axis].max(p);
            right.push(c);
        }
    }
    let Some((lp, rp)) = path.children(n, left.len(), right.len(), bad) else {
        leaf(&mut out, &refs);
        return vec![out];
    };
    drop(refs);
    let (lv, rv) = child_voxels(&voxel, axis, p);
    let (l, r) = rayon::join(|| build_rec(left, lv, lp, b), || build_rec(right, rv, rp, b));
    // The right child follows the left subtree (an index too large is rejected after the build).
    let left_nodes: usize = l.iter().map(|s| s.nodes.len()).sum();
    let flags = axis as u32 | ((1 + left_nodes) as u32).wrapping_shl(2);
    out.nodes.push(KdNode { split_or_count: p.to_bits(), flags });
    let mut segments = Vec::with_capacity(1 + l.len() + r.len());
    segments.push(out);
    segments.extend(l);
    segments.extend(r);
    segments
}

/// [`build_rec`] without allocation: the node's references are `stack[start..]`; its children's are pushed above
/// them (right, then left, so that the left child's sit on top) and the stack is cut back to `start` on return.
/// The same tree as the recursive form, node for node.
fn build_seq(stack: &mut Vec<KRef>, start: usize, voxel: Aabb, path: Path, b: &Build, out: &mut Built) {
    let end = stack.len();
    let n = end - start;
    let Some((axis, p, bad)) = b.decide(&stack[start..], &voxel, path) else {
        leaf(out, &stack[start..]);
        stack.truncate(start);
        return;
    };
    stack.reserve(2 * n);
    for i in start..end {
        let r = stack[i];
        if goes_right(r.max[axis], p) {
            let mut c = r;
            c.min[axis] = c.min[axis].max(p);
            stack.push(c);
        }
    }
    let mid = stack.len();
    for i in start..end {
        let r = stack[i];
        if goes_left(r.min[axis], r.max[axis], p) {
            let mut c = r;
            c.max[axis] = c.max[axis].min(p);
            stack.push(c);
        }
    }
    let (nl, nr) = (stack.len() - mid, mid - end);
    let Some((lp, rp)) = path.children(n, nl, nr, bad) else {
        stack.truncate(end);
        leaf(out, &stack[start..]);
        stack.truncate(start);
        return;
    };
    let (lv, rv) = child_voxels(&voxel, axis, p);
    let here = out.nodes.len();
    out.nodes.push(KdNode { split_or_count: p.to_bits(), flags: axis as u32 });
    build_seq(stack, mid, lv, lp, b, out);
    out.nodes[here].flags |= ((out.nodes.len() - here) as u32) << 2;
    build_seq(stack, end, rv, rp, b, out);
    stack.truncate(start);
}

/// The segments of [`build_rec`] as one tree, each leaf's first reference moved by the references before its
/// segment.
fn concat(segments: Vec<Built>) -> Built {
    let nodes = segments.iter().map(|s| s.nodes.len()).sum();
    let refs = segments.iter().map(|s| s.refs.len()).sum();
    let mut out = Built { nodes: Vec::with_capacity(nodes), refs: Vec::with_capacity(refs) };
    for sub in segments {
        let off = out.refs.len() as u32;
        out.nodes.extend(sub.nodes.into_iter().map(|mut nd| {
            if nd.is_leaf() {
                nd.flags = LEAF | (((nd.flags >> 2) + off) << 2);
            }
            nd
        }));
        out.refs.extend(sub.refs);
    }
    out
}

impl KdTree {
    /// Builds with explicit options.
    pub fn build_with(mesh: &Mesh, o: &KdOptions) -> Result<Self, AccelError> {
        crate::in_pool(|| Self::build_here(mesh, o))
    }

    fn build_here(mesh: &Mesh, o: &KdOptions) -> Result<Self, AccelError> {
        let (mut tris, mut boxes) = prepare(mesh, "kdtree")?;
        let n = tris.len();
        if n == 0 {
            return Ok(KdTree::default());
        }
        let bounds = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        // Coincident copies keep their smallest index only: every leaf would hold each copy, and a ray test them all.
        let copies = super::copies::position_copies(mesh, &tris);
        let is_copy = super::copies::copy_mask(n, &copies);
        let refs: Vec<KRef> = (0..n)
            .filter(|&i| !is_copy[i])
            .map(|i| {
                let b = reference_box(&tris[i], &boxes[i]);
                KRef { min: b.min, idx: i as u32, max: b.max }
            })
            .collect();
        let max_depth = (8.0 + 1.3 * (n as f64).log2()).round() as u32;
        let b = Build { o, max_depth };
        let kept = n - copies.len();
        let root = Path { depth: 0, chain: 0, bad: 0, allowance: o.reference_budget(kept).max(kept) };
        let mut out = concat(build_rec(refs, bounds, root, &b));
        if out.refs.len() > MAX_INDEX || out.nodes.len() > MAX_INDEX {
            return Err(AccelError::TooLarge {
                structure: "kdtree",
                what: "references or nodes",
                count: out.refs.len().max(out.nodes.len()),
                limit: MAX_INDEX,
            });
        }
        let lists: Vec<(usize, usize)> = out
            .nodes
            .iter()
            .filter(|nd| nd.is_leaf())
            .map(|nd| ((nd.flags >> 2) as usize, (nd.flags >> 2) as usize + nd.split_or_count as usize))
            .collect();
        let ids = super::renumber_by_first_use(&mut out.refs, &lists, &mut tris, &mut boxes);
        let mut record = vec![0u32; n];
        for (r, &i) in ids.iter().enumerate() {
            record[i as usize] = r as u32;
        }
        let copies = copies.iter().map(|&(c, k)| (record[c as usize], record[k as usize])).collect();
        Ok(KdTree { nodes: out.nodes, refs: out.refs, tris, boxes, ids, bounds, copies })
    }

    /// The nodes, depth-first, root first.
    pub fn nodes(&self) -> &[KdNode] {
        &self.nodes
    }

    /// Triangle references of the leaves (record indices; record `r` is mesh triangle `triangle_ids()[r]`).
    pub fn references(&self) -> &[u32] {
        &self.refs
    }

    /// Mesh index of every triangle record (records are numbered in order of first use by the leaves).
    pub fn triangle_ids(&self) -> &[u32] {
        &self.ids
    }

    /// The arrays the device traversal reads (see [`crate::accel::device_trace`]).
    pub fn device_layout(&self) -> crate::accel::device_trace::DeviceLayout<'_> {
        crate::accel::device_trace::DeviceLayout::KdTree {
            nodes: &self.nodes,
            refs: &self.refs,
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
        loop {
            if tn <= bound {
                let nd = self.nodes[node];
                if nd.is_leaf() {
                    let first = (nd.flags >> 2) as usize;
                    for &id in &self.refs[first..first + nd.split_or_count as usize] {
                        c.prim_tests += 1;
                        if let Some(h) = closer_hit(
                            &self.tris[id as usize],
                            self.ids[id as usize],
                            r.o,
                            r.d,
                            ray.tmin,
                            best_t,
                            &best,
                        ) {
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
                    let a = nd.axis();
                    let p = nd.split();
                    let ts = (p - r.o[a]) * r.inv[a];
                    let below_first = r.o[a] < p || (r.o[a] == p && r.d[a] <= 0.0);
                    let right = node + (nd.flags >> 2) as usize;
                    let (near, far) = if below_first { (node + 1, right) } else { (right, node + 1) };
                    if ts < 0.0 {
                        node = near;
                        continue;
                    }
                    if ts == 0.0 {
                        stack.push((far as u32, tn, tf));
                        node = near;
                        continue;
                    }
                    let e = ts * 1e-5;
                    let near_ok = tn <= ts + e;
                    let far_ok = ts - e <= tf;
                    match (near_ok, far_ok) {
                        (true, true) => {
                            stack.push((far as u32, tn.max(ts - e), tf));
                            node = near;
                            tf = tf.min(ts + e);
                            continue;
                        }
                        (true, false) => {
                            node = near;
                            continue;
                        }
                        (false, true) => {
                            node = far;
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

    /// Descends with triangle `i`'s box by the partition rule and checks that every leaf reached references it.
    fn check_reference(&self, i: usize) -> Result<usize, AccelError> {
        let b = &reference_box(&self.tris[i], &self.boxes[i]);
        let mut stack = vec![0usize];
        let mut leaves = 0;
        while let Some(k) = stack.pop() {
            let nd = self.nodes[k];
            if nd.is_leaf() {
                let first = (nd.flags >> 2) as usize;
                let list = &self.refs[first..first + nd.split_or_count as usize];
                if list.binary_search(&(i as u32)).is_err() {
                    return Err(invalid("kdtree", format!("triangle {i} lost: missing from leaf {k}")));
                }
                leaves += 1;
            } else {
                let (a, p) = (nd.axis(), nd.split());
                if goes_left(b.min[a], b.max[a], p) {
                    stack.push(k + 1);
                }
                if goes_right(b.max[a], p) {
                    stack.push(k + (nd.flags >> 2) as usize);
                }
            }
        }
        Ok(leaves)
    }
}

impl AccelStructure for KdTree {
    fn build(mesh: &Mesh) -> Result<Self, AccelError> {
        KdTree::build_with(mesh, &KdOptions::default())
    }
    fn name(&self) -> StructureName {
        StructureName::KdTree
    }
    traversal_methods!();
    fn memory_bytes(&self) -> usize {
        bytes_of(&self.nodes)
            + bytes_of(&self.refs)
            + bytes_of(&self.tris)
            + bytes_of(&self.ids)
            + bytes_of(&self.copies)
    }

    /// Checks: every node reached exactly once, splits strictly inside their voxel, leaf ranges inside the
    /// reference array and disjoint, every reference entry in exactly one leaf, each leaf's references overlap its
    /// voxel, and every triangle is referenced by every leaf the partition rule sends it to (no lost reference).
    fn validate(&self) -> Result<AccelStats, AccelError> {
        let n = self.tris.len();
        let mut v = Validation::new("kdtree", n, self.memory_bytes(), self.nodes.len(), self.refs.len());
        if self.nodes.is_empty() {
            return v.without_nodes(n != 0 || !self.refs.is_empty(), "no nodes but triangles or references");
        }
        let mut stack = vec![(0usize, self.bounds, 0usize)];
        while let Some((k, voxel, depth)) = stack.pop() {
            v.visit(k, depth)?;
            let nd = self.nodes[k];
            if nd.is_leaf() {
                let first = (nd.flags >> 2) as usize;
                let count = nd.split_or_count as usize;
                v.leaf(k, first, count)?;
                for &id in &self.refs[first..first + count] {
                    let b = self.boxes.get(id as usize).ok_or_else(|| v.invalid(format!("reference to {id}")))?;
                    if !voxel.overlaps(b) {
                        return Err(v.invalid(format!("triangle {id} in leaf {k} outside its voxel")));
                    }
                }
            } else {
                let (a, p) = (nd.axis(), nd.split());
                if !(p > voxel.min[a] && p < voxel.max[a]) {
                    return Err(v.invalid(format!("node {k}: split {p} outside voxel {voxel:?}")));
                }
                let right = k + (nd.flags >> 2) as usize;
                if right <= k + 1 || right >= self.nodes.len() {
                    return Err(v.invalid(format!("node {k}: right child {right} out of range")));
                }
                let mut lv = voxel;
                lv.max[a] = p;
                let mut rv = voxel;
                rv.min[a] = p;
                if !voxel.contains(&lv) || !voxel.contains(&rv) {
                    return Err(v.invalid(format!("node {k}: child voxel outside parent")));
                }
                stack.push((k + 1, lv, depth + 1));
                stack.push((right, rv, depth + 1));
            }
        }
        let mut stats = v.finish()?;
        let mut copy = vec![false; n];
        let mut referenced = vec![false; n];
        for &r in &self.refs {
            if let Some(x) = referenced.get_mut(r as usize) {
                *x = true;
            }
        }
        for &(c, k) in &self.copies {
            let (tc, tk) = match (self.tris.get(c as usize), self.tris.get(k as usize)) {
                (Some(tc), Some(tk)) if c != k => (tc, tk),
                _ => return Err(invalid("kdtree", format!("copy ({c}, {k}) out of range"))),
            };
            if record_bits(tc) != record_bits(tk) || self.ids[k as usize] >= self.ids[c as usize] {
                return Err(invalid("kdtree", format!("record {c} is no copy of record {k} with a smaller index")));
            }
            if std::mem::replace(&mut copy[c as usize], true) || referenced[c as usize] {
                return Err(invalid("kdtree", format!("copy {c} listed twice or in a leaf")));
            }
            if !referenced[k as usize] {
                return Err(invalid("kdtree", format!("record {k}, kept for copy {c}, in no leaf")));
            }
        }
        for (i, &is_copy) in copy.iter().enumerate() {
            if !is_copy && self.check_reference(i)? == 0 {
                return Err(invalid("kdtree", format!("triangle {i} in no leaf")));
            }
        }
        stats.copies = self.copies.len();
        Ok(stats)
    }

    fn sah_cost(&self) -> Option<f64> {
        if self.nodes.is_empty() {
            return Some(0.0);
        }
        let mut items = Vec::with_capacity(self.nodes.len());
        let mut stack = vec![(0usize, self.bounds)];
        while let Some((k, v)) = stack.pop() {
            let nd = self.nodes[k];
            if nd.is_leaf() {
                items.push((v.surface_area(), true, nd.split_or_count as usize));
            } else {
                items.push((v.surface_area(), false, 0));
                let (a, p) = (nd.axis(), nd.split());
                let mut l = v;
                l.max[a] = p;
                let mut r = v;
                r.min[a] = p;
                stack.push((k + 1, l));
                stack.push((k + (nd.flags >> 2) as usize, r));
            }
        }
        Some(sah_cost(self.bounds.surface_area(), items.into_iter()))
    }
}

#[cfg(test)]
mod tests {
    use super::split::*;
    use super::*;
    use crate::rng::SplitMix64;

    /// Bin counts of `n` references over `nb` bins: each reference starts in a bin and ends in the same or a later
    /// one; with `skew`, most of them in the first or last bin, so that sides with every reference or none occur.
    fn counts<const B: usize>(g: &mut SplitMix64, n: u32, nb: usize, skew: bool) -> ([u32; B], [u32; B]) {
        let (mut start, mut end) = ([0u32; B], [0u32; B]);
        for _ in 0..n {
            let (s, e) = if skew && g.below(4) > 0 {
                let b = if g.below(2) == 0 { 0 } else { nb - 1 };
                (b, b)
            } else {
                let s = g.below(nb as u64) as usize;
                (s, s + g.below((nb - s) as u64) as usize)
            };
            start[s] += 1;
            end[e] += 1;
        }
        (start, end)
    }

    fn check<const B: usize>(g: &mut SplitMix64) {
        for case in 0..400 {
            let nb = 2 + g.below(B as u64 - 1) as usize;
            let n = if case % 7 == 0 { 0 } else { g.below(3 * nb as u64 + 2) as u32 };
            let (start, end) = counts::<B>(g, n, nb, case % 3 == 0);
            let v0 = g.range(-10.0, 10.0) as f32;
            let e = if case % 11 == 0 { 1e-30 } else { g.range(1e-3, 100.0) as f32 };
            let sweep = SweepAxis {
                v0,
                v1: v0 + e,
                e,
                sm: g.range(0.0, 50.0) as f32,
                cr: g.range(0.0, 500.0) as f32,
                kt: 1.0,
                ki: g.range(0.5, 3.0) as f32,
                empty: 1.0 - g.range(0.0, 0.9) as f32,
                inv_sa: g.range(1e-3, 10.0) as f32,
                n,
                keep_all: case % 2 == 0,
            };
            let mut fast = [f32::INFINITY; B];
            sweep.bin_costs(&start, &end, nb, &mut fast);
            let (mut nl, mut nr) = (0u32, n);
            assert_eq!(fast[0], f32::INFINITY);
            for j in 1..nb {
                nl += start[j - 1];
                nr -= end[j - 1];
                let slow = sweep.cost(sweep.plane(j, nb), nl, nr);
                assert_eq!(fast[j].to_bits(), slow.to_bits(), "case {case}, j {j} of {nb}, n {n}: {sweep:?}");
            }
            assert!(fast[nb..].iter().all(|&c| c == f32::INFINITY));
        }
    }

    #[test]
    fn binned_sweep_matches_the_scalar_cost_to_the_bit() {
        let mut g = SplitMix64::new(7);
        check::<8>(&mut g);
        check::<16>(&mut g);
        check::<32>(&mut g);
        check::<MAX_BINS>(&mut g);
    }

    #[test]
    fn bin_indices_truncate_and_send_nan_to_bin_zero() {
        let b = bins(Vec3A::new(0.0, 2.999, 63.0));
        assert_eq!(&b[..3], &[0, 2, 63]);
        assert_eq!(bins(Vec3A::new(f32::NAN, 1.0, 0.5))[0] as usize & (MAX_BINS - 1), 0);
    }
}
