//! Linear BVH over the Morton codes of docs/spec.md, as a binary radix tree (Karras 2012): the reference that a GPU
//! builder must reproduce node for node.
//!
//! # Definition
//!
//! 1. Keys: for triangle `i`, `s_i = centroid_key(v0, v1, v2)`; bounds `lo`, `hi` = per-axis [`min_total`] /
//!    [`max_total`] of all `s_i`; `scale = quantization_scale(lo, hi, bits)`; `code_i = morton(quantize(s_i, lo,
//!    scale, bits), bits)` ([`crate::keys`], docs/spec.md steps 1 to 4; 30-bit by default, 63-bit optional).
//! 2. Sort by the pair `(code_i, i)`; position `k` of the sorted order holds triangle `ids[k]`. The *extended key*
//!    of position `k` is the concatenation `code_k ‖ ids[k]` (`3b + 32` bits); all extended keys are distinct.
//! 3. `delta(k, j)` = length of the common prefix of the extended keys of positions `k` and `j`, or `-1` when `j`
//!    is outside `0 .. n`.
//! 4. Internal node `k` for `k` in `0 .. n-1` (Karras 2012, Fig. 4): direction `d = sign(delta(k, k+1) -
//!    delta(k, k-1))`; the other end `j` of its range is found by exponential then binary search for the farthest
//!    position with `delta(k, j) > delta(k, k - d)`; the split `gamma` is the last position of the range whose
//!    prefix with `k` is longer than `delta(k, j)`, found by binary search, adjusted by `min(d, 0)`.
//!    Its left child covers `min(k, j) ..= gamma`, its right child `gamma + 1 ..= max(k, j)`; a child covering one
//!    position `p` is the leaf of `p`, otherwise the internal node of index `gamma` (left) or `gamma + 1` (right).
//! 5. Node numbering in the shared [`BvhNode`] array: internal node `k` is node `k` (`0 .. n-1`, the root is 0),
//!    the leaf of position `p` is node `n - 1 + p`; a leaf holds one triangle record, `first = p`, `count = 1`.
//!    For `n = 1` the single leaf is node 0.
//! 6. Boxes bottom-up: a leaf's box is its triangle's box (from the mesh vertices), an internal node's the union of
//!    its children's. (Here: the parallel bottom-up pass of Karras 2012, each leaf walking up and the second
//!    arrival at a node computing its box.)
//! 7. Optional SAH leaf collapse ([`LbvhOptions::max_leaf`] `> 1`; off by default, on by default in the
//!    [`super::hlbvh`]), applied by [`collapse_leaves`] to any tree of one-record leaves. A radix tree splits at
//!    Morton bits down to single triangles, where the binned-SAH builder ([`super::bvh`]) stops as soon as a leaf
//!    is cheaper; the collapse takes that decision back bottom-up, in the spirit of the post-processing of Karras
//!    and Aila 2013 ("Fast parallel construction of high-quality bounding volume hierarchies", HPG), which also
//!    collapses subtrees into leaves by the SAH. Bottom-up, with the SAH constants `K_T = K_I = 1` of the crate and
//!    half areas `h` ([`collapse_half_area`]): a leaf of `c` records costs `h c`; an internal node's record range
//!    is `first = min`, `end = max` of its children's, `count` their sum; its split cost is `(h + C_L) + C_R`, its
//!    leaf cost `h count`; it *collapses* when `end - first == count` (its records are contiguous, always true
//!    inside a Karras tree, not always above the HLBVH's clusters), `count <= max_leaf` and leaf cost `<=` split
//!    cost; its cost is then the leaf cost, else the split cost. Each of these values is an f32 computed in that
//!    order, without fused multiply-add, every difference and product flushed to 0 below the smallest normal
//!    ([`flush_subnormal`]): a GPU computes the same bits, so GPU and CPU make the same decisions. The kept nodes
//!    (those with no collapsed ancestor) are renumbered depth first: the root is 0, an internal node `k` has its
//!    left child at `k + 1` and its right child at `k + 1 + size(left)` (`size` = kept nodes of a subtree); a
//!    collapsed node becomes the leaf `first .. end`. The records keep their sorted order. The greedy bottom-up
//!    choice is optimal for the SAH cost of the crate over all collapses of the given tree (the cost is a sum over
//!    nodes; a subtree's best cost does not depend on what lies above it).
//!
//! [`min_total`]: crate::keys::min_total
//! [`max_total`]: crate::keys::max_total

