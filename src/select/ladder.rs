//! The value of knowing more: whether a level of inquiry pays for itself.
//!
//! Each candidate's predicted total `P_i` is off by a factor `exp(sigma_i z)`, `z` standard normal, where
//! `sigma_i` is the calibration's own held-out error of that structure's total at the knowledge in hand
//! ([`crate::cost::Uncertainty`]). Deciding now picks `c`, the least prediction; its expected regret is
//! `E[T_c - min_i T_i]` over the true totals `T_i = P_i exp(sigma_i z_i)`. An inquiry replaces the predictions of
//! the structures it covers by estimates off by `exp(sigma'_i z'_i)` (the calibration's error after that level);
//! the choice is then the least of the new estimates, and its expected regret is computed the same way. The
//! expected gain of the inquiry is the difference of the two, in ms of the workload's frames; the inquiry is worth
//! making when the gain exceeds its predicted cost.
//!
//! The expectations are means over [`DRAWS`] fixed draws (quantiles of the normal distribution in a rotated
//! lattice, the same on every call), so the decision is deterministic. For six structures this costs a few
//! microseconds.

use std::sync::OnceLock;

/// Draws of the expectations.
pub const DRAWS: usize = 256;

/// Candidates a draw table covers (the project's six structures and room for more).
const WIDTH: usize = 8;

/// Standard normal draws per draw and candidate: the truth's (`[0]`) and an inquiry's error (`[1]`). A Latin
/// hypercube: every column holds the quantiles at `(j + 1/2) / DRAWS`, each column in its own order (a shuffle
/// from a fixed seed), so every marginal is exactly stratified and the columns are independent.
fn table() -> &'static [[[f64; WIDTH]; 2]; DRAWS] {
    static TABLE: OnceLock<Box<[[[f64; WIDTH]; 2]; DRAWS]>> = OnceLock::new();
    TABLE.get_or_init(|| {
        use statrs::distribution::{ContinuousCDF, Normal};
        let normal = Normal::standard();
        let quantiles: Vec<f64> = (0..DRAWS).map(|j| normal.inverse_cdf((j as f64 + 0.5) / DRAWS as f64)).collect();
        let mut rng = crate::rng::SplitMix64::new(0x6c61_6464_6572);
        let mut t = Box::new([[[0.0; WIDTH]; 2]; DRAWS]);
        for k in 0..2 {
            for i in 0..WIDTH {
                let mut order: Vec<usize> = (0..DRAWS).collect();
                for j in (1..DRAWS).rev() {
                    order.swap(j, rng.below(j as u64 + 1) as usize);
                }
                for (j, &o) in order.iter().enumerate() {
                    t[j][k][i] = quantiles[o];
                }
            }
        }
        t
    })
}

/// One candidate as the ladder sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Predicted total over the workload, ms.
    pub total_ms: f64,
    /// Its error now (log-space standard deviation).
    pub sigma: f64,
    /// Its error after the inquiry under consideration; `None`: the inquiry does not cover it (its prediction
    /// stays).
    pub sigma_after: Option<f64>,
}

/// Expected regret (ms) of choosing the least prediction now, and after the inquiry the candidates describe.
/// Candidates past [`WIDTH`] are ignored, as are those with a total that is not finite and positive.
pub(crate) fn expected_regret(candidates: &[Candidate]) -> (f64, f64) {
    let c: Vec<&Candidate> =
        candidates.iter().filter(|c| c.total_ms.is_finite() && c.total_ms > 0.0).take(WIDTH).collect();
    if c.len() < 2 {
        return (0.0, 0.0);
    }
    let now = (0..c.len()).min_by(|&a, &b| c[a].total_ms.total_cmp(&c[b].total_ms)).unwrap_or(0);
    let (mut before, mut after) = (0.0, 0.0);
    for draw in table().iter() {
        let truth: Vec<f64> =
            c.iter().enumerate().map(|(i, x)| x.total_ms * (x.sigma.max(0.0) * draw[0][i]).exp()).collect();
        let least = truth.iter().copied().fold(f64::INFINITY, f64::min);
        before += truth[now] - least;
        let estimate = |i: usize| match c[i].sigma_after {
            Some(s) => truth[i] * (s.max(0.0) * draw[1][i]).exp(),
            None => c[i].total_ms,
        };
        let pick = (0..c.len()).min_by(|&a, &b| estimate(a).total_cmp(&estimate(b))).unwrap_or(now);
        after += truth[pick] - least;
    }
    (before / DRAWS as f64, after / DRAWS as f64)
}

