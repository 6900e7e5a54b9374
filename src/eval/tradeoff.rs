//! Speed against accuracy of the characterization's knobs: for each setting (backend, sample stride, Morton bits,
//! class-count rule) and each scene, the time of the characterization, how far its statistics move from the full
//! computation, whether the policy's selection changes, and the regret of that selection against oracle results.
//!
//! # Method
//!
//! * **Settings** ([`GridSpec::settings`]): one knob at a time around the reference (the rayon CPU backend, every
//!   triangle, 30-bit codes, Doane): every backend at every sample stride; the other bit depths at every stride on
//!   the reference backend; every other class rule on every triangle. The three backends report identical bits
//!   for the same parameters, so their accuracy is the same and only their time differs.
//! * **Time** of a setting on a scene: the median wall time of `repeats` characterizations of every frame on that
//!   backend (the Vulkan device and pipelines are created once, before timing; uploads are timed).
//! * **Drift** ([`Drift`]) against the reference computation, the largest over the frames: the change of `k`, of
//!   Cramér's V (the effect size), of the empty-class count and of the concentrated share, and the total-variation
//!   distance between the two class histograms read as step densities over the normalized code range
//!   ([`histogram_distance`], defined for different `k` too).
//! * **Selection** ([`Selector`]): either one policy (any [`Policy`], e.g. the thesis policy) on the scene's
//!   characterized frames, one selection per scene; or the calibrated policy ([`CalibratedPolicy`]), one selection
//!   per scene *and workload*, since its answer depends on the rays per frame: for each workload, the oracle line's
//!   `rays_per_frame` and `frames` and the scene's features ([`features_cpu`]) computed with the setting's
//!   parameters (sampling and bit depth change the features too). The features are one more pass over the
//!   triangles on the CPU reference, after the timed characterization and not counted in the setting's time.
//! * **Accuracy** against oracle results ([`OracleScene`], read from `evaluate --json` lines or measured): whether
//!   the selection is the oracle's best, whether it is within noise of it, and its regret
//!   `total(selected) / total(best) - 1`; per setting the mean and the worst regret over the scenes.
//! * **Pareto front** ([`pareto_front`]): the settings no other setting beats in both time and mean regret.
//! * **Least work** ([`sufficiency`]): per scene, the coarsest sample, the smallest fixed class count and whether
//!   30-bit codes suffice, such that the selection (and, stricter, the statistics within [`StatsTolerance`]) equal
//!   the reference's at that setting and at every finer one.

use super::chart::{ScatterChart, ScatterPoint};
use super::{EvalError, Measurement, SceneEvaluation};
use crate::accel::StructureName;
use crate::characterize::{
    features_cpu, Backend, CharError, Characterization, Characterizer, ClassRule, Features, MortonBits, Params, Policy,
    SceneSummary,
};
use crate::cost::{CalibratedPolicy, CostModel};
use crate::mesh::Animation;
use crate::trace::WorkloadKind;
use std::path::Path;
use std::time::Instant;

/// Errors of the trade-off study.
#[derive(Debug, thiserror::Error)]
pub enum TradeoffError {
    /// A characterization failed.
    #[error(transparent)]
    Char(#[from] CharError),
    /// The oracle failed.
    #[error(transparent)]
    Eval(#[from] EvalError),
    /// An oracle file cannot be read or parsed.
    #[error("{file}: {reason}")]
    Oracle {
        /// The file (and line).
        file: String,
        /// Why.
        reason: String,
    },
    /// The settings or inputs make no study.
    #[error("{0}")]
    Input(String),
}

/// One point of the settings grid: a backend and the characterization parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Setting {
    /// Which backend runs it.
    pub backend: Backend,
    /// The parameters (`keep_per_triangle` is always off).
    pub params: Params,
}

impl Setting {
    /// The reference: the rayon CPU backend with the default parameters (every triangle, 30-bit codes, Doane).
    pub fn reference() -> Setting {
        Setting { backend: Backend::Cpu, params: Params::default() }
    }

    /// A short label, `backend/bits/rule/1:stride`, e.g. `cpu/30/doane/1:16`.
    pub fn label(&self) -> String {
        format!(
            "{}/{}/{}/1:{}",
            self.backend.name(),
            self.params.morton_bits.total(),
            self.params.class_rule.name(),
            self.params.sample_stride
        )
    }

