//! Overlap: how many triangle boxes a ray crosses, and the floor it puts under a structure's tests per ray.
//!
//! The count laws of the model are log-linear in the characterization's features, none of which sees triangles
//! that overlap or coincide: on 2,000 large triangles with vertices uniform in a cube the model predicted 1.4
//! triangle tests per ray for the BVH where it makes 153, and picked it at 6.9x the grid's total
//! (`docs/results/2026-12-04-cost-model-degenerate-overlap-floor.md`). [`Crossings`] measures the overlap exactly from the mesh,
//! [`Crossings::for_workload`] turns it into the boxes a ray of a workload crosses on average ([`RayCrossings`]),
//! and [`overlap_floor`] bounds the hierarchies' box and triangle tests per ray, and the grid's triangle tests per
//! primary ray, from below with it. Where the view was probed (`Crossings::with_probes_but`), [`overlap_floor`] also
//! carries each probed structure's sampled counts and build work, and bounds the one unprobed hierarchy, the
//! kd-tree, from below by the probed hierarchies' fewest triangle tests ([`CountBounds::kd_tree_prim_floor`]).
//!
//! # Crossings of a view
//!
//! A line of direction `d` meets an axis-aligned box of extents `e` with probability proportional to the box's area
//! projected along `d`, `|d_x| e_y e_z + |d_y| e_x e_z + |d_z| e_x e_y`, among parallel lines spread uniformly
//! over the scene's box. So the mean number of triangle boxes crossed by a line along `d` that meets the scene's box
//! is the sum of the triangle boxes' projected areas over the scene box's, and a camera's ray crosses that many
//! times the share of its rays that meet the scene's box ([`crate::cost::ViewFeatures::coverage`]). Averaged over
//! every direction, the first factor is the Cauchy-Crofton ratio `sum_i S(box_i) / S(scene)` ([`Crossings::mean`]).
//!
//! That parallel estimate misses perspective: a camera close to dense geometry sees it magnified. So a camera's
//! crossings are counted on its image ([`screen_crossings`]: per triangle box, the share of the image its screen
//! rectangle covers, summed; one more pass over the boxes) and kept with the crossings (`Crossings::with_view`,
//! [`crate::select::BuildBounds::of_mesh_viewed`] for the camera the policy is given, the framing one without);
//! [`Crossings::per_ray`] takes that count for that camera and the parallel estimate for any other. On the
//! engineering family at 200K triangles seen close up the count is 2,163 boxes per ray, the parallel estimate 150.
//!
//! # Secondary rays
//!
//! Shadow and diffuse rays start at the primary hits, inside the scene's box, in directions the camera does not
//! fix (toward the light; about the surface normal): they are given the mean over every direction
//! ([`Crossings::isotropic`]), with no coverage factor, and the camera's count on its image
//! ([`RayCrossings::image`]): they start where the camera's rays stop, so a camera looking into dense geometry sends
//! them into it. The factors per crossing ([`StructureCountBounds`]) are fitted
//! on the training records of each workload separately (`calibrate`), and the floor is the larger of the two.
//!
//! # Rays that leave the scene at once
//!
//! A secondary ray that starts on the scene's outer boundary, on the camera's side, tests the root box and
//! nothing else, in every structure. Two cases are counted: a flat scene, whose every secondary ray leaves its
//! plane ([`secondary_rays_leave_the_plane`]: the hierarchies' counts are fixed at one box test and no triangle test,
//! above and below, [`TestFloor::box_tests_most`]), and a closed scene seen from outside, whose walls lie in the
//! faces of its box ([`Crossings::leave_share`]: that share of the rays is counted at one box test, the others as
//! the laws and floors say). Both rest on the scene's box staying put over an animation's frames
//! ([`Crossings::over_frames`]) and on the workloads' secondary rays starting a little off the surface on the
//! camera's side (`trace::workload`; a camera hundreds of scene diagonals away can put that offset inside the
//! rounding of the hit point).
//!
//! # Boxes entered before the first hit
//!
//! The image count includes the boxes behind a ray's first hit, which a closest-hit traversal never reaches, so the
//! factors above are small (set by closed rooms). [`near_crossings`] counts, on a sample of a camera's rays, the
//! boxes each enters before its first hit, those holding the origin of the diffuse ray each hit starts, and those
//! crossed by the shadow rays no triangle occludes: every node of a BVH, LBVH, HLBVH or BIH bounds whole triangles,
//! so each such triangle is tested, and the counts floor those four structures' triangle tests per ray of all three
//! workloads with no fitted factor ([`overlap_floor`]).
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
pub(crate) struct Crossings {
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
    /// The crossings of one camera counted on its image ([`screen_crossings`]), when computed
    /// (`Crossings::with_view`): [`Crossings::per_ray`] takes them for that camera.
    pub view: Option<ViewCrossings>,
    /// Per face of the scene's box (`-x, +x, -y, +y, -z, +z`), the share of it covered by triangles lying in its
    /// plane: their areas summed over the face's, at most 1 (overlapping triangles in the plane count twice, up to
    /// that cap). A closed room or stadium has its outer walls there ([`Crossings::leave_share`]). Over an
    /// animation's frames ([`Crossings::over_frames`]) the least of every frame's, and 0 where the box moves.
    pub boundary_fill: [f64; 6],
    /// The scene's box (the union of the triangles' boxes, every triangle counted): its low corner.
    pub lo: [f32; 3],
    /// Its high corner.
    pub hi: [f32; 3],
    /// Whether the box differs between an animation's frames ([`Crossings::over_frames`]): then no secondary ray is
    /// taken to leave the scene at once ([`secondary_rays_leave_the_plane`], [`Crossings::leave_share`]).
    pub box_moves: bool,
}

/// The triangle boxes crossed by one camera's primary rays, counted on its image ([`screen_crossings`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub(crate) struct ViewCrossings {
    /// The camera.
    #[serde(skip)]
    pub camera: Camera,
    /// Whether it is the framing camera of the scene's box (what the policy assumes without a camera).
    pub framing: bool,
    /// The mean number of triangle boxes covering a point of its image, over every triangle.
    pub all: f64,
    /// On a sample of its rays ([`near_crossings`]): the triangle boxes a primary ray enters no later than its
    /// first hit, those holding the origin of the diffuse ray the hit starts, and those an unoccluded shadow ray
    /// crosses; lower bounds on the triangle tests of the hierarchies whose nodes bound whole triangles. Counted
    /// only where [`ViewCrossings::all`] is at least [`Crossings::NEAR_FROM`].
    pub near: Option<NearCrossings>,
    /// On a sample of its primary rays (that of [`ViewCrossings::near`] where it is counted) and the shadow and
    /// diffuse rays their hits start, the own tests per ray of each structure of [`super::PROBED`], in that order
    /// ([`super::probe()`]): counted where the caller has the mesh of a static scene (`Crossings::with_probes_but`);
    /// `None` for a structure that did not build.
    pub probes: [Option<super::Probe>; super::probe::PROBES],
}

/// The triangle boxes a ray crosses on average (`Crossings::per_ray` for a camera's primary rays,
/// `Crossings::isotropic` for secondary rays): over every triangle, over the distinct vertex-index triples (what
/// the binned-SAH BVH holds), and over the triangles of non-zero area (what the kd-tree holds as boxes).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RayCrossings {
    /// Over every triangle.
    pub all: f64,
    /// Over the distinct vertex-index triples.
    pub distinct: f64,
    /// Over the triangles of non-zero area.
    pub nondegenerate: f64,
    /// Secondary rays only (`Crossings::for_workload`): the camera's primary-ray crossings counted on its image
    /// ([`screen_crossings`], over every triangle), when counted; 0 otherwise. The secondary rays start where those
    /// rays hit, so a close camera looking into dense geometry sends them into it too.
    pub image: f64,
    /// When counted (`Crossings::view` of that camera, [`near_crossings`] on a sample of its rays): for primary
    /// rays the triangle boxes a ray enters no later than its first hit, for diffuse rays those holding the ray's
    /// origin (entered at once), for shadow rays those an unoccluded ray crosses (0 for an occluded one); over every
    /// triangle. Each is a lower bound on the triangle tests of a hierarchy whose nodes bound whole triangles.
    pub near: Option<f64>,
    /// Secondary rays only: every ray leaves a flat scene without meeting it again
    /// (`secondary_rays_leave_the_plane`), so it crosses no box (the counts above are then 0) and every
    /// hierarchy tests its root box once and no triangle (`overlap_floor` gives those counts exactly).
    pub leave_flat_scene: bool,
    /// When counted (`ViewCrossings::probes`): the own tests per ray of each structure of [`super::PROBED`] on the
    /// sample of the camera's rays of the workload's kind ([`RayCrossings::probe`]): its primary rays, or the shadow
    /// or diffuse rays their hits start.
    pub probes: [Option<super::ProbeCounts>; super::probe::PROBES],
    /// When probed (`ViewCrossings::probes`): the work of each probed structure's build, in the order of
    /// [`super::PROBED`] ([`super::Probe::build_work`]; 0 where unknown), whatever rays were traced: what the build
    /// laws read ([`RayCrossings::build_work`]).
    pub probe_work: [f64; super::probe::PROBES],
    /// Secondary rays only: the share of them that start on the scene's outer boundary and leave it at once
    /// (`Crossings::leave_share`): each tests the root box once and no triangle, in every structure.
    pub leave_share: f64,
}

