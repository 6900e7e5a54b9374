//! The oracle's record: one scene under one workload, as `evaluate --json` writes it (one JSON object per line) and
//! as everything that reads oracle results reads it back: the cost-model fit ([`OracleRecord::sample`],
//! [`load_samples`]), the policy comparison ([`super::compare`]) and the trade-off study ([`super::tradeoff`]).
//!
//! A record is written with its keys in alphabetical order at every level (through [`serde_json::Value`], whose
//! maps are sorted), as the records in `docs/data` are. Fields that older records lack read as their defaults; a
//! number written as `null` (a NaN) reads back as NaN.

use super::oracle::{Measurement, Rebuild};
use crate::accel::{AccelStats, StructureName};
use crate::characterize::{features_cpu, Features, Params};
use crate::cost::{Prediction, Workload};
use crate::eval::fit::{DriverMeasured, Measured, Sample, StageCosts};
use crate::geom::Camera;
use crate::geom::WorkloadKind;
use serde::{Deserialize, Deserializer, Serialize};
use std::path::{Path, PathBuf};

/// Errors of reading oracle records.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A line is not a valid record.
    #[error("{place}: {reason}")]
    Parse {
        /// `file:line`.
        place: String,
        /// Why.
        reason: String,
    },
    /// Records of different tracers (backend or device) where one fit or comparison needs one tracer.
    #[error(
        "{place}: traced with {found}, but {first_place} with {first}: one calibration describes one tracer, \
         fit (or compare) the records of each backend and device apart"
    )]
    MixedTracers {
        /// `file:line` of the first record that differs.
        place: String,
        /// Its tracer ([`TracerOf::describe`]).
        found: String,
        /// `file:line` of the first record.
        first_place: String,
        /// The first record's tracer.
        first: String,
    },
    /// The scene a record names could not be loaded or characterized.
    #[error("{file}: {mesh}: {reason}")]
    Scene {
        /// The oracle file.
        file: String,
        /// The scene's path as recorded.
        mesh: String,
        /// Why.
        reason: String,
    },
}

fn nan_if_null<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

fn nan_pair_if_null<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
    let v = Option::<[Option<f64>; 2]>::deserialize(d)?.unwrap_or([None, None]);
    Ok([v[0].unwrap_or(f64::NAN), v[1].unwrap_or(f64::NAN)])
}

fn default_one() -> usize {
    1
}

fn default_once() -> Rebuild {
    Rebuild::Once
}

/// A pinhole camera as a record holds it ([`Camera`]'s fields).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    /// Eye position.
    pub eye: [f32; 3],
    /// Unit viewing direction.
    pub forward: [f32; 3],
    /// Unit right vector.
    pub right: [f32; 3],
    /// Unit up vector.
    pub up: [f32; 3],
    /// `tan(fov_y / 2)`.
    pub tan_half_fov: f32,
}

impl From<&Camera> for CameraRecord {
    fn from(c: &Camera) -> Self {
        CameraRecord {
            eye: c.eye.to_array(),
            forward: c.forward.to_array(),
            right: c.right.to_array(),
            up: c.up.to_array(),
            tan_half_fov: c.tan_half_fov,
        }
    }
}

impl CameraRecord {
    /// Checks that the record describes a camera rays can be made from: every number finite, the three directions of
    /// about unit length (0.5 to 2: the oracle writes them normalized, a hand-edited file may round them), and
    /// `tan_half_fov` in `(0, 1e4]` (a field of view short of 180 degrees). A record without these (all-zero
    /// vectors, a zero field of view) made every ray of a view the same and the measured policies trace minutes of
    /// them.
    pub fn check(&self) -> Result<(), String> {
        let vectors = [("eye", self.eye), ("forward", self.forward), ("right", self.right), ("up", self.up)];
        for (name, v) in vectors {
            if !v.iter().all(|x| x.is_finite()) {
                return Err(format!("camera.{name} {v:?} is not finite"));
            }
        }
        for (name, v) in &vectors[1..] {
            let len = v.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt();
            if !(0.5..=2.0).contains(&len) {
                return Err(format!("camera.{name} {v:?} has length {len}, not about 1"));
            }
        }
        let t = self.tan_half_fov;
        if !(t.is_finite() && t > 0.0 && t <= 1e4) {
            return Err(format!("camera.tan_half_fov {t} is not in (0, 1e4]"));
        }
        Ok(())
    }

