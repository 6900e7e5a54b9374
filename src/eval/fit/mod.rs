//! Fitting a calibration: the cost model's constants from oracle records ([`Sample`]: what the oracle measured of
//! every structure on a scene and workload, with the scene's features). The model's form, and the predictions a
//! fitted model makes, are in [`crate::cost`]; this module holds only the estimation (`calibrate` runs it).
//!
//! Per structure: the build law by least squares in log space (`ln build = a + b ln n + d q(ln n)`, `d` held at 0
//! where it fits below or where the sizes span too little), the work law of the probed structures on samples whose
//! records counted the work, the test counts by ridge regression in log space, and the per-ray prices by
//! non-negative least squares on the measured counts, weighted by `1 / t^2` (relative error). Fit errors are
//! root-mean-square natural-log ratios of prediction to measurement ([`crate::cost::FitError`]).

mod bounds;
mod driver;
mod ladder;
mod laws;
pub(crate) mod linalg;
mod prior;
mod sample;
mod timed;

pub use crate::cost::drift;
pub use bounds::fit_count_bounds;
pub use driver::fit_driver;
pub(crate) use ladder::without_probes;
pub use ladder::{fit_inquiry_costs, fit_uncertainty};
pub use prior::{choose_prior_ridge, PRIOR_RIDGES};
pub use sample::{DriverMeasured, Measured, Sample, StageCosts};

use crate::accel::device::TraceBackend;
use crate::accel::StructureName;
use crate::cost::{
    timed::TimedRatios, CostError, CostModel, ViewFeatures, COST_MODEL_VERSION, FEATURE_NAMES, PRICE_NAMES, RIDGE,
};
use laws::{fit_structure, rms};

impl CostModel {
    /// Fits the driver structures' models ([`driver::fit_driver`]) on the samples' driver results, replacing
    /// [`CostModel::driver`]; structures with fewer than 3 valid samples are left out. Needs a model whose
    /// `trace_backend` is `vulkan` to validate.
    pub fn fit_driver(&mut self, samples: &[Sample]) -> Result<(), CostError> {
        let mut out = Vec::new();
        for f in crate::accel::driver::DriverFlags::ALL {
            if let Some(m) = fit_driver(samples, f)? {
                out.push(m);
            }
        }
        self.driver = out;
        for (i, d) in self.driver.iter().enumerate() {
            d.validate(i).map_err(|e| CostError::Fit(format!("the fitted driver model is out of range: {e}")))?;
        }
        Ok(())
    }

    /// Fits a model on oracle samples (see the module docs). Structures with fewer than 3 valid samples are left
    /// out. The driver structures are fitted apart ([`CostModel::fit_driver`]).
    pub fn fit(samples: &[Sample], device: &str, source: &str) -> Result<CostModel, CostError> {
        Self::fit_on(samples, device, source, true, RIDGE)
    }

    /// [`CostModel::fit`] with another ridge than [`RIDGE`] on the test-count laws' coefficients (`calibrate
    /// --ridge`): larger values shrink the geometric and view coefficients towards the size-only model. A ridge
    /// that is negative or not finite is an error.
    pub fn fit_with_ridge(samples: &[Sample], device: &str, source: &str, ridge: f64) -> Result<CostModel, CostError> {
        Self::fit_with(samples, device, source, ridge, false)
    }

    /// [`CostModel::fit_with_ridge`], and with `crossings` the test-count laws also take `ln(1 + crossings)`
    /// ([`crate::cost::StructureModel::crossing_coef`]) from each sample's [`Sample::crossings`] (none counts as 0): the
    /// triangle boxes a ray of the workload crosses (`crate::cost::TestFloor::crossings`), which the predictions then read
    /// from the floor they are given (`CostModel::predict_floored`). A caller without a count ([`CostModel::predict`],
    /// a floor of `crate::cost::TestFloor::default`) gets the samples' mean per workload kind
    /// ([`crate::cost::StructureModel::crossing_mean`]).
    pub fn fit_with(
        samples: &[Sample],
        device: &str,
        source: &str,
        ridge: f64,
        crossings: bool,
    ) -> Result<CostModel, CostError> {
        if !(ridge.is_finite() && ridge >= 0.0) {
            return Err(CostError::Fit(format!("the ridge must be a finite number at least 0, not {ridge}")));
        }
        Self::fit_on_with(samples, device, source, true, ridge, crossings)
    }

