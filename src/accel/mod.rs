//! CPU ray-tracing acceleration structures behind one trait.
//!
//! Six structures implement [`AccelStructure`]:
//!
//! | name | module | kind |
//! |---|---|---|
//! | `bvh` | [`bvh`] | binned-SAH bounding volume hierarchy (Wald 2007), built in parallel with rayon |
//! | `kdtree` | [`kdtree`] | binned-SAH kd-tree with empty-space cut-off (after Wald and Havran 2006) |
//! | `grid` | [`grid`] | uniform grid, 3D-DDA traversal (Amanatides and Woo 1987) with mailboxing |
//! | `bih` | [`bih`] | bounding interval hierarchy, global spatial-median heuristic (Wächter and Keller 2006) |
//! | `lbvh` | [`lbvh`] | linear BVH over docs/spec.md Morton codes, binary radix tree of Karras 2012 |
//! | `hlbvh` | [`hlbvh`] | hierarchical LBVH: Morton clusters, LBVH per cluster, binned SAH on top (Pantaleoni and Luebke 2010) |
//!
//! [`brute::BruteForce`] tests every triangle and is the reference in tests.
//!
//! # Conventions shared by every structure
//!
//! * **Intersection**: every structure calls [`crate::geom::intersect_triangle`] (Möller and Trumbore 1997, in f32)
//!   on the same precomputed [`Triangle`] records, so a ray hitting one triangle yields the same `t` bit for bit in
//!   every structure. Zero-area triangles (exactly zero in f64) are stored with zero edges: their determinant is
//!   exactly zero and they are never hit. They still belong to every structure (they are real input) and count as
//!   references.
//! * **Empty mesh**: building from a mesh without triangles succeeds and gives an empty structure that hits nothing
//!   and validates with all-zero statistics.
//! * **Errors**: non-finite coordinates or out-of-range indices ([`AccelError::Mesh`]), more triangles than the node
//!   encodings can address ([`AccelError::TooLarge`]), coordinates too far apart for f32 extents
//!   ([`AccelError::CoordinateRange`]: the Morton keys of the LBVH and HLBVH, the grid's cells), centroid keys that
//!   overflow f32 ([`AccelError::KeyOverflow`], LBVH and HLBVH), more references than the grid's budget
//!   ([`AccelError::OverBudget`]). Building never panics on input.
//! * **Degenerate input** (coincident, collinear, coplanar triangles, fans of polygons over a few points): every
//!   build stays within `O(n log n)` work, or, for the grid and the kd-tree, whose references can grow faster
//!   than `n` on any input, within its reference budget: past [`grid::GridOptions::reference_budget`] the grid's
//!   build fails with [`AccelError::OverBudget`]; the kd-tree stops splitting where a split would pass its share
//!   of [`kdtree::KdOptions::reference_budget`], so it always builds. Tracing
//!   is another matter: under the tie rule every ray that hits `k` coincident triangles tests all `k` of them.
//! * **SAH cost** ([`sah_cost`]): `C = K_T * sum_internal SA(n)/SA(root) + K_I * sum_leaf SA(n)/SA(root) * refs(n)`
//!   with `K_T = 1`, `K_I = 1` ([`SAH_TRAVERSAL_COST`], [`SAH_INTERSECTION_COST`]), the expected-cost model of
//!   MacDonald and Booth 1990 used by Wald 2007. For the kd-tree and BIH the node regions (voxels, clipped
//!   intervals) stand in for boxes.
//! * **Counters**: `box_tests` counts ray-box slab tests for BVH-like structures, node visits (one split-plane test
//!   each) for the kd-tree and BIH, and cells visited for the grid; `prim_tests` counts ray-triangle tests.

