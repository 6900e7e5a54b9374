//! The policy comparison: in-sample and leave-one-scene-out selection accuracy and regret of the calibrated policy
//! against another policy's recorded selections (the thesis policy's), from calibration samples.
//!
//! **Leave-one-out** ([`compare`]): for every scene, the model is fitted on the samples of all *other* scenes (all
//! workloads of the held-out scene are left out together) and selects for the held-out scene's samples; the regret
//! is then read from the held-out scene's measurements. The in-sample ("calibration") figures fit on everything.

use crate::accel::StructureName;
use crate::cost::{CostError, CostModel};
use crate::eval::fit::Sample;
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
    /// Mean regret beyond the measurement's noise ([`Sample::regret_beyond_noise`]: 0 where the selection's 95%
    /// interval overlaps the best's, the gap between the intervals otherwise; the raw regret where a sample has no
    /// intervals): how much of [`PolicyScore::mean_regret`] the oracle's precision can vouch for.
    pub mean_regret_beyond_noise: f64,
    /// Worst regret.
    pub worst_regret: f64,
    /// Where the worst regret occurred (`scene (workload)`).
    pub worst: String,
    /// Worst regret beyond the measurement's noise ([`Sample::regret_beyond_noise`]): the worst regret the
    /// oracle's 95% intervals vouch for.
    pub worst_regret_beyond_noise: f64,
    /// Where it occurred (`scene (workload)`; empty when every selection is within noise of the best).
    pub worst_beyond_noise: String,
    /// Samples where the selection was not validly measured (it failed to build, over a budget, or disagreed with
    /// the reference) while another structure was: a catastrophe the regret figures cannot show; they are not
    /// scored.
    pub failed: usize,
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
    /// With the driver's acceleration structures measured: the choice among all candidates.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub candidates: Option<CandidateComparison>,
    /// The calibrated policy against the four baselines ([`compare_baselines`]).
    pub baselines: Baselines,
    /// Every policy and level with the decision's cost counted ([`super::e2e::compare_e2e`]), at the frames of
    /// [`super::e2e::E2E_FRAMES`].
    pub e2e: Vec<super::e2e::E2ePolicy>,
}

/// One sample's choice among every candidate, the project's structures and the driver's (`rt_*`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CandidateRow {
    /// Scene.
    pub scene: String,
    /// Workload kind.
    pub workload: WorkloadKind,
    /// The measured best candidate (a structure's or a driver structure's name).
    pub oracle_best: Option<String>,
    /// The measured best among the driver's structures only (which build flags).
    pub oracle_best_flag: Option<String>,
    /// The held-out calibrated policy's overall choice.
    pub held_out: Option<String>,
    /// Its regret against the measured best candidate.
    pub held_out_regret: Option<f64>,
    /// The held-out policy's pick among the driver's structures (whether or not it beats the project's).
    pub held_out_flag: Option<String>,
    /// That pick's regret against the best driver structure.
    pub held_out_flag_regret: Option<f64>,
    /// The in-sample (all scenes) policy's overall choice and its regret.
    pub in_sample: Option<String>,
    /// Its regret.
    pub in_sample_regret: Option<f64>,
}

/// The calibrated policy's choice among all candidates, in sample and held out.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CandidateComparison {
    /// Per sample with driver measurements.
    pub rows: Vec<CandidateRow>,
    /// Held out: the overall choice is the measured best (share), mean and worst regret.
    pub held_out_accuracy: f64,
    /// Mean regret of the held-out overall choice.
    pub held_out_mean_regret: f64,
    /// Worst regret of the held-out overall choice.
    pub held_out_worst_regret: f64,
    /// Held out: the driver flag picked is the measured best flag (share).
    pub held_out_flag_accuracy: f64,
    /// Mean regret of the held-out flag pick among the driver structures.
    pub held_out_flag_mean_regret: f64,
    /// In sample: share right and mean regret of the overall choice.
    pub in_sample_accuracy: f64,
    /// Mean regret of the in-sample overall choice.
    pub in_sample_mean_regret: f64,
}

/// Measured total of a candidate named as the policy names it; `None` when not validly measured.
fn candidate_total(smp: &Sample, name: &str) -> Option<f64> {
    if let Some(f) = crate::accel::driver::DriverFlags::parse(name) {
        return smp.driver_result(f).filter(|d| d.valid && d.total_ms > 0.0).map(|d| d.total_ms);
    }
    let s: StructureName = name.parse().ok()?;
    smp.get(s).filter(|m| m.valid && m.total_ms > 0.0).map(|m| m.total_ms)
}

