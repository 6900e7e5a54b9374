//! Calibrates the cost model (`meshchar::cost`) on this machine: runs the oracle on a few synthetic and real scenes
//! at a small resolution (or reads cached oracle results), fits the per-structure constants, optionally fits the
//! refit model on animations, prints the constants and fit errors, and writes the calibration file.
//!
//! ```text
//! cargo run --release --example calibrate -- [--out FILE] [--from-oracle FILE.jsonl ...] [--scene PATH ...]
//!     [--resolution N] [--repeats R] [--refit DIR ...] [--device NAME] [--help]
//! ```

use meshchar::accel::lbvh::Lbvh;
use meshchar::accel::AccelStructure;
use meshchar::characterize::{features_cpu, Features, Params};
use meshchar::cost::drift;
use meshchar::cost::{CostModel, RefitModel, Sample};
use meshchar::eval::record::load_samples as load_oracle_samples;
use meshchar::eval::{evaluate_scene, OracleConfig, Rebuild};
use meshchar::geom::WorkloadKind;
use meshchar::mesh::{generate, Animation};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[path = "support/cli.rs"]
mod cli;

const USAGE: &str = "\
usage: calibrate [options]

Fits the cost model's constants on this machine and writes a calibration file (JSON, versioned) that
characterize and evaluate load with --cost-model FILE.

Without --from-oracle, the oracle runs here on three synthetic scenes (random soup, clusters, teapot in a
stadium) and the --scene paths (default: four small shared meshes when ../shared/meshes exists), for the primary,
shadow and diffuse workloads at --resolution, about a minute in release.

options:
  --out FILE              write the calibration file (default: print the constants only)
  --from-oracle FILE      fit on cached `evaluate --json` lines instead of measuring (repeatable); the meshes are
                          loaded from the recorded paths to compute their features
  --scene PATH            a real scene to measure (repeatable)
  --resolution N          image side of the measurements (default 128)
  --repeats R             repeats per measurement (default 1)
  --refit DIR             an animation (directory of frames) for the refit model (repeatable; default: the BART
                          animations under ../shared/meshes/bart when present)
  --no-refit              do not fit the refit model
  --device NAME           device name stored in the file (default: the CPU)
  -h, --help              this text
";

struct Args {
    out: Option<PathBuf>,
    oracle: Vec<PathBuf>,
    scenes: Vec<PathBuf>,
    resolution: u32,
    repeats: usize,
    refit: Vec<PathBuf>,
    no_refit: bool,
    device: Option<String>,
}

fn parse_args() -> Result<Option<Args>, String> {
    let mut a = Args {
        out: None,
        oracle: Vec::new(),
        scenes: Vec::new(),
        resolution: 128,
        repeats: 1,
        refit: Vec::new(),
        no_refit: false,
        device: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |n: &str| it.next().ok_or_else(|| format!("{n} needs a value"));
        match arg.as_str() {
            "-h" | "--help" => return Ok(None),
            "--out" => a.out = Some(PathBuf::from(value("--out")?)),
            "--from-oracle" => a.oracle.push(PathBuf::from(value("--from-oracle")?)),
            "--scene" => a.scenes.push(PathBuf::from(value("--scene")?)),
            "--resolution" => {
                a.resolution = value("--resolution")?
                    .parse()
                    .ok()
                    .filter(|n: &u32| (1..=4096).contains(n))
                    .ok_or("--resolution needs an integer in 1..=4096")?
            }
            "--repeats" => {
                a.repeats =
                    value("--repeats")?.parse().ok().filter(|&n: &usize| n >= 1).ok_or("--repeats needs >= 1")?
            }
            "--refit" => a.refit.push(PathBuf::from(value("--refit")?)),
            "--no-refit" => a.no_refit = true,
            "--device" => a.device = Some(value("--device")?),
            s => return Err(format!("unknown argument {s} (see --help)")),
        }
    }
    Ok(Some(a))
}

