//! The calibrated selection policy: predict every structure's total for the scene and workload at hand with a
//! [`CostModel`], and pick the smallest; among structures whose predicted totals are within `tie_margin` of the
//! smallest, the one that is cheapest to build (a cheaper build is the smaller risk when the totals cannot be told
//! apart).
//!
//! For animations, [`plan_frames`] decides per frame between rebuilding (with which builder) and refitting the
//! current BVH-family tree, from the [`crate::cost::RefitModel`]: the refitted tree's trace cost is the fresh tree's
//! times `1 + g * drift`, where the drift ([`crate::cost::drift`]) is measured from the features of the frame the
//! tree was built for to the current frame.

use super::{Level, Policy, Reason, ReasonKind, SceneSummary, Selection, ThesisPolicy};
use crate::accel::StructureName;
use crate::characterize::Features;
use crate::cost::{overlap_floor, priced_floor, CostModel, Prediction, RayCrossings, ViewFeatures, Workload};

/// The calibrated choice among predictions: the smallest predicted total, then, within `tie_margin` (relative) of
/// it, the smallest predicted build. `None` for no predictions.
pub fn choose(preds: &[Prediction], tie_margin: f64) -> Option<StructureName> {
    let best = preds.iter().filter(|p| p.total_ms.is_finite()).min_by(|a, b| a.total_ms.total_cmp(&b.total_ms))?;
    let limit = best.total_ms * (1.0 + tie_margin.max(0.0));
    preds.iter().filter(|p| p.total_ms <= limit).min_by(|a, b| a.build_ms.total_cmp(&b.build_ms)).map(|p| p.structure)
}

/// What a frame of an animation does with its structure.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameAction {
    /// Build the structure anew for this frame.
    Rebuild,
    /// Refit the tree in use to this frame.
    Refit,
}

impl FrameAction {
    /// `rebuild` or `refit` (as in JSON).
    pub fn as_str(self) -> &'static str {
        match self {
            FrameAction::Rebuild => "rebuild",
            FrameAction::Refit => "refit",
        }
    }
}

impl std::fmt::Display for FrameAction {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One frame's decision for an animation.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FrameDecision {
    /// Frame index.
    pub frame: usize,
    /// Rebuild or refit (`rebuild`, `refit` in JSON).
    pub action: FrameAction,
    /// The structure traced in this frame.
    pub structure: StructureName,
    /// Predicted ms of the action (build or refit).
    pub update_ms: f64,
    /// Predicted trace ms of the frame.
    pub trace_ms: f64,
    /// Drift since the tree was built (0 after a rebuild).
    pub drift: f64,
}

fn bvh_family(s: StructureName) -> bool {
    matches!(s, StructureName::Bvh | StructureName::Lbvh | StructureName::Hlbvh)
}

/// The project's side for an animation (`features` of more than one frame): the total of its per-frame plan
/// ([`plan_frames`]: rebuilds and refits), or `None` for a static scene or when nothing plans. What the policy
/// weighs the driver's structures against, and what the policy comparison scores it by.
pub(crate) fn planned_total(
    model: &CostModel,
    features: &[Features],
    kind: crate::geom::WorkloadKind,
    rays_per_frame: u64,
    tie_margin: f64,
    crossings: Option<RayCrossings>,
) -> Option<f64> {
    if features.len() < 2 {
        return None;
    }
    let plan = plan_frames(model, features, kind, rays_per_frame, tie_margin, crossings);
    (!plan.is_empty()).then(|| plan.iter().map(|d| d.update_ms + d.trace_ms).sum())
}

/// Per-frame rebuild-or-refit plan for an animation with per-frame `features` and `rays_per_frame` rays of `kind`
/// per frame: greedy, frame by frame, the cheaper of rebuilding with the calibrated choice and refitting the tree in
/// use (BVH family only, and only with a refit model). Each step is [`FrameRule::decide`] over all calibrated
/// structures, with the overlap floor of `crossings` ([`FrameRule::crossings`]; `None`: none).
pub fn plan_frames(
    model: &CostModel,
    features: &[Features],
    kind: crate::geom::WorkloadKind,
    rays_per_frame: u64,
    tie_margin: f64,
    crossings: Option<RayCrossings>,
) -> Vec<FrameDecision> {
    let rule = FrameRule { model, kind, rays_per_frame, tie_margin, structures: &[], crossings };
    let mut out = Vec::new();
    let mut built: Option<(usize, StructureName)> = None;
    for (i, f) in features.iter().enumerate() {
        let Some(d) = rule.decide(i, f, built.map(|(b, s)| (&features[b], s))) else { break };
        if d.action == FrameAction::Rebuild {
            built = Some((i, d.structure));
        }
        out.push(d);
    }
    out
}

