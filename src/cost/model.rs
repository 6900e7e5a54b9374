//! The calibrated cost model ([`CostModel`]): reading, validating and predicting with a calibration file.

use super::*;

/// A calibrated cost model: per structure constants, fit errors and provenance.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CostModel {
    /// File format version, [`COST_MODEL_VERSION`].
    pub version: u32,
    /// The device the constants were measured on (not empty).
    pub device: String,
    /// Where the measurements came from (command, files).
    pub source: String,
    /// Scenes of the calibration.
    pub scenes: Vec<String>,
    /// Names of the `phi` columns, [`FEATURE_NAMES`].
    pub feature_names: Vec<String>,
    /// Names of the trace price columns, [`PRICE_NAMES`].
    pub price_names: Vec<String>,
    /// One model per structure (at least one, each structure once).
    pub structures: Vec<StructureModel>,
    /// RMS log error of the totals over all samples and structures.
    #[serde(deserialize_with = "f64_or_null")]
    pub total_rms_log: f64,
    /// Refit model for animations, when calibrated.
    pub refit: Option<RefitModel>,
    /// Where the calibration's rays were traced: `cpu` (the counting CPU tracer) or `vulkan` (the device traversal
    /// kernel). Files written before the field existed are `cpu`.
    #[serde(default)]
    pub trace_backend: TraceBackend,
    /// The device that traced (`vulkan` only; absent for `cpu`): its name, type, driver, driver version and UUID
    /// as [`crate::accel::device::DeviceRecord`] records them. [`registry`] matches a device to a file by it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trace_device: Option<DeviceRecord>,
    /// The driver's acceleration structures ([`driver`]), when the calibration measured them (a device with ray
    /// queries); absent in files written before they existed, and for the CPU tracer.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub driver: Vec<DriverModel>,
    /// The ratios that turn timed probes into this calibration's times ([`timed::TimedRatios`]), when it was fitted
    /// with them (`calibrate --timed-probes`); absent otherwise, and then the policy cannot blend timed probes in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timed: Option<timed::TimedRatios>,
    /// The overlap floor's factors ([`CountBounds`]), read off the calibration's records.
    pub count_bounds: CountBounds,
    /// The calibration's own held-out errors of each structure's total, by what the selection knows
    /// ([`Uncertainty`]): what the selection's ladder weighs against the cost of knowing more. Absent in files
    /// written before it: then the selection decides on the prior alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<Uncertainty>,
    /// What each stage of a decision costs on the calibration's machine ([`InquiryCost`]), as laws in the triangle
    /// count; absent in files written before it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inquiry_costs: Vec<InquiryCost>,
    /// Which file this model was read from and why it was chosen (`assets/cost-model-lavapipe.json: device name
    /// ...`), set by [`CostModel::for_trace_target`]; not part of the file, `None` for a model made otherwise.
    #[serde(skip)]
    pub chosen_as: Option<String>,
}

impl CostModel {
    /// Parses and validates a calibration file's text (see the module docs, Validation): refuses another version,
    /// a missing, malformed or unknown field, and any value [`CostModel::validate`] refuses, naming the field.
    pub fn from_json(text: &str) -> Result<CostModel, CostError> {
        use serde_json::Value;
        let mut v: Value = serde_json::from_str(text).map_err(|e| CostError::Parse(e.to_string()))?;
        let Some(obj) = v.as_object_mut() else {
            return Err(invalid(None, "top level", format!("{}, not a JSON object", json_kind(&v))));
        };
        // The version first: a file of another version may have another layout.
        let found = match obj.get("version") {
            None => return Err(invalid(None, "version", "missing")),
            Some(x) => x.as_u64().ok_or_else(|| invalid(None, "version", format!("{x} is not a whole number")))?,
        };
        if found != u64::from(COST_MODEL_VERSION) {
            return Err(CostError::Version { found, expected: COST_MODEL_VERSION });
        }
        match obj.get("device") {
            None => return Err(invalid(None, "device", "missing")),
            Some(Value::String(_)) => {}
            Some(x) => return Err(invalid(None, "device", format!("{}, not a string", json_kind(x)))),
        }
        // The structures one by one, so that an error names the structure.
        let structures = match obj.remove("structures") {
            None => return Err(invalid(None, "structures", "missing")),
            Some(Value::Array(a)) => a,
            Some(x) => return Err(invalid(None, "structures", format!("{}, not an array", json_kind(&x)))),
        };
        let structures: Vec<StructureModel> =
            structures.into_iter().enumerate().map(|(i, s)| structure_from_json(i, s)).collect::<Result<_, _>>()?;
        obj.insert("structures".into(), Value::Array(Vec::new()));
        let mut m: CostModel = serde_json::from_value(v).map_err(|e| invalid(None, "top level", e.to_string()))?;
        m.structures = structures;
        m.validate()?;
        Ok(m)
    }

