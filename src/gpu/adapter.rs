//! Choosing a physical device: what the engine needs of one ([`required_device_features`],
//! [`required_device_extensions`], the optional ray-tracing ones), what a device has ([`DeviceCaps`], queried, never
//! assumed), and the list of devices with the one the engine would pick ([`enumerate_devices`]).

use super::instance::Objects;
use super::pipeline_cache::CacheKey;
use super::{GpuError, Result};
use ash::vk;
use std::ffi::CStr;

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
pub(super) enum Lack {
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
    /// [`RawDevice::float64_enabled`](super::RawDevice::float64_enabled)).
    pub float64: bool,
    /// The driver's ray tracing for compute ([`ray_tracing_device_extensions`], [`ray_tracing_device_features`]:
    /// acceleration structures and ray queries), supported and enabled (an owned context enables it where
    /// supported; see [`RawDevice::ray_query_enabled`](super::RawDevice::ray_query_enabled)).
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

    pub(super) fn lacks(&self) -> Vec<Lack> {
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

/// Device extensions a host engine must enable for [`Context::from_raw`](super::Context::from_raw). Everything the engine uses is core in
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
pub(super) fn pick(list: &[DeviceSummary], wanted: Option<&str>) -> Result<usize> {
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

/// The summary of every physical device, in enumeration order.
pub(super) fn summaries(instance: &ash::Instance, pdevs: &[vk::PhysicalDevice]) -> Vec<DeviceSummary> {
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

#[cfg(test)]
mod tests {
    use super::*;

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
