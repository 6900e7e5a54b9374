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
//! `q` ([`curvature_term`]) is `(ln n - 10)^2` over the calibration's sizes and its tangent beyond them, with
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
pub fn price_row(kind: WorkloadKind, box_tests: f64, prim_tests: f64, outside_ln_n: f64) -> Vec<f64> {
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
pub fn curvature_term(x: f64, lo: f64, hi: f64) -> f64 {
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
pub fn phi(d: &Derived, kind: WorkloadKind) -> Vec<f64> {
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

/// The fitted constants of one structure (see the module docs for the formulas).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StructureModel {
    /// The structure.
    pub structure: StructureName,
    /// `a_s`: `ln` of the build ms of a one-triangle scene, in [`BUILD_LN_A_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub build_ln_a: f64,
    /// `b_s`: exponent of `n` in the build time, in [`BUILD_EXPONENT_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub build_exponent: f64,
    /// `theta_box_s`, one per [`FEATURE_NAMES`], each of magnitude at most [`COEF_LIMIT`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub box_coef: Vec<f64>,
    /// `theta_prim_s`, one per [`FEATURE_NAMES`], each of magnitude at most [`COEF_LIMIT`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub prim_coef: Vec<f64>,
    /// Trace prices, ns, one per [`PRICE_NAMES`] (all in `0..=PRICE_LIMIT_NS`, not all 0).
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub trace_price: Vec<f64>,
    /// The view's coefficients in the box-test law, one per [`VIEW_FEATURE_NAMES`], or none (a calibration
    /// fitted without views, which ignores the camera).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub view_box_coef: Vec<f64>,
    /// The view's coefficients in the triangle-test law, as `view_box_coef`.
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub view_prim_coef: Vec<f64>,
    /// The coefficients of `ln(1 + crossings)` (`TestFloor::crossings`: the triangle boxes a ray of the workload
    /// crosses) in the box-test and the triangle-test laws, `[box, prim]`, each of magnitude at most
    /// [`COEF_LIMIT`]; or none (a calibration fitted without them, [`CostModel::fit_with`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub crossing_coef: Vec<f64>,
    /// With [`StructureModel::crossing_coef`]: per workload kind (primary, shadow, diffuse), the mean of
    /// `ln(1 + crossings)` over the calibration's samples of that kind (a sample without a count counting 0, as in
    /// the fit), in `[0, 45]`; what a prediction reads when the caller has no count (`TestFloor::crossings` NaN:
    /// features alone, no mesh), so that it predicts for the calibration's typical scene instead of one whose rays
    /// cross nothing. Absent in files written before it (such a file reads an unknown count as 0).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub crossing_mean: Vec<f64>,
    /// Per [`FEATURE_NAMES`] column, the least and the largest value over the samples the count laws were fitted
    /// on, `[lo, hi]`; a prediction clamps the geometric columns ([`CLAMPED_FEATURES`]) into it, so that a scene
    /// unlike every calibration scene is not extrapolated to by a log-linear law. Absent in files written before
    /// it (no clamp).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub feature_range: Vec<[f64; 2]>,
    /// The build law a probe's build work reads, `[a', b', c']`: `build_ms = exp(a') * n^b' * (work / n)^c'`, with
    /// `work` the built structure's [`crate::accel::AccelStats::build_work`] (its references times their levels)
    /// where a probe built it (`TestFloor::build_work`); the plain law
    /// ([`StructureModel::build_ln_a`], [`StructureModel::build_exponent`]) otherwise. `a'` in [`BUILD_LN_A_RANGE`],
    /// `b'` in [`BUILD_EXPONENT_RANGE`], `c'` in [`BUILD_WORK_EXPONENT_RANGE`]. Fitted for the probed structures
    /// ([`PROBED`]) on samples whose records counted the work; absent in files written before it (and for the other
    /// structures).
    ///
    /// A fourth constant `d'`, when present, is the law's curvature in `ln n`, as
    /// [`StructureModel::build_curvature`] is the plain law's.
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub build_work_coef: Vec<f64>,
    /// `d_s`: the plain build law's curvature in `ln n`, in [`BUILD_CURVATURE_RANGE`]: `ln build` gains
    /// `d_s * curvature_term(ln n)` ([`curvature_term`]: `(ln n - BUILD_CURVATURE_CENTER)^2` over the calibration's
    /// sizes, [`StructureModel::build_ln_n_range`], and its tangent beyond them). The time per triangle is U-shaped
    /// in `n`: fixed costs weigh on small builds, cache misses on large ones. 0 in files written before it, and
    /// where the calibration's sizes span less than [`BUILD_CURVATURE_MIN_SPAN`].
    #[serde(default, skip_serializing_if = "is_zero", deserialize_with = "f64_or_null")]
    pub build_curvature: f64,
    /// `[lo, hi]`: the range of `ln n` over the builds the laws were fitted on, beyond which the curvature terms
    /// follow their tangent ([`curvature_term`]); required with a curvature, else absent.
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub build_ln_n_range: Vec<f64>,
    /// The prior's own count laws ([`CountLaw`]), read where the caller knows nothing of the scene beyond its
    /// features (no crossings, no probe); absent in files written before them (the laws above serve then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior: Option<CountLaw>,
    /// The count laws of the triangle count alone ([`CountLaw`] with every geometric coefficient 0), read before
    /// the mesh is characterized: the selection's rung below level 0 ([`CostModel::predict_size`]); absent in files
    /// written without them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<CountLaw>,
    /// Fit errors on the calibration samples.
    pub fit: FitError,
}

/// The count laws the prior reads (level 0: nothing known of the scene but its features), fitted apart from the
/// laws that the crossings and probes correct, with a shrinkage chosen by how well the prior alone chooses on held-out
/// records (`calibrate`): geometric laws that follow the calibration's scenes closely extrapolate poorly to a scene
/// unlike them when nothing measured bounds them.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CountLaw {
    /// Coefficients of `ln` box tests per ray, one per [`FEATURE_NAMES`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub box_coef: Vec<f64>,
    /// Coefficients of `ln` triangle tests per ray, one per [`FEATURE_NAMES`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub prim_coef: Vec<f64>,
    /// The view's coefficients of the box-test law (none: the view ignored).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub view_box_coef: Vec<f64>,
    /// The view's coefficients of the triangle-test law.
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub view_prim_coef: Vec<f64>,
}

/// A structure's predicted costs for a scene and workload.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Prediction {
    /// The structure.
    pub structure: StructureName,
    /// Build ms of one build.
    pub build_ms_per_build: f64,
    /// Build ms over the run.
    pub build_ms: f64,
    /// Predicted box tests per ray.
    pub box_tests_per_ray: f64,
    /// Predicted triangle tests per ray.
    pub prim_tests_per_ray: f64,
    /// Predicted trace ns per ray.
    pub trace_ns_per_ray: f64,
    /// Trace ms over the run.
    pub trace_ms: f64,
    /// `build_ms + trace_ms`.
    pub total_ms: f64,
}

