//! A calibrated cost model: predicted build and trace time of every acceleration structure for a scene and a
//! workload, from the scene's [`Features`] and a few constants fitted on the device at hand.
//!
//! # Model
//!
//! For structure `s`, a scene of `n` triangles with features `f`, and a workload of `R` rays per frame, `F` frames
//! and `B` builds:
//!
//! ```text
//! build_ms(s)        = exp(a_s) * n^b_s                                  (per build; b_s ~ 1 for O(n), > 1 for n log n)
//! box_tests(s)       = exp(theta_box_s . phi(f, kind))                   (per ray)
//! prim_tests(s)      = exp(theta_prim_s . phi(f, kind))                  (per ray)
//! trace_ns(s)        = c_ray_s,kind + (c_box_s + [incoherent] c'_box_s) * box_tests(s)
//!                                 + (c_prim_s + [incoherent] c'_prim_s) * prim_tests(s)   (per ray, c >= 0)
//! total_ms(s)        = B * build_ms(s) + F * R * trace_ns(s) * 1e-6
//! ```
//!
//! `phi` ([`FEATURE_NAMES`]) is: an intercept, the workload kind (shadow, diffuse as indicators; primary is the
//! base), `ln n`, `ln` triangles per occupied Morton cell at the depth of a 4-cells-per-triangle grid, the occupied
//! share at one cell per triangle, the empty share at depth 3, the mean and spread of the triangle size exponents
//! and the `log2` aspect of the bounds ([`crate::characterize::features::Derived`]). The test counts are geometry
//! (device independent); `a_s, b_s, c_s` are the device's constants. The physical reading: builds are linear to
//! `n log n`; a ray's cost is its node visits and its triangle tests, each at a device-specific price; the counts
//! grow with `ln n` for hierarchies and with triangles per cell for a grid, and shrink where space is empty.
//!
//! # Fit
//!
//! [`CostModel::fit`] takes oracle results ([`Sample`]: measured build ms, trace ms, tests per ray of every
//! structure on every scene and workload) and fits, per structure: the build law by least squares in log space
//! (`ln build = a + b ln n`); the test counts by ridge regression in log space (ridge [`RIDGE`] on all but the
//! intercept); the per-ray prices by non-negative least squares on the measured counts, weighted by `1 / t^2` so
//! that the relative error is minimized. Fit errors are root-mean-square natural-log ratios of prediction to
//! measurement ([`FitError`]); `0.1` means about 10%.
//!
//! # Files
//!
//! A calibration file is the JSON of [`CostModel`] with `version` ([`COST_MODEL_VERSION`]) and `device`.
//! [`CostModel::load`] falls back to the shipped default (`assets/cost-model-cpu.json`, fitted on this project's
//! oracle data: the CPU structures of the oracle on the build machine; lavapipe runs on the same CPU, so it serves
//! for lavapipe hosts too) with a warning when the file is missing, unreadable, unparsable or of another version.

pub mod linalg;
mod sample;

use crate::accel::StructureName;
use crate::characterize::features::Derived;
use crate::characterize::Features;
use crate::geom::WorkloadKind;
use std::path::Path;

pub use sample::{drift, Measured, Sample};

/// Version of the calibration file format (and of the feature set `phi`). Files of another version are stale.
pub const COST_MODEL_VERSION: u32 = 1;

/// The shipped default calibration (CPU oracle on the project's build machine).
pub const SHIPPED_CPU: &str = include_str!("../../assets/cost-model-cpu.json");

/// Names of the columns of `phi` (see the module docs).
pub const FEATURE_NAMES: [&str; 10] = [
    "intercept",
    "shadow",
    "diffuse",
    "ln_n",
    "ln_tris_per_cell",
    "fill_at_n",
    "empty_d3",
    "size_mean",
    "size_spread",
    "aspect_log2",
];

/// Names of the trace price columns: a per-ray overhead for each workload kind, ns per box test and per triangle
/// test for coherent (primary) rays, and the extra ns per test for incoherent (shadow, diffuse) rays.
pub const PRICE_NAMES: [&str; 7] =
    ["ray_primary", "ray_shadow", "ray_diffuse", "box", "prim", "box_incoherent", "prim_incoherent"];

/// The price row of [`PRICE_NAMES`] for a kind and test counts.
pub fn price_row(kind: WorkloadKind, box_tests: f64, prim_tests: f64) -> Vec<f64> {
    let inc = (kind != WorkloadKind::Primary) as u8 as f64;
    vec![
        (kind == WorkloadKind::Primary) as u8 as f64,
        (kind == WorkloadKind::Shadow) as u8 as f64,
        (kind == WorkloadKind::Diffuse) as u8 as f64,
        box_tests,
        prim_tests,
        inc * box_tests,
        inc * prim_tests,
    ]
}

