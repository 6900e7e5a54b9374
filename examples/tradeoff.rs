//! Speed against accuracy of the characterization's knobs (sample stride, Morton bits, class rule, backend): time,
//! drift of the statistics from the full computation, and regret of the policy's selection against oracle results;
//! charts with the Pareto front, a JSON file and markdown tables.
//!
//! ```text
//! cargo run --release --example tradeoff -- [FILE|DIR ...] [--oracle FILE ...] --out DIR [options]
//! ```

use meshchar::characterize::{Backend, Characterizer, ClassRule, MortonBits};
use meshchar::cost::CostModel;
use meshchar::eval::tradeoff::{self, GridSpec, Selector, StatsTolerance};
use meshchar::eval::OracleRecord;
use meshchar::eval::{evaluate_scene, OracleConfig, Rebuild};
use meshchar::geom::WorkloadKind;
use meshchar::mesh::Animation;
use meshchar::select::ThesisPolicy;
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::Instant;

#[path = "support/cli.rs"]
mod cli;

const USAGE: &str = "\
usage: tradeoff [FILE|DIR ...] --out DIR [options]

For each characterization setting (one knob at a time around the reference: the CPU backend, every triangle,
30-bit codes, Doane) and each scene: the median time of the characterization, the drift of its statistics (k,
histogram, Cramér's V, empty classes) from the full computation, the policy's selection, and, against oracle
results, whether the selection is the measured best or within noise of it and its regret. The calibrated policy
selects per scene and workload (rays per frame and frames from the oracle line), from features computed with the
setting's parameters on the CPU (one more pass, not timed); the thesis policy selects once per scene. Writes into DIR:
  tradeoff-<workload>.svg    time (log) against mean regret per setting, Pareto front marked
  tradeoff-statistics.svg    time (log) against the largest drift of Cramér's V
  tradeoff.json              every number
  tradeoff.md                the tables (per workload, and the least work per scene)

Without FILE|DIR, the scenes are those of the oracle files.

options:
  --out DIR              where to write (required)
  --policy NAME          thesis | calibrated (default calibrated)
  --cost-model FILE      cost model JSON for the calibrated policy (default: the shipped model)
  --tie-margin X         calibrated policy: relative margin within which the cheaper build wins (default 0.05)
  --oracle FILE          oracle results, `evaluate --json` lines (repeat for several workloads); without it
                         the oracle is measured here, at --oracle-resolution
  --workloads LIST       workloads to measure when no --oracle is given (default primary)
  --oracle-resolution N  image side for a measured oracle (default 64)
  --oracle-repeats R     repeats for a measured oracle (default 3)
  --oracle-frames F      frames of an animation used by a measured oracle (default 3)
  --backends LIST        comma-separated cpu,vulkan,naive (default cpu,vulkan,naive; the first is the reference;
                         vulkan is dropped with a note when no device is usable)
  --strides LIST         sample strides (default 1,2,4,8,16,32,64,128,256)
  --bits LIST            30,63 (default both)
  --rules LIST           doane,sturges,sqrt and fixed counts (default doane,sturges,sqrt,8,16,32,64)
  --repeats R            timed repeats per setting and scene, median reported (default 3)
  --help                 this text
";

struct Args {
    inputs: Vec<PathBuf>,
    out: PathBuf,
    oracle: Vec<PathBuf>,
    workloads: Vec<WorkloadKind>,
    oracle_resolution: u32,
    oracle_repeats: usize,
    oracle_frames: usize,
    grid: GridSpec,
    repeats: usize,
    policy: String,
    cost_model: Option<PathBuf>,
    tie_margin: f64,
}

fn list<T>(v: &str, name: &str, f: impl Fn(&str) -> Option<T>) -> Result<Vec<T>, String> {
    let out: Vec<T> = v
        .split(',')
        .filter(|s| !s.is_empty())
        .map(|s| f(s.trim()).ok_or_else(|| format!("{name}: {s:?} is not valid (see --help)")))
        .collect::<Result<_, _>>()?;
    if out.is_empty() {
        return Err(format!("{name} needs at least one value"));
    }
    Ok(out)
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        inputs: Vec::new(),
        out: PathBuf::new(),
        oracle: Vec::new(),
        workloads: vec![WorkloadKind::Primary],
        oracle_resolution: 64,
        oracle_repeats: 3,
        oracle_frames: 3,
        grid: GridSpec::default(),
        repeats: 3,
        policy: "calibrated".into(),
        cost_model: None,
        tie_margin: 0.05,
    };
    let mut out = None;
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        let positive = |v: String, name: &str| -> Result<usize, String> {
            v.parse().ok().filter(|&n: &usize| n >= 1).ok_or(format!("{name} needs an integer >= 1"))
        };
        match arg.as_str() {
            "--help" | "-h" => {
                print!("{USAGE}");
                std::process::exit(0);
            }
            "--out" => out = Some(PathBuf::from(value("--out")?)),
            "--policy" => a.policy = cli::policy_arg(value("--policy")?)?,
            "--cost-model" => a.cost_model = Some(PathBuf::from(value("--cost-model")?)),
            "--tie-margin" => a.tie_margin = cli::tie_margin_arg(&value("--tie-margin")?)?,
            "--oracle" => a.oracle.push(PathBuf::from(value("--oracle")?)),
            "--workloads" => a.workloads = list(&value("--workloads")?, "--workloads", |s| s.parse().ok())?,
            "--oracle-resolution" => {
                a.oracle_resolution = positive(value("--oracle-resolution")?, "--oracle-resolution")?
                    .try_into()
                    .ok()
                    .filter(|&n: &u32| n <= 16384)
                    .ok_or("--oracle-resolution needs an integer in 1..=16384")?
            }
            "--oracle-repeats" => a.oracle_repeats = positive(value("--oracle-repeats")?, "--oracle-repeats")?,
            "--oracle-frames" => a.oracle_frames = positive(value("--oracle-frames")?, "--oracle-frames")?,
            "--backends" => a.grid.backends = list(&value("--backends")?, "--backends", |s| s.parse::<Backend>().ok())?,
            "--strides" => {
                a.grid.strides = list(&value("--strides")?, "--strides", |s| s.parse::<u32>().ok().filter(|&n| n >= 1))?
            }
            "--bits" => {
                a.grid.bits = list(&value("--bits")?, "--bits", |s| s.parse().ok().and_then(MortonBits::from_total))?
            }
            "--rules" => a.grid.rules = list(&value("--rules")?, "--rules", |s| s.parse::<ClassRule>().ok())?,
            "--repeats" => a.repeats = positive(value("--repeats")?, "--repeats")?,
            s if s.starts_with("--") => return Err(format!("unknown option {s} (see --help)")),
            _ => a.inputs.push(PathBuf::from(arg)),
        }
    }
    a.out = out.ok_or("--out DIR is required (see --help)")?;
    if a.inputs.is_empty() && a.oracle.is_empty() {
        return Err("no input: give mesh files or directories of frames, or --oracle files (see --help)".into());
    }
    Ok(a)
}

