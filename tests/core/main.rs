//! The engine's CPU layers: mesh loading and generators, the characterization, the structures and their
//! agreement, the failure study, and the source tree's layering.
//!
//! One binary for the layer (each module was its own test binary, linked once per file).
#[path = "../common/mod.rs"]
mod common;
#[path = "../../src/characterize/tests/exact.rs"]
mod exact;
#[path = "../gpu_support/mod.rs"]
mod gpu_support;

mod accel;
mod agreement;
mod characterize_cpu;
mod failure_study;
mod families;
mod fuzz_seeds;
mod layers;
mod mesh_load;
mod readme;
