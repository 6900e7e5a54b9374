//! meshchar inside an engine's frame: an engine as its author writes it, with its own Vulkan instance (validation
//! layer on, with its own debug messenger counting warnings and errors), device, queue and gpu-allocator
//! allocator, and meshchar only through [`Context::from_raw`].
//!
//! `cargo run --release --example engine_frame -- [--frames N] [--mode pipelined|staged] [--check] [--json]
//! [--png PATH] [--mesh FILE] [--ray-query auto|on|off]` (`--help` explains each).
//!
//! The scene is one interleaved vertex buffer (position, normal, uv: 32 bytes a vertex) and one index buffer holding
//! two meshes at offsets: the embedded Utah teapot as a triangle soup with 16-bit indices, exploding (its triangles
//! fly apart along their normals, as `meshchar::mesh::generate::explode`), and a larger mesh with 32-bit indices and
//! a base vertex (the embedded bunny, subdivided; or `--mesh`), turning rigidly about a tilted axis. The engine's
//! own compute kernel (`examples/shaders/engine_animate.comp`, its pipeline made here with ash) animates both from a rest copy.
//!
//! Each frame is ONE command buffer (two frames in flight, a fence each): the animation, a barrier, the planned
//! characterization and scene features of each mesh (a `VulkanBackend` per mesh with one slot per frame in
//! flight; the plan from the latest report read back, `Plan::after`; the first frame's from a staged
//! characterization of the rest pose before the loop), then, per mesh, an LBVH rebuild (`record_lbvh` with the
//! plan's quantizer) or a refit (`record_refit`), as the calibrated policy's per-frame rule (`FrameRule`, the step
//! of `plan_frames`, restricted to the LBVH the engine builds) says from the latest features read back. Waiting for
//! frame t-2's fence before reusing its resources is the engine's frame pacing; inside a frame nothing waits, which
//! the example counts with `Context::host_waits`. `--mode staged` runs the staged characterization instead (the
//! animation submitted and waited for, the positions read back, `characterize_with_features` with its own host
//! waits), for comparison. `--check` copies each frame's animated positions to a host-visible buffer inside the
//! frame's command buffer and, once the frame's fence has been observed, compares every report with the CPU
//! reference (`meshchar::characterize::plan::reference`) on those positions.
//!
//! When the device has `VK_KHR_acceleration_structure` and `VK_KHR_ray_query` (`--ray-query auto`, the default, or
//! `on`) and the cost model calibrated the driver's `rt_update`, the engine enables them and each mesh's per-frame
//! decision is among the LBVH (rebuild or refit) and the driver's updatable structure (rebuild, or a `MODE_UPDATE`
//! update, as `DriverFrameRule` says from the drift since its build), whichever the model predicts cheaper for the
//! frame's rays; the frame line names each mesh's `structure`. With `--png` the last frame's picture is then traced
//! by ray queries through each mesh's driver structure (one built with PREFER_FAST_TRACE where the mesh runs on its
//! LBVH), and the count of pixels that hit the CPU reference's triangle is printed.

use anyhow::{anyhow, bail, ensure, Context as _, Result};
use ash::vk;
use clap::Parser;
use cli::args::{JsonArg, TieMarginArg, WorkloadArgs};
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc};
use gpu_allocator::MemoryLocation;
use meshchar::accel::bvh::Bvh;
use meshchar::accel::device_trace::{TraceHit, TraceRay};
use meshchar::accel::driver::{DriverBuilder, DriverFlags, DriverStructure};
use meshchar::accel::gpu::{BvhBuilder, GpuBvh};
use meshchar::accel::lbvh::LbvhOptions;
use meshchar::accel::{AccelStructure, StructureName};
use meshchar::characterize::plan::{reference, Plan};
use meshchar::characterize::vulkan::VulkanBackend;
use meshchar::characterize::{Characterization, Features, Params, PassTime};
use meshchar::characterize::{KeyBounds, Quantizer};
use meshchar::cost::CostModel;
use meshchar::gpu::{Context, GeometryView, IndexType, RawDevice, Recorder};
use meshchar::mesh::{generate, Mesh};
use meshchar::select::{DriverAction, DriverFrameRule, FrameAction, FrameRule};
use serde_json::json;
use std::ffi::{c_void, CStr};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

#[path = "support/cli.rs"]
mod cli;

/// An engine's frame with meshchar inside: its own Vulkan instance, device, queue and allocator; two animated
/// meshes in one interleaved vertex buffer and one index buffer; per frame one command buffer with the animation,
/// the planned characterization and features of each mesh and an LBVH rebuild or refit as the calibrated rule
/// says; no host wait inside a frame.
///
/// Prints one row per frame (with --json one JSON object per frame: frame, mode, triangles, characterize_ms,
/// build_ms and/or refit_ms, decision, host_waits, engine_waits, validation_messages, reference_equal with
/// --check, animate_ms, record_ms, and per mesh the same in "meshes"), then a summary (with --json an object with
/// "summary": true). A frame's "decision" is "rebuild" when it rebuilt any mesh's tree, else "refit"; its
/// build_ms and refit_ms add up the meshes rebuilt and refitted. host_waits counts meshchar's own host waits
/// inside the frame (Context::host_waits), engine_waits the engine's (only --mode staged has any);
/// validation_messages counts the validation layer's warnings and errors since the previous row (the first row
/// includes the setup's). Exits 1 when a frame waited in pipelined mode, when the validation layer reported
/// anything, or, with --check, when a report differs from the reference.
#[derive(Parser, Debug)]
#[command(name = "engine_frame", args_override_self = true)]
#[command(mut_arg("json", |a| a.help("One JSON object per frame, then a summary object, instead of the table")))]
struct Args {
    /// Frames to run
    #[arg(long, value_name = "N", default_value_t = 60, value_parser = cli::args::positive_max(1_000_000))]
    frames: usize,
    /// How each frame characterizes its meshes
    #[arg(long, value_enum, value_name = "M", default_value_t = Mode::Pipelined)]
    mode: Mode,
    /// Copy each frame's animated positions to the host inside its command buffer and compare every report with
    /// the CPU reference on them (reference_equal)
    #[arg(long)]
    check: bool,
    /// The turning mesh (OBJ or PLY, 32-bit indices) [default: the embedded bunny, subdivided --subdivide times]
    #[arg(long, value_name = "FILE")]
    mesh: Option<PathBuf>,
    /// Subdivisions of the embedded bunny (each multiplies its 3,674 triangles by 4)
    #[arg(long, value_name = "L", default_value_t = 1, value_parser = clap::value_parser!(u32).range(0..=4))]
    subdivide: u32,
    /// Write a PNG of the last frame: both meshes, read back, ray traced from the automatic camera with every
    /// triangle in the colour of its class (the teapot's classes first, then the other mesh's) [default: none]
    #[arg(long, value_name = "PATH")]
    png: Option<PathBuf>,
    /// Create the engine's instance without the Khronos validation layer
    #[arg(long)]
    no_validation: bool,
    /// Calibration file of the per-frame rule [default: the shipped one; with ray queries, the one chosen for the
    /// device, whose driver structures it weighs]
    #[arg(long, value_name = "FILE")]
    cost_model: Option<PathBuf>,
    /// The driver's acceleration structures (VK_KHR_acceleration_structure, traced with ray queries): auto uses
    /// them when the device has them, on requires them, off never creates the device with them
    #[arg(long, value_enum, value_name = "R", default_value_t = RayQuery::Auto)]
    ray_query: RayQuery,
    /// The structures each mesh's per-frame decision weighs: auto the LBVH and (with ray queries) the driver's
    /// rt_update, whichever the cost model predicts cheaper; lbvh or rt_update only that one (rt_update needs ray
    /// queries and a cost model that calibrated it)
    #[arg(long, value_enum, value_name = "S", default_value_t = Candidates::Auto)]
    structure: Candidates,
    #[command(flatten)]
    workload: WorkloadArgs,
    /// With --workload shadow or diffuse: the rays one frame traces, when known [default: estimated from a sample
    /// of at most 128 x 128 of the primary rays of a camera framing the rest poses]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64))]
    secondary_rays: Option<u64>,
    #[command(flatten)]
    tie_margin: TieMarginArg,
    #[command(flatten)]
    json: JsonArg,
}

/// `--mode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Mode {
    /// Record the planned characterization into the frame's command buffer: no host wait inside a frame
    Pipelined,
    /// Submit the animation and wait for it, read the positions back and run the staged characterization (its
    /// own submissions and waits), then record the rebuilds and refits
    Staged,
}

/// `--structure`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Candidates {
    /// The cheaper per the cost model
    Auto,
    /// The project's LBVH (rebuild or refit)
    Lbvh,
    /// The driver's updatable structure (rebuild or update)
    #[value(name = "rt_update")]
    RtUpdate,
}

/// `--ray-query`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum RayQuery {
    /// When the device has the extensions and features
    Auto,
    /// Required: fail without them
    On,
    /// Never
    Off,
}

impl Mode {
    fn as_str(self) -> &'static str {
        match self {
            Mode::Pipelined => "pipelined",
            Mode::Staged => "staged",
        }
    }
}

fn main() -> ExitCode {
    cli::main_with(run)
}

/// Frames in flight.
const FRAMES_IN_FLIGHT: usize = 2;
/// Bytes per interleaved vertex: position (12), normal (12), uv (8).
const STRIDE: u32 = 32;
/// Floats per vertex.
const VERTEX_FLOATS: usize = (STRIDE / 4) as usize;
/// Side of the `--png` picture's render area.
const PNG_RESOLUTION: u32 = 512;

// ------------------------------------------------------------------------------------------------------------------
// The engine: instance, device, queue, allocator, and every object it creates.
// ------------------------------------------------------------------------------------------------------------------

/// What the engine's debug messenger counts: every warning and error of the validation layer.
#[derive(Default)]
struct MessageSink {
    count: AtomicU64,
}

/// Messages printed to standard error (the rest are only counted).
const SHOWN_MESSAGES: u64 = 20;

unsafe extern "system" fn on_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _kind: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    use std::io::Write as _;
    // SAFETY: `user` is the engine's MessageSink, kept alive (by `Instance::_sink`) until after vkDestroyInstance;
    // `data` is valid for the duration of the callback, as the layer guarantees.
    let (sink, text) = unsafe {
        let text = data
            .as_ref()
            .and_then(|d| d.message_as_c_str())
            .map(|m| m.to_string_lossy().into_owned())
            .unwrap_or_default();
        (&*(user as *const MessageSink), text)
    };
    let counted = vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR;
    if severity.intersects(counted) && sink.count.fetch_add(1, Ordering::Relaxed) < SHOWN_MESSAGES {
        let _ = writeln!(std::io::stderr(), "engine_frame: validation {severity:?}: {text}");
    }
    vk::FALSE
}

/// The engine's instance and debug messenger; destroyed in that order, the sink freed after.
struct Instance {
    _entry: ash::Entry,
    instance: ash::Instance,
    messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    _sink: Arc<MessageSink>,
}

