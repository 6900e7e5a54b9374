//! End-to-end scoring: every policy's choice with the decision's own cost counted.
//!
//! For a static scene rendered `F` frames with one build, a policy that decided in `d` ms and chose `c` has
//! `e2e = (d + build_c + F trace_c) / min_s (build_s + F trace_s) - 1`: its regret with the decision paid. `d` is
//! what the stages the policy read took on this machine, warm, when the records were loaded ([`StageCosts`]:
//! the CPU characterization and features for any policy that reads them, the bounds pass, the crossings and each
//! probe for one that climbs to them); the records' own build and trace times give the rest. Each family of the
//! records (or each scene, with fewer than three families) is scored by a model fitted on the others, its
//! held-out errors ([`crate::eval::fit::fit_uncertainty`]) and stage laws fitted on the others too.

use super::fit::{choose_prior_ridge, fit_inquiry_costs, fit_uncertainty, without_probes, Sample, StageCosts};
use crate::accel::StructureName;
use crate::cost::measured::MeasuredTotal;
use crate::cost::{CostError, CostModel, Prediction, RayCrossings};
use crate::select::{choose, climb, Inquiry, Knowledge, Level, Selector, TargetWorkload};

/// The frames of the end-to-end columns.
pub const E2E_FRAMES: [u64; 4] = [1, 10, 100, 1000];

/// One policy's figures at one number of frames.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct E2eScore {
    /// Frames rendered with one build.
    pub frames: u64,
    /// Samples scored.
    pub scored: usize,
    /// Mean and worst plain regret (the decision free).
    pub mean_regret: f64,
    /// Worst plain regret.
    pub worst_regret: f64,
    /// Mean and worst regret with the decision's cost counted.
    pub mean_e2e: f64,
    /// Worst end-to-end regret.
    pub worst_e2e: f64,
    /// Where the worst end-to-end regret occurred.
    pub worst_at: String,
    /// Median decision cost, ms.
    pub median_decision_ms: f64,
    /// Median decision cost over the best structure's total.
    pub median_decision_share: f64,
    /// Per level (0 to 3), how many samples the policy decided there (the ladder's; others report their fixed
    /// level).
    pub levels: [usize; 4],
    /// Of those at level 0, how many the triangle count alone decided (the ladder's size rung: no
    /// characterization, no features).
    pub by_size: usize,
}

/// One policy scored end to end, overall and per workload kind.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct E2ePolicy {
    /// `thesis`, `best_single`, `always_bvh`, `size_only`, `level0` .. `level3`, `crossings` (level 1 without its
    /// probes), `ladder`, `oracle`.
    pub policy: String,
    /// How it was fitted (`recorded`, `hindsight`, `none`, `family_out` or `scene_out`).
    pub holdout: String,
    /// Per number of frames.
    pub overall: Vec<E2eScore>,
    /// Per workload kind, then per number of frames.
    pub by_workload: Vec<(String, Vec<E2eScore>)>,
}

/// A sample's choice and decision cost under one policy.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Choice {
    structure: Option<StructureName>,
    decision_ms: f64,
    level: Level,
    /// Decided on the triangle count alone, before any characterization ([`Selector::size_rung`]).
    by_size: bool,
}

/// A record's knowledge as the ladder sees it: what the oracle's load computed for the record's camera (the
/// crossings, every probe, the timed probes, the measured frames) handed out level by level, each at the cost
/// measured for it.
struct RecordKnowledge<'a> {
    model: &'a CostModel,
    sample: &'a Sample,
    crossings: Option<RayCrossings>,
    grid_work: f64,
    timed: bool,
    spent_ms: f64,
}

impl<'a> RecordKnowledge<'a> {
    fn new(model: &'a CostModel, sample: &'a Sample) -> Self {
        RecordKnowledge { model, sample, crossings: None, grid_work: 0.0, timed: false, spent_ms: 0.0 }
    }
}

