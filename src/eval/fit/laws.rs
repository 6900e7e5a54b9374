//! The laws of one structure fitted on samples: build (plain and work), test counts, trace prices.

use super::linalg;
use super::{Measured, Sample};
use crate::accel::device::TraceBackend;
use crate::accel::StructureName;
use crate::cost::overlap::{self, TestFloor};
use crate::cost::*;
use crate::cost::{count_error, dot, resolve_view};
use crate::geom::WorkloadKind;

/// The trace prices ([`PRICE_NAMES`]) fitted to `rows` of [`price_row`] and ns per ray `y`, weights `w`: weighted
/// least squares, every price `>= 0`, and with `cpu` (samples of the CPU tracer) each triangle-test price at least
/// its box-test price (`prim >= box`, `prim_incoherent >= box_incoherent`). On the CPU a ray-triangle test does more
/// work than a slab test (13.5 against 2.35 ns in isolation, `eval::proxy`), but where a calibration's scenes keep
/// the two counts in about the same ratio the plain fit cannot tell their prices apart and puts the triangles' on
/// the boxes, pricing triangle tests at zero (the shipped CPU file did for the BVH's, LBVH's and HLBVH's primary
/// rays); a scene that makes many triangle tests per box test (large overlapping triangles) was then predicted
/// several times too cheap. Fitted as `box' = box`, `prim' = prim - box >= 0` (the same for the incoherent pair), so
/// the constraint costs nothing where the data choose the larger triangle price themselves. Device samples keep the
/// plain fit: no isolated price says what a test costs there, and on the lavapipe records the constraint cost the
/// shipped file's selections 1.66% -> 2.38% mean regret in sample (`docs/results/2026-12-06-cost-model-curved-builds-incoherent-price.md`).
fn fit_prices(rows: &[Vec<f64>], y: &[f64], w: &[f64], cpu: bool) -> Option<Vec<f64>> {
    if !cpu {
        return linalg::weighted_nonneg(rows, y, w, &[true; PRICE_NAMES.len()]);
    }
    const BOX: usize = 3;
    const PRIM: usize = 4;
    const BOX_INC: usize = 5;
    const PRIM_INC: usize = 6;
    // Columns: the shared part of each pair is paid by both tests, the triangle's excess by triangle tests alone.
    let t: Vec<Vec<f64>> = rows
        .iter()
        .map(|r| {
            let mut q = r.clone();
            q[BOX] = r[BOX] + r[PRIM];
            q[BOX_INC] = r[BOX_INC] + r[PRIM_INC];
            q
        })
        .collect();
    let mut c = linalg::weighted_nonneg(&t, y, w, &[true; PRICE_NAMES.len()])?;
    c[PRIM] += c[BOX];
    c[PRIM_INC] += c[BOX_INC];
    Some(c)
}

/// The range of `ln n` a curvature may be fitted over: that of `ln_ns`, where it spans at least
/// [`BUILD_CURVATURE_MIN_SPAN`] with at least [`BUILD_CURVATURE_MIN_SIZES`] distinct sizes and stays within
/// `[0, BUILD_LN_N_LIMIT]`; `None` otherwise.
fn curvature_range(ln_ns: &[f64]) -> Option<[f64; 2]> {
    let mut sizes: Vec<f64> = ln_ns.iter().copied().filter(|x| x.is_finite()).collect();
    sizes.sort_by(f64::total_cmp);
    sizes.dedup();
    let (&lo, &hi) = (sizes.first()?, sizes.last()?);
    (sizes.len() >= BUILD_CURVATURE_MIN_SIZES
        && hi - lo >= BUILD_CURVATURE_MIN_SPAN
        && lo >= 0.0
        && hi <= BUILD_LN_N_LIMIT)
        .then_some([lo, hi])
}

pub(crate) fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    }
}

/// The share of a sample's rays that leave the scene at once ([`TestFloor::leave_share`]) above which the sample
/// takes no part in the fit of the test-count laws: its few remaining rays say little about the others.
pub const LEAVE_SHARE_UNFITTED: f64 = 0.9;

