//! One part of the device measurements of `scripts/device_bench`, as one JSON object on standard output.
//!
//! `device_bench PART [--quick] [--mesh NAME=FILE ...] [--rounds R]` with PART one of `characterize`, `sort`,
//! `lbvh`, `hlbvh`, `trace`. Every figure is a median of `--rounds` runs (default 5; 3 with `--quick`); GPU times
//! are the passes' timestamps, wall times the host's clock around the call. Each GPU result is checked against the
//! CPU reference in the same run (`agrees`), so that a fast wrong kernel shows. `--quick` is the size CI runs on
//! lavapipe: small generated meshes and few keys and rays.
//!
//! Meshes: every `--mesh NAME=FILE` (OBJ or PLY), then generated ones: the embedded bunny subdivided up to the
//! largest size of the part (`bunny-sub1` 4x, `bunny-sub2` 16x, ...), and random soups.

use clap::Parser;
use meshchar::accel::device_trace::{DeviceStructure, DeviceTracer, TraceRay};
use meshchar::accel::gpu::BvhBuilder;
use meshchar::accel::hlbvh::{Hlbvh, HlbvhOptions};
use meshchar::accel::lbvh::{Lbvh, LbvhOptions};
use meshchar::accel::{build_structure, AccelStructure, StructureName};
use meshchar::characterize::vulkan::VulkanBackend;
use meshchar::characterize::{cpu, Params};
use meshchar::geom::{Camera, WorkloadKind};
use meshchar::gpu::sort::{KeyBits, RadixSort, SortConfig, SortStorage};
use meshchar::gpu::{Context, ContextDesc, MemoryKind, MeshBuffers, Timer};
use meshchar::mesh::{generate, load_mesh, Mesh};
use meshchar::trace::workload::{build_workload, mesh_bounds};
use meshchar::trace::{trace, RaySet};
use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[path = "support/cli.rs"]
mod cli;

/// One part of the device measurements, as one JSON object (see `scripts/device_bench`).
#[derive(Parser, Debug)]
#[command(name = "device_bench", args_override_self = true)]
struct Args {
    /// The part to measure
    #[arg(value_enum)]
    part: Part,
    /// The small sizes CI runs on lavapipe
    #[arg(long)]
    quick: bool,
    /// A mesh to measure, as NAME=FILE (repeatable); generated meshes follow
    #[arg(long, value_name = "NAME=FILE")]
    mesh: Vec<String>,
    /// Timed runs per figure (the median is reported) [default: 5, 3 with --quick]
    #[arg(long, value_name = "R", value_parser = clap::value_parser!(u32).range(1..=1000))]
    rounds: Option<u32>,
    /// Largest mesh the part generates, in triangles [default: 16M, for trace 1M; 20K with --quick]
    #[arg(long, value_name = "N")]
    max_triangles: Option<u64>,
}

/// `PART`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Part {
    /// The characterization, per pass, beside the CPU path
    Characterize,
    /// The radix sort of key-value pairs, beside the device's copy bandwidth
    Sort,
    /// The device LBVH build, beside the CPU LBVH
    Lbvh,
    /// The device HLBVH build, beside the CPU HLBVH
    Hlbvh,
    /// Traversal of every structure, primary, shadow and diffuse rays
    Trace,
}