/// The [`AccelStructure`] methods every structure that keeps its triangle records in `tris` and traverses with
/// `traverse(ray, any, counters) -> Option<Hit>` and lays itself out with `device_layout()` shares: triangle count,
/// closest hit, any hit, the device layout. The optional field
/// path says where those live (`traversal_methods!(tree)` for the BVH family's [`bvh::BvhTree`]).
macro_rules! traversal_methods {
    ($($field:ident).*) => {
        fn triangle_count(&self) -> usize {
            self$(.$field)*.tris.len()
        }
        fn intersect(&self, ray: &$crate::geom::Ray, c: &mut $crate::geom::TraceCounters) -> Option<$crate::geom::Hit> {
            self$(.$field)*.traverse(ray, false, c)
        }
        fn occluded(&self, ray: &$crate::geom::Ray, c: &mut $crate::geom::TraceCounters) -> bool {
            self$(.$field)*.traverse(ray, true, c).is_some()
        }
        fn device_layout(&self) -> Option<$crate::accel::device_trace::DeviceLayout<'_>> {
            Some(self$(.$field)*.device_layout())
        }
    };
}

#[cfg(feature = "eval")]
pub mod bih;
pub(crate) mod bounce;
#[cfg(feature = "eval")]
pub mod brute;
pub mod bvh;
pub(crate) mod copies;
pub mod device;
pub mod device_trace;
pub mod driver;
pub mod gpu;
#[cfg(feature = "eval")]
pub mod grid;
pub(crate) mod grid_rule;
pub mod hlbvh;
#[cfg(feature = "eval")]
pub mod kdtree;
pub mod lbvh;
mod radix;

use crate::geom::{Aabb, Hit, Ray, TraceCounters, Triangle};
use crate::keys::KeyError;
use crate::mesh::{Mesh, MeshError};

/// `K_T` of the SAH cost model: cost of one traversal step.
pub const SAH_TRAVERSAL_COST: f64 = 1.0;
/// `K_I` of the SAH cost model: cost of one ray-triangle test.
pub const SAH_INTERSECTION_COST: f64 = 1.0;

/// Largest triangle count any structure accepts (node encodings keep 30 bits for indices).
pub const MAX_TRIANGLES: usize = (1 << 30) - 1;

/// Errors of building or validating a structure.
#[derive(Debug, thiserror::Error)]
pub enum AccelError {
    /// The mesh is malformed (non-finite coordinate, index out of range).
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// More triangles (or references) than the node encoding can address.
    #[error("{structure}: {count} {what} exceed the limit of {limit}")]
    TooLarge {
        /// Which structure.
        structure: &'static str,
        /// What overflowed (triangles, references, cells).
        what: &'static str,
        /// How many there were.
        count: usize,
        /// The limit.
        limit: usize,
    },
    /// Bounds that f32 cannot quantize or divide: an extent that overflows f32 (Morton quantization of
    /// docs/spec.md step 3, grid cells), or a non-zero extent so small that the quantization scale `2^b / extent`
    /// overflows (Morton quantization).
    #[error("{structure}: bounds {lo:?}..{hi:?} too wide for f32 extents")]
    CoordinateRange {
        /// Which structure.
        structure: &'static str,
        /// Lower bound (of the centroid keys for the LBVH and HLBVH, of the triangles for the grid).
        lo: [f32; 3],
        /// Upper bound.
        hi: [f32; 3],
    },
    /// A centroid key `(v0 + v1) + v2` overflows f32 (coordinates above about 1e38; LBVH and HLBVH).
    #[error(
        "{structure}: triangle {triangle}: centroid key (v0 + v1) + v2 = {key:?} overflows f32 (coordinates too large)"
    )]
    KeyOverflow {
        /// Which structure.
        structure: &'static str,
        /// The first triangle whose key overflows.
        triangle: usize,
        /// The key as computed.
        key: [f32; 3],
    },
    /// The build needs more than its budget: grid cell references or bytes ([`grid::GridOptions`]), kd-tree
    /// references ([`kdtree::KdOptions`]). On degenerate input (many large overlapping or coincident triangles) these
    /// structures duplicate references without bound; the build stops as soon as the budget is exceeded instead of
    /// running for minutes or exhausting memory. The oracle reports such a structure as failed for the scene, with
    /// this message, and measures the others.
    #[error("{structure}: needs at least {needed} {what}, over its budget of {budget} ({rule})")]
    OverBudget {
        /// Which structure.
        structure: &'static str,
        /// What ran over (`cell references`, `bytes`, `references`).
        what: &'static str,
        /// How many were needed, at least: the count when the build stopped (the grid's is deterministic; the
        /// kd-tree's, counted by parallel subtrees, is only known to exceed the budget).
        needed: usize,
        /// The budget.
        budget: usize,
        /// How the budget follows from the options (`64 per triangle for 300000 triangles, at least 33554432`).
        rule: String,
    },
    /// `validate()` found a broken invariant, or the input breaks one the builder needs (a quantizer of another code
    /// width).
    #[error("{structure}: invalid: {reason}")]
    Invalid {
        /// Which structure.
        structure: &'static str,
        /// The broken invariant.
        reason: String,
    },
    /// The structure is not compiled into this build (the kd-tree, grid, BIH and brute force need the `eval`
    /// feature).
    #[error("{structure}: not built into this library (enable the `eval` feature)")]
    Unavailable {
        /// Which structure.
        structure: &'static str,
    },
}