    /// Whether the two settings compute the same numbers (they may differ in backend only).
    pub fn same_parameters(&self, o: &Setting) -> bool {
        self.params == o.params
    }
}

/// The knobs to sweep. [`GridSpec::settings`] varies one knob at a time around the reference.
#[derive(Clone, Debug, PartialEq)]
pub struct GridSpec {
    /// Backends; the first is the reference backend for the bit-depth and class-rule variations.
    pub backends: Vec<Backend>,
    /// Sample strides (1 = every triangle, 2 = half, ...).
    pub strides: Vec<u32>,
    /// Bit depths; the default (30) is always included.
    pub bits: Vec<MortonBits>,
    /// Class rules; Doane is always included.
    pub rules: Vec<ClassRule>,
}

impl Default for GridSpec {
    /// Every backend (CPU first), strides 1 to 256 in powers of two, 30 and 63 bits, Doane, Sturges, square root
    /// and fixed 8, 16, 32, 64 classes.
    fn default() -> Self {
        GridSpec {
            backends: vec![Backend::Cpu, Backend::Vulkan, Backend::Naive],
            strides: (0..=8).map(|i| 1u32 << i).collect(),
            bits: vec![MortonBits::Bits30, MortonBits::Bits63],
            rules: vec![
                ClassRule::Doane,
                ClassRule::Sturges,
                ClassRule::Sqrt,
                ClassRule::Fixed(8),
                ClassRule::Fixed(16),
                ClassRule::Fixed(32),
                ClassRule::Fixed(64),
            ],
        }
    }
}

impl GridSpec {
    /// The settings, one knob at a time: every backend at every stride (30 bits, Doane); on the first backend,
    /// every other bit depth at every stride, and every other rule with every triangle. No duplicates; the first
    /// setting is the reference when the first backend is the CPU and stride 1 is in the list.
    pub fn settings(&self) -> Vec<Setting> {
        let mut out: Vec<Setting> = Vec::new();
        let mut push = |s: Setting| {
            if !out.contains(&s) {
                out.push(s);
            }
        };
        let base = Params::default();
        let mut strides = self.strides.clone();
        strides.retain(|&s| s >= 1);
        if !strides.contains(&1) {
            strides.insert(0, 1);
        }
        for &backend in &self.backends {
            for &s in &strides {
                push(Setting { backend, params: Params { sample_stride: s, ..base.clone() } });
            }
        }
        let Some(&first) = self.backends.first() else {
            return out;
        };
        for &bits in self.bits.iter().filter(|&&b| b != base.morton_bits) {
            for &s in &strides {
                push(Setting {
                    backend: first,
                    params: Params { morton_bits: bits, sample_stride: s, ..base.clone() },
                });
            }
        }
        for &rule in self.rules.iter().filter(|&&r| r != base.class_rule) {
            push(Setting { backend: first, params: Params { class_rule: rule, ..base.clone() } });
        }
        out
    }
}

/// How far a characterization's statistics are from the reference's (largest over frames).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Drift {
    /// `k - k_ref` of the frame with the largest `|k - k_ref|`.
    pub k_delta: i64,
    /// Largest `|V - V_ref|` (Cramér's V, the effect size).
    pub effect_size: f64,
    /// Largest total-variation distance between the class histograms ([`histogram_distance`]), in `[0, 1]`.
    pub histogram: f64,
    /// `empty - empty_ref` of the frame with the largest difference.
    pub empty_delta: i64,
    /// Largest `|concentrated share - concentrated share_ref|`.
    pub concentrated_share: f64,
}

/// The total-variation distance between two class histograms, each read as a step density over the normalized code
/// range `[0, 1)` (class `i` of `k` covers `[i / k, (i + 1) / k)` and holds its share of the triangles): half the
/// integral of the absolute difference of the densities. 0 for equal shares, 1 for disjoint supports; defined for
/// different class counts. An empty histogram counts as uniform.
pub fn histogram_distance(a: &[u64], b: &[u64]) -> f64 {
    fn density(h: &[u64]) -> Vec<f64> {
        let n: u64 = h.iter().sum();
        let k = h.len().max(1) as f64;
        if n == 0 || h.is_empty() {
            return vec![1.0];
        }
        h.iter().map(|&c| c as f64 / n as f64 * k).collect()
    }
    let (da, db) = (density(a), density(b));
    let (ka, kb) = (da.len() as u64, db.len() as u64);
    // Breakpoints i / ka and j / kb, merged exactly as fractions over ka * kb.
    let mut pts: Vec<u64> = (0..=ka).map(|i| i * kb).chain((0..=kb).map(|j| j * ka)).collect();
    pts.sort_unstable();
    pts.dedup();
    let total = (ka * kb) as f64;
    let mut sum = 0.0;
    for w in pts.windows(2) {
        let (x0, x1) = (w[0], w[1]);
        let ia = (x0 / kb).min(ka - 1) as usize;
        let ib = (x0 / ka).min(kb - 1) as usize;
        sum += (da[ia] - db[ib]).abs() * (x1 - x0) as f64 / total;
    }
    0.5 * sum
}

/// The drift of `c` from `reference`, frame by frame (the largest over the frames both have).
pub fn drift(reference: &[Characterization], c: &[Characterization]) -> Drift {
    let mut d = Drift::default();
    for (r, x) in reference.iter().zip(c) {
        let dk = x.classes as i64 - r.classes as i64;
        if dk.abs() > d.k_delta.abs() {
            d.k_delta = dk;
        }
        let de = x.stats.empty_classes as i64 - r.stats.empty_classes as i64;
        if de.abs() > d.empty_delta.abs() {
            d.empty_delta = de;
        }
        d.effect_size = d.effect_size.max((x.stats.cramers_v - r.stats.cramers_v).abs());
        d.histogram = d.histogram.max(histogram_distance(&r.histogram, &x.histogram));
        d.concentrated_share =
            d.concentrated_share.max((x.stats.concentrated_share - r.stats.concentrated_share).abs());
    }
    d
}

