//! The report of one characterized mesh (or one frame): the JSON object of `docs/spec.md` and a text rendering for people.

use super::{SceneKind, Selection, Structure};
use crate::characterize::{Characterization, Features, PassTime};
use serde::ser::SerializeMap;
use std::fmt::Write as _;

/// `lo` and `hi` of step 2 (three times the centroid bounds).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Bounds {
    /// Per-axis minimum of the centroid keys.
    pub lo: [f32; 3],
    /// Per-axis maximum of the centroid keys.
    pub hi: [f32; 3],
}

/// Pass timings, serialized as a JSON object `{pass: ms, ..., "total": ms}` in pass order.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Timings(pub Vec<PassTime>);

impl serde::Serialize for Timings {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for p in &self.0 {
            m.serialize_entry(&p.name, &p.ms)?;
        }
        m.end()
    }
}

/// One JSON object per mesh or frame: every field `docs/spec.md` asks for, and more.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Report {
    /// The input path or mesh name.
    pub mesh: String,
    /// Frame index within an animation (absent for a static scene).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<usize>,
    /// The frame's own file or name within an animation (absent for a static scene).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame_file: Option<String>,
    /// `n`: triangles characterized (the sample).
    pub triangles: u64,
    /// Triangles in the mesh.
    pub total_triangles: u64,
    /// Triangles in the sample (equal to `triangles`).
    pub sampled_triangles: u64,
    /// Every `sample_stride`-th triangle was characterized.
    pub sample_stride: u32,
    /// Sampled triangles whose area is exactly zero (they are characterized like the others).
    pub zero_area_triangles: u64,
    /// `3 b`.
    pub morton_bits: u32,
    /// Step 2.
    pub bounds: Bounds,
    /// Smallest Morton code.
    pub code_min: u64,
    /// Largest Morton code.
    pub code_max: u64,
    /// Mean code.
    pub mean: f64,
    /// Population standard deviation of the codes.
    pub std_dev: f64,
    /// Population skewness of the codes.
    pub skewness: f64,
    /// Class-count rule (`doane`, `sturges`, `sqrt` or a fixed count).
    pub class_rule: String,
    /// `k`.
    pub classes: u32,
    /// `O_0 .. O_{k-1}`.
    pub histogram: Vec<u64>,
    /// Chi-square against uniform.
    pub chi_square: f64,
    /// `k - 1`.
    pub dof: u32,
    /// Significance of the test.
    pub alpha: f64,
    /// `P(X >= chi_square)`.
    pub p_value: f64,
    /// Critical value at `alpha`.
    pub critical_value: f64,
    /// `chi_square <= critical_value`.
    pub uniform: bool,
    /// Cramér's V.
    pub effect_size: f64,
    /// Classes with no triangle.
    pub empty_classes: u32,
    /// Classes with more triangles than the mean.
    pub concentrated_classes: u32,
    /// Share of the triangles in concentrated classes.
    pub concentrated_share: f64,
    /// `static` or `dynamic`.
    pub kind: SceneKind,
    /// The selected structure.
    pub selected: Structure,
    /// The policy that selected it.
    pub policy: String,
    /// Why.
    pub reasons: Vec<String>,
    /// The best of the driver's acceleration structures when the policy weighed them (`flags`,
    /// `predicted_total_ms`, `chosen`, and for an animation traced with `rt_update` its per-frame `plan`); when
    /// `chosen`, it is the overall choice (see [`super::Selection::driver`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub driver: Option<super::DriverSelection>,
    /// The calibrated policy's predicted costs per structure (absent for the thesis policy).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub predicted: Option<Vec<crate::cost::Prediction>>,
    /// The structures the policy did not consider because their reference or byte bound exceeds the budget
    /// ([`super::budget`]), each with `structure`, `what`, `needed`, `budget`, `bound` and `reason`; empty when none.
    pub excluded: Vec<super::Exclusion>,
    /// The scene features of this frame the calibrated policy read (see [`crate::characterize::features`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub features: Option<Features>,
    /// `naive`, `cpu` or `vulkan`.
    pub backend: String,
    /// The device.
    pub device: String,
    /// Milliseconds per pass, and `total`.
    pub timings_ms: Timings,
    /// What deciding cost against what the decision is about ([`SelectionCost`]), when measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub selection_cost: Option<SelectionCost>,
    /// The close call the policy measured (level 3 of [`super::Selector`]): per structure measured,
    /// `structure`, `total_ms` (median over the repeats), `build_ms`, `trace_ms` (one frame), `repeats`, `rays`;
    /// absent when nothing was measured.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub measured: Vec<crate::cost::measured::MeasuredTotal>,
    /// The level of inquiry that decided (`prior`, `counted`, `timed`, `measured`; absent for the thesis policy).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub level: Option<super::Level>,
    /// Each level the calibrated policy weighed beyond the prior ([`super::Step`]); absent when none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub steps: Vec<super::Step>,
}