    /// The camera.
    pub fn camera(&self) -> Camera {
        use glam::Vec3;
        Camera {
            eye: Vec3::from_array(self.eye),
            forward: Vec3::from_array(self.forward),
            right: Vec3::from_array(self.right),
            up: Vec3::from_array(self.up),
            tan_half_fov: self.tan_half_fov,
        }
    }
}

/// What the oracle measured for one structure on one scene and workload.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StructureRecord {
    /// Box tests (or node visits, cells) per ray.
    #[serde(default, deserialize_with = "nan_if_null")]
    pub box_tests_per_ray: f64,
    /// Median build time over the run (all builds of all frames), ms.
    #[serde(default, deserialize_with = "nan_if_null")]
    pub build_ms: f64,
    /// Smallest and largest build time over the repeats, ms.
    #[serde(default, deserialize_with = "nan_pair_if_null")]
    pub build_ms_range: [f64; 2],
    /// Where the structure was built: `host` (CPU builder; with `--trace-backend vulkan` its `build_ms` includes
    /// the upload, `upload_ms`) or `device` (device passes, timestamps). Absent in CPU-only records.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build_backend: Option<String>,
    /// Median upload of a host-built structure to the device (checks, staging, copies), ms; part of `build_ms`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub upload_ms: Option<f64>,
    /// Rays that disagreed with the reference.
    #[serde(default)]
    pub disagreements: usize,
    /// The build or validation error, if any.
    #[serde(default)]
    pub error: Option<String>,
    /// Whether every hit agreed with the reference on every frame.
    #[serde(default)]
    pub hits_agree: bool,
    /// Memory of the structure (largest frame), bytes.
    #[serde(default)]
    pub memory_bytes: usize,
    /// Millions of rays per second, from the median trace time.
    #[serde(default, deserialize_with = "nan_if_null")]
    pub mrays_per_s: f64,
    /// Which structure (`None` for a name this version does not know).
    #[serde(default, deserialize_with = "known_structure")]
    pub name: Option<StructureName>,
    /// Triangle tests per ray.
    #[serde(default, deserialize_with = "nan_if_null")]
    pub prim_tests_per_ray: f64,
    /// SAH cost (first frame), where it applies.
    #[serde(default)]
    pub sah_cost: Option<f64>,
    /// Statistics of `validate()` (first frame).
    #[serde(default)]
    pub stats: Option<AccelStats>,
    /// Median total (see [`super::oracle`]), ms.
    #[serde(default, deserialize_with = "nan_if_null")]
    pub total_ms: f64,
    /// Half the range of the totals over the repeats (the noise estimate), ms.
    #[serde(default, deserialize_with = "nan_if_null")]
    pub total_ms_spread: f64,
    /// The median total's 95% confidence interval, ms ([`super::oracle::median_ci95`]; from 6 repeats on). When
    /// present, "within noise" means overlapping intervals.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub total_ms_ci95: Option<[f64; 2]>,
    /// Repeats measured of this structure (the precise oracle measures every structure in rounds until every
    /// interval is narrow enough, or its cap);
    /// absent in records written before the field existed (then the record's `repeats`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub repeats_measured: Option<usize>,
    /// Under a precision target (the record's `precision`): whether the interval met it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub precision_met: Option<bool>,
    /// Median trace time over the run (all frames), ms.
    #[serde(default, deserialize_with = "nan_if_null")]
    pub trace_ms: f64,
    /// Smallest and largest trace time over the repeats, ms.
    #[serde(default, deserialize_with = "nan_pair_if_null")]
    pub trace_ms_range: [f64; 2],
    /// Whether `validate()` passed on every frame.
    #[serde(default)]
    pub valid: bool,
    /// Whether its total is within noise of the best total.
    #[serde(default)]
    pub within_noise_of_best: bool,
}

