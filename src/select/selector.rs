//! The one entry of the selection: a [`Selector`] (what to choose for: model, workload, budgets, how far to
//! inquire) and its [`Decision`] for a scene.
//!
//! The calibrated policy decides on a ladder of inquiry. Level 0, the prior: the fitted laws read the
//! characterization's features, and nothing is built. Level 1: the mesh's crossings and count probes (chosen
//! structures built and traced on a small sample of the view's rays). Level 2: timed probes. Level 3: the close
//! call measured over whole frames. Under [`Inquiry::Auto`] the selector climbs one level only when the expected
//! gain of knowing more ([`super::ladder`]: the margin's uncertainty, from the calibration's own held-out errors,
//! over the workload's predicted frames) exceeds that level's predicted cost, and never past the decision budget
//! (a share of the predicted frames). [`Inquiry::Fixed`] climbs to a level whatever it costs (for studies, and for
//! callers that know their scene is worth it).

use super::budget::{Budget, BuildBounds};
use super::climb::{climb, MeshKnowledge};
use super::ladder::{expected_gain, Candidate};
use super::{CalibratedPolicy, Policy as _, SceneKind, SceneSummary, Structure, TargetWorkload};
use crate::characterize::{Characterization, Features};
use crate::cost::measured::MeasuredTotal;
use crate::cost::{CostModel, Prediction, PROBED};
use crate::mesh::Mesh;

/// How much a decision knows, from the fitted laws alone up to a measurement.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Level {
    /// The fitted laws on the characterization's features; nothing built.
    #[default]
    Prior = 0,
    /// The mesh's crossings and count probes on a small sample of rays.
    Counted = 1,
    /// Timed probes blended into the predictions.
    Timed = 2,
    /// The close call built and traced over whole frames.
    Measured = 3,
}

impl Level {
    /// The level's number, 0 to 3.
    pub fn number(self) -> u8 {
        self as u8
    }

    /// The level numbered `n` (0 to 3).
    pub fn from_number(n: u8) -> Option<Level> {
        [Level::Prior, Level::Counted, Level::Timed, Level::Measured].get(usize::from(n)).copied()
    }
}

impl std::fmt::Display for Level {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = match self {
            Level::Prior => "prior",
            Level::Counted => "count probes",
            Level::Timed => "timed probes",
            Level::Measured => "measured close call",
        };
        write!(f, "level {} ({name})", self.number())
    }
}

/// How far a decision inquires beyond the prior.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Inquiry {
    /// Climb while the expected gain exceeds the predicted cost, within [`Selector::decision_budget`], up to
    /// [`Selector::max_level`] (the default).
    Auto,
    /// Climb to this level, whatever it costs.
    Fixed(Level),
}

/// Which rules decide.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Policy {
    /// The thesis's rules on the characterization's statistics.
    Thesis,
    /// Predicted build and trace times from the cost model, on the ladder of inquiry.
    #[default]
    Calibrated,
}

impl Policy {
    /// `thesis` or `calibrated`.
    pub fn name(self) -> &'static str {
        match self {
            Policy::Thesis => "thesis",
            Policy::Calibrated => "calibrated",
        }
    }
}

/// What to choose for, and how far to inquire: the single entry of the selection. Public fields with defaults
/// ([`Selector::new`]); [`Selector::select`] decides.
#[derive(Clone, Debug)]
pub struct Selector<'m> {
    /// The calibration.
    pub model: &'m CostModel,
    /// Thesis or calibrated.
    pub policy: Policy,
    /// The rays, frames and camera.
    pub workload: TargetWorkload,
    /// What the grid and the kd-tree may need before they are no candidates.
    pub budget: Budget,
    /// How far to inquire.
    pub inquiry: Inquiry,
    /// Under [`Inquiry::Auto`], the most the inquiry beyond the prior may cost, as a share of the chosen
    /// structure's predicted total over the workload's frames (0.01).
    pub decision_budget: f64,
    /// Under [`Inquiry::Auto`], the highest level climbed.
    pub max_level: Level,
    /// The structures the caller can build (empty: every calibrated one), for instance those an engine builds on
    /// its device.
    pub structures: Vec<Structure>,
    /// Relative margin within which the cheaper build wins.
    pub tie_margin: f64,
    /// The side of the square image a measured close call traces (the workload's resolution).
    pub resolution: u32,
    /// Under [`Inquiry::Fixed`], the most a measured close call may cost by its prediction, ms (one predicted to
    /// take longer is not measured); infinite by default.
    pub max_inquiry_ms: f64,
}