/// A candidate's name and measured total, ms.
type Named = Option<(String, f64)>;

/// The measured best driver structure and overall candidate of a sample.
fn measured_best(smp: &Sample) -> (Named, Named) {
    let flag = smp
        .driver
        .iter()
        .filter(|d| d.valid && d.total_ms > 0.0)
        .min_by(|a, b| a.total_ms.total_cmp(&b.total_ms))
        .map(|d| (d.flags.name().to_string(), d.total_ms));
    let own = smp.best().map(|m| (m.structure.as_str().to_string(), m.total_ms));
    let overall = match (&flag, &own) {
        (Some(f), Some(o)) => Some(if f.1 < o.1 { f.clone() } else { o.clone() }),
        (a, b) => a.clone().or_else(|| b.clone()),
    };
    (flag, overall)
}

/// The calibrated policy's overall choice and driver flag for a sample under `model` (fitted with driver models):
/// the project's structure by [`choose`], then the driver structure that [`crate::select::driver`] picks, chosen
/// overall when predicted cheaper (for an animation with its per-frame update plan).
fn policy_candidate(model: &CostModel, smp: &Sample, tie_margin: f64) -> (Option<String>, Option<String>) {
    let preds = smp.predict(model);
    let frames: Vec<crate::characterize::Features> =
        if smp.frame_features.is_empty() { vec![smp.features.clone()] } else { smp.frame_features.clone() };
    // The project's side as the policy weighs it: for an animation, its per-frame plan.
    let planned = crate::select::planned_total(
        model,
        &frames,
        smp.workload.kind,
        smp.workload.rays_per_frame,
        tie_margin,
        smp.crossings,
    );
    let own = choose(&preds, tie_margin).map(|c| {
        let single = preds.iter().find(|p| p.structure == c).map_or(0.0, |p| p.total_ms);
        (c, planned.unwrap_or(single))
    });
    match crate::select::driver::choose_driver(model, &frames, &smp.workload, own) {
        Some((d, _)) => {
            let overall =
                if d.chosen { Some(d.flags.name().to_string()) } else { own.map(|o| o.0.as_str().to_string()) };
            (overall, Some(d.flags.name().to_string()))
        }
        None => (own.map(|o| o.0.as_str().to_string()), None),
    }
}

