//! The Vulkan compute engine: a device (owned, or borrowed from a host engine), buffers through gpu-allocator,
//! compute kernels built from reflected SPIR-V, command recording with timestamps.
//!
//! ```no_run
//! use meshchar::gpu::{Context, ContextDesc};
//! let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() })?;
//! println!("running on {} (subgroup size {})", ctx.caps().name, ctx.caps().subgroup_size);
//! # Ok::<(), meshchar::gpu::GpuError>(())
//! ```
//!
//! Limits are queried from the device, never assumed: [`DeviceCaps`] carries the subgroup size, workgroup limits and
//! buffer limits, and kernels are specialized for them at pipeline creation. Large arrays are addressed through
//! buffer device addresses, so no work is limited by `maxStorageBufferRange`.

mod adapter;
mod bounds;
mod buffer;
mod context;
mod geometry;
mod instance;
mod kernel;
mod mesh;
mod pipeline_cache;
mod record;
// The reflection of every shader is data: not every field, constant or checker is read by the library itself.
#[allow(dead_code)]
pub(crate) mod shaders;
pub mod sort;
mod submit;
#[cfg(test)]
pub(crate) mod testing;
#[cfg(test)]
mod tests;

pub use adapter::{
    enumerate_devices, ray_tracing_device_extensions, ray_tracing_device_features, required_device_extensions,
    required_device_features, DeviceCaps, DeviceSummary, DeviceType,
};
pub use bounds::PointBounds;
pub use buffer::{Buffer, MemoryKind};
pub use context::{Context, ContextDesc, RawDevice};
pub(crate) use geometry::geometry_push;
pub use geometry::{GeometryView, IndexType, Indices, Vertices};
pub(crate) use kernel::{Kernel, KernelDesc};
pub(crate) use mesh::bounds_read_back;
pub(crate) use mesh::KeysPush;
pub use mesh::{InputError, MeshBuffers, RunError};
pub(crate) use record::CompletionFlag;
pub use record::{Pass, Recorder, Timer};

use ash::vk;

/// Errors of the Vulkan engine.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// The Vulkan loader (`libvulkan.so.1`) could not be loaded.
    #[error("cannot load the Vulkan loader: {0} (install libvulkan1 and a driver such as mesa-vulkan-drivers)")]
    Loader(String),
    /// No physical device was found.
    #[error("no Vulkan device found (install a driver; for a CPU device: mesa-vulkan-drivers, lavapipe)")]
    NoDevice,
    /// `MESHCHAR_DEVICE` names no device.
    #[error("MESHCHAR_DEVICE={0:?} matches no device; available: {1}")]
    DeviceNotFound(String, String),
    /// The device lacks what the engine needs.
    #[error("device {name} cannot run meshchar; missing: {}", missing.join(", "))]
    Unsupported {
        /// Device name.
        name: String,
        /// Every missing version, feature, extension or property.
        missing: Vec<String>,
    },
    /// The validation layer was asked for but is not installed.
    #[error("the Khronos validation layer VK_LAYER_KHRONOS_validation is not installed (apt install vulkan-validationlayers)")]
    NoValidationLayer,
    /// A Vulkan call failed.
    #[error("{call} failed: {result}")]
    Vk {
        /// The Vulkan function.
        call: &'static str,
        /// Its result code.
        result: vk::Result,
    },
    /// Memory allocation failed.
    #[error("memory allocation of {bytes} bytes ({name}) failed: {source}")]
    Alloc {
        /// Buffer name.
        name: String,
        /// Requested size.
        bytes: u64,
        /// The allocator's error.
        #[source]
        source: gpu_allocator::AllocationError,
    },
    /// A request exceeds a device limit.
    #[error("{what}: {requested} exceeds the device limit {limit}")]
    Limit {
        /// What was requested.
        what: String,
        /// The amount.
        requested: u64,
        /// The device's limit.
        limit: u64,
    },
    /// A push-constant struct does not match its shader's block.
    #[error("push-constant layout mismatch: {0}")]
    Layout(String),
    /// The results of a recorded operation were asked for before its command buffer completed (or was submitted).
    #[error("{0}: the recorded work has not completed (submit the command buffer and wait for its fence first)")]
    NotReady(String),
    /// A buffer access outside its size, or a wrong kind of buffer.
    #[error("buffer misuse: {0}")]
    Buffer(String),
    /// The pipeline-cache file could not be written ([`Context::save_pipeline_cache`]).
    #[error("cannot write the pipeline cache {}: {source}", path.display())]
    PipelineCache {
        /// The file.
        path: std::path::PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

/// Result alias of this module.
pub type Result<T, E = GpuError> = std::result::Result<T, E>;

/// Maps a `VkResult` to [`GpuError::Vk`] naming the call.
pub(crate) fn vk_check<T>(call: &'static str, r: std::result::Result<T, vk::Result>) -> Result<T> {
    r.map_err(|result| GpuError::Vk { call, result })
}