/// Tolerances under which two characterizations count as having the same statistics.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct StatsTolerance {
    /// Largest `|V - V_ref|` (default 0.005: half the 0.01 the report rounds the effect size to in tables).
    pub effect_size: f64,
    /// Largest change of the concentrated share (default 0.01, one percentage point).
    pub concentrated_share: f64,
}

impl Default for StatsTolerance {
    fn default() -> Self {
        StatsTolerance { effect_size: 0.005, concentrated_share: 0.01 }
    }
}

impl StatsTolerance {
    /// Whether a drift is within the tolerances (the empty-class count must be equal; `k` may differ, since
    /// Doane's and Sturges' `k` grow with `log2 n` by design).
    pub fn accepts(&self, d: &Drift) -> bool {
        d.effect_size <= self.effect_size && d.concentrated_share <= self.concentrated_share && d.empty_delta == 0
    }
}

/// What the oracle measured for one structure, as much as the study needs.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct OracleStructure {
    /// The structure.
    pub name: StructureName,
    /// Median total and its noise (half range), ms.
    pub total: Measurement,
    /// Median build time, ms.
    pub build_ms: f64,
    /// Memory, bytes.
    pub memory_bytes: u64,
    /// Built, validated and agreed with the reference hits.
    pub ok: bool,
}

/// The oracle's result for one scene and workload: read from an `evaluate --json` line or taken from a
/// [`SceneEvaluation`].
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct OracleScene {
    /// The scene (path as measured).
    pub mesh: String,
    /// `primary`, `shadow` or `diffuse`.
    pub workload: String,
    /// Image side of the measurement.
    pub resolution: u32,
    /// Rays traced per frame (0 when the line does not say).
    pub rays_per_frame: u64,
    /// Frames the totals are for (a static scene rendered `frames` times with one build, or the frames of an
    /// animation used; 1 when the line does not say).
    pub frames: u64,
    /// Per structure.
    pub structures: Vec<OracleStructure>,
}

impl OracleScene {
    /// From an oracle evaluation.
    pub fn from_evaluation(e: &SceneEvaluation) -> OracleScene {
        OracleScene {
            mesh: e.mesh.clone(),
            workload: e.workload.as_str().to_string(),
            resolution: e.resolution,
            rays_per_frame: e.rays_per_frame as u64,
            frames: e.frames.max(1) as u64,
            structures: e
                .structures
                .iter()
                .filter_map(|s| {
                    Some(OracleStructure {
                        name: s.name?,
                        total: s.total_ms.clone(),
                        build_ms: s.build_ms.median,
                        memory_bytes: s.memory_bytes as u64,
                        ok: s.valid && s.hits_agree,
                    })
                })
                .collect(),
        }
    }

    /// From one line of `evaluate --json` (fields `mesh`, `workload`, `resolution`, optional `rays_per_frame` and
    /// `frames`, `structures[]` with `name`,
    /// `total_ms`, `total_ms_spread`, `build_ms`, `memory_bytes`, `valid`, `hits_agree`).
    pub fn from_json(v: &serde_json::Value) -> Result<OracleScene, String> {
        let str_field = |o: &serde_json::Value, k: &str| -> Result<String, String> {
            o.get(k).and_then(|x| x.as_str()).map(str::to_string).ok_or_else(|| format!("missing string field {k:?}"))
        };
        let num = |o: &serde_json::Value, k: &str| -> f64 { o.get(k).and_then(|x| x.as_f64()).unwrap_or(f64::NAN) };
        let mesh = str_field(v, "mesh")?;
        let workload = str_field(v, "workload")?;
        let resolution = v.get("resolution").and_then(|x| x.as_u64()).unwrap_or(0) as u32;
        let rays_per_frame = v.get("rays_per_frame").and_then(|x| x.as_u64()).unwrap_or(0);
        let frames = v.get("frames").and_then(|x| x.as_u64()).unwrap_or(1).max(1);
        let list = v.get("structures").and_then(|x| x.as_array()).ok_or("missing array field \"structures\"")?;
        let mut structures = Vec::new();
        for s in list {
            let name: StructureName = str_field(s, "name")?.parse().map_err(|e| format!("{e:?}"))?;
            let median = num(s, "total_ms");
            let spread = num(s, "total_ms_spread");
            let flag = |k: &str| s.get(k).and_then(|x| x.as_bool()).unwrap_or(false);
            let ok = flag("valid") && flag("hits_agree") && median.is_finite();
            let spread = if spread.is_finite() { spread } else { 0.0 };
            structures.push(OracleStructure {
                name,
                total: Measurement { median, min: median - spread, max: median + spread, spread },
                build_ms: num(s, "build_ms"),
                memory_bytes: s.get("memory_bytes").and_then(|x| x.as_u64()).unwrap_or(0),
                ok,
            });
        }
        Ok(OracleScene { mesh, workload, resolution, rays_per_frame, frames, structures })
    }

