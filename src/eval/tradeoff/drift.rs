//! How far a setting's statistics move from the reference computation.

use super::*;

/// How far a characterization's statistics are from the reference's (largest over frames).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Drift {
    /// `k - k_ref` of the frame with the largest `|k - k_ref|`.
    pub k_delta: i64,
    /// Largest `|V - V_ref|` (Cramér's V, the effect size).
    pub effect_size: f64,
    /// Largest total-variation distance between the class histograms ([`histogram_distance`]), in `[0, 1]`.
    pub histogram: f64,
    /// `empty - empty_ref` of the frame with the largest difference.
    pub empty_delta: i64,
    /// Largest `|concentrated share - concentrated share_ref|`.
    pub concentrated_share: f64,
}

/// The total-variation distance between two class histograms, each read as a step density over the normalized code
/// range `[0, 1)` (class `i` of `k` covers `[i / k, (i + 1) / k)` and holds its share of the triangles): half the
/// integral of the absolute difference of the densities. 0 for equal shares, 1 for disjoint supports; defined for
/// different class counts. An empty histogram counts as uniform.
pub fn histogram_distance(a: &[u64], b: &[u64]) -> f64 {
    fn density(h: &[u64]) -> Vec<f64> {
        let n: u64 = h.iter().sum();
        let k = h.len().max(1) as f64;
        if n == 0 || h.is_empty() {
            return vec![1.0];
        }
        h.iter().map(|&c| c as f64 / n as f64 * k).collect()
    }
    let (da, db) = (density(a), density(b));
    let (ka, kb) = (da.len() as u64, db.len() as u64);
    // Breakpoints i / ka and j / kb, merged exactly as fractions over ka * kb.
    let mut pts: Vec<u64> = (0..=ka).map(|i| i * kb).chain((0..=kb).map(|j| j * ka)).collect();
    pts.sort_unstable();
    pts.dedup();
    let total = (ka * kb) as f64;
    let mut sum = 0.0;
    for w in pts.windows(2) {
        let (x0, x1) = (w[0], w[1]);
        let ia = (x0 / kb).min(ka - 1) as usize;
        let ib = (x0 / ka).min(kb - 1) as usize;
        sum += (da[ia] - db[ib]).abs() * (x1 - x0) as f64 / total;
    }
    0.5 * sum
}

/// The drift of `c` from `reference`, frame by frame (the largest over the frames both have).
pub fn drift(reference: &[Characterization], c: &[Characterization]) -> Drift {
    let mut d = Drift::default();
    for (r, x) in reference.iter().zip(c) {
        let dk = x.classes as i64 - r.classes as i64;
        if dk.abs() > d.k_delta.abs() {
            d.k_delta = dk;
        }
        let de = x.stats.empty_classes as i64 - r.stats.empty_classes as i64;
        if de.abs() > d.empty_delta.abs() {
            d.empty_delta = de;
        }
        d.effect_size = d.effect_size.max((x.stats.cramers_v - r.stats.cramers_v).abs());
        d.histogram = d.histogram.max(histogram_distance(&r.histogram, &x.histogram));
        d.concentrated_share =
            d.concentrated_share.max((x.stats.concentrated_share - r.stats.concentrated_share).abs());
    }
    d
}

/// Tolerances under which two characterizations count as having the same statistics.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct StatsTolerance {
    /// Largest `|V - V_ref|` (default 0.005: half the 0.01 the report rounds the effect size to in tables).
    pub effect_size: f64,
    /// Largest change of the concentrated share (default 0.01, one percentage point).
    pub concentrated_share: f64,
}

impl Default for StatsTolerance {
    fn default() -> Self {
        StatsTolerance { effect_size: 0.005, concentrated_share: 0.01 }
    }
}

impl StatsTolerance {
    /// Whether a drift is within the tolerances (the empty-class count must be equal; `k` may differ, since
    /// Doane's and Sturges' `k` grow with `log2 n` by design).
    pub fn accepts(&self, d: &Drift) -> bool {
        d.effect_size <= self.effect_size && d.concentrated_share <= self.concentrated_share && d.empty_delta == 0
    }
}
