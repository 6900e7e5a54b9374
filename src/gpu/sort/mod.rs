//! Stable GPU radix sort of 32-bit and 64-bit keys with an optional 32-bit payload.
//!
//! Least-significant digit first, 8-bit digits (4 passes for 32-bit keys, 8 for 64-bit keys), each pass in three
//! kernels in the reduce-then-scan shape of Merrill and Grimshaw (*High Performance and Scalable Radix Sorting*,
//! Parallel Processing Letters 21(2), 2011):
//!
//! 1. **count** (`glsl/sort_count.comp`): every block of `SortConfig::block_keys` keys writes its 256-bin digit
//!    histogram to `counts[digit * blocks + block]`;
//! 2. **scan** (`glsl/sort_scan_reduce.comp`, `glsl/sort_scan_down.comp`): an exclusive prefix sum of that whole
//!    array, which turns each count into the first output position of that digit from that block. Tile sums go up a
//!    level and are scanned in turn until one tile remains, then the levels are scanned back down; no workgroup ever
//!    waits for another, so the sort runs on drivers without forward-progress guarantees between workgroups
//!    (lavapipe, many mobile and Apple drivers);
//! 3. **scatter** (`glsl/sort_scatter.comp`): every block moves its keys (and payloads) to those positions plus
//!    their stable rank among the block's keys with the same digit. Ranks come from eight subgroup ballots per key
//!    (lanes with equal digits find each other) and per-subgroup digit counters in shared memory, with no assumption
//!    on the subgroup size (4 to 128) or on how the driver fills subgroups (see `glsl/include/sort.glsl`).
//!
//! Keys and payloads ping-pong between the caller's buffers and their alternates; with an even number of passes
//! (always, for [`KeyBits::U32`] and [`KeyBits::U64`]) the sorted result is back in the caller's first buffers, and
//! [`RadixSort::record`] says so by returning [`SortedIn`].
//!
//! The API follows the shape of Fuchsia's Vulkan radix sort (also shipped in Mesa): [`RadixSort::requirements`] of
//! the device, creation on the caller's device ([`RadixSort::new`] on a [`Context`], which may wrap the caller's own
//! device through [`Context::from_raw`]), [`RadixSort::memory_requirements`] for a count, and
//! [`RadixSort::record`] into the caller's command buffer with the barriers it begins and ends with documented; plus
//! [`RadixSort::sort_u32`] and [`RadixSort::sort_u64`], which upload, sort, read back and wait. Tuning (workgroup
//! size, keys per invocation) is data: [`SortConfig`], with a profile for CPU drivers.
//!
//! ```no_run
//! use meshchar::gpu::{Context, ContextDesc};
//! use meshchar::gpu::sort::{RadixSort, SortConfig};
//! let ctx = Context::new(&ContextDesc::default())?;
//! let sort = RadixSort::new(&ctx, SortConfig::for_device(ctx.caps()))?;
//! let (keys, order) = sort.sort_u64(&[30, 10, 20, 10], Some(&[0, 1, 2, 3]))?;
//! assert_eq!(keys, [10, 10, 20, 30]);
//! assert_eq!(order, Some(vec![1, 3, 2, 0]));
//! # Ok::<(), meshchar::gpu::GpuError>(())
//! ```

use crate::gpu::{
    shaders, Buffer, Context, DeviceCaps, DeviceType, GpuError, Kernel, KernelDesc, MemoryKind, Pass, Recorder, Result,
};

/// Bits per digit.
pub const DIGIT_BITS: u32 = 8;
/// Bins per digit.
const RADIX: u64 = 1 << DIGIT_BITS;
/// Shared memory of the scatter kernel per subgroup, in bytes: 256 digit counters, the subgroup's lane count and
/// its sum (`glsl/include/sort.glsl`), and one word of margin.
const SCATTER_SHARED_PER_SUBGROUP: u32 = 4 * RADIX as u32 + 12;
/// Shared memory of the scan kernels per subgroup, in bytes: lane count and sum.
const SCAN_SHARED_PER_SUBGROUP: u32 = 8;
/// Largest keys per invocation (they are held in registers between the scatter kernel's two phases).
pub const MAX_KEYS_PER_THREAD: u32 = 64;
/// Alignment of the regions inside the internal buffer, in bytes.
const REGION_ALIGN: u64 = 256;

