//! Selection: from the characterization of a scene (and, for the calibrated policy, its features and a cost model)
//! to an acceleration structure, with reasons a person can check.
//!
//! A [`Policy`] sees a [`SceneSummary`] (the characterization of every frame, whether the scene moves, its size and
//! bounds, how much it changes between frames) and returns a [`Selection`]. [`ThesisPolicy`] writes down the rules of
//! the seed thesis (section 3.1.3 and the outcomes of chapter 5) with explicit thresholds; [`CalibratedPolicy`]
//! predicts every structure's build and trace time with a fitted [`crate::cost::CostModel`] and takes the cheapest.
//! [`Report`] is the JSON and text report of one characterized mesh or frame with its selection.
//!
//! Before either policy chooses, the structures whose build would blow up are taken out of its candidates:
//! [`BuildBounds`] bounds the grid's and the kd-tree's references from the mesh or its features, and a structure
//! whose bound exceeds the scene's [`Budget`] is excluded, with the reason recorded in [`Selection::excluded`] (see
//! [`budget`]).

pub mod budget;
mod calibrated;
mod climb;
pub mod driver;
pub(crate) mod ladder;
mod reason;
mod report;
mod selector;
mod thesis;

pub use budget::{Budget, BuildBounds, Exclusion};
#[cfg(feature = "eval")]
pub(crate) use calibrated::planned_total;
pub use calibrated::{choose, plan_frames, CalibratedPolicy, FrameAction, FrameDecision, FrameRule};
#[cfg(feature = "eval")]
pub(crate) use climb::{climb, Knowledge};
#[cfg(test)]
pub(crate) use driver::plan_driver_frames;
pub use driver::{DriverAction, DriverFrameDecision, DriverFrameRule, DriverSelection};
pub use reason::{Reason, ReasonKind};
pub use report::{Bounds, Report, SelectionCost, Timings};
pub use selector::{
    Decision, Inquiry, Level, Policy as PolicyKind, Scene, Selector, SizeRung, Step, DEFAULT_DECISION_BUDGET,
};
pub use thesis::ThesisPolicy;

use crate::characterize::{Characterization, Features};
use crate::geom::WorkloadKind;

/// An acceleration structure a policy can select: the oracle's [`crate::accel::StructureName`] (a policy never
/// selects [`crate::accel::StructureName::Brute`]).
pub use crate::accel::StructureName as Structure;

/// Whether the scene's geometry changes between frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SceneKind {
    /// One frame.
    #[default]
    Static,
    /// Several frames (an animation).
    Dynamic,
}

impl SceneKind {
    /// `static` or `dynamic`.
    pub fn name(self) -> &'static str {
        match self {
            SceneKind::Static => "static",
            SceneKind::Dynamic => "dynamic",
        }
    }
}

/// How much an animation changes from one frame to the next (largest change over consecutive pairs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FrameChange {
    /// Number of frames.
    pub frames: usize,
    /// Largest relative change of the bounds diagonal `|d_{i+1} - d_i| / max(d_i, d_{i+1})`.
    pub max_diagonal_change: f64,
    /// Largest absolute change of Cramér's V.
    pub max_effect_size_change: f64,
    /// Largest absolute change of the share of empty classes.
    pub max_empty_share_change: f64,
}

/// What a policy may look at.
#[derive(Clone, Debug)]
pub struct SceneSummary<'a> {
    /// The scene's name (file or directory).
    pub name: String,
    /// Static (one frame) or dynamic.
    pub kind: SceneKind,
    /// The characterization of every frame, in order (one for a static scene).
    pub frames: &'a [Characterization],
    /// Triangles per frame (of the mesh, before sampling).
    pub triangles: u64,
    /// Union over the frames of `lo` (step 2: three times the centroid).
    pub lo: [f32; 3],
    /// Union over the frames of `hi`.
    pub hi: [f32; 3],
    /// Frame-to-frame change, for more than one frame.
    pub change: Option<FrameChange>,
    /// Cost-model features of every frame ([`crate::characterize::features`]); empty unless set with
    /// `SceneSummary::with_features`. [`ThesisPolicy`] ignores them; the calibrated policy needs them.
    pub features: &'a [Features],
    /// Bounds on the grid's and the kd-tree's references, from the mesh ([`BuildBounds::of_mesh`], set with
    /// `SceneSummary::with_build_bounds`); `None`: the policies bound them from [`SceneSummary::features`] (the
    /// largest over the frames), or exclude nothing without features.
    pub build_bounds: Option<BuildBounds>,
    /// The budget a structure's bound must fit to be a candidate ([`Budget::default`] unless set with
    /// `SceneSummary::with_budget`).
    pub budget: Budget,
}

