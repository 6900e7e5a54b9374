//! meshchar: surface-mesh characterization of static and animated scenes for ray tracing, on Vulkan compute.
//!
//! The crate implements the method of Olivares' thesis *Surface Mesh Characterization of Dynamic Scenes for Ray
//! Tracing in Real-time* as explicit Vulkan compute pipelines with CPU references beside them: centroid keys, Morton
//! codes, moments, Doane's number of equivalence classes, a histogram of classes, a chi-square uniformity test,
//! concentration and empty classes; then the selection of an acceleration structure.
#![deny(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod accel;
pub mod characterize;
pub mod cost;
#[cfg(feature = "eval")]
pub mod eval;
pub mod geom;
pub mod gpu;
pub mod keys;
pub mod mesh;
pub mod rng;
pub mod select;
pub mod stats;
#[cfg(feature = "eval")]
pub mod trace;
