//! A calibrated cost model: predicted build and trace time of every acceleration structure for a scene and a
//! workload, from the scene's [`Features`] and a few constants fitted on the device at hand.
//!
//! # Model
//!
//! For structure `s`, a scene of `n` triangles with features `f`, and a workload of `R` rays per frame, `F` frames
//! and `B` builds:
//!
//! ```text
//! build_ms(s)        = exp(a_s) * n^b_s * exp(d_s q(ln n))               (per build; b_s ~ 1 for O(n), > 1 for n log n)
//!                    = exp(a'_s) * n^b'_s * (work / n)^c'_s * exp(d'_s q(ln n))   (where a probe built it: work law)
//! box_tests(s)       = exp(theta_box_s . phi(f, kind))                   (per ray)
//! prim_tests(s)      = exp(theta_prim_s . phi(f, kind))                  (per ray)
//! trace_ns(s)        = c_ray_s,kind + (c_box_s + [incoherent] c'_box_s) * box_tests(s)
//!                                 + (c_prim_s + [incoherent] c'_prim_s) * prim_tests(s)
//!                                 + [incoherent] c''_s * t(s) ln(1 + t(s))     (per ray, c >= 0; t = box + prim tests)
//! total_ms(s)        = B * build_ms(s) + F * R * trace_ns(s) * 1e-6
//! ```
//!
//! `phi` ([`FEATURE_NAMES`]) is: an intercept, the workload kind (shadow, diffuse as indicators; primary is the
//! base), `ln n`, `ln` triangles per occupied Morton cell at the depth of a 4-cells-per-triangle grid, the occupied
//! share at one cell per triangle, the empty share at depth 3, the mean and spread of the triangle size exponents
//! and the `log2` aspect of the bounds ([`crate::characterize::features::Derived`]). The test counts are geometry
//! (device independent); `a_s, b_s, c_s` are the device's constants. The physical reading: builds are linear to
//! `n log n`; a ray's cost is its node visits and its triangle tests, each at a device-specific price; the counts
//! grow with `ln n` for hierarchies and with triangles per cell for a grid, and shrink where space is empty.
//! Where the selection's probe built a structure ([`probe()`], [`PROBED`]), its build is priced by the work that
//! build did, `work` = [`crate::accel::AccelStats::build_work`] (its references times the levels they were handled
//! on; the grid's references), with a law of its own ([`StructureModel::build_work_coef`], `TestFloor::build_work`).
//! A calibration fitted with views adds the camera's features to `phi` ([`ViewFeatures`]); one fitted with the
//! crossings ([`CostModel::fit_with`]) adds `ln(1 + crossings)` ([`crossings_feature`]: the triangle boxes a ray
//! crosses) with coefficients of its own; and the predictions take each count at least at its overlap floor
//! (`overlap_floor`) when the caller gives one. A fitted calibration clamps the geometric features into the range
//! it was fitted on ([`StructureModel::feature_range`]).
//!
//! Two terms bend the straight laws where measurement showed they must (`docs/results/2026-12-06-cost-model-curved-builds-incoherent-price.md`).
//! `q` (`curvature_term`) is `(ln n - 10)^2` over the calibration's sizes and its tangent beyond them, with
//! `d_s, d'_s >= 0` ([`StructureModel::build_curvature`]): the build time per triangle is U-shaped in `n` (the
//! BVH's 0.28, 0.19 and 0.22 us at 2K, 20K and 200K triangles), fixed costs weighing on small builds and cache
//! misses on large ones, which one power of `n` cannot follow. `c''_s` (`test_incoherent_log`) prices an
//! incoherent ray's tests higher the more of them it makes: its neighbours share the top of a tree but not the
//! deep, scattered nodes and triangles a long traversal reaches (a BVH's diffuse rays in the sliver-filled
//! engineering models pay 5.2 ns per test at 1,080 tests per ray, 3.1 ns at 430, against 2.2 to 2.5 ns for primary
//! rays). Two more prices per test follow the rays and the view (`docs/results/2026-12-06-cost-model-diffuse-view-prices.md`): `test_diffuse`, the extra of
//! a diffuse ray's test over a shadow ray's (a closest hit among scattered rays against a first hit), and
//! `test_outside_log_n`, an extra per unit of `ln n` when the eye is outside the bounds (`price_outside_ln_n`:
//! seen from outside, neighbouring rays land far apart and share less of the structure: on the first family set's
//! 200K-triangle scenes a BVH's primary rays took a median 2.3 ns per test from the inside and close-up views and
//! 4.9 ns from the framing and grazing ones). The latter is fitted only on records that hold both kinds of eye.
//!
//! # Fit
//!
//! [`CostModel::fit`] takes oracle results ([`crate::eval::fit::Sample`]: measured build ms, trace ms, tests per ray of every
//! structure on every scene and workload) and fits, per structure: the build law by least squares in log space
//! (`ln build = a + b ln n + d q(ln n)`, `d` held at 0 where it fits below or where the sizes span less than
//! [`BUILD_CURVATURE_MIN_SPAN`], every constant within the ranges of the validation below, edge slopes included) and, for the probed structures on samples whose records counted the work, the
//! work law (`ln build = a' + b' ln n + c' ln(work / n) + d' q(ln n)`, `c'` and `d'` held at 0 where they fit
//! below); the test counts by ridge regression in log space (ridge [`RIDGE`] on all but the
//! intercept); the per-ray prices by non-negative least squares on the measured counts, weighted by `1 / t^2` so
//! that the relative error is minimized. Fit errors are root-mean-square natural-log ratios of prediction to
//! measurement ([`FitError`]); `0.1` means about 10%.
//!
//! # Files
//!
//! A calibration file is the JSON of [`CostModel`]: `version` ([`COST_MODEL_VERSION`]), `device`, `source`,
//! `scenes`, `feature_names` ([`FEATURE_NAMES`]), `price_names` ([`PRICE_NAMES`]), `structures` (one
//! [`StructureModel`] each), `total_rms_log`, an optional `refit` ([`RefitModel`]), `trace_backend` (`cpu` or
//! `vulkan`; `cpu` when absent, as in files written before it existed) and, for `vulkan`, `trace_device` (the
//! device's name, type, driver, driver version and UUID); no other key. [`CostModel::load`] with a path reads that
//! file and fails when it is missing, unreadable or invalid; without a path it returns the shipped CPU default
//! (`assets/cost-model-cpu.json`, fitted on this project's CPU oracle on the build machine). Two calibrations ship
//! ([`SHIPPED_MODELS`]): the CPU tracer's and lavapipe's (`assets/cost-model-lavapipe.json`, the device oracle on
//! the same machine); [`CostModel::for_trace_target`] picks the one for the tracer at hand ([`registry`]: the CPU's
//! for the CPU tracer, the device's by UUID, then by name) and records which in [`CostModel::chosen_as`]. A file
//! that was asked for is never silently replaced by another.
//!
//! # Validation
//!
//! [`CostModel::from_json`] (and so [`CostModel::load`]) accepts a file only when [`CostModel::validate`] does, and
//! [`CostModel::fit`] refuses to return a model it would not accept. The error ([`CostError::Invalid`]) names the
//! field as a path into the file (`structures[2] (grid).trace_price[3] (box)`) and the structure it belongs to. The
//! rules, and where each range comes from:
//!
//! * `version` is [`COST_MODEL_VERSION`]; `device` is a non-empty string.
//! * `trace_device` is present exactly when `trace_backend` is `vulkan`, with a non-empty `name`: a device
//!   calibration is chosen by its device, and a CPU calibration has none.
//! * `feature_names` equals [`FEATURE_NAMES`] and `price_names` equals [`PRICE_NAMES`], name for name and in
//!   order: the coefficients are read by position, so a reordered or renamed column would silently multiply the
//!   wrong feature or count. The error names the first position that differs.
//! * `structures` is not empty; each names one of [`StructureName::ALL`] (brute force is the reference, never
//!   calibrated) and none appears twice.
//! * Every number is finite (a NaN or an infinity is written as `null` in JSON, and read back as not finite).
//! * `build_exponent` `b` lies in [`BUILD_EXPONENT_RANGE`], `[0, 2]`: a build reads every triangle, so a larger
//!   scene never builds faster (`b < 0`); `b ~ 1` is `O(n)`, slightly above 1 is `n log n` over the sizes of real
//!   scenes, fixed per-build overhead (a GPU dispatch) pulls a fit on small scenes below 1 toward 0, and no
//!   builder here is worse than quadratic (`b <= 2`). The shipped fits are 0.76 to 0.95.
//! * `build_ln_a` `a`, the `ln` of the build ms the law gives for one triangle, lies in [`BUILD_LN_A_RANGE`],
//!   `[-23, 9]`, that is `exp(a)` between 0.1 ps and 8 s: `e^9` ms for a single triangle is beyond any device, and
//!   the floor, far below one clock cycle, leaves room for the small `a` of fits with `b` up to 2 (a quadratic
//!   build of a million triangles at 1 ns per pair has `a = -13.8`). The shipped fits are -8.1 to -4.5.
//! * `build_work_coef` is absent or has three or four constants `[a', b', c', d']`: `a'` in [`BUILD_LN_A_RANGE`] and
//!   `b'` in [`BUILD_EXPONENT_RANGE`] for the reasons above, `c'` in [`BUILD_WORK_EXPONENT_RANGE`], `[0, 2]` (more
//!   work per triangle never builds faster, and no builder here handles a reference more than quadratically often),
//!   `d'` as `build_curvature`.
//! * `build_curvature` (0 when absent) lies in [`BUILD_CURVATURE_RANGE`], `[0, 1]` (see there); with a nonzero
//!   curvature (of either law), `build_ln_n_range` is `[lo, hi]`, both finite in `[0, BUILD_LN_N_LIMIT]`
//!   ([`BUILD_LN_N_LIMIT`], `ln 2^40`, so that the term stays finite) and `lo <= hi` (the sizes the law was fitted
//!   on); without one it may be absent. Each curved law's slopes in `ln n` at `lo` and `hi`
//!   (`build_law_slopes`), which it keeps beyond them, lie in [`BUILD_EXPONENT_RANGE`], for the reasons of `b`.
//! * Each of `box_coef` and `prim_coef` has one coefficient per [`FEATURE_NAMES`], each of magnitude at most
//!   [`COEF_LIMIT`] (1000): a coefficient is the change of `ln` tests per ray per unit of a feature, and
//!   [`StructureModel::predict`] clamps `theta . phi` to `±30`; with every `|phi_j| <= 45` (`ln n <= ln 2^64`, the
//!   shares in `[0, 1]`, the size exponents below 24), a slope above 1000 would cross the whole clamp range within
//!   0.06 units of a feature, which is no count model. The shipped coefficients are below 8 in magnitude.
//! * `view_box_coef` and `view_prim_coef` are absent or have one coefficient per [`VIEW_FEATURE_NAMES`];
//!   `crossing_coef` is absent or has two (`box`, `prim`: of `ln(1 + crossings)`, [`crossings_feature`]); each
//!   of magnitude at most [`COEF_LIMIT`], for the same reason.
//! * `crossing_mean` is absent, or has three values (primary, shadow, diffuse) when `crossing_coef` is present: the
//!   calibration's mean `ln(1 + crossings)` per kind, read for a caller without a count; each in `[0, 45]` (a ray
//!   crosses at most every triangle box, and `ln(1 + 2^64) < 45`).
//! * `feature_range` is absent, or has one `[lo, hi]` per [`FEATURE_NAMES`], both finite and `lo <= hi`: the range
//!   of each feature over the samples the count laws were fitted on; a prediction clamps the geometric features
//!   ([`CLAMPED_FEATURES`]) into it, so that a log-linear law does not extrapolate to a scene unlike every
//!   calibration scene (a small object in a vast empty box: the teapot in a stadium, whose mean triangle size and
//!   triangles per cell lie 1.7 and 1.9 times beyond the other families' largest).
//! * `trace_price` has one price per [`PRICE_NAMES`], each `>= 0` (ns per ray or per test: the fit is
//!   non-negative least squares, and a negative price would make more work cheaper; a CPU calibration also keeps each triangle-test price at least its box-test price, `fit_prices`, which the
//!   validation does not require of other files) and at most [`PRICE_LIMIT_NS`] (1 ms: the devices in scope pay 1
//!   to 40 ns per test, so a larger price is a unit error), and not all zero (tracing is never free).
//! * The fit errors (`fit.*`, `total_rms_log`) are root-mean-square values: `>= 0`.
//! * `refit`, when present: `sah_growth_per_drift` in [`SAH_GROWTH_RANGE`], `[0, 1000]` (a refitted tree is not
//!   better than a fresh one on average, and above 1000 a drift of 0.001 would already double the trace cost; the
//!   shipped fit is 1.08); `refit_ns_per_triangle` in `(0, PRICE_LIMIT_NS]` (a refit visits every node); `fit_rms`
//!   `>= 0`; `samples >= 1`.
//! * `timed`, when present ([`timed::TimedRatios`], the timed probes' ratios): each structure at most once, and
//!   every ratio given (`build`, `trace` per kind; `null` where none was fitted) in [`timed::TIMED_RATIO_RANGE`],
//!   `[0.001, 1000]`: a probe and the oracle differ by threads, caches and repeats, not by orders of magnitude (the
//!   shipped ratios are 0.28 to 0.99).

