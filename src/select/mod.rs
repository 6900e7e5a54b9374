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
pub mod driver;
pub(crate) mod ladder;
mod report;
mod selector;
mod thesis;

pub use crate::cost::Crossings;
pub use budget::{Budget, BuildBounds, Exclusion};
#[cfg(feature = "eval")]
pub(crate) use calibrated::planned_total;
pub use calibrated::{choose, margin_reason, plan_frames, CalibratedPolicy, FrameAction, FrameDecision, FrameRule};
pub use driver::{plan_driver_frames, DriverAction, DriverFrameDecision, DriverFrameRule, DriverSelection};
pub use report::{Bounds, Report, SelectionCost, Timings};
pub(crate) use selector::{climb, Knowledge};
pub use selector::{Decision, Inquiry, Level, Policy as PolicyKind, Scene, Selector, Step, DEFAULT_DECISION_BUDGET};
pub use thesis::ThesisPolicy;

use crate::characterize::{Characterization, Features};
use crate::cost::{CostModel, Prediction};
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
    /// [`SceneSummary::with_features`]. [`ThesisPolicy`] ignores them; the calibrated policy needs them.
    pub features: &'a [Features],
    /// Bounds on the grid's and the kd-tree's references, from the mesh ([`BuildBounds::of_mesh`], set with
    /// [`SceneSummary::with_build_bounds`]); `None`: the policies bound them from [`SceneSummary::features`] (the
    /// largest over the frames), or exclude nothing without features.
    pub build_bounds: Option<BuildBounds>,
    /// The budget a structure's bound must fit to be a candidate ([`Budget::default`] unless set with
    /// [`SceneSummary::with_budget`]).
    pub budget: Budget,
}

fn diagonal(lo: [f32; 3], hi: [f32; 3]) -> f64 {
    (0..3).map(|a| (hi[a] as f64 - lo[a] as f64).powi(2)).sum::<f64>().sqrt()
}

/// Share of empty classes in a characterization.
pub fn empty_share(c: &Characterization) -> f64 {
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
    pub fn with_build_bounds(mut self, bounds: BuildBounds) -> Self {
        self.build_bounds = Some(bounds);
        self
    }

    /// The summary with another budget ([`Budget::UNLIMITED`] turns the exclusions off).
    pub fn with_budget(mut self, budget: Budget) -> Self {
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
    pub fn exclusions(&self) -> Vec<Exclusion> {
        self.bounds().map(|b| self.budget.check(&b)).unwrap_or_default()
    }

    /// [`SceneSummary::exclusions`] for a policy that prices no build ([`Budget::check_unpriced`]).
    pub fn exclusions_unpriced(&self) -> Vec<Exclusion> {
        self.bounds().map(|b| self.budget.check_unpriced(&b)).unwrap_or_default()
    }

    /// The summary with the cost-model features of every frame.
    pub fn with_features(mut self, features: &'a [Features]) -> Self {
        self.features = features;
        self
    }

    /// Ratio of the largest to the smallest extent of the union bounds (`f64::INFINITY` for a flat scene, 1 for an
    /// empty summary).
    pub fn aspect(&self) -> f64 {
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
    pub reasons: Vec<String>,
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
    pub fn new(structure: Structure, reasons: Vec<String>) -> Self {
        Selection { structure, reasons, excluded: Vec::new(), driver: None }
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

/// Which policy [`select_for_scene`] runs.
#[derive(Clone, Copy, Debug)]
pub enum PolicyChoice<'a> {
    /// The thesis's rules ([`ThesisPolicy`] with its default thresholds).
    Thesis,
    /// The calibrated policy over a cost model, with the relative margin within which the cheaper build wins.
    Calibrated {
        /// The cost model.
        model: &'a CostModel,
        /// See [`CalibratedPolicy::tie_margin`].
        tie_margin: f64,
    },
}

impl PolicyChoice<'_> {
    /// `thesis` or `calibrated`, as reports name it.
    pub fn name(&self) -> &'static str {
        match self {
            PolicyChoice::Thesis => "thesis",
            PolicyChoice::Calibrated { .. } => "calibrated",
        }
    }
}

/// The workload a scene is selected for.
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

/// What [`select_for_scene`] decided.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneSelection {
    /// The policy that decided (`thesis` or `calibrated`).
    pub policy: &'static str,
    /// Static (one frame) or dynamic.
    pub kind: SceneKind,
    /// The structure and the reasons.
    pub selection: Selection,
    /// The calibrated policy's predictions for every structure (`None` for the thesis policy, or without features).
    pub predicted: Option<Vec<Prediction>>,
    /// The close calls measured ([`select_for_scene_measured`], [`crate::cost::measured`]): the structures built
    /// and traced over whole frames, with their measured totals; empty when none was measured.
    pub measured: Vec<crate::cost::measured::MeasuredTotal>,
}