impl Knowledge for RecordKnowledge<'_> {
    fn predictions(&self) -> Vec<Prediction> {
        let s = self.sample;
        let (kind, c, g) = (s.workload.kind, self.crossings, self.grid_work);
        let b = &self.model.count_bounds;
        let mut p =
            self.model.predict_floored(&s.features, &s.workload, &|st| crate::cost::priced_floor(b, st, kind, c, g));
        if let (true, Some(r)) = (self.timed, &self.model.timed) {
            crate::cost::timed::blend(&mut p, &s.timed, r, &s.workload);
        }
        p
    }

    fn triangles(&self) -> u64 {
        self.sample.features.scene_triangles()
    }

    fn climbable(&self, level: Level) -> Result<(), String> {
        let animation = !self.sample.frame_features.is_empty() || self.sample.workload.builds > 1;
        match (self.sample.crossings, animation) {
            (None, _) => Err("no crossings were computed for this record".into()),
            (_, true) if level > Level::Counted => Err("an animation".into()),
            _ => Ok(()),
        }
    }

    fn count(&mut self, probes: &[StructureName]) -> f64 {
        let s = self.sample;
        let mut c = s.crossings.map(without_probes);
        if let (Some(c), Some(full)) = (c.as_mut(), s.crossings) {
            for (i, st) in crate::cost::PROBED.iter().enumerate() {
                if probes.contains(st) {
                    c.probes[i] = full.probes[i];
                    c.probe_work[i] = full.probe_work[i];
                }
            }
        }
        self.crossings = c;
        self.grid_work = s.grid_build_work;
        let m = &s.stage_ms;
        let ms = m.bounds_ms + m.crossings_ms + probes.iter().filter_map(|&p| m.probe(p)).sum::<f64>();
        self.spent_ms += ms;
        ms
    }

    fn time(&mut self, structures: &[StructureName]) -> Option<f64> {
        let k = crate::cost::timed::kind_index(self.sample.workload.kind);
        let taken: Vec<_> = self.sample.timed.iter().filter(|t| structures.contains(&t.structure)).collect();
        if taken.is_empty() {
            return None;
        }
        self.timed = true;
        let reps = crate::cost::timed::TIMED_REPEATS as f64;
        let ms: f64 = taken
            .iter()
            .map(|t| {
                let tr = t.trace_ns_per_ray[k];
                t.build_ms + if tr.is_finite() { reps * tr * t.rays[k] as f64 * 1e-6 } else { 0.0 }
            })
            .sum();
        self.spent_ms += ms;
        Some(ms)
    }

    fn measure(&mut self, structures: &[StructureName]) -> Option<(Vec<MeasuredTotal>, f64, f64)> {
        let w = &self.sample.workload;
        let timings: Vec<_> = self.sample.frame_timings.iter().filter(|t| structures.contains(&t.structure)).collect();
        let totals: Vec<MeasuredTotal> =
            timings.iter().filter_map(|t| MeasuredTotal::of(t, w.builds, w.frames)).collect();
        if totals.is_empty() {
            return None;
        }
        let rounds = crate::cost::measured::MEASURED_WARMUP + crate::cost::measured::MEASURED_REPEATS;
        let ms: f64 = timings
            .iter()
            .map(|t| {
                let per =
                    (t.build_ms.iter().sum::<f64>() + t.trace_ms.iter().sum::<f64>()) / t.build_ms.len().max(1) as f64;
                per * rounds as f64
            })
            .sum();
        self.spent_ms += ms;
        Some((totals, ms, 1.0))
    }
}

/// The level-0 base every calibrated decision pays: the characterization and the features.
fn base_ms(c: &StageCosts) -> f64 {
    c.characterize_ms + c.features_ms
}