fn face_areas(b: &Aabb) -> [f64; 3] {
    let e = (b.max - b.min).as_dvec3();
    [e.y * e.z, e.x * e.z, e.x * e.y]
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// [`Crossings::boundary_fill`] of the triangles whose boxes are `boxes` (in mesh order) in the box `scene`.
fn boundary_fill(mesh: &Mesh, boxes: impl Iterator<Item = (Aabb, bool)>, scene: &Aabb) -> [f64; 6] {
    let e = (scene.max - scene.min).as_dvec3();
    if scene.is_empty() || !e.is_finite() {
        return [0.0; 6];
    }
    let mut area = [0.0f64; 6];
    for (i, (b, _)) in boxes.enumerate() {
        for a in 0..3 {
            if b.min[a] != b.max[a] {
                continue;
            }
            let side = if b.min[a] == scene.min[a] {
                0
            } else if b.max[a] == scene.max[a] {
                1
            } else {
                continue;
            };
            let [p, q, r] = mesh.triangle(i).map(|v| v.as_dvec3());
            area[2 * a + side] += 0.5 * (q - p).cross(r - p).length();
        }
    }
    let face = [e.y * e.z, e.y * e.z, e.x * e.z, e.x * e.z, e.x * e.y, e.x * e.y];
    std::array::from_fn(|f| if face[f] > 0.0 && area[f].is_finite() { (area[f] / face[f]).min(1.0) } else { 0.0 })
}

impl Crossings {
    /// [`Crossings::most`] from which [`Crossings::distinct_faces`] is counted apart.
    pub const DISTINCT_FROM: f64 = 16.0;

    /// The count on a camera's image ([`ViewCrossings::all`]) from which the boxes its rays enter before their
    /// first hits are counted ([`ViewCrossings::near`], [`near_crossings`]). Below it a ray meets few boxes on
    /// average, so the floor they give could bind by a few tests only; scenes whose rays meet few boxes skip the
    /// pass.
    pub const NEAR_FROM: f64 = 8.0;

    /// The crossings of a mesh's triangles, `boxes` their boxes in mesh order with whether the triangle has zero
    /// area, `scene` their union (one pass, plus a hash of the vertex-index triples from
    /// [`Crossings::DISTINCT_FROM`] on).
    pub fn of(mesh: &Mesh, boxes: impl Iterator<Item = (Aabb, bool)> + Clone, scene: &Aabb) -> Crossings {
        let (faces, nondegenerate_faces) = boxes.clone().fold(([0.0; 3], [0.0; 3]), |(s, t), (b, degenerate)| {
            let f = face_areas(&b);
            (add(s, f), if degenerate { t } else { add(t, f) })
        });
        let mut c = Crossings {
            faces,
            distinct_faces: faces,
            nondegenerate_faces,
            scene: face_areas(scene),
            view: None,
            boundary_fill: boundary_fill(mesh, boxes.clone(), scene),
            lo: scene.min.to_array(),
            hi: scene.max.to_array(),
            box_moves: false,
        };
        if !scene.is_empty() && c.most() >= Self::DISTINCT_FROM {
            let mut seen = std::collections::HashSet::with_capacity(mesh.indices.len());
            c.distinct_faces = boxes
                .zip(&mesh.indices)
                .filter(|(_, t)| seen.insert(**t))
                .fold([0.0; 3], |s, ((b, _), _)| add(s, face_areas(&b)));
        }
        c
    }

    /// The crossings of a mesh, its triangles' boxes computed here, with the view of `camera` counted on its image
    /// (`Crossings::with_view`; `None`: the framing camera of the mesh's box, what the policy assumes without a
    /// camera). [`crate::select::BuildBounds::of_mesh_viewed`] records the same.
    #[cfg(test)]
    pub fn of_mesh_viewed(mesh: &Mesh, camera: Option<&Camera>) -> Crossings {
        Crossings::of_first_frame_viewed(mesh, camera, 1)
    }

    /// [`Crossings::of_mesh_viewed`] of the first of `frames` frames of a scene: for an animation (more than one
    /// frame) without the boxes entered before the hits ([`ViewCrossings::near`]), which bound that frame's rays only
    /// (the pass is skipped, not run and dropped).
    #[cfg(test)]
    pub(crate) fn of_first_frame_viewed(mesh: &Mesh, camera: Option<&Camera>, frames: usize) -> Crossings {
        Crossings::of_first_frame_timed(mesh, camera, frames).0
    }

    /// [`Crossings::of_first_frame_viewed`], and what its parts took on this machine (wall time, ms): the
    /// crossings (the boxes, their sums, the view's count on its image and the boxes entered before the hits) and
    /// each probe of [`super::PROBED`] (0 for a structure not probed).
    #[cfg(feature = "eval")]
    pub(crate) fn of_first_frame_timed(
        mesh: &Mesh,
        camera: Option<&Camera>,
        frames: usize,
    ) -> (Crossings, f64, [f64; super::probe::PROBES]) {
        let t = std::time::Instant::now();
        let (boxes, tris): (Vec<Aabb>, Vec<crate::geom::Triangle>) = (0..mesh.triangle_count())
            .map(|i| {
                let v = mesh.triangle(i);
                (Aabb::of_triangle(&v), crate::geom::Triangle::new(&v))
            })
            .unzip();
        let scene = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        let c = Crossings::of(mesh, boxes.iter().zip(&tris).map(|(b, t)| (*b, t.is_degenerate())), &scene);
        let mut probe_ms = [0.0; super::probe::PROBES];
        if frames > 1 {
            let c = c.viewed_from(&boxes, &[], &scene, camera);
            return (c, t.elapsed().as_secs_f64() * 1e3, probe_ms);
        }
        let mut c = c.viewed_from(&boxes, &tris, &scene, camera);
        let crossings_ms = t.elapsed().as_secs_f64() * 1e3;
        if let Some(v) = c.view.as_mut() {
            let side = near_sample_side(v.all);
            for (i, s) in super::PROBED.into_iter().enumerate() {
                let t = std::time::Instant::now();
                v.probes[i] = super::probe(s, mesh, &scene, &v.camera, side, true);
                probe_ms[i] = t.elapsed().as_secs_f64() * 1e3;
            }
        }
        (c, crossings_ms, probe_ms)
    }

    /// [`Crossings::of_mesh_viewed`] from the framing camera.
    #[cfg(test)]
    pub fn of_mesh(mesh: &Mesh) -> Crossings {
        Crossings::of_mesh_viewed(mesh, None)
    }

    /// [`Crossings::with_view`] of `camera`, or of the framing camera of `scene` (the triangles' union) when `None`;
    /// no view for an empty or non-finite scene. With no triangles in `tris`, no boxes entered before the hits.
    pub(crate) fn viewed_from(
        self,
        boxes: &[Aabb],
        tris: &[crate::geom::Triangle],
        scene: &Aabb,
        camera: Option<&Camera>,
    ) -> Crossings {
        if scene.is_empty() || !(scene.max - scene.min).is_finite() {
            return self;
        }
        match camera {
            Some(c) => self.with_view(boxes, tris, c, false),
            None => {
                let c = super::view::framing_camera(scene.min.to_array(), scene.max.to_array());
                self.with_view(boxes, tris, &c, true)
            }
        }
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
    #[cfg(test)]
    pub fn mean(&self) -> f64 {
        ratio(self.faces, self.scene, [1.0; 3])
    }

    /// Along the direction `d`, for lines that meet the scene's box: `(all, distinct)`.
    #[cfg(test)]
    pub fn along(&self, d: Vec3) -> (f64, f64) {
        let w = d.abs().as_dvec3().to_array();
        (ratio(self.faces, self.scene, w), ratio(self.distinct_faces, self.scene, w))
    }

    /// Over every direction ([`Crossings::mean`]), for all three kinds of triangle: what a secondary ray is given.
    pub(crate) fn isotropic(&self) -> RayCrossings {
        RayCrossings {
            all: ratio(self.faces, self.scene, [1.0; 3]),
            distinct: ratio(self.distinct_faces, self.scene, [1.0; 3]),
            nondegenerate: ratio(self.nondegenerate_faces, self.scene, [1.0; 3]),
            near: None,
            image: 0.0,
            leave_flat_scene: false,
            leave_share: 0.0,
            probes: [None; super::probe::PROBES],
            probe_work: [0.0; super::probe::PROBES],
        }
    }

    /// Per ray of a workload: [`Crossings::per_ray`] of `camera` for primary rays; for shadow and diffuse rays
    /// (which start at the primary hits, in directions the camera does not fix) [`Crossings::isotropic`], with
    /// [`RayCrossings::image`] the camera's count on its image when [`Crossings::view`] is of that camera, and
    /// [`RayCrossings::near`] its sampled counts for the workload ([`near_crossings`], their lower bounds) when
    /// counted; none for secondary rays that leave a flat scene ([`secondary_rays_leave_the_plane`]).
    pub(crate) fn for_workload(
        &self,
        kind: WorkloadKind,
        camera: Option<&Camera>,
        lo: [f32; 3],
        hi: [f32; 3],
    ) -> RayCrossings {
        match kind {
            WorkloadKind::Primary => self.per_ray(camera, lo, hi),
            _ if !self.box_moves && secondary_rays_leave_the_plane(kind, camera, self.lo, self.hi) => RayCrossings {
                // The hierarchies' counts are fixed ([`overlap_floor`]); the grid, which still steps through the
                // cells at the rays' origins, keeps the crossings its laws read.
                image: self.counted(camera).map_or(0.0, |v| v.all),
                leave_flat_scene: true,
                probe_work: self.probe_work(camera),
                ..self.isotropic()
            },
            WorkloadKind::Shadow | WorkloadKind::Diffuse => RayCrossings {
                image: self.counted(camera).map_or(0.0, |v| v.all),
                leave_share: self.leave_share(kind, camera),
                probes: self
                    .counted(camera)
                    .map_or([None; super::probe::PROBES], |v| v.probes.map(|p| p.map(|p| *p.of_kind(kind)))),
                probe_work: self.probe_work(camera),
                near: self.counted(camera).and_then(|v| v.near).map(|n| {
                    if kind == WorkloadKind::Diffuse {
                        n.holding_origin.lower_bound()
                    } else {
                        n.unoccluded_shadow.lower_bound()
                    }
                }),
                ..self.isotropic()
            },
        }
    }

    /// These crossings (an animation's first frame's, which the policy floors every frame with) combined with
    /// another frame's: where the scene's box is the same, the least boundary fill of the two; where it moves,
    /// [`Crossings::box_moves`] (no ray is then taken to leave at once, in any frame).
    pub(crate) fn over_frames(mut self, other: &Crossings) -> Crossings {
        // The boxes a ray enters before its hit are counted on the first frame's geometry: no bound for the others.
        if let Some(v) = self.view.as_mut() {
            v.near = None;
            v.probes = [None; super::probe::PROBES];
        }
        if self.box_moves || other.box_moves || self.lo != other.lo || self.hi != other.hi {
            self.box_moves = true;
            self.boundary_fill = [0.0; 6];
        } else {
            self.boundary_fill = std::array::from_fn(|f| self.boundary_fill[f].min(other.boundary_fill[f]));
        }
        self
    }

    /// The share of the secondary rays of `kind` that leave the scene at once: those that start on a face of the
    /// scene's box ([`Crossings::lo`], [`Crossings::hi`]) seen from outside by `camera` (`None`: the framing camera
    /// of that box), on a triangle lying in
    /// that face's plane. Nothing of the scene lies beyond the face, so such a triangle is the first hit of the
    /// camera's rays that meet it; the secondary ray starts off it on the camera's side (outside the box) and, a
    /// diffuse ray about the facing normal, a shadow ray when the workload's light
    /// ([`crate::geom::camera::default_light`]) is outside that face too, never enters the box: one box test (the
    /// root's), no triangle test, in every structure. The share of the camera's rays entering through each face is
    /// its solid angle from the eye (area times the cosine to the eye over the squared distance, from the face's
    /// centre), and of those the covered share is [`Crossings::boundary_fill`]. A lower bound on the share among the
    /// secondary rays (whose rays are the hits, not all rays entering the box), 0 for primary rays, a camera inside
    /// the box, or a scene with nothing on its faces. Measured on the 252 family records: closed rooms and the
    /// stadium seen from outside (framing and grazing views) make exactly 1 box test and no triangle test per
    /// diffuse ray in every hierarchy.
    pub(crate) fn leave_share(&self, kind: WorkloadKind, camera: Option<&Camera>) -> f64 {
        let (lo, hi) = (self.lo, self.hi);
        let b = Aabb { min: Vec3::from_array(lo), max: Vec3::from_array(hi) };
        if kind == WorkloadKind::Primary || self.box_moves || b.is_empty() || !(b.min.is_finite() && b.max.is_finite())
        {
            return 0.0;
        }
        let cam = camera_or_framing(camera, lo, hi);
        let light = crate::geom::camera::default_light(&b);
        let (eye, e, c) = (cam.eye.as_dvec3(), (b.max - b.min).as_dvec3(), b.center().as_dvec3());
        let (mut seen, mut leave) = (0.0, 0.0);
        for a in 0..3 {
            let area = e[(a + 1) % 3] * e[(a + 2) % 3];
            for side in 0..2 {
                let (plane, outside, lit) = if side == 0 {
                    (b.min[a], cam.eye[a] < b.min[a], light[a] < b.min[a])
                } else {
                    (b.max[a], cam.eye[a] > b.max[a], light[a] > b.max[a])
                };
                if !outside || area <= 0.0 {
                    continue;
                }
                let mut centre = c;
                centre[a] = plane as f64;
                let to_eye = eye - centre;
                let d2 = to_eye.length_squared();
                if !(d2 > 0.0 && d2.is_finite()) {
                    continue;
                }
                let w = area * to_eye[a].abs() / (d2 * d2.sqrt());
                seen += w;
                if kind == WorkloadKind::Diffuse || lit {
                    leave += w * self.boundary_fill[2 * a + side];
                }
            }
        }
        if seen > 0.0 && leave.is_finite() {
            (leave / seen).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }

    /// [`Crossings::view`] when it is of `camera` (`None` matches a view of the framing camera).
    fn counted(&self, camera: Option<&Camera>) -> Option<ViewCrossings> {
        self.view.filter(|v| match camera {
            Some(c) => v.camera == *c,
            None => v.framing,
        })
    }

    /// These crossings with `camera`'s counted on its image ([`screen_crossings`] of `boxes`, the triangles' boxes)
    /// and, on a sample of its rays, in front of their first hits ([`near_crossings`] of `boxes` and `tris`, the
    /// triangles, in the same order; not with no triangles, nor below [`Crossings::NEAR_FROM`]); `framing`: it is the
    /// framing camera of the scene's box, [`super::view::framing_camera`].
    pub(crate) fn with_view(
        mut self,
        boxes: &[Aabb],
        tris: &[crate::geom::Triangle],
        camera: &Camera,
        framing: bool,
    ) -> Crossings {
        let all = screen_crossings(boxes, camera);
        let near = (all >= Self::NEAR_FROM && !tris.is_empty()).then(|| near_crossings(boxes, tris, camera, all));
        self.view = Some(ViewCrossings { camera: *camera, framing, all, near, probes: [None; super::probe::PROBES] });
        self
    }

    /// These crossings with each structure of [`super::PROBED`] built over `mesh` (whose triangles' box is `scene`)
    /// and probed on a sample of primary rays of their view and the shadow and diffuse rays their hits start
    /// ([`super::probe()`], [`ViewCrossings::probes`]): the primary sample [`ViewCrossings::near`] is counted on where
    /// the view is dense enough for it ([`near_sample_side`]), 32 x 32 rays otherwise; unchanged without a view. For
    /// a static scene: an animation's later frames are not what the probes built.
    /// Structures of `skip` get no probe: a caller that already knows a structure is out of its budget (the
    /// selection's bounds, for a grid over it) spares its build.
    pub(crate) fn with_probes_but(mut self, mesh: &Mesh, scene: &Aabb, skip: &[StructureName]) -> Crossings {
        if let Some(v) = self.view.as_mut() {
            let side = near_sample_side(v.all);
            v.probes = super::PROBED.map(|s| {
                if skip.contains(&s) {
                    None
                } else {
                    super::probe(s, mesh, scene, &v.camera, side, true)
                }
            });
        }
        self
    }

    /// Per primary ray of `camera` (`None`: the framing camera of the box, `super::view::framing_camera`) over
    /// the box `lo`..`hi` (the one [`ViewFeatures::of`] reads). With [`Crossings::view`] of that camera (`None`
    /// matches a view of the framing camera): its count on the image, the distinct and non-degenerate shares
    /// taken from the face sums along its forward direction. Otherwise the crossings along its forward direction
    /// times the share of its rays that meet the box (parallel rays: a close camera's perspective is not seen).
    pub(crate) fn per_ray(&self, camera: Option<&Camera>, lo: [f32; 3], hi: [f32; 3]) -> RayCrossings {
        let cam = &camera_or_framing(camera, lo, hi);
        let w = cam.forward.abs().as_dvec3().to_array();
        let along = ratio(self.faces, self.scene, w);
        let share = |f: [f64; 3]| if along > 0.0 { ratio(f, self.scene, w) / along } else { 0.0 };
        let counted = self.counted(camera);
        let all = match counted {
            Some(v) => v.all,
            None => along * ViewFeatures::of(cam, lo, hi).coverage,
        };
        RayCrossings {
            all,
            distinct: all * share(self.distinct_faces),
            nondegenerate: all * share(self.nondegenerate_faces),
            near: counted.and_then(|v| v.near).map(|n| n.entered.lower_bound()),
            image: 0.0,
            leave_flat_scene: false,
            leave_share: 0.0,
            probes: counted.map_or([None; super::probe::PROBES], |v| v.probes.map(|p| p.map(|p| p.primary))),
            probe_work: self.probe_work(camera),
        }
    }

    /// The work of each probed structure's build ([`RayCrossings::probe_work`]) when the view of `camera` was
    /// probed; zeros otherwise.
    fn probe_work(&self, camera: Option<&Camera>) -> [f64; super::probe::PROBES] {
        self.counted(camera).map_or([0.0; super::probe::PROBES], |v| v.probes.map(|p| p.map_or(0.0, |p| p.build_work)))
    }
}

impl RayCrossings {
    /// The work of `structure`'s build in its probe ([`RayCrossings::probe_work`]), when it was probed and built
    /// something; 0 otherwise.
    pub fn build_work(&self, structure: StructureName) -> f64 {
        let i = super::PROBED.iter().position(|s| *s == structure);
        i.map_or(0.0, |i| self.probe_work[i])
    }

    /// The counts of `structure` on the camera's sample ([`RayCrossings::probes`]), when probed on at least
    /// [`super::probe::MIN_PROBED_RAYS`] rays (a sparse view's few hits start few secondary rays, and a mean of one
    /// or two has no standard error worth the name).
    pub fn probe(&self, structure: StructureName) -> Option<super::ProbeCounts> {
        let i = super::PROBED.iter().position(|s| *s == structure)?;
        self.probes[i].filter(|p| p.box_tests.rays >= super::probe::MIN_PROBED_RAYS)
    }
}

/// A share of rays as given by a caller ([`RayCrossings::leave_share`], [`TestFloor::leave_share`], both public
/// fields): clamped to `[0, 1]`, 0 when not finite.
pub(crate) fn unit_share(x: f64) -> f64 {
    if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// `camera`, or the framing camera of the box `lo`..`hi` ([`super::view::framing_camera`]) when `None`.
fn camera_or_framing(camera: Option<&Camera>, lo: [f32; 3], hi: [f32; 3]) -> Camera {
    camera.copied().unwrap_or_else(|| super::view::framing_camera(lo, hi))
}

/// Whether every secondary ray of the workload `kind` leaves a flat scene without crossing it again: the box
/// `lo`..`hi` has no extent along an axis (every triangle lies in one axis-aligned plane) and the camera (`None`: the
/// framing camera of the box) is off that plane. A secondary ray starts at a primary hit, moved off the surface
/// towards the camera's side (the shadow and diffuse workloads of `trace::workload`); a diffuse ray leaves about
/// that facing normal, so it never meets the plane again, and a shadow ray does not when the workload's light
/// ([`crate::geom::camera::default_light`]) is on the camera's side too. Such a ray crosses no triangle box:
/// every hierarchy tests its root box once and no triangle (measured on the flat degenerate generators, `flat`,
/// `all-equal`, `fan` and `lattice`, in `docs/data/degenerate-{shadow,diffuse}.jsonl`). The isotropic count
/// ([`Crossings::isotropic`]) would have it cross every box stacked at a point of the plane: 2,000 on 2,000
/// coincident triangles. False for primary rays, a box of extent along every axis, an empty or non-finite box,
/// or a camera in the plane.
pub(crate) fn secondary_rays_leave_the_plane(
    kind: WorkloadKind,
    camera: Option<&Camera>,
    lo: [f32; 3],
    hi: [f32; 3],
) -> bool {
    if kind == WorkloadKind::Primary || !(0..3).all(|a| lo[a].is_finite() && hi[a].is_finite() && lo[a] <= hi[a]) {
        return false;
    }
    let Some(axis) = (0..3).find(|&a| lo[a] == hi[a]) else { return false };
    let cam = camera_or_framing(camera, lo, hi);
    let plane = lo[axis];
    let eye_side = cam.eye[axis] - plane;
    if !(eye_side != 0.0 && eye_side.is_finite()) {
        return false;
    }
    match kind {
        WorkloadKind::Diffuse => true,
        _ => {
            let b = Aabb { min: Vec3::from_array(lo), max: Vec3::from_array(hi) };
            let light = crate::geom::camera::default_light(&b);
            (light[axis] - plane) * eye_side > 0.0
        }
    }
}

/// The mean number of triangle boxes covering a point of `camera`'s square image: per box, the share of the image
/// its screen rectangle covers (the rectangle of its corners' projections, clipped at a near plane a millionth of
/// the boxes' extent in front of the eye and to the image), 1 for a box holding the eye, summed. What a primary ray
/// crosses on average, perspective included: a close camera looking into dense geometry sees far more than the
/// parallel estimate of `Crossings::per_ray` without a view (the engineering family close up: 2,163 against 150).
/// One pass over the boxes, in parallel chunks summed in order (deterministic): 4.9 ms for 200,000 boxes and 24 ms
/// for the dragon's 871,414 on the 2-core VM (two threads, warm; `cargo bench --bench accel -- screen_crossings`,
/// 2026-12-05).
/// Non-finite projections count nothing.
pub fn screen_crossings(boxes: &[Aabb], camera: &Camera) -> f64 {
    use rayon::prelude::*;
    let near = near_plane(&boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b)));
    let parts: Vec<f64> =
        boxes.par_chunks(4096).map(|c| c.iter().map(|b| screen_share(b, camera, near)).sum::<f64>()).collect();
    parts.iter().sum()
}

/// The share of `camera`'s image covered by the screen rectangle of `b` (see [`screen_crossings`]).
fn screen_share(b: &Aabb, camera: &Camera, near: f32) -> f64 {
    match screen_rect(b, camera, near) {
        Some((lo, hi)) => {
            let size = hi - lo;
            let share = f64::from(size.x) * f64::from(size.y) / 4.0;
            if share.is_finite() {
                share
            } else {
                0.0
            }
        }
        None => 0.0,
    }
}

/// The screen rectangle of `b` on `camera`'s square image, `(lo, hi)` in `[-1, 1]^2` (x to the right, y up): the
/// rectangle of its corners' projections, clipped at the plane `near` in front of the eye and to the image; the
/// whole image for a box holding the eye; `None` when it covers nothing or a projection is not finite.
fn screen_rect(b: &Aabb, camera: &Camera, near: f32) -> Option<(glam::Vec2, glam::Vec2)> {
    if b.min.cmple(camera.eye).all() && b.max.cmpge(camera.eye).all() {
        return Some((-glam::Vec2::ONE, glam::Vec2::ONE));
    }
    let corner = |k: usize| {
        Vec3::new(
            if k & 1 == 0 { b.min.x } else { b.max.x },
            if k & 2 == 0 { b.min.y } else { b.max.y },
            if k & 4 == 0 { b.min.z } else { b.max.z },
        ) - camera.eye
    };
    let (mut lo, mut hi) = (glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY));
    let mut add = |v: Vec3| {
        let z = v.dot(camera.forward).max(near) * camera.tan_half_fov;
        let p = glam::Vec2::new(v.dot(camera.right) / z, v.dot(camera.up) / z);
        lo = lo.min(p);
        hi = hi.max(p);
    };
    for k in 0..8 {
        let v = corner(k);
        let z = v.dot(camera.forward);
        if z >= near {
            add(v);
        }
        // The edges from this corner towards larger coordinates, cut by the near plane.
        for bit in [1, 2, 4] {
            if k & bit == 0 {
                let u = corner(k | bit);
                let zu = u.dot(camera.forward);
                if (z < near) != (zu < near) {
                    add(v + (u - v) * ((near - z) / (zu - z)));
                }
            }
        }
    }
    let (lo, hi) = (lo.max(-glam::Vec2::ONE), hi.min(glam::Vec2::ONE));
    if lo.is_finite() && hi.is_finite() && lo.cmplt(hi).all() {
        Some((lo, hi))
    } else {
        None
    }
}

/// The near plane [`screen_crossings`] and [`near_crossings`] clip at: a millionth of the extent of `scene` (or of
/// their distance from the origin, if larger) in front of the eye.
fn near_plane(scene: &Aabb) -> f32 {
    let extent = (scene.max - scene.min).max_element().max((scene.max.abs().max(scene.min.abs())).max_element());
    if extent.is_finite() && extent > 0.0 {
        extent * 1e-6
    } else {
        1e-6
    }
}

/// The side of the square sample of primary rays [`near_crossings`] traces at most (1,024 rays).
pub const NEAR_SAMPLES: u32 = 32;

/// The box-ray pairs each of the two passes of [`near_crossings`] over its primary sample examines at most, about:
/// the sample shrinks (to 8 x 8 at least) where the image count times the sample's rays would exceed it. The shadow
/// passes are not bounded by it: each box visits the shadow rays in the bins it covers.
const NEAR_WORK: f64 = 16.0 * 1024.0 * 1024.0;

/// The side of the square sample of primary rays of [`near_crossings`] (and [`super::probe()`]) for a camera whose
/// image count ([`screen_crossings`]) is `image`: `NEAR_SAMPLES`, less (8 at least) where `image` times the
/// sample's rays would exceed about 16 million box-ray pairs.
pub fn near_sample_side(image: f64) -> u32 {
    let mut side = NEAR_SAMPLES;
    if image.is_finite() && image * f64::from(side * side) > NEAR_WORK {
        side = ((NEAR_WORK / image).sqrt() as u32).clamp(8, NEAR_SAMPLES);
    }
    side
}

/// The mean number of triangle boxes a primary ray of `camera` enters no later than its first hit (or at all, for
/// a ray that hits nothing), over a square sample of its rays: the rays through the pixel centres of a
/// `NEAR_SAMPLES`-square image (fewer where `image`, the count of [`screen_crossings`], times their number would
/// exceed about 16 million box-ray pairs), `boxes[i]` the box of `tris[i]`. Two passes over the triangles, each
/// visiting only the sample rays inside the triangle box's screen rectangle (the rectangle of
/// [`screen_crossings`]): the first finds each ray's closest hit, the second counts the boxes each ray enters no
/// later than it (up to where a closest-hit traversal still visits nodes: `geom::cull_bound` of the hit) and the
/// boxes holding the origin of the secondary ray each hit starts; then the shadow rays from those origins, sorted by
/// direction into the faces of a cube around the light, are tested for occlusion and their crossings counted the
/// same way, in two more passes ([`NearCrossings`]). Each count is kept per ray, as a mean with its standard
/// error ([`SampledMean`]); the floors take the mean less two standard errors (`SampledMean::lower_bound`).
/// Counted only on the triangles' boxes as screen rectangles: a box of no area on the image (seen edge-on) and a
/// box that holds a secondary ray's origin without covering its pixel's centre (within the surface offset of its
/// edge) are missed, which errs on the low side.
///
/// Why it matters: a hierarchy whose every node bounds whole triangles (the binned-SAH BVH, the LBVH, the HLBVH and
/// the BIH) visits, in front-to-back closest-hit traversal, every leaf whose box the ray enters before the closest
/// hit found so far, so it tests at least every triangle whose own box the ray enters before its first hit: this
/// count, per ray, is a lower bound on their triangle tests (`overlap_floor`). The image count of
/// [`screen_crossings`] also counts the boxes behind the first hit, which the traversal never reaches. A kd-tree
/// and a grid store a triangle only in the cells it overlaps, not in every cell its box does, so the bound does not
/// hold for them (long thin triangles across a grid's cells: the engineering family).
///
/// The same argument holds for a diffuse ray (closest hit) and the boxes holding its origin, which it enters at
/// once ([`NearCrossings::holding_origin`]), and for a shadow ray that nothing occludes (an any-hit query that
/// finds nothing visits every node its segment crosses; [`NearCrossings::unoccluded_shadow`]): the four structures'
/// floors for diffuse and shadow rays.
///
/// Deterministic: the closest hits are minima (the lower triangle index on equal distances) and the counts
/// integers. All zero for no triangle.
pub fn near_crossings(boxes: &[Aabb], tris: &[crate::geom::Triangle], camera: &Camera, image: f64) -> NearCrossings {
    use crate::geom::ray::RayInv;
    use rayon::prelude::*;
    let n = boxes.len().min(tris.len());
    if n == 0 {
        return NearCrossings::default();
    }
    let side = near_sample_side(image);
    let s = side as usize;
    let rays: Vec<RayInv> =
        (0..side * side).map(|k| RayInv::new(&camera.ray(k % side, k / side, side, side))).collect();
    let scene = boxes[..n].iter().fold(Aabb::EMPTY, |a, b| a.union(b));
    let near = near_plane(&scene);
    let sf = side as f32;
    // The sample rays whose pixel centres lie in a box's screen rectangle (widened by a thousandth of a sample
    // against the rounding of the projections; the tests below are exact): columns x0..x1, rows y0..y1. Computed
    // once per box, for both passes; most boxes of a large mesh hold no sample centre.
    let at = |p: f32| (p * sf - 0.5 - 1e-3).ceil().max(0.0) as usize;
    let to = |p: f32| ((p * sf - 0.5 + 1e-3).floor() + 1.0).clamp(0.0, sf) as usize;
    let ranges: Vec<Option<[u16; 4]>> = boxes[..n]
        .par_iter()
        .map(|b| {
            let (lo, hi) = screen_rect(b, camera, near)?;
            // Column x has its centre at (x + 0.5) / side * 2 - 1; row y at 1 - (y + 0.5) / side * 2.
            let (cx0, cx1) = (at((lo.x + 1.0) * 0.5), to((hi.x + 1.0) * 0.5));
            let (ry0, ry1) = (at((1.0 - hi.y) * 0.5), to((1.0 - lo.y) * 0.5));
            (cx0 < cx1 && ry0 < ry1).then_some([cx0 as u16, cx1 as u16, ry0 as u16, ry1 as u16])
        })
        .collect();
    const CHUNK: usize = 4096;
    // Per sample ray, its closest hit: distance and triangle (the lower index on equal distances, whatever the
    // chunking).
    let closest = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut d = vec![(f32::INFINITY, u32::MAX); s * s];
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let Some([x0, x1, y0, y1]) = ranges[i] else { continue };
                for y in y0 as usize..y1 as usize {
                    for x in x0 as usize..x1 as usize {
                        let k = y * s + x;
                        let r = &rays[k];
                        if let Some((t, _, _)) = crate::geom::intersect_triangle(&tris[i], r.o, r.d, 0.0, d[k].0) {
                            d[k] = (t, i as u32);
                        }
                    }
                }
            }
            d
        })
        .reduce(
            || vec![(f32::INFINITY, u32::MAX); s * s],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| {
                    if y.0 < x.0 || (y.0 == x.0 && y.1 < x.1) {
                        *x = y;
                    }
                });
                a
            },
        );
    // Counted up to where a traversal still visits nodes once the closest hit is found: the hit's distance enlarged
    // as the slab test enlarges exits, plus the tie margin (`geom::cull_bound`), so that a box the ray enters at
    // its hit point counts whatever the rounding.
    let bound: Vec<f32> = rays
        .iter()
        .zip(&closest)
        .map(|(r, &(t, _))| crate::geom::cull_bound(t, crate::geom::tie_margin(r.o, r.d, &scene)))
        .collect();
    // The origin of the secondary ray each hit starts, as the shadow and diffuse workloads place it.
    let origins: Vec<Option<Vec3>> = rays
        .iter()
        .zip(&closest)
        .map(|(r, &(t, i))| {
            let tri = tris.get(i as usize)?;
            crate::geom::camera::secondary_start(tri, r.o + r.d * t, r.d, &scene).map(|(o, _)| o)
        })
        .collect();
    // Per sample ray: the boxes it enters, and those holding its hit's secondary origin.
    let (entered, holding) = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (mut entered, mut holding) = (vec![0u32; s * s], vec![0u32; s * s]);
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let Some([x0, x1, y0, y1]) = ranges[i] else { continue };
                let b = &boxes[i];
                let (lo, hi) = (b.min.to_array(), b.max.to_array());
                for y in y0 as usize..y1 as usize {
                    for x in x0 as usize..x1 as usize {
                        let k = y * s + x;
                        entered[k] += rays[k].slab(&lo, &hi, 0.0, bound[k]).is_some() as u32;
                        if let Some(o) = origins[k] {
                            holding[k] += (b.min.cmple(o).all() && b.max.cmpge(o).all()) as u32;
                        }
                    }
                }
            }
            (entered, holding)
        })
        .reduce(|| (vec![0u32; s * s], vec![0u32; s * s]), |a, b| (add_counts(a.0, &b.0), add_counts(a.1, &b.1)));
    let hits = origins.iter().filter(|o| o.is_some()).count();
    let light = crate::geom::camera::default_light(&scene);
    let unoccluded = shadow_crossings(&boxes[..n], &tris[..n], &origins, light, near);
    let holding: Vec<u32> = holding.iter().zip(&origins).filter(|(_, o)| o.is_some()).map(|(h, _)| *h).collect();
    NearCrossings {
        entered: SampledMean::of(&entered),
        holding_origin: SampledMean::of(&holding),
        hit_share: hits as f64 / (s * s) as f64,
        unoccluded_shadow: SampledMean::of(&unoccluded),
    }
}