impl Drop for Instance {
    fn drop(&mut self) {
        // SAFETY: the device and everything made from it are gone (Engine destroys them first); each object is
        // destroyed once, the messenger before its instance.
        unsafe {
            if let Some((du, m)) = self.messenger.take() {
                du.destroy_debug_utils_messenger(m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

impl Instance {
    fn new(validation: bool, sink: Arc<MessageSink>) -> Result<Instance> {
        // SAFETY: loads the system Vulkan loader; ash checks the symbols it resolves.
        let entry = unsafe { ash::Entry::load() }.context("cannot load the Vulkan loader")?;
        if validation {
            // SAFETY: a plain query of the loader.
            let layers = unsafe { entry.enumerate_instance_layer_properties() }.context("instance layers")?;
            let found = layers.iter().any(|l| l.layer_name_as_c_str().is_ok_and(|n| n == VALIDATION_LAYER));
            ensure!(found, "the Khronos validation layer is not installed (run with --no-validation without it)");
        }
        let app = vk::ApplicationInfo::default()
            .application_name(c"engine_frame")
            .engine_name(c"engine_frame")
            .api_version(vk::API_VERSION_1_2);
        let layers = if validation { vec![VALIDATION_LAYER.as_ptr()] } else { Vec::new() };
        let extensions = if validation { vec![ash::ext::debug_utils::NAME.as_ptr()] } else { Vec::new() };
        let severity = vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR;
        let kinds = vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
            | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
            | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE;
        let user = Arc::as_ptr(&sink) as *mut c_void;
        let mut messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
            .message_severity(severity)
            .message_type(kinds)
            .pfn_user_callback(Some(on_message))
            .user_data(user);
        let mut info = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&extensions);
        if validation {
            // The messenger chained to the instance's creation reports during vkCreateInstance/vkDestroyInstance.
            info = info.push_next(&mut messenger_info);
        }
        // SAFETY: valid create info; the sink the messenger points to outlives the instance (it is a field of the
        // guard, dropped after the instance is destroyed).
        let instance = unsafe { entry.create_instance(&info, None) }.context("vkCreateInstance")?;
        let mut out = Instance { _entry: entry, instance, messenger: None, _sink: sink };
        if validation {
            let du = ash::ext::debug_utils::Instance::new(&out._entry, &out.instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(severity)
                .message_type(kinds)
                .pfn_user_callback(Some(on_message))
                .user_data(user);
            // SAFETY: valid instance with VK_EXT_debug_utils enabled; the sink outlives the messenger.
            let m = unsafe { du.create_debug_utils_messenger(&info, None) }.context("debug messenger")?;
            out.messenger = Some((du, m));
        }
        Ok(out)
    }
}

/// A buffer of the engine: its handle, device address, size and, for host-visible memory, the mapping.
#[derive(Clone, Copy, Debug)]
struct EngineBuffer {
    buffer: vk::Buffer,
    address: u64,
    size: u64,
    mapped: Option<std::ptr::NonNull<u8>>,
    memory: vk::DeviceMemory,
    coherent: bool,
}

/// An object the engine created, destroyed when the engine drops.
enum Owned {
    Buffer(vk::Buffer, Allocation),
    CommandPool(vk::CommandPool),
    Fence(vk::Fence),
    QueryPool(vk::QueryPool),
    Pipeline(vk::Pipeline),
    PipelineLayout(vk::PipelineLayout),
    ShaderModule(vk::ShaderModule),
}

/// The engine's device and everything it created.
struct Engine {
    device: ash::Device,
    physical: vk::PhysicalDevice,
    queue: vk::Queue,
    family: u32,
    device_name: String,
    /// Nanoseconds per timestamp tick.
    timestamp_period: f64,
    /// Valid bits of the queue's timestamps.
    timestamp_mask: u64,
    allocator: Option<Allocator>,
    owned: Vec<Owned>,
    /// The device was created with the ray-tracing extensions and features (`--ray-query`).
    ray_query: bool,
    /// Last field: dropped after [`Engine::drop`] destroyed the device.
    instance: Instance,
}

impl Drop for Engine {
    fn drop(&mut self) {
        // SAFETY: the device is idle after the wait; every object was created on it and is destroyed once, in
        // reverse order of creation, the allocator's memory after the buffers bound to it, the device last.
        unsafe {
            let _ = self.device.device_wait_idle();
            while let Some(o) = self.owned.pop() {
                match o {
                    Owned::Buffer(b, a) => {
                        self.device.destroy_buffer(b, None);
                        if let Some(al) = self.allocator.as_mut() {
                            let _ = al.free(a);
                        }
                    }
                    Owned::CommandPool(p) => self.device.destroy_command_pool(p, None),
                    Owned::Fence(f) => self.device.destroy_fence(f, None),
                    Owned::QueryPool(q) => self.device.destroy_query_pool(q, None),
                    Owned::Pipeline(p) => self.device.destroy_pipeline(p, None),
                    Owned::PipelineLayout(l) => self.device.destroy_pipeline_layout(l, None),
                    Owned::ShaderModule(m) => self.device.destroy_shader_module(m, None),
                }
            }
            drop(self.allocator.take());
            self.device.destroy_device(None);
        }
    }
}

impl Engine {
    /// Picks a device with a compute queue that has timestamps and everything meshchar needs, and creates it with
    /// the features of `meshchar::gpu::required_device_features` and the extensions of
    /// `required_device_extensions`.
    fn new(validation: bool, sink: Arc<MessageSink>, ray_query: RayQuery) -> Result<Engine> {
        let inst = Instance::new(validation, sink)?;
        let instance = &inst.instance;
        // SAFETY: valid instance.
        let pdevs = unsafe { instance.enumerate_physical_devices() }.context("vkEnumeratePhysicalDevices")?;
        let wanted = std::env::var("MESHCHAR_DEVICE").ok();
        let mut chosen = None;
        for (i, &p) in pdevs.iter().enumerate() {
            // SAFETY: valid physical device of the instance.
            let (props, families) = unsafe {
                (instance.get_physical_device_properties(p), instance.get_physical_device_queue_family_properties(p))
            };
            let name = props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            if let Some(w) = &wanted {
                if w.parse::<usize>().ok() != Some(i) && !name.to_lowercase().contains(&w.to_lowercase()) {
                    continue;
                }
            }
            let family = families.iter().position(|f| {
                f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.timestamp_valid_bits > 0 && f.queue_count > 0
            });
            let v = props.api_version;
            if let (Some(f), true) = (family, (vk::api_version_major(v), vk::api_version_minor(v)) >= (1, 2)) {
                chosen = Some((p, f as u32, name, props.limits.timestamp_period, families[f].timestamp_valid_bits));
                break;
            }
        }
        let (physical, family, device_name, period, bits) =
            chosen.ok_or_else(|| anyhow!("no Vulkan 1.2 device with a compute queue that has timestamps"))?;
        let priorities = [1.0f32];
        let queues = [vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(&priorities)];
        let mut core = vk::PhysicalDeviceFeatures::default();
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
        let needed = meshchar::gpu::required_device_features(&mut core, &mut v12);
        // SAFETY: valid physical device.
        let has = unsafe {
            let mut has12 = vk::PhysicalDeviceVulkan12Features::default();
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut has12);
            instance.get_physical_device_features2(physical, &mut f2);
            let core_has = f2.features;
            [core_has.shader_int64, has12.buffer_device_address, has12.shader_buffer_int64_atomics]
        };
        ensure!(has.iter().all(|&f| f == vk::TRUE), "{device_name} lacks one of {needed:?}");
        // The driver's ray tracing for compute, when wanted and there: its extensions and features beside the
        // required ones.
        let rt_names = meshchar::gpu::ray_tracing_device_extensions();
        // SAFETY: valid physical device.
        let rt_has = unsafe {
            let exts = instance.enumerate_device_extension_properties(physical).context("device extensions")?;
            let mut f_as = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
            let mut f_rq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f_as).push_next(&mut f_rq);
            instance.get_physical_device_features2(physical, &mut f2);
            rt_names.iter().all(|n| exts.iter().any(|e| e.extension_name_as_c_str().is_ok_and(|x| x == *n)))
                && f_as.acceleration_structure == vk::TRUE
                && f_rq.ray_query == vk::TRUE
        };
        let rt = match ray_query {
            RayQuery::Off => false,
            RayQuery::Auto => rt_has,
            RayQuery::On => {
                ensure!(
                    rt_has,
                    "--ray-query on: {device_name} lacks VK_KHR_acceleration_structure or VK_KHR_ray_query (or their \
                     features); lavapipe has them from Mesa 24.1"
                );
                true
            }
        };
        let mut f_as = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
        let mut f_rq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
        meshchar::gpu::ray_tracing_device_features(&mut f_as, &mut f_rq);
        let mut f2 = vk::PhysicalDeviceFeatures2::default().features(core).push_next(&mut v12);
        if rt {
            f2 = f2.push_next(&mut f_as).push_next(&mut f_rq);
        }
        let mut extensions: Vec<*const std::ffi::c_char> =
            meshchar::gpu::required_device_extensions().iter().map(|e| e.as_ptr()).collect();
        if rt {
            extensions.extend(rt_names.iter().map(|e| e.as_ptr()));
        }
        let info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_extension_names(&extensions)
            .push_next(&mut f2);
        // SAFETY: the physical device has every enabled feature (checked above) and the extensions meshchar names.
        let device = unsafe { instance.create_device(physical, &info, None) }.context("vkCreateDevice")?;
        // SAFETY: queue 0 of a family the device was created with.
        let queue = unsafe { device.get_device_queue(family, 0) };
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings: Default::default(),
            buffer_device_address: true,
            allocation_sizes: Default::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: nothing was created on the device yet.
                unsafe { device.destroy_device(None) };
                return Err(e).context("gpu-allocator");
            }
        };
        Ok(Engine {
            device,
            physical,
            queue,
            family,
            device_name,
            timestamp_period: f64::from(period),
            timestamp_mask: if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 },
            allocator: Some(allocator),
            owned: Vec::new(),
            ray_query: rt,
            instance: inst,
        })
    }

    fn allocator(&mut self) -> Result<&mut Allocator> {
        self.allocator.as_mut().ok_or_else(|| anyhow!("the allocator is gone"))
    }