mod file_check;
use file_check::{check_names, check_number, check_structure, json_kind, structure_from_json};
mod model;
mod structure_model;
mod uncertainty;
pub use model::CostModel;
pub use structure_model::{CountLaw, Prediction, StructureModel};
pub use uncertainty::{InquiryCost, StructureUncertainty, Uncertainty};

pub mod driver;
pub mod measured;
pub mod registry;
pub mod view;

pub(crate) mod overlap;
pub(crate) use overlap::{overlap_floor, priced_floor};
pub mod probe;
pub mod timed;
pub use overlap::{
    crossings_feature, near_crossings, near_sample_side, screen_crossings, CountBounds, NearCrossings, RayCrossings,
    SampledMean, StructureCountBounds,
};
pub(crate) use overlap::{Crossings, TestFloor};
pub use probe::{probe, Probe, ProbeCounts, PROBED};

/// The half-width of a law's band about a probe's sampled mean, in the fit's RMS errors of `ln(1 + count)`
/// ([`FitError::box_tests`]): a probed count whose law `c` lies outside `(1 + c) / (1 + mean)` in
/// `exp(+-PROBE_BAND * rms)` is held to the sample
/// (`StructureModel::predict_floored`). One RMS: of 0 (always held), 1 and 2, measured held
/// out on the scene families (by family 6.9%, 3.9%, 4.2%; by scene 6.1%, 4.2%, 3.8%) and checked on the other record
/// sets (`docs/results/2026-12-05-cost-model-probes.md`).
pub const PROBE_BAND: f64 = 1.0;