    /// The size-only model: [`CostModel::fit`] with every geometric feature left out of the test-count laws (their
    /// coefficients are zero), so that a prediction depends on the triangle count, the workload kind, the rays and
    /// the frames alone ([`crate::cost::SIZE_FEATURES`] of [`FEATURE_NAMES`]). Against the full model it measures what the
    /// scene's geometry adds to the choice (the thesis's first hypothesis).
    pub fn fit_size_only(samples: &[Sample], device: &str, source: &str) -> Result<CostModel, CostError> {
        Self::fit_on(samples, device, source, false, RIDGE)
    }

    fn fit_on(
        samples: &[Sample],
        device: &str,
        source: &str,
        geometric: bool,
        ridge: f64,
    ) -> Result<CostModel, CostError> {
        Self::fit_on_with(samples, device, source, geometric, ridge, false)
    }

    fn fit_on_with(
        samples: &[Sample],
        device: &str,
        source: &str,
        geometric: bool,
        ridge: f64,
        crossings: bool,
    ) -> Result<CostModel, CostError> {
        if samples.is_empty() {
            return Err(CostError::Fit("no samples".into()));
        }
        // The view enters the laws when some sample was seen from another camera than its scene's framing one (and
        // not in the size-only model): samples without a view stand for the framing camera. Records of the framing
        // camera alone, recorded or not, fit no view coefficient (there is nothing to learn it from), so the model
        // is then the one fitted before views existed.
        let views = geometric
            && samples
                .iter()
                .any(|s| s.workload.view.is_some_and(|v| v != ViewFeatures::framing(s.features.lo, s.features.hi)));
        let mut structures = Vec::new();
        for s in StructureName::ALL {
            if let Some(m) = fit_structure(samples, s, geometric, views, geometric && crossings, ridge)? {
                structures.push(m);
            }
        }
        if structures.is_empty() {
            return Err(CostError::Fit("no structure has 3 valid samples".into()));
        }
        let mut scenes: Vec<String> = samples.iter().map(|s| s.scene.clone()).collect();
        scenes.sort();
        scenes.dedup();
        // Samples all traced on a device make a device calibration (`calibrate` then names the device in full).
        let on_device = !samples.is_empty() && samples.iter().all(|s| s.trace_backend == TraceBackend::Vulkan);
        let (trace_backend, trace_device) = if on_device {
            let name = if device.is_empty() { "unnamed device" } else { device };
            (
                TraceBackend::Vulkan,
                Some(crate::accel::device::DeviceRecord { name: name.to_string(), ..Default::default() }),
            )
        } else {
            (TraceBackend::Cpu, None)
        };
        let mut m = CostModel {
            version: COST_MODEL_VERSION,
            device: device.to_string(),
            source: source.to_string(),
            scenes,
            feature_names: FEATURE_NAMES.iter().map(|s| s.to_string()).collect(),
            price_names: PRICE_NAMES.iter().map(|s| s.to_string()).collect(),
            structures,
            total_rms_log: 0.0,
            refit: None,
            trace_backend,
            trace_device,
            driver: Vec::new(),
            timed: TimedRatios::fit(samples),
            count_bounds: fit_count_bounds(samples),
            uncertainty: None,
            inquiry_costs: Vec::new(),
            chosen_as: None,
        };
        let mut se = Vec::new();
        for smp in samples {
            // With crossing coefficients the sample's crossings enter (and its floor with them); without, the plain
            // prediction, as before they existed.
            let preds = if crossings { smp.predict(&m) } else { m.predict(&smp.features, &smp.workload) };
            for p in preds {
                if let Some(meas) = smp.get(p.structure).filter(|x| x.valid && x.total_ms > 0.0) {
                    se.push((p.total_ms / meas.total_ms).ln());
                }
            }
        }
        m.total_rms_log = rms(&se);
        // A model that a calibration file could not hold is no calibration: say which constant the data pushed out
        // of range rather than write a file that `load` refuses.
        m.validate().map_err(|e| CostError::Fit(format!("the fitted model is out of range: {e}")))?;
        Ok(m)
    }
}
