//! The options and value parsers that several examples share, defined once (clap derive): an example flattens the
//! `#[derive(clap::Args)]` structs it needs (`#[command(flatten)]`) and names the value parsers in its own fields
//! (`#[arg(value_parser = args::backend())]`), so that a flag parses, checks and documents its values the same way
//! in every example.

use anyhow::Context as _;
use clap::builder::{PossibleValuesParser, RangedU64ValueParser, TypedValueParser};
use meshchar::accel::StructureName;
use meshchar::characterize::{Backend, ClassRule, MortonBits};
use meshchar::cost::{CostModel, TraceTarget};
use meshchar::eval::oracle::{DeviceRecord, TraceBackend};
use meshchar::geom::WorkloadKind;
use meshchar::select::Budget;
use std::path::PathBuf;

/// `--json`. Each example says what it prints in its own words with
/// `#[command(mut_arg("json", |a| a.help("...")))]`.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct JsonArg {
    /// Print JSON instead of text
    #[arg(long)]
    pub json: bool,
}

/// The selection policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Policy {
    /// The thesis's rules on the characterization's statistics.
    Thesis,
    /// Predicted build and trace times from the cost model.
    Calibrated,
}

impl Policy {
    /// `thesis` or `calibrated`, as the reports name it.
    pub fn as_str(self) -> &'static str {
        match self {
            Policy::Thesis => "thesis",
            Policy::Calibrated => "calibrated",
        }
    }
}

/// `--policy` and `--cost-model` (characterize, evaluate, tradeoff).
#[derive(clap::Args, Clone, Debug)]
pub struct PolicyArgs {
    /// The selection policy
    #[arg(long, value_enum, value_name = "P", default_value_t = Policy::Calibrated)]
    pub policy: Policy,
    /// Calibration file of the calibrated policy [default: the shipped one of the tracer: the CPU calibration, or
    /// with --trace-backend vulkan the one that matches the device (lavapipe's on lavapipe); a missing, unreadable
    /// or invalid file is an error]
    #[arg(long, value_name = "FILE")]
    pub cost_model: Option<PathBuf>,
}

impl PolicyArgs {
    /// The cost model of `--cost-model`, or without it the shipped one for `target`
    /// ([`CostModel::for_trace_target`]: its `chosen_as` says which file and why); a file that cannot be loaded is
    /// an error.
    /// Tracing on a device that no calibration describes falls back to the CPU file: that is said on standard
    /// error too, with the step that fixes it.
    pub fn cost_model_for(&self, target: TraceTarget<'_>) -> anyhow::Result<CostModel> {
        let model = CostModel::for_trace_target(self.cost_model.as_deref(), target).context("cost model")?;
        if let TraceTarget::Device(d) = target {
            if model.trace_backend == meshchar::accel::device::TraceBackend::Cpu {
                eprintln!(
                    "warning: no calibration of {} ({}): the selection prices device traces with the CPU \
                     tracer's calibration; run `calibrate --trace-backend vulkan` on this device and pass \
                     --cost-model",
                    d.name, d.driver
                );
            }
        }
        Ok(model)
    }

    /// [`PolicyArgs::cost_model_for`] the CPU tracer.
    pub fn cost_model(&self) -> anyhow::Result<CostModel> {
        self.cost_model_for(TraceTarget::Cpu)
    }
}

/// `--level` and `--decision-budget` (characterize, evaluate): how far the calibrated policy inquires beyond the
/// prior ([`meshchar::select::Inquiry`]).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct DecisionArgs {
    /// Calibrated policy: auto (climb the ladder of inquiry only where the expected gain exceeds the predicted cost,
    /// within --decision-budget), or a level to climb to whatever it costs: 0 (the prior: the fitted laws on the
    /// features, nothing built), 1 (the mesh's crossings and count probes), 2 (timed probes), 3 (the close call
    /// measured over whole frames)
    #[arg(long, value_name = "auto|0|1|2|3", default_value = "auto", value_parser = inquiry)]
    pub level: meshchar::select::Inquiry,
    /// Calibrated policy, --level auto: the most the inquiry beyond the prior may cost, as a share of the chosen
    /// structure's predicted total over the workload's frames
    #[arg(long, value_name = "SHARE", default_value_t = meshchar::select::DEFAULT_DECISION_BUDGET, value_parser = nonnegative_number)]
    pub decision_budget: f64,
}

