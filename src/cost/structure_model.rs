//! One structure's fitted laws ([`StructureModel`]) and what they predict ([`Prediction`]).

use super::*;

/// The fitted constants of one structure (see the module docs for the formulas).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StructureModel {
    /// The structure.
    pub structure: StructureName,
    /// `a_s`: `ln` of the build ms of a one-triangle scene, in [`BUILD_LN_A_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub build_ln_a: f64,
    /// `b_s`: exponent of `n` in the build time, in [`BUILD_EXPONENT_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub build_exponent: f64,
    /// `theta_box_s`, one per [`FEATURE_NAMES`], each of magnitude at most [`COEF_LIMIT`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub box_coef: Vec<f64>,
    /// `theta_prim_s`, one per [`FEATURE_NAMES`], each of magnitude at most [`COEF_LIMIT`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub prim_coef: Vec<f64>,
    /// Trace prices, ns, one per [`PRICE_NAMES`] (all in `0..=PRICE_LIMIT_NS`, not all 0).
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub trace_price: Vec<f64>,
    /// The view's coefficients in the box-test law, one per [`VIEW_FEATURE_NAMES`], or none (a calibration
    /// fitted without views, which ignores the camera).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub view_box_coef: Vec<f64>,
    /// The view's coefficients in the triangle-test law, as `view_box_coef`.
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub view_prim_coef: Vec<f64>,
    /// The coefficients of `ln(1 + crossings)` (`TestFloor::crossings`: the triangle boxes a ray of the workload
    /// crosses) in the box-test and the triangle-test laws, `[box, prim]`, each of magnitude at most
    /// [`COEF_LIMIT`]; or none (a calibration fitted without them, [`CostModel::fit_with`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub crossing_coef: Vec<f64>,
    /// With [`StructureModel::crossing_coef`]: per workload kind (primary, shadow, diffuse), the mean of
    /// `ln(1 + crossings)` over the calibration's samples of that kind (a sample without a count counting 0, as in
    /// the fit), in `[0, 45]`; what a prediction reads when the caller has no count (`TestFloor::crossings` NaN:
    /// features alone, no mesh), so that it predicts for the calibration's typical scene instead of one whose rays
    /// cross nothing. Absent in files written before it (such a file reads an unknown count as 0).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub crossing_mean: Vec<f64>,
    /// Per [`FEATURE_NAMES`] column, the least and the largest value over the samples the count laws were fitted
    /// on, `[lo, hi]`; a prediction clamps the geometric columns ([`CLAMPED_FEATURES`]) into it, so that a scene
    /// unlike every calibration scene is not extrapolated to by a log-linear law. Absent in files written before
    /// it (no clamp).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub feature_range: Vec<[f64; 2]>,
    /// The build law a probe's build work reads, `[a', b', c']`: `build_ms = exp(a') * n^b' * (work / n)^c'`, with
    /// `work` the built structure's [`crate::accel::AccelStats::build_work`] (its references times their levels)
    /// where a probe built it (`TestFloor::build_work`); the plain law
    /// ([`StructureModel::build_ln_a`], [`StructureModel::build_exponent`]) otherwise. `a'` in [`BUILD_LN_A_RANGE`],
    /// `b'` in [`BUILD_EXPONENT_RANGE`], `c'` in [`BUILD_WORK_EXPONENT_RANGE`]. Fitted for the probed structures
    /// ([`PROBED`]) on samples whose records counted the work; absent in files written before it (and for the other
    /// structures).
    ///
    /// A fourth constant `d'`, when present, is the law's curvature in `ln n`, as
    /// [`StructureModel::build_curvature`] is the plain law's.
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub build_work_coef: Vec<f64>,
    /// `d_s`: the plain build law's curvature in `ln n`, in [`BUILD_CURVATURE_RANGE`]: `ln build` gains
    /// `d_s * curvature_term(ln n)` (`curvature_term`: `(ln n - BUILD_CURVATURE_CENTER)^2` over the calibration's
    /// sizes, [`StructureModel::build_ln_n_range`], and its tangent beyond them). The time per triangle is U-shaped
    /// in `n`: fixed costs weigh on small builds, cache misses on large ones. 0 in files written before it, and
    /// where the calibration's sizes span less than [`BUILD_CURVATURE_MIN_SPAN`].
    #[serde(default, skip_serializing_if = "is_zero", deserialize_with = "f64_or_null")]
    pub build_curvature: f64,
    /// `[lo, hi]`: the range of `ln n` over the builds the laws were fitted on, beyond which the curvature terms
    /// follow their tangent (`curvature_term`); required with a curvature, else absent.
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub build_ln_n_range: Vec<f64>,
    /// The prior's own count laws ([`CountLaw`]), read where the caller knows nothing of the scene beyond its
    /// features (no crossings, no probe); absent in files written before them (the laws above serve then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prior: Option<CountLaw>,
    /// The count laws of the triangle count alone ([`CountLaw`] with every geometric coefficient 0), read before
    /// the mesh is characterized: the selection's rung below level 0 (`CostModel::predict_size`); absent in files
    /// written without them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<CountLaw>,
    /// Fit errors on the calibration samples.
    pub fit: FitError,
}

