//! The calibration's held-out errors by level of knowledge ([`Uncertainty`]) and what each stage of a decision
//! costs ([`InquiryCost`]): what the selection's ladder weighs.

use super::*;

/// One structure's held-out errors of its predicted total (RMS of `ln(predicted / measured)`), by what is known.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StructureUncertainty {
    /// The structure.
    pub structure: StructureName,
    /// From the triangle count alone, before any characterization ([`StructureModel::size`]); absent in files
    /// written without size laws.
    #[serde(default)]
    pub size: Option<f64>,
    /// From the features alone (level 0).
    #[serde(deserialize_with = "f64_or_null")]
    pub prior: f64,
    /// With the mesh's crossings, the structure itself not probed (level 1, another structure's probe).
    #[serde(deserialize_with = "f64_or_null")]
    pub crossings: f64,
    /// With the crossings and its own count probe (level 1).
    #[serde(deserialize_with = "f64_or_null")]
    pub probed: f64,
    /// With its timed probe blended in as well (level 2), when the records had timed probes.
    #[serde(default)]
    pub timed: Option<f64>,
    /// Measured over whole frames (level 3) against the oracle, when the records had measured frames.
    #[serde(default)]
    pub measured: Option<f64>,
    /// Samples behind the figures.
    pub samples: usize,
}

/// The calibration's held-out errors ([`StructureUncertainty`] per structure): each group of the records
/// (`holdout`: its family, or its scene where the records hold fewer than three families) predicted by a fit on
/// the others.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Uncertainty {
    /// `family` or `scene`.
    pub holdout: String,
    /// One per structure fitted.
    pub structures: Vec<StructureUncertainty>,
}

impl Uncertainty {
    /// The figures of `structure`.
    pub fn of(&self, structure: StructureName) -> Option<&StructureUncertainty> {
        self.structures.iter().find(|u| u.structure == structure)
    }
}

/// What one stage of a decision costs, `ms = exp(ln_a) * n^exponent` for `n` triangles, fitted on the wall times
/// measured warm when the calibration's records were loaded.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InquiryCost {
    /// `characterize`, `features`, `crossings`, or `probe:<structure>` ([`PROBED`]).
    pub stage: String,
    /// `ln` of the ms of one triangle.
    #[serde(deserialize_with = "f64_or_null")]
    pub ln_a: f64,
    /// The exponent of `n`.
    #[serde(deserialize_with = "f64_or_null")]
    pub exponent: f64,
    /// RMS of `ln(law / measured)` over the samples.
    #[serde(deserialize_with = "f64_or_null")]
    pub rms: f64,
    /// Samples fitted.
    pub samples: usize,
}

impl InquiryCost {
    /// The stage's name for a probe of `structure`.
    pub(crate) fn probe_stage(structure: StructureName) -> String {
        format!("probe:{structure}")
    }

    /// The law's ms for `n` triangles.
    pub fn ms(&self, n: u64) -> f64 {
        (self.ln_a + self.exponent * (n.max(1) as f64).ln()).exp()
    }
}
