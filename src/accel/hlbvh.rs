//! Hierarchical LBVH (Pantaleoni and Luebke 2010, in the form pbrt gives it: Morton clusters, an LBVH per cluster,
//! SAH over the clusters at the top), with the SAH leaf collapse of the [`super::lbvh`] step 7.
//!
//! The default options reach an SAH cost within 1.15 x the binned-SAH BVH's ([`super::bvh`]) on the shared static
//! meshes (measured in `tests/gpu/gpu_lbvh.rs` and `benches/bvh_build.rs`; `docs/bvh-builders.md` has the table):
//! 21 cluster bits (7 of the 10 Morton bits per axis, up to 2^21 clusters; pbrt's 12 bits left 1.2 to 1.4 x, the
//! Morton splits below the clusters being the expensive part) and leaves of up to 8 triangles where the SAH
//! prefers them. Garanzha et al. 2011 ("Simpler and faster HLBVH with work queues", HPG) likewise build the SAH
//! levels over fine Morton clusters.
//!
//! # Definition (what a GPU builder reproduces)
//!
//! 1. Keys and sort exactly as the [`super::lbvh`] steps 1 and 2.
//! 2. Clusters: maximal runs of sorted positions whose codes share their top [`HlbvhOptions::cluster_bits`] bits
//!    (21 by default; pbrt uses 12 with 30-bit codes), numbered in sorted order. Cluster `c` covers positions
//!    `s_c .. e_c`, `m_c = e_c - s_c`.
//! 3. Bottom: each cluster is a Karras 2012 radix tree over its positions (the [`super::lbvh`] steps 3 to 6 applied
//!    to the sub-array, with `delta = -1` outside it), stored as a block of `2 m_c - 1` nodes in the LBVH numbering
//!    (internal `0 .. m_c - 1`, leaves after), leaf of position `p` holding record `p` (global).
//! 4. Top: with `C` clusters, nodes `0 .. C - 1` are the top tree, in depth-first order (a node's left subtree
//!    follows it); cluster blocks follow in cluster order from node `C - 1`. The top tree is binned SAH
//!    (Wald 2007) over the cluster root boxes: [`HlbvhOptions::bins`] bins per axis on the box centroids, cost
//!    `A_L N_L + A_R N_R` with `N` counting clusters, the least cost taken (ties: lower axis, then lower bin);
//!    clusters keep their order within each side; a node with one cluster is that cluster's root (the parent
//!    points into the block); a node whose cluster centroids coincide on every axis splits its list in the middle.
//!    A top node's box is the union of its children's. With one cluster, node 0 is that cluster's root.
//! 5. With [`HlbvhOptions::max_leaf`] `> 1` (8 by default), the SAH leaf collapse of the [`super::lbvh`] step 7
//!    over the whole tree (a top node collapses only where its clusters are adjacent in sorted order), which
//!    renumbers the kept nodes depth first; with 1 the layout of steps 3 and 4 stays.

use super::bvh::{sweep_bins, BvhNode, BvhTree};
use super::lbvh::{
    check_depth_first_shape, check_karras_shape, collapse_leaves, karras_nodes, morton_codes, sorted_keys,
    MAX_COLLAPSE_LEAF,
};
use super::{invalid, prepare, AccelError, AccelStats, AccelStructure, StructureName};
use crate::geom::Aabb;
use crate::keys::MortonBits;
use crate::mesh::Mesh;
use glam::Vec3;
use rayon::prelude::*;

/// Options of the HLBVH.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HlbvhOptions {
    /// Morton code width.
    pub bits: MortonBits,
    /// Top code bits that define a cluster (at most the code width).
    pub cluster_bits: u32,
    /// Bins per axis of the top-level SAH (2 to 64).
    pub bins: usize,
    /// Largest leaf the SAH collapse (step 5 of the module docs) may form, clamped to `1 ..=`
    /// [`MAX_COLLAPSE_LEAF`]; 1 turns the collapse off (one triangle per leaf, the layout of steps 3 and 4).
    pub max_leaf: u32,
}

impl Default for HlbvhOptions {
    fn default() -> Self {
        HlbvhOptions { bits: MortonBits::Bits30, cluster_bits: 21, bins: 16, max_leaf: 8 }
    }
}

/// The HLBVH (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct Hlbvh {
    tree: BvhTree,
    /// `(first position, count, block offset)` of every cluster.
    clusters: Vec<(u32, u32, u32)>,
    max_leaf: u32,
}

/// Largest number of bins per axis of the top level.
const MAX_TOP_BINS: usize = 64;