/// The workload of a record, as a selector's target.
fn target_of(smp: &Sample) -> TargetWorkload {
    let w = &smp.workload;
    TargetWorkload {
        kind: w.kind,
        rays_per_frame: w.rays_per_frame,
        frames: w.frames,
        animation_frames: None,
        driver: false,
        camera: None,
    }
}

/// The size rung's choice for `smp` when it decides on the triangle count alone, its cost timed from `t`.
fn by_size(s: &Selector<'_>, smp: &Sample, t: std::time::Instant) -> Option<Choice> {
    let rung = s.size_rung(smp.features.scene_triangles()).filter(|r| !r.characterize)?;
    let own_ms = t.elapsed().as_secs_f64() * 1e3;
    Some(Choice { structure: rung.structure, decision_ms: own_ms, level: Level::Prior, by_size: true })
}

/// The calibrated policy's choice for `smp` under `model` at `inquiry`, and what the decision cost.
fn decide(model: &CostModel, smp: &Sample, inquiry: Inquiry, tie_margin: f64, decision_budget: f64) -> Choice {
    let mut s = Selector::new(model, target_of(smp));
    s.inquiry = inquiry;
    s.tie_margin = tie_margin;
    s.decision_budget = decision_budget;
    let t = std::time::Instant::now();
    if let Some(c) = by_size(&s, smp, t) {
        return c;
    }
    let mut k = RecordKnowledge::new(model, smp);
    let c = climb(&s, &mut k);
    let preds = k.predictions();
    let structure = match c.measured.iter().min_by(|a, b| a.total_ms.total_cmp(&b.total_ms)) {
        Some(m) => Some(m.structure),
        None => choose(&preds, tie_margin),
    };
    let own_ms = t.elapsed().as_secs_f64() * 1e3;
    Choice { structure, decision_ms: base_ms(&smp.stage_ms) + k.spent_ms + own_ms, level: c.level, by_size: false }
}

/// The calibrated policy's choice for `smp` under `model` from the prior and the mesh's crossings alone (level 1
/// without its probes: an O(n) pass over the triangle boxes, nothing built), and what the decision cost.
fn decide_on_crossings(model: &CostModel, smp: &Sample, tie_margin: f64) -> Choice {
    let mut s = Selector::new(model, target_of(smp));
    s.tie_margin = tie_margin;
    let t = std::time::Instant::now();
    if let Some(c) = by_size(&s, smp, t) {
        return c;
    }
    let mut k = RecordKnowledge::new(model, smp);
    let level = if k.climbable(Level::Counted).is_ok() {
        k.count(&[]);
        Level::Counted
    } else {
        Level::Prior
    };
    let structure = choose(&k.predictions(), tie_margin);
    let own_ms = t.elapsed().as_secs_f64() * 1e3;
    Choice { structure, decision_ms: base_ms(&smp.stage_ms) + k.spent_ms + own_ms, level, by_size: false }
}

/// The score of `choices` over `samples` (all of one number of frames).
fn score(samples: &[&Sample], choices: &[Choice], frames: u64) -> E2eScore {
    let mut out = E2eScore { frames, ..Default::default() };
    let (mut regrets, mut e2es, mut ms, mut shares) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (smp, c) in samples.iter().zip(choices) {
        let (Some(s), Some(best)) = (c.structure, smp.best()) else { continue };
        let Some(m) = smp.get(s).filter(|m| m.valid && m.total_ms > 0.0) else { continue };
        let r = m.total_ms / best.total_ms - 1.0;
        let e = (c.decision_ms + m.total_ms) / best.total_ms - 1.0;
        regrets.push(r);
        if e > out.worst_e2e || e2es.is_empty() {
            out.worst_e2e = e;
            out.worst_at = format!("{} ({})", smp.scene, smp.workload.kind.as_str());
        }
        e2es.push(e);
        ms.push(c.decision_ms);
        shares.push(c.decision_ms / best.total_ms);
        out.levels[c.level.number() as usize] += 1;
        out.by_size += usize::from(c.by_size);
    }
    let mean = |v: &[f64]| if v.is_empty() { 0.0 } else { v.iter().sum::<f64>() / v.len() as f64 };
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    out.scored = regrets.len();
    out.mean_regret = mean(&regrets);
    out.worst_regret = regrets.iter().copied().fold(0.0, f64::max);
    out.mean_e2e = mean(&e2es);
    out.median_decision_ms = median(ms);
    out.median_decision_share = median(shares);
    out
}

