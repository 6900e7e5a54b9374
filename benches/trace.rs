//! Device traversal benches (`glsl/trace.comp`) beside the CPU tracer.
//!
//! * `device_trace/<scene>/<structure>`: primary rays at 256 x 256 through every structure on the Vulkan device;
//!   the time is the traversal dispatch's GPU timestamps (`iter_custom`), not the upload or the read-back; criterion's
//!   throughput is rays per second.
//! * `side_by_side`: one run that prints, per scene and structure, the CPU tracer's Mrays/s (rayon over rays, host
//!   wall time) and the device kernel's Mrays/s (GPU timestamps), medians of 5 measured alternately, and their ratio.
//!
//! On lavapipe the kernel runs on the same CPU cores as the CPU tracer: its figures are a CPU driver's, not GPU
//! speed. Scenes: bunny, dragon, Sponza, conference from `../shared/meshes` (the bench fails naming the path when
//! one is missing). Run: `cargo bench --bench trace` (filter with e.g. `-- side_by_side`). MESHCHAR_DEVICE picks
//! the device.

mod common;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use meshchar::accel::device_trace::{DeviceStructure, DeviceTracer, TraceRay};
use meshchar::accel::{build_structure, AccelStructure, StructureName};
use meshchar::geom::Camera;
use meshchar::geom::WorkloadKind;
use meshchar::gpu::{Context, ContextDesc};
use meshchar::mesh::Mesh;
use meshchar::trace::workload::{mesh_bounds, primary_rays};
use meshchar::trace::{trace, RaySet};
use std::time::Duration;

const SCENES: [(&str, &str); 4] = [
    ("bunny", "stanford-bunny/bun_zipper.ply"),
    ("dragon", "stanford-dragon/dragon_vrip.ply"),
    ("sponza", "dabrovic-sponza/sponza.obj"),
    ("conference", "conference/conference.obj"),
];

const RES: u32 = 256;

fn rays_for(mesh: &Mesh) -> RaySet {
    let cam = Camera::frame(&mesh_bounds(mesh));
    RaySet { kind: WorkloadKind::Primary, rays: primary_rays(&cam, RES, RES), any_hit: false }
}

fn context() -> Context {
    Context::new(&ContextDesc::default())
        .expect("the trace bench needs a Vulkan device (lavapipe: mesa-vulkan-drivers)")
}

/// Every structure that builds on `mesh`, uploaded.
fn uploaded(ctx: &Context, mesh: &Mesh) -> Vec<(StructureName, Box<dyn AccelStructure>, DeviceStructure)> {
    StructureName::ALL
        .iter()
        .filter_map(|&name| {
            let s = build_structure(name, mesh).ok()?;
            let d = DeviceStructure::upload(ctx, &s.device_layout()?).expect("upload");
            Some((name, s, d))
        })
        .collect()
}

fn device_trace(c: &mut Criterion) {
    let ctx = context();
    let tracer = DeviceTracer::new(&ctx).expect("device tracer");
    let mut g = c.benchmark_group("device_trace");
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    for (scene, rel) in SCENES {
        let mesh = common::load_shared(rel);
        let rays = rays_for(&mesh);
        let dev_rays: Vec<TraceRay> = rays.rays.iter().map(TraceRay::from).collect();
        g.throughput(Throughput::Elements(rays.rays.len() as u64));
        for (name, _, mut d) in uploaded(&ctx, &mesh) {
            // Warm (lavapipe compiles the pipeline at its first dispatch).
            tracer.trace(&ctx, &mut d, &dev_rays, false).expect("trace");
            g.bench_function(BenchmarkId::new(scene, name.as_str()), |b| {
                b.iter_custom(|iters| {
                    let mut total = 0.0;
                    for _ in 0..iters {
                        total += tracer.trace(&ctx, &mut d, &dev_rays, false).expect("trace").gpu_ms;
                    }
                    Duration::from_secs_f64(total * 1e-3)
                })
            });
        }
    }
    g.finish();
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn side_by_side(_c: &mut Criterion) {
    let ctx = context();
    let tracer = DeviceTracer::new(&ctx).expect("device tracer");
    let caps = ctx.caps();
    println!(
        "\nside_by_side: primary rays {RES}x{RES}, Mrays/s, medians of 5 alternating runs; device {} ({}, {}); {} host threads",
        caps.name,
        caps.device_type.as_str(),
        caps.driver,
        rayon::current_num_threads()
    );
    println!("{:<11} {:<7} {:>10} {:>12} {:>8} {:>10}", "scene", "struct", "CPU", "device", "dev/CPU", "hits agree");
    for (scene, rel) in SCENES {
        let mesh = common::load_shared(rel);
        let rays = rays_for(&mesh);
        let dev_rays: Vec<TraceRay> = rays.rays.iter().map(TraceRay::from).collect();
        let n = rays.rays.len() as f64;
        for (name, s, mut d) in uploaded(&ctx, &mesh) {
            let warm = tracer.trace(&ctx, &mut d, &dev_rays, false).expect("trace");
            let cpu_out = trace(s.as_ref(), &rays);
            let agree = cpu_out.hits.iter().zip(&warm.hits).all(|(c, g)| meshchar::geom::hits_agree(c, &g.hit()));
            let (mut cpu, mut dev) = (Vec::new(), Vec::new());
            for _ in 0..5 {
                cpu.push(n / trace(s.as_ref(), &rays).seconds * 1e-6);
                dev.push(n / (tracer.trace(&ctx, &mut d, &dev_rays, false).expect("trace").gpu_ms * 1e-3) * 1e-6);
            }
            let (c, g) = (median(cpu), median(dev));
            println!("{scene:<11} {:<7} {c:>10.2} {g:>12.2} {:>8.2} {agree:>10}", name.as_str(), g / c);
        }
    }
}

criterion_group!(benches, side_by_side, device_trace);
criterion_main!(benches);