use super::bvh::{fit_boxes, BvhNode, BvhTree};
use super::{prepare, AccelError, AccelStats, AccelStructure, StructureName};
use crate::geom::{Aabb, Triangle};
use crate::keys::{centroid_key, MortonBits};
use crate::mesh::Mesh;
use rayon::prelude::*;

/// Options of the LBVH.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LbvhOptions {
    /// Morton code width.
    pub bits: MortonBits,
    /// Largest leaf the SAH collapse (step 7 of the module docs) may form, clamped to `1 ..= MAX_COLLAPSE_LEAF`;
    /// 1 (the default) turns the collapse off and keeps one triangle per leaf in the Karras numbering.
    pub max_leaf: u32,
}

impl Default for LbvhOptions {
    fn default() -> Self {
        LbvhOptions { bits: MortonBits::Bits30, max_leaf: 1 }
    }
}

/// Largest leaf the SAH collapse forms.
pub const MAX_COLLAPSE_LEAF: u32 = 64;

/// Morton codes of docs/spec.md for every triangle, in mesh order ([`crate::keys::morton_codes`] over the keys of
/// the mesh, computed once). The mesh must be valid (see [`prepare`]).
pub fn morton_codes(mesh: &Mesh, bits: MortonBits, structure: &'static str) -> Result<Vec<u64>, AccelError> {
    let n = mesh.triangle_count();
    if n == 0 {
        return Ok(Vec::new());
    }
    let keys: Vec<[f32; 3]> = (0..n)
        .into_par_iter()
        .map(|i| {
            let [a, b, c] = mesh.indices[i];
            let p = |k: u32| mesh.positions[k as usize];
            centroid_key(p(a), p(b), p(c))
        })
        .collect();
    let (_, codes) = crate::keys::morton_codes(n, |i| keys[i], bits).map_err(|e| AccelError::of_keys(structure, e))?;
    Ok(codes)
}

/// Sorted `(code, triangle)` pairs.
pub fn sorted_keys(codes: &[u64]) -> Vec<(u64, u32)> {
    let mut v: Vec<(u64, u32)> = codes.iter().enumerate().map(|(i, &c)| (c, i as u32)).collect();
    v.par_sort_unstable();
    v
}

/// Karras 2012 radix tree over sorted, distinct extended keys: for each internal node `k` in `0 .. n-1`, its
/// `(left, right)` children in the unified numbering (internal `k`, leaf `n - 1 + p`).
pub fn radix_tree_children(keys: &[(u64, u32)], code_bits: u32) -> Vec<(u32, u32)> {
    let n = keys.len() as i64;
    let delta = |i: i64, j: i64| -> i64 {
        if j < 0 || j >= n {
            return -1;
        }
        let (a, b) = (keys[i as usize], keys[j as usize]);
        if a.0 != b.0 {
            (a.0 ^ b.0).leading_zeros() as i64 - (64 - code_bits as i64)
        } else {
            code_bits as i64 + (a.1 ^ b.1).leading_zeros() as i64
        }
    };
    (0..(n - 1).max(0))
        .into_par_iter()
        .map(|i| {
            let d: i64 = if delta(i, i + 1) - delta(i, i - 1) >= 0 { 1 } else { -1 };
            let dmin = delta(i, i - d);
            let mut lmax: i64 = 2;
            while delta(i, i + lmax * d) > dmin {
                lmax *= 2;
            }
            let mut l: i64 = 0;
            let mut t = lmax / 2;
            while t >= 1 {
                if delta(i, i + (l + t) * d) > dmin {
                    l += t;
                }
                t /= 2;
            }
            let j = i + l * d;
            let dnode = delta(i, j);
            let mut s: i64 = 0;
            let mut t = l;
            loop {
                t = (t + 1) >> 1;
                if delta(i, i + (s + t) * d) > dnode {
                    s += t;
                }
                if t <= 1 {
                    break;
                }
            }
            let gamma = i + s * d + d.min(0);
            let leaf = |p: i64| (n - 1 + p) as u32;
            let left = if i.min(j) == gamma { leaf(gamma) } else { gamma as u32 };
            let right = if i.max(j) == gamma + 1 { leaf(gamma + 1) } else { (gamma + 1) as u32 };
            (left, right)
        })
        .collect()
}

