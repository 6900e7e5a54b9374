//! The arrays of every structure as the traversal kernel reads them ([`DeviceLayout`]), checked before an upload:
//! one tree rooted at 0, leaves and references inside their arrays, grid starts monotone.

use super::*;

/// How a structure is laid out for the traversal kernel (its `STRUCTURE` constant).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TraversalKind {
    /// Binary BVH of [`BvhNode`]s (binned-SAH BVH, LBVH, HLBVH).
    Bvh,
    /// kd-tree of [`KdNode`]s.
    KdTree,
    /// Uniform grid.
    Grid,
    /// Bounding interval hierarchy of [`BihNode`]s.
    Bih,
}

impl TraversalKind {
    /// The four kinds, in the order of the kernel's `STRUCTURE` constant.
    pub const ALL: [TraversalKind; 4] =
        [TraversalKind::Bvh, TraversalKind::KdTree, TraversalKind::Grid, TraversalKind::Bih];

    pub(super) fn constant(self) -> u32 {
        self as u32
    }
}

/// A structure's arrays as the traversal kernel reads them, borrowed from a CPU structure
/// ([`crate::accel::AccelStructure::device_layout`]) or put together by an engine. [`DeviceStructure::upload`]
/// checks every index before anything reaches the device.
#[derive(Clone, Copy, Debug)]
pub enum DeviceLayout<'a> {
    /// A binary BVH: nodes (root 0), triangle records in leaf order and the mesh index of each.
    Bvh {
        /// The nodes.
        nodes: &'a [BvhNode],
        /// Triangle records in leaf order.
        tris: &'a [Triangle],
        /// Mesh index of each record.
        ids: &'a [u32],
    },
    /// A kd-tree: nodes (root 0), leaf references into the records, records and mesh indices, the scene box.
    KdTree {
        /// The nodes.
        nodes: &'a [KdNode],
        /// Leaf references (indices into `tris`).
        refs: &'a [u32],
        /// Triangle records.
        tris: &'a [Triangle],
        /// Mesh index of each record.
        ids: &'a [u32],
        /// The scene box the traversal clips the ray to.
        bounds: Aabb,
    },
    /// A uniform grid: cell starts into the references (mesh indices), records in mesh order.
    Grid {
        /// The grid's box.
        bounds: Aabb,
        /// Cells per axis.
        res: [u32; 3],
        /// Cell size.
        cell_size: Vec3,
        /// Inverse cell size, as the traversal uses it.
        inv_cell: Vec3,
        /// `cells + 1` starts into `refs`; cell `(x, y, z)` is `x + res[0] * (y + res[1] * z)`.
        cell_start: &'a [u32],
        /// References: mesh indices.
        refs: &'a [u32],
        /// Triangle records in mesh order.
        tris: &'a [Triangle],
    },
    /// A bounding interval hierarchy: nodes (root 0), records in leaf order and their mesh indices, the scene box.
    Bih {
        /// The nodes.
        nodes: &'a [BihNode],
        /// Triangle records in leaf order.
        tris: &'a [Triangle],
        /// Mesh index of each record.
        ids: &'a [u32],
        /// The scene box.
        bounds: Aabb,
    },
}

/// Why a ray's traversal stopped short (never on a structure this crate built).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TraceStatus {
    /// The traversal ran to its end.
    Ok,
    /// The stack was too small for the tree.
    StackFull,
    /// More than 65,535^2 steps.
    StepLimit,
    /// A status the kernel does not write (a corrupted result).
    Unknown(u32),
}

impl TraceStatus {
    fn of(s: u32) -> Self {
        match s {
            TRACE_OK => TraceStatus::Ok,
            TRACE_STACK_FULL => TraceStatus::StackFull,
            TRACE_STEP_LIMIT => TraceStatus::StepLimit,
            other => TraceStatus::Unknown(other),
        }
    }
}

impl TraceHit {
    /// The closest hit (closest-hit rays) or an occluder (any-hit rays), `None` for a miss.
    pub fn hit(&self) -> Option<Hit> {
        (self.triangle != TRACE_MISS).then_some(Hit { t: self.t, triangle: self.triangle, u: self.u, v: self.v })
    }
    /// Whether the traversal ran to its end.
    pub fn status(&self) -> TraceStatus {
        TraceStatus::of(self.status)
    }
}

