//! Characterization benchmarks: the whole pipeline and each pass, for the naive reference, the rayon CPU path and
//! Vulkan, on bunny, dragon res2, the full dragon and Sponza; then the scaling from 1K triangles to the largest mesh
//! (the dragon subdivided). GPU figures are sums of the passes' timestamps (`iter_custom`), so they exclude the
//! host round trips between passes, which are reported separately as wall time.
//!
//! The `speed` group measures the rayon CPU path against the memory system: for each mesh, in interleaved rounds of
//! one run, a single-threaded copy of the mesh's input bytes (positions and index triples, into buffers allocated
//! and touched beforehand), the same copy on every rayon thread, [`cpu::fast`] (its working memory allocated afresh,
//! page faults included), [`cpu::fast_with`] with a [`cpu::Scratch`] kept across the rounds (as `Characterizer`
//! keeps it: what a caller that characterizes every frame pays); it prints the medians, the bytes per second each
//! achieves and the ratio of the reused path's time to the copy's.
//!
//! The `features` group sets the scene features beside the characterization, in interleaved rounds of one run on a
//! CPU `Characterizer` (its scratch kept): the characterization alone, `features_cpu` alone, and both as
//! `characterize_with_features` takes them (the features from the characterization's codes); it prints the medians
//! and the ratio of both to the characterization alone.
//!
//! `cargo bench --bench characterize` (all), `-- whole` (only the meshes), `-- scaling` (only the scaling run),
//! `-- speed` (only the bandwidth comparison), `-- features` (only the features). Set `MESHCHAR_BENCH_NAIVE=0` to skip the slow naive path and
//! `MESHCHAR_BENCH_ROUNDS=N` to change the rounds of `speed` (default 30).

mod common;

use common::load_shared as load;
use criterion::{criterion_group, criterion_main, Criterion};
use meshchar::characterize::vulkan::VulkanBackend;
use meshchar::characterize::{cpu, Characterization, MortonBits, Params};
use meshchar::gpu::{Context, ContextDesc};
use meshchar::mesh::{generate, Mesh};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Whether the group `name` (`whole`, `scaling`, `speed`) runs: the command line names no filter, or a filter that
/// begins with the group's name, or one that begins with no group's name (criterion then matches it against every
/// benchmark's id).
fn selected(name: &str) -> bool {
    const GROUPS: [&str; 4] = ["whole", "scaling", "speed", "features"];
    let filters: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).collect();
    filters.is_empty() || filters.iter().any(|f| f.starts_with(name) || !GROUPS.iter().any(|g| f.starts_with(g)))
}

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
    if !selected("whole") {
        return;
    }
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
        let mut group = crit.benchmark_group(format!("whole/{name}"));
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
    if !selected("scaling") {
        return;
    }
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