/// Ridge penalty of the test-count regressions (on every coefficient but the intercept).
pub const RIDGE: f64 = 0.05;

/// Errors of the cost model.
#[derive(Debug, thiserror::Error)]
pub enum CostError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A file or record could not be parsed.
    #[error("{0}")]
    Parse(String),
    /// A calibration file of another format version.
    #[error("calibration file version {found}, this build reads version {expected}")]
    Version {
        /// Version in the file.
        found: u32,
        /// [`COST_MODEL_VERSION`].
        expected: u32,
    },
    /// Too little or degenerate data to fit.
    #[error("cannot fit the cost model: {0}")]
    Fit(String),
}

/// What a structure is used for: rays per frame, frames and builds.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Workload {
    /// Kind of rays.
    pub kind: WorkloadKind,
    /// Rays traced per frame.
    pub rays_per_frame: u64,
    /// Frames traced.
    pub frames: u64,
    /// Builds over the run (1 for a static scene built once, `frames` when rebuilt every frame).
    pub builds: u64,
}

/// The phi row of [`FEATURE_NAMES`] for derived features and a workload kind.
pub fn phi(d: &Derived, kind: WorkloadKind) -> Vec<f64> {
    vec![
        1.0,
        (kind == WorkloadKind::Shadow) as u8 as f64,
        (kind == WorkloadKind::Diffuse) as u8 as f64,
        d.ln_n,
        d.ln_tris_per_cell,
        d.fill_at_n,
        d.empty_d3,
        d.size_mean,
        d.size_spread,
        d.aspect_log2,
    ]
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Fit errors of one structure or of the whole model: RMS of `ln(predicted / measured)` over the samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitError {
    /// Samples used.
    pub samples: usize,
    /// Build time per build.
    pub build: f64,
    /// Box tests per ray.
    pub box_tests: f64,
    /// Triangle tests per ray.
    pub prim_tests: f64,
    /// Trace ns per ray from the measured test counts (the price model alone).
    pub trace_given_counts: f64,
    /// Trace ns per ray from predicted counts.
    pub trace: f64,
    /// Total ms of the workload.
    pub total: f64,
}

/// The fitted constants of one structure (see the module docs for the formulas).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StructureModel {
    /// The structure.
    pub structure: StructureName,
    /// `a_s`: `ln` of the build ms of a one-triangle scene.
    pub build_ln_a: f64,
    /// `b_s`: exponent of `n` in the build time.
    pub build_exponent: f64,
    /// `theta_box_s`, one per [`FEATURE_NAMES`].
    pub box_coef: Vec<f64>,
    /// `theta_prim_s`, one per [`FEATURE_NAMES`].
    pub prim_coef: Vec<f64>,
    /// Trace prices, ns, one per [`PRICE_NAMES`] (all `>= 0`).
    pub trace_price: Vec<f64>,
    /// Fit errors on the calibration samples.
    pub fit: FitError,
}

/// A structure's predicted costs for a scene and workload.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Prediction {
    /// The structure.
    pub structure: StructureName,
    /// Build ms of one build.
    pub build_ms_per_build: f64,
    /// Build ms over the run.
    pub build_ms: f64,
    /// Predicted box tests per ray.
    pub box_tests_per_ray: f64,
    /// Predicted triangle tests per ray.
    pub prim_tests_per_ray: f64,
    /// Predicted trace ns per ray.
    pub trace_ns_per_ray: f64,
    /// Trace ms over the run.
    pub trace_ms: f64,
    /// `build_ms + trace_ms`.
    pub total_ms: f64,
}

impl StructureModel {
    /// Predicted costs for features `d` of a scene with `n` triangles and a workload.
    pub fn predict(&self, d: &Derived, n: u64, w: &Workload) -> Prediction {
        let x = phi(d, w.kind);
        let bx = dot(&self.box_coef, &x).clamp(-30.0, 30.0).exp();
        let pr = dot(&self.prim_coef, &x).clamp(-30.0, 30.0).exp();
        let ns = dot(&self.trace_price, &price_row(w.kind, bx, pr));
        let per_build = (self.build_ln_a + self.build_exponent * (n.max(1) as f64).ln()).exp();
        let build_ms = per_build * w.builds as f64;
        let trace_ms = ns * 1e-6 * w.rays_per_frame as f64 * w.frames as f64;
        Prediction {
            structure: self.structure,
            build_ms_per_build: per_build,
            build_ms,
            box_tests_per_ray: bx,
            prim_tests_per_ray: pr,
            trace_ns_per_ray: ns,
            trace_ms,
            total_ms: build_ms + trace_ms,
        }
    }
}

