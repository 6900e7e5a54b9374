//! What the oracle measures: the workload, the frames, the repeats and the precision target ([`OracleConfig`]).

use super::RefitCandidate;
use crate::accel::StructureName;
use crate::geom::Camera;
use crate::geom::WorkloadKind;

/// When structures are (re)built.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Rebuild {
    /// Built for every frame.
    PerFrame,
    /// Built once (static scenes only).
    Once,
}

/// A workload for the oracle.
#[derive(Clone, Debug)]
pub struct OracleConfig {
    /// Kind of rays.
    pub workload: WorkloadKind,
    /// Image side: `resolution x resolution` primary rays per frame (1024 in the thesis).
    pub resolution: u32,
    /// Frames: how many times a static scene is rendered, or how many frames of an animation are used
    /// (`None`: 1 for a static scene, all for an animation).
    pub frames: Option<usize>,
    /// When structures are built.
    pub rebuild: Rebuild,
    /// Repeats of every measurement (medians are reported).
    pub repeats: usize,
    /// Structures to compare.
    pub structures: Vec<StructureName>,
    /// Camera; `None` frames the scene automatically ([`Camera::frame`] on the bounds of all frames).
    pub camera: Option<Camera>,
    /// The driver's acceleration structures to measure beside `structures` (device backend with ray queries).
    pub driver: Vec<crate::accel::driver::DriverFlags>,
    /// The trace budget: most box and triangle tests per ray (mean over a sample of the rays) before a structure
    /// is reported as failed instead of traced (see the module docs).
    pub max_tests_per_ray: f64,
    /// The precise oracle: when set (a fraction, 0.02 for +-2%), every structure is measured at least `repeats`
    /// times and then in further rounds of all of them (interleaved), until the 95% confidence interval of each
    /// one's median total ([`median_ci95`](super::median_ci95)) lies within this fraction of its median, or `max_repeats` rounds are
    /// reached (see `precision_ms`; a structure whose interval is still wider has `precision_met` `false`).
    /// `None`: exactly `repeats` repeats.
    pub precision: Option<f64>,
    /// The most repeats of one structure under `precision`, unless `precision_ms` allows more.
    pub max_repeats: usize,
    /// Under `precision`, the rounds go on past `max_repeats` (up to [`MAX_PRECISION_REPEATS`]) while a structure
    /// is still short of the target and the record's frame-0 builds and traces so far (the times measured: a static
    /// scene's one frame, not the `frames` it stands for; on the device the traces' timestamps) sum to less than
    /// this many milliseconds: cheap records are repeated until precise, costly ones stop at `max_repeats`. 0: no
    /// rounds past `max_repeats`.
    pub precision_ms: f64,
    /// Refit candidates to measure on an animation beside the rebuilt structures ([`RefitCandidate`]): frame 0
    /// built, every later frame refitted. Ignored for a static scene; measured on the CPU tracer only.
    pub refit: Vec<RefitCandidate>,
}

/// The default [`OracleConfig::max_repeats`].
pub const DEFAULT_MAX_REPEATS: usize = 60;

/// The most rounds [`OracleConfig::precision_ms`] may add up to under a precision target (a larger
/// [`OracleConfig::max_repeats`] is still run in full).
pub const MAX_PRECISION_REPEATS: usize = 500;

/// The records' `rounds` under a precision target ([`crate::eval::OracleRecord::rounds`]): every structure is measured
/// in every round until all of them meet the target, as this oracle measures.
pub const ROUNDS_EVERY_STRUCTURE: &str = "every_structure";

/// The default [`OracleConfig::max_tests_per_ray`] (the trace budget's, [`crate::trace::DEFAULT_MAX_TESTS_PER_RAY`]).
pub use crate::trace::DEFAULT_MAX_TESTS_PER_RAY;

pub use crate::trace::{check_trace_budget, TRACE_SAMPLE_RAYS};

impl Default for OracleConfig {
    fn default() -> Self {
        OracleConfig {
            workload: WorkloadKind::Primary,
            resolution: 1024,
            frames: None,
            rebuild: Rebuild::Once,
            repeats: 3,
            structures: StructureName::ALL.to_vec(),
            camera: None,
            driver: Vec::new(),
            max_tests_per_ray: DEFAULT_MAX_TESTS_PER_RAY,
            precision: None,
            max_repeats: DEFAULT_MAX_REPEATS,
            precision_ms: 0.0,
            refit: Vec::new(),
        }
    }
}
