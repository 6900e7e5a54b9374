//! The cost model, its calibration file, the build budget, the oracle and the selection scored against it: tests
//! inside the crate, so that they reach the internals of the cost model and the selection, which stay crate-private.
//! They name the crate `meshchar`, as a user does.
#[path = "../../../tests/common/mod.rs"]
mod common;
#[path = "../../../tests/gpu_support/mod.rs"]
mod gpu_support;

mod budget;
mod budget_floor;
mod budget_probes;
mod cost;
mod cost_driver;
mod cost_families;
mod cost_file;
mod cost_policy;
mod eval;
mod tradeoff;
