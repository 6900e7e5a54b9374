//! Characterizes meshes and animations (docs/spec.md) and selects an acceleration structure for each.
//!
//! ```text
//! cargo run --release --example characterize -- [FILE|DIR ...] [--json] [--backend vulkan|cpu|naive]
//!     [--morton-bits 30|63] [--alpha A] [--sample-stride S] [--class-rule doane|sturges|sqrt|N]
//!     [--policy thesis|calibrated] [--cost-model FILE] [--budget-references-per-triangle R]
//!     [--budget-min-references N] [--budget-bytes BYTES] [--budget-grid-references-per-triangle R]
//!     [--budget-grid-min-references N] [--workload primary|shadow|diffuse] [--resolution N]
//!     [--frames F] [--secondary-rays N] [--trace-backend cpu|vulkan]
//! ```
//!
//! A FILE is a static mesh (.obj or .ply); a DIR holds the frames of an animation (one report per frame, `kind`
//! dynamic when there is more than one). Without a path, the embedded default scene is characterized. Without
//! `--json` the reports are printed for people; with it, one JSON object per mesh or frame per line.

use anyhow::Context as _;
use clap::Parser;
use cli::args::{
    self, BackendArg, BudgetArgs, DecisionArgs, JsonArg, MortonBitsArg, Policy, PolicyArgs, TraceBackendArg,
    WorkloadArgs,
};
use cli::Progress;
use meshchar::characterize::Features;
use meshchar::characterize::{cpu, Characterization, Characterizer, ClassRule, Params};
use meshchar::cost::CostModel;
use meshchar::mesh::Animation;
use meshchar::select::{Inquiry, Level, PolicyKind, Report, Scene, SelectionCost, Selector, TargetWorkload};
use meshchar::trace::workload::mesh_bounds;
use std::path::PathBuf;
use std::process::ExitCode;

#[path = "support/cli.rs"]
mod cli;

/// Characterizes meshes and animations (docs/spec.md) and selects an acceleration structure for each.
///
/// Without --json the reports are printed for people; with it, one JSON object per mesh or frame per line.
/// --workload, --resolution and --frames describe the workload that the calibrated policy predicts for.
#[derive(Parser, Debug)]
#[command(name = "characterize", args_override_self = true)]
#[command(mut_arg("json", |a| a.help("One JSON object per mesh or frame per line (default: a report for people)")))]
#[command(mut_arg("workload", |a| a.help("Calibrated policy: the kind of rays")))]
#[command(mut_arg("resolution", |a| {
    a.help("Calibrated policy: N x N primary rays per frame (shadow and diffuse rays start where they hit: their \
            number is estimated from a sample of them, or given with --secondary-rays)")
}))]
struct Args {
    /// None: the embedded default scene. A mesh (.obj, .ply): a static scene; or a directory: the frames of an
    /// animation, in name order, a dynamic scene with one report per frame; or a generated scene,
    /// family:NAME:TRIANGLES[:SEED] or degenerate:NAME:TRIANGLES[:SEED]
    #[arg(value_name = "FILE|DIR")]
    paths: Vec<PathBuf>,
    #[command(flatten)]
    json: JsonArg,
    #[command(flatten)]
    backend: BackendArg,
    #[command(flatten)]
    morton: MortonBitsArg,
    /// Significance of the chi-square test, in (0, 1)
    #[arg(long, value_name = "A", default_value_t = 0.005, value_parser = args::alpha)]
    alpha: f64,
    /// Characterize every S-th triangle only (1: all)
    #[arg(long, value_name = "S", default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    sample_stride: u32,
    /// The number of classes: doane, sturges, sqrt or a fixed number of classes
    #[arg(long, value_name = "doane|sturges|sqrt|N", default_value = "doane", value_parser = args::class_rule)]
    class_rule: ClassRule,
    #[command(flatten)]
    policy: PolicyArgs,
    #[command(flatten)]
    budget: BudgetArgs,
    #[command(flatten)]
    decision: DecisionArgs,
    #[command(flatten)]
    trace_backend: TraceBackendArg,
    #[command(flatten)]
    workload: WorkloadArgs,
    /// Calibrated policy, shadow or diffuse rays: how many a frame traces, when known (an engine's primary pass
    /// knows its hits) [default: estimated by tracing a sample of at most 128 x 128 of the primary rays through a
    /// reference LBVH, meshchar::trace::workload::estimate_secondary_rays, the whole image at --resolution 128 and
    /// below]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64))]
    secondary_rays: Option<u64>,
    /// Calibrated policy: frames rendered with one build of a static scene
    #[arg(long, value_name = "F", default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    frames: u64,
    /// Calibrated policy: the camera the engine will trace from, eye, target (and vertical field of view in
    /// degrees, default 45), +y up [default: a camera framing the scene]
    #[arg(long, value_name = "EX,EY,EZ,TX,TY,TZ[,FOV]", allow_hyphen_values = true, value_parser = args::camera)]
    camera: Option<meshchar::geom::Camera>,
    /// Calibrated policy: a camera preset from the scene's bounds instead of --camera: framing, inside, close-up or
    /// grazing
    #[arg(long, value_name = "PRESET", conflicts_with = "camera", value_parser = args::view)]
    view: Option<meshchar::trace::views::View>,
    /// Calibrated policy, static scene: build each contender (a structure within the budget predicted within 2x of
    /// the cheapest), time that build and a single-threaded trace of a 64 x 64 sample of the view's rays
    /// (meshchar::cost::timed), and blend those times into the predictions when the cost model has their ratios
    /// (`calibrate --from-oracle ... --timed-probes`). Costs the builds; not deterministic: close calls may go
    /// either way between runs
    #[arg(long)]
    timed_probes: bool,
    /// Calibrated policy, static scene: after the timed probes (implied), settle a close call by measuring it:
    /// every structure within the budget whose predicted total lies within 20% of the least is built and traced
    /// over whole frames of the view's rays at --resolution, once untimed and then three times, and the least
    /// median total over --frames is taken (meshchar::cost::measured). Costs four builds and frames of each; not
    /// deterministic
    #[arg(long)]
    measure_close_calls: bool,
    /// With --measure-close-calls: measure only when the predictions put the measurement at no more than MS
    /// milliseconds
    #[arg(long, value_name = "MS", default_value_t = meshchar::cost::measured::DEFAULT_MAX_MS, requires = "measure_close_calls", value_parser = args::positive_number)]
    measure_max_ms: f64,
}