    fn get(&self, name: StructureName) -> Option<&OracleStructure> {
        self.structures.iter().find(|s| s.name == name && s.ok)
    }

    /// The structure with the smallest median total (among those that built, validated and agreed).
    pub fn best(&self) -> Option<&OracleStructure> {
        self.structures.iter().filter(|s| s.ok).min_by(|a, b| a.total.median.total_cmp(&b.total.median))
    }

    /// The structures within noise of the best, the best included (see [`Measurement::within_noise`]).
    pub fn within_noise(&self) -> Vec<StructureName> {
        let Some(best) = self.best() else { return Vec::new() };
        self.structures.iter().filter(|s| s.ok && s.total.within_noise(&best.total)).map(|s| s.name).collect()
    }

    /// Among [`OracleScene::within_noise`], the least median build time, then the least memory.
    pub fn cheapest_within_noise(&self) -> Option<StructureName> {
        let near = self.within_noise();
        self.structures
            .iter()
            .filter(|s| near.contains(&s.name))
            .min_by(|a, b| a.build_ms.total_cmp(&b.build_ms).then(a.memory_bytes.cmp(&b.memory_bytes)))
            .map(|s| s.name)
    }

    /// `total(s) / total(best) - 1`, or `None` when `s` or the best was not measured.
    pub fn regret(&self, s: StructureName) -> Option<f64> {
        let (sel, best) = (self.get(s)?, self.best()?);
        (best.total.median > 0.0).then(|| sel.total.median / best.total.median - 1.0)
    }
}

/// Reads `evaluate --json` lines (one scene per line; blank lines are skipped).
pub fn read_oracle_jsonl(path: &Path) -> Result<Vec<OracleScene>, TradeoffError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| TradeoffError::Oracle { file: file.clone(), reason: e.to_string() })?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let place = || format!("{file}:{}", i + 1);
        let v: serde_json::Value =
            serde_json::from_str(line).map_err(|e| TradeoffError::Oracle { file: place(), reason: e.to_string() })?;
        out.push(OracleScene::from_json(&v).map_err(|reason| TradeoffError::Oracle { file: place(), reason })?);
    }
    Ok(out)
}

/// A key that identifies a scene path across working directories: the part after the last `meshes` folder of
/// the canonical path when there is one, else the canonical (or given) path.
pub fn scene_key(path: &str) -> String {
    let p = std::fs::canonicalize(path).unwrap_or_else(|_| Path::new(path).to_path_buf());
    let parts: Vec<String> = p.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
    match parts.iter().rposition(|c| c == "meshes") {
        Some(i) if i + 1 < parts.len() => parts[i + 1..].join("/"),
        _ => p.display().to_string(),
    }
}

/// One setting on one scene.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SceneRun {
    /// The scene.
    pub mesh: String,
    /// Triangles per frame.
    pub triangles: u64,
    /// Frames characterized.
    pub frames: usize,
    /// Wall time of characterizing every frame, over the repeats, ms.
    pub time_ms: Measurement,
    /// The policy's selection: the structure, or, when the selection is made per workload and differs between
    /// workloads, `workload=structure` pairs separated by commas (`-` for none).
    pub selected: String,
    /// The selection per workload of the study (the same structure for every workload when one policy selects;
    /// `None` where the calibrated policy has no oracle line, hence no rays per frame, for the scene).
    pub per_workload: Vec<WorkloadSelection>,
    /// Drift from the reference computation.
    pub drift: Drift,
    /// `k` of the first frame.
    pub k: u32,
    /// Cramér's V of the first frame.
    pub effect_size: f64,
    /// Whether the selection equals the reference's.
    pub same_selection: bool,
    /// For a sampled setting with the reference's class rule: the same sample read with the reference's `k` (per
    /// frame), which isolates the sampling error from the change of `k` with `n`.
    pub same_k: Option<SameK>,
}

/// One workload's selection on one scene.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct WorkloadSelection {
    /// The workload.
    pub workload: String,
    /// The selected structure, if a selection was made.
    pub selected: Option<StructureName>,
}

/// A sample characterized with the full computation's class count.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SameK {
    /// Drift from the reference (`k_delta` is 0).
    pub drift: Drift,
    /// Whether the policy's selection equals the reference's.
    pub same_selection: bool,
}

