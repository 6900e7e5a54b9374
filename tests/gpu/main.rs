//! The Vulkan device paths, each against the CPU reference, with the validation layer on (lavapipe in CI).
//!
//! One binary for the layer (each module was its own test binary, linked once per file).
#[path = "../common/mod.rs"]
mod common;
#[path = "../gpu_support/mod.rs"]
mod gpu_support;

mod characterize_vulkan;
mod gpu_context;
mod gpu_driver;
mod gpu_features;
mod gpu_grid;
mod gpu_lbvh;
mod gpu_pipeline_cache;
mod gpu_recording;
mod gpu_trace;