/// Width of the keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum KeyBits {
    /// `u32` keys: 4 passes.
    U32,
    /// `u64` keys: 8 passes.
    U64,
}

impl KeyBits {
    /// Bytes per key.
    pub fn bytes(self) -> u64 {
        match self {
            KeyBits::U32 => 4,
            KeyBits::U64 => 8,
        }
    }

    /// Digit passes (8 bits each).
    pub(crate) fn passes(self) -> u32 {
        (self.bytes() as u32 * 8) / DIGIT_BITS
    }
}

/// Which pair of buffers holds the sorted keys (and payloads) after [`RadixSort::record`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SortedIn {
    /// [`SortBuffers::keys`] and [`SortBuffers::payload`]: the buffers the unsorted data came in.
    Input,
    /// [`SortBuffers::keys_alt`] and [`SortBuffers::payload_alt`].
    Alternate,
}

/// Per-device tuning of the sort, as plain data.
///
/// [`SortConfig::for_device`] picks a profile and fits it to the device's limits; tests and benchmarks may build
/// their own. [`RadixSort::new`] rejects a configuration the device cannot run with [`GpuError::Limit`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct SortConfig {
    /// Invocations per workgroup of the count and scatter kernels. The scatter kernel's shared memory holds 256
    /// counters per subgroup, so this is bounded by `maxComputeSharedMemorySize` and the smallest subgroup size.
    pub workgroup_size: u32,
    /// Keys each invocation handles per block (1 to [`MAX_KEYS_PER_THREAD`]); a block is
    /// `workgroup_size * keys_per_thread` keys.
    pub keys_per_thread: u32,
    /// Invocations per workgroup of the scan kernels.
    pub scan_workgroup_size: u32,
    /// Elements each scan invocation handles per tile.
    pub scan_items: u32,
}

impl SortConfig {
    /// Profile for GPUs: 256 invocations, 16 keys each (blocks of 4,096 keys), scan tiles of 2,048 counts.
    pub const GPU: SortConfig =
        SortConfig { workgroup_size: 256, keys_per_thread: 16, scan_workgroup_size: 256, scan_items: 8 };

    /// Profile for CPU drivers (lavapipe, SwiftShader): a workgroup runs on one CPU thread, one subgroup per SIMD
    /// vector, so few subgroups per workgroup (the per-block counter work grows with them) and many keys per
    /// invocation (per-block work is amortized over more keys) are cheaper. On lavapipe (2-core VM, subgroup 8) the
    /// scatter kernel ran about 2x faster with 32 invocations x 64 keys than with 64 x 32 or 32 x 32, and the count
    /// of workgroups dispatched made no measurable difference.
    pub const CPU: SortConfig =
        SortConfig { workgroup_size: 32, keys_per_thread: 64, scan_workgroup_size: 64, scan_items: 32 };

    /// The profile for the device ([`SortConfig::CPU`] for a [`DeviceType::Cpu`], else [`SortConfig::GPU`]), fitted
    /// to its limits with `SortConfig::fitted`.
    pub fn for_device(caps: &DeviceCaps) -> Self {
        let profile = if caps.device_type == DeviceType::Cpu { Self::CPU } else { Self::GPU };
        profile.fitted(caps)
    }