/// `a + b`, element by element (saturating).
fn add_counts(mut a: Vec<u32>, b: &[u32]) -> Vec<u32> {
    a.iter_mut().zip(b).for_each(|(x, y)| *x = x.saturating_add(*y));
    a
}

/// A per-ray count averaged over a sample of rays: its mean and the standard error of that mean.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct SampledMean {
    /// The mean over the sample (0 for no ray).
    pub mean: f64,
    /// The standard error of the mean: the sample's standard deviation over the square root of its size (0 for
    /// fewer than two rays).
    pub standard_error: f64,
    /// The rays sampled.
    pub rays: usize,
}

impl SampledMean {
    /// The mean and standard error of `counts`.
    pub fn of(counts: &[u32]) -> SampledMean {
        let n = counts.len();
        if n == 0 {
            return SampledMean::default();
        }
        let mean = counts.iter().map(|&c| f64::from(c)).sum::<f64>() / n as f64;
        let var = if n > 1 {
            counts.iter().map(|&c| (f64::from(c) - mean).powi(2)).sum::<f64>() / (n - 1) as f64
        } else {
            0.0
        };
        SampledMean { mean, standard_error: (var / n as f64).sqrt(), rays: n }
    }

    /// What the floor takes ([`overlap_floor`]): the mean less twice its standard error, at least 0. The count is a
    /// lower bound per ray, but its sampled mean can exceed the mean over a workload's every ray by its sampling
    /// error; two standard errors below it, it does so for about 1 in 40 samples.
    pub(crate) fn lower_bound(&self) -> f64 {
        (self.mean - 2.0 * self.standard_error).max(0.0)
    }