    /// A buffer with a device address, bound to memory from the engine's allocator at `location`.
    fn create_buffer(
        &mut self,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> Result<EngineBuffer> {
        let info = vk::BufferCreateInfo::default()
            .size(size.max(4))
            .usage(usage | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info.
        let buffer = unsafe { self.device.create_buffer(&info, None) }.with_context(|| format!("buffer {name}"))?;
        // SAFETY: a buffer of this device.
        let requirements = unsafe { self.device.get_buffer_memory_requirements(buffer) };
        let desc = AllocationCreateDesc {
            name,
            requirements,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        };
        let allocation = match self.allocator()?.allocate(&desc) {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: the buffer is not in use and bound to nothing.
                unsafe { self.device.destroy_buffer(buffer, None) };
                return Err(e).with_context(|| format!("memory of buffer {name} ({size} bytes)"));
            }
        };
        // SAFETY: the memory handle is only bound to this buffer and used for flushes and invalidations of its
        // mapping; the allocation (which owns it) stays alive until the engine drops, after the buffer.
        let (memory, offset) = (unsafe { allocation.memory() }, allocation.offset());
        let mapped = allocation.mapped_ptr().map(|p| p.cast::<u8>());
        let coherent = allocation.memory_properties().contains(vk::MemoryPropertyFlags::HOST_COHERENT);
        self.owned.push(Owned::Buffer(buffer, allocation));
        // SAFETY: fresh buffer and memory of this device that fits its requirements (the allocator's job).
        unsafe { self.device.bind_buffer_memory(buffer, memory, offset) }.context("vkBindBufferMemory")?;
        // SAFETY: the buffer has SHADER_DEVICE_ADDRESS usage and bound memory; the feature is enabled.
        let address =
            unsafe { self.device.get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(buffer)) };
        Ok(EngineBuffer { buffer, address, size, mapped, memory, coherent })
    }

    /// Makes the device's writes to `b` visible to the host (non-coherent memory only; after its fence).
    fn invalidate(&self, b: &EngineBuffer) -> Result<()> {
        if !b.coherent {
            let range = [vk::MappedMemoryRange::default().memory(b.memory).offset(0).size(vk::WHOLE_SIZE)];
            // SAFETY: the memory is mapped by the allocator; the whole object is a valid range.
            unsafe { self.device.invalidate_mapped_memory_ranges(&range) }.context("invalidate")?;
        }
        Ok(())
    }

    /// Makes the host's writes to `b` visible to the device (non-coherent memory only).
    fn flush(&self, b: &EngineBuffer) -> Result<()> {
        if !b.coherent {
            let range = [vk::MappedMemoryRange::default().memory(b.memory).offset(0).size(vk::WHOLE_SIZE)];
            // SAFETY: the memory is mapped by the allocator; the whole object is a valid range.
            unsafe { self.device.flush_mapped_memory_ranges(&range) }.context("flush")?;
        }
        Ok(())
    }

    /// The host copy of `b`'s bytes (a host-visible buffer, after the device's last write to it was observed).
    fn read_mapped(&self, b: &EngineBuffer) -> Result<&[u8]> {
        self.invalidate(b)?;
        let p = b.mapped.ok_or_else(|| anyhow!("buffer is not host-visible"))?;
        // SAFETY: the allocator keeps the mapping of `b.size` bytes alive while the engine lives; the caller has
        // observed the fence of the last device write, and nothing writes while the slice is borrowed.
        Ok(unsafe { std::slice::from_raw_parts(p.as_ptr(), b.size as usize) })
    }

    fn command_pool(&mut self) -> Result<vk::CommandPool> {
        let info = vk::CommandPoolCreateInfo::default().queue_family_index(self.family);
        // SAFETY: valid device.
        let pool = unsafe { self.device.create_command_pool(&info, None) }.context("vkCreateCommandPool")?;
        self.owned.push(Owned::CommandPool(pool));
        Ok(pool)
    }

    fn command_buffers(&self, pool: vk::CommandPool, n: u32) -> Result<Vec<vk::CommandBuffer>> {
        let info = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(n);
        // SAFETY: a pool of this device, used by this thread only.
        unsafe { self.device.allocate_command_buffers(&info) }.context("vkAllocateCommandBuffers")
    }

    fn fence(&mut self, signaled: bool) -> Result<vk::Fence> {
        let flags = if signaled { vk::FenceCreateFlags::SIGNALED } else { vk::FenceCreateFlags::empty() };
        // SAFETY: valid device.
        let f = unsafe { self.device.create_fence(&vk::FenceCreateInfo::default().flags(flags), None) }
            .context("vkCreateFence")?;
        self.owned.push(Owned::Fence(f));
        Ok(f)
    }

    fn query_pool(&mut self, n: u32) -> Result<vk::QueryPool> {
        let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(n);
        // SAFETY: valid device.
        let q = unsafe { self.device.create_query_pool(&info, None) }.context("vkCreateQueryPool")?;
        self.owned.push(Owned::QueryPool(q));
        Ok(q)
    }

    /// Submits `cmd` signalling `fence`.
    fn submit(&self, cmd: vk::CommandBuffer, fence: vk::Fence) -> Result<()> {
        let cmds = [cmd];
        let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
        // SAFETY: the queue is used by this thread only (meshchar's convenience paths submit to it from the same
        // thread, never concurrently); `cmd` is executable and `fence` unsignalled.
        unsafe { self.device.queue_submit(self.queue, &submit, fence) }.context("vkQueueSubmit")
    }

    /// Waits for `fence` and resets it.
    fn wait_and_reset(&self, fence: vk::Fence) -> Result<()> {
        // SAFETY: a fence of this device, signalled or pending.
        unsafe {
            self.device.wait_for_fences(&[fence], true, u64::MAX).context("vkWaitForFences")?;
            self.device.reset_fences(&[fence]).context("vkResetFences")
        }
    }

    /// Begins `cmd` (its pool reset or fresh) for one submission.
    fn begin(&self, cmd: vk::CommandBuffer) -> Result<()> {
        let info = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: `cmd` is in the initial state (fresh, or its pool reset after its last submission completed).
        unsafe { self.device.begin_command_buffer(cmd, &info) }.context("vkBeginCommandBuffer")
    }

    fn end(&self, cmd: vk::CommandBuffer) -> Result<()> {
        // SAFETY: `cmd` is recording.
        unsafe { self.device.end_command_buffer(cmd) }.context("vkEndCommandBuffer")
    }

    /// A global memory barrier in `cmd` from `src` stages' `src_access` to `dst` stages' `dst_access`.
    fn barrier(
        &self,
        cmd: vk::CommandBuffer,
        (src, src_access): (vk::PipelineStageFlags, vk::AccessFlags),
        (dst, dst_access): (vk::PipelineStageFlags, vk::AccessFlags),
    ) {
        let mb = [vk::MemoryBarrier::default().src_access_mask(src_access).dst_access_mask(dst_access)];
        // SAFETY: `cmd` is recording.
        unsafe { self.device.cmd_pipeline_barrier(cmd, src, dst, vk::DependencyFlags::empty(), &mb, &[], &[]) };
    }

    /// The frame's first command: every earlier command in submission order (the frames before, which read and
    /// write the vertex buffer and meshchar's scratch) completes, and its writes are visible, before the rest.
    fn frame_start_barrier(&self, cmd: vk::CommandBuffer) {
        let mut stages = vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER;
        let mut writes = vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE;
        let mut reads = vk::AccessFlags::SHADER_READ | vk::AccessFlags::TRANSFER_READ;
        if self.ray_query {
            // The frames before may still build, update or trace driver structures this frame updates.
            stages |= vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR;
            writes |= vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR;
            reads |= vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR;
        }
        self.barrier(cmd, (stages, writes), (stages, writes | reads));
    }

    fn timestamp(&self, cmd: vk::CommandBuffer, pool: vk::QueryPool, q: u32) {
        // SAFETY: `cmd` is recording; the query was reset earlier in this submission's frame.
        unsafe { self.device.cmd_write_timestamp(cmd, vk::PipelineStageFlags::BOTTOM_OF_PIPE, pool, q) };
    }

    /// Milliseconds between consecutive timestamps `0 ..= n - 1` of `pool` (after the fence of the command buffers
    /// that wrote them was observed).
    fn read_timestamps(&self, pool: vk::QueryPool, n: usize) -> Result<Vec<f64>> {
        let mut ticks = vec![0u64; n];
        // SAFETY: the queries were reset and written by command buffers whose fence was observed; without WAIT an
        // unavailable query gives VK_NOT_READY.
        unsafe { self.device.get_query_pool_results(pool, 0, &mut ticks, vk::QueryResultFlags::TYPE_64) }
            .context("timestamps not available after the frame's fence")?;
        let m = self.timestamp_mask;
        Ok(ticks
            .windows(2)
            .map(|w| ((w[1] & m).wrapping_sub(w[0] & m) & m) as f64 * self.timestamp_period * 1e-6)
            .collect())
    }
}

// ------------------------------------------------------------------------------------------------------------------
// The scene: two meshes in one vertex buffer and one index buffer, and the engine's animation kernel.
// ------------------------------------------------------------------------------------------------------------------

/// How a mesh moves.
#[derive(Clone, Copy, Debug)]
enum Motion {
    /// Triangles fly apart along their rest normals (`examples/shaders/engine_animate.comp`, mode 1).
    Explode { speed: f32, seed: u32 },
    /// Rigid rotation about `axis` through `center`, `angle` radians a frame (mode 0).
    Rotate { axis: [f32; 3], center: [f32; 3], angle: f32 },
}

impl Motion {
    fn as_str(&self) -> &'static str {
        match self {
            Motion::Explode { .. } => "explode",
            Motion::Rotate { .. } => "rotate",
        }
    }
}

/// One mesh of the scene: its rest pose on the host, where it lies in the engine's buffers, how it moves.
struct SceneMesh {
    name: String,
    rest: Mesh,
    index_type: IndexType,
    /// First vertex in the vertex buffer.
    first_vertex: u32,
    /// Byte offset of its first index in the index buffer.
    index_offset: u64,
    motion: Motion,
}

fn bounds(positions: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// Area-weighted vertex normals.
fn vertex_normals(m: &Mesh) -> Vec<[f32; 3]> {
    let mut n = vec![glam::Vec3::ZERO; m.positions.len()];
    for t in 0..m.triangle_count() {
        let [a, b, c] = m.triangle(t);
        let f = (b - a).cross(c - a);
        for &i in &m.indices[t] {
            n[i as usize] += f;
        }
    }
    n.iter().map(|v| v.try_normalize().unwrap_or(glam::Vec3::Y).to_array()).collect()
}

/// The scene's meshes: the exploding teapot soup (16-bit indices) first, then the turning mesh (32-bit).
fn scene(args: &Args) -> Result<Vec<SceneMesh>> {
    let teapot = meshchar::mesh::default_teapot();
    // One frame of generate::explode is the teapot as a soup, every triangle with vertices of its own.
    let soup = generate::explode(&teapot, 1, 23)?.frames.into_iter().next().ok_or_else(|| anyhow!("no frame"))?;
    ensure!(soup.positions.len() <= 1 << 16, "the teapot soup does not fit 16-bit indices");
    let (lo, hi) = bounds(&soup.positions);
    let diag = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f32>().sqrt();
    let mut turning = match &args.mesh {
        Some(path) => cli::load_mesh_checked(path, cli::BYTES_PER_TRIANGLE)?,
        None => generate::subdivide(&meshchar::mesh::default_scene(), args.subdivide)?,
    };
    ensure!(turning.triangle_count() > 0, "{}: no triangles", turning.name);
    // Placed in the world beside the teapot, at its size (the bunny is a few centimetres, the teapot 30 units).
    let (tlo, thi) = bounds(&turning.positions);
    let tdiag = (0..3).map(|a| (thi[a] - tlo[a]).powi(2)).sum::<f32>().sqrt();
    let scale = if tdiag > 0.0 && tdiag.is_finite() { diag / tdiag } else { 1.0 };
    let from = [0, 1, 2].map(|a| 0.5 * (tlo[a] + thi[a]));
    let center = [0.5 * (lo[0] + hi[0]) + 0.9 * diag, 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])];
    for p in &mut turning.positions {
        *p = [0, 1, 2].map(|a| (p[a] - from[a]) * scale + center[a]);
    }
    ensure!(turning.positions.iter().flatten().all(|x| x.is_finite()), "{}: coordinates too large", turning.name);
    let axis = glam::Vec3::new(0.35, 1.0, 0.2).normalize().to_array();
    let small_vertices = soup.positions.len() as u32;
    let small_index_bytes = (6 * soup.triangle_count() as u64).next_multiple_of(4);
    Ok(vec![
        SceneMesh {
            name: "teapot".into(),
            rest: soup,
            index_type: IndexType::U16,
            first_vertex: 0,
            index_offset: 0,
            motion: Motion::Explode { speed: diag, seed: 23 },
        },
        SceneMesh {
            name: if args.mesh.is_some() { turning.name.clone() } else { "bunny".into() },
            rest: turning,
            index_type: IndexType::U32,
            first_vertex: small_vertices,
            index_offset: small_index_bytes,
            motion: Motion::Rotate { axis, center, angle: 2f32.to_radians() },
        },
    ])
}

