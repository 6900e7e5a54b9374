//! Reinsertion: a pass over a built binary BVH that moves subtrees to where the tree's SAH cost is lower (Bittner,
//! Hapala and Havran 2013, "Fast insertion-based optimization of bounding volume hierarchies"; Meister and Bittner
//! 2018, "Parallel reinsertion for bounding volume hierarchy optimization"). A top-down builder decides each plane
//! once, from the node it splits; reinsertion revisits those decisions with the whole tree in view.
//!
//! One move takes a node `N` out (its parent `P` leaves the tree, `N`'s sibling takes `P`'s place, the boxes above
//! shrink) and puts it back beside the node `X` where it costs least (`P` becomes the parent of `X` and `N`, the boxes
//! above grow). Leaves move whole, so the leaves, their triangles and the number of internal nodes stay: only the
//! internal nodes' areas change, and the SAH cost falls by `K_T` times the change of their sum. The best `X` is found
//! by a best-first search with the bound of Bittner et al.: putting `N` below a node costs at least the growth of
//! every box on the way plus `N`'s own area. A move is kept only when it lowers the sum; otherwise `N` goes back
//! where it was, with the same boxes (unions are exact).
//!
//! Candidates are the nodes with the largest boxes below the root's children, a fraction of all nodes per round,
//! taken in that order. The pass is sequential and deterministic.

use super::BvhNode;
use crate::geom::Aabb;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

const NONE: u32 = u32::MAX;

/// Candidates are taken in batches of this many; a round ends after a batch where fewer than one in
/// [`FEW_MOVES`] moved (the smaller boxes that follow improve less).
const BATCH: usize = 256;
const FEW_MOVES: usize = 32;

/// Best-first searches stop after this many nodes (the best place found so far is taken).
const MAX_VISITS: usize = 1 << 12;

struct Tree<'a> {
    nodes: &'a mut [BvhNode],
    /// Parents (`NONE` for the root).
    p: Vec<u32>,
    root: u32,
}

/// A search entry: a key and a node; the heap pops the smallest key first.
#[derive(PartialEq)]
struct Entry(f64, u32);
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
    }
}