impl StructureModel {
    /// Predicted costs for features `d` of a scene with `n` triangles and a workload. With view coefficients,
    /// `w.view` enters the test-count laws (`None` counts as zeros here: [`CostModel::predict`] first resolves a
    /// missing view to the framing camera).
    pub fn predict(&self, d: &Derived, n: u64, w: &Workload) -> Prediction {
        self.predict_floored(d, n, w, TestFloor::default())
    }

    /// [`StructureModel::predict`] with the box and triangle tests per ray bounded by `floor` (bounds the caller
    /// knows from the scene, such as the selection's overlap floor, [`overlap_floor`]: at least its lower bounds, at
    /// most its upper ones, and the share of rays that leave the scene at once counted at one box test and no
    /// triangle test); the trace time follows from the bounded counts. A law within [`PROBE_BAND`] of a sampled
    /// count ([`TestFloor::sampled`]) stands; [`CostModel::predict_floored`] applies the calibration's own band
    /// ([`CostModel::own_probe_band`]).
    pub(crate) fn predict_floored(&self, d: &Derived, n: u64, w: &Workload, floor: TestFloor) -> Prediction {
        self.predict_corrected(d, n, w, floor, [1.0, 1.0], PROBE_BAND)
    }

    /// [`StructureModel::predict_floored`] with the laws' box and triangle tests per ray multiplied by
    /// `correction` before the floor bounds them (the probed structures' shared correction,
    /// [`CostModel::predict_floored`]), and a law kept where it lies within `band` of its sample (in the fit's RMS
    /// errors, as [`PROBE_BAND`]).
    fn predict_corrected(
        &self,
        d: &Derived,
        n: u64,
        w: &Workload,
        floor: TestFloor,
        correction: [f64; 2],
        band: f64,
    ) -> Prediction {
        let mut x = phi(d, w.kind);
        if self.feature_range.len() == x.len() {
            for j in CLAMPED_FEATURES {
                let [lo, hi] = self.feature_range[j];
                if lo <= hi {
                    x[j] = x[j].clamp(lo, hi);
                }
            }
        }
        let v = w.view.map_or([0.0; 3], |v| v.row());
        // Nothing known beyond the features: the prior's own laws, where the calibration has them.
        let unknown = floor.crossings.is_nan() && floor.sampled.is_none();
        let (box_coef, prim_coef, view_box, view_prim) = match (&self.prior, unknown) {
            (Some(p), true) => (&p.box_coef, &p.prim_coef, &p.view_box_coef, &p.view_prim_coef),
            _ => (&self.box_coef, &self.prim_coef, &self.view_box_coef, &self.view_prim_coef),
        };
        let (cb, cp) = match (self.crossing_coef.as_slice(), unknown && self.prior.is_some()) {
            (_, true) => (0.0, 0.0),
            (&[b, p], false) => {
                // An unknown count (NaN) reads the calibration's mean for the kind (0 in files without one).
                let xc = if floor.crossings.is_nan() {
                    self.crossing_mean.get(kind_index(w.kind)).copied().unwrap_or(0.0)
                } else {
                    (1.0 + floor.crossings.max(0.0)).ln()
                };
                (b * xc, p * xc)
            }
            _ => (0.0, 0.0),
        };
        let bx = (dot(box_coef, &x) + dot(view_box, &v) + cb).clamp(-30.0, 30.0).exp() * correction[0];
        let pr = (dot(prim_coef, &x) + dot(view_prim, &v) + cp).clamp(-30.0, 30.0).exp() * correction[1];
        // A NaN bound (never given) must not poison the counts: f64::max and f64::min ignore it.
        let bx = bx.max(floor.box_tests).min(floor.box_tests_most);
        let pr = pr.max(floor.prim_tests).min(floor.prim_tests_most);
        // Rays that leave the scene at once test the root box and nothing else.
        let leave = overlap::unit_share(floor.leave_share);
        let (mut bx, mut pr) = (leave + (1.0 - leave) * bx, (1.0 - leave) * pr);
        if let Some(p) = floor.sampled {
            // The structure's own counts on a sample of the rays: where the law's count lies outside its own error
            // band about the sampled mean (`band` times its fit's RMS error of `ln(1 + count)`), the law has
            // missed this scene, and the count is held within two standard errors of that mean instead.
            let held = |law: f64, m: overlap::SampledMean, rms: f64| {
                let within = count_error(law, m.mean).abs() <= band * rms.max(0.0);
                if within {
                    law
                } else {
                    law.clamp(m.lower_bound(), m.upper_bound())
                }
            };
            bx = held(bx, p.box_tests, self.fit.box_tests);
            pr = held(pr, p.prim_tests, self.fit.prim_tests);
        }
        let per_build = self.build_ms(n, floor.build_work);
        let build_ms = per_build * w.builds as f64;
        self.with_counts(build_ms, per_build, w, n, bx, pr)
    }

