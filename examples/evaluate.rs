//! The measurement oracle on the command line: for each scene, build and trace every acceleration structure and
//! report the ground-truth best, the regret of the selection, and per structure build and trace times, Mrays/s,
//! tests per ray and memory.
//!
//! ```text
//! cargo run --release --example evaluate -- [FILE|DIR ...] [--json] [--workload primary|shadow|diffuse]
//!     [--resolution N] [--frames F] [--repeats R] [--precision FRACTION] [--max-repeats R] [--precision-ms MS] [--rebuild once|frame] [--structures bvh,kdtree,...]
//!     [--camera EX,EY,EZ,TX,TY,TZ[,FOV]] [--charts DIR] [--policy thesis|calibrated] [--cost-model FILE]
//!     [--budget-references-per-triangle R] [--budget-min-references N] [--budget-bytes BYTES]
//!     [--budget-grid-references-per-triangle R] [--budget-grid-min-references N]
//!     [--tie-margin X] [--oracle-cache FILE] [--trace-backend cpu|vulkan] [--max-tests-per-ray TESTS] [--help]
//! cargo run --release --example evaluate -- --compare-policies FILE.jsonl ... [--charts DIR] [--json]
//!     [--frames-sweep F,F,...] [--proxy]
//! ```
//!
//! With `--compare-policies`, nothing is measured: the cached oracle results are read back, the thesis policy's
//! recorded selections and the calibrated policy (fitted on all scenes, and leave-one-scene-out) are scored side by
//! side, then against the baselines (`meshchar::eval::compare::compare_baselines`): the best single structure per
//! workload, the size-only model, the calibrated model and the calibrated model with its ridge chosen inside each
//! training set (`calibrated_cv`), each held out by scene and, over several families, by family; each with its mean
//! regret and its regret beyond the oracle's noise. `--proxy` adds the deterministic proxy (`meshchar::eval::proxy`):
//! two per-test prices are measured in isolation (milliseconds), and the policies are scored again with every trace
//! time replaced by the counted tests times those prices.

use anyhow::Context as _;
use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::Parser;
use cli::args::{self, BudgetArgs, JsonArg, Policy, PolicyArgs, TieMarginArg, WorkloadArgs};
use cli::Progress;
use meshchar::accel::driver::DriverFlags;
use meshchar::accel::{AccelStructure, StructureName};
use meshchar::characterize::{Characterizer, Params};
use meshchar::cost::{CostModel, Prediction};
use meshchar::eval::chart::BarChart;
use meshchar::eval::compare::{compare, score, PolicyScore};
use meshchar::eval::oracle::{evaluate_scene_on, DeviceOracle, RefitCandidate, TraceBackend};
use meshchar::eval::proxy::{agreement, proxied, Agreement, TestPrices};
use meshchar::eval::record::{load_samples_admitted, tracer_of, SampleProbes};
use meshchar::eval::{OracleConfig, Rebuild, SceneEvaluation};
use meshchar::geom::Camera;
use meshchar::geom::WorkloadKind;
use meshchar::mesh::Animation;
use meshchar::select::{Budget, Decision, PolicyKind, Scene, Selector, TargetWorkload};
use meshchar::trace::views::View;
use meshchar::trace::workload::{build_workload, mesh_bounds};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[path = "support/cli.rs"]
mod cli;