fn fail(msg: impl std::fmt::Display) -> ! {
    eprintln!("tradeoff: {msg}");
    std::process::exit(1);
}

fn main() {
    cli::exit_quietly_on_broken_pipe();
    let mut args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("tradeoff: {e}");
            std::process::exit(2);
        }
    };
    let tty = std::io::stderr().is_terminal();
    let last = std::cell::Cell::new(None::<Instant>);
    let progress = |msg: &str| {
        if tty {
            let mut err = std::io::stderr();
            let _ = write!(err, "\r\x1b[K{msg}");
            let _ = err.flush();
        } else if last.get().is_none_or(|t| t.elapsed().as_secs_f64() >= 2.0) {
            eprintln!("{msg}");
            last.set(Some(Instant::now()));
        }
    };
    let done_line = || {
        if tty {
            eprint!("\r\x1b[K");
        }
    };

    // Oracle results from files.
    let mut oracle: Vec<OracleRecord> = Vec::new();
    for f in &args.oracle {
        match meshchar::eval::record::read_jsonl(f) {
            Ok(v) => oracle.extend(v),
            Err(e) => fail(e),
        }
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
    for (i, p) in args.inputs.iter().enumerate() {
        progress(&format!("loading {}/{}: {}", i + 1, args.inputs.len(), p.display()));
        match meshchar::mesh::load_path(p) {
            Ok(s) => scenes.push(s),
            Err(e) => fail(e),
        }
    }
    done_line();

    // Workloads: those of the files, or measured here.
    let mut workloads: Vec<String> = Vec::new();
    for o in &oracle {
        if !workloads.iter().any(|w| w == o.workload.as_str()) {
            workloads.push(o.workload.as_str().to_string());
        }
    }
    if args.oracle.is_empty() {
        for &w in &args.workloads {
            for scene in &scenes {
                let config = OracleConfig {
                    workload: w,
                    resolution: args.oracle_resolution,
                    frames: scene.is_dynamic().then_some(args.oracle_frames),
                    rebuild: if scene.is_dynamic() { Rebuild::PerFrame } else { Rebuild::Once },
                    repeats: args.oracle_repeats,
                    ..OracleConfig::default()
                };
                let pr = |m: &str| {
                    progress(&format!("oracle ({} {}x{}): {m}", w.as_str(), config.resolution, config.resolution))
                };
                match evaluate_scene(scene, &config, None, &pr) {
                    Ok(e) => oracle.push(e.record()),
                    Err(e) => fail(e),
                }
            }
            workloads.push(w.as_str().to_string());
        }
        done_line();
    }

    // Backends: drop Vulkan with a note when there is no device.
    if args.grid.backends.contains(&Backend::Vulkan) {
        if let Err(e) = Characterizer::new(Some(Backend::Vulkan)) {
            eprintln!("tradeoff: note: no usable Vulkan device ({e}); measuring the CPU backends only");
            args.grid.backends.retain(|&b| b != Backend::Vulkan);
            if args.grid.backends.is_empty() {
                fail("no backend left to measure");
            }
        }
    }
    let settings = args.grid.settings();
    let thesis = ThesisPolicy::default();
    let model = if args.policy == "calibrated" {
        match CostModel::load(args.cost_model.as_deref()) {
            Ok(m) => Some(m),
            Err(e) => fail(format!("cost model: {e}")),
        }
    } else {
        None
    };
    let policy = match &model {
        Some(model) => Selector::Calibrated { model, tie_margin: args.tie_margin },
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
    let results = match tradeoff::sweep(&study, &mut engine_for, &progress) {
        Ok(r) => r,
        Err(e) => fail(e),
    };
    done_line();
    let tol = StatsTolerance::default();
    let suff = tradeoff::sufficiency(&results, &tol);

    if let Err(e) = std::fs::create_dir_all(&args.out) {
        fail(format!("{}: {e}", args.out.display()));
    }
    let write = |name: &str, text: &str| {
        let p = args.out.join(name);
        if let Err(e) = std::fs::write(&p, text) {
            fail(format!("{}: {e}", p.display()));
        }
        p
    };
    let mut written = Vec::new();
    for (name, chart) in tradeoff::charts(&results, &workloads) {
        written.push(write(&name, &chart.to_svg()));
    }
    let mut md = tradeoff::markdown(&results, &workloads, &suff);
    md.push_str("\n### Structures within noise of the oracle's best\n\n");
    md.push_str(&tradeoff::structures_markdown(&oracle, &workloads));
    written.push(write("tradeoff.md", &md));
    let json = serde_json::json!({
        "policy": policy.name(),
        "tie_margin": model.as_ref().map(|_| args.tie_margin),
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
    written.push(write("tradeoff.json", &json.to_string()));
    println!("{md}");
    println!("{} settings x {} scenes in {:.1} s; wrote:", settings.len(), scenes.len(), t0.elapsed().as_secs_f64());
    for p in written {
        println!("  {}", p.display());
    }
}
