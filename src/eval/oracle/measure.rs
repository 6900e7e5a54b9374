//! The measurement loop of the oracle ([`evaluate_scene`]): the rays and reference hits of every frame, then
//! rounds of every structure (interleaved), the totals, the best and the regret.

use super::device::{DeviceOracle, DriverAcc};
use super::refit::{RefitAcc, RefitCandidate};
use super::{
    check_trace_budget, DeviceRecord, EvalError, Measurement, OracleConfig, Rebuild, SceneEvaluation, StructureResult,
    TraceBackend, MAX_PRECISION_REPEATS,
};
use crate::accel::{build_structure, AccelStats, AccelStructure, StructureName};
use crate::geom::Camera;
use crate::geom::WorkloadKind;
use crate::mesh::{Animation, Mesh};
use crate::trace::workload::{build_workload, mesh_bounds};
use crate::trace::{count_disagreements, trace, RaySet, TraceOutcome};
use std::time::Instant;

pub(super) fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Per structure, per repeat accumulators.
#[derive(Clone, Default)]
struct Acc {
    build: Vec<f64>,
    upload: Vec<f64>,
    trace: Vec<f64>,
    rays: u64,
    box_tests: u64,
    prim_tests: u64,
    memory: usize,
    sah: Option<f64>,
    stats: Option<AccelStats>,
    valid: bool,
    disagreements: usize,
    error: Option<String>,
    /// Built on the host after the device builder hit the driver's loop limit (some frame).
    host_fallback: bool,
}

/// One frame's rays and reference hits, what the driver structures and refit candidates measure against.
pub(super) struct Frame<'a> {
    pub(super) scene: &'a str,
    pub(super) index: usize,
    pub(super) count: usize,
    pub(super) repeats: usize,
    pub(super) mesh: &'a Mesh,
    pub(super) rays: &'a RaySet,
    pub(super) want: &'a TraceOutcome,
    pub(super) progress: &'a dyn Fn(&str),
}

impl Frame<'_> {
    /// Reports repeat `r` of `name` on this frame.
    pub(super) fn progress_step(&self, r: usize, name: &str) {
        (self.progress)(&format!(
            "{}: frame {}/{} repeat {}/{}: {}",
            self.scene,
            self.index + 1,
            self.count,
            r + 1,
            self.repeats,
            name
        ));
    }
}

/// Runs the oracle on one scene (see the module docs). `selected` is the characterization's choice, if any: it
/// only feeds `regret`; the measurement is the same either way. `progress` receives one line per step.
pub fn evaluate_scene(
    scene: &Animation,
    config: &OracleConfig,
    selected: Option<StructureName>,
    progress: &dyn Fn(&str),
) -> Result<SceneEvaluation, EvalError> {
    evaluate_scene_on(scene, config, selected, progress, None)
}

