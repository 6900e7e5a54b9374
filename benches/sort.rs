//! Sort throughput (keys/s), 2^10 to 2^24 keys, 32- and 64-bit keys with a 32-bit payload: the GPU radix sort
//! (GPU time from timestamps around the recorded sort, uploads excluded) beside `slice::sort_unstable_by_key` and
//! rayon's `par_sort_unstable_by_key` on (key, payload) pairs in the same run.
//!
//! Environment: `MESHCHAR_BENCH_MIN_LOG2` / `MESHCHAR_BENCH_MAX_LOG2` (default 10 and 24) bound the sizes (every
//! second power of two); `MESHCHAR_SORT_TUNING=wg,kpt,scan_wg,scan_items` replaces the device's
//! [`SortConfig`] (for tuning); `MESHCHAR_BENCH_CPU=0` leaves out the CPU sorts. Without a Vulkan device only the
//! CPU sorts run.
//!
//! Measured on lavapipe (Mesa 22.3.6, LLVM 15, subgroup 8, CPU profile 32 x 64) in a 2-core AMD EPYC VM shared with
//! other builds (load average 5 to 7), medians: GPU sort 1.1 to 1.8 M keys/s for u32 keys and 0.3 to 1.0 M keys/s
//! for u64 keys (2^14 to 2^24), against 20 to 80 M keys/s for `sort_unstable_by_key` and 17 to 90 M keys/s for
//! rayon, on the same cores. lavapipe is the correctness device; throughput claims for the sort belong to a GPU.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, SamplingMode, Throughput};
use meshchar::gpu::sort::{KeyBits, RadixSort, SortConfig, SortStorage};
use meshchar::gpu::{Context, ContextDesc, Timer};
use meshchar::rng::SplitMix64 as Rng;
use rayon::slice::ParallelSliceMut;
use std::time::Duration;

fn env_u32(name: &str, default: u32) -> u32 {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok()).unwrap_or(default)
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    format!("{cpu}, {threads} hardware threads, rayon {} threads", rayon::current_num_threads())
}

fn tuning(ctx: &Context) -> SortConfig {
    let fitted = SortConfig::for_device(ctx.caps());
    let Ok(text) = std::env::var("MESHCHAR_SORT_TUNING") else { return fitted };
    let v: Vec<u32> = text.split(',').filter_map(|s| s.trim().parse().ok()).collect();
    match v[..] {
        [wg, kpt, swg, items] => {
            SortConfig { workgroup_size: wg, keys_per_thread: kpt, scan_workgroup_size: swg, scan_items: items }
        }
        _ => {
            eprintln!("MESHCHAR_SORT_TUNING={text:?}: expected wg,kpt,scan_wg,scan_items; using {fitted:?}");
            fitted
        }
    }
}

/// GPU seconds of `iters` sorts of `keys` (with payload), from timestamps around the recorded sort; the keys are
/// restored from a pristine copy before each sort, outside the timed span.
fn gpu_time<K: bytemuck::Pod>(
    ctx: &Context,
    sort: &RadixSort,
    timer: &mut Timer,
    keys: &[K],
    bits: KeyBits,
    iters: u64,
) -> Duration {
    let n = keys.len() as u64;
    let mem = sort.memory_requirements(n, bits);
    let storage = SortStorage::new(ctx, &mem, true).expect("sort buffers");
    let pristine_keys = ctx.upload("pristine keys", keys).expect("upload");
    let order: Vec<u32> = (0..n as u32).collect();
    let pristine_payload = ctx.upload("pristine payload", &order).expect("upload");
    let (payload, _) = storage.payload.as_ref().expect("payload");
    let mut total = 0.0f64;
    for _ in 0..iters {
        ctx.submit_and_wait(|rec| {
            rec.copy(&pristine_keys, 0, &storage.keys, 0, n * bits.bytes());
            rec.copy(&pristine_payload, 0, payload, 0, 4 * n);
            rec.reset_timer(timer);
            rec.barrier();
            rec.timestamp(timer, "start");
            sort.record(rec, &storage.buffers(), n, bits)?;
            rec.timestamp(timer, "sort");
            Ok(())
        })
        .expect("sort");
        total += timer.read().expect("timestamps").iter().map(|(_, ms)| ms).sum::<f64>();
    }
    Duration::from_secs_f64(total * 1e-3)
}

