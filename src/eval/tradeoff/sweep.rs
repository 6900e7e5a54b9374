//! Timing characterizations and the sweep over settings and scenes.

use super::selection::features_for;
use super::*;

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
    pub oracle: &'a [OracleRecord],
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
            setting: setting.clone(),
        });
    }
    Ok(out)
}
