//! The GPU radix sort against a stable CPU sort, exactly: keys and payloads (the original index, so stability is
//! checked too), for adversarial inputs at edge counts, 32- and 64-bit keys; tiny workgroups that need more blocks
//! than one dispatch dimension allows; every subgroup size lavapipe can emulate (4 to 128); caller-recorded sorts
//! sharing one command buffer; and errors for bad input. The validation layer must stay silent throughout.

use super::{sort_cpu, KeyBits, RadixSort, SortConfig, SortStorage, SortedIn};
use crate::gpu::testing as gpu_support;
use crate::gpu::{Context, GpuError, MemoryKind};
use crate::rng::SplitMix64 as Rng;
use std::fmt::Debug;

#[derive(Clone, Copy, Debug)]
enum Pattern {
    AllEqual,
    Sorted,
    Reversed,
    FewUnique,
    Random,
}
const PATTERNS: [Pattern; 5] =
    [Pattern::AllEqual, Pattern::Sorted, Pattern::Reversed, Pattern::FewUnique, Pattern::Random];

/// `n` 64-bit keys of a pattern; every byte of the keys varies except in `AllEqual`.
fn keys64(p: Pattern, n: usize, rng: &mut Rng) -> Vec<u64> {
    // Few unique values that differ in low, middle and high digits.
    const FEW: [u64; 5] = [0, u64::MAX, 0x0000_00ff_0000_0000, 0x8000_0000_0000_0001, 0x0101_0101_0101_0101];
    let mut k: Vec<u64> = match p {
        Pattern::AllEqual => vec![0xdead_beef_0bad_f00d; n],
        Pattern::FewUnique => (0..n).map(|_| FEW[(rng.next_u64() % 5) as usize]).collect(),
        _ => (0..n).map(|_| rng.next_u64()).collect(),
    };
    match p {
        Pattern::Sorted => k.sort_unstable(),
        Pattern::Reversed => k.sort_unstable_by(|a, b| b.cmp(a)),
        _ => {}
    }
    k
}

fn keys32(p: Pattern, n: usize, rng: &mut Rng) -> Vec<u32> {
    const FEW: [u32; 5] = [0, u32::MAX, 0x00ff_0000, 0x8000_0001, 0x0101_0101];
    let mut k: Vec<u32> = match p {
        Pattern::AllEqual => vec![0x0bad_f00d; n],
        Pattern::FewUnique => (0..n).map(|_| FEW[(rng.next_u64() % 5) as usize]).collect(),
        _ => (0..n).map(|_| rng.next_u64() as u32).collect(),
    };
    match p {
        Pattern::Sorted => k.sort_unstable(),
        Pattern::Reversed => k.sort_unstable_by(|a, b| b.cmp(a)),
        _ => {}
    }
    k
}

/// Fails with the first differing position instead of printing a million elements.
fn assert_same<T: PartialEq + Debug>(gpu: &[T], cpu: &[T], what: &str) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: lengths");
    if let Some(i) = gpu.iter().zip(cpu).position(|(a, b)| a != b) {
        let lo = i.saturating_sub(2);
        let hi = (i + 3).min(gpu.len());
        panic!("{what}: first difference at {i}: gpu {:?} cpu {:?}", &gpu[lo..hi], &cpu[lo..hi]);
    }
}

fn check_u64(sort: &RadixSort, keys: &[u64], what: &str) {
    let order: Vec<u32> = (0..keys.len() as u32).collect();
    let (gk, gp) = sort.sort_u64(keys, Some(&order)).expect("gpu sort");
    let (ck, cp) = sort_cpu(keys, Some(&order));
    assert_same(&gk, &ck, &format!("{what}: keys"));
    assert_same(&gp.expect("payload"), &cp.expect("payload"), &format!("{what}: payload (stability)"));
}

fn check_u32(sort: &RadixSort, keys: &[u32], what: &str) {
    let order: Vec<u32> = (0..keys.len() as u32).collect();
    let (gk, gp) = sort.sort_u32(keys, Some(&order)).expect("gpu sort");
    let (ck, cp) = sort_cpu(keys, Some(&order));
    assert_same(&gk, &ck, &format!("{what}: keys"));
    assert_same(&gp.expect("payload"), &cp.expect("payload"), &format!("{what}: payload (stability)"));
}