    /// Predicted ms of one build over `n` triangles: by the work law ([`StructureModel::build_work_coef`]) where
    /// `work` (the probe's [`crate::accel::AccelStats::build_work`]) is known (`> 0`) and the model has one, by the
    /// plain law in `n` otherwise.
    pub fn build_ms(&self, n: u64, work: f64) -> f64 {
        let ln_n = (n.max(1) as f64).ln();
        let q = self.build_curvature_term(ln_n);
        match self.build_work_coef[..] {
            [a, b, c, ref d @ ..] if work > 0.0 && work.is_finite() && d.len() <= 1 => {
                let d = d.first().copied().unwrap_or(0.0);
                (a + b * ln_n + c * (work.ln() - ln_n) + d * q).exp()
            }
            _ => (self.build_ln_a + self.build_exponent * ln_n + self.build_curvature * q).exp(),
        }
    }

    /// The curvature terms' [`curvature_term`] over [`StructureModel::build_ln_n_range`]; 0 without a range (a
    /// model without curvature).
    fn build_curvature_term(&self, ln_n: f64) -> f64 {
        match self.build_ln_n_range[..] {
            [lo, hi] => curvature_term(ln_n, lo, hi),
            _ => 0.0,
        }
    }

    /// The prediction of a build of `build_ms` (`per_build` ms each) and `bx` box and `pr` triangle tests per ray
    /// for workload `w` over `n` triangles: the trace time from the counts at this structure's prices.
    fn with_counts(&self, build_ms: f64, per_build: f64, w: &Workload, n: u64, bx: f64, pr: f64) -> Prediction {
        let ns = dot(&self.trace_price, &price_row(w.kind, bx, pr, price_outside_ln_n(w, n)));
        let trace_ms = ns * 1e-6 * w.rays_per_frame as f64 * w.frames as f64;
        Prediction {
            structure: self.structure,
            build_ms_per_build: per_build,
            build_ms,
            box_tests_per_ray: bx,
            prim_tests_per_ray: pr,
            trace_ns_per_ray: ns,
            trace_ms,
            total_ms: build_ms + trace_ms,
        }
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

/// A calibrated cost model: per structure constants, fit errors and provenance.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CostModel {
    /// File format version, [`COST_MODEL_VERSION`].
    pub version: u32,
    /// The device the constants were measured on (not empty).
    pub device: String,
    /// Where the measurements came from (command, files).
    pub source: String,
    /// Scenes of the calibration.
    pub scenes: Vec<String>,
    /// Names of the `phi` columns, [`FEATURE_NAMES`].
    pub feature_names: Vec<String>,
    /// Names of the trace price columns, [`PRICE_NAMES`].
    pub price_names: Vec<String>,
    /// One model per structure (at least one, each structure once).
    pub structures: Vec<StructureModel>,
    /// RMS log error of the totals over all samples and structures.
    #[serde(deserialize_with = "f64_or_null")]
    pub total_rms_log: f64,
    /// Refit model for animations, when calibrated.
    pub refit: Option<RefitModel>,
    /// Where the calibration's rays were traced: `cpu` (the counting CPU tracer) or `vulkan` (the device traversal
    /// kernel). Files written before the field existed are `cpu`.
    #[serde(default)]
    pub trace_backend: TraceBackend,
    /// The device that traced (`vulkan` only; absent for `cpu`): its name, type, driver, driver version and UUID
    /// as [`crate::accel::device::DeviceRecord`] records them. [`registry`] matches a device to a file by it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trace_device: Option<DeviceRecord>,
    /// The driver's acceleration structures ([`driver`]), when the calibration measured them (a device with ray
    /// queries); absent in files written before they existed, and for the CPU tracer.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub driver: Vec<DriverModel>,
    /// The ratios that turn timed probes into this calibration's times ([`timed::TimedRatios`]), when it was fitted
    /// with them (`calibrate --timed-probes`); absent otherwise, and then the policy cannot blend timed probes in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timed: Option<timed::TimedRatios>,
    /// The overlap floor's factors ([`CountBounds`]), read off the calibration's records.
    pub count_bounds: CountBounds,
    /// The calibration's own held-out errors of each structure's total, by what the selection knows
    /// ([`Uncertainty`]): what the selection's ladder weighs against the cost of knowing more. Absent in files
    /// written before it: then the selection decides on the prior alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<Uncertainty>,
    /// What each stage of a decision costs on the calibration's machine ([`InquiryCost`]), as laws in the triangle
    /// count; absent in files written before it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inquiry_costs: Vec<InquiryCost>,
    /// Which file this model was read from and why it was chosen (`assets/cost-model-lavapipe.json: device name
    /// ...`), set by [`CostModel::for_trace_target`]; not part of the file, `None` for a model made otherwise.
    #[serde(skip)]
    pub chosen_as: Option<String>,
}

impl CostModel {
    /// Parses and validates a calibration file's text (see the module docs, Validation): refuses another version,
    /// a missing, malformed or unknown field, and any value [`CostModel::validate`] refuses, naming the field.
    pub fn from_json(text: &str) -> Result<CostModel, CostError> {
        use serde_json::Value;
        let mut v: Value = serde_json::from_str(text).map_err(|e| CostError::Parse(e.to_string()))?;
        let Some(obj) = v.as_object_mut() else {
            return Err(invalid(None, "top level", format!("{}, not a JSON object", json_kind(&v))));
        };
        // The version first: a file of another version may have another layout.
        let found = match obj.get("version") {
            None => return Err(invalid(None, "version", "missing")),
            Some(x) => x.as_u64().ok_or_else(|| invalid(None, "version", format!("{x} is not a whole number")))?,
        };
        if found != u64::from(COST_MODEL_VERSION) {
            return Err(CostError::Version { found, expected: COST_MODEL_VERSION });
        }
        match obj.get("device") {
            None => return Err(invalid(None, "device", "missing")),
            Some(Value::String(_)) => {}
            Some(x) => return Err(invalid(None, "device", format!("{}, not a string", json_kind(x)))),
        }
        // The structures one by one, so that an error names the structure.
        let structures = match obj.remove("structures") {
            None => return Err(invalid(None, "structures", "missing")),
            Some(Value::Array(a)) => a,
            Some(x) => return Err(invalid(None, "structures", format!("{}, not an array", json_kind(&x)))),
        };
        let structures: Vec<StructureModel> =
            structures.into_iter().enumerate().map(|(i, s)| structure_from_json(i, s)).collect::<Result<_, _>>()?;
        obj.insert("structures".into(), Value::Array(Vec::new()));
        let mut m: CostModel = serde_json::from_value(v).map_err(|e| invalid(None, "top level", e.to_string()))?;
        m.structures = structures;
        m.validate()?;
        Ok(m)
    }

