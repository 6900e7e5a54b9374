//! Which calibration file serves a tracer: the shipped models ([`SHIPPED_MODELS`]) and the rule that picks one for
//! the device the rays will be traced on ([`choose`], [`CostModel::for_trace_target`]).
//!
//! # The rule
//!
//! * Tracing on the CPU ([`TraceTarget::Cpu`], the default everywhere): the CPU calibration
//!   (`assets/cost-model-cpu.json`).
//! * Tracing on a Vulkan device ([`TraceTarget::Device`]), in order:
//!   1. a `vulkan` calibration whose recorded `device_uuid` equals the device's (an exact match; a file that
//!      records no UUID never matches here);
//!   2. a `vulkan` calibration of the same device family: lavapipe by name (the device name or the driver says
//!      `llvmpipe` or `lavapipe`, on both sides), otherwise the same device name; a different driver version is
//!      said in the reason;
//!   3. otherwise the CPU calibration, and the reason says that no calibration of this device exists (its
//!      prices are the CPU tracer's, not the device's).
//! * An explicit file (`--cost-model FILE`) overrides the rule ([`CostModel::for_trace_target`] with a path); the
//!   reason says when the file was measured on another tracer.
//!
//! Whatever chooses records which file it used and why in [`CostModel::chosen_as`], which the calibrated policy
//! puts in its first reason.

use super::{CostError, CostModel, SHIPPED_CPU, SHIPPED_LAVAPIPE};
use crate::accel::device::{DeviceRecord, TraceBackend};
use std::path::Path;

/// A calibration file shipped with the crate (compiled in).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShippedModel {
    /// Its path in the repository (`assets/cost-model-cpu.json`), as the reasons name it.
    pub file: &'static str,
    /// Its text.
    pub text: &'static str,
}

/// The shipped calibrations: the CPU tracer's first (the fallback), then lavapipe's.
pub const SHIPPED_MODELS: [ShippedModel; 2] = [
    ShippedModel { file: "assets/cost-model-cpu.json", text: SHIPPED_CPU },
    ShippedModel { file: "assets/cost-model-lavapipe.json", text: SHIPPED_LAVAPIPE },
];

/// Where the rays of the workload will be traced, for choosing a calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TraceTarget<'a> {
    /// The counting CPU tracer.
    Cpu,
    /// The device traversal kernel on this device.
    Device(&'a DeviceRecord),
}

impl TraceTarget<'_> {
    /// `cpu`, or the device's name and driver.
    pub fn describe(&self) -> String {
        match self {
            TraceTarget::Cpu => "the CPU tracer".to_string(),
            TraceTarget::Device(d) => format!("{} ({})", d.name, d.driver),
        }
    }
}

/// A calibration and why it was chosen.
#[derive(Clone, Debug, PartialEq)]
pub struct ChosenModel {
    /// Index into the candidates given to [`choose`].
    pub index: usize,
    /// Why (one sentence, without the file name).
    pub reason: String,
}

/// The family of a device for matching: `lavapipe` when its name or driver says `llvmpipe` or `lavapipe`
/// (lavapipe's device name is `llvmpipe (LLVM 15.0.6, 256 bits)`), else its name.
pub fn device_family(d: &DeviceRecord) -> String {
    let text = format!("{} {}", d.name, d.driver).to_lowercase();
    if text.contains("llvmpipe") || text.contains("lavapipe") {
        "lavapipe".to_string()
    } else {
        d.name.trim().to_string()
    }
}

/// The calibration among `candidates` for `target` (see the module docs for the rule). `None` only when no
/// candidate fits and none is a CPU calibration to fall back on.
pub fn choose(candidates: &[CostModel], target: TraceTarget<'_>) -> Option<ChosenModel> {
    let cpu = candidates.iter().position(|m| m.trace_backend == TraceBackend::Cpu);
    let d = match target {
        TraceTarget::Cpu => {
            return cpu.map(|index| ChosenModel { index, reason: "tracing on the CPU: the CPU calibration".into() })
        }
        TraceTarget::Device(d) => d,
    };
    let devices = || {
        candidates
            .iter()
            .enumerate()
            .filter(|(_, m)| m.trace_backend == TraceBackend::Vulkan)
            .filter_map(|(i, m)| m.trace_device.as_ref().map(|r| (i, r)))
    };
    let uuid = d.device_uuid.trim();
    if !uuid.is_empty() {
        if let Some((index, _)) = devices().find(|(_, r)| r.device_uuid.trim().eq_ignore_ascii_case(uuid)) {
            return Some(ChosenModel { index, reason: format!("the device UUID {uuid} of {} matches", d.name) });
        }
    }
    let family = device_family(d);
    if let Some((index, r)) = devices().find(|(_, r)| device_family(r) == family) {
        let how = if family == "lavapipe" { "lavapipe, matched by name" } else { "the same device name" };
        let driver = if r.driver_version != d.driver_version || r.driver != d.driver {
            format!(
                "; measured with driver {} (version {}), this one is {} (version {})",
                r.driver, r.driver_version, d.driver, d.driver_version
            )
        } else {
            String::new()
        };
        return Some(ChosenModel { index, reason: format!("{} is {how} ({}){driver}", d.name, r.name) });
    }
    cpu.map(|index| ChosenModel {
        index,
        reason: format!(
            "no calibration of {} ({}) is shipped: the CPU calibration is used, and its prices are the CPU tracer's, \
             not this device's (run calibrate --trace-backend vulkan and pass --cost-model)",
            d.name, d.driver
        ),
    })
}

impl CostModel {
    /// The shipped calibrations ([`SHIPPED_MODELS`]), parsed and validated, in that order.
    pub(crate) fn shipped_models() -> Result<Vec<CostModel>, CostError> {
        SHIPPED_MODELS
            .iter()
            .map(|s| {
                CostModel::from_json(s.text)
                    .map_err(|e| CostError::File { path: s.file.to_string(), source: Box::new(e) })
            })
            .collect()
    }

    /// The calibration for rays traced on `target`, with [`CostModel::chosen_as`] saying which file and why:
    /// `explicit` when given (loaded with [`CostModel::load`]; a file that cannot be used is an error, never
    /// replaced), else the shipped model that [`choose`] picks.
    pub fn for_trace_target(explicit: Option<&Path>, target: TraceTarget<'_>) -> Result<CostModel, CostError> {
        if let Some(path) = explicit {
            let mut m = CostModel::load(Some(path))?;
            let measured = match &m.trace_device {
                Some(d) => format!("{} on {}", m.trace_backend.as_str(), d.name),
                None => m.trace_backend.as_str().to_string(),
            };
            let fits = match (target, &m.trace_device) {
                (TraceTarget::Cpu, _) => m.trace_backend == TraceBackend::Cpu,
                (TraceTarget::Device(d), Some(r)) => device_family(d) == device_family(r),
                (TraceTarget::Device(_), None) => false,
            };
            let note =
                if fits { String::new() } else { format!(", measured with {measured}, not {}", target.describe()) };
            m.chosen_as = Some(format!("{}: --cost-model{note}", path.display()));
            return Ok(m);
        }
        let mut models = CostModel::shipped_models()?;
        let chosen = choose(&models, target).ok_or_else(|| CostError::NoCalibration(target.describe()))?;
        let mut m = models.swap_remove(chosen.index);
        m.chosen_as = Some(format!("{}: {}", SHIPPED_MODELS[chosen.index].file, chosen.reason));
        Ok(m)
    }
}
