//! The measurement oracle on the command line: for each scene, build and trace every acceleration structure and
//! report the ground-truth best, the regret of the selection, and per structure build and trace times, Mrays/s,
//! tests per ray and memory.
//!
//! ```text
//! cargo run --release --example evaluate -- [FILE|DIR ...] [--json] [--workload primary|shadow|diffuse]
//!     [--resolution N] [--frames F] [--repeats R] [--rebuild once|frame] [--structures bvh,kdtree,...]
//!     [--camera EX,EY,EZ,TX,TY,TZ[,FOV]] [--charts DIR] [--policy thesis|calibrated] [--cost-model FILE]
//!     [--tie-margin X] [--oracle-cache FILE] [--help]
//! cargo run --release --example evaluate -- --compare-policies FILE.jsonl ... [--charts DIR] [--json]
//! ```
//!
//! With `--compare-policies`, nothing is measured: the cached oracle results are read back, the thesis policy's
//! recorded selections and the calibrated policy (fitted on all scenes, and leave-one-scene-out) are scored side by
//! side.

use meshchar::accel::{AccelStructure, StructureName};
use meshchar::characterize::{Characterizer, Params};
use meshchar::cost::{CostModel, Prediction};
use meshchar::eval::chart::BarChart;
use meshchar::eval::compare::compare;
use meshchar::eval::record::load_samples as load_oracle_samples;
use meshchar::eval::{evaluate_scene, OracleConfig, Rebuild, SceneEvaluation};
use meshchar::geom::WorkloadKind;
use meshchar::mesh::Animation;
use meshchar::select::{select_for_scene, PolicyChoice, TargetWorkload};
use meshchar::trace::workload::{build_workload, mesh_bounds};
use meshchar::trace::Camera;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};

#[path = "support/cli.rs"]
mod cli;

const USAGE: &str = "\
usage: evaluate [FILE|DIR ...] [options]

For each scene (a mesh file, or a directory of frame files forming an animation), build and trace every
acceleration structure, and print the oracle's best structure, the regret of the selection, and per structure:
build ms, trace ms, total ms (with its noise), Mrays/s, box and triangle tests per ray, memory, SAH cost.

options:
  --json                     one JSON object per scene per line instead of tables
  --workload KIND            primary (default), shadow or diffuse rays
  --resolution N             N x N primary rays per frame (default 1024, as in the thesis)
  --frames F                 frames rendered (static scene) or frames used (animation)
  --repeats R                repeats of every measurement; medians are reported (default 3)
  --rebuild once|frame       build once (static scenes, default) or every frame (default for animations)
  --structures LIST          comma-separated subset of bvh,kdtree,grid,bih,lbvh,hlbvh
  --camera EX,EY,EZ,TX,TY,TZ[,FOV]
                             eye, target (and vertical field of view in degrees, default 45); +y is up;
                             default: a camera framing the scene
  --charts DIR               write SVG bar charts (build time, frame rate, tests per ray) into DIR; with
                             --compare-policies, the per-scene regret charts policy-regret-<workload>.svg
  --policy thesis|calibrated the selection policy whose choice is `selected` and `regret` (default calibrated)
  --cost-model FILE          calibration file of the calibrated policy (default: the shipped one; a missing or
                             stale file falls back to it with a warning)
  --tie-margin X             calibrated policy: relative margin within which the cheaper build wins (default 0.05)
  --oracle-cache FILE        append every scene's JSON line to FILE (to compare policies later without measuring)
  --compare-policies FILE    read cached oracle JSON lines (repeatable) and compare the thesis policy's recorded
                             selections with the calibrated policy, in sample and leave-one-scene-out; measures
                             nothing (meshes are loaded from the recorded paths for their features)
  --help                     this text
";

