//! What the oracle reports: medians with their spread and confidence interval ([`Measurement`]), per structure
//! ([`StructureResult`], [`DriverResult`]) and per scene ([`SceneEvaluation`], whose [`SceneEvaluation::record`] is
//! the JSONL record).

use super::{DeviceRecord, Rebuild, RefitResult, TraceBackend, ROUNDS_EVERY_STRUCTURE};
use crate::accel::{AccelStats, StructureName};
use crate::eval::record::{OracleRecord, StructureRecord};
use crate::geom::Camera;
use crate::geom::WorkloadKind;

/// Errors of the oracle.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The scene has no frame.
    #[error("{0}: the scene has no frame")]
    NoFrames(String),
    /// A configuration that cannot be measured.
    #[error("{scene}: {reason}")]
    Config {
        /// The scene.
        scene: String,
        /// Why.
        reason: String,
    },
    /// The reference structure could not be built.
    #[error(transparent)]
    Accel(#[from] crate::accel::AccelError),
    /// The device failed outside any one structure (the frame's upload).
    #[error("device: {0}")]
    Device(String),
}

/// Median and range of repeated measurements, in milliseconds.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Measurement {
    /// Median.
    pub median: f64,
    /// Smallest sample.
    pub min: f64,
    /// Largest sample.
    pub max: f64,
    /// Half the range, the noise estimate.
    pub spread: f64,
    /// Samples.
    pub samples: usize,
    /// The median's distribution-free 95% confidence interval ([`median_ci95`]); `None` below 6 samples, where no
    /// pair of order statistics covers the median with 95% confidence.
    pub ci95: Option<[f64; 2]>,
}

/// The distribution-free 95% confidence interval of the median of `sorted` (ascending) samples: the order
/// statistics `x_(j)` and `x_(n+1-j)` (1-based) for the largest `j` with `2 P(B <= j - 1) <= 0.05`, `B` binomial
/// with `n` trials and probability 1/2 (the sign-test interval; it assumes independent samples from one
/// distribution, nothing about its shape). `None` for fewer than 6 samples (at 5, even `[min, max]` covers the
/// median with only 93.75%).
pub fn median_ci95(sorted: &[f64]) -> Option<[f64; 2]> {
    let n = sorted.len();
    // Cumulative binomial in log space (0.5^n underflows past n = 1074).
    let ln_half_n = n as f64 * 0.5f64.ln();
    let (mut ln_pmf, mut cdf, mut j) = (ln_half_n, 0.0f64, 0usize);
    for k in 0..n / 2 {
        cdf += ln_pmf.exp();
        if 2.0 * cdf > 0.05 {
            break;
        }
        j = k + 1;
        ln_pmf += ((n - k) as f64).ln() - ((k + 1) as f64).ln();
    }
    (j >= 1).then(|| [sorted[j - 1], sorted[n - j]])
}

impl Measurement {
    /// Summary of samples (all zero when there are none).
    pub fn of(samples: &[f64]) -> Self {
        if samples.is_empty() {
            return Measurement::default();
        }
        let mut s = samples.to_vec();
        s.sort_by(f64::total_cmp);
        let k = s.len();
        let median = if k % 2 == 1 { s[k / 2] } else { 0.5 * (s[k / 2 - 1] + s[k / 2]) };
        Measurement {
            median,
            min: s[0],
            max: s[k - 1],
            spread: 0.5 * (s[k - 1] - s[0]),
            samples: k,
            ci95: median_ci95(&s),
        }
    }

    /// Whether two measurements are within noise of each other: with confidence intervals on both, when the
    /// intervals overlap; otherwise when the medians differ by no more than the sum of the spreads (see the module
    /// docs).
    pub fn within_noise(&self, o: &Measurement) -> bool {
        match (self.ci95, o.ci95) {
            (Some(a), Some(b)) => a[0] <= b[1] && b[0] <= a[1],
            _ => (self.median - o.median).abs() <= self.spread + o.spread,
        }
    }

    /// Whether the confidence interval lies within `precision` (a fraction: 0.02 is +-2%) of the median on both
    /// sides; `false` without an interval or with a median of zero.
    pub fn precise_to(&self, precision: f64) -> bool {
        match self.ci95 {
            Some([lo, hi]) if self.median > 0.0 => {
                lo >= self.median * (1.0 - precision) && hi <= self.median * (1.0 + precision)
            }
            _ => false,
        }
    }
}