/// The measurement oracle: for each scene (a mesh file, or a directory of frame files forming an animation), build
/// and trace every acceleration structure, and print the oracle's best structure, the regret of the selection, and
/// per structure: build ms, trace ms, total ms (with its noise), Mrays/s, box and triangle tests per ray, memory,
/// SAH cost.
///
/// With --compare-policies, nothing is measured: the cached oracle results are read back, and the thesis policy's
/// recorded selections and the calibrated policy (fitted on all scenes, and leave-one-scene-out) are scored side by
/// side.
#[derive(Parser, Debug)]
#[command(name = "evaluate", args_override_self = true)]
#[command(mut_arg("json", |a| a.help("One JSON object per scene per line instead of tables")))]
#[command(mut_arg("resolution", |a| a.help("N x N primary rays per frame (1024: as in the thesis)")))]
#[command(mut_arg("policy", |a| a.help("The selection policy whose choice is `selected` and `regret`")))]
struct Args {
    /// Mesh files, directories of frame files (animations), or generated scenes (family:NAME:TRIANGLES[:SEED],
    /// degenerate:NAME:TRIANGLES[:SEED])
    #[arg(value_name = "FILE|DIR", required_unless_present = "compare_policies")]
    inputs: Vec<PathBuf>,
    #[command(flatten)]
    json: JsonArg,
    #[command(flatten)]
    workload: WorkloadArgs,
    /// Frames rendered (static scene) or frames used (animation) [default: 1 for a static scene, all of an
    /// animation]
    #[arg(long, value_name = "F", value_parser = args::positive())]
    frames: Option<usize>,
    /// Repeats of every measurement (at most 10,000); medians are reported
    #[arg(long, value_name = "R", default_value_t = 3, value_parser = args::repeats())]
    repeats: usize,
    /// The precise oracle: repeat every structure (at least --repeats times, in rounds of all of them) until the
    /// 95% confidence interval of each one's median total lies within this fraction of the median (0.02: +-2%), or
    /// --max-repeats rounds; "within noise" then means overlapping intervals [default: exactly --repeats repeats]
    #[arg(long, value_name = "FRACTION", value_parser = args::alpha)]
    precision: Option<f64>,
    /// The most rounds under --precision (more with --precision-ms; at most 10,000)
    #[arg(long, value_name = "R", default_value_t = meshchar::eval::oracle::DEFAULT_MAX_REPEATS,
          value_parser = args::repeats())]
    max_repeats: usize,
    /// Under --precision, go on past --max-repeats (up to 500 rounds) while a structure is short of the target and
    /// the builds and traces measured so far (one frame's) sum to under MS milliseconds: cheap records repeated
    /// until precise
    #[arg(long, value_name = "MS", default_value_t = 0.0, requires = "precision",
          value_parser = args::nonnegative_number)]
    precision_ms: f64,
    /// Build once (static scenes, the default) or every frame (the default for animations)
    #[arg(long, value_name = "once|frame", value_parser = rebuild())]
    rebuild: Option<Rebuild>,
    /// Comma-separated subset of bvh,kdtree,grid,bih,lbvh,hlbvh and the driver's acceleration structures
    /// rt_fast_trace,rt_fast_build,rt_update,rt_fast_trace_compact (ray queries: --trace-backend vulkan on a device
    /// with VK_KHR_ray_query) [default: the six project structures]
    #[arg(long, value_name = "LIST", value_delimiter = ',', value_parser = candidate)]
    structures: Vec<Candidate>,
    /// Eye, target (and vertical field of view in degrees, default 45); +y is up [default: a camera framing the
    /// scene]
    #[arg(long, value_name = "EX,EY,EZ,TX,TY,TZ[,FOV]", allow_hyphen_values = true, value_parser = args::camera)]
    camera: Option<Camera>,
    /// A camera preset computed from the scene's bounds: framing (the whole scene from outside), inside (the eye
    /// inside the bounds), close-up (near the centre, narrow field of view) or grazing (nearly parallel to the
    /// dominant plane); the record's `view` names it
    #[arg(long, value_name = "PRESET", conflicts_with = "camera", value_parser = args::view)]
    view: Option<View>,
    /// Write SVG bar charts (build time, frame rate, tests per ray) into DIR; with --compare-policies, the
    /// per-scene regret charts policy-regret-<workload>.svg
    #[arg(long, value_name = "DIR")]
    charts: Option<PathBuf>,
    #[command(flatten)]
    policy: PolicyArgs,
    #[command(flatten)]
    budget: BudgetArgs,
    #[command(flatten)]
    decision: cli::args::DecisionArgs,
    /// The characterization backend of the decision (timed warm: decision_ms) [default: vulkan when a device is
    /// found, else cpu]
    #[command(flatten)]
    backend: cli::args::BackendArg,
    #[command(flatten)]
    tie_margin: TieMarginArg,
    /// Append every scene's JSON line to FILE (to compare policies later without measuring)
    #[arg(long, value_name = "FILE")]
    oracle_cache: Option<PathBuf>,
    /// Read cached oracle JSON lines (one or more files; repeatable) and compare the thesis policy's recorded selections with the
    /// calibrated policy, in sample and leave-one-scene-out; measures nothing (meshes are loaded from the recorded
    /// paths for their features)
    #[arg(long, value_name = "FILE", num_args = 1..)]
    compare_policies: Vec<PathBuf>,
    /// With --compare-policies: every static scene measured over one frame also stands for F frames with one build
    /// (each structure's total: its build plus F times its trace, the oracle's own formula), for each F listed, so
    /// that the policies are scored where the build amortizes (for instance 1,10,100,1000)
    #[arg(long, value_name = "F,F,...", value_parser = args::list(clap::value_parser!(u64).range(1..)))]
    frames_sweep: Option<args::List<u64>>,
    /// (With --compare-policies, --cost-model FILE adds that calibration as it is, not refitted, scored on the
    /// records, over all of them and per workload: how a calibration fitted on other scenes does on these; with
    /// --json, a line {"fixed_cost_model": {"file", "score", "timed_score", "measured_score", "by_workload"}}.)
    ///
    /// With --compare-policies: also score the policies against the deterministic proxy (every structure's counted
    /// box and triangle tests times per-test prices measured in isolation on this machine, the builds as measured)
    /// and print how well the proxy agrees with the measured truth (meshchar::eval::proxy); with --json, a second
    /// line {"proxy": {"prices", "agreement", "comparison"}}
    #[arg(long, requires = "compare_policies")]
    proxy: bool,
    /// With --compare-policies: time probes of every structure on each record's scene and camera on this machine
    /// (meshchar::cost::timed: one build and the fastest of a few single-threaded traces of 64 x 64 sample rays per
    /// kind) and add the policy `calibrated_timed`: the held-out `calibrated_cv` models with the probes' times
    /// blended into their predictions, the ratios fitted on the training records. Not deterministic: the probes are
    /// timed anew on every run
    #[arg(long, requires = "compare_policies")]
    timed_probes: bool,
    /// With --compare-policies: measure anew, on this machine, whole frames of every static record's workload
    /// through every structure (four builds and traced frames each, the first untimed, meshchar::cost::measured;
    /// minutes on the scene families) and add the policy `calibrated_measured`: the held-out choices (with --timed-probes, the
    /// timed ones) with their close call (structures predicted within 20% of the least) settled by those frames,
    /// as `characterize --measure-close-calls` settles it. Not deterministic
    #[arg(long, requires = "compare_policies")]
    measure_close_calls: bool,
    /// With --compare-policies: a second run of the oracle over the same scenes, workloads and cameras (JSONL
    /// oracle records, repeatable; every record of --compare-policies must have its match there); adds the policy
    /// `repeat_oracle`: each record's best by the second run, scored on the first. Its regret is the oracle's own
    /// noise, the floor under any policy that measures
    #[arg(long, value_name = "FILE", requires = "compare_policies", conflicts_with = "frames_sweep")]
    repeat_oracle: Vec<PathBuf>,
    /// Where the rays are traced: `cpu` (the counting CPU tracer, host wall time) or `vulkan` (the device traversal
    /// kernel on the Vulkan device, GPU timestamps; structures are built on the host and uploaded, the upload
    /// timed apart; every ray's hit is checked against the CPU reference). MESHCHAR_DEVICE picks the device
    #[arg(long, value_name = "cpu|vulkan", default_value = "cpu", value_parser = trace_backend)]
    trace_backend: TraceBackend,
    /// The trace budget: a structure whose box and triangle tests per ray, on a sample of 1,024 of the rays, exceed
    /// this is reported as failed instead of traced (a reference over it fails the scene); coincident copies of
    /// many triangles make every ray test them all
    #[arg(long, value_name = "TESTS", default_value_t = meshchar::eval::oracle::DEFAULT_MAX_TESTS_PER_RAY,
          value_parser = args::positive_number)]
    max_tests_per_ray: f64,
}

