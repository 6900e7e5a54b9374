//! The rules a calibration file's values obey (the module docs' Validation), with errors naming the field.

use super::*;

/// What a JSON value is, for error messages.
pub(super) fn json_kind(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    }
}

/// Entry `i` of a file's `structures`: its name first (known, calibrated), then the typed model.
pub(super) fn structure_from_json(i: usize, v: serde_json::Value) -> Result<StructureModel, CostError> {
    let field = format!("structures[{i}].structure");
    let structure = match v.get("structure") {
        None => return Err(invalid(None, field, "missing")),
        Some(serde_json::Value::String(name)) => {
            StructureName::from_name(name).filter(|s| StructureName::ALL.contains(s)).ok_or_else(|| {
                invalid(None, field, format!("{name:?} is not a calibrated structure ({})", known_names()))
            })?
        }
        Some(x) => return Err(invalid(None, field, format!("{}, not a string", json_kind(x)))),
    };
    serde_json::from_value(v)
        .map_err(|e| invalid(Some(structure), format!("structures[{i}] ({})", structure.as_str()), e.to_string()))
}

/// The names of [`StructureName::ALL`], comma-separated.
pub(super) fn known_names() -> String {
    StructureName::ALL.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ")
}

/// `got` equals `want`, name for name and in order; the error names the first position that differs.
pub(super) fn check_names(field: &str, got: &[String], want: &[&str]) -> Result<(), CostError> {
    let order = want.join(", ");
    for (i, w) in want.iter().enumerate() {
        match got.get(i) {
            None => {
                return Err(invalid(
                    None,
                    format!("{field}[{i}]"),
                    format!("missing: expected {w:?} ({} names, in order: {order}; found {})", want.len(), got.len()),
                ))
            }
            Some(g) if g != w => {
                return Err(invalid(
                    None,
                    format!("{field}[{i}]"),
                    format!("{g:?}, expected {w:?} (the columns are read by position, in order: {order})"),
                ))
            }
            Some(_) => {}
        }
    }
    match got.get(want.len()) {
        Some(extra) => Err(invalid(
            None,
            format!("{field}[{}]", want.len()),
            format!("{extra:?}: unexpected, {} names expected ({order})", want.len()),
        )),
        None => Ok(()),
    }
}

/// `x` is finite and in `range`; `what` says what the number is.
pub(super) fn check_number(
    structure: Option<StructureName>,
    field: String,
    x: f64,
    range: RangeInclusive<f64>,
    what: &str,
) -> Result<(), CostError> {
    if !x.is_finite() {
        return Err(invalid(structure, field, format!("{x} is not a finite number ({what})")));
    }
    if !range.contains(&x) {
        let bounds = if *range.end() == f64::MAX {
            format!(">= {}", range.start())
        } else {
            format!("in [{}, {}]", range.start(), range.end())
        };
        return Err(invalid(structure, field, format!("{x} is out of range: {what}, must be {bounds}")));
    }
    Ok(())
}