/// Per-frame refit model for animations (see [`crate::select::plan_frames`]): a refitted BVH's SAH cost grows with the drift of the
/// geometry since its build, `sah_refit / sah_fresh = 1 + sah_growth_per_drift * drift`, and a refit costs
/// `refit_ns_per_triangle * n`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RefitModel {
    /// Slope of the SAH ratio in the drift ([`drift`]).
    pub sah_growth_per_drift: f64,
    /// Refit time per triangle, ns.
    pub refit_ns_per_triangle: f64,
    /// RMS error of the SAH ratio fit (absolute, in ratio units).
    pub fit_rms: f64,
    /// Frame pairs measured.
    pub samples: usize,
}

/// A calibrated cost model: per structure constants, fit errors and provenance.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CostModel {
    /// File format version, [`COST_MODEL_VERSION`].
    pub version: u32,
    /// The device the constants were measured on.
    pub device: String,
    /// Where the measurements came from (command, files).
    pub source: String,
    /// Scenes of the calibration.
    pub scenes: Vec<String>,
    /// Names of the `phi` columns, [`FEATURE_NAMES`].
    pub feature_names: Vec<String>,
    /// One model per structure.
    pub structures: Vec<StructureModel>,
    /// RMS log error of the totals over all samples and structures.
    pub total_rms_log: f64,
    /// Refit model for animations, when calibrated.
    pub refit: Option<RefitModel>,
}

impl CostModel {
    /// Parses a calibration file's text; refuses other versions.
    pub fn from_json(text: &str) -> Result<CostModel, CostError> {
        let v: serde_json::Value = serde_json::from_str(text).map_err(|e| CostError::Parse(e.to_string()))?;
        let found = v.get("version").and_then(|x| x.as_u64()).ok_or_else(|| CostError::Parse("no version".into()))?;
        if found != COST_MODEL_VERSION as u64 {
            return Err(CostError::Version { found: found.min(u32::MAX as u64) as u32, expected: COST_MODEL_VERSION });
        }
        let m: CostModel = serde_json::from_value(v).map_err(|e| CostError::Parse(e.to_string()))?;
        if m.feature_names.len() != FEATURE_NAMES.len()
            || m.structures.iter().any(|s| {
                s.box_coef.len() != FEATURE_NAMES.len()
                    || s.prim_coef.len() != FEATURE_NAMES.len()
                    || s.trace_price.len() != PRICE_NAMES.len()
            })
        {
            return Err(CostError::Parse(format!("expected {} feature coefficients", FEATURE_NAMES.len())));
        }
        Ok(m)
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

    /// Loads a calibration file; without a path, or when the file is missing, unreadable, unparsable or of another
    /// version, the shipped default with a warning (logged with `log::warn` and returned as the note).
    pub fn load(path: Option<&Path>) -> Result<(CostModel, Option<String>), CostError> {
        let Some(path) = path else {
            return Ok((CostModel::shipped()?, None));
        };
        let why = match std::fs::read_to_string(path) {
            Err(e) => format!("cannot read {}: {e}", path.display()),
            Ok(text) => match CostModel::from_json(&text) {
                Ok(m) => return Ok((m, None)),
                Err(e) => format!("{}: {e}", path.display()),
            },
        };
        let note = format!("{why}; using the shipped default calibration");
        log::warn!("{note}");
        Ok((CostModel::shipped()?, Some(note)))
    }

    /// The model of one structure.
    pub fn get(&self, s: StructureName) -> Option<&StructureModel> {
        self.structures.iter().find(|m| m.structure == s)
    }

    /// Predicted costs of every calibrated structure for a scene (its first frame's features) and a workload.
    pub fn predict(&self, f: &Features, w: &Workload) -> Vec<Prediction> {
        let d = f.derived();
        self.structures.iter().map(|m| m.predict(&d, f.total_triangles.max(f.triangles), w)).collect()
    }

    /// Fits a model on oracle samples (see the module docs). Structures with fewer than 3 valid samples are left
    /// out.
    pub fn fit(samples: &[Sample], device: &str, source: &str) -> Result<CostModel, CostError> {
        if samples.is_empty() {
            return Err(CostError::Fit("no samples".into()));
        }
        let mut structures = Vec::new();
        for s in StructureName::ALL {
            if let Some(m) = fit_structure(samples, s)? {
                structures.push(m);
            }
        }
        if structures.is_empty() {
            return Err(CostError::Fit("no structure has 3 valid samples".into()));
        }
        let mut scenes: Vec<String> = samples.iter().map(|s| s.scene.clone()).collect();
        scenes.sort();
        scenes.dedup();
        let mut m = CostModel {
            version: COST_MODEL_VERSION,
            device: device.to_string(),
            source: source.to_string(),
            scenes,
            feature_names: FEATURE_NAMES.iter().map(|s| s.to_string()).collect(),
            structures,
            total_rms_log: 0.0,
            refit: None,
        };
        let mut se = Vec::new();
        for smp in samples {
            let preds = m.predict(&smp.features, &smp.workload);
            for p in preds {
                if let Some(meas) = smp.get(p.structure).filter(|x| x.valid && x.total_ms > 0.0) {
                    se.push((p.total_ms / meas.total_ms).ln());
                }
            }
        }
        m.total_rms_log = rms(&se);
        Ok(m)
    }
}

fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    }
}