/// The default [`Selector::decision_budget`].
pub const DEFAULT_DECISION_BUDGET: f64 = 0.01;

impl<'m> Selector<'m> {
    /// The calibrated policy on the ladder with its defaults: [`Inquiry::Auto`], the default budgets, every
    /// structure, [`CalibratedPolicy::DEFAULT_TIE_MARGIN`], a 1024 x 1024 image.
    pub fn new(model: &'m CostModel, workload: TargetWorkload) -> Self {
        Selector {
            model,
            policy: Policy::Calibrated,
            workload,
            budget: Budget::default(),
            inquiry: Inquiry::Auto,
            decision_budget: DEFAULT_DECISION_BUDGET,
            max_level: Level::Measured,
            structures: Vec::new(),
            tie_margin: CalibratedPolicy::DEFAULT_TIE_MARGIN,
            resolution: 1024,
            max_inquiry_ms: f64::INFINITY,
        }
    }

    /// Decides for `scene`: the thesis's rules, or the calibrated policy on the ladder (a static scene's mesh in
    /// [`Scene::meshes`] lets it climb; without one, or for an animation, it decides on the prior, and for an
    /// animation plans each frame).
    pub fn select(&self, scene: &Scene<'_>) -> Decision {
        let kind = if scene.characterizations.len() > 1 { SceneKind::Dynamic } else { SceneKind::Static };
        if self.policy == Policy::Thesis {
            let bounds = if scene.meshes.is_empty() {
                None
            } else {
                BuildBounds::of_frames_probed(scene.meshes, self.workload.camera.as_ref(), &self.budget, &[])
                    .ok()
                    .flatten()
            };
            let summary = self.summary(scene, bounds);
            let mut selection = super::ThesisPolicy::default().select(&summary);
            if let Inquiry::Fixed(asked) = self.inquiry {
                if asked >= Level::Timed {
                    selection.reasons.push(super::Reason::new(
                        super::ReasonKind::Inquiry { level: Level::Timed, taken: false },
                        "timed probes: none taken: the thesis policy predicts no times",
                    ));
                }
                if asked >= Level::Measured {
                    selection.reasons.push(super::Reason::new(
                        super::ReasonKind::Inquiry { level: Level::Measured, taken: false },
                        "measured close call: none: the thesis policy predicts no times",
                    ));
                }
            }
            return Decision {
                policy: Policy::Thesis,
                kind,
                level: Level::Prior,
                selection,
                predicted: None,
                measured: Vec::new(),
                steps: Vec::new(),
                inquiry_ms: 0.0,
                characterized: true,
            };
        }
        if let Some(decision) = self.decide_by_size(scene, kind) {
            return decision;
        }
        let mut known = MeshKnowledge::new(self, scene);
        let climb = climb(self, &mut known);
        let summary = self.summary(scene, known.bounds.clone());
        let policy = self.calibrated();
        let mut selection = policy.select(&summary);
        let predicted = policy.predictions(&summary);
        if let Some(best) = climb.measured.iter().min_by(|a, b| a.total_ms.total_cmp(&b.total_ms)) {
            selection.structure = best.structure;
        }
        // The policy's own reasons first (docs/spec.md: the choice, then the margin), then the ladder's.
        let ladder = climb.reasons(self, selection.structure);
        selection.reasons.extend(ladder);
        Decision {
            policy: Policy::Calibrated,
            kind,
            level: climb.level,
            selection,
            predicted,
            measured: climb.measured,
            steps: climb.steps,
            inquiry_ms: known.spent_ms,
            characterized: true,
        }
    }