/// The band ([`PROBE_BAND`]'s unit) within which a model traced on the CPU keeps a probed structure's own law
/// (`CostModel::own_probe_band`): 0, every probed count is held to its sample. On the CPU tracer the probe traces
/// the very tree the frame would trace, with a sample of the frame's rays, so its mean is that structure's count up
/// to the sample's error, and a law that differs from it has nothing to add. The probed structures' shared
/// correction of the unprobed kd-tree still reads its counts held at [`PROBE_BAND`] (a correction from counts held
/// everywhere picked the kd-tree for sliver-rich scenes over many frames at up to 11x the grid). A
/// device calibration keeps [`PROBE_BAND`]: there the probe's CPU tree stands in for the device's own build (held
/// at 0 its LBVH and BVH counts cost the H200 family records' primary rays 3.9% -> 19.6%, worst 313%). Measured in
/// `docs/results/2026-12-06-cost-model-bvh-nodes-probe-band.md`.
pub const OWN_PROBE_BAND_CPU: f64 = 0.0;

/// The hierarchy that is not probed but takes the probed hierarchies' correction of its counts
/// (`CostModel::predict_floored`): the kd-tree, whose laws' errors on the scene families follow the LBVH's
/// (residual correlation 0.83). The HLBVH shared it too until it was probed ([`PROBED`]). The
/// grid's errors (0.58) are its own: it is probed, and its correction is not shared (taking it into the shared mean
/// sent particle soups and cities to the HLBVH: held out by family 2.8% -> 3.6%).
pub const SHARES_PROBES: [StructureName; 1] = [StructureName::KdTree];