fn diagonal(lo: [f32; 3], hi: [f32; 3]) -> f64 {
    (0..3).map(|a| (hi[a] as f64 - lo[a] as f64).powi(2)).sum::<f64>().sqrt()
}

/// Share of empty classes in a characterization.
pub(crate) fn empty_share(c: &Characterization) -> f64 {
    c.stats.empty_classes as f64 / c.classes.max(1) as f64
}

impl<'a> SceneSummary<'a> {
    /// Summarizes the frames of a scene: dynamic when there is more than one frame.
    pub fn new(name: impl Into<String>, frames: &'a [Characterization]) -> Self {
        let mut lo = [0.0f32; 3];
        let mut hi = [0.0f32; 3];
        if let Some(f) = frames.first() {
            lo = f.lo;
            hi = f.hi;
        }
        for f in frames {
            for a in 0..3 {
                lo[a] = lo[a].min(f.lo[a]);
                hi[a] = hi[a].max(f.hi[a]);
            }
        }
        let change = (frames.len() > 1).then(|| {
            let mut ch = FrameChange {
                frames: frames.len(),
                max_diagonal_change: 0.0,
                max_effect_size_change: 0.0,
                max_empty_share_change: 0.0,
            };
            for w in frames.windows(2) {
                let (d0, d1) = (diagonal(w[0].lo, w[0].hi), diagonal(w[1].lo, w[1].hi));
                let dd = if d0.max(d1) > 0.0 { (d1 - d0).abs() / d0.max(d1) } else { 0.0 };
                ch.max_diagonal_change = ch.max_diagonal_change.max(dd);
                ch.max_effect_size_change =
                    ch.max_effect_size_change.max((w[1].stats.cramers_v - w[0].stats.cramers_v).abs());
                ch.max_empty_share_change =
                    ch.max_empty_share_change.max((empty_share(&w[1]) - empty_share(&w[0])).abs());
            }
            ch
        });
        SceneSummary {
            name: name.into(),
            kind: if frames.len() > 1 { SceneKind::Dynamic } else { SceneKind::Static },
            frames,
            triangles: frames.first().map_or(0, |f| f.total_triangles),
            lo,
            hi,
            change,
            features: &[],
            build_bounds: None,
            budget: Budget::default(),
        }
    }

    /// The summary with bounds computed from the mesh (exact box-cell counts, tighter than the features').
    pub(crate) fn with_build_bounds(mut self, bounds: BuildBounds) -> Self {
        self.build_bounds = Some(bounds);
        self
    }

    /// The summary with another budget ([`Budget::UNLIMITED`] turns the exclusions off).
    pub(crate) fn with_budget(mut self, budget: Budget) -> Self {
        self.budget = budget;
        self
    }

    /// The bounds the policies use: [`SceneSummary::build_bounds`], else the largest of the frames' bounds from
    /// their features, else `None`.
    pub fn bounds(&self) -> Option<BuildBounds> {
        self.build_bounds
            .clone()
            .or_else(|| self.features.iter().map(BuildBounds::of_features).reduce(|a, b| a.max(&b)))
    }

    /// The structures whose bound exceeds the budget ([`Budget::check`] on [`SceneSummary::bounds`]): the policies
    /// never select them.
    pub(crate) fn exclusions(&self) -> Vec<Exclusion> {
        self.bounds().map(|b| self.budget.check(&b)).unwrap_or_default()
    }