/// `auto` or a level 0 to 3.
pub fn inquiry(s: &str) -> Result<meshchar::select::Inquiry, String> {
    use meshchar::select::{Inquiry, Level};
    if s == "auto" {
        return Ok(Inquiry::Auto);
    }
    s.parse::<u8>()
        .ok()
        .and_then(Level::from_number)
        .map(Inquiry::Fixed)
        .ok_or_else(|| format!("{s:?}: expected auto, 0, 1, 2 or 3"))
}

/// `--budget-*` (characterize, evaluate): how many cell references and bytes the grid and the kd-tree may need
/// before a policy drops them ([`Budget`]; the bounds are computed from the mesh before anything is built).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct BudgetArgs {
    /// Budget: cell references per triangle the kd-tree may need, and the grid too when given (either kd-tree flag
    /// gives the grid both of the kd-tree's limits), at most the builders' own 64; a structure whose bound exceeds the budget is no candidate, and the report lists it under
    /// excluded with the numbers [default: 16 for the kd-tree; for the grid, whose build the calibrated policy
    /// prices by its references counted exactly, the builder's own 64]
    #[arg(long, value_name = "R", value_parser = budget_per_triangle)]
    pub budget_references_per_triangle: Option<f64>,
    /// Budget: cell references always allowed, however few the triangles, for the kd-tree, and the grid too when
    /// given, at most the builders' own 2^25 [default: 4194304 for the kd-tree, 33554432 for the grid]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(..=Budget::BUILDERS.min_references))]
    pub budget_min_references: Option<u64>,
    /// Budget: the grid's cell references per triangle, whatever --budget-references-per-triangle says, at most the
    /// builder's own 64 [default: 64, or the kd-tree's when either kd-tree flag is given]
    #[arg(long, value_name = "R", value_parser = budget_per_triangle)]
    pub budget_grid_references_per_triangle: Option<f64>,
    /// Budget: the grid's cell references always allowed, whatever --budget-min-references says, at most the
    /// builder's own 2^25 [default: 33554432, or the kd-tree's when either kd-tree flag is given]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(..=Budget::BUILDERS.grid_min_references))]
    pub budget_grid_min_references: Option<u64>,
    /// Budget: bytes the grid or the kd-tree may need, at most the builders' own 4 GiB
    #[arg(long, value_name = "BYTES", default_value_t = Budget::default().max_bytes,
          value_parser = clap::value_parser!(u64).range(..=Budget::BUILDERS.max_bytes))]
    pub budget_bytes: u64,
}

/// `--budget-references-per-triangle`: a number in `[0, 64]`, the builders' own limit (a budget above it would keep
/// a grid or kd-tree whose build then fails).
fn budget_per_triangle(s: &str) -> Result<f64, String> {
    let most = Budget::BUILDERS.references_per_triangle;
    s.parse()
        .ok()
        .filter(|x: &f64| x.is_finite() && (0.0..=most).contains(x))
        .ok_or_else(|| format!("needs a number from 0 to {most}, the builders' own references per triangle"))
}

impl BudgetArgs {
    /// The budget the flags describe: [`Budget::default`] where none is given; a kd-tree flag sets the grid's limit
    /// too unless the grid's own flag is given.
    pub fn budget(&self) -> Budget {
        let d = Budget::default();
        let per = self.budget_references_per_triangle.unwrap_or(d.references_per_triangle);
        let least = self.budget_min_references.unwrap_or(d.min_references);
        // Either kd-tree flag given: the grid takes the kd-tree's resolved limits (both), unless its own are given.
        let kd_given = self.budget_references_per_triangle.is_some() || self.budget_min_references.is_some();
        let (grid_per, grid_least) =
            if kd_given { (per, least) } else { (d.grid_references_per_triangle, d.grid_min_references) };
        Budget {
            references_per_triangle: per,
            min_references: least,
            max_bytes: self.budget_bytes,
            grid_references_per_triangle: self.budget_grid_references_per_triangle.unwrap_or(grid_per),
            grid_min_references: self.budget_grid_min_references.unwrap_or(grid_least),
        }
    }
}

/// `--trace-backend` (calibrate, characterize, evaluate): where the workload's rays are traced.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct TraceBackendArg {
    /// Where the rays are traced: the CPU tracer, or the device traversal kernel (Vulkan); the calibrated
    /// policy uses the calibration of that tracer
    #[arg(long, value_name = "cpu|vulkan", default_value = "cpu", value_parser = trace_backend)]
    pub trace_backend: TraceBackend,
}

