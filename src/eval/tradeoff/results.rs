//! Accuracy against the oracle, the Pareto front of time against regret, and the least work per scene.

use super::*;

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
    /// The setting itself (its backend and parameters, named in the fields above), for comparing results.
    #[serde(skip)]
    pub setting: Setting,
}

impl SettingResult {
    /// The accuracy on `workload`, if measured.
    pub fn accuracy(&self, workload: &str) -> Option<&Accuracy> {
        self.accuracy.iter().find(|a| a.workload == workload)
    }
}

/// The accuracy of the selections `selected[i]` (scene `scenes[i]`) against the oracle results of one workload;
/// scenes without an oracle result are skipped.
pub fn accuracy(workload: &str, scenes: &[String], selected: &[StructureName], oracle: &[OracleRecord]) -> Accuracy {
    let mut a = Accuracy { workload: workload.into(), worst_regret: 0.0, ..Default::default() };
    let mut sum = 0.0;
    for (scene, &sel) in scenes.iter().zip(selected) {
        let key = scene_key(scene);
        let Some(o) = oracle.iter().find(|o| o.workload.as_str() == workload && scene_key(&o.mesh) == key) else {
            continue;
        };
        let Some(r) = o.regret(sel) else { continue };
        a.scenes += 1;
        if o.best().and_then(|b| b.name) == Some(sel) {
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
    let (ref_backend, ref_params) = (reference.setting.backend, &reference.setting.params);
    let on_ref = |r: &&SettingResult| r.setting.backend == ref_backend;
    let same_rule = |r: &SettingResult| r.setting.params.class_rule == ref_params.class_rule;
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
                .filter(|r| r.morton_bits == reference.morton_bits && same_rule(r))
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
                .filter_map(|r| match r.setting.params.class_rule {
                    ClassRule::Fixed(k) => Some((k, r)),
                    _ => None,
                })
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
                .filter(|r| !same_rule(r))
                .filter(|r| scene(r).is_some_and(|s| s.same_selection))
                .map(|r| r.class_rule.clone())
                .collect();
            let bits30_enough = results
                .iter()
                .filter(on_ref)
                .filter(|r| r.sample_stride == 1 && same_rule(r))
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