/// The per-frame rule of [`plan_frames`], one frame at a time: for a caller that learns each frame's features only
/// as it goes (an engine deciding, frame by frame, whether to rebuild or refit; see `examples/engine_frame.rs`).
#[derive(Clone, Copy, Debug)]
pub struct FrameRule<'a> {
    /// The cost model.
    pub model: &'a CostModel,
    /// Kind of the rays traced per frame.
    pub kind: crate::geom::WorkloadKind,
    /// Rays per frame (for shadow and diffuse rays the secondary rays traced, not the image's pixels; see
    /// [`crate::select::TargetWorkload::rays_per_frame`]).
    pub rays_per_frame: u64,
    /// Relative margin within which the cheaper build wins ([`choose`]).
    pub tie_margin: f64,
    /// The structures a rebuild may choose from (the builders the caller has); empty: every calibrated structure.
    pub structures: &'a [StructureName],
    /// The triangle boxes a ray of the workload crosses in the scene (`crate::cost::Crossings::for_workload` of
    /// the first frame, as the static choice takes them): every frame's predictions are floored by them
    /// (`overlap_floor`). `None`: no floor (a caller without the mesh's boxes), and a calibration fitted with the
    /// crossings reads its mean count ([`crate::cost::StructureModel::crossing_mean`]).
    pub crossings: Option<RayCrossings>,
}

impl FrameRule<'_> {
    /// The drift ([`crate::cost::drift`]) from the frame a decision was made on past which it is made again: the
    /// drift at which a refitted tree's predicted trace time grows by the tie margin (`tie_margin / g`, `g` the
    /// calibration's growth per unit of drift, [`crate::cost::RefitModel::sah_growth_per_drift`]), below which no
    /// prediction moves by more than the margin the choice already ignores; 0 (decide every frame) without a refit
    /// model.
    pub fn redecide_drift(&self) -> f64 {
        match self.model.refit {
            Some(r) if r.sah_growth_per_drift > 0.0 => self.tie_margin.max(0.0) / r.sah_growth_per_drift,
            Some(_) => f64::INFINITY,
            None => 0.0,
        }
    }

    /// Whether a decision made on the features `decided` is made again at `now`: the drift between them exceeds
    /// [`FrameRule::redecide_drift`] (the thesis's per-frame statistics as the trigger, so that an animation
    /// decides again only where its geometry changed), and the drift.
    pub fn redecide(&self, decided: &Features, now: &Features) -> (bool, f64) {
        let d = crate::cost::drift(decided, now);
        (d > self.redecide_drift(), d)
    }

    /// Frame `frame`'s decision for a scene with features `now`, given the tree in use (`built`: the features of
    /// the frame it was built for and its structure, `None` before the first build): rebuild with the calibrated
    /// choice among [`FrameRule::structures`] for a one-frame workload, or refit the tree in use (BVH family only,
    /// and only when the model has a refit model), whichever predicts the smaller update plus trace time; without
    /// a tree, rebuild. The refitted tree's trace time is the fresh one's times `1 + g * drift(built, now)`.
    /// `None` when the model predicts none of the structures.
    pub fn decide(
        &self,
        frame: usize,
        now: &Features,
        built: Option<(&Features, StructureName)>,
    ) -> Option<FrameDecision> {
        let w = Workload { kind: self.kind, rays_per_frame: self.rays_per_frame, frames: 1, builds: 1, view: None };
        let bounds = &self.model.count_bounds;
        let preds = self.model.predict_floored(now, &w, &|s| overlap_floor(bounds, s, self.kind, self.crossings));
        let allowed: Vec<Prediction> = preds
            .iter()
            .filter(|p| self.structures.is_empty() || self.structures.contains(&p.structure))
            .copied()
            .collect();
        let fresh = choose(&allowed, self.tie_margin)?;
        let pf = allowed.iter().find(|p| p.structure == fresh)?;
        let rebuild = FrameDecision {
            frame,
            action: FrameAction::Rebuild,
            structure: fresh,
            update_ms: pf.build_ms,
            trace_ms: pf.trace_ms,
            drift: 0.0,
        };
        let refit = match (built, self.model.refit) {
            (Some((b, s)), Some(r)) if bvh_family(s) => preds.iter().find(|p| p.structure == s).map(|p| {
                let d = crate::cost::drift(b, now);
                FrameDecision {
                    frame,
                    action: FrameAction::Refit,
                    structure: s,
                    update_ms: r.refit_ns_per_triangle * now.scene_triangles() as f64 * 1e-6,
                    trace_ms: p.trace_ms * (1.0 + r.sah_growth_per_drift.max(0.0) * d),
                    drift: d,
                }
            }),
            _ => None,
        };
        Some(match refit {
            Some(r) if r.update_ms + r.trace_ms < rebuild.update_ms + rebuild.trace_ms => r,
            _ => rebuild,
        })
    }
}