struct Args {
    inputs: Vec<PathBuf>,
    json: bool,
    config: OracleConfig,
    rebuild: Option<Rebuild>,
    charts: Option<PathBuf>,
    policy: String,
    cost_model: Option<PathBuf>,
    tie_margin: f64,
    oracle_cache: Option<PathBuf>,
    compare: Vec<PathBuf>,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        inputs: Vec::new(),
        json: false,
        config: OracleConfig::default(),
        rebuild: None,
        charts: None,
        policy: "calibrated".into(),
        cost_model: None,
        tie_margin: 0.05,
        oracle_cache: None,
        compare: Vec::new(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        match arg.as_str() {
            "--help" | "-h" => {
                print!("{USAGE}");
                std::process::exit(0);
            }
            "--json" => a.json = true,
            "--workload" => a.config.workload = value("--workload")?.parse::<WorkloadKind>()?,
            "--resolution" => {
                a.config.resolution = value("--resolution")?
                    .parse()
                    .ok()
                    .filter(|&n: &u32| (1..=16384).contains(&n))
                    .ok_or("--resolution needs an integer in 1..=16384")?
            }
            "--frames" => {
                a.config.frames =
                    Some(value("--frames")?.parse().ok().filter(|&n: &usize| n >= 1).ok_or("--frames needs >= 1")?)
            }
            "--repeats" => {
                a.config.repeats =
                    value("--repeats")?.parse().ok().filter(|&n: &usize| n >= 1).ok_or("--repeats needs >= 1")?
            }
            "--rebuild" => {
                a.rebuild = Some(match value("--rebuild")?.as_str() {
                    "once" => Rebuild::Once,
                    "frame" | "per-frame" | "every" => Rebuild::PerFrame,
                    other => return Err(format!("--rebuild: {other:?} is not once or frame")),
                })
            }
            "--structures" => {
                a.config.structures = value("--structures")?
                    .split(',')
                    .filter(|s| !s.is_empty())
                    .map(|s| s.parse::<StructureName>())
                    .collect::<Result<Vec<_>, _>>()?;
                if a.config.structures.is_empty() {
                    return Err("--structures needs at least one name".into());
                }
            }
            "--camera" => {
                let v: Vec<f32> = value("--camera")?
                    .split(',')
                    .map(|s| s.trim().parse::<f32>())
                    .collect::<Result<_, _>>()
                    .map_err(|_| "--camera needs numbers")?;
                if v.len() != 6 && v.len() != 7 {
                    return Err("--camera needs EX,EY,EZ,TX,TY,TZ[,FOV]".into());
                }
                let fov = v.get(6).copied().unwrap_or(45.0);
                let cam = Camera::look_at(
                    glam::Vec3::new(v[0], v[1], v[2]),
                    glam::Vec3::new(v[3], v[4], v[5]),
                    glam::Vec3::Y,
                    fov,
                )
                .ok_or("--camera: eye equals target, view along +y, or bad field of view")?;
                a.config.camera = Some(cam);
            }
            "--charts" => a.charts = Some(PathBuf::from(value("--charts")?)),
            "--policy" => a.policy = cli::policy_arg(value("--policy")?)?,
            "--cost-model" => a.cost_model = Some(PathBuf::from(value("--cost-model")?)),
            "--tie-margin" => a.tie_margin = cli::tie_margin_arg(&value("--tie-margin")?)?,
            "--oracle-cache" => a.oracle_cache = Some(PathBuf::from(value("--oracle-cache")?)),
            "--compare-policies" => a.compare.push(PathBuf::from(value("--compare-policies")?)),
            s if s.starts_with("--") => return Err(format!("unknown option {s} (see --help)")),
            _ => a.inputs.push(PathBuf::from(arg)),
        }
    }
    if a.inputs.is_empty() && a.compare.is_empty() {
        return Err("no input: give mesh files or directories of frames (see --help)".into());
    }
    Ok(a)
}

/// Loads a mesh file as a one-frame scene, or a directory of `.obj`/`.ply` frames (sorted by name) as an animation.
fn load_scene(path: &Path) -> Result<Animation, String> {
    meshchar::mesh::load_path(path).map_err(|e| e.to_string())
}

/// A selection, its reasons, and the calibrated policy's predictions.
type Selected = (StructureName, Vec<String>, Option<Vec<Prediction>>);

/// The policy's selection for a scene: every frame characterized (Vulkan when a device is found, else the CPU
/// path) and its features computed; then the thesis policy over the frames, or the calibrated policy for the
/// workload of `config` (rays per frame counted by generating the workload's rays as the oracle will).
fn select(
    engine: &mut Characterizer,
    scene: &Animation,
    config: &OracleConfig,
    policy: &str,
    model: &CostModel,
    tie_margin: f64,
) -> Result<Selected, String> {
    let (chars, features) =
        engine.characterize_animation_with_features(scene, &Params::default()).map_err(|e| e.to_string())?;
    let choice = match policy {
        "thesis" => PolicyChoice::Thesis,
        _ => PolicyChoice::Calibrated { model, tie_margin },
    };
    let workload = TargetWorkload {
        kind: config.workload,
        rays_per_frame: if policy == "thesis" { 0 } else { rays_per_frame(scene, config)? },
        frames: config.frames.unwrap_or(1) as u64,
        animation_frames: config.frames,
    };
    let chosen = select_for_scene(&scene.name, &chars, &features, choice, &workload);
    let (sel, preds) = (chosen.selection, chosen.predicted);
    let name = sel.structure;
    Ok((name, sel.reasons, preds))
}