fn known_structure<'de, D: Deserializer<'de>>(d: D) -> Result<Option<StructureName>, D::Error> {
    Ok(Option::<String>::deserialize(d)?.and_then(|s| s.parse().ok()))
}

impl StructureRecord {
    /// Built, validated, agreed with the reference hits, and has a finite total that is not negative (no time is).
    pub fn ok(&self) -> bool {
        self.name.is_some() && self.valid && self.hits_agree && self.total_ms.is_finite() && self.total_ms >= 0.0
    }

    /// The total as a [`Measurement`]: the median with a symmetric range of the recorded spread.
    pub fn total(&self) -> Measurement {
        let spread = if self.total_ms_spread.is_finite() { self.total_ms_spread } else { 0.0 };
        Measurement {
            median: self.total_ms,
            min: self.total_ms - spread,
            max: self.total_ms + spread,
            spread,
            samples: self.repeats_measured.unwrap_or(0),
            ci95: self.total_ms_ci95,
        }
    }
}

/// The oracle's verdict on one scene and workload: one line of `evaluate --json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OracleRecord {
    /// Frames the totals stand for.
    #[serde(default = "default_one")]
    pub frames: usize,
    /// Frames measured (distinct geometries).
    #[serde(default = "default_one")]
    pub frames_measured: usize,
    /// Scene name (the path it was loaded from).
    pub mesh: String,
    /// Why no best structure is named (the workload traces no ray), when none is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub no_best_reason: Option<String>,
    /// The structure with the smallest median total.
    #[serde(default, deserialize_with = "known_structure")]
    pub oracle_best: Option<StructureName>,
    /// Among the structures within noise of the best, the one with the least median build time, then the least
    /// memory.
    #[serde(default, deserialize_with = "known_structure")]
    pub oracle_cheapest_within_noise: Option<StructureName>,
    /// The structures within noise of the best, the best included, in the order measured.
    #[serde(default)]
    pub oracle_within_noise: Vec<StructureName>,
    /// The policy that made `selected` (written by `evaluate`; absent in records from the library alone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub policy: Option<String>,
    /// The calibrated policy's predictions for every structure (written by `evaluate` when it has them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted: Option<Vec<Prediction>>,
    /// The calibration the calibrated policy used (file and why it was chosen, [`crate::cost::CostModel::chosen_as`]),
    /// when it selected.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cost_model: Option<String>,
    /// Rays per frame (first frame; 0 when the record does not say).
    #[serde(default)]
    pub rays_per_frame: usize,
    /// Whether structures were built once or per frame.
    #[serde(default = "default_once")]
    pub rebuild: Rebuild,
    /// Rays that hit (or were occluded) in the reference over every measured frame (0 in records written before
    /// the field existed).
    #[serde(default)]
    pub reference_hits: u64,
    /// `total(selected) / total(best) - 1`, when a selection was given and both were measured.
    #[serde(default)]
    pub regret: Option<f64>,
    /// Whether the selection is within noise of the best.
    #[serde(default)]
    pub regret_within_noise: Option<bool>,
    /// Repeats of the measurement (the least per structure under a precision target).
    #[serde(default = "default_one")]
    pub repeats: usize,
    /// The camera preset the scene was seen from (`evaluate --view`; [`crate::trace::views::View`]), when one was
    /// named.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<String>,
    /// The camera the rays were made from (absent in records written before the field existed: the framing camera
    /// of the scene's bounds). The calibrated policy reads it as the sample's view ([`crate::cost::ViewFeatures`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraRecord>,
    /// The precise oracle's target: the structures' totals were repeated until the 95% confidence interval of each
    /// median lay within this fraction of it, or the cap (each structure's `precision_met` says whether it did).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub precision: Option<f64>,
    /// Under a precision target: the cap on rounds the oracle ran under (`evaluate --max-repeats`, at least
    /// `--repeats`), absent in records written before the field existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_repeats: Option<usize>,
    /// Under a precision target: the measured time past which no round beyond `max_repeats` was begun, ms
    /// (`evaluate --precision-ms`; 0: none), absent in records written before the field existed (and where a library
    /// caller gave a non-finite allowance, which the command line refuses).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub precision_ms: Option<f64>,
    /// Under a precision target: how the repeats past the first were made. `every_structure`: in rounds of every
    /// structure until all intervals met the target (the oracle in rounds, [`super::oracle::OracleConfig::precision`]);
    /// absent in records written before, where a structure whose interval met the target stopped while the others
    /// went on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rounds: Option<String>,
    /// Image side of the workload.
    #[serde(default)]
    pub resolution: u32,
    /// The selection passed to the oracle, if any.
    #[serde(default, deserialize_with = "known_structure")]
    pub selected: Option<StructureName>,
    /// Per structure, in the order measured.
    pub structures: Vec<StructureRecord>,
    /// Where the rays were traced: `cpu` (the counting CPU tracer, rayon) or `vulkan` (the device traversal
    /// kernel, GPU timestamps). Records written before the field existed are `cpu`.
    #[serde(default)]
    pub trace_backend: super::oracle::TraceBackend,
    /// The device that traced (`--trace-backend vulkan`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<super::oracle::DeviceRecord>,
    /// How the device's hits were checked against the CPU reference (`--trace-backend vulkan`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hits_checked: Option<String>,
    /// Where the rays were made (`--trace-backend vulkan`): `device` (every workload's rays, checked bit for bit
    /// against the host's once per frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ray_generation: Option<String>,
    /// Triangles per frame.
    #[serde(default)]
    pub triangles: usize,
    /// The workload.
    pub workload: WorkloadKind,
    /// The driver's acceleration structures measured beside the project's (`--structures rt_*` with
    /// `--trace-backend vulkan`; see [`crate::accel::driver`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub driver_structures: Vec<super::oracle::DriverResult>,
    /// The refit candidates of an animation (`bvh_refit`, `lbvh_refit`: frame 0 built, later frames refitted;
    /// see [`super::oracle::RefitResult`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub refit_structures: Vec<super::oracle::RefitResult>,
    /// With driver structures: the best of all candidates by median total (the project's and the driver's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_candidate: Option<String>,
    /// With driver structures: the policy's overall choice among all candidates (`evaluate` writes it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub selected_candidate: Option<String>,
    /// With driver structures: `total(selected_candidate) / total(best_candidate) - 1`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub candidate_regret: Option<f64>,
}