/// What the oracle measured for one structure.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StructureResult {
    /// Which structure.
    pub name: Option<StructureName>,
    /// Build time over the run (all builds of all frames), ms; with the device backend, host build plus upload.
    pub build_ms: Measurement,
    /// Upload to the device over the run (device backend, host-built structures; part of `build_ms`), ms.
    pub upload_ms: Option<Measurement>,
    /// Where it was built with the device backend: `host` (then uploaded) or `device`; `None` on the CPU backend.
    pub build_backend: Option<&'static str>,
    /// Trace time over the run (all frames), ms.
    pub trace_ms: Measurement,
    /// Total (see the module docs), ms.
    pub total_ms: Measurement,
    /// Rays traced per repeat (over all measured frames).
    pub rays: u64,
    /// Millions of rays per second, from the median trace time.
    pub mrays_per_s: f64,
    /// Box tests (or node visits, cells) per ray.
    pub box_tests_per_ray: f64,
    /// Triangle tests per ray.
    pub prim_tests_per_ray: f64,
    /// Memory of the structure (largest frame), bytes.
    pub memory_bytes: usize,
    /// SAH cost (first frame), where it applies.
    pub sah_cost: Option<f64>,
    /// Statistics of `validate()` (first frame).
    pub stats: Option<AccelStats>,
    /// Whether `validate()` passed on every frame.
    pub valid: bool,
    /// Whether every hit agreed with the reference on every frame.
    pub hits_agree: bool,
    /// Rays that disagreed with the reference.
    pub disagreements: usize,
    /// Whether its total is within noise of the best total.
    pub within_noise_of_best: bool,
    /// Under [`OracleConfig::precision`](super::OracleConfig::precision): whether the total's confidence interval met it by the last round
    /// ([`OracleConfig::max_repeats`](super::OracleConfig::max_repeats), or more under [`OracleConfig::precision_ms`](super::OracleConfig::precision_ms)); `None` without a precision
    /// target.
    pub precision_met: Option<bool>,
    /// The build or validation error, if any.
    pub error: Option<String>,
}

/// The oracle's verdict on one scene and workload.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SceneEvaluation {
    /// Scene name (path).
    pub mesh: String,
    /// Triangles per frame.
    pub triangles: usize,
    /// Frames measured (distinct geometries).
    pub frames_measured: usize,
    /// Frames the totals stand for.
    pub frames: usize,
    /// Workload.
    pub workload: WorkloadKind,
    /// Image side.
    pub resolution: u32,
    /// Rebuild policy.
    pub rebuild: Rebuild,
    /// Repeats.
    pub repeats: usize,
    /// The camera the rays were made from.
    #[serde(skip)]
    pub camera: Camera,
    /// The precision target ([`OracleConfig::precision`](super::OracleConfig::precision)), when one was set.
    pub precision: Option<f64>,
    /// Under a precision target: [`OracleConfig::max_repeats`](super::OracleConfig::max_repeats).
    pub max_repeats: Option<usize>,
    /// Under a precision target: [`OracleConfig::precision_ms`](super::OracleConfig::precision_ms).
    pub precision_ms: Option<f64>,
    /// Rays per frame (first frame).
    pub rays_per_frame: usize,
    /// The selection passed in (from the characterization's policy), if any.
    pub selected: Option<StructureName>,
    /// The structure with the smallest median total.
    pub oracle_best: Option<StructureName>,
    /// The structures within noise of the best (see the module docs), the best included, in the order measured.
    pub oracle_within_noise: Vec<StructureName>,
    /// Among [`SceneEvaluation::oracle_within_noise`], the one with the least median build time, then the least
    /// memory: the cheapest structure the measurement cannot tell from the best.
    pub oracle_cheapest_within_noise: Option<StructureName>,
    /// `total(selected) / total(best) - 1`, when a selection was given and both were measured.
    pub regret: Option<f64>,
    /// Whether the selection is within noise of the best.
    pub regret_within_noise: Option<bool>,
    /// Rays that hit something in the reference (closest-hit workloads) or were occluded (any-hit), over every
    /// measured frame.
    pub reference_hits: u64,
    /// Why no best structure is named, when none is: the workload traces no ray (secondary rays of a camera whose
    /// primary rays all miss), so the totals are builds alone. Rays that all miss (`reference_hits` 0) still rank
    /// the structures: a miss costs every node and cell the ray visits on its way out.
    pub no_best_reason: Option<String>,
    /// Where the rays were traced.
    pub trace_backend: TraceBackend,
    /// The device (device backend).
    pub device: Option<DeviceRecord>,
    /// Per structure.
    pub structures: Vec<StructureResult>,
    /// The driver's acceleration structures, when asked for ([`OracleConfig::driver`](super::OracleConfig::driver)).
    pub driver_structures: Vec<DriverResult>,
    /// The refit candidates of an animation ([`OracleConfig::refit`](super::OracleConfig::refit)): frame 0 built, later frames refitted.
    pub refit_structures: Vec<RefitResult>,
    /// With driver structures or refit candidates measured: the candidate with the smallest median total among
    /// the project's rebuilt structures, the refitted ones and the driver's (valid and agreeing with the
    /// reference), by name; `None` without such candidates or without a best (`oracle_best` stays the best of
    /// the project's rebuilt structures).
    pub best_candidate: Option<String>,
}

