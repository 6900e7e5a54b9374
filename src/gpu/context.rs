//! The device of a [`Context`]: instance and device creation (or a host engine's device), device choice, the
//! capabilities the engine checks, and the guard that destroys everything a context made, in order.

use super::pipeline_cache::{self, CacheKey};
use super::{vk_check, GpuError, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{c_void, CStr};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// How to create a [`Context`].
#[derive(Clone, Debug, Default)]
pub struct ContextDesc {
    /// Enable the Khronos validation layer and record every warning and error it reports (see
    /// [`Context::validation_messages`]). Tests always ask for it.
    pub validation: bool,
    /// Device to use: an index into [`enumerate_devices`]'s list or a case-insensitive substring of its name. `None`
    /// reads `MESHCHAR_DEVICE`, and without it picks discrete, then integrated, then virtual, then CPU devices.
    pub device: Option<String>,
    /// Caps the workgroups per dispatch dimension below the device's `maxComputeWorkGroupCount` (`None`: the
    /// device's limit). Every kernel splits its work into dispatches of at most this many workgroups, so a small cap
    /// exercises the tiling loops with little data on devices whose limit is 2^31 - 1 (tests use it).
    pub max_dispatch_groups: Option<u32>,
    /// A pipeline-cache file of the crate's own: loaded into the context's `VkPipelineCache` when it exists and
    /// was written for this device and driver (the file is keyed by `deviceUUID` and `driverUUID` of
    /// `VkPhysicalDeviceIDProperties`, and the Vulkan cache header's vendor, device and `pipelineCacheUUID` are
    /// checked), written by [`Context::save_pipeline_cache`]. A missing file is an empty cache; a corrupted,
    /// truncated or foreign one is ignored with a warning ([`Context::warnings`]) and an empty cache is used.
    /// `None`: an empty in-memory cache that is never written.
    pub pipeline_cache: Option<PathBuf>,
}

/// The kind of a device (`VkPhysicalDeviceType`), in the engine's order of preference when it picks one: discrete,
/// integrated, virtual, CPU, other.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DeviceType {
    /// A discrete GPU.
    Discrete,
    /// A GPU integrated with the host.
    Integrated,
    /// A virtual GPU.
    Virtual,
    /// A CPU driver (lavapipe, SwiftShader).
    Cpu,
    /// Anything else.
    Other,
}

impl DeviceType {
    /// `discrete`, `integrated`, `virtual`, `cpu` or `other` (as in JSON).
    pub fn as_str(self) -> &'static str {
        match self {
            DeviceType::Discrete => "discrete",
            DeviceType::Integrated => "integrated",
            DeviceType::Virtual => "virtual",
            DeviceType::Cpu => "cpu",
            DeviceType::Other => "other",
        }
    }

    fn of(t: vk::PhysicalDeviceType) -> DeviceType {
        match t {
            vk::PhysicalDeviceType::DISCRETE_GPU => DeviceType::Discrete,
            vk::PhysicalDeviceType::INTEGRATED_GPU => DeviceType::Integrated,
            vk::PhysicalDeviceType::VIRTUAL_GPU => DeviceType::Virtual,
            vk::PhysicalDeviceType::CPU => DeviceType::Cpu,
            _ => DeviceType::Other,
        }
    }
}

impl std::fmt::Display for DeviceType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The subgroup operations the kernels use, with their names in [`DeviceCaps::subgroup_operations`].
const NEEDED_SUBGROUP_OPS: [(vk::SubgroupFeatureFlags, &str); 4] = [
    (vk::SubgroupFeatureFlags::BASIC, "basic"),
    (vk::SubgroupFeatureFlags::ARITHMETIC, "arithmetic"),
    (vk::SubgroupFeatureFlags::BALLOT, "ballot"),
    (vk::SubgroupFeatureFlags::SHUFFLE, "shuffle"),
];

/// One thing a device lacks for the engine; [`DeviceCaps::missing`] lists them as text.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Lack {
    Vulkan12(String),
    ComputeQueue,
    SubgroupsInCompute,
    SubgroupOp(&'static str),
    Int64,
    Int64Atomics,
    BufferDeviceAddress,
    QueueTimestamps,
    SubgroupSize(u32),
}

impl std::fmt::Display for Lack {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Lack::Vulkan12(has) => write!(f, "Vulkan 1.2 (device has {has})"),
            Lack::ComputeQueue => f.write_str("a compute queue"),
            Lack::SubgroupsInCompute => f.write_str("subgroup operations in compute shaders"),
            Lack::SubgroupOp(op) => write!(f, "subgroup {op} operations"),
            Lack::Int64 => f.write_str("shaderInt64"),
            Lack::Int64Atomics => f.write_str("shaderBufferInt64Atomics"),
            Lack::BufferDeviceAddress => f.write_str("bufferDeviceAddress"),
            Lack::QueueTimestamps => f.write_str("timestamps on the compute queue"),
            Lack::SubgroupSize(has) => write!(f, "a subgroup size between 4 and 128 (device has {has})"),
        }
    }
}