pub(super) fn fit_structure(
    samples: &[Sample],
    s: StructureName,
    geometric: bool,
    views: bool,
    crossings: bool,
    ridge_value: f64,
) -> Result<Option<StructureModel>, CostError> {
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
    let ln_ns: Vec<f64> = rows.iter().map(|(smp, _)| (smp.features.scene_triangles().max(1) as f64).ln()).collect();
    // A curvature only where the sizes span enough to show one; the term reads 0 otherwise (and fits to 0).
    let range = curvature_range(&ln_ns);
    let q = |ln_n: f64| range.map_or(0.0, |[lo, hi]| curvature_term(ln_n, lo, hi));
    let bx: Vec<Vec<f64>> = ln_ns.iter().map(|&x| vec![1.0, x, q(x)]).collect();
    let by: Vec<f64> = rows.iter().map(|(_, m)| m.build_ms_per_build.ln()).collect();
    // No fit within the accepted ranges: the straight law with its exponent held in BUILD_EXPONENT_RANGE (the
    // constrained least squares of one slope: the plain one, or at the bound it crosses with the intercept refitted;
    // small, noisy builds can time a larger scene faster), which the validation refuses only for an intercept out
    // of range.
    let in_range = |c: &[f64]| build_law_ok(c[0], c[1], c[2], range);
    let build = match fit_build_law(&bx, &by, &[2], &in_range) {
        Some(c) => c,
        None => {
            let x2: Vec<Vec<f64>> = bx.iter().map(|r| r[..2].to_vec()).collect();
            let c = linalg::weighted_ridge(&x2, &by, &vec![1.0; x2.len()], &[0.0, 1e-9]).ok_or_else(|| err("build"))?;
            let b = c[1].clamp(*BUILD_EXPONENT_RANGE.start(), *BUILD_EXPONENT_RANGE.end());
            let a = if b == c[1] {
                c[0]
            } else {
                bx.iter().zip(&by).map(|(r, y)| y - b * r[1]).sum::<f64>() / by.len().max(1) as f64
            };
            vec![a, b, 0.0]
        }
    };
    let build_work_coef = if PROBED.contains(&s) { fit_work_law(&rows, range) } else { Vec::new() };
    let curved = build[2] != 0.0 || build_work_coef.get(3).is_some_and(|&d| d != 0.0);
    // Test counts.
    let p = FEATURE_NAMES.len();
    let x: Vec<Vec<f64>> = rows
        .iter()
        .map(|(smp, _)| {
            let mut row = phi(&smp.features.derived(), smp.workload.kind);
            if !geometric {
                row[SIZE_FEATURES..].iter_mut().for_each(|v| *v = 0.0);
            }
            if views {
                row.extend(resolve_view(&smp.features, &smp.workload).view.map_or([0.0; 3], |v| v.row()));
            }
            if crossings {
                row.push((1.0 + overlap::crossings_feature(smp.workload.kind, smp.crossings)).ln());
            }
            row
        })
        .collect();
    let nv = if views { VIEW_FEATURE_NAMES.len() } else { 0 };
    let mut ridge = vec![ridge_value; p + nv + crossings as usize];
    ridge[0] = 0.0;
    // A geometric model predicts the rays that leave the scene at once apart (one box test, no triangle test:
    // `TestFloor::leave_share`), so its laws are fitted on the other rays' counts; a sample whose rays nearly all
    // leave tells nothing of them and takes no part (weight 0).
    let share = |smp: &Sample| {
        if geometric {
            smp.crossings.map_or(0.0, |c| overlap::unit_share(c.leave_share))
        } else {
            0.0
        }
    };
    let lbox: Vec<f64> = rows
        .iter()
        .map(|(smp, m)| {
            let s = share(smp);
            ((m.box_tests_per_ray - s).max(0.0) / (1.0 - s).max(1e-9)).max(1e-3).ln()
        })
        .collect();
    let lprim: Vec<f64> =
        rows.iter().map(|(smp, m)| (m.prim_tests_per_ray / (1.0 - share(smp)).max(1e-9)).max(1e-3).ln()).collect();
    let law_w: Vec<f64> =
        rows.iter().map(|(smp, _)| if share(smp) > LEAVE_SHARE_UNFITTED { 0.0 } else { 1.0 }).collect();
    let mut box_coef = linalg::weighted_ridge(&x, &lbox, &law_w, &ridge).ok_or_else(|| err("box tests"))?;
    let mut prim_coef = linalg::weighted_ridge(&x, &lprim, &law_w, &ridge).ok_or_else(|| err("triangle tests"))?;
    let crossing_box = if crossings { box_coef.pop() } else { None };
    let crossing_prim = if crossings { prim_coef.pop() } else { None };
    let crossing_coef: Vec<f64> = crossing_box.into_iter().chain(crossing_prim).collect();
    // The feature's mean per kind over these rows (the design matrix's last column; all rows for a kind without
    // any), for callers without a count.
    let crossing_mean: Vec<f64> = if crossings {
        let mean = |k: Option<WorkloadKind>| {
            let v: Vec<f64> = rows
                .iter()
                .zip(&x)
                .filter(|((smp, _), _)| k.is_none_or(|k| smp.workload.kind == k))
                .filter_map(|(_, row)| row.last().copied())
                .collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        };
        let all = mean(None).unwrap_or(0.0);
        [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse]
            .map(|k| mean(Some(k)).unwrap_or(all))
            .to_vec()
    } else {
        Vec::new()
    };
    let view_box_coef = box_coef.split_off(p);
    let view_prim_coef = prim_coef.split_off(p);
    // The range of every feature over the rows the laws were fitted on (a geometric model only: the size-only
    // model reads no geometric feature); none when no row took part.
    let fitted = || x.iter().zip(&law_w).filter(|(_, w)| **w > 0.0).map(|(r, _)| r);
    let feature_range: Vec<[f64; 2]> = if geometric && fitted().next().is_some() {
        (0..p)
            .map(|j| fitted().fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], r| [lo.min(r[j]), hi.max(r[j])]))
            .collect()
    } else {
        Vec::new()
    };
    // Prices.
    // The view's price is fitted only where the rows hold eyes both inside and outside the bounds: over outside
    // eyes alone it is one more price per test and `ln n`, which says nothing of an eye inside and would drop
    // from every prediction there (fitted on the shared meshes' framing cameras, it priced the families' inside
    // views far too cheaply).
    // Each row's workload with its view resolved (the framing camera's where the record has none), once.
    let workloads: Vec<Workload> = rows.iter().map(|(smp, _)| resolve_view(&smp.features, &smp.workload)).collect();
    let inside = |w: &Workload| w.view.is_some_and(|v| v.eye_inside);
    let views_differ = workloads.iter().any(inside) && !workloads.iter().all(inside);
    let tx: Vec<Vec<f64>> = rows
        .iter()
        .zip(&workloads)
        .map(|((smp, m), w)| {
            let n = smp.features.scene_triangles();
            let outside = if views_differ { price_outside_ln_n(w, n) } else { 0.0 };
            price_row(w.kind, m.box_tests_per_ray, m.prim_tests_per_ray, outside)
        })
        .collect();
    let ty: Vec<f64> = rows.iter().map(|(_, m)| m.trace_ns_per_ray).collect();
    let tw: Vec<f64> = ty.iter().map(|t| 1.0 / (t * t)).collect();
    let cpu = rows.iter().all(|(smp, _)| smp.trace_backend == TraceBackend::Cpu);
    let c = fit_prices(&tx, &ty, &tw, cpu).ok_or_else(|| err("trace price"))?;
    let mut m = StructureModel {
        structure: s,
        build_ln_a: build[0],
        build_exponent: build[1],
        build_curvature: build[2],
        build_ln_n_range: if curved { range.map_or(Vec::new(), |r| r.to_vec()) } else { Vec::new() },
        box_coef,
        prim_coef,
        trace_price: c,
        view_box_coef,
        view_prim_coef,
        crossing_coef,
        crossing_mean,
        feature_range,
        build_work_coef,
        prior: None,
        size: None,
        fit: FitError::default(),
    };
    let (mut eb, mut ebox, mut eprim, mut etc, mut et, mut etot) = (vec![], vec![], vec![], vec![], vec![], vec![]);
    let ewk: Vec<f64> = rows
        .iter()
        .filter(|(_, meas)| meas.build_work > 0.0 && !m.build_work_coef.is_empty())
        .map(|(smp, meas)| {
            let n = smp.features.scene_triangles();
            (m.build_ms(n, meas.build_work).max(1e-12) / meas.build_ms_per_build.max(1e-12)).ln()
        })
        .collect();
    for ((smp, meas), w) in rows.iter().zip(&workloads) {
        let floor = TestFloor {
            crossings: overlap::crossings_feature(smp.workload.kind, smp.crossings),
            leave_share: share(smp),
            ..TestFloor::default()
        };
        let n = smp.features.scene_triangles();
        let pr = m.predict_floored(&smp.features.derived(), n, w, floor);
        let lr = |a: f64, b: f64| (a.max(1e-12) / b.max(1e-12)).ln();
        eb.push(lr(pr.build_ms_per_build, meas.build_ms_per_build));
        ebox.push(count_error(pr.box_tests_per_ray, meas.box_tests_per_ray));
        eprim.push(count_error(pr.prim_tests_per_ray, meas.prim_tests_per_ray));
        let given = dot(
            &m.trace_price,
            &price_row(w.kind, meas.box_tests_per_ray, meas.prim_tests_per_ray, price_outside_ln_n(w, n)),
        );
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
        build_work: if ewk.is_empty() { 0.0 } else { rms(&ewk) },
    };
    Ok(Some(m))
}