impl AccelError {
    /// The builders' error for a [`KeyError`] of the Morton keys of every triangle (key `i` is triangle `i`).
    pub(crate) fn of_keys(structure: &'static str, e: KeyError) -> AccelError {
        match e {
            KeyError::Overflow { index, key } => AccelError::KeyOverflow { structure, triangle: index, key },
            KeyError::Extent { lo, hi, .. } => AccelError::CoordinateRange { structure, lo, hi },
            KeyError::Empty => invalid(structure, "Morton codes of no triangles"),
        }
    }
}

/// Names of the structures, as used on the command line and in JSON (`bvh`, `kdtree`, `grid`, `bih`, `lbvh`,
/// `hlbvh`; `brute` for the reference).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StructureName {
    /// Binned-SAH BVH.
    Bvh,
    /// SAH kd-tree.
    #[serde(rename = "kdtree")]
    KdTree,
    /// Uniform grid.
    Grid,
    /// Bounding interval hierarchy.
    Bih,
    /// Linear BVH (Karras 2012).
    Lbvh,
    /// Hierarchical LBVH.
    Hlbvh,
    /// Brute force (reference only, not part of [`StructureName::ALL`]).
    Brute,
}

impl StructureName {
    /// The six structures the oracle compares, in report order.
    pub const ALL: [StructureName; 6] = [
        StructureName::Bvh,
        StructureName::KdTree,
        StructureName::Grid,
        StructureName::Bih,
        StructureName::Lbvh,
        StructureName::Hlbvh,
    ];

    /// The name used in reports and on the command line (the same as [`StructureName::as_str`]).
    pub fn name(self) -> &'static str {
        self.as_str()
    }

    /// Parses a name of [`StructureName::name`] exactly (the [`std::str::FromStr`] impl also takes aliases).
    pub fn from_name(s: &str) -> Option<StructureName> {
        StructureName::ALL.into_iter().chain([StructureName::Brute]).find(|x| x.as_str() == s)
    }

    /// The lowercase name.
    pub fn as_str(self) -> &'static str {
        match self {
            StructureName::Bvh => "bvh",
            StructureName::KdTree => "kdtree",
            StructureName::Grid => "grid",
            StructureName::Bih => "bih",
            StructureName::Lbvh => "lbvh",
            StructureName::Hlbvh => "hlbvh",
            StructureName::Brute => "brute",
        }
    }
}

impl std::fmt::Display for StructureName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for StructureName {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "bvh" => Ok(StructureName::Bvh),
            "kdtree" | "kd-tree" | "kd" => Ok(StructureName::KdTree),
            "grid" => Ok(StructureName::Grid),
            "bih" => Ok(StructureName::Bih),
            "lbvh" => Ok(StructureName::Lbvh),
            "hlbvh" => Ok(StructureName::Hlbvh),
            "brute" => Ok(StructureName::Brute),
            other => Err(format!("unknown structure {other:?} (bvh, kdtree, grid, bih, lbvh, hlbvh, brute)")),
        }
    }
}

