//! Grouped bar charts and log-x scatter charts drawn with [`plotters`] (SVG backend), and the charts of the
//! thesis's Figures 5.3 to 5.8 from oracle results: build time and frame rate per structure per scene, and box and
//! triangle tests per ray for each structure.
//!
//! Text is written as SVG `<text>` elements in the generic `sans-serif` family, so no font is loaded; plotters
//! estimates text widths for the layout.

use super::SceneEvaluation;
use crate::accel::StructureName;
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::ops::Range;
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

const PALETTE: [RGBColor; 8] = [
    RGBColor(0x4e, 0x79, 0xa7),
    RGBColor(0xf2, 0x8e, 0x2b),
    RGBColor(0xe1, 0x57, 0x59),
    RGBColor(0x76, 0xb7, 0xb2),
    RGBColor(0x59, 0xa1, 0x4f),
    RGBColor(0xed, 0xc9, 0x48),
    RGBColor(0xb0, 0x7a, 0xa1),
    RGBColor(0x9c, 0x75, 0x5f),
];
const GRID: RGBColor = RGBColor(0xdd, 0xdd, 0xdd);
const FRONT: RGBColor = RGBColor(0xe1, 0x57, 0x59);
const FRONT_TEXT: RGBColor = RGBColor(0xb0, 0x30, 0x30);
const NOTE: RGBColor = RGBColor(0x55, 0x55, 0x55);

/// The colour of series `i`.
fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// A sans-serif text style whose SVG `font-size` is `px` (plotters writes `size / 1.24`).
fn font(px: f64) -> TextStyle<'static> {
    FontDesc::new(FontFamily::SansSerif, px * 1.24, FontStyle::Normal).into()
}

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;
type DrawResult = Result<(), DrawingAreaErrorKind<std::io::Error>>;

/// An SVG document of `w x h` on a white background, drawn by `draw`. The SVG backend writes into a string, so
/// drawing does not fail in practice; if it does, the error is logged and the document so far (closed) returned.
fn render(size: (u32, u32), draw: impl FnOnce(&Area<'_>) -> DrawResult) -> String {
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, size).into_drawing_area();
        if let Err(e) = root.fill(&WHITE).and_then(|_| draw(&root)).and_then(|_| root.present()) {
            log::warn!("chart: drawing failed: {e}");
        }
    }
    s
}

/// A legend marker.
enum Swatch {
    /// A filled square (bars).
    Square(RGBColor),
    /// A filled dot (scatter points).
    Dot(RGBColor),
    /// An open ring (the marked front).
    Ring,
}

/// Draws a legend in the right margin of `chart`: entries `(marker, name, extra gap above)` from the top of the
/// plotting area down, 18 px apart. (Plotters' own series labels are drawn inside the plotting area, which clips
/// them.)
fn legend<X: Ranged, Y: Ranged>(
    root: &Area<'_>,
    chart: &ChartContext<'_, SVGBackend<'_>, Cartesian2d<X, Y>>,
    entries: &[(Swatch, &str, i32)],
) -> DrawResult {
    let area = chart.plotting_area();
    let (x0, top) = area.get_base_pixel();
    let x = x0 + area.dim_in_pixel().0 as i32 + 20;
    let style = font(12.0).pos(Pos::new(HPos::Left, VPos::Center));
    for (i, (swatch, name, gap)) in entries.iter().enumerate() {
        let y = top + 18 * i as i32 + gap;
        match swatch {
            Swatch::Square(c) => root.draw(&Rectangle::new([(x, y), (x + 12, y + 12)], c.filled()))?,
            Swatch::Dot(c) => root.draw(&Circle::new((x + 6, y + 6), 5, c.filled()))?,
            Swatch::Ring => root.draw(&Circle::new((x + 6, y + 6), 7, FRONT.stroke_width(2)))?,
        }
        root.draw(&Text::new(*name, (x + 18, y + 6), style.clone()))?;
    }
    Ok(())
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

/// The ticks `y0, y0 + step, ..., y1` of a value axis.
fn ticks(y0: f64, y1: f64, step: f64) -> Vec<f64> {
    let n = ((y1 - y0) / step).round().clamp(0.0, 1000.0) as usize;
    (0..=n).map(|i| y0 + i as f64 * step).collect()
}

/// A value axis (linear or log) with the ticks given instead of chosen by plotters; no light grid lines.
struct Ticked<R> {
    inner: R,
    ticks: Vec<f64>,
}

impl<R: Ranged<ValueType = f64>> Ranged for Ticked<R> {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }

    fn key_points<H: KeyPointHint>(&self, hint: H) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            self.ticks.clone()
        }
    }

    fn range(&self) -> Range<f64> {
        self.inner.range()
    }
}

