//! The prior's count laws ([`crate::cost::CountLaw`]): fitted apart from the laws the crossings and probes
//! correct, with the shrinkage under which the prior alone chooses best on held-out records.

use super::laws::fit_structure;
use super::Sample;
use crate::cost::{CostError, CostModel, CountLaw, ViewFeatures};
use crate::select::choose;

/// The shrinkages the prior is chosen among: ridges on the geometric and view coefficients, and `None`, the
/// size-only laws (triangle count and kind of ray).
pub const PRIOR_RIDGES: [Option<f64>; 8] =
    [Some(0.05), Some(0.2), Some(1.0), Some(5.0), Some(20.0), Some(100.0), Some(1000.0), None];

impl CostModel {
    /// This model with the prior's count laws fitted on `samples` at `ridge` (`None`: the size-only laws).
    pub fn with_prior(mut self, samples: &[Sample], ridge: Option<f64>) -> Result<CostModel, CostError> {
        let geometric = ridge.is_some();
        let views = geometric
            && samples
                .iter()
                .any(|s| s.workload.view.is_some_and(|v| v != ViewFeatures::framing(s.features.lo, s.features.hi)));
        for m in &mut self.structures {
            let fitted = fit_structure(samples, m.structure, geometric, views, false, ridge.unwrap_or(0.05))?;
            m.prior = fitted.map(|f| CountLaw {
                box_coef: f.box_coef,
                prim_coef: f.prim_coef,
                view_box_coef: f.view_box_coef,
                view_prim_coef: f.view_prim_coef,
            });
        }
        Ok(self)
    }

    /// The model with each structure's size law ([`crate::cost::StructureModel::size`]) fitted on `samples`: the
    /// count laws of the triangle count alone, as the size-only model has them.
    pub fn with_size(mut self, samples: &[Sample]) -> Result<CostModel, CostError> {
        for m in &mut self.structures {
            let fitted = fit_structure(samples, m.structure, false, false, false, 0.05)?;
            m.size = fitted.map(|f| CountLaw {
                box_coef: f.box_coef,
                prim_coef: f.prim_coef,
                view_box_coef: Vec::new(),
                view_prim_coef: Vec::new(),
            });
        }
        Ok(self)
    }
}

/// The prior's shrinkage chosen inside `samples`: each group (its family where the samples span at least three,
/// else its scene) held out in turn, the model fitted on the others with each of [`PRIOR_RIDGES`], its prior's
/// choices on the group scored; the least mean regret wins (the first on a tie). Returns it and every candidate's
/// mean regret; `Some(0.05)` (the count laws' own ridge) when the samples hold fewer than two groups.
pub fn choose_prior_ridge(samples: &[Sample], device: &str, tie_margin: f64) -> (Option<f64>, Vec<(Option<f64>, f64)>) {
    let family = |s: &Sample| crate::eval::compare::family_of(&s.scene);
    let mut families: Vec<String> = samples.iter().map(family).collect();
    families.sort();
    families.dedup();
    let by_family = families.len() >= 3;
    let keys: Vec<String> = samples.iter().map(|s| if by_family { family(s) } else { s.scene.clone() }).collect();
    let mut groups = keys.clone();
    groups.sort();
    groups.dedup();
    if groups.len() < 2 {
        return (Some(0.05), Vec::new());
    }
    let trains: Vec<(String, Vec<Sample>, Option<CostModel>)> = groups
        .iter()
        .map(|g| {
            let t: Vec<Sample> = samples.iter().zip(&keys).filter(|(_, k)| *k != g).map(|(s, _)| s.clone()).collect();
            let m = CostModel::fit(&t, device, "prior").ok();
            (g.clone(), t, m)
        })
        .collect();
    let mut scores = Vec::new();
    for r in PRIOR_RIDGES {
        let mut regrets = Vec::new();
        for (g, train, base) in &trains {
            let Some(m) = base.clone().and_then(|b| b.with_prior(train, r).ok()) else { continue };
            for (smp, _) in samples.iter().zip(&keys).filter(|(_, k)| *k == g) {
                if let Some(x) =
                    choose(&m.predict(&smp.features, &smp.workload), tie_margin).and_then(|c| smp.regret(c))
                {
                    regrets.push(x);
                }
            }
        }
        let mean = if regrets.is_empty() { f64::INFINITY } else { regrets.iter().sum::<f64>() / regrets.len() as f64 };
        scores.push((r, mean));
    }
    let best = scores.iter().fold(None, |b: Option<(Option<f64>, f64)>, &x| match b {
        Some(b) if b.1 <= x.1 => Some(b),
        _ => Some(x),
    });
    (best.map_or(Some(0.05), |b| b.0), scores)
}