    /// The rung below level 0, for a static scene of `n` triangles: the structures predicted by the triangle count
    /// alone, and whether characterizing the mesh is worth its cost. The expected gain is the ladder's (`select::ladder`),
    /// with each prediction off by the calibration's held-out error of the size laws and, after the inquiry, by
    /// that of level 0, or of level 1 (the count probes the characterization opens), whichever nets more; the
    /// cost is the characterization's and the features' (and the crossings' and probes') by the stage laws.
    /// Characterizing pays when the gain exceeds the cost and the cost stays within [`Selector::decision_budget`]
    /// of the least predicted total. `None` where the rung does not apply: a fixed level or the thesis policy, the
    /// driver's structures weighed, a camera given ([`TargetWorkload::camera`]: the size laws know only the framing
    /// one), or a calibration without size laws, their errors or the stage laws.
    pub fn size_rung(&self, n: u64) -> Option<SizeRung> {
        // The size laws are of the framing camera: an engine's own camera is a view they cannot read.
        if self.policy != Policy::Calibrated
            || self.inquiry != Inquiry::Auto
            || self.workload.driver
            || self.workload.camera.is_some()
        {
            return None;
        }
        let w = self.calibrated().workload(1);
        let preds: Vec<Prediction> = self
            .model
            .predict_size(n, &w)?
            .into_iter()
            .filter(|p| self.structures.is_empty() || self.structures.contains(&p.structure))
            .collect();
        let u = self.model.uncertainty.as_ref()?;
        let candidates: Vec<Candidate> = preds
            .iter()
            .map(|p| {
                let e = u.of(p.structure);
                Some(Candidate {
                    total_ms: p.total_ms,
                    sigma: e.and_then(|e| e.size)?,
                    sigma_after: Some(e.map(|e| e.prior)?),
                })
            })
            .collect::<Option<_>>()?;
        let base_ms = self.stage_ms("characterize", n)? + self.stage_ms("features", n)?;
        let least = preds.iter().map(|p| p.total_ms).fold(f64::INFINITY, f64::min);
        let allowed_ms = self.decision_budget * least;
        // Characterizing is worth it for what it tells (level 0) or for what it opens: the count probes (level
        // 1), each weighed by its gain over the size laws less everything it costs from here.
        let mut options = vec![(expected_gain(&candidates), base_ms)];
        let probed: Vec<Candidate> = preds
            .iter()
            .zip(&candidates)
            .map(|(p, c)| {
                let e = u.of(p.structure);
                let after = if PROBED.contains(&p.structure) { e.map(|e| e.probed) } else { e.map(|e| e.crossings) };
                Candidate { sigma_after: after, ..*c }
            })
            .collect();
        let probes: Option<f64> =
            PROBED.iter().map(|s| self.stage_ms(&format!("probe:{}", s.as_str()), n)).sum::<Option<f64>>();
        if let (Some(c), Some(p)) = (self.stage_ms("crossings", n), probes) {
            options.push((expected_gain(&probed), base_ms + c + p));
        }
        let (gain_ms, cost_ms) =
            options.into_iter().max_by(|a, b| (a.0 - a.1).total_cmp(&(b.0 - b.1))).unwrap_or((0.0, base_ms));
        let structure = super::choose(&preds, self.tie_margin);
        // The grid and the kd-tree are candidates only within the build budget (`budget`), which their references
        // on the mesh decide: a size choice of either is no choice before they are known.
        let budgeted = matches!(structure, Some(Structure::Grid | Structure::KdTree));
        let characterize = budgeted || (gain_ms > cost_ms && cost_ms <= allowed_ms);
        Some(SizeRung { predicted: preds, structure, gain_ms, cost_ms, allowed_ms, characterize })
    }

