//! meshchar: surface-mesh characterization of static and animated scenes for ray tracing, on Vulkan compute.
#![deny(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod accel;
pub mod eval;
pub mod keys;
pub mod mesh;
pub mod trace;
