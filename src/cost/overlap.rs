//! Overlap: how many triangle boxes a ray crosses, and the floor it puts under a hierarchy's tests per ray.
//!
//! The count laws of the model are log-linear in the characterization's features, none of which sees triangles
//! that overlap or coincide: on 2,000 large triangles with vertices uniform in a cube the model predicted 1.4
//! triangle tests per ray for the BVH where it makes 153, and picked it at 6.9x the grid's total
//! (`docs/cost-model.md`, "No catastrophe"). [`Crossings`] measures the overlap exactly from the mesh,
//! [`Crossings::for_workload`] turns it into the boxes a ray of a workload crosses on average ([`RayCrossings`]),
//! and [`overlap_floor`] bounds the hierarchies' box and triangle tests per ray from below with it.
//!
//! # Crossings of a view
//!
//! A line of direction `d` meets an axis-aligned box of extents `e` with probability proportional to the box's area
//! projected along `d`, `|d_x| e_y e_z + |d_y| e_x e_z + |d_z| e_x e_y`, among parallel lines spread uniformly
//! over the scene's box. So the mean number of triangle boxes crossed by a line along `d` that meets the scene's box
//! is the sum of the triangle boxes' projected areas over the scene box's, and a camera's ray crosses that many
//! times the share of its rays that meet the scene's box ([`crate::cost::ViewFeatures::coverage`]). Averaged over
//! every direction, the first factor is the Cauchy-Crofton ratio `sum_i S(box_i) / S(scene)` ([`Crossings::mean`]).
//! A perspective camera's rays are taken parallel to its forward direction ([`Crossings::per_ray`]).
//!
//! # Secondary rays
//!
//! Shadow and diffuse rays start at the primary hits, inside the scene's box, in directions the camera does not
//! fix (toward the light; about the surface normal): they are given the mean over every direction
//! ([`Crossings::isotropic`]), with no coverage factor. The factors per crossing ([`tests_per_crossing`]) are read
//! off the training records of each workload separately: a shadow ray stops at its first hit and a diffuse ray
//! leaves the surface, so neither crosses what a full line would, and the envelope says how much less at least.
//!
//! # Where the floor applies, and where not yet
//!
//! The calibrated policy's predictions for a scene (`CalibratedPolicy::predictions`: the first frame, static
//! choice), the per-frame plan of an animation (`plan_frames`, `FrameRule::crossings`) and `evaluate
//! --compare-policies` take it, from the first frame's crossings, for all three workloads. Not yet: the driver's
//! structures (which have no test counts), and the trade-off study's selections (which pass no mesh bounds). The distinct triples are found
//! with a hash set of every triple when some direction crosses at least [`Crossings::DISTINCT_FROM`] boxes: about 20
//! bytes per triangle for the length of the pass.

use super::ViewFeatures;
use crate::accel::StructureName;
use crate::geom::{Aabb, Camera, WorkloadKind};
use crate::mesh::Mesh;
use glam::Vec3;

/// A scene's triangle boxes as projected areas (see the module docs): the sums, over the triangles' boxes, of their
/// face areas `[e_y e_z, e_x e_z, e_x e_y]`, the same over the distinct vertex-index triples, and the scene box's.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Crossings {
    /// Face areas summed over every triangle's box.
    pub faces: [f64; 3],
    /// The same over the distinct vertex-index triples (in order): the binned-SAH BVH keeps one of coincident
    /// copies of a triangle, so its rays cross only these. Counted apart only when [`Crossings::most`] is at least
    /// [`Crossings::DISTINCT_FROM`] (a hash of every triple); equal to [`Crossings::faces`] below, where no floor
    /// can matter.
    pub distinct_faces: [f64; 3],
    /// The same over the triangles of non-zero area: the kd-tree stores a zero-area triangle as a point, so its
    /// rays never cross such a box.
    pub nondegenerate_faces: [f64; 3],
    /// The scene box's face areas.
    pub scene: [f64; 3],
}