    /// This configuration with workgroup sizes lowered (never below the largest subgroup size) until the device's
    /// workgroup and shared-memory limits hold, and keys per invocation clamped to `1..=`[`MAX_KEYS_PER_THREAD`].
    pub(crate) fn fitted(mut self, caps: &DeviceCaps) -> Self {
        let max_sg = caps.max_subgroup_size.max(1);
        let min_sg = caps.min_subgroup_size.max(1);
        let max_wg = caps.max_workgroup_size[0].min(caps.max_workgroup_invocations).max(1);
        let fit = |wanted: u32, shared_per_subgroup: u32| -> u32 {
            let by_shared = (caps.max_shared_memory / shared_per_subgroup).max(1) * min_sg;
            let wg = wanted.min(max_wg).min(by_shared);
            // A multiple of the largest subgroup size keeps subgroups full (the kernels do not need it).
            let wg = if wg >= max_sg { wg - wg % max_sg } else { wg };
            wg.max(max_sg.min(max_wg))
        };
        self.workgroup_size = fit(self.workgroup_size, SCATTER_SHARED_PER_SUBGROUP);
        self.scan_workgroup_size = fit(self.scan_workgroup_size, SCAN_SHARED_PER_SUBGROUP);
        self.keys_per_thread = self.keys_per_thread.clamp(1, MAX_KEYS_PER_THREAD);
        self.scan_items = self.scan_items.max(1);
        self
    }

    /// Keys per block of the count and scatter kernels.
    pub(crate) fn block_keys(&self) -> u64 {
        self.workgroup_size as u64 * self.keys_per_thread as u64
    }

    /// Counts per tile of the scan kernels.
    pub(crate) fn scan_tile(&self) -> u64 {
        self.scan_workgroup_size as u64 * self.scan_items as u64
    }

    /// Every reason the device cannot run this configuration (empty when it can).
    pub(crate) fn check(&self, caps: &DeviceCaps) -> Vec<String> {
        let mut why = Vec::new();
        let max_wg = caps.max_workgroup_size[0].min(caps.max_workgroup_invocations);
        let min_sg = caps.min_subgroup_size.max(1);
        for (name, wg, per_subgroup) in [
            ("workgroup_size", self.workgroup_size, SCATTER_SHARED_PER_SUBGROUP),
            ("scan_workgroup_size", self.scan_workgroup_size, SCAN_SHARED_PER_SUBGROUP),
        ] {
            if wg == 0 || wg > max_wg {
                why.push(format!("{name} {wg} outside 1..={max_wg}"));
            }
            let shared = wg.div_ceil(min_sg) as u64 * per_subgroup as u64;
            if shared > caps.max_shared_memory as u64 {
                why.push(format!(
                    "{name} {wg} needs {shared} bytes of shared memory with subgroups of {min_sg}; the device has {}",
                    caps.max_shared_memory
                ));
            }
        }
        if self.keys_per_thread == 0 || self.keys_per_thread > MAX_KEYS_PER_THREAD {
            why.push(format!("keys_per_thread {} outside 1..={MAX_KEYS_PER_THREAD}", self.keys_per_thread));
        }
        if self.scan_items == 0 {
            why.push("scan_items is 0".into());
        }
        if self.block_keys() > 1 << 31 || self.scan_tile() > 1 << 31 {
            why.push("a block or scan tile above 2^31 elements".into());
        }
        why
    }
}

/// Sizes of the buffers a sort of a given count needs (see [`RadixSort::memory_requirements`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SortMemory {
    /// Keys sorted.
    pub count: u64,
    /// Key width.
    pub key_bits: KeyBits,
    /// Bytes of each key buffer ([`SortBuffers::keys`] and [`SortBuffers::keys_alt`]).
    pub keys_bytes: u64,
    /// Bytes of each payload buffer ([`SortBuffers::payload`] and [`SortBuffers::payload_alt`]), when there is one.
    pub payload_bytes: u64,
    /// Bytes of the internal buffer ([`SortBuffers::internal`]): per-block digit counts and the scan's levels.
    pub internal_bytes: u64,
    /// Blocks of the count and scatter kernels.
    pub blocks: u64,
    /// Element counts of the scan's levels, the per-block counts first.
    pub scan_levels: Vec<u64>,
    /// Byte offsets of those levels in the internal buffer.
    scan_offsets: Vec<u64>,
}