/// Statistics returned by `validate()`.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AccelStats {
    /// Triangles in the mesh.
    pub triangles: usize,
    /// Nodes (or cells for the grid), leaves included.
    pub nodes: usize,
    /// Leaves (non-empty and empty; cells for the grid).
    pub leaves: usize,
    /// Leaves (or cells) without any reference.
    pub empty_leaves: usize,
    /// Longest root-to-leaf path in edges (0 for a single leaf and for the grid).
    pub max_depth: usize,
    /// Triangle references stored in leaves (equal to `triangles` for object hierarchies, larger for spatial
    /// subdivisions that duplicate references).
    pub references: usize,
    /// Bytes of the structure: nodes, references and the triangle records it traces against.
    pub bytes: usize,
    /// The sum over leaves of their references times their depth plus one: how many times a top-down build handles
    /// a reference, once on each level from the root to its leaf (the build work of the BVH, the kd-tree and the
    /// BIH, whose every node passes over its references; equal to `references` for the grid). Read by the cost
    /// model's build law where a probe built the structure (`cost::StructureModel::build_work_coef`). 0 in
    /// records written before it existed.
    #[serde(default)]
    pub reference_levels: usize,
    /// Triangles that no leaf holds because another one stands for them: copies with bit-identical positions in
    /// the same order, which the binned-SAH BVH keeps once (`bvh::BvhTree::copies`); `references + copies` covers
    /// every triangle of an object hierarchy. 0 in records written before it existed.
    #[serde(default)]
    pub copies: usize,
}

/// A ray-tracing acceleration structure over one mesh.
///
/// Implementations are immutable after `build` and can be traced from many threads at once.
pub trait AccelStructure: Send + Sync {
    /// Builds the structure with its default options. An empty mesh gives an empty structure.
    fn build(mesh: &Mesh) -> Result<Self, AccelError>
    where
        Self: Sized;
    /// Which structure this is.
    fn name(&self) -> StructureName;
    /// Number of triangles of the mesh it was built from.
    fn triangle_count(&self) -> usize;
    /// Closest hit with `ray.tmin < t < ray.tmax`, counting tests into `counters`.
    fn intersect(&self, ray: &Ray, counters: &mut TraceCounters) -> Option<Hit>;
    /// Whether any triangle is hit with `ray.tmin < t < ray.tmax` (shadow rays); stops at the first hit found.
    fn occluded(&self, ray: &Ray, counters: &mut TraceCounters) -> bool;
    /// Walks the whole structure, checks every invariant and returns its statistics.
    fn validate(&self) -> Result<AccelStats, AccelError>;
    /// [`AccelStats::build_work`] of this structure without `validate`'s checks (what a probe reads,
    /// `cost::probe`): the hierarchies the policy probes walk their nodes, the grid counts its references; the
    /// default validates. `None` for an empty structure.
    fn build_work(&self) -> Option<f64> {
        self.validate().ok().and_then(|s| s.build_work(self.name()))
    }
    /// Memory of the structure in bytes (same as `validate().bytes`, without the walk).
    fn memory_bytes(&self) -> usize;
    /// SAH cost with the constants of [`SAH_TRAVERSAL_COST`] and [`SAH_INTERSECTION_COST`], where it applies.
    fn sah_cost(&self) -> Option<f64>;
    /// The arrays the device traversal reads ([`device_trace::DeviceStructure::upload`]); `None` for a structure without
    /// one (the brute-force reference).
    fn device_layout(&self) -> Option<device_trace::DeviceLayout<'_>> {
        None
    }
}

/// Builds the named structure with default options, behind a trait object.
pub fn build_structure(name: StructureName, mesh: &Mesh) -> Result<Box<dyn AccelStructure>, AccelError> {
    Ok(match name {
        StructureName::Bvh => Box::new(bvh::Bvh::build(mesh)?),
        #[cfg(feature = "eval")]
        StructureName::KdTree => Box::new(kdtree::KdTree::build(mesh)?),
        #[cfg(feature = "eval")]
        StructureName::Grid => Box::new(grid::Grid::build(mesh)?),
        #[cfg(feature = "eval")]
        StructureName::Bih => Box::new(bih::Bih::build(mesh)?),
        #[cfg(feature = "eval")]
        StructureName::Brute => Box::new(brute::BruteForce::build(mesh)?),
        #[cfg(not(feature = "eval"))]
        StructureName::KdTree | StructureName::Grid | StructureName::Bih | StructureName::Brute => {
            return Err(AccelError::Unavailable { structure: name.as_str() })
        }
        StructureName::Lbvh => Box::new(lbvh::Lbvh::build(mesh)?),
        StructureName::Hlbvh => Box::new(hlbvh::Hlbvh::build(mesh)?),
    })
}

