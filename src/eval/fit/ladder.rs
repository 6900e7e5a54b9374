//! What the selection's ladder reads from a calibration: the model's own held-out errors at each level of
//! knowledge ([`Uncertainty`]) and what each stage of a decision costs ([`InquiryCost`]).

use super::laws::rms;
use super::linalg;
use super::Sample;
use crate::accel::StructureName;
use crate::cost::{
    CostError, CostModel, InquiryCost, Prediction, StructureUncertainty, Uncertainty, BUILD_EXPONENT_RANGE, PROBED,
};

/// A sample's predictions at the levels of knowledge [`Uncertainty`] distinguishes (each `None` where the sample
/// cannot say: no timed probes, no measured frames).
struct Levels {
    pub size: Option<Vec<Prediction>>,
    pub prior: Vec<Prediction>,
    pub crossings: Vec<Prediction>,
    pub probed: Vec<Prediction>,
    pub timed: Option<Vec<Prediction>>,
}

/// The predictions of `model` for `smp` at each level: features alone; with the crossings but no probe; with
/// every probe; and with the timed probes blended in.
fn levels(model: &CostModel, smp: &Sample) -> Levels {
    let prior = model.predict(&smp.features, &smp.workload);
    let stripped = Sample { crossings: smp.crossings.map(without_probes), grid_build_work: 0.0, ..smp.clone() };
    let crossings = stripped.predict(model);
    let probed = smp.predict(model);
    let timed = match (&model.timed, smp.timed.is_empty()) {
        (Some(r), false) => {
            let mut p = probed.clone();
            crate::cost::timed::blend(&mut p, &smp.timed, r, &smp.workload);
            Some(p)
        }
        _ => None,
    };
    let size = model.predict_size(smp.features.scene_triangles(), &smp.workload);
    Levels { size, prior, crossings, probed, timed }
}

/// `c` without any probe's counts or build work.
pub(crate) fn without_probes(mut c: crate::cost::RayCrossings) -> crate::cost::RayCrossings {
    c.probes = Default::default();
    c.probe_work = [0.0; crate::cost::probe::PROBES];
    c
}

/// The held-out errors of each structure's total: the samples' groups (families where they span at least three,
/// else scenes; [`super::super::compare::family_of`]) each predicted by `fit` on the others, at every level of
/// levels (features alone, crossings, probes, timed probes), and the measured frames (where the samples have them) against the oracle. `None` with fewer than
/// two groups, or where no fit succeeds.
pub fn fit_uncertainty(
    samples: &[Sample],
    fit: &dyn Fn(&[Sample]) -> Result<CostModel, CostError>,
) -> Option<Uncertainty> {
    let family = |s: &Sample| crate::eval::compare::family_of(&s.scene);
    let mut families: Vec<String> = samples.iter().map(family).collect();
    families.sort();
    families.dedup();
    let by_family = families.len() >= 3;
    let key = |s: &Sample| if by_family { family(s) } else { s.scene.clone() };
    let keys: Vec<String> = samples.iter().map(key).collect();
    let mut groups = keys.clone();
    groups.sort();
    groups.dedup();
    if groups.len() < 2 {
        return None;
    }
    // Per structure: the log errors at each level.
    type Errors = [Vec<f64>; 6];
    let mut errors: Vec<(StructureName, Errors)> =
        StructureName::ALL.iter().map(|&s| (s, Default::default())).collect();
    let mut fitted = false;
    for g in &groups {
        let train: Vec<Sample> = samples.iter().zip(&keys).filter(|(_, k)| *k != g).map(|(s, _)| s.clone()).collect();
        let Ok(model) = fit(&train) else { continue };
        fitted = true;
        for (smp, _) in samples.iter().zip(&keys).filter(|(_, k)| *k == g) {
            let l = levels(&model, smp);
            for (s, e) in errors.iter_mut() {
                let Some(m) = smp.get(*s).filter(|m| m.valid && m.total_ms > 0.0) else { continue };
                let err = |p: &[Prediction]| {
                    p.iter().find(|p| p.structure == *s).map(|p| (p.total_ms.max(1e-12) / m.total_ms).ln())
                };
                let lists = [Some(&l.prior[..]), Some(&l.crossings[..]), Some(&l.probed[..]), l.timed.as_deref()];
                for (k, p) in lists.into_iter().enumerate() {
                    if let Some(x) = p.and_then(err).filter(|x| x.is_finite()) {
                        e[k].push(x);
                    }
                }
                let w = &smp.workload;
                let measured =
                    smp.frame_timings.iter().find(|t| t.structure == *s).and_then(|t| t.total_ms(w.builds, w.frames));
                if let Some(x) = measured.map(|t| (t.max(1e-12) / m.total_ms).ln()).filter(|x| x.is_finite()) {
                    e[4].push(x);
                }
                if let Some(x) = l.size.as_deref().and_then(err).filter(|x| x.is_finite()) {
                    e[5].push(x);
                }
            }
        }
    }
    if !fitted {
        return None;
    }
    let structures = errors
        .into_iter()
        .filter(|(_, e)| !e[0].is_empty())
        .map(|(structure, e)| {
            let opt = |v: &Vec<f64>| (!v.is_empty()).then(|| rms(v));
            StructureUncertainty {
                structure,
                prior: rms(&e[0]),
                crossings: rms(&e[1]),
                probed: rms(&e[2]),
                timed: opt(&e[3]),
                measured: opt(&e[4]),
                size: opt(&e[5]),
                samples: e[0].len(),
            }
        })
        .collect();
    Some(Uncertainty { holdout: if by_family { "family" } else { "scene" }.into(), structures })
}