/// Times `repeats` characterizations of every frame of `scene` with `params` on `engine`, after one untimed run;
/// returns the frames of the last one and the time.
pub fn time_characterization(
    engine: &mut Characterizer,
    scene: &Animation,
    params: &Params,
    repeats: usize,
) -> Result<(Vec<Characterization>, Measurement), CharError> {
    // One untimed run first: first-touch page faults, pipeline and buffer creation are not what is measured.
    let mut frames = engine.characterize_animation(scene, params)?;
    let mut times = Vec::new();
    for _ in 0..repeats.max(1) {
        let t = Instant::now();
        frames = engine.characterize_animation(scene, params)?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok((frames, Measurement::of(&times)))
}

/// The selection of `policy` on characterized frames, as a [`StructureName`].
pub fn select(policy: &dyn Policy, name: &str, frames: &[Characterization]) -> Result<StructureName, TradeoffError> {
    let sel = policy.select(&SceneSummary::new(name, frames));
    sel.structure.name().parse::<StructureName>().map_err(|e| TradeoffError::Input(format!("{e:?}")))
}

/// How a sweep selects.
#[derive(Clone, Copy)]
pub enum Selector<'a> {
    /// One policy for every workload (e.g. [`crate::characterize::ThesisPolicy`]): one selection per scene, from
    /// the characterized frames alone.
    Policy(&'a dyn Policy),
    /// The calibrated policy with this cost model and tie margin (see [`CalibratedPolicy`]): one selection per
    /// scene and workload, for the rays per frame and frames of the scene's oracle line of that workload, from the
    /// features computed with the setting's parameters.
    Calibrated {
        /// The cost model.
        model: &'a CostModel,
        /// Relative margin within which the cheaper build wins ([`CalibratedPolicy::tie_margin`]).
        tie_margin: f64,
    },
}

impl Selector<'_> {
    /// The policy's name: the policy's own, or `calibrated`.
    pub fn name(&self) -> &str {
        match self {
            Selector::Policy(p) => p.name(),
            Selector::Calibrated { .. } => "calibrated",
        }
    }

    /// Whether the selection needs the scene's features.
    pub fn needs_features(&self) -> bool {
        matches!(self, Selector::Calibrated { .. })
    }
}

/// The calibrated policy for `scene` on `workload`, from the scene's oracle line of that workload: its rays per
/// frame and frames. `None` when there is no such line; an error when the line has no rays per frame or the
/// workload is not one the cost model knows.
pub fn calibrated_for(
    model: &CostModel,
    tie_margin: f64,
    scene: &str,
    workload: &str,
    oracle: &[OracleScene],
) -> Result<Option<(CalibratedPolicy, usize)>, TradeoffError> {
    let key = scene_key(scene);
    let Some(o) = oracle.iter().find(|o| o.workload == workload && scene_key(&o.mesh) == key) else {
        return Ok(None);
    };
    if o.rays_per_frame == 0 {
        return Err(TradeoffError::Input(format!(
            "{}: the {workload} oracle line has no rays_per_frame, which the calibrated policy needs",
            o.mesh
        )));
    }
    let kind: WorkloadKind = workload.parse().map_err(TradeoffError::Input)?;
    let mut p = CalibratedPolicy::new(model.clone(), kind, o.rays_per_frame, o.frames);
    p.tie_margin = tie_margin;
    Ok(Some((p, o.frames.max(1) as usize)))
}

/// The selections of `selector` on one scene: a label ([`SceneRun::selected`]) and one per workload.
/// `features` (one per frame) are needed for [`Selector::Calibrated`] only.
pub fn select_per_workload(
    selector: &Selector<'_>,
    scene: &Animation,
    frames: &[Characterization],
    features: &[Features],
    workloads: &[String],
    oracle: &[OracleScene],
) -> Result<(String, Vec<WorkloadSelection>), TradeoffError> {
    match selector {
        Selector::Policy(p) => {
            let sel = select(*p, &scene.name, frames)?;
            let per = workloads.iter().map(|w| WorkloadSelection { workload: w.clone(), selected: Some(sel) });
            Ok((sel.as_str().to_string(), per.collect()))
        }
        Selector::Calibrated { model, tie_margin } => {
            let mut per = Vec::new();
            for w in workloads {
                let selected = match calibrated_for(model, *tie_margin, &scene.name, w, oracle)? {
                    None => None,
                    Some((p, used)) => {
                        // An animation: the frames the oracle measured; a static scene: its one frame.
                        let used = if scene.is_dynamic() { used } else { 1 }.clamp(1, features.len().max(1));
                        let n = used.min(frames.len()).min(features.len());
                        let summary = SceneSummary::new(&scene.name, &frames[..n]).with_features(&features[..n]);
                        let sel = p.select(&summary);
                        Some(
                            sel.structure
                                .name()
                                .parse::<StructureName>()
                                .map_err(|e| TradeoffError::Input(format!("{e:?}")))?,
                        )
                    }
                };
                per.push(WorkloadSelection { workload: w.clone(), selected });
            }
            let name = |s: Option<StructureName>| s.map_or("-", |s| s.as_str());
            let first = per.first().and_then(|x| x.selected);
            let label = if per.iter().all(|x| x.selected == first) {
                name(first).to_string()
            } else {
                per.iter().map(|x| format!("{}={}", x.workload, name(x.selected))).collect::<Vec<_>>().join(",")
            };
            Ok((label, per))
        }
    }
}

/// The features of every frame of `scene` with `params` (CPU reference), or none when `selector` does not need
/// them.
fn features_for(selector: &Selector<'_>, scene: &Animation, params: &Params) -> Result<Vec<Features>, CharError> {
    if !selector.needs_features() {
        return Ok(Vec::new());
    }
    scene.frames.iter().map(|m| features_cpu(m, params)).collect()
}