/// [`select_for_scene_within`] with timed probes ([`crate::cost::timed`]) for a static scene whose mesh is `mesh`
/// (with `policy` calibrated and `bounds` given): a first selection predicts every structure, the contenders among
/// those the budget allows (predicted within [`crate::cost::timed::CONTENDER_FACTOR`] of the cheapest,
/// [`crate::cost::timed::contenders`]) are built and timed on a sample of the view
/// ([`BuildBounds::with_timed_probes`]), and the selection is made again with their times blended in (when the model
/// has the ratios, [`crate::cost::CostModel::timed`]). Otherwise (an animation, the thesis policy, no bounds, a model
/// without those ratios: nothing is probed then) it is [`select_for_scene_within`]'s selection. Not deterministic: the probes are timed on this machine now.
#[allow(clippy::too_many_arguments)]
pub fn select_for_scene_timed(
    name: &str,
    frames: &[Characterization],
    features: &[Features],
    policy: PolicyChoice<'_>,
    workload: &TargetWorkload,
    bounds: Option<BuildBounds>,
    budget: Budget,
    mesh: &crate::mesh::Mesh,
) -> SceneSelection {
    let mut first = select_for_scene_within(name, frames, features, policy, workload, bounds.clone(), budget);
    // Nothing to blend with: no probe is worth its builds. The caller asked for probes: say why none was taken.
    let why_not = match policy {
        PolicyChoice::Thesis => Some("the thesis policy predicts no times"),
        PolicyChoice::Calibrated { model, .. } if model.timed.is_none() => {
            Some("this calibration has no timed-probe ratios (calibrate --from-oracle ... --timed-probes)")
        }
        _ if frames.len() != 1 => Some("the scene is an animation"),
        _ if bounds.is_none() || first.predicted.is_none() => Some("no mesh bounds or no predictions"),
        _ => None,
    };
    if let Some(why) = why_not {
        first.selection.reasons.push(format!("timed probes: none taken: {why}"));
        return first;
    }
    let (Some(b), Some(preds)) = (bounds, first.predicted.as_ref()) else { return first };
    let allowed: Vec<Prediction> = preds
        .iter()
        .filter(|p| !first.selection.excluded.iter().any(|e| e.structure == p.structure))
        .copied()
        .collect();
    let only = crate::cost::timed::contenders(&allowed);
    let b = b.with_timed_probes(mesh, workload.camera.as_ref(), workload.kind, &only, &budget);
    select_for_scene_within(name, frames, features, policy, workload, Some(b), budget)
}

/// What [`select_for_scene_measured`] may spend on measuring a close call.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeasureBudget {
    /// The side of the square image whose rays are measured (the workload's resolution: its primary rays, and for
    /// shadow and diffuse rays those their hits start).
    pub resolution: u32,
    /// The most the measurement may take by the predictions, ms ([`crate::cost::measured::measuring_cost_ms`]:
    /// [`crate::cost::measured::MEASURED_WARMUP`] + [`crate::cost::measured::MEASURED_REPEATS`] builds
    /// and traced frames of every structure of the close call ([`MeasureBudget::DEFAULT_MAX_MS`] by default).
    pub max_ms: f64,
}

impl MeasureBudget {
    /// The default [`MeasureBudget::max_ms`]: 2 s ([`crate::cost::measured::DEFAULT_MAX_MS`]).
    pub const DEFAULT_MAX_MS: f64 = crate::cost::measured::DEFAULT_MAX_MS;

    /// A budget for `resolution` x `resolution` frames, at the default [`MeasureBudget::max_ms`].
    pub fn new(resolution: u32) -> Self {
        MeasureBudget { resolution, max_ms: Self::DEFAULT_MAX_MS }
    }
}