impl OracleRecord {
    /// The JSON line (no trailing newline).
    pub fn to_json_line(&self) -> String {
        self.to_json().to_string()
    }

    /// The record as a JSON value (maps sorted by key).
    pub fn to_json(&self) -> serde_json::Value {
        // A record holds only strings, numbers, booleans, lists and maps with string keys: this cannot fail.
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }

    /// Reads a record from a parsed JSON value.
    pub fn from_json(v: &serde_json::Value) -> Result<OracleRecord, String> {
        OracleRecord::deserialize(v).map_err(|e| e.to_string())
    }

    /// Parses one JSON line.
    pub fn from_json_line(line: &str) -> Result<OracleRecord, String> {
        serde_json::from_str(line).map_err(|e| e.to_string())
    }

    /// The record of a structure that was measured validly (see [`StructureRecord::ok`]).
    pub fn get(&self, name: StructureName) -> Option<&StructureRecord> {
        self.structures.iter().find(|s| s.name == Some(name) && s.ok())
    }

    /// The valid structure with the smallest median total.
    pub fn best(&self) -> Option<&StructureRecord> {
        self.structures.iter().filter(|s| s.ok()).min_by(|a, b| a.total_ms.total_cmp(&b.total_ms))
    }

    /// The valid structures within noise of the best, the best included (see [`Measurement::within_noise`]).
    pub fn within_noise(&self) -> Vec<StructureName> {
        let Some(best) = self.best() else { return Vec::new() };
        let best = best.total();
        self.structures.iter().filter(|s| s.ok() && s.total().within_noise(&best)).filter_map(|s| s.name).collect()
    }