/// Accuracy of one setting against the oracle on one workload.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Accuracy {
    /// The workload.
    pub workload: String,
    /// Scenes with an oracle result.
    pub scenes: usize,
    /// Share of them where the selection is the oracle's best.
    pub agree_best: f64,
    /// Share where the selection is within noise of the best.
    pub agree_within_noise: f64,
    /// Mean regret.
    pub mean_regret: f64,
    /// Worst regret.
    pub worst_regret: f64,
    /// The scene of the worst regret.
    pub worst_scene: String,
}

/// Everything measured for one setting.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SettingResult {
    /// `backend/bits/rule/1:stride`.
    pub label: String,
    /// Backend name.
    pub backend: String,
    /// The device it ran on (GPU name, or the CPU and thread count).
    pub device: String,
    /// Sample stride.
    pub sample_stride: u32,
    /// Bits of the codes.
    pub morton_bits: u32,
    /// Class rule.
    pub class_rule: String,
    /// Sum over scenes of the median time, ms.
    pub time_ms: f64,
    /// Share of scenes whose selection equals the reference's.
    pub same_selection: f64,
    /// Largest `|V - V_ref|` over scenes.
    pub max_effect_size_drift: f64,
    /// Mean over scenes of `|V - V_ref|`.
    pub mean_effect_size_drift: f64,
    /// Mean histogram distance over scenes.
    pub mean_histogram_distance: f64,
    /// Largest `|k - k_ref|` over scenes.
    pub max_k_delta: i64,
    /// Per workload.
    pub accuracy: Vec<Accuracy>,
    /// Per scene.
    pub scenes: Vec<SceneRun>,
}

impl SettingResult {
    /// The accuracy on `workload`, if measured.
    pub fn accuracy(&self, workload: &str) -> Option<&Accuracy> {
        self.accuracy.iter().find(|a| a.workload == workload)
    }
}

/// The accuracy of the selections `selected[i]` (scene `scenes[i]`) against the oracle results of one workload;
/// scenes without an oracle result are skipped.
pub fn accuracy(workload: &str, scenes: &[String], selected: &[StructureName], oracle: &[OracleScene]) -> Accuracy {
    let mut a = Accuracy { workload: workload.into(), worst_regret: 0.0, ..Default::default() };
    let mut sum = 0.0;
    for (scene, &sel) in scenes.iter().zip(selected) {
        let key = scene_key(scene);
        let Some(o) = oracle.iter().find(|o| o.workload == workload && scene_key(&o.mesh) == key) else {
            continue;
        };
        let Some(r) = o.regret(sel) else { continue };
        a.scenes += 1;
        if o.best().map(|b| b.name) == Some(sel) {
            a.agree_best += 1.0;
        }
        if o.within_noise().contains(&sel) {
            a.agree_within_noise += 1.0;
        }
        sum += r;
        if r > a.worst_regret || a.worst_scene.is_empty() {
            a.worst_regret = r;
            a.worst_scene = scene.clone();
        }
    }
    if a.scenes > 0 {
        let n = a.scenes as f64;
        a.agree_best /= n;
        a.agree_within_noise /= n;
        a.mean_regret = sum / n;
    }
    a
}

/// The indices of the points on the Pareto front when both coordinates are to be minimized (no other point is at
/// most as large in both and smaller in one), sorted by `x`. Non-finite points are never on it; of equal points,
/// the first is.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut front: Vec<usize> = (0..points.len())
        .filter(|&i| {
            let (xi, yi) = points[i];
            xi.is_finite()
                && yi.is_finite()
                && !points.iter().enumerate().any(|(j, &(xj, yj))| {
                    xj.is_finite()
                        && yj.is_finite()
                        && xj <= xi
                        && yj <= yi
                        && (xj < xi || yj < yi || (j < i && xj == xi && yj == yi))
                })
        })
        .collect();
    front.sort_by(|&a, &b| points[a].0.total_cmp(&points[b].0));
    front
}

/// The least work that still gives the reference's answer on one scene.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Sufficiency {
    /// The scene.
    pub mesh: String,
    /// Triangles per frame.
    pub triangles: u64,
    /// The largest stride whose selection, and every finer stride's, equals the reference's (`None`: not even the
    /// finest tried).
    pub stride_selection: Option<u32>,
    /// The largest stride whose statistics (within [`StatsTolerance`]) and selection, and every finer stride's,
    /// equal the reference's.
    pub stride_statistics: Option<u32>,
    /// The largest stride whose sample, read with the reference's `k`, gives the reference's selection and
    /// statistics (within [`StatsTolerance`]), and every finer stride's too.
    pub stride_same_k: Option<u32>,
    /// The smallest fixed class count whose selection, and every larger fixed count's, equals the reference's.
    pub fixed_k_selection: Option<u32>,
    /// The class rules other than the reference's (Sturges, square root, fixed counts) that give the reference's
    /// selection with every triangle.
    pub rules_with_same_selection: Vec<String>,
    /// Whether 63-bit codes (every triangle) give the same selection and statistics as 30-bit codes: if so, 30 bits
    /// are enough.
    pub bits30_enough: bool,
}