/// The checks of [`prepare`] without its arrays: the mesh is valid ([`Mesh::validate`]) and has at most
/// [`MAX_TRIANGLES`] triangles.
pub(crate) fn check_mesh(mesh: &Mesh, structure: &'static str) -> Result<(), AccelError> {
    mesh.validate()?;
    let n = mesh.triangle_count();
    if n > MAX_TRIANGLES {
        return Err(AccelError::TooLarge { structure, what: "triangles", count: n, limit: MAX_TRIANGLES });
    }
    Ok(())
}

/// Triangle records and bounding boxes of a mesh, in mesh order, after checking the mesh.
///
/// Bounding boxes come from the mesh's vertices (also for zero-area triangles).
pub(crate) fn prepare(mesh: &Mesh, structure: &'static str) -> Result<(Vec<Triangle>, Vec<Aabb>), AccelError> {
    check_mesh(mesh, structure)?;
    let n = mesh.triangle_count();
    use rayon::prelude::*;
    Ok((0..n)
        .into_par_iter()
        .map(|i| {
            let v = mesh.triangle(i);
            (Triangle::new(&v), Aabb::of_triangle(&v))
        })
        .unzip())
}

/// Renumbers triangle records in the order in which `lists` (concatenated reference lists, each a range of `refs`)
/// first use them, so that the triangles of one leaf or cell lie together in memory. Permutes `tris` and `boxes`,
/// rewrites `refs` and sorts every list again; returns the mesh index of every record.
#[cfg(feature = "eval")]
pub(crate) fn renumber_by_first_use(
    refs: &mut [u32],
    lists: &[(usize, usize)],
    tris: &mut Vec<Triangle>,
    boxes: &mut Vec<Aabb>,
) -> Vec<u32> {
    let n = tris.len();
    let mut new_of = vec![u32::MAX; n];
    let mut order: Vec<u32> = Vec::with_capacity(n);
    for &id in refs.iter() {
        if new_of[id as usize] == u32::MAX {
            new_of[id as usize] = order.len() as u32;
            order.push(id);
        }
    }
    for (i, slot) in new_of.iter_mut().enumerate() {
        if *slot == u32::MAX {
            *slot = order.len() as u32;
            order.push(i as u32);
        }
    }
    for r in refs.iter_mut() {
        *r = new_of[*r as usize];
    }
    for &(s, e) in lists {
        refs[s..e].sort_unstable();
    }
    *tris = order.iter().map(|&i| tris[i as usize]).collect();
    *boxes = order.iter().map(|&i| boxes[i as usize]).collect();
    order
}

impl AccelStats {
    /// The work of the build of `structure` (the structure these statistics are of): its
    /// [`AccelStats::reference_levels`] (for the grid, its references) plus `node_build_work` per node, which the
    /// cost model's build law reads where a probe built the structure (`cost::StructureModel::build_work_coef`).
    /// Only the SAH BVH's nodes count ([`BVH_NODE_WORK`]); a grid's cells (about four per triangle in every grid
    /// here) cost a prefix sum, far less than its references, and would drown them (`docs/results/2026-12-06-cost-model-build-work-law.md`). `None` for statistics without reference levels (records written before they were counted) and for
    /// an empty structure.
    pub fn build_work(&self, structure: StructureName) -> Option<f64> {
        (self.reference_levels > 0)
            .then_some(self.reference_levels as f64 + node_build_work(structure) * self.nodes as f64)
    }
}