/// The laws of what each decision stage took when the samples were loaded ([`Sample::stage_ms`]): one per stage
/// with at least three distinct measurements over at least two sizes, by least squares in log space (the exponent
/// held in [`BUILD_EXPONENT_RANGE`]).
pub fn fit_inquiry_costs(samples: &[Sample]) -> Vec<InquiryCost> {
    type Stage = (String, Box<dyn Fn(&Sample) -> f64>);
    let mut stages: Vec<Stage> = vec![
        ("characterize".into(), Box::new(|s: &Sample| s.stage_ms.characterize_ms)),
        ("features".into(), Box::new(|s: &Sample| s.stage_ms.features_ms)),
        ("crossings".into(), Box::new(|s: &Sample| s.stage_ms.crossings_ms)),
    ];
    for (i, &p) in PROBED.iter().enumerate() {
        stages.push((InquiryCost::probe_stage(p), Box::new(move |s: &Sample| s.stage_ms.probe_ms[i])));
    }
    let mut out = Vec::new();
    for (stage, of) in stages {
        let mut points: Vec<(u64, f64)> = samples
            .iter()
            .map(|s| (s.features.scene_triangles().max(1), of(s)))
            .filter(|(_, ms)| ms.is_finite() && *ms > 0.0)
            .collect();
        points.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        points.dedup();
        let sizes = points.windows(2).filter(|w| w[0].0 != w[1].0).count() + 1;
        if points.len() < 3 || sizes < 2 {
            continue;
        }
        let x: Vec<Vec<f64>> = points.iter().map(|&(n, _)| vec![1.0, (n as f64).ln()]).collect();
        let y: Vec<f64> = points.iter().map(|&(_, ms)| ms.ln()).collect();
        let Some(c) = linalg::weighted_ridge(&x, &y, &vec![1.0; x.len()], &[0.0, 1e-9]) else { continue };
        let b = c[1].clamp(*BUILD_EXPONENT_RANGE.start(), *BUILD_EXPONENT_RANGE.end());
        let a =
            if b == c[1] { c[0] } else { x.iter().zip(&y).map(|(r, ly)| ly - b * r[1]).sum::<f64>() / y.len() as f64 };
        let e: Vec<f64> = x.iter().zip(&y).map(|(r, ly)| a + b * r[1] - ly).collect();
        out.push(InquiryCost { stage, ln_a: a, exponent: b, rms: rms(&e), samples: points.len() });
    }
    out
}