use crate::accel::device::{DeviceRecord, TraceBackend};
use crate::accel::StructureName;
use crate::characterize::features::Derived;
use crate::characterize::Features;
use crate::geom::WorkloadKind;
use serde::{Deserialize, Deserializer};
use std::ops::RangeInclusive;
use std::path::Path;

pub use driver::{DriverFit, DriverModel, DriverPrediction, DriverUpdateModel};
pub use registry::{ChosenModel, ShippedModel, TraceTarget, SHIPPED_MODELS};
pub use view::{ViewFeatures, VIEW_FEATURE_NAMES};

/// Version of the calibration file format (and of the feature set `phi`). Files of another version are stale.
pub const COST_MODEL_VERSION: u32 = 2;

/// The shipped default calibration (CPU oracle on the project's build machine).
pub const SHIPPED_CPU: &str = include_str!("../../assets/cost-model-cpu.json");

/// The shipped calibration of lavapipe (Mesa's CPU Vulkan driver, `llvmpipe` in its device name): the device
/// oracle (`evaluate --trace-backend vulkan`) on the project's build machine.
pub const SHIPPED_LAVAPIPE: &str = include_str!("../../assets/cost-model-lavapipe.json");

/// Names of the columns of `phi` (see the module docs).
pub const FEATURE_NAMES: [&str; 10] = [
    "intercept",
    "shadow",
    "diffuse",
    "ln_n",
    "ln_tris_per_cell",
    "fill_at_n",
    "empty_d3",
    "size_mean",
    "size_spread",
    "aspect_log2",
];

