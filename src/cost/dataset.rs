//! Oracle results as calibration samples, and the policy comparison: in-sample and leave-one-out selection accuracy
//! and regret of the calibrated policy against another policy's recorded selections (the thesis policy's).
//!
//! A [`Sample`] is one scene under one workload: its [`Features`] and what the oracle measured for every structure
//! (from [`crate::eval::SceneEvaluation`] or from a line of `evaluate --json`, so that oracle runs can be cached in a
//! JSONL file and compared without measuring again).
//!
//! **Leave-one-out** ([`compare`]): for every scene, the model is fitted on the samples of all *other* scenes (all
//! workloads of the held-out scene are left out together) and selects for the held-out scene's samples; the regret
//! is then read from the held-out scene's measurements. The in-sample ("calibration") figures fit on everything.

use super::{CostError, CostModel, Workload};
use crate::accel::StructureName;
use crate::characterize::features::FeatureChange;
use crate::characterize::Features;
use crate::eval::SceneEvaluation;
use crate::trace::WorkloadKind;

/// What the oracle measured for one structure, normalized per build and per ray.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Measured {
    /// The structure.
    pub structure: StructureName,
    /// Built, validated and agreed with the reference hits.
    pub valid: bool,
    /// Median total ms of the run.
    pub total_ms: f64,
    /// Median build ms over the run.
    pub build_ms: f64,
    /// Median trace ms over the run.
    pub trace_ms: f64,
    /// Build ms of one build.
    pub build_ms_per_build: f64,
    /// Trace ns per ray.
    pub trace_ns_per_ray: f64,
    /// Box tests per ray.
    pub box_tests_per_ray: f64,
    /// Triangle tests per ray.
    pub prim_tests_per_ray: f64,
    /// Within noise of the best total.
    pub within_noise_of_best: bool,
}

/// One scene under one workload: features and measurements.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Sample {
    /// Scene name (path).
    pub scene: String,
    /// The workload measured.
    pub workload: Workload,
    /// Features of the first frame.
    pub features: Features,
    /// Per structure.
    pub measured: Vec<Measured>,
    /// The selection of the policy compared against (the thesis policy), when known.
    pub baseline: Option<StructureName>,
}

fn f(v: &serde_json::Value, k: &str) -> f64 {
    v.get(k).and_then(|x| x.as_f64()).unwrap_or(0.0)
}

impl Sample {
    /// The measurement of one structure.
    pub fn get(&self, s: StructureName) -> Option<&Measured> {
        self.measured.iter().find(|m| m.structure == s)
    }

    /// The valid structure with the smallest measured total.
    pub fn best(&self) -> Option<&Measured> {
        self.measured.iter().filter(|m| m.valid && m.total_ms > 0.0).min_by(|a, b| a.total_ms.total_cmp(&b.total_ms))
    }

    /// `total(s) / total(best) - 1`; `None` when `s` or the best was not validly measured.
    pub fn regret(&self, s: StructureName) -> Option<f64> {
        let best = self.best()?;
        let m = self.get(s).filter(|m| m.valid)?;
        Some(m.total_ms / best.total_ms - 1.0)
    }

    /// A sample from an oracle result and the scene's features.
    pub fn from_evaluation(
        e: &SceneEvaluation,
        features: Features,
        baseline: Option<StructureName>,
    ) -> Result<Sample, CostError> {
        Sample::from_json(&e.to_json(), features, baseline)
    }