/// Rays per frame of the oracle's workload on the first frame: `resolution^2` primary rays, or the secondary rays
/// generated from their hits (same camera and reference structure as the oracle, untimed).
fn rays_per_frame(scene: &Animation, config: &OracleConfig) -> Result<u64, String> {
    let n = config.resolution as u64 * config.resolution as u64;
    if config.workload == WorkloadKind::Primary {
        return Ok(n);
    }
    let first = scene.frames.first().ok_or("no frames")?;
    let f =
        if scene.is_dynamic() { config.frames.unwrap_or(scene.frames.len()).clamp(1, scene.frames.len()) } else { 1 };
    let camera = config.camera.unwrap_or_else(|| {
        let b = scene.frames[..f].iter().fold(meshchar::geom::Aabb::EMPTY, |a, m| a.union(&mesh_bounds(m)));
        Camera::frame(&b)
    });
    let reference = meshchar::accel::bvh::Bvh::build(first).map_err(|e| e.to_string())?;
    Ok(build_workload(config.workload, first, &camera, config.resolution, &reference).rays.len() as u64)
}

fn fmt_opt(v: Option<f64>, prec: usize) -> String {
    v.map(|x| format!("{x:.prec$}")).unwrap_or_else(|| "null".into())
}

fn print_table(e: &SceneEvaluation) {
    println!(
        "\n{}  ({} triangles, {} frame(s) measured, totals for {} frame(s), {} rays {}x{}, {} rays/frame, {} repeat(s))",
        e.mesh,
        e.triangles,
        e.frames_measured,
        e.frames,
        e.workload.as_str(),
        e.resolution,
        e.resolution,
        e.rays_per_frame,
        e.repeats
    );
    println!(
        "  selected: {}   oracle best: {}   cheapest within noise: {}   regret: {}{}",
        e.selected.map(|s| s.as_str()).unwrap_or("null"),
        e.oracle_best.map(|s| s.as_str()).unwrap_or("null"),
        e.oracle_cheapest_within_noise.map(|s| s.as_str()).unwrap_or("null"),
        fmt_opt(e.regret, 3),
        match e.regret_within_noise {
            Some(true) => " (within noise)",
            _ => "",
        }
    );
    println!(
        "  {:<7} {:>10} {:>10} {:>18} {:>9} {:>9} {:>9} {:>10} {:>9} {:>5} {:>5}",
        "", "build ms", "trace ms", "total ms", "Mrays/s", "box/ray", "tri/ray", "memory MB", "SAH", "valid", "agree"
    );
    for s in &e.structures {
        let name = s.name.map(|n| n.as_str()).unwrap_or("?");
        if let (Some(err), 0) = (&s.error, s.rays) {
            println!("  {name:<7} error: {err}");
            continue;
        }
        let mark = if Some(s.name).flatten() == e.oracle_best {
            " best"
        } else if s.within_noise_of_best {
            " ~best"
        } else {
            ""
        };
        println!(
            "  {:<7} {:>10.2} {:>10.2} {:>11.2} ±{:<6.2} {:>9.2} {:>9.2} {:>9.2} {:>10.2} {:>9} {:>5} {:>5}{}",
            name,
            s.build_ms.median,
            s.trace_ms.median,
            s.total_ms.median,
            s.total_ms.spread,
            s.mrays_per_s,
            s.box_tests_per_ray,
            s.prim_tests_per_ray,
            s.memory_bytes as f64 / (1024.0 * 1024.0),
            fmt_opt(s.sah_cost, 1),
            s.valid,
            s.hits_agree,
            mark
        );
        if let Some(err) = &s.error {
            println!("          error: {err}");
        }
    }
}

fn append_line(path: &Path, line: &str) -> std::io::Result<()> {
    let mut f = std::fs::OpenOptions::new().create(true).append(true).open(path)?;
    writeln!(f, "{line}")
}