    /// Among [`OracleRecord::within_noise`], the least median build time, then the least memory.
    pub fn cheapest_within_noise(&self) -> Option<StructureName> {
        let near = self.within_noise();
        self.structures
            .iter()
            .filter(|s| s.name.is_some_and(|n| near.contains(&n)))
            .min_by(|a, b| a.build_ms.total_cmp(&b.build_ms).then(a.memory_bytes.cmp(&b.memory_bytes)))
            .and_then(|s| s.name)
    }

    /// `total(s) / total(best) - 1`, or `None` when `s` or the best was not validly measured.
    pub fn regret(&self, s: StructureName) -> Option<f64> {
        let (sel, best) = (self.get(s)?, self.best()?);
        (best.total_ms > 0.0).then(|| sel.total_ms / best.total_ms - 1.0)
    }

    /// The workload as the cost model sees it: rays per frame, frames, and how many builds the run made (one per
    /// frame for an animation or a per-frame rebuild, else one).
    pub fn cost_workload(&self) -> Workload {
        let frames = self.frames.max(1) as u64;
        let animated = self.frames_measured > 1;
        let builds = if animated || self.rebuild == Rebuild::PerFrame { frames } else { 1 };
        Workload { kind: self.workload, rays_per_frame: self.rays_per_frame as u64, frames, builds, view: None }
    }

    /// A calibration sample: the record's measurements with the scene's `features`. `baseline` defaults to the
    /// record's `selected` when its `policy` is `thesis` or absent (records written before policies had names).
    pub fn sample(&self, features: Features, baseline: Option<StructureName>) -> Sample {
        let mut workload = self.cost_workload();
        workload.view = self.camera.map(|c| crate::cost::ViewFeatures::of(&c.camera(), features.lo, features.hi));
        let measured = self
            .structures
            .iter()
            .filter_map(|s| {
                let name = s.name?;
                let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
                let mrays = finite(s.mrays_per_s);
                let build_ms = finite(s.build_ms);
                Some(Measured {
                    structure: name,
                    valid: s.valid && s.hits_agree && mrays > 0.0,
                    total_ms: finite(s.total_ms),
                    build_ms,
                    trace_ms: finite(s.trace_ms),
                    build_ms_per_build: build_ms / workload.builds as f64,
                    trace_ns_per_ray: if mrays > 0.0 { 1e3 / mrays } else { 0.0 },
                    box_tests_per_ray: finite(s.box_tests_per_ray),
                    prim_tests_per_ray: finite(s.prim_tests_per_ray),
                    within_noise_of_best: s.within_noise_of_best,
                    total_ms_ci95: s.total_ms_ci95,
                    build_work: s.stats.and_then(|st| st.build_work(name)).unwrap_or(0.0),
                })
            })
            .collect();
        let recorded = match self.policy.as_deref() {
            None | Some("thesis") => self.selected,
            Some(_) => None,
        };
        let driver = self
            .driver_structures
            .iter()
            .filter_map(|d| {
                let flags = crate::accel::driver::DriverFlags::parse(&d.name)?;
                let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
                let mrays = finite(d.mrays_per_s);
                // rt_update over an animation builds once and updates after: its build is its first frame's.
                let per_build = match (flags, d.frame_build_ms.first()) {
                    (crate::accel::driver::DriverFlags::Update, Some(&first)) if d.frame_build_ms.len() > 1 => {
                        finite(first)
                    }
                    _ => finite(d.build_ms) / workload.builds as f64,
                };
                Some(DriverMeasured {
                    flags,
                    valid: d.valid && d.hits_agree && mrays > 0.0,
                    total_ms: finite(d.total_ms),
                    build_ms_per_build: per_build,
                    trace_ns_per_ray: if mrays > 0.0 { 1e3 / mrays } else { 0.0 },
                    frame_build_ms: d.frame_build_ms.clone(),
                    frame_trace_ms: d.frame_trace_ms.clone(),
                })
            })
            .collect();
        Sample {
            scene: self.mesh.clone(),
            workload,
            features,
            measured,
            baseline: baseline.or(recorded),
            driver,
            frame_features: Vec::new(),
            crossings: None,
            timed: Vec::new(),
            frame_timings: Vec::new(),
            grid_build_work: 0.0,
            trace_backend: self.trace_backend,
            stage_ms: Default::default(),
        }
    }
}

