//! Linear BVH over the Morton codes of docs/spec.md, as a binary radix tree (Karras 2012): the reference that a GPU
//! builder must reproduce node for node.
//!
//! # Definition
//!
//! 1. Keys: for triangle `i`, `s_i = centroid_key(v0, v1, v2)`; bounds `lo`, `hi` = per-axis `min_total` /
//!    `max_total` of all `s_i`; `scale = quantization_scale(lo, hi, bits)`; `code_i = morton(quantize(s_i, lo,
//!    scale, bits), bits)` (`crate::keys`, docs/spec.md steps 1 to 4; 30-bit by default, 63-bit optional).
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
//!    [`super::hlbvh`]), applied by `collapse_leaves` to any tree of one-record leaves. A radix tree splits at
//!    Morton bits down to single triangles, where the binned-SAH builder ([`super::bvh`]) stops as soon as a leaf
//!    is cheaper; the collapse takes that decision back bottom-up, in the spirit of the post-processing of Karras
//!    and Aila 2013 ("Fast parallel construction of high-quality bounding volume hierarchies", HPG), which also
//!    collapses subtrees into leaves by the SAH. Bottom-up, with the SAH constants `K_T = K_I = 1` of the crate and
//!    half areas `h` (`collapse_half_area`): a leaf of `c` records costs `h c`; an internal node's record range
//!    is `first = min`, `end = max` of its children's, `count` their sum; its split cost is `(h + C_L) + C_R`, its
//!    leaf cost `h count`; it *collapses* when `end - first == count` (its records are contiguous, always true
//!    inside a Karras tree, not always above the HLBVH's clusters), `count <= max_leaf` and leaf cost `<=` split
//!    cost; its cost is then the leaf cost, else the split cost. Each of these values is an f32 computed in that
//!    order, without fused multiply-add, every difference and product flushed to 0 below the smallest normal
//!    (`flush_subnormal`): a GPU computes the same bits, so GPU and CPU make the same decisions. The kept nodes
//!    (those with no collapsed ancestor) are renumbered depth first: the root is 0, an internal node `k` has its
//!    left child at `k + 1` and its right child at `k + 1 + size(left)` (`size` = kept nodes of a subtree); a
//!    collapsed node becomes the leaf `first .. end`. The records keep their sorted order. The greedy bottom-up
//!    choice is optimal for the SAH cost of the crate over all collapses of the given tree (the cost is a sum over
//!    nodes; a subtree's best cost does not depend on what lies above it).
//!

use super::bvh::{BvhNode, BvhTree};
use super::{check_mesh, AccelError, AccelStats, AccelStructure, StructureName};
use crate::geom::{Aabb, Triangle};
use crate::keys::{centroid_key, MortonBits, Quantizer};
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