/// Reused storage of [`top_split`]: the partition buffer and the bins (only the first `bins` entries are used).
struct SplitScratch {
    list: Vec<u32>,
    bb: [Aabb; MAX_TOP_BINS],
    bn: [u32; MAX_TOP_BINS],
}

impl SplitScratch {
    fn new() -> Self {
        SplitScratch { list: Vec::new(), bb: [Aabb::EMPTY; MAX_TOP_BINS], bn: [0; MAX_TOP_BINS] }
    }
}

/// The bins per axis of the top level for the option `bins` (clamped to `2 ..= 64`) and the numerator of every
/// axis' bin scale, `nb as f32 * (1.0 - 1e-6)` (the scale is that divided by the axis' centroid extent), shared
/// with the GPU top level (`glsl/hlbvh_top.comp`).
pub(crate) fn top_bins(bins: usize) -> (usize, f32) {
    let nb = bins.clamp(2, MAX_TOP_BINS);
    (nb, nb as f32 * (1.0 - 1e-6))
}

/// Split position of a top node's cluster list (reordered in place, stable on each side) by the binned SAH of
/// step 4 (the sweep of the binned-SAH builder, [`sweep_bins`]); `centers` are the cluster boxes' centres
/// (`Aabb::center`), `scratch` is reused storage.
fn top_split(list: &mut [u32], boxes: &[Aabb], centers: &[Vec3], bins: usize, scratch: &mut SplitScratch) -> usize {
    let mut cb = Aabb::EMPTY;
    for &c in list.iter() {
        cb.grow(centers[c as usize]);
    }
    let (nb, factor) = top_bins(bins);
    let ext = cb.max - cb.min;
    // The scale of every axis, evaluated as the definition writes it (the same f32 operations in the same order).
    let scale: [f32; 3] = std::array::from_fn(|a| factor / ext[a]);
    let bin_of = |c: u32, a: usize| -> usize {
        let x = (centers[c as usize][a] - cb.min[a]) * scale[a];
        (x as usize).min(nb - 1)
    };
    let mut best: Option<(usize, usize, f32)> = None;
    for a in 0..3 {
        if ext[a].is_nan() || ext[a] <= 0.0 {
            continue;
        }
        let (bb, bn) = (&mut scratch.bb, &mut scratch.bn);
        bb[..nb].fill(Aabb::EMPTY);
        bn[..nb].fill(0);
        for &c in list.iter() {
            let b = bin_of(c, a);
            bb[b] = bb[b].union(&boxes[c as usize]);
            bn[b] += 1;
        }
        sweep_bins::<Aabb, MAX_TOP_BINS>(
            nb,
            |i| (bb[i], bn[i]),
            |s, cost, _| {
                if best.is_none_or(|(_, _, c)| cost < c) {
                    best = Some((a, s, cost));
                }
            },
        );
    }
    match best {
        Some((a, s, _)) => {
            // Stable partition: clusters keep their order on each side.
            let buf = &mut scratch.list;
            buf.clear();
            buf.extend(list.iter().copied().filter(|&c| bin_of(c, a) < s));
            let m = buf.len();
            buf.extend(list.iter().copied().filter(|&c| bin_of(c, a) >= s));
            list.copy_from_slice(buf);
            m
        }
        None => list.len() / 2,
    }
}

/// Top lists larger than this are split into two tasks that build their subtrees in parallel.
const PARALLEL_TOP: usize = 4096;

/// Splits the top node over `list` (at least two clusters), writes it at `out[pos]` (global index `base + pos`)
/// and returns the split position and the node's box. A node of `m` clusters has `m - 1` top nodes in its subtree,
/// so its left child's block starts at `pos + 1` and its right child's at `pos + split`.
#[allow(clippy::too_many_arguments)]
fn top_node(
    list: &mut [u32],
    roots: &[u32],
    boxes: &[Aabb],
    centers: &[Vec3],
    bins: usize,
    scratch: &mut SplitScratch,
    out: &mut [BvhNode],
    base: u32,
    pos: usize,
) -> (usize, Aabb) {
    let mut b = Aabb::EMPTY;
    for &c in list.iter() {
        b = b.union(&boxes[c as usize]);
    }
    let m = top_split(list, boxes, centers, bins, scratch);
    let n = list.len();
    let here = base + pos as u32;
    let li = if m == 1 { roots[list[0] as usize] } else { here + 1 };
    let ri = if n - m == 1 { roots[list[m] as usize] } else { here + m as u32 };
    out[pos] = BvhNode::internal(&b, li, ri);
    (m, b)
}