impl Args {
    fn params(&self) -> Params {
        Params {
            morton_bits: self.morton.morton_bits,
            alpha: self.alpha,
            sample_stride: self.sample_stride,
            class_rule: self.class_rule,
            ..Params::default()
        }
    }
}

/// The scene characterized when no path is given: the embedded low-resolution bunny.
fn default_scene() -> Animation {
    let mesh = meshchar::mesh::default_scene();
    Animation { name: mesh.name.clone(), frames: vec![mesh] }
}

/// Characterizes every frame of a scene and prints one report per frame.
fn process(
    engine: &mut Characterizer,
    scene: &Animation,
    args: &Args,
    model: &CostModel,
    bar: &Progress,
) -> anyhow::Result<()> {
    let params = args.params();
    let t0 = std::time::Instant::now();
    let (results, features): (Vec<Characterization>, Vec<Features>) =
        engine.characterize_animation_with_features(scene, &params)?;
    let characterize_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = std::time::Instant::now();
    let resolution = u64::from(args.workload.resolution);
    let bounds_all = || scene.frames.iter().fold(meshchar::geom::Aabb::EMPTY, |a, m| a.union(&mesh_bounds(m)));
    let camera = args.camera.or_else(|| args.view.map(|v| v.camera(&bounds_all())));
    // Shadow and diffuse rays start where the primary rays hit: as many as the caller says, or as a sample of the
    // primary rays makes (on the first frame, from the camera the policy assumes). The thesis policy reads no count.
    let (rays_per_frame, rays_reason) = secondary_rays(args, scene, camera, &bounds_all, resolution * resolution);
    let workload = TargetWorkload {
        kind: args.workload.workload,
        rays_per_frame,
        frames: args.frames,
        animation_frames: None,
        // The driver's structures are weighed when the cost model chosen for this device calibrated them (a device
        // calibration: `calibrate --trace-backend vulkan` on a device with ray queries).
        driver: !model.driver.is_empty(),
        camera,
    };
    let mut selector = Selector::new(model, workload);
    selector.policy = match args.policy.policy {
        Policy::Thesis => PolicyKind::Thesis,
        Policy::Calibrated => PolicyKind::Calibrated,
    };
    // --budget-*: no structure whose grid or kd-tree references would exceed the budget is a candidate.
    selector.budget = args.budget.budget();
    selector.inquiry = if args.measure_close_calls {
        Inquiry::Fixed(Level::Measured)
    } else if args.timed_probes {
        Inquiry::Fixed(Level::Timed)
    } else {
        args.decision.level
    };
    selector.decision_budget = args.decision.decision_budget;
    selector.resolution = args.workload.resolution;
    if args.measure_close_calls {
        selector.max_inquiry_ms = args.measure_max_ms;
    }
    let decision = selector.select(&Scene {
        name: &scene.name,
        characterizations: &results,
        features: &features,
        meshes: &scene.frames,
    });
    let (level, steps) = (decision.level, decision.steps.clone());
    let mut chosen = decision;
    // Last, so that the policy's own reasons keep their places (docs/spec.md: the first, the margin second).
    if let Some(r) = rays_reason {
        chosen.selection.reasons.push(meshchar::select::Reason::new(meshchar::select::ReasonKind::Workload, r));
    }
    let select_ms = t1.elapsed().as_secs_f64() * 1e3;
    let frames = if scene.frames.len() > 1 { scene.frames.len() as u64 } else { args.frames };
    // A decision on the triangle count alone did not read the characterization (which fills the report).
    let cost = SelectionCost::new(
        if chosen.characterized { characterize_ms } else { 0.0 },
        select_ms,
        scene.frames.len(),
        chosen.predicted.as_ref().and_then(|p| p.iter().find(|p| p.structure == chosen.selection.structure)),
        frames,
    );
    let dynamic = scene.frames.len() > 1;
    for (i, (frame, c)) in scene.frames.iter().zip(&results).enumerate() {
        let mut report = Report::new(if dynamic { scene.name.clone() } else { frame.name.clone() }, c)
            .selection(chosen.kind, chosen.policy.name(), &chosen.selection)
            .zero_area(cpu::zero_area_triangles(frame, params.sample_stride))
            .features(features[i].clone())
            .selection_cost(cost)
            .measured(chosen.measured.clone());
        if chosen.policy == PolicyKind::Calibrated {
            report = report.inquiry(level, steps.clone());
        }
        if let Some(p) = &chosen.predicted {
            report = report.predicted(p.clone());
        }
        if dynamic {
            report = report.frame(i, frame.name.clone());
        }
        bar.suspend(|| {
            if args.json.json {
                println!("{}", report.to_json());
            } else {
                println!("{}", report.to_text());
            }
        });
    }
    Ok(())
}