/// One driver acceleration structure in the oracle ([`crate::accel::driver`]): build flags, times (GPU timestamps),
/// memory and the agreement of its ray-query hits with the CPU reference ([`crate::accel::driver::hit_agrees`]).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DriverResult {
    /// `rt_fast_trace`, `rt_fast_build`, `rt_update` or `rt_fast_trace_compact`.
    pub name: String,
    /// How it follows an animation's frames: `rebuild`, or `update` (`rt_update`: built on the first frame,
    /// updated on the next ones).
    pub per_frame: String,
    /// Median build (or update) time over the run, ms: the bottom and top levels' timestamps (and the compaction).
    pub build_ms: f64,
    /// Median trace time over the run, ms (the ray-query dispatch's timestamps).
    pub trace_ms: f64,
    /// Median total, ms.
    pub total_ms: f64,
    /// Half the range of the totals.
    pub total_ms_spread: f64,
    /// Rays traced over the measured frames (first repeat).
    pub rays: u64,
    /// Million rays per second (median trace time).
    pub mrays_per_s: f64,
    /// Device bytes held (both levels, the instance, the scratch kept for updates), largest over the frames.
    pub memory_bytes: u64,
    /// Bytes of the bottom level as built.
    pub built_bytes: u64,
    /// Bytes of the compacted bottom level (`rt_fast_trace_compact`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compacted_bytes: Option<u64>,
    /// Built and traced without error.
    pub valid: bool,
    /// Every ray agreed with the CPU reference.
    pub hits_agree: bool,
    /// Rays that did not.
    pub disagreements: usize,
    /// Why it was not measured, or what failed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Per measured frame of an animation, the median build (or update) time, ms: with `rt_update` frame 0 is the
    /// build and the others updates.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frame_build_ms: Vec<f64>,
    /// Per measured frame of an animation, the median trace time, ms: how an update's trace cost drifts from the
    /// built frame's.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frame_trace_ms: Vec<f64>,
}

impl SceneEvaluation {
    /// The best of all candidates (see [`SceneEvaluation::best_candidate`]).
    pub(super) fn best_of_all(&self) -> Option<String> {
        if (self.driver_structures.is_empty() && self.refit_structures.is_empty()) || self.no_best_reason.is_some() {
            return None;
        }
        let ours = self
            .structures
            .iter()
            .filter(|s| s.valid && s.hits_agree)
            .filter_map(|s| s.name.map(|n| (n.as_str().to_string(), s.total_ms.median)));
        let theirs =
            self.driver_structures.iter().filter(|d| d.valid && d.hits_agree).map(|d| (d.name.clone(), d.total_ms));
        let refitted =
            self.refit_structures.iter().filter(|d| d.valid && d.hits_agree).map(|d| (d.name.clone(), d.total_ms));
        ours.chain(theirs).chain(refitted).min_by(|a, b| a.1.total_cmp(&b.1)).map(|b| b.0)
    }

    /// The median total of a candidate by name (a project structure's, `bvh`, or a driver structure's,
    /// `rt_fast_trace`), when it was measured valid and agreeing with the reference.
    pub fn candidate_total(&self, name: &str) -> Option<f64> {
        let ours = self
            .structures
            .iter()
            .find(|s| s.name.is_some_and(|n| n.as_str() == name) && s.valid && s.hits_agree)
            .map(|s| s.total_ms.median);
        ours.or_else(|| {
            self.driver_structures.iter().find(|d| d.name == name && d.valid && d.hits_agree).map(|d| d.total_ms)
        })
        .or_else(|| {
            self.refit_structures.iter().find(|d| d.name == name && d.valid && d.hits_agree).map(|d| d.total_ms)
        })
    }