fn fit_structure(samples: &[Sample], s: StructureName) -> Result<Option<StructureModel>, CostError> {
    let rows: Vec<(&Sample, &Measured)> = samples
        .iter()
        .filter_map(|smp| {
            smp.get(s).filter(|m| m.valid && m.build_ms_per_build > 0.0 && m.trace_ns_per_ray > 0.0).map(|m| (smp, m))
        })
        .collect();
    if rows.len() < 3 {
        return Ok(None);
    }
    let err = |what: &str| CostError::Fit(format!("{}: {what} system is singular", s.as_str()));
    // Build law.
    let bx: Vec<Vec<f64>> = rows
        .iter()
        .map(|(smp, _)| vec![1.0, (smp.features.total_triangles.max(smp.features.triangles).max(1) as f64).ln()])
        .collect();
    let by: Vec<f64> = rows.iter().map(|(_, m)| m.build_ms_per_build.ln()).collect();
    let ones = vec![1.0; rows.len()];
    let build = linalg::weighted_ridge(&bx, &by, &ones, &[0.0, 1e-9]).ok_or_else(|| err("build"))?;
    // Test counts.
    let p = FEATURE_NAMES.len();
    let x: Vec<Vec<f64>> = rows.iter().map(|(smp, _)| phi(&smp.features.derived(), smp.workload.kind)).collect();
    let mut ridge = vec![RIDGE; p];
    ridge[0] = 0.0;
    let lbox: Vec<f64> = rows.iter().map(|(_, m)| m.box_tests_per_ray.max(1e-3).ln()).collect();
    let lprim: Vec<f64> = rows.iter().map(|(_, m)| m.prim_tests_per_ray.max(1e-3).ln()).collect();
    let box_coef = linalg::weighted_ridge(&x, &lbox, &ones, &ridge).ok_or_else(|| err("box tests"))?;
    let prim_coef = linalg::weighted_ridge(&x, &lprim, &ones, &ridge).ok_or_else(|| err("triangle tests"))?;
    // Prices.
    let tx: Vec<Vec<f64>> =
        rows.iter().map(|(smp, m)| price_row(smp.workload.kind, m.box_tests_per_ray, m.prim_tests_per_ray)).collect();
    let ty: Vec<f64> = rows.iter().map(|(_, m)| m.trace_ns_per_ray).collect();
    let tw: Vec<f64> = ty.iter().map(|t| 1.0 / (t * t)).collect();
    let c = linalg::weighted_nonneg(&tx, &ty, &tw, &[true; PRICE_NAMES.len()]).ok_or_else(|| err("trace price"))?;
    let mut m = StructureModel {
        structure: s,
        build_ln_a: build[0],
        build_exponent: build[1],
        box_coef,
        prim_coef,
        trace_price: c,
        fit: FitError::default(),
    };
    let (mut eb, mut ebox, mut eprim, mut etc, mut et, mut etot) = (vec![], vec![], vec![], vec![], vec![], vec![]);
    for (smp, meas) in &rows {
        let pr =
            m.predict(&smp.features.derived(), smp.features.total_triangles.max(smp.features.triangles), &smp.workload);
        let lr = |a: f64, b: f64| (a.max(1e-12) / b.max(1e-12)).ln();
        eb.push(lr(pr.build_ms_per_build, meas.build_ms_per_build));
        ebox.push(lr(pr.box_tests_per_ray, meas.box_tests_per_ray.max(1e-3)));
        eprim.push(lr(pr.prim_tests_per_ray, meas.prim_tests_per_ray.max(1e-3)));
        let given = dot(&m.trace_price, &price_row(smp.workload.kind, meas.box_tests_per_ray, meas.prim_tests_per_ray));
        etc.push(lr(given, meas.trace_ns_per_ray));
        et.push(lr(pr.trace_ns_per_ray, meas.trace_ns_per_ray));
        etot.push(lr(pr.total_ms, meas.total_ms));
    }
    m.fit = FitError {
        samples: rows.len(),
        build: rms(&eb),
        box_tests: rms(&ebox),
        prim_tests: rms(&eprim),
        trace_given_counts: rms(&etc),
        trace: rms(&et),
        total: rms(&etot),
    };
    Ok(Some(m))
}
