//! The measurement oracle on the command line: for each scene, build and trace every acceleration structure and
//! report the ground-truth best, the regret of the selection, and per structure build and trace times, Mrays/s,
//! tests per ray and memory.
//!
//! ```text
//! cargo run --release --example evaluate -- [FILE|DIR ...] [--json] [--workload primary|shadow|diffuse]
//!     [--resolution N] [--frames F] [--repeats R] [--rebuild once|frame] [--structures bvh,kdtree,...]
//!     [--camera EX,EY,EZ,TX,TY,TZ[,FOV]] [--charts DIR] [--help]
//! ```

use meshchar::accel::StructureName;
use meshchar::characterize::{Characterizer, Params, Policy, SceneSummary, ThesisPolicy};
use meshchar::eval::{evaluate_scene, OracleConfig, Rebuild, SceneEvaluation};
use meshchar::mesh::Animation;
use meshchar::trace::{Camera, WorkloadKind};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};

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
  --charts DIR               write SVG bar charts (build time, frame rate, tests per ray) into DIR
  --help                     this text
";

struct Args {
    inputs: Vec<PathBuf>,
    json: bool,
    config: OracleConfig,
    rebuild: Option<Rebuild>,
    charts: Option<PathBuf>,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args { inputs: Vec::new(), json: false, config: OracleConfig::default(), rebuild: None, charts: None };
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
            s if s.starts_with("--") => return Err(format!("unknown option {s} (see --help)")),
            _ => a.inputs.push(PathBuf::from(arg)),
        }
    }
    if a.inputs.is_empty() {
        return Err("no input: give mesh files or directories of frames (see --help)".into());
    }
    Ok(a)
}

/// Loads a mesh file as a one-frame scene, or a directory of `.obj`/`.ply` frames (sorted by name) as an animation.
fn load_scene(path: &Path) -> Result<Animation, String> {
    meshchar::mesh::load_path(path).map_err(|e| e.to_string())
}

/// The characterization's selection for a scene: every frame characterized (Vulkan when a device is found, else
/// the CPU path), then the thesis policy over the frames.
fn select(engine: &mut Characterizer, scene: &Animation) -> Result<(StructureName, Vec<String>), String> {
    let frames = engine.characterize_animation(scene, &Params::default()).map_err(|e| e.to_string())?;
    let summary = SceneSummary::new(scene.name.clone(), &frames);
    let sel = ThesisPolicy::default().select(&summary);
    let name = sel.structure.name().parse::<StructureName>().map_err(|e| format!("{e:?}"))?;
    Ok((name, sel.reasons))
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

fn main() {
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

        let selected = match select(&mut engine, &scene) {
            Ok((s, reasons)) => {
                if !args.json {
                    println!("\n{}: the thesis policy selects {}", scene.name, s.as_str());
                    for r in &reasons {
                        println!("  - {r}");
                    }
                }
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
                if args.json {
                    println!("{}", e.to_json());
                } else {
                    print_table(&e);
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