fn bench_width<K>(c: &mut Criterion, gpu: Option<(&Context, &RadixSort)>, bits: KeyBits, make: fn(u64) -> K)
where
    K: bytemuck::Pod + Ord + Send,
{
    let (lo, hi) = (env_u32("MESHCHAR_BENCH_MIN_LOG2", 10), env_u32("MESHCHAR_BENCH_MAX_LOG2", 24));
    let with_cpu = env_u32("MESHCHAR_BENCH_CPU", 1) != 0;
    let mut group = c.benchmark_group(format!("sort_{}_payload", if bits == KeyBits::U32 { "u32" } else { "u64" }));
    let mut timer = gpu.map(|(ctx, _)| Timer::new(ctx, 2).expect("timer"));
    for log2 in (lo..=hi).step_by(2) {
        let n = 1u64 << log2;
        let mut rng = Rng(log2 as u64);
        let keys: Vec<K> = (0..n).map(|_| make(rng.next_u64())).collect();
        group.throughput(Throughput::Elements(n));
        // Large sizes take seconds per sort on a CPU driver: few samples, one iteration each.
        if log2 >= 18 {
            group.sample_size(10).sampling_mode(SamplingMode::Flat).warm_up_time(Duration::from_millis(500));
            group.measurement_time(Duration::from_secs(if log2 >= 22 { 20 } else { 5 }));
        } else {
            group.sample_size(20).sampling_mode(SamplingMode::Auto).warm_up_time(Duration::from_millis(500));
            group.measurement_time(Duration::from_secs(2));
        }
        if let (Some((ctx, sort)), Some(timer)) = (gpu, timer.as_mut()) {
            group.bench_with_input(BenchmarkId::new("gpu_radix", n), &keys, |b, keys| {
                b.iter_custom(|iters| gpu_time(ctx, sort, timer, keys, bits, iters))
            });
        }
        if with_cpu {
            let pairs: Vec<(K, u32)> = keys.iter().copied().zip(0u32..).collect();
            group.bench_with_input(BenchmarkId::new("cpu_sort_unstable", n), &pairs, |b, pairs| {
                b.iter_batched_ref(
                    || pairs.clone(),
                    |v| v.sort_unstable_by_key(|p| p.0),
                    criterion::BatchSize::LargeInput,
                )
            });
            group.bench_with_input(BenchmarkId::new("cpu_rayon_par_sort_unstable", n), &pairs, |b, pairs| {
                b.iter_batched_ref(
                    || pairs.clone(),
                    |v| v.par_sort_unstable_by_key(|p| p.0),
                    criterion::BatchSize::LargeInput,
                )
            });
        }
    }
    group.finish();
}

fn benches(c: &mut Criterion) {
    println!("machine: {}", machine());
    let ctx = match Context::new(&ContextDesc::default()) {
        Ok(ctx) => Some(ctx),
        Err(e) => {
            println!("no Vulkan device ({e}): CPU sorts only");
            None
        }
    };
    let sort = ctx.as_ref().map(|ctx| {
        let config = tuning(ctx);
        let caps = ctx.caps();
        println!(
            "device: {} ({}, {}), subgroup {}, sort {:?}",
            caps.name, caps.device_type, caps.driver, caps.subgroup_size, config
        );
        RadixSort::new(ctx, config).expect("sort pipelines")
    });
    let gpu = ctx.as_ref().zip(sort.as_ref());
    bench_width::<u32>(c, gpu, KeyBits::U32, |x| x as u32);
    bench_width::<u64>(c, gpu, KeyBits::U64, |x| x);
}

criterion_group!(sort_benches, benches);
criterion_main!(sort_benches);
