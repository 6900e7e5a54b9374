//! Speed against accuracy of the characterization's knobs (sample stride, Morton bits, class rule, backend): time,
//! drift of the statistics from the full computation, and regret of the policy's selection against oracle results;
//! charts with the Pareto front, a JSON file and markdown tables.
//!
//! ```text
//! cargo run --release --example tradeoff -- [FILE|DIR ...] [--oracle FILE ...] --out DIR [options]
//! ```

use anyhow::Context as _;
use clap::Parser;
use cli::args::{self, List, Policy, PolicyArgs, TieMarginArg};
use cli::Progress;
use meshchar::characterize::{Backend, Characterizer, ClassRule, MortonBits};
use meshchar::eval::tradeoff::{self, GridSpec, Selector, StatsTolerance};
use meshchar::eval::OracleRecord;
use meshchar::eval::{evaluate_scene, OracleConfig, Rebuild};
use meshchar::geom::WorkloadKind;
use meshchar::mesh::Animation;
use meshchar::select::ThesisPolicy;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[path = "support/cli.rs"]
mod cli;

/// Speed against accuracy of the characterization's knobs.
///
/// For each characterization setting (one knob at a time around the reference: the CPU backend, every triangle,
/// 30-bit codes, Doane) and each scene: the median time of the characterization, the drift of its statistics (k,
/// histogram, Cramér's V, empty classes) from the full computation, the policy's selection, and, against oracle
/// results, whether the selection is the measured best or within noise of it and its regret. The calibrated policy
/// selects per scene and workload (rays per frame and frames from the oracle line), from features computed with the
/// setting's parameters on the CPU (one more pass, not timed); the thesis policy selects once per scene.
///
/// Without FILE|DIR, the scenes are those of the oracle files.
#[derive(Parser, Debug)]
#[command(name = "tradeoff", args_override_self = true)]
#[command(after_long_help = "\
Writes into DIR:
  tradeoff-<workload>.svg    time (log) against mean regret per setting, Pareto front marked
  tradeoff-statistics.svg    time (log) against the largest drift of Cramér's V
  tradeoff.json              every number
  tradeoff.md                the tables (per workload, and the least work per scene)")]
struct Args {
    /// Mesh files, directories of frame files (animations), or generated scenes (family:NAME:TRIANGLES[:SEED],
    /// degenerate:NAME:TRIANGLES[:SEED]) [default: the scenes of the oracle files]
    #[arg(value_name = "FILE|DIR", required_unless_present = "oracle")]
    inputs: Vec<PathBuf>,
    /// Where to write
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    #[command(flatten)]
    policy: PolicyArgs,
    #[command(flatten)]
    tie_margin: TieMarginArg,
    /// Oracle results, `evaluate --json` lines (repeat for several workloads); without it the oracle is measured
    /// here, at --oracle-resolution
    #[arg(long, value_name = "FILE")]
    oracle: Vec<PathBuf>,
    /// Comma-separated workloads to measure when no --oracle is given
    #[arg(long, value_name = "LIST", default_value = "primary", value_parser = args::list(args::workload()))]
    workloads: List<WorkloadKind>,
    /// Image side for a measured oracle
    #[arg(long, value_name = "N", default_value_t = 64, value_parser = args::resolution(1, 16384))]
    oracle_resolution: u32,
    /// Repeats for a measured oracle (at most 10,000)
    #[arg(long, value_name = "R", default_value_t = 3, value_parser = args::repeats())]
    oracle_repeats: usize,
    /// Frames of an animation used by a measured oracle
    #[arg(long, value_name = "F", default_value_t = 3, value_parser = args::positive())]
    oracle_frames: usize,
    /// Comma-separated backends; the first is the reference; vulkan is dropped with a note when no device is usable
    /// [default: cpu,vulkan,naive]
    #[arg(long, value_name = "LIST", value_parser = args::list(args::backend()))]
    backends: Option<List<Backend>>,
    /// Comma-separated sample strides [default: 1,2,4,8,16,32,64,128,256]
    #[arg(long, value_name = "LIST", value_parser = args::list(clap::value_parser!(u32).range(1..)))]
    strides: Option<List<u32>>,
    /// Comma-separated Morton bits, 30 and 63 [default: 30,63]
    #[arg(long, value_name = "LIST", value_parser = args::list(args::morton_bits()))]
    bits: Option<List<MortonBits>>,
    /// Comma-separated class rules: doane, sturges, sqrt and fixed counts [default: doane,sturges,sqrt,8,16,32,64]
    #[arg(long, value_name = "LIST", value_parser = args::list(args::class_rule))]
    rules: Option<List<ClassRule>>,
    /// Timed repeats per setting and scene (at most 10,000), median reported
    #[arg(long, value_name = "R", default_value_t = 3, value_parser = args::repeats())]
    repeats: usize,
}

impl Args {
    /// The settings' grid: the lists given, the library's defaults for the others.
    fn grid(&self) -> GridSpec {
        let d = GridSpec::default();
        GridSpec {
            backends: self.backends.clone().map_or(d.backends, |l| l.0),
            strides: self.strides.clone().map_or(d.strides, |l| l.0),
            bits: self.bits.clone().map_or(d.bits, |l| l.0),
            rules: self.rules.clone().map_or(d.rules, |l| l.0),
        }
    }
}

fn main() -> ExitCode {
    cli::main_with(run)
}