/// The properties and limits of a device that the engine relies on, all queried, none assumed.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceCaps {
    /// Device name.
    pub name: String,
    /// Discrete, integrated, virtual, CPU or other (`discrete`, ... in JSON).
    pub device_type: DeviceType,
    /// Vulkan API version `major.minor.patch`.
    pub api_version: String,
    /// The API version as Vulkan encodes it.
    #[serde(skip)]
    pub(crate) api: u32,
    /// Driver name and version string (from `VkPhysicalDeviceDriverProperties`).
    pub driver: String,
    /// Raw driver version.
    pub driver_version: u32,
    /// PCI vendor id.
    pub vendor_id: u32,
    /// Vendor-specific device id (`VkPhysicalDeviceProperties::deviceID`).
    pub device_id: u32,
    /// `deviceUUID` of `VkPhysicalDeviceIDProperties`, 32 hex digits (zeros when the device reports none).
    pub device_uuid: String,
    /// `driverUUID` of `VkPhysicalDeviceIDProperties`, 32 hex digits.
    pub driver_uuid: String,
    /// `pipelineCacheUUID`, 32 hex digits: pipeline-cache data is only valid for the same one.
    pub pipeline_cache_uuid: String,
    /// The same three UUIDs as bytes.
    #[serde(skip)]
    pub(crate) uuids: [[u8; vk::UUID_SIZE]; 3],
    /// Subgroup size (the default one for compute).
    pub subgroup_size: u32,
    /// Smallest subgroup size the device may use (equal to `subgroup_size` without subgroup size control).
    pub min_subgroup_size: u32,
    /// Largest subgroup size.
    pub max_subgroup_size: u32,
    /// Supported subgroup operations (`basic`, `vote`, `arithmetic`, `ballot`, `shuffle`, ...).
    pub subgroup_operations: Vec<String>,
    /// The same as Vulkan reports them.
    #[serde(skip)]
    pub(crate) subgroup_flags: vk::SubgroupFeatureFlags,
    /// Whether subgroup operations are supported in compute shaders.
    pub subgroup_in_compute: bool,
    /// `maxComputeWorkGroupCount`.
    pub max_workgroup_count: [u32; 3],
    /// `maxComputeWorkGroupSize`.
    pub max_workgroup_size: [u32; 3],
    /// `maxComputeWorkGroupInvocations`.
    pub max_workgroup_invocations: u32,
    /// `maxComputeSharedMemorySize` in bytes.
    pub max_shared_memory: u32,
    /// `maxStorageBufferRange` in bytes.
    pub max_storage_buffer_range: u32,
    /// `maxMemoryAllocationSize` in bytes.
    pub max_memory_allocation_size: u64,
    /// `maxBufferSize` (Vulkan 1.3), when reported.
    pub max_buffer_size: Option<u64>,
    /// `maxPushConstantsSize` in bytes.
    pub max_push_constants_size: u32,
    /// `shaderFloat64`, supported and enabled (an owned context enables it where supported; see
    /// [`RawDevice::float64_enabled`]).
    pub float64: bool,
    /// The driver's ray tracing for compute ([`ray_tracing_device_extensions`], [`ray_tracing_device_features`]:
    /// acceleration structures and ray queries), supported and enabled (an owned context enables it where
    /// supported; see [`RawDevice::ray_query_enabled`]).
    pub ray_query: bool,
    /// `minAccelerationStructureScratchOffsetAlignment` (bytes; 0 without [`DeviceCaps::ray_query`]).
    pub acceleration_scratch_alignment: u32,
    /// `shaderInt64`.
    pub int64: bool,
    /// `shaderBufferInt64Atomics`.
    pub int64_atomics: bool,
    /// `bufferDeviceAddress`.
    pub buffer_device_address: bool,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period: f32,
    /// Valid bits of timestamps on the chosen queue family (0: no timestamps).
    pub timestamp_valid_bits: u32,
    /// Queue family used for compute.
    pub queue_family: Option<u32>,
}

impl DeviceCaps {
    /// Everything this device lacks for the engine (empty when it can run it).
    pub fn missing(&self) -> Vec<String> {
        self.lacks().iter().map(Lack::to_string).collect()
    }

    fn lacks(&self) -> Vec<Lack> {
        let mut m = Vec::new();
        if (vk::api_version_major(self.api), vk::api_version_minor(self.api)) < (1, 2) {
            m.push(Lack::Vulkan12(self.api_version.clone()));
        }
        if self.queue_family.is_none() {
            m.push(Lack::ComputeQueue);
        }
        if !self.subgroup_in_compute {
            m.push(Lack::SubgroupsInCompute);
        }
        for (flag, op) in NEEDED_SUBGROUP_OPS {
            if !self.subgroup_flags.contains(flag) {
                m.push(Lack::SubgroupOp(op));
            }
        }
        if !self.int64 {
            m.push(Lack::Int64);
        }
        if !self.int64_atomics {
            m.push(Lack::Int64Atomics);
        }
        if !self.buffer_device_address {
            m.push(Lack::BufferDeviceAddress);
        }
        if self.timestamp_valid_bits == 0 {
            m.push(Lack::QueueTimestamps);
        }
        if self.subgroup_size < 4 || self.max_subgroup_size > 128 || !self.subgroup_size.is_power_of_two() {
            m.push(Lack::SubgroupSize(self.subgroup_size));
        }
        m
    }

    /// What a pipeline-cache file of this device must match.
    pub(crate) fn cache_key(&self) -> CacheKey {
        CacheKey {
            device_uuid: self.uuids[0],
            driver_uuid: self.uuids[1],
            vendor_id: self.vendor_id,
            device_id: self.device_id,
            pipeline_cache_uuid: self.uuids[2],
        }
    }

    /// Workgroup size the kernels use: 256 invocations where the device allows it (at least one subgroup), never
    /// more than 64 subgroups of the smallest size.
    pub fn workgroup_size(&self) -> u32 {
        let cap = self.max_workgroup_size[0].min(self.max_workgroup_invocations).min(256);
        let cap = cap.min(64 * self.min_subgroup_size.max(1));
        cap.max(self.max_subgroup_size.min(self.max_workgroup_size[0]))
    }
}

/// A device as listed by [`enumerate_devices`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceSummary {
    /// Index in enumeration order (what `MESHCHAR_DEVICE=<index>` refers to).
    pub index: usize,
    /// Its properties.
    #[serde(flatten)]
    pub caps: DeviceCaps,
    /// What it lacks for the engine.
    pub missing: Vec<String>,
}

/// A device handed over by a host engine, for [`Context::from_raw`]. Build it with [`RawDevice::new`] (no
/// pipeline cache, no allocation callbacks) and set the other fields as needed:
/// `RawDevice { pipeline_cache, ..RawDevice::new(instance, device, physical_device, family, 0) }`.
pub struct RawDevice {
    /// The engine's instance.
    pub instance: ash::Instance,
    /// The engine's logical device, created with [`required_device_extensions`] and [`required_device_features`].
    pub device: ash::Device,
    /// The physical device of `device`.
    pub physical_device: vk::PhysicalDevice,
    /// A queue family with compute support and timestamps.
    pub queue_family_index: u32,
    /// The queue index within that family.
    pub queue_index: u32,
    /// The engine's pipeline cache, through which every kernel of the context is created; null: none. The context
    /// never destroys it (see [`Context::from_raw`] for what it must satisfy).
    pub pipeline_cache: vk::PipelineCache,
    /// The engine's host allocation callbacks, passed to every create and destroy call the context makes
    /// (pipelines, pipeline layouts, shader modules, query pools, command pools, fences, buffers); `None`: the
    /// driver's allocator. Device memory is allocated by gpu-allocator, which takes no callbacks.
    pub allocation_callbacks: Option<vk::AllocationCallbacks<'static>>,
    /// Whether `device` was created with `shaderFloat64` enabled (default `false`): the device traversal
    /// ([`crate::accel::device::DeviceTracer`]) needs it; nothing else does. [`DeviceCaps::float64`] of the context
    /// is true only when this is.
    pub float64_enabled: bool,
    /// Whether `device` was created with the extensions of [`ray_tracing_device_extensions`] and the features of
    /// [`ray_tracing_device_features`] (default `false`): the driver's acceleration structures
    /// ([`crate::accel::driver`]) need them; nothing else does. [`DeviceCaps::ray_query`] of the context is true
    /// only when this is.
    pub ray_query_enabled: bool,
}