/// The nodes of the Karras tree of `keys` (sorted) in the unified numbering, boxes fitted: internal node `k` has
/// the children [`radix_tree_children`] gives, the leaf of position `p` holds record `first + p` with the box of
/// its triangle (`boxes`, in mesh order). Shared by the LBVH and every HLBVH cluster (`first` = the cluster's first
/// position).
pub(crate) fn karras_nodes(keys: &[(u64, u32)], bits: MortonBits, boxes: &[Aabb], first: usize) -> Vec<BvhNode> {
    let m = keys.len();
    if m == 0 {
        return Vec::new();
    }
    let children = radix_tree_children(keys, bits.total());
    let mut nodes = vec![BvhNode::default(); 2 * m - 1];
    let (internal, leaves) = nodes.split_at_mut(m - 1);
    for (nd, &(l, r)) in internal.iter_mut().zip(&children) {
        *nd = BvhNode::internal(&Aabb::EMPTY, l, r);
    }
    leaves.par_iter_mut().enumerate().with_min_len(1024).for_each(|(p, nd)| {
        *nd = BvhNode::leaf(&boxes[keys[p].1 as usize], (first + p) as u32, 1);
    });
    // A Karras tree is a tree over all its nodes, so the fit cannot fail; its leaves keep the boxes set here.
    let fitted = fit_boxes(&mut nodes, |leaf| Some(leaf.aabb()));
    debug_assert!(fitted.is_ok(), "{fitted:?}");
    nodes
}

/// Builds the Karras tree of sorted keys whose triangle boxes are `boxes` (mesh order), with triangle records
/// `tris`: nodes in the unified numbering and the records in sorted order.
pub(crate) fn karras_tree(
    keys: &[(u64, u32)],
    bits: MortonBits,
    boxes: &[Aabb],
    tris: &[Triangle],
) -> (Vec<BvhNode>, Vec<Triangle>, Vec<u32>) {
    let nodes = karras_nodes(keys, bits, boxes, 0);
    let ids: Vec<u32> = keys.iter().map(|k| k.1).collect();
    let sorted_tris = ids.par_iter().map(|&i| tris[i as usize]).collect();
    (nodes, sorted_tris, ids)
}

/// `x`, or 0 where it is below the smallest normal f32: the collapse's arithmetic never meets a subnormal, so a
/// device that flushes subnormals computes the same values as the host.
#[inline]
pub fn flush_subnormal(x: f32) -> f32 {
    if x < f32::MIN_POSITIVE {
        0.0
    } else {
        x
    }
}

/// Half the surface area of a node's box as the SAH collapse computes it (step 7 of the module docs):
/// `e = max - min` per axis, then `(e.x e.y + e.y e.z) + e.z e.x`, every difference and product flushed with
/// [`flush_subnormal`], no fused multiply-add.
#[inline]
pub fn collapse_half_area(nd: &BvhNode) -> f32 {
    let e: [f32; 3] = std::array::from_fn(|a| flush_subnormal(nd.max[a] - nd.min[a]));
    let xy = flush_subnormal(e[0] * e[1]);
    let yz = flush_subnormal(e[1] * e[2]);
    let zx = flush_subnormal(e[2] * e[0]);
    (xy + yz) + zx
}

/// Per-node results of the collapse's bottom-up pass.
#[derive(Clone, Copy, Debug, Default)]
struct CollapseInfo {
    first: u32,
    end: u32,
    count: u32,
    cost: f32,
    size: u32,
    collapse: bool,
}