/// The calibrated policy (see the module docs). Needs the scene's features (`SceneSummary::with_features`);
/// without them it falls back to the thesis policy and says so in the reasons.
#[derive(Clone, Debug)]
pub struct CalibratedPolicy {
    /// The cost model.
    pub model: CostModel,
    /// Rays of the workload per frame and their kind.
    pub kind: crate::geom::WorkloadKind,
    /// Rays per frame (for shadow and diffuse rays the secondary rays traced, not the image's pixels; see
    /// [`crate::select::TargetWorkload::rays_per_frame`]).
    pub rays_per_frame: u64,
    /// Frames of a static scene rendered with one build (animations: one frame per characterized frame, rebuilt or
    /// refitted every frame).
    pub frames: u64,
    /// Relative margin within which the cheaper build wins (default 0.05).
    pub tie_margin: f64,
    /// Weigh the driver's acceleration structures too (the device traces with ray queries), when the model has
    /// them ([`crate::cost::CostModel::driver`]); default `false`.
    pub driver: bool,
    /// The engine's camera, when it gives one: the first frame's predictions read its [`ViewFeatures`] (a model
    /// calibrated with views weighs them; see [`crate::cost::view`]). `None` (the default): the framing camera of
    /// the scene's bounds, the oracle's default. The per-frame rule of an animation ([`FrameRule`]) reads it only
    /// through the overlap floor's crossings ([`CalibratedPolicy::crossings`]).
    pub camera: Option<crate::geom::Camera>,
    /// The structures the caller can build (empty, the default: every calibrated one).
    pub structures: Vec<StructureName>,
}

impl CalibratedPolicy {
    /// The default [`CalibratedPolicy::tie_margin`].
    pub const DEFAULT_TIE_MARGIN: f64 = 0.05;

    /// A policy for `rays_per_frame` rays of `kind` over `frames` frames of a static scene (one build).
    pub fn new(model: CostModel, kind: crate::geom::WorkloadKind, rays_per_frame: u64, frames: u64) -> Self {
        CalibratedPolicy {
            model,
            kind,
            rays_per_frame,
            frames: frames.max(1),
            tie_margin: Self::DEFAULT_TIE_MARGIN,
            driver: false,
            camera: None,
            structures: Vec::new(),
        }
    }

    /// The workload a scene of `frame_count` frames implies.
    pub fn workload(&self, frame_count: usize) -> Workload {
        if frame_count > 1 {
            let f = frame_count as u64;
            Workload { kind: self.kind, rays_per_frame: self.rays_per_frame, frames: f, builds: f, view: None }
        } else {
            Workload {
                kind: self.kind,
                rays_per_frame: self.rays_per_frame,
                frames: self.frames,
                builds: 1,
                view: None,
            }
        }
    }