/// The leading [`FEATURE_NAMES`] that do not describe the geometry: the intercept, the workload kind and the
/// triangle count (`ln_n`). The size-only model ([`CostModel::fit_size_only`]) uses these alone.
pub const SIZE_FEATURES: usize = 4;

/// Names of the trace price columns: a per-ray overhead for each workload kind, ns per box test and per triangle
/// test for coherent (primary) rays, the extra ns per test for incoherent (shadow, diffuse) rays, the extra ns
/// per incoherent test per unit of `ln(1 + tests per ray)`, box and triangle tests together
/// (`test_incoherent_log`: an incoherent ray that makes many tests reaches deep, scattered nodes and triangles
/// that its neighbours do not share, and pays more per test; see the module docs), the extra ns per test of a
/// diffuse ray (`test_diffuse`: a closest hit among scattered rays, where a shadow ray stops at its first hit), and
/// the extra ns per test per unit of `ln n` when the eye is outside the scene's bounds (`test_outside_log_n`:
/// seen from outside, neighbouring rays land far apart on the scene and their traversals share less of a
/// structure that grows with `n`; `price_outside_ln_n`).
pub const PRICE_NAMES: [&str; 10] = [
    "ray_primary",
    "ray_shadow",
    "ray_diffuse",
    "box",
    "prim",
    "box_incoherent",
    "prim_incoherent",
    "test_incoherent_log",
    "test_diffuse",
    "test_outside_log_n",
];

/// The view's term of the price row ([`PRICE_NAMES`]' `test_outside_log_n` per test): `ln n` for `n` triangles
/// when the eye lies outside the scene's bounds, 0 when inside. A workload without a view is priced as the framing
/// camera's, whose eye is outside (what [`CostModel::predict`] assumes without one).
pub(crate) fn price_outside_ln_n(w: &Workload, n: u64) -> f64 {
    if w.view.is_some_and(|v| v.eye_inside) {
        0.0
    } else {
        (n.max(1) as f64).ln()
    }
}

/// The price row of [`PRICE_NAMES`] for a kind, test counts and the view's term (`price_outside_ln_n`).
pub(crate) fn price_row(kind: WorkloadKind, box_tests: f64, prim_tests: f64, outside_ln_n: f64) -> Vec<f64> {
    let inc = (kind != WorkloadKind::Primary) as u8 as f64;
    let diffuse = (kind == WorkloadKind::Diffuse) as u8 as f64;
    let tests = box_tests + prim_tests;
    vec![
        (kind == WorkloadKind::Primary) as u8 as f64,
        (kind == WorkloadKind::Shadow) as u8 as f64,
        diffuse,
        box_tests,
        prim_tests,
        inc * box_tests,
        inc * prim_tests,
        inc * tests * tests.max(0.0).ln_1p(),
        diffuse * tests,
        tests * outside_ln_n.max(0.0),
    ]
}

/// Accepted range of [`StructureModel::build_exponent`] (see the module docs, Validation).
pub const BUILD_EXPONENT_RANGE: RangeInclusive<f64> = 0.0..=2.0;