fn main() -> ExitCode {
    cli::main_with(run)
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The meshes of a part: the named files, then the embedded bunny subdivided while it stays at most `max`
/// triangles (every level from `min` up), then random soups of the thesis's Table 5.3 sizes up to `max`.
fn meshes(args: &Args, min: u64, max: u64, soups: bool) -> anyhow::Result<Vec<(String, Mesh)>> {
    let mut out = Vec::new();
    for spec in &args.mesh {
        let (name, file) = spec.split_once('=').ok_or_else(|| anyhow::anyhow!("--mesh {spec}: expected NAME=FILE"))?;
        let mesh = load_mesh(&PathBuf::from(file)).map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
        out.push((name.to_string(), mesh));
    }
    let base = meshchar::mesh::default_scene();
    let mut level = 0;
    let mut m = base.clone();
    while (m.triangle_count() as u64) <= max {
        if m.triangle_count() as u64 >= min {
            out.push((format!("bunny-lowres-sub{level}"), m.clone()));
        }
        if (m.triangle_count() as u64) * 4 > max {
            break;
        }
        level += 1;
        m = generate::subdivide(&base, level)?;
    }
    if soups {
        for n in [6_146u64, 20_482, 279_163, 935_236, 2_210_673] {
            if n <= max && n >= min.min(6_146) {
                out.push((format!("soup-{n}"), generate::random_soup(n as usize, n)));
            }
        }
    }
    Ok(out)
}

fn context() -> anyhow::Result<Context> {
    Context::new(&ContextDesc::default()).map_err(|e| anyhow::anyhow!("no Vulkan device: {e}"))
}

fn device_json(ctx: &Context) -> Value {
    let c = ctx.caps();
    json!({"name": c.name, "type": c.device_type.as_str(), "driver": c.driver, "api": c.api_version,
           "subgroup_size": c.subgroup_size})
}

fn run(args: Args) -> anyhow::Result<()> {
    let rounds = args.rounds.unwrap_or(if args.quick { 3 } else { 5 }) as usize;
    let max = args.max_triangles.unwrap_or(if args.quick { 20_000 } else { 16_000_000 });
    // The meshes first, so that a bad file is named before any device is looked for.
    let list = match args.part {
        Part::Characterize => meshes(&args, 0, max, true)?,
        Part::Sort => Vec::new(),
        Part::Lbvh | Part::Hlbvh => meshes(&args, 1_000, max, false)?,
        Part::Trace => {
            let limit = args.max_triangles.unwrap_or(if args.quick { 20_000 } else { 1_000_000 });
            meshes(&args, if args.quick { 1_000 } else { 50_000 }, limit, false)?
        }
    };
    let ctx = context()?;
    let t = Instant::now();
    let mut out = match args.part {
        Part::Characterize => characterize(&ctx, &list, rounds)?,
        Part::Sort => sort(&ctx, args.quick, rounds)?,
        Part::Lbvh | Part::Hlbvh => build(&ctx, &list, rounds, args.part)?,
        Part::Trace => trace_part(&ctx, &list, args.quick, rounds)?,
    };
    out["device"] = device_json(&ctx);
    out["rounds"] = json!(rounds);
    out["cpu_threads"] = json!(rayon::current_num_threads());
    out["wall_s"] = json!(t.elapsed().as_secs_f64());
    println!("{}", serde_json::to_string(&out)?);
    Ok(())
}

fn characterize(ctx: &Context, meshes: &[(String, Mesh)], rounds: usize) -> anyhow::Result<Value> {
    let mut vk = VulkanBackend::new(ctx)?;
    let params = Params::default();
    let mut rows = Vec::new();
    for (name, mesh) in meshes {
        let reference = cpu::fast(mesh, &params)?;
        let (mut cpu_ms, mut gpu_ms, mut wall_ms) = (Vec::new(), Vec::new(), Vec::new());
        let mut passes: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
        let mut agrees = true;
        vk.characterize(mesh, &params)?; // pipelines and buffers warm
        for _ in 0..rounds {
            let t = Instant::now();
            let c = cpu::fast(mesh, &params)?;
            cpu_ms.push(ms_since(t));
            agrees &= c.same_result(&reference);
            let t = Instant::now();
            let g = vk.characterize(mesh, &params)?;
            wall_ms.push(ms_since(t));
            agrees &= g.same_result(&reference);
            let mut sum = 0.0;
            for p in g.timings.iter().filter(|p| p.name != "total" && p.name != "upload") {
                passes.entry(p.name.clone()).or_default().push(p.ms);
                sum += p.ms;
            }
            gpu_ms.push(sum);
        }
        let passes: serde_json::Map<String, Value> = passes.into_iter().map(|(k, v)| (k, json!(median(v)))).collect();
        rows.push(json!({"mesh": name, "triangles": mesh.triangle_count(), "gpu_ms": median(gpu_ms),
            "wall_ms": median(wall_ms), "cpu_ms": median(cpu_ms), "passes_gpu_ms": passes, "agrees": agrees}));
    }
    Ok(json!({"meshes": rows}))
}

/// GB/s of a device-local copy (bytes read plus bytes written over the GPU time), the reference the sort's
/// traffic is set against.
fn copy_gbs(ctx: &Context, bytes: u64, rounds: usize) -> anyhow::Result<f64> {
    let a = ctx.create_buffer("copy source", bytes, MemoryKind::DeviceLocal)?;
    let b = ctx.create_buffer("copy target", bytes, MemoryKind::DeviceLocal)?;
    let mut timer = Timer::new(ctx, 2)?;
    let mut times = Vec::new();
    for _ in 0..rounds.max(3) {
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut timer);
            rec.timestamp(&mut timer, "start");
            rec.copy(&a, 0, &b, 0, bytes);
            rec.timestamp(&mut timer, "copy");
            Ok(())
        })?;
        times.push(timer.read()?.iter().map(|(_, ms)| ms).sum::<f64>());
    }
    Ok(2.0 * bytes as f64 / (median(times) * 1e-3) / 1e9)
}

