//! Selections per scene and workload, by one policy or by the calibrated policy from oracle records.

use super::*;

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

/// The selection of `policy` on characterized frames, as a [`StructureName`].
pub fn select(policy: &dyn Policy, name: &str, frames: &[Characterization]) -> StructureName {
    policy.select(&SceneSummary::new(name, frames)).structure
}

/// How a sweep selects.
#[derive(Clone, Copy)]
pub enum Selector<'a> {
    /// One policy for every workload (e.g. [`crate::select::ThesisPolicy`]): one selection per scene, from
    /// the characterized frames alone.
    Policy(&'a dyn Policy),
    /// The calibrated policy with this cost model and tie margin (see [`crate::select::CalibratedPolicy`]): one selection per
    /// scene and workload, for the rays per frame and frames of the scene's oracle line of that workload, from the
    /// features computed with the setting's parameters.
    Calibrated {
        /// The cost model.
        model: &'a CostModel,
        /// Relative margin within which the cheaper build wins ([`crate::select::CalibratedPolicy::tie_margin`]).
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

/// The workload of `scene`'s oracle record for `workload`: its rays per frame and its frames (an animation: the
/// frames the oracle measured). `None` when there is no such record.
pub fn oracle_workload(
    scene: &str,
    workload: &str,
    oracle: &[OracleRecord],
) -> Result<Option<TargetWorkload>, TradeoffError> {
    let key = scene_key(scene);
    let Some(o) = oracle.iter().find(|o| o.workload.as_str() == workload && scene_key(&o.mesh) == key) else {
        return Ok(None);
    };
    if o.rays_per_frame == 0 {
        return Err(TradeoffError::Input(format!(
            "{}: the {workload} oracle line has no rays_per_frame, which the calibrated policy needs",
            o.mesh
        )));
    }
    Ok(Some(TargetWorkload {
        kind: o.workload,
        rays_per_frame: o.rays_per_frame as u64,
        frames: o.frames.max(1) as u64,
        animation_frames: Some(o.frames.max(1)),
        driver: false,
        camera: o.camera.map(|c| c.camera()),
    }))
}

/// The selections of `selector` on one scene: a label ([`SceneRun::selected`]) and one per workload.
/// `features` (one per frame) are needed for [`Selector::Calibrated`] only.
pub fn select_per_workload(
    selector: &Selector<'_>,
    scene: &Animation,
    frames: &[Characterization],
    features: &[Features],
    workloads: &[String],
    oracle: &[OracleRecord],
) -> Result<(String, Vec<WorkloadSelection>), TradeoffError> {
    match selector {
        Selector::Policy(p) => {
            let sel = select(*p, &scene.name, frames);
            let per = workloads.iter().map(|w| WorkloadSelection { workload: w.clone(), selected: Some(sel) });
            Ok((sel.as_str().to_string(), per.collect()))
        }
        Selector::Calibrated { model, tie_margin } => {
            let mut per = Vec::new();
            for w in workloads {
                let selected = oracle_workload(&scene.name, w, oracle)?.map(|target| {
                    // The prior: the features of the study's characterization settings are what it compares.
                    let mut s = crate::select::Selector::new(model, target);
                    s.tie_margin = *tie_margin;
                    s.inquiry = crate::select::Inquiry::Fixed(crate::select::Level::Prior);
                    let scene =
                        crate::select::Scene { name: &scene.name, characterizations: frames, features, meshes: &[] };
                    s.select(&scene).selection.structure
                });
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
pub(super) fn features_for(
    selector: &Selector<'_>,
    scene: &Animation,
    params: &Params,
) -> Result<Vec<Features>, CharError> {
    if !selector.needs_features() {
        return Ok(Vec::new());
    }
    scene.frames.iter().map(|m| features_cpu(m, params)).collect()
}