    /// Checks every rule of the module docs (Validation); the error names the first field that breaks one.
    pub fn validate(&self) -> Result<(), CostError> {
        if self.version != COST_MODEL_VERSION {
            return Err(CostError::Version { found: u64::from(self.version), expected: COST_MODEL_VERSION });
        }
        if self.device.trim().is_empty() {
            return Err(invalid(None, "device", "empty: name the device the constants were measured on"));
        }
        check_names("feature_names", &self.feature_names, &FEATURE_NAMES)?;
        check_names("price_names", &self.price_names, &PRICE_NAMES)?;
        if self.structures.is_empty() {
            return Err(invalid(None, "structures", "empty: no structure is calibrated"));
        }
        if let Some(t) = &self.timed {
            t.validate().map_err(|e| invalid(None, "timed", &e))?;
        }
        self.count_bounds.validate().map_err(|e| invalid(None, "count_bounds", &e))?;
        for (i, s) in self.structures.iter().enumerate() {
            if let Some(j) = self.structures[..i].iter().position(|t| t.structure == s.structure) {
                return Err(invalid(
                    Some(s.structure),
                    format!("structures[{i}].structure"),
                    format!("{} appears twice (also structures[{j}])", s.structure.as_str()),
                ));
            }
            check_structure(i, s)?;
        }
        check_number(None, "total_rms_log".into(), self.total_rms_log, 0.0..=f64::MAX, "a root-mean-square error")?;
        match (self.trace_backend, &self.trace_device) {
            (TraceBackend::Cpu, Some(_)) => {
                return Err(invalid(
                    None,
                    "trace_device",
                    "present with trace_backend cpu: only a device calibration names a device",
                ))
            }
            (TraceBackend::Vulkan, None) => {
                return Err(invalid(
                    None,
                    "trace_device",
                    "missing: a vulkan calibration names the device it was measured on",
                ))
            }
            (TraceBackend::Vulkan, Some(d)) if d.name.trim().is_empty() => {
                return Err(invalid(None, "trace_device.name", "empty: name the device the constants were measured on"))
            }
            _ => {}
        }
        if let Some(r) = &self.refit {
            let f = |name: &str| format!("refit.{name}");
            check_number(
                None,
                f("sah_growth_per_drift"),
                r.sah_growth_per_drift,
                SAH_GROWTH_RANGE,
                "the growth of the SAH ratio per unit of drift",
            )?;
            check_number(None, f("refit_ns_per_triangle"), r.refit_ns_per_triangle, 0.0..=PRICE_LIMIT_NS, "ns")?;
            if r.refit_ns_per_triangle == 0.0 {
                return Err(invalid(None, f("refit_ns_per_triangle"), "0: a refit visits every node, it is not free"));
            }
            check_number(None, f("fit_rms"), r.fit_rms, 0.0..=f64::MAX, "a root-mean-square error")?;
            if r.samples == 0 {
                return Err(invalid(None, f("samples"), "0: a refit model needs at least one measured frame pair"));
            }
        }
        for (i, d) in self.driver.iter().enumerate() {
            if let Some(j) = self.driver[..i].iter().position(|e| e.name == d.name) {
                return Err(invalid(
                    None,
                    format!("driver[{i}].name"),
                    format!("{} appears twice (also driver[{j}])", d.name),
                ));
            }
            d.validate(i)?;
        }
        if let Some(u) = &self.uncertainty {
            for (i, x) in u.structures.iter().enumerate() {
                let at = |f: &str| format!("uncertainty.structures[{i}] ({}).{f}", x.structure.as_str());
                let st = Some(x.structure);
                let figures = [
                    ("size", x.size),
                    ("prior", Some(x.prior)),
                    ("crossings", Some(x.crossings)),
                    ("probed", Some(x.probed)),
                ];
                let more = [("timed", x.timed), ("measured", x.measured)];
                for (name, v) in figures.into_iter().chain(more) {
                    if let Some(v) = v {
                        check_number(st, at(name), v, 0.0..=10.0, "an RMS error of ln(predicted / measured)")?;
                    }
                }
            }
        }
        for (i, c) in self.inquiry_costs.iter().enumerate() {
            let at = |f: &str| format!("inquiry_costs[{i}] ({}).{f}", c.stage);
            check_number(None, at("ln_a"), c.ln_a, BUILD_LN_A_RANGE, "ln of the ms of one triangle")?;
            check_number(None, at("exponent"), c.exponent, BUILD_EXPONENT_RANGE, "the exponent of n")?;
            check_number(None, at("rms"), c.rms, 0.0..=f64::MAX, "a root-mean-square error")?;
        }
        if !self.driver.is_empty() && self.trace_backend != TraceBackend::Vulkan {
            return Err(invalid(
                None,
                "driver",
                "present with trace_backend cpu: driver structures are traced on a Vulkan device",
            ));
        }
        Ok(())
    }