/// The buffers of one sort, all owned by the caller. Sizes come from [`RadixSort::memory_requirements`].
#[derive(Clone, Copy, Debug)]
pub struct SortBuffers<'a> {
    /// The keys to sort (`u32` or `u64`, tightly packed).
    pub keys: &'a Buffer,
    /// Second key buffer of the ping-pong.
    pub keys_alt: &'a Buffer,
    /// The payloads (`u32`, one per key), or `None` to sort keys alone.
    pub payload: Option<&'a Buffer>,
    /// Second payload buffer of the ping-pong (required with a payload).
    pub payload_alt: Option<&'a Buffer>,
    /// Scratch for the per-block counts and the scan.
    pub internal: &'a Buffer,
}

/// Device-local buffers for sorts of up to a given count, for callers without buffers of their own (the
/// convenience paths and the benchmarks use it).
#[derive(Debug)]
pub struct SortStorage {
    /// Key buffer the data goes in (and, for even pass counts, comes out of).
    pub keys: Buffer,
    /// Alternate key buffer.
    pub keys_alt: Buffer,
    /// Payload buffers, when asked for.
    pub payload: Option<(Buffer, Buffer)>,
    /// Internal scratch.
    pub internal: Buffer,
}

impl SortStorage {
    /// Allocates device-local buffers of the sizes in `memory`.
    pub fn new(ctx: &Context, memory: &SortMemory, with_payload: bool) -> Result<Self> {
        let dl = MemoryKind::DeviceLocal;
        Ok(SortStorage {
            keys: ctx.create_buffer("sort keys", memory.keys_bytes, dl)?,
            keys_alt: ctx.create_buffer("sort keys alt", memory.keys_bytes, dl)?,
            payload: if with_payload {
                Some((
                    ctx.create_buffer("sort payload", memory.payload_bytes, dl)?,
                    ctx.create_buffer("sort payload alt", memory.payload_bytes, dl)?,
                ))
            } else {
                None
            },
            internal: ctx.create_buffer("sort internal", memory.internal_bytes, dl)?,
        })
    }

    /// The buffers, for [`RadixSort::record`].
    pub fn buffers(&self) -> SortBuffers<'_> {
        SortBuffers {
            keys: &self.keys,
            keys_alt: &self.keys_alt,
            payload: self.payload.as_ref().map(|p| &p.0),
            payload_alt: self.payload.as_ref().map(|p| &p.1),
            internal: &self.internal,
        }
    }

    /// The key and payload buffers holding the result, given what [`RadixSort::record`] returned.
    pub fn result(&self, sorted_in: SortedIn) -> (&Buffer, Option<&Buffer>) {
        match sorted_in {
            SortedIn::Input => (&self.keys, self.payload.as_ref().map(|p| &p.0)),
            SortedIn::Alternate => (&self.keys_alt, self.payload.as_ref().map(|p| &p.1)),
        }
    }
}

pub(crate) use crate::gpu::shaders::sort_count::Push as SortCountPush;
pub(crate) use crate::gpu::shaders::sort_scan_down::Push as SortScanDownPush;
pub(crate) use crate::gpu::shaders::sort_scan_reduce::Push as SortScanReducePush;
pub(crate) use crate::gpu::shaders::sort_scatter::Push as SortScatterPush;

/// What a device needs for the sort, beyond what every [`Context`] already requires.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SortRequirements {
    /// Device extensions (none: everything is core Vulkan 1.2).
    pub extensions: Vec<&'static str>,
    /// Device features (`shaderInt64`, `bufferDeviceAddress`; enabled by
    /// [`required_device_features`](crate::gpu::required_device_features)).
    pub features: Vec<&'static str>,
    /// Subgroup operations used in compute shaders.
    pub subgroup_operations: Vec<&'static str>,
}

/// The stable GPU radix sort: its pipelines for one device and tuning.
pub struct RadixSort {
    ctx: Context,
    config: SortConfig,
    count: [Kernel<SortCountPush>; 2],
    scatter: [Kernel<SortScatterPush>; 2],
    reduce: Kernel<SortScanReducePush>,
    down: Kernel<SortScanDownPush>,
}

impl std::fmt::Debug for RadixSort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RadixSort").field("device", &self.ctx.caps().name).field("config", &self.config).finish()
    }
}