/// The interleaved vertex data (position, normal, uv) and the index bytes of the scene.
fn scene_data(meshes: &[SceneMesh]) -> Result<(Vec<f32>, Vec<u8>)> {
    let mut v = Vec::new();
    let mut idx: Vec<u8> = Vec::new();
    for m in meshes {
        ensure!(v.len() / VERTEX_FLOATS == m.first_vertex as usize, "vertex layout");
        ensure!(idx.len() as u64 == m.index_offset, "index layout");
        let normals = vertex_normals(&m.rest);
        let (lo, hi) = bounds(&m.rest.positions);
        for (p, n) in m.rest.positions.iter().zip(&normals) {
            let uv = [0, 2].map(|a| if hi[a] > lo[a] { (p[a] - lo[a]) / (hi[a] - lo[a]) } else { 0.0 });
            v.extend_from_slice(p);
            v.extend_from_slice(n);
            v.extend_from_slice(&uv);
        }
        for t in &m.rest.indices {
            for &i in t {
                match m.index_type {
                    IndexType::U16 => idx.extend_from_slice(&u16::try_from(i)?.to_le_bytes()),
                    _ => idx.extend_from_slice(&i.to_le_bytes()),
                }
            }
        }
        while idx.len() % 4 != 0 {
            idx.push(0);
        }
    }
    Ok((v, idx))
}

/// The engine's buffers, animation pipeline and per-frame objects.
struct Resources {
    vertices: EngineBuffer,
    rest: EngineBuffer,
    indices: EngineBuffer,
    vertex_bytes: u64,
    pipeline: vk::Pipeline,
    layout: vk::PipelineLayout,
    workgroup: u32,
    slots: Vec<Slot>,
}

/// The objects of one frame in flight.
struct Slot {
    pool: vk::CommandPool,
    /// The frame's command buffer; `staged` uses `anim` for its animation submission.
    cmd: vk::CommandBuffer,
    anim: vk::CommandBuffer,
    fence: vk::Fence,
    anim_fence: vk::Fence,
    queries: vk::QueryPool,
    readback: EngineBuffer,
    in_flight: Option<InFlight>,
}

/// Timestamps of a frame: start, after the animation, after each mesh's characterization, after each mesh's
/// rebuild or refit.
fn query_count(meshes: usize) -> u32 {
    2 + 2 * meshes as u32
}

impl Resources {
    fn new(engine: &mut Engine, meshes: &[SceneMesh]) -> Result<Resources> {
        let (v, idx) = scene_data(meshes)?;
        let vertex_bytes = 4 * v.len() as u64;
        let mut usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST;
        if engine.ray_query {
            // The driver's builds read the engine's vertices and indices.
            usage |= vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;
        }
        let vertices = engine.create_buffer(
            "vertices",
            vertex_bytes,
            usage | vk::BufferUsageFlags::VERTEX_BUFFER,
            MemoryLocation::GpuOnly,
        )?;
        let rest = engine.create_buffer("rest vertices", vertex_bytes, usage, MemoryLocation::GpuOnly)?;
        let indices = engine.create_buffer(
            "indices",
            idx.len() as u64,
            usage | vk::BufferUsageFlags::INDEX_BUFFER,
            MemoryLocation::GpuOnly,
        )?;
        // Upload once, before the frames: a staging buffer, copies, one wait.
        let staging = engine.create_buffer(
            "staging",
            vertex_bytes + idx.len() as u64,
            vk::BufferUsageFlags::TRANSFER_SRC,
            MemoryLocation::CpuToGpu,
        )?;
        let p = staging.mapped.ok_or_else(|| anyhow!("staging buffer is not host-visible"))?;
        let bytes: Vec<u8> = bytemuck::cast_slice(&v).iter().chain(&idx).copied().collect();
        // SAFETY: the mapping holds `staging.size` bytes (= bytes.len()); the device does not use it yet.
        unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), p.as_ptr(), bytes.len()) };
        engine.flush(&staging)?;
        let pool = engine.command_pool()?;
        let cmd = engine.command_buffers(pool, 1)?[0];
        let fence = engine.fence(false)?;
        engine.begin(cmd)?;
        let copies = [
            (vertices.buffer, vk::BufferCopy { src_offset: 0, dst_offset: 0, size: vertex_bytes }),
            (rest.buffer, vk::BufferCopy { src_offset: 0, dst_offset: 0, size: vertex_bytes }),
            (indices.buffer, vk::BufferCopy { src_offset: vertex_bytes, dst_offset: 0, size: idx.len() as u64 }),
        ];
        for (dst, region) in copies {
            // SAFETY: recording; both ranges lie inside their buffers, which have transfer usage.
            unsafe { engine.device.cmd_copy_buffer(cmd, staging.buffer, dst, &[region]) };
        }
        engine.end(cmd)?;
        engine.submit(cmd, fence)?;
        engine.wait_and_reset(fence)?;

        let (pipeline, layout, workgroup) = animation_pipeline(engine)?;
        let mut slots = Vec::new();
        for i in 0..FRAMES_IN_FLIGHT {
            let pool = engine.command_pool()?;
            let cmds = engine.command_buffers(pool, 2)?;
            slots.push(Slot {
                pool,
                cmd: cmds[0],
                anim: cmds[1],
                fence: engine.fence(false)?,
                anim_fence: engine.fence(false)?,
                queries: engine.query_pool(query_count(meshes.len()))?,
                readback: engine.create_buffer(
                    &format!("readback {i}"),
                    vertex_bytes,
                    vk::BufferUsageFlags::TRANSFER_DST,
                    MemoryLocation::GpuToCpu,
                )?,
                in_flight: None,
            });
        }
        Ok(Resources { vertices, rest, indices, vertex_bytes, pipeline, layout, workgroup, slots })
    }
}

/// The engine's own animation kernel, `examples/shaders/engine_animate.comp`: its SPIR-V and push-constant struct,
/// compiled by meshchar's build with the feature `compile-glsl` into `examples/shaders/generated/` (the library's
/// shader table does not hold it).
mod engine_animate {
    include!("shaders/generated/engine_animate.rs");
}

/// The engine's animation pipeline over `examples/shaders/engine_animate.comp` (the pipeline, its layout and
/// workgroup size are the engine's), and its workgroup size.
fn animation_pipeline(engine: &mut Engine) -> Result<(vk::Pipeline, vk::PipelineLayout, u32)> {
    let words = engine_animate::spirv();
    // SAFETY: valid device; the words are a SPIR-V module compiled by meshchar's build (feature compile-glsl).
    let module =
        unsafe { engine.device.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None) }
            .context("vkCreateShaderModule")?;
    engine.owned.push(Owned::ShaderModule(module));
    let range = [vk::PushConstantRange::default()
        .stage_flags(vk::ShaderStageFlags::COMPUTE)
        .offset(0)
        .size(std::mem::size_of::<engine_animate::Push>() as u32)];
    // SAFETY: valid device; no descriptor sets, one push-constant range.
    let layout = unsafe {
        engine
            .device
            .create_pipeline_layout(&vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&range), None)
    }
    .context("vkCreatePipelineLayout")?;
    engine.owned.push(Owned::PipelineLayout(layout));
    // SAFETY: valid physical device.
    let limits = unsafe { engine.instance.instance.get_physical_device_properties(engine.physical) }.limits;
    let workgroup = 64u32.min(limits.max_compute_work_group_size[0]).min(limits.max_compute_work_group_invocations);
    let entries = [vk::SpecializationMapEntry { constant_id: engine_animate::LOCAL_SIZE_X_ID, offset: 0, size: 4 }];
    let data = workgroup.to_le_bytes();
    let spec = vk::SpecializationInfo::default().map_entries(&entries).data(&data);
    let stage = vk::PipelineShaderStageCreateInfo::default()
        .stage(vk::ShaderStageFlags::COMPUTE)
        .module(module)
        .name(c"main")
        .specialization_info(&spec);
    let create = [vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout)];
    // SAFETY: valid module, layout and specialization data.
    let pipelines = unsafe { engine.device.create_compute_pipelines(vk::PipelineCache::null(), &create, None) }
        .map_err(|(_, e)| anyhow!("vkCreateComputePipelines: {e}"))?;
    let pipeline = pipelines.first().copied().ok_or_else(|| anyhow!("no pipeline created"))?;
    engine.owned.push(Owned::Pipeline(pipeline));
    Ok((pipeline, layout, workgroup))
}

/// Records the animation of every mesh for frame `frame` (its pipeline, push constants, one dispatch each).
fn record_animation(engine: &Engine, res: &Resources, meshes: &[SceneMesh], cmd: vk::CommandBuffer, frame: usize) {
    let dev = &engine.device;
    // SAFETY: `cmd` is recording; pipeline and layout of this device.
    unsafe { dev.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::COMPUTE, res.pipeline) };
    for m in meshes {
        let mut push = engine_animate::Push {
            rest: res.rest.address,
            live: res.vertices.address,
            indices: res.indices.address + m.index_offset,
            first_vertex: m.first_vertex,
            stride: STRIDE,
            index_bytes: m.index_type.bytes() as u32,
            time: frame as f32,
            ..Default::default()
        };
        let items = match m.motion {
            Motion::Explode { speed, seed } => {
                push.mode = 1;
                push.speed = speed;
                push.seed = seed;
                m.rest.triangle_count()
            }
            Motion::Rotate { axis, center, angle } => {
                push.mode = 0;
                push.angle = angle;
                [push.axis_x, push.axis_y, push.axis_z] = axis;
                [push.center_x, push.center_y, push.center_z] = center;
                m.rest.positions.len()
            }
        };
        push.count = items as u32;
        let groups = (items as u64).div_ceil(u64::from(res.workgroup)).clamp(1, 65_535) as u32;
        // SAFETY: `cmd` is recording; the push constants match the layout's range; every address points into the
        // engine's live buffers with room for the mesh's vertices and indices (laid out by `scene_data`); the
        // kernel loops over what the groups do not cover.
        unsafe {
            dev.cmd_push_constants(cmd, res.layout, vk::ShaderStageFlags::COMPUTE, 0, bytemuck::bytes_of(&push));
            dev.cmd_dispatch(cmd, groups, 1, 1);
        }
    }
}