impl TraceBackendArg {
    /// A Vulkan context for `--trace-backend vulkan` (`None` for cpu); no device is an error.
    pub fn context(&self) -> anyhow::Result<Option<meshchar::gpu::Context>> {
        match self.trace_backend {
            TraceBackend::Cpu => Ok(None),
            TraceBackend::Vulkan => Ok(Some(
                meshchar::gpu::Context::new(&meshchar::gpu::ContextDesc::default())
                    .context("--trace-backend vulkan needs a Vulkan device")?,
            )),
        }
    }
}

/// The device record of a context for choosing a calibration (`None`: the CPU tracer).
pub fn device_record(ctx: Option<&meshchar::gpu::Context>) -> Option<DeviceRecord> {
    ctx.map(DeviceRecord::of)
}

/// The trace target of a device record (`None`: the CPU tracer).
pub fn trace_target(device: Option<&DeviceRecord>) -> TraceTarget<'_> {
    device.map_or(TraceTarget::Cpu, TraceTarget::Device)
}

/// `--trace-backend`: `cpu` or `vulkan`.
pub fn trace_backend(s: &str) -> Result<TraceBackend, String> {
    s.parse()
}

/// `--tie-margin` (evaluate, tradeoff).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct TieMarginArg {
    /// Calibrated policy: relative margin within which the cheaper build wins, in 0..=1
    #[arg(long, value_name = "X", default_value_t = 0.05, value_parser = tie_margin)]
    pub tie_margin: f64,
}

/// `--backend` of the characterization (characterize, failure_study, render_classes).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct BackendArg {
    /// The characterization backend [default: vulkan when a device is found, else cpu]
    #[arg(long, value_name = "B", value_parser = backend())]
    pub backend: Option<Backend>,
}

/// `--morton-bits` (characterize, render_classes).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct MortonBitsArg {
    /// Bits of the Morton codes
    #[arg(long, value_name = "B", default_value = "30", value_parser = morton_bits())]
    pub morton_bits: MortonBits,
}

/// `--workload` and `--resolution` of a ray-tracing workload (characterize, evaluate).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct WorkloadArgs {
    /// Kind of rays
    #[arg(long, value_name = "KIND", default_value = "primary", value_parser = workload())]
    pub workload: WorkloadKind,
    /// N x N primary rays per frame (for shadow and diffuse rays an upper bound, as only rays that hit spawn them)
    #[arg(long, value_name = "N", default_value_t = 1024, value_parser = resolution(1, 16384))]
    pub resolution: u32,
}

/// `vulkan`, `cpu` or `naive`.
pub fn backend() -> impl TypedValueParser<Value = Backend> {
    PossibleValuesParser::new(["vulkan", "cpu", "naive"]).map(|s| s.parse().expect("a possible value"))
}

/// `30` or `63`.
pub fn morton_bits() -> impl TypedValueParser<Value = MortonBits> {
    PossibleValuesParser::new(["30", "63"])
        .map(|s| s.parse().ok().and_then(MortonBits::from_total).expect("a possible value"))
}

/// `primary`, `shadow` or `diffuse`.
pub fn workload() -> impl TypedValueParser<Value = WorkloadKind> {
    PossibleValuesParser::new(["primary", "shadow", "diffuse"]).map(|s| s.parse().expect("a possible value"))
}

/// An image side in `lo..=hi`.
pub fn resolution(lo: u32, hi: u32) -> impl TypedValueParser<Value = u32> {
    clap::value_parser!(u32).range(lo as i64..=hi as i64)
}

/// A count `>= 1` (repeats, frames).
pub fn positive() -> impl TypedValueParser<Value = usize> {
    RangedU64ValueParser::<usize>::new().range(1..)
}

/// The most repeats (or rounds) a measuring tool takes: 10,000, far past any interval's need and short of a run
/// that never ends.
pub const MAX_REPEATS: u64 = 10_000;

/// A count of repeats in `1..=`[`MAX_REPEATS`].
pub fn repeats() -> impl TypedValueParser<Value = usize> {
    positive_max(MAX_REPEATS)
}

/// A count in `1..=max`.
pub fn positive_max(max: u64) -> impl TypedValueParser<Value = usize> {
    RangedU64ValueParser::<usize>::new().range(1..=max)
}