/// [`CandidateComparison`] over the samples with driver measurements (`None` when none has them): the model and
/// its driver models fitted on all samples (in sample) and, per scene, on the other scenes (held out).
pub fn compare_candidates(
    samples: &[Sample],
    tie_margin: f64,
    device: &str,
) -> Result<Option<CandidateComparison>, CostError> {
    if samples.iter().all(|s| s.driver.is_empty()) {
        return Ok(None);
    }
    let fit = |train: &[Sample], source: &str| -> Result<CostModel, CostError> {
        let mut m = CostModel::fit(train, device, source)?;
        m.fit_driver(train)?;
        Ok(m)
    };
    let full = fit(samples, "comparison, all samples")?;
    let mut scenes: Vec<&str> = samples.iter().map(|s| s.scene.as_str()).collect();
    scenes.sort();
    scenes.dedup();
    let mut held: Vec<(Option<String>, Option<String>)> = vec![(None, None); samples.len()];
    for scene in &scenes {
        let train: Vec<Sample> = samples.iter().filter(|s| s.scene != *scene).cloned().collect();
        let Ok(model) = fit(&train, "leave-one-out") else { continue };
        for (i, smp) in samples.iter().enumerate().filter(|(_, s)| s.scene == *scene) {
            held[i] = policy_candidate(&model, smp, tie_margin);
        }
    }
    let regret = |smp: &Sample, name: &Option<String>, best: &Named| -> Option<f64> {
        Some(candidate_total(smp, name.as_deref()?)? / best.as_ref()?.1 - 1.0)
    };
    let mut rows = Vec::new();
    for (i, smp) in samples.iter().enumerate().filter(|(_, s)| !s.driver.is_empty()) {
        let (flag, overall) = measured_best(smp);
        let (ins, _) = policy_candidate(&full, smp, tie_margin);
        let (h, hf) = held[i].clone();
        rows.push(CandidateRow {
            scene: smp.scene.clone(),
            workload: smp.workload.kind,
            held_out_regret: regret(smp, &h, &overall),
            held_out_flag_regret: regret(smp, &hf, &flag),
            in_sample_regret: regret(smp, &ins, &overall),
            oracle_best: overall.map(|o| o.0),
            oracle_best_flag: flag.map(|f| f.0),
            held_out: h,
            held_out_flag: hf,
            in_sample: ins,
        });
    }
    let share = |f: &dyn Fn(&CandidateRow) -> Option<bool>| {
        let v: Vec<bool> = rows.iter().filter_map(f).collect();
        if v.is_empty() {
            0.0
        } else {
            v.iter().filter(|&&b| b).count() as f64 / v.len() as f64
        }
    };
    let mean = |f: &dyn Fn(&CandidateRow) -> Option<f64>| {
        let v: Vec<f64> = rows.iter().filter_map(f).collect();
        if v.is_empty() {
            0.0
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let same = |a: &Option<String>, b: &Option<String>| Some(a.as_ref()? == b.as_ref()?);
    Ok(Some(CandidateComparison {
        held_out_accuracy: share(&|r| same(&r.held_out, &r.oracle_best)),
        held_out_mean_regret: mean(&|r| r.held_out_regret),
        held_out_worst_regret: rows.iter().filter_map(|r| r.held_out_regret).fold(0.0, f64::max),
        held_out_flag_accuracy: share(&|r| same(&r.held_out_flag, &r.oracle_best_flag)),
        held_out_flag_mean_regret: mean(&|r| r.held_out_flag_regret),
        in_sample_accuracy: share(&|r| same(&r.in_sample, &r.oracle_best)),
        in_sample_mean_regret: mean(&|r| r.in_sample_regret),
        rows,
    }))
}

/// Scores `(sample, selection)` pairs.
pub fn score<'a>(pairs: impl Iterator<Item = (&'a Sample, Option<StructureName>)>) -> PolicyScore {
    let mut s = PolicyScore::default();
    let (mut hit, mut near, mut sum, mut beyond) = (0usize, 0usize, 0.0, 0.0);
    for (smp, sel) in pairs {
        let (Some(sel), Some(best)) = (sel, smp.best()) else { continue };
        let Some(r) = smp.regret(sel) else {
            s.failed += 1;
            continue;
        };
        s.scored += 1;
        hit += (sel == best.structure) as usize;
        near += (sel == best.structure || smp.get(sel).is_some_and(|m| m.within_noise_of_best)) as usize;
        sum += r;
        let b = smp.regret_beyond_noise(sel).unwrap_or(r);
        beyond += b;
        if b > s.worst_regret_beyond_noise {
            s.worst_regret_beyond_noise = b;
            s.worst_beyond_noise = format!("{} ({})", smp.scene, smp.workload.kind.as_str());
        }
        if r > s.worst_regret || s.worst.is_empty() {
            s.worst_regret = s.worst_regret.max(r);
            s.worst = format!("{} ({})", smp.scene, smp.workload.kind.as_str());
        }
    }
    if s.scored > 0 {
        s.accuracy = hit as f64 / s.scored as f64;
        s.within_noise = near as f64 / s.scored as f64;
        s.mean_regret = sum / s.scored as f64;
        s.mean_regret_beyond_noise = beyond / s.scored as f64;
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
            let preds = smp.predict(&model);
            if let Some(c) = choose(&preds, tie_margin) {
                let t = preds.iter().find(|p| p.structure == c).map_or(0.0, |p| p.total_ms);
                held[i] = Some((c, t));
            }
        }
    }
    let ins: Vec<Option<StructureName>> = samples.iter().map(|smp| choose(&smp.predict(&full), tie_margin)).collect();
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
        candidates: compare_candidates(samples, tie_margin, device)?,
        baselines: compare_baselines(samples, tie_margin, device),
        e2e: super::e2e::compare_e2e(samples, tie_margin, crate::select::DEFAULT_DECISION_BUDGET, device)?,
    })
}