    /// The mean plus twice its standard error: with [`SampledMean::lower_bound`], the band that holds the mean over
    /// every ray of the workload for about 19 samples in 20 ([`overlap_floor`] holds a probed structure's predicted
    /// counts in it, [`super::probe()`]).
    pub(crate) fn upper_bound(&self) -> f64 {
        (self.mean + 2.0 * self.standard_error).max(self.lower_bound())
    }
}

/// Bins per side of the grid over the rays' span on each face of the cube around the light that
/// [`shadow_crossings`] sorts its rays into.
const SHADOW_BINS: usize = 32;

/// For the shadow rays from `origins` to `light` (as the shadow workload makes them: `tmax` just short of the
/// light), per ray, the boxes it crosses if no triangle occludes it (0 if one does). The rays all meet at the
/// light, so each is sorted by its direction from the light into a bin of one face of a cube around it, and each
/// box visits only the bins its screen rectangle on a face covers (a camera at the light with a 90-degree view per
/// face): first the triangles, to find the occluded rays, then the boxes, to count the crossings of the others.
fn shadow_crossings(
    boxes: &[Aabb],
    tris: &[crate::geom::Triangle],
    origins: &[Option<Vec3>],
    light: Vec3,
    near: f32,
) -> Vec<u32> {
    use crate::geom::ray::RayInv;
    use rayon::prelude::*;
    let axes = [Vec3::X, Vec3::Y, Vec3::Z];
    // Face f looks along +axis (f even) or -axis (f odd) of axis f / 2.
    let faces: Vec<Camera> = (0..6)
        .map(|f| {
            let forward = if f % 2 == 0 { axes[f / 2] } else { -axes[f / 2] };
            let up = if f / 2 == 1 { Vec3::Z } else { Vec3::Y };
            Camera { eye: light, forward, right: forward.cross(up), up, tan_half_fov: 1.0 }
        })
        .collect();
    // Each ray's direction seen from the light: the face of its largest component, and its place there.
    let mut rays: Vec<(RayInv, f32)> = Vec::new();
    let mut placed: Vec<(usize, glam::Vec2)> = Vec::new();
    for o in origins.iter().flatten() {
        let Some(ray) = crate::geom::camera::shadow_ray(*o, light) else { continue };
        let tmax = ray.tmax;
        let u = *o - light;
        let a = (0..3).max_by(|&i, &j| u[i].abs().total_cmp(&u[j].abs())).unwrap_or(0);
        let f = 2 * a + (u[a] < 0.0) as usize;
        let cam = &faces[f];
        let z = u.dot(cam.forward);
        if z.is_nan() || z <= 0.0 {
            continue;
        }
        placed.push((f, glam::Vec2::new(u.dot(cam.right) / z, u.dot(cam.up) / z)));
        rays.push((RayInv::new(&ray), tmax));
    }
    // Per face, a grid of SHADOW_BINS x SHADOW_BINS bins over the rectangle its rays' places span.
    let g = SHADOW_BINS;
    let mut span = [(glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY)); 6];
    for &(f, p) in &placed {
        span[f] = (span[f].0.min(p), span[f].1.max(p));
    }
    let used: Vec<usize> = (0..6).filter(|&f| span[f].0.x <= span[f].1.x).collect();
    let bin_of = |f: usize, p: glam::Vec2| -> (usize, usize) {
        let (lo, hi) = span[f];
        let cell = |x: f32, l: f32, h: f32| {
            let w = h - l;
            if w > 0.0 {
                (((x - l) / w * g as f32).floor().max(0.0) as usize).min(g - 1)
            } else {
                0
            }
        };
        (cell(p.x, lo.x, hi.x), cell(p.y, lo.y, hi.y))
    };
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); 6 * g * g];
    for (k, &(f, p)) in placed.iter().enumerate() {
        let (x, y) = bin_of(f, p);
        bins[(f * g + y) * g + x].push(k as u32);
    }
    // Per box and used face, the bins its rectangle covers (widened by a hundred-thousandth against the rounding of
    // the projections; the tests are exact), none where it misses the rays' span.
    let cover = |b: &Aabb, f: usize| -> Option<[u8; 4]> {
        let (lo, hi) = screen_rect(b, &faces[f], near)?;
        let (lo, hi) = (lo - glam::Vec2::splat(1e-5), hi + glam::Vec2::splat(1e-5));
        let (slo, shi) = span[f];
        if hi.x < slo.x || hi.y < slo.y || lo.x > shi.x || lo.y > shi.y {
            return None;
        }
        let ((x0, y0), (x1, y1)) = (bin_of(f, lo.max(slo)), bin_of(f, hi.min(shi)));
        // Bins per side fit a byte (SHADOW_BINS <= 255).
        Some([x0 as u8, (x1 + 1) as u8, y0 as u8, (y1 + 1) as u8])
    };
    // Computed once per box and used face, for both passes.
    let covers: Vec<Option<[u8; 4]>> =
        boxes.par_iter().flat_map_iter(|b| used.iter().map(move |&f| cover(b, f))).collect();
    let visit = |i: usize, each: &mut dyn FnMut(usize)| {
        for (j, &f) in used.iter().enumerate() {
            let Some([x0, x1, y0, y1]) = covers[i * used.len() + j] else { continue };
            for y in y0 as usize..y1 as usize {
                for x in x0 as usize..x1 as usize {
                    for &k in &bins[(f * g + y) * g + x] {
                        each(k as usize);
                    }
                }
            }
        }
    };
    const CHUNK: usize = 4096;
    let m = rays.len();
    let n = boxes.len().min(tris.len());
    let occluded = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut o = vec![false; m];
            let (start, end) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            for (i, tri) in (start..end).zip(&tris[start..end]) {
                visit(i, &mut |k| {
                    let (r, tmax) = &rays[k];
                    if !o[k] && crate::geom::intersect_triangle(tri, r.o, r.d, 0.0, *tmax).is_some() {
                        o[k] = true;
                    }
                });
            }
            o
        })
        .reduce(
            || vec![false; m],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x |= y);
                a
            },
        );
    (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut count = vec![0u32; m];
            let (start, end) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            for (i, b) in (start..end).zip(&boxes[start..end]) {
                let (lo, hi) = (b.min.to_array(), b.max.to_array());
                visit(i, &mut |k| {
                    let (r, tmax) = &rays[k];
                    count[k] += (!occluded[k] && r.slab(&lo, &hi, 0.0, *tmax).is_some()) as u32;
                });
            }
            count
        })
        .reduce(|| vec![0u32; m], |a, b| add_counts(a, &b))
}