/// The work law of a probed structure's build ([`StructureModel::build_work_coef`]): `ln build = a' + b' ln n +
/// c' ln(work / n) + d' q(ln n)` (`q` the curvature term over `range`, the sizes of all the structure's builds, as
/// the plain law's) by least squares over the rows whose records counted the work, with `c'` and `d'` held at 0
/// where they fit below ([`fit_build_law`]), and `d'` at 0 where those rows' own sizes do not show a curvature
/// ([`BUILD_CURVATURE_MIN_SPAN`]); none with fewer than three such rows or no fit within the accepted ranges. The
/// fourth constant is left out when it is 0.
fn fit_work_law(rows: &[(&Sample, &Measured)], range: Option<[f64; 2]>) -> Vec<f64> {
    let counted: Vec<(f64, &Measured)> = rows
        .iter()
        .filter(|(_, m)| m.build_work > 0.0 && m.build_work.is_finite())
        .map(|(smp, m)| ((smp.features.scene_triangles().max(1) as f64).ln(), *m))
        .collect();
    if counted.len() < 3 {
        return Vec::new();
    }
    let ln_ns: Vec<f64> = counted.iter().map(|(x, _)| *x).collect();
    let range = range.filter(|_| curvature_range(&ln_ns).is_some());
    let (x, y): (Vec<Vec<f64>>, Vec<f64>) = counted
        .iter()
        .map(|(ln_n, m)| {
            let q = range.map_or(0.0, |[lo, hi]| curvature_term(*ln_n, lo, hi));
            (vec![1.0, *ln_n, m.build_work.ln() - ln_n, q], m.build_ms_per_build.ln())
        })
        .unzip();
    let in_range = |c: &[f64]| BUILD_WORK_EXPONENT_RANGE.contains(&c[2]) && build_law_ok(c[0], c[1], c[3], range);
    match fit_build_law(&x, &y, &[2, 3], &in_range) {
        Some(mut c) => {
            if c[3] == 0.0 {
                c.pop();
            }
            c
        }
        None => Vec::new(),
    }
}