/// [`evaluate_scene`] with the rays traced on the device when `device` is given (`trace_backend` `vulkan`): every
/// structure is built on the host (timed), uploaded (timed, reported apart as `upload_ms` and counted in the build
/// time) and traced by the device kernel (timed by GPU timestamps); every ray's hit is compared with the CPU
/// reference. Without `device`, exactly [`evaluate_scene`].
pub fn evaluate_scene_on(
    scene: &Animation,
    config: &OracleConfig,
    selected: Option<StructureName>,
    progress: &dyn Fn(&str),
    device: Option<&DeviceOracle<'_>>,
) -> Result<SceneEvaluation, EvalError> {
    let first = scene.frames.first().ok_or_else(|| EvalError::NoFrames(scene.name.clone()))?;
    let animated = scene.frames.len() > 1;
    if animated && config.rebuild == Rebuild::Once {
        return Err(EvalError::Config {
            scene: scene.name.clone(),
            reason: "building once is only meaningful for a static scene (the oracle measures no refits); use per-frame rebuilds"
                .into(),
        });
    }
    let (measured, frames): (&[Mesh], usize) = if animated {
        let f = config.frames.unwrap_or(scene.frames.len()).clamp(1, scene.frames.len());
        (&scene.frames[..f], f)
    } else {
        (&scene.frames[..1], config.frames.unwrap_or(1).max(1))
    };
    let repeats = config.repeats.max(1);
    let camera = config.camera.unwrap_or_else(|| {
        let b = measured.iter().fold(crate::geom::Aabb::EMPTY, |a, m| a.union(&mesh_bounds(m)));
        Camera::frame(&b)
    });
    let names = &config.structures;
    let mut acc: Vec<Acc> = vec![Acc { valid: true, ..Default::default() }; names.len()];
    // Totals per repeat: a static scene's frame stands for `frames` frames.
    let (build_factor, trace_factor) = if animated {
        (1.0, 1.0)
    } else {
        let f = frames as f64;
        (if config.rebuild == Rebuild::PerFrame { f } else { 1.0 }, f)
    };
    let precision = config.precision.filter(|p| p.is_finite() && *p > 0.0);
    let max_repeats = if precision.is_some() { config.max_repeats.max(repeats) } else { repeats };
    // Whether frame 0's repeats so far settle a structure's total (precise oracle).
    let settled = |a: &Acc| match precision {
        None => true,
        Some(p) => {
            let totals: Vec<f64> =
                a.build.iter().zip(&a.trace).map(|(b, t)| b * build_factor + t * trace_factor).collect();
            Measurement::of(&totals).precise_to(p)
        }
    };
    let mut dacc: Vec<DriverAcc> = config
        .driver
        .iter()
        .map(|_| DriverAcc {
            build: vec![0.0; repeats],
            trace: vec![0.0; repeats],
            kept: (0..repeats).map(|_| None).collect(),
            ..Default::default()
        })
        .collect();
    let refits: Vec<RefitCandidate> = if animated { config.refit.clone() } else { Vec::new() };
    let mut racc: Vec<RefitAcc> = refits
        .iter()
        .map(|_| RefitAcc { kept: (0..repeats).map(|_| None).collect(), valid: true, ..Default::default() })
        .collect();
    let mut rays_per_frame = 0;
    let mut reference_hits = 0u64;
    let mut rays_total = 0u64;
    for (fi, mesh) in measured.iter().enumerate() {
        progress(&format!("{}: frame {}/{}: rays and reference hits", scene.name, fi + 1, measured.len()));
        let reference = crate::accel::bvh::Bvh::build(mesh)?;
        let over =
            |reason: String| EvalError::Config { scene: scene.name.clone(), reason: format!("reference {reason}") };
        if config.workload != WorkloadKind::Primary {
            // The secondary rays start where the reference's primary rays hit.
            let primary = RaySet {
                kind: WorkloadKind::Primary,
                rays: crate::trace::workload::primary_rays(&camera, config.resolution, config.resolution),
                any_hit: false,
            };
            check_trace_budget(&reference, &primary, config.max_tests_per_ray).map_err(over)?;
        }
        let rays: RaySet = build_workload(config.workload, mesh, &camera, config.resolution, &reference);
        check_trace_budget(&reference, &rays, config.max_tests_per_ray).map_err(over)?;
        if fi == 0 {
            rays_per_frame = rays.rays.len();
        }
        let want: TraceOutcome = trace(&reference, &rays);
        drop(reference);
        reference_hits +=
            (want.hits.iter().filter(|h| h.is_some()).count() + want.occluded.iter().filter(|&&o| o).count()) as u64;
        rays_total += rays.rays.len() as u64;
        // The device builders read the frame from device memory, where an engine's geometry already is (untimed).
        let mesh_buffers = match device {
            Some(d) if names.iter().any(|&n| DeviceOracle::builds_on_device(n)) || !config.driver.is_empty() => Some(
                crate::gpu::MeshBuffers::upload(d.ctx, &mesh.positions, &mesh.indices)
                    .map_err(|e| EvalError::Device(e.to_string()))?,
            ),
            _ => None,
        };
        // Primary and shadow rays are made on the device (never uploaded), checked once against the host's, bit
        // for bit.
        let device_rays = match (device, config.workload) {
            (Some(d), WorkloadKind::Primary) => {
                Some(d.primary_rays(&camera, config.resolution, &rays.rays).map_err(EvalError::Device)?)
            }
            (Some(d), kind) => {
                Some(d.secondary_rays(kind, &camera, config.resolution, mesh, &rays.rays).map_err(EvalError::Device)?)
            }
            (None, _) => None,
        };
        // Repeats, in rounds of every structure (interleaved). On frame 0 each structure runs `repeats` times and,
        // under a precision target, further rounds of all of them follow until every total is precise enough (or
        // `max_repeats` rounds, more while `precision_ms` allows); later frames repeat each structure as often as
        // frame 0 did, so that every repeat's total covers every frame.
        let mut r = 0;
        loop {
            // Frame 0, past `repeats`: another round of every structure while one is short of the target, up to
            // `max_repeats` rounds, or past them while the record's measured time allows.
            let another_round = fi == 0 && r >= repeats && precision.is_some() && {
                let live = acc.iter().filter(|a| a.error.is_none());
                let short = live.clone().any(|a| !settled(a));
                let spent: f64 = live.flat_map(|a| a.build.iter().chain(&a.trace)).sum();
                short && (r < max_repeats || (r < MAX_PRECISION_REPEATS && spent < config.precision_ms))
            };
            let mut ran = false;
            for (si, &name) in names.iter().enumerate() {
                let a = &mut acc[si];
                if a.error.is_some() {
                    continue;
                }
                let wanted = match fi {
                    0 => r < repeats || another_round,
                    _ => r < a.build.len(),
                };
                if !wanted {
                    continue;
                }
                ran = true;
                if fi == 0 {
                    a.build.push(0.0);
                    a.upload.push(0.0);
                    a.trace.push(0.0);
                }
                let bound = match fi {
                    0 if r < max_repeats => max_repeats,
                    0 => MAX_PRECISION_REPEATS.max(r + 1),
                    _ => a.build.len(),
                };
                progress(&format!(
                    "{}: frame {}/{} repeat {}/{}{}: {name}",
                    scene.name,
                    fi + 1,
                    measured.len(),
                    r + 1,
                    if r < repeats { repeats } else { bound },
                    if r < repeats || fi > 0 { "" } else { " (precision)" },
                ));
                let t = Instant::now();
                let built = build_structure(name, mesh);
                let build_ms = ms(t);
                let s: Box<dyn AccelStructure> = match built {
                    Ok(s) => s,
                    Err(e) => {
                        a.error = Some(e.to_string());
                        a.valid = false;
                        continue;
                    }
                };
                if r == 0 {
                    if let Err(e) = check_trace_budget(s.as_ref(), &rays, config.max_tests_per_ray) {
                        a.error = Some(e);
                        a.valid = false;
                        continue;
                    }
                }
                let run = match (device, &mesh_buffers) {
                    (None, _) => Ok((build_ms, 0.0, trace(s.as_ref(), &rays))),
                    (Some(d), Some(m)) if DeviceOracle::builds_on_device(name) => {
                        match d.run_device_built(name, m, &rays, device_rays.as_ref(), (s.as_ref(), mesh)) {
                            Ok(Some((b, o))) => Ok((b, 0.0, o)),
                            // The driver cut the device builder's loops: the host build, uploaded.
                            Ok(None) => {
                                a.host_fallback = true;
                                d.run(s.as_ref(), &rays, device_rays.as_ref()).map(|(u, o)| (build_ms + u, u, o))
                            }
                            Err(e) => Err(e),
                        }
                    }
                    (Some(d), _) => d.run(s.as_ref(), &rays, device_rays.as_ref()).map(|(u, o)| (build_ms + u, u, o)),
                };
                let (build_ms, upload_ms, out) = match run {
                    Ok(x) => x,
                    Err(e) => {
                        a.error = Some(format!("device: {e}"));
                        a.valid = false;
                        continue;
                    }
                };
                a.build[r] += build_ms;
                a.upload[r] += upload_ms;
                a.trace[r] += out.seconds * 1e3;
                if r == 0 {
                    a.rays += out.rays() as u64;
                    a.box_tests += out.counters.box_tests;
                    a.prim_tests += out.counters.prim_tests;
                    a.memory = a.memory.max(s.memory_bytes());
                    a.disagreements += count_disagreements(&out, &want);
                    match s.validate() {
                        Ok(st) => {
                            if fi == 0 {
                                a.stats = Some(st);
                            }
                        }
                        Err(e) => {
                            a.valid = false;
                            a.error.get_or_insert(e.to_string());
                        }
                    }
                    if fi == 0 {
                        a.sah = s.sah_cost();
                    }
                }
            }
            if !ran {
                break;
            }
            r += 1;
        }
        let frame = Frame {
            scene: &scene.name,
            index: fi,
            count: measured.len(),
            repeats,
            mesh,
            rays: &rays,
            want: &want,
            progress,
        };
        for (a, &flags) in dacc.iter_mut().zip(&config.driver) {
            a.measure_frame(flags, &frame, device, mesh_buffers.as_ref(), device_rays.as_ref());
        }
        for (a, &cand) in racc.iter_mut().zip(&refits) {
            a.measure_frame(cand, &frame, device.is_some(), config.max_tests_per_ray);
        }
    }
    let mut results: Vec<StructureResult> = names
        .iter()
        .zip(&acc)
        .map(|(&name, a)| {
            let builds: Vec<f64> = a.build.iter().map(|b| b * build_factor).collect();
            let traces: Vec<f64> = a.trace.iter().map(|t| t * trace_factor).collect();
            let totals: Vec<f64> = builds.iter().zip(&traces).map(|(b, t)| b + t).collect();
            let measured_ok = a.error.is_none() || a.rays > 0;
            let trace_ms = Measurement::of(&a.trace);
            let per_ray = |x: u64| {
                if a.rays > 0 {
                    x as f64 / a.rays as f64
                } else {
                    0.0
                }
            };
            StructureResult {
                name: Some(name),
                build_ms: if measured_ok { Measurement::of(&builds) } else { Measurement::default() },
                build_backend: device.map(|_| {
                    if DeviceOracle::builds_on_device(name) && !a.host_fallback {
                        "device"
                    } else {
                        "host"
                    }
                }),
                upload_ms: device.filter(|_| !DeviceOracle::builds_on_device(name) || a.host_fallback).map(|_| {
                    let uploads: Vec<f64> = a.upload.iter().map(|u| u * build_factor).collect();
                    Measurement::of(&uploads)
                }),
                trace_ms: if measured_ok { Measurement::of(&traces) } else { Measurement::default() },
                total_ms: if measured_ok { Measurement::of(&totals) } else { Measurement::default() },
                rays: a.rays,
                mrays_per_s: if trace_ms.median > 0.0 { a.rays as f64 / (trace_ms.median * 1e3) } else { 0.0 },
                box_tests_per_ray: per_ray(a.box_tests),
                prim_tests_per_ray: per_ray(a.prim_tests),
                memory_bytes: a.memory,
                sah_cost: a.sah,
                stats: a.stats,
                valid: a.valid && a.error.is_none(),
                hits_agree: a.disagreements == 0 && a.rays > 0,
                disagreements: a.disagreements,
                within_noise_of_best: false,
                precision_met: precision.map(|p| measured_ok && Measurement::of(&totals).precise_to(p)),
                error: a.error.clone(),
            }
        })
        .collect();
    // Rays that all miss still measure work (a ray that hits nothing visits every node and cell on its way out:
    // zero-area triangles, coordinates where the f32 test finds no hit), so they rank the structures as any other
    // rays do; a workload that traces no ray at all (secondary rays of a camera that sees nothing) leaves the
    // builds alone, which rank nothing for tracing.
    let no_best_reason = (rays_total == 0).then(|| {
        "the workload traces no ray (no primary ray hits the scene, so there are no secondary rays): the totals are \
         builds alone, so no structure is named best"
            .to_string()
    });
    let best = results
        .iter()
        .filter(|_| no_best_reason.is_none())
        .filter(|s| s.valid && s.hits_agree)
        .min_by(|a, b| a.total_ms.median.total_cmp(&b.total_ms.median))
        .map(|s| (s.name, s.total_ms.clone()));
    if let Some((_, bt)) = &best {
        for s in results.iter_mut() {
            s.within_noise_of_best = s.valid && s.hits_agree && s.total_ms.within_noise(bt);
        }
    }
    let oracle_best = best.as_ref().and_then(|b| b.0);
    let near: Vec<&StructureResult> = results.iter().filter(|s| s.within_noise_of_best).collect();
    let oracle_within_noise: Vec<StructureName> = near.iter().filter_map(|s| s.name).collect();
    let oracle_cheapest_within_noise = near
        .iter()
        .min_by(|a, b| a.build_ms.median.total_cmp(&b.build_ms.median).then(a.memory_bytes.cmp(&b.memory_bytes)))
        .and_then(|s| s.name);
    let sel = selected.and_then(|n| results.iter().find(|s| s.name == Some(n)));
    let (regret, regret_within_noise) = match (sel, &best) {
        (Some(s), Some((_, bt))) if s.valid && bt.median > 0.0 => {
            (Some(s.total_ms.median / bt.median - 1.0), Some(s.within_noise_of_best))
        }
        _ => (None, None),
    };
    let mut e = SceneEvaluation {
        best_candidate: None,
        refit_structures: Vec::new(),
        mesh: scene.name.clone(),
        triangles: first.triangle_count(),
        frames_measured: measured.len(),
        frames,
        workload: config.workload,
        resolution: config.resolution,
        rebuild: config.rebuild,
        repeats,
        precision,
        max_repeats: precision.map(|_| max_repeats),
        precision_ms: precision.and(Some(config.precision_ms).filter(|x| x.is_finite()).map(|x| x.max(0.0))),
        camera,
        rays_per_frame,
        selected,
        oracle_best,
        oracle_within_noise,
        oracle_cheapest_within_noise,
        regret,
        regret_within_noise,
        reference_hits,
        no_best_reason,
        trace_backend: if device.is_some() { TraceBackend::Vulkan } else { TraceBackend::Cpu },
        device: device.map(|d| DeviceRecord::of(d.ctx)),
        structures: results,
        driver_structures: config
            .driver
            .iter()
            .zip(&dacc)
            .map(|(&flags, a)| a.result(flags, build_factor, trace_factor, animated))
            .collect(),
    };
    e.refit_structures = refits.iter().zip(&racc).map(|(c, a)| a.result(c.name(), repeats)).collect();
    e.best_candidate = e.best_of_all();
    Ok(e)
}
