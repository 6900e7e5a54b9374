//! The driver's acceleration structures in the cost model (`VK_KHR_acceleration_structure` built with one of
//! [`DriverFlags`], traced with ray queries).
//!
//! The driver reports no box or triangle test counts, so a driver structure's model has no counts and no prices:
//!
//! ```text
//! build_ms(r)      = exp(a_r) * n^b_r                        (per build, the bottom and top levels)
//! trace_ns(r)      = exp(theta_r . phi(f, kind))             (per ray, phi as for the project's structures)
//! update_ms(r)     = exp(a'_r) * n^b'_r                      (rt_update: one MODE_UPDATE of an animation's frame)
//! trace_update(r)  = trace_ns(r) * (1 + g_r * drift)         (rt_update: the updated structure's trace cost
//!                                                             against the frame it was built for)
//! ```
//!
//! [`crate::eval::fit::fit_driver`] fits the build and update laws by least squares in log space and `theta_r` by ridge regression of
//! `ln` ns per ray on `phi` (ridge [`super::RIDGE`] on all but the intercept), from the oracle's driver results
//! ([`crate::eval::fit::DriverMeasured`]). `g_r` is the least-squares slope through the origin of
//! `trace(updated frame i) / trace(fresh frame i) - 1` against the drift ([`super::drift`]) of frame `i` from the
//! built frame, where the fresh trace is `rt_fast_trace`'s on the same frame (rebuilt every frame, the same
//! `PREFER_FAST_TRACE` flag without `ALLOW_UPDATE`). A negative slope (an updated structure traced faster than a
//! fresh one, which is noise) is clamped to 0.
//!
//! For a whole workload ([`DriverModel::predict`]) `rt_update` pays one build and `builds - 1` updates and traces
//! at the fresh cost; the per-frame plan ((`select::driver::plan_driver_frames`)) charges the drift.

use super::{check_number, dot, invalid, phi, CostError, Workload, SAH_GROWTH_RANGE};
use super::{f64_or_null, vec_f64_or_null, BUILD_EXPONENT_RANGE, BUILD_LN_A_RANGE, COEF_LIMIT, FEATURE_NAMES};
use crate::accel::driver::DriverFlags;
use crate::characterize::features::Derived;

/// The fitted constants of one driver structure (see the module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriverModel {
    /// The candidate's name ([`DriverFlags::name`]: `rt_fast_trace`, `rt_fast_build`, `rt_update`,
    /// `rt_fast_trace_compact`).
    pub name: String,
    /// `a_r`: `ln` of the build ms of a one-triangle scene, in [`BUILD_LN_A_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub build_ln_a: f64,
    /// `b_r`: exponent of `n` in the build time, in [`BUILD_EXPONENT_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub build_exponent: f64,
    /// `theta_r`: `ln` ns per ray against [`FEATURE_NAMES`], each of magnitude at most [`COEF_LIMIT`].
    #[serde(deserialize_with = "vec_f64_or_null")]
    pub trace_coef: Vec<f64>,
    /// The update law and the trace growth with drift (`rt_update`, fitted on animations).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub update: Option<DriverUpdateModel>,
    /// Fit errors on the calibration samples.
    pub fit: DriverFit,
}

/// An updatable driver structure's per-frame law (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriverUpdateModel {
    /// `a'_r`: `ln` of the update ms of a one-triangle scene, in [`BUILD_LN_A_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub update_ln_a: f64,
    /// `b'_r`, in [`BUILD_EXPONENT_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub update_exponent: f64,
    /// `g_r`: relative growth of the trace cost per unit of drift, in [`SAH_GROWTH_RANGE`].
    #[serde(deserialize_with = "f64_or_null")]
    pub trace_growth_per_drift: f64,
    /// RMS log error of the update law.
    #[serde(deserialize_with = "f64_or_null")]
    pub update_rms: f64,
    /// RMS error of `trace ratio - 1` against `g * drift`.
    #[serde(deserialize_with = "f64_or_null")]
    pub growth_rms: f64,
    /// Updated frames measured.
    pub samples: usize,
}

/// Root-mean-square natural-log errors of a driver structure's fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriverFit {
    /// Samples fitted.
    pub samples: usize,
    /// Build time.
    #[serde(deserialize_with = "f64_or_null")]
    pub build: f64,
    /// Trace ns per ray.
    #[serde(deserialize_with = "f64_or_null")]
    pub trace: f64,
    /// Totals.
    #[serde(deserialize_with = "f64_or_null")]
    pub total: f64,
}

/// A driver structure's predicted costs for a scene and a workload.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DriverPrediction {
    /// The build flags.
    #[serde(serialize_with = "flags_name")]
    pub flags: DriverFlags,
    /// Build ms of one build.
    pub build_ms_per_build: f64,
    /// Build (and, for `rt_update`, update) ms over the run.
    pub build_ms: f64,
    /// Predicted trace ns per ray.
    pub trace_ns_per_ray: f64,
    /// Trace ms over the run.
    pub trace_ms: f64,
    /// `build_ms + trace_ms`.
    pub total_ms: f64,
}