/// The price of the decision against what it decides: the characterization (with the features) and the selection,
/// wall time, this process. A static scene decides once per build, and its decision is spread over the frames that
/// build serves (`--frames`); an animation decides on every frame. The goal is at most 1% ([`SelectionCost::GOAL`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SelectionCost {
    /// Characterizing every frame and computing the features, ms (wall time, this process).
    pub characterize_ms: f64,
    /// The selection (the predictions, any inquiry beyond the prior, the choice), ms.
    pub select_ms: f64,
    /// The decision's cost per frame rendered: both of the above over the frames they serve (an animation's
    /// decisions over its frames; a static scene's one decision over the frames of its one build).
    pub per_frame_ms: f64,
    /// The chosen structure's predicted time per frame: its predicted total (build and traces) over the frames,
    /// ms; `None` without predictions (the thesis policy).
    pub predicted_frame_ms: Option<f64>,
    /// `per_frame_ms / predicted_frame_ms`: the decision's share of what it decides.
    pub share: Option<f64>,
    /// `share <= GOAL`.
    pub within_goal: Option<bool>,
    /// `once per build` (a static scene) or `per frame` (an animation).
    pub counted: &'static str,
}

impl SelectionCost {
    /// The goal: the decision costs at most this share of what it decides.
    pub const GOAL: f64 = 0.01;

    /// The cost of a decision that took `characterize_ms` and `select_ms`, for a scene of `frames_characterized`
    /// frames (more than one: an animation, deciding per frame) whose chosen prediction (`predicted`) totals
    /// `frames` frames.
    pub fn new(
        characterize_ms: f64,
        select_ms: f64,
        frames_characterized: usize,
        predicted: Option<&crate::cost::Prediction>,
        frames: u64,
    ) -> Self {
        let frames = frames.max(1);
        let animation = frames_characterized > 1;
        let served = if animation { frames_characterized as u64 } else { frames };
        let per_frame_ms = (characterize_ms + select_ms) / served as f64;
        let predicted_frame_ms = predicted.map(|p| p.total_ms / frames as f64);
        let share = predicted_frame_ms.filter(|&f| f > 0.0).map(|f| per_frame_ms / f);
        SelectionCost {
            characterize_ms,
            select_ms,
            per_frame_ms,
            predicted_frame_ms,
            share,
            within_goal: share.map(|s| s <= Self::GOAL),
            counted: if animation { "per frame" } else { "once per build" },
        }
    }
}

