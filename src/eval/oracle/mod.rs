//! The measurement oracle: build and trace every structure on a scene and a workload, and from the timings the
//! ground-truth best structure, each structure's total, and the regret of a selection.
//!
//! # Method
//!
//! For each frame of the scene, the rays of the workload are generated once (from a binned-SAH BVH built for that
//! frame, not timed) together with the reference hits. Then, `repeats` times, every structure is built (timed),
//! traced over the rays (timed, rayon over rays), and, in the first repeat, validated and compared with the
//! reference hits (not timed). Repeats are interleaved across structures so that slow drift of the machine affects
//! them alike. Reported times are **medians over repeats**.
//!
//! # Totals
//!
//! * A static scene (one mesh) rendered for `F` frames: `total = B + F * T` when the structure is built once,
//!   `F * (B + T)` when rebuilt every frame, with `B`, `T` the build and trace time of one frame.
//! * An animation (several meshes, one topology): frames `0 .. F` are used, each rebuilt and traced:
//!   `total = sum_f (B_f + T_f)`. Building once is refused for an animation (tracing frame `f` through frame 0's
//!   structure without an update would give wrong hits).
//! * **Refit candidates** of an animation ([`OracleConfig::refit`], `bvh_refit` and `lbvh_refit`): frame 0 built,
//!   every later frame refitted ([`crate::accel::bvh::BvhTree::refit`]) and traced, every frame's hits checked
//!   against the reference: `total = B_0 + sum_{f >= 1} R_f + sum_f T_f`. They are candidates of their own
//!   ([`SceneEvaluation::refit_structures`], named in [`SceneEvaluation::best_candidate`]), so that what refitting
//!   saves is measured rather than predicted; they are measured with `repeats` repeats (no precision target) on
//!   the CPU tracer.
//!
//! The **oracle best** is the structure with the smallest median total among those that built, validated and
//! agreed with the reference hits. The **regret** of a selection `s` is `total(s) / total(best) - 1`.
//!
//! # Noise
//!
//! Each structure's total has a spread, half the range of its totals over the repeats. Two structures are *within
//! noise* of each other when their medians differ by no more than the sum of their spreads; a regret is within
//! noise when the selection is within noise of the best. With one repeat the spread is zero and nothing is ever
//! within noise: use at least three repeats to judge.
//!
//! # The precise oracle
//!
//! With [`OracleConfig::precision`] set (0.02 for +-2%), every structure is measured `repeats` times and then in
//! further rounds, each round measuring every structure once (interleaved), until the distribution-free 95%
//! confidence interval of each structure's median total ([`median_ci95`], the sign-test interval from order
//! statistics: at least 6 repeats) lies within the target of its median, or [`OracleConfig::max_repeats`] rounds
//! are reached (more while [`OracleConfig::precision_ms`] allows); each structure's `precision_met` says whether
//! its interval met the target. Every structure takes part in every round so that the machine's drift hits all
//! alike: on the 2-core VM the same build and trace run up to 1.6x slower for seconds at a time, and when a
//! structure already precise stopped while another went on into such a stretch, the one measured on was judged
//! slower than it is (`docs/results/2026-12-06-cost-model-oracle-in-rounds.md`). With intervals, two totals are within noise when
//! their intervals overlap. On an animation, frame 0 decides the repeats and later frames repeat each structure as
//! often, so that every repeat's total covers every frame.
//!
//! # Trace budget
//!
//! Building is bounded by the grid's and the kd-tree's reference budgets; tracing is bounded here. Before a
//! structure's first timed trace on a frame, a sample of the rays (every `k`-th ray, [`TRACE_SAMPLE_RAYS`] of them;
//! not timed) is traced with counters; when its box and triangle tests per ray exceed
//! [`OracleConfig::max_tests_per_ray`], the structure is reported as failed for the scene, with the counts and the
//! projected total, and the others are measured. The reference is checked the same way before it makes the rays,
//! and a reference over the budget is an error for the scene. Such scenes exist: a polygon face over three points
//! loads to many coincident copies of one triangle, and under the tie rule a ray that reaches them tests every copy
//! (the binned-SAH BVH keeps one copy of a triangle whose vertex indices repeat, [`crate::accel::bvh::BvhTree::copies`],
//! the other structures test them all). On every scene of `docs/data` the most tests per ray of any structure is
//! 134 (the grid on the dragon, shadow rays), so the default of 4,096 stops only the pathological.
//!
//! # The cheapest structure within noise
//!
//! When several structures are within noise of the best, the measurement cannot tell them apart, and the one that
//! costs least to have is the better answer: [`SceneEvaluation::oracle_within_noise`] lists them (the best
//! included) and [`SceneEvaluation::oracle_cheapest_within_noise`] names the one with the least median build time,
//! then the least memory. `oracle_best` stays the structure with the smallest median total, and `regret` is still
//! measured against it; a policy (or a calibration) that wants the cheapest defensible answer targets
//! `oracle_cheapest_within_noise` instead.

mod config;
mod device;
mod measure;
mod refit;
mod result;

pub use crate::accel::device::{DeviceRecord, TraceBackend};
pub use config::{
    check_trace_budget, OracleConfig, Rebuild, DEFAULT_MAX_REPEATS, DEFAULT_MAX_TESTS_PER_RAY, MAX_PRECISION_REPEATS,
    ROUNDS_EVERY_STRUCTURE, TRACE_SAMPLE_RAYS,
};
pub use device::DeviceOracle;
pub use measure::{evaluate_scene, evaluate_scene_on};
pub use refit::{RefitCandidate, RefitResult};
pub use result::{median_ci95, DriverResult, EvalError, Measurement, SceneEvaluation, StructureResult};
