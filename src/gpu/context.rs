//! The device of a [`Context`]: an owned one ([`Context::new`]) or a host engine's ([`Context::from_raw`]), its
//! queue, allocator and pipeline cache. The device choice is in `adapter.rs`, the instance and the teardown guard in
//! `instance.rs`, the convenience submission in `submit.rs`.

use super::adapter::{
    pick, query_caps, ray_tracing_device_extensions, ray_tracing_device_features, required_device_extensions,
    required_device_features, summaries, DeviceCaps, DeviceSummary, Lack,
};
use super::instance::{lock, HostAllocator, Messages, Objects, Ownership};
use super::pipeline_cache;
use super::{vk_check, GpuError, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

/// How to create a [`Context`].
#[derive(Clone, Debug, Default)]
pub struct ContextDesc {
    /// Enable the Khronos validation layer and record every warning and error it reports (see
    /// [`Context::validation_messages`]). Tests always ask for it.
    pub validation: bool,
    /// Device to use: an index into [`enumerate_devices`](super::enumerate_devices)'s list or a case-insensitive substring of its name. `None`
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
    /// ([`crate::accel::device_trace::DeviceTracer`]) needs it; nothing else does. [`DeviceCaps::float64`] of the context
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
    pub(super) cache_file: Option<PathBuf>,
    /// What the context noticed and ignored ([`Context::warnings`]).
    pub(super) warnings: Mutex<Vec<String>>,
    pub(super) messages: Messages,
    /// Destroys everything above (the handles are copies of the ones it holds).
    pub(super) objects: Objects,
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

/// The allocator's shared memory blocks: gpu-allocator's default sizes (256 MiB device-local, 64 MiB host-visible),
/// never above `maxMemoryAllocationSize` (Vulkan guarantees at least 1 GiB; gpu-allocator keeps blocks between
/// 4 MiB and 256 MiB).
fn memory_block_sizes(max_allocation: u64) -> (u64, u64) {
    const MIB: u64 = 1 << 20;
    let fit = |size: u64| size.min(max_allocation / (4 * MIB) * (4 * MIB)).max(4 * MIB);
    (fit(256 * MIB), fit(64 * MIB))
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

    /// Every warning and error the validation layer reported so far (empty without validation). Only a context
    /// that owns its instance ([`Context::new`]) installs a messenger: on a borrowed device ([`Context::from_raw`])
    /// this is always empty, and the messages go to the engine's own messenger.
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
}