/// The triangle boxes a ray crosses on average ([`Crossings::per_ray`] for a camera's primary rays,
/// [`Crossings::isotropic`] for secondary rays): over every triangle, over the distinct vertex-index triples (what
/// the binned-SAH BVH holds), and over the triangles of non-zero area (what the kd-tree holds as boxes).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RayCrossings {
    /// Over every triangle.
    pub all: f64,
    /// Over the distinct vertex-index triples.
    pub distinct: f64,
    /// Over the triangles of non-zero area.
    pub nondegenerate: f64,
}

fn face_areas(b: &Aabb) -> [f64; 3] {
    let e = (b.max - b.min).as_dvec3();
    [e.y * e.z, e.x * e.z, e.x * e.y]
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

impl Crossings {
    /// [`Crossings::most`] from which [`Crossings::distinct_faces`] is counted apart.
    pub const DISTINCT_FROM: f64 = 16.0;

    /// The crossings of a mesh's triangles, `boxes` their boxes in mesh order with whether the triangle has zero
    /// area, `scene` their union (one pass, plus a hash of the vertex-index triples from
    /// [`Crossings::DISTINCT_FROM`] on).
    pub fn of(mesh: &Mesh, boxes: impl Iterator<Item = (Aabb, bool)> + Clone, scene: &Aabb) -> Crossings {
        let (faces, nondegenerate_faces) = boxes.clone().fold(([0.0; 3], [0.0; 3]), |(s, t), (b, degenerate)| {
            let f = face_areas(&b);
            (add(s, f), if degenerate { t } else { add(t, f) })
        });
        let mut c = Crossings { faces, distinct_faces: faces, nondegenerate_faces, scene: face_areas(scene) };
        if !scene.is_empty() && c.most() >= Self::DISTINCT_FROM {
            let mut seen = std::collections::HashSet::with_capacity(mesh.indices.len());
            c.distinct_faces = boxes
                .zip(&mesh.indices)
                .filter(|(_, t)| seen.insert(**t))
                .fold([0.0; 3], |s, ((b, _), _)| add(s, face_areas(&b)));
        }
        c
    }

    /// The crossings of a mesh, its triangles' boxes computed here (what [`crate::select::BuildBounds::of_mesh`]
    /// records).
    pub fn of_mesh(mesh: &Mesh) -> Crossings {
        let boxes: Vec<(Aabb, bool)> = (0..mesh.triangle_count())
            .map(|i| {
                let v = mesh.triangle(i);
                (Aabb::of_triangle(&v), crate::geom::Triangle::new(&v).is_degenerate())
            })
            .collect();
        let scene = boxes.iter().fold(Aabb::EMPTY, |a, (b, _)| a.union(b));
        Crossings::of(mesh, boxes.iter().copied(), &scene)
    }

    /// The most crossings along any direction: the largest of the three face ratios (each `along` is a weighted
    /// mean of them).
    pub fn most(&self) -> f64 {
        (0..3)
            .map(|a| ratio(self.faces, self.scene, std::array::from_fn(|b| (a == b) as u8 as f64)))
            .fold(0.0, f64::max)
    }

    /// Over every direction: `sum_i S(box_i) / S(scene)` (Cauchy-Crofton), 0 for a scene box of no area. 0 to 169
    /// on every shared mesh and generated family (3.5 on the bunny, 16.4 on Sponza, 169 on the engineering family
    /// at 200K triangles); hundreds to thousands where triangles overlap heavily or coincide.
    pub fn mean(&self) -> f64 {
        ratio(self.faces, self.scene, [1.0; 3])
    }

    /// Along the direction `d`, for lines that meet the scene's box: `(all, distinct)`.
    pub fn along(&self, d: Vec3) -> (f64, f64) {
        let w = d.abs().as_dvec3().to_array();
        (ratio(self.faces, self.scene, w), ratio(self.distinct_faces, self.scene, w))
    }

    /// Over every direction ([`Crossings::mean`]), for all three kinds of triangle: what a secondary ray is given.
    pub fn isotropic(&self) -> RayCrossings {
        RayCrossings {
            all: ratio(self.faces, self.scene, [1.0; 3]),
            distinct: ratio(self.distinct_faces, self.scene, [1.0; 3]),
            nondegenerate: ratio(self.nondegenerate_faces, self.scene, [1.0; 3]),
        }
    }

    /// Per ray of a workload: [`Crossings::per_ray`] of `camera` for primary rays, [`Crossings::isotropic`] for
    /// shadow and diffuse rays (which start at the primary hits, in directions the camera does not fix).
    pub fn for_workload(
        &self,
        kind: WorkloadKind,
        camera: Option<&Camera>,
        lo: [f32; 3],
        hi: [f32; 3],
    ) -> RayCrossings {
        match kind {
            WorkloadKind::Primary => self.per_ray(camera, lo, hi),
            WorkloadKind::Shadow | WorkloadKind::Diffuse => self.isotropic(),
        }
    }

    /// Per primary ray of `camera` (`None`: the framing camera of the box, [`super::view::framing_camera`]) over
    /// the box `lo`..`hi` (the one [`ViewFeatures::of`] reads): the crossings along its forward direction times the
    /// share of its rays that meet the box.
    pub fn per_ray(&self, camera: Option<&Camera>, lo: [f32; 3], hi: [f32; 3]) -> RayCrossings {
        let framing;
        let camera = match camera {
            Some(c) => c,
            None => {
                framing = super::view::framing_camera(lo, hi);
                &framing
            }
        };
        let coverage = ViewFeatures::of(camera, lo, hi).coverage;
        let w = camera.forward.abs().as_dvec3().to_array();
        RayCrossings {
            all: ratio(self.faces, self.scene, w) * coverage,
            distinct: ratio(self.distinct_faces, self.scene, w) * coverage,
            nondegenerate: ratio(self.nondegenerate_faces, self.scene, w) * coverage,
        }
    }
}

/// `sum_a w_a f_a / sum_a w_a s_a`, 0 when the denominator is not positive and finite.
fn ratio(f: [f64; 3], s: [f64; 3], w: [f64; 3]) -> f64 {
    let den: f64 = (0..3).map(|a| w[a] * s[a]).sum();
    if den.is_finite() && den > 0.0 {
        (0..3).map(|a| w[a] * f[a]).sum::<f64>() / den
    } else {
        0.0
    }
}

/// Least tests per primary ray per crossed triangle box ([`RayCrossings`]), `(box, triangle)`, of each structure:
/// the lower envelope of the measured ratio on the training records (`docs/data/oracle-primary.jsonl` and
/// `docs/data/families-primary.jsonl`, the 33 scenes and views whose rays cross at least 4 boxes),
/// rounded down to two significant digits, with where the least was found (`docs/cost-model.md` lists them).
/// Read off the training records only; checked, not fitted, on the degenerate generators
/// (`docs/data/degenerate-*.jsonl`). The kd-tree floors no box tests (one that cannot split overlapping triangles
/// visits one node), the grid nothing (its cells, not the triangles' boxes, bound what a ray visits).
pub fn primary_tests_per_crossing(structure: StructureName) -> (f64, f64) {
    match structure {
        StructureName::Bvh => BVH,
        StructureName::KdTree => (0.0, KDTREE_PRIM),
        StructureName::Bih => BIH,
        StructureName::Lbvh => LBVH,
        StructureName::Hlbvh => HLBVH,
        _ => (0.0, 0.0),
    }
}

// The envelopes (see primary_tests_per_crossing), `(box, triangle)` per crossing, and where the least was found:
// BVH box 0.395 (engineering 200K, grazing), triangle 0.0645 (city 200K, inside); kd-tree triangle 0.171
// (Sponza); BIH box 0.938 (engineering 200K, grazing), triangle 0.433 (engineering 2K, inside); LBVH box 1.48
// (engineering 200K, grazing), triangle 0.0944 (engineering 2K, inside); HLBVH box 0.665 (engineering 200K,
// grazing), triangle 0.0692 (engineering 2K, inside).
const BVH: (f64, f64) = (0.39, 0.064);
const KDTREE_PRIM: f64 = 0.17;
const BIH: (f64, f64) = (0.93, 0.43);
const LBVH: (f64, f64) = (1.4, 0.094);
const HLBVH: (f64, f64) = (0.66, 0.069);

/// Least tests per crossed triangle box ([`RayCrossings`]), `(box, triangle)`, of each structure for a workload:
/// [`primary_tests_per_crossing`] for primary rays; for shadow and diffuse rays the lower envelope of the measured
/// ratio to [`Crossings::isotropic`] on the training records of that workload (`docs/data/oracle-<w>.jsonl` and
/// `docs/data/families-<w>.jsonl`, the scenes and views with at least one hit whose isotropic crossings are at least
/// 4: 56 shadow, 46 diffuse), rounded down to two significant digits. Read off the training records only; checked,
/// not fitted, on the degenerate generators. As for primary rays, the kd-tree floors no box tests and the grid
/// nothing.
pub fn tests_per_crossing(structure: StructureName, kind: WorkloadKind) -> (f64, f64) {
    let table = match kind {
        WorkloadKind::Primary => return primary_tests_per_crossing(structure),
        WorkloadKind::Shadow => &SHADOW,
        WorkloadKind::Diffuse => &DIFFUSE,
    };
    match structure {
        StructureName::Bvh => table[0],
        StructureName::KdTree => (0.0, table[1].1),
        StructureName::Bih => table[2],
        StructureName::Lbvh => table[3],
        StructureName::Hlbvh => table[4],
        _ => (0.0, 0.0),
    }
}

// The secondary rays' envelopes (see tests_per_crossing), `(box, triangle)` per isotropic crossing for the BVH,
// kd-tree (triangle only), BIH, LBVH and HLBVH, and where the least was found. Shadow: BVH box 0.167 (Sponza),
// triangle 0.0049 (interior 2K, framing); kd-tree triangle 0.0075 (interior 20K, framing); BIH 0.195 (interior
// 20K, framing) / 0.0096 (interior 2K, framing); LBVH 0.294 (interior 200K, framing) / 0.0051 (interior 20K,
// framing); HLBVH 0.208 (Sponza) / 0.0040 (interior 20K, framing). Diffuse: BVH 0.147 (Sponza) / 0.0061 (interior
// 2K, grazing); kd-tree triangle 0.0074 (Sponza); BIH 0.281 / 0.0625 (Sponza); LBVH 0.299 (Sponza) / 0.0052
// (interior 2K, grazing); HLBVH 0.180 / 0.0070 (Sponza).
const SHADOW: [(f64, f64); 5] = [(0.16, 0.0049), (0.0, 0.0075), (0.19, 0.0096), (0.29, 0.0051), (0.20, 0.0040)];
const DIFFUSE: [(f64, f64); 5] = [(0.14, 0.0061), (0.0, 0.0074), (0.28, 0.062), (0.29, 0.0052), (0.18, 0.0070)];

/// Lower bounds on a structure's tests per ray, for [`crate::cost::StructureModel::predict_floored`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TestFloor {
    /// Box tests (node visits) per ray.
    pub box_tests: f64,
    /// Triangle tests per ray.
    pub prim_tests: f64,
}

/// The overlap floor of `structure`'s tests per ray of the workload `kind` whose [`RayCrossings`] are at hand
/// ([`Crossings::for_workload`]): its factors of [`tests_per_crossing`] times the crossings (the distinct
/// triangles' for the binned-SAH BVH, which keeps one of coincident copies; those of non-zero area for the kd-tree,
/// which stores zero-area triangles as points; all of them for the others). Zero without crossings.
pub fn overlap_floor(structure: StructureName, kind: WorkloadKind, c: Option<RayCrossings>) -> TestFloor {
    let Some(c) = c else { return TestFloor::default() };
    let x = match structure {
        StructureName::Bvh => c.distinct,
        StructureName::KdTree => c.nondegenerate,
        _ => c.all,
    };
    let (b, p) = tests_per_crossing(structure, kind);
    TestFloor { box_tests: b * x, prim_tests: p * x }
}