impl Report {
    /// A report of `c` for the mesh called `mesh`: static, not yet selected (BVH with no reasons), no zero-area
    /// count. Fill the rest with [`Report::frame`], [`Report::selection`] and [`Report::zero_area`].
    pub fn new(mesh: impl Into<String>, c: &Characterization) -> Report {
        let mut timings = c.timings.clone();
        if !timings.iter().any(|p| p.name == PassTime::TOTAL) {
            let total = timings.iter().map(|p| p.ms).sum();
            timings.push(PassTime { name: PassTime::TOTAL.into(), ms: total });
        }
        let s = &c.stats;
        Report {
            mesh: mesh.into(),
            frame: None,
            frame_file: None,
            triangles: c.triangles,
            total_triangles: c.total_triangles,
            sampled_triangles: c.triangles,
            sample_stride: c.params.sample_stride,
            zero_area_triangles: 0,
            morton_bits: c.params.morton_bits.total(),
            bounds: Bounds { lo: c.lo, hi: c.hi },
            code_min: c.code_stats.code_min,
            code_max: c.code_stats.code_max,
            mean: c.moments.mean,
            std_dev: c.moments.std_dev,
            skewness: c.moments.skewness,
            class_rule: c.params.class_rule.name(),
            classes: c.classes,
            histogram: c.histogram.clone(),
            chi_square: s.chi_square,
            dof: s.dof,
            alpha: c.params.alpha,
            p_value: s.p_value,
            critical_value: s.critical_value,
            uniform: s.uniform,
            effect_size: s.cramers_v,
            empty_classes: s.empty_classes,
            concentrated_classes: s.concentrated_classes,
            concentrated_share: s.concentrated_share,
            kind: SceneKind::Static,
            selected: Structure::Bvh,
            policy: String::new(),
            reasons: Vec::new(),
            driver: None,
            predicted: None,
            excluded: Vec::new(),
            features: None,
            backend: c.backend.clone(),
            device: c.device.clone(),
            timings_ms: Timings(timings),
            selection_cost: None,
            measured: Vec::new(),
            level: None,
            steps: Vec::new(),
        }
    }

    /// Sets the frame index and the frame's file or name (for animations).
    pub fn frame(mut self, frame: usize, file: impl Into<String>) -> Report {
        self.frame = Some(frame);
        self.frame_file = Some(file.into());
        self
    }

    /// Sets the scene kind, the policy's name and its selection (structure, reasons, exclusions).
    pub fn selection(mut self, kind: SceneKind, policy: &str, sel: &Selection) -> Report {
        self.kind = kind;
        self.policy = policy.to_string();
        self.selected = sel.structure;
        self.reasons = sel.reasons.iter().map(|r| r.text.clone()).collect();
        self.excluded = sel.excluded.clone();
        self.driver = sel.driver.clone();
        self
    }

    /// Sets the calibrated policy's predicted costs.
    pub fn predicted(mut self, p: Vec<crate::cost::Prediction>) -> Report {
        self.predicted = Some(p);
        self
    }

    /// Sets the close call measured ([`Report::measured`]).
    pub fn measured(mut self, m: Vec<crate::cost::measured::MeasuredTotal>) -> Report {
        self.measured = m;
        self
    }

    /// Sets the level that decided and the steps weighed ([`super::Decision`]).
    pub fn inquiry(mut self, level: super::Level, steps: Vec<super::Step>) -> Report {
        self.level = Some(level);
        self.steps = steps;
        self
    }

    /// Sets the cost of the decision.
    pub fn selection_cost(mut self, c: SelectionCost) -> Report {
        self.selection_cost = Some(c);
        self
    }

    /// Sets the scene features of this frame.
    pub fn features(mut self, f: Features) -> Report {
        self.features = Some(f);
        self
    }

    /// Sets the number of zero-area triangles.
    pub fn zero_area(mut self, count: u64) -> Report {
        self.zero_area_triangles = count;
        self
    }

    /// One line of JSON.
    pub fn to_json(&self) -> String {
        // Serializing plain data with string keys cannot fail; fall back to an error object rather than panic.
        serde_json::to_string(self).unwrap_or_else(|e| format!("{{\"error\":{:?}}}", e.to_string()))
    }

    /// The human-readable rendering: counts, `k`, a text histogram, the test, the selection and the timings.
    pub fn to_text(&self) -> String {
        let mut o = String::new();
        let _ = self.write_text(&mut o);
        o
    }