    /// [`SceneSummary::exclusions`] for a policy that prices no build ([`Budget::check_unpriced`]).
    pub(crate) fn exclusions_unpriced(&self) -> Vec<Exclusion> {
        self.bounds().map(|b| self.budget.check_unpriced(&b)).unwrap_or_default()
    }

    /// The summary with the cost-model features of every frame.
    pub(crate) fn with_features(mut self, features: &'a [Features]) -> Self {
        self.features = features;
        self
    }

    /// Ratio of the largest to the smallest extent of the union bounds (`f64::INFINITY` for a flat scene, 1 for an
    /// empty summary).
    pub(crate) fn aspect(&self) -> f64 {
        let e: Vec<f64> = (0..3).map(|a| self.hi[a] as f64 - self.lo[a] as f64).collect();
        let max = e.iter().cloned().fold(0.0, f64::max);
        let min = e.iter().cloned().fold(f64::INFINITY, f64::min);
        if max == 0.0 {
            1.0
        } else if min == 0.0 {
            f64::INFINITY
        } else {
            max / min
        }
    }
}

/// A selected structure and why.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Selection {
    /// The structure.
    pub structure: Structure,
    /// The rules that fired, each with the numbers that made it fire.
    pub reasons: Vec<Reason>,
    /// The structures that were no candidates because their bound exceeds the budget, with the numbers (see
    /// [`budget`]); empty when none was excluded.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub excluded: Vec<Exclusion>,
    /// The best of the driver's acceleration structures, when the policy weighed them (the calibrated policy with
    /// a model that calibrated them, on a device with ray queries: [`TargetWorkload::driver`]); when
    /// [`DriverSelection::chosen`], it is the overall choice and [`Selection::structure`] the project's best.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub driver: Option<DriverSelection>,
}

impl Selection {
    /// A selection of `structure` for `reasons`, excluding nothing.
    pub fn new(structure: Structure, reasons: Vec<Reason>) -> Self {
        Selection { structure, reasons, excluded: Vec::new(), driver: None }
    }

    /// The reasons' sentences, joined by "; ".
    pub fn explain(&self) -> String {
        reason::join(&self.reasons, "; ")
    }

    /// The overall choice's name: the driver structure's (`rt_fast_trace`, ...) when it was chosen, else the
    /// project's structure's.
    pub fn candidate(&self) -> &'static str {
        match &self.driver {
            Some(d) if d.chosen => d.flags.name(),
            _ => self.structure.as_str(),
        }
    }
}

/// A rule set that picks a structure for a scene.
pub trait Policy {
    /// A short name for reports.
    fn name(&self) -> &str;
    /// Selects a structure for `scene`.
    fn select(&self, scene: &SceneSummary<'_>) -> Selection;
}

/// The workload a scene is selected for. The default: primary rays of a 1024 x 1024 image, one frame, the framing
/// camera, the project's structures only.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TargetWorkload {
    /// Kind of rays.
    pub kind: WorkloadKind,
    /// Rays per frame: for shadow and diffuse rays the secondary rays the frame traces (one per primary ray that
    /// hits, as the oracle makes them), not the image's pixels; an engine knows them from its primary pass, and
    /// [`crate::trace::workload::estimate_secondary_rays`] estimates them from a sample of the primary rays.
    pub rays_per_frame: u64,
    /// Frames of a static scene rendered with one build.
    pub frames: u64,
    /// For an animation, how many of its leading frames the run covers (`None`: all of them).
    pub animation_frames: Option<usize>,
    /// The device traces with the driver's acceleration structures (ray queries): the calibrated policy weighs
    /// them too, when its model calibrated them ([`crate::cost::CostModel::driver`]).
    pub driver: bool,
    /// The camera the rays will be made from, when the engine knows it ([`CalibratedPolicy::camera`]); `None`: the
    /// framing camera of the scene's bounds.
    pub camera: Option<crate::geom::Camera>,
}

impl Default for TargetWorkload {
    fn default() -> Self {
        TargetWorkload {
            kind: WorkloadKind::Primary,
            rays_per_frame: 1024 * 1024,
            frames: 1,
            animation_frames: None,
            driver: false,
            camera: None,
        }
    }
}
