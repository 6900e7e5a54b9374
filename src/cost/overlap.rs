//! Overlap: how many triangle boxes a ray through the scene crosses, and the floor it puts under a hierarchy's
//! triangle tests per primary ray.
//!
//! The count laws of the model are log-linear in the characterization's features, none of which sees triangles
//! that overlap or coincide: on 2,000 large triangles with vertices uniform in a cube the model predicted 1.4
//! triangle tests per ray for the BVH where it makes 153, and picked it at 6.9x the grid's total
//! (`docs/cost-model.md`, "No catastrophe"). [`Crossings`] measures that overlap exactly from the mesh, and
//! [`overlap_floor`] bounds the hierarchies' box and triangle tests per primary ray from below with it.

use crate::accel::StructureName;
use crate::geom::{Aabb, WorkloadKind};
use crate::mesh::Mesh;

/// The mean number of triangle boxes a random line meeting the scene's box crosses: `sum_i S(box_i) / S(scene)`,
/// `S` a box's surface area (Cauchy-Crofton: a random line meeting a convex body `A` meets a convex body `B`
/// inside it with probability `S(B) / S(A)`). 0 to 169 on every shared mesh and generated family (3.5 on the bunny,
/// 16.4 on Sponza, 169 on the engineering family at 200K triangles); hundreds to thousands where triangles overlap
/// heavily or coincide. A flat scene's box has the area of its two faces; a scene of
/// zero area (a line, a point) counts 0.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Crossings {
    /// Over every triangle.
    pub all: f64,
    /// Over the distinct vertex-index triples (in order): the binned-SAH BVH keeps one of coincident copies of a
    /// triangle, so its rays cross only these. Counted only when [`Crossings::all`] is at least
    /// [`Crossings::DISTINCT_FROM`] (a hash of every triple); equal to it below.
    pub distinct: f64,
}

impl Crossings {
    /// [`Crossings::all`] from which [`Crossings::distinct`] is counted apart.
    pub const DISTINCT_FROM: f64 = 16.0;

    /// The crossings of a mesh's triangles, `boxes` their boxes in mesh order, `scene` their union (one pass, plus a
    /// hash of the vertex-index triples from [`Crossings::DISTINCT_FROM`] on).
    pub fn of(mesh: &Mesh, boxes: impl Iterator<Item = Aabb> + Clone, scene: &Aabb) -> Crossings {
        let s = scene.surface_area();
        if s.is_nan() || s <= 0.0 {
            return Crossings { all: 0.0, distinct: 0.0 };
        }
        let all = boxes.clone().map(|b| b.surface_area()).sum::<f64>() / s;
        let distinct = if all >= Self::DISTINCT_FROM {
            let mut seen = std::collections::HashSet::with_capacity(mesh.indices.len());
            boxes.zip(&mesh.indices).filter(|(_, t)| seen.insert(**t)).map(|(b, _)| b.surface_area()).sum::<f64>() / s
        } else {
            all
        };
        Crossings { all, distinct }
    }

    /// The larger of two, figure by figure.
    pub fn max(self, o: Crossings) -> Crossings {
        Crossings { all: self.all.max(o.all), distinct: self.distinct.max(o.distinct) }
    }
}

/// Least triangle tests per primary ray of a hierarchy per triangle box a random line crosses ([`Crossings`]): the
/// lower envelope, rounded down, of the measured ratio on the training records (`docs/data/oracle-*.jsonl` and
/// `docs/data/families-*.jsonl`, primary rays, every structure but the grid, scenes with at least 8 crossings),
/// whose least is 0.064 (Sponza's kd-tree: 1.04 tests per ray at 16.4 crossings). Checked, not fitted, on the
/// degenerate generators (`docs/data/degenerate-*.jsonl`).
pub const PRIMARY_TESTS_PER_CROSSING: f64 = 0.06;

/// Least box tests per primary ray of a bounding-volume hierarchy (BVH, LBVH, HLBVH, BIH) per crossing: the same
/// envelope of box tests, whose least is 0.141 (the engineering family at 200K triangles, framing view: 23.8 box
/// tests per ray at 168.6 crossings, by the BVH).
pub const PRIMARY_BOX_TESTS_PER_CROSSING: f64 = 0.14;

/// Lower bounds on a structure's tests per ray, for [`crate::cost::StructureModel::predict_floored`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TestFloor {
    /// Box tests (node visits) per ray.
    pub box_tests: f64,
    /// Triangle tests per ray.
    pub prim_tests: f64,
}

/// The overlap floor of `structure`'s tests per ray, for primary rays with the scene's [`Crossings`] at hand (the
/// distinct triangles' for the binned-SAH BVH, which keeps one of coincident copies; all of them for the others):
/// triangle tests at least [`PRIMARY_TESTS_PER_CROSSING`] times the crossings for every structure but the grid
/// (whose cells, not the triangles' boxes, bound what a ray visits), box tests at least
/// [`PRIMARY_BOX_TESTS_PER_CROSSING`] times them for the bounding-volume hierarchies (a kd-tree that cannot split
/// overlapping triangles visits one node). Zero otherwise. Shadow and diffuse rays get none: on the training
/// records some make no triangle test at all where many boxes overlap, so no such envelope exists for them.
pub fn overlap_floor(structure: StructureName, kind: WorkloadKind, c: Option<Crossings>) -> TestFloor {
    let Some(c) = c else { return TestFloor::default() };
    if kind != WorkloadKind::Primary || structure == StructureName::Grid {
        return TestFloor::default();
    }
    let x = if structure == StructureName::Bvh { c.distinct } else { c.all };
    let bvh_like = !matches!(structure, StructureName::KdTree);
    TestFloor {
        box_tests: if bvh_like { PRIMARY_BOX_TESTS_PER_CROSSING * x } else { 0.0 },
        prim_tests: PRIMARY_TESTS_PER_CROSSING * x,
    }
}

impl Crossings {
    /// The crossings of a mesh, its triangles' boxes computed here (what [`crate::select::BuildBounds::of_mesh`]
    /// records).
    pub fn of_mesh(mesh: &Mesh) -> Crossings {
        let boxes: Vec<Aabb> = (0..mesh.triangle_count()).map(|i| Aabb::of_triangle(&mesh.triangle(i))).collect();
        let scene = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        Crossings::of(mesh, boxes.iter().copied(), &scene)
    }
}
