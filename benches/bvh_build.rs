//! BVH build throughput and quality: the CPU binned-SAH BVH, the CPU LBVH and HLBVH references and the GPU LBVH and
//! HLBVH, on bunny, dragon res2, the full dragon and Sponza, with default options (LBVH: one triangle per leaf;
//! HLBVH: 21 cluster bits, SAH leaf collapse up to 8 triangles). Criterion groups time each build (GPU builds as
//! host wall time, which includes the two or three submissions, the bounds and cluster readbacks and, for the
//! HLBVH, the host's SAH top over the clusters); then a markdown table gives, per mesh and builder, the median wall
//! time and Mtris/s, for GPU builds also the sum of the per-pass GPU timestamps (`GpuBvh::timings`, `top_cpu`
//! excluded and listed apart) and its Mtris/s, and the SAH cost with its ratio to the binned-SAH BVH's.
//!
//! `cargo bench --bench bvh_build`. Without a Vulkan device (lavapipe on the CI machine) the GPU builders are
//! skipped with a printed line. `MESHCHAR_BENCH_MESHES=bunny,sponza` restricts the meshes (names: bunny,
//! dragon-res2, dragon, sponza).

mod common;

use common::load_shared as load;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, SamplingMode};
use meshchar::accel::bvh::{Bvh, BvhTree};
use meshchar::accel::gpu::{BvhBuilder, GpuBvh};
use meshchar::accel::hlbvh::{Hlbvh, HlbvhOptions};
use meshchar::accel::lbvh::{Lbvh, LbvhOptions};
use meshchar::gpu::MeshBuffers;
use meshchar::gpu::{Context, ContextDesc};
use meshchar::mesh::Mesh;
use std::time::{Duration, Instant};

const MESHES: [(&str, &str); 4] = [
    ("bunny", "stanford-bunny/bun_zipper.ply"),
    ("dragon-res2", "stanford-dragon/dragon_vrip_res2.ply"),
    ("dragon", "stanford-dragon/dragon_vrip.ply"),
    ("sponza", "dabrovic-sponza/sponza.obj"),
];

const BUILDERS: [&str; 5] = ["cpu_binned_sah", "cpu_lbvh", "cpu_hlbvh", "gpu_lbvh", "gpu_hlbvh"];

/// Timed runs per builder and mesh for the table.
const TABLE_RUNS: usize = 3;

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

struct Gpu {
    ctx: Context,
    builder: BvhBuilder,
}

/// One build: the tree (read back for GPU builds, outside the timed span), its wall ms, and for GPU builds the summed
/// GPU pass ms and the host top ms.
fn build(name: &str, mesh: &Mesh, gpu: Option<(&mut Gpu, &MeshBuffers)>) -> (BvhTree, f64, Option<(f64, f64)>) {
    let t = Instant::now();
    let cpu_tree = match name {
        "cpu_binned_sah" => Some(Bvh::build_with(mesh, &Default::default()).expect("bvh").tree().clone()),
        "cpu_lbvh" => Some(Lbvh::build_with(mesh, &LbvhOptions::default()).expect("lbvh").tree().clone()),
        "cpu_hlbvh" => Some(Hlbvh::build_with(mesh, &HlbvhOptions::default()).expect("hlbvh").tree().clone()),
        _ => None,
    };
    if let Some(tree) = cpu_tree {
        return (tree, t.elapsed().as_secs_f64() * 1e3, None);
    }
    let (g, buffers) = gpu.expect("a GPU build needs a device");
    let t = Instant::now();
    let bvh: GpuBvh = match name {
        "gpu_lbvh" => g.builder.build_lbvh(&buffers.view(), &LbvhOptions::default()),
        _ => g.builder.build_hlbvh(&buffers.view(), &HlbvhOptions::default()),
    }
    .expect("gpu build");
    let wall = t.elapsed().as_secs_f64() * 1e3;
    let device: f64 = bvh.timings().iter().filter(|(n, _)| n != "top_cpu").map(|(_, ms)| ms).sum();
    let top: f64 = bvh.timings().iter().filter(|(n, _)| n == "top_cpu").map(|(_, ms)| ms).sum();
    let tree = bvh.read_back(&g.ctx, buffers).expect("read back");
    (tree, wall, Some((device, top)))
}