    /// A sample from one object of `evaluate --json` and the scene's features. `baseline` defaults to the
    /// record's `selected` when its `policy` is `thesis` or absent (records written before policies had names).
    pub fn from_json(
        v: &serde_json::Value,
        features: Features,
        baseline: Option<StructureName>,
    ) -> Result<Sample, CostError> {
        let bad = |w: &str| CostError::Parse(format!("oracle record: {w}"));
        let scene = v.get("mesh").and_then(|x| x.as_str()).ok_or_else(|| bad("no mesh"))?.to_string();
        let kind: WorkloadKind = v
            .get("workload")
            .and_then(|x| x.as_str())
            .ok_or_else(|| bad("no workload"))?
            .parse()
            .map_err(|e: String| bad(&e))?;
        let rebuild = v.get("rebuild").and_then(|x| x.as_str()).unwrap_or("once");
        let frames_measured = v.get("frames_measured").and_then(|x| x.as_u64()).unwrap_or(1).max(1);
        let frames = v.get("frames").and_then(|x| x.as_u64()).unwrap_or(1).max(1);
        let rays_per_frame =
            v.get("rays_per_frame").and_then(|x| x.as_u64()).ok_or_else(|| bad("no rays_per_frame"))?;
        let animated = frames_measured > 1;
        let builds = if animated || rebuild == "per_frame" { frames } else { 1 };
        let workload = Workload { kind, rays_per_frame, frames, builds };
        let structures = v.get("structures").and_then(|x| x.as_array()).ok_or_else(|| bad("no structures"))?;
        let mut measured = Vec::new();
        for s in structures {
            let Some(name) = s.get("name").and_then(|x| x.as_str()).and_then(|n| n.parse::<StructureName>().ok())
            else {
                continue;
            };
            let ok = |k: &str| s.get(k).and_then(|x| x.as_bool()).unwrap_or(false);
            let mrays = f(s, "mrays_per_s");
            let build_ms = f(s, "build_ms");
            measured.push(Measured {
                structure: name,
                valid: ok("valid") && ok("hits_agree") && mrays > 0.0,
                total_ms: f(s, "total_ms"),
                build_ms,
                trace_ms: f(s, "trace_ms"),
                build_ms_per_build: build_ms / builds as f64,
                trace_ns_per_ray: if mrays > 0.0 { 1e3 / mrays } else { 0.0 },
                box_tests_per_ray: f(s, "box_tests_per_ray"),
                prim_tests_per_ray: f(s, "prim_tests_per_ray"),
                within_noise_of_best: ok("within_noise_of_best"),
            });
        }
        let policy = v.get("policy").and_then(|x| x.as_str()).unwrap_or("thesis");
        let recorded = if policy == "thesis" {
            v.get("selected").and_then(|x| x.as_str()).and_then(|n| n.parse::<StructureName>().ok())
        } else {
            None
        };
        Ok(Sample { scene, workload, features, measured, baseline: baseline.or(recorded) })
    }
}

/// Parses JSONL text (one `evaluate --json` object per line; blank lines skipped).
pub fn parse_jsonl(text: &str) -> Result<Vec<serde_json::Value>, CostError> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| serde_json::from_str(l).map_err(|e| CostError::Parse(format!("line {}: {e}", i + 1))))
        .collect()
}

/// Drift of an animation frame from the frame a structure was built for: the largest of the feature changes
/// ([`FeatureChange`]: occupancy in log units, relative bounds change, size exponent change / 4).
pub fn drift(built: &Features, now: &Features) -> f64 {
    let c = FeatureChange::between(built, now);
    c.occupancy.max(c.bounds).max(c.size / 4.0)
}

/// Selection quality of a policy over samples.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PolicyScore {
    /// Samples scored (both the selection and the best validly measured).
    pub scored: usize,
    /// Share of samples where the selection is the oracle best.
    pub accuracy: f64,
    /// Share where the selection is the best or within noise of it.
    pub within_noise: f64,
    /// Mean regret.
    pub mean_regret: f64,
    /// Worst regret.
    pub worst_regret: f64,
    /// Where the worst regret occurred (`scene (workload)`).
    pub worst: String,
}

/// One sample's selections and regrets.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ComparisonRow {
    /// Scene.
    pub scene: String,
    /// Workload kind.
    pub workload: WorkloadKind,
    /// The oracle's best.
    pub oracle_best: Option<StructureName>,
    /// The baseline (thesis) selection and its regret.
    pub baseline: Option<StructureName>,
    /// Regret of the baseline.
    pub baseline_regret: Option<f64>,
    /// Calibrated selection, model fitted on all samples.
    pub calibrated_in_sample: Option<StructureName>,
    /// Its regret.
    pub calibrated_in_sample_regret: Option<f64>,
    /// Calibrated selection, model fitted without this scene.
    pub calibrated_held_out: Option<StructureName>,
    /// Its regret.
    pub calibrated_held_out_regret: Option<f64>,
    /// Held-out model's predicted total of its selection, ms.
    pub predicted_total_ms: Option<f64>,
    /// Measured total of the held-out selection, ms.
    pub measured_total_ms: Option<f64>,
}

/// The policy comparison over a set of samples.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Comparison {
    /// Per sample.
    pub rows: Vec<ComparisonRow>,
    /// Baseline (thesis) over all samples.
    pub baseline: PolicyScore,
    /// Calibrated, in-sample (calibration scenes).
    pub calibrated_in_sample: PolicyScore,
    /// Calibrated, leave-one-scene-out (held-out scenes).
    pub calibrated_held_out: PolicyScore,
    /// Tie margin used by the calibrated selection.
    pub tie_margin: f64,
}

/// Scores `(sample, selection)` pairs.
pub fn score<'a>(pairs: impl Iterator<Item = (&'a Sample, Option<StructureName>)>) -> PolicyScore {
    let mut s = PolicyScore::default();
    let (mut hit, mut near, mut sum) = (0usize, 0usize, 0.0);
    for (smp, sel) in pairs {
        let (Some(sel), Some(best)) = (sel, smp.best()) else { continue };
        let Some(r) = smp.regret(sel) else { continue };
        s.scored += 1;
        hit += (sel == best.structure) as usize;
        near += (sel == best.structure || smp.get(sel).is_some_and(|m| m.within_noise_of_best)) as usize;
        sum += r;
        if r > s.worst_regret || s.worst.is_empty() {
            s.worst_regret = s.worst_regret.max(r);
            s.worst = format!("{} ({})", smp.scene, smp.workload.kind.as_str());
        }
    }
    if s.scored > 0 {
        s.accuracy = hit as f64 / s.scored as f64;
        s.within_noise = near as f64 / s.scored as f64;
        s.mean_regret = sum / s.scored as f64;
    }
    s
}