    /// The decision on the triangle count alone, where the size rung says characterizing does not pay (a static
    /// scene under [`Inquiry::Auto`]); `None` otherwise.
    fn decide_by_size(&self, scene: &Scene<'_>, kind: SceneKind) -> Option<Decision> {
        if kind != SceneKind::Static {
            return None;
        }
        let n = scene.features.first().map(|f| f.scene_triangles())?;
        let rung = self.size_rung(n)?;
        let structure = rung.structure.filter(|_| !rung.characterize)?;
        let why = if rung.gain_ms <= rung.cost_ms {
            format!("its expected gain {:.3} ms is below its predicted cost {:.3} ms", rung.gain_ms, rung.cost_ms)
        } else {
            format!(
                "its predicted cost {:.3} ms is over the decision budget ({:.3} ms, {:.2}% of the least predicted total)",
                rung.cost_ms,
                rung.allowed_ms,
                100.0 * self.decision_budget
            )
        };
        let w = &self.workload;
        let mut reasons = vec![super::Reason::new(
            super::ReasonKind::Choice { structure },
            format!(
            "calibrated cost model ({}{}) on the triangle count alone for {} {} rays/frame x {} frame(s), n = {n}: \
             {structure} has the smallest predicted total; characterizing the mesh does not pay here: {why}",
            self.model.device,
            self.model.chosen_as.as_ref().map(|c| format!("; {c}")).unwrap_or_default(),
            w.rays_per_frame,
            w.kind.as_str(),
            w.frames.max(1),
        ),
        )];
        reasons.extend(super::calibrated::margin_reason(self.model, &rung.predicted, structure));
        for p in &rung.predicted {
            let kind = super::ReasonKind::Prediction { structure: p.structure, total_ms: p.total_ms };
            reasons.push(super::Reason::new(
                kind,
                format!(
                    "{}: predicted build {:.3} ms, trace {:.3} ms, total {:.3} ms (size laws)",
                    p.structure, p.build_ms, p.trace_ms, p.total_ms
                ),
            ));
        }
        Some(Decision {
            policy: Policy::Calibrated,
            kind,
            level: Level::Prior,
            selection: super::Selection { structure, reasons, excluded: Vec::new(), driver: None },
            predicted: Some(rung.predicted),
            measured: Vec::new(),
            steps: Vec::new(),
            inquiry_ms: 0.0,
            characterized: false,
        })
    }

    /// The calibrated policy this selector runs.
    pub(super) fn calibrated(&self) -> CalibratedPolicy {
        let w = &self.workload;
        let mut p = CalibratedPolicy::new(self.model.clone(), w.kind, w.rays_per_frame, w.frames);
        p.tie_margin = self.tie_margin;
        p.driver = w.driver;
        p.camera = w.camera;
        p.structures = self.structures.clone();
        p
    }

    /// The summary a policy reads: the frames the run covers (a static scene's one; an animation's first
    /// `animation_frames`), their features, the budget and the bounds known.
    pub(super) fn summary<'s>(&self, scene: &Scene<'s>, bounds: Option<BuildBounds>) -> SceneSummary<'s> {
        let (frames, features) = (scene.characterizations, scene.features);
        let used = if frames.len() > 1 { self.workload.animation_frames.unwrap_or(frames.len()) } else { 1 };
        let used = used.clamp(1, frames.len().min(features.len()).max(1)).min(frames.len()).min(features.len());
        let used = if self.policy == Policy::Thesis { frames.len() } else { used };
        let s = SceneSummary::new(scene.name, &frames[..used.min(frames.len())])
            .with_features(&features[..used.min(features.len())])
            .with_budget(self.budget);
        match bounds {
            Some(b) => s.with_build_bounds(b),
            None => s,
        }
    }

    /// The predicted ms of inquiry stage `stage` for this scene, by the calibration's law ([`InquiryCost`]).
    pub(super) fn stage_ms(&self, stage: &str, n: u64) -> Option<f64> {
        self.model.inquiry_ms(stage, n)
    }
}

/// A scene as the selection sees it.
#[derive(Clone, Copy, Debug)]
pub struct Scene<'a> {
    /// Its name (a file, a directory).
    pub name: &'a str,
    /// The characterization of every frame.
    pub characterizations: &'a [Characterization],
    /// The features of every frame.
    pub features: &'a [Features],
    /// The meshes of the frames, when the caller has them on the host: the ladder's upper levels build and trace
    /// on them (empty: the prior decides).
    pub meshes: &'a [Mesh],
}