/// Parses JSONL text (one record per line; blank lines skipped); `file` names the source in errors.
pub fn parse_jsonl(text: &str, file: &str) -> Result<Vec<OracleRecord>, RecordError> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            OracleRecord::from_json_line(l)
                .and_then(|r| r.camera.as_ref().map_or(Ok(()), CameraRecord::check).map(|()| r))
                .map_err(|reason| RecordError::Parse { place: format!("{file}:{}", i + 1), reason })
        })
        .collect()
}

/// The tracer of oracle records: the backend and, for `vulkan`, the device.
#[derive(Clone, Debug, PartialEq)]
pub struct TracerOf {
    /// Where the rays were traced.
    pub backend: super::oracle::TraceBackend,
    /// The device (`vulkan`).
    pub device: Option<super::oracle::DeviceRecord>,
}

impl TracerOf {
    /// `cpu`, or `vulkan on NAME (driver DRIVER, version V, UUID U)`.
    pub fn describe(&self) -> String {
        match &self.device {
            None => self.backend.as_str().to_string(),
            Some(d) => format!(
                "{} on {} (driver {}, version {}, UUID {})",
                self.backend.as_str(),
                d.name,
                d.driver,
                d.driver_version,
                if d.device_uuid.is_empty() { "none" } else { &d.device_uuid }
            ),
        }
    }
}

/// The one tracer of every record of `files` (`None` for no record at all); records of different backends or
/// devices (name, driver, driver version or UUID) are refused ([`RecordError::MixedTracers`], naming the first
/// record that differs and the first record), since one fit describes one tracer.
pub fn tracer_of(files: &[PathBuf]) -> Result<Option<TracerOf>, RecordError> {
    let mut first: Option<(String, TracerOf)> = None;
    for file in files {
        for (i, rec) in read_jsonl(file)?.into_iter().enumerate() {
            let place = format!("{}:{}", file.display(), i + 1);
            let t = TracerOf { backend: rec.trace_backend, device: rec.device };
            match &first {
                None => first = Some((place, t)),
                Some((first_place, f)) if *f != t => {
                    return Err(RecordError::MixedTracers {
                        place,
                        found: t.describe(),
                        first_place: first_place.clone(),
                        first: f.describe(),
                    })
                }
                Some(_) => {}
            }
        }
    }
    Ok(first.map(|(_, t)| t))
}

/// Reads a JSONL file of records (`evaluate --json` output, `--oracle-cache`, `docs/data/oracle-*.jsonl`).
pub fn read_jsonl(path: &Path) -> Result<Vec<OracleRecord>, RecordError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| RecordError::Io { path: file.clone(), source })?;
    parse_jsonl(&text, &file)
}

/// Calibration samples from oracle files: every scene named in a record is loaded from its recorded path (relative
/// to the working directory) once, and the features of its frames computed with `params`: the first frame's for
/// [`Sample::features`], and for an animation's records with driver structures the features of every measured frame
/// ([`Sample::frame_features`], against which an updated structure's drift is measured). `progress` receives the
/// name of each scene loaded.
pub fn load_samples(files: &[PathBuf], params: &Params, progress: &dyn Fn(&str)) -> Result<Vec<Sample>, RecordError> {
    load_samples_admitted(files, params, SampleProbes::default(), &|_, _| Ok(()), progress)
}

/// The camera a record was traced from: its own, or the framing camera of the mesh (what the oracle and the policy
/// assume without one).
fn record_camera(camera: Option<crate::geom::Camera>, mesh: &crate::mesh::Mesh) -> crate::geom::Camera {
    camera.unwrap_or_else(|| {
        let b = crate::trace::workload::mesh_bounds(mesh);
        crate::cost::view::framing_camera(b.min.to_array(), b.max.to_array())
    })
}