fn sort(ctx: &Context, quick: bool, rounds: usize) -> anyhow::Result<Value> {
    let config = SortConfig::for_device(ctx.caps());
    let sort = RadixSort::new(ctx, config)?;
    let logs: Vec<u32> = if quick { vec![10, 14] } else { vec![20, 22, 24, 26, 28] };
    let bandwidth = copy_gbs(ctx, if quick { 1 << 22 } else { 1 << 30 }, rounds)?;
    let mut timer = Timer::new(ctx, 2)?;
    let mut rows = Vec::new();
    for log2 in logs {
        let n = 1u64 << log2;
        let mut rng = meshchar::rng::SplitMix64::new(u64::from(log2));
        let keys: Vec<u32> = (0..n).map(|_| rng.next_u64() as u32).collect();
        let mem = sort.memory_requirements(n, KeyBits::U32);
        let storage = match SortStorage::new(ctx, &mem, true) {
            Ok(s) => s,
            Err(e) => {
                rows.push(json!({"pairs": n, "skipped": e.to_string()}));
                continue;
            }
        };
        let pristine = ctx.upload("keys", &keys)?;
        let order: Vec<u32> = (0..n as u32).collect();
        let pristine_payload = ctx.upload("payload", &order)?;
        let (payload, _) = storage.payload.as_ref().ok_or_else(|| anyhow::anyhow!("sort storage without payload"))?;
        let mut times = Vec::new();
        for _ in 0..rounds {
            ctx.submit_and_wait(|rec| {
                rec.copy(&pristine, 0, &storage.keys, 0, 4 * n);
                rec.copy(&pristine_payload, 0, payload, 0, 4 * n);
                rec.reset_timer(&mut timer);
                rec.barrier();
                rec.timestamp(&mut timer, "start");
                sort.record(rec, &storage.buffers(), n, KeyBits::U32)?;
                rec.timestamp(&mut timer, "sort");
                Ok(())
            })?;
            times.push(timer.read()?.iter().map(|(_, ms)| ms).sum::<f64>());
        }
        // Check the last sort against the CPU's stable sort of the same pairs.
        let got_keys: Vec<u32> = ctx.read_buffer(&storage.keys, 0, n as usize)?;
        let got_payload: Vec<u32> = ctx.read_buffer(payload, 0, n as usize)?;
        let mut want: Vec<(u32, u32)> = keys.iter().copied().zip(0u32..).collect();
        want.sort_by_key(|p| p.0);
        let agrees = want.iter().zip(got_keys.iter().zip(&got_payload)).all(|(w, (k, p))| w.0 == *k && w.1 == *p);
        let t = Instant::now();
        let mut pairs: Vec<(u32, u32)> = keys.iter().copied().zip(0u32..).collect();
        use rayon::slice::ParallelSliceMut;
        pairs.par_sort_by_key(|p| p.0);
        let cpu_ms = ms_since(t);
        let ms = median(times);
        let pairs_per_s = n as f64 / (ms * 1e-3);
        // One read and one write of every key and payload (16 bytes a pair): the least traffic of any sort.
        let one_pass_gbs = 16.0 * n as f64 / (ms * 1e-3) / 1e9;
        rows.push(json!({"pairs": n, "gpu_ms": ms, "pairs_per_s": pairs_per_s, "cpu_par_sort_ms": cpu_ms,
            "one_pass_gbs": one_pass_gbs, "one_pass_share_of_copy": one_pass_gbs / bandwidth, "agrees": agrees}));
    }
    Ok(json!({"config": format!("{config:?}"), "copy_gbs": bandwidth, "sizes": rows}))
}