/// Whether a build law's constants lie in the accepted ranges: `ln a` in [`BUILD_LN_A_RANGE`], the exponent `b`
/// in [`BUILD_EXPONENT_RANGE`], the curvature `d` in [`BUILD_CURVATURE_RANGE`] and, with a curvature over `range`,
/// the slopes at its edges ([`build_law_slopes`]) in [`BUILD_EXPONENT_RANGE`].
fn build_law_ok(a: f64, b: f64, d: f64, range: Option<[f64; 2]>) -> bool {
    let slopes_ok = match range {
        Some([lo, hi]) if d != 0.0 => build_law_slopes(b, d, lo, hi).iter().all(|s| BUILD_EXPONENT_RANGE.contains(s)),
        _ => true,
    };
    BUILD_LN_A_RANGE.contains(&a)
        && BUILD_EXPONENT_RANGE.contains(&b)
        && BUILD_CURVATURE_RANGE.contains(&d)
        && slopes_ok
}

/// A build law by least squares over rows `[1, ln n, ...]` (log build ms `y`), the columns `held` (curvature,
/// work exponent) constrained to `>= 0`: every subset of them left in is fitted (the left-out constants read 0),
/// and the least squared error among the fits whose kept constrained constants are all `>= 0` and which `valid`
/// accepts (the ranges of the file's validation) wins. For the `>= 0` constraints alone that is the constrained
/// least squares exactly; with the ranges it is the best of the subsets' fits. `None` when no subset gives one.
fn fit_build_law(x: &[Vec<f64>], y: &[f64], held: &[usize], valid: &dyn Fn(&[f64]) -> bool) -> Option<Vec<f64>> {
    let p = x.first()?.len();
    let ones = vec![1.0; x.len()];
    let mut best: Option<(f64, Vec<f64>)> = None;
    for mask in 0..(1u32 << held.len()) {
        let dropped: Vec<usize> =
            held.iter().enumerate().filter(|(k, _)| mask & (1 << k) != 0).map(|(_, &j)| j).collect();
        let keep: Vec<usize> = (0..p).filter(|j| !dropped.contains(j)).collect();
        let xs: Vec<Vec<f64>> = x.iter().map(|r| keep.iter().map(|&j| r[j]).collect()).collect();
        let ridge: Vec<f64> = keep.iter().map(|&j| if j == 0 { 0.0 } else { 1e-9 }).collect();
        let Some(c) = linalg::weighted_ridge(&xs, y, &ones, &ridge) else { continue };
        let mut full = vec![0.0; p];
        for (&j, v) in keep.iter().zip(c) {
            full[j] = v;
        }
        let ok = held.iter().all(|&j| full[j] >= 0.0) && full.iter().all(|v| v.is_finite()) && valid(&full);
        if !ok {
            continue;
        }
        let sse: f64 = x.iter().zip(y).map(|(r, yy)| (dot(&full, r) - yy).powi(2)).sum();
        if best.as_ref().is_none_or(|(b, _)| sse < *b) {
            best = Some((sse, full));
        }
    }
    best.map(|(_, c)| c)
}