/// The family a sample's scene belongs to, for leave-one-family-out: a generated scene's family
/// (`family:NAME:...`, [`crate::mesh::families::parse_spec`]); otherwise `animation` for a directory of frames (a
/// path that is a directory, or, wherever the command runs, one with no extension that names no generator, as
/// records name the BART animations) and `mesh` for anything else (mesh files, the degenerate generators).
pub fn family_of(scene: &str) -> String {
    let path = std::path::Path::new(scene);
    match crate::mesh::families::parse_spec(scene) {
        Some(Ok((f, _, _))) => f.name().to_string(),
        _ if path.is_dir() || (path.extension().is_none() && !scene.contains(':')) => "animation".to_string(),
        _ => "mesh".to_string(),
    }
}

/// The workload a sample stands for, as the baselines group it: the ray kind, and the frames when more than one
/// (`primary`, `shadow x100`).
pub fn workload_of(smp: &Sample) -> String {
    match smp.workload.frames {
        0 | 1 => smp.workload.kind.as_str().to_string(),
        f => format!("{} x{f}", smp.workload.kind.as_str()),
    }
}

/// One policy's selections over the samples and their scores, overall, by workload and by family.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PolicyRun {
    /// `thesis`, `best_single`, `size_only`, `calibrated`, `calibrated_cv` (the calibrated model with its ridge
    /// chosen by cross-validation inside its training samples, [`fit_ridge_by_cv`]) or `calibrated_timed` (the
    /// same held-out models with the samples' timed probes blended in, [`crate::cost::timed`]; only where the
    /// samples have them) or `calibrated_measured` (those choices with the close call settled by the samples'
    /// frames measured anew, [`crate::cost::measured`]; only where the samples have them).
    pub policy: String,
    /// How it was fitted: `recorded` (the thesis policy's recorded choice), `hindsight` (the best single structure
    /// per workload, chosen on all samples), `in_sample`, `scene_out` (fitted without the sample's scene) or
    /// `family_out` (fitted without the sample's family).
    pub holdout: String,
    /// The selection per sample (in the samples' order).
    pub choices: Vec<Option<StructureName>>,
    /// Over all samples.
    pub overall: PolicyScore,
    /// Per workload ([`workload_of`]), sorted by name.
    pub by_workload: Vec<(String, PolicyScore)>,
    /// Per family ([`family_of`]), sorted by name.
    pub by_family: Vec<(String, PolicyScore)>,
    /// For `calibrated_cv`: per held-out group (scene or family, sorted by name), the ridge chosen inside the
    /// training records without it and whether the laws take the crossings ([`fit_ridge_by_cv`]); empty for the
    /// other policies.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub ridges: Vec<(String, f64, bool)>,
}

/// The selection against four baselines (see [`compare_baselines`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Baselines {
    /// Per sample: its family ([`family_of`]).
    pub families: Vec<String>,
    /// Per sample: its workload ([`workload_of`]).
    pub workloads: Vec<String>,
    /// The policies, in the order: thesis (recorded), best single structure (hindsight), size-only and calibrated
    /// (each leave-one-scene-out and, with more than one family, leave-one-family-out), calibrated with the ridge
    /// chosen by cross-validation (the same two hold-outs), calibrated in sample.
    pub policies: Vec<PolicyRun>,
}

impl Baselines {
    /// The run of `policy` fitted as `holdout`.
    pub fn get(&self, policy: &str, holdout: &str) -> Option<&PolicyRun> {
        self.policies.iter().find(|p| p.policy == policy && p.holdout == holdout)
    }
}

/// A fit for [`held_out_choices`]: the held-out group's name and the other samples, to a model.
type GroupFit<'a> = dyn Fn(&str, &[Sample]) -> Result<CostModel, CostError> + 'a;

/// Selections of a model fitted without each group (`group` of a sample: its scene or its family) on the samples
/// of that group (`fit` gets the group's name and the other samples); `None` where the fit failed or the model
/// predicts nothing.
/// `geometric`: whether the predictions take the scene's overlap floor ([`Sample::predict`]); the size-only model
/// must not, as the floor reads the geometry.
fn held_out_choices(
    samples: &[Sample],
    group: &dyn Fn(&Sample) -> String,
    fit: &GroupFit<'_>,
    tie_margin: f64,
    geometric: bool,
) -> Vec<Option<StructureName>> {
    held_out_choices_probed(samples, group, fit, tie_margin, geometric, false, false).0
}

