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
use super::ladder::{chance_best, expected_gain, Candidate};
use super::{CalibratedPolicy, Policy as _, SceneKind, SceneSummary, Structure, TargetWorkload};
use crate::characterize::{Characterization, Features};
use crate::cost::measured::{MeasuredTotal, MEASURED_REPEATS, MEASURED_WARMUP};
use crate::cost::{CostModel, InquiryCost, Prediction, PROBED};
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
                    selection.reasons.push("timed probes: none taken: the thesis policy predicts no times".into());
                }
                if asked >= Level::Measured {
                    selection.reasons.push("measured close call: none: the thesis policy predicts no times".into());
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
        let mut reasons = vec![format!(
            "calibrated cost model ({}{}) on the triangle count alone for {} {} rays/frame x {} frame(s), n = {n}: \
             {structure} has the smallest predicted total; characterizing the mesh does not pay here: {why}",
            self.model.device,
            self.model.chosen_as.as_ref().map(|c| format!("; {c}")).unwrap_or_default(),
            w.rays_per_frame,
            w.kind.as_str(),
            w.frames.max(1),
        )];
        reasons.extend(super::calibrated::margin_reason(self.model, &rung.predicted, structure));
        for p in &rung.predicted {
            reasons.push(format!(
                "{}: predicted build {:.3} ms, trace {:.3} ms, total {:.3} ms (size laws)",
                p.structure, p.build_ms, p.trace_ms, p.total_ms
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
    fn calibrated(&self) -> CalibratedPolicy {
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
    fn summary<'s>(&self, scene: &Scene<'s>, bounds: Option<BuildBounds>) -> SceneSummary<'s> {
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
    fn stage_ms(&self, stage: &str, n: u64) -> Option<f64> {
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
    /// Each structure's predicted costs by the size laws ([`crate::cost::CostModel::predict_size`]).
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

/// What the ladder can learn about a scene, and at what cost: the live scene's ([`MeshKnowledge`]) or a record's
/// (the policy comparison's).
pub(crate) trait Knowledge {
    /// The predictions at what is known now (every calibrated structure the budget allows).
    fn predictions(&self) -> Vec<Prediction>;
    /// The scene's triangle count.
    fn triangles(&self) -> u64;
    /// Whether `level` can be climbed at all (a scene at hand; a static one above level 1), and why not.
    fn climbable(&self, level: Level) -> Result<(), String>;
    /// Level 1: the crossings and count probes of `probes`. Returns the ms it took.
    fn count(&mut self, probes: &[Structure]) -> f64;
    /// Level 2: timed probes of `structures`. Returns the ms it took; `None` when nothing could be timed.
    fn time(&mut self, structures: &[Structure]) -> Option<f64>;
    /// Level 3: `structures` measured over whole frames, the ms it took and the scale of the traces (the workload's
    /// rays over the rays measured); `None` when nothing was measured.
    fn measure(&mut self, structures: &[Structure]) -> Option<(Vec<MeasuredTotal>, f64, f64)>;
}

/// The outcome of [`climb`].
pub(crate) struct Climb {
    pub level: Level,
    pub steps: Vec<Step>,
    pub measured: Vec<MeasuredTotal>,
    pub spent_ms: f64,
    pub note: Option<String>,
    /// The scale of a measured close call's traces (the workload's rays over the rays measured).
    pub scale: f64,
    /// The predictions' choice before the close call was measured.
    pub predicted_choice: Option<Structure>,
}

impl Climb {
    fn reasons(&self, s: &Selector<'_>, chosen: Structure) -> Vec<String> {
        let mut out = vec![format!(
            "decided at {} ({}){}",
            self.level,
            match s.inquiry {
                Inquiry::Auto => format!(
                    "climbing only where the expected gain exceeds the predicted cost, within {:.1}% of the \
                     predicted frames",
                    100.0 * s.decision_budget
                ),
                Inquiry::Fixed(l) => format!("asked for {l}"),
            },
            self.note.as_ref().map(|n| format!("; {n}")).unwrap_or_default()
        )];
        for st in &self.steps {
            out.push(st.to_string());
        }
        // A level asked for and not climbed says why, as the level's own line.
        if let Inquiry::Fixed(asked) = s.inquiry {
            for st in self.steps.iter().filter(|st| !st.taken && st.level <= asked) {
                let why = st.why_not.as_deref().unwrap_or("");
                match st.level {
                    Level::Timed => out.push(format!("timed probes: none taken: {why}")),
                    Level::Measured => out.push(format!("measured close call: none: {why}")),
                    _ => {}
                }
            }
        }
        if !self.measured.is_empty() {
            let list: Vec<String> = self
                .measured
                .iter()
                .map(|t| {
                    format!(
                        "{} {:.3} ms (build {:.3}, trace {:.3} per frame)",
                        t.structure, t.total_ms, t.build_ms, t.trace_ms
                    )
                })
                .collect();
            let w = &s.workload;
            let measured: Vec<Structure> = self.measured.iter().map(|t| t.structure).collect();
            out.push(format!(
                "measured close call ({}: each built and traced over whole frames of {}x{} {} rays, the median of \
                 {MEASURED_REPEATS} repeats after {MEASURED_WARMUP} untimed, totals over {} frame(s) of {} rays{}; \
                 not deterministic): {}: {chosen} {}",
                names(&measured),
                s.resolution,
                s.resolution,
                w.kind.as_str(),
                w.frames.max(1),
                w.rays_per_frame,
                if self.scale == 1.0 { String::new() } else { format!(", traces scaled by {:.3}", self.scale) },
                list.join(", "),
                if Some(chosen) == self.predicted_choice {
                    "confirmed"
                } else {
                    "taken instead of the predictions' choice"
                }
            ));
        }
        out
    }
}

/// The structures of `preds` the selector may choose (its [`Selector::structures`], every finite one).
fn allowed<'a>(s: &Selector<'_>, preds: &'a [Prediction]) -> Vec<&'a Prediction> {
    preds
        .iter()
        .filter(|p| p.total_ms.is_finite() && p.total_ms > 0.0)
        .filter(|p| s.structures.is_empty() || s.structures.contains(&p.structure))
        .collect()
}

/// The ladder: from the prior, each level in turn, climbed while it pays (or to the fixed level).
pub(crate) fn climb(s: &Selector<'_>, k: &mut dyn Knowledge) -> Climb {
    let mut out = Climb {
        level: Level::Prior,
        steps: Vec::new(),
        measured: Vec::new(),
        spent_ms: 0.0,
        note: None,
        scale: 1.0,
        predicted_choice: None,
    };
    let (auto, target) = match s.inquiry {
        Inquiry::Auto => (true, s.max_level),
        Inquiry::Fixed(l) => (false, l),
    };
    if target == Level::Prior {
        return out;
    }
    let u = s.model.uncertainty.as_ref();
    if auto && u.is_none() {
        out.note = Some("this calibration has no held-out errors to weigh an inquiry by (calibrate anew)".into());
        return out;
    }
    let n = k.triangles();
    let sigma = |st: Structure, level: usize| -> f64 {
        let Some(x) = u.and_then(|u| u.of(st)) else { return f64::NAN };
        match level {
            0 => x.prior,
            1 => x.crossings,
            2 => x.probed,
            3 => x.timed.unwrap_or(x.probed),
            _ => x.measured.unwrap_or(0.0),
        }
    };
    // Each allowed structure's error now: the prior's, then the probed or the crossings'.
    let mut now: Vec<(Structure, f64)> = Vec::new();
    for level in [Level::Counted, Level::Timed, Level::Measured] {
        if level > target {
            break;
        }
        if let Err(why) = k.climbable(level) {
            if auto {
                out.note = Some(why);
                break;
            }
            out.steps.push(Step {
                level,
                structures: Vec::new(),
                gain_ms: None,
                cost_ms: None,
                allowed_ms: None,
                taken: false,
                spent_ms: 0.0,
                why_not: Some(why),
            });
            continue;
        }
        let preds = k.predictions();
        let cands = allowed(s, &preds);
        if now.is_empty() {
            now = cands.iter().map(|p| (p.structure, sigma(p.structure, 0))).collect();
        }
        let sig = |st: Structure| now.iter().find(|x| x.0 == st).map_or(f64::NAN, |x| x.1);
        let base: Vec<Candidate> = cands
            .iter()
            .map(|p| Candidate { total_ms: p.total_ms, sigma: sig(p.structure), sigma_after: None })
            .collect();
        // The candidates by their chance of being the best, most likely first.
        let chance = chance_best(&base);
        let mut order: Vec<usize> = (0..cands.len()).collect();
        order.sort_by(|&a, &b| chance[b].total_cmp(&chance[a]));
        let chosen_total = cands.iter().map(|p| p.total_ms).fold(f64::INFINITY, f64::min);
        let allowed_ms = (s.decision_budget * chosen_total - out.spent_ms).max(0.0);
        // The options of this level: the structures it would cover, a prefix of `order`.
        let eligible: Vec<usize> = order
            .iter()
            .copied()
            .filter(|&i| match level {
                Level::Counted => PROBED.contains(&cands[i].structure),
                Level::Timed => s.model.timed.as_ref().is_some_and(|r| r.of(cands[i].structure).is_some()),
                _ => true,
            })
            .collect();
        let first = if level == Level::Counted { 0 } else { 2.min(eligible.len()) };
        let cost_of = |set: &[usize]| -> Option<f64> {
            let mut c = 0.0;
            if level == Level::Counted {
                c += s.stage_ms("crossings", n)?;
            }
            for &i in set {
                let p = cands[i];
                c += match level {
                    Level::Counted => s.stage_ms(&InquiryCost::probe_stage(p.structure), n)?,
                    Level::Timed => {
                        let threads = rayon::current_num_threads().max(1) as f64;
                        let side = f64::from(crate::cost::timed::TIMED_SIDE);
                        p.build_ms_per_build
                            + crate::cost::timed::TIMED_REPEATS as f64
                                * side
                                * side
                                * p.trace_ns_per_ray
                                * threads
                                * 1e-6
                    }
                    _ => {
                        let frames = s.workload.frames.max(1) as f64;
                        (MEASURED_WARMUP + MEASURED_REPEATS) as f64 * (p.build_ms_per_build + p.trace_ms / frames)
                    }
                };
            }
            Some(c)
        };
        let gain_of = |set: &[usize]| -> Option<f64> {
            let after: Vec<Candidate> = cands
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let covered = set.contains(&i);
                    let sa = match level {
                        Level::Counted if covered => Some(sigma(p.structure, 2)),
                        Level::Counted => Some(sigma(p.structure, 1)),
                        Level::Timed if covered => Some(sigma(p.structure, 3)),
                        Level::Measured if covered => Some(sigma(p.structure, 4)),
                        _ => None,
                    };
                    Candidate { total_ms: p.total_ms, sigma: sig(p.structure), sigma_after: sa }
                })
                .collect();
            let g = expected_gain(&after);
            after.iter().all(|c| c.sigma.is_finite() && c.sigma_after.is_none_or(f64::is_finite)).then_some(g)
        };
        // Under a fixed level: the structures the earlier rules took (every probe, the contenders, the close call).
        let set: Vec<usize> = if !auto {
            match level {
                Level::Counted => eligible.clone(),
                Level::Timed => {
                    let list: Vec<Prediction> = cands.iter().map(|p| **p).collect();
                    let c = crate::cost::timed::contenders(&list);
                    eligible.iter().copied().filter(|&i| c.contains(&cands[i].structure)).collect()
                }
                _ => {
                    let list: Vec<Prediction> = cands.iter().map(|p| **p).collect();
                    let c = crate::cost::measured::close_calls(&list);
                    (0..cands.len()).filter(|&i| c.contains(&cands[i].structure)).collect()
                }
            }
        } else {
            // The option with the largest expected net gain.
            let mut best: Option<(Vec<usize>, f64)> = None;
            for len in first.max(if level == Level::Counted { 0 } else { 2 })..=eligible.len() {
                let set = &eligible[..len];
                if let (Some(g), Some(c)) = (gain_of(set), cost_of(set)) {
                    if best.as_ref().is_none_or(|b| g - c > b.1) {
                        best = Some((set.to_vec(), g - c));
                    }
                }
            }
            best.map(|b| b.0).unwrap_or_default()
        };
        let mut structures: Vec<Structure> = set.iter().map(|&i| cands[i].structure).collect();
        if !auto && level == Level::Counted {
            // Every probed structure the caller can build: the bounds pass leaves out what the mesh's own bounds
            // exclude (the features' looser bounds may have excluded more).
            structures = PROBED.into_iter().filter(|p| s.structures.is_empty() || s.structures.contains(p)).collect();
        }
        let (gain, cost) = (gain_of(&set), cost_of(&set));
        let mut step = Step {
            level,
            structures: structures.clone(),
            gain_ms: gain,
            cost_ms: cost,
            allowed_ms: auto.then_some(allowed_ms),
            taken: false,
            spent_ms: 0.0,
            why_not: None,
        };
        let why_not = if level == Level::Timed && s.model.timed.is_none() {
            Some("this calibration has no timed-probe ratios (calibrate --from-oracle ... --timed-probes)".to_string())
        } else if level == Level::Measured && structures.len() < 2 {
            Some(format!(
                "no close call (no other structure predicted within {:.0}% of the least)",
                100.0 * crate::cost::measured::CLOSE_CALL_MARGIN
            ))
        } else if level != Level::Counted && structures.len() < 2 {
            Some("fewer than two structures to time".to_string())
        } else if !auto {
            match cost {
                Some(c) if level == Level::Measured && (c.is_nan() || c > s.max_inquiry_ms) => Some(format!(
                    "measuring {} would take about {c:.0} ms by the predictions, over the {:.0} ms allowed",
                    names(&structures),
                    s.max_inquiry_ms
                )),
                _ => None,
            }
        } else {
            match (gain, cost) {
                (None, _) => Some("the calibration has no held-out error for this level".to_string()),
                (_, None) => Some("the calibration has no cost law for this level".to_string()),
                (Some(g), Some(c)) if g <= c => {
                    Some(format!("the expected gain is below the cost ({g:.3} <= {c:.3} ms)"))
                }
                (Some(_), Some(c)) if c > allowed_ms => {
                    Some(format!("over the decision budget ({c:.3} > {allowed_ms:.3} ms)"))
                }
                _ => None,
            }
        };
        if let Some(w) = why_not {
            step.why_not = Some(w);
            out.steps.push(step);
            // A climb stops at the first level that does not pay; a fixed level goes on to the next.
            if auto {
                break;
            }
            continue;
        }
        let spent = match level {
            Level::Counted => Some(k.count(&structures)),
            Level::Timed => k.time(&structures),
            _ => {
                let list: Vec<Prediction> = cands.iter().map(|p| **p).collect();
                out.predicted_choice = super::choose(&list, s.tie_margin);
                k.measure(&structures).map(|(m, ms, scale)| {
                    out.measured = m;
                    out.scale = scale;
                    ms
                })
            }
        };
        let Some(spent) = spent else {
            step.why_not = Some("nothing could be built".into());
            out.steps.push(step);
            break;
        };
        step.taken = true;
        step.spent_ms = spent;
        out.spent_ms += spent;
        out.level = level;
        out.steps.push(step);
        // The errors after the level.
        for (st, e) in now.iter_mut() {
            *e = match level {
                Level::Counted if structures.contains(st) => sigma(*st, 2),
                Level::Counted => sigma(*st, 1),
                Level::Timed if structures.contains(st) => sigma(*st, 3),
                Level::Measured if structures.contains(st) => sigma(*st, 4),
                _ => *e,
            };
        }
        if level == Level::Measured {
            break;
        }
    }
    out
}

/// What a static scene on the host lets the ladder learn: the bounds pass with crossings and probes, timed
/// probes, measured frames.
struct MeshKnowledge<'s, 'm> {
    selector: &'s Selector<'m>,
    scene: Scene<'s>,
    /// The bounds known (`None`: the features' alone).
    bounds: Option<BuildBounds>,
    spent_ms: f64,
}

impl<'s, 'm> MeshKnowledge<'s, 'm> {
    fn new(selector: &'s Selector<'m>, scene: &Scene<'s>) -> Self {
        MeshKnowledge { selector, scene: *scene, bounds: None, spent_ms: 0.0 }
    }
}

impl Knowledge for MeshKnowledge<'_, '_> {
    fn predictions(&self) -> Vec<Prediction> {
        let summary = self.selector.summary(&self.scene, self.bounds.clone());
        let excluded = summary.exclusions();
        let mut p = self.selector.calibrated().predictions(&summary).unwrap_or_default();
        p.retain(|p| !excluded.iter().any(|e| e.structure == p.structure));
        p
    }

    fn triangles(&self) -> u64 {
        self.scene.features.first().map_or(0, |f| f.scene_triangles())
    }

    fn climbable(&self, level: Level) -> Result<(), String> {
        let r = self.selector.resolution;
        let most = crate::cost::measured::MAX_MEASURED_RAYS;
        match self.scene.meshes {
            [] => Err("no mesh at hand: the prior decides".into()),
            _ if self.scene.characterizations.len() > 1 && level > Level::Counted => {
                Err("the scene is an animation".into())
            }
            _ if level == Level::Measured && r == 0 => Err("no rays (resolution 0)".into()),
            _ if level == Level::Measured && u64::from(r).pow(2) > most => {
                Err(format!("{r}x{r} rays per frame, over the {most} a measured frame may hold"))
            }
            _ => Ok(()),
        }
    }

    fn count(&mut self, probes: &[Structure]) -> f64 {
        let t = std::time::Instant::now();
        let s = self.selector;
        self.bounds = BuildBounds::of_frames_probed(self.scene.meshes, s.workload.camera.as_ref(), &s.budget, probes)
            .ok()
            .flatten();
        let ms = t.elapsed().as_secs_f64() * 1e3;
        self.spent_ms += ms;
        ms
    }

    fn time(&mut self, structures: &[Structure]) -> Option<f64> {
        let (Some(b), [mesh]) = (self.bounds.take(), self.scene.meshes) else { return None };
        let t = std::time::Instant::now();
        let s = self.selector;
        let b = b.with_timed_probes(mesh, s.workload.camera.as_ref(), s.workload.kind, structures, &s.budget);
        let timed = !b.timed.is_empty();
        self.bounds = Some(b);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        self.spent_ms += ms;
        timed.then_some(ms)
    }

    fn measure(&mut self, structures: &[Structure]) -> Option<(Vec<MeasuredTotal>, f64, f64)> {
        let [mesh] = self.scene.meshes else { return None };
        let s = self.selector;
        let w = &s.workload;
        let t = std::time::Instant::now();
        let b = crate::cost::timed::mesh_box(mesh);
        let camera = w.camera.unwrap_or_else(|| crate::cost::view::framing_camera(b.min.to_array(), b.max.to_array()));
        let timings =
            crate::cost::measured::measure_frames(mesh, &camera, s.resolution, w.kind, structures, MEASURED_REPEATS);
        let traced = timings.first().map_or(0, |t| t.rays);
        let scale = if traced == 0 { 1.0 } else { w.rays_per_frame as f64 / traced as f64 };
        let totals: Vec<MeasuredTotal> =
            timings.iter().filter_map(|t| MeasuredTotal::of(&t.scaled(scale), 1, w.frames.max(1))).collect();
        let ms = t.elapsed().as_secs_f64() * 1e3;
        self.spent_ms += ms;
        (!totals.is_empty()).then_some((totals, ms, scale))
    }
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
