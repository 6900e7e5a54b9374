//! The driver structures' models fitted on the samples' driver results.

use super::laws::rms;
use super::linalg;
use super::Sample;
use crate::accel::driver::DriverFlags;
use crate::cost::driver::law;
use crate::cost::{
    phi, CostError, DriverFit, DriverModel, DriverUpdateModel, BUILD_EXPONENT_RANGE, FEATURE_NAMES, RIDGE,
    SAH_GROWTH_RANGE,
};

/// `ln y = a + b ln n` by least squares; `None` for a singular system.
fn fit_law(points: &[(u64, f64)]) -> Option<(f64, f64, f64)> {
    let x: Vec<Vec<f64>> = points.iter().map(|&(n, _)| vec![1.0, (n.max(1) as f64).ln()]).collect();
    let y: Vec<f64> = points.iter().map(|&(_, ms)| ms.ln()).collect();
    let mut c = linalg::weighted_ridge(&x, &y, &vec![1.0; points.len()], &[0.0, 1e-9])?;
    // Few distinct sizes (an animation's frames share one) can put the exponent out of its range: then the
    // nearest exponent in range, with the intercept that fits it.
    if !BUILD_EXPONENT_RANGE.contains(&c[1]) || !c[1].is_finite() {
        let b =
            if c[1].is_finite() { c[1].clamp(*BUILD_EXPONENT_RANGE.start(), *BUILD_EXPONENT_RANGE.end()) } else { 1.0 };
        let a = x.iter().zip(&y).map(|(r, ly)| ly - b * r[1]).sum::<f64>() / points.len() as f64;
        c = vec![a, b];
    }
    let e: Vec<f64> = points.iter().map(|&(n, ms)| (law(c[0], c[1], n) / ms).ln()).collect();
    Some((c[0], c[1], rms(&e)))
}

/// Fits one driver structure's model on the samples' driver results (see the module docs); `None` with fewer
/// than 3 valid samples. The update law needs animations where `rt_update` was measured frame by frame; the
/// drift growth also `rt_fast_trace` on the same frames and [`Sample::frame_features`].
pub fn fit_driver(samples: &[Sample], flags: DriverFlags) -> Result<Option<DriverModel>, CostError> {
    let rows: Vec<(&Sample, &super::DriverMeasured)> = samples
        .iter()
        .filter_map(|s| {
            s.driver_result(flags)
                .filter(|m| m.valid && m.build_ms_per_build > 0.0 && m.trace_ns_per_ray > 0.0)
                .map(|m| (s, m))
        })
        .collect();
    if rows.len() < 3 {
        return Ok(None);
    }
    let err = |what: &str| CostError::Fit(format!("{}: {what} system is singular", flags.name()));
    let n_of = |s: &Sample| s.features.scene_triangles().max(1);
    let builds: Vec<(u64, f64)> = rows.iter().map(|(s, m)| (n_of(s), m.build_ms_per_build)).collect();
    let (build_ln_a, build_exponent, _) = fit_law(&builds).ok_or_else(|| err("build"))?;
    let x: Vec<Vec<f64>> = rows.iter().map(|(s, _)| phi(&s.features.derived(), s.workload.kind)).collect();
    let y: Vec<f64> = rows.iter().map(|(_, m)| m.trace_ns_per_ray.ln()).collect();
    let mut ridge = vec![RIDGE; FEATURE_NAMES.len()];
    ridge[0] = 0.0;
    let trace_coef = linalg::weighted_ridge(&x, &y, &vec![1.0; rows.len()], &ridge).ok_or_else(|| err("trace"))?;
    let update = if flags == DriverFlags::Update { fit_update(samples) } else { None };
    let mut m = DriverModel {
        name: flags.name().to_string(),
        build_ln_a,
        build_exponent,
        trace_coef,
        update,
        fit: DriverFit::default(),
    };
    let lr = |a: f64, b: f64| (a.max(1e-12) / b.max(1e-12)).ln();
    let (mut eb, mut et, mut etot) = (Vec::new(), Vec::new(), Vec::new());
    for (s, meas) in &rows {
        let Some(p) = m.predict(&s.features.derived(), n_of(s), &s.workload) else { continue };
        eb.push(lr(p.build_ms_per_build, meas.build_ms_per_build));
        et.push(lr(p.trace_ns_per_ray, meas.trace_ns_per_ray));
        etot.push(lr(p.total_ms, meas.total_ms));
    }
    m.fit = DriverFit { samples: rows.len(), build: rms(&eb), trace: rms(&et), total: rms(&etot) };
    Ok(Some(m))
}

/// The update law and drift growth of `rt_update` from the animations' per-frame results.
fn fit_update(samples: &[Sample]) -> Option<DriverUpdateModel> {
    let (mut updates, mut xs, mut ys) = (Vec::new(), Vec::new(), Vec::new());
    for s in samples {
        let Some(u) = s.driver_result(DriverFlags::Update).filter(|m| m.valid) else { continue };
        let n = s.features.scene_triangles().max(1);
        for &ms in u.frame_build_ms.iter().skip(1).filter(|&&ms| ms > 0.0 && ms.is_finite()) {
            updates.push((n, ms));
        }
        let fresh = s.driver_result(DriverFlags::FastTrace).filter(|m| m.valid);
        let (Some(fresh), Some(built)) = (fresh, s.frame_features.first()) else { continue };
        for i in 1..u.frame_trace_ms.len().min(fresh.frame_trace_ms.len()).min(s.frame_features.len()) {
            let (tu, tf) = (u.frame_trace_ms[i], fresh.frame_trace_ms[i]);
            if tu > 0.0 && tf > 0.0 && tu.is_finite() && tf.is_finite() {
                xs.push(super::drift(built, &s.frame_features[i]));
                ys.push(tu / tf - 1.0);
            }
        }
    }
    if updates.len() < 3 {
        return None;
    }
    let (update_ln_a, update_exponent, update_rms) = fit_law(&updates)?;
    // The median of the frames' slopes through the origin, not a least-squares slope: a frame or two whose trace
    // timing jumped (lavapipe, 2026-12-05: robots' shadow rays at frame 4, update 1.89x the rebuild; the kitchen's
    // diffuse rays at frame 5, 1.45x) would otherwise set the growth (least squares 3.97, the median 0).
    let mut slopes: Vec<f64> = xs.iter().zip(&ys).filter(|(x, _)| **x > 0.0).map(|(x, y)| y / x).collect();
    slopes.sort_by(f64::total_cmp);
    let g = match slopes.len() {
        0 => 0.0,
        k if k % 2 == 1 => slopes[k / 2],
        k => 0.5 * (slopes[k / 2 - 1] + slopes[k / 2]),
    };
    let g = if g.is_finite() { g.clamp(0.0, *SAH_GROWTH_RANGE.end()) } else { 0.0 };
    let growth_rms = if xs.is_empty() {
        0.0
    } else {
        (xs.iter().zip(&ys).map(|(x, y)| (g * x - y).powi(2)).sum::<f64>() / xs.len() as f64).sqrt()
    };
    Some(DriverUpdateModel {
        update_ln_a,
        update_exponent,
        trace_growth_per_drift: g,
        update_rms,
        growth_rms,
        samples: updates.len(),
    })
}