/// What a node of the binned-SAH BVH costs its build, in [`AccelStats::reference_levels`]: every node sweeps its
/// bins and is written, whatever its references, so a tree of one-triangle leaves (a particle soup, vegetation:
/// two nodes per triangle) takes longer than one of the same reference levels with fewer, fuller leaves
/// (engineering models: 0.6 nodes per triangle). Chosen on the first set of family records
/// (`docs/data/families-rounds-*.jsonl`, the BVH's median build per scene, the build law's RMS error of `ln` ms
/// 0.115 -> 0.077 at 3 over 0 to 240) and checked on the second (`families-seed2-*`, fitted on the first: 0.196 ->
/// 0.146); neutral on the shared meshes (0.84-1.15 nodes per triangle; leave-one-scene-out 0.089 -> 0.091).
/// `docs/results/2026-12-06-cost-model-bvh-nodes-probe-band.md`.
pub const BVH_NODE_WORK: f64 = 3.0;

/// The build work a node of `structure` adds to its [`AccelStats::build_work`]: [`BVH_NODE_WORK`] for the SAH BVH,
/// 0 for every other structure (the LBVH's and the HLBVH's nodes come from the sorted keys at a cost their
/// references already carry; the BIH's and the kd-tree's showed no gain, and the grid's cells are left out).
pub(crate) fn node_build_work(structure: StructureName) -> f64 {
    match structure {
        StructureName::Bvh => BVH_NODE_WORK,
        _ => 0.0,
    }
}

/// A node of a binary tree as [`reference_levels_of`] walks it.
pub(crate) enum LevelNode {
    /// A leaf holding this many references.
    Leaf(usize),
    /// An inner node and its two children.
    Inner(usize, usize),
}

/// [`AccelStats::reference_levels`] of a binary tree of `nodes` nodes rooted at node 0, `node(k)` giving node `k`
/// (`None` out of range), as [`AccelStats::build_work`] reads it; `None` when the walk leaves the tree or reaches
/// more nodes than it has (a cycle), or counts nothing.
pub(crate) fn reference_levels_of(nodes: usize, node: impl Fn(usize) -> Option<LevelNode>) -> Option<f64> {
    let (mut stack, mut reached, mut levels) = (vec![(0usize, 1usize)], 0usize, 0usize);
    while let Some((k, level)) = stack.pop() {
        reached += 1;
        if reached > nodes {
            return None;
        }
        match node(k)? {
            LevelNode::Leaf(count) => levels = levels.saturating_add(count.saturating_mul(level)),
            LevelNode::Inner(l, r) => stack.extend([(l, level + 1), (r, level + 1)]),
        }
    }
    (levels > 0).then_some(levels as f64)
}

/// Bytes of a slice's elements.
pub(crate) fn bytes_of<T>(v: &[T]) -> usize {
    std::mem::size_of_val(v)
}

/// Shorthand for a validation failure.
pub(crate) fn invalid(structure: &'static str, reason: impl Into<String>) -> AccelError {
    AccelError::Invalid { structure, reason: reason.into() }
}

/// The checks and counts every `validate()` shares: the statistics, the rule for a structure without nodes, the
/// walk's bookkeeping (every node reached exactly once, depth) and the leaves' (every record or reference entry in
/// exactly one leaf, leaf and reference counts). Each structure walks its own layout and checks its own geometry
/// (boxes, voxels, clip planes, cells) and reports what it finds through this.
pub(crate) struct Validation {
    structure: &'static str,
    stats: AccelStats,
    visited: Vec<bool>,
    covered: Vec<bool>,
    /// The node last visited and its depth (a leaf is counted right after its visit).
    last: (usize, usize),
}

impl Validation {
    /// Validation of `structure` over `triangles` triangles taking `bytes`, walking `nodes` nodes (or cells) whose
    /// leaves cover `entries` records (or reference entries).
    pub(crate) fn new(structure: &'static str, triangles: usize, bytes: usize, nodes: usize, entries: usize) -> Self {
        Validation {
            structure,
            stats: AccelStats { triangles, bytes, ..Default::default() },
            visited: vec![false; nodes],
            covered: vec![false; entries],
            last: (usize::MAX, 0),
        }
    }

    /// The failure `reason` of this structure.
    pub(crate) fn invalid(&self, reason: impl Into<String>) -> AccelError {
        invalid(self.structure, reason)
    }

    /// For a structure without nodes: the all-zero statistics when it holds nothing (`holds` false: no triangle,
    /// no reference), else the failure `what`.
    pub(crate) fn without_nodes(self, holds: bool, what: &str) -> Result<AccelStats, AccelError> {
        if holds {
            return Err(self.invalid(what));
        }
        Ok(self.stats)
    }

