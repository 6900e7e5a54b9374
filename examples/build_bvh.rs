//! Builds a BVH over a mesh and prints its statistics.
//!
//! `cargo run --release --example build_bvh -- FILE [--builder lbvh|hlbvh|sah] [--backend vulkan|cpu]
//! [--max-leaf N] [--cluster-bits B] [--json]` (`--help` explains each).

use clap::Parser;
use cli::args::JsonArg;
use meshchar::accel::bvh::{Bvh, BvhTree};
use meshchar::accel::gpu::{BvhBuilder, MAX_GPU_CLUSTER_BITS};
use meshchar::accel::hlbvh::{Hlbvh, HlbvhOptions};
use meshchar::accel::lbvh::{Lbvh, LbvhOptions, MAX_COLLAPSE_LEAF};
use meshchar::accel::AccelStructure;
use meshchar::gpu::MeshBuffers;
use meshchar::gpu::{Context, ContextDesc};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[path = "support/cli.rs"]
mod cli;

/// Builds a BVH over a mesh and prints its statistics, with the time of each GPU pass.
#[derive(Parser, Debug)]
#[command(name = "build_bvh", args_override_self = true)]
#[command(mut_arg("json", |a| a.help("One JSON object instead of text")))]
struct Args {
    /// A mesh (OBJ or PLY), or a generated scene: family:NAME:TRIANGLES[:SEED] or degenerate:NAME:TRIANGLES[:SEED]
    #[arg(value_name = "FILE")]
    file: PathBuf,
    /// The builder
    #[arg(long, value_enum, value_name = "B", default_value_t = Builder::Lbvh)]
    builder: Builder,
    /// The builder's backend [default: vulkan for lbvh and hlbvh, cpu for sah]
    #[arg(long, value_enum, value_name = "B")]
    backend: Option<BuildBackend>,
    /// LBVH/HLBVH: largest leaf of the SAH leaf collapse, 1 = off [default: lbvh 1, hlbvh 8]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_COLLAPSE_LEAF)))]
    max_leaf: Option<u32>,
    /// HLBVH: top Morton bits defining a cluster [default: 21]
    #[arg(long, value_name = "B", value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_GPU_CLUSTER_BITS)))]
    cluster_bits: Option<u32>,
    #[command(flatten)]
    json: JsonArg,
}

/// `--builder`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Builder {
    /// Karras 2012 (LBVH)
    Lbvh,
    /// Pantaleoni and Luebke 2010 (HLBVH)
    Hlbvh,
    /// CPU binned SAH; always the CPU backend
    Sah,
}

/// `--backend` of a build: no naive path here.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum BuildBackend {
    /// Vulkan compute
    Vulkan,
    /// The CPU reference builders
    Cpu,
}

impl Builder {
    fn as_str(self) -> &'static str {
        match self {
            Builder::Lbvh => "lbvh",
            Builder::Hlbvh => "hlbvh",
            Builder::Sah => "sah",
        }
    }
}

fn main() -> ExitCode {
    cli::main_with(run)
}

fn run(args: Args) -> anyhow::Result<()> {
    let builder = args.builder;
    let backend =
        args.backend.unwrap_or(if builder == Builder::Sah { BuildBackend::Cpu } else { BuildBackend::Vulkan });
    if builder == Builder::Sah && backend != BuildBackend::Cpu {
        cli::usage_error::<Args>(
            clap::error::ErrorKind::ArgumentConflict,
            "the sah builder runs on the CPU only (--backend cpu)",
        );
    }
    let mut lo = LbvhOptions::default();
    let mut ho = HlbvhOptions::default();
    if let Some(m) = args.max_leaf {
        lo.max_leaf = m;
        ho.max_leaf = m;
    }
    if let Some(b) = args.cluster_bits {
        ho.cluster_bits = b;
    }
    let file = &args.file;
    let mesh = cli::load_mesh_checked(file, cli::BUILD_BYTES_PER_TRIANGLE)?;
    let mut passes: Vec<(String, f64)> = Vec::new();
    let (tree, build_ms): (BvhTree, f64) = if backend == BuildBackend::Cpu {
        let t = Instant::now();
        let tree = match builder {
            Builder::Lbvh => Lbvh::build_with(&mesh, &lo).map(|b| b.tree().clone()),
            Builder::Hlbvh => Hlbvh::build_with(&mesh, &ho).map(|b| b.tree().clone()),
            Builder::Sah => Bvh::build(&mesh).map(|b| b.tree().clone()),
        }?;
        (tree, t.elapsed().as_secs_f64() * 1e3)
    } else {
        let ctx = Context::new(&ContextDesc::default())?;
        let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices)?;
        let mut b = BvhBuilder::new(&ctx)?;
        // One warm-up build (pipelines, allocations), then the measured one.
        let build = |b: &mut BvhBuilder| match builder {
            Builder::Hlbvh => b.build_hlbvh(&buffers.view(), &ho),
            _ => b.build_lbvh(&buffers.view(), &lo),
        };
        build(&mut b)?;
        let t = Instant::now();
        let gpu = build(&mut b)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        passes = gpu.timings().to_vec();
        (gpu.read_back(&ctx, &buffers)?, ms)
    };
    let (valid, stats) = match tree.validate("build_bvh") {
        Ok(s) => (true, Some(s)),
        Err(e) => {
            eprintln!("build_bvh: validation failed: {e}");
            (false, None)
        }
    };
    let nodes = tree.nodes().len();
    let leaves = tree.nodes().iter().filter(|n| n.is_leaf()).count();
    let depth = stats.as_ref().map_or(0, |s| s.max_depth);
    let sah = tree.sah_cost();
    let (builder, backend) = (builder.as_str(), if backend == BuildBackend::Cpu { "cpu" } else { "vulkan" });
    if args.json.json {
        let v = serde_json::json!({
            "builder": builder, "backend": backend, "triangles": mesh.triangle_count(), "nodes": nodes,
            "leaves": leaves, "depth": depth, "sah_cost": sah, "valid": valid, "build_ms": build_ms,
            "passes_ms": passes.iter().map(|(n, ms)| serde_json::json!({"pass": n, "ms": ms})).collect::<Vec<_>>(),
        });
        println!("{v}");
    } else {
        println!("builder    {builder}\nbackend    {backend}\ntriangles  {}", mesh.triangle_count());
        println!(
            "nodes      {nodes}\nleaves     {leaves}\ndepth      {depth}\nsah_cost   {sah:.3}\nvalid      {valid}"
        );
        println!("build_ms   {build_ms:.2}");
        for (n, ms) in &passes {
            println!("  {n:12} {ms:.3} ms");
        }
    }
    anyhow::ensure!(valid, "the tree failed validation");
    Ok(())
}
