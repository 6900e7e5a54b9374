//! meshchar: surface-mesh characterization of static and animated scenes for ray tracing, on Vulkan compute.
//!
//! The crate implements the method of Olivares' thesis *Surface Mesh Characterization of Dynamic Scenes for Ray
//! Tracing in Real-time* as explicit Vulkan compute pipelines with CPU references beside them: centroid keys, Morton
//! codes, moments, Doane's number of equivalence classes, a histogram of classes, a chi-square uniformity test,
//! concentration and empty classes; then the selection of an acceleration structure.
//!
//! The main job, on the host: characterize a mesh, then ask which structure gives the lowest total time for a
//! camera and a workload, the decision's own cost counted, and why.
//!
//! ```
//! use meshchar::characterize::{cpu, features_cpu, Params};
//! use meshchar::cost::CostModel;
//! use meshchar::select::{Scene, Selector, TargetWorkload};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let mesh = meshchar::mesh::default_teapot(); // or meshchar::mesh::load_mesh(Path::new("bunny.ply"))?
//! let params = Params::default();
//! let characterizations = [cpu::fast(&mesh, &params)?];
//! let features = [features_cpu(&mesh, &params)?];
//!
//! let model = CostModel::shipped()?; // the calibration file fitted on this project's CPU records
//! let workload = TargetWorkload { frames: 100, ..TargetWorkload::default() }; // 1024 x 1024 primary rays
//! let selector = Selector::new(&model, workload);
//! let meshes = std::slice::from_ref(&mesh); // lets the selector build probes when they pay
//! let scene = Scene { name: "teapot", characterizations: &characterizations, features: &features, meshes };
//! let decision = selector.select(&scene);
//!
//! println!("{} (decided at level {})", decision.structure(), decision.level.number());
//! for reason in &decision.selection.reasons {
//!     println!("  {reason}");
//! }
//! assert!(!decision.selection.reasons.is_empty());
//! # Ok(())
//! # }
//! ```
//!
//! In an engine, on its device, inside its frame (the same calls as `examples/engine_frame.rs`, one mesh):
//!
//! ```no_run
//! # use meshchar::ash::{self, vk};
//! use meshchar::accel::{gpu::BvhBuilder, lbvh::LbvhOptions};
//! use meshchar::characterize::{plan::Plan, vulkan::VulkanBackend, Params};
//! use meshchar::cost::CostModel;
//! use meshchar::gpu::{Context, GeometryView, IndexType, RawDevice, Recorder};
//! use meshchar::select::{Scene, Selector, Structure, TargetWorkload};
//! # #[allow(clippy::too_many_arguments)]
//! # fn frame(instance: ash::Instance, device: ash::Device, physical_device: vk::PhysicalDevice, queue_family: u32,
//! #     cmd: vk::CommandBuffer, mesh: &meshchar::mesh::Mesh, vertices: u64, indices: u64, vertex_count: u64,
//! #     triangles: u64, slot: usize) -> Result<(), Box<dyn std::error::Error>> {
//!
//! // At load: the engine's device (created with gpu::required_device_features), handed over, never destroyed.
//! let ctx = unsafe { Context::from_raw(RawDevice::new(instance, device, physical_device, queue_family, 0)) }?;
//! let params = Params::default();
//! let mut backend = VulkanBackend::with_slots(&ctx, 2)?; // one slot per frame in flight
//! let mut builder = BvhBuilder::new(&ctx)?;
//! let model = CostModel::shipped()?; // or the file `calibrate` wrote on this device
//! let mut plan = Plan::exact(&mesh, &params, backend.max_classes())?; // from the host copy, once
//!
//! // Each frame: the engine's own vertex (32-byte stride) and index buffers, its own command buffer, begun.
//! let view = unsafe {
//!     GeometryView::from_addresses(vertices, 32, vertex_count, Some((indices, IndexType::U32, 0)), triangles)
//! }?;
//! let mut rec = unsafe { Recorder::new(&ctx, cmd) };
//! backend.record_planned(&mut rec, slot, &view, "mesh", &params, &plan, true)?; // characterization + features
//! let mut bvh = builder.record_lbvh(&mut rec, &view, &plan.quantizer(), &LbvhOptions::default())?;
//! // ... the engine ends `cmd`, submits it, and (a frame or more later) sees its fence signalled ...
//!
//! let (planned, features) = backend.finish_planned(slot)?;
//! bvh.finish()?; // the tree is ready on the device for the engine's trace
//! plan = Plan::after(&planned.report, &params, backend.max_classes())?; // the next frame's plan
//! let mut selector = Selector::new(&model, TargetWorkload::default()); // 1024 x 1024 primary rays
//! selector.structures = vec![Structure::Lbvh, Structure::Hlbvh]; // what this engine builds on its device
//! let (reports, features) = ([planned.report], [features.ok_or("recorded with features")?]);
//! let scene = Scene { name: "mesh", characterizations: &reports, features: &features, meshes: &[] };
//! let decision = selector.select(&scene); // level 0: microseconds on the host, no wait
//! println!("{}: {}", decision.structure(), decision.selection.explain());
//! # Ok(())
//! # }
//! ```
#![deny(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

/// The `ash` crate meshchar is built on (0.38): an engine hands its device over as these types
/// ([`gpu::Context::from_raw`]), so it uses this re-export, or the same `ash` version, to make them.
pub use ash;

// The crate's own tests of its internals (`eval/tests/`) name it as a user does.
#[cfg(test)]
extern crate self as meshchar;

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