    /// Node `k`, reached at `depth`: fails when it is out of range or was reached before.
    pub(crate) fn visit(&mut self, k: usize, depth: usize) -> Result<(), AccelError> {
        let seen = self.visited.get_mut(k).ok_or_else(|| invalid(self.structure, format!("node {k} out of range")))?;
        if std::mem::replace(seen, true) {
            return Err(self.invalid(format!("node {k} reached twice")));
        }
        self.stats.nodes += 1;
        self.stats.max_depth = self.stats.max_depth.max(depth);
        self.last = (k, depth);
        Ok(())
    }

    /// Leaf `k`, the node just visited, covering entries `first .. first + count` (none: an empty leaf): fails when
    /// `k` is not the node just visited, when they are out of range or one is in another leaf already.
    pub(crate) fn leaf(&mut self, k: usize, first: usize, count: usize) -> Result<(), AccelError> {
        if self.last.0 != k {
            return Err(self.invalid(format!("leaf {k} counted without its visit")));
        }
        let range = first.checked_add(count).and_then(|end| self.covered.get_mut(first..end));
        let entries = range.ok_or_else(|| invalid(self.structure, format!("leaf {k} covers {first}+{count}")))?;
        if let Some(j) = entries.iter().position(|&c| c) {
            return Err(self.invalid(format!("entry {} in two leaves", first + j)));
        }
        entries.fill(true);
        self.stats.leaves += 1;
        self.stats.references += count;
        self.stats.reference_levels += count * (self.last.1 + 1);
        self.stats.empty_leaves += usize::from(count == 0);
        Ok(())
    }

    /// Entry `copy`, in no leaf, stands for a copy of entry `kept`, which is in a leaf (the caller checks that they
    /// are copies): fails otherwise, or when `copy` is in a leaf or listed twice.
    pub(crate) fn copy(&mut self, copy: usize, kept: usize) -> Result<(), AccelError> {
        if !self.covered.get(kept).copied().unwrap_or(false) {
            return Err(self.invalid(format!("entry {copy} copies entry {kept}, which is in no leaf")));
        }
        match self.covered.get_mut(copy) {
            Some(c) if !*c => *c = true,
            _ => return Err(self.invalid(format!("copy {copy} in a leaf, listed twice or out of range"))),
        }
        self.stats.copies += 1;
        Ok(())
    }

    /// The statistics, after checking that the walk reached every node and the leaves cover every entry.
    pub(crate) fn finish(self) -> Result<AccelStats, AccelError> {
        let unreached = self.visited.iter().filter(|&&v| !v).count();
        if unreached > 0 {
            return Err(self.invalid(format!("{unreached} of {} nodes unreachable", self.visited.len())));
        }
        if let Some(j) = self.covered.iter().position(|&c| !c) {
            return Err(self.invalid(format!("entry {j} in no leaf")));
        }
        Ok(self.stats)
    }
}

/// Checks that `ids` (the mesh index of every triangle record) is a permutation of `0 .. n`.
pub(crate) fn check_permutation(structure: &'static str, ids: &[u32], n: usize) -> Result<(), AccelError> {
    if ids.len() != n {
        return Err(invalid(structure, format!("{} ids for {n} triangle records", ids.len())));
    }
    let mut seen = vec![false; n];
    for &id in ids {
        match seen.get_mut(id as usize) {
            Some(s) if !*s => *s = true,
            _ => return Err(invalid(structure, format!("triangle id {id} repeated or out of range"))),
        }
    }
    Ok(())
}

/// Whether the box of triangle record `t` lies in `b` widened by a relative `1e-6` (the records are stored as
/// `v0` and two edges, so their corners may round outside the exact box).
pub(crate) fn triangle_in_box(t: &Triangle, b: &Aabb) -> bool {
    let slack = (b.max.abs() + b.min.abs()) * 1e-6;
    let loose = Aabb::new(b.min - slack, b.max + slack);
    loose.contains(&Aabb::of_triangle(&[t.v0, t.v0 + t.e1, t.v0 + t.e2]))
}