/// A decision and how it was reached.
#[derive(Clone, Debug, PartialEq)]
pub struct Decision {
    /// The policy that decided.
    pub policy: Policy,
    /// Static or dynamic.
    pub kind: SceneKind,
    /// The level that decided.
    pub level: Level,
    /// The structure, the reasons, the exclusions and the driver's side.
    pub selection: super::Selection,
    /// The predictions at the level that decided (`None` for the thesis policy).
    pub predicted: Option<Vec<Prediction>>,
    /// The close call measured (level 3), when measured.
    pub measured: Vec<MeasuredTotal>,
    /// Each level weighed beyond the prior: what it would have cost, what it was expected to gain, whether it was
    /// climbed.
    pub steps: Vec<Step>,
    /// What the inquiry beyond the prior took, wall time, ms.
    pub inquiry_ms: f64,
    /// Whether the decision read the characterization. `false`: the triangle count alone decided
    /// ([`Selector::size_rung`]), and an engine that asks first need not characterize the mesh for it.
    pub characterized: bool,
}

/// The rung below level 0 ([`Selector::size_rung`]): whether characterizing the mesh pays, judged from its
/// triangle count alone.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SizeRung {
    /// Each structure's predicted costs by the size laws (`CostModel::predict_size`).
    pub predicted: Vec<Prediction>,
    /// The choice on these predictions.
    pub structure: Option<Structure>,
    /// Expected gain over the workload, ms (`select::ladder`), of the better of knowing the features (level 0) and
    /// of the count probes that the characterization opens (level 1).
    pub gain_ms: f64,
    /// Predicted cost of that inquiry from here (the characterization and the features, and for the probes the
    /// crossings and every probe too), ms (the calibration's `inquiry_costs`).
    pub cost_ms: f64,
    /// The decision budget over the predicted frames, ms.
    pub allowed_ms: f64,
    /// Whether to characterize: the gain exceeds the cost, within the budget, or the size laws chose the grid or
    /// the kd-tree, which only the mesh's references can admit within the build budget.
    pub characterize: bool,
}

impl Decision {
    /// The chosen structure.
    pub fn structure(&self) -> Structure {
        self.selection.structure
    }
}

/// One level weighed by the ladder.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Step {
    /// The level.
    pub level: Level,
    /// The structures it would build (probes, timed probes, or the close call).
    pub structures: Vec<Structure>,
    /// Expected gain over the workload's frames, ms (`None` when the calibration cannot say).
    pub gain_ms: Option<f64>,
    /// Predicted cost, ms (`None` when the calibration has no law for it).
    pub cost_ms: Option<f64>,
    /// What the budget left for it, ms (`None` under [`Inquiry::Fixed`]).
    pub allowed_ms: Option<f64>,
    /// Whether it was climbed.
    pub taken: bool,
    /// What it took, ms (0 when not taken).
    pub spent_ms: f64,
    /// Why not, when not taken.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub why_not: Option<String>,
}

impl std::fmt::Display for Step {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = self.structures.iter().map(|s| s.as_str()).collect();
        let ms = |x: Option<f64>| x.map_or_else(|| "unknown".to_string(), |v| format!("{v:.3} ms"));
        write!(f, "{}", self.level)?;
        if !names.is_empty() {
            write!(f, " of {}", names.join(", "))?;
        }
        write!(f, ": expected gain {}, predicted cost {}", ms(self.gain_ms), ms(self.cost_ms))?;
        if let Some(a) = self.allowed_ms {
            write!(f, ", budget left {a:.3} ms")?;
        }
        if self.taken {
            write!(f, ": climbed ({:.3} ms)", self.spent_ms)
        } else {
            write!(f, ": not climbed ({})", self.why_not.as_deref().unwrap_or("it does not pay"))
        }
    }
}