/// A name in `--structures`: one of the project's structures or a driver acceleration structure.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Candidate {
    Ours(StructureName),
    Driver(DriverFlags),
    Refit(RefitCandidate),
}

/// `--structures` item.
fn candidate(s: &str) -> Result<Candidate, String> {
    if let Some(f) = DriverFlags::parse(s.trim()) {
        return Ok(Candidate::Driver(f));
    }
    if let Some(r) = RefitCandidate::parse(s.trim()) {
        return Ok(Candidate::Refit(r));
    }
    args::structure(s).map(Candidate::Ours).map_err(|e| {
        format!(
            "{e} (or a driver structure: rt_fast_trace, rt_fast_build, rt_update, rt_fast_trace_compact; or a refit \
             candidate: bvh_refit, lbvh_refit)"
        )
    })
}

/// `--trace-backend`: `cpu` or `vulkan`.
fn trace_backend(s: &str) -> Result<TraceBackend, String> {
    s.parse()
}

impl Args {
    /// The oracle's configuration (its `rebuild` set per scene).
    fn config(&self) -> OracleConfig {
        let default = OracleConfig::default();
        OracleConfig {
            workload: self.workload.workload,
            resolution: self.workload.resolution,
            frames: self.frames,
            repeats: self.repeats,
            structures: if self.structures.is_empty() {
                default.structures.clone()
            } else {
                self.structures
                    .iter()
                    .filter_map(|c| match c {
                        Candidate::Ours(n) => Some(*n),
                        _ => None,
                    })
                    .collect()
            },
            driver: self
                .structures
                .iter()
                .filter_map(|c| match c {
                    Candidate::Driver(f) => Some(*f),
                    _ => None,
                })
                .collect(),
            // Refit candidates: as listed, or both for an animation when nothing is listed (set per scene).
            refit: self
                .structures
                .iter()
                .filter_map(|c| match c {
                    Candidate::Refit(r) => Some(*r),
                    _ => None,
                })
                .collect(),
            camera: self.camera,
            max_tests_per_ray: self.max_tests_per_ray,
            precision: self.precision,
            max_repeats: self.max_repeats,
            precision_ms: self.precision_ms,
            ..default
        }
    }
}

/// `--rebuild`: `once`, or `frame` (also `per-frame`, `every`).
fn rebuild() -> impl TypedValueParser<Value = Rebuild> {
    PossibleValuesParser::new([PossibleValue::new("once"), PossibleValue::new("frame").aliases(["per-frame", "every"])])
        .map(|s| if s == "once" { Rebuild::Once } else { Rebuild::PerFrame })
}

/// Loads a mesh file as a one-frame scene, or a directory of `.obj`/`.ply` frames (sorted by name) as an animation.
fn load_scene(path: &Path) -> anyhow::Result<Animation> {
    cli::load_path_checked(path)
}

/// A selection (the project's structure and the overall candidate, a driver structure's name when the policy chose
/// one), its reasons, and the calibrated policy's predictions.
/// The policy's selection and what deciding cost.
struct Selected {
    structure: StructureName,
    candidate: &'static str,
    reasons: Vec<meshchar::select::Reason>,
    predicted: Option<Vec<Prediction>>,
    level: Option<meshchar::select::Level>,
    /// The decision as an engine calls it (characterization, features, selection), warm, this process, ms.
    decision_ms: f64,
}

/// The policy's selection for a scene: every frame characterized (Vulkan when a device is found, else the CPU
/// path) and its features computed; then the thesis policy over the frames, or the calibrated policy for the
/// workload of `config` (rays per frame counted by generating the workload's rays as the oracle will). The whole
/// decision runs twice and the second is timed: what an engine that decides again pays, warm.
#[allow(clippy::too_many_arguments)]
fn select(
    engine: &mut Characterizer,
    scene: &Animation,
    config: &OracleConfig,
    policy: Policy,
    model: &CostModel,
    tie_margin: f64,
    budget: Budget,
    decision: &cli::args::DecisionArgs,
) -> anyhow::Result<Selected> {
    let workload = TargetWorkload {
        kind: config.workload,
        rays_per_frame: if policy == Policy::Thesis { 0 } else { rays_per_frame(scene, config)? },
        frames: config.frames.unwrap_or(1) as u64,
        animation_frames: config.frames,
        // The oracle measures driver structures: the calibrated policy weighs them too.
        driver: !config.driver.is_empty(),
        // The engine's view, when the command line names one (else the oracle frames the scene, as the policy
        // assumes without a camera).
        camera: config.camera,
    };
    let mut selector = Selector::new(model, workload);
    selector.policy = match policy {
        Policy::Thesis => PolicyKind::Thesis,
        Policy::Calibrated => PolicyKind::Calibrated,
    };
    selector.budget = budget;
    selector.tie_margin = tie_margin;
    selector.inquiry = decision.level;
    selector.decision_budget = decision.decision_budget;
    selector.resolution = config.resolution;
    // As an engine decides: a static scene asks the size rung first, and characterizes only when it pays.
    let by_size = |selector: &Selector<'_>| match &scene.frames[..] {
        [only] => selector.size_rung(only.triangle_count() as u64).is_some_and(|r| !r.characterize),
        _ => false,
    };
    let run = |engine: &mut Characterizer| -> anyhow::Result<(Decision, f64)> {
        let t = std::time::Instant::now();
        let sized = by_size(&selector);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let (chars, features) = engine.characterize_animation_with_features(scene, &Params::default())?;
        let d = selector.select(&Scene {
            name: &scene.name,
            characterizations: &chars,
            features: &features,
            meshes: &scene.frames,
        });
        // Decided by size: the decision was the rung alone (the characterization above only fills the report).
        Ok((d, if sized { ms } else { t.elapsed().as_secs_f64() * 1e3 }))
    };
    run(engine)?;
    let (d, decision_ms) = run(engine)?;
    let level = (d.policy == PolicyKind::Calibrated).then_some(d.level);
    let sel = d.selection;
    Ok(Selected {
        structure: sel.structure,
        candidate: sel.candidate(),
        reasons: sel.reasons,
        predicted: d.predicted,
        level,
        decision_ms,
    })
}