/// The expected gain of an inquiry (ms, `>= 0`): [`expected_regret`] now less after.
pub(crate) fn expected_gain(candidates: &[Candidate]) -> f64 {
    let (before, after) = expected_regret(candidates);
    (before - after).max(0.0)
}

/// Per candidate, the share of draws in which it is truly the cheapest (its chance of being the best, by the
/// errors now): the order in which an inquiry of a few candidates takes them.
pub(crate) fn chance_best(candidates: &[Candidate]) -> Vec<f64> {
    let n = candidates.len().min(WIDTH);
    let mut wins = vec![0usize; candidates.len()];
    for draw in table().iter() {
        let best = (0..n)
            .filter(|&i| candidates[i].total_ms.is_finite() && candidates[i].total_ms > 0.0)
            .map(|i| (i, candidates[i].total_ms * (candidates[i].sigma.max(0.0) * draw[0][i]).exp()))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((i, _)) = best {
            wins[i] += 1;
        }
    }
    wins.iter().map(|&w| w as f64 / DRAWS as f64).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cand(total_ms: f64, sigma: f64, after: Option<f64>) -> Candidate {
        Candidate { total_ms, sigma, sigma_after: after }
    }

    #[test]
    fn the_draws_are_standard_normal() {
        let t = table();
        for k in 0..2 {
            for i in 0..WIDTH {
                let v: Vec<f64> = t.iter().map(|d| d[k][i]).collect();
                let mean = v.iter().sum::<f64>() / v.len() as f64;
                let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64;
                assert!(mean.abs() < 1e-9 && (var - 1.0).abs() < 0.05, "column {k}/{i}: mean {mean}, var {var}");
            }
        }
    }

    #[test]
    fn certain_predictions_gain_nothing_and_a_perfect_inquiry_of_a_close_call_gains_most() {
        assert_eq!(expected_regret(&[cand(10.0, 0.0, Some(0.0)), cand(11.0, 0.0, Some(0.0))]), (0.0, 0.0));
        let close = [cand(10.0, 0.5, Some(0.0)), cand(10.5, 0.5, Some(0.0))];
        let far = [cand(10.0, 0.5, Some(0.0)), cand(100.0, 0.5, Some(0.0))];
        let (before, after) = expected_regret(&close);
        assert!(before > 1.0 && after.abs() < 1e-9, "{before} {after}");
        assert!(expected_gain(&close) > 10.0 * expected_gain(&far), "{:?} {:?}", close, far);
        // A noisier inquiry gains less; one that covers nothing gains nothing.
        let noisy = [cand(10.0, 0.5, Some(0.3)), cand(10.5, 0.5, Some(0.3))];
        assert!(expected_gain(&noisy) < expected_gain(&close));
        assert_eq!(expected_gain(&[cand(10.0, 0.5, None), cand(10.5, 0.5, None)]), 0.0);
        // Deterministic.
        assert_eq!(expected_regret(&close), expected_regret(&close));
    }

    #[test]
    fn the_chance_of_being_best_follows_the_margin() {
        let p = chance_best(&[cand(10.0, 0.3, None), cand(12.0, 0.3, None), cand(1000.0, 0.3, None)]);
        assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        assert!(p[0] > p[1] && p[1] > p[2] && p[2] == 0.0, "{p:?}");
        // Independent columns: P(T0 < T1) = Phi(ln(1.2) / (0.3 sqrt 2)) = 0.667.
        assert!((p[0] - 0.667).abs() < 0.05, "{p:?}");
    }
}
