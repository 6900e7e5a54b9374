//! Calibrates the cost model (`meshchar::cost`) on this machine: runs the oracle on a few synthetic and real scenes
//! at a small resolution (or reads cached oracle results), fits the per-structure constants, optionally fits the
//! refit model on animations, prints the constants and fit errors, and writes the calibration file.
//!
//! ```text
//! cargo run --release --example calibrate -- [--out FILE] [--from-oracle FILE.jsonl ...] [--scene PATH ...]
//!     [--resolution N] [--repeats R] [--refit DIR ...] [--device NAME] [--trace-backend cpu|vulkan]
//!     [--ridge R | --ridge-cv] [--tie-margin X] [--help]
//! ```
//!
//! `--ridge R` sets the shrinkage of the test-count laws; `--ridge-cv` chooses it, and whether the laws take the
//! crossings (`meshchar::cost::crossings_feature`), inside the samples by holding out each family (or each scene)
//! in turn (`meshchar::eval::compare::fit_ridge_by_cv`) and prints every candidate's held-out regret
//! (`--tie-margin` is the calibrated policy's tie margin those selections use; it matters only with `--ridge-cv`).
//! On the shipped 84 oracle records it chooses the default, 0.05.
//!
//! With `--trace-backend vulkan` the oracle traces on the Vulkan device (`evaluate_scene_on` with a
//! `DeviceOracle`) and the file records the device (name, type, driver, driver version, UUID), which the calibrated
//! policy matches to choose it. On a device with ray queries the oracle also measures the driver's acceleration
//! structures (`rt_fast_trace`, `rt_fast_build`, `rt_update`, `rt_fast_trace_compact`) and the file gets their
//! build, update and trace laws (`driver`, see `meshchar::cost::driver`); records with `driver_structures` do the
//! same with `--from-oracle`. `--from-oracle` files carry their tracer (`trace_backend`, `device`): records of
//! different backends or devices in one fit are refused.

use anyhow::Context as _;
use clap::Parser;
use cli::args::{self, TraceBackendArg};
use cli::Progress;
use meshchar::accel::driver::DriverFlags;
use meshchar::accel::lbvh::Lbvh;
use meshchar::accel::AccelStructure;
use meshchar::characterize::{features_cpu, Features, Params};
use meshchar::cost::drift;
use meshchar::cost::{CostModel, RefitModel};
use meshchar::eval::fit::Sample;
use meshchar::eval::oracle::{evaluate_scene_on, DeviceOracle, DeviceRecord, TraceBackend};
use meshchar::eval::record::{load_samples_admitted, tracer_of, SampleProbes};
use meshchar::eval::{OracleConfig, Rebuild};
use meshchar::geom::WorkloadKind;
use meshchar::mesh::{generate, Animation};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[path = "support/cli.rs"]
mod cli;