impl RawDevice {
    /// The engine's device and queue, with no pipeline cache and no allocation callbacks.
    pub fn new(
        instance: ash::Instance,
        device: ash::Device,
        physical_device: vk::PhysicalDevice,
        queue_family_index: u32,
        queue_index: u32,
    ) -> Self {
        RawDevice {
            instance,
            device,
            physical_device,
            queue_family_index,
            queue_index,
            pipeline_cache: vk::PipelineCache::null(),
            allocation_callbacks: None,
            float64_enabled: false,
            ray_query_enabled: false,
        }
    }
}

/// Device extensions of the driver's ray tracing for compute (optional: [`crate::accel::driver`] needs them):
/// `VK_KHR_acceleration_structure`, `VK_KHR_ray_query` and `VK_KHR_deferred_host_operations` (which the first
/// requires).
pub fn ray_tracing_device_extensions() -> &'static [&'static CStr] {
    &[ash::khr::acceleration_structure::NAME, ash::khr::ray_query::NAME, ash::khr::deferred_host_operations::NAME]
}

/// Sets the features of the driver's ray tracing for compute (optional, beyond [`required_device_features`]):
/// `accelerationStructure` and `rayQuery` (with `bufferDeviceAddress`, already required). Returns their names.
pub fn ray_tracing_device_features(
    acceleration: &mut vk::PhysicalDeviceAccelerationStructureFeaturesKHR<'_>,
    ray_query: &mut vk::PhysicalDeviceRayQueryFeaturesKHR<'_>,
) -> &'static [&'static str] {
    acceleration.acceleration_structure = vk::TRUE;
    ray_query.ray_query = vk::TRUE;
    &["accelerationStructure", "rayQuery", "bufferDeviceAddress"]
}

/// Device extensions a host engine must enable for [`Context::from_raw`]. Everything the engine uses is core in
/// Vulkan 1.2, so the list is empty; it exists so that engines need not change when that stops being true.
pub fn required_device_extensions() -> &'static [&'static CStr] {
    &[]
}

/// Enables, in the host engine's feature structs, every device feature the engine needs: `shaderInt64`
/// (Vulkan 1.0), `bufferDeviceAddress` and `shaderBufferInt64Atomics` (Vulkan 1.2). Returns their names.
pub fn required_device_features(
    core: &mut vk::PhysicalDeviceFeatures,
    v12: &mut vk::PhysicalDeviceVulkan12Features<'_>,
) -> &'static [&'static str] {
    core.shader_int64 = vk::TRUE;
    v12.buffer_device_address = vk::TRUE;
    v12.shader_buffer_int64_atomics = vk::TRUE;
    &["shaderInt64", "bufferDeviceAddress", "shaderBufferInt64Atomics"]
}

type Messages = Arc<Mutex<Vec<String>>>;
type Messenger = (ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT);

/// The host engine's allocation callbacks ([`RawDevice::allocation_callbacks`]; none for owned contexts), passed
/// to every create and destroy call the context and its buffers, kernels and timers make.
#[derive(Clone, Copy, Default)]
pub(crate) struct HostAllocator(Option<vk::AllocationCallbacks<'static>>);

// SAFETY: the callbacks are plain function pointers and the engine's `pUserData`; `Context::from_raw`'s contract
// requires that they may be called from any thread, concurrently, and that `pUserData` stays valid as long as the
// context and everything made from it. The context never dereferences `pUserData` itself: it only hands the struct
// to Vulkan calls. (ash declares `AllocationCallbacks` Send and Sync unconditionally; this impl states the reason
// here instead of relying on that.)
unsafe impl Send for HostAllocator {}
// SAFETY: as above; the struct is never mutated after creation.
unsafe impl Sync for HostAllocator {}

impl HostAllocator {
    /// The callbacks to pass to a create or destroy call.
    pub(crate) fn get(&self) -> Option<&vk::AllocationCallbacks<'static>> {
        self.0.as_ref()
    }
}

/// Whether a context destroys its device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ownership {
    /// Created by the context ([`Context::new`]).
    Owned,
    /// A host engine's ([`Context::from_raw`]): never destroyed here.
    Borrowed,
}

/// Every Vulkan object a context made, the guard that destroys them: each is recorded here as soon as it exists,
/// so an error at any step of creation just returns and drops the guard, and a finished context drops it last.
/// Drop destroys in reverse order of creation: it waits for the device, frees the allocator's memory, destroys the
/// command pools and the context's own pipeline cache, then what the context owns: the device, the debug messenger,
/// the instance; then frees the message
/// sink the messengers write into, which must outlive `vkDestroyInstance` (the messenger chained to the instance's
/// creation may report during it); the loader is unloaded last.
#[derive(Default)]
struct Objects {
    /// The Vulkan loader (owned contexts).
    entry: Option<ash::Entry>,
    /// The boxed [`Messages`] the debug messengers get as user data (null without validation).
    sink: Option<std::ptr::NonNull<Messages>>,
    /// The instance, when the context created it.
    instance: Option<ash::Instance>,
    /// The debug messenger on that instance.
    messenger: Option<Messenger>,
    /// The device the pool and allocator belong to, and whether the context created it.
    device: Option<(ash::Device, Ownership)>,
    /// The idle command pools of the convenience submissions (one per submission in progress, reused after).
    pools: Mutex<Vec<vk::CommandPool>>,
    /// The pipeline cache the context created ([`Context::new`]); an engine's cache is never destroyed here.
    own_cache: Option<vk::PipelineCache>,
    /// The engine's allocation callbacks, for every create and destroy call.
    host_alloc: HostAllocator,
    /// The allocator.
    allocator: Option<Mutex<Allocator>>,
}

// SAFETY: the sink pointer is a boxed Arc only touched at creation and destruction, and by the driver's callback,
// which only locks the mutex inside it; everything else is Vulkan handles and ash's function tables.
unsafe impl Send for Objects {}
unsafe impl Sync for Objects {}

impl Drop for Objects {
    fn drop(&mut self) {
        // SAFETY: every buffer, kernel and timer holds an Arc<Inner>, so none is alive when the context's objects
        // go; the device is idle after the wait; each object is destroyed once, after everything made from it.
        unsafe {
            if let Some((device, ownership)) = &self.device {
                let _ = device.device_wait_idle();
                drop(self.allocator.take());
                let alloc = self.host_alloc.get();
                for pool in lock(&self.pools).drain(..) {
                    device.destroy_command_pool(pool, alloc);
                }
                if let Some(cache) = self.own_cache.take() {
                    device.destroy_pipeline_cache(cache, alloc);
                }
                if *ownership == Ownership::Owned {
                    device.destroy_device(None);
                }
            }
            if let Some((du, messenger)) = self.messenger.take() {
                du.destroy_debug_utils_messenger(messenger, None);
            }
            if let Some(instance) = &self.instance {
                instance.destroy_instance(None);
            }
            if let Some(sink) = self.sink.take() {
                drop(Box::from_raw(sink.as_ptr()));
            }
        }
        // `entry` drops after this, unloading the loader when nothing uses it any more.
    }
}

