//! Characterizes meshes and animations (docs/spec.md) and selects an acceleration structure for each.
//!
//! ```text
//! cargo run --release --example characterize -- [FILE|DIR ...] [--json] [--backend vulkan|cpu|naive]
//!     [--morton-bits 30|63] [--alpha A] [--sample-stride S] [--class-rule doane|sturges|sqrt|N]
//!     [--policy thesis|calibrated] [--cost-model FILE] [--workload primary|shadow|diffuse] [--resolution N]
//!     [--frames F]
//! ```
//!
//! A FILE is a static mesh (.obj or .ply); a DIR holds the frames of an animation (one report per frame, `kind`
//! dynamic when there is more than one). Without a path, the embedded default scene is characterized. Without
//! `--json` the reports are printed for people; with it, one JSON object per mesh or frame per line.

use meshchar::characterize::Features;
use meshchar::characterize::{cpu, Backend, Characterization, Characterizer, ClassRule, MortonBits, Params};
use meshchar::cost::CostModel;
use meshchar::geom::WorkloadKind;
use meshchar::mesh::Animation;
use meshchar::select::{select_for_scene, CalibratedPolicy, PolicyChoice, Report, TargetWorkload};
use std::path::PathBuf;
use std::process::ExitCode;

#[path = "support/cli.rs"]
mod cli;

const USAGE: &str = "\
usage: characterize [FILE|DIR ...] [options]

  FILE                  a mesh (.obj, .ply): a static scene
  DIR                   the frames of an animation, in name order: a dynamic scene, one report per frame
  (none)                the embedded default scene

options:
  --json                one JSON object per mesh or frame per line (default: a report for people)
  --backend B           vulkan, cpu or naive (default: vulkan when a device is found, else cpu)
  --morton-bits B       30 or 63 (default 30)
  --alpha A             significance of the chi-square test, in (0, 1) (default 0.005)
  --sample-stride S     characterize every S-th triangle only (default 1: all)
  --class-rule R        doane, sturges, sqrt or a fixed number of classes (default doane)
  --policy P            thesis or calibrated (default calibrated): the selection policy
  --cost-model FILE     calibration file of the calibrated policy (default: the shipped one; a missing or stale
                        file falls back to it with a warning)
  --workload KIND       calibrated policy: primary (default), shadow or diffuse rays
  --resolution N        calibrated policy: N x N rays per frame (default 1024; for shadow and diffuse rays an upper
                        bound, as only rays that hit spawn them)
  --frames F            calibrated policy: frames rendered with one build of a static scene (default 1)
  -h, --help            this text";

struct Args {
    paths: Vec<PathBuf>,
    json: bool,
    backend: Option<Backend>,
    params: Params,
    policy: String,
    cost_model: Option<PathBuf>,
    workload: WorkloadKind,
    resolution: u64,
    frames: u64,
}

fn parse_args(argv: Vec<String>) -> Result<Option<Args>, String> {
    let mut args = Args {
        paths: Vec::new(),
        json: false,
        backend: None,
        params: Params::default(),
        policy: "calibrated".into(),
        cost_model: None,
        workload: WorkloadKind::Primary,
        resolution: 1024,
        frames: 1,
    };
    let mut it = argv.into_iter();
    while let Some(arg) = it.next() {
        let (flag, inline) = match arg.split_once('=') {
            Some((f, v)) if f.starts_with("--") => (f.to_string(), Some(v.to_string())),
            _ => (arg.clone(), None),
        };
        let mut value = |name: &str| -> Result<String, String> {
            inline.clone().or_else(|| it.next()).ok_or_else(|| format!("{name} needs a value"))
        };
        match flag.as_str() {
            "-h" | "--help" => return Ok(None),
            "--json" => args.json = true,
            "--backend" => args.backend = Some(value("--backend")?.parse().map_err(|e| format!("{e}"))?),
            "--morton-bits" => {
                let v = value("--morton-bits")?;
                args.params.morton_bits = v
                    .parse::<u32>()
                    .ok()
                    .and_then(MortonBits::from_total)
                    .ok_or_else(|| format!("--morton-bits must be 30 or 63, got {v:?}"))?;
            }
            "--alpha" => {
                let v = value("--alpha")?;
                args.params.alpha = v.parse().map_err(|_| format!("--alpha must be a number, got {v:?}"))?;
            }
            "--sample-stride" => {
                let v = value("--sample-stride")?;
                args.params.sample_stride =
                    v.parse().map_err(|_| format!("--sample-stride must be a positive integer, got {v:?}"))?;
            }
            "--class-rule" => {
                args.params.class_rule = value("--class-rule")?.parse::<ClassRule>().map_err(|e| format!("{e}"))?;
            }
            "--policy" => args.policy = cli::policy_arg(value("--policy")?)?,
            "--cost-model" => args.cost_model = Some(PathBuf::from(value("--cost-model")?)),
            "--workload" => args.workload = value("--workload")?.parse()?,
            "--resolution" => {
                let v = value("--resolution")?;
                args.resolution = v
                    .parse()
                    .ok()
                    .filter(|n| (1..=16384).contains(n))
                    .ok_or_else(|| format!("--resolution must be an integer in 1..=16384, got {v:?}"))?;
            }
            "--frames" => {
                let v = value("--frames")?;
                args.frames =
                    v.parse().ok().filter(|&n| n >= 1).ok_or_else(|| format!("--frames must be >= 1, got {v:?}"))?;
            }
            f if f.starts_with('-') && f.len() > 1 => return Err(format!("unknown option {f}")),
            _ => args.paths.push(PathBuf::from(arg)),
        }
    }
    args.params.validate().map_err(|e| format!("{e}"))?;
    Ok(Some(args))
}

