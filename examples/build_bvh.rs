//! Builds a BVH over a mesh and prints its statistics.
//!
//! `cargo run --release --example build_bvh -- FILE [--builder lbvh|hlbvh|sah] [--backend vulkan|cpu]
//! [--max-leaf N] [--cluster-bits B] [--json]`

use meshchar::accel::bvh::{Bvh, BvhTree};
use meshchar::accel::gpu::{BvhBuilder, MAX_GPU_CLUSTER_BITS};
use meshchar::accel::hlbvh::{Hlbvh, HlbvhOptions};
use meshchar::accel::lbvh::{Lbvh, LbvhOptions, MAX_COLLAPSE_LEAF};
use meshchar::accel::AccelStructure;
use meshchar::gpu::MeshBuffers;
use meshchar::gpu::{Context, ContextDesc};
use std::time::Instant;

#[path = "support/cli.rs"]
mod cli;

const USAGE: &str = "usage: build_bvh FILE [--builder lbvh|hlbvh|sah] [--backend vulkan|cpu] [--max-leaf N]
                 [--cluster-bits B] [--json]
  FILE            a mesh (OBJ or PLY)
  --builder       lbvh (default), hlbvh, or sah (CPU binned SAH; always the CPU backend)
  --backend       vulkan (default for lbvh and hlbvh) or cpu (the CPU reference builders)
  --max-leaf      LBVH/HLBVH: largest leaf of the SAH leaf collapse, 1 = off (defaults: lbvh 1, hlbvh 8)
  --cluster-bits  HLBVH: top Morton bits defining a cluster (default 21)
  --json          one JSON object instead of text";

fn main() {
    cli::exit_quietly_on_broken_pipe();
    if let Err(e) = run() {
        eprintln!("build_bvh: {e}");
        std::process::exit(2);
    }
}

fn run() -> Result<(), String> {
    let mut file = None;
    let mut builder = "lbvh".to_string();
    let mut backend = None;
    let mut json = false;
    let mut max_leaf: Option<u32> = None;
    let mut cluster_bits: Option<u32> = None;
    let number = |flag: &str, v: Option<String>| -> Result<u32, String> {
        let v = v.ok_or(format!("{flag} needs a value"))?;
        v.parse().map_err(|_| format!("{flag}: {v:?} is not a non-negative integer"))
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "-h" | "--help" => {
                println!("{USAGE}");
                return Ok(());
            }
            "--builder" => builder = args.next().ok_or("--builder needs a value")?,
            "--backend" => backend = Some(args.next().ok_or("--backend needs a value")?),
            "--json" => json = true,
            "--max-leaf" => max_leaf = Some(number("--max-leaf", args.next())?),
            "--cluster-bits" => cluster_bits = Some(number("--cluster-bits", args.next())?),
            s if s.starts_with('-') => return Err(format!("unknown option {s}\n{USAGE}")),
            s => file = Some(s.to_string()),
        }
    }
    let file = file.ok_or(format!("no mesh file given\n{USAGE}"))?;
    if !["lbvh", "hlbvh", "sah"].contains(&builder.as_str()) {
        return Err(format!("unknown builder {builder} (lbvh, hlbvh or sah)"));
    }
    let backend = backend.unwrap_or_else(|| if builder == "sah" { "cpu".into() } else { "vulkan".into() });
    if !["vulkan", "cpu"].contains(&backend.as_str()) {
        return Err(format!("unknown backend {backend} (vulkan or cpu)"));
    }
    if builder == "sah" && backend != "cpu" {
        return Err("the sah builder runs on the CPU only (--backend cpu)".into());
    }
    let mut lo = LbvhOptions::default();
    let mut ho = HlbvhOptions::default();
    if let Some(m) = max_leaf {
        if m == 0 || m > MAX_COLLAPSE_LEAF {
            return Err(format!("--max-leaf must be 1 to {MAX_COLLAPSE_LEAF}"));
        }
        lo.max_leaf = m;
        ho.max_leaf = m;
    }
    if let Some(b) = cluster_bits {
        if b == 0 || b > MAX_GPU_CLUSTER_BITS {
            return Err(format!("--cluster-bits must be 1 to {MAX_GPU_CLUSTER_BITS}"));
        }
        ho.cluster_bits = b;
    }
    let mesh = meshchar::mesh::load::load_mesh(std::path::Path::new(&file)).map_err(|e| e.to_string())?;
    let mut passes: Vec<(String, f64)> = Vec::new();
    let (tree, build_ms): (BvhTree, f64) = if backend == "cpu" {
        let t = Instant::now();
        let tree = match builder.as_str() {
            "lbvh" => Lbvh::build_with(&mesh, &lo).map(|b| b.tree().clone()),
            "hlbvh" => Hlbvh::build_with(&mesh, &ho).map(|b| b.tree().clone()),
            _ => Bvh::build(&mesh).map(|b| b.tree().clone()),
        }
        .map_err(|e| e.to_string())?;
        (tree, t.elapsed().as_secs_f64() * 1e3)
    } else {
        let ctx = Context::new(&ContextDesc::default()).map_err(|e| e.to_string())?;
        let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).map_err(|e| e.to_string())?;
        let mut b = BvhBuilder::new(&ctx).map_err(|e| e.to_string())?;
        // One warm-up build (pipelines, allocations), then the measured one.
        let build = |b: &mut BvhBuilder| match builder.as_str() {
            "lbvh" => b.build_lbvh(&buffers, &lo),
            _ => b.build_hlbvh(&buffers, &ho),
        };
        build(&mut b).map_err(|e| e.to_string())?;
        let t = Instant::now();
        let gpu = build(&mut b).map_err(|e| e.to_string())?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        passes = gpu.timings().to_vec();
        (gpu.read_back(&ctx, &buffers).map_err(|e| e.to_string())?, ms)
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
    if json {
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
    if valid {
        Ok(())
    } else {
        Err("the tree failed validation".into())
    }
}