    /// Predictions for a scene (first frame's features), `None` without features; with the mesh's
    /// [`crate::select::BuildBounds`], the hierarchies' tests per ray are floored by the overlap
    /// (`crate::cost::overlap_floor`).
    pub fn predictions(&self, scene: &SceneSummary<'_>) -> Option<Vec<Prediction>> {
        let f = scene.features.first()?;
        let mut w = self.workload(scene.features.len());
        w.view = self.camera.map(|c| ViewFeatures::of(&c, f.lo, f.hi));
        let crossings = self.crossings(scene);
        // A static scene's grid counted exactly is priced by its references (an animation's builds are priced by the
        // law in `n`, as its frames' counts differ).
        let grid_work = scene
            .build_bounds
            .as_ref()
            .and_then(|b| b.grid_build_work())
            .filter(|_| scene.features.len() == 1)
            .unwrap_or(0.0);
        let bounds = &self.model.count_bounds;
        let mut preds =
            self.model.predict_floored(f, &w, &|s| priced_floor(bounds, s, self.kind, crossings, grid_work));
        if let (Some(r), Some(t)) = (&self.model.timed, self.timed_probes(scene)) {
            crate::cost::timed::blend(&mut preds, t, r, &w);
        }
        Some(preds)
    }

    /// The timed probes the policy blends in ([`crate::select::BuildBounds::timed`]): those of a static scene's
    /// bounds, when taken and the model has their ratios ([`crate::cost::CostModel::timed`]); `None` otherwise.
    pub fn timed_probes<'s>(&self, scene: &'s SceneSummary<'_>) -> Option<&'s [crate::cost::timed::TimedProbe]> {
        let t = &scene.build_bounds.as_ref()?.timed;
        (scene.features.len() == 1 && self.model.timed.is_some() && !t.is_empty()).then_some(t.as_slice())
    }

    /// The per-frame plan of an animation's frames ([`plan_frames`] with this policy's settings and the first
    /// frame's crossings).
    fn plan(&self, scene: &SceneSummary<'_>) -> Vec<FrameDecision> {
        plan_frames(&self.model, scene.features, self.kind, self.rays_per_frame, self.tie_margin, self.crossings(scene))
    }

    /// The triangle boxes a ray of the workload crosses in the scene's first frame
    /// (`crate::cost::Crossings::for_workload` with [`CalibratedPolicy::camera`]), `None` without the mesh's
    /// [`crate::select::BuildBounds`] or features.
    pub fn crossings(&self, scene: &SceneSummary<'_>) -> Option<RayCrossings> {
        let f = scene.features.first()?;
        let c = scene.build_bounds.as_ref()?.box_crossings?;
        Some(c.for_workload(self.kind, self.camera.as_ref(), f.lo, f.hi))
    }
}

impl Policy for CalibratedPolicy {
    fn name(&self) -> &str {
        "calibrated"
    }