/// What [`near_crossings`] counts on its sample of a camera's primary rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct NearCrossings {
    /// The triangle boxes a ray enters no later than its first hit (every box it enters, for a ray that hits
    /// nothing), over the sample rays.
    pub entered: SampledMean,
    /// Over the rays that hit, the triangle boxes holding the origin of the secondary ray the hit starts (off the
    /// surface along the normal facing the ray: `geom::camera::surface_offset`). A diffuse ray enters each such box
    /// at once, so a closest-hit traversal of a hierarchy whose nodes bound whole triangles tests each of their
    /// triangles.
    pub holding_origin: SampledMean,
    /// The share of the sample rays that hit.
    pub hit_share: f64,
    /// Over the shadow rays those hits start (to the shadow workload's light, `geom::camera::default_light`), the
    /// triangle boxes a ray crosses when no triangle occludes it (0 for an occluded ray). An any-hit query that
    /// finds nothing visits every node its segment crosses, so a hierarchy whose nodes bound whole triangles tests
    /// every such triangle.
    pub unoccluded_shadow: SampledMean,
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

/// The least tests per crossed triangle box of each structure and kind of ray, read off the calibration's records
/// by `calibrate` (the lower envelope of the measured ratio, rounded down to two significant digits): the overlap
/// floor's factors (`overlap_floor`). Per crossing ([`RayCrossings`]: counted on the camera's image for primary
/// rays, over every direction for shadow and diffuse rays), over the records whose rays cross at least
/// [`CountBounds::FROM`] boxes; per crossing of the camera's primary rays counted on its image
/// ([`RayCrossings::image`]), for shadow and diffuse rays, over the records whose image count is at least that.
/// By the structures' definitions some factors are 0 whatever the records say: the kd-tree floors no box tests (one
/// that cannot split overlapping triangles visits one node), the grid no box tests (its cells, not the triangles'
/// boxes, bound the cells a ray visits) and, for shadow and diffuse rays, no triangle tests. `kd_tree_prim_floor`:
/// the kd-tree's triangle tests are at least this share of the fewest the probed object hierarchies make on the
/// same rays, the least measured ratio over the records without zero-area triangles whose fewest count is at
/// least 0.5 (a kd-tree leaf holds every triangle that overlaps it, and a ray tests a triangle again in each leaf).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CountBounds {
    /// One per structure with a floor.
    pub structures: Vec<StructureCountBounds>,
    /// The kd-tree's triangle tests over the probed hierarchies' fewest (0: no such floor).
    pub kd_tree_prim_floor: f64,
}