/// Accepted range of the exponent of the build work per triangle in [`StructureModel::build_work_coef`]: `[0, 2]`,
/// as [`BUILD_EXPONENT_RANGE`] (more work per triangle never builds faster; the fit holds it at 0 or above).
pub const BUILD_WORK_EXPONENT_RANGE: RangeInclusive<f64> = 0.0..=2.0;

/// Accepted range of the build laws' curvature in `ln n` ([`StructureModel::build_curvature`], the fourth
/// constant of [`StructureModel::build_work_coef`]): `[0, 1]`. The fit holds it at 0 or above (a time per
/// triangle that peaks at mid sizes has no mechanism); the shipped fits are below 0.1, and at 1 the law would
/// double its time per triangle within 0.8 units of `ln n` of the centre.
pub const BUILD_CURVATURE_RANGE: RangeInclusive<f64> = 0.0..=1.0;

/// The `ln n` about which the curvature terms are centred: `ln 22026`, mid-way through the calibration sizes. The
/// centre re-parametrizes `a` and `b` (`b` is the law's slope in `ln n` there); the slopes at the edges of the
/// fitted sizes, which the law keeps beyond them, are checked apart (`build_law_slopes`).
pub const BUILD_CURVATURE_CENTER: f64 = 10.0;

/// The least span of `ln n` over a structure's calibration builds for a curvature to be fitted: `ln 30` (3.4012),
/// sizes a factor of 30 apart, with at least [`BUILD_CURVATURE_MIN_SIZES`] distinct sizes. Over a narrower span the
/// curvature fits the noise, not the U-shape of the time per triangle.
pub const BUILD_CURVATURE_MIN_SPAN: f64 = 3.4012;

/// The least number of distinct triangle counts among a structure's calibration builds for a curvature to be
/// fitted: 3, the fewest that identify one. (The scene families have exactly three sizes, 2K, 20K and 200K
/// triangles, each built on 84 records, which the parabola does not meet exactly; held out by family it lowers the
/// build error of every probed hierarchy, `docs/results/2026-12-06-cost-model-curved-builds-incoherent-price.md`.)
pub const BUILD_CURVATURE_MIN_SIZES: usize = 3;

/// The largest `ln n` a [`StructureModel::build_ln_n_range`] may name: `ln 2^40`, far beyond any scene, so that
/// the curvature term stays finite (at most `(27.8 - 10)^2` within the range).
pub const BUILD_LN_N_LIMIT: f64 = 27.8;

/// The curvature terms' shape in `x = ln n`: `(x - BUILD_CURVATURE_CENTER)^2` within `[lo, hi]` (the sizes the law
/// was fitted on), continued along its tangent beyond them, so that the law keeps the slope it has at the edge of
/// its sizes instead of bending further. 0 for a range that is not one (`lo > hi`, or a NaN bound).
pub(crate) fn curvature_term(x: f64, lo: f64, hi: f64) -> f64 {
    if lo.is_nan() || hi.is_nan() || lo > hi {
        return 0.0;
    }
    let edge = x.clamp(lo, hi);
    let e = edge - BUILD_CURVATURE_CENTER;
    e * e + 2.0 * e * (x - edge)
}

/// The slopes of `ln build` in `ln n` at the two edges `[lo, hi]` of the fitted sizes, for a law with exponent `b`
/// (its slope at the centre) and curvature `d`: `b + 2 d (edge - BUILD_CURVATURE_CENTER)`. Beyond the edges the law
/// keeps them; both must lie in [`BUILD_EXPONENT_RANGE`] (no build gets faster with more triangles, none is worse
/// than quadratic), which the fit holds and the validation checks.
pub(crate) fn build_law_slopes(b: f64, d: f64, lo: f64, hi: f64) -> [f64; 2] {
    [lo, hi].map(|e| b + 2.0 * d * (e - BUILD_CURVATURE_CENTER))
}

/// Accepted range of [`StructureModel::build_ln_a`]: `exp(a)` from 1e-10 ms to 8 s (see the module docs,
/// Validation).
pub const BUILD_LN_A_RANGE: RangeInclusive<f64> = -23.0..=9.0;

/// Largest accepted magnitude of a test-count coefficient (see the module docs, Validation).
pub const COEF_LIMIT: f64 = 1000.0;

/// Largest accepted trace price and refit time per triangle, ns (see the module docs, Validation).
pub const PRICE_LIMIT_NS: f64 = 1e6;