/// [`select_for_scene_timed`], and then, for a static scene, the close call settled by measuring it
/// ([`crate::cost::measured`]): the structures the budget allows whose final predicted total lies within
/// [`crate::cost::measured::CLOSE_CALL_MARGIN`] of the least are built and traced over whole frames of the view's
/// rays at `measure.resolution` ([`crate::cost::measured::MEASURED_REPEATS`] times after an untimed round,
/// interleaved; each trace scaled to the workload's rays per frame, `rays_per_frame` over the rays the frame traced
/// (`resolution^2` primary rays, or the secondary rays their hits start), so that the totals compared are the
/// predictions' own), and the one with the least median total over the workload's frames
/// is selected; a reason lists the measured totals, or says why
/// nothing was measured (no close call, an animation, the thesis policy, the driver's structure chosen, or the
/// predicted cost of measuring over `measure.max_ms`). The measurement is what the oracle measures, on this machine
/// now: the choice is not deterministic, and it costs [`crate::cost::measured::MEASURED_WARMUP`] +
/// [`crate::cost::measured::MEASURED_REPEATS`] frames and builds of each structure measured.
#[allow(clippy::too_many_arguments)]
pub fn select_for_scene_measured(
    name: &str,
    frames: &[Characterization],
    features: &[Features],
    policy: PolicyChoice<'_>,
    workload: &TargetWorkload,
    bounds: Option<BuildBounds>,
    budget: Budget,
    mesh: &crate::mesh::Mesh,
    measure: MeasureBudget,
) -> SceneSelection {
    use crate::cost::measured::{
        close_calls, measure_frames, measuring_cost_ms, MeasuredTotal, CLOSE_CALL_MARGIN, MEASURED_REPEATS,
        MEASURED_WARMUP,
    };
    let mut chosen = select_for_scene_timed(name, frames, features, policy, workload, bounds, budget, mesh);
    let allowed: Vec<Prediction> = chosen
        .predicted
        .iter()
        .flatten()
        .filter(|p| !chosen.selection.excluded.iter().any(|e| e.structure == p.structure))
        .copied()
        .collect();
    let close = close_calls(&allowed);
    let frames_run = workload.frames.max(1);
    let cost = measuring_cost_ms(&allowed, &close, frames_run);
    let why_not = match policy {
        PolicyChoice::Thesis => Some("the thesis policy predicts no times".to_string()),
        _ if frames.is_empty() => Some("no frame".to_string()),
        _ if frames.len() != 1 => Some("the scene is an animation".to_string()),
        _ if chosen.selection.driver.as_ref().is_some_and(|d| d.chosen) => {
            Some("the driver's structure was chosen".to_string())
        }
        _ if chosen.predicted.is_none() => Some("no predictions".to_string()),
        _ if close.is_empty() => Some(format!(
            "no close call (no other structure predicted within {:.0}% of the least)",
            100.0 * CLOSE_CALL_MARGIN
        )),
        _ if measure.resolution == 0 => Some("no rays (resolution 0)".to_string()),
        _ if u64::from(measure.resolution).pow(2) > crate::cost::measured::MAX_MEASURED_RAYS => Some(format!(
            "{0}x{0} rays per frame, over the {1} a measured frame may hold",
            measure.resolution,
            crate::cost::measured::MAX_MEASURED_RAYS
        )),
        _ if cost.is_nan() || measure.max_ms.is_nan() || cost > measure.max_ms => Some(format!(
            "measuring {} would take about {cost:.0} ms by the predictions, over the {:.0} ms allowed",
            names(&close),
            measure.max_ms
        )),
        _ => None,
    };
    if let Some(why) = why_not {
        chosen.selection.reasons.push(format!("measured close call: none: {why}"));
        return chosen;
    }
    let b = crate::cost::timed::mesh_box(mesh);
    let camera =
        workload.camera.unwrap_or_else(|| crate::cost::view::framing_camera(b.min.to_array(), b.max.to_array()));
    let timings = measure_frames(mesh, &camera, measure.resolution, workload.kind, &close, MEASURED_REPEATS);
    // The frames measured hold `resolution^2` primary rays, or the secondary rays their hits start (every structure
    // traces the same rays); the predictions, and so the totals compared, are for the workload's rays per frame:
    // the traces are scaled to it (a frame without a ray has no trace to scale).
    let traced = timings.first().map_or(0, |t| t.rays);
    let scale = if traced == 0 { 1.0 } else { workload.rays_per_frame as f64 / traced as f64 };
    let totals: Vec<MeasuredTotal> =
        timings.iter().filter_map(|t| MeasuredTotal::of(&t.scaled(scale), 1, frames_run)).collect();
    let Some(best) = totals.iter().min_by(|a, b| a.total_ms.total_cmp(&b.total_ms)) else {
        chosen.selection.reasons.push(format!("measured close call: none: no structure of {} built", names(&close)));
        return chosen;
    };
    let list: Vec<String> = totals
        .iter()
        .map(|t| {
            format!("{} {:.3} ms (build {:.3}, trace {:.3} per frame)", t.structure, t.total_ms, t.build_ms, t.trace_ms)
        })
        .collect();
    let measured: Vec<Structure> = totals.iter().map(|t| t.structure).collect();
    chosen.selection.reasons.push(format!(
        "measured close call ({}: each built and traced over whole frames of {}x{} {} rays, the median of \
         {MEASURED_REPEATS} repeats after {MEASURED_WARMUP} untimed, totals over {frames_run} frame(s) of {} rays{}; \
         not deterministic): {}: {} {}",
        names(&measured),
        measure.resolution,
        measure.resolution,
        workload.kind.as_str(),
        workload.rays_per_frame,
        if scale == 1.0 { String::new() } else { format!(", traces scaled by {scale:.3}") },
        list.join(", "),
        best.structure,
        if best.structure == chosen.selection.structure {
            "confirmed"
        } else {
            "taken instead of the predictions' choice"
        },
    ));
    chosen.selection.structure = best.structure;
    chosen.measured = totals;
    chosen
}