impl Tree<'_> {
    fn aabb(&self, i: u32) -> Aabb {
        self.nodes[i as usize].aabb()
    }
    fn area(&self, i: u32) -> f32 {
        self.aabb(i).half_area()
    }
    fn children(&self, i: u32) -> Option<[u32; 2]> {
        let n = &self.nodes[i as usize];
        (!n.is_leaf()).then_some([n.left_or_first, n.right_or_count])
    }
    fn set_children(&mut self, i: u32, [l, r]: [u32; 2]) {
        let n = &mut self.nodes[i as usize];
        n.left_or_first = l;
        n.right_or_count = r;
    }
    /// Recomputes the boxes from `i` up to the root; returns the sum of the areas' decrease.
    fn refit_up(&mut self, mut i: u32) -> f64 {
        let mut gain = 0.0f64;
        while i != NONE {
            let [l, r] = self.children(i).unwrap_or([i, i]);
            let old = self.aabb(i);
            let nb = self.aabb(l).union(&self.aabb(r));
            gain += f64::from(old.half_area()) - f64::from(nb.half_area());
            let n = &mut self.nodes[i as usize];
            n.min = nb.min.to_array();
            n.max = nb.max.to_array();
            i = self.p[i as usize];
        }
        gain
    }
    /// Replaces child `old` of `parent` (or the root) by `new`.
    fn replace_child(&mut self, parent: u32, old: u32, new: u32) {
        if parent == NONE {
            self.root = new;
        } else if let Some([l, r]) = self.children(parent) {
            self.set_children(parent, if l == old { [new, r] } else { [l, new] });
        }
        self.p[new as usize] = parent;
    }
    /// The node beside which `nb` costs least, and that cost (the growth of the boxes above it plus the area of the
    /// union with it).
    fn best_place(&self, nb: &Aabb, heap: &mut BinaryHeap<Entry>) -> (u32, f64) {
        // In f64: the growth sums differences of nearly equal areas near the root.
        let own = f64::from(nb.half_area());
        let (mut best, mut best_cost) = (self.root, f64::INFINITY);
        heap.clear();
        heap.push(Entry(0.0, self.root));
        let mut visits = 0;
        while let Some(Entry(ci, x)) = heap.pop() {
            if ci + own >= best_cost || visits == MAX_VISITS {
                break;
            }
            visits += 1;
            let b = self.aabb(x);
            let u = f64::from(b.union(nb).half_area());
            if ci + u < best_cost {
                (best, best_cost) = (x, ci + u);
            }
            if let Some(c) = self.children(x) {
                let below = ci + u - f64::from(b.half_area());
                if below + own < best_cost {
                    for k in c {
                        heap.push(Entry(below, k));
                    }
                }
            }
        }
        (best, best_cost)
    }
    /// Takes `n` out and puts it back where the internal areas' sum is least; returns whether it moved.
    fn reinsert(&mut self, n: u32, heap: &mut BinaryHeap<Entry>) -> bool {
        let p = self.p[n as usize];
        if p == NONE || self.p[p as usize] == NONE {
            return false;
        }
        let g = self.p[p as usize];
        let Some([l, r]) = self.children(p) else { return false };
        let s = if l == n { r } else { l };
        self.replace_child(g, p, s);
        let removed = f64::from(self.area(p)) + self.refit_up(g);
        let (x, cost) = self.best_place(&self.aabb(n), heap);
        let (x, moved) = if cost < removed * (1.0 - 1e-6) { (x, true) } else { (s, false) };
        let xp = self.p[x as usize];
        self.replace_child(xp, x, p);
        self.set_children(p, if moved || l != n { [x, n] } else { [n, x] });
        self.p[x as usize] = p;
        self.p[n as usize] = p;
        self.refit_up(p);
        moved
    }
    /// The `take` nodes of largest boxes, largest first: a best-first walk from the root (a child's box lies in its
    /// parent's, so it visits only what it returns and their children).
    fn largest(&self, take: usize) -> Vec<u32> {
        let mut heap = BinaryHeap::new();
        heap.push(Entry(-f64::from(self.area(self.root)), self.root));
        let mut out = Vec::with_capacity(take);
        while let Some(Entry(_, i)) = heap.pop() {
            out.push(i);
            if out.len() == take {
                break;
            }
            for c in self.children(i).into_iter().flatten() {
                heap.push(Entry(-f64::from(self.area(c)), c));
            }
        }
        out
    }
}

/// Reinserts, in up to `rounds` rounds, the `ratio` of the nodes with the largest boxes (see the module docs);
/// `nodes` is one binary tree rooted at node 0 with siblings adjacent, and comes back as one with the same leaves.
/// Returns the number of moves.
pub(crate) fn reinsert(nodes: &mut Vec<BvhNode>, ratio: f32, rounds: usize) -> usize {
    let n = nodes.len();
    if n < 7 || ratio <= 0.0 {
        return 0;
    }
    let mut p = vec![NONE; n];
    for (i, x) in nodes.iter().enumerate() {
        if !x.is_leaf() {
            p[x.left_or_first as usize] = i as u32;
            p[x.right_or_count as usize] = i as u32;
        }
    }
    let take = ((n as f32 * ratio) as usize).clamp(1, n);
    let mut t = Tree { nodes: &mut nodes[..], p, root: 0 };
    let mut heap = BinaryHeap::new();
    let mut moves = 0;
    for _ in 0..rounds {
        let order = t.largest(take);
        let mut moved = 0;
        for batch in order.chunks(BATCH) {
            let m: usize = batch.iter().map(|&i| usize::from(t.reinsert(i, &mut heap))).sum();
            moved += m;
            if m * FEW_MOVES < batch.len() {
                break;
            }
        }
        moves += moved;
        if moved == 0 {
            break;
        }
    }
    let root = t.root;
    if moves == 0 {
        return 0;
    }
    // Back to the layout of the builders: root first, siblings adjacent, depth first.
    *nodes = super::sah::compact_sibling_pairs_from(nodes, root);
    moves
}