/// Choices of [`held_out_choices_probed`]: the model's, with the timed probes blended in, and with the close
/// call then measured.
type ProbedChoices = (Vec<Option<StructureName>>, Vec<Option<StructureName>>, Vec<Option<StructureName>>);

/// [`held_out_choices`], and beside them the choices of the same held-out models with the samples' timed probes
/// blended in ([`crate::cost::timed::blend_contenders`], the ratios fitted on the training samples with the model; a
/// sample without probes, or a model without ratios, keeps the model's choice), and with `measured`, those choices
/// with the close call of the (blended) predictions settled by the sample's measured frames
/// ([`Sample::settle_close_call`]; a sample without
/// a close call or without frames measured keeps the timed choice); a list not asked for is all `None`.
fn held_out_choices_probed(
    samples: &[Sample],
    group: &dyn Fn(&Sample) -> String,
    fit: &GroupFit<'_>,
    tie_margin: f64,
    geometric: bool,
    timed: bool,
    measured: bool,
) -> ProbedChoices {
    let keys: Vec<String> = samples.iter().map(group).collect();
    let mut groups = keys.clone();
    groups.sort();
    groups.dedup();
    let mut out = vec![None; samples.len()];
    let mut timed_out = vec![None; samples.len()];
    let mut measured_out = vec![None; samples.len()];
    for g in &groups {
        let train: Vec<Sample> = samples.iter().zip(&keys).filter(|(_, k)| *k != g).map(|(s, _)| s.clone()).collect();
        let Ok(model) = fit(g, &train) else { continue };
        for (i, smp) in samples.iter().enumerate().filter(|(i, _)| keys[*i] == *g) {
            let mut preds = if geometric { smp.predict(&model) } else { model.predict(&smp.features, &smp.workload) };
            out[i] = choose(&preds, tie_margin);
            if !timed && !measured {
                continue;
            }
            // As the policy does: the contenders' probes only (`cost::timed::contenders`); a sample without probes
            // (an animation), or a model without ratios, keeps the model's choice.
            timed_out[i] = match model.timed.as_ref().filter(|_| timed) {
                Some(r) => {
                    crate::cost::timed::blend_contenders(&mut preds, &smp.timed, r, &smp.workload);
                    choose(&preds, tie_margin)
                }
                None => out[i],
            };
            if measured {
                // Like the held-out choices above, no budget exclusion: the records measured every structure.
                let settled = smp.settle_close_call(&preds);
                measured_out[i] = settled.or(timed_out[i]);
            }
        }
    }
    (out, timed_out, measured_out)
}

/// The ridges [`fit_ridge_by_cv`] tries, smallest first: [`crate::cost::RIDGE`] and then a factor of about 4 to
/// 5 apart up to 100, where the geometric coefficients are mostly shrunk away (the range of the fixed-ridge sweep
/// in `docs/cost-model.md`).
pub const CV_RIDGES: [f64; 6] = [crate::cost::RIDGE, 0.2, 1.0, 5.0, 20.0, 100.0];

/// A model whose ridge (and whether its laws take the crossings) was chosen by cross-validation inside its own
/// training samples ([`fit_ridge_by_cv`]).
#[derive(Clone, Debug)]
pub struct CvFit {
    /// The model, fitted on all the samples with [`CvFit::ridge`] and [`CvFit::crossings`].
    pub model: CostModel,
    /// The chosen ridge, one of [`CV_RIDGES`].
    pub ridge: f64,
    /// Whether the chosen laws take the crossings ([`CostModel::fit_with`]).
    pub crossings: bool,
    /// `family` or `scene`: the groups held out in turn.
    pub groups: &'static str,
    /// Per candidate, in the order tried (every ridge of [`CV_RIDGES`] without the crossings, then with them):
    /// `(ridge, crossings, mean regret of the selections on the held-out groups)`, the regret infinite when none
    /// could be scored.
    pub inner_regret: Vec<(f64, bool, f64)>,
}