// ------------------------------------------------------------------------------------------------------------------
// The frames.
// ------------------------------------------------------------------------------------------------------------------

/// What the engine knows about a mesh across frames.
struct MeshState {
    view: GeometryView<'static>,
    backend: VulkanBackend,
    builder: BvhBuilder,
    /// The tree in use and the frame that built it.
    tree: Option<(GpuBvh, usize)>,
    /// The features the rule compared against when the tree was built (see [`decide`]).
    built_features: Option<Features>,
    /// With ray queries: the driver structure in use (`rt_update`, updatable) and the frame that built it.
    driver: Option<(DriverStructure, usize)>,
    /// The features the driver rule compared against when the driver structure was built.
    driver_features: Option<Features>,
    /// The latest report read back: its frame (`None`: the rest pose, before the loop), report, features.
    latest: (Option<usize>, Characterization, Features),
    /// The features of the last decision and whether it chose the driver's structure: kept while the features
    /// stay within the rule's drift of them ([`FrameRule::redecide`]).
    decided: Option<(Features, bool)>,
}

/// A frame submitted and not yet read back.
struct InFlight {
    frame: usize,
    meshes: Vec<MeshFrame>,
    host_waits: u64,
    engine_waits: u64,
    record_ms: f64,
    /// Whether the frame copied its animated positions to the slot's readback buffer.
    copied: bool,
    /// Trees replaced in this frame, kept alive until it completes (the frame before may still refit them).
    retired: Vec<GpuBvh>,
    /// Driver structures replaced in this frame (or built for its picture), kept alive likewise.
    retired_driver: Vec<DriverStructure>,
    /// With --png and ray queries, the last frame: per mesh the ray-query hits of the picture's rays.
    picture: Vec<meshchar::gpu::Buffer>,
}

/// One mesh in one frame.
struct MeshFrame {
    decision: FrameAction,
    /// Whether the rule decided this frame (else the last decision was kept: the features stayed within its drift).
    decided: bool,
    /// The drift from the features of the last decision.
    drift_since_decision: f64,
    /// The host's time deciding (or checking that the last decision holds), µs.
    decision_us: f64,
    /// `lbvh`, or `rt_update` (the driver structure; its update counts as a refit).
    structure: &'static str,
    drift: f64,
    plan_from: Option<usize>,
    plan: Plan,
    /// Staged mode: the report, features and GPU pass time of the frame's own staged characterization.
    staged: Option<(Characterization, Features, f64)>,
}

/// A frame's results, as printed.
struct FrameLine {
    json: serde_json::Value,
    characterize_ms: f64,
    rebuilds: usize,
    refits: usize,
    build_ms: f64,
    refit_ms: f64,
    host_waits: u64,
    engine_waits: u64,
    messages: u64,
    reference_equal: Option<bool>,
    /// Meshes of this frame traced with the driver's structure (rt_update) rather than the LBVH.
    driver_meshes: usize,
    /// The host's time deciding for every mesh, µs.
    decision_us: f64,
    /// The meshes the rule decided for again (their features drifted past the rule's bound).
    redecided: Vec<String>,
    /// The frame's GPU time: animation, characterization and the builds and refits (timestamps), ms.
    gpu_ms: f64,
}

/// The report without what differs between a device run and the CPU reference by construction.
fn comparable(mut c: Characterization) -> Characterization {
    c.timings.clear();
    c.backend.clear();
    c.device.clear();
    c
}

/// The quantizer of the bounds a report read back (the plan's: `Plan::after` takes the same bounds).
fn quantizer_of(report: &Characterization, params: &Params) -> Result<Quantizer> {
    let mut b = KeyBounds::EMPTY;
    b.add(report.lo);
    b.add(report.hi);
    Ok(Quantizer::new(&b, params.morton_bits)?)
}

/// The rule's decision for mesh `m` at frame `frame`, from the latest features read back: the LBVH's (rebuild or
/// refit, [`FrameRule`]) and, with ray queries, the driver structure's (rebuild or update, [`DriverFrameRule`]),
/// whichever predicts the smaller update plus trace time (the LBVH on a tie); `true` for the driver. Drift is
/// measured from the features that were the latest when the structure in use was built to the latest now: both lag
/// the frames they describe by the same few frames in flight, so their change estimates the change since the
/// structure's own frame.
fn decide(
    rule: &FrameRule<'_>,
    driver: Option<&DriverFrameRule<'_>>,
    candidates: Candidates,
    m: &MeshState,
    frame: usize,
    now: &Features,
) -> Result<(FrameAction, f64, bool)> {
    let built = match (&m.tree, &m.built_features) {
        (Some(_), Some(f)) => Some((f, StructureName::Lbvh)),
        _ => None,
    };
    let d = rule.decide(frame, now, built).ok_or_else(|| anyhow!("the cost model predicts no LBVH"))?;
    let mut choice = (d.action, d.drift, false);
    if let Some(dr) = driver {
        let built = m.driver.as_ref().and(m.driver_features.as_ref());
        if let Some(x) = dr.decide(frame, now, built) {
            let cheaper = x.update_ms + x.trace_ms < d.update_ms + d.trace_ms;
            if candidates == Candidates::RtUpdate || (candidates == Candidates::Auto && cheaper) {
                let action = match x.action {
                    DriverAction::Rebuild => FrameAction::Rebuild,
                    DriverAction::Update => FrameAction::Refit,
                };
                choice = (action, x.drift, true);
            }
        }
    }
    Ok(choice)
}

/// The CPU copy of mesh `m` with the positions read back from the engine's vertex buffer.
fn read_back_mesh(bytes: &[u8], m: &SceneMesh, frame: usize) -> Result<Mesh> {
    let first = m.first_vertex as usize * STRIDE as usize;
    let n = m.rest.positions.len();
    let floats: &[f32] = bytemuck::try_cast_slice(bytes.get(first..first + n * STRIDE as usize).unwrap_or(&[]))
        .map_err(|e| anyhow!("readback: {e}"))?;
    ensure!(floats.len() == n * VERTEX_FLOATS, "readback of {} is short", m.name);
    let positions = floats.chunks_exact(VERTEX_FLOATS).map(|v| [v[0], v[1], v[2]]).collect();
    Ok(Mesh::new(format!("{} frame {frame}", m.name), positions, m.rest.indices.clone())?)
}

/// Everything the frame loop needs.
struct Run<'a> {
    args: &'a Args,
    engine: &'a Engine,
    res: &'a mut Resources,
    scene: &'a [SceneMesh],
    ctx: &'a Context,
    states: Vec<MeshState>,
    params: Params,
    rule: FrameRule<'a>,
    /// With ray queries and a cost model that calibrated the driver structures: their builder and rule.
    driver: Option<(DriverBuilder, DriverFrameRule<'a>)>,
    /// With --png and ray queries: the picture's primary rays (device buffer, count) traced in the last frame.
    picture_rays: Option<(meshchar::gpu::Buffer, u64)>,
    lbvh: LbvhOptions,
    messages: &'a MessageSink,
    messages_seen: u64,
    lines: Vec<FrameLine>,
    /// The last frame's read-back meshes with their plans (for --png).
    last: Option<Vec<(Mesh, Plan)>>,
    /// The last frame's ray-query hits of the picture's rays, per mesh (--png with ray queries).
    picture: Option<Vec<Vec<TraceHit>>>,
}