/// The subtree over `list` (at least two clusters) into `out` (its `list.len() - 1` nodes, global indices from
/// `base`), one node at a time with an explicit stack (no recursion, whatever the tree's depth).
fn top_sequential(
    list: &mut [u32],
    roots: &[u32],
    boxes: &[Aabb],
    centers: &[Vec3],
    bins: usize,
    out: &mut [BvhNode],
    base: u32,
) {
    let mut scratch = SplitScratch::new();
    let mut stack = vec![(0usize, list.len(), 0usize)];
    while let Some((s, e, pos)) = stack.pop() {
        let (m, _) = top_node(&mut list[s..e], roots, boxes, centers, bins, &mut scratch, out, base, pos);
        if e - s - m > 1 {
            stack.push((s + m, e, pos + m));
        }
        if m > 1 {
            stack.push((s, s + m, pos + 1));
        }
    }
}

/// The subtree over `list` (at least two clusters) into `out` (its `list.len() - 1` nodes, global indices from
/// `base`); returns its box. While both sides of a split are large they are built in parallel into disjoint slices
/// (the result does not depend on the schedule); a small side is built sequentially and the loop goes on with the
/// large one, so the recursion is at most `log2(C / PARALLEL_TOP)` deep.
fn top_subtree(
    mut list: &mut [u32],
    roots: &[u32],
    boxes: &[Aabb],
    centers: &[Vec3],
    bins: usize,
    mut out: &mut [BvhNode],
    mut base: u32,
) -> Aabb {
    let mut scratch = SplitScratch::new();
    let mut root_box = None;
    while list.len() > PARALLEL_TOP {
        let (m, b) = top_node(list, roots, boxes, centers, bins, &mut scratch, out, base, 0);
        root_box.get_or_insert(b);
        let (l, r) = list.split_at_mut(m);
        let (lo, ro) = out[1..].split_at_mut(m - 1);
        let (lbase, rbase) = (base + 1, base + m as u32);
        let side = |x: &mut [u32], o: &mut [BvhNode], b0: u32| {
            if x.len() > 1 {
                top_subtree(x, roots, boxes, centers, bins, o, b0);
            }
        };
        if l.len() > PARALLEL_TOP && r.len() > PARALLEL_TOP {
            rayon::join(|| side(l, lo, lbase), || side(r, ro, rbase));
            return b_or(root_box, b);
        }
        // One side is small: build it here, go on with the other.
        if l.len() > r.len() {
            side(r, ro, rbase);
            (list, out, base) = (l, lo, lbase);
        } else {
            side(l, lo, lbase);
            (list, out, base) = (r, ro, rbase);
        }
        if list.len() == 1 {
            return b_or(root_box, b);
        }
    }
    if list.len() > 1 {
        // The first node's box, when the loop above did not run.
        let mut b = Aabb::EMPTY;
        if root_box.is_none() {
            for &c in list.iter() {
                b = b.union(&boxes[c as usize]);
            }
        }
        top_sequential(list, roots, boxes, centers, bins, out, base);
        return b_or(root_box, b);
    }
    root_box.unwrap_or(Aabb::EMPTY)
}

fn b_or(root: Option<Aabb>, b: Aabb) -> Aabb {
    root.unwrap_or(b)
}

/// The top tree of step 4 over the clusters in `list` (their root node indices `roots` and boxes `boxes`),
/// appended to `out` in depth-first order; returns the index and box of its root (a cluster's root when `list`
/// holds one cluster).
pub(crate) fn top_tree(
    list: &mut [u32],
    roots: &[u32],
    boxes: &[Aabb],
    bins: usize,
    out: &mut Vec<BvhNode>,
) -> (u32, Aabb) {
    if list.len() == 1 {
        let c = list[0] as usize;
        return (roots[c], boxes[c]);
    }
    let base = out.len() as u32;
    let centers: Vec<Vec3> = boxes.iter().map(Aabb::center).collect();
    out.resize(out.len() + list.len() - 1, BvhNode::default());
    let block = &mut out[base as usize..];
    let root_box = top_subtree(list, roots, boxes, &centers, bins, block, base);
    (base, root_box)
}

impl Hlbvh {
    /// Builds with explicit options.
    pub fn build_with(mesh: &Mesh, o: &HlbvhOptions) -> Result<Self, AccelError> {
        crate::in_pool(|| Self::build_here(mesh, o))
    }

