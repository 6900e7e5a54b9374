//! The policy comparison: in-sample and leave-one-scene-out selection accuracy and regret of the calibrated policy
//! against another policy's recorded selections (the thesis policy's), from calibration samples.
//!
//! **Leave-one-out** ([`compare`]): for every scene, the model is fitted on the samples of all *other* scenes (all
//! workloads of the held-out scene are left out together) and selects for the held-out scene's samples; the regret
//! is then read from the held-out scene's measurements. The in-sample ("calibration") figures fit on everything.

use crate::accel::StructureName;
use crate::cost::{CostError, CostModel, Sample};
use crate::geom::WorkloadKind;
use crate::select::choose;

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
/// [`crate::select::choose`]) with each sample's `baseline`.
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
            if let Some(c) = choose(&preds, tie_margin) {
                let t = preds.iter().find(|p| p.structure == c).map_or(0.0, |p| p.total_ms);
                held[i] = Some((c, t));
            }
        }
    }
    let ins: Vec<Option<StructureName>> =
        samples.iter().map(|smp| choose(&full.predict(&smp.features, &smp.workload), tie_margin)).collect();
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