/// The SAH leaf collapse (step 7 of the module docs) of a tree in the crate's layout whose leaves hold one record
/// each: bottom-up costs, then the surviving nodes in depth-first order. `max_leaf <= 1` returns the tree as is.
pub fn collapse_leaves(nodes: &[BvhNode], max_leaf: u32) -> Vec<BvhNode> {
    let max_leaf = max_leaf.min(MAX_COLLAPSE_LEAF);
    if max_leaf <= 1 || nodes.is_empty() {
        return nodes.to_vec();
    }
    // Preorder from the root; its reverse visits children before parents.
    let mut order = Vec::with_capacity(nodes.len());
    let mut stack = vec![0u32];
    while let Some(k) = stack.pop() {
        order.push(k);
        let nd = &nodes[k as usize];
        if !nd.is_leaf() {
            stack.push(nd.right_or_count);
            stack.push(nd.left_or_first);
        }
    }
    let mut info = vec![CollapseInfo::default(); nodes.len()];
    for &k in order.iter().rev() {
        let nd = &nodes[k as usize];
        let h = collapse_half_area(nd);
        info[k as usize] = if nd.is_leaf() {
            CollapseInfo {
                first: nd.left_or_first,
                end: nd.left_or_first + nd.count(),
                count: nd.count(),
                cost: h * nd.count() as f32,
                size: 1,
                collapse: false,
            }
        } else {
            let (l, r) = (info[nd.left_or_first as usize], info[nd.right_or_count as usize]);
            let first = l.first.min(r.first);
            let end = l.end.max(r.end);
            let count = l.count + r.count;
            let split = (h + l.cost) + r.cost;
            let leaf = h * count as f32;
            let collapse = count <= max_leaf && end - first == count && leaf <= split;
            CollapseInfo {
                first,
                end,
                count,
                cost: if collapse { leaf } else { split },
                size: if collapse { 1 } else { 1 + l.size + r.size },
                collapse,
            }
        };
    }
    let mut out = vec![BvhNode::default(); info[0].size as usize];
    let mut stack = vec![(0u32, 0u32)];
    while let Some((old, new)) = stack.pop() {
        let nd = &nodes[old as usize];
        let i = info[old as usize];
        out[new as usize] = if nd.is_leaf() || i.collapse {
            BvhNode::leaf(&nd.aabb(), i.first, i.count)
        } else {
            let (l, r) = (new + 1, new + 1 + info[nd.left_or_first as usize].size);
            stack.push((nd.right_or_count, r));
            stack.push((nd.left_or_first, l));
            BvhNode::internal(&nd.aabb(), l, r)
        };
    }
    out
}

/// The LBVH (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct Lbvh {
    tree: BvhTree,
    codes: Vec<u64>,
    max_leaf: u32,
}

impl Lbvh {
    /// Builds with explicit options.
    pub fn build_with(mesh: &Mesh, o: &LbvhOptions) -> Result<Self, AccelError> {
        let (tris, boxes) = prepare(mesh, "lbvh")?;
        let codes = morton_codes(mesh, o.bits, "lbvh")?;
        let keys = sorted_keys(&codes);
        let (nodes, tris, ids) = karras_tree(&keys, o.bits, &boxes, &tris);
        let nodes = collapse_leaves(&nodes, o.max_leaf);
        Ok(Lbvh {
            tree: BvhTree { nodes, tris, ids, copies: Vec::new() },
            codes: keys.iter().map(|k| k.0).collect(),
            max_leaf: o.max_leaf,
        })
    }
    /// The nodes and triangle records.
    pub fn tree(&self) -> &BvhTree {
        &self.tree
    }
    /// The tree, by value (to refit it for later frames, [`BvhTree::refit`]).
    pub fn into_tree(self) -> BvhTree {
        self.tree
    }
    /// Refits the tree to the positions of `mesh` (the next frame of an animation): see [`BvhTree::refit`]. The
    /// sorted codes are those of the frame the tree was built for.
    pub fn refit(&mut self, mesh: &Mesh) -> Result<(), AccelError> {
        self.tree.refit(mesh)
    }
    /// Sorted Morton codes (position `k` belongs to triangle `tree().triangle_ids()[k]`).
    pub fn sorted_codes(&self) -> &[u64] {
        &self.codes
    }
}