impl From<&Ray> for TraceRay {
    fn from(r: &Ray) -> Self {
        TraceRay { origin: r.origin.to_array(), tmin: r.tmin, dir: r.dir.to_array(), tmax: r.tmax }
    }
}

pub(super) fn bad(reason: String) -> AccelError {
    AccelError::Invalid { structure: "device layout", reason }
}

pub(super) fn records(tris: &[Triangle], ids: impl Fn(usize) -> u32) -> Vec<TriRecord> {
    tris.iter()
        .enumerate()
        .map(|(i, t)| TriRecord {
            v0: t.v0.to_array(),
            id: ids(i),
            e1: t.e1.to_array(),
            pad_a: 0,
            e2: t.e2.to_array(),
            pad_b: 0,
        })
        .collect()
}

/// Largest depth (edges from the root) of a binary tree given as a child function, checking that the nodes form one
/// tree rooted at 0 (every node reached at most once) and every leaf range lies inside `0..leaf_limit`.
pub(super) fn tree_depth(
    count: usize,
    children: impl Fn(usize) -> Option<(usize, usize)>,
    leaf: impl Fn(usize) -> (usize, usize),
    leaf_limit: usize,
) -> Result<usize, AccelError> {
    if count == 0 {
        return Ok(0);
    }
    let mut seen = vec![false; count];
    let mut stack = vec![(0usize, 0usize)];
    let mut depth = 0;
    while let Some((k, d)) = stack.pop() {
        if k >= count || std::mem::replace(&mut seen[k], true) {
            return Err(bad(format!("node {k} out of range or reached twice")));
        }
        depth = depth.max(d);
        match children(k) {
            Some((a, b)) => {
                stack.push((a, d + 1));
                stack.push((b, d + 1));
            }
            None => {
                let (first, n) = leaf(k);
                if first.checked_add(n).is_none_or(|e| e > leaf_limit) {
                    return Err(bad(format!("leaf {k}: records {first}..{first}+{n} past {leaf_limit}")));
                }
            }
        }
    }
    Ok(depth)
}

pub(super) fn check_ids(ids: &[u32], tris: usize) -> Result<(), AccelError> {
    if ids.len() != tris {
        return Err(bad(format!("{} mesh indices for {tris} records", ids.len())));
    }
    match ids.iter().position(|&i| i == TRACE_MISS) {
        Some(k) => Err(bad(format!("record {k}: mesh index {TRACE_MISS:#x} is reserved for a miss"))),
        None => Ok(()),
    }
}

pub(super) fn scene_header(bounds: &Aabb, nodes: usize) -> TraceScene {
    TraceScene { lo: bounds.min.to_array(), hi: bounds.max.to_array(), nodes: nodes as u32, ..TraceScene::default() }
}

/// What the upload of a [`DeviceLayout`] sends: the arrays, checked, and the header.
pub(super) struct Prepared {
    pub(super) kind: TraversalKind,
    pub(super) nodes: Vec<u8>,
    pub(super) records: Vec<TriRecord>,
    pub(super) refs: Vec<u32>,
    pub(super) scene: TraceScene,
    pub(super) stack_entries: u32,
}

