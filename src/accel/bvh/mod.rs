//! The node layout, traversal, bottom-up box fit, refit and validation shared by every BVH of the crate ([`Bvh`],
//! [`super::lbvh::Lbvh`], [`super::hlbvh::Hlbvh`]), and the binned-SAH builder of [`Bvh`] (module `sah`).
//!
//! # Node layout ([`BvhNode`], 32 bytes, `#[repr(C)]`, `bytemuck::Pod`)
//!
//! | bytes | field | internal node | leaf |
//! |---|---|---|---|
//! | 0..12 | `min: [f32; 3]` | box lower corner | box lower corner |
//! | 12..16 | `left_or_first: u32` | index of the left child | index of the first triangle record |
//! | 16..28 | `max: [f32; 3]` | box upper corner | box upper corner |
//! | 28..32 | `right_or_count: u32` | index of the right child (bit 31 clear) | [`LEAF_FLAG`] \| triangle count |
//!
//! The root is node 0. A leaf covers triangle records `first .. first + count` of [`BvhTree::triangles`], whose
//! mesh indices are the same range of [`BvhTree::triangle_ids`]. "Left" and "right" are only names: traversal
//! visits the child with the nearer box entry first. Where the children of a node lie in the array is builder
//! specific: the binned-SAH builder stores the two children of a node next to each other (`right = left + 1`, one
//! cache line for both boxes), the LBVH uses the
//! Karras 2012 numbering (internal nodes `0 .. n-1`, leaves `n-1 .. 2n-1`), see [`super::lbvh`]; after their SAH
//! leaf collapse the LBVH and HLBVH use a depth-first numbering (left child at `k + 1`) with leaves of up to
//! `max_leaf` records. Traversal code must not assume one record per leaf.

mod reinsert;
mod sah;

#[cfg(feature = "eval")]
pub(crate) use sah::partition;
pub(crate) use sah::sweep_bins;
pub use sah::{Bvh, BvhOptions};

use super::{
    bytes_of, check_permutation, sah_cost, triangle_in_box, AccelError, AccelStats, TraversalStack, Validation,
};
use crate::accel::copies::record_bits;
use crate::geom::{closer_hit, cull_bound, tie_margin, Hit, Ray, RayInv, TraceCounters};
use crate::geom::{Aabb, Triangle};
use crate::mesh::Mesh;
use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, AtomicUsize, Ordering};

/// Bit 31 of [`BvhNode::right_or_count`] marks a leaf (`BVH_LEAF_FLAG` of `glsl/include/bvh.glsl`).
pub const LEAF_FLAG: u32 = crate::gpu::shaders::layout::BVH_LEAF_FLAG;

// One BVH node, shared by the BVH, LBVH and HLBVH and by GPU builders (see the module docs for the layout): the
// struct is generated from `glsl/include/bvh.glsl`, its one definition; the methods are here.
pub use crate::gpu::shaders::BvhNode;

const _: () = assert!(std::mem::size_of::<BvhNode>() == 32);
// 32: a node never straddles two cache lines (see `HOST_ALIGN` in build.rs).
const _: () = assert!(std::mem::align_of::<BvhNode>() == 32);

impl BvhNode {
    /// An internal node.
    pub fn internal(b: &Aabb, left: u32, right: u32) -> Self {
        BvhNode { min: b.min.to_array(), left_or_first: left, max: b.max.to_array(), right_or_count: right }
    }
    /// A leaf over `count` triangle records from `first`.
    pub fn leaf(b: &Aabb, first: u32, count: u32) -> Self {
        BvhNode {
            min: b.min.to_array(),
            left_or_first: first,
            max: b.max.to_array(),
            right_or_count: LEAF_FLAG | count,
        }
    }
    /// Whether this is a leaf.
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.right_or_count & LEAF_FLAG != 0
    }
    /// Triangle count of a leaf.
    #[inline]
    pub fn count(&self) -> u32 {
        self.right_or_count & !LEAF_FLAG
    }
    /// The node's box.
    #[inline]
    pub fn aabb(&self) -> Aabb {
        Aabb::new(Vec3::from_array(self.min), Vec3::from_array(self.max))
    }
}