/// What [`load_samples_admitted`] measures anew on this machine, beside the records.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SampleProbes {
    /// The timed probes of every static scene's camera (`crate::cost::timed::time_probes` of every structure this
    /// build has, every kind of ray; taken once per scene and camera, on this machine, now) in [`Sample::timed`]:
    /// what the timed policy's ratios are fitted on ([`crate::cost::timed::TimedRatios::fit`]) and what it blends
    /// in. Records of animations get none.
    pub timed: bool,
    /// Whole frames of every static record's workload at its resolution, through every structure this build has
    /// (`crate::cost::measured::measure_frames`, [`crate::cost::measured::MEASURED_REPEATS`] times each after
    /// [`crate::cost::measured::MEASURED_WARMUP`] untimed rounds):
    /// [`Sample::frame_timings`], what a measured close call reads ([`crate::cost::measured::settle`]). Records of
    /// animations, or of several frames measured, or rebuilt every frame, get none.
    pub measured: bool,
}

/// [`load_samples`] with the probes of `probes` taken, and every scene passed to `admit` (its recorded path and its
/// first frame's triangle count) as soon as it is loaded and before any work on it: an `Err(reason)` fails the load with
/// [`RecordError::Scene`] naming the file, the record's mesh and the reason. A tool uses it to refuse a record
/// whose scene would need more memory than the process may have ([`Sample`]s keep every scene loaded until the
/// last record), as it refuses a scene given on its command line.
pub fn load_samples_admitted(
    files: &[PathBuf],
    params: &Params,
    probes: SampleProbes,
    admit: &dyn Fn(&str, usize) -> Result<(), String>,
    progress: &dyn Fn(&str),
) -> Result<Vec<Sample>, RecordError> {
    let timed = probes.timed;
    let probes_measured = probes.measured;
    // Per scene: the features of its frames, as far as computed, and the first frame's crossings per camera met
    // (the three workloads of a view share one), with its timed probes when taken.
    type Views =
        Vec<(Option<crate::geom::Camera>, crate::cost::Crossings, Vec<crate::cost::timed::TimedProbe>, StageCosts)>;
    // And the grid's references where the selection's bound pass counts them exactly (static scenes), and what the
    // scene's own stages cost (characterization, features, bounds).
    type Loaded = (crate::mesh::Animation, Vec<Features>, Views, f64, StageCosts);
    let mut cache: std::collections::HashMap<String, Loaded> = std::collections::HashMap::new();
    let mut out = Vec::new();
    for file in files {
        let name = file.display().to_string();
        for rec in read_jsonl(file)? {
            let scene_err = |reason: String| RecordError::Scene { file: name.clone(), mesh: rec.mesh.clone(), reason };
            if !cache.contains_key(&rec.mesh) {
                progress(&rec.mesh);
                let scene = super::scene::load_scene(Path::new(&rec.mesh)).map_err(|e| scene_err(e.to_string()))?;
                let first = scene.frames.first().ok_or_else(|| scene_err("the scene has no frames".into()))?;
                admit(&rec.mesh, first.triangle_count()).map_err(scene_err)?;
                let (f, mut costs) = time_scene_stages(first, params).map_err(scene_err)?;
                let grid_work = match &scene.frames[..] {
                    [only] => {
                        let t = std::time::Instant::now();
                        let b = crate::select::BuildBounds::of_mesh_with(only, &Default::default())
                            .map_err(|e| scene_err(format!("build bounds: {e}")))?;
                        costs.bounds_ms = t.elapsed().as_secs_f64() * 1e3;
                        b.grid_build_work().unwrap_or(0.0)
                    }
                    _ => 0.0,
                };
                cache.insert(rec.mesh.clone(), (scene, vec![f], Vec::new(), grid_work, costs));
            }
            let (scene, feats, views, grid_work, scene_costs) =
                cache.get_mut(&rec.mesh).ok_or_else(|| scene_err("not loaded".into()))?;
            let wanted = if rec.frames_measured > 1 && !rec.driver_structures.is_empty() {
                rec.frames_measured.min(scene.frames.len())
            } else {
                1
            };
            while feats.len() < wanted {
                let f = features_cpu(&scene.frames[feats.len()], params)
                    .map_err(|e| scene_err(format!("features of frame {}: {e}", feats.len())))?;
                feats.push(f);
            }
            let mut sample = rec.sample(feats[0].clone(), None);
            let camera = rec.camera.as_ref().map(|c| c.camera());
            // The record's camera counted on its image, what the policy computes from the mesh for the camera it
            // is given.
            let (viewed, probes, costs) = match views.iter().find(|v| v.0 == camera) {
                Some(v) => (v.1, v.2.clone(), v.3),
                None => {
                    let (c, crossings_ms, probe_ms) = crate::cost::Crossings::of_first_frame_timed(
                        &scene.frames[0],
                        camera.as_ref(),
                        scene.frames.len(),
                    );
                    let costs = StageCosts { crossings_ms, probe_ms, ..*scene_costs };
                    let probes = if timed && scene.frames.len() == 1 {
                        progress(&format!("{} (timed probes)", rec.mesh));
                        let cam = record_camera(camera, &scene.frames[0]);
                        crate::cost::timed::time_probes(
                            &scene.frames[0],
                            &cam,
                            &StructureName::ALL,
                            &[WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse],
                        )
                    } else {
                        Vec::new()
                    };
                    views.push((camera, c, probes.clone(), costs));
                    (c, probes, costs)
                }
            };
            sample.stage_ms = costs;
            if rec.rebuild == Rebuild::Once && rec.frames_measured <= 1 {
                sample.timed = probes;
                if probes_measured && scene.frames.len() == 1 {
                    let view = rec.view.as_deref().unwrap_or("framing");
                    progress(&format!("{} (measured frames, {view}, {})", rec.mesh, rec.workload.as_str()));
                    sample.frame_timings = crate::cost::measured::measure_frames(
                        &scene.frames[0],
                        &record_camera(camera, &scene.frames[0]),
                        rec.resolution,
                        rec.workload,
                        &StructureName::ALL,
                        crate::cost::measured::MEASURED_REPEATS,
                    );
                }
            }
            sample.crossings = Some(viewed.for_workload(rec.workload, camera.as_ref(), feats[0].lo, feats[0].hi));
            sample.grid_build_work = *grid_work;
            if wanted > 1 {
                sample.frame_features = feats[..wanted].to_vec();
            }
            out.push(sample);
        }
    }
    Ok(out)
}