/// One structure's [`CountBounds`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StructureCountBounds {
    /// The structure.
    pub structure: StructureName,
    /// `[box, triangle]` tests per crossing, for primary, shadow and diffuse rays.
    pub per_crossing: [[f64; 2]; 3],
    /// `[box, triangle]` tests per crossing counted on the image, for shadow and diffuse rays.
    pub per_image_crossing: [[f64; 2]; 2],
}

impl CountBounds {
    /// The crossings (and image crossings) from which a record's ratio enters the envelope: 4.
    pub const FROM: f64 = 4.0;

    fn of(&self, structure: StructureName) -> Option<&StructureCountBounds> {
        self.structures.iter().find(|s| s.structure == structure)
    }

    /// Least `(box, triangle)` tests per crossed box of `structure` for rays of `kind`; `(0, 0)` without a floor.
    pub(crate) fn tests_per_crossing(&self, structure: StructureName, kind: WorkloadKind) -> (f64, f64) {
        self.of(structure).map_or((0.0, 0.0), |s| {
            let [b, p] = s.per_crossing[super::timed::kind_index(kind)];
            (b, p)
        })
    }

    /// Least `(box, triangle)` tests per secondary ray per box crossed by the camera's primary rays on its image;
    /// `(0, 0)` for primary rays and without a floor.
    pub(crate) fn tests_per_image_crossing(&self, structure: StructureName, kind: WorkloadKind) -> (f64, f64) {
        match (kind, self.of(structure)) {
            (WorkloadKind::Primary, _) | (_, None) => (0.0, 0.0),
            (k, Some(s)) => {
                let [b, p] = s.per_image_crossing[super::timed::kind_index(k) - 1];
                (b, p)
            }
        }
    }

