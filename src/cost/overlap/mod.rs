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

mod floor;
mod screen;
#[cfg(test)]
pub(crate) use floor::BIH_MAX_LEAF;
pub use floor::{crossings_feature, CountBounds, StructureCountBounds};
pub(crate) use floor::{overlap_floor, priced_floor, TestFloor};
use screen::ratio;
#[cfg(test)]
pub(crate) use screen::NEAR_SAMPLES;
pub use screen::{near_crossings, near_sample_side, screen_crossings, NearCrossings, SampledMean};