/// `a, b and c`.
fn names(s: &[Structure]) -> String {
    let v: Vec<&str> = s.iter().map(|s| s.as_str()).collect();
    match v.split_last() {
        None => String::new(),
        Some((last, [])) => last.to_string(),
        Some((last, rest)) => format!("{} and {last}", rest.join(", ")),
    }
}

/// Selects a structure for a scene (the characterization of its frames and their features) under a workload: the
/// one selection routine of the command-line tools and the studies.
///
/// The thesis policy reads every frame. The calibrated policy reads the frames the run covers: the first frame of a
/// static scene, or the first `animation_frames` frames of an animation (all when `None`), at least one and no more
/// than there are characterizations and features.
///
/// Structures over the default [`Budget`] by the bounds from the features are no candidates
/// ([`select_for_scene_within`] takes the mesh's bounds and another budget).
pub fn select_for_scene(
    name: &str,
    frames: &[Characterization],
    features: &[Features],
    policy: PolicyChoice<'_>,
    workload: &TargetWorkload,
) -> SceneSelection {
    select_for_scene_within(name, frames, features, policy, workload, None, Budget::default())
}

/// [`select_for_scene`] with the mesh's [`BuildBounds`] (`None`: from the features) and a [`Budget`]: no structure
/// whose bound exceeds the budget is selected, and the excluded ones are listed in [`Selection::excluded`].
pub fn select_for_scene_within(
    name: &str,
    frames: &[Characterization],
    features: &[Features],
    policy: PolicyChoice<'_>,
    workload: &TargetWorkload,
    bounds: Option<BuildBounds>,
    budget: Budget,
) -> SceneSelection {
    let kind = if frames.len() > 1 { SceneKind::Dynamic } else { SceneKind::Static };
    fn bounded<'a>(s: SceneSummary<'a>, bounds: &Option<BuildBounds>, budget: Budget) -> SceneSummary<'a> {
        let s = s.with_budget(budget);
        match bounds.clone() {
            Some(b) => s.with_build_bounds(b),
            None => s,
        }
    }
    match policy {
        PolicyChoice::Thesis => {
            let summary = bounded(SceneSummary::new(name, frames).with_features(features), &bounds, budget);
            SceneSelection {
                policy: "thesis",
                kind,
                selection: ThesisPolicy::default().select(&summary),
                predicted: None,
                measured: Vec::new(),
            }
        }
        PolicyChoice::Calibrated { model, tie_margin } => {
            let mut p = CalibratedPolicy::new(model.clone(), workload.kind, workload.rays_per_frame, workload.frames);
            p.tie_margin = tie_margin;
            p.driver = workload.driver;
            p.camera = workload.camera;
            let used = if frames.len() > 1 { workload.animation_frames.unwrap_or(frames.len()) } else { 1 };
            let used = used.clamp(1, frames.len().min(features.len()).max(1)).min(frames.len()).min(features.len());
            let summary =
                bounded(SceneSummary::new(name, &frames[..used]).with_features(&features[..used]), &bounds, budget);
            let predicted = p.predictions(&summary);
            SceneSelection {
                policy: "calibrated",
                kind,
                selection: p.select(&summary),
                predicted,
                measured: Vec::new(),
            }
        }
    }
}
