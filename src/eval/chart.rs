//! A small SVG grouped bar-chart writer, and the charts of the thesis's Figures 5.3 to 5.8 from oracle results:
//! build time and frame rate per structure per scene, and box and triangle tests per ray for each structure.

use super::SceneEvaluation;
use crate::accel::StructureName;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A grouped bar chart: one group per category, one bar per series.
#[derive(Clone, Debug, Default)]
pub struct BarChart {
    /// Title above the plot.
    pub title: String,
    /// Label of the value axis.
    pub y_label: String,
    /// Category names (groups along x).
    pub categories: Vec<String>,
    /// `(series name, one value per category)`; `None` or non-finite values draw no bar.
    pub series: Vec<(String, Vec<Option<f64>>)>,
}

const PALETTE: [&str; 8] = ["#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#9c755f"];

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// The start of an SVG document of `w x h` on a white background, with `title` centred at `title_x`.
fn svg_open(w: f64, h: f64, title_x: f64, title: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    let _ = writeln!(s, r#"<text x="{title_x}" y="28" text-anchor="middle" font-size="16">{}</text>"#, esc(title));
    s
}

/// A horizontal grid line from `x0` to `x1` at `y`, labelled at its left end.
fn grid_line(s: &mut String, x0: f64, x1: f64, y: f64, label: &str) {
    let _ = writeln!(
        s,
        r##"<line x1="{x0}" y1="{y:.1}" x2="{x1:.1}" y2="{y:.1}" stroke="#ddd"/><text x="{:.1}" y="{:.1}" text-anchor="end">{label}</text>"##,
        x0 - 6.0,
        y + 4.0
    );
}

/// A "nice" step (1, 2 or 5 times a power of ten) so that `max` spans about `ticks` steps.
fn nice_step(max: f64, ticks: f64) -> f64 {
    let raw = (max / ticks).max(f64::MIN_POSITIVE);
    let p = 10f64.powf(raw.log10().floor());
    let m = raw / p;
    p * if m <= 1.0 {
        1.0
    } else if m <= 2.0 {
        2.0
    } else if m <= 5.0 {
        5.0
    } else {
        10.0
    }
}

/// A tick label with as many decimals as the step needs (scientific notation beyond 1e7).
fn fmt_tick(v: f64, step: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    if v.abs() >= 1e7 {
        return format!("{v:.1e}");
    }
    let decimals = (-step.log10().floor()).clamp(0.0, 9.0) as usize;
    format!("{v:.decimals$}")
}

impl BarChart {
    /// The chart as a standalone SVG document.
    pub fn to_svg(&self) -> String {
        // Wider for many categories (at least 26 px per group), taller bottom margin for their slanted labels.
        let many = self.categories.len() > 12;
        let longest = self.categories.iter().map(|c| c.chars().count()).max().unwrap_or(0) as f64;
        let bottom = if many { (30.0 + 6.0 * longest).clamp(90.0, 200.0) } else { 90.0 };
        let (left, right, top) = (80.0, 170.0, 50.0);
        let w = (left + right + 26.0 * self.categories.len() as f64).max(900.0);
        let h = 390.0 + bottom;
        let pw = w - left - right;
        let ph = h - top - bottom;
        let max = self
            .series
            .iter()
            .flat_map(|(_, v)| v.iter().flatten())
            .copied()
            .filter(|v| v.is_finite() && *v > 0.0)
            .fold(0.0f64, f64::max);
        let step = nice_step(if max > 0.0 { max } else { 1.0 }, 5.0);
        let top_v = (max / step).ceil().max(1.0) * step;
        let y = |v: f64| top + ph - (v / top_v).clamp(0.0, 1.0) * ph;
        let mut s = svg_open(w, h, left + pw / 2.0, &self.title);
        // Grid and ticks.
        let ticks = (top_v / step).round() as usize;
        for i in 0..=ticks {
            let v = i as f64 * step;
            let yy = y(v);
            grid_line(&mut s, left, left + pw, yy, &fmt_tick(v, step));
        }
        let _ = writeln!(
            s,
            r#"<text transform="translate(20 {:.1}) rotate(-90)" text-anchor="middle">{}</text>"#,
            top + ph / 2.0,
            esc(&self.y_label)
        );
        let _ = writeln!(
            s,
            r#"<line x1="{left}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="black"/>"#,
            top + ph,
            left + pw,
            top + ph
        );
        let nc = self.categories.len().max(1) as f64;
        let ns = self.series.len().max(1) as f64;
        let gw = pw / nc;
        let bw = gw * 0.8 / ns;
        for (ci, cat) in self.categories.iter().enumerate() {
            let gx = left + gw * ci as f64;
            for (si, (name, vals)) in self.series.iter().enumerate() {
                let Some(v) = vals.get(ci).copied().flatten().filter(|v| v.is_finite()) else {
                    continue;
                };
                let x = gx + gw * 0.1 + bw * si as f64;
                let yy = y(v.max(0.0));
                let _ = writeln!(
                    s,
                    r#"<rect x="{x:.1}" y="{yy:.1}" width="{:.1}" height="{:.1}" fill="{}"><title>{}: {}: {v:.4}</title></rect>"#,
                    (bw - 1.0).max(0.5),
                    (top + ph - yy).max(0.0),
                    PALETTE[si % PALETTE.len()],
                    esc(cat),
                    esc(name)
                );
            }
            let _ = writeln!(
                s,
                r#"<text transform="translate({:.1} {:.1}) rotate({})" text-anchor="end">{}</text>"#,
                gx + gw / 2.0,
                top + ph + 16.0,
                if many { -60 } else { -25 },
                esc(cat)
            );
        }
        for (si, (name, _)) in self.series.iter().enumerate() {
            let ly = top + 18.0 * si as f64;
            let _ = writeln!(
                s,
                r#"<rect x="{:.1}" y="{ly:.1}" width="12" height="12" fill="{}"/><text x="{:.1}" y="{:.1}">{}</text>"#,
                w - right + 20.0,
                PALETTE[si % PALETTE.len()],
                w - right + 38.0,
                ly + 10.5,
                esc(name)
            );
        }
        s.push_str("</svg>\n");
        s
    }
}

fn short_name(path: &str) -> String {
    Path::new(path).file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_else(|| path.to_string())
}

/// The charts for a set of scene evaluations: `(file name, chart)`.
///
/// * `build_ms.svg`: build time per structure per scene (Figure 5.3);
/// * `frame_rate.svg`: frames per second, `1000 / trace ms per frame` (Figure 5.4);
/// * `box_tests.svg`, `prim_tests.svg`: tests per ray per structure per scene;
/// * `tests_<structure>.svg`: box and triangle tests per ray across scenes for one structure (Figures 5.5 to 5.8).
pub fn charts(evals: &[SceneEvaluation]) -> Vec<(String, BarChart)> {
    let cats: Vec<String> = evals.iter().map(|e| short_name(&e.mesh)).collect();
    let mut names: Vec<StructureName> = Vec::new();
    for e in evals {
        for s in &e.structures {
            if let Some(n) = s.name {
                if !names.contains(&n) {
                    names.push(n);
                }
            }
        }
    }
    let per =
        |f: &dyn Fn(&SceneEvaluation, &super::StructureResult) -> Option<f64>| -> Vec<(String, Vec<Option<f64>>)> {
            names
                .iter()
                .map(|&n| (n.to_string(), evals.iter().map(|e| e.get(n).and_then(|s| f(e, s))).collect()))
                .collect()
        };
    let ok = |s: &super::StructureResult| s.error.is_none() || s.rays > 0;
    let workload = evals.first().map(|e| format!(" ({} rays, {}x{})", e.workload.as_str(), e.resolution, e.resolution));
    let workload = workload.unwrap_or_default();
    let mut out = vec![
        (
            "build_ms.svg".to_string(),
            BarChart {
                title: "Construction time".into(),
                y_label: "build time (ms)".into(),
                categories: cats.clone(),
                series: per(&|_, s| ok(s).then_some(s.build_ms.median)),
            },
        ),
        (
            "frame_rate.svg".to_string(),
            BarChart {
                title: format!("Frame rate{workload}"),
                y_label: "frames per second".into(),
                categories: cats.clone(),
                series: per(&|e, s| {
                    let per_frame = s.trace_ms.median / e.frames.max(1) as f64;
                    (ok(s) && per_frame > 0.0).then(|| 1000.0 / per_frame)
                }),
            },
        ),
        (
            "box_tests.svg".to_string(),
            BarChart {
                title: format!("Box tests per ray{workload}"),
                y_label: "box tests / node visits per ray".into(),
                categories: cats.clone(),
                series: per(&|_, s| ok(s).then_some(s.box_tests_per_ray)),
            },
        ),
        (
            "prim_tests.svg".to_string(),
            BarChart {
                title: format!("Triangle tests per ray{workload}"),
                y_label: "triangle tests per ray".into(),
                categories: cats.clone(),
                series: per(&|_, s| ok(s).then_some(s.prim_tests_per_ray)),
            },
        ),
    ];
    for &n in &names {
        let col = |f: &dyn Fn(&super::StructureResult) -> f64| -> Vec<Option<f64>> {
            evals.iter().map(|e| e.get(n).filter(|s| ok(s)).map(f)).collect()
        };
        out.push((
            format!("tests_{n}.svg"),
            BarChart {
                title: format!("Intersection tests per ray: {n}{workload}"),
                y_label: "tests per ray".into(),
                categories: cats.clone(),
                series: vec![
                    ("box tests".into(), col(&|s| s.box_tests_per_ray)),
                    ("triangle tests".into(), col(&|s| s.prim_tests_per_ray)),
                ],
            },
        ));
    }
    out
}

/// Writes [`charts`] into `dir` (created if needed); returns the paths written.
pub fn write_charts(dir: &Path, evals: &[SceneEvaluation]) -> std::io::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    let mut paths = Vec::new();
    for (file, chart) in charts(evals) {
        let p = dir.join(file);
        std::fs::write(&p, chart.to_svg())?;
        paths.push(p);
    }
    Ok(paths)
}