/// Fits the calibrated model with its ridge, and whether its test-count laws take the crossings, chosen inside
/// `samples` alone: for every candidate (each ridge of [`CV_RIDGES`], without the crossings and with them), each
/// group of samples is held out in turn (its family when the samples span at least 3 families ([`family_of`]),
/// else its scene), a model is fitted on the others and selects (tie margin `tie_margin`) on the held-out group;
/// the candidate whose held-out selections have the least mean regret is kept (on a tie the first tried: the
/// smaller ridge, and without the crossings before with them) and the model refitted on all the samples with it.
/// With fewer than two groups nothing can be held out and the model is [`CostModel::fit`]'s. Nothing outside
/// `samples` is read, so wrapped in another hold-out (as [`compare_baselines`] does) the held-out scene or family
/// never sees its own records, the choice included.
pub fn fit_ridge_by_cv(samples: &[Sample], device: &str, source: &str, tie_margin: f64) -> Result<CvFit, CostError> {
    let mut families: Vec<String> = samples.iter().map(|s| family_of(&s.scene)).collect();
    families.sort();
    families.dedup();
    let by_family = families.len() >= 3;
    let groups = if by_family { "family" } else { "scene" };
    let key = |s: &Sample| if by_family { family_of(&s.scene) } else { s.scene.clone() };
    let mut distinct: Vec<String> = samples.iter().map(key).collect();
    distinct.sort();
    distinct.dedup();
    let mut inner_regret = Vec::new();
    if distinct.len() >= 2 {
        for crossings in [false, true] {
            for r in CV_RIDGES {
                let fit = |_: &str, t: &[Sample]| CostModel::fit_with(t, device, "cross-validation", r, crossings);
                let choices = held_out_choices(samples, &key, &fit, tie_margin, true);
                let sc = score(samples.iter().zip(&choices).map(|(s, c)| (s, *c)));
                inner_regret.push((r, crossings, if sc.scored > 0 { sc.mean_regret } else { f64::INFINITY }));
            }
        }
    }
    let (ridge, crossings) = inner_regret
        .iter()
        .filter(|x| x.2.is_finite())
        .fold(None, |b: Option<(f64, bool, f64)>, &x| match b {
            Some(b) if b.2 <= x.2 => Some(b),
            _ => Some(x),
        })
        .map_or((crate::cost::RIDGE, false), |b| (b.0, b.1));
    let with = if crossings { ", with the crossings" } else { "" };
    let source = format!("{source}, ridge {ridge}{with} by leave-one-{groups}-out");
    let model = CostModel::fit_with(samples, device, &source, ridge, crossings)?;
    Ok(CvFit { model, ridge, crossings, groups, inner_regret })
}

/// Per workload, the structure with the least mean regret over the samples of that workload (ties: the first in
/// [`StructureName::ALL`]): the best single structure chosen in hindsight.
fn best_single(samples: &[Sample], workloads: &[String]) -> Vec<Option<StructureName>> {
    let mut keys = workloads.to_vec();
    keys.sort();
    keys.dedup();
    let mut pick = std::collections::HashMap::new();
    for k in &keys {
        let of: Vec<&Sample> = samples.iter().zip(workloads).filter(|(_, w)| *w == k).map(|(s, _)| s).collect();
        let mean = |s: StructureName| -> f64 {
            // A structure that failed where another was measured counts as a miss of unbounded cost.
            let r: Vec<f64> =
                of.iter().filter(|x| x.best().is_some()).map(|x| x.regret(s).unwrap_or(f64::INFINITY)).collect();
            if r.is_empty() {
                f64::INFINITY
            } else {
                r.iter().sum::<f64>() / r.len() as f64
            }
        };
        let best = StructureName::ALL.into_iter().map(|s| (s, mean(s))).fold(
            None,
            |b: Option<(StructureName, f64)>, x| match b {
                Some(b) if b.1 <= x.1 => Some(b),
                _ => Some(x),
            },
        );
        pick.insert(k.clone(), best.map(|b| b.0));
    }
    workloads.iter().map(|w| pick.get(w).copied().flatten()).collect()
}

/// What identifies an oracle record's measurement: the scene, the workload, the camera (or view), the resolution, the
/// frames and the rebuild rule; two records with the same key measured the same thing.
fn record_key(r: &super::record::OracleRecord) -> String {
    format!(
        "{}|{}|{:?}|{}|{}|{}|{:?}|{:?}",
        r.mesh,
        r.workload.as_str(),
        r.view,
        serde_json::to_string(&r.camera).unwrap_or_default(),
        r.resolution,
        r.frames,
        r.rebuild,
        r.trace_backend,
    )
}