impl AccelStructure for Lbvh {
    fn build(mesh: &Mesh) -> Result<Self, AccelError> {
        Lbvh::build_with(mesh, &LbvhOptions::default())
    }
    fn name(&self) -> StructureName {
        StructureName::Lbvh
    }
    traversal_methods!(tree);
    /// The BVH checks of [`BvhTree::validate`], plus the LBVH shape: `n - 1` internal nodes and `n` leaves of one
    /// record each, leaf `n - 1 + p` holding record `p` (after the collapse: the depth-first numbering of step 7 and
    /// leaves of at most `max_leaf` records), codes sorted with ids ascending among equal codes.
    fn validate(&self) -> Result<AccelStats, AccelError> {
        let s = self.tree.validate("lbvh")?;
        let n = self.tree.tris.len();
        if self.max_leaf.min(MAX_COLLAPSE_LEAF) > 1 {
            check_depth_first_shape("lbvh", &self.tree.nodes, self.max_leaf)?;
        } else {
            check_karras_shape("lbvh", &self.tree.nodes, n, 0, 0)?;
        }
        let keys: Vec<(u64, u32)> = self.codes.iter().copied().zip(self.tree.ids.iter().copied()).collect();
        if keys.windows(2).any(|w| w[0] >= w[1]) {
            return Err(super::invalid("lbvh", "keys not strictly increasing"));
        }
        Ok(s)
    }
    fn memory_bytes(&self) -> usize {
        self.tree.memory_bytes()
    }
    fn sah_cost(&self) -> Option<f64> {
        Some(self.tree.sah_cost())
    }
}

/// Checks the depth-first numbering of a collapsed tree (step 7 of the module docs): every internal node `k` has
/// its left child at `k + 1` and its right child after it, and no leaf holds more than `max_leaf` records.
pub(crate) fn check_depth_first_shape(
    structure: &'static str,
    nodes: &[BvhNode],
    max_leaf: u32,
) -> Result<(), AccelError> {
    for (k, nd) in nodes.iter().enumerate() {
        let ok = if nd.is_leaf() {
            nd.count() <= max_leaf.min(MAX_COLLAPSE_LEAF)
        } else {
            nd.left_or_first as usize == k + 1 && nd.right_or_count > nd.left_or_first
        };
        if !ok {
            return Err(super::invalid(
                structure,
                format!("node {k} breaks the depth-first numbering of the collapse"),
            ));
        }
    }
    Ok(())
}