/// Fits the cost model's constants on this machine and writes a calibration file (JSON, versioned) that
/// characterize and evaluate load with --cost-model FILE.
///
/// Without --from-oracle, the oracle runs here on three synthetic scenes (random soup, clusters, teapot in a
/// stadium) and the --scene paths (default: four small shared meshes when ../shared/meshes exists), for the
/// primary, shadow and diffuse workloads at --resolution, about a minute in release.
#[derive(Parser, Debug)]
#[command(name = "calibrate", args_override_self = true)]
struct Args {
    /// Write the calibration file [default: print the constants only]
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Fit on cached `evaluate --json` lines instead of measuring (repeatable); the meshes are loaded from the
    /// recorded paths to compute their features
    #[arg(long = "from-oracle", value_name = "FILE")]
    oracle: Vec<PathBuf>,
    /// With --from-oracle: time probes of every structure on each record's scene and camera on this machine
    /// (meshchar::cost::timed) and store, per structure and kind of ray, the ratios of the records' times to the
    /// probes' in the file (`timed`): what lets the calibrated policy blend timed probes in (`characterize
    /// --timed-probes`). Run it on the machine the records were measured on
    #[arg(long, requires = "oracle")]
    timed_probes: bool,
    /// A real scene to measure (repeatable)
    #[arg(long = "scene", value_name = "PATH")]
    scenes: Vec<PathBuf>,
    /// Image side of the measurements
    #[arg(long, value_name = "N", default_value_t = 128, value_parser = args::resolution(1, 4096))]
    resolution: u32,
    /// Repeats per measurement (at most 10,000)
    #[arg(long, value_name = "R", default_value_t = 1, value_parser = args::repeats())]
    repeats: usize,
    /// An animation (directory of frames) for the refit model (repeatable) [default: the BART animations under
    /// ../shared/meshes/bart when present]
    #[arg(long, value_name = "DIR")]
    refit: Vec<PathBuf>,
    /// Do not fit the refit model
    #[arg(long)]
    no_refit: bool,
    /// Device name stored in the file [default: the CPU, or the Vulkan device with --trace-backend vulkan]
    #[arg(long, value_name = "NAME")]
    device: Option<String>,
    /// Ridge on the test-count laws' coefficients (meshchar::cost::RIDGE by default): larger values shrink the
    /// geometric and view coefficients towards the size-only model
    #[arg(long, value_name = "R", default_value_t = meshchar::cost::RIDGE, value_parser = args::nonnegative_number)]
    ridge: f64,
    /// Choose the ridge, and whether the count laws take the crossings, by cross-validation inside the samples
    /// instead (meshchar::eval::compare::fit_ridge_by_cv: each family, or each scene when the samples span fewer
    /// than 3 families, held out in turn; the candidate whose held-out selections have the least mean regret);
    /// prints each candidate's held-out regret
    #[arg(long, conflicts_with = "ridge")]
    ridge_cv: bool,
    /// The calibrated policy's tie margin used to score held-out selections (choosing the prior's shrinkage, and with
    /// --ridge-cv the ridge)
    #[command(flatten)]
    tie: args::TieMarginArg,
    /// With --from-oracle the records' own tracer is used (vulkan here refuses CPU records)
    #[command(flatten)]
    trace_backend: TraceBackendArg,
}

fn shared() -> PathBuf {
    PathBuf::from("..").join("shared").join("meshes")
}

fn samples_from_oracle(files: &[PathBuf], timed: bool) -> anyhow::Result<Vec<Sample>> {
    let bar = Progress::new("features", None, false);
    let probes = SampleProbes { timed, measured: false };
    let samples = load_samples_admitted(files, &Params::default(), probes, &cli::admit_record_scene, &|m| {
        bar.step(m);
        bar.eprintln(&format!("calibrate: features of {m}"));
    })?;
    Ok(samples)
}

fn measure(args: &Args, device: Option<&DeviceOracle<'_>>, ray_query: bool) -> anyhow::Result<Vec<Sample>> {
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
        scenes.push(cli::load_path_checked(p)?);
    }
    let mut out = Vec::new();
    let kinds = [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse];
    let bar = Progress::new("oracle", Some(scenes.len() * kinds.len()), false);
    for (i, scene) in scenes.iter().enumerate() {
        let first = scene.frames.first().with_context(|| format!("{}: no frames", scene.name))?;
        bar.item(i * kinds.len(), 1, &format!("{}: features", scene.name));
        let f = features_cpu(first, &Params::default()).with_context(|| scene.name.clone())?;
        for (j, kind) in kinds.into_iter().enumerate() {
            let config = OracleConfig {
                workload: kind,
                resolution: args.resolution,
                repeats: args.repeats,
                rebuild: if scene.is_dynamic() { Rebuild::PerFrame } else { Rebuild::Once },
                driver: if device.is_some() && ray_query { DriverFlags::ALL.to_vec() } else { Vec::new() },
                ..OracleConfig::default()
            };
            // Steps: per frame the reference and every structure at every repeat.
            bar.item(i * kinds.len() + j, scene.frames.len() * (1 + config.repeats * config.structures.len()), "");
            let t = Instant::now();
            let e = evaluate_scene_on(scene, &config, None, &|m| bar.step(&format!("{} {m}", kind.as_str())), device)?;
            bar.eprintln(&format!("calibrate: {} {}: {:.1} s", scene.name, kind.as_str(), t.elapsed().as_secs_f64()));
            out.push(e.record().sample(f.clone(), None));
        }
    }
    Ok(out)
}