    /// Checks every rule of the module docs (Validation); the error names the first field that breaks one.
    pub fn validate(&self) -> Result<(), CostError> {
        if self.version != COST_MODEL_VERSION {
            return Err(CostError::Version { found: u64::from(self.version), expected: COST_MODEL_VERSION });
        }
        if self.device.trim().is_empty() {
            return Err(invalid(None, "device", "empty: name the device the constants were measured on"));
        }
        check_names("feature_names", &self.feature_names, &FEATURE_NAMES)?;
        check_names("price_names", &self.price_names, &PRICE_NAMES)?;
        if self.structures.is_empty() {
            return Err(invalid(None, "structures", "empty: no structure is calibrated"));
        }
        if let Some(t) = &self.timed {
            t.validate().map_err(|e| invalid(None, "timed", &e))?;
        }
        self.count_bounds.validate().map_err(|e| invalid(None, "count_bounds", &e))?;
        for (i, s) in self.structures.iter().enumerate() {
            if let Some(j) = self.structures[..i].iter().position(|t| t.structure == s.structure) {
                return Err(invalid(
                    Some(s.structure),
                    format!("structures[{i}].structure"),
                    format!("{} appears twice (also structures[{j}])", s.structure.as_str()),
                ));
            }
            check_structure(i, s)?;
        }
        check_number(None, "total_rms_log".into(), self.total_rms_log, 0.0..=f64::MAX, "a root-mean-square error")?;
        match (self.trace_backend, &self.trace_device) {
            (TraceBackend::Cpu, Some(_)) => {
                return Err(invalid(
                    None,
                    "trace_device",
                    "present with trace_backend cpu: only a device calibration names a device",
                ))
            }
            (TraceBackend::Vulkan, None) => {
                return Err(invalid(
                    None,
                    "trace_device",
                    "missing: a vulkan calibration names the device it was measured on",
                ))
            }
            (TraceBackend::Vulkan, Some(d)) if d.name.trim().is_empty() => {
                return Err(invalid(None, "trace_device.name", "empty: name the device the constants were measured on"))
            }
            _ => {}
        }
        if let Some(r) = &self.refit {
            let f = |name: &str| format!("refit.{name}");
            check_number(
                None,
                f("sah_growth_per_drift"),
                r.sah_growth_per_drift,
                SAH_GROWTH_RANGE,
                "the growth of the SAH ratio per unit of drift",
            )?;
            check_number(None, f("refit_ns_per_triangle"), r.refit_ns_per_triangle, 0.0..=PRICE_LIMIT_NS, "ns")?;
            if r.refit_ns_per_triangle == 0.0 {
                return Err(invalid(None, f("refit_ns_per_triangle"), "0: a refit visits every node, it is not free"));
            }
            check_number(None, f("fit_rms"), r.fit_rms, 0.0..=f64::MAX, "a root-mean-square error")?;
            if r.samples == 0 {
                return Err(invalid(None, f("samples"), "0: a refit model needs at least one measured frame pair"));
            }
        }
        for (i, d) in self.driver.iter().enumerate() {
            if let Some(j) = self.driver[..i].iter().position(|e| e.name == d.name) {
                return Err(invalid(
                    None,
                    format!("driver[{i}].name"),
                    format!("{} appears twice (also driver[{j}])", d.name),
                ));
            }
            d.validate(i)?;
        }
        if let Some(u) = &self.uncertainty {
            for (i, x) in u.structures.iter().enumerate() {
                let at = |f: &str| format!("uncertainty.structures[{i}] ({}).{f}", x.structure.as_str());
                let st = Some(x.structure);
                let figures = [
                    ("size", x.size),
                    ("prior", Some(x.prior)),
                    ("crossings", Some(x.crossings)),
                    ("probed", Some(x.probed)),
                ];
                let more = [("timed", x.timed), ("measured", x.measured)];
                for (name, v) in figures.into_iter().chain(more) {
                    if let Some(v) = v {
                        check_number(st, at(name), v, 0.0..=10.0, "an RMS error of ln(predicted / measured)")?;
                    }
                }
            }
        }
        for (i, c) in self.inquiry_costs.iter().enumerate() {
            let at = |f: &str| format!("inquiry_costs[{i}] ({}).{f}", c.stage);
            check_number(None, at("ln_a"), c.ln_a, BUILD_LN_A_RANGE, "ln of the ms of one triangle")?;
            check_number(None, at("exponent"), c.exponent, BUILD_EXPONENT_RANGE, "the exponent of n")?;
            check_number(None, at("rms"), c.rms, 0.0..=f64::MAX, "a root-mean-square error")?;
        }
        if !self.driver.is_empty() && self.trace_backend != TraceBackend::Vulkan {
            return Err(invalid(
                None,
                "driver",
                "present with trace_backend cpu: driver structures are traced on a Vulkan device",
            ));
        }
        Ok(())
    }

