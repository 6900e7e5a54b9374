//! Oracle results as calibration samples: a [`Sample`] is one scene under one workload, its [`Features`] and what
//! the oracle measured for every structure ([`crate::eval::record::OracleRecord::sample`] makes one from a record).

use crate::accel::driver::DriverFlags;
use crate::accel::StructureName;
use crate::characterize::Features;
use crate::cost::Workload;

/// What the oracle measured for one structure, normalized per build and per ray.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Measured {
    /// The structure.
    pub structure: StructureName,
    /// Built, validated and agreed with the reference hits.
    pub valid: bool,
    /// Median total ms of the run.
    pub total_ms: f64,
    /// Median build ms over the run.
    pub build_ms: f64,
    /// Median trace ms over the run.
    pub trace_ms: f64,
    /// Build ms of one build.
    pub build_ms_per_build: f64,
    /// Trace ns per ray.
    pub trace_ns_per_ray: f64,
    /// Box tests per ray.
    pub box_tests_per_ray: f64,
    /// Triangle tests per ray.
    pub prim_tests_per_ray: f64,
    /// Within noise of the best total.
    pub within_noise_of_best: bool,
    /// The 95% confidence interval of the median total (ms), when the precise oracle measured it.
    pub total_ms_ci95: Option<[f64; 2]>,
    /// The build's work ([`crate::accel::AccelStats::build_work`]), which the build law of a probed structure
    /// reads ([`crate::cost::StructureModel::build_work_coef`]); 0 when unknown.
    pub build_work: f64,
}

/// What the oracle measured for one driver structure ([`crate::eval::oracle::DriverResult`]), normalized per build
/// and per ray.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DriverMeasured {
    /// The build flags.
    #[serde(serialize_with = "flags_name")]
    pub flags: DriverFlags,
    /// Built, traced and agreed with the reference hits.
    pub valid: bool,
    /// Median total ms of the run.
    pub total_ms: f64,
    /// Median build ms of one build (for `rt_update` over an animation: its first frame's build).
    pub build_ms_per_build: f64,
    /// Trace ns per ray.
    pub trace_ns_per_ray: f64,
    /// Per measured frame of an animation, the build (or update) ms; empty for one frame.
    pub frame_build_ms: Vec<f64>,
    /// Per measured frame of an animation, the trace ms; empty for one frame.
    pub frame_trace_ms: Vec<f64>,
}

fn flags_name<S: serde::Serializer>(f: &DriverFlags, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(f.name())
}

/// One scene under one workload: features and measurements.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Sample {
    /// Scene name (path).
    pub scene: String,
    /// The workload measured.
    pub workload: Workload,
    /// Features of the first frame.
    pub features: Features,
    /// Per structure.
    pub measured: Vec<Measured>,
    /// The selection of the policy compared against (the thesis policy), when known.
    pub baseline: Option<StructureName>,
    /// Per driver structure measured (empty when the oracle measured none).
    pub driver: Vec<DriverMeasured>,
    /// Features of every measured frame of an animation (empty for one frame, or when not computed): the drift of
    /// an updated driver structure is measured against them.
    pub frame_features: Vec<Features>,
    /// The triangle boxes the record's rays cross on average (the first frame's `crate::cost::Crossings` for its
    /// workload and camera, `crate::cost::Crossings::for_workload`; `None` when not computed): the policies' overlap floor (`crate::cost::overlap_floor`) reads them.
    pub crossings: Option<crate::cost::RayCrossings>,
    /// The timed probes of the record's scene and camera (`crate::cost::timed::time_probes`), when taken (empty
    /// otherwise): what [`crate::cost::timed::TimedRatios::fit`] reads and the timed policy blends in.
    pub timed: Vec<crate::cost::timed::TimedProbe>,
    /// Whole frames of the record's workload measured anew per structure (`crate::cost::measured::measure_frames`),
    /// when taken (empty otherwise): what a measured close call ([`crate::cost::measured::settle`]) reads.
    pub frame_timings: Vec<crate::cost::measured::FrameTiming>,
    /// The grid's references counted exactly from the record's static scene where the selection's bound pass counts
    /// them (`select::BuildBounds::grid_build_work`: past `select::budget::grid_count_threshold`), which prices the
    /// grid's build as the policy does; 0 otherwise (not computed, an animation, or within the threshold).
    pub grid_build_work: f64,
    /// Where the record's rays were traced: the CPU tracer's samples fit their trace prices with each triangle-test
    /// price at least its box-test price ([`crate::cost::StructureModel::trace_price`]; `fit_prices` in `cost`), devices'
    /// without.
    pub trace_backend: crate::accel::device::TraceBackend,
    /// What each stage of a decision took on this scene and camera, measured warm on this machine when the sample
    /// was loaded ([`StageCosts`]); all 0 when not measured.
    pub stage_ms: StageCosts,
}