impl Objects {
    /// Loads Vulkan and creates an instance (with the validation layer and a messenger recording its warnings and
    /// errors when `validation`); the guard and the messages the messenger records.
    fn with_instance(validation: bool) -> Result<(Objects, Messages)> {
        let mut o = Objects::default();
        // SAFETY: loading the system Vulkan loader library; ash checks the symbols it resolves.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| GpuError::Loader(e.to_string()))?;
        // The guard keeps the loader loaded until everything made from it is destroyed.
        o.entry = Some(entry.clone());
        let messages: Messages = Arc::new(Mutex::new(Vec::new()));
        // SAFETY: plain queries of the loader.
        let loader_version =
            unsafe { entry.try_enumerate_instance_version() }.ok().flatten().unwrap_or(vk::API_VERSION_1_0);
        if vk::api_version_major(loader_version) == 1 && vk::api_version_minor(loader_version) < 2 {
            return Err(GpuError::Unsupported {
                name: "Vulkan loader".into(),
                missing: vec![format!(
                    "Vulkan 1.2 instance (loader supports {}.{})",
                    vk::api_version_major(loader_version),
                    vk::api_version_minor(loader_version)
                )],
            });
        }
        let api = if vk::api_version_minor(loader_version) >= 3 { vk::API_VERSION_1_3 } else { vk::API_VERSION_1_2 };
        let app =
            vk::ApplicationInfo::default().application_name(c"meshchar").engine_name(c"meshchar").api_version(api);
        let mut layers = Vec::new();
        let mut exts = Vec::new();
        if validation {
            // SAFETY: plain query.
            let available = unsafe { entry.enumerate_instance_layer_properties() }.unwrap_or_default();
            if !available.iter().any(|l| l.layer_name_as_c_str().is_ok_and(|n| n == VALIDATION_LAYER)) {
                return Err(GpuError::NoValidationLayer);
            }
            layers.push(VALIDATION_LAYER.as_ptr());
            exts.push(ash::ext::debug_utils::NAME.as_ptr());
            o.sink = Some(std::ptr::NonNull::from(Box::leak(Box::new(messages.clone()))));
        }
        let user = o.sink.map_or(std::ptr::null_mut(), |p| p.as_ptr() as *mut c_void);
        let messenger_info = || {
            vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(debug_callback))
                .user_data(user)
        };
        // Chained to the instance's creation, this messenger also reports during vkCreateInstance and
        // vkDestroyInstance.
        let mut chained = messenger_info();
        let mut info = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&exts);
        if validation {
            info = info.push_next(&mut chained);
        }
        // SAFETY: the create info and everything it points to live until the call returns; the sink outlives the
        // instance (see Drop).
        let instance = vk_check("vkCreateInstance", unsafe { entry.create_instance(&info, None) })?;
        o.instance = Some(instance.clone());
        if validation {
            let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
            // SAFETY: valid instance with VK_EXT_debug_utils enabled; the sink outlives the messenger.
            let m = vk_check("vkCreateDebugUtilsMessengerEXT", unsafe {
                du.create_debug_utils_messenger(&messenger_info(), None)
            })?;
            o.messenger = Some((du, m));
        }
        Ok((o, messages))
    }

    fn instance(&self) -> Result<&ash::Instance> {
        self.instance.as_ref().ok_or_else(|| GpuError::Buffer("context: no instance".into()))
    }
}

pub(crate) struct Inner {
    pub(crate) device: ash::Device,
    pub(crate) physical_device: vk::PhysicalDevice,
    pub(crate) queue: Mutex<vk::Queue>,
    pub(crate) queue_family: u32,
    pub(crate) caps: DeviceCaps,
    pub(crate) host_waits: std::sync::atomic::AtomicU64,
    /// The acceleration-structure functions, with [`DeviceCaps::ray_query`].
    pub(crate) acceleration: Option<ash::khr::acceleration_structure::Device>,
    /// The cache every kernel is created through (the context's own, the engine's, or null).
    pub(crate) pipeline_cache: vk::PipelineCache,
    /// Where [`Context::save_pipeline_cache`] writes the context's own cache.
    cache_file: Option<PathBuf>,
    /// What the context noticed and ignored ([`Context::warnings`]).
    warnings: Mutex<Vec<String>>,
    messages: Messages,
    /// Destroys everything above (the handles are copies of the ones it holds).
    objects: Objects,
}

impl Inner {
    /// The engine's allocation callbacks for every create and destroy call (`None`: the driver's allocator).
    pub(crate) fn alloc(&self) -> Option<&vk::AllocationCallbacks<'static>> {
        self.objects.host_alloc.get()
    }

    /// The allocator (always there once the context exists).
    pub(crate) fn allocator(&self) -> Result<MutexGuard<'_, Allocator>> {
        self.objects.allocator.as_ref().map(lock).ok_or_else(|| GpuError::Buffer("context: no allocator".into()))
    }
}

/// A Vulkan device ready for the engine's kernels. Cheap to clone (reference counted); buffers and kernels keep it
/// alive, so destruction happens in the right order whatever the drop order of the handles.
#[derive(Clone)]
pub struct Context {
    pub(crate) inner: Arc<Inner>,
}

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context").field("device", &self.inner.caps.name).finish()
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    if data.is_null() || user.is_null() {
        return vk::FALSE;
    }
    // SAFETY: the driver passes a valid callback data pointer; `user` is the boxed Arc created with the messenger.
    let (data, messages) = unsafe { (&*data, &*(user as *const Messages)) };
    let text = if data.p_message.is_null() {
        String::new()
    } else {
        // SAFETY: p_message is a NUL-terminated string when not null.
        unsafe { CStr::from_ptr(data.p_message) }.to_string_lossy().into_owned()
    };
    if let Ok(mut m) = messages.lock() {
        m.push(format!("[{severity:?} {types:?}] {text}"));
    }
    vk::FALSE
}

fn version_string(v: u32) -> String {
    format!("{}.{}.{}", vk::api_version_major(v), vk::api_version_minor(v), vk::api_version_patch(v))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn has_device_extension(instance: &ash::Instance, pdev: vk::PhysicalDevice, name: &CStr) -> bool {
    // SAFETY: plain query on a valid physical device.
    unsafe { instance.enumerate_device_extension_properties(pdev) }
        .unwrap_or_default()
        .iter()
        .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == name))
}