    /// The JSON text of a calibration file.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\":{:?}}}", e.to_string()))
    }

    /// Writes the calibration file.
    pub fn save(&self, path: &Path) -> Result<(), CostError> {
        std::fs::write(path, self.to_json() + "\n")
            .map_err(|source| CostError::Io { path: path.display().to_string(), source })
    }

    /// The shipped default (fitted on this project's oracle data, CPU structures).
    pub fn shipped() -> Result<CostModel, CostError> {
        CostModel::from_json(SHIPPED_CPU)
    }

    /// Loads a calibration file. With a path, that file: one that is missing or unreadable is an error
    /// ([`CostError::Io`]), and so is one that [`CostModel::from_json`] refuses ([`CostError::File`], with the path
    /// and the field). Without a path, the shipped default ([`CostModel::shipped`]). A file that was asked for is
    /// never replaced by the shipped default.
    pub fn load(path: Option<&Path>) -> Result<CostModel, CostError> {
        let Some(path) = path else {
            return CostModel::shipped();
        };
        let text = std::fs::read_to_string(path)
            .map_err(|source| CostError::Io { path: path.display().to_string(), source })?;
        CostModel::from_json(&text)
            .map_err(|e| CostError::File { path: path.display().to_string(), source: Box::new(e) })
    }

    /// The predicted ms of decision stage `stage` ([`InquiryCost`]) for `n` triangles; `None` without its law.
    pub(crate) fn inquiry_ms(&self, stage: &str, n: u64) -> Option<f64> {
        self.inquiry_costs.iter().find(|c| c.stage == stage).map(|c| c.ms(n))
    }

    /// The model of one structure.
    pub fn get(&self, s: StructureName) -> Option<&StructureModel> {
        self.structures.iter().find(|m| m.structure == s)
    }

    /// Predicted costs of every calibrated structure for a scene (its first frame's features) and a workload.
    ///
    /// A workload without a view is predicted for the framing camera of the features' bounds
    /// ([`ViewFeatures::framing`]), the oracle's default camera.
    pub fn predict(&self, f: &Features, w: &Workload) -> Vec<Prediction> {
        self.predict_floored(f, w, &|_| TestFloor::default())
    }

    /// Predicted costs from the triangle count `n` alone, before the mesh is characterized: each structure's size
    /// law ([`StructureModel::size`]) with its build law and prices, the framing camera; `None` when the file has no
    /// size laws.
    pub fn predict_size(&self, n: u64, w: &Workload) -> Option<Vec<Prediction>> {
        let d = Derived {
            ln_n: (n.max(1) as f64).ln(),
            fill_at_n: 0.0,
            ln_tris_per_cell: 0.0,
            empty_d3: 0.0,
            size_mean: 0.0,
            size_spread: 0.0,
            aspect_log2: 0.0,
        };
        let w = Workload { view: None, ..*w };
        let preds: Vec<Prediction> = self
            .structures
            .iter()
            .filter_map(|m| {
                let law = m.size.clone()?;
                let sized = StructureModel { prior: Some(law), ..m.clone() };
                Some(sized.predict(&d, n.max(1), &w))
            })
            .collect();
        (!preds.is_empty() && preds.len() == self.structures.len()).then_some(preds)
    }

    /// [`CostModel::predict`] with each structure's tests per ray bounded by `floor(structure)`
    /// ([`StructureModel::predict_floored`]); where a probed structure's counts are held to its sample, the
    /// structures of [`SHARES_PROBES`] that were not probed take the same correction.
    pub(crate) fn predict_floored(
        &self,
        f: &Features,
        w: &Workload,
        floor: &dyn Fn(StructureName) -> TestFloor,
    ) -> Vec<Prediction> {
        let d = f.derived();
        // Only a model fitted with views reads them: the others skip the framing camera's slab tests.
        let w = if self.structures.iter().any(|m| !m.view_box_coef.is_empty() || !m.view_prim_coef.is_empty()) {
            resolve_view(f, w)
        } else {
            *w
        };
        let n = f.scene_triangles();
        let band = self.own_probe_band();
        let mut preds: Vec<Prediction> = self
            .structures
            .iter()
            .map(|m| m.predict_corrected(&d, n, &w, floor(m.structure), [1.0, 1.0], band))
            .collect();
        self.share_probed_corrections(&d, n, &w, floor, &mut preds);
        preds
    }

