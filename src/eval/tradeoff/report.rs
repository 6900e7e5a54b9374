//! Charts and Markdown tables of a sweep.

use super::*;

/// The series a setting is drawn in: which knob it varies.
fn knob(r: &SettingResult, reference: &SettingResult) -> String {
    if r.class_rule != reference.class_rule {
        format!("class rules ({})", r.backend)
    } else {
        format!("{}-bit, sampled, {}", r.morton_bits, r.backend)
    }
}

/// The labelled scatter of `(time, y)` per setting, with its Pareto front (both minimized).
fn scatter(
    results: &[SettingResult],
    title: String,
    y_label: &str,
    y: &dyn Fn(&SettingResult) -> Option<f64>,
) -> ScatterChart {
    let Some(reference) = results.first() else { return ScatterChart::default() };
    let mut series: Vec<(String, Vec<ScatterPoint>)> = Vec::new();
    let mut order: Vec<&SettingResult> = Vec::new();
    for r in results {
        let name = knob(r, reference);
        if !series.iter().any(|(n, _)| *n == name) {
            series.push((name, Vec::new()));
        }
    }
    for (name, pts) in series.iter_mut() {
        for r in results.iter().filter(|r| knob(r, reference) == *name) {
            pts.push(ScatterPoint { label: r.label.clone(), x: r.time_ms, y: y(r).unwrap_or(f64::NAN) });
            order.push(r);
        }
    }
    let xy: Vec<(f64, f64)> = order.iter().map(|r| (r.time_ms, y(r).unwrap_or(f64::NAN))).collect();
    ScatterChart {
        title,
        x_label: "characterization time, all scenes (ms, log scale)".into(),
        y_label: y_label.into(),
        series,
        front: pareto_front(&xy),
        note:
            "circled: the Pareto front (no other setting is both faster and lower); labels backend/bits/rule/1:stride"
                .into(),
    }
}

/// The charts of a sweep: `tradeoff-<workload>.svg` (time against mean regret per setting) for each workload, and
/// `tradeoff-statistics.svg` (time against the mean drift of the effect size, workload-free).
pub fn charts(results: &[SettingResult], workloads: &[String]) -> Vec<(String, ScatterChart)> {
    let scenes = results.first().map_or(0, |r| r.scenes.len());
    let mut out: Vec<(String, ScatterChart)> = workloads
        .iter()
        .map(|w| {
            let n = results.first().and_then(|r| r.accuracy(w)).map_or(0, |a| a.scenes);
            (
                format!("tradeoff-{w}.svg"),
                scatter(
                    results,
                    format!("Speed against accuracy: {w} rays ({n} scenes with oracle results)"),
                    "mean regret of the selection vs the oracle's best (lower is better)",
                    &|r| r.accuracy(w).filter(|a| a.scenes > 0).map(|a| a.mean_regret),
                ),
            )
        })
        .collect();
    out.push((
        "tradeoff-statistics.svg".into(),
        scatter(
            results,
            format!("Speed against fidelity of the statistics ({scenes} scenes)"),
            "mean |V - V_full| over scenes (lower is better)",
            &|r| Some(r.mean_effect_size_drift),
        ),
    ));
    out
}

fn stride_label(s: Option<u32>) -> String {
    s.map_or("-".into(), |s| format!("1/{s}"))
}

/// The markdown tables of a sweep: per workload, one row per setting (time, agreement, regret, drift, front), and
/// the least-work table per scene.
pub fn markdown(results: &[SettingResult], workloads: &[String], suff: &[Sufficiency]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let Some(reference) = results.first() else { return s };
    for w in workloads {
        let xy: Vec<(f64, f64)> = results
            .iter()
            .map(|r| (r.time_ms, r.accuracy(w).filter(|a| a.scenes > 0).map_or(f64::NAN, |a| a.mean_regret)))
            .collect();
        let front = pareto_front(&xy);
        let n = reference.accuracy(w).map_or(0, |a| a.scenes);
        let _ = writeln!(s, "### {w} rays ({n} scenes with oracle results)\n");
        let _ = writeln!(
            s,
            "| setting | time ms | vs full | same selection | oracle best | within noise | mean regret | worst regret \
             (scene) | mean dV | max dV | mean TV | max dk | front |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|:-:|");
        for (i, r) in results.iter().enumerate() {
            let a = r.accuracy(w).cloned().unwrap_or_default();
            let worst = Path::new(&a.worst_scene).file_name().map_or(String::new(), |f| f.to_string_lossy().into());
            let _ = writeln!(
                s,
                "| {} | {:.1} | {:.2}x | {:.0}% | {:.0}% | {:.0}% | {:.3} | {:.3} ({}) | {:.4} | {:.4} | {:.4} | {} | {} |",
                r.label,
                r.time_ms,
                r.time_ms / reference.time_ms.max(f64::MIN_POSITIVE),
                100.0 * r.same_selection,
                100.0 * a.agree_best,
                100.0 * a.agree_within_noise,
                a.mean_regret,
                a.worst_regret,
                worst,
                r.mean_effect_size_drift,
                r.max_effect_size_drift,
                r.mean_histogram_distance,
                r.max_k_delta,
                if front.contains(&i) { "yes" } else { "" }
            );
        }
        s.push('\n');
    }
    let _ = writeln!(s, "### Least work that still gives the full computation's answer\n");
    let _ = writeln!(
        s,
        "| scene | triangles | sample: same selection | sample: same statistics | sample at the full k: same statistics \
         | fixed k: same selection | other rules, same selection | 30 bits enough |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---|:-:|");
    for x in suff {
        let name = scene_key(&x.mesh);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} |",
            name,
            x.triangles,
            stride_label(x.stride_selection),
            stride_label(x.stride_statistics),
            stride_label(x.stride_same_k),
            x.fixed_k_selection.map_or("-".into(), |k| k.to_string()),
            if x.rules_with_same_selection.is_empty() { "-".into() } else { x.rules_with_same_selection.join(", ") },
            if x.bits30_enough { "yes" } else { "no" }
        );
    }
    s
}

/// The structures table: per workload and scene, the oracle's best, the structures within noise of it and the
/// cheapest of them (least build time, then memory), and a count of the scenes where a cheaper structure than the
/// best is within noise.
pub fn structures_markdown(oracle: &[OracleRecord], workloads: &[String]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "| workload | scene | best | within noise of the best | cheapest within noise |");
    let _ = writeln!(s, "|---|---|---|---|---|");
    let mut counts = Vec::new();
    for w in workloads {
        let mut cheaper = 0;
        let mut total = 0;
        for o in oracle.iter().filter(|o| o.workload.as_str() == w) {
            let Some(best) = o.best().and_then(|b| b.name) else { continue };
            let near = o.within_noise();
            let cheapest = o.cheapest_within_noise();
            total += 1;
            if cheapest != Some(best) {
                cheaper += 1;
            }
            let _ = writeln!(
                s,
                "| {w} | {} | {best} | {} | {}{} |",
                scene_key(&o.mesh),
                near.iter().map(|n| n.as_str()).collect::<Vec<_>>().join(", "),
                cheapest.map_or("-", |c| c.as_str()),
                if cheapest != Some(best) { " (cheaper than the best)" } else { "" }
            );
        }
        counts.push(format!("{w}: {cheaper} of {total} scenes"));
    }
    let _ = writeln!(s, "\nA cheaper structure is within noise of the best on {}.", counts.join("; "));
    s
}