/// Queries everything the engine needs to know about a physical device.
pub(crate) fn query_caps(instance: &ash::Instance, pdev: vk::PhysicalDevice) -> DeviceCaps {
    // SAFETY: all calls are queries on a valid physical device; chained structs are only those the device supports.
    unsafe {
        let props = instance.get_physical_device_properties(pdev);
        let api = props.api_version;
        let v12 = vk::api_version_major(api) > 1 || vk::api_version_minor(api) >= 2;
        let v13 = vk::api_version_major(api) > 1 || vk::api_version_minor(api) >= 3;
        let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
        let mut maint3 = vk::PhysicalDeviceMaintenance3Properties::default();
        let mut driver = vk::PhysicalDeviceDriverProperties::default();
        let mut size_control = vk::PhysicalDeviceSubgroupSizeControlProperties::default();
        let mut maint4 = vk::PhysicalDeviceMaintenance4Properties::default();
        let mut ids = vk::PhysicalDeviceIDProperties::default();
        let v11 = vk::api_version_major(api) > 1 || vk::api_version_minor(api) >= 1;
        let has_size_control = v13 || has_device_extension(instance, pdev, ash::ext::subgroup_size_control::NAME);
        let has_maint4 = v13 || has_device_extension(instance, pdev, ash::khr::maintenance4::NAME);
        {
            let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut subgroup).push_next(&mut maint3);
            if v11 {
                p2 = p2.push_next(&mut ids);
            }
            if v12 {
                p2 = p2.push_next(&mut driver);
            }
            if has_size_control {
                p2 = p2.push_next(&mut size_control);
            }
            if has_maint4 {
                p2 = p2.push_next(&mut maint4);
            }
            instance.get_physical_device_properties2(pdev, &mut p2);
        }
        let has_rt = v12 && ray_tracing_device_extensions().iter().all(|e| has_device_extension(instance, pdev, e));
        let mut as_props = vk::PhysicalDeviceAccelerationStructurePropertiesKHR::default();
        if has_rt {
            let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut as_props);
            instance.get_physical_device_properties2(pdev, &mut p2);
        }
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f_as = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
        let mut f_rq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default();
        if v12 {
            f2 = f2.push_next(&mut f12);
        }
        if has_rt {
            f2 = f2.push_next(&mut f_as).push_next(&mut f_rq);
        }
        instance.get_physical_device_features2(pdev, &mut f2);
        let features = f2.features;
        let ray_query = has_rt && f_as.acceleration_structure == vk::TRUE && f_rq.ray_query == vk::TRUE;
        let families = instance.get_physical_device_queue_family_properties(pdev);
        let queue_family = families
            .iter()
            .enumerate()
            .filter(|(_, f)| f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.timestamp_valid_bits > 0)
            .map(|(i, _)| i as u32)
            .next()
            .or_else(|| {
                families.iter().position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE)).map(|i| i as u32)
            });
        let timestamp_valid_bits = queue_family.map(|q| families[q as usize].timestamp_valid_bits).unwrap_or(0);
        let ops = subgroup.supported_operations;
        let names = [
            (vk::SubgroupFeatureFlags::BASIC, "basic"),
            (vk::SubgroupFeatureFlags::VOTE, "vote"),
            (vk::SubgroupFeatureFlags::ARITHMETIC, "arithmetic"),
            (vk::SubgroupFeatureFlags::BALLOT, "ballot"),
            (vk::SubgroupFeatureFlags::SHUFFLE, "shuffle"),
            (vk::SubgroupFeatureFlags::SHUFFLE_RELATIVE, "shuffle_relative"),
            (vk::SubgroupFeatureFlags::CLUSTERED, "clustered"),
            (vk::SubgroupFeatureFlags::QUAD, "quad"),
        ];
        let (min_sg, max_sg) = if has_size_control && size_control.min_subgroup_size > 0 {
            (size_control.min_subgroup_size, size_control.max_subgroup_size)
        } else {
            (subgroup.subgroup_size, subgroup.subgroup_size)
        };
        let driver_name = if v12 {
            format!(
                "{} {}",
                driver.driver_name_as_c_str().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(),
                driver.driver_info_as_c_str().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
            )
            .trim()
            .to_string()
        } else {
            String::new()
        };
        DeviceCaps {
            name: props.device_name_as_c_str().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(),
            device_type: DeviceType::of(props.device_type),
            api_version: version_string(api),
            api,
            driver: driver_name,
            driver_version: props.driver_version,
            vendor_id: props.vendor_id,
            device_id: props.device_id,
            device_uuid: hex(&ids.device_uuid),
            driver_uuid: hex(&ids.driver_uuid),
            pipeline_cache_uuid: hex(&props.pipeline_cache_uuid),
            uuids: [ids.device_uuid, ids.driver_uuid, props.pipeline_cache_uuid],
            subgroup_size: subgroup.subgroup_size,
            min_subgroup_size: min_sg,
            max_subgroup_size: max_sg,
            subgroup_operations: names.iter().filter(|(f, _)| ops.contains(*f)).map(|(_, n)| n.to_string()).collect(),
            subgroup_flags: ops,
            subgroup_in_compute: subgroup.supported_stages.contains(vk::ShaderStageFlags::COMPUTE),
            max_workgroup_count: props.limits.max_compute_work_group_count,
            max_workgroup_size: props.limits.max_compute_work_group_size,
            max_workgroup_invocations: props.limits.max_compute_work_group_invocations,
            max_shared_memory: props.limits.max_compute_shared_memory_size,
            max_storage_buffer_range: props.limits.max_storage_buffer_range,
            max_memory_allocation_size: maint3.max_memory_allocation_size,
            max_buffer_size: has_maint4.then_some(maint4.max_buffer_size),
            max_push_constants_size: props.limits.max_push_constants_size,
            float64: features.shader_float64 == vk::TRUE,
            ray_query,
            acceleration_scratch_alignment: if ray_query {
                as_props.min_acceleration_structure_scratch_offset_alignment
            } else {
                0
            },
            int64: features.shader_int64 == vk::TRUE,
            int64_atomics: v12 && f12.shader_buffer_int64_atomics == vk::TRUE,
            buffer_device_address: v12 && f12.buffer_device_address == vk::TRUE,
            timestamp_period: props.limits.timestamp_period,
            timestamp_valid_bits,
            queue_family,
        }
    }
}

/// Picks a device: `wanted` (an index or a name substring) if given, else the best supported one by type.
fn pick(list: &[DeviceSummary], wanted: Option<&str>) -> Result<usize> {
    if list.is_empty() {
        return Err(GpuError::NoDevice);
    }
    if let Some(w) = wanted.map(str::trim).filter(|w| !w.is_empty()) {
        let names = || list.iter().map(|d| format!("{}: {}", d.index, d.caps.name)).collect::<Vec<_>>().join("; ");
        let found = match w.parse::<usize>() {
            Ok(i) => list.iter().position(|d| d.index == i),
            Err(_) => list.iter().position(|d| d.caps.name.to_lowercase().contains(&w.to_lowercase())),
        };
        return found.ok_or_else(|| GpuError::DeviceNotFound(w.to_string(), names()));
    }
    let best = list
        .iter()
        .enumerate()
        .filter(|(_, d)| d.missing.is_empty())
        .min_by_key(|(_, d)| (d.caps.device_type, d.index))
        .map(|(i, _)| i);
    match best {
        Some(i) => Ok(i),
        // No device is complete: report what the preferred one lacks.
        None => {
            let d = list.iter().min_by_key(|d| d.caps.device_type).ok_or(GpuError::NoDevice)?;
            Err(GpuError::Unsupported { name: d.caps.name.clone(), missing: d.missing.clone() })
        }
    }
}