/// Copies `src` into `dst` (of equal length) on every rayon thread, one contiguous piece each.
fn par_copy<T: Copy + Send + Sync>(dst: &mut [T], src: &[T]) {
    use rayon::prelude::*;
    let piece = src.len().div_ceil(rayon::current_num_threads()).max(1);
    dst.par_chunks_mut(piece).zip(src.par_chunks(piece)).for_each(|(d, s)| d.copy_from_slice(s));
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

fn speed(crit: &mut Criterion) {
    if !selected("speed") {
        return;
    }
    // `--list` only names the benchmarks: no rounds then.
    let listing = std::env::args().any(|a| a == "--list");
    let rounds: usize = if listing {
        0
    } else {
        std::env::var("MESHCHAR_BENCH_ROUNDS").ok().and_then(|v| v.parse().ok()).unwrap_or(30)
    };
    let meshes = [
        ("bunny", "stanford-bunny/bun_zipper.ply"),
        ("dragon", "stanford-dragon/dragon_vrip.ply"),
        ("sponza", "dabrovic-sponza/sponza.obj"),
    ];
    let settings = [
        ("30-bit", Params::default()),
        (
            "63-bit 1:3 sturges",
            Params {
                morton_bits: MortonBits::Bits63,
                sample_stride: 3,
                class_rule: meshchar::characterize::ClassRule::Sturges,
                ..Params::default()
            },
        ),
        ("30-bit kept", Params { keep_per_triangle: true, ..Params::default() }),
    ];
    let mut rows = Vec::new();
    for (name, rel) in meshes {
        let mesh = load(rel);
        let bytes = std::mem::size_of_val(&mesh.positions[..]) + std::mem::size_of_val(&mesh.indices[..]);
        // Destinations allocated and written once, so that the copies measure the copy and not page faults.
        let mut pos = mesh.positions.clone();
        let mut idx = mesh.indices.clone();
        for (setting, params) in &settings {
            if name != "dragon" && *setting != "30-bit" {
                continue;
            }
            let (mut copy1, mut copy_n, mut fast) = (Vec::new(), Vec::new(), Vec::new());
            // The working memory kept from one call to the next, as `Characterizer` keeps it.
            let (mut reused, mut scratch) = (Vec::new(), cpu::Scratch::default());
            // Interleaved rounds: a change of load moves all figures alike.
            for _ in 0..rounds {
                let t = Instant::now();
                pos.copy_from_slice(&mesh.positions);
                idx.copy_from_slice(&mesh.indices);
                std::hint::black_box((&pos, &idx));
                copy1.push(ms(t));
                let t = Instant::now();
                par_copy(&mut pos, &mesh.positions);
                par_copy(&mut idx, &mesh.indices);
                std::hint::black_box((&pos, &idx));
                copy_n.push(ms(t));
                let t = Instant::now();
                let a = cpu::fast(&mesh, params).expect("cpu");
                fast.push(ms(t));
                let t = Instant::now();
                let r = cpu::fast_with(&mesh, params, &mut scratch).expect("cpu reused");
                reused.push(ms(t));
                assert_eq!((&a.code_stats, &a.histogram), (&r.code_stats, &r.histogram), "{name}: scratch differs");
            }
            if rounds > 0 {
                let (c1, cn, f) = (median(&mut copy1), median(&mut copy_n), median(&mut fast));
                let fr = median(&mut reused);
                rows.push((name, *setting, mesh.triangle_count(), bytes, c1, cn, f, fr));
            }
        }
        let mut group = crit.benchmark_group(format!("speed/{name}"));
        group.sample_size(10).measurement_time(Duration::from_secs(2)).warm_up_time(Duration::from_millis(200));
        group.throughput(criterion::Throughput::Bytes(bytes as u64));
        group.bench_function("copy", |b| {
            b.iter(|| {
                pos.copy_from_slice(&mesh.positions);
                idx.copy_from_slice(&mesh.indices);
                std::hint::black_box((&pos, &idx));
            })
        });
        let params = Params::default();
        group.bench_function("cpu", |b| b.iter(|| cpu::fast(&mesh, &params).expect("cpu")));
        let mut scratch = cpu::Scratch::default();
        group.bench_function("cpu_reused", |b| {
            b.iter(|| cpu::fast_with(&mesh, &params, &mut scratch).expect("cpu reused"))
        });
        group.finish();
    }
    if rows.is_empty() {
        return;
    }
    let gbs = |ms: f64, bytes: usize| bytes as f64 / (ms * 1e-3) / 1e9;
    println!(
        "\ninput bandwidth of the CPU path ({}; medians of {rounds} interleaved rounds; input = positions + index \
         triples)",
        cpu::cpu_device_name(rayon::current_num_threads())
    );
    println!(
        "| mesh | setting | triangles | input MB | copy 1 thread ms (GB/s) | copy {} threads ms (GB/s) | cpu ms (GB/s) | \
         cpu, scratch reused, ms (GB/s) | reused / copy 1 thread |",
        rayon::current_num_threads()
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for (name, setting, n, bytes, c1, cn, f, fr) in rows {
        println!(
            "| {name} | {setting} | {n} | {:.1} | {c1:.3} ({:.1}) | {cn:.3} ({:.1}) | {f:.3} ({:.2}) | {fr:.3} ({:.2}) | \
             {:.1}x |",
            bytes as f64 / 1e6,
            gbs(c1, bytes),
            gbs(cn, bytes),
            gbs(f, bytes),
            gbs(fr, bytes),
            fr / c1
        );
    }
}

fn features(_: &mut Criterion) {
    if !selected("features") || std::env::args().any(|a| a == "--list") {
        return;
    }
    let rounds: usize = std::env::var("MESHCHAR_BENCH_ROUNDS").ok().and_then(|v| v.parse().ok()).unwrap_or(30);
    let mut meshes: Vec<(String, Mesh)> = [
        ("bunny", "stanford-bunny/bun_zipper.ply"),
        ("dragon", "stanford-dragon/dragon_vrip.ply"),
        ("sponza", "dabrovic-sponza/sponza.obj"),
    ]
    .into_iter()
    .map(|(name, rel)| (name.to_string(), load(rel)))
    .collect();
    for n in [20_000, 500_000] {
        let city = meshchar::mesh::families::generate(meshchar::mesh::families::Family::City, n, 1).expect("city");
        meshes.push((format!("city {n}"), city));
    }
    let params = Params::default();
    let mut engine = meshchar::characterize::Characterizer::new(Some(meshchar::characterize::Backend::Cpu))
        .expect("the CPU characterizer");
    println!(
        "
the scene features beside the characterization ({}; medians of {rounds} interleaved rounds, ms)",
        cpu::cpu_device_name(rayon::current_num_threads())
    );
    println!("| mesh | triangles | characterize | features_cpu | characterize_with_features | both / characterize |");
    println!("|---|---:|---:|---:|---:|---:|");
    for (name, mesh) in &meshes {
        let (mut alone, mut feats, mut both) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..rounds {
            let t = Instant::now();
            let c = engine.characterize(mesh, &params).expect("characterize");
            alone.push(ms(t));
            let t = Instant::now();
            let f = meshchar::characterize::features_cpu(mesh, &params).expect("features");
            feats.push(ms(t));
            let t = Instant::now();
            let (c2, f2) = engine.characterize_with_features(mesh, &params).expect("both");
            both.push(ms(t));
            assert!(c.same_result(&c2) && f == f2, "{name}: the paths differ");
        }
        let (a, f, b) = (median(&mut alone), median(&mut feats), median(&mut both));
        println!("| {name} | {} | {a:.3} | {f:.3} | {b:.3} | {:.2}x |", mesh.triangle_count(), b / a);
    }
}

criterion_group!(benches, speed, whole, scaling, features);
criterion_main!(benches);