/// SAH of a refitted frame-0 LBVH against a fresh LBVH per frame, and refit time per triangle.
fn fit_refit(dirs: &[PathBuf]) -> anyhow::Result<Option<RefitModel>> {
    let (mut xs, mut ys, mut ns_per_tri) = (Vec::new(), Vec::new(), Vec::new());
    let bar = Progress::new("refit", Some(dirs.len()), false);
    for (k, dir) in dirs.iter().enumerate() {
        bar.item(k, 1, &format!("loading {}", dir.display()));
        let anim = cli::load_path_checked(dir)?;
        if anim.frames.len() < 2 {
            continue;
        }
        // Steps: the features of every frame, then every frame after the first.
        bar.item(k, 2 * anim.frames.len() - 1, &anim.name);
        let feats: Vec<Features> = anim
            .frames
            .iter()
            .map(|m| {
                bar.step(&format!("{}: features of {}", anim.name, m.name));
                features_cpu(m, &Params::default())
            })
            .collect::<Result<_, _>>()?;
        let mut tree = Lbvh::build(&anim.frames[0])?.into_tree();
        for (i, m) in anim.frames.iter().enumerate().skip(1) {
            bar.step(&format!("{}: frame {i}/{}", anim.name, anim.frames.len() - 1));
            let t = Instant::now();
            tree.refit(m)?;
            ns_per_tri.push(t.elapsed().as_secs_f64() * 1e9 / m.triangle_count().max(1) as f64);
            let fresh = Lbvh::build(m)?.tree().sah_cost();
            let ratio = tree.sah_cost() / fresh.max(f64::MIN_POSITIVE);
            let d = drift(&feats[0], &feats[i]);
            bar.eprintln(&format!("calibrate: {} frame {i}: drift {d:.4}, SAH refit / fresh {ratio:.3}", anim.name));
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

fn run(args: Args) -> anyhow::Result<()> {
    let args = &args;
    let t = Instant::now();
    // The tracer of the calibration: the records' (one backend and device for all of them), or this machine's.
    let (backend, record, samples): (TraceBackend, Option<DeviceRecord>, Vec<Sample>) = if args.oracle.is_empty() {
        let ctx = args.trace_backend.context()?;
        let oracle = match &ctx {
            Some(c) => Some(DeviceOracle::new(c).context("device traversal")?),
            None => None,
        };
        let ray_query = ctx.as_ref().is_some_and(|c| c.caps().ray_query);
        let samples = measure(args, oracle.as_ref(), ray_query)?;
        (args.trace_backend.trace_backend, args::device_record(ctx.as_ref()), samples)
    } else {
        let tracer = tracer_of(&args.oracle)?.context("--from-oracle: the files hold no record")?;
        if args.trace_backend.trace_backend == TraceBackend::Vulkan && tracer.backend != TraceBackend::Vulkan {
            anyhow::bail!(
                "--trace-backend vulkan, but the --from-oracle records were traced with {}",
                tracer.describe()
            );
        }
        if tracer.backend == TraceBackend::Vulkan && tracer.device.is_none() {
            anyhow::bail!("--from-oracle: the records were traced with vulkan but name no device");
        }
        let samples = samples_from_oracle(&args.oracle, args.timed_probes)?;
        (tracer.backend, tracer.device, samples)
    };
    let device = args.device.clone().unwrap_or_else(|| match &record {
        Some(d) => d.name.clone(),
        None => meshchar::characterize::cpu::cpu_device_name(rayon::current_num_threads()),
    });
    let source = if args.oracle.is_empty() {
        format!(
            "calibrate: oracle at {}x{}, {} repeat(s), {} samples, traced with {}",
            args.resolution,
            args.resolution,
            args.repeats,
            samples.len(),
            backend.as_str()
        )
    } else {
        format!(
            "calibrate --from-oracle {}",
            args.oracle.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" ")
        )
    };
    let source = if args.ridge == meshchar::cost::RIDGE { source } else { format!("{source}, ridge {}", args.ridge) };
    let mut model = if args.ridge_cv {
        let cv = meshchar::eval::compare::fit_ridge_by_cv(&samples, &device, &source, args.tie.tie_margin)?;
        for (r, crossings, regret) in &cv.inner_regret {
            let with = if *crossings { ", with the crossings" } else { "" };
            eprintln!("ridge {r}{with}: mean regret held out by {} {:.1}%", cv.groups, 100.0 * regret);
        }
        eprintln!("chosen ridge: {}{}", cv.ridge, if cv.crossings { ", with the crossings" } else { "" });
        cv.model
    } else {
        CostModel::fit_with_ridge(&samples, &device, &source, args.ridge)?
    };
    model.trace_backend = backend;
    model.trace_device = record;
    // What the selection's ladder weighs: the model's own held-out errors at each level (each family, or each
    // scene, predicted by the same fit on the others) and the laws of what each decision stage took here.
    let (ridge, crossings) = if args.ridge_cv {
        (model_ridge(&model), model.structures.iter().any(|s| !s.crossing_coef.is_empty()))
    } else {
        (args.ridge, false)
    };
    // The prior's own count laws, with the shrinkage under which the prior alone chooses best held out.
    let (prior_ridge, prior_scores) = meshchar::eval::fit::choose_prior_ridge(&samples, &device, args.tie.tie_margin);
    for (r, regret) in &prior_scores {
        let name = r.map_or_else(|| "size only".to_string(), |r| format!("ridge {r}"));
        eprintln!("prior, {name}: mean regret held out {:.1}%", 100.0 * regret);
    }
    model = model.with_prior(&samples, prior_ridge)?.with_size(&samples)?;
    model.uncertainty = meshchar::eval::fit::fit_uncertainty(&samples, &|t| {
        CostModel::fit_with(t, &device, "held out", ridge, crossings)?.with_prior(t, prior_ridge)?.with_size(t)
    });
    model.inquiry_costs = meshchar::eval::fit::fit_inquiry_costs(&samples);
    if backend == TraceBackend::Vulkan && samples.iter().any(|s| !s.driver.is_empty()) {
        model.fit_driver(&samples)?;
    }
    model.validate()?;
    if !args.no_refit {
        let mut dirs = args.refit.clone();
        if dirs.is_empty() && shared().join("bart").is_dir() {
            for d in ["museum5", "robots", "kitchen"] {
                dirs.push(shared().join("bart").join(d));
            }
        }
        model.refit = fit_refit(&dirs)?;
    }
    if let Some(t) = &model.timed {
        println!("timed-probe ratios (records' time / probe's, median over {} records):", t.records);
        let f = |x: Option<f64>| x.map_or_else(|| "-".into(), |x| format!("{x:.3}"));
        for r in &t.structures {
            println!(
                "  {:<7} build {}  ns/ray: primary {}, shadow {}, diffuse {}",
                r.structure.as_str(),
                f(r.build),
                f(r.trace[0]),
                f(r.trace[1]),
                f(r.trace[2])
            );
        }
    }
    println!(
        "cost model: device {}, {} samples, {} scenes; total fit error {:.1}% RMS (log)",
        model.device,
        samples.len(),
        model.scenes.len(),
        100.0 * model.total_rms_log
    );
    println!(
        "{:<7} {:>8} {:>6} {:>6} | ns: {:>6} {:>6} {:>6} {:>5} {:>5} {:>5} {:>5} {:>5} | RMS log error: {:>6} {:>6} {:>6} {:>7} {:>6} {:>6}",
        "", "ln a", "b", "d", "ray/p", "ray/s", "ray/d", "box", "tri", "box+", "tri+", "tst+ln", "build", "box", "tri", "tr|cnt", "trace", "total"
    );
    for s in &model.structures {
        println!(
            "{:<7} {:>8.3} {:>6.3} {:>6.3} |     {:>6.1} {:>6.1} {:>6.1} {:>5.2} {:>5.2} {:>5.2} {:>5.2} {:>6.2} |                {:>6.3} {:>6.3} {:>6.3} {:>7.3} {:>6.3} {:>6.3}",
            s.structure.as_str(),
            s.build_ln_a,
            s.build_exponent,
            s.build_curvature,
            s.trace_price[0],
            s.trace_price[1],
            s.trace_price[2],
            s.trace_price[3],
            s.trace_price[4],
            s.trace_price[5],
            s.trace_price[6],
            s.trace_price[7],
            s.fit.build,
            s.fit.box_tests,
            s.fit.prim_tests,
            s.fit.trace_given_counts,
            s.fit.trace,
            s.fit.total
        );
    }
    let work: Vec<_> = model.structures.iter().filter(|s| s.build_work_coef.len() >= 3).collect();
    if !work.is_empty() {
        println!(
            "{:<7} {:>8} {:>6} {:>6} {:>6} | RMS log error: build by work (by n alone)",
            "work", "ln a'", "b'", "c'", "d'"
        );
        for s in work {
            let c = &s.build_work_coef;
            println!(
                "{:<7} {:>8.3} {:>6.3} {:>6.3} {:>6.3} |                {:>6.3} ({:.3})",
                s.structure.as_str(),
                c[0],
                c[1],
                c[2],
                c.get(3).copied().unwrap_or(0.0),
                s.fit.build_work,
                s.fit.build
            );
        }
    }
    match &model.trace_device {
        Some(d) => println!(
            "traced with {} on {} ({}, {}, driver version {}, UUID {})",
            model.trace_backend.as_str(),
            d.name,
            d.device_type,
            d.driver,
            d.driver_version,
            d.device_uuid
        ),
        None => println!("traced with {}", model.trace_backend.as_str()),
    }
    if !model.driver.is_empty() {
        println!(
            "{:<22} {:>8} {:>6} | {:>8} {:>6} {:>7} | RMS log error: {:>6} {:>6} {:>6} | samples",
            "driver", "ln a", "b", "upd ln a", "upd b", "g/drift", "build", "trace", "total"
        );
        for d in &model.driver {
            let u = d.update;
            let opt = |x: Option<f64>, w: usize, p: usize| x.map_or(format!("{:>w$}", "-"), |x| format!("{x:>w$.p$}"));
            println!(
                "{:<22} {:>8.3} {:>6.3} | {} {} {} |                {:>6.3} {:>6.3} {:>6.3} | {}",
                d.name,
                d.build_ln_a,
                d.build_exponent,
                opt(u.map(|u| u.update_ln_a), 8, 3),
                opt(u.map(|u| u.update_exponent), 6, 3),
                opt(u.map(|u| u.trace_growth_per_drift), 7, 3),
                d.fit.build,
                d.fit.trace,
                d.fit.total,
                d.fit.samples
            );
        }
    }
    if let Some(u) = &model.uncertainty {
        println!(
            "held-out errors of the totals (RMS log, by {}): prior | crossings | probed | timed | measured",
            u.holdout
        );
        let f = |x: Option<f64>| x.map_or_else(|| "-".into(), |x| format!("{x:.3}"));
        for x in &u.structures {
            println!(
                "  {:<7} {:.3} | {:.3} | {:.3} | {} | {}  ({} samples)",
                x.structure.as_str(),
                x.prior,
                x.crossings,
                x.probed,
                f(x.timed),
                f(x.measured),
                x.samples
            );
        }
    }
    for c in &model.inquiry_costs {
        println!(
            "inquiry {:<14} ms = exp({:.3}) n^{:.3} (RMS log {:.3}, {} samples): {:.3} ms at 100K triangles",
            c.stage,
            c.ln_a,
            c.exponent,
            c.rms,
            c.samples,
            c.ms(100_000)
        );
    }
    if let Some(r) = &model.refit {
        println!(
            "refit: SAH(refit)/SAH(fresh) = 1 + {:.3} * drift (RMS {:.3}, {} frame pairs); refit {:.1} ns/triangle",
            r.sah_growth_per_drift, r.fit_rms, r.samples, r.refit_ns_per_triangle
        );
    }
    if let Some(out) = &args.out {
        model.save(out)?;
        println!("wrote {}", out.display());
    }
    eprintln!("calibrate: {:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

/// The ridge a cross-validated fit chose, as its source names it (`..., ridge R ...`), else the default.
fn model_ridge(model: &CostModel) -> f64 {
    model
        .source
        .split(", ridge ")
        .nth(1)
        .and_then(|r| r.split([' ', ',']).next())
        .and_then(|r| r.parse().ok())
        .unwrap_or(meshchar::cost::RIDGE)
}

fn main() -> ExitCode {
    cli::main_with(run)
}