/// Predicted against measured totals of the calibrated policy, per structure.
fn print_predictions(e: &SceneEvaluation, preds: &[Prediction]) {
    println!("  calibrated prediction vs measurement (ms):");
    println!("  {:<7} {:>12} {:>12} {:>12} {:>12}", "", "pred build", "pred trace", "pred total", "measured");
    for p in preds {
        let m = e.get(p.structure).map(|s| format!("{:.2}", s.total_ms.median)).unwrap_or_else(|| "-".into());
        println!(
            "  {:<7} {:>12.2} {:>12.2} {:>12.2} {:>12}",
            p.structure.as_str(),
            p.build_ms,
            p.trace_ms,
            p.total_ms,
            m
        );
    }
}

fn pct(x: Option<f64>) -> String {
    x.map(|v| format!("{:.1}%", 100.0 * v)).unwrap_or_else(|| "-".into())
}

/// `--compare-policies`: thesis (recorded) against calibrated (in sample and leave-one-scene-out) on cached
/// oracle results. Returns the exit code.
fn compare_policies(args: &Args) -> i32 {
    let samples = match load_oracle_samples(&args.compare, &Params::default(), &|m| {
        if std::io::stderr().is_terminal() {
            eprint!("\r\x1b[Kfeatures of {m}");
        }
    }) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("\nevaluate: {e}");
            return 1;
        }
    };
    if std::io::stderr().is_terminal() {
        eprint!("\r\x1b[K");
    }
    let device = meshchar::characterize::cpu::cpu_device_name(rayon::current_num_threads());
    let c = match compare(&samples, args.tie_margin, &device) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("evaluate: {e}");
            return 1;
        }
    };
    if args.json {
        println!("{}", serde_json::json!(c));
    } else {
        println!(
            "{:<44} {:<8} {:>7} | {:>7} {:>7} | {:>7} {:>7} | {:>7} {:>7}",
            "scene", "workload", "best", "thesis", "regret", "cal-in", "regret", "cal-out", "regret"
        );
        let name = |s: Option<meshchar::accel::StructureName>| s.map(|x| x.as_str()).unwrap_or("-");
        for r in &c.rows {
            let scene: String = r.scene.chars().rev().take(44).collect::<Vec<_>>().into_iter().rev().collect();
            println!(
                "{:<44} {:<8} {:>7} | {:>7} {:>7} | {:>7} {:>7} | {:>7} {:>7}",
                scene,
                r.workload.as_str(),
                name(r.oracle_best),
                name(r.baseline),
                pct(r.baseline_regret),
                name(r.calibrated_in_sample),
                pct(r.calibrated_in_sample_regret),
                name(r.calibrated_held_out),
                pct(r.calibrated_held_out_regret)
            );
        }
        println!(
            "\n{:<34} {:>6} {:>9} {:>12} {:>12} {:>12}  worst at",
            "policy", "scored", "accuracy", "within noise", "mean regret", "worst regret"
        );
        for (label, s) in [
            ("thesis (recorded selections)", &c.baseline),
            ("calibrated, calibration scenes", &c.calibrated_in_sample),
            ("calibrated, held out (LOO)", &c.calibrated_held_out),
        ] {
            println!(
                "{:<34} {:>6} {:>8.1}% {:>11.1}% {:>11.1}% {:>11.1}%  {}",
                label,
                s.scored,
                100.0 * s.accuracy,
                100.0 * s.within_noise,
                100.0 * s.mean_regret,
                100.0 * s.worst_regret,
                s.worst
            );
        }
        println!("(tie margin {:.2}; leave-one-out holds out every workload of a scene together)", c.tie_margin);
    }
    if let Some(dir) = &args.charts {
        // One chart per workload (a scene's bars side by side: thesis, calibrated held out).
        let mut workloads: Vec<&str> = c.rows.iter().map(|r| r.workload.as_str()).collect();
        workloads.dedup();
        workloads.sort_unstable();
        workloads.dedup();
        for wl in workloads {
            let rows: Vec<_> = c.rows.iter().filter(|r| r.workload.as_str() == wl).collect();
            let chart = BarChart {
                title: format!("Regret per scene, {wl} rays: thesis policy vs calibrated policy (held out)"),
                y_label: "regret (total / best total - 1)".into(),
                categories: rows
                    .iter()
                    .map(|r| {
                        let p = Path::new(&r.scene);
                        p.file_stem().and_then(|s| s.to_str()).unwrap_or(&r.scene).to_string()
                    })
                    .collect(),
                series: vec![
                    ("thesis".into(), rows.iter().map(|r| r.baseline_regret).collect()),
                    ("calibrated (held out)".into(), rows.iter().map(|r| r.calibrated_held_out_regret).collect()),
                ],
            };
            let path = dir.join(format!("policy-regret-{wl}.svg"));
            if let Err(e) = std::fs::create_dir_all(dir).and_then(|_| std::fs::write(&path, chart.to_svg())) {
                eprintln!("evaluate: {}: {e}", path.display());
                return 1;
            }
            if !args.json {
                println!("chart: {}", path.display());
            }
        }
    }
    0
}