impl Run<'_> {
    /// Records and submits frame `t` into slot `t % FRAMES_IN_FLIGHT` (whose previous frame has completed).
    fn frame(&mut self, t: usize) -> Result<()> {
        let s = t % FRAMES_IN_FLIGHT;
        let start = Instant::now();
        let waits_before = self.ctx.host_waits();
        let (engine, scene) = (self.engine, self.scene);
        let slot = &self.res.slots[s];
        let (cmd, queries, pool) = (slot.cmd, slot.queries, slot.pool);
        // SAFETY: every command buffer of the pool has completed (its fences were observed) and is not in use.
        unsafe { engine.device.reset_command_pool(pool, vk::CommandPoolResetFlags::empty()) }
            .context("vkResetCommandPool")?;
        let staged = self.args.mode == Mode::Staged;
        let copy = staged || self.args.check || (self.args.png.is_some() && t + 1 == self.args.frames);
        let mut engine_waits = 0;
        let copy_region = [vk::BufferCopy { src_offset: 0, dst_offset: 0, size: self.res.vertex_bytes }];
        let compute = vk::PipelineStageFlags::COMPUTE_SHADER;
        let after_animation = (
            (compute, vk::AccessFlags::SHADER_WRITE),
            (compute | vk::PipelineStageFlags::TRANSFER, vk::AccessFlags::SHADER_READ | vk::AccessFlags::TRANSFER_READ),
        );
        let to_host = (
            (vk::PipelineStageFlags::TRANSFER, vk::AccessFlags::TRANSFER_WRITE),
            (vk::PipelineStageFlags::HOST, vk::AccessFlags::HOST_READ),
        );
        // Staged: the animation in a submission of its own, waited for, and the positions read back.
        let mut staged_reports = Vec::new();
        if staged {
            let anim = slot.anim;
            engine.begin(anim)?;
            engine.frame_start_barrier(anim);
            // SAFETY: recording; a query pool of this device.
            unsafe { engine.device.cmd_reset_query_pool(anim, queries, 0, query_count(scene.len())) };
            engine.timestamp(anim, queries, 0);
            record_animation(engine, self.res, scene, anim, t);
            engine.barrier(anim, after_animation.0, after_animation.1);
            engine.timestamp(anim, queries, 1);
            // SAFETY: recording; the whole vertex buffer fits the readback buffer (same size).
            unsafe {
                engine.device.cmd_copy_buffer(anim, self.res.vertices.buffer, slot.readback.buffer, &copy_region)
            };
            engine.barrier(anim, to_host.0, to_host.1);
            engine.end(anim)?;
            engine.submit(anim, slot.anim_fence)?;
            engine.wait_and_reset(slot.anim_fence)?;
            engine_waits += 1;
            let bytes = engine.read_mapped(&slot.readback)?;
            for (m, st) in scene.iter().zip(self.states.iter_mut()) {
                let mesh = read_back_mesh(bytes, m, t)?;
                let (report, features) = st.backend.characterize_with_features(&mesh, &self.params)?;
                let gpu_ms: f64 = report
                    .timings
                    .iter()
                    .filter(|p| p.name != "upload" && p.name != PassTime::TOTAL)
                    .map(|p| p.ms)
                    .sum();
                staged_reports.push((report, features, gpu_ms));
            }
        }

        engine.begin(cmd)?;
        engine.frame_start_barrier(cmd);
        if !staged {
            // SAFETY: recording; a query pool of this device.
            unsafe { engine.device.cmd_reset_query_pool(cmd, queries, 0, query_count(scene.len())) };
            engine.timestamp(cmd, queries, 0);
            record_animation(engine, self.res, scene, cmd, t);
            engine.barrier(cmd, after_animation.0, after_animation.1);
            engine.timestamp(cmd, queries, 1);
            if copy {
                // SAFETY: recording; the whole vertex buffer fits the readback buffer (same size).
                unsafe {
                    engine.device.cmd_copy_buffer(cmd, self.res.vertices.buffer, slot.readback.buffer, &copy_region)
                };
            }
        }
        // SAFETY: `cmd` is recording, from a pool of the context's queue family used by this thread only; the
        // engine submits it and keeps every buffer, tree and slot recorded into it alive until its fence is
        // observed (the slot's state and `retired` hold them), and resets its pool only after that.
        let mut rec = unsafe { Recorder::new(self.ctx, cmd) };
        let mut frames = Vec::new();
        let mut reports = staged_reports.into_iter();
        for (i, st) in self.states.iter_mut().enumerate() {
            let (plan, plan_from, own) = match reports.next() {
                Some((report, features, ms)) => {
                    let max = st.backend.max_classes();
                    (Plan::after(&report, &self.params, max)?, Some(t), Some((report, features, ms)))
                }
                None => {
                    let max = st.backend.max_classes();
                    let (from, report, _) = &st.latest;
                    let plan = Plan::after(report, &self.params, max)?;
                    st.backend.record_planned(&mut rec, s, &st.view, &scene[i].name, &self.params, &plan, true)?;
                    engine.timestamp(cmd, queries, 2 + i as u32);
                    (plan, *from, None)
                }
            };
            frames.push(MeshFrame {
                decision: FrameAction::Rebuild,
                decided: false,
                drift_since_decision: 0.0,
                decision_us: 0.0,
                structure: "lbvh",
                drift: 0.0,
                plan_from,
                plan,
                staged: own,
            });
        }
        if staged {
            // The characterization ran before this command buffer: its timestamps only mark the start of the
            // rebuilds and refits.
            for i in 0..scene.len() {
                engine.timestamp(cmd, queries, 2 + i as u32);
            }
        }
        let mut retired = Vec::new();
        let mut retired_driver = Vec::new();
        for (i, (st, mf)) in self.states.iter_mut().zip(frames.iter_mut()).enumerate() {
            // The latest features: this frame's own (staged), else the latest read back.
            let (now_report, now_features) = match &mf.staged {
                Some((r, f, _)) => (r.clone(), f.clone()),
                None => (st.latest.1.clone(), st.latest.2.clone()),
            };
            let driver_rule = self.driver.as_ref().map(|(_, r)| r);
            // The last decision holds while the features stay within the rule's drift of the ones it was made on;
            // past it, or without a structure, the rule decides again.
            let clock = Instant::now();
            let (redecide, since) = match (&st.decided, st.tree.is_some() || st.driver.is_some()) {
                (Some((f, _)), true) => self.rule.redecide(f, &now_features),
                _ => (true, 0.0),
            };
            let (action, drift, use_driver) = if redecide {
                let c = decide(&self.rule, driver_rule, self.args.structure, st, t, &now_features)?;
                st.decided = Some((now_features.clone(), c.2));
                c
            } else {
                let on_driver = st.decided.as_ref().is_some_and(|d| d.1);
                let built = if on_driver { st.driver_features.as_ref() } else { st.built_features.as_ref() };
                let drift = built.map_or(0.0, |b| meshchar::cost::drift(b, &now_features));
                (FrameAction::Refit, drift, on_driver)
            };
            mf.decision_us = clock.elapsed().as_secs_f64() * 1e6;
            (mf.decided, mf.drift_since_decision) = (redecide, since);
            (mf.decision, mf.drift) = (action, drift);
            if let (true, Some((builder, _))) = (use_driver, &self.driver) {
                mf.structure = DriverFlags::Update.name();
                // The LBVH is no longer traced: kept alive until this frame completes.
                if let Some((old, _)) = st.tree.take() {
                    retired.push(old);
                }
                st.built_features = None;
                match (action, st.driver.as_mut()) {
                    (FrameAction::Refit, Some((ds, _))) => builder.record_update(&mut rec, &st.view, ds)?,
                    _ => {
                        let ds = builder.record_build(&mut rec, &st.view, DriverFlags::Update)?;
                        if let Some((old, _)) = st.driver.replace((ds, t)) {
                            retired_driver.push(old);
                        }
                        st.driver_features = Some(now_features);
                        mf.decision = FrameAction::Rebuild;
                    }
                }
                engine.timestamp(cmd, queries, 2 + (scene.len() + i) as u32);
                continue;
            }
            if let Some((old, _)) = st.driver.take() {
                retired_driver.push(old);
                st.driver_features = None;
            }
            match (action, &st.tree) {
                (FrameAction::Refit, Some((tree, _))) => st.builder.record_refit(&mut rec, &st.view, tree)?,
                _ => {
                    let q = quantizer_of(&now_report, &self.params)?;
                    ensure!(q.lo() == mf.plan.lo && q.scale() == mf.plan.scale, "the plan's quantizer differs");
                    let tree = st.builder.record_lbvh(&mut rec, &st.view, &q, &self.lbvh)?;
                    if let Some((old, _)) = st.tree.replace((tree, t)) {
                        retired.push(old);
                    }
                    st.built_features = Some(now_features);
                    mf.decision = FrameAction::Rebuild;
                }
            }
            engine.timestamp(cmd, queries, 2 + (scene.len() + i) as u32);
        }
        // The last frame's picture with --png and ray queries: the picture's rays through each mesh's driver
        // structure (one built with PREFER_FAST_TRACE for the picture where the mesh is traced with its LBVH).
        let mut picture = Vec::new();
        if let (Some((rays, count)), Some((builder, _)), true) =
            (&self.picture_rays, &self.driver, self.args.png.is_some() && t + 1 == self.args.frames)
        {
            for st in self.states.iter() {
                let hits = self.ctx.create_buffer(
                    "picture hits",
                    count * std::mem::size_of::<TraceHit>() as u64,
                    meshchar::gpu::MemoryKind::Readback,
                )?;
                match &st.driver {
                    Some((ds, _)) => builder.record_trace(&mut rec, ds, rays, &hits, *count, false)?,
                    None => {
                        let ds = builder.record_build(&mut rec, &st.view, DriverFlags::FastTrace)?;
                        builder.record_trace(&mut rec, &ds, rays, &hits, *count, false)?;
                        retired_driver.push(ds);
                    }
                }
                picture.push(hits);
            }
            let shader = (compute, vk::AccessFlags::SHADER_WRITE);
            engine.barrier(cmd, shader, (vk::PipelineStageFlags::HOST, vk::AccessFlags::HOST_READ));
        }
        if copy && !staged {
            engine.barrier(cmd, to_host.0, to_host.1);
        }
        engine.end(cmd)?;
        engine.submit(cmd, slot.fence)?;
        let host_waits = self.ctx.host_waits() - waits_before;
        self.res.slots[s].in_flight = Some(InFlight {
            frame: t,
            meshes: frames,
            host_waits,
            engine_waits,
            record_ms: start.elapsed().as_secs_f64() * 1e3,
            copied: copy,
            retired,
            retired_driver,
            picture,
        });
        Ok(())
    }

    /// Reads back the frame in slot `s` (its fence observed): reports, features, timestamps, the check; appends
    /// its line.
    fn complete(&mut self, s: usize) -> Result<()> {
        let Some(f) = self.res.slots[s].in_flight.take() else { return Ok(()) };
        let (engine, scene) = (self.engine, self.scene);
        let ms = engine.read_timestamps(self.res.slots[s].queries, query_count(scene.len()) as usize)?;
        let n = scene.len();
        let bytes = if f.copied { Some(engine.read_mapped(&self.res.slots[s].readback)?) } else { None };
        let mut meshes_json = Vec::new();
        let mut line = FrameLine {
            json: json!(null),
            characterize_ms: 0.0,
            rebuilds: 0,
            refits: 0,
            build_ms: 0.0,
            refit_ms: 0.0,
            host_waits: f.host_waits,
            engine_waits: f.engine_waits,
            messages: 0,
            reference_equal: None,
            driver_meshes: 0,
            decision_us: 0.0,
            redecided: Vec::new(),
            gpu_ms: 0.0,
        };
        let mut last = Vec::new();
        for (i, (mf, st)) in f.meshes.into_iter().zip(self.states.iter_mut()).enumerate() {
            let m = &scene[i];
            let (report, features, char_ms) = match mf.staged {
                Some(own) => own,
                None => {
                    let (planned, features) = st.backend.finish_planned(s)?;
                    let features = features.ok_or_else(|| anyhow!("no features recorded"))?;
                    (planned.report, features, ms[1 + i])
                }
            };
            if let Some((tree, built)) = &mut st.tree {
                if *built == f.frame {
                    tree.finish()?;
                }
            }
            if let Some((ds, _)) = &mut st.driver {
                // The timers of this frame's build or update (and any before) have completed.
                ds.finish()?;
            }
            let op_ms = ms[1 + n + i];
            let equal = match (&bytes, self.args.check) {
                (Some(b), true) => {
                    let mesh = read_back_mesh(b, m, f.frame)?;
                    let want = reference(&mesh, &self.params, &mf.plan)?;
                    Some(want.plan == mf.plan && comparable(want.report) == comparable(report.clone()))
                }
                _ => None,
            };
            if let (Some(b), true) = (&bytes, self.args.png.is_some() && f.frame + 1 == self.args.frames) {
                last.push((read_back_mesh(b, m, f.frame)?, mf.plan.clone()));
            }
            line.characterize_ms += char_ms;
            line.decision_us += mf.decision_us;
            if mf.decided {
                line.redecided.push(m.name.clone());
            }
            let op = match mf.decision {
                FrameAction::Rebuild => {
                    line.rebuilds += 1;
                    line.build_ms += op_ms;
                    "build_ms"
                }
                FrameAction::Refit => {
                    line.refits += 1;
                    line.refit_ms += op_ms;
                    "refit_ms"
                }
            };
            if let Some(e) = equal {
                line.reference_equal = Some(line.reference_equal.unwrap_or(true) && e);
            }
            line.driver_meshes += usize::from(mf.structure != "lbvh");
            let mut mj = json!({
                "mesh": m.name, "triangles": m.rest.triangle_count(), "index_type": index_name(m.index_type),
                "motion": m.motion.as_str(), "decision": mf.decision.as_str(), "structure": mf.structure,
                "drift": mf.drift, "decided": mf.decided, "drift_since_decision": mf.drift_since_decision,
                "decision_us": mf.decision_us,
                "plan_from_frame": mf.plan_from, "classes": report.classes, "cramers_v": report.stats.cramers_v,
                "characterize_ms": char_ms,
            });
            mj[op] = json!(op_ms);
            if let Some(e) = equal {
                mj["reference_equal"] = json!(e);
            }
            meshes_json.push(mj);
            if st.latest.0.is_none_or(|l| l < f.frame) {
                st.latest = (Some(f.frame), report, features);
            }
        }
        drop(f.retired);
        drop(f.retired_driver);
        if !f.picture.is_empty() {
            let count = self.picture_rays.as_ref().map_or(0, |r| r.1) as usize;
            let mut hits = Vec::new();
            for b in &f.picture {
                hits.push(self.ctx.read_buffer::<TraceHit>(b, 0, count)?);
            }
            self.picture = Some(hits);
        }
        if !last.is_empty() {
            self.last = Some(last);
        }
        let total = self.messages.count.load(Ordering::Relaxed);
        line.messages = total - self.messages_seen;
        self.messages_seen = total;
        let triangles: usize = scene.iter().map(|m| m.rest.triangle_count()).sum();
        line.gpu_ms = ms[0] + line.characterize_ms + line.build_ms + line.refit_ms;
        let mut j = json!({
            "frame": f.frame, "mode": self.args.mode.as_str(), "triangles": triangles,
            "characterize_ms": line.characterize_ms,
            "decision": if line.rebuilds > 0 { "rebuild" } else { "refit" },
            "host_waits": line.host_waits, "engine_waits": line.engine_waits,
            "validation_messages": line.messages, "animate_ms": ms[0], "record_ms": f.record_ms,
            "decision_us": line.decision_us, "redecided": line.redecided, "gpu_ms": line.gpu_ms,
        });
        if line.rebuilds > 0 {
            j["build_ms"] = json!(line.build_ms);
        }
        if line.refits > 0 {
            j["refit_ms"] = json!(line.refit_ms);
        }
        if let Some(e) = line.reference_equal {
            j["reference_equal"] = json!(e);
        }
        j["meshes"] = json!(meshes_json);
        line.json = j;
        self.print(&line);
        self.lines.push(line);
        Ok(())
    }

    fn print(&self, line: &FrameLine) {
        let j = &line.json;
        if self.args.json.json {
            println!("{j}");
            return;
        }
        if self.lines.is_empty() {
            println!(
                "{:>5} {:>8} {:>9} {:>9} {:>9} {:>17} {:>5} {:>5} {:>5} {:>5}",
                "frame", "tris", "char_ms", "build_ms", "refit_ms", "decisions", "waits", "eng_w", "valid", "ref"
            );
        }
        let decisions: Vec<&str> = j["meshes"]
            .as_array()
            .map(|a| a.iter().filter_map(|m| m["decision"].as_str()).collect())
            .unwrap_or_default();
        let opt = |k: &str| j[k].as_f64().map_or("-".to_string(), |v| format!("{v:.3}"));
        println!(
            "{:>5} {:>8} {:>9.3} {:>9} {:>9} {:>17} {:>5} {:>5} {:>5} {:>5}",
            j["frame"].as_u64().unwrap_or(0),
            j["triangles"].as_u64().unwrap_or(0),
            line.characterize_ms,
            opt("build_ms"),
            opt("refit_ms"),
            decisions.join(","),
            line.host_waits,
            line.engine_waits,
            line.messages,
            line.reference_equal.map_or("-", |e| if e { "equal" } else { "DIFF" })
        );
    }
}