/// A linear axis over `range` with `ticks`.
fn linear(range: Range<f64>, ticks: Vec<f64>) -> Ticked<RangedCoordf64> {
    Ticked { inner: range.into(), ticks }
}

impl BarChart {
    /// The chart as a standalone SVG document.
    ///
    /// Category labels are horizontal under their group when they fit, vertical (reading upwards) otherwise; the
    /// chart widens to at least 26 px per group for many categories. Series share a legend at the right.
    pub fn to_svg(&self) -> String {
        let nc = self.categories.len();
        let (left, right) = (80.0, 170.0);
        let w = (left + right + 26.0 * nc as f64).max(900.0).ceil();
        let label_style = font(12.0);
        let estimate = |s: &str| label_style.font.box_size(s).map_or(7 * s.chars().count() as u32, |b| b.0);
        let longest = self.categories.iter().map(|c| estimate(c)).max().unwrap_or(0) as f64;
        let group_px = (w - left - right) / nc.max(1) as f64;
        let vertical = nc > 12 || longest > group_px - 8.0;
        let bottom = if vertical { (30.0 + longest).clamp(90.0, 240.0).ceil() } else { 90.0 };
        let h = 390.0 + bottom;
        let max = self
            .series
            .iter()
            .flat_map(|(_, v)| v.iter().flatten())
            .copied()
            .filter(|v| v.is_finite() && *v > 0.0)
            .fold(0.0f64, f64::max);
        let step = nice_step(if max > 0.0 { max } else { 1.0 }, 5.0);
        let top_v = (max / step).ceil().max(1.0) * step;
        render((w as u32, h as u32), |root| {
            let mut chart = ChartBuilder::on(root)
                .caption(&self.title, font(16.0))
                .margin_top(20)
                .margin_left(8)
                .margin_right(right as u32)
                .y_label_area_size(left as u32 - 8)
                .x_label_area_size(bottom as u32)
                .build_cartesian_2d(
                    linear(0.0..nc.max(1) as f64, Vec::new()),
                    linear(0.0..top_v, ticks(0.0, top_v, step)),
                )?;
            let y_fmt = |v: &f64| fmt_tick(*v, step);
            chart
                .configure_mesh()
                .disable_x_mesh()
                .bold_line_style(GRID)
                .axis_style(BLACK)
                .label_style(font(12.0))
                .axis_desc_style(font(12.0))
                .y_label_formatter(&y_fmt)
                .y_desc(&self.y_label)
                .draw()?;
            let ns = self.series.len().max(1) as f64;
            let bw = 0.8 / ns;
            // A 1 px gap between neighbouring bars, unless that would leave too little of them.
            let gap = u32::from(group_px * bw >= 3.0);
            for (si, (_, vals)) in self.series.iter().enumerate() {
                let fill = colour(si).filled();
                let bars = vals.iter().take(nc).enumerate().filter_map(|(ci, v)| {
                    let v = v.filter(|v| v.is_finite())?.clamp(0.0, top_v);
                    let x = ci as f64 + 0.1 + bw * si as f64;
                    let mut bar = Rectangle::new([(x, 0.0), (x + bw, v)], fill);
                    bar.set_margin(0, 0, 0, gap);
                    Some(bar)
                });
                chart.draw_series(bars)?;
            }
            let (slant, pos) = if vertical {
                (FontTransform::Rotate270, Pos::new(HPos::Right, VPos::Center))
            } else {
                (FontTransform::None, Pos::new(HPos::Center, VPos::Top))
            };
            let style = label_style.transform(slant).pos(pos);
            for (ci, cat) in self.categories.iter().enumerate() {
                let (x, y) = chart.backend_coord(&(ci as f64 + 0.5, 0.0));
                root.draw(&Text::new(cat.as_str(), (x, y + 8), style.clone()))?;
            }
            let entries: Vec<_> = self
                .series
                .iter()
                .enumerate()
                .map(|(si, (name, _))| (Swatch::Square(colour(si)), name.as_str(), 0))
                .collect();
            legend(root, &chart, &entries)
        })
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
    /// Drawn next to the point when it is on the front.
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

/// The x tick values of a log axis over the decades `10^d0 ..= 10^d1`: `1, 2, 5` times each power of ten, and
/// whether each is a decade.
fn log_ticks(d0: f64, d1: f64) -> Vec<(f64, bool)> {
    let mut out = Vec::new();
    let mut d = d0 as i32;
    while f64::from(d) <= d1 {
        for m in [1.0, 2.0, 5.0] {
            let v = m * 10f64.powi(d);
            if v.log10() <= d1 + 1e-9 {
                out.push((v, m == 1.0));
            }
        }
        d += 1;
    }
    out
}

/// A log-axis tick label: integers from 1 up, as many decimals as the decade needs below.
fn fmt_log_tick(v: f64) -> String {
    if v >= 1.0 {
        format!("{v}")
    } else {
        let prec = (-v.log10().floor()).clamp(0.0, 400.0) as usize;
        format!("{v:.prec$}")
    }
}

impl ScatterChart {
    /// The chart as a standalone SVG document.
    pub fn to_svg(&self) -> String {
        let (w, h) = (960u32, 560u32);
        let (left, right, bottom) = (80u32, 210u32, 90u32);
        let all: Vec<&ScatterPoint> = self.series.iter().flat_map(|(_, p)| p.iter()).collect();
        let drawable = |p: &ScatterPoint| p.x.is_finite() && p.x > 0.0 && p.y.is_finite();
        let good: Vec<&ScatterPoint> = all.iter().copied().filter(|p| drawable(p)).collect();
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
        let xticks = log_ticks(lx0, lx1);
        let front: Vec<&ScatterPoint> =
            self.front.iter().filter_map(|&i| all.get(i).copied()).filter(|p| drawable(p)).collect();
        render((w, h), |root| {
            let mut chart = ChartBuilder::on(root)
                .caption(&self.title, font(16.0))
                .margin_top(20)
                .margin_left(8)
                .margin_right(right)
                .margin_bottom(bottom - 45)
                .y_label_area_size(left - 8)
                .x_label_area_size(45)
                .build_cartesian_2d(
                    Ticked {
                        inner: LogCoord::from((10f64.powf(lx0)..10f64.powf(lx1)).log_scale()),
                        ticks: xticks.iter().map(|t| t.0).collect(),
                    },
                    linear(y0..y1, ticks(y0, y1, step)),
                )?;
            let y_fmt = |v: &f64| fmt_tick(*v, step);
            let x_fmt = |v: &f64| fmt_log_tick(*v);
            chart
                .configure_mesh()
                .disable_x_mesh()
                .bold_line_style(GRID)
                .axis_style(BLACK)
                .label_style(font(12.0))
                .axis_desc_style(font(12.0))
                .x_label_formatter(&x_fmt)
                .y_label_formatter(&y_fmt)
                .x_desc(&self.x_label)
                .y_desc(&self.y_label)
                .draw()?;
            // x grid: decades darker than the 2s and 5s between them; then the frame.
            chart.draw_series(xticks.iter().map(|&(v, decade)| {
                let c = if decade { RGBColor(0xcc, 0xcc, 0xcc) } else { RGBColor(0xee, 0xee, 0xee) };
                PathElement::new(vec![(v, y0), (v, y1)], c)
            }))?;
            let (xr, yr) = (chart.x_range(), chart.y_range());
            chart.draw_series(std::iter::once(Rectangle::new([(xr.start, yr.start), (xr.end, yr.end)], BLACK)))?;
            if !self.note.is_empty() {
                let style = font(11.0).color(&NOTE).pos(Pos::new(HPos::Left, VPos::Bottom));
                root.draw(&Text::new(self.note.as_str(), (left as i32, h as i32 - 16), style))?;
            }
            if front.len() > 1 {
                chart.draw_series(DashedLineSeries::new(
                    front.iter().map(|p| (p.x, p.y)),
                    5,
                    3,
                    FRONT.stroke_width(2),
                ))?;
            }
            for (si, (_, pts)) in self.series.iter().enumerate() {
                let c = colour(si);
                chart.draw_series(
                    pts.iter().filter(|p| drawable(p)).map(|p| Circle::new((p.x, p.y), 5, c.mix(0.8).filled())),
                )?;
            }
            let label_style = font(11.0).color(&FRONT_TEXT).pos(Pos::new(HPos::Left, VPos::Bottom));
            chart.draw_series(front.iter().enumerate().map(|(i, p)| {
                EmptyElement::at((p.x, p.y))
                    + Circle::new((0, 0), 8, FRONT.stroke_width(2))
                    + Text::new(p.label.clone(), (9, -9 - 12 * (i % 2) as i32), label_style.clone())
            }))?;
            let mut entries: Vec<_> = self
                .series
                .iter()
                .enumerate()
                .map(|(si, (name, _))| (Swatch::Dot(colour(si)), name.as_str(), 0))
                .collect();
            entries.push((Swatch::Ring, "Pareto front", 8));
            legend(root, &chart, &entries)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The elements of an SVG document named `tag`, each as its source text.
    fn elements<'a>(svg: &'a str, tag: &str) -> Vec<&'a str> {
        let open = format!("<{tag} ");
        svg.match_indices(&open).map(|(i, _)| &svg[i..i + svg[i..].find('>').map_or(0, |e| e + 1)]).collect()
    }

    /// The text of every `<text>` element, trimmed.
    fn texts(svg: &str) -> Vec<&str> {
        svg.split("<text ")
            .skip(1)
            .filter_map(|t| {
                let body = &t[t.find('>')? + 1..];
                Some(body[..body.find("</text>")?].trim())
            })
            .collect()
    }

    /// A document with one `<svg>` root whose `<text>` elements are all closed.
    fn assert_well_formed(svg: &str) {
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"), "{svg}");
        assert_eq!(svg.matches("<svg").count(), 1);
        assert_eq!(svg.matches("<text ").count(), svg.matches("</text>").count());
    }

    #[test]
    fn svg_has_one_bar_per_finite_value() {
        let c = BarChart {
            title: "t <&>".into(),
            y_label: "y".into(),
            categories: vec!["a".into(), "b".into()],
            series: vec![("s1".into(), vec![Some(1.0), Some(2.5)]), ("s2".into(), vec![None, Some(f64::NAN)])],
        };
        let svg = c.to_svg();
        assert_well_formed(&svg);
        let rects = elements(&svg, "rect");
        let filled = |colour: &str| rects.iter().filter(|r| r.contains(&format!("fill=\"{colour}\""))).count();
        // One legend square per series, plus one bar per finite value.
        assert_eq!(filled("#4E79A7"), 3, "{svg}");
        assert_eq!(filled("#F28E2B"), 1, "{svg}");
        let texts = texts(&svg);
        for t in ["t &lt;&amp;&gt;", "y", "a", "b", "s1", "s2", "0", "2.5"] {
            assert!(texts.contains(&t), "{t} in {texts:?}");
        }
        assert_eq!(svg.matches("rotate(").count(), 1, "only the axis title is turned: short labels fit");
    }

    #[test]
    fn many_categories_widen_the_chart_and_turn_their_labels() {
        let categories: Vec<String> = (0..40).map(|i| format!("scene-with-a-long-name-{i}")).collect();
        let c = BarChart {
            title: "t".into(),
            y_label: "y".into(),
            series: vec![("s".into(), (0..40).map(|i| Some(f64::from(i))).collect())],
            categories,
        };
        let svg = c.to_svg();
        assert_well_formed(&svg);
        assert!(svg.starts_with(r#"<svg width="1290" height="#), "{}", &svg[..60]);
        // 40 bars (the value 0 draws an empty one) and the legend square.
        assert_eq!(elements(&svg, "rect").iter().filter(|r| r.contains("#4E79A7")).count(), 41);
        assert_eq!(svg.matches("rotate(270").count(), 41, "the axis title and one upright label per category");
    }

    #[test]
    fn empty_charts_still_draw() {
        assert_well_formed(&BarChart::default().to_svg());
        assert_well_formed(&ScatterChart::default().to_svg());
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
        assert_well_formed(&svg);
        let circles = elements(&svg, "circle");
        let dots = |colour: &str| circles.iter().filter(|c| c.contains(&format!("fill=\"{colour}\""))).count();
        // x <= 0 and NaN are not drawn; every series has a legend dot.
        assert_eq!(dots("#4E79A7"), 3, "{svg}");
        assert_eq!(dots("#F28E2B"), 1, "{svg}");
        // Two front rings and the legend's.
        assert_eq!(circles.iter().filter(|c| c.contains("stroke=\"#E15759\"")).count(), 3, "{svg}");
        assert!(elements(&svg, "polyline").iter().any(|l| l.contains("#E15759")), "the front is joined");
        let texts = texts(&svg);
        for t in ["a1", "a2", "n", "ms", "regret", "Pareto front", "1", "10", "100", "0.5"] {
            assert!(texts.contains(&t), "{t} in {texts:?}");
        }
        assert!(!texts.contains(&"b1"), "only front points are labelled");
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