/// The features of `mesh` and what its characterization and features take on this machine, warm (the median of
/// three timed runs after an untimed one; the characterization on the CPU path with its scratch kept, as an engine
/// keeps it across frames, and the features from its codes).
fn time_scene_stages(mesh: &crate::mesh::Mesh, params: &Params) -> Result<(Features, StageCosts), String> {
    use std::time::Instant;
    const RUNS: usize = 3;
    let mut scratch = crate::characterize::cpu::Scratch::default();
    let mut char_ms = Vec::with_capacity(RUNS);
    let mut feat_ms = Vec::with_capacity(RUNS);
    let mut features = None;
    for run in 0..=RUNS {
        let t = Instant::now();
        let ch = crate::characterize::cpu::fast_with(mesh, params, &mut scratch)
            .map_err(|e| format!("characterize: {e}"))?;
        let c = t.elapsed().as_secs_f64() * 1e3;
        // The features from the characterization's codes, as `Characterizer::characterize_with_features` takes them.
        let t = Instant::now();
        let f = match (&ch.per_triangle, scratch.sample_codes(ch.triangles as usize, params.morton_bits)) {
            (None, Some(codes)) => crate::characterize::features::features_of_codes(mesh, params, codes),
            _ => features_cpu(mesh, params),
        }
        .map_err(|e| format!("features: {e}"))?;
        let fm = t.elapsed().as_secs_f64() * 1e3;
        if run > 0 {
            char_ms.push(c);
            feat_ms.push(fm);
        }
        features = Some(f);
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let f = features.ok_or("no features")?;
    Ok((f, StageCosts { characterize_ms: median(char_ms), features_ms: median(feat_ms), ..Default::default() }))
}