    fn write_text(&self, o: &mut String) -> std::fmt::Result {
        match self.frame {
            Some(f) => writeln!(
                o,
                "{} (frame {f}: {}, {} scene)",
                self.mesh,
                self.frame_file.as_deref().unwrap_or("?"),
                self.kind.name()
            )?,
            None => writeln!(o, "{} ({} scene)", self.mesh, self.kind.name())?,
        }
        if self.sample_stride > 1 {
            writeln!(
                o,
                "  triangles      {} sampled (every {}th) of {}; {} with zero area",
                group(self.triangles),
                self.sample_stride,
                group(self.total_triangles),
                group(self.zero_area_triangles)
            )?;
        } else {
            writeln!(
                o,
                "  triangles      {}; {} with zero area",
                group(self.triangles),
                group(self.zero_area_triangles)
            )?;
        }
        writeln!(o, "  bounds (3x)    lo {:?}  hi {:?}", self.bounds.lo, self.bounds.hi)?;
        writeln!(
            o,
            "  morton codes   {} bits, min {} max {}; mean {:.6e}, std dev {:.6e}, skewness {:.4}",
            self.morton_bits, self.code_min, self.code_max, self.mean, self.std_dev, self.skewness
        )?;
        writeln!(o, "  classes        k = {} ({})", self.classes, self.class_rule)?;
        let max = self.histogram.iter().copied().max().unwrap_or(0).max(1);
        let expected = self.triangles as f64 / self.classes.max(1) as f64;
        let width = digits(max);
        for (i, &h) in self.histogram.iter().enumerate() {
            let bar = ((h as f64 / max as f64) * 40.0).round() as usize;
            let mark = if h == 0 {
                " empty"
            } else if h as f64 > expected {
                " +"
            } else {
                ""
            };
            writeln!(
                o,
                "    {i:>4} {h:>width$} {:>5.1}% |{:<40}|{mark}",
                100.0 * h as f64 / self.triangles.max(1) as f64,
                "#".repeat(bar)
            )?;
        }
        writeln!(
            o,
            "  chi-square     {:.4} (dof {}), p = {:.4e}; critical value {:.4} at alpha {}: {}",
            self.chi_square,
            self.dof,
            self.p_value,
            self.critical_value,
            self.alpha,
            if self.uniform { "uniform" } else { "not uniform" }
        )?;
        writeln!(
            o,
            "  effect size    Cramér's V = {:.4}; {} concentrated classes (+) hold {:.1}% of the triangles; {} empty",
            self.effect_size,
            self.concentrated_classes,
            100.0 * self.concentrated_share,
            self.empty_classes
        )?;
        writeln!(o, "  selected       {} (policy {})", self.selected, self.policy)?;
        if let Some(d) = self.driver.as_ref().filter(|d| d.chosen) {
            writeln!(o, "  overall        {} (the driver's acceleration structure)", d.flags.name())?;
        }
        for r in &self.reasons {
            writeln!(o, "    - {r}")?;
        }
        for e in &self.excluded {
            writeln!(o, "  excluded       {}", e.reason)?;
        }
        if let Some(c) = &self.selection_cost {
            writeln!(
                o,
                "  decision cost  {:.3} ms, {} (characterize {:.3} ms, select {:.3} ms; {:.3} ms per frame){}",
                c.characterize_ms + c.select_ms,
                c.counted,
                c.characterize_ms,
                c.select_ms,
                c.per_frame_ms,
                match (c.predicted_frame_ms, c.share) {
                    (Some(f), Some(s)) => format!(
                        "; {:.2}% of the chosen structure's predicted {f:.3} ms per frame{}",
                        100.0 * s,
                        if s <= SelectionCost::GOAL { "" } else { ": over the 1% goal" }
                    ),
                    _ => String::new(),
                }
            )?;
        }
        let t: Vec<String> = self.timings_ms.0.iter().map(|p| format!("{} {:.3}", p.name, p.ms)).collect();
        writeln!(o, "  timings (ms)   {} [{} on {}]", t.join(", "), self.backend, self.device)
    }
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.to_text())
    }
}

fn digits(x: u64) -> usize {
    x.to_string().len()
}

/// `1234567` as `1,234,567`.
fn group(x: u64) -> String {
    let s = x.to_string();
    let mut out = String::new();
    for (i, ch) in s.chars().enumerate() {
        if i > 0 && (s.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(ch);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn group_digits() {
        assert_eq!(group(0), "0");
        assert_eq!(group(999), "999");
        assert_eq!(group(1000), "1,000");
        assert_eq!(group(871_414), "871,414");
        assert_eq!(group(12_345_678), "12,345,678");
    }
}
