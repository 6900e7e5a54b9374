//! Characterization benchmarks: the whole pipeline and each pass, for the naive reference, the rayon CPU path and
//! Vulkan, on bunny, dragon res2, the full dragon and Sponza; then the scaling from 1K triangles to the largest mesh
//! (the dragon subdivided). GPU figures are sums of the passes' timestamps (`iter_custom`), so they exclude the
//! host round trips between passes, which are reported separately as wall time.
//!
//! `cargo bench --bench characterize` (all), `-- whole` (only the meshes), `-- scaling` (only the scaling run).
//! Set `MESHCHAR_BENCH_NAIVE=0` to skip the slow naive path.

mod common;

use common::load_shared as load;
use criterion::{criterion_group, criterion_main, Criterion};
use meshchar::characterize::vulkan::VulkanBackend;
use meshchar::characterize::{cpu, Characterization, Params};
use meshchar::gpu::{Context, ContextDesc};
use meshchar::mesh::{generate, Mesh};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Pass times (ms) collected from every run of one backend on one mesh.
#[derive(Default)]
struct PassLog(BTreeMap<String, Vec<f64>>);

impl PassLog {
    fn add(&mut self, c: &Characterization) {
        for t in &c.timings {
            self.0.entry(t.name.clone()).or_default().push(t.ms);
        }
    }
    fn median(&mut self, pass: &str) -> f64 {
        self.0.get_mut(pass).map(|v| median(v)).unwrap_or(f64::NAN)
    }
}

fn gpu_ms(c: &Characterization) -> f64 {
    c.timings.iter().filter(|t| t.name != "total" && t.name != "upload").map(|t| t.ms).sum()
}

fn whole(crit: &mut Criterion) {
    let ctx = Context::new(&ContextDesc::default()).ok();
    let mut vk = ctx.as_ref().and_then(|c| VulkanBackend::new(c).ok());
    let naive = std::env::var("MESHCHAR_BENCH_NAIVE").map(|v| v != "0").unwrap_or(true);
    let params = Params::default();
    let meshes = [
        ("bunny", "stanford-bunny/bun_zipper.ply"),
        ("dragon_res2", "stanford-dragon/dragon_vrip_res2.ply"),
        ("dragon", "stanford-dragon/dragon_vrip.ply"),
        ("sponza", "dabrovic-sponza/sponza.obj"),
    ];
    let mut table = Vec::new();
    for (name, rel) in meshes {
        let mesh = load(rel);
        let mut group = crit.benchmark_group(format!("characterize/{name}"));
        group.sample_size(10).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_millis(500));
        let mut logs: BTreeMap<&str, PassLog> = BTreeMap::new();
        if naive {
            let log = logs.entry("naive").or_default();
            group.bench_function("naive", |b| {
                b.iter_custom(|iters| {
                    let t = Instant::now();
                    for _ in 0..iters {
                        log.add(&cpu::naive(&mesh, &params).expect("naive"));
                    }
                    t.elapsed()
                })
            });
        }
        let log = logs.entry("cpu").or_default();
        group.bench_function("cpu", |b| {
            b.iter_custom(|iters| {
                let t = Instant::now();
                for _ in 0..iters {
                    log.add(&cpu::fast(&mesh, &params).expect("cpu"));
                }
                t.elapsed()
            })
        });
        if let Some(vk) = vk.as_mut() {
            let mut gpu_times = Vec::new();
            let log = logs.entry("vulkan").or_default();
            group.bench_function("vulkan_gpu_time", |b| {
                b.iter_custom(|iters| {
                    let mut sum = 0.0;
                    for _ in 0..iters {
                        let c = vk.characterize(&mesh, &params).expect("vulkan");
                        sum += gpu_ms(&c);
                        gpu_times.push(gpu_ms(&c));
                        log.add(&c);
                    }
                    Duration::from_secs_f64(sum * 1e-3)
                })
            });
            logs.entry("vulkan").or_default().0.insert("gpu_passes".into(), gpu_times);
        }
        group.finish();
        for (backend, log) in logs.iter_mut() {
            let passes = ["keys_bounds", "morton_moments", "classes_histogram", "chi_square", "gpu_passes", "total"];
            let row: Vec<f64> = passes.iter().map(|p| log.median(p)).collect();
            table.push((name, backend.to_string(), mesh.triangle_count(), row));
        }
    }
    let device = ctx.as_ref().map(|c| c.caps().name.clone()).unwrap_or_else(|| "no Vulkan device".into());
    println!("\nmedian ms per pass ({}; Vulkan device: {device})", cpu::cpu_device_name(rayon::current_num_threads()));
    println!(
        "| mesh | triangles | backend | keys_bounds | morton_moments | classes_histogram | chi_square | GPU passes | total (wall) |"
    );
    println!("|---|---:|---|---:|---:|---:|---:|---:|---:|");
    for (name, backend, n, row) in &table {
        let f = |x: f64| if x.is_nan() { "-".to_string() } else { format!("{x:.3}") };
        println!(
            "| {name} | {n} | {backend} | {} | {} | {} | {} | {} | {} |",
            f(row[0]),
            f(row[1]),
            f(row[2]),
            f(row[3]),
            f(row[4]),
            f(row[5])
        );
    }
    println!("\nratios of total wall time, naive : cpu : vulkan (vulkan's GPU-pass time in parentheses)");
    for (name, ..) in meshes {
        let get = |b: &str, col: usize| {
            table.iter().find(|(m, bk, ..)| *m == name && bk == b).map(|r| r.3[col]).unwrap_or(f64::NAN)
        };
        let (nv, cp, vk_wall, vk_gpu) = (get("naive", 5), get("cpu", 5), get("vulkan", 5), get("vulkan", 4));
        println!(
            "{name}: {:.1} : 1 : {:.2} ({:.2}); naive/cpu = {:.1}x, cpu/vulkan wall = {:.2}x",
            nv / cp,
            vk_wall / cp,
            vk_gpu / cp,
            nv / cp,
            cp / vk_wall
        );
    }
}

