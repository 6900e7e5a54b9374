//! Speed against accuracy of the characterization's knobs: for each setting (backend, sample stride, Morton bits,
//! class-count rule) and each scene, the time of the characterization, how far its statistics move from the full
//! computation, whether the policy's selection changes, and the regret of that selection against oracle results.
//!
//! # Method
//!
//! * **Settings** ([`GridSpec::settings`]): one knob at a time around the reference (the rayon CPU backend, every
//!   triangle, 30-bit codes, Doane): every backend at every sample stride; the other bit depths at every stride on
//!   the reference backend; every other class rule on every triangle. The three backends report identical bits
//!   for the same parameters, so their accuracy is the same and only their time differs.
//! * **Time** of a setting on a scene: the median wall time of `repeats` characterizations of every frame on that
//!   backend (the Vulkan device and pipelines are created once, before timing; uploads are timed).
//! * **Drift** ([`Drift`]) against the reference computation, the largest over the frames: the change of `k`, of
//!   Cramér's V (the effect size), of the empty-class count and of the concentrated share, and the total-variation
//!   distance between the two class histograms read as step densities over the normalized code range
//!   ([`histogram_distance`], defined for different `k` too).
//! * **Selection** ([`Selector`]): either one policy (any [`Policy`], e.g. the thesis policy) on the scene's
//!   characterized frames, one selection per scene; or the calibrated policy ([`crate::select::CalibratedPolicy`]), one selection
//!   per scene *and workload*, since its answer depends on the rays per frame: for each workload, the oracle line's
//!   `rays_per_frame` and `frames` and the scene's features ([`features_cpu`]) computed with the setting's
//!   parameters (sampling and bit depth change the features too). The features are one more pass over the
//!   triangles on the CPU reference, after the timed characterization and not counted in the setting's time.
//! * **Accuracy** against oracle results ([`OracleRecord`], read from `evaluate --json` lines or measured): whether
//!   the selection is the oracle's best, whether it is within noise of it, and its regret
//!   `total(selected) / total(best) - 1`; per setting the mean and the worst regret over the scenes.
//! * **Pareto front** ([`pareto_front`]): the settings no other setting beats in both time and mean regret.
//! * **Least work** ([`sufficiency`]): per scene, the coarsest sample, the smallest fixed class count and whether
//!   30-bit codes suffice, such that the selection (and, stricter, the statistics within [`StatsTolerance`]) equal
//!   the reference's at that setting and at every finer one.

use crate::accel::StructureName;
use crate::characterize::{
    features_cpu, Backend, CharError, Characterization, Characterizer, ClassRule, Features, MortonBits, Params,
};
use crate::cost::CostModel;
use crate::eval::chart::{ScatterChart, ScatterPoint};
use crate::eval::record::OracleRecord;
use crate::eval::{EvalError, Measurement};
use crate::mesh::Animation;
use crate::select::{Policy, SceneSummary, TargetWorkload};
use std::path::Path;
use std::time::Instant;

/// Errors of the trade-off study.
#[derive(Debug, thiserror::Error)]
pub enum TradeoffError {
    /// A characterization failed.
    #[error(transparent)]
    Char(#[from] CharError),
    /// The oracle failed.
    #[error(transparent)]
    Eval(#[from] EvalError),
    /// An oracle file cannot be read or parsed.
    #[error("{file}: {reason}")]
    Oracle {
        /// The file (and line).
        file: String,
        /// Why.
        reason: String,
    },
    /// The settings or inputs make no study.
    #[error("{0}")]
    Input(String),
}

mod drift;
mod report;
mod results;
mod selection;
mod settings;
mod sweep;

pub use drift::{drift, histogram_distance, Drift, StatsTolerance};
pub use report::{charts, markdown, structures_markdown};
pub use results::{accuracy, pareto_front, sufficiency, Accuracy, SettingResult, Sufficiency};
pub use selection::{
    oracle_workload, scene_key, select, select_per_workload, SameK, SceneRun, Selector, WorkloadSelection,
};
pub use settings::{GridSpec, Setting};
pub use sweep::{sweep, time_characterization, Study};