/// Lists every Vulkan device with its capabilities, and the index (into the returned list) the engine would pick
/// (following `MESHCHAR_DEVICE` when set), or `None` when none is usable.
pub fn enumerate_devices() -> Result<(Vec<DeviceSummary>, Option<usize>)> {
    let (objects, _messages) = Objects::with_instance(false)?;
    let instance = objects.instance()?;
    // SAFETY: valid instance.
    let pdevs = unsafe { instance.enumerate_physical_devices() }.unwrap_or_default();
    let list = summaries(instance, &pdevs);
    let wanted = std::env::var("MESHCHAR_DEVICE").ok();
    let selected = pick(&list, wanted.as_deref()).ok().filter(|&i| list[i].missing.is_empty());
    Ok((list, selected))
}

/// The allocator's shared memory blocks: gpu-allocator's default sizes (256 MiB device-local, 64 MiB host-visible),
/// never above `maxMemoryAllocationSize` (Vulkan guarantees at least 1 GiB; gpu-allocator keeps blocks between
/// 4 MiB and 256 MiB).
fn memory_block_sizes(max_allocation: u64) -> (u64, u64) {
    const MIB: u64 = 1 << 20;
    let fit = |size: u64| size.min(max_allocation / (4 * MIB) * (4 * MIB)).max(4 * MIB);
    (fit(256 * MIB), fit(64 * MIB))
}

/// The summary of every physical device, in enumeration order.
fn summaries(instance: &ash::Instance, pdevs: &[vk::PhysicalDevice]) -> Vec<DeviceSummary> {
    pdevs
        .iter()
        .enumerate()
        .map(|(index, &p)| {
            let caps = query_caps(instance, p);
            let missing = caps.missing();
            DeviceSummary { index, caps, missing }
        })
        .collect()
}