impl RadixSort {
    /// What the sort needs of a device. Every [`Context`] already checks these; a host engine creating its own
    /// device enables them with [`required_device_features`](crate::gpu::required_device_features).
    pub fn requirements() -> SortRequirements {
        SortRequirements {
            extensions: Vec::new(),
            features: vec!["shaderInt64", "bufferDeviceAddress"],
            subgroup_operations: vec!["basic", "arithmetic", "ballot", "shuffle"],
        }
    }

    /// Builds the pipelines on the context's device. A configuration the device cannot run gives
    /// [`GpuError::Limit`] (see `SortConfig::check`).
    pub fn new(ctx: &Context, config: SortConfig) -> Result<Self> {
        let caps = ctx.caps();
        let why = config.check(caps);
        if !why.is_empty() {
            return Err(GpuError::Limit {
                what: format!("sort configuration {config:?}: {}", why.join("; ")),
                requested: config.workgroup_size as u64,
                limit: caps.max_workgroup_size[0].min(caps.max_workgroup_invocations) as u64,
            });
        }
        let min_sg = caps.min_subgroup_size.max(1);
        let wg = config.workgroup_size;
        let swg = config.scan_workgroup_size;
        let with_wg = |mut desc: KernelDesc, size: u32| {
            desc.workgroup_size = Some(size);
            desc
        };
        let count = |key64: u32| -> Result<Kernel<SortCountPush>> {
            Kernel::new(ctx, &with_wg(KernelDesc::new(&shaders::sort_count::INFO).constant("KEY64", key64), wg))
        };
        let scatter = |key64: u32| -> Result<Kernel<SortScatterPush>> {
            let desc = KernelDesc::new(&shaders::sort_scatter::INFO)
                .constant("KPT", config.keys_per_thread)
                .constant("MAX_SUBGROUPS", wg.div_ceil(min_sg))
                .constant("KEY64", key64);
            Kernel::new(ctx, &with_wg(desc, wg))
        };
        let scan_desc = |info| {
            with_wg(
                KernelDesc::new(info)
                    .constant("ITEMS", config.scan_items)
                    .constant("MAX_SUBGROUPS", swg.div_ceil(min_sg)),
                swg,
            )
        };
        Ok(RadixSort {
            ctx: ctx.clone(),
            config,
            count: [count(0)?, count(1)?],
            scatter: [scatter(0)?, scatter(1)?],
            reduce: Kernel::new(ctx, &scan_desc(&shaders::sort_scan_reduce::INFO))?,
            down: Kernel::new(ctx, &scan_desc(&shaders::sort_scan_down::INFO))?,
        })
    }

    /// The tuning in use.
    pub fn config(&self) -> &SortConfig {
        &self.config
    }

    /// Largest count one sort accepts: output positions are 32-bit.
    pub fn max_count(&self) -> u64 {
        u32::MAX as u64
    }

    /// Sizes of the buffers a sort of `count` keys of `key_bits` needs. Buffers at least this large may be reused
    /// for any smaller count.
    pub fn memory_requirements(&self, count: u64, key_bits: KeyBits) -> SortMemory {
        let blocks = count.div_ceil(self.config.block_keys());
        let tile = self.config.scan_tile();
        let mut scan_levels = vec![RADIX * blocks];
        while *scan_levels.last().unwrap_or(&0) > tile {
            let n = scan_levels.last().copied().unwrap_or(0).div_ceil(tile);
            scan_levels.push(n);
        }
        let mut scan_offsets = Vec::with_capacity(scan_levels.len());
        let mut offset = 0u64;
        for n in &scan_levels {
            scan_offsets.push(offset);
            offset = (offset + 4 * n).next_multiple_of(REGION_ALIGN);
        }
        SortMemory {
            count,
            key_bits,
            keys_bytes: (count * key_bits.bytes()).max(4),
            payload_bytes: (count * 4).max(4),
            internal_bytes: offset.max(4),
            blocks,
            scan_levels,
            scan_offsets,
        }
    }