fn flags_name<S: serde::Serializer>(f: &DriverFlags, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(f.name())
}

pub(crate) fn law(ln_a: f64, b: f64, n: u64) -> f64 {
    (ln_a + b * (n.max(1) as f64).ln()).exp()
}

impl DriverModel {
    /// The build flags of [`DriverModel::name`] (`None` for a name no flag set has, which
    /// [`DriverModel::validate`] refuses).
    pub fn flags(&self) -> Option<DriverFlags> {
        DriverFlags::parse(&self.name)
    }

    /// Predicted trace ns per ray for features `d` and rays of `kind`.
    pub(crate) fn trace_ns(&self, d: &Derived, kind: crate::geom::WorkloadKind) -> f64 {
        dot(&self.trace_coef, &phi(d, kind)).clamp(-30.0, 30.0).exp()
    }

    /// Predicted ms of one build of a scene of `n` triangles.
    pub fn build_ms(&self, n: u64) -> f64 {
        law(self.build_ln_a, self.build_exponent, n)
    }

    /// Predicted ms of one update of a scene of `n` triangles (`None` without an update law).
    pub fn update_ms(&self, n: u64) -> Option<f64> {
        self.update.map(|u| law(u.update_ln_a, u.update_exponent, n))
    }

    /// Predicted costs for features `d` of a scene with `n` triangles and a workload: `rt_update` with an update
    /// law pays one build and `builds - 1` updates, the others `builds` builds; the trace at the fresh cost.
    /// `None` when the name is no flag set.
    pub fn predict(&self, d: &Derived, n: u64, w: &Workload) -> Option<DriverPrediction> {
        let flags = self.flags()?;
        let per_build = self.build_ms(n);
        let build_ms = match (flags, self.update_ms(n)) {
            (DriverFlags::Update, Some(u)) if w.builds > 1 => per_build + u * (w.builds - 1) as f64,
            _ => per_build * w.builds as f64,
        };
        let ns = self.trace_ns(d, w.kind);
        let trace_ms = ns * 1e-6 * w.rays_per_frame as f64 * w.frames as f64;
        Some(DriverPrediction {
            flags,
            build_ms_per_build: per_build,
            build_ms,
            trace_ns_per_ray: ns,
            trace_ms,
            total_ms: build_ms + trace_ms,
        })
    }

    /// The rules of the module docs of [`super`] (Validation) for entry `i` of a file's `driver`: a known name, the
    /// build law in [`BUILD_LN_A_RANGE`] and [`BUILD_EXPONENT_RANGE`], one coefficient per feature within
    /// [`COEF_LIMIT`], the update law in the same ranges with its growth in [`SAH_GROWTH_RANGE`], and
    /// non-negative fit errors.
    pub fn validate(&self, i: usize) -> Result<(), CostError> {
        let at = |f: &str| format!("driver[{i}] ({}).{f}", self.name);
        if self.flags().is_none() {
            let known: Vec<&str> = DriverFlags::ALL.iter().map(|f| f.name()).collect();
            return Err(invalid(
                None,
                format!("driver[{i}].name"),
                format!("{:?} is not a driver structure ({})", self.name, known.join(", ")),
            ));
        }
        check_number(None, at("build_ln_a"), self.build_ln_a, BUILD_LN_A_RANGE, "ln of the build ms of one triangle")?;
        check_number(
            None,
            at("build_exponent"),
            self.build_exponent,
            BUILD_EXPONENT_RANGE,
            "the exponent of n in the build",
        )?;
        if self.trace_coef.len() != FEATURE_NAMES.len() {
            return Err(invalid(
                None,
                at("trace_coef"),
                format!("{} coefficients, expected one per feature ({})", self.trace_coef.len(), FEATURE_NAMES.len()),
            ));
        }
        for (j, (&c, f)) in self.trace_coef.iter().zip(FEATURE_NAMES).enumerate() {
            check_number(None, at(&format!("trace_coef[{j}] ({f})")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
        }
        if let Some(u) = &self.update {
            check_number(None, at("update.update_ln_a"), u.update_ln_a, BUILD_LN_A_RANGE, "ln of the update ms")?;
            check_number(
                None,
                at("update.update_exponent"),
                u.update_exponent,
                BUILD_EXPONENT_RANGE,
                "the exponent of n in the update",
            )?;
            check_number(
                None,
                at("update.trace_growth_per_drift"),
                u.trace_growth_per_drift,
                SAH_GROWTH_RANGE,
                "the growth of the trace cost per unit of drift",
            )?;
            for (name, x) in [("update_rms", u.update_rms), ("growth_rms", u.growth_rms)] {
                check_number(None, at(&format!("update.{name}")), x, 0.0..=f64::MAX, "a root-mean-square error")?;
            }
            if u.samples == 0 {
                return Err(invalid(None, at("update.samples"), "0: an update law needs at least one updated frame"));
            }
        }
        for (name, x) in [("build", self.fit.build), ("trace", self.fit.trace), ("total", self.fit.total)] {
            check_number(None, at(&format!("fit.{name}")), x, 0.0..=f64::MAX, "a root-mean-square error")?;
        }
        Ok(())
    }
}