/// The rules of one structure's model (entry `i` of `structures`).
pub(super) fn check_structure(i: usize, s: &StructureModel) -> Result<(), CostError> {
    let st = Some(s.structure);
    let at = |f: &str| format!("structures[{i}] ({}).{f}", s.structure.as_str());
    if !StructureName::ALL.contains(&s.structure) {
        return Err(invalid(
            st,
            format!("structures[{i}].structure"),
            format!("{:?} is not a calibrated structure ({})", s.structure.as_str(), known_names()),
        ));
    }
    check_number(st, at("build_ln_a"), s.build_ln_a, BUILD_LN_A_RANGE, "ln of the build ms of one triangle")?;
    check_number(st, at("build_exponent"), s.build_exponent, BUILD_EXPONENT_RANGE, "the exponent of n in the build")?;
    check_number(st, at("build_curvature"), s.build_curvature, BUILD_CURVATURE_RANGE, "a curvature in ln n")?;
    match s.build_work_coef[..] {
        [] => {}
        [a, b, c, ref d @ ..] if d.len() <= 1 => {
            let what = "ln of the build ms of one triangle (work law)";
            check_number(st, at("build_work_coef[0]"), a, BUILD_LN_A_RANGE, what)?;
            let what = "the exponent of n in the build (work law)";
            check_number(st, at("build_work_coef[1]"), b, BUILD_EXPONENT_RANGE, what)?;
            let what = "the exponent of the build work per triangle";
            check_number(st, at("build_work_coef[2]"), c, BUILD_WORK_EXPONENT_RANGE, what)?;
            if let [d] = d {
                let what = "a curvature in ln n (work law)";
                check_number(st, at("build_work_coef[3]"), *d, BUILD_CURVATURE_RANGE, what)?;
            }
        }
        _ => {
            return Err(invalid(
                st,
                at("build_work_coef"),
                format!("{} coefficients, expected none, three or four", s.build_work_coef.len()),
            ))
        }
    }
    let curved = s.build_curvature != 0.0 || s.build_work_coef.get(3).is_some_and(|&d| d != 0.0);
    match s.build_ln_n_range[..] {
        [] if curved => {
            return Err(invalid(st, at("build_ln_n_range"), "missing: a curved build law needs the range of ln n"))
        }
        [] => {}
        [lo, hi] => {
            let field = at("build_ln_n_range");
            let limit = 0.0..=BUILD_LN_N_LIMIT;
            if !(limit.contains(&lo) && limit.contains(&hi)) {
                let why = format!("[{lo}, {hi}]: the bounds must be finite, in [0, {BUILD_LN_N_LIMIT}] (ln 2^40)");
                return Err(invalid(st, field, why));
            }
            if lo > hi {
                return Err(invalid(st, field, format!("[{lo}, {hi}]: the low bound exceeds the high one")));
            }
            // The slopes the laws keep beyond the fitted sizes: no build gets faster with more triangles.
            let laws = [("build_curvature", s.build_exponent, s.build_curvature)].into_iter().chain(
                match s.build_work_coef[..] {
                    [_, b, _, d] => Some(("build_work_coef[3]", b, d)),
                    _ => None,
                },
            );
            for (name, b, d) in laws {
                for (slope, edge) in build_law_slopes(b, d, lo, hi).into_iter().zip([lo, hi]) {
                    if !BUILD_EXPONENT_RANGE.contains(&slope) {
                        let why = format!(
                            "the law's slope in ln n at the edge {edge} of its sizes, b + 2 d (edge - \
                             {BUILD_CURVATURE_CENTER}), is {slope}, outside [0, 2]"
                        );
                        return Err(invalid(st, at(name), why));
                    }
                }
            }
        }
        _ => {
            return Err(invalid(
                st,
                at("build_ln_n_range"),
                format!("{} values, expected none or two (lo, hi)", s.build_ln_n_range.len()),
            ))
        }
    }
    for (name, coef) in [("box_coef", &s.box_coef), ("prim_coef", &s.prim_coef)] {
        if coef.len() != FEATURE_NAMES.len() {
            return Err(invalid(
                st,
                at(name),
                format!("{} coefficients, expected one per feature ({})", coef.len(), FEATURE_NAMES.len()),
            ));
        }
        for (j, (&c, f)) in coef.iter().zip(FEATURE_NAMES).enumerate() {
            check_number(st, at(&format!("{name}[{j}] ({f})")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
        }
    }
    for (name, coef) in [("view_box_coef", &s.view_box_coef), ("view_prim_coef", &s.view_prim_coef)] {
        if !coef.is_empty() && coef.len() != VIEW_FEATURE_NAMES.len() {
            return Err(invalid(
                st,
                at(name),
                format!(
                    "{} coefficients, expected none or one per view feature ({})",
                    coef.len(),
                    VIEW_FEATURE_NAMES.len()
                ),
            ));
        }
        for (j, (&c, f)) in coef.iter().zip(VIEW_FEATURE_NAMES).enumerate() {
            check_number(st, at(&format!("{name}[{j}] ({f})")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
        }
    }
    if !s.crossing_coef.is_empty() && s.crossing_coef.len() != 2 {
        return Err(invalid(
            st,
            at("crossing_coef"),
            format!("{} coefficients, expected none or two (box, prim)", s.crossing_coef.len()),
        ));
    }
    for (j, (&c, f)) in s.crossing_coef.iter().zip(["box", "prim"]).enumerate() {
        check_number(st, at(&format!("crossing_coef[{j}] ({f})")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
    }
    if !s.crossing_mean.is_empty() && (s.crossing_coef.is_empty() || s.crossing_mean.len() != 3) {
        let why = if s.crossing_coef.is_empty() {
            "present without crossing_coef: a model without crossing coefficients reads no count".to_string()
        } else {
            format!("{} means, expected none or three (primary, shadow, diffuse)", s.crossing_mean.len())
        };
        return Err(invalid(st, at("crossing_mean"), why));
    }
    for (j, (&c, f)) in s.crossing_mean.iter().zip(["primary", "shadow", "diffuse"]).enumerate() {
        check_number(st, at(&format!("crossing_mean[{j}] ({f})")), c, 0.0..=45.0, "a mean of ln(1 + crossings)")?;
    }
    if !s.feature_range.is_empty() && s.feature_range.len() != FEATURE_NAMES.len() {
        return Err(invalid(
            st,
            at("feature_range"),
            format!("{} ranges, expected none or one per feature ({})", s.feature_range.len(), FEATURE_NAMES.len()),
        ));
    }
    for (j, (&[lo, hi], f)) in s.feature_range.iter().zip(FEATURE_NAMES).enumerate() {
        let field = at(&format!("feature_range[{j}] ({f})"));
        if !(lo.is_finite() && hi.is_finite()) {
            return Err(invalid(st, field, format!("[{lo}, {hi}]: the bounds must be finite numbers")));
        }
        if lo > hi {
            return Err(invalid(st, field, format!("[{lo}, {hi}]: the low bound exceeds the high one")));
        }
    }
    for (law, p) in [("prior", &s.prior), ("size", &s.size)] {
        let Some(p) = p else { continue };
        for (field, coef, want) in [
            ("box_coef", &p.box_coef, FEATURE_NAMES.len()),
            ("prim_coef", &p.prim_coef, FEATURE_NAMES.len()),
            ("view_box_coef", &p.view_box_coef, VIEW_FEATURE_NAMES.len()),
            ("view_prim_coef", &p.view_prim_coef, VIEW_FEATURE_NAMES.len()),
        ] {
            let name = format!("{law}.{field}");
            let name = name.as_str();
            let view = name.contains("view");
            if law == "size"
                && (view && !coef.is_empty() || coef.get(CLAMPED_FEATURES).is_some_and(|c| c.iter().any(|&x| x != 0.0)))
            {
                return Err(invalid(
                    st,
                    at(name),
                    String::from("the triangle count's law reads no geometric feature and no view"),
                ));
            }
            if coef.len() != want && !(view && coef.is_empty()) {
                return Err(invalid(st, at(name), format!("{} coefficients, expected {want}", coef.len())));
            }
            for (j, &c) in coef.iter().enumerate() {
                check_number(st, at(&format!("{name}[{j}]")), c, -COEF_LIMIT..=COEF_LIMIT, "a coefficient")?;
            }
        }
    }
    if s.trace_price.len() != PRICE_NAMES.len() {
        return Err(invalid(
            st,
            at("trace_price"),
            format!("{} prices, expected one per price name ({})", s.trace_price.len(), PRICE_NAMES.len()),
        ));
    }
    for (j, (&p, name)) in s.trace_price.iter().zip(PRICE_NAMES).enumerate() {
        check_number(st, at(&format!("trace_price[{j}] ({name})")), p, 0.0..=PRICE_LIMIT_NS, "a price in ns")?;
    }
    if s.trace_price.iter().all(|&p| p == 0.0) {
        return Err(invalid(st, at("trace_price"), "every price is 0: tracing would be free"));
    }
    for (name, x) in s.fit.figures() {
        check_number(st, at(&format!("fit.{name}")), x, 0.0..=f64::MAX, "a root-mean-square error")?;
    }
    Ok(())
}