    /// The band within which a probed structure keeps its own law instead of its sample's count
    /// ([`StructureModel::predict_floored`]): [`OWN_PROBE_BAND_CPU`] for a calibration traced on the CPU, where the
    /// probe traces the frame's own tree; [`PROBE_BAND`] for a device calibration.
    pub(crate) fn own_probe_band(&self) -> f64 {
        match self.trace_backend {
            TraceBackend::Cpu => OWN_PROBE_BAND_CPU,
            TraceBackend::Vulkan => PROBE_BAND,
        }
    }

    /// Where probed structures' counts were held to their samples ([`TestFloor::sampled`]), the unprobed structures
    /// of [`SHARES_PROBES`] take the same correction: their laws' box and triangle tests per ray times the geometric
    /// mean, over the probed structures, of the count held at [`PROBE_BAND`] over the law's (1 where a law lies
    /// within that band, whatever [`CostModel::own_probe_band`] held the structure's own count to), then their own
    /// floors as before. The
    /// laws' errors are shared across the hierarchies (see the module docs, Probes), so a count held for some
    /// alone would set them against others that keep the same error. `preds` are the predictions of
    /// [`CostModel::structures`], in that order.
    fn share_probed_corrections(
        &self,
        d: &Derived,
        n: u64,
        w: &Workload,
        floor: &dyn Fn(StructureName) -> TestFloor,
        preds: &mut [Prediction],
    ) {
        // Per count, the sum of `ln(held / law)` and how many probed structures gave one (a zero count, where every
        // sampled ray tests no triangle, says nothing about a ratio).
        let (mut boxes, mut prims) = ((0.0, 0u32), (0.0, 0u32));
        let add = |acc: &mut (f64, u32), held: f64, law: f64| {
            if held > 0.0 && law > 0.0 && held.is_finite() && law.is_finite() {
                acc.0 += (held / law).ln();
                acc.1 += 1;
            }
        };
        for m in &self.structures {
            let f = floor(m.structure);
            if f.sampled.is_some() && m.structure != StructureName::Grid {
                let law = m.predict_floored(d, n, w, TestFloor { sampled: None, ..f });
                let held = m.predict_corrected(d, n, w, f, [1.0, 1.0], PROBE_BAND);
                add(&mut boxes, held.box_tests_per_ray, law.box_tests_per_ray);
                add(&mut prims, held.prim_tests_per_ray, law.prim_tests_per_ray);
            }
        }
        let mean = |(sum, k): (f64, u32)| if k > 0 { (sum / f64::from(k)).exp() } else { 1.0 };
        let (gb, gp) = (mean(boxes), mean(prims));
        if gb == 1.0 && gp == 1.0 {
            return;
        }
        for (m, p) in self.structures.iter().zip(preds.iter_mut()) {
            let f = floor(m.structure);
            if SHARES_PROBES.contains(&m.structure) && f.sampled.is_none() {
                // The law corrected, then bounded by the structure's own floor as before.
                *p = m.predict_corrected(d, n, w, f, [gb, gp], PROBE_BAND);
            }
        }
    }

    /// Predicted costs of every calibrated driver structure ([`driver`]) for a scene and a workload.
    pub(crate) fn predict_driver(&self, f: &Features, w: &Workload) -> Vec<DriverPrediction> {
        let d = f.derived();
        self.driver.iter().filter_map(|m| m.predict(&d, f.scene_triangles(), w)).collect()
    }

    /// The model of one driver structure.
    pub fn get_driver(&self, f: crate::accel::driver::DriverFlags) -> Option<&DriverModel> {
        self.driver.iter().find(|m| m.name == f.name())
    }
}

/// `w` with its view resolved: its own, or the framing camera of the features' bounds (it costs
/// [`view::COVERAGE_GRID`]^2 slab tests).
pub(crate) fn resolve_view(f: &Features, w: &Workload) -> Workload {
    Workload { view: Some(w.view.unwrap_or_else(|| ViewFeatures::framing(f.lo, f.hi))), ..*w }
}

/// What a JSON value is, for error messages.
fn json_kind(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    }
}

/// Entry `i` of a file's `structures`: its name first (known, calibrated), then the typed model.
fn structure_from_json(i: usize, v: serde_json::Value) -> Result<StructureModel, CostError> {
    let field = format!("structures[{i}].structure");
    let structure = match v.get("structure") {
        None => return Err(invalid(None, field, "missing")),
        Some(serde_json::Value::String(name)) => {
            StructureName::from_name(name).filter(|s| StructureName::ALL.contains(s)).ok_or_else(|| {
                invalid(None, field, format!("{name:?} is not a calibrated structure ({})", known_names()))
            })?
        }
        Some(x) => return Err(invalid(None, field, format!("{}, not a string", json_kind(x)))),
    };
    serde_json::from_value(v)
        .map_err(|e| invalid(Some(structure), format!("structures[{i}] ({})", structure.as_str()), e.to_string()))
}