fn shared() -> PathBuf {
    PathBuf::from("..").join("shared").join("meshes")
}

fn samples_from_oracle(files: &[PathBuf]) -> Result<Vec<Sample>, String> {
    load_oracle_samples(files, &Params::default(), &|m| eprintln!("calibrate: features of {m}"))
        .map_err(|e| e.to_string())
}

fn measure(args: &Args) -> Result<Vec<Sample>, String> {
    let mut scenes: Vec<Animation> = vec![
        Animation { name: "synthetic:random-soup-20k".into(), frames: vec![generate::random_soup(20_000, 1)] },
        Animation { name: "synthetic:clustered-20k".into(), frames: vec![generate::clustered(20_000, 8, 2)] },
        Animation { name: "synthetic:teapot-in-stadium".into(), frames: vec![generate::teapot_in_stadium(3)] },
    ];
    let mut paths = args.scenes.clone();
    if paths.is_empty() && shared().is_dir() {
        for p in ["small/cow.obj", "small/fandisk.obj", "stanford-bunny/bun_zipper_res2.ply", "sibenik/sibenik.obj"] {
            paths.push(shared().join(p));
        }
    }
    for p in &paths {
        scenes.push(meshchar::mesh::load_path(p).map_err(|e| e.to_string())?);
    }
    let mut out = Vec::new();
    for scene in &scenes {
        let first = scene.frames.first().ok_or(format!("{}: no frames", scene.name))?;
        let f = features_cpu(first, &Params::default()).map_err(|e| format!("{}: {e}", scene.name))?;
        for kind in [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
            let config = OracleConfig {
                workload: kind,
                resolution: args.resolution,
                repeats: args.repeats,
                rebuild: if scene.is_dynamic() { Rebuild::PerFrame } else { Rebuild::Once },
                ..OracleConfig::default()
            };
            let t = Instant::now();
            let e = evaluate_scene(scene, &config, None, &|_| {}).map_err(|e| e.to_string())?;
            eprintln!("calibrate: {} {}: {:.1} s", scene.name, kind.as_str(), t.elapsed().as_secs_f64());
            out.push(e.record().sample(f.clone(), None));
        }
    }
    Ok(out)
}

/// SAH of a refitted frame-0 LBVH against a fresh LBVH per frame, and refit time per triangle.
fn fit_refit(dirs: &[PathBuf]) -> Result<Option<RefitModel>, String> {
    let (mut xs, mut ys, mut ns_per_tri) = (Vec::new(), Vec::new(), Vec::new());
    for dir in dirs {
        let anim = meshchar::mesh::load_path(dir).map_err(|e| e.to_string())?;
        if anim.frames.len() < 2 {
            continue;
        }
        let feats: Vec<Features> = anim
            .frames
            .iter()
            .map(|m| features_cpu(m, &Params::default()))
            .collect::<Result<_, _>>()
            .map_err(|e| e.to_string())?;
        let mut tree = Lbvh::build(&anim.frames[0]).map_err(|e| e.to_string())?.into_tree();
        for (i, m) in anim.frames.iter().enumerate().skip(1) {
            let t = Instant::now();
            tree.refit(m).map_err(|e| e.to_string())?;
            ns_per_tri.push(t.elapsed().as_secs_f64() * 1e9 / m.triangle_count().max(1) as f64);
            let fresh = Lbvh::build(m).map_err(|e| e.to_string())?.tree().sah_cost();
            let ratio = tree.sah_cost() / fresh.max(f64::MIN_POSITIVE);
            let d = drift(&feats[0], &feats[i]);
            eprintln!("calibrate: {} frame {i}: drift {d:.4}, SAH refit / fresh {ratio:.3}", anim.name);
            xs.push(d);
            ys.push(ratio - 1.0);
        }
    }
    if xs.is_empty() {
        return Ok(None);
    }
    // Least squares through the origin: ratio - 1 = g * drift.
    let sxx: f64 = xs.iter().map(|x| x * x).sum();
    let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| x * y).sum();
    let g = if sxx > 0.0 { (sxy / sxx).max(0.0) } else { 0.0 };
    let rms = (xs.iter().zip(&ys).map(|(x, y)| (g * x - y).powi(2)).sum::<f64>() / xs.len() as f64).sqrt();
    ns_per_tri.sort_by(f64::total_cmp);
    Ok(Some(RefitModel {
        sah_growth_per_drift: g,
        refit_ns_per_triangle: ns_per_tri[ns_per_tri.len() / 2],
        fit_rms: rms,
        samples: xs.len(),
    }))
}