/// In-sample and leave-one-scene-out comparison of the calibrated selection (tie margin `tie_margin`, see
/// [`super::policy::choose`]) with each sample's `baseline`.
pub fn compare(samples: &[Sample], tie_margin: f64, device: &str) -> Result<Comparison, CostError> {
    let full = CostModel::fit(samples, device, "comparison, all samples")?;
    let mut scenes: Vec<&str> = samples.iter().map(|s| s.scene.as_str()).collect();
    scenes.sort();
    scenes.dedup();
    let mut held: Vec<Option<(StructureName, f64)>> = vec![None; samples.len()];
    for scene in &scenes {
        let train: Vec<Sample> = samples.iter().filter(|s| s.scene != *scene).cloned().collect();
        let Ok(model) = CostModel::fit(&train, device, "leave-one-out") else { continue };
        for (i, smp) in samples.iter().enumerate().filter(|(_, s)| s.scene == *scene) {
            let preds = model.predict(&smp.features, &smp.workload);
            if let Some(c) = super::policy::choose(&preds, tie_margin) {
                let t = preds.iter().find(|p| p.structure == c).map_or(0.0, |p| p.total_ms);
                held[i] = Some((c, t));
            }
        }
    }
    let ins: Vec<Option<StructureName>> = samples
        .iter()
        .map(|smp| super::policy::choose(&full.predict(&smp.features, &smp.workload), tie_margin))
        .collect();
    let rows = samples
        .iter()
        .enumerate()
        .map(|(i, smp)| ComparisonRow {
            scene: smp.scene.clone(),
            workload: smp.workload.kind,
            oracle_best: smp.best().map(|m| m.structure),
            baseline: smp.baseline,
            baseline_regret: smp.baseline.and_then(|b| smp.regret(b)),
            calibrated_in_sample: ins[i],
            calibrated_in_sample_regret: ins[i].and_then(|c| smp.regret(c)),
            calibrated_held_out: held[i].map(|h| h.0),
            calibrated_held_out_regret: held[i].and_then(|h| smp.regret(h.0)),
            predicted_total_ms: held[i].map(|h| h.1),
            measured_total_ms: held[i].and_then(|h| smp.get(h.0)).map(|m| m.total_ms),
        })
        .collect();
    Ok(Comparison {
        rows,
        baseline: score(samples.iter().map(|s| (s, s.baseline))),
        calibrated_in_sample: score(samples.iter().zip(&ins).map(|(s, &c)| (s, c))),
        calibrated_held_out: score(samples.iter().zip(&held).map(|(s, h)| (s, h.map(|x| x.0)))),
        tie_margin,
    })
}

/// Samples from cached oracle files (`evaluate --json` lines): every scene named in a record is loaded from its
/// recorded path (relative to the working directory) once, and its first frame's features computed with `params`.
/// `progress` receives the name of each scene loaded.
pub fn load_oracle_samples(
    files: &[std::path::PathBuf],
    params: &crate::characterize::Params,
    progress: &dyn Fn(&str),
) -> Result<Vec<Sample>, CostError> {
    let mut cache: std::collections::HashMap<String, Features> = std::collections::HashMap::new();
    let mut out = Vec::new();
    for file in files {
        let io = |source| CostError::Io { path: file.display().to_string(), source };
        let text = std::fs::read_to_string(file).map_err(io)?;
        let ctx = |e: CostError| CostError::Parse(format!("{}: {e}", file.display()));
        for rec in parse_jsonl(&text).map_err(ctx)? {
            let mesh = rec
                .get("mesh")
                .and_then(|m| m.as_str())
                .ok_or_else(|| CostError::Parse(format!("{}: a record without mesh", file.display())))?
                .to_string();
            if !cache.contains_key(&mesh) {
                progress(&mesh);
                let scene = crate::mesh::load_path(std::path::Path::new(&mesh))
                    .map_err(|e| CostError::Parse(format!("{}: {mesh}: {e}", file.display())))?;
                let first =
                    scene.frames.first().ok_or_else(|| CostError::Parse(format!("{mesh}: the scene has no frames")))?;
                let f = crate::characterize::features_cpu(first, params)
                    .map_err(|e| CostError::Parse(format!("{mesh}: features: {e}")))?;
                cache.insert(mesh.clone(), f);
            }
            out.push(Sample::from_json(&rec, cache[&mesh].clone(), None).map_err(ctx)?);
        }
    }
    Ok(out)
}