/// The names of [`StructureName::ALL`], comma-separated.
fn known_names() -> String {
    StructureName::ALL.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ")
}

/// `got` equals `want`, name for name and in order; the error names the first position that differs.
fn check_names(field: &str, got: &[String], want: &[&str]) -> Result<(), CostError> {
    let order = want.join(", ");
    for (i, w) in want.iter().enumerate() {
        match got.get(i) {
            None => {
                return Err(invalid(
                    None,
                    format!("{field}[{i}]"),
                    format!("missing: expected {w:?} ({} names, in order: {order}; found {})", want.len(), got.len()),
                ))
            }
            Some(g) if g != w => {
                return Err(invalid(
                    None,
                    format!("{field}[{i}]"),
                    format!("{g:?}, expected {w:?} (the columns are read by position, in order: {order})"),
                ))
            }
            Some(_) => {}
        }
    }
    match got.get(want.len()) {
        Some(extra) => Err(invalid(
            None,
            format!("{field}[{}]", want.len()),
            format!("{extra:?}: unexpected, {} names expected ({order})", want.len()),
        )),
        None => Ok(()),
    }
}

/// `x` is finite and in `range`; `what` says what the number is.
fn check_number(
    structure: Option<StructureName>,
    field: String,
    x: f64,
    range: RangeInclusive<f64>,
    what: &str,
) -> Result<(), CostError> {
    if !x.is_finite() {
        return Err(invalid(structure, field, format!("{x} is not a finite number ({what})")));
    }
    if !range.contains(&x) {
        let bounds = if *range.end() == f64::MAX {
            format!(">= {}", range.start())
        } else {
            format!("in [{}, {}]", range.start(), range.end())
        };
        return Err(invalid(structure, field, format!("{x} is out of range: {what}, must be {bounds}")));
    }
    Ok(())
}