/// The oracle against itself: for each sample of `b` (loaded from `records`, in their order), the best structure of
/// the record of `repeat` that measured the same thing (the same scene, workload, camera or view, resolution, frames,
/// rebuild rule and tracer: a second run of the oracle), scored on the sample's measurements as the policy
/// `repeat_oracle` (holdout `repeat`); `None` where that record names no best. What no policy can beat on average:
/// a second run's best is the most a measuring policy could know, and its regret is the first run's noise.
///
/// Fails when `records` and `samples` differ in number, when `repeat` holds two records of one measurement, or when
/// a record has none in `repeat` (a second run of other scenes, or of the same scenes under other paths, would
/// otherwise score nothing and read as no regret).
pub fn repeat_oracle(
    b: &Baselines,
    samples: &[Sample],
    records: &[super::record::OracleRecord],
    repeat: &[super::record::OracleRecord],
) -> Result<PolicyRun, String> {
    if records.len() != samples.len() {
        return Err(format!("{} records for {} samples", records.len(), samples.len()));
    }
    let mut best: std::collections::HashMap<String, Option<StructureName>> = std::collections::HashMap::new();
    for r in repeat {
        if best.insert(record_key(r), r.oracle_best).is_some() {
            return Err(format!("the second run holds two records of {} ({})", r.mesh, r.workload.as_str()));
        }
    }
    let mut choices = Vec::with_capacity(records.len());
    let mut missing = Vec::new();
    for r in records {
        match best.get(&record_key(r)) {
            Some(c) => choices.push(*c),
            None => {
                missing.push(format!(
                    "{} ({}, {})",
                    r.mesh,
                    r.workload.as_str(),
                    r.view.as_deref().unwrap_or("camera")
                ));
                choices.push(None);
            }
        }
    }
    if let Some(first) = missing.first() {
        return Err(format!(
            "{} of {} records have no record of the same measurement in the second run, the first {first}",
            missing.len(),
            records.len()
        ));
    }
    Ok(policy_run("repeat_oracle", "repeat", samples, choices, &b.workloads, &b.families))
}

/// Scores of `choices` over `samples`: overall, per workload and per family.
fn policy_run(
    policy: &str,
    holdout: &str,
    samples: &[Sample],
    choices: Vec<Option<StructureName>>,
    workloads: &[String],
    families: &[String],
) -> PolicyRun {
    let by = |keys: &[String]| -> Vec<(String, PolicyScore)> {
        let mut names = keys.to_vec();
        names.sort();
        names.dedup();
        names
            .into_iter()
            .map(|k| {
                let sc =
                    score(samples.iter().zip(&choices).zip(keys).filter(|(_, g)| **g == k).map(|((s, c), _)| (s, *c)));
                (k, sc)
            })
            .collect()
    };
    PolicyRun {
        policy: policy.to_string(),
        holdout: holdout.to_string(),
        overall: score(samples.iter().zip(&choices).map(|(s, c)| (s, *c))),
        by_workload: by(workloads),
        by_family: by(families),
        choices,
        ridges: Vec::new(),
    }
}