/// The wall time of each stage a decision may run on one scene and camera, ms, measured warm in this process on
/// the CPU path (each the median of a few runs after one untimed): what a policy that reads a stage pays for it.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct StageCosts {
    /// The characterization of the first frame (the CPU path, its scratch kept across runs as an engine keeps it).
    pub characterize_ms: f64,
    /// The scene features of the first frame.
    pub features_ms: f64,
    /// The build bounds of the grid and the kd-tree from the mesh (the pass that counts the grid's references).
    pub bounds_ms: f64,
    /// The crossings of the record's camera: the triangle boxes, their sums, the count on the image and the boxes
    /// entered before the hits.
    pub crossings_ms: f64,
    /// Each count probe, in the order of [`crate::cost::PROBED`] (its build and the traced sample).
    pub probe_ms: [f64; crate::cost::probe::PROBES],
}

impl StageCosts {
    /// The probe of `structure`, ms; `None` for a structure that is not probed.
    pub fn probe(&self, structure: StructureName) -> Option<f64> {
        crate::cost::PROBED.iter().position(|s| *s == structure).map(|i| self.probe_ms[i])
    }
}

impl Sample {
    /// The model's predictions for this sample's scene and workload, with the overlap floor of
    /// [`Sample::crossings`] and the grid's build priced by [`Sample::grid_build_work`] where known (what the
    /// calibrated policy predicts with the mesh at hand).
    pub fn predict(&self, model: &crate::cost::CostModel) -> Vec<crate::cost::Prediction> {
        model.predict_floored(&self.features, &self.workload, &|s| {
            crate::cost::priced_floor(&model.count_bounds, s, self.workload.kind, self.crossings, self.grid_build_work)
        })
    }

    /// The choice a measured close call of `preds` (this sample's predictions) makes from the sample's
    /// [`Sample::frame_timings`], over its workload's builds and frames, within the default measuring budget
    /// ([`crate::cost::measured::settle`], [`crate::cost::measured::DEFAULT_MAX_MS`]); `None` where nothing is settled.
    pub fn settle_close_call(&self, preds: &[crate::cost::Prediction]) -> Option<StructureName> {
        let w = &self.workload;
        crate::cost::measured::settle(
            preds,
            &self.frame_timings,
            w.builds,
            w.frames,
            crate::cost::measured::DEFAULT_MAX_MS,
        )
    }

    /// The measurement of one structure.
    pub fn get(&self, s: StructureName) -> Option<&Measured> {
        self.measured.iter().find(|m| m.structure == s)
    }

    /// The measurement of one driver structure.
    pub fn driver_result(&self, f: DriverFlags) -> Option<&DriverMeasured> {
        self.driver.iter().find(|m| m.flags == f)
    }

    /// The valid structure with the smallest measured total.
    pub fn best(&self) -> Option<&Measured> {
        self.measured.iter().filter(|m| m.valid && m.total_ms > 0.0).min_by(|a, b| a.total_ms.total_cmp(&b.total_ms))
    }

    /// `total(s) / total(best) - 1`; `None` when `s` or the best was not validly measured.
    pub fn regret(&self, s: StructureName) -> Option<f64> {
        let best = self.best()?;
        let m = self.get(s).filter(|m| m.valid)?;
        Some(m.total_ms / best.total_ms - 1.0)
    }

    /// The regret beyond the measurement's noise: how far the lower end of `s`'s 95% interval lies above the upper
    /// end of the best's, `max(0, low(s) / high(best) - 1)` (0 when the intervals overlap: the measurement cannot
    /// tell the two apart); [`Sample::regret`] when either has no interval. `None` as [`Sample::regret`].
    pub fn regret_beyond_noise(&self, s: StructureName) -> Option<f64> {
        let raw = self.regret(s)?;
        let best = self.best()?;
        let m = self.get(s)?;
        Some(match (m.total_ms_ci95, best.total_ms_ci95) {
            (Some([lo, _]), Some([_, hi])) if hi > 0.0 && lo.is_finite() && hi.is_finite() => (lo / hi - 1.0).max(0.0),
            _ => raw,
        })
    }
}