    fn select(&self, scene: &SceneSummary<'_>) -> Selection {
        let Some(preds) = self.predictions(scene) else {
            let mut s = ThesisPolicy::default().select(scene);
            s.reasons.insert(
                0,
                Reason::new(
                    ReasonKind::Fallback,
                    "calibrated policy: no features for this scene, the thesis policy decides",
                ),
            );
            return s;
        };
        let w = self.workload(scene.features.len());
        let excluded = scene.exclusions();
        let all = preds;
        let preds: Vec<Prediction> = all
            .iter()
            .filter(|p| !excluded.iter().any(|e| e.structure == p.structure))
            .filter(|p| self.structures.is_empty() || self.structures.contains(&p.structure))
            .copied()
            .collect();
        let Some(choice) = choose(&preds, self.tie_margin) else {
            let mut s = ThesisPolicy::default().select(scene);
            s.reasons.insert(
                0,
                Reason::new(
                    ReasonKind::Fallback,
                    "calibrated policy: the model predicts nothing, the thesis policy decides",
                ),
            );
            return s;
        };
        let best = preds.iter().map(|p| p.total_ms).fold(f64::INFINITY, f64::min);
        let mut reasons = vec![Reason::new(
            ReasonKind::Choice { structure: choice },
            format!(
            "calibrated cost model ({}{}; total fit error {:.0}% RMS) for {} {} rays/frame x {} frame(s), {} build(s), \
             n = {}: {choice} has the smallest predicted total{}",
            self.model.device,
            self.model.chosen_as.as_ref().map(|c| format!("; {c}")).unwrap_or_default(),
            100.0 * self.model.total_rms_log,
            self.rays_per_frame,
            self.kind.as_str(),
            w.frames,
            w.builds,
            scene.features[0].scene_triangles(),
            if preds.iter().any(|p| p.structure == choice && p.total_ms > best) {
                format!(" within {:.0}% and the cheapest build", 100.0 * self.tie_margin)
            } else {
                String::new()
            }
        ),
        )];
        if let Some(r) = margin_reason(&self.model, &preds, choice) {
            reasons.push(r);
        }
        if let Some(t) = self.timed_probes(scene) {
            let timed: Vec<String> = t
                .iter()
                .map(|p| {
                    let ns = p.ns_per_ray(self.kind).map_or_else(|| "no rays".into(), |ns| format!("{ns:.0} ns/ray"));
                    format!("{} {:.2} ms, {ns}", p.structure, p.build_ms)
                })
                .collect();
            reasons.push(Reason::new(
                ReasonKind::Inquiry { level: Level::Timed, taken: true },
                format!(
                "timed probes (one build each, the fastest of up to {} single-threaded traces of a {}x{} sample of \
                 {} rays): {}; blended into the predictions (geometric mean of each build and time per ray with \
                 the probe's times the calibration's ratios, fitted on {} records): not deterministic",
                crate::cost::timed::TIMED_REPEATS,
                crate::cost::timed::TIMED_SIDE,
                crate::cost::timed::TIMED_SIDE,
                self.kind.as_str(),
                timed.join(", "),
                self.model.timed.as_ref().map_or(0, |r| r.records)
            ),
            ));
        } else if scene.build_bounds.as_ref().is_some_and(|b| !b.timed.is_empty()) {
            reasons.push(Reason::new(
                ReasonKind::Inquiry { level: Level::Timed, taken: true },
                "timed probes: taken, but not blended in (this calibration has no timed-probe ratios, or the scene \
                 is an animation)",
            ));
        }
        if let Some(c) = &self.camera {
            let f = &scene.features[0];
            let v = ViewFeatures::of(c, f.lo, f.hi);
            let reads = self.model.structures.iter().any(|s| !s.view_box_coef.is_empty());
            reasons.push(Reason::new(
                ReasonKind::View,
                format!(
                    "view: eye {} the bounds, {:.0}% of the image on them, {:.2} half-diagonals from the centre{}",
                    if v.eye_inside { "inside" } else { "outside" },
                    100.0 * v.coverage,
                    v.distance,
                    if reads {
                        ""
                    } else {
                        " (this calibration was fitted without views: the view changes no prediction)"
                    }
                ),
            ));
        }
        if let Some(c) = self.crossings(scene) {
            let probed: Vec<String> = crate::cost::PROBED
                .iter()
                .filter_map(|&s| {
                    let p = c.probe(s)?;
                    Some(format!(
                        "{s} {:.1} +- {:.1} box and {:.2} +- {:.2} triangle tests/ray",
                        p.box_tests.mean,
                        2.0 * p.box_tests.standard_error,
                        p.prim_tests.mean,
                        2.0 * p.prim_tests.standard_error
                    ))
                })
                .collect();
            if let Some(rays) = crate::cost::PROBED.iter().find_map(|&s| c.probe(s)).map(|p| p.box_tests.rays) {
                let sharing: Vec<String> = crate::cost::SHARES_PROBES.iter().map(|s| s.to_string()).collect();
                let held = if self.model.own_probe_band() == 0.0 {
                    "each structure's counts below are held there"
                } else {
                    "each structure's counts below are held there where its laws miss by more than their own error"
                };
                reasons.push(Reason::new(
                    ReasonKind::Inquiry { level: Level::Counted, taken: true },
                    format!(
                    "probes: built and traced on {rays} sample {} rays of the view: {} (two standard errors; {held}, \
                     and where a hierarchy's are held the {} {} the probed hierarchies' correction; the grid's box \
                     tests are cells)",
                    self.kind.as_str(),
                    probed.join(", "),
                    sharing.join(" and "),
                    if sharing.len() == 1 { "takes" } else { "take" }
                ),
                ));
            }
            // The probes' builds price the structures' builds where the calibration has a work law.
            let n_tris = scene.features[0].scene_triangles();
            let by_work: Vec<String> = crate::cost::PROBED
                .iter()
                .filter(|&&s| c.build_work(s) > 0.0)
                .filter(|&&s| self.model.get(s).is_some_and(|m| !m.build_work_coef.is_empty()))
                .map(|&s| format!("{s} {:.1}", c.build_work(s) / n_tris.max(1) as f64))
                .collect();
            if !by_work.is_empty() {
                reasons.push(Reason::new(
                    ReasonKind::Inquiry { level: Level::Counted, taken: true },
                    format!(
                        "builds priced by the probes' work (references times the levels they were handled on, per \
                         triangle): {}",
                        by_work.join(", ")
                    ),
                ));
            }
        }
        for e in &excluded {
            reasons.push(Reason::new(ReasonKind::Excluded, format!("excluded before choosing: {}", e.reason)));
        }
        let mut sorted = all.clone();
        sorted.sort_by(|a, b| a.total_ms.total_cmp(&b.total_ms));
        for p in &sorted {
            let kind = ReasonKind::Prediction { structure: p.structure, total_ms: p.total_ms };
            reasons.push(Reason::new(
                kind,
                format!(
                "{}: predicted build {:.2} ms ({} x {:.2}), trace {:.2} ms ({:.1} ns/ray: {:.1} box + {:.2} triangle \
                 tests/ray), total {:.2} ms",
                p.structure,
                p.build_ms,
                w.builds,
                p.build_ms_per_build,
                p.trace_ms,
                p.trace_ns_per_ray,
                p.box_tests_per_ray,
                p.prim_tests_per_ray,
                p.total_ms
            ),
            ));
        }
        if scene.features.len() > 1 {
            let plan = self.plan(scene);
            let refits = plan.iter().filter(|d| d.action == FrameAction::Refit).count();
            let total: f64 = plan.iter().map(|d| d.update_ms + d.trace_ms).sum();
            reasons.push(Reason::new(
                ReasonKind::Plan,
                format!(
                    "per frame: {} rebuild(s), {refits} refit(s), predicted {total:.2} ms in all: {}",
                    plan.len() - refits,
                    plan.iter()
                        .map(|d| format!("{}:{} {} (drift {:.3})", d.frame, d.action, d.structure, d.drift))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
        let mut driver = None;
        if self.driver {
            let own = preds.iter().find(|p| p.structure == choice).map(|p| {
                let t = planned_total(
                    &self.model,
                    scene.features,
                    self.kind,
                    self.rays_per_frame,
                    self.tie_margin,
                    self.crossings(scene),
                );
                (choice, t.unwrap_or(p.total_ms))
            });
            match super::driver::choose_driver(&self.model, scene.features, &w, own) {
                Some((d, r)) => {
                    reasons.extend(r);
                    driver = Some(d);
                }
                None => reasons.push(Reason::new(
                    ReasonKind::Driver,
                    format!(
                        "the driver's acceleration structures are not weighed: the cost model ({}) has not calibrated \
                         them",
                        self.model.device
                    ),
                )),
            }
        }
        Selection { structure: choice, reasons, excluded, driver }
    }
}

/// How far the choice stands from the next structure the policy could have chosen, against the calibration's
/// errors: `margin: the next, S, is predicted R x the chosen's total; ...`, the ratio set beside the two
/// structures' fit errors of the total ([`crate::cost::FitError::total`], RMS of `ln(predicted / measured)` on the
/// calibration records, in sample, so a lower bound of the error on an unseen scene): a close call where the log of
/// the ratio is below the two errors combined (`sqrt(e1^2 + e2^2)`). `None` with a single candidate.
pub(crate) fn margin_reason(model: &CostModel, preds: &[Prediction], choice: StructureName) -> Option<Reason> {
    let chosen = preds.iter().find(|p| p.structure == choice)?;
    let next = preds
        .iter()
        .filter(|p| p.structure != choice && p.total_ms.is_finite())
        .min_by(|a, b| a.total_ms.total_cmp(&b.total_ms))?;
    let ratio = next.total_ms / chosen.total_ms;
    let err = |s: StructureName| model.get(s).map_or(0.0, |m| m.fit.total);
    let (e1, e2) = (err(choice), err(next.structure));
    let combined = (e1 * e1 + e2 * e2).sqrt();
    let close_call = ratio.ln().abs() < combined;
    let verdict = if close_call {
        "a close call: the margin is within the two predictions' errors combined"
    } else {
        "the margin exceeds the two predictions' errors combined"
    };
    let kind = ReasonKind::Margin { runner_up: next.structure, ratio, close_call };
    Some(Reason::new(
        kind,
        format!(
            "margin: the next, {}, is predicted {ratio:.2}x the {choice}'s total; the calibration's fit errors of the \
         total (RMS, in sample) are {:.0}% ({choice}) and {:.0}% ({}): {verdict}",
            next.structure,
            100.0 * e1,
            100.0 * e2,
            next.structure
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::characterize::{features_cpu, Params};
    use crate::geom::WorkloadKind;
    use crate::mesh::generate;

    fn exploding_features() -> Vec<Features> {
        let anim = generate::explode(&generate::random_soup(400, 3), 5, 1).expect("animation");
        anim.frames.iter().map(|m| features_cpu(m, &Params::default()).expect("features")).collect()
    }

    #[test]
    fn frame_rule_rebuilds_without_a_tree_with_its_structures_and_sees_no_drift_in_the_same_scene() {
        let model = CostModel::shipped().expect("shipped model");
        let f = exploding_features();
        let only = [StructureName::Lbvh];
        let rule = FrameRule {
            model: &model,
            kind: WorkloadKind::Primary,
            rays_per_frame: 1 << 20,
            tie_margin: 0.05,
            structures: &only,
            crossings: None,
        };
        let first = rule.decide(0, &f[0], None).expect("a decision");
        assert_eq!((first.frame, first.action, first.structure), (0, FrameAction::Rebuild, StructureName::Lbvh));
        let same = rule.decide(1, &f[0], Some((&f[0], StructureName::Lbvh))).expect("a decision");
        assert_eq!(same.frame, 1);
        if same.action == FrameAction::Refit {
            assert_eq!((same.structure, same.drift), (StructureName::Lbvh, 0.0));
        }
        let later = rule.decide(4, &f[4], Some((&f[0], StructureName::Lbvh))).expect("a decision");
        let drift = crate::cost::drift(&f[0], &f[4]);
        assert!(drift > 0.0, "an explosion drifts");
        if later.action == FrameAction::Refit {
            assert_eq!(later.drift, drift);
        }
        // A structure the model does not predict: no decision.
        let none: Vec<StructureName> = Vec::new();
        let model_without = CostModel {
            structures: model.structures.iter().filter(|s| s.structure != StructureName::Lbvh).cloned().collect(),
            ..model.clone()
        };
        let rule = FrameRule { model: &model_without, structures: &only, ..rule };
        assert!(rule.decide(0, &f[0], None).is_none());
        let rule = FrameRule { structures: &none, ..rule };
        assert!(rule.decide(0, &f[0], None).is_some(), "an empty list allows every calibrated structure");
    }

    #[test]
    fn plan_frames_is_frame_rule_over_every_structure() {
        let model = CostModel::shipped().expect("shipped model");
        let f = exploding_features();
        let plan = plan_frames(&model, &f, WorkloadKind::Primary, 1 << 20, 0.05, None);
        assert_eq!(plan.len(), f.len());
        let rule = FrameRule {
            model: &model,
            kind: WorkloadKind::Primary,
            rays_per_frame: 1 << 20,
            tie_margin: 0.05,
            structures: &[],
            crossings: None,
        };
        let mut built: Option<usize> = None;
        for (i, d) in plan.iter().enumerate() {
            let tree = built.map(|b| (&f[b], plan[b].structure));
            assert_eq!(Some(d.clone()), rule.decide(i, &f[i], tree), "frame {i}");
            if d.action == FrameAction::Rebuild {
                built = Some(i);
            }
        }
        assert_eq!(plan[0].action, FrameAction::Rebuild);
    }
}