fn scaling(crit: &mut Criterion) {
    let ctx = Context::new(&ContextDesc::default()).ok();
    let mut vk = ctx.as_ref().and_then(|c| VulkanBackend::new(c).ok());
    let params = Params::default();
    let dragon = load("stanford-dragon/dragon_vrip.ply");
    // Sizes from 1K: random soups below the dragon, then the dragon and its subdivisions (x4, x16).
    let mut meshes: Vec<(String, Mesh)> = [1usize << 10, 1 << 12, 1 << 14, 1 << 16, 1 << 18]
        .iter()
        .map(|&n| (format!("soup{n}"), generate::random_soup(n, 1)))
        .collect();
    meshes.push(("dragon".into(), dragon.clone()));
    for levels in 1..=2 {
        meshes.push((format!("dragon_sub{levels}"), generate::subdivide(&dragon, levels).expect("subdivide")));
    }
    println!("\nscaling: median ms and ns per triangle");
    println!("| mesh | triangles | cpu ms | cpu ns/tri | vulkan GPU ms | vulkan ns/tri |");
    println!("|---|---:|---:|---:|---:|---:|");
    let mut group = crit.benchmark_group("scaling");
    group.sample_size(10).measurement_time(Duration::from_secs(2)).warm_up_time(Duration::from_millis(200));
    for (name, mesh) in &meshes {
        let mut cpu_ms = Vec::new();
        group.bench_function(format!("cpu/{name}"), |b| {
            b.iter_custom(|iters| {
                let t = Instant::now();
                for _ in 0..iters {
                    let s = Instant::now();
                    cpu::fast(mesh, &params).expect("cpu");
                    cpu_ms.push(s.elapsed().as_secs_f64() * 1e3);
                }
                t.elapsed()
            })
        });
        let mut gpu = Vec::new();
        if let Some(vk) = vk.as_mut() {
            group.bench_function(format!("vulkan/{name}"), |b| {
                b.iter_custom(|iters| {
                    let mut sum = 0.0;
                    for _ in 0..iters {
                        let g = gpu_ms(&vk.characterize(mesh, &params).expect("vulkan"));
                        gpu.push(g);
                        sum += g;
                    }
                    Duration::from_secs_f64(sum * 1e-3)
                })
            });
        }
        let n = mesh.triangle_count() as f64;
        let (c, g) = (median(&mut cpu_ms), median(&mut gpu));
        println!("| {name} | {} | {c:.3} | {:.2} | {g:.3} | {:.2} |", n, c * 1e6 / n, g * 1e6 / n);
    }
    group.finish();
}

criterion_group!(benches, whole, scaling);
criterion_main!(benches);