    fn build_here(mesh: &Mesh, o: &HlbvhOptions) -> Result<Self, AccelError> {
        let (tris, boxes) = prepare(mesh, "hlbvh")?;
        let codes = morton_codes(mesh, o.bits, "hlbvh")?;
        let keys = sorted_keys(&codes);
        let n = keys.len();
        if n == 0 {
            return Ok(Hlbvh::default());
        }
        let shift = o.bits.total() - o.cluster_bits.min(o.bits.total());
        let prefix = |k: &(u64, u32)| if shift >= 64 { 0 } else { k.0 >> shift };
        let mut ranges: Vec<(usize, usize)> = Vec::new();
        let mut s = 0;
        for i in 1..=n {
            if i == n || prefix(&keys[i]) != prefix(&keys[s]) {
                ranges.push((s, i));
                s = i;
            }
        }
        let c = ranges.len();
        let mut offsets = Vec::with_capacity(c);
        let mut off = c - 1;
        for &(s, e) in &ranges {
            offsets.push(off);
            off += 2 * (e - s) - 1;
        }
        let total = off;
        // Bottom: one Karras tree per cluster, in parallel.
        let blocks: Vec<Vec<BvhNode>> = ranges
            .par_iter()
            .zip(offsets.par_iter())
            .map(|(&(s, e), &offset)| {
                let m = e - s;
                let mut nodes = karras_nodes(&keys[s..e], o.bits, &|p| boxes[keys[s + p].1 as usize], s);
                for nd in nodes[..m - 1].iter_mut() {
                    nd.left_or_first += offset as u32;
                    nd.right_or_count += offset as u32;
                }
                nodes
            })
            .collect();
        let roots: Vec<u32> = offsets.iter().map(|&x| x as u32).collect();
        let root_boxes: Vec<Aabb> = blocks.iter().map(|b| b[0].aabb()).collect();
        let mut nodes: Vec<BvhNode> = Vec::with_capacity(total);
        let mut list: Vec<u32> = (0..c as u32).collect();
        top_tree(&mut list, &roots, &root_boxes, o.bins, &mut nodes);
        debug_assert_eq!(nodes.len(), c - 1);
        for b in blocks {
            nodes.extend(b);
        }
        let nodes = collapse_leaves(&nodes, o.max_leaf);
        let ids: Vec<u32> = keys.iter().map(|k| k.1).collect();
        let tris = ids.par_iter().map(|&i| tris[i as usize]).collect();
        let clusters =
            ranges.iter().zip(&offsets).map(|(&(s, e), &off)| (s as u32, (e - s) as u32, off as u32)).collect();
        Ok(Hlbvh { tree: BvhTree { nodes, tris, ids, copies: Vec::new() }, clusters, max_leaf: o.max_leaf })
    }

    /// The nodes and triangle records.
    pub fn tree(&self) -> &BvhTree {
        &self.tree
    }

    /// Number of Morton clusters.
    pub fn cluster_count(&self) -> usize {
        self.clusters.len()
    }
}

impl AccelStructure for Hlbvh {
    fn build(mesh: &Mesh) -> Result<Self, AccelError> {
        Hlbvh::build_with(mesh, &HlbvhOptions::default())
    }
    fn name(&self) -> StructureName {
        StructureName::Hlbvh
    }
    traversal_methods!(tree);
    fn build_work(&self) -> Option<f64> {
        self.tree.build_work()
    }
    /// The BVH checks of [`BvhTree::validate`], plus the HLBVH shape: `C - 1` top nodes, then one Karras block per
    /// cluster covering its positions, clusters contiguous and in order; after the collapse, the depth-first
    /// numbering, leaves of at most `max_leaf` records and clusters covering the records.
    fn validate(&self) -> Result<AccelStats, AccelError> {
        let s = self.tree.validate("hlbvh")?;
        if self.max_leaf.min(MAX_COLLAPSE_LEAF) > 1 {
            check_depth_first_shape("hlbvh", &self.tree.nodes, self.max_leaf)?;
            let covered: u32 = self.clusters.iter().map(|c| c.1).sum();
            if covered as usize != self.tree.tris.len() {
                return Err(invalid("hlbvh", "clusters do not cover the records"));
            }
            return Ok(s);
        }
        let c = self.clusters.len();
        let mut pos = 0usize;
        let mut off = c.saturating_sub(1);
        for &(first, m, offset) in &self.clusters {
            if first as usize != pos || offset as usize != off || m == 0 {
                return Err(invalid("hlbvh", format!("cluster at {first} (offset {offset}) out of order")));
            }
            check_karras_shape("hlbvh", &self.tree.nodes, m as usize, off, pos)?;
            pos += m as usize;
            off += 2 * m as usize - 1;
        }
        if pos != self.tree.tris.len() || off != self.tree.nodes.len() {
            return Err(invalid("hlbvh", "clusters do not cover the records and nodes"));
        }
        if self.tree.nodes[..c.saturating_sub(1)].iter().any(|n| n.is_leaf()) {
            return Err(invalid("hlbvh", "leaf among the top nodes"));
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