/// `doane`, `sturges`, `sqrt` or a fixed number of classes `>= 1`.
pub fn class_rule(s: &str) -> Result<ClassRule, String> {
    s.parse().map_err(|_| "must be doane, sturges, sqrt or a number of classes >= 1".to_string())
}

/// A structure name (`bvh`, `kdtree`, `grid`, `bih`, `lbvh`, `hlbvh`, `brute`).
pub fn structure(s: &str) -> Result<StructureName, String> {
    s.parse()
}

/// A share of the best predicted total in `0..=1`.
pub fn tie_margin(s: &str) -> Result<f64, String> {
    s.parse().ok().filter(|x: &f64| (0.0..=1.0).contains(x)).ok_or_else(|| "needs a number in 0..=1".into())
}

/// A finite number above zero (`--max-tests-per-ray`).
pub fn positive_number(s: &str) -> Result<f64, String> {
    s.parse().ok().filter(|x: &f64| x.is_finite() && *x > 0.0).ok_or_else(|| "needs a positive number".into())
}

/// A finite number at least zero (`calibrate --ridge`).
pub fn nonnegative_number(s: &str) -> Result<f64, String> {
    s.parse().ok().filter(|x: &f64| x.is_finite() && *x >= 0.0).ok_or_else(|| "needs a finite number at least 0".into())
}

/// The significance of a test, in `(0, 1)`.
pub fn alpha(s: &str) -> Result<f64, String> {
    s.parse().ok().filter(|x: &f64| *x > 0.0 && *x < 1.0).ok_or_else(|| "needs a number in (0, 1)".into())
}

/// The value of a comma-separated list option (`--strides 1,2,4`): items trimmed, empty ones skipped, at least one.
/// A later occurrence of the option replaces an earlier one.
#[derive(Clone, Debug, PartialEq)]
pub struct List<T>(pub Vec<T>);

/// The value parser of a [`List`] whose items `item` parses (and whose possible values `--help` lists).
pub fn list<P: TypedValueParser>(item: P) -> ListParser<P> {
    ListParser(item)
}

/// See [`list`].
#[derive(Clone)]
pub struct ListParser<P>(P);

impl<P> TypedValueParser for ListParser<P>
where
    P: TypedValueParser,
    P::Value: Clone + Send + Sync + 'static,
{
    type Value = List<P::Value>;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        arg: Option<&clap::Arg>,
        value: &std::ffi::OsStr,
    ) -> Result<Self::Value, clap::Error> {
        let text = value.to_str().ok_or_else(|| clap::Error::new(clap::error::ErrorKind::InvalidUtf8).with_cmd(cmd))?;
        let items = text
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(|s| self.0.parse_ref(cmd, arg, std::ffi::OsStr::new(s)))
            .collect::<Result<Vec<_>, _>>()?;
        if items.is_empty() {
            let name = arg.and_then(|a| a.get_long()).map_or_else(|| "the list".to_string(), |l| format!("--{l}"));
            let msg = format!("{name} needs at least one value\n");
            return Err(clap::Error::raw(clap::error::ErrorKind::InvalidValue, msg).with_cmd(cmd));
        }
        Ok(List(items))
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = clap::builder::PossibleValue> + '_>> {
        self.0.possible_values()
    }
}

/// `--camera EX,EY,EZ,TX,TY,TZ[,FOV]`.
pub fn camera(s: &str) -> Result<meshchar::geom::Camera, String> {
    let v: Vec<f32> =
        s.split(',').map(|s| s.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|_| "needs numbers")?;
    if v.len() != 6 && v.len() != 7 {
        return Err("needs EX,EY,EZ,TX,TY,TZ[,FOV]".into());
    }
    let fov = v.get(6).copied().unwrap_or(45.0);
    meshchar::geom::Camera::look_at(
        glam::Vec3::new(v[0], v[1], v[2]),
        glam::Vec3::new(v[3], v[4], v[5]),
        glam::Vec3::Y,
        fov,
    )
    .ok_or_else(|| "eye equals target, view along +y, or bad field of view".into())
}

/// `--view`: a camera preset.
pub fn view(s: &str) -> Result<meshchar::trace::views::View, String> {
    meshchar::trace::views::View::from_name(s)
        .ok_or_else(|| format!("unknown view {s:?} (framing, inside, close-up, grazing)"))
}