fn run(mut args: Args) -> anyhow::Result<()> {
    let mut grid = args.grid();
    // Oracle results from files.
    let mut oracle: Vec<OracleRecord> = Vec::new();
    for f in &args.oracle {
        let records = meshchar::eval::record::read_jsonl(f)?;
        // A record without a validly measured structure has no best to score a selection against.
        let unscored = records.iter().filter(|r| r.best().is_none()).count();
        anyhow::ensure!(
            records.is_empty() || unscored < records.len(),
            "{}: no record names a validly measured structure (each has only errors, invalid times or no \
             structures)",
            f.display()
        );
        if unscored > 0 {
            eprintln!(
                "tradeoff: {}: {unscored} of {} records name no validly measured structure; no regret is scored on them",
                f.display(),
                records.len()
            );
        }
        oracle.extend(records);
    }
    if args.inputs.is_empty() {
        for o in &oracle {
            let p = PathBuf::from(&o.mesh);
            if !args.inputs.contains(&p) {
                args.inputs.push(p);
            }
        }
    }
    let mut scenes: Vec<Animation> = Vec::new();
    let bar = Progress::new("loading", Some(args.inputs.len()), false);
    for (i, p) in args.inputs.iter().enumerate() {
        bar.item(i, 1, &p.display().to_string());
        scenes.push(cli::load_path_checked(p)?);
    }
    bar.finish();

    // Workloads: those of the files, or measured here.
    let mut workloads: Vec<String> = Vec::new();
    for o in &oracle {
        if !workloads.iter().any(|w| w == o.workload.as_str()) {
            workloads.push(o.workload.as_str().to_string());
        }
    }
    if args.oracle.is_empty() {
        let bar = Progress::new("oracle", Some(args.workloads.0.len() * scenes.len()), false);
        for (k, &w) in args.workloads.0.iter().enumerate() {
            for (i, scene) in scenes.iter().enumerate() {
                let config = OracleConfig {
                    workload: w,
                    resolution: args.oracle_resolution,
                    frames: scene.is_dynamic().then_some(args.oracle_frames),
                    rebuild: if scene.is_dynamic() { Rebuild::PerFrame } else { Rebuild::Once },
                    repeats: args.oracle_repeats,
                    ..OracleConfig::default()
                };
                // Steps: per measured frame the reference and every structure at every repeat.
                let frames = if scene.is_dynamic() { args.oracle_frames.min(scene.frames.len()) } else { 1 };
                bar.item(k * scenes.len() + i, frames * (1 + config.repeats * config.structures.len()), "");
                let pr =
                    |m: &str| bar.step(&format!("{} {}x{}: {m}", w.as_str(), config.resolution, config.resolution));
                oracle.push(evaluate_scene(scene, &config, None, &pr)?.record());
            }
            workloads.push(w.as_str().to_string());
        }
        bar.finish();
    }

    // Backends: drop Vulkan with a note when there is no device.
    if grid.backends.contains(&Backend::Vulkan) {
        if let Err(e) = Characterizer::new(Some(Backend::Vulkan)) {
            eprintln!("tradeoff: note: no usable Vulkan device ({e}); measuring the CPU backends only");
            grid.backends.retain(|&b| b != Backend::Vulkan);
            anyhow::ensure!(!grid.backends.is_empty(), "no backend left to measure");
        }
    }
    let settings = grid.settings();
    let thesis = ThesisPolicy::default();
    let model = match args.policy.policy {
        Policy::Calibrated => Some(args.policy.cost_model()?),
        Policy::Thesis => None,
    };
    let tie_margin = args.tie_margin.tie_margin;
    let policy = match &model {
        Some(model) => Selector::Calibrated { model, tie_margin },
        None => Selector::Policy(&thesis),
    };
    let mut engine_for = |b: Backend| Characterizer::new(Some(b));
    let t0 = Instant::now();
    let study = tradeoff::Study {
        scenes: &scenes,
        settings: &settings,
        policy,
        oracle: &oracle,
        workloads: &workloads,
        repeats: args.repeats,
    };
    // Steps: the reference on every scene, then every setting on every scene.
    let bar = Progress::new("sweep", Some(1), false);
    bar.item(0, (1 + settings.len()) * scenes.len(), "");
    let results = tradeoff::sweep(&study, &mut engine_for, &|m| bar.step(m))?;
    bar.finish();
    let tol = StatsTolerance::default();
    let suff = tradeoff::sufficiency(&results, &tol);

    std::fs::create_dir_all(&args.out).with_context(|| args.out.display().to_string())?;
    let write = |name: &str, text: &str| -> anyhow::Result<PathBuf> {
        let p = args.out.join(name);
        std::fs::write(&p, text).with_context(|| p.display().to_string())?;
        Ok(p)
    };
    let mut written = Vec::new();
    for (name, chart) in tradeoff::charts(&results, &workloads) {
        written.push(write(&name, &chart.to_svg())?);
    }
    let mut md = tradeoff::markdown(&results, &workloads, &suff);
    md.push_str("\n### Structures within noise of the oracle's best\n\n");
    md.push_str(&tradeoff::structures_markdown(&oracle, &workloads));
    written.push(write("tradeoff.md", &md)?);
    let json = serde_json::json!({
        "policy": policy.name(),
        "tie_margin": model.as_ref().map(|_| tie_margin),
        "reference": settings.first().map(|s| s.label()),
        "repeats": args.repeats,
        "workloads": workloads,
        "oracle_files": args.oracle.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "oracle": oracle,
        "statistics_tolerance": tol,
        "threads": rayon::current_num_threads(),
        "seconds": t0.elapsed().as_secs_f64(),
        "settings": results,
        "sufficiency": suff,
    });
    written.push(write("tradeoff.json", &json.to_string())?);
    println!("{md}");
    println!("{} settings x {} scenes in {:.1} s; wrote:", settings.len(), scenes.len(), t0.elapsed().as_secs_f64());
    for p in written {
        println!("  {}", p.display());
    }
    Ok(())
}