    /// Records the sort of the first `count` keys (and payloads) of `buffers` into `rec`, and returns which buffers
    /// will hold the result.
    ///
    /// Synchronization:
    /// - **Begins** with [`Recorder::barrier`] (compute and transfer writes before it are visible to the sort, and
    ///   earlier reads of the buffers are finished), so the caller's uploads or kernels that produced the keys need
    ///   no barrier of their own.
    /// - Between its passes it records the same barrier.
    /// - **Ends** with the last scatter dispatch's shader writes to the result buffers, with no barrier after it:
    ///   the caller records one (such as [`Recorder::barrier`], or [`Recorder::host_read_barrier`] after a copy)
    ///   before reading the result.
    ///
    /// Every buffer must stay alive, and must not be used by other work, until the command buffer completes. Both
    /// key buffers (and both payload buffers) are overwritten; the internal buffer's content is meaningless after.
    ///
    /// Counts 0 and 1 record only the leading barrier (the input is sorted).
    ///
    /// Errors ([`GpuError::Buffer`], [`GpuError::Limit`]): a buffer smaller than [`RadixSort::memory_requirements`]
    /// says, a payload without its alternate, or `count` above [`RadixSort::max_count`]. Nothing is recorded then.
    pub fn record(
        &self,
        rec: &mut Recorder<'_>,
        buffers: &SortBuffers<'_>,
        count: u64,
        key_bits: KeyBits,
    ) -> Result<SortedIn> {
        if count > self.max_count() {
            return Err(GpuError::Limit { what: "keys in one sort".into(), requested: count, limit: self.max_count() });
        }
        let mem = self.memory_requirements(count, key_bits);
        let small = |b: &Buffer, need: u64| -> Result<()> {
            if b.size() < need {
                return Err(GpuError::Buffer(format!(
                    "sort of {count} keys: buffer {} has {} bytes, needs {need}",
                    b.name(),
                    b.size()
                )));
            }
            Ok(())
        };
        small(buffers.keys, mem.keys_bytes)?;
        small(buffers.keys_alt, mem.keys_bytes)?;
        small(buffers.internal, mem.internal_bytes)?;
        let payload = match (buffers.payload, buffers.payload_alt) {
            (Some(p), Some(q)) => {
                small(p, mem.payload_bytes)?;
                small(q, mem.payload_bytes)?;
                Some((p, q))
            }
            (None, None) => None,
            _ => return Err(GpuError::Buffer("sort: a payload buffer needs its alternate".into())),
        };

        rec.barrier();
        if count <= 1 {
            return Ok(SortedIn::Input);
        }
        let key64 = usize::from(key_bits == KeyBits::U64);
        let blocks = mem.blocks as u32;
        let counts = buffers.internal.address() + mem.scan_offsets[0];
        let block_groups = rec.groups_for(mem.blocks, 1);
        let passes = key_bits.passes();
        let (mut src, mut dst) = (buffers.keys, buffers.keys_alt);
        let mut vals = payload;
        for pass in 0..passes {
            let shift = pass * DIGIT_BITS;
            let push = SortCountPush {
                keys: src.address(),
                counts,
                count,
                blocks,
                block_keys: self.config.block_keys() as u32,
                shift,
                pad: 0,
            };
            // SAFETY: the sort buffers were sized by memory_requirements for these keys (checked in
            // record), and the kernel touches only those ranges.
            unsafe { rec.dispatch(&self.count[key64], &push, block_groups) };
            rec.dependency(Pass::Compute, Pass::Compute);
            self.record_scan(rec, buffers.internal, &mem);
            rec.dependency(Pass::Compute, Pass::Compute);
            let push = SortScatterPush {
                keys_in: src.address(),
                keys_out: dst.address(),
                vals_in: vals.map_or(0, |v| v.0.address()),
                vals_out: vals.map_or(0, |v| v.1.address()),
                counts,
                count,
                blocks,
                shift,
            };
            // SAFETY: the sort buffers were sized by memory_requirements for these keys (checked in
            // record), and the kernel touches only those ranges.
            unsafe { rec.dispatch(&self.scatter[key64], &push, block_groups) };
            if pass + 1 < passes {
                rec.dependency(Pass::Compute, Pass::Compute);
            }
            std::mem::swap(&mut src, &mut dst);
            vals = vals.map(|(a, b)| (b, a));
        }
        Ok(if passes % 2 == 0 { SortedIn::Input } else { SortedIn::Alternate })
    }