/// Per scene, the least work that still gives the reference's answer, from the results of a sweep
/// (`results[0]` must be the reference setting; the others are read by their parameters, on the reference's
/// backend).
pub fn sufficiency(results: &[SettingResult], tol: &StatsTolerance) -> Vec<Sufficiency> {
    let Some(reference) = results.first() else { return Vec::new() };
    let ref_backend = reference.backend.clone();
    let on_ref = |r: &&SettingResult| r.backend == ref_backend;
    reference
        .scenes
        .iter()
        .enumerate()
        .map(|(si, base)| {
            let scene = |r: &SettingResult| r.scenes.get(si).filter(|s| s.mesh == base.mesh).cloned();
            // Strides, finest first.
            let mut strides: Vec<&SettingResult> = results
                .iter()
                .filter(on_ref)
                .filter(|r| r.morton_bits == reference.morton_bits && r.class_rule == reference.class_rule)
                .collect();
            strides.sort_by_key(|r| r.sample_stride);
            let chain = |ok: &dyn Fn(&SceneRun) -> bool| -> Option<u32> {
                let mut last = None;
                for r in &strides {
                    match scene(r) {
                        Some(s) if ok(&s) => last = Some(r.sample_stride),
                        _ => break,
                    }
                }
                last
            };
            let stride_selection = chain(&|s| s.same_selection);
            let stride_statistics = chain(&|s| s.same_selection && tol.accepts(&s.drift));
            let stride_same_k = chain(&|s| match &s.same_k {
                Some(x) => x.same_selection && tol.accepts(&x.drift),
                None => s.same_selection && tol.accepts(&s.drift),
            });
            // Fixed class counts, largest first.
            let mut fixed: Vec<(u32, &SettingResult)> = results
                .iter()
                .filter(on_ref)
                .filter(|r| r.sample_stride == 1 && r.morton_bits == reference.morton_bits)
                .filter_map(|r| r.class_rule.parse::<u32>().ok().map(|k| (k, r)))
                .collect();
            fixed.sort_by_key(|&(k, _)| std::cmp::Reverse(k));
            let mut fixed_k_selection = None;
            for (k, r) in &fixed {
                match scene(r) {
                    Some(s) if s.same_selection => fixed_k_selection = Some(*k),
                    _ => break,
                }
            }
            let rules_with_same_selection = results
                .iter()
                .filter(on_ref)
                .filter(|r| r.sample_stride == 1 && r.morton_bits == reference.morton_bits)
                .filter(|r| r.class_rule != reference.class_rule)
                .filter(|r| scene(r).is_some_and(|s| s.same_selection))
                .map(|r| r.class_rule.clone())
                .collect();
            let bits30_enough = results
                .iter()
                .filter(on_ref)
                .filter(|r| r.sample_stride == 1 && r.class_rule == reference.class_rule)
                .filter(|r| r.morton_bits != reference.morton_bits)
                .all(|r| scene(r).is_some_and(|s| s.same_selection && tol.accepts(&s.drift)));
            Sufficiency {
                mesh: base.mesh.clone(),
                triangles: base.triangles,
                stride_selection,
                stride_statistics,
                stride_same_k,
                fixed_k_selection,
                rules_with_same_selection,
                bits30_enough,
            }
        })
        .collect()
}

/// What a sweep measures: the scenes, the settings (the first is the reference, normally
/// [`Setting::reference`]), how the policy selects, and the oracle results and workloads to judge it by.
pub struct Study<'a> {
    /// The scenes.
    pub scenes: &'a [Animation],
    /// The settings; the first is the reference the drift is measured from.
    pub settings: &'a [Setting],
    /// How the selection is made: one [`Policy`] per scene, or the calibrated policy per scene and workload.
    pub policy: Selector<'a>,
    /// Oracle results (scenes are matched by [`scene_key`], workloads by name; the calibrated policy also takes
    /// the rays per frame and frames of each workload from them).
    pub oracle: &'a [OracleScene],
    /// The workloads to report accuracy for.
    pub workloads: &'a [String],
    /// Timed repeats per setting and scene (the median is reported).
    pub repeats: usize,
}