    /// Checks that every factor is finite and `>= 0`, each structure appears once, and the definitions' zeros hold.
    pub fn validate(&self) -> Result<(), String> {
        let ok = |x: f64| x.is_finite() && x >= 0.0;
        if !ok(self.kd_tree_prim_floor) {
            return Err(format!("kd_tree_prim_floor {} is not a finite number >= 0", self.kd_tree_prim_floor));
        }
        for (i, s) in self.structures.iter().enumerate() {
            if self.structures[..i].iter().any(|o| o.structure == s.structure) {
                return Err(format!("{} appears twice", s.structure));
            }
            let all = s.per_crossing.iter().chain(&s.per_image_crossing).flatten();
            if let Some(x) = all.copied().find(|x| !ok(*x)) {
                return Err(format!("{}: factor {x} is not a finite number >= 0", s.structure));
            }
        }
        Ok(())
    }
}

/// The BIH's largest leaf under its default build options (`accel::bih::BihOptions`, built with the `eval` feature;
/// a test checks that the two agree), for the floor of [`overlap_floor`] in the engine core too.
pub const BIH_MAX_LEAF: usize = 4;

/// The largest leaf of a structure whose every node bounds whole triangles (its default build options), for the
/// floor of [`near_crossings`]; `None` for the others (kd-tree, grid), which store a triangle only in the cells it
/// overlaps.
fn near_leaf(structure: StructureName) -> Option<f64> {
    match structure {
        StructureName::Bvh => Some(crate::accel::bvh::BvhOptions::default().max_leaf as f64),
        StructureName::Lbvh => Some(crate::accel::lbvh::LbvhOptions::default().max_leaf as f64),
        StructureName::Hlbvh => Some(crate::accel::hlbvh::HlbvhOptions::default().max_leaf as f64),
        StructureName::Bih => Some(BIH_MAX_LEAF as f64),
        _ => None,
    }
    .map(|l| l.max(1.0))
}

/// Lower (and, where the geometry fixes them, upper) bounds on a structure's tests per ray, for
/// [`crate::cost::StructureModel::predict_floored`], and the crossings they come from. The default bounds nothing
/// and knows no crossings (`crossings` NaN; two unknown counts are equal).
#[derive(Clone, Copy, Debug)]
pub(crate) struct TestFloor {
    /// Box tests (node visits) per ray: at least this many.
    pub box_tests: f64,
    /// Triangle tests per ray: at least this many.
    pub prim_tests: f64,
    /// Box tests per ray: at most this many (infinite unless the geometry fixes the count: secondary rays that
    /// leave a flat scene, [`RayCrossings::leave_flat_scene`]).
    pub box_tests_most: f64,
    /// Triangle tests per ray: at most this many (infinite unless the geometry fixes the count).
    pub prim_tests_most: f64,
    /// The share of the rays that leave the scene at once ([`RayCrossings::leave_share`]): each makes one box
    /// test and no triangle test, the others the bounded counts above.
    pub leave_share: f64,
    /// The triangle boxes a ray of the workload crosses ([`crossings_feature`]), which a model fitted with crossings
    /// reads ([`crate::cost::StructureModel::crossing_coef`]); NaN when the caller has no count (no mesh at hand:
    /// such a model then reads its training records' mean, [`crate::cost::StructureModel::crossing_mean`]).
    pub crossings: f64,
    /// The structure's own tests per ray of the workload counted on a sample of its rays ([`super::probe()`]): where
    /// a law's count (with the bounds above) lies outside its own error band about the sampled mean
    /// ([`super::CostModel::own_probe_band`] times the fit's RMS error of `ln(1 + count)`: none for a calibration
    /// traced on the CPU), the prediction holds it within two standard errors of that mean instead
    /// ([`crate::cost::StructureModel::predict_floored`]).
    pub sampled: Option<super::ProbeCounts>,
    /// The work of the structure's build where a probe built it ([`RayCrossings::build_work`]; 0 when unknown):
    /// a model with a work law predicts the build from it ([`crate::cost::StructureModel::build_work_coef`]).
    pub build_work: f64,
}