    /// `total(name) / total(best of all candidates) - 1` ([`SceneEvaluation::best_candidate`]); `None` without
    /// driver structures, without a best, or when `name` was not validly measured.
    pub fn candidate_regret(&self, name: &str) -> Option<f64> {
        let best = self.candidate_total(self.best_candidate.as_deref()?)?;
        let t = self.candidate_total(name)?;
        (best > 0.0).then(|| t / best - 1.0)
    }

    /// The result of one structure.
    pub fn get(&self, name: StructureName) -> Option<&StructureResult> {
        self.structures.iter().find(|s| s.name == Some(name))
    }

    /// The record of `evaluate --json` (one per scene; see [`OracleRecord`]): `mesh`, `triangles`, `selected`,
    /// `oracle_best`, `regret`, `structures` (each with `name`, `build_ms`, `trace_ms`, `mrays_per_s`,
    /// `box_tests_per_ray`, `prim_tests_per_ray`, `memory_bytes`, `sah_cost`, `valid`, `hits_agree`, and more), plus
    /// the workload and the noise figures: `oracle_within_noise` (names) and `oracle_cheapest_within_noise`.
    pub fn record(&self) -> OracleRecord {
        OracleRecord {
            frames: self.frames,
            frames_measured: self.frames_measured,
            mesh: self.mesh.clone(),
            no_best_reason: self.no_best_reason.clone(),
            oracle_best: self.oracle_best,
            oracle_cheapest_within_noise: self.oracle_cheapest_within_noise,
            oracle_within_noise: self.oracle_within_noise.clone(),
            policy: None,
            predicted: None,
            cost_model: None,
            rays_per_frame: self.rays_per_frame,
            rebuild: self.rebuild,
            reference_hits: self.reference_hits,
            regret: self.regret,
            regret_within_noise: self.regret_within_noise,
            repeats: self.repeats,
            precision: self.precision,
            max_repeats: self.max_repeats,
            precision_ms: self.precision_ms,
            rounds: self.precision.map(|_| ROUNDS_EVERY_STRUCTURE.to_string()),
            view: None,
            camera: Some((&self.camera).into()),
            resolution: self.resolution,
            selected: self.selected,
            structures: self
                .structures
                .iter()
                .map(|s| StructureRecord {
                    box_tests_per_ray: s.box_tests_per_ray,
                    build_ms: s.build_ms.median,
                    build_ms_range: [s.build_ms.min, s.build_ms.max],
                    build_backend: s.build_backend.map(str::to_string),
                    upload_ms: s.upload_ms.as_ref().map(|m| m.median),
                    disagreements: s.disagreements,
                    error: s.error.clone(),
                    hits_agree: s.hits_agree,
                    memory_bytes: s.memory_bytes,
                    mrays_per_s: s.mrays_per_s,
                    name: s.name,
                    prim_tests_per_ray: s.prim_tests_per_ray,
                    sah_cost: s.sah_cost,
                    stats: s.stats,
                    total_ms: s.total_ms.median,
                    total_ms_spread: s.total_ms.spread,
                    total_ms_ci95: s.total_ms.ci95,
                    repeats_measured: Some(s.total_ms.samples).filter(|&k| k > 0),
                    precision_met: s.precision_met,
                    trace_ms: s.trace_ms.median,
                    trace_ms_range: [s.trace_ms.min, s.trace_ms.max],
                    valid: s.valid,
                    within_noise_of_best: s.within_noise_of_best,
                })
                .collect(),
            trace_backend: self.trace_backend,
            device: self.device.clone(),
            hits_checked: (self.trace_backend == TraceBackend::Vulkan)
                .then(|| "every ray against the CPU reference (triangle and t bits)".to_string()),
            ray_generation: (self.trace_backend == TraceBackend::Vulkan).then(|| "device".to_string()),
            triangles: self.triangles,
            workload: self.workload,
            driver_structures: self.driver_structures.clone(),
            refit_structures: self.refit_structures.clone(),
            best_candidate: self.best_candidate.clone(),
            selected_candidate: None,
            candidate_regret: None,
        }
    }

    /// [`SceneEvaluation::record`] as a JSON value.
    pub fn to_json(&self) -> serde_json::Value {
        self.record().to_json()
    }
}