fn index_name(t: IndexType) -> &'static str {
    match t {
        IndexType::None => "none",
        IndexType::U16 => "u16",
        IndexType::U32 => "u32",
    }
}

/// What the frames leave.
struct Outcome {
    /// One per frame, in order.
    lines: Vec<FrameLine>,
    /// Wall time of the frame loop, ms.
    wall_ms: f64,
    /// The last frame's read-back meshes and plans (for --png).
    last: Option<Vec<(Mesh, Plan)>>,
    /// With ray queries: the last frame's ray-query hits of the picture's rays (per mesh) and their camera.
    picture: Option<(Vec<Vec<TraceHit>>, meshchar::geom::Camera)>,
    /// The drift past which the rule decides again ([`FrameRule::redecide_drift`]).
    redecide_drift: f64,
}

/// The rays of one frame the per-frame rule weighs: `--resolution` squared primary rays, or for shadow and diffuse
/// rays `--secondary-rays`, or else as many as the primary rays of a camera framing the rest poses make
/// ([`meshchar::trace::workload::estimate_secondary_rays`] over all the meshes together; printed on standard error).
fn frame_rays(args: &Args, scene: &[SceneMesh]) -> Result<u64> {
    use meshchar::trace::workload::{estimate_secondary_rays, mesh_bounds, SECONDARY_SAMPLE_SIDE};
    let (kind, res) = (args.workload.workload, args.workload.resolution);
    if kind == meshchar::geom::WorkloadKind::Primary {
        return Ok(u64::from(res).pow(2));
    }
    if let Some(n) = args.secondary_rays {
        return Ok(n);
    }
    let tris: Vec<[glam::Vec3; 3]> =
        scene.iter().flat_map(|m| (0..m.rest.triangle_count()).map(|i| m.rest.triangle(i))).collect();
    let all = Mesh::from_triangles("rest poses", &tris).context("the rest poses")?;
    let camera = meshchar::geom::Camera::frame(&mesh_bounds(&all));
    let e = estimate_secondary_rays(kind, &all, &camera, res, SECONDARY_SAMPLE_SIDE).context("secondary rays")?;
    eprintln!(
        "engine_frame: {} rays per frame: {} estimated from {}x{} of the {res}x{res} primary rays of a camera framing \
         the rest poses (--secondary-rays N to give them)",
        kind.as_str(),
        e.rays,
        e.side,
        e.side
    );
    Ok(e.rays)
}

/// Runs the frames on the engine.
fn frames(
    args: &Args,
    engine: &Engine,
    res: &mut Resources,
    scene: &[SceneMesh],
    sink: &MessageSink,
) -> Result<Outcome> {
    let raw = RawDevice {
        ray_query_enabled: engine.ray_query,
        ..RawDevice::new(engine.instance.instance.clone(), engine.device.clone(), engine.physical, engine.family, 0)
    };
    // SAFETY: the device was created from this physical device of this instance with every feature of
    // required_device_features and the extensions of required_device_extensions (and, with `ray_query_enabled`,
    // those of the ray-tracing functions), and has queue 0 of a compute family; the engine outlives the context and
    // everything made from it (all dropped before this function returns, after the device is idle); the queue is
    // used from this thread only.
    let ctx = unsafe { Context::from_raw(raw) }?;
    // With ray queries the rule weighs the driver's structures too, with the calibration of this device.
    let model = if engine.ray_query {
        let record = meshchar::accel::device::DeviceRecord::of(&ctx);
        CostModel::for_trace_target(args.cost_model.as_deref(), meshchar::cost::TraceTarget::Device(&record))
            .context("cost model")?
    } else {
        CostModel::load(args.cost_model.as_deref()).context("cost model")?
    };
    let params = Params::default();
    let lbvh = LbvhOptions { bits: params.morton_bits, ..LbvhOptions::default() };
    let mut states = Vec::new();
    for m in scene {
        let first = res.vertices.address + u64::from(m.first_vertex) * u64::from(STRIDE);
        // The teapot's view starts at its first vertex; the turning mesh's at vertex 0 of the buffer, its indices
        // relative to its own first vertex, which the view adds as a base vertex (as vkCmdDrawIndexed's
        // vertexOffset).
        let (positions, vertex_count, base) = match m.index_type {
            IndexType::U16 => (first, m.rest.positions.len() as u64, 0),
            _ => (res.vertices.address, u64::from(m.first_vertex) + m.rest.positions.len() as u64, m.first_vertex),
        };
        let indices = Some((res.indices.address + m.index_offset, m.index_type, base));
        // SAFETY: both buffers have SHADER_DEVICE_ADDRESS usage on the context's device; they hold `vertex_count`
        // vertices at STRIDE from `positions` and the mesh's 3 n indices from its offset (scene_data laid them
        // out, 16-bit ones padded to 4 bytes); they live as long as the engine, longer than every command
        // recorded with the view, and only the engine's animation writes them, ordered by its barriers.
        let view = unsafe {
            GeometryView::from_addresses(positions, STRIDE, vertex_count, indices, m.rest.triangle_count() as u64)
        }?;
        let mut backend = VulkanBackend::with_slots(&ctx, FRAMES_IN_FLIGHT)?;
        // The first frame's plan: a staged characterization of the rest pose, before the frames.
        let (report, features) = backend.characterize_with_features(&m.rest, &params)?;
        states.push(MeshState {
            view,
            backend,
            builder: BvhBuilder::new(&ctx)?,
            tree: None,
            built_features: None,
            driver: None,
            driver_features: None,
            latest: (None, report, features),
            decided: None,
        });
    }
    let structures = [StructureName::Lbvh];
    let rays_per_frame = frame_rays(args, scene)?;
    let rule = FrameRule {
        model: &model,
        kind: args.workload.workload,
        rays_per_frame,
        tie_margin: args.tie_margin.tie_margin,
        structures: &structures,
        // The meshes live in the engine's device buffers and only the features come back to the host, not the
        // triangle boxes' crossings: no overlap floor here (with the LBVH the only builder, a floor could not
        // change which structure a rebuild takes).
        crossings: None,
    };
    let redecide_drift = rule.redecide_drift();
    let driver = match (engine.ray_query, model.get_driver(DriverFlags::Update)) {
        (true, Some(_)) => Some((
            DriverBuilder::new(&ctx)?,
            DriverFrameRule { model: &model, kind: args.workload.workload, rays_per_frame },
        )),
        (true, None) => {
            eprintln!(
                "engine_frame: the cost model ({}) has not calibrated the driver's rt_update: the frames decide \
                 among LBVH rebuilds and refits only",
                model.chosen_as.as_deref().unwrap_or(&model.device)
            );
            None
        }
        _ => None,
    };
    if args.structure == Candidates::RtUpdate && driver.is_none() {
        bail!(
            "--structure rt_update: {}",
            if engine.ray_query {
                "the cost model has not calibrated the driver's rt_update"
            } else {
                "the device was created without ray queries (see --ray-query)"
            }
        );
    }
    // The picture's primary rays, made and uploaded before the frames (a wait outside them), from a camera
    // framing twice the rest poses' bounds (the meshes move).
    let picture_rays = match (&driver, &args.png) {
        (Some(_), Some(_)) => {
            let mut b = meshchar::geom::Aabb::EMPTY;
            for m in scene {
                b = b.union(&meshchar::trace::workload::mesh_bounds(&m.rest));
            }
            let (c, e) = (b.center(), b.extent());
            let camera = meshchar::geom::Camera::frame(&meshchar::geom::Aabb::new(c - e, c + e));
            let rays: Vec<TraceRay> = (0..PNG_RESOLUTION * PNG_RESOLUTION)
                .map(|p| {
                    TraceRay::from(&camera.ray(p % PNG_RESOLUTION, p / PNG_RESOLUTION, PNG_RESOLUTION, PNG_RESOLUTION))
                })
                .collect();
            Some((ctx.upload("picture rays", &rays)?, rays.len() as u64, camera))
        }
        _ => None,
    };
    let picture_camera = picture_rays.as_ref().map(|r| r.2);
    let mut run = Run {
        args,
        engine,
        res,
        scene,
        ctx: &ctx,
        states,
        params,
        rule,
        driver,
        picture_rays: picture_rays.map(|(b, n, _)| (b, n)),
        picture: None,
        lbvh,
        messages: sink,
        messages_seen: 0,
        lines: Vec::new(),
        last: None,
    };
    let start = Instant::now();
    let result = (|| -> Result<()> {
        for t in 0..args.frames {
            let s = t % FRAMES_IN_FLIGHT;
            // Frame pacing: frame t - 2's fence before its slot is reused (not a wait inside a frame).
            if run.res.slots[s].in_flight.is_some() {
                engine.wait_and_reset(run.res.slots[s].fence)?;
                run.complete(s)?;
            }
            // The frame before, if it is done already (a status query, not a wait).
            let p = (t + FRAMES_IN_FLIGHT - 1) % FRAMES_IN_FLIGHT;
            if run.res.slots[p].in_flight.is_some() {
                // SAFETY: a fence of this device.
                if unsafe { engine.device.get_fence_status(run.res.slots[p].fence) }.context("vkGetFenceStatus")? {
                    engine.wait_and_reset(run.res.slots[p].fence)?;
                    run.complete(p)?;
                }
            }
            run.frame(t)?;
        }
        // The frames still in flight, oldest first.
        for k in 0..FRAMES_IN_FLIGHT {
            let s = (args.frames + k) % FRAMES_IN_FLIGHT;
            if run.res.slots[s].in_flight.is_some() {
                engine.wait_and_reset(run.res.slots[s].fence)?;
                run.complete(s)?;
            }
        }
        Ok(())
    })();
    let wall = start.elapsed().as_secs_f64() * 1e3;
    // Whatever happened, nothing of meshchar's may be freed while the device may still use it.
    // SAFETY: valid device; the engine's queue is used by this thread only.
    let _ = unsafe { engine.device.device_wait_idle() };
    result?;
    let Run { lines, last, picture, .. } = run;
    Ok(Outcome { lines, wall_ms: wall, last, picture: picture.zip(picture_camera), redecide_drift })
}

