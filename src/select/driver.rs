//! The driver's acceleration structures as candidates of the calibrated policy: which build flags, and, for an
//! animation, when to update (`MODE_UPDATE`) and when to rebuild.
//!
//! A static scene takes the driver flag set with the smallest predicted total ([`crate::cost::DriverModel`]); an
//! animation compares rebuilding every frame with each flag set against the per-frame plan of the updatable
//! structure (`rt_update`, [`DriverFrameRule`]): per frame, update the structure in use or rebuild it, whichever
//! predicts the smaller update-plus-trace time, where the updated structure's trace time grows with the drift of the
//! geometry since its build (`1 + g * drift`, [`crate::cost::DriverUpdateModel`]).

use crate::accel::driver::DriverFlags;
use crate::characterize::Features;
use crate::cost::{CostModel, DriverPrediction, Workload};
use crate::geom::WorkloadKind;

/// What a frame does with the driver structure.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DriverAction {
    /// Build it anew (`MODE_BUILD`).
    Rebuild,
    /// Update it in place (`MODE_UPDATE`, needs `ALLOW_UPDATE`).
    Update,
}

impl DriverAction {
    /// `rebuild` or `update` (as in JSON).
    pub fn as_str(self) -> &'static str {
        match self {
            DriverAction::Rebuild => "rebuild",
            DriverAction::Update => "update",
        }
    }
}

/// One frame of a driver structure's plan.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DriverFrameDecision {
    /// Frame index.
    pub frame: usize,
    /// Rebuild or update.
    pub action: DriverAction,
    /// Predicted ms of the action.
    pub update_ms: f64,
    /// Predicted trace ms of the frame.
    pub trace_ms: f64,
    /// Drift since the structure was built (0 after a rebuild).
    pub drift: f64,
}

/// The per-frame rule of the updatable driver structure (`rt_update`), one frame at a time, for a caller that
/// learns each frame's features as it goes (see `examples/engine_frame.rs`).
#[derive(Clone, Copy, Debug)]
pub struct DriverFrameRule<'a> {
    /// The cost model (with a driver model for `rt_update`).
    pub model: &'a CostModel,
    /// Kind of the rays traced per frame.
    pub kind: WorkloadKind,
    /// Rays per frame (for shadow and diffuse rays the secondary rays traced, not the image's pixels; see
    /// [`crate::select::TargetWorkload::rays_per_frame`]).
    pub rays_per_frame: u64,
}

impl DriverFrameRule<'_> {
    /// Frame `frame`'s decision for a scene with features `now`, given the features of the frame the structure in
    /// use was built for (`None` before the first build): update when the model has an update law and the update
    /// plus the drifted trace predicts less than a rebuild plus a fresh trace, else rebuild. `None` when the model
    /// has no `rt_update` model.
    pub fn decide(&self, frame: usize, now: &Features, built: Option<&Features>) -> Option<DriverFrameDecision> {
        let m = self.model.get_driver(DriverFlags::Update)?;
        let n = now.scene_triangles();
        let trace = m.trace_ns(&now.derived(), self.kind) * 1e-6 * self.rays_per_frame as f64;
        let rebuild = DriverFrameDecision {
            frame,
            action: DriverAction::Rebuild,
            update_ms: m.build_ms(n),
            trace_ms: trace,
            drift: 0.0,
        };
        let update = match (built, m.update, m.update_ms(n)) {
            (Some(b), Some(u), Some(ms)) => {
                let d = crate::cost::drift(b, now);
                Some(DriverFrameDecision {
                    frame,
                    action: DriverAction::Update,
                    update_ms: ms,
                    trace_ms: trace * (1.0 + u.trace_growth_per_drift.max(0.0) * d),
                    drift: d,
                })
            }
            _ => None,
        };
        Some(match update {
            Some(u) if u.update_ms + u.trace_ms < rebuild.update_ms + rebuild.trace_ms => u,
            _ => rebuild,
        })
    }
}

/// The per-frame plan of the updatable driver structure over an animation's `features` ([`DriverFrameRule`] frame
/// by frame); empty when the model has no `rt_update` model.
pub(crate) fn plan_driver_frames(
    model: &CostModel,
    features: &[Features],
    kind: WorkloadKind,
    rays_per_frame: u64,
) -> Vec<DriverFrameDecision> {
    let rule = DriverFrameRule { model, kind, rays_per_frame };
    let mut out = Vec::new();
    let mut built: Option<usize> = None;
    for (i, f) in features.iter().enumerate() {
        let Some(d) = rule.decide(i, f, built.map(|b| &features[b])) else { break };
        if d.action == DriverAction::Rebuild {
            built = Some(i);
        }
        out.push(d);
    }
    out
}

/// The calibrated policy's pick among the driver structures (see the module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DriverSelection {
    /// The build flags (`rt_fast_trace`, ... in JSON).
    #[serde(serialize_with = "flags_name")]
    pub flags: DriverFlags,
    /// Predicted total ms over the workload (for an animation with `rt_update`: of its per-frame plan).
    pub predicted_total_ms: f64,
    /// Whether it is predicted cheaper than the project's structure the policy selected: then it is the policy's
    /// overall choice ([`super::Selection::candidate`]).
    pub chosen: bool,
    /// For an animation traced with `rt_update`: the per-frame update-or-rebuild plan (empty otherwise).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub plan: Vec<DriverFrameDecision>,
}