/// Checks the Karras numbering of a block of `2m - 1` nodes starting at `offset` whose records start at
/// `first`: internal nodes first (children inside the block), then one single-record leaf per position in order.
pub(crate) fn check_karras_shape(
    structure: &'static str,
    nodes: &[BvhNode],
    m: usize,
    offset: usize,
    first: usize,
) -> Result<(), AccelError> {
    if m == 0 {
        return Ok(());
    }
    let block =
        nodes.get(offset..offset + 2 * m - 1).ok_or_else(|| super::invalid(structure, "Karras block out of range"))?;
    for (k, nd) in block.iter().enumerate() {
        let is_leaf = k >= m - 1;
        let ok = if is_leaf {
            nd.is_leaf() && nd.count() == 1 && nd.left_or_first as usize == first + k - (m - 1)
        } else {
            let inside = |c: u32| (offset..offset + 2 * m - 1).contains(&(c as usize));
            !nd.is_leaf() && inside(nd.left_or_first) && inside(nd.right_or_count)
        };
        if !ok {
            return Err(super::invalid(structure, format!("node {} breaks the Karras numbering", offset + k)));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn karras_children_of_distinct_codes() {
        // Codes 000, 001, 100, 101: the root splits at the top bit, each half at the lowest.
        let keys = [(0b000, 0), (0b001, 1), (0b100, 2), (0b101, 3)];
        assert_eq!(radix_tree_children(&keys, 3), vec![(1, 2), (3, 4), (5, 6)]);
    }

    #[test]
    fn karras_children_of_equal_codes_split_by_triangle_index() {
        // All codes equal: the extended keys differ only in the triangle index (0, 1, 2): the root separates
        // index 2 (bit 1) from 0 and 1 (bit 0).
        let keys = [(5, 0), (5, 1), (5, 2)];
        assert_eq!(radix_tree_children(&keys, 3), vec![(1, 4), (2, 3)]);
    }

    fn unit_box_at(x: f32) -> Aabb {
        Aabb::new(Vec3::splat(x), Vec3::splat(x + 1.0))
    }

    #[test]
    fn collapse_merges_coincident_leaves_and_keeps_distant_ones() {
        // Root 0 over internal 1 (leaves 3, 4: unit boxes at 0, records 0 and 1) and leaf 2 (unit box at 10,
        // record 2). Node 1: split (3 + 3) + 3 = 9 > leaf 3 * 2 = 6: collapses. Root: half area 3 * 121 = 363,
        // split (363 + 6) + 3 = 372 < leaf 363 * 3: stays.
        let near = unit_box_at(0.0);
        let far = unit_box_at(10.0);
        let all = near.union(&far);
        let nodes = [
            BvhNode::internal(&all, 1, 2),
            BvhNode::internal(&near, 3, 4),
            BvhNode::leaf(&far, 2, 1),
            BvhNode::leaf(&near, 0, 1),
            BvhNode::leaf(&near, 1, 1),
        ];
        let out = collapse_leaves(&nodes, 8);
        assert_eq!(out, vec![BvhNode::internal(&all, 1, 2), BvhNode::leaf(&near, 0, 2), BvhNode::leaf(&far, 2, 1)]);
        check_depth_first_shape("test", &out, 8).unwrap();
        // Off: the tree comes back as it was.
        assert_eq!(collapse_leaves(&nodes, 1), nodes.to_vec());
        // A cap of 1 record per leaf is the same as off.
        assert_eq!(collapse_leaves(&nodes, 0), nodes.to_vec());
    }

    #[test]
    fn collapse_respects_the_cap_and_needs_contiguous_records() {
        let b = unit_box_at(0.0);
        // Three coincident leaves: everything would collapse, but the cap of 2 keeps the root.
        let nodes = [
            BvhNode::internal(&b, 1, 2),
            BvhNode::internal(&b, 3, 4),
            BvhNode::leaf(&b, 2, 1),
            BvhNode::leaf(&b, 0, 1),
            BvhNode::leaf(&b, 1, 1),
        ];
        assert_eq!(collapse_leaves(&nodes, 2), vec![BvhNode::internal(&b, 1, 2), BvhNode::leaf(&b, 0, 2), nodes[2]]);
        assert_eq!(collapse_leaves(&nodes, 3), vec![BvhNode::leaf(&b, 0, 3)]);
        // Records 0 and 2 under one node (as above the HLBVH's clusters): not a range, no collapse there.
        let split = [
            BvhNode::internal(&b, 1, 2),
            BvhNode::internal(&b, 3, 4),
            BvhNode::leaf(&b, 1, 1),
            BvhNode::leaf(&b, 0, 1),
            BvhNode::leaf(&b, 2, 1),
        ];
        let out = collapse_leaves(&split, 2);
        assert_eq!(out.len(), 5);
        assert!(out.iter().all(|n| !n.is_leaf() || n.count() == 1));
        check_depth_first_shape("test", &out, 2).unwrap();
    }

    #[test]
    fn half_area_flushes_subnormal_products() {
        let tiny = BvhNode::leaf(&Aabb::new(Vec3::ZERO, Vec3::splat(1e-20)), 0, 1);
        assert_eq!(collapse_half_area(&tiny), 0.0);
        assert_eq!(collapse_half_area(&BvhNode::leaf(&unit_box_at(0.0), 0, 1)), 3.0);
        assert_eq!(flush_subnormal(f32::MIN_POSITIVE / 2.0), 0.0);
        assert_eq!(flush_subnormal(f32::MIN_POSITIVE), f32::MIN_POSITIVE);
    }

    #[test]
    fn single_key_has_no_internal_node() {
        assert!(radix_tree_children(&[(7, 0)], 30).is_empty());
        assert!(radix_tree_children(&[], 30).is_empty());
    }
}