/// Runs the sweep: every setting on every scene, drift against the first setting, selections by the study's
/// policy (per workload for [`Selector::Calibrated`], from features computed with the setting's parameters, untimed),
/// accuracy against its oracle results for each of its workloads.
///
/// `engine_for` gives the characterizer of a backend (so that the caller decides how the Vulkan device is made);
/// each is made once. `progress` receives one line per step.
pub fn sweep(
    study: &Study<'_>,
    engine_for: &mut dyn FnMut(Backend) -> Result<Characterizer, CharError>,
    progress: &dyn Fn(&str),
) -> Result<Vec<SettingResult>, TradeoffError> {
    let Study { scenes, settings, policy, oracle, workloads, repeats } = *study;
    let Some(reference) = settings.first() else {
        return Err(TradeoffError::Input("no settings to measure".into()));
    };
    if scenes.is_empty() {
        return Err(TradeoffError::Input("no scenes to measure".into()));
    }
    let mut engines: Vec<(Backend, Characterizer)> = Vec::new();
    let mut engine = |b: Backend, engines: &mut Vec<(Backend, Characterizer)>| -> Result<usize, CharError> {
        if let Some(i) = engines.iter().position(|(x, _)| *x == b) {
            return Ok(i);
        }
        engines.push((b, engine_for(b)?));
        Ok(engines.len() - 1)
    };
    // Reference frames and selections.
    let mut ref_frames = Vec::new();
    let mut ref_sel = Vec::new();
    let ei = engine(reference.backend, &mut engines)?;
    let ref_engine = ei;
    for (i, scene) in scenes.iter().enumerate() {
        progress(&format!("reference {} ({}/{}): {}", reference.label(), i + 1, scenes.len(), scene.name));
        let frames = engines[ei].1.characterize_animation(scene, &reference.params)?;
        let features = features_for(&policy, scene, &reference.params)?;
        ref_sel.push(select_per_workload(&policy, scene, &frames, &features, workloads, oracle)?);
        ref_frames.push(frames);
    }
    let names: Vec<String> = scenes.iter().map(|s| s.name.clone()).collect();
    let mut out = Vec::new();
    for (k, setting) in settings.iter().enumerate() {
        let ei = engine(setting.backend, &mut engines)?;
        let mut runs = Vec::new();
        let mut sels = Vec::new();
        let mut device = String::new();
        for (i, scene) in scenes.iter().enumerate() {
            progress(&format!(
                "setting {}/{} {}: scene {}/{} {}",
                k + 1,
                settings.len(),
                setting.label(),
                i + 1,
                scenes.len(),
                scene.name
            ));
            let (frames, time_ms) = time_characterization(&mut engines[ei].1, scene, &setting.params, repeats)?;
            let features = features_for(&policy, scene, &setting.params)?;
            let sel = select_per_workload(&policy, scene, &frames, &features, workloads, oracle)?;
            if let Some(f) = frames.first() {
                device.clone_from(&f.device);
            }
            sels.push(sel.1.clone());
            // A sample read with the full computation's class count: separates sampling error from the change of
            // k that Doane's rule makes for a smaller n (computed on the reference backend, untimed).
            let same_k = if setting.params.sample_stride > 1 && setting.params.class_rule == reference.params.class_rule
            {
                let mut fk = Vec::with_capacity(frames.len());
                for (mesh, r) in scene.frames.iter().zip(&ref_frames[i]) {
                    let p = Params { class_rule: ClassRule::Fixed(r.classes), ..setting.params.clone() };
                    fk.push(engines[ref_engine].1.characterize(mesh, &p)?);
                }
                // The features do not depend on the class rule: the setting's serve.
                let sel_k = select_per_workload(&policy, scene, &fk, &features, workloads, oracle)?;
                Some(SameK { drift: drift(&ref_frames[i], &fk), same_selection: sel_k == ref_sel[i] })
            } else {
                None
            };
            runs.push(SceneRun {
                same_k,
                mesh: scene.name.clone(),
                triangles: scene.frames.first().map_or(0, |f| f.triangle_count() as u64),
                frames: frames.len(),
                time_ms,
                same_selection: sel == ref_sel[i],
                selected: sel.0,
                per_workload: sel.1,
                drift: drift(&ref_frames[i], &frames),
                k: frames.first().map_or(0, |f| f.classes),
                effect_size: frames.first().map_or(0.0, |f| f.stats.cramers_v),
            });
        }
        let n = runs.len().max(1) as f64;
        out.push(SettingResult {
            label: setting.label(),
            backend: setting.backend.name().into(),
            device,
            sample_stride: setting.params.sample_stride,
            morton_bits: setting.params.morton_bits.total(),
            class_rule: setting.params.class_rule.name(),
            time_ms: runs.iter().map(|r| r.time_ms.median).sum(),
            same_selection: runs.iter().filter(|r| r.same_selection).count() as f64 / n,
            max_effect_size_drift: runs.iter().map(|r| r.drift.effect_size).fold(0.0, f64::max),
            mean_effect_size_drift: runs.iter().map(|r| r.drift.effect_size).sum::<f64>() / n,
            mean_histogram_distance: runs.iter().map(|r| r.drift.histogram).sum::<f64>() / n,
            max_k_delta: runs.iter().map(|r| r.drift.k_delta.abs()).max().unwrap_or(0),
            accuracy: workloads
                .iter()
                .enumerate()
                .map(|(wi, w)| {
                    let (n, s): (Vec<String>, Vec<StructureName>) =
                        names.iter().zip(&sels).filter_map(|(n, s)| Some((n.clone(), s.get(wi)?.selected?))).unzip();
                    accuracy(w, &n, &s, oracle)
                })
                .collect(),
            scenes: runs,
        });
    }
    Ok(out)
}

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
pub fn structures_markdown(oracle: &[OracleScene], workloads: &[String]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "| workload | scene | best | within noise of the best | cheapest within noise |");
    let _ = writeln!(s, "|---|---|---|---|---|");
    let mut counts = Vec::new();
    for w in workloads {
        let mut cheaper = 0;
        let mut total = 0;
        for o in oracle.iter().filter(|o| &o.workload == w) {
            let Some(best) = o.best().map(|b| b.name) else { continue };
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