fn build(ctx: &Context, meshes: &[(String, Mesh)], rounds: usize, part: Part) -> anyhow::Result<Value> {
    let mut builder = BvhBuilder::new(ctx)?;
    let mut rows = Vec::new();
    for (name, mesh) in meshes {
        let buffers = MeshBuffers::upload(ctx, &mesh.positions, &mesh.indices)?;
        let (mut wall, mut gpu, mut top, mut cpu_ms) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut last = None;
        for r in 0..=rounds {
            let t = Instant::now();
            let bvh = match part {
                Part::Lbvh => builder.build_lbvh(&buffers.view(), &LbvhOptions::default())?,
                _ => builder.build_hlbvh(&buffers.view(), &HlbvhOptions::default())?,
            };
            let w = ms_since(t);
            if r > 0 {
                // The first build compiles nothing but touches every buffer the first time: left out.
                wall.push(w);
                gpu.push(bvh.timings().iter().filter(|(n, _)| n != "top_cpu").map(|(_, ms)| ms).sum());
                top.push(bvh.timings().iter().filter(|(n, _)| n == "top_cpu").map(|(_, ms)| ms).sum());
            }
            last = Some(bvh);
        }
        let t = Instant::now();
        let cpu_tree = match part {
            Part::Lbvh => Lbvh::build_with(mesh, &LbvhOptions::default())?.tree().clone(),
            _ => Hlbvh::build_with(mesh, &HlbvhOptions::default())?.tree().clone(),
        };
        cpu_ms.push(ms_since(t));
        let agrees = match last {
            Some(b) => b.read_back(ctx, &buffers)?.nodes() == cpu_tree.nodes(),
            None => false,
        };
        let n = mesh.triangle_count() as f64;
        let g = median(gpu);
        rows.push(json!({"mesh": name, "triangles": mesh.triangle_count(), "gpu_ms": g,
            "host_top_ms": median(top), "wall_ms": median(wall), "cpu_ms": median(cpu_ms),
            "gpu_mtris_per_s": n / (g * 1e-3) / 1e6, "agrees": agrees}));
    }
    Ok(json!({"meshes": rows}))
}

fn trace_part(ctx: &Context, meshes: &[(String, Mesh)], quick: bool, rounds: usize) -> anyhow::Result<Value> {
    let tracer = DeviceTracer::new(ctx)?;
    let sides: Vec<u32> = if quick { vec![64] } else { vec![1024, 2048, 4096] };
    let mut rows = Vec::new();
    for (name, mesh) in meshes {
        let cam = Camera::frame(&mesh_bounds(mesh));
        let reference = build_structure(StructureName::Lbvh, mesh)?;
        let structures: Vec<(StructureName, Box<dyn AccelStructure>)> =
            StructureName::ALL.iter().filter_map(|&s| Some((s, build_structure(s, mesh).ok()?))).collect();
        for kind in [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
            for &side in &sides {
                // Secondary rays at the two smaller sizes: their CPU reference pass is the long part.
                if kind != WorkloadKind::Primary && side > 2048 {
                    continue;
                }
                let rays: RaySet = build_workload(kind, mesh, &cam, side, reference.as_ref());
                let dev_rays: Vec<TraceRay> = rays.rays.iter().map(TraceRay::from).collect();
                let cpu_check = side <= 1024;
                let cpu = cpu_check.then(|| trace(reference.as_ref(), &rays));
                for (s, accel) in &structures {
                    let Some(layout) = accel.device_layout() else { continue };
                    let mut d = DeviceStructure::upload(ctx, &layout)?;
                    let first = tracer.trace(ctx, &mut d, &dev_rays, rays.any_hit)?;
                    let agrees = cpu.as_ref().map(|c| {
                        if rays.any_hit {
                            c.occluded.iter().zip(&first.hits).all(|(o, h)| *o == h.hit().is_some())
                        } else {
                            c.hits.iter().zip(&first.hits).all(|(a, h)| meshchar::geom::hits_agree(a, &h.hit()))
                        }
                    });
                    let mut times = Vec::new();
                    for _ in 0..rounds {
                        times.push(tracer.trace(ctx, &mut d, &dev_rays, rays.any_hit)?.gpu_ms);
                    }
                    let ms = median(times);
                    rows.push(json!({"mesh": name, "triangles": mesh.triangle_count(), "structure": s.as_str(),
                        "workload": kind.as_str(), "rays": dev_rays.len(), "gpu_ms": ms,
                        "mrays_per_s": dev_rays.len() as f64 / (ms * 1e-3) / 1e6, "agrees": agrees}));
                }
            }
        }
    }
    Ok(json!({"runs": rows}))
}