/// The bottom-up box fit of every BVH of the crate (the LBVH's Karras tree, each HLBVH cluster, [`BvhTree::refit`]):
/// every leaf's box is `leaf_box(leaf)` (`None`: the leaf is out of range), every internal node's the union
/// `left ∪ right` of its children's. In parallel, after Karras 2012: each leaf walks up towards the root and the
/// second arrival at a node computes its box, so every node is computed once, after both children. Unions are exact,
/// so the result does not depend on the schedule.
///
/// `nodes` must form one tree rooted at node 0 (any numbering): the error says where it does not (a child index out
/// of range, a node with two parents or none, a cycle). On error the boxes are unspecified.
pub(crate) fn fit_boxes(
    nodes: &mut [BvhNode],
    leaf_box: impl Fn(&BvhNode) -> Option<Aabb> + Sync,
) -> Result<(), String> {
    if nodes.is_empty() {
        return Ok(());
    }
    let mut parent = vec![u32::MAX; nodes.len()];
    let mut internal = 0usize;
    for (k, nd) in nodes.iter().enumerate().filter(|(_, nd)| !nd.is_leaf()) {
        internal += 1;
        for c in [nd.left_or_first, nd.right_or_count] {
            let slot = parent.get_mut(c as usize).filter(|_| c != 0);
            let slot = slot.ok_or_else(|| format!("node {k}: child {c} out of range"))?;
            if *slot != u32::MAX {
                return Err(format!("node {c} has two parents"));
            }
            *slot = k as u32;
        }
    }
    if let Some(k) = parent.iter().skip(1).position(|&p| p == u32::MAX) {
        return Err(format!("node {} is nobody's child", k + 1));
    }
    // Small trees (the HLBVH's clusters) stay on one thread.
    const MIN_LEN: usize = 1024;
    let bad_leaf = AtomicUsize::new(usize::MAX);
    let boxes: Vec<[AtomicU32; 6]> = nodes
        .par_iter()
        .enumerate()
        .with_min_len(MIN_LEN)
        .map(|(k, nd)| {
            let b = match nd.is_leaf() {
                false => Aabb::EMPTY,
                true => leaf_box(nd).unwrap_or_else(|| {
                    bad_leaf.fetch_min(k, Ordering::Relaxed);
                    Aabb::EMPTY
                }),
            };
            [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(|x| AtomicU32::new(x.to_bits()))
        })
        .collect();
    let bad_leaf = bad_leaf.into_inner();
    if bad_leaf != usize::MAX {
        return Err(format!("leaf {bad_leaf} out of range"));
    }
    let load = |k: usize| -> Aabb {
        let f = |i: usize| f32::from_bits(boxes[k][i].load(Ordering::Relaxed));
        Aabb::new(Vec3::new(f(0), f(1), f(2)), Vec3::new(f(3), f(4), f(5)))
    };
    let arrivals: Vec<AtomicU32> = (0..nodes.len()).map(|_| AtomicU32::new(0)).collect();
    let nodes_ro = &*nodes;
    let fitted: usize = (0..nodes.len())
        .into_par_iter()
        .with_min_len(MIN_LEN)
        .filter(|&k| nodes_ro[k].is_leaf())
        .map(|leaf| {
            let mut fitted = 0;
            let mut k = parent[leaf];
            while k != u32::MAX {
                // AcqRel: the second arrival sees the box the first one stored before its increment.
                if arrivals[k as usize].fetch_add(1, Ordering::AcqRel) == 0 {
                    break;
                }
                let nd = &nodes_ro[k as usize];
                let b = load(nd.left_or_first as usize).union(&load(nd.right_or_count as usize));
                let v = [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z];
                for (slot, x) in boxes[k as usize].iter().zip(v) {
                    slot.store(x.to_bits(), Ordering::Relaxed);
                }
                fitted += 1;
                k = parent[k as usize];
            }
            fitted
        })
        .sum();
    // Every internal node is computed exactly once when the nodes form a tree; one on a cycle never is.
    if fitted != internal {
        return Err("the nodes do not form a tree".into());
    }
    for (k, nd) in nodes.iter_mut().enumerate() {
        let b = load(k);
        nd.min = b.min.to_array();
        nd.max = b.max.to_array();
    }
    Ok(())
}

/// Nodes plus the triangle records in leaf order: the traversable part of every BVH of the crate.
#[derive(Clone, Debug, Default)]
pub struct BvhTree {
    pub(crate) nodes: Vec<BvhNode>,
    pub(crate) tris: Vec<Triangle>,
    pub(crate) ids: Vec<u32>,
    /// Records in no leaf: copies of the triangle of another record (same positions, larger triangle index),
    /// as `(record, record kept)`; see [`BvhTree::copies`].
    pub(crate) copies: Vec<(u32, u32)>,
}

impl BvhTree {
    /// The triangle records that no leaf holds, each with the record that stands for it: copies of one triangle
    /// (the same three vertex positions, bit for bit, in the same order) that the binned-SAH builder found in a node of coincident
    /// centroids, where it keeps the copy of the smallest triangle index. Under the tie rule (equal `t`: the
    /// smallest triangle index) a copy never changes a hit, so the tree answers every ray as if all were there,
    /// with fewer tests. A [`BvhTree::refit`] that moves a copy off its kept triangle fails. Empty for the
    /// LBVH and HLBVH, whose trees equal the device builders' node for node.
    pub fn copies(&self) -> &[(u32, u32)] {
        &self.copies
    }
    /// The nodes; the root is node 0 (empty for an empty mesh).
    pub fn nodes(&self) -> &[BvhNode] {
        &self.nodes
    }
    /// Triangle records in leaf order.
    pub fn triangles(&self) -> &[Triangle] {
        &self.tris
    }
    /// Mesh index of every triangle record.
    pub fn triangle_ids(&self) -> &[u32] {
        &self.ids
    }

    /// Bytes of nodes, triangle records and ids.
    pub fn memory_bytes(&self) -> usize {
        bytes_of(&self.nodes) + bytes_of(&self.tris) + bytes_of(&self.ids) + bytes_of(&self.copies)
    }

    /// The arrays the device traversal reads (see [`crate::accel::device_trace`]).
    pub fn device_layout(&self) -> crate::accel::device_trace::DeviceLayout<'_> {
        crate::accel::device_trace::DeviceLayout::Bvh { nodes: &self.nodes, tris: &self.tris, ids: &self.ids }
    }

    /// Closest hit (or any hit when `any`), counting box and triangle tests.
    #[inline]
    pub(crate) fn traverse(&self, ray: &Ray, any: bool, c: &mut TraceCounters) -> Option<Hit> {
        let nodes = &self.nodes[..];
        let root = nodes.first()?;
        let r = RayInv::new(ray);
        let mut best_t = ray.tmax;
        let mut bound = ray.tmax;
        let mut best: Option<Hit> = None;
        c.box_tests += 1;
        r.slab(&root.min, &root.max, ray.tmin, best_t)?;
        let margin = tie_margin(ray.origin, ray.dir, &Aabb::new(Vec3::from(root.min), Vec3::from(root.max)));
        let mut stack: TraversalStack<(u32, f32)> = TraversalStack::new();
        let mut node = 0usize;
        loop {
            let n = &nodes[node];
            if n.is_leaf() {
                let first = n.left_or_first as usize;
                let end = first + n.count() as usize;
                for i in first..end {
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
                let (l, rr) = (n.left_or_first as usize, n.right_or_count as usize);
                let (nl, nr) = (&nodes[l], &nodes[rr]);
                c.box_tests += 2;
                let tl = r.slab(&nl.min, &nl.max, ray.tmin, bound);
                let tr = r.slab(&nr.min, &nr.max, ray.tmin, bound);
                match (tl, tr) {
                    (Some(a), Some(b)) => {
                        if a <= b {
                            stack.push((rr as u32, b));
                            node = l;
                        } else {
                            stack.push((l as u32, a));
                            node = rr;
                        }
                        continue;
                    }
                    (Some(_), None) => {
                        node = l;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = rr;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            loop {
                match stack.pop() {
                    None => return best,
                    Some((nd, t)) => {
                        if t <= bound {
                            node = nd as usize;
                            break;
                        }
                    }
                }
            }
        }
    }

    /// Refits the tree to new vertex positions of the same triangles (the next frame of an animation): every
    /// triangle record is recomputed from `mesh`, every leaf's box from its triangles' vertices and every internal
    /// box from its children, bottom up (the fit the builders use); the topology is kept.
    ///
    /// # Errors
    ///
    /// [`AccelError::Invalid`] when `mesh` has another triangle count or the tree is malformed (an index out of
    /// range, nodes that do not form one tree rooted at node 0) or when a copy ([`BvhTree::copies`]) no longer has
    /// its kept triangle's record bits (copies over their own vertices that moved apart: rebuild instead),
    /// [`AccelError::Mesh`] for an invalid mesh.
    pub fn refit(&mut self, mesh: &Mesh) -> Result<(), AccelError> {
        mesh.validate()?;
        let bad = |reason: String| AccelError::Invalid { structure: "refit", reason };
        if mesh.triangle_count() != self.tris.len() {
            return Err(bad(format!("mesh has {} triangles, the tree {}", mesh.triangle_count(), self.tris.len())));
        }
        if let Some(id) = self.ids.iter().find(|&&id| id as usize >= self.tris.len()) {
            return Err(bad(format!("triangle id {id} out of range")));
        }
        for (t, &id) in self.tris.iter_mut().zip(&self.ids) {
            *t = Triangle::new(&mesh.triangle(id as usize));
        }
        if let Some(&(copy, kept)) = self.copies.iter().find(|&&(c, k)| {
            let bits = |r: u32| self.tris.get(r as usize).map(record_bits);
            bits(c) != bits(k)
        }) {
            return Err(bad(format!(
                "triangle {} no longer coincides with triangle {}, whose copy the tree keeps: rebuild",
                self.ids.get(copy as usize).copied().unwrap_or(copy),
                self.ids.get(kept as usize).copied().unwrap_or(kept)
            )));
        }
        let ids = &self.ids;
        fit_boxes(&mut self.nodes, |leaf| {
            let (first, count) = (leaf.left_or_first as usize, leaf.count() as usize);
            let mut b = Aabb::EMPTY;
            for &id in ids.get(first..first + count)? {
                for v in mesh.triangle(id as usize) {
                    b.grow(v);
                }
            }
            Some(b)
        })
        .map_err(bad)
    }

    /// SAH cost of the tree (see [`super::sah_cost`]).
    pub fn sah_cost(&self) -> f64 {
        let Some(root) = self.nodes.first() else {
            return 0.0;
        };
        sah_cost(
            root.aabb().surface_area(),
            self.nodes
                .iter()
                .map(|n| (n.aabb().surface_area(), n.is_leaf(), n.count() as usize * usize::from(n.is_leaf()))),
        )
    }

    /// [`AccelStats::build_work`] by a walk over the nodes, without [`BvhTree::validate`]'s checks.
    pub fn build_work(&self) -> Option<f64> {
        crate::accel::reference_levels_of(self.nodes.len(), |k| {
            let nd = self.nodes.get(k)?;
            Some(if nd.is_leaf() {
                crate::accel::LevelNode::Leaf(nd.count() as usize)
            } else {
                crate::accel::LevelNode::Inner(nd.left_or_first as usize, nd.right_or_count as usize)
            })
        })
    }

    /// Walks the tree from the root and checks every invariant: indices in range, every node reached exactly once
    /// (no sharing, no cycle, no orphan), children boxes inside their parent's, leaves non-empty and inside the
    /// triangle array, every triangle record in exactly one leaf and inside its leaf's box or a copy
    /// ([`BvhTree::copies`]) of a record in a leaf with a smaller triangle index and the same record bits, ids a
    /// permutation.
    pub fn validate(&self, structure: &'static str) -> Result<AccelStats, AccelError> {
        let n = self.tris.len();
        check_permutation(structure, &self.ids, n)?;
        let mut v = Validation::new(structure, n, self.memory_bytes(), self.nodes.len(), n);
        if self.nodes.is_empty() {
            return v.without_nodes(n != 0, &format!("no nodes for {n} triangles"));
        }
        let mut stack = vec![(0usize, 0usize)];
        while let Some((i, depth)) = stack.pop() {
            v.visit(i, depth)?;
            let node = &self.nodes[i];
            let b = node.aabb();
            if b.is_empty() || !b.min.is_finite() || !b.max.is_finite() {
                return Err(v.invalid(format!("node {i} has an empty or non-finite box {b:?}")));
            }
            if node.is_leaf() {
                let (first, count) = (node.left_or_first as usize, node.count() as usize);
                if count == 0 {
                    return Err(v.invalid(format!("leaf {i} is empty")));
                }
                v.leaf(i, first, count)?;
                for (t, &id) in self.tris[first..first + count].iter().zip(&self.ids[first..]) {
                    if !b.contains(&Aabb::new(t.v0, t.v0)) || !triangle_in_box(t, &b) {
                        return Err(v.invalid(format!("triangle {id} outside leaf {i}")));
                    }
                }
            } else {
                for c in [node.left_or_first as usize, node.right_or_count as usize] {
                    let child =
                        self.nodes.get(c).ok_or_else(|| v.invalid(format!("node {i}: child {c} out of range")))?;
                    if !b.contains(&child.aabb()) {
                        return Err(v.invalid(format!("node {i}: child {c} box outside parent")));
                    }
                    stack.push((c, depth + 1));
                }
            }
        }
        for &(copy, kept) in &self.copies {
            let (c, k) = (copy as usize, kept as usize);
            let (Some(tc), Some(tk)) = (self.tris.get(c), self.tris.get(k)) else {
                return Err(v.invalid(format!("copy {copy} of {kept}: out of range")));
            };
            if record_bits(tc) != record_bits(tk) || self.ids[k] >= self.ids[c] {
                return Err(v.invalid(format!(
                    "record {copy} (triangle {}) is no later copy of record {kept} (triangle {})",
                    self.ids[c], self.ids[k]
                )));
            }
            v.copy(copy as usize, kept as usize)?;
        }
        v.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_boxes_fits_any_numbering_and_rejects_what_is_not_a_tree() {
        let unit = |x: f32| Aabb::new(Vec3::splat(x), Vec3::splat(x + 1.0));
        let e = Aabb::EMPTY;
        // Root 0 -> (3, 1); 1 -> (2, 4): leaves 2, 3, 4 hold records 0, 1, 2 at x = 0, 1, 2.
        let mut nodes = vec![
            BvhNode::internal(&e, 3, 1),
            BvhNode::internal(&e, 2, 4),
            BvhNode::leaf(&e, 0, 1),
            BvhNode::leaf(&e, 1, 1),
            BvhNode::leaf(&e, 2, 1),
        ];
        let leaf_box = |nd: &BvhNode| (nd.left_or_first < 3).then(|| unit(nd.left_or_first as f32));
        fit_boxes(&mut nodes, leaf_box).unwrap();
        assert_eq!(nodes[1].aabb(), unit(0.0).union(&unit(2.0)));
        assert_eq!(nodes[0].aabb(), unit(1.0).union(&nodes[1].aabb()));
        assert_eq!(nodes[3].aabb(), unit(1.0));
        let broken = |edit: &dyn Fn(&mut Vec<BvhNode>)| {
            let mut v = nodes.clone();
            edit(&mut v);
            fit_boxes(&mut v, leaf_box).unwrap_err()
        };
        assert!(broken(&|v| v[1].right_or_count = 9).contains("out of range"));
        assert!(broken(&|v| v[1].right_or_count = 3).contains("two parents"));
        assert!(broken(&|v| v[1].right_or_count = 0).contains("out of range"));
        assert!(broken(&|v| v.push(BvhNode::leaf(&e, 0, 1))).contains("nobody's child"));
        assert!(broken(&|v| v[4].left_or_first = 7).contains("leaf 4"));
        // 1 and 5 are each other's child: every node has one parent, but 1 and 5 hang on a cycle.
        let cycle = |v: &mut Vec<BvhNode>| {
            v[1].right_or_count = 5;
            v.push(BvhNode::internal(&e, 1, 4));
            v[0].right_or_count = 6;
            v.push(BvhNode::leaf(&e, 0, 1));
        };
        assert!(broken(&cycle).contains("do not form a tree"));
    }
}