fn run(args: Args) -> Result<()> {
    if args.secondary_rays.is_some() && args.workload.workload == meshchar::geom::WorkloadKind::Primary {
        cli::usage_error::<Args>(
            clap::error::ErrorKind::ArgumentConflict,
            "--secondary-rays counts shadow or diffuse rays (--workload shadow|diffuse)",
        );
    }
    let sink = Arc::new(MessageSink::default());
    let scene = scene(&args)?;
    let outcome = {
        let mut engine = Engine::new(!args.no_validation, sink.clone(), args.ray_query)?;
        let mut res = Resources::new(&mut engine, &scene)?;
        let name = (engine.device_name.clone(), engine.ray_query);
        frames(&args, &engine, &mut res, &scene, &sink).map(|o| (o, name))
        // The engine drops here: its objects, allocator, device, messenger and instance, in that order.
    };
    let (Outcome { lines, wall_ms: wall, last, picture, redecide_drift }, (device, ray_query)) = outcome?;
    let total_messages = sink.count.load(Ordering::Relaxed);
    let n = lines.len().max(1) as f64;
    let sum = |f: &dyn Fn(&FrameLine) -> f64| lines.iter().map(f).sum::<f64>();
    let rebuilds: usize = lines.iter().map(|l| l.rebuilds).sum();
    let refits: usize = lines.iter().map(|l| l.refits).sum();
    let driver_meshes: usize = lines.iter().map(|l| l.driver_meshes).sum();
    let host_waits: u64 = lines.iter().map(|l| l.host_waits).sum();
    let engine_waits: u64 = lines.iter().map(|l| l.engine_waits).sum();
    let all_equal = args.check.then(|| lines.iter().all(|l| l.reference_equal == Some(true)));
    // The host's decision against the frame's GPU time, per frame (the median of each over the frames).
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let decision_us = median(lines.iter().map(|l| l.decision_us).collect());
    let gpu_ms = median(lines.iter().map(|l| l.gpu_ms).collect());
    let redecisions: usize = lines.iter().map(|l| l.redecided.len()).sum();
    let mean_or_null = |total: f64, count: usize| if count > 0 { json!(total / count as f64) } else { json!(null) };
    // The picture first, so that the summary can say how it was traced.
    let mut picture_line = None;
    if let (Some(path), Some(last)) = (&args.png, last) {
        if let Some((same, pixels)) = write_png(path, &last, &Params::default(), picture.as_ref())? {
            picture_line = Some((path.display().to_string(), same, pixels));
        }
    }
    let mut summary = json!({
        "summary": true, "mode": args.mode.as_str(), "device": device, "frames": lines.len(),
        "meshes": scene.iter().map(|m| json!({
            "mesh": m.name, "triangles": m.rest.triangle_count(), "index_type": index_name(m.index_type),
            "motion": m.motion.as_str(),
        })).collect::<Vec<_>>(),
        "mean_characterize_ms": sum(&|l| l.characterize_ms) / n,
        "rebuilds": rebuilds, "refits": refits, "ray_query": ray_query, "driver_mesh_frames": driver_meshes,
        "mean_build_ms": mean_or_null(sum(&|l| l.build_ms), rebuilds),
        "mean_refit_ms": mean_or_null(sum(&|l| l.refit_ms), refits),
        "mean_record_ms": sum(&|l| l.json["record_ms"].as_f64().unwrap_or(0.0)) / n,
        "wall_ms_per_frame": wall / n,
        "host_waits": host_waits, "engine_waits": engine_waits, "validation_messages": total_messages,
        "median_decision_us": decision_us, "median_gpu_ms": gpu_ms,
        "decision_share": if gpu_ms > 0.0 { json!(decision_us * 1e-3 / gpu_ms) } else { json!(null) },
        "redecisions": redecisions, "redecide_drift": redecide_drift,
    });
    if let Some(e) = all_equal {
        summary["reference_equal"] = json!(e);
    }
    if let Some((path, same, pixels)) = &picture_line {
        summary["picture"] =
            json!({"path": path, "traced_by": "ray query", "pixels": pixels, "pixels_equal_to_cpu": same});
    }
    if args.json.json {
        println!("{summary}");
    } else {
        println!(
            "{} frames ({}, {device}): characterization {:.3} ms/frame (GPU), {rebuilds} rebuilds, {refits} refits, \
             {}{:.2} ms wall/frame, {host_waits} host waits in frames, {total_messages} validation messages{}",
            lines.len(),
            args.mode.as_str(),
            sum(&|l| l.characterize_ms) / n,
            if ray_query { format!("{driver_meshes} mesh-frames on the driver's rt_update, ") } else { String::new() },
            wall / n,
            all_equal.map_or(String::new(), |e| format!(
                ", reports {}",
                if e { "equal to the reference" } else { "DIFFER" }
            ))
        );
    }
    if let (Some((path, same, pixels)), false) = (&picture_line, args.json.json) {
        println!(
            "picture {path}: traced by ray queries, {same} of {pixels} pixels hit the triangle the CPU reference hits"
        );
    }
    if args.mode == Mode::Pipelined && host_waits > 0 {
        bail!("{host_waits} host waits inside the frames");
    }
    ensure!(total_messages == 0, "the validation layer reported {total_messages} warnings or errors");
    if all_equal == Some(false) {
        bail!("a report differs from the CPU reference");
    }
    Ok(())
}

/// The picture of the last frame: both meshes as read back, each triangle in the colour of its class under the
/// frame's plan (the CPU reference's classes, equal to the device's), the teapot's classes first. With `picture`
/// (ray queries), the pixels are the ray-query hits (per pixel the nearest over the meshes), and the return is how
/// many of them hit the triangle that the CPU reference's BVH hits, of how many pixels.
fn write_png(
    path: &std::path::Path,
    last: &[(Mesh, Plan)],
    params: &Params,
    picture: Option<&(Vec<Vec<TraceHit>>, meshchar::geom::Camera)>,
) -> Result<Option<(usize, usize)>> {
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    let mut classes = Vec::new();
    let mut counts = Vec::new();
    let mut starts = Vec::new();
    let per = Params { keep_per_triangle: true, ..params.clone() };
    for (mesh, plan) in last {
        let r = reference(mesh, &per, plan)?;
        let pt = r.report.per_triangle.ok_or_else(|| anyhow!("no per-triangle classes"))?;
        let (v0, k0) = (positions.len() as u32, counts.len() as u32);
        starts.push(indices.len() as u32);
        positions.extend_from_slice(&mesh.positions);
        indices.extend(mesh.indices.iter().map(|t| t.map(|i| i + v0)));
        classes.extend(pt.classes.iter().map(|c| c + k0));
        counts.extend_from_slice(&r.report.histogram);
    }
    let mesh = Mesh::new("last frame", positions, indices)?;
    let (img, agreement) = match picture {
        None => (meshchar::eval::render::render_classes(&mesh, &classes, &counts, PNG_RESOLUTION, None)?, None),
        Some((per_mesh, camera)) => {
            ensure!(per_mesh.len() == last.len(), "{} picture hit lists for {} meshes", per_mesh.len(), last.len());
            let pixels = (PNG_RESOLUTION * PNG_RESOLUTION) as usize;
            let mut nearest: Vec<Option<(f32, u32)>> = vec![None; pixels];
            for (hits, &start) in per_mesh.iter().zip(&starts) {
                ensure!(hits.len() == pixels, "{} picture hits for {pixels} pixels", hits.len());
                for (n, h) in nearest.iter_mut().zip(hits) {
                    if let Some(h) = h.hit().filter(|h| n.is_none_or(|(t, _)| h.t < t)) {
                        *n = Some((h.t, start + h.triangle));
                    }
                }
            }
            let hits: Vec<Option<u32>> = nearest.iter().map(|n| n.map(|(_, t)| t)).collect();
            // The CPU reference's hits of the same rays, for the agreement count.
            let bvh = Bvh::build(&mesh)?;
            let same = hits
                .iter()
                .enumerate()
                .filter(|&(p, &h)| {
                    let ray = camera.ray(
                        p as u32 % PNG_RESOLUTION,
                        p as u32 / PNG_RESOLUTION,
                        PNG_RESOLUTION,
                        PNG_RESOLUTION,
                    );
                    let w = bvh.intersect(&ray, &mut Default::default()).map(|x| x.triangle);
                    w == h
                })
                .count();
            let img = meshchar::eval::render::render_classes_from_hits(
                &mesh,
                &classes,
                &counts,
                PNG_RESOLUTION,
                camera,
                &hits,
            )?;
            (img, Some((same, pixels)))
        }
    };
    std::fs::write(path, img.encode_png()?).with_context(|| format!("writing {}", path.display()))?;
    Ok(agreement)
}