/// Rays per frame of the oracle's workload on the first frame: `resolution^2` primary rays, or the secondary rays
/// generated from their hits (same camera and reference structure as the oracle, untimed).
fn rays_per_frame(scene: &Animation, config: &OracleConfig) -> anyhow::Result<u64> {
    let n = config.resolution as u64 * config.resolution as u64;
    if config.workload == WorkloadKind::Primary {
        return Ok(n);
    }
    let first = scene.frames.first().context("no frames")?;
    let f =
        if scene.is_dynamic() { config.frames.unwrap_or(scene.frames.len()).clamp(1, scene.frames.len()) } else { 1 };
    let camera = config.camera.unwrap_or_else(|| {
        let b = scene.frames[..f].iter().fold(meshchar::geom::Aabb::EMPTY, |a, m| a.union(&mesh_bounds(m)));
        Camera::frame(&b)
    });
    let reference = meshchar::accel::bvh::Bvh::build(first)?;
    Ok(build_workload(config.workload, first, &camera, config.resolution, &reference).rays.len() as u64)
}

fn fmt_opt(v: Option<f64>, prec: usize) -> String {
    v.map(|x| format!("{x:.prec$}")).unwrap_or_else(|| "null".into())
}

fn print_table(e: &SceneEvaluation) {
    println!(
        "\n{}  ({} triangles, {} frame(s) measured, totals for {} frame(s), {} rays {}x{}, {} rays/frame, repeats: {})",
        e.mesh,
        e.triangles,
        e.frames_measured,
        e.frames,
        e.workload.as_str(),
        e.resolution,
        e.resolution,
        e.rays_per_frame,
        match e.precision {
            Some(p) => format!("at least {}, to a 95% interval within ±{}%", e.repeats, 100.0 * p),
            None => e.repeats.to_string(),
        }
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
    println!("  reference hits: {} rays over {} frame(s)", e.reference_hits, e.frames_measured);
    if let Some(d) = &e.device {
        println!(
            "  traced on the device: {} ({}, {}); trace ms are GPU timestamps; build ms: lbvh, hlbvh and grid \
             built on the device (timestamps; build_backend says where), the others on the host plus the upload; \
             every ray's hit checked against the CPU reference",
            d.name, d.device_type, d.driver
        );
    }
    if let Some(why) = &e.no_best_reason {
        println!("  no best structure: {why}");
    }
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
        if let Some([lo, hi]) = s.total_ms.ci95 {
            let m = s.total_ms.median.max(f64::MIN_POSITIVE);
            println!(
                "          total 95% interval [{lo:.2}, {hi:.2}] ms (-{:.1}% +{:.1}%), {} repeats{}",
                100.0 * (1.0 - lo / m),
                100.0 * (hi / m - 1.0),
                s.total_ms.samples,
                match s.precision_met {
                    Some(false) => ", precision not met (--max-repeats, --precision-ms)",
                    _ => "",
                }
            );
        }
        if let Some(err) = &s.error {
            println!("          error: {err}");
        }
    }
    if !e.driver_structures.is_empty() {
        println!(
            "  driver acceleration structures (ray queries; GPU timestamps; no test counts: the driver exposes none):"
        );
        println!(
            "  {:<22} {:>10} {:>10} {:>18} {:>9} {:>10} {:>10} {:>5} {:>5}",
            "", "build ms", "trace ms", "total ms", "Mrays/s", "memory MB", "compact MB", "valid", "agree"
        );
        if let Some(b) = &e.best_candidate {
            println!("  best of all candidates (the project's and the driver's): {b}");
        }
        for d in &e.driver_structures {
            if let (Some(err), 0) = (&d.error, d.rays) {
                println!("  {:<22} error: {err}", d.name);
                continue;
            }
            println!(
                "  {:<22} {:>10.2} {:>10.2} {:>11.2} ±{:<6.2} {:>9.2} {:>10.2} {:>10} {:>5} {:>5}",
                d.name,
                d.build_ms,
                d.trace_ms,
                d.total_ms,
                d.total_ms_spread,
                d.mrays_per_s,
                d.memory_bytes as f64 / (1024.0 * 1024.0),
                d.compacted_bytes.map(|b| format!("{:.2}", b as f64 / (1024.0 * 1024.0))).unwrap_or_else(|| "-".into()),
                d.valid,
                d.hits_agree
            );
            if let Some(err) = &d.error {
                println!("          error: {err}");
            }
        }
    }
    if !e.refit_structures.is_empty() {
        println!("  refit candidates (frame 0 built, every later frame refitted):");
        println!(
            "  {:<12} {:>10} {:>10} {:>10} {:>18} {:>9} {:>9} {:>15} {:>5} {:>5}",
            "",
            "build ms",
            "refit ms",
            "trace ms",
            "total ms",
            "box/ray",
            "tri/ray",
            "SAH first/last",
            "valid",
            "agree"
        );
        for r in &e.refit_structures {
            println!(
                "  {:<12} {:>10.2} {:>10.2} {:>10.2} {:>11.2} ±{:<6.2} {:>9.2} {:>9.2} {:>15} {:>5} {:>5}",
                r.name,
                r.build_ms,
                r.refit_ms,
                r.trace_ms,
                r.total_ms,
                r.total_ms_spread,
                r.box_tests_per_ray,
                r.prim_tests_per_ray,
                r.sah_first_last.map(|[a, b]| format!("{a:.1}/{b:.1}")).unwrap_or_else(|| "-".into()),
                r.valid,
                r.hits_agree
            );
            if let Some(err) = &r.error {
                println!("          error: {err}");
            }
        }
        if let Some(b) = &e.best_candidate {
            println!("  best of all candidates (rebuilt and refitted): {b}");
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
/// oracle results.
/// The policies against the baselines: overall, then mean / worst regret per workload and per family.
/// The end-to-end table: per policy and frames, plain and end-to-end mean regret (worst), the median decision cost.
fn print_e2e(e: &[meshchar::eval::e2e::E2ePolicy]) {
    let Some(first) = e.first() else { return };
    println!("\nwith the decision's cost (held out; e2e = (decision + chosen build + F trace) / best - 1):");
    print!("{:<24}", "policy");
    for s in &first.overall {
        print!(" | {:>33}", format!("F = {}: regret / e2e (worst), ms", s.frames));
    }
    println!();
    for p in e {
        print!("{:<24}", format!("{} ({})", p.policy, p.holdout));
        for s in &p.overall {
            print!(
                " | {:>6.1}% {:>6.1}% ({:>6.1}%) {:>8.3}",
                100.0 * s.mean_regret,
                100.0 * s.mean_e2e,
                100.0 * s.worst_e2e,
                s.median_decision_ms
            );
        }
        println!();
    }
    let ladder = e.iter().find(|p| p.policy == "ladder");
    if let Some(l) = ladder {
        let levels: Vec<String> =
            l.overall.iter().map(|s| format!("F = {}: {:?} ({} by size)", s.frames, s.levels, s.by_size)).collect();
        println!(
            "ladder: samples decided at levels 0/1/2/3 (of level 0, on the triangle count alone): {}",
            levels.join("; ")
        );
    }
}

fn print_baselines(b: &meshchar::eval::compare::Baselines) {
    println!("\nbaselines ({} samples; families: {}):", b.families.len(), {
        let mut f = b.families.clone();
        f.sort();
        f.dedup();
        f.join(", ")
    });
    println!(
        "{:<34} {:>6} {:>6} {:>9} {:>12} {:>12} {:>12} {:>12}  worst at",
        "policy (how fitted)",
        "scored",
        "failed",
        "accuracy",
        "within noise",
        "mean regret",
        "beyond noise",
        "worst regret"
    );
    for p in &b.policies {
        let s = &p.overall;
        println!(
            "{:<34} {:>6} {:>6} {:>8.1}% {:>11.1}% {:>11.1}% {:>11.1}% {:>11.1}%  {}",
            format!("{} ({})", p.policy, p.holdout),
            s.scored,
            s.failed,
            100.0 * s.accuracy,
            100.0 * s.within_noise,
            100.0 * s.mean_regret,
            100.0 * s.mean_regret_beyond_noise,
            100.0 * s.worst_regret,
            s.worst
        );
    }
    println!(
        "(beyond noise: the regret the 95% intervals vouch for, 0 where the selection's interval overlaps the \
         best's; the raw regret where a record has no intervals)"
    );
    for p in b.policies.iter().filter(|p| !p.ridges.is_empty()) {
        // "20" or "20+x" (with the crossings), per group or counted.
        let name = |r: f64, x: bool| format!("{r}{}", if x { "+x" } else { "" });
        let mut by_choice: Vec<(f64, bool, usize)> = Vec::new();
        for &(_, r, x) in &p.ridges {
            match by_choice.iter_mut().find(|c| c.0 == r && c.1 == x) {
                Some(c) => c.2 += 1,
                None => by_choice.push((r, x, 1)),
            }
        }
        by_choice.sort_by(|a, b| a.1.cmp(&b.1).then(a.0.total_cmp(&b.0)));
        let list: Vec<String> = if p.ridges.len() <= 12 {
            p.ridges.iter().map(|(g, r, x)| format!("{g} {}", name(*r, *x))).collect()
        } else {
            by_choice.iter().map(|(r, x, n)| format!("{} for {n}", name(*r, *x))).collect()
        };
        println!(
            "{} ({}): ridge chosen without each group (+x: with the crossings): {}",
            p.policy,
            p.holdout,
            list.join(", ")
        );
    }
    // Per workload (and per family): mean / worst regret, and the worst regret the 95% intervals vouch for.
    let mean_worst = |s: &PolicyScore| format!("{:.1}/{:.0}%", 100.0 * s.mean_regret, 100.0 * s.worst_regret);
    let beyond = |s: &PolicyScore| format!("{:.1}%", 100.0 * s.worst_regret_beyond_noise);
    print_by(b, "worst regret beyond noise by workload", false, &beyond);
    print_by(b, "mean / worst regret by workload", false, &mean_worst);
    print_by(b, "mean / worst regret by family", true, &mean_worst);
}

/// One table of [`print_baselines`]: a row per policy, a column per workload (or per family), `cell` of each score.
fn print_by(
    b: &meshchar::eval::compare::Baselines,
    title: &str,
    by_family: bool,
    cell: &dyn Fn(&PolicyScore) -> String,
) {
    fn groups(p: &meshchar::eval::compare::PolicyRun, by_family: bool) -> &[(String, PolicyScore)] {
        if by_family {
            &p.by_family
        } else {
            &p.by_workload
        }
    }
    let keys: Vec<&str> =
        b.policies.first().map(|p| groups(p, by_family).iter().map(|k| k.0.as_str()).collect()).unwrap_or_default();
    print!("\n{title:<37}");
    for k in &keys {
        print!(" {k:>15}");
    }
    println!();
    for p in &b.policies {
        print!("{:<37}", format!("{} ({})", p.policy, p.holdout));
        for (_, s) in groups(p, by_family) {
            print!(" {:>15}", cell(s));
        }
        println!();
    }
}

/// `--proxy`: the prices, the agreement with the measured truth, and the policies scored against the proxy.
fn print_proxy(prices: &TestPrices, a: &Agreement, pc: &meshchar::eval::compare::Comparison) {
    println!(
        "\ndeterministic proxy: counted tests x prices measured in isolation ({:.2} ns per box test, {:.2} ns per \
         triangle test, medians of {}), builds as measured; within noise = within 2% of the best",
        prices.box_ns, prices.triangle_ns, prices.repeats
    );
    println!(
        "agreement over {} samples: same best {:.1}%, the proxy's best within the measured noise {:.1}%, its mean \
         regret judged by the measurement {:.1}%",
        a.samples,
        100.0 * a.same_best,
        100.0 * a.best_within_noise,
        100.0 * a.mean_regret_of_proxy_best
    );
    println!("measured / proxy trace time per structure (median, RMS of the log, traces):");
    for (s, n, med, rms) in &a.trace_ratio {
        println!("  {s:<7} {med:>7.2}x  {rms:>5.2}  {n}");
    }
    println!(
        "against the proxy: calibrated held out (LOO) mean regret {:.1}% (worst {:.1}%, {}), accuracy {:.1}%; \
         calibrated in sample {:.1}%; thesis {:.1}%",
        100.0 * pc.calibrated_held_out.mean_regret,
        100.0 * pc.calibrated_held_out.worst_regret,
        pc.calibrated_held_out.worst,
        100.0 * pc.calibrated_held_out.accuracy,
        100.0 * pc.calibrated_in_sample.mean_regret,
        100.0 * pc.baseline.mean_regret
    );
    print_baselines(&pc.baselines);
}

fn compare_policies(args: &Args) -> anyhow::Result<()> {
    let bar = Progress::new("compare-policies", None, args.json.json);
    // One tracer per comparison: the calibrated policy is fitted on these records, so they must describe one
    // backend and one device.
    let tracer = tracer_of(&args.compare_policies)?;
    let probes = SampleProbes { timed: args.timed_probes, measured: args.measure_close_calls };
    let samples =
        load_samples_admitted(&args.compare_policies, &Params::default(), probes, &cli::admit_record_scene, &|m| {
            bar.step(&format!("features of {m}"))
        })?;
    bar.finish();
    let device = match tracer.as_ref().and_then(|t| t.device.as_ref()) {
        Some(d) => d.name.clone(),
        None => meshchar::characterize::cpu::cpu_device_name(rayon::current_num_threads()),
    };
    if !args.json.json {
        println!(
            "records traced with {}",
            tracer.as_ref().map_or_else(|| "nothing (no records)".into(), |t| t.describe())
        );
    }
    let samples = match &args.frames_sweep {
        Some(f) => meshchar::eval::compare::with_frames(&samples, &f.0),
        None => samples,
    };
    let mut c = compare(&samples, args.tie_margin.tie_margin, &device)?;
    if !args.repeat_oracle.is_empty() {
        // The samples come in the records' order, file by file.
        let mut records = Vec::new();
        for f in &args.compare_policies {
            records.extend(meshchar::eval::record::read_jsonl(f)?);
        }
        let mut repeat = Vec::new();
        for f in &args.repeat_oracle {
            repeat.extend(meshchar::eval::record::read_jsonl(f)?);
        }
        let run = meshchar::eval::compare::repeat_oracle(&c.baselines, &samples, &records, &repeat)
            .map_err(|e| anyhow::anyhow!("--repeat-oracle: {e}"))?;
        c.baselines.policies.push(run);
    }
    // With --cost-model: that calibration as it is, fitted on other records (no refit), scored on these.
    let fixed = match &args.policy.cost_model {
        Some(path) => {
            let model =
                args.policy.cost_model_for(args::trace_target(tracer.as_ref().and_then(|t| t.device.as_ref())))?;
            let picks: Vec<_> = samples
                .iter()
                .map(|s| meshchar::select::choose(&s.predict(&model), args.tie_margin.tie_margin))
                .collect();
            // With --timed-probes and a file that has their ratios: its predictions with the probes blended in;
            // with --measure-close-calls, then the close call settled by the frames measured.
            let probed = |s: &meshchar::eval::fit::Sample| {
                let mut p = s.predict(&model);
                if let Some(r) = model.timed.as_ref().filter(|_| args.timed_probes) {
                    meshchar::cost::timed::blend_contenders(&mut p, &s.timed, r, &s.workload);
                }
                p
            };
            let timed = model.timed.as_ref().filter(|_| args.timed_probes).map(|_| {
                samples.iter().map(|s| meshchar::select::choose(&probed(s), args.tie_margin.tie_margin)).collect()
            });
            let measured = args.measure_close_calls.then(|| {
                samples
                    .iter()
                    .map(|s| {
                        let p = probed(s);
                        s.settle_close_call(&p).or_else(|| meshchar::select::choose(&p, args.tie_margin.tie_margin))
                    })
                    .collect()
            });
            Some(FixedScores::of(path.display().to_string(), &samples, &picks, timed, measured))
        }
        None => None,
    };
    let proxy = if args.proxy {
        let prices = TestPrices::measure(21);
        let p = proxied(&samples, &prices, 0.02);
        let agree = agreement(&samples, &p);
        Some((prices, agree, compare(&p, args.tie_margin.tie_margin, &device)?))
    } else {
        None
    };
    if args.json.json {
        println!("{}", serde_json::json!(c));
        if let Some(f) = &fixed {
            println!("{}", serde_json::json!({ "fixed_cost_model": f }));
        }
        if let Some((prices, agree, pc)) = &proxy {
            println!("{}", serde_json::json!({"proxy": {"prices": prices, "agreement": agree, "comparison": pc}}));
        }
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
        print_e2e(&c.e2e);
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
        if let Some(f) = &fixed {
            let label = if args.timed_probes { "as given, timed + measured" } else { "as given, close calls measured" };
            let file = &f.file;
            for (label, sc) in std::iter::once(("calibrated, as given", &f.score))
                .chain(f.timed_score.iter().map(|t| ("as given, timed probes", t)))
                .chain(f.measured_score.iter().map(|t| (label, t)))
            {
                println!(
                    "{:<34} {:>6} {:>8.1}% {:>11.1}% {:>11.1}% {:>11.1}%  {}",
                    label,
                    sc.scored,
                    100.0 * sc.accuracy,
                    100.0 * sc.within_noise,
                    100.0 * sc.mean_regret,
                    100.0 * sc.worst_regret,
                    sc.worst
                );
            }
            for w in &f.by_workload {
                let pc = |x: &Option<PolicyScore>| {
                    x.as_ref().map_or_else(String::new, |x| {
                        format!(" {:.1}% ({:.1}%)", 100.0 * x.mean_regret, 100.0 * x.worst_regret)
                    })
                };
                println!(
                    "  {:<16} {:>4}: as given {:.1}% ({:.1}%), timed{}, measured{}",
                    w.workload,
                    w.score.scored,
                    100.0 * w.score.mean_regret,
                    100.0 * w.score.worst_regret,
                    pc(&w.timed_score),
                    pc(&w.measured_score)
                );
            }
            println!(
                "(as given: --cost-model {file}, not refitted on these records; mean (worst) regret by workload above)"
            );
        }
        println!("(tie margin {:.2}; leave-one-out holds out every workload of a scene together)", c.tie_margin);
        if let Some(k) = &c.candidates {
            println!(
                "\nwith the driver's acceleration structures ({} samples): best flag and best candidate measured, the \
                 calibrated policy's picks held out",
                k.rows.len()
            );
            println!(
                "{:<44} {:<8} {:>21} | {:>21} {:>7} | {:>21} | {:>21} {:>7}",
                "scene", "workload", "best flag", "flag (held out)", "regret", "best", "choice (held out)", "regret"
            );
            let o = |s: &Option<String>| s.clone().unwrap_or_else(|| "-".into());
            for r in &k.rows {
                let scene: String = r.scene.chars().rev().take(44).collect::<Vec<_>>().into_iter().rev().collect();
                println!(
                    "{:<44} {:<8} {:>21} | {:>21} {:>7} | {:>21} | {:>21} {:>7}",
                    scene,
                    r.workload.as_str(),
                    o(&r.oracle_best_flag),
                    o(&r.held_out_flag),
                    pct(r.held_out_flag_regret),
                    o(&r.oracle_best),
                    o(&r.held_out),
                    pct(r.held_out_regret)
                );
            }
            println!(
                "held out: flag right {:.1}%, flag mean regret {:.1}%; overall choice right {:.1}%, mean regret {:.1}%, \
                 worst {:.1}%; in sample: right {:.1}%, mean regret {:.1}%",
                100.0 * k.held_out_flag_accuracy,
                100.0 * k.held_out_flag_mean_regret,
                100.0 * k.held_out_accuracy,
                100.0 * k.held_out_mean_regret,
                100.0 * k.held_out_worst_regret,
                100.0 * k.in_sample_accuracy,
                100.0 * k.in_sample_mean_regret
            );
        }
        print_baselines(&c.baselines);
        if let Some((prices, a, pc)) = &proxy {
            print_proxy(prices, a, pc);
        }
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
            std::fs::create_dir_all(dir)
                .and_then(|_| std::fs::write(&path, chart.to_svg()))
                .with_context(|| path.display().to_string())?;
            if !args.json.json {
                println!("chart: {}", path.display());
            }
        }
    }
    Ok(())
}

/// One scene: loaded, selected by the policy, measured by the oracle, printed (and appended to the oracle cache).
/// `None` after a failure of this scene, printed.
#[allow(clippy::too_many_arguments)]
fn scene(
    args: &Args,
    i: usize,
    input: &Path,
    engine: &mut Characterizer,
    model: &CostModel,
    device: Option<&DeviceOracle<'_>>,
    bar: &Progress,
    failed: &mut bool,
) -> Option<SceneEvaluation> {
    let mut fail = |msg: String| {
        bar.eprintln(&format!("evaluate: {msg}"));
        *failed = true;
    };
    bar.item(i, 1, &format!("loading {}", input.display()));
    let scene = match load_scene(input) {
        Ok(s) => s,
        Err(e) => {
            fail(cli::message(&e));
            return None;
        }
    };
    let mut config = args.config();
    config.rebuild = args.rebuild.unwrap_or(if scene.is_dynamic() { Rebuild::PerFrame } else { Rebuild::Once });
    if args.structures.is_empty() && scene.is_dynamic() && args.trace_backend == TraceBackend::Cpu {
        config.refit = RefitCandidate::ALL.to_vec();
    }
    if let Some(v) = args.view {
        let f = scene.frames.len().min(config.frames.unwrap_or(scene.frames.len()).max(1));
        let b = scene.frames[..f].iter().fold(meshchar::geom::Aabb::EMPTY, |a, m| a.union(&mesh_bounds(m)));
        config.camera = Some(v.camera(&b));
    }
    // Steps: the selection, then per measured frame the reference and every structure at every repeat.
    let frames =
        if scene.is_dynamic() { config.frames.unwrap_or(scene.frames.len()).clamp(1, scene.frames.len()) } else { 1 };
    bar.item(
        i,
        1 + frames * (1 + config.repeats * (config.structures.len() + config.refit.len() + config.driver.len())),
        &scene.name,
    );
    bar.step(&format!("{}: characterization and selection", scene.name));
    let policy = args.policy.policy;
    let selection = select(
        engine,
        &scene,
        &config,
        policy,
        model,
        args.tie_margin.tie_margin,
        args.budget.budget(),
        &args.decision,
    );
    let chosen = match selection {
        Ok(s) => {
            if !args.json.json {
                bar.suspend(|| {
                    println!(
                        "\n{}: the {} policy selects {} (decision {:.3} ms, warm)",
                        scene.name,
                        policy.as_str(),
                        s.candidate,
                        s.decision_ms
                    );
                    for r in &s.reasons {
                        println!("  - {r}");
                    }
                });
            }
            s
        }
        Err(e) => {
            fail(format!("{}: characterization failed: {}", scene.name, cli::message(&e)));
            return None;
        }
    };
    let (selected, candidate, predictions) = (chosen.structure, chosen.candidate, chosen.predicted.clone());
    let e = match evaluate_scene_on(&scene, &config, Some(selected), &|m| bar.step(m), device) {
        Ok(e) => e,
        Err(e) => {
            fail(e.to_string());
            return None;
        }
    };
    let mut json = e.to_json();
    json["policy"] = serde_json::json!(policy.as_str());
    if let Some(v) = args.view {
        json["view"] = serde_json::json!(v.name());
    }
    if policy == Policy::Calibrated {
        json["cost_model"] = serde_json::json!(model.chosen_as);
    }
    if let Some(p) = &predictions {
        json["predicted"] = serde_json::json!(p);
    }
    // The decision counted: once per build of a static scene, once per frame of an animation.
    let decisions = if scene.is_dynamic() { e.frames_measured.max(1) as f64 } else { 1.0 };
    let total = |s: Option<StructureName>| {
        e.structures.iter().find(|r| r.name == s && s.is_some()).map(|r| r.total_ms.median).filter(|t| *t > 0.0)
    };
    let e2e = match (total(Some(selected)), total(e.oracle_best)) {
        (Some(c), Some(b)) => Some((decisions * chosen.decision_ms + c) / b - 1.0),
        _ => None,
    };
    json["decision_ms"] = serde_json::json!(chosen.decision_ms);
    json["e2e_regret"] = serde_json::json!(e2e);
    if let Some(l) = chosen.level {
        json["decision_level"] = serde_json::json!(l);
    }
    if !e.driver_structures.is_empty() {
        // The overall choice among the project's and the driver's structures, and its regret against the best of
        // them all.
        json["selected_candidate"] = serde_json::json!(candidate);
        json["candidate_regret"] = serde_json::json!(e.candidate_regret(candidate));
    }
    bar.suspend(|| {
        if args.json.json {
            println!("{json}");
        } else {
            print_table(&e);
            println!(
                "  decision: {:.3} ms warm ({}){}",
                chosen.decision_ms,
                if scene.is_dynamic() { "every frame" } else { "once per build" },
                e2e.map(|x| format!("; end-to-end regret over {} frame(s): {x:.3}", e.frames)).unwrap_or_default()
            );
            if let Some(p) = &predictions {
                print_predictions(&e, p);
            }
        }
    });
    if let Some(path) = &args.oracle_cache {
        if let Err(err) = append_line(path, &json.to_string()) {
            fail(format!("{}: {err}", path.display()));
        }
    }
    Some(e)
}

fn run(args: Args) -> anyhow::Result<()> {
    if !args.compare_policies.is_empty() {
        return compare_policies(&args);
    }
    let mut engine = Characterizer::new(args.backend.backend)?;
    let ctx = match args.trace_backend {
        TraceBackend::Cpu => None,
        TraceBackend::Vulkan => Some(
            meshchar::gpu::Context::new(&meshchar::gpu::ContextDesc::default())
                .context("--trace-backend vulkan needs a Vulkan device")?,
        ),
    };
    // The calibration of the tracer that the oracle measures: the CPU's, or the device's.
    let record = args::device_record(ctx.as_ref());
    let model = args.policy.cost_model_for(args::trace_target(record.as_ref()))?;
    if args.policy.policy == Policy::Calibrated && !args.json.json {
        println!("calibrated policy: cost model {}", model.chosen_as.as_deref().unwrap_or("?"));
    }
    let device = match &ctx {
        Some(c) => Some(DeviceOracle::new(c).context("device traversal")?),
        None => None,
    };
    let mut evals = Vec::new();
    let mut failed = false;
    let bar = Progress::new("evaluate", Some(args.inputs.len()), args.json.json);
    for (i, input) in args.inputs.iter().enumerate() {
        if let Some(e) = scene(&args, i, input, &mut engine, &model, device.as_ref(), &bar, &mut failed) {
            evals.push(e);
        }
    }
    bar.finish();
    if !args.json.json && evals.len() > 1 {
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
                if !args.json.json {
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
        Err(cli::Reported.into())
    } else {
        Ok(())
    }
}

fn main() -> ExitCode {
    cli::main_with(run)
}

/// A calibration given with `--cost-model`, scored as it is on the records (`fixed_cost_model` in the JSON): its
/// own choices, with the timed probes blended in, and with the close calls then measured, over all the records
/// and per workload.
#[derive(serde::Serialize)]
struct FixedScores {
    /// The calibration file.
    file: String,
    /// Its choices' score.
    score: PolicyScore,
    /// With `--timed-probes` and a file that has their ratios.
    timed_score: Option<PolicyScore>,
    /// With `--measure-close-calls`.
    measured_score: Option<PolicyScore>,
    /// The same per workload ([`meshchar::eval::compare::workload_of`]), in the order first met.
    by_workload: Vec<WorkloadScores>,
}

/// [`FixedScores`] of one workload.
#[derive(serde::Serialize)]
struct WorkloadScores {
    /// `primary`, `shadow x100`, ...
    workload: String,
    /// The calibration's own choices.
    score: PolicyScore,
    /// With the timed probes blended in.
    timed_score: Option<PolicyScore>,
    /// With the close calls then measured.
    measured_score: Option<PolicyScore>,
}

/// One choice per sample (`None`: no choice).
type Picks = Vec<Option<meshchar::accel::StructureName>>;

impl FixedScores {
    /// The scores of `picks`, `timed` and `measured` (one choice per sample each) over `samples`.
    fn of(
        file: String,
        samples: &[meshchar::eval::fit::Sample],
        picks: &Picks,
        timed: Option<Picks>,
        measured: Option<Picks>,
    ) -> Self {
        let scored = |keep: &dyn Fn(&meshchar::eval::fit::Sample) -> bool, c: &Picks| {
            score(samples.iter().zip(c).filter(|(s, _)| keep(s)).map(|(s, c)| (s, *c)))
        };
        let mut workloads: Vec<String> = Vec::new();
        for s in samples {
            let w = meshchar::eval::compare::workload_of(s);
            if !workloads.contains(&w) {
                workloads.push(w);
            }
        }
        let all = |_: &meshchar::eval::fit::Sample| true;
        let by_workload = workloads
            .into_iter()
            .map(|w| {
                let keep = |s: &meshchar::eval::fit::Sample| meshchar::eval::compare::workload_of(s) == w;
                WorkloadScores {
                    score: scored(&keep, picks),
                    timed_score: timed.as_ref().map(|c| scored(&keep, c)),
                    measured_score: measured.as_ref().map(|c| scored(&keep, c)),
                    workload: w,
                }
            })
            .collect();
        FixedScores {
            file,
            score: scored(&all, picks),
            timed_score: timed.as_ref().map(|c| scored(&all, c)),
            measured_score: measured.as_ref().map(|c| scored(&all, c)),
            by_workload,
        }
    }
}