/// One point of a [`ScatterChart`].
#[derive(Clone, Debug, PartialEq)]
pub struct ScatterPoint {
    /// Shown on hover, and next to the point when it is on the front.
    pub label: String,
    /// x value (must be positive on a log axis).
    pub x: f64,
    /// y value.
    pub y: f64,
}

/// A scatter chart with a logarithmic x axis and a marked front: points in series (one colour each), the points
/// of `front` (indices into the flattened series, in order) joined by a line and labelled.
#[derive(Clone, Debug, Default)]
pub struct ScatterChart {
    /// Title above the plot.
    pub title: String,
    /// Label of the x axis (drawn on a log scale).
    pub x_label: String,
    /// Label of the y axis (linear).
    pub y_label: String,
    /// `(series name, points)`; non-finite points (and non-positive x) are not drawn.
    pub series: Vec<(String, Vec<ScatterPoint>)>,
    /// Indices into the points of all series in order (series 0 first), sorted by x: the front to mark.
    pub front: Vec<usize>,
    /// A note under the plot.
    pub note: String,
}

impl ScatterChart {
    /// The chart as a standalone SVG document.
    pub fn to_svg(&self) -> String {
        let (w, h) = (960.0f64, 560.0f64);
        let (left, right, top, bottom) = (80.0, 210.0, 50.0, 90.0);
        let pw = w - left - right;
        let ph = h - top - bottom;
        let all: Vec<&ScatterPoint> = self.series.iter().flat_map(|(_, p)| p.iter()).collect();
        let drawable = |p: &ScatterPoint| p.x.is_finite() && p.x > 0.0 && p.y.is_finite();
        let good: Vec<&&ScatterPoint> = all.iter().filter(|p| drawable(p)).collect();
        let (mut x0, mut x1) =
            good.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.x), b.max(p.x)));
        if !x0.is_finite() {
            (x0, x1) = (1.0, 10.0);
        }
        let (lx0, lx1) = (x0.log10().floor(), x1.log10().ceil().max(x0.log10().floor() + 1.0));
        let ymax = good.iter().map(|p| p.y).fold(0.0f64, f64::max);
        let ymin = good.iter().map(|p| p.y).fold(0.0f64, f64::min);
        let step = nice_step(if ymax - ymin > 0.0 { ymax - ymin } else { 1.0 }, 5.0);
        let (y0, y1) = ((ymin / step).floor() * step, ((ymax / step).ceil().max(1.0)) * step);
        let sx = |x: f64| left + (x.log10() - lx0) / (lx1 - lx0) * pw;
        let sy = |y: f64| top + ph - (y - y0) / (y1 - y0) * ph;
        let mut s = svg_open(w, h, left + pw / 2.0, &self.title);
        // y grid.
        let ticks = ((y1 - y0) / step).round() as usize;
        for i in 0..=ticks {
            let v = y0 + i as f64 * step;
            let yy = sy(v);
            grid_line(&mut s, left, left + pw, yy, &fmt_tick(v, step));
        }
        // x grid: decades, with 2 and 5 between.
        let mut d = lx0 as i32;
        while d as f64 <= lx1 {
            for m in [1.0, 2.0, 5.0] {
                let v = m * 10f64.powi(d);
                if v.log10() > lx1 + 1e-9 {
                    continue;
                }
                let xx = sx(v);
                let label = if v >= 1.0 { format!("{v}") } else { format!("{v:.prec$}", prec = (-d).max(0) as usize) };
                let _ = writeln!(
                    s,
                    r##"<line x1="{xx:.1}" y1="{top}" x2="{xx:.1}" y2="{:.1}" stroke="{}"/><text x="{xx:.1}" y="{:.1}" text-anchor="middle">{}</text>"##,
                    top + ph,
                    if m == 1.0 { "#ccc" } else { "#eee" },
                    top + ph + 16.0,
                    label
                );
            }
            d += 1;
        }
        let _ =
            writeln!(s, r#"<rect x="{left}" y="{top}" width="{pw:.1}" height="{ph:.1}" fill="none" stroke="black"/>"#);
        let _ = writeln!(
            s,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            left + pw / 2.0,
            top + ph + 36.0,
            esc(&self.x_label)
        );
        let _ = writeln!(
            s,
            r#"<text transform="translate(20 {:.1}) rotate(-90)" text-anchor="middle">{}</text>"#,
            top + ph / 2.0,
            esc(&self.y_label)
        );
        if !self.note.is_empty() {
            let _ = writeln!(
                s,
                r##"<text x="{left}" y="{:.1}" font-size="11" fill="#555">{}</text>"##,
                h - 16.0,
                esc(&self.note)
            );
        }
        // Front line.
        let front: Vec<&ScatterPoint> =
            self.front.iter().filter_map(|&i| all.get(i).copied()).filter(|p| drawable(p)).collect();
        if front.len() > 1 {
            let pts: Vec<String> = front.iter().map(|p| format!("{:.1},{:.1}", sx(p.x), sy(p.y))).collect();
            let _ = writeln!(
                s,
                r##"<polyline points="{}" fill="none" stroke="#e15759" stroke-width="1.5" stroke-dasharray="5 3"/>"##,
                pts.join(" ")
            );
        }
        // Points.
        for (si, (name, pts)) in self.series.iter().enumerate() {
            let colour = PALETTE[si % PALETTE.len()];
            for p in pts.iter().filter(|p| drawable(p)) {
                let _ = writeln!(
                    s,
                    r#"<circle cx="{:.1}" cy="{:.1}" r="4.5" fill="{colour}" fill-opacity="0.8"><title>{}: {} (x {:.4}, y {:.4})</title></circle>"#,
                    sx(p.x),
                    sy(p.y),
                    esc(name),
                    esc(&p.label),
                    p.x,
                    p.y
                );
            }
            let ly = top + 18.0 * si as f64;
            let _ = writeln!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="5" fill="{colour}"/><text x="{:.1}" y="{:.1}">{}</text>"#,
                w - right + 26.0,
                ly + 6.0,
                w - right + 38.0,
                ly + 10.5,
                esc(name)
            );
        }
        for (i, p) in front.iter().enumerate() {
            let _ = writeln!(
                s,
                r##"<circle cx="{:.1}" cy="{:.1}" r="8" fill="none" stroke="#e15759" stroke-width="2"/><text x="{:.1}" y="{:.1}" font-size="11" fill="#b03030">{}</text>"##,
                sx(p.x),
                sy(p.y),
                sx(p.x) + 9.0,
                sy(p.y) - 9.0 - 12.0 * (i % 2) as f64,
                esc(&p.label)
            );
        }
        let ly = top + 18.0 * self.series.len() as f64 + 8.0;
        let _ = writeln!(
            s,
            r##"<circle cx="{:.1}" cy="{:.1}" r="7" fill="none" stroke="#e15759" stroke-width="2"/><text x="{:.1}" y="{:.1}">Pareto front</text>"##,
            w - right + 26.0,
            ly + 6.0,
            w - right + 38.0,
            ly + 10.5
        );
        s.push_str("</svg>\n");
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn svg_has_one_bar_per_finite_value() {
        let c = BarChart {
            title: "t <&>".into(),
            y_label: "y".into(),
            categories: vec!["a".into(), "b".into()],
            series: vec![("s1".into(), vec![Some(1.0), Some(2.5)]), ("s2".into(), vec![None, Some(f64::NAN)])],
        };
        let svg = c.to_svg();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<title>").count(), 2);
        assert!(svg.contains("t &lt;&amp;&gt;"));
    }

    #[test]
    fn scatter_draws_finite_points_and_the_front() {
        let p = |label: &str, x: f64, y: f64| ScatterPoint { label: label.into(), x, y };
        let c = ScatterChart {
            title: "t".into(),
            x_label: "ms".into(),
            y_label: "regret".into(),
            series: vec![
                ("a".into(), vec![p("a1", 1.0, 0.5), p("a2", 100.0, 0.1)]),
                ("b".into(), vec![p("b1", 0.0, 0.2), p("b2", 10.0, f64::NAN)]),
            ],
            front: vec![0, 1],
            note: "n".into(),
        };
        let svg = c.to_svg();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<title>").count(), 2, "x <= 0 and NaN are not drawn");
        assert_eq!(svg.matches("<polyline").count(), 1);
        assert!(svg.contains(">a2</text>"), "front points are labelled");
    }

    #[test]
    fn tick_labels() {
        assert_eq!(fmt_tick(15000.0, 5000.0), "15000");
        assert_eq!(fmt_tick(0.30000000000000004, 0.1), "0.3");
        assert_eq!(fmt_tick(0.0, 0.1), "0");
        assert_eq!(fmt_tick(2.5e7, 5e6), "2.5e7");
    }

    #[test]
    fn nice_steps() {
        assert_eq!(nice_step(10.0, 5.0), 2.0);
        assert_eq!(nice_step(7.0, 5.0), 2.0);
        assert!((nice_step(0.3, 5.0) - 0.1).abs() < 1e-12);
        assert_eq!(nice_step(900.0, 5.0), 200.0);
    }
}
