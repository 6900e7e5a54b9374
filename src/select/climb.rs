//! The ladder's climb ([`climb`]): what each level of inquiry would cost and gain, and what it learned.

use super::budget::BuildBounds;
use super::ladder::{chance_best, expected_gain, Candidate};
use super::selector::*;
use super::{Reason, ReasonKind, Structure};
use crate::cost::measured::{MeasuredTotal, MEASURED_REPEATS, MEASURED_WARMUP};
use crate::cost::{InquiryCost, Prediction, PROBED};

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
    pub(super) fn reasons(&self, s: &Selector<'_>, chosen: Structure) -> Vec<Reason> {
        let mut out = vec![Reason::new(
            ReasonKind::Decided { level: self.level },
            format!(
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
            ),
        )];
        for st in &self.steps {
            out.push(Reason::new(ReasonKind::Inquiry { level: st.level, taken: st.taken }, st.to_string()));
        }
        // A level asked for and not climbed says why, as the level's own line.
        if let Inquiry::Fixed(asked) = s.inquiry {
            for st in self.steps.iter().filter(|st| !st.taken && st.level <= asked) {
                let why = st.why_not.as_deref().unwrap_or("");
                let kind = ReasonKind::Inquiry { level: st.level, taken: false };
                match st.level {
                    Level::Timed => out.push(Reason::new(kind, format!("timed probes: none taken: {why}"))),
                    Level::Measured => out.push(Reason::new(kind, format!("measured close call: none: {why}"))),
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
            let kind = ReasonKind::Inquiry { level: Level::Measured, taken: true };
            out.push(Reason::new(
                kind,
                format!(
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
                ),
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
pub(super) struct MeshKnowledge<'s, 'm> {
    selector: &'s Selector<'m>,
    scene: Scene<'s>,
    /// The bounds known (`None`: the features' alone).
    pub(super) bounds: Option<BuildBounds>,
    pub(super) spent_ms: f64,
}

impl<'s, 'm> MeshKnowledge<'s, 'm> {
    pub(super) fn new(selector: &'s Selector<'m>, scene: &Scene<'s>) -> Self {
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