/// The rules of one structure's model (entry `i` of `structures`).
fn check_structure(i: usize, s: &StructureModel) -> Result<(), CostError> {
    let st = Some(s.structure);
    let at = |f: &str| format!("structures[{i}] ({}).{f}", s.structure.as_str());
    if !StructureName::ALL.contains(&s.structure) {
        return Err(invalid(
            st,
            format!("structures[{i}].structure"),
            format!("{:?} is not a calibrated structure ({})", s.structure.as_str(), known_names()),
        ));
    }
    check_number(st, at("build_ln_a"), s.build_ln_a, BUILD_LN_A_RANGE, "ln of the build ms of one triangle")?;
    check_number(st, at("build_exponent"), s.build_exponent, BUILD_EXPONENT_RANGE, "the exponent of n in the build")?;
    check_number(st, at("build_curvature"), s.build_curvature, BUILD_CURVATURE_RANGE, "a curvature in ln n")?;
    match s.build_work_coef[..] {
        [] => {}
        [a, b, c, ref d @ ..] if d.len() <= 1 => {
            let what = "ln of the build ms of one triangle (work law)";
            check_number(st, at("build_work_coef[0]"), a, BUILD_LN_A_RANGE, what)?;
            let what = "the exponent of n in the build (work law)";
            check_number(st, at("build_work_coef[1]"), b, BUILD_EXPONENT_RANGE, what)?;
            let what = "the exponent of the build work per triangle";
            check_number(st, at("build_work_coef[2]"), c, BUILD_WORK_EXPONENT_RANGE, what)?;
            if let [d] = d {
                let what = "a curvature in ln n (work law)";
                check_number(st, at("build_work_coef[3]"), *d, BUILD_CURVATURE_RANGE, what)?;
            }
        }
        _ => {
            return Err(invalid(
                st,
                at("build_work_coef"),
                format!("{} coefficients, expected none, three or four", s.build_work_coef.len()),
            ))
        }
    }
    let curved = s.build_curvature != 0.0 || s.build_work_coef.get(3).is_some_and(|&d| d != 0.0);
    match s.build_ln_n_range[..] {
        [] if curved => {
            return Err(invalid(st, at("build_ln_n_range"), "missing: a curved build law needs the range of ln n"))
        }
        [] => {}
        [lo, hi] => {
            let field = at("build_ln_n_range");
            let limit = 0.0..=BUILD_LN_N_LIMIT;
            if !(limit.contains(&lo) && limit.contains(&hi)) {
                let why = format!("[{lo}, {hi}]: the bounds must be finite, in [0, {BUILD_LN_N_LIMIT}] (ln 2^40)");
                return Err(invalid(st, field, why));
            }
            if lo > hi {
                return Err(invalid(st, field, format!("[{lo}, {hi}]: the low bound exceeds the high one")));
            }
            // The slopes the laws keep beyond the fitted sizes: no build gets faster with more triangles.
            let laws = [("build_curvature", s.build_exponent, s.build_curvature)].into_iter().chain(
                match s.build_work_coef[..] {
                    [_, b, _, d] => Some(("build_work_coef[3]", b, d)),
                    _ => None,
                },
            );
            for (name, b, d) in laws {
                for (slope, edge) in build_law_slopes(b, d, lo, hi).into_iter().zip([lo, hi]) {
                    if !BUILD_EXPONENT_RANGE.contains(&slope) {
                        let why = format!(
                            "the law's slope in ln n at the edge {edge} of its sizes, b + 2 d (edge - \
                             {BUILD_CURVATURE_CENTER}), is {slope}, outside [0, 2]"
                        );
                        return Err(invalid(st, at(name), why));
                    }
                }
            }
        }
        _ => {
            return Err(invalid(
                st,
                at("build_ln_n_range"),
                format!("{} values, expected none or two (lo, hi)", s.build_ln_n_range.len()),
            ))
        }
    }
    for (name, coef) in [("box_coef", &s.box_coef), ("prim_coef", &s.prim_coef)] {
        if coef.len() != FEATURE_NAMES.len() {
            return Err(invalid(
                st,
                at(name),
                format!("{} coefficients, expected one per feature ({})", coef.len(), FEATURE_NAMES.len()),
            ));
        }
        for (j, (&c, f)) in coef.iter().zip(FEATURE_NAMES).enumerate() {
            check_number(st, at(&format!("{name}[{j}] ({f})")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
        }
    }
    for (name, coef) in [("view_box_coef", &s.view_box_coef), ("view_prim_coef", &s.view_prim_coef)] {
        if !coef.is_empty() && coef.len() != VIEW_FEATURE_NAMES.len() {
            return Err(invalid(
                st,
                at(name),
                format!(
                    "{} coefficients, expected none or one per view feature ({})",
                    coef.len(),
                    VIEW_FEATURE_NAMES.len()
                ),
            ));
        }
        for (j, (&c, f)) in coef.iter().zip(VIEW_FEATURE_NAMES).enumerate() {
            check_number(st, at(&format!("{name}[{j}] ({f})")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
        }
    }
    if !s.crossing_coef.is_empty() && s.crossing_coef.len() != 2 {
        return Err(invalid(
            st,
            at("crossing_coef"),
            format!("{} coefficients, expected none or two (box, prim)", s.crossing_coef.len()),
        ));
    }
    for (j, (&c, f)) in s.crossing_coef.iter().zip(["box", "prim"]).enumerate() {
        check_number(st, at(&format!("crossing_coef[{j}] ({f})")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
    }
    if !s.crossing_mean.is_empty() && (s.crossing_coef.is_empty() || s.crossing_mean.len() != 3) {
        let why = if s.crossing_coef.is_empty() {
            "present without crossing_coef: a model without crossing coefficients reads no count".to_string()
        } else {
            format!("{} means, expected none or three (primary, shadow, diffuse)", s.crossing_mean.len())
        };
        return Err(invalid(st, at("crossing_mean"), why));
    }
    for (j, (&c, f)) in s.crossing_mean.iter().zip(["primary", "shadow", "diffuse"]).enumerate() {
        check_number(st, at(&format!("crossing_mean[{j}] ({f})")), c, 0.0..=45.0, "a mean of ln(1 + crossings)")?;
    }
    if !s.feature_range.is_empty() && s.feature_range.len() != FEATURE_NAMES.len() {
        return Err(invalid(
            st,
            at("feature_range"),
            format!("{} ranges, expected none or one per feature ({})", s.feature_range.len(), FEATURE_NAMES.len()),
        ));
    }
    for (j, (&[lo, hi], f)) in s.feature_range.iter().zip(FEATURE_NAMES).enumerate() {
        let field = at(&format!("feature_range[{j}] ({f})"));
        if !(lo.is_finite() && hi.is_finite()) {
            return Err(invalid(st, field, format!("[{lo}, {hi}]: the bounds must be finite numbers")));
        }
        if lo > hi {
            return Err(invalid(st, field, format!("[{lo}, {hi}]: the low bound exceeds the high one")));
        }
    }
    for (law, p) in [("prior", &s.prior), ("size", &s.size)] {
        let Some(p) = p else { continue };
        for (field, coef, want) in [
            ("box_coef", &p.box_coef, FEATURE_NAMES.len()),
            ("prim_coef", &p.prim_coef, FEATURE_NAMES.len()),
            ("view_box_coef", &p.view_box_coef, VIEW_FEATURE_NAMES.len()),
            ("view_prim_coef", &p.view_prim_coef, VIEW_FEATURE_NAMES.len()),
        ] {
            let name = format!("{law}.{field}");
            let name = name.as_str();
            let view = name.contains("view");
            if law == "size"
                && (view && !coef.is_empty() || coef.get(CLAMPED_FEATURES).is_some_and(|c| c.iter().any(|&x| x != 0.0)))
            {
                return Err(invalid(
                    st,
                    at(name),
                    String::from("the triangle count's law reads no geometric feature and no view"),
                ));
            }
            if coef.len() != want && !(view && coef.is_empty()) {
                return Err(invalid(st, at(name), format!("{} coefficients, expected {want}", coef.len())));
            }
            for (j, &c) in coef.iter().enumerate() {
                check_number(st, at(&format!("{name}[{j}]")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
            }
        }
    }
    if s.trace_price.len() != PRICE_NAMES.len() {
        return Err(invalid(
            st,
            at("trace_price"),
            format!("{} prices, expected one per price name ({})", s.trace_price.len(), PRICE_NAMES.len()),
        ));
    }
    for (j, (&p, name)) in s.trace_price.iter().zip(PRICE_NAMES).enumerate() {
        check_number(st, at(&format!("trace_price[{j}] ({name})")), p, 0.0..=PRICE_LIMIT_NS, "a price in ns")?;
    }
    if s.trace_price.iter().all(|&p| p == 0.0) {
        return Err(invalid(st, at("trace_price"), "every price is 0: tracing would be free"));
    }
    for (name, x) in s.fit.figures() {
        check_number(st, at(&format!("fit.{name}")), x, 0.0..=f64::MAX, "a root-mean-square error")?;
    }
    Ok(())
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