/// The counts of the acceptance list.
const COUNTS: [usize; 7] = [0, 1, 255, 256, 257, (1 << 16) + 1, (1 << 20) + 7];

#[test]
fn sort_u32_equals_stable_cpu_sort() {
    let Some(ctx) = gpu_support::context() else { return };
    let sort = RadixSort::new(&ctx, SortConfig::for_device(ctx.caps())).expect("pipelines");
    eprintln!("{} (subgroup {}): {:?}", ctx.caps().name, ctx.caps().subgroup_size, sort.config());
    let mut rng = Rng(1);
    for &n in &COUNTS {
        for p in PATTERNS {
            check_u32(&sort, &keys32(p, n, &mut rng), &format!("u32 {p:?} n = {n}"));
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn sort_u64_equals_stable_cpu_sort() {
    let Some(ctx) = gpu_support::context() else { return };
    let sort = RadixSort::new(&ctx, SortConfig::for_device(ctx.caps())).expect("pipelines");
    let mut rng = Rng(2);
    for &n in &COUNTS {
        for p in PATTERNS {
            check_u64(&sort, &keys64(p, n, &mut rng), &format!("u64 {p:?} n = {n}"));
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// The smallest tuning: one subgroup per workgroup, one key per invocation, scan tiles of 8 subgroup widths.
fn tiny_config(ctx: &Context) -> SortConfig {
    let sg = ctx.caps().max_subgroup_size;
    SortConfig { workgroup_size: sg, keys_per_thread: 1, scan_workgroup_size: sg, scan_items: 8 }
}

#[test]
fn tiny_workgroups_need_more_blocks_than_one_dispatch_allows() {
    // Dispatches capped at TEST_DISPATCH_GROUPS workgroups: the tiling is exercised on any device with little data.
    let Some(ctx) = gpu_support::capped_context() else { return };
    let config = tiny_config(&ctx);
    let sort = RadixSort::new(&ctx, config).expect("pipelines");
    let limit = ctx.caps().max_workgroup_count[0] as u64;
    // One block more than one dispatch dimension holds, plus a partial block.
    let n = ((limit + 1) * config.block_keys() + 5) as usize;
    let mem = sort.memory_requirements(n as u64, KeyBits::U32);
    assert!(mem.blocks > limit, "{} blocks", mem.blocks);
    assert!(mem.scan_levels[0].div_ceil(config.scan_tile()) > limit, "scan tiles {:?}", mem.scan_levels);
    eprintln!("n = {n}: {} blocks (dispatch limit {limit}), scan levels {:?}", mem.blocks, mem.scan_levels);
    let mut rng = Rng(3);
    check_u32(&sort, &keys32(Pattern::Random, n, &mut rng), "tiny workgroups, u32 random");
    // 64-bit keys and every pattern at moderate counts with many blocks.
    for p in PATTERNS {
        for n in [257, 4099, 70_001] {
            check_u64(&sort, &keys64(p, n, &mut rng), &format!("tiny workgroups, u64 {p:?} n = {n}"));
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn workgroup_and_keys_per_thread_variations() {
    let Some(ctx) = gpu_support::context() else { return };
    let caps = ctx.caps().clone();
    let sg = caps.max_subgroup_size;
    let mut rng = Rng(4);
    for (wg, kpt, swg, items) in [(sg, 64, sg, 1), (2 * sg, 3, 3 * sg, 5), (4 * sg, 7, sg, 64)] {
        let config =
            SortConfig { workgroup_size: wg, keys_per_thread: kpt, scan_workgroup_size: swg, scan_items: items };
        if !config.check(&caps).is_empty() {
            continue;
        }
        let sort = RadixSort::new(&ctx, config).expect("pipelines");
        for n in [1, 2, 255, 257, 12_345, 100_003] {
            check_u64(&sort, &keys64(Pattern::Random, n, &mut rng), &format!("{config:?} u64 n = {n}"));
            check_u32(&sort, &keys32(Pattern::FewUnique, n, &mut rng), &format!("{config:?} u32 n = {n}"));
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn recorded_sorts_share_one_command_buffer_and_keys_sort_alone() {
    let Some(ctx) = gpu_support::context() else { return };
    let sort = RadixSort::new(&ctx, SortConfig::for_device(ctx.caps())).expect("pipelines");
    let mut rng = Rng(5);
    let n = 50_001usize;
    let a = keys64(Pattern::Random, n, &mut rng);
    let b = keys32(Pattern::FewUnique, n / 2, &mut rng);
    let mem = sort.memory_requirements(n as u64, KeyBits::U64);
    let storage = SortStorage::new(&ctx, &mem, true).expect("buffers");
    // A second set of key buffers sharing the first one's internal buffer; keys only, no payload.
    let keys_b = ctx.upload("keys b", &b).expect("upload");
    let keys_b_alt = ctx.create_buffer("keys b alt", 4 * b.len() as u64, MemoryKind::DeviceLocal).expect("alt");
    ctx.write_buffer(&storage.keys, 0, &a).expect("write");
    let order: Vec<u32> = (0..n as u32).collect();
    let (pa, _) = storage.payload.as_ref().expect("payload");
    ctx.write_buffer(pa, 0, &order).expect("write");
    let mut bufs_b = storage.buffers();
    bufs_b.keys = &keys_b;
    bufs_b.keys_alt = &keys_b_alt;
    bufs_b.payload = None;
    bufs_b.payload_alt = None;
    let (ra, rb) = ctx
        .submit_and_wait(|rec| {
            let ra = sort.record(rec, &storage.buffers(), n as u64, KeyBits::U64)?;
            let rb = sort.record(rec, &bufs_b, b.len() as u64, KeyBits::U32)?;
            rec.barrier();
            Ok((ra, rb))
        })
        .expect("sort");
    assert_eq!((ra, rb), (SortedIn::Input, SortedIn::Input));
    let (ka, pa) = storage.result(ra);
    let (ck, cp) = sort_cpu(&a, Some(&order));
    assert_same(&ctx.read_buffer::<u64>(ka, 0, n).expect("read"), &ck, "recorded u64 keys");
    assert_same(&ctx.read_buffer::<u32>(pa.expect("payload"), 0, n).expect("read"), &cp.expect("p"), "payload");
    let (cb, none) = sort_cpu(&b, None);
    assert!(none.is_none());
    assert_same(&ctx.read_buffer::<u32>(&keys_b, 0, b.len()).expect("read"), &cb, "recorded u32 keys alone");
    // The convenience path without payload.
    let (k, p) = sort.sort_u64(&a, None).expect("sort");
    assert!(p.is_none());
    assert_same(&k, &ck, "u64 keys alone");
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let Some(ctx) = gpu_support::context() else { return };
    let caps = ctx.caps().clone();
    let sort = RadixSort::new(&ctx, SortConfig::for_device(&caps)).expect("pipelines");
    assert!(matches!(sort.sort_u32(&[3, 1, 2], Some(&[0, 1])), Err(GpuError::Buffer(_))));
    let bad = [
        SortConfig { workgroup_size: 0, ..SortConfig::GPU },
        SortConfig { workgroup_size: caps.max_workgroup_invocations + 1, ..SortConfig::GPU },
        SortConfig { keys_per_thread: 0, ..SortConfig::GPU },
        SortConfig { scan_items: 0, ..SortConfig::GPU },
        // More subgroups than shared memory has counters for.
        SortConfig { workgroup_size: caps.max_workgroup_invocations, ..SortConfig::GPU },
    ];
    for config in bad {
        if config.workgroup_size == caps.max_workgroup_invocations && config.check(&caps).is_empty() {
            continue; // this device has the shared memory for it
        }
        assert!(!config.check(&caps).is_empty(), "{config:?}");
        assert!(matches!(RadixSort::new(&ctx, config), Err(GpuError::Limit { .. })), "{config:?}");
    }
    // Buffers smaller than the requirements, and a payload without its alternate: errors, nothing recorded.
    let mem = sort.memory_requirements(1000, KeyBits::U64);
    let storage = SortStorage::new(&ctx, &mem, true).expect("buffers");
    let short = ctx.create_buffer("short", 8 * 999, MemoryKind::DeviceLocal).expect("buffer");
    let r = ctx.submit_and_wait(|rec| {
        let mut b = storage.buffers();
        b.keys_alt = &short;
        assert!(matches!(sort.record(rec, &b, 1000, KeyBits::U64), Err(GpuError::Buffer(_))));
        let mut b = storage.buffers();
        b.payload_alt = None;
        assert!(matches!(sort.record(rec, &b, 1000, KeyBits::U64), Err(GpuError::Buffer(_))));
        assert!(matches!(
            sort.record(rec, &storage.buffers(), u32::MAX as u64 + 1, KeyBits::U32),
            Err(GpuError::Limit { .. })
        ));
        Ok(())
    });
    r.expect("submit");
    // The fitted profiles always pass their own check.
    for profile in [SortConfig::GPU, SortConfig::CPU] {
        assert!(profile.fitted(&caps).check(&caps).is_empty(), "{profile:?}");
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// lavapipe's subgroup size follows `LP_NATIVE_VECTOR_WIDTH` (32 bits per lane): sizes 4 and 16 (8 is the default)
/// run the sort in a child process of this test binary ([`sort_at_emulated_subgroup_size`]).
///
/// Wider settings are not faithful devices: at 1024 to 4096 bits lavapipe reports subgroups (and a minimum subgroup
/// size) of 32 to 128 lanes but executes 16, so `gl_NumSubgroups` exceeds the workgroup size divided by the reported
/// minimum, which no conformant driver does and which the kernels' shared-memory sizing relies on. (With the shared
/// arrays enlarged by hand, the sort was correct on those partially filled subgroups too.)
#[test]
fn sort_is_correct_at_every_subgroup_size_lavapipe_emulates() {
    if std::env::var_os("MESHCHAR_SORT_SUBGROUP").is_some() {
        return; // a child
    }
    let Some(ctx) = gpu_support::context() else { return };
    if !ctx.caps().name.starts_with("llvmpipe") || std::env::var_os("LP_NATIVE_VECTOR_WIDTH").is_some() {
        eprintln!("{}: subgroup size fixed by the device, emulation skipped", ctx.caps().name);
        return;
    }
    drop(ctx);
    let exe = std::env::current_exe().expect("test binary");
    // The child's full test name within the crate's test binary (its module path without the crate's name).
    let module = module_path!().split_once("::").map_or("", |m| m.1);
    let child = format!("{module}::sort_at_emulated_subgroup_size");
    for sg in [4u32, 16] {
        let out = std::process::Command::new(&exe)
            .args(["--exact", child.as_str(), "--nocapture", "--test-threads=1"])
            .env("LP_NATIVE_VECTOR_WIDTH", (32 * sg).to_string())
            .env("MESHCHAR_SORT_SUBGROUP", sg.to_string())
            .env("REQUIRE_GPU", "1")
            .output()
            .expect("run child");
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "subgroup size {sg}:\n{text}");
        assert!(
            text.contains(&format!("sorted at subgroup size {sg}")),
            "subgroup size {sg}: child did not run\n{text}"
        );
    }
}

/// Runs only as the child of [`sort_is_correct_at_every_subgroup_size_lavapipe_emulates`].
#[test]
fn sort_at_emulated_subgroup_size() {
    let Ok(sg) = std::env::var("MESHCHAR_SORT_SUBGROUP") else { return };
    let Some(ctx) = gpu_support::context() else { return };
    assert_eq!(ctx.caps().subgroup_size.to_string(), sg, "LP_NATIVE_VECTOR_WIDTH was not honoured");
    let mut rng = Rng(6);
    for config in [SortConfig::for_device(ctx.caps()), tiny_config(&ctx)] {
        let sort = RadixSort::new(&ctx, config).expect("pipelines");
        for n in [0, 1, 255, 257, 3 * config.block_keys() as usize + 5, 20_001] {
            for p in [Pattern::FewUnique, Pattern::Random, Pattern::Reversed] {
                check_u32(&sort, &keys32(p, n, &mut rng), &format!("sg {sg} {config:?} u32 {p:?} n = {n}"));
                check_u64(&sort, &keys64(p, n, &mut rng), &format!("sg {sg} {config:?} u64 {p:?} n = {n}"));
            }
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
    println!("sorted at subgroup size {sg}");
}
