//! The overlap floor: the least tests per crossed triangle box ([`CountBounds`]) that bound a structure's predicted
//! test counts from below ([`TestFloor`]).

use super::*;

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
            let [b, p] = s.per_crossing[crate::cost::timed::kind_index(kind)];
            (b, p)
        })
    }

    /// Least `(box, triangle)` tests per secondary ray per box crossed by the camera's primary rays on its image;
    /// `(0, 0)` for primary rays and without a floor.
    pub(crate) fn tests_per_image_crossing(&self, structure: StructureName, kind: WorkloadKind) -> (f64, f64) {
        match (kind, self.of(structure)) {
            (WorkloadKind::Primary, _) | (_, None) => (0.0, 0.0),
            (k, Some(s)) => {
                let [b, p] = s.per_image_crossing[crate::cost::timed::kind_index(k) - 1];
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
    /// The structure's own tests per ray of the workload counted on a sample of its rays ([`crate::cost::probe()`]): where
    /// a law's count (with the bounds above) lies outside its own error band about the sampled mean
    /// ([`crate::cost::CostModel::own_probe_band`] times the fit's RMS error of `ln(1 + count)`: none for a calibration
    /// traced on the CPU), the prediction holds it within two standard errors of that mean instead
    /// ([`crate::cost::StructureModel::predict_floored`]).
    pub sampled: Option<crate::cost::ProbeCounts>,
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
/// ([`crate::cost::StructureModel::build_work_coef`]) in place of the probe's work or the law in `n`; 0 leaves the floor
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
        StructureName::Bvh | StructureName::Grid => c.distinct,
        StructureName::KdTree => c.nondegenerate,
        _ => c.all,
    };
    let (b, p) = bounds.tests_per_crossing(structure, kind);
    let leave_share = if kind == WorkloadKind::Primary { 0.0 } else { unit_share(c.leave_share) };
    let mut f = TestFloor { box_tests: b * x, prim_tests: p * x, crossings, leave_share, ..TestFloor::default() };
    if let (Some(near), Some(leaf)) = (c.near, near_leaf(structure)) {
        // Every triangle whose box a closest-hit ray enters before its first hit is tested, and every triangle whose
        // box an unoccluded any-hit ray crosses ([`near_crossings`]: for primary rays the boxes entered, for diffuse
        // rays those holding the origin, for shadow rays those the unoccluded ones cross); the binned-SAH BVH and
        // the grid keep one of coincident copies, so their counts are scaled by the distinct share. Each such
        // triangle's leaf box is tested too, and a leaf holds at most `leaf` triangles.
        let merges = matches!(structure, StructureName::Bvh | StructureName::Grid);
        let near = if merges && c.all > 0.0 { near * c.distinct / c.all } else { near };
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
    // A probed structure's own counts on the camera's sample of rays of this kind ([`crate::cost::probe()`]).
    f.sampled = c.probe(structure);
    f.build_work = c.build_work(structure);
    if structure == StructureName::KdTree && c.nondegenerate >= c.all && bounds.kd_tree_prim_floor > 0.0 {
        // The kd-tree, which no probe counts: at least [`KD_TREE_PRIM_FLOOR`] times the fewest triangle tests of the
        // probed object hierarchies on the same rays (where no triangle has zero area: the kd-tree stores those as
        // points, which a ray never tests).
        let fewest = crate::cost::PROBED
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