fn run(args: &Args) -> Result<(), String> {
    let t = Instant::now();
    let samples = if args.oracle.is_empty() { measure(args)? } else { samples_from_oracle(&args.oracle)? };
    let device = args
        .device
        .clone()
        .unwrap_or_else(|| meshchar::characterize::cpu::cpu_device_name(rayon::current_num_threads()));
    let source = if args.oracle.is_empty() {
        format!(
            "calibrate: oracle at {}x{}, {} repeat(s), {} samples",
            args.resolution,
            args.resolution,
            args.repeats,
            samples.len()
        )
    } else {
        format!(
            "calibrate --from-oracle {}",
            args.oracle.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" ")
        )
    };
    let mut model = CostModel::fit(&samples, &device, &source).map_err(|e| e.to_string())?;
    if !args.no_refit {
        let mut dirs = args.refit.clone();
        if dirs.is_empty() && shared().join("bart").is_dir() {
            for d in ["museum5", "robots", "kitchen"] {
                dirs.push(shared().join("bart").join(d));
            }
        }
        model.refit = fit_refit(&dirs)?;
    }
    println!(
        "cost model: device {}, {} samples, {} scenes; total fit error {:.1}% RMS (log)",
        model.device,
        samples.len(),
        model.scenes.len(),
        100.0 * model.total_rms_log
    );
    println!(
        "{:<7} {:>8} {:>6} | ns: {:>6} {:>6} {:>6} {:>5} {:>5} {:>5} {:>5} | RMS log error: {:>6} {:>6} {:>6} {:>7} {:>6} {:>6}",
        "", "ln a", "b", "ray/p", "ray/s", "ray/d", "box", "tri", "box+", "tri+", "build", "box", "tri", "tr|cnt", "trace", "total"
    );
    for s in &model.structures {
        println!(
            "{:<7} {:>8.3} {:>6.3} |     {:>6.1} {:>6.1} {:>6.1} {:>5.2} {:>5.2} {:>5.2} {:>5.2} |                {:>6.3} {:>6.3} {:>6.3} {:>7.3} {:>6.3} {:>6.3}",
            s.structure.as_str(),
            s.build_ln_a,
            s.build_exponent,
            s.trace_price[0],
            s.trace_price[1],
            s.trace_price[2],
            s.trace_price[3],
            s.trace_price[4],
            s.trace_price[5],
            s.trace_price[6],
            s.fit.build,
            s.fit.box_tests,
            s.fit.prim_tests,
            s.fit.trace_given_counts,
            s.fit.trace,
            s.fit.total
        );
    }
    if let Some(r) = &model.refit {
        println!(
            "refit: SAH(refit)/SAH(fresh) = 1 + {:.3} * drift (RMS {:.3}, {} frame pairs); refit {:.1} ns/triangle",
            r.sah_growth_per_drift, r.fit_rms, r.samples, r.refit_ns_per_triangle
        );
    }
    if let Some(out) = &args.out {
        model.save(out).map_err(|e| e.to_string())?;
        println!("wrote {}", out.display());
    }
    eprintln!("calibrate: {:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

fn main() -> ExitCode {
    cli::exit_quietly_on_broken_pipe();
    cli::main_with("calibrate", USAGE, parse_args(), run)
}