/// Every policy scored end to end over `samples` (static single-frame records stand for each of [`E2E_FRAMES`];
/// other samples for themselves), each family (or scene) held out.
pub fn compare_e2e(
    samples: &[Sample],
    tie_margin: f64,
    decision_budget: f64,
    device: &str,
) -> Result<Vec<E2ePolicy>, CostError> {
    let family = |s: &Sample| super::compare::family_of(&s.scene);
    let mut families: Vec<String> = samples.iter().map(family).collect();
    families.sort();
    families.dedup();
    let by_family = families.len() >= 3;
    let holdout = if by_family { "family_out" } else { "scene_out" };
    let key = |s: &Sample| if by_family { family(s) } else { s.scene.clone() };
    let keys: Vec<String> = samples.iter().map(key).collect();
    let mut groups = keys.clone();
    groups.sort();
    groups.dedup();
    let fit = |t: &[Sample]| CostModel::fit(t, device, "held out");
    // Per group: the held-out model with its errors and stage laws, fitted without it.
    let mut models: Vec<(String, CostModel)> = Vec::new();
    for g in &groups {
        let train: Vec<Sample> = samples.iter().zip(&keys).filter(|(_, k)| *k != g).map(|(s, _)| s.clone()).collect();
        let (ridge, _) = choose_prior_ridge(&train, device, tie_margin);
        let fit_prior = |t: &[Sample]| fit(t)?.with_prior(t, ridge)?.with_size(t);
        let Ok(mut m) = fit_prior(&train) else { continue };
        m.uncertainty = fit_uncertainty(&train, &fit_prior);
        m.inquiry_costs = fit_inquiry_costs(&train);
        models.push((g.clone(), m));
    }
    let size = |t: &[Sample]| CostModel::fit_size_only(t, device, "held out, size only");
    let mut size_models: Vec<(String, CostModel)> = Vec::new();
    for g in &groups {
        let train: Vec<Sample> = samples.iter().zip(&keys).filter(|(_, k)| *k != g).map(|(s, _)| s.clone()).collect();
        if let Ok(m) = size(&train) {
            size_models.push((g.clone(), m));
        }
    }
    let model_of = |ms: &'_ [(String, CostModel)], smp: &Sample| -> Option<CostModel> {
        let k = key(smp);
        ms.iter().find(|(g, _)| *g == k).map(|(_, m)| m.clone())
    };
    let mut kinds: Vec<String> = samples.iter().map(|s| s.workload.kind.as_str().to_string()).collect();
    kinds.sort();
    kinds.dedup();
    // The best single structure per kind in hindsight (over the single-frame samples).
    let by_frames: Vec<(u64, Vec<Sample>)> =
        E2E_FRAMES.iter().map(|&f| (f, super::compare::with_frames(samples, &[f]))).collect();
    let best_single: Vec<(u64, String, Option<StructureName>)> = by_frames
        .iter()
        .flat_map(|(f, set)| kinds.iter().map(move |k| (*f, k, set)))
        .map(|(f, k, set)| {
            let of: Vec<&Sample> = set.iter().filter(|s| s.workload.kind.as_str() == k).collect();
            let mean = |st: StructureName| {
                let r: Vec<f64> =
                    of.iter().filter(|x| x.best().is_some()).map(|x| x.regret(st).unwrap_or(f64::INFINITY)).collect();
                if r.is_empty() {
                    f64::INFINITY
                } else {
                    r.iter().sum::<f64>() / r.len() as f64
                }
            };
            let b = StructureName::ALL.into_iter().min_by(|a, b| mean(*a).total_cmp(&mean(*b)));
            (f, k.clone(), b)
        })
        .collect();
    let has_timed = samples.iter().any(|s| !s.timed.is_empty());
    let has_measured = samples.iter().any(|s| !s.frame_timings.is_empty());
    type Rule<'r> = Box<dyn Fn(&Sample) -> Choice + 'r>;
    let fixed = |c: Option<StructureName>, ms: f64, level: Level| Choice {
        structure: c,
        decision_ms: ms,
        level,
        by_size: false,
    };
    let mut rules: Vec<(&str, &str, Rule<'_>)> = vec![
        ("oracle", "hindsight", Box::new(|s: &Sample| fixed(s.best().map(|m| m.structure), 0.0, Level::Prior))),
        ("thesis", "recorded", Box::new(|s: &Sample| fixed(s.baseline, s.stage_ms.characterize_ms, Level::Prior))),
        (
            "best_single",
            "hindsight",
            Box::new(|s: &Sample| {
                let (f, k) = (s.workload.frames, s.workload.kind.as_str());
                fixed(best_single.iter().find(|b| b.0 == f && b.1 == k).and_then(|b| b.2), 0.0, Level::Prior)
            }),
        ),
        ("always_bvh", "none", Box::new(|_: &Sample| fixed(Some(StructureName::Bvh), 0.0, Level::Prior))),
        (
            "size_only",
            holdout,
            Box::new(|s: &Sample| {
                let c =
                    model_of(&size_models, s).and_then(|m| choose(&m.predict(&s.features, &s.workload), tie_margin));
                fixed(c, 0.0, Level::Prior)
            }),
        ),
    ];
    let mut levels = vec![("level0", Level::Prior), ("level1", Level::Counted)];
    if has_timed {
        levels.push(("level2", Level::Timed));
    }
    if has_measured {
        levels.push(("level3", Level::Measured));
    }
    let models = &models;
    for (name, level) in levels {
        rules.push((
            name,
            holdout,
            Box::new(move |s: &Sample| match model_of(models, s) {
                Some(m) => decide(&m, s, Inquiry::Fixed(level), tie_margin, decision_budget),
                None => fixed(None, 0.0, level),
            }),
        ));
    }
    rules.push((
        "crossings",
        holdout,
        Box::new(move |s: &Sample| match model_of(models, s) {
            Some(m) => decide_on_crossings(&m, s, tie_margin),
            None => fixed(None, 0.0, Level::Counted),
        }),
    ));
    rules.push((
        "ladder",
        holdout,
        Box::new(|s: &Sample| match model_of(models, s) {
            Some(m) => decide(&m, s, Inquiry::Auto, tie_margin, decision_budget),
            None => fixed(None, 0.0, Level::Prior),
        }),
    ));
    let mut out = Vec::new();
    for (name, how, rule) in &rules {
        let mut overall = Vec::new();
        let mut per_kind: Vec<(String, Vec<E2eScore>)> = kinds.iter().map(|k| (k.clone(), Vec::new())).collect();
        for (f, set) in &by_frames {
            let all: Vec<&Sample> = set.iter().collect();
            let choices: Vec<Choice> = all.iter().map(|s| rule(s)).collect();
            overall.push(score(&all, &choices, *f));
            for (k, v) in per_kind.iter_mut() {
                let (sub, ch): (Vec<&Sample>, Vec<Choice>) = all
                    .iter()
                    .zip(&choices)
                    .filter(|(s, _)| s.workload.kind.as_str() == k)
                    .map(|(s, c)| (*s, *c))
                    .unzip();
                v.push(score(&sub, &ch, *f));
            }
        }
        out.push(E2ePolicy { policy: name.to_string(), holdout: how.to_string(), overall, by_workload: per_kind });
    }
    Ok(out)
}