impl DeviceLayout<'_> {
    /// Which traversal the layout needs.
    pub fn kind(&self) -> TraversalKind {
        match self {
            DeviceLayout::Bvh { .. } => TraversalKind::Bvh,
            DeviceLayout::KdTree { .. } => TraversalKind::KdTree,
            DeviceLayout::Grid { .. } => TraversalKind::Grid,
            DeviceLayout::Bih { .. } => TraversalKind::Bih,
        }
    }

    pub(super) fn prepare(&self) -> Result<Prepared, AccelError> {
        let too_many = |what: &'static str, count: usize| AccelError::TooLarge {
            structure: "device layout",
            what,
            count,
            limit: u32::MAX as usize - 1,
        };
        let fits = |what: &'static str, n: usize| if n >= u32::MAX as usize { Err(too_many(what, n)) } else { Ok(()) };
        Ok(match *self {
            DeviceLayout::Bvh { nodes, tris, ids } => {
                fits("nodes", nodes.len())?;
                fits("records", tris.len())?;
                check_ids(ids, tris.len())?;
                let n = nodes.len();
                let depth = tree_depth(
                    n,
                    |k| {
                        (!nodes[k].is_leaf())
                            .then(|| (nodes[k].left_or_first as usize, nodes[k].right_or_count as usize))
                    },
                    |k| (nodes[k].left_or_first as usize, nodes[k].count() as usize),
                    tris.len(),
                )?;
                Prepared {
                    kind: TraversalKind::Bvh,
                    nodes: bytemuck::cast_slice(nodes).to_vec(),
                    records: records(tris, |i| ids[i]),
                    refs: Vec::new(),
                    scene: scene_header(&Aabb::EMPTY, n),
                    stack_entries: depth as u32 + 1,
                }
            }
            DeviceLayout::KdTree { nodes, refs, tris, ids, bounds } => {
                fits("nodes", nodes.len())?;
                fits("references", refs.len())?;
                check_ids(ids, tris.len())?;
                if let Some(k) = refs.iter().position(|&r| r as usize >= tris.len()) {
                    return Err(bad(format!("kd-tree reference {k} past the {} records", tris.len())));
                }
                let n = nodes.len();
                let kd_leaf = |k: usize| nodes[k].flags & 3 == 3;
                let depth = tree_depth(
                    n,
                    |k| (!kd_leaf(k)).then(|| (k + 1, k + (nodes[k].flags >> 2) as usize)),
                    |k| ((nodes[k].flags >> 2) as usize, nodes[k].split_or_count as usize),
                    refs.len(),
                )?;
                Prepared {
                    kind: TraversalKind::KdTree,
                    nodes: bytemuck::cast_slice(nodes).to_vec(),
                    records: records(tris, |i| ids[i]),
                    refs: refs.to_vec(),
                    scene: scene_header(&bounds, n),
                    stack_entries: depth as u32 + 1,
                }
            }
            DeviceLayout::Grid { bounds, res, cell_size, inv_cell, cell_start, refs, tris } => {
                fits("records", tris.len())?;
                fits("references", refs.len())?;
                if !tris.is_empty() {
                    if !res.iter().all(|&r| r > 0 && r < (1 << 24)) {
                        return Err(bad(format!("grid: resolution {res:?}")));
                    }
                    let cells = res.iter().try_fold(1usize, |a, &r| a.checked_mul(r as usize));
                    if cells.and_then(|c| c.checked_add(1)) != Some(cell_start.len()) {
                        return Err(bad(format!("grid: {} cell starts for {res:?} cells", cell_start.len())));
                    }
                    if cell_start.windows(2).any(|w| w[0] > w[1]) || cell_start.last() != Some(&(refs.len() as u32)) {
                        return Err(bad("grid: cell starts not monotone or not ending at the references".into()));
                    }
                    if let Some(k) = refs.iter().position(|&r| r as usize >= tris.len()) {
                        return Err(bad(format!("grid reference {k} past the {} records", tris.len())));
                    }
                }
                let mut scene = scene_header(&bounds, tris.len());
                [scene.res_x, scene.res_y, scene.res_z] = res;
                scene.cell_size = cell_size.to_array();
                scene.inv_cell = inv_cell.to_array();
                Prepared {
                    kind: TraversalKind::Grid,
                    nodes: bytemuck::cast_slice(cell_start).to_vec(),
                    records: records(tris, |i| i as u32),
                    refs: refs.to_vec(),
                    scene,
                    stack_entries: 0,
                }
            }
            DeviceLayout::Bih { nodes, tris, ids, bounds } => {
                fits("nodes", nodes.len())?;
                fits("records", tris.len())?;
                check_ids(ids, tris.len())?;
                let n = nodes.len();
                let bih_leaf = |k: usize| nodes[k].flags & 3 == 3;
                let depth = tree_depth(
                    n,
                    |k| (!bih_leaf(k)).then(|| ((nodes[k].flags >> 2) as usize, (nodes[k].flags >> 2) as usize + 1)),
                    |k| ((nodes[k].flags >> 2) as usize, nodes[k].clip[0].to_bits() as usize),
                    tris.len(),
                )?;
                Prepared {
                    kind: TraversalKind::Bih,
                    nodes: bytemuck::cast_slice(nodes).to_vec(),
                    records: records(tris, |i| ids[i]),
                    refs: Vec::new(),
                    scene: scene_header(&bounds, n),
                    stack_entries: depth as u32 + 1,
                }
            }
        })
    }
}