    /// The JSON text of a calibration file.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\":{:?}}}", e.to_string()))
    }

    /// Writes the calibration file.
    pub fn save(&self, path: &Path) -> Result<(), CostError> {
        std::fs::write(path, self.to_json() + "\n")
            .map_err(|source| CostError::Io { path: path.display().to_string(), source })
    }

    /// The shipped default (fitted on this project's oracle data, CPU structures).
    pub fn shipped() -> Result<CostModel, CostError> {
        CostModel::from_json(SHIPPED_CPU)
    }

    /// Loads a calibration file. With a path, that file: one that is missing or unreadable is an error
    /// ([`CostError::Io`]), and so is one that [`CostModel::from_json`] refuses ([`CostError::File`], with the path
    /// and the field). Without a path, the shipped default ([`CostModel::shipped`]). A file that was asked for is
    /// never replaced by the shipped default.
    pub fn load(path: Option<&Path>) -> Result<CostModel, CostError> {
        let Some(path) = path else {
            return CostModel::shipped();
        };
        let text = std::fs::read_to_string(path)
            .map_err(|source| CostError::Io { path: path.display().to_string(), source })?;
        CostModel::from_json(&text)
            .map_err(|e| CostError::File { path: path.display().to_string(), source: Box::new(e) })
    }

    /// The predicted ms of decision stage `stage` ([`InquiryCost`]) for `n` triangles; `None` without its law.
    pub(crate) fn inquiry_ms(&self, stage: &str, n: u64) -> Option<f64> {
        self.inquiry_costs.iter().find(|c| c.stage == stage).map(|c| c.ms(n))
    }

    /// The model of one structure.
    pub fn get(&self, s: StructureName) -> Option<&StructureModel> {
        self.structures.iter().find(|m| m.structure == s)
    }

    /// Predicted costs of every calibrated structure for a scene (its first frame's features) and a workload.
    ///
    /// A workload without a view is predicted for the framing camera of the features' bounds
    /// ([`ViewFeatures::framing`]), the oracle's default camera.
    pub fn predict(&self, f: &Features, w: &Workload) -> Vec<Prediction> {
        self.predict_floored(f, w, &|_| TestFloor::default())
    }

    /// Predicted costs from the triangle count `n` alone, before the mesh is characterized: each structure's size
    /// law ([`StructureModel::size`]) with its build law and prices, the framing camera; `None` when the file has no
    /// size laws.
    pub(crate) fn predict_size(&self, n: u64, w: &Workload) -> Option<Vec<Prediction>> {
        let d = Derived {
            ln_n: (n.max(1) as f64).ln(),
            fill_at_n: 0.0,
            ln_tris_per_cell: 0.0,
            empty_d3: 0.0,
            size_mean: 0.0,
            size_spread: 0.0,
            aspect_log2: 0.0,
        };
        let w = Workload { view: None, ..*w };
        let preds: Vec<Prediction> = self
            .structures
            .iter()
            .filter_map(|m| {
                let law = m.size.clone()?;
                let sized = StructureModel { prior: Some(law), ..m.clone() };
                Some(sized.predict(&d, n.max(1), &w))
            })
            .collect();
        (!preds.is_empty() && preds.len() == self.structures.len()).then_some(preds)
    }

    /// [`CostModel::predict`] with each structure's tests per ray bounded by `floor(structure)`
    /// ([`StructureModel::predict_floored`]); where a probed structure's counts are held to its sample, the
    /// structures of [`SHARES_PROBES`] that were not probed take the same correction.
    pub(crate) fn predict_floored(
        &self,
        f: &Features,
        w: &Workload,
        floor: &dyn Fn(StructureName) -> TestFloor,
    ) -> Vec<Prediction> {
        let d = f.derived();
        // Only a model fitted with views reads them: the others skip the framing camera's slab tests.
        let w = if self.structures.iter().any(|m| !m.view_box_coef.is_empty() || !m.view_prim_coef.is_empty()) {
            resolve_view(f, w)
        } else {
            *w
        };
        let n = f.scene_triangles();
        let band = self.own_probe_band();
        let mut preds: Vec<Prediction> = self
            .structures
            .iter()
            .map(|m| m.predict_corrected(&d, n, &w, floor(m.structure), [1.0, 1.0], band))
            .collect();
        self.share_probed_corrections(&d, n, &w, floor, &mut preds);
        preds
    }

    /// The band within which a probed structure keeps its own law instead of its sample's count
    /// ([`StructureModel::predict_floored`]): [`OWN_PROBE_BAND_CPU`] for a calibration traced on the CPU, where the
    /// probe traces the frame's own tree; [`PROBE_BAND`] for a device calibration.
    pub(crate) fn own_probe_band(&self) -> f64 {
        match self.trace_backend {
            TraceBackend::Cpu => OWN_PROBE_BAND_CPU,
            TraceBackend::Vulkan => PROBE_BAND,
        }
    }

    /// Where probed structures' counts were held to their samples ([`TestFloor::sampled`]), the unprobed structures
    /// of [`SHARES_PROBES`] take the same correction: their laws' box and triangle tests per ray times the geometric
    /// mean, over the probed structures, of the count held at [`PROBE_BAND`] over the law's (1 where a law lies
    /// within that band, whatever [`CostModel::own_probe_band`] held the structure's own count to), then their own
    /// floors as before. The
    /// laws' errors are shared across the hierarchies (see the module docs, Probes), so a count held for some
    /// alone would set them against others that keep the same error. `preds` are the predictions of
    /// [`CostModel::structures`], in that order.
    fn share_probed_corrections(
        &self,
        d: &Derived,
        n: u64,
        w: &Workload,
        floor: &dyn Fn(StructureName) -> TestFloor,
        preds: &mut [Prediction],
    ) {
        // Per count, the sum of `ln(held / law)` and how many probed structures gave one (a zero count, where every
        // sampled ray tests no triangle, says nothing about a ratio).
        let (mut boxes, mut prims) = ((0.0, 0u32), (0.0, 0u32));
        let add = |acc: &mut (f64, u32), held: f64, law: f64| {
            if held > 0.0 && law > 0.0 && held.is_finite() && law.is_finite() {
                acc.0 += (held / law).ln();
                acc.1 += 1;
            }
        };
        for m in &self.structures {
            let f = floor(m.structure);
            if f.sampled.is_some() && m.structure != StructureName::Grid {
                let law = m.predict_floored(d, n, w, TestFloor { sampled: None, ..f });
                let held = m.predict_corrected(d, n, w, f, [1.0, 1.0], PROBE_BAND);
                add(&mut boxes, held.box_tests_per_ray, law.box_tests_per_ray);
                add(&mut prims, held.prim_tests_per_ray, law.prim_tests_per_ray);
            }
        }
        let mean = |(sum, k): (f64, u32)| if k > 0 { (sum / f64::from(k)).exp() } else { 1.0 };
        let (gb, gp) = (mean(boxes), mean(prims));
        if gb == 1.0 && gp == 1.0 {
            return;
        }
        for (m, p) in self.structures.iter().zip(preds.iter_mut()) {
            let f = floor(m.structure);
            if SHARES_PROBES.contains(&m.structure) && f.sampled.is_none() {
                // The law corrected, then bounded by the structure's own floor as before.
                *p = m.predict_corrected(d, n, w, f, [gb, gp], PROBE_BAND);
            }
        }
    }

    /// Predicted costs of every calibrated driver structure ([`driver`]) for a scene and a workload.
    pub(crate) fn predict_driver(&self, f: &Features, w: &Workload) -> Vec<DriverPrediction> {
        let d = f.derived();
        self.driver.iter().filter_map(|m| m.predict(&d, f.scene_triangles(), w)).collect()
    }

    /// The model of one driver structure.
    pub fn get_driver(&self, f: crate::accel::driver::DriverFlags) -> Option<&DriverModel> {
        self.driver.iter().find(|m| m.name == f.name())
    }
}