/// The scene characterized when no path is given: the embedded low-resolution bunny.
fn default_scene() -> Animation {
    let mesh = meshchar::mesh::default_scene();
    Animation { name: mesh.name.clone(), frames: vec![mesh] }
}

/// Characterizes every frame of a scene and prints one report per frame. Returns false after an error (printed).
fn process(engine: &mut Characterizer, scene: &Animation, args: &Args, model: &CostModel) -> bool {
    let (results, features): (Vec<Characterization>, Vec<Features>) =
        match engine.characterize_animation_with_features(scene, &args.params) {
            Ok(r) => r,
            Err(e) => {
                eprintln!("characterize: {e}");
                return false;
            }
        };
    let policy = match args.policy.as_str() {
        "thesis" => PolicyChoice::Thesis,
        _ => PolicyChoice::Calibrated { model, tie_margin: CalibratedPolicy::DEFAULT_TIE_MARGIN },
    };
    let workload = TargetWorkload {
        kind: args.workload,
        rays_per_frame: args.resolution * args.resolution,
        frames: args.frames,
        animation_frames: None,
    };
    let chosen = select_for_scene(&scene.name, &results, &features, policy, &workload);
    let dynamic = scene.frames.len() > 1;
    for (i, (frame, c)) in scene.frames.iter().zip(&results).enumerate() {
        let mut report = Report::new(if dynamic { scene.name.clone() } else { frame.name.clone() }, c)
            .selection(chosen.kind, chosen.policy, &chosen.selection)
            .zero_area(cpu::zero_area_triangles(frame, args.params.sample_stride))
            .features(features[i].clone());
        if let Some(p) = &chosen.predicted {
            report = report.predicted(p.clone());
        }
        if dynamic {
            report = report.frame(i, frame.name.clone());
        }
        if args.json {
            println!("{}", report.to_json());
        } else {
            println!("{}", report.to_text());
        }
    }
    true
}

fn main() -> ExitCode {
    cli::exit_quietly_on_broken_pipe();
    let args = match parse_args(std::env::args().skip(1).collect()) {
        Ok(Some(a)) => a,
        Ok(None) => {
            println!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("characterize: {e}\n\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    let mut engine = match Characterizer::new(args.backend) {
        Ok(e) => e,
        Err(e) => {
            eprintln!("characterize: {e}");
            return ExitCode::FAILURE;
        }
    };
    if let Some(note) = engine.note() {
        eprintln!("characterize: {note}");
    }
    let model = match cli::cost_model("characterize", args.cost_model.as_deref()) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("characterize: {e}");
            return ExitCode::FAILURE;
        }
    };
    let mut ok = true;
    if args.paths.is_empty() {
        ok &= process(&mut engine, &default_scene(), &args, &model);
    }
    for path in &args.paths {
        match meshchar::mesh::load_path(path) {
            Ok(scene) if scene.frames.is_empty() => {
                eprintln!("characterize: {}: no frames found", path.display());
                ok = false;
            }
            Ok(scene) => ok &= process(&mut engine, &scene, &args, &model),
            Err(e) => {
                eprintln!("characterize: {e}");
                ok = false;
            }
        }
    }
    if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