    /// Exclusive sum of the per-block counts, in place: tile sums up the levels, then scans down them.
    fn record_scan(&self, rec: &mut Recorder<'_>, internal: &Buffer, mem: &SortMemory) {
        let levels: Vec<(u64, u64)> = (0..mem.scan_levels.len())
            .map(|i| (internal.address() + mem.scan_offsets[i], mem.scan_levels[i]))
            .collect();
        self.record_scan_levels(rec, &levels);
    }

    /// Bytes of scratch [`RadixSort::record_exclusive_scan`] needs for `n` elements (the levels above the data).
    pub(crate) fn scan_scratch_bytes(&self, n: u64) -> u64 {
        self.scan_levels(n, 0).iter().skip(1).map(|&(_, m)| (4 * m).next_multiple_of(REGION_ALIGN)).sum::<u64>().max(4)
    }

    /// The levels of a scan of `n` elements at `data`, the upper ones packed from `scratch`.
    fn scan_levels(&self, n: u64, data: u64) -> Vec<(u64, u64)> {
        let tile = self.config.scan_tile();
        let mut levels = vec![(data, n)];
        let mut offset = 0u64;
        while levels.last().map_or(0, |l| l.1) > tile {
            let m = levels.last().map_or(0, |l| l.1).div_ceil(tile);
            levels.push((offset, m));
            offset += (4 * m).next_multiple_of(REGION_ALIGN);
        }
        levels
    }

    /// Records the exclusive prefix sum of the `n` `u32` at the start of `data`, in place (wrapping on overflow),
    /// with the sort's reduce-then-scan kernels; `scratch` holds [`RadixSort::scan_scratch_bytes`] bytes. Begins
    /// with [`Recorder::barrier`]; ends with the last kernel's writes to `data`, no barrier after.
    ///
    /// # Errors
    ///
    /// [`GpuError::Buffer`] when `data` holds fewer than `n` elements or `scratch` is too small.
    pub(crate) fn record_exclusive_scan(
        &self,
        rec: &mut Recorder<'_>,
        data: &Buffer,
        n: u64,
        scratch: &Buffer,
    ) -> Result<()> {
        if data.size() < 4 * n || scratch.size() < self.scan_scratch_bytes(n) {
            return Err(GpuError::Buffer(format!(
                "scan of {n} elements: buffers of {} and {} bytes (need {} and {})",
                data.size(),
                scratch.size(),
                4 * n,
                self.scan_scratch_bytes(n)
            )));
        }
        rec.barrier();
        if n == 0 {
            return Ok(());
        }
        let mut levels = self.scan_levels(n, data.address());
        for l in levels.iter_mut().skip(1) {
            l.0 += scratch.address();
        }
        self.record_scan_levels(rec, &levels);
        Ok(())
    }

    /// Up the levels (tile sums), then down (scans with the partials of the level above).
    fn record_scan_levels(&self, rec: &mut Recorder<'_>, levels: &[(u64, u64)]) {
        let tile = self.config.scan_tile();
        let level = |i: usize| levels[i];
        let top = levels.len() - 1;
        for i in 0..top {
            let ((src, n), (dst, _)) = (level(i), level(i + 1));
            let push = SortScanReducePush { src, dst, n };
            // SAFETY: the sort buffers were sized by memory_requirements for these keys (checked in
            // record), and the kernel touches only those ranges.
            unsafe { rec.dispatch(&self.reduce, &push, rec.groups_for(n, tile)) };
            rec.dependency(Pass::Compute, Pass::Compute);
        }
        let (data, n) = level(top);
        // SAFETY: the sort buffers were sized by memory_requirements for these keys (checked in
        // record), and the kernel touches only those ranges.
        unsafe { rec.dispatch(&self.down, &SortScanDownPush { data, partials: 0, n }, 1) };
        for i in (0..top).rev() {
            rec.dependency(Pass::Compute, Pass::Compute);
            let ((data, n), (partials, _)) = (level(i), level(i + 1));
            // SAFETY: the sort buffers were sized by memory_requirements for these keys (checked in
            // record), and the kernel touches only those ranges.
            unsafe { rec.dispatch(&self.down, &SortScanDownPush { data, partials, n }, rec.groups_for(n, tile)) };
        }
    }

