//! The cost model, its calibration file, the oracle and the selection scored against it.
//!
//! One binary for the layer (each module was its own test binary, linked once per file).
#[path = "../common/mod.rs"]
mod common;
#[path = "../gpu_support/mod.rs"]
mod gpu_support;

mod cost;
mod cost_driver;
mod cost_file;
mod eval;
mod tradeoff;