#[cfg(test)]
mod price_fit_tests {
    use super::*;

    /// Rows of primary and shadow rays with `box` and `prim` tests, timed at `box_ns` and `prim_ns` per test plus a
    /// per-kind overhead.
    fn rows(pairs: &[(f64, f64)], box_ns: f64, prim_ns: f64) -> (Vec<Vec<f64>>, Vec<f64>) {
        let mut x = Vec::new();
        let mut y = Vec::new();
        for (k, &(b, p)) in pairs.iter().enumerate() {
            let kind = if k % 2 == 0 { WorkloadKind::Primary } else { WorkloadKind::Shadow };
            x.push(price_row(kind, b, p, 0.0));
            y.push(10.0 + box_ns * b + prim_ns * p);
        }
        (x, y)
    }

    #[test]
    fn a_cpu_fit_prices_a_triangle_test_at_least_like_a_box_test_and_a_device_fit_does_not_have_to() {
        // Triangle tests a fixed share of the box tests: the data cannot tell the two prices apart.
        let pairs: Vec<(f64, f64)> = (1..40).map(|i| (i as f64 * 7.0, i as f64 * 3.5)).collect();
        let (x, y) = rows(&pairs, 2.0, 2.0);
        let w: Vec<f64> = y.iter().map(|t| 1.0 / (t * t)).collect();
        let plain = fit_prices(&x, &y, &w, false).expect("plain fit");
        let cpu = fit_prices(&x, &y, &w, true).expect("cpu fit");
        assert!(cpu[4] >= cpu[3] && cpu[6] >= cpu[5], "{cpu:?}");
        // Both explain the data: the same predictions on every row.
        for (r, t) in x.iter().zip(&y) {
            let (a, b) = (dot(&cpu, r) / t - 1.0, dot(&plain, r) / t - 1.0);
            assert!(a.abs() < 1e-4 && b.abs() < 1e-4, "{r:?} {a} {b} {cpu:?} {plain:?}");
        }
        // On a scene with 20 times more triangle tests than boxes, the constrained prices say at least the cost of
        // its tests at the box price.
        let heavy = price_row(WorkloadKind::Primary, 100.0, 2000.0, 0.0);
        assert!(dot(&cpu, &heavy) >= cpu[3] * 2100.0, "{cpu:?}");
        // Where the data separate the prices, the constraint is idle: the same fit either way.
        let pairs: Vec<(f64, f64)> = (1..40).map(|i| (i as f64 * 7.0, ((i * i) % 17) as f64 * 3.0)).collect();
        let (x, y) = rows(&pairs, 1.5, 6.0);
        let w: Vec<f64> = y.iter().map(|t| 1.0 / (t * t)).collect();
        let (plain, cpu) = (fit_prices(&x, &y, &w, false).expect("plain"), fit_prices(&x, &y, &w, true).expect("cpu"));
        for (a, b) in plain.iter().zip(&cpu) {
            assert!((a - b).abs() < 1e-4, "{plain:?} {cpu:?}");
        }
        assert!((cpu[3] - 1.5).abs() < 1e-4 && (cpu[4] - 6.0).abs() < 1e-4, "{cpu:?}");
        // Data that want the triangle cheaper than the box: the CPU fit holds it at the box's price.
        let (x, y) = rows(&pairs, 4.0, 1.0);
        let w: Vec<f64> = y.iter().map(|t| 1.0 / (t * t)).collect();
        let cpu = fit_prices(&x, &y, &w, true).expect("cpu");
        assert!((cpu[4] - cpu[3]).abs() < 1e-9, "{cpu:?}");
        let plain = fit_prices(&x, &y, &w, false).expect("plain");
        assert!((plain[4] - 1.0).abs() < 1e-4, "{plain:?}");
    }
}