impl Context {
    /// Creates an instance and a device of its own: validation layer and message recording when asked, device
    /// chosen as [`ContextDesc::device`] says, every requirement checked (the error lists all that is missing).
    pub fn new(desc: &ContextDesc) -> Result<Self> {
        let (mut objects, messages) = Objects::with_instance(desc.validation)?;
        let instance = objects.instance()?.clone();
        // SAFETY: valid instance.
        let pdevs = vk_check("vkEnumeratePhysicalDevices", unsafe { instance.enumerate_physical_devices() })?;
        let list = summaries(&instance, &pdevs);
        let wanted = desc.device.clone().or_else(|| std::env::var("MESHCHAR_DEVICE").ok());
        let chosen = pick(&list, wanted.as_deref())?;
        let DeviceSummary { index, caps, missing } = &list[chosen];
        if !missing.is_empty() {
            return Err(GpuError::Unsupported { name: caps.name.clone(), missing: missing.clone() });
        }
        let (pdev, mut caps) = (pdevs[*index], caps.clone());
        if let Some(cap) = desc.max_dispatch_groups {
            for c in &mut caps.max_workgroup_count {
                *c = (*c).min(cap.max(1));
            }
        }
        let Some(family) = caps.queue_family else {
            return Err(GpuError::Unsupported {
                name: caps.name.clone(),
                missing: vec![Lack::ComputeQueue.to_string()],
            });
        };
        let priorities = [1.0f32];
        let queue_info =
            [vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(&priorities)];
        let mut core = vk::PhysicalDeviceFeatures::default();
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
        required_device_features(&mut core, &mut v12);
        // Optional: the device traversal's exact division needs it, nothing else does.
        core.shader_float64 = caps.float64 as vk::Bool32;
        // Optional: the driver's acceleration structures and ray queries, where supported.
        let mut f_as = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
        let mut f_rq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default().features(core).push_next(&mut v12);
        let mut ext_names: Vec<*const std::ffi::c_char> =
            required_device_extensions().iter().map(|e| e.as_ptr()).collect();
        if caps.ray_query {
            ray_tracing_device_features(&mut f_as, &mut f_rq);
            f2 = f2.push_next(&mut f_as).push_next(&mut f_rq);
            ext_names.extend(ray_tracing_device_extensions().iter().map(|e| e.as_ptr()));
        }
        let info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_info)
            .enabled_extension_names(&ext_names)
            .push_next(&mut f2);
        // SAFETY: the physical device supports every enabled feature (checked by `missing`).
        let device = vk_check("vkCreateDevice", unsafe { instance.create_device(pdev, &info, None) })?;
        objects.device = Some((device.clone(), Ownership::Owned));
        let mut warnings = Vec::new();
        let cache = own_pipeline_cache(&device, &caps, desc.pipeline_cache.as_deref(), &mut warnings)?;
        objects.own_cache = Some(cache);
        let cache = CacheSetup { cache, file: desc.pipeline_cache.clone(), warnings };
        Self::finish(objects, &instance, device, pdev, family, 0, caps, messages, cache)
    }

    /// Wraps a host engine's device. The engine keeps ownership: dropping the context (and everything made from it)
    /// destroys only what the context created (its command pool, allocator, buffers and pipelines), never the
    /// device or instance.
    ///
    /// # Safety
    ///
    /// - `raw.device` must have been created from `raw.physical_device` of `raw.instance` with the features named
    ///   by [`required_device_features`] enabled and the extensions of [`required_device_extensions`], and with a
    ///   queue at `(queue_family_index, queue_index)` whose family supports compute.
    /// - The instance and device must outlive the returned context and every buffer, kernel and recorder made
    ///   from it.
    /// - The convenience submission paths ([`Context::submit_and_wait`]) submit to that queue: the engine must not
    ///   use the queue from another thread at the same time (Vulkan requires external synchronization of queues).
    /// - `raw.pipeline_cache`, when not null, is a pipeline cache of `raw.device` that stays alive (the context
    ///   never destroys it) as long as the context and every kernel made from it, and was not created with
    ///   `VK_PIPELINE_CACHE_CREATE_EXTERNALLY_SYNCHRONIZED_BIT`: kernels may be created through it from any thread
    ///   while the engine uses it too.
    /// - `raw.allocation_callbacks`, when set, follow Vulkan's rules for `VkAllocationCallbacks` and may be called
    ///   from any thread, concurrently, at any time until the context and everything made from it are dropped (they
    ///   free what they allocated then); their `pUserData` stays valid all that time. Every object the context
    ///   creates is created and destroyed with them (compatible callbacks, as Vulkan requires).
    pub unsafe fn from_raw(raw: RawDevice) -> Result<Self> {
        let caps = query_caps(&raw.instance, raw.physical_device);
        // The engine names its queue: what the device's own choice of compute queue lacks does not matter (the
        // given queue's timestamps are checked below).
        let missing: Vec<String> = caps
            .lacks()
            .iter()
            .filter(|m| !matches!(m, Lack::ComputeQueue | Lack::QueueTimestamps))
            .map(Lack::to_string)
            .collect();
        if !missing.is_empty() {
            return Err(GpuError::Unsupported { name: caps.name.clone(), missing });
        }
        let mut caps = caps;
        caps.queue_family = Some(raw.queue_family_index);
        caps.float64 &= raw.float64_enabled;
        caps.ray_query &= raw.ray_query_enabled;
        // SAFETY: per this function's contract.
        let families = unsafe { raw.instance.get_physical_device_queue_family_properties(raw.physical_device) };
        caps.timestamp_valid_bits =
            families.get(raw.queue_family_index as usize).map(|f| f.timestamp_valid_bits).unwrap_or(0);
        if caps.timestamp_valid_bits == 0 {
            return Err(GpuError::Unsupported {
                name: caps.name,
                missing: vec!["timestamps on the given queue".into()],
            });
        }
        let mut objects = Objects::default();
        objects.device = Some((raw.device.clone(), Ownership::Borrowed));
        objects.host_alloc = HostAllocator(raw.allocation_callbacks);
        let messages = Arc::new(Mutex::new(Vec::new()));
        let cache = CacheSetup { cache: raw.pipeline_cache, file: None, warnings: Vec::new() };
        Self::finish(
            objects,
            &raw.instance,
            raw.device,
            raw.physical_device,
            raw.queue_family_index,
            raw.queue_index,
            caps,
            messages,
            cache,
        )
    }

    /// The context on `device` (recorded in `objects`, with whatever else was created so far): its queue, command
    /// pool and allocator.
    #[allow(clippy::too_many_arguments)]
    fn finish(
        mut objects: Objects,
        instance: &ash::Instance,
        device: ash::Device,
        pdev: vk::PhysicalDevice,
        family: u32,
        queue_index: u32,
        caps: DeviceCaps,
        messages: Messages,
        cache: CacheSetup,
    ) -> Result<Self> {
        // SAFETY: valid device and queue family/index (ours, or the engine's per from_raw's contract).
        let queue = unsafe { device.get_device_queue(family, queue_index) };
        let mut debug_settings = gpu_allocator::AllocatorDebugSettings::default();
        debug_settings.log_leaks_on_shutdown = true;
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: pdev,
            debug_settings,
            buffer_device_address: true,
            allocation_sizes: {
                let (device_block, host_block) = memory_block_sizes(caps.max_memory_allocation_size);
                gpu_allocator::AllocationSizes::new(device_block, host_block)
            },
        })
        .map_err(|e| GpuError::Alloc { name: "allocator".into(), bytes: 0, source: e })?;
        objects.allocator = Some(Mutex::new(allocator));
        let acceleration = caps.ray_query.then(|| ash::khr::acceleration_structure::Device::new(instance, &device));
        Ok(Context {
            inner: Arc::new(Inner {
                device,
                physical_device: pdev,
                queue: Mutex::new(queue),
                queue_family: family,
                caps,
                host_waits: std::sync::atomic::AtomicU64::new(0),
                acceleration,
                pipeline_cache: cache.cache,
                cache_file: cache.file,
                warnings: Mutex::new(cache.warnings),
                messages,
                objects,
            }),
        })
    }

    /// The device's capabilities and limits.
    pub fn caps(&self) -> &DeviceCaps {
        &self.inner.caps
    }

    /// The logical device (for engines that record the engine's work into their own command buffers).
    pub fn device(&self) -> &ash::Device {
        &self.inner.device
    }

    /// The physical device.
    pub fn physical_device(&self) -> vk::PhysicalDevice {
        self.inner.physical_device
    }

    /// The queue family the context submits to.
    pub fn queue_family(&self) -> u32 {
        self.inner.queue_family
    }

    /// Every warning and error the validation layer reported so far (empty without validation).
    pub fn validation_messages(&self) -> Vec<String> {
        lock(&self.inner.messages).clone()
    }

    /// What the context noticed and ignored, as text: a pipeline-cache file that was corrupted, truncated or
    /// written for another device or driver ([`ContextDesc::pipeline_cache`]). The library prints nothing.
    pub fn warnings(&self) -> Vec<String> {
        lock(&self.inner.warnings).clone()
    }

    /// The pipeline cache every kernel is created through: the context's own ([`Context::new`]), the engine's
    /// ([`RawDevice::pipeline_cache`]), or null.
    pub fn pipeline_cache(&self) -> vk::PipelineCache {
        self.inner.pipeline_cache
    }

    /// The data of [`Context::pipeline_cache`] (`vkGetPipelineCacheData`: the driver's header and whatever it
    /// cached), empty when there is no cache.
    pub fn pipeline_cache_data(&self) -> Result<Vec<u8>> {
        if self.inner.pipeline_cache == vk::PipelineCache::null() {
            return Ok(Vec::new());
        }
        // SAFETY: a pipeline cache of this device, alive as long as the context (ours, or the engine's per
        // from_raw's contract), not externally synchronized.
        vk_check("vkGetPipelineCacheData", unsafe {
            self.inner.device.get_pipeline_cache_data(self.inner.pipeline_cache)
        })
    }

    /// Writes the context's pipeline cache to the file of [`ContextDesc::pipeline_cache`], atomically (a
    /// temporary file in the same directory, then a rename; the directory is created if needed), keyed by this
    /// device and driver. Returns the file's size in bytes, or `None` when the context has no cache file (no
    /// `pipeline_cache` path, or a host engine's device: the engine saves its own cache).
    pub fn save_pipeline_cache(&self) -> Result<Option<usize>> {
        let Some(path) = &self.inner.cache_file else { return Ok(None) };
        let data = self.pipeline_cache_data()?;
        let file = pipeline_cache::encode(&self.inner.caps.cache_key(), &data);
        pipeline_cache::write_atomic(path, &file)
            .map_err(|source| GpuError::PipelineCache { path: path.clone(), source })?;
        Ok(Some(file.len()))
    }

    /// How many times the context's convenience paths ([`Context::submit_and_wait`] and everything built on it)
    /// have waited on the host for the device. An engine counts the waits inside its frame with it: the recording
    /// paths never wait.
    pub fn host_waits(&self) -> u64 {
        self.inner.host_waits.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// A command pool of the context's queue family, idle and owned by the caller until [`Context::put_pool`].
    fn take_pool(&self) -> Result<vk::CommandPool> {
        if let Some(pool) = lock(&self.inner.objects.pools).pop() {
            return Ok(pool);
        }
        let info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(self.inner.queue_family)
            .flags(vk::CommandPoolCreateFlags::TRANSIENT);
        // SAFETY: valid device.
        vk_check("vkCreateCommandPool", unsafe { self.inner.device.create_command_pool(&info, self.inner.alloc()) })
    }

    /// Returns a pool taken by [`Context::take_pool`], reset (none of its command buffers is pending).
    fn put_pool(&self, pool: vk::CommandPool) {
        // SAFETY: no command buffer of the pool is pending (the caller waited or never submitted); the pool is
        // owned by this thread until it goes back to the list.
        let reset = unsafe { self.inner.device.reset_command_pool(pool, vk::CommandPoolResetFlags::empty()) };
        if reset.is_ok() {
            lock(&self.inner.objects.pools).push(pool);
        } else {
            // SAFETY: as above; a pool that cannot be reset is not reused.
            unsafe { self.inner.device.destroy_command_pool(pool, self.inner.alloc()) };
        }
    }

    /// Records one command buffer with `record`, submits it, waits for it, and returns what `record` returned.
    ///
    /// No lock is held while `record` runs or while the host waits: each call records into a command pool of its
    /// own (taken from an idle list), and the queue's mutex is held only around `vkQueueSubmit`. Every call counts
    /// in [`Context::host_waits`].
    pub fn submit_and_wait<T>(&self, record: impl FnOnce(&mut super::Recorder<'_>) -> Result<T>) -> Result<T> {
        let dev = &self.inner.device;
        let pool = self.take_pool()?;
        let result = (|| {
            let alloc = vk::CommandBufferAllocateInfo::default()
                .command_pool(pool)
                .level(vk::CommandBufferLevel::PRIMARY)
                .command_buffer_count(1);
            // SAFETY: the pool is owned by this call until put back.
            let cmd = vk_check("vkAllocateCommandBuffers", unsafe { dev.allocate_command_buffers(&alloc) })?[0];
            let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            // SAFETY: fresh command buffer from our pool.
            vk_check("vkBeginCommandBuffer", unsafe { dev.begin_command_buffer(cmd, &begin) })?;
            // SAFETY: `cmd` is recording, from a pool of the context's compute family owned by this call; the
            // call waits for the submission before anything recorded can be freed by the caller.
            let mut rec = unsafe { super::Recorder::new(self, cmd) };
            let value = record(&mut rec)?;
            // SAFETY: recording state.
            vk_check("vkEndCommandBuffer", unsafe { dev.end_command_buffer(cmd) })?;
            // SAFETY: valid device.
            let fence_info = vk::FenceCreateInfo::default();
            // SAFETY: valid device.
            let fence = vk_check("vkCreateFence", unsafe { dev.create_fence(&fence_info, self.inner.alloc()) })?;
            let cmds = [cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            let submitted = {
                let queue = lock(&self.inner.queue);
                // SAFETY: the queue is externally synchronized by its mutex; the command buffer is executable.
                vk_check("vkQueueSubmit", unsafe { dev.queue_submit(*queue, &submit, fence) })
            };
            let waited = submitted.and_then(|_| {
                self.inner.host_waits.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                // SAFETY: fence from this device; no lock is held while waiting.
                vk_check("vkWaitForFences", unsafe { dev.wait_for_fences(&[fence], true, u64::MAX) })
            });
            // SAFETY: the fence is signalled or was never submitted.
            unsafe { dev.destroy_fence(fence, self.inner.alloc()) };
            waited?;
            Ok(value)
        })();
        // The pool's command buffers are not pending (waited, or never submitted): resetting frees them.
        self.put_pool(pool);
        result
    }
}

/// The pipeline cache of [`Context::new`] and how it came to be.
struct CacheSetup {
    /// The cache kernels are created through (null: none).
    cache: vk::PipelineCache,
    /// The file [`Context::save_pipeline_cache`] writes.
    file: Option<PathBuf>,
    /// Why a file's data was not used.
    warnings: Vec<String>,
}

/// The context's own pipeline cache: `file`'s data when it holds a valid cache for this device and driver, else
/// empty (with a warning saying why, unless the file does not exist).
fn own_pipeline_cache(
    device: &ash::Device,
    caps: &DeviceCaps,
    file: Option<&Path>,
    warnings: &mut Vec<String>,
) -> Result<vk::PipelineCache> {
    let data = match file.map(|path| (path, pipeline_cache::load(path, &caps.cache_key()))) {
        Some((_, Ok(data))) => data,
        Some((path, Err(reason))) => {
            warnings.push(format!("pipeline cache {}: {reason}; using an empty cache", path.display()));
            Vec::new()
        }
        None => Vec::new(),
    };
    if let (Some(path), false) = (file, data.is_empty()) {
        let info = vk::PipelineCacheCreateInfo::default().initial_data(&data);
        // SAFETY: valid device; the data's Vulkan header names this device and its pipelineCacheUUID, and its
        // checksum matches what this crate wrote from vkGetPipelineCacheData.
        match unsafe { device.create_pipeline_cache(&info, None) } {
            Ok(cache) => return Ok(cache),
            Err(e) => warnings.push(format!(
                "pipeline cache {}: the driver refused its data ({e}); using an empty cache",
                path.display()
            )),
        }
    }
    let info = vk::PipelineCacheCreateInfo::default();
    // SAFETY: valid device.
    vk_check("vkCreatePipelineCache", unsafe { device.create_pipeline_cache(&info, None) })
}

pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_blocks_stay_within_the_allocation_limit() {
        const MIB: u64 = 1 << 20;
        assert_eq!(memory_block_sizes(1 << 30), (256 * MIB, 64 * MIB));
        assert_eq!(memory_block_sizes(u64::MAX), (256 * MIB, 64 * MIB));
        assert_eq!(memory_block_sizes(100 * MIB + 3), (100 * MIB, 64 * MIB));
        assert_eq!(memory_block_sizes(10 * MIB), (8 * MIB, 8 * MIB));
    }

    #[test]
    fn device_types_rank_and_print_as_before() {
        let mut t =
            [DeviceType::Other, DeviceType::Cpu, DeviceType::Virtual, DeviceType::Integrated, DeviceType::Discrete];
        t.sort();
        let names: Vec<String> = t.iter().map(|d| d.to_string()).collect();
        assert_eq!(names, ["discrete", "integrated", "virtual", "cpu", "other"]);
        assert_eq!(serde_json::to_string(&DeviceType::Cpu).ok().as_deref(), Some("\"cpu\""));
        assert_eq!(Lack::QueueTimestamps.to_string(), "timestamps on the compute queue");
        assert_eq!(Lack::SubgroupOp("ballot").to_string(), "subgroup ballot operations");
    }
}