/// Morton codes of docs/spec.md for every triangle, in mesh order (`crate::keys::morton_codes` over the keys of
/// the mesh, computed once). The mesh must be valid (see [`crate::accel::prepare`]).
pub(crate) fn morton_codes(mesh: &Mesh, bits: MortonBits, structure: &'static str) -> Result<Vec<u64>, AccelError> {
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
pub(crate) fn sorted_keys(codes: &[u64]) -> Vec<(u64, u32)> {
    let top = codes.par_iter().copied().max().unwrap_or(0);
    let bits = 64 - top.leading_zeros();
    // A stable sort by code of the pairs in triangle order sorts them by (code, triangle). Codes of up to 32 bits
    // travel packed with their index in one u64 (half the bytes per pass).
    if bits <= 32 && codes.len() as u64 <= u64::from(u32::MAX) + 1 {
        let mut packed: Vec<u64> = codes.par_iter().enumerate().map(|(i, &c)| (c << 32) | i as u64).collect();
        super::radix::sort_by_key(&mut packed, bits, |x| x >> 32);
        return packed.par_iter().map(|&x| (x >> 32, x as u32)).collect();
    }
    let mut v: Vec<(u64, u32)> = codes.par_iter().enumerate().map(|(i, &c)| (c, i as u32)).collect();
    super::radix::sort_by_key(&mut v, bits, |x| x.0);
    v
}

/// Karras 2012 radix tree over sorted, distinct extended keys: for each internal node `k` in `0 .. n-1`, its
/// `(left, right)` children in the unified numbering (internal `k`, leaf `n - 1 + p`).
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn radix_tree_children(keys: &[(u64, u32)], code_bits: u32) -> Vec<(u32, u32)> {
    let n = keys.len() as i64;
    let delta = |i: i64, j: i64| -> i64 {
        if j < 0 || j >= n {
            return -1;
        }
        prefix(keys[i as usize], keys[j as usize], code_bits)
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

/// Length of the common prefix of two extended keys `code ‖ triangle` (step 3 of the module docs).
#[inline]
fn prefix(a: (u64, u32), b: (u64, u32), code_bits: u32) -> i64 {
    if a.0 != b.0 {
        (a.0 ^ b.0).leading_zeros() as i64 - (64 - code_bits as i64)
    } else {
        code_bits as i64 + (a.1 ^ b.1).leading_zeros() as i64
    }
}

/// Ranges of at least this many positions build their two subtrees in parallel.
const KARRAS_PARALLEL: usize = 4096;

/// The nodes of the Karras tree of `keys` (sorted) in the unified numbering, boxes fitted: internal node `k` has
/// the children [`radix_tree_children`] gives, the leaf of position `p` holds record `first + p` with the box of
/// its triangle (`leaf_box` of its position in `keys`). Shared by the LBVH and every HLBVH cluster (`first` = the
/// cluster's first position).
///
/// Built top down in one pass with the box fit: the node over positions `a ..= b` splits after `gamma`, the last
/// position whose extended key shares more than `delta(a, b)` leading bits with that of `a` (a binary search; the
/// same split as the Karras construction, which builds this one binary radix tree), its left child is the leaf of
/// `a` or internal node `gamma`, its right child the leaf of `b` or internal node `gamma + 1`, and its box is the
/// union of its children's (left, then right, as [`fit_boxes`] takes it). A node over `a ..= b` is internal node
/// `a` or `b`; the internal nodes below it lie in `a ..= b` without it, so the two subtrees own disjoint parts of
/// the node array and ranges of [`KARRAS_PARALLEL`] positions and more build them in parallel. The depth is at most
/// the extended key's bit count, so the recursion is shallow. [`radix_tree_children`] with [`fit_boxes`] is the
/// reference it is tested against.
pub(crate) fn karras_nodes<F>(keys: &[(u64, u32)], bits: MortonBits, leaf_box: &F, first: usize) -> Vec<BvhNode>
where
    F: Fn(usize) -> Aabb + Sync,
{
    let m = keys.len();
    if m == 0 {
        return Vec::new();
    }
    let mut nodes = vec![BvhNode::default(); 2 * m - 1];
    if m == 1 {
        nodes[0] = BvhNode::leaf(&leaf_box(0), first as u32, 1);
        return nodes;
    }
    let (internal, leaves) = nodes.split_at_mut(m - 1);
    let cx = KarrasBuild { keys, code_bits: bits.total(), leaf_box, first: first as u32, m };
    cx.node(0, m - 1, true, internal, leaves);
    nodes
}

/// What every step of [`karras_nodes`] reads.
struct KarrasBuild<'a, F> {
    keys: &'a [(u64, u32)],
    code_bits: u32,
    leaf_box: &'a F,
    first: u32,
    m: usize,
}

impl<F: Fn(usize) -> Aabb + Sync> KarrasBuild<'_, F> {
    /// Builds the subtree over positions `a ..= b` (`a < b`). Its node is internal node `a` when it is the root or
    /// a right child (`own_first`), internal node `b` when it is a left child; `internal` holds exactly the internal
    /// nodes of the subtree: `a ..= b - 1` for the root and right children, `a + 1 ..= b` for left children (by
    /// induction from the root's `0 ..= m - 2`: either way the children share `a + 1 ..= b - 1`, the left one taking
    /// `a + 1 ..= gamma`). `leaves` holds the leaves of `a ..= b`. Returns the subtree's box.
    fn node(&self, a: usize, b: usize, own_first: bool, internal: &mut [BvhNode], leaves: &mut [BvhNode]) -> Aabb {
        let keys = self.keys;
        let dnode = prefix(keys[a], keys[b], self.code_bits);
        // The last position p in a ..= b - 1 with prefix(a, p) > dnode (p = a qualifies).
        let (mut lo, mut hi) = (a, b - 1);
        while lo < hi {
            let mid = lo + (hi - lo).div_ceil(2);
            if prefix(keys[a], keys[mid], self.code_bits) > dnode {
                lo = mid;
            } else {
                hi = mid - 1;
            }
        }
        let gamma = lo;
        let split = if own_first { internal.split_first_mut() } else { internal.split_last_mut() };
        let Some((own, rest)) = split else { unreachable!("a node over two or more positions owns its own slot") };
        let (li, ri) = rest.split_at_mut(gamma - a);
        let (ll, rl) = leaves.split_at_mut(gamma + 1 - a);
        let leaf_index = |p: usize| (self.m - 1 + p) as u32;
        let left_index = if a == gamma { leaf_index(a) } else { gamma as u32 };
        let right_index = if b == gamma + 1 { leaf_index(b) } else { (gamma + 1) as u32 };
        let left = |li: &mut [BvhNode], ll: &mut [BvhNode]| self.child(a, gamma, false, li, ll);
        let right = |ri: &mut [BvhNode], rl: &mut [BvhNode]| self.child(gamma + 1, b, true, ri, rl);
        let (lb, rb) = if b - a >= KARRAS_PARALLEL {
            rayon::join(|| left(li, ll), || right(ri, rl))
        } else {
            (left(li, ll), right(ri, rl))
        };
        let bx = lb.union(&rb);
        *own = BvhNode::internal(&bx, left_index, right_index);
        bx
    }

    /// A child over `a ..= b`: the leaf of `a` when `a == b`, else the subtree.
    fn child(&self, a: usize, b: usize, own_first: bool, internal: &mut [BvhNode], leaves: &mut [BvhNode]) -> Aabb {
        if a == b {
            let bx = (self.leaf_box)(a);
            leaves[0] = BvhNode::leaf(&bx, self.first + a as u32, 1);
            return bx;
        }
        self.node(a, b, own_first, internal, leaves)
    }
}

/// `x`, or 0 where it is below the smallest normal f32: the collapse's arithmetic never meets a subnormal, so a
/// device that flushes subnormals computes the same values as the host.
#[inline]
pub(crate) fn flush_subnormal(x: f32) -> f32 {
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
pub(crate) fn collapse_half_area(nd: &BvhNode) -> f32 {
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
pub(crate) fn collapse_leaves(nodes: &[BvhNode], max_leaf: u32) -> Vec<BvhNode> {
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
        crate::in_pool(|| Self::build_here(mesh, o))
    }

    /// The LBVH of `mesh` over the codes of a given quantizer instead of the mesh's own bounds: what
    /// [`crate::accel::gpu::BvhBuilder::record_lbvh`] builds on the device with that quantizer (a planned rebuild
    /// with the quantizer of a [`crate::characterize::plan::Plan`]), node for node. A key outside the quantizer's
    /// bounds gets the code of the nearest cell (docs/spec.md, "Planned characterization"). With the quantizer of
    /// the mesh's own bounds it is [`Lbvh::build_with`]'s tree.
    ///
    /// Errors: those of [`Lbvh::build_with`], and [`AccelError::Invalid`] when the quantizer's code width is not
    /// `o.bits`.
    pub fn build_quantized(mesh: &Mesh, quantizer: &Quantizer, o: &LbvhOptions) -> Result<Self, AccelError> {
        if quantizer.bits() != o.bits {
            return Err(AccelError::Invalid {
                structure: "lbvh",
                reason: format!(
                    "the quantizer has {}-bit codes, the options ask for {}",
                    quantizer.bits().total(),
                    o.bits.total()
                ),
            });
        }
        crate::in_pool(|| {
            check_mesh(mesh, "lbvh")?;
            let codes: Vec<u64> = (0..mesh.triangle_count())
                .into_par_iter()
                .map(|i| {
                    let [a, b, c] = mesh.indices[i];
                    let p = |k: u32| mesh.positions[k as usize];
                    quantizer.code(centroid_key(p(a), p(b), p(c)))
                })
                .collect();
            Self::build_from_codes(mesh, &codes, o)
        })
    }

    fn build_here(mesh: &Mesh, o: &LbvhOptions) -> Result<Self, AccelError> {
        check_mesh(mesh, "lbvh")?;
        let codes = morton_codes(mesh, o.bits, "lbvh")?;
        Self::build_from_codes(mesh, &codes, o)
    }

    /// The tree over the Morton codes of every triangle, in mesh order (the mesh checked).
    fn build_from_codes(mesh: &Mesh, codes: &[u64], o: &LbvhOptions) -> Result<Self, AccelError> {
        let keys = sorted_keys(codes);
        // The vertices gathered once in sorted order, so that the leaf boxes and the triangle records read them in
        // order: on meshes stored in no spatial order (a particle soup) a second gather from the mesh cost the
        // build a third of its time at 200K triangles.
        let ids: Vec<u32> = keys.par_iter().map(|k| k.1).collect();
        let verts: Vec<[glam::Vec3; 3]> = ids.par_iter().map(|&i| mesh.triangle(i as usize)).collect();
        let nodes = karras_nodes(&keys, o.bits, &|p| Aabb::of_triangle(&verts[p]), 0);
        let nodes = if o.max_leaf.min(MAX_COLLAPSE_LEAF) > 1 { collapse_leaves(&nodes, o.max_leaf) } else { nodes };
        let tris = verts.par_iter().map(Triangle::new).collect();
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
    fn build_work(&self) -> Option<f64> {
        self.tree.build_work()
    }
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
    use crate::accel::bvh::fit_boxes;
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

    /// The Karras construction node by node ([`radix_tree_children`], then [`fit_boxes`]): the reference of the
    /// top-down [`karras_nodes`].
    fn karras_reference(keys: &[(u64, u32)], bits: MortonBits, boxes: &[Aabb], first: usize) -> Vec<BvhNode> {
        let m = keys.len();
        let children = radix_tree_children(keys, bits.total());
        let mut nodes: Vec<BvhNode> = children.iter().map(|&(l, r)| BvhNode::internal(&Aabb::EMPTY, l, r)).collect();
        nodes.extend((0..m).map(|p| BvhNode::leaf(&boxes[keys[p].1 as usize], (first + p) as u32, 1)));
        fit_boxes(&mut nodes, |leaf| Some(leaf.aabb())).unwrap();
        nodes
    }

    #[test]
    fn the_top_down_build_equals_the_karras_construction() {
        let mut seed = 11u64;
        let mut rnd = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            seed >> 33
        };
        for &(n, range, bits) in &[
            (1usize, 1u64 << 30, MortonBits::Bits30),
            (2, 1 << 30, MortonBits::Bits30),
            (3, 1, MortonBits::Bits30),
            (17, 4, MortonBits::Bits30),
            (1000, 1 << 30, MortonBits::Bits30),
            (20_000, 1 << 30, MortonBits::Bits30),
            (20_000, 1, MortonBits::Bits30),
            (20_000, 64, MortonBits::Bits30),
            (9_000, 1 << 63, MortonBits::Bits63),
            (9_000, 3, MortonBits::Bits63),
        ] {
            let boxes: Vec<Aabb> = (0..n)
                .map(|_| {
                    let p = Vec3::new(rnd() as f32, rnd() as f32, rnd() as f32) / 1e6;
                    Aabb::new(p, p + Vec3::splat((rnd() % 7) as f32 / 3.0))
                })
                .collect();
            let codes: Vec<u64> = (0..n).map(|_| ((rnd() << 31) ^ rnd()) % range).collect();
            let keys = sorted_keys(&codes);
            let mut expect = keys.clone();
            expect.sort_unstable();
            assert_eq!(keys, expect, "sorted keys, n {n}");
            for first in [0, 5] {
                let got = karras_nodes(&keys, bits, &|p| boxes[keys[p].1 as usize], first);
                assert_eq!(got, karras_reference(&keys, bits, &boxes, first), "n {n}, codes below {range}");
            }
        }
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
