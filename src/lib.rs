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
pub(crate) mod keys;
pub mod mesh;
pub mod rng;
pub mod select;
pub(crate) mod stats;
#[cfg(feature = "eval")]
pub mod trace;

/// Runs `f` inside rayon's global pool: as one job when called from a thread outside the pool (a command-line
/// tool's main thread, an engine's render thread), so that a builder's or the characterization's many parallel steps
/// start on the pool's own threads instead of each being handed over from the caller's thread and waited for; inside
/// the pool, in place. On one thread, the LBVH against `obvhs`'s PLOC went from 0.69-1.14x to 0.94-1.41x with it
/// (`RAYON_NUM_THREADS=1 cargo bench --bench accel -- side_by_side`, 2-core VM). The result is the same either way.
pub(crate) fn in_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}

/// `crate::push_layout!` for the generated shader mirrors (`gpu/generated/shaders.rs`).
pub(crate) use gpu::shaders::push_layout;