fn benches(c: &mut Criterion) {
    let only: Option<Vec<String>> =
        std::env::var("MESHCHAR_BENCH_MESHES").ok().map(|s| s.split(',').map(|x| x.trim().to_string()).collect());
    let mut gpu = match Context::new(&ContextDesc::default()) {
        Ok(ctx) => {
            let caps = ctx.caps();
            println!("device: {} ({}, {})", caps.name, caps.device_type, caps.driver);
            let builder = BvhBuilder::new(&ctx).expect("bvh pipelines");
            Some(Gpu { ctx, builder })
        }
        Err(e) => {
            println!("no Vulkan device ({e}): GPU LBVH and HLBVH skipped, CPU builders only");
            None
        }
    };
    println!("threads: rayon {}", rayon::current_num_threads());
    let mut rows = Vec::new();
    for (short, rel) in MESHES {
        if only.as_ref().is_some_and(|o| !o.iter().any(|m| m == short)) {
            continue;
        }
        let mesh = load(rel);
        let n = mesh.triangle_count() as f64;
        let buffers =
            gpu.as_ref().map(|g| MeshBuffers::upload(&g.ctx, &mesh.positions, &mesh.indices).expect("upload"));
        let mut group = c.benchmark_group(format!("bvh_build/{short}"));
        group
            .sample_size(10)
            .sampling_mode(SamplingMode::Flat)
            .warm_up_time(Duration::from_millis(200))
            .measurement_time(Duration::from_secs(2));
        let mut sah_reference = f64::NAN;
        for name in BUILDERS {
            let on_gpu = name.starts_with("gpu");
            if on_gpu && gpu.is_none() {
                continue;
            }
            group.bench_function(BenchmarkId::new(name, mesh.triangle_count()), |b| {
                b.iter(|| build(name, &mesh, gpu.as_mut().zip(buffers.as_ref())).1)
            });
            let mut walls = Vec::new();
            let mut devices = Vec::new();
            let mut tops = Vec::new();
            let mut tree = BvhTree::default();
            for _ in 0..TABLE_RUNS {
                let (t, wall, dev) = build(name, &mesh, gpu.as_mut().zip(buffers.as_ref()));
                walls.push(wall);
                if let Some((d, top)) = dev {
                    devices.push(d);
                    tops.push(top);
                }
                tree = t;
            }
            tree.validate(name).unwrap_or_else(|e| panic!("{name} on {short}: {e}"));
            let sah = tree.sah_cost();
            if name == "cpu_binned_sah" {
                sah_reference = sah;
            }
            let wall = median(&mut walls);
            let device = (!devices.is_empty()).then(|| (median(&mut devices), median(&mut tops)));
            rows.push((short, n, name, wall, device, sah, sah / sah_reference, tree.nodes().len()));
        }
        group.finish();
    }
    println!("\nBVH builds, median of {TABLE_RUNS} runs (wall: host time of the whole build; GPU: sum of the pass");
    println!("timestamps; top: the HLBVH's host SAH top over the clusters, with its readback and upload)");
    println!("| mesh | triangles | builder | wall ms | Mtris/s (wall) | GPU ms | Mtris/s (GPU) | top ms | nodes | SAH cost | / binned SAH |");
    println!("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (mesh, n, name, wall, device, sah, ratio, nodes) in rows {
        let (gms, gmt, top) = match device {
            Some((d, t)) => (
                format!("{d:.1}"),
                format!("{:.2}", n / d / 1e3),
                if name == "gpu_hlbvh" { format!("{t:.1}") } else { "-".into() },
            ),
            None => ("-".into(), "-".into(), "-".into()),
        };
        println!(
            "| {mesh} | {n} | {name} | {wall:.1} | {:.2} | {gms} | {gmt} | {top} | {nodes} | {sah:.2} | {ratio:.3} |",
            n / wall / 1e3
        );
    }
}

criterion_group!(bvh_build_benches, benches);
criterion_main!(bvh_build_benches);