/// A fixed-capacity stack that spills to the heap past 64 entries, for traversal.
pub(crate) struct TraversalStack<T: Copy + Default> {
    buf: [T; 64],
    len: usize,
    spill: Vec<T>,
}

impl<T: Copy + Default> TraversalStack<T> {
    #[inline]
    pub(crate) fn new() -> Self {
        TraversalStack { buf: [T::default(); 64], len: 0, spill: Vec::new() }
    }
    #[inline]
    pub(crate) fn push(&mut self, x: T) {
        if self.len < 64 {
            self.buf[self.len] = x;
        } else {
            self.spill.push(x);
        }
        self.len += 1;
    }
    #[inline]
    pub(crate) fn pop(&mut self) -> Option<T> {
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        if self.len < 64 {
            Some(self.buf[self.len])
        } else {
            self.spill.pop()
        }
    }
}

/// SAH cost from per-node (area, is_leaf, references) triples and the root area (see the module docs).
pub fn sah_cost(root_area: f64, nodes: impl Iterator<Item = (f64, bool, usize)>) -> f64 {
    if root_area <= 0.0 {
        // Degenerate scene (all triangles in a point or a segment): every ray that reaches the root reaches every
        // node, so each area ratio counts as 1.
        return nodes
            .map(|(_, leaf, refs)| if leaf { SAH_INTERSECTION_COST * refs as f64 } else { SAH_TRAVERSAL_COST })
            .sum();
    }
    nodes
        .map(|(a, leaf, refs)| {
            let p = a / root_area;
            if leaf {
                SAH_INTERSECTION_COST * p * refs as f64
            } else {
                SAH_TRAVERSAL_COST * p
            }
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_counts_a_walk_and_names_what_breaks_it() {
        // Root 0 over leaves 1 (entries 0..2) and 2 (empty) at depth 1.
        let mut v = Validation::new("t", 2, 10, 3, 2);
        v.visit(0, 0).unwrap();
        v.visit(1, 1).unwrap();
        v.leaf(1, 0, 2).unwrap();
        v.visit(2, 1).unwrap();
        v.leaf(2, 2, 0).unwrap();
        let s = v.finish().unwrap();
        let want = AccelStats {
            triangles: 2,
            nodes: 3,
            leaves: 2,
            empty_leaves: 1,
            max_depth: 1,
            references: 2,
            bytes: 10,
            reference_levels: 4,
            copies: 0,
        };
        assert_eq!(s, want);
        let msg = |e: AccelError| e.to_string();
        let mut v = Validation::new("t", 2, 0, 2, 2);
        assert!(msg(v.visit(2, 0).unwrap_err()).contains("node 2 out of range"));
        v.visit(0, 0).unwrap();
        assert!(msg(v.visit(0, 1).unwrap_err()).contains("reached twice"));
        assert!(msg(v.leaf(0, 1, 2).unwrap_err()).contains("covers 1+2"));
        v.leaf(0, 0, 1).unwrap();
        assert!(msg(v.leaf(0, 0, 2).unwrap_err()).contains("entry 0 in two leaves"));
        assert!(msg(v.leaf(1, 1, 1).unwrap_err()).contains("leaf 1 counted without its visit"));
        assert!(msg(v.finish().unwrap_err()).contains("1 of 2 nodes unreachable"));
        let mut v = Validation::new("t", 2, 0, 1, 2);
        v.visit(0, 0).unwrap();
        v.leaf(0, 0, 1).unwrap();
        assert!(msg(v.finish().unwrap_err()).contains("entry 1 in no leaf"));
        assert_eq!(Validation::new("t", 0, 4, 0, 0).without_nodes(false, "x").unwrap().bytes, 4);
        assert!(Validation::new("t", 1, 4, 0, 0).without_nodes(true, "x").is_err());
        check_permutation("t", &[2, 0, 1], 3).unwrap();
        assert!(check_permutation("t", &[0, 0, 1], 3).is_err());
        assert!(check_permutation("t", &[0, 3, 1], 3).is_err());
        assert!(check_permutation("t", &[0, 1], 3).is_err());
    }
}