/// The rays per frame the calibrated policy is told, and a reason saying where the number comes from (none for
/// primary rays or the thesis policy): `pixels` primary rays; for shadow and diffuse rays, `--secondary-rays` or
/// the estimate of [`meshchar::trace::workload::estimate_secondary_rays`] on the first frame, seen from `camera` or
/// else the camera framing the scene's bounds (`bounds`; as the policy assumes without a camera).
fn secondary_rays(
    args: &Args,
    scene: &Animation,
    camera: Option<meshchar::geom::Camera>,
    bounds: &dyn Fn() -> meshchar::geom::Aabb,
    pixels: u64,
) -> (u64, Option<String>) {
    use meshchar::trace::workload::{estimate_secondary_rays, SECONDARY_SAMPLE_SIDE};
    let kind = args.workload.workload;
    if kind == meshchar::geom::WorkloadKind::Primary || args.policy.policy == Policy::Thesis {
        return (pixels, None);
    }
    if let Some(n) = args.secondary_rays {
        return (n, Some(format!("{} rays per frame: {n} (--secondary-rays)", kind.as_str())));
    }
    let Some(first) = scene.frames.first() else { return (pixels, None) };
    let camera = camera.unwrap_or_else(|| meshchar::geom::Camera::frame(&bounds()));
    match estimate_secondary_rays(kind, first, &camera, args.workload.resolution, SECONDARY_SAMPLE_SIDE) {
        Ok(e) => (
            e.rays,
            Some(format!(
                "{} rays per frame: {} estimated from {}x{} of the {}x{} primary rays ({} of them made one; {:.1} ms)",
                kind.as_str(),
                e.rays,
                e.side,
                e.side,
                args.workload.resolution,
                args.workload.resolution,
                e.made,
                e.ms
            )),
        ),
        Err(err) => {
            (pixels, Some(format!("{} rays per frame: {pixels}, one per pixel (not estimated: {err})", kind.as_str())))
        }
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    if args.secondary_rays.is_some()
        && (args.workload.workload == meshchar::geom::WorkloadKind::Primary || args.policy.policy == Policy::Thesis)
    {
        cli::usage_error::<Args>(
            clap::error::ErrorKind::ArgumentConflict,
            "--secondary-rays counts shadow or diffuse rays for the calibrated policy (--workload shadow|diffuse)",
        );
    }
    let mut engine = Characterizer::new(args.backend.backend)?;
    if let Some(note) = engine.note() {
        eprintln!("characterize: {note}");
    }
    // The calibrated policy predicts for the tracer of --trace-backend: the CPU's calibration, or the device's.
    let ctx = args.trace_backend.context()?;
    let record = args::device_record(ctx.as_ref());
    let model = args.policy.cost_model_for(args::trace_target(record.as_ref()))?;
    drop(ctx);
    if args.policy.policy == Policy::Calibrated && !args.json.json {
        println!("calibrated policy: cost model {}", model.chosen_as.as_deref().unwrap_or("?"));
    }
    let bar = Progress::new("characterize", Some(args.paths.len().max(1)), args.json.json);
    if args.paths.is_empty() {
        bar.item(0, 1, "the default scene");
        return process(&mut engine, &default_scene(), &args, &model, &bar);
    }
    let mut ok = true;
    for (i, path) in args.paths.iter().enumerate() {
        bar.item(i, 1, &path.display().to_string());
        let result = cli::load_path_checked(path).and_then(|scene| {
            if scene.frames.is_empty() {
                return Err(anyhow::anyhow!("no frames found")).with_context(|| path.display().to_string());
            }
            process(&mut engine, &scene, &args, &model, &bar)
        });
        if let Err(e) = result {
            bar.eprintln(&format!("characterize: {}", cli::message(&e)));
            ok = false;
        }
    }
    if ok {
        Ok(())
    } else {
        Err(cli::Reported.into())
    }
}

fn main() -> ExitCode {
    cli::main_with(run)
}