fn main() {
    cli::exit_quietly_on_broken_pipe();
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("evaluate: {e}");
            std::process::exit(2);
        }
    };
    let tty = std::io::stderr().is_terminal();
    let progress = |msg: &str| {
        if tty {
            let mut err = std::io::stderr();
            let _ = write!(err, "\r\x1b[K{msg}");
            let _ = err.flush();
        }
    };
    if !args.compare.is_empty() {
        std::process::exit(compare_policies(&args));
    }
    let model = cli::cost_model("evaluate", args.cost_model.as_deref()).unwrap_or_else(|e| {
        eprintln!("evaluate: {e}");
        std::process::exit(1);
    });
    let mut evals = Vec::new();
    let mut failed = false;
    let mut engine = match Characterizer::new(None) {
        Ok(e) => e,
        Err(e) => {
            eprintln!("evaluate: {e}");
            std::process::exit(1);
        }
    };
    for input in &args.inputs {
        let scene = match load_scene(input) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("evaluate: {e}");
                failed = true;
                continue;
            }
        };
        let mut config = args.config.clone();
        config.rebuild = args.rebuild.unwrap_or(if scene.is_dynamic() { Rebuild::PerFrame } else { Rebuild::Once });

        let predictions;
        let selected = match select(&mut engine, &scene, &config, &args.policy, &model, args.tie_margin) {
            Ok((s, reasons, preds)) => {
                if !args.json {
                    println!("\n{}: the {} policy selects {}", scene.name, args.policy, s.as_str());
                    for r in &reasons {
                        println!("  - {r}");
                    }
                }
                predictions = preds;
                Some(s)
            }
            Err(e) => {
                eprintln!("evaluate: {}: characterization failed: {e}", scene.name);
                failed = true;
                continue;
            }
        };

        match evaluate_scene(&scene, &config, selected, &progress) {
            Ok(e) => {
                if tty {
                    eprint!("\r\x1b[K");
                }
                let mut json = e.to_json();
                json["policy"] = serde_json::json!(args.policy);
                if let Some(p) = &predictions {
                    json["predicted"] = serde_json::json!(p);
                }
                if args.json {
                    println!("{json}");
                } else {
                    print_table(&e);
                    if let Some(p) = &predictions {
                        print_predictions(&e, p);
                    }
                }
                if let Some(path) = &args.oracle_cache {
                    if let Err(err) = append_line(path, &json.to_string()) {
                        eprintln!("evaluate: {}: {err}", path.display());
                        failed = true;
                    }
                }
                evals.push(e);
            }
            Err(e) => {
                if tty {
                    eprint!("\r\x1b[K");
                }
                eprintln!("evaluate: {e}");
                failed = true;
            }
        }
    }
    if !args.json && evals.len() > 1 {
        println!("\n{:<48} {:>10} {:>9} {:>12} {:>8}", "scene", "triangles", "selected", "oracle best", "regret");
        for e in &evals {
            println!(
                "{:<48} {:>10} {:>9} {:>12} {:>8}",
                e.mesh,
                e.triangles,
                e.selected.map(|s| s.as_str()).unwrap_or("null"),
                e.oracle_best.map(|s| s.as_str()).unwrap_or("null"),
                fmt_opt(e.regret, 3)
            );
        }
    }
    if let Some(dir) = &args.charts {
        match meshchar::eval::chart::write_charts(dir, &evals) {
            Ok(paths) => {
                if !args.json {
                    println!(
                        "\ncharts: {}",
                        paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" ")
                    );
                }
            }
            Err(e) => {
                eprintln!("evaluate: {}: {e}", dir.display());
                failed = true;
            }
        }
    }
    if failed {
        std::process::exit(1);
    }
}