/// The calibrated policy against four baselines on the same samples: the thesis policy (its recorded choices),
/// the best single structure per workload chosen in hindsight, the size-only model ([`CostModel::fit_size_only`])
/// and the calibrated model, each of the last two fitted leave-one-scene-out and, when the samples span more than
/// one family ([`family_of`]), leave-one-family-out; the calibrated model with its ridge chosen by cross-validation
/// inside each training set ([`fit_ridge_by_cv`]), held out the same two ways; and the calibrated model in sample.
pub fn compare_baselines(samples: &[Sample], tie_margin: f64, device: &str) -> Baselines {
    let families: Vec<String> = samples.iter().map(|s| family_of(&s.scene)).collect();
    let workloads: Vec<String> = samples.iter().map(workload_of).collect();
    let fam_of: std::collections::HashMap<&str, &str> =
        samples.iter().zip(&families).map(|(s, f)| (s.scene.as_str(), f.as_str())).collect();
    let scene = |s: &Sample| s.scene.clone();
    let family = |s: &Sample| fam_of.get(s.scene.as_str()).map_or_else(String::new, |f| f.to_string());
    let full = |_: &str, t: &[Sample]| CostModel::fit(t, device, "held out");
    let size = |_: &str, t: &[Sample]| CostModel::fit_size_only(t, device, "held out, size only");
    let mut distinct = families.clone();
    distinct.sort();
    distinct.dedup();
    let run = |p: &str, h: &str, c: Vec<Option<StructureName>>| policy_run(p, h, samples, c, &workloads, &families);
    let mut policies = vec![
        run("thesis", "recorded", samples.iter().map(|s| s.baseline).collect()),
        run("best_single", "hindsight", best_single(samples, &workloads)),
        run("size_only", "scene_out", held_out_choices(samples, &scene, &size, tie_margin, false)),
    ];
    if distinct.len() > 1 {
        policies.push(run("size_only", "family_out", held_out_choices(samples, &family, &size, tie_margin, false)));
    }
    policies.push(run("calibrated", "scene_out", held_out_choices(samples, &scene, &full, tie_margin, true)));
    if distinct.len() > 1 {
        policies.push(run("calibrated", "family_out", held_out_choices(samples, &family, &full, tie_margin, true)));
    }
    // The ridge each fit chose, under the name of the group it was fitted without.
    let probed = samples.iter().any(|s| !s.timed.is_empty());
    let measured = samples.iter().any(|s| !s.frame_timings.is_empty());
    let cv_run = |holdout: &str, group: &dyn Fn(&Sample) -> String| -> (PolicyRun, Vec<PolicyRun>) {
        let ridges = std::cell::RefCell::new(Vec::new());
        let cv = |g: &str, t: &[Sample]| {
            let fit = fit_ridge_by_cv(t, device, "held out, ridge by cross-validation", tie_margin)?;
            ridges.borrow_mut().push((g.to_string(), fit.ridge, fit.crossings));
            Ok(fit.model)
        };
        let (choices, timed, settled) =
            held_out_choices_probed(samples, group, &cv, tie_margin, true, probed, measured);
        let ridges = ridges.into_inner();
        let mut extra = Vec::new();
        if probed {
            extra.push(PolicyRun { ridges: ridges.clone(), ..run("calibrated_timed", holdout, timed) });
        }
        if measured {
            extra.push(PolicyRun { ridges: ridges.clone(), ..run("calibrated_measured", holdout, settled) });
        }
        (PolicyRun { ridges, ..run("calibrated_cv", holdout, choices) }, extra)
    };
    let mut timed_runs = Vec::new();
    let (cv, timed) = cv_run("scene_out", &scene);
    policies.push(cv);
    timed_runs.extend(timed);
    if distinct.len() > 1 {
        let (cv, timed) = cv_run("family_out", &family);
        policies.push(cv);
        timed_runs.extend(timed);
    }
    let ins: Vec<Option<StructureName>> = match CostModel::fit(samples, device, "held out") {
        Ok(m) => samples.iter().map(|s| choose(&s.predict(&m), tie_margin)).collect(),
        Err(_) => vec![None; samples.len()],
    };
    policies.push(run("calibrated", "in_sample", ins));
    policies.extend(timed_runs);
    Baselines { families, workloads, policies }
}

/// Static samples rendered over more frames: every sample of a static scene measured over one frame with one
/// build (`frames == 1`, `builds == 1`) stands, for each `F` of `frames`, for a sample of `F` frames with the same
/// build: each structure's total becomes `build_ms + F * trace_ms`, the oracle's own total for a static scene
/// built once ([`super::oracle`]), from the same measured build and trace. Other samples (animations, per-frame
/// rebuilds, several frames measured) are kept once, as they are. The derived samples carry no noise verdict
/// (`within_noise_of_best` is false, no interval): the oracle measured one frame, not `F`.
pub fn with_frames(samples: &[Sample], frames: &[u64]) -> Vec<Sample> {
    let mut out = Vec::new();
    for s in samples {
        let sweepable = s.workload.frames == 1 && s.workload.builds == 1 && s.frame_features.is_empty();
        if !sweepable || frames.is_empty() {
            out.push(s.clone());
            continue;
        }
        for &f in frames {
            let f = f.max(1);
            let mut d = s.clone();
            d.workload.frames = f;
            if f > 1 {
                for m in d.measured.iter_mut() {
                    m.trace_ms *= f as f64;
                    m.total_ms = m.build_ms + m.trace_ms;
                    m.within_noise_of_best = false;
                    m.total_ms_ci95 = None;
                }
                d.driver.clear();
            }
            out.push(d);
        }
    }
    out
}