impl Default for TestFloor {
    fn default() -> Self {
        TestFloor {
            box_tests: 0.0,
            prim_tests: 0.0,
            box_tests_most: f64::INFINITY,
            prim_tests_most: f64::INFINITY,
            leave_share: 0.0,
            crossings: f64::NAN,
            sampled: None,
            build_work: 0.0,
        }
    }
}

impl PartialEq for TestFloor {
    fn eq(&self, o: &Self) -> bool {
        let same_count = self.crossings == o.crossings || (self.crossings.is_nan() && o.crossings.is_nan());
        self.box_tests == o.box_tests
            && self.prim_tests == o.prim_tests
            && self.box_tests_most == o.box_tests_most
            && self.prim_tests_most == o.prim_tests_most
            && self.leave_share == o.leave_share
            && self.sampled == o.sampled
            && self.build_work == o.build_work
            && same_count
    }
}

/// The crossings a model fitted with crossings reads for a workload: for primary rays the count of
/// [`RayCrossings::all`] (on the camera's image when counted there), for shadow and diffuse rays the larger of it
/// (over every direction) and [`RayCrossings::image`]; 0 without crossings. The same for every structure.
pub fn crossings_feature(kind: WorkloadKind, c: Option<RayCrossings>) -> f64 {
    match c {
        None => 0.0,
        Some(c) if kind == WorkloadKind::Primary => c.all.max(0.0),
        Some(c) => c.all.max(c.image).max(0.0),
    }
}

/// The overlap floor of `structure`'s tests per ray of the workload `kind` whose [`RayCrossings`] are at hand
/// ([`Crossings::for_workload`]): its factors of [`StructureCountBounds::per_crossing`] times the crossings (the distinct
/// triangles' for the binned-SAH BVH, which keeps one of coincident copies; those of non-zero area for the kd-tree,
/// which stores zero-area triangles as points; all of them for the others); for secondary rays with
/// [`RayCrossings::image`], the larger of that and the factors of [`StructureCountBounds::per_image_crossing`] times the
/// image's count (scaled by the same share of distinct or non-degenerate triangles). Without crossings, no floor and
/// no count ([`TestFloor::default`]). Secondary rays that leave a flat scene ([`RayCrossings::leave_flat_scene`])
/// cross 0 boxes, and every hierarchy (BVH, kd-tree, BIH, LBVH, HLBVH) makes exactly one box test and no triangle
/// test per ray; the grid, which still steps through the cells at the ray's origin, is left to its laws. With
/// [`RayCrossings::near`] (the boxes a ray enters before its first hit, holding a diffuse ray's origin, or crossed
/// by an unoccluded shadow ray; [`near_crossings`]), the BVH's, LBVH's, HLBVH's and BIH's triangle tests are at least
/// that count (the BVH's scaled by its distinct share) and their box tests at least it over their largest leaf.
/// With [`RayCrossings::probes`], a probed structure's floor carries its counts sampled on rays of this kind
/// ([`TestFloor::sampled`]).
pub(crate) fn overlap_floor(
    bounds: &CountBounds,
    structure: StructureName,
    kind: WorkloadKind,
    c: Option<RayCrossings>,
) -> TestFloor {
    priced_floor(bounds, structure, kind, c, 0.0)
}

/// [`overlap_floor`] with the grid's build work given: `grid_work` (`> 0`) is the grid's references counted exactly
/// from the mesh (`select::BuildBounds::grid_build_work`), which prices its build by the work law
/// ([`super::StructureModel::build_work_coef`]) in place of the probe's work or the law in `n`; 0 leaves the floor
/// as [`overlap_floor`] gives it.
pub(crate) fn priced_floor(
    bounds: &CountBounds,
    structure: StructureName,
    kind: WorkloadKind,
    c: Option<RayCrossings>,
    grid_work: f64,
) -> TestFloor {
    let mut f = floor_of(bounds, structure, kind, c);
    if structure == StructureName::Grid && grid_work > 0.0 {
        f.build_work = grid_work;
    }
    f
}

fn floor_of(bounds: &CountBounds, structure: StructureName, kind: WorkloadKind, c: Option<RayCrossings>) -> TestFloor {
    let Some(c) = c else { return TestFloor::default() };
    let crossings = crossings_feature(kind, Some(c));
    let hierarchy = matches!(
        structure,
        StructureName::Bvh | StructureName::KdTree | StructureName::Bih | StructureName::Lbvh | StructureName::Hlbvh
    );
    if c.leave_flat_scene && kind != WorkloadKind::Primary && hierarchy {
        return TestFloor {
            box_tests: 1.0,
            prim_tests: 0.0,
            box_tests_most: 1.0,
            prim_tests_most: 0.0,
            crossings,
            build_work: c.build_work(structure),
            ..TestFloor::default()
        };
    }
    let x = match structure {
        StructureName::Bvh => c.distinct,
        StructureName::KdTree => c.nondegenerate,
        _ => c.all,
    };
    let (b, p) = bounds.tests_per_crossing(structure, kind);
    let leave_share = if kind == WorkloadKind::Primary { 0.0 } else { unit_share(c.leave_share) };
    let mut f = TestFloor { box_tests: b * x, prim_tests: p * x, crossings, leave_share, ..TestFloor::default() };
    if let (Some(near), Some(leaf)) = (c.near, near_leaf(structure)) {
        // Every triangle whose box a closest-hit ray enters before its first hit is tested, and every triangle whose
        // box an unoccluded any-hit ray crosses ([`near_crossings`]: for primary rays the boxes entered, for diffuse
        // rays those holding the origin, for shadow rays those the unoccluded ones cross); the binned-SAH BVH keeps
        // one of coincident copies, so its count is scaled by the distinct share. Each such triangle's leaf box is
        // tested too, and a leaf holds at most `leaf` triangles.
        let near = if structure == StructureName::Bvh && c.all > 0.0 { near * c.distinct / c.all } else { near };
        // The secondary counts are means over every ray, those that leave the scene at once (which cross nothing)
        // included; the floor bounds the others' counts (`predict_floored` applies it to them alone).
        let stay = 1.0 - leave_share;
        let near = if kind != WorkloadKind::Primary && stay > 0.0 { near / stay } else { near };
        if near.is_finite() && near > 0.0 {
            f.prim_tests = f.prim_tests.max(near);
            f.box_tests = f.box_tests.max(near / leaf);
        }
    }
    if kind != WorkloadKind::Primary && c.image > 0.0 {
        let y = if c.all > 0.0 { c.image * x / c.all } else { 0.0 };
        let (bi, pi) = bounds.tests_per_image_crossing(structure, kind);
        f.box_tests = f.box_tests.max(bi * y);
        f.prim_tests = f.prim_tests.max(pi * y);
    }
    // A probed structure's own counts on the camera's sample of rays of this kind ([`super::probe()`]).
    f.sampled = c.probe(structure);
    f.build_work = c.build_work(structure);
    if structure == StructureName::KdTree && c.nondegenerate >= c.all && bounds.kd_tree_prim_floor > 0.0 {
        // The kd-tree, which no probe counts: at least [`KD_TREE_PRIM_FLOOR`] times the fewest triangle tests of the
        // probed object hierarchies on the same rays (where no triangle has zero area: the kd-tree stores those as
        // points, which a ray never tests).
        let fewest = super::PROBED
            .iter()
            .filter(|&&s| s != StructureName::Grid)
            .filter_map(|&s| c.probe(s))
            .map(|p| p.prim_tests.lower_bound())
            .fold(f64::INFINITY, f64::min);
        // The probes' secondary means count the rays that leave the scene at once too; the floor bounds the others
        // (`predict_floored` applies it to them alone), as the boxes-entered floor above.
        let stay = 1.0 - leave_share;
        let fewest = if kind != WorkloadKind::Primary && stay > 0.0 { fewest / stay } else { fewest };
        if fewest.is_finite() {
            f.prim_tests = f.prim_tests.max(bounds.kd_tree_prim_floor * fewest);
        }
    }
    f
}