    fn sort_slice<K: bytemuck::Pod>(
        &self,
        keys: &[K],
        payload: Option<&[u32]>,
        key_bits: KeyBits,
    ) -> Result<(Vec<K>, Option<Vec<u32>>)> {
        if let Some(p) = payload {
            if p.len() != keys.len() {
                return Err(GpuError::Buffer(format!("sort: {} keys but {} payloads", keys.len(), p.len())));
            }
        }
        let count = keys.len() as u64;
        if count > self.max_count() {
            return Err(GpuError::Limit { what: "keys in one sort".into(), requested: count, limit: self.max_count() });
        }
        let ctx = &self.ctx;
        let mem = self.memory_requirements(count, key_bits);
        let storage = SortStorage::new(ctx, &mem, payload.is_some())?;
        let key_bytes = count * key_bits.bytes();
        let mut staging = ctx.create_buffer("sort staging", key_bytes + 4 * count, MemoryKind::Upload)?;
        staging.write(0, keys)?;
        if let Some(p) = payload {
            staging.write(key_bytes, p)?;
        }
        let readback = ctx.create_buffer("sort readback", key_bytes + 4 * count, MemoryKind::Readback)?;
        ctx.submit_and_wait(|rec| {
            rec.copy(&staging, 0, &storage.keys, 0, key_bytes);
            if let Some((p, _)) = &storage.payload {
                rec.copy(&staging, key_bytes, p, 0, 4 * count);
            }
            let sorted_in = self.record(rec, &storage.buffers(), count, key_bits)?;
            rec.barrier();
            let (k, p) = storage.result(sorted_in);
            rec.copy(k, 0, &readback, 0, key_bytes);
            if let Some(p) = p {
                rec.copy(p, 0, &readback, key_bytes, 4 * count);
            }
            rec.host_read_barrier();
            Ok(())
        })?;
        let sorted: Vec<K> = readback.read(0, keys.len())?;
        let order = match payload {
            Some(_) => Some(readback.read(key_bytes, keys.len())?),
            None => None,
        };
        Ok((sorted, order))
    }

    /// Sorts `u32` keys (and their payloads, when given) on the device: uploads, sorts, reads back, waits.
    /// Stable: equal keys keep their input order.
    pub fn sort_u32(&self, keys: &[u32], payload: Option<&[u32]>) -> Result<(Vec<u32>, Option<Vec<u32>>)> {
        self.sort_slice(keys, payload, KeyBits::U32)
    }

    /// Sorts `u64` keys (and their payloads, when given) on the device: uploads, sorts, reads back, waits.
    /// Stable: equal keys keep their input order.
    pub fn sort_u64(&self, keys: &[u64], payload: Option<&[u32]>) -> Result<(Vec<u64>, Option<Vec<u32>>)> {
        self.sort_slice(keys, payload, KeyBits::U64)
    }
}

/// The CPU reference: a stable sort of `keys` carrying `payload` along (the test oracle of the GPU sort). Payloads
/// shorter than the keys are an error of the caller and give `None` for them.
#[cfg(test)]
pub(crate) fn sort_cpu<K: Ord + Copy>(keys: &[K], payload: Option<&[u32]>) -> (Vec<K>, Option<Vec<u32>>) {
    match payload.filter(|p| p.len() == keys.len()) {
        Some(p) => {
            let mut pairs: Vec<(K, u32)> = keys.iter().copied().zip(p.iter().copied()).collect();
            pairs.sort_by_key(|&(k, _)| k); // stable
            let (k, v) = pairs.into_iter().unzip();
            (k, Some(v))
        }
        None => {
            let mut k = keys.to_vec();
            k.sort_unstable(); // equal keys are indistinguishable
            (k, None)
        }
    }
}

#[cfg(test)]
mod tests;