fn flags_name<S: serde::Serializer>(f: &DriverFlags, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(f.name())
}

/// The best driver structure for a scene (`features` of the frames the run covers: one for a static scene) under
/// workload `w`, with reasons; `None` when the model has no driver structures. `own_total_ms` is the predicted
/// total of the project's structure chosen otherwise, for the comparison the reasons state.
pub(crate) fn choose_driver(
    model: &CostModel,
    features: &[Features],
    w: &Workload,
    own: Option<(crate::accel::StructureName, f64)>,
) -> Option<(DriverSelection, Vec<super::Reason>)> {
    let first = features.first()?;
    let preds = model.predict_driver(first, w);
    if preds.is_empty() {
        return None;
    }
    let mut reasons = Vec::new();
    let mut sorted: Vec<DriverPrediction> = preds.clone();
    sorted.sort_by(|a, b| a.total_ms.total_cmp(&b.total_ms));
    for p in &sorted {
        reasons.push(format!(
            "driver {} ({}): predicted build {:.2} ms ({} x {:.2}{}), trace {:.2} ms ({:.1} ns/ray), total {:.2} ms",
            p.flags.name(),
            flag_words(p.flags),
            p.build_ms,
            w.builds,
            p.build_ms_per_build,
            if p.flags == DriverFlags::Update && w.builds > 1 { ", then updates" } else { "" },
            p.trace_ms,
            p.trace_ns_per_ray,
            p.total_ms
        ));
    }
    // An animation: the update plan against rebuilding every frame.
    let mut plan = Vec::new();
    let mut totals: Vec<(DriverFlags, f64)> = sorted.iter().map(|p| (p.flags, p.total_ms)).collect();
    if features.len() > 1 {
        plan = plan_driver_frames(model, features, w.kind, w.rays_per_frame);
        if !plan.is_empty() {
            let updates = plan.iter().filter(|d| d.action == DriverAction::Update).count();
            let total: f64 = plan.iter().map(|d| d.update_ms + d.trace_ms).sum();
            let growth =
                model.get_driver(DriverFlags::Update).and_then(|m| m.update).map_or(0.0, |u| u.trace_growth_per_drift);
            reasons.push(format!(
                "driver rt_update per frame: {} rebuild(s), {updates} update(s), predicted {total:.2} ms in all \
                 (trace grows {growth:.2} x drift after an update): {}",
                plan.len() - updates,
                plan.iter()
                    .map(|d| format!("{}:{} (drift {:.3})", d.frame, d.action.as_str(), d.drift))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
            if let Some(t) = totals.iter_mut().find(|(f, _)| *f == DriverFlags::Update) {
                t.1 = total;
            }
        }
    }
    totals.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (flags, total) = totals[0];
    if flags != DriverFlags::Update {
        plan.clear();
    }
    // Why this flag set: what it saves over the runner-up, in build and in trace.
    if let Some(&(second, second_total)) = totals.get(1) {
        let p = |f: DriverFlags| sorted.iter().find(|p| p.flags == f).copied();
        if let (Some(a), Some(b)) = (p(flags), p(second)) {
            let (db, dt) = (b.build_ms - a.build_ms, b.trace_ms - a.trace_ms);
            let why = match (db >= 0.0, dt >= 0.0) {
                (true, true) => format!("builds {db:.2} ms and traces {dt:.2} ms faster"),
                (true, false) => format!("its build saves {db:.2} ms, more than its trace loses ({:.2} ms)", -dt),
                (false, true) => format!("its trace saves {dt:.2} ms, more than its build costs ({:.2} ms)", -db),
                (false, false) => "its per-frame plan is cheaper".to_string(),
            };
            reasons.push(format!(
                "driver choice: {} ({}), {:.0}% below {} ({}): {why}",
                flags.name(),
                flag_words(flags),
                100.0 * (1.0 - total / second_total.max(f64::MIN_POSITIVE)),
                second.name(),
                flag_words(second)
            ));
        }
    }
    let chosen = own.is_none_or(|(_, own_total)| total < own_total);
    match own {
        Some((s, own_total)) if chosen => reasons.push(format!(
            "overall: the driver's {} (predicted {total:.2} ms) is {:.0}% below the project's {s} ({own_total:.2} ms)",
            flags.name(),
            100.0 * (1.0 - total / own_total.max(f64::MIN_POSITIVE))
        )),
        Some((s, own_total)) => reasons.push(format!(
            "overall: the project's {s} (predicted {own_total:.2} ms) stays below the driver's {} ({total:.2} ms)",
            flags.name()
        )),
        None => {}
    }
    let reasons = reasons.into_iter().map(|r| super::Reason::new(super::ReasonKind::Driver, r)).collect();
    Some((DriverSelection { flags, predicted_total_ms: total, chosen, plan }, reasons))
}

/// The Vulkan flags of a choice, in words.
fn flag_words(f: DriverFlags) -> &'static str {
    match f {
        DriverFlags::FastTrace => "PREFER_FAST_TRACE",
        DriverFlags::FastBuild => "PREFER_FAST_BUILD",
        DriverFlags::Update => "PREFER_FAST_TRACE | ALLOW_UPDATE",
        DriverFlags::FastTraceCompact => "PREFER_FAST_TRACE | ALLOW_COMPACTION, compacted",
    }
}