/// The count laws the prior reads (level 0: nothing known of the scene but its features), fitted apart from the
/// laws that the crossings and probes correct, with a shrinkage chosen by how well the prior alone chooses on held-out
/// records (`calibrate`): geometric laws that follow the calibration's scenes closely extrapolate poorly to a scene
/// unlike them when nothing measured bounds them.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CountLaw {
    /// Coefficients of `ln` box tests per ray, one per [`FEATURE_NAMES`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub box_coef: Vec<f64>,
    /// Coefficients of `ln` triangle tests per ray, one per [`FEATURE_NAMES`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub prim_coef: Vec<f64>,
    /// The view's coefficients of the box-test law (none: the view ignored).
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub view_box_coef: Vec<f64>,
    /// The view's coefficients of the triangle-test law.
    #[serde(default, skip_serializing_if = "Vec::is_empty", deserialize_with = "vec_f64_or_null")]
    pub view_prim_coef: Vec<f64>,
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
    /// Predicted costs for features `d` of a scene with `n` triangles and a workload. With view coefficients,
    /// `w.view` enters the test-count laws (`None` counts as zeros here: [`CostModel::predict`] first resolves a
    /// missing view to the framing camera).
    pub fn predict(&self, d: &Derived, n: u64, w: &Workload) -> Prediction {
        self.predict_floored(d, n, w, TestFloor::default())
    }

    /// [`StructureModel::predict`] with the box and triangle tests per ray bounded by `floor` (bounds the caller
    /// knows from the scene, such as the selection's overlap floor, [`overlap_floor`]: at least its lower bounds, at
    /// most its upper ones, and the share of rays that leave the scene at once counted at one box test and no
    /// triangle test); the trace time follows from the bounded counts. A law within [`PROBE_BAND`] of a sampled
    /// count ([`TestFloor::sampled`]) stands; [`CostModel::predict_floored`] applies the calibration's own band
    /// ([`CostModel::own_probe_band`]).
    pub(crate) fn predict_floored(&self, d: &Derived, n: u64, w: &Workload, floor: TestFloor) -> Prediction {
        self.predict_corrected(d, n, w, floor, [1.0, 1.0], PROBE_BAND)
    }

    /// [`StructureModel::predict_floored`] with the laws' box and triangle tests per ray multiplied by
    /// `correction` before the floor bounds them (the probed structures' shared correction,
    /// [`CostModel::predict_floored`]), and a law kept where it lies within `band` of its sample (in the fit's RMS
    /// errors, as [`PROBE_BAND`]).
    pub(super) fn predict_corrected(
        &self,
        d: &Derived,
        n: u64,
        w: &Workload,
        floor: TestFloor,
        correction: [f64; 2],
        band: f64,
    ) -> Prediction {
        let mut x = phi(d, w.kind);
        if self.feature_range.len() == x.len() {
            for j in CLAMPED_FEATURES {
                let [lo, hi] = self.feature_range[j];
                if lo <= hi {
                    x[j] = x[j].clamp(lo, hi);
                }
            }
        }
        let v = w.view.map_or([0.0; 3], |v| v.row());
        // Nothing known beyond the features: the prior's own laws, where the calibration has them.
        let unknown = floor.crossings.is_nan() && floor.sampled.is_none();
        let (box_coef, prim_coef, view_box, view_prim) = match (&self.prior, unknown) {
            (Some(p), true) => (&p.box_coef, &p.prim_coef, &p.view_box_coef, &p.view_prim_coef),
            _ => (&self.box_coef, &self.prim_coef, &self.view_box_coef, &self.view_prim_coef),
        };
        let (cb, cp) = match (self.crossing_coef.as_slice(), unknown && self.prior.is_some()) {
            (_, true) => (0.0, 0.0),
            (&[b, p], false) => {
                // An unknown count (NaN) reads the calibration's mean for the kind (0 in files without one).
                let xc = if floor.crossings.is_nan() {
                    self.crossing_mean.get(kind_index(w.kind)).copied().unwrap_or(0.0)
                } else {
                    (1.0 + floor.crossings.max(0.0)).ln()
                };
                (b * xc, p * xc)
            }
            _ => (0.0, 0.0),
        };
        let bx = (dot(box_coef, &x) + dot(view_box, &v) + cb).clamp(-30.0, 30.0).exp() * correction[0];
        let pr = (dot(prim_coef, &x) + dot(view_prim, &v) + cp).clamp(-30.0, 30.0).exp() * correction[1];
        // A NaN bound (never given) must not poison the counts: f64::max and f64::min ignore it.
        let bx = bx.max(floor.box_tests).min(floor.box_tests_most);
        let pr = pr.max(floor.prim_tests).min(floor.prim_tests_most);
        // Rays that leave the scene at once test the root box and nothing else.
        let leave = overlap::unit_share(floor.leave_share);
        let (mut bx, mut pr) = (leave + (1.0 - leave) * bx, (1.0 - leave) * pr);
        if let Some(p) = floor.sampled {
            // The structure's own counts on a sample of the rays: where the law's count lies outside its own error
            // band about the sampled mean (`band` times its fit's RMS error of `ln(1 + count)`), the law has
            // missed this scene, and the count is held within two standard errors of that mean instead.
            let held = |law: f64, m: overlap::SampledMean, rms: f64| {
                let within = count_error(law, m.mean).abs() <= band * rms.max(0.0);
                if within {
                    law
                } else {
                    law.clamp(m.lower_bound(), m.upper_bound())
                }
            };
            bx = held(bx, p.box_tests, self.fit.box_tests);
            pr = held(pr, p.prim_tests, self.fit.prim_tests);
        }
        let per_build = self.build_ms(n, floor.build_work);
        let build_ms = per_build * w.builds as f64;
        self.with_counts(build_ms, per_build, w, n, bx, pr)
    }

    /// Predicted ms of one build over `n` triangles: by the work law ([`StructureModel::build_work_coef`]) where
    /// `work` (the probe's [`crate::accel::AccelStats::build_work`]) is known (`> 0`) and the model has one, by the
    /// plain law in `n` otherwise.
    pub fn build_ms(&self, n: u64, work: f64) -> f64 {
        let ln_n = (n.max(1) as f64).ln();
        let q = self.build_curvature_term(ln_n);
        match self.build_work_coef[..] {
            [a, b, c, ref d @ ..] if work > 0.0 && work.is_finite() && d.len() <= 1 => {
                let d = d.first().copied().unwrap_or(0.0);
                (a + b * ln_n + c * (work.ln() - ln_n) + d * q).exp()
            }
            _ => (self.build_ln_a + self.build_exponent * ln_n + self.build_curvature * q).exp(),
        }
    }

    /// The curvature terms' [`curvature_term`] over [`StructureModel::build_ln_n_range`]; 0 without a range (a
    /// model without curvature).
    fn build_curvature_term(&self, ln_n: f64) -> f64 {
        match self.build_ln_n_range[..] {
            [lo, hi] => curvature_term(ln_n, lo, hi),
            _ => 0.0,
        }
    }

    /// The prediction of a build of `build_ms` (`per_build` ms each) and `bx` box and `pr` triangle tests per ray
    /// for workload `w` over `n` triangles: the trace time from the counts at this structure's prices.
    fn with_counts(&self, build_ms: f64, per_build: f64, w: &Workload, n: u64, bx: f64, pr: f64) -> Prediction {
        let ns = dot(&self.trace_price, &price_row(w.kind, bx, pr, price_outside_ln_n(w, n)));
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