/// Accepted range of [`RefitModel::sah_growth_per_drift`] (see the module docs, Validation).
pub const SAH_GROWTH_RANGE: RangeInclusive<f64> = 0.0..=1000.0;

/// Ridge penalty of the test-count regressions (on every coefficient but the intercept).
pub const RIDGE: f64 = 0.05;

/// Errors of the cost model.
#[derive(Debug, thiserror::Error)]
pub enum CostError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A file or record could not be parsed (not JSON).
    #[error("{0}")]
    Parse(String),
    /// A calibration file of another format version.
    #[error("version: calibration file version {found}, this build reads version {expected}")]
    Version {
        /// Version in the file.
        found: u64,
        /// [`COST_MODEL_VERSION`].
        expected: u32,
    },
    /// A calibration file or model with a field that is missing, malformed or out of range (see the module docs,
    /// Validation).
    #[error("{field}: {reason}")]
    Invalid {
        /// The field, as a path into the file: `device`, `feature_names[3]`,
        /// `structures[2] (grid).trace_price[3] (box)`.
        field: String,
        /// The structure the field belongs to, when it belongs to one.
        structure: Option<StructureName>,
        /// What is wrong.
        reason: String,
    },
    /// No calibration serves the trace target (no shipped CPU calibration to fall back on).
    #[error("no calibration for {0}")]
    NoCalibration(String),
    /// A calibration file that [`CostModel::load`] was asked for and cannot use: its path and why.
    #[error("calibration file {path}: {source}")]
    File {
        /// The file.
        path: String,
        /// What is wrong with it.
        source: Box<CostError>,
    },
    /// Too little or degenerate data to fit.
    #[error("cannot fit the cost model: {0}")]
    Fit(String),
}

fn invalid(structure: Option<StructureName>, field: impl Into<String>, reason: impl Into<String>) -> CostError {
    CostError::Invalid { field: field.into(), structure, reason: reason.into() }
}

/// serde: a number, or `null`, which serde_json writes for NaN and the infinities, read back as NaN so that
/// [`CostModel::validate`] names the field instead of the parser failing on it.
fn f64_or_null<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// [`f64_or_null`] for every element of an array.
fn vec_f64_or_null<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
    Ok(Vec::<Option<f64>>::deserialize(d)?.into_iter().map(|x| x.unwrap_or(f64::NAN)).collect())
}

/// What a structure is used for: rays per frame, frames and builds.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Workload {
    /// Kind of rays.
    pub kind: WorkloadKind,
    /// Rays traced per frame.
    pub rays_per_frame: u64,
    /// Frames traced.
    pub frames: u64,
    /// Builds over the run (1 for a static scene built once, `frames` when rebuilt every frame).
    pub builds: u64,
    /// The camera, reduced to [`ViewFeatures`]; `None`: the framing camera of the scene's bounds
    /// ([`CostModel::predict`] resolves it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<ViewFeatures>,
}

/// The phi row of [`FEATURE_NAMES`] for derived features and a workload kind.
pub(crate) fn phi(d: &Derived, kind: WorkloadKind) -> Vec<f64> {
    vec![
        1.0,
        (kind == WorkloadKind::Shadow) as u8 as f64,
        (kind == WorkloadKind::Diffuse) as u8 as f64,
        d.ln_n,
        d.ln_tris_per_cell,
        d.fill_at_n,
        d.empty_d3,
        d.size_mean,
        d.size_spread,
        d.aspect_log2,
    ]
}

/// The columns of [`FEATURE_NAMES`] a prediction clamps into the calibration's range
/// ([`StructureModel::feature_range`]): the geometric ones after `ln_n` (the triangle count, whose law is the
/// build's and the size-only model's too, extrapolates).
pub const CLAMPED_FEATURES: std::ops::Range<usize> = 4..10;

/// Position of a workload kind in per-kind arrays ([`StructureModel::crossing_mean`]): primary, shadow, diffuse.
fn kind_index(kind: WorkloadKind) -> usize {
    match kind {
        WorkloadKind::Primary => 0,
        WorkloadKind::Shadow => 1,
        WorkloadKind::Diffuse => 2,
    }
}

pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Fit errors of one structure or of the whole model: RMS of `ln(predicted / measured)` over the samples (of
/// `ln((1 + predicted) / (1 + measured))` for the test counts).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitError {
    /// Samples used.
    pub samples: usize,
    /// Build time per build.
    #[serde(deserialize_with = "f64_or_null")]
    pub build: f64,
    /// Box tests per ray, as the error of `ln(1 + count)` (every ray tests at least one box, so a miss by a
    /// fraction of a test counts for little however large its ratio).
    #[serde(deserialize_with = "f64_or_null")]
    pub box_tests: f64,
    /// Triangle tests per ray, as the error of `ln(1 + count)` (as [`FitError::box_tests`]).
    #[serde(deserialize_with = "f64_or_null")]
    pub prim_tests: f64,
    /// Trace ns per ray from the measured test counts (the price model alone).
    #[serde(deserialize_with = "f64_or_null")]
    pub trace_given_counts: f64,
    /// Trace ns per ray from predicted counts.
    #[serde(deserialize_with = "f64_or_null")]
    pub trace: f64,
    /// Total ms of the workload.
    #[serde(deserialize_with = "f64_or_null")]
    pub total: f64,
    /// Build time per build by the work law ([`StructureModel::build_work_coef`]), over the samples whose records
    /// counted the work; 0 without a work law (and in files written before it; not written when 0).
    #[serde(default, skip_serializing_if = "is_zero", deserialize_with = "f64_or_null")]
    pub build_work: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl FitError {
    /// The error figures with their names, in field order.
    fn figures(&self) -> [(&'static str, f64); 7] {
        [
            ("build", self.build),
            ("box_tests", self.box_tests),
            ("prim_tests", self.prim_tests),
            ("trace_given_counts", self.trace_given_counts),
            ("trace", self.trace),
            ("total", self.total),
            ("build_work", self.build_work),
        ]
    }
}

/// Per-frame refit model for animations (see [`crate::select::plan_frames`]): a refitted BVH's SAH cost grows with the drift of the
/// geometry since its build, `sah_refit / sah_fresh = 1 + sah_growth_per_drift * drift`, and a refit costs
/// `refit_ns_per_triangle * n`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RefitModel {
    /// Slope of the SAH ratio in the drift ([`drift`]), in [`SAH_GROWTH_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub sah_growth_per_drift: f64,
    /// Refit time per triangle, ns, in `(0, PRICE_LIMIT_NS]`.
    #[serde(deserialize_with = "f64_or_null")]
    pub refit_ns_per_triangle: f64,
    /// RMS error of the SAH ratio fit (absolute, in ratio units).
    #[serde(deserialize_with = "f64_or_null")]
    pub fit_rms: f64,
    /// Frame pairs measured (at least 1).
    pub samples: usize,
}

/// `w` with its view resolved: its own, or the framing camera of the features' bounds (it costs
/// [`view::COVERAGE_GRID`]^2 slab tests).
pub(crate) fn resolve_view(f: &Features, w: &Workload) -> Workload {
    Workload { view: Some(w.view.unwrap_or_else(|| ViewFeatures::framing(f.lo, f.hi))), ..*w }
}

/// The error of a predicted count of tests per ray against a measured (or sampled) one, as the fit reports it
/// ([`FitError::box_tests`], [`FitError::prim_tests`]) and the probes' band reads it ([`PROBE_BAND`]):
/// `ln((1 + predicted) / (1 + measured))`. Every ray tests at least the root's box, so a law that misses by a
/// fraction of one test per ray costs a fraction of a ray's least cost however large its ratio: a shadow workload
/// whose rays mostly leave the scene measures 0.02 triangle tests per ray, and a law's 0.7 there is a ratio of 35
/// (a log error of 3.6) but 0.5 of a ray's cost (0.5 here).
pub(crate) fn count_error(predicted: f64, measured: f64) -> f64 {
    ((1.0 + predicted.max(0.0)) / (1.0 + measured.max(0.0))).ln()
}

/// Drift of an animation frame from the frame a structure was built for: the largest of the feature changes
/// ([`crate::characterize::features::FeatureChange`]: occupancy in log units, relative bounds change, size exponent
/// change / 4).
pub fn drift(built: &Features, now: &Features) -> f64 {
    let c = crate::characterize::features::FeatureChange::between(built, now);
    c.occupancy.max(c.bounds).max(c.size / 4.0)
}
