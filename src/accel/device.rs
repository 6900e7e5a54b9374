//! Which tracer measured and on what device: the [`TraceBackend`] of a measurement and the [`DeviceRecord`] that
//! records and calibration files name the device by.
//!
//! ```no_run
//! use meshchar::accel::device::{DeviceRecord, TraceBackend};
//! let ctx = meshchar::gpu::Context::new(&Default::default())?;
//! let record = DeviceRecord::of(&ctx);
//! assert_eq!("vulkan".parse::<TraceBackend>(), Ok(TraceBackend::Vulkan));
//! println!("{} ({}, driver {})", record.name, record.device_type, record.driver);
//! # Ok::<(), meshchar::gpu::GpuError>(())
//! ```

/// Where rays are traced: the oracle's `--trace-backend`, and the tracer a calibration describes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TraceBackend {
    /// The counting CPU tracer ([`crate::trace::trace`], rayon over rays); trace time is host wall time.
    #[default]
    Cpu,
    /// The device traversal kernel ([`crate::accel::device_trace`]); trace time is the kernel's GPU timestamps.
    Vulkan,
}

impl TraceBackend {
    /// `cpu` or `vulkan`.
    pub fn as_str(self) -> &'static str {
        match self {
            TraceBackend::Cpu => "cpu",
            TraceBackend::Vulkan => "vulkan",
        }
    }
}

impl std::str::FromStr for TraceBackend {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "cpu" => Ok(TraceBackend::Cpu),
            "vulkan" => Ok(TraceBackend::Vulkan),
            other => Err(format!("unknown trace backend {other:?} (cpu, vulkan)")),
        }
    }
}

/// The device a device oracle ran on, as its records name it.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeviceRecord {
    /// Device name.
    pub name: String,
    /// Device type (`cpu`, `discrete`, ...).
    #[serde(default)]
    pub device_type: String,
    /// Driver name and version.
    #[serde(default)]
    pub driver: String,
    /// Raw driver version.
    #[serde(default)]
    pub driver_version: u32,
    /// `deviceUUID`, 32 hex digits.
    #[serde(default)]
    pub device_uuid: String,
}

impl DeviceRecord {
    /// The record of a context's device.
    pub fn of(ctx: &crate::gpu::Context) -> Self {
        let c = ctx.caps();
        DeviceRecord {
            name: c.name.clone(),
            device_type: c.device_type.as_str().to_string(),
            driver: c.driver.clone(),
            driver_version: c.driver_version,
            device_uuid: c.device_uuid.clone(),
        }
    }
}
