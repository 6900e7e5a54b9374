//! The HLBVH on the device: its clusters' top level, built on the host in the staged build
//! ([`BvhBuilder::build_hlbvh`]) or on the device in the recorded one ([`BvhBuilder::record_hlbvh`],
//! `glsl/hlbvh_top.comp`).

use super::*;

/// left after the last round is built serially too.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct TopPlan {
    task_min: u32,
    rounds: u32,
    groups: u32,
}

impl TopPlan {
    fn new(l: u64, nb: usize, cpu: bool) -> Self {
        let task_min = (2048 / nb.max(1) as u32).clamp(16, 128);
        let big = l.div_ceil(task_min as u64).max(1);
        let rounds = 64 - (big - 1).leading_zeros() + 1 + 8;
        let groups = if cpu { big.div_ceil(128).clamp(2, 128) } else { big.min(128) };
        TopPlan { task_min, rounds, groups: groups as u32 }
    }
}

/// Words of the device top level's scratch for at most `l` clusters (list, partition scratch, stack, header, tasks
/// and three queues: the layout of `glsl/hlbvh_top.comp`).
pub(super) fn top_work_words(l: u64) -> u64 {
    5 * l + 8 + 12 * (l / 2 + 1)
}

/// Word of the top level's error flags in its scratch.
pub(super) fn top_error_word(l: u64) -> u64 {
    5 * l + 1
}

/// The cluster count and the top level's error flags, copied to `readback` at the end of an HLBVH build with the
/// device top level: the count, or [`GpuError::Buffer`] when the flags are set or the count is out of range.
pub(super) fn read_top_status(readback: &Buffer, limit: u64) -> Result<u64> {
    let w: Vec<u32> = readback.read(0, 2)?;
    if w[1] != 0 {
        return Err(GpuError::Buffer(format!("hlbvh top level: error flags {:#x}", w[1])));
    }
    let c = w[0] as u64;
    if c == 0 || c > limit {
        return Err(GpuError::Buffer(format!("hlbvh: {c} clusters read back")));
    }
    Ok(c)
}

impl BvhBuilder {
    /// Builds the HLBVH of the geometry: everything but the top level over the clusters on the device (see the
    /// module docs). `cluster_bits` above [`MAX_GPU_CLUSTER_BITS`] gives [`GpuError::Limit`].
    pub fn build_hlbvh(&mut self, mesh: &GeometryView<'_>, o: &HlbvhOptions) -> std::result::Result<GpuBvh, RunError> {
        let cb = gpu_cluster_bits(o)?;
        self.build(mesh, o.bits, Some((cb, o.bins)), o.max_leaf)
    }

    /// Records a whole HLBVH build into `rec` with a quantizer given in advance: keys, codes, sort, clusters, the
    /// cluster trees and their boxes, the cluster roots, the top level on the device (`glsl/hlbvh_top.comp`, the
    /// binned SAH of the CPU reference, node for node), the parent links and the SAH collapse, with no host
    /// round trip; then [`GpuBvh::finish`] once the command buffer has completed (it reads the cluster count into
    /// [`GpuBvh::kind`], which says 0 clusters before). With the quantizer of the geometry's own bounds the tree
    /// equals [`BvhBuilder::build_hlbvh`]'s and the CPU reference's ([`crate::accel::hlbvh::Hlbvh::build_with`]).
    ///
    /// The recording contract is [`BvhBuilder::record_lbvh`]'s (the first geometry access a compute-shader read,
    /// the last accesses compute-shader writes to the tree's buffers and transfer writes to readback buffers of the
    /// tree's own; the caller records a barrier before reading the tree; tree and builder alive until the command
    /// buffer completes). Errors: [`InputError::Plan`] when the quantizer's code width is not the options',
    /// [`GpuError::Limit`] above [`MAX_GPU_CLUSTER_BITS`], [`InputError::Empty`] for no triangles.
    pub fn record_hlbvh(
        &mut self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        quantizer: &Quantizer,
        o: &HlbvhOptions,
    ) -> std::result::Result<GpuBvh, RunError> {
        check_quantizer(quantizer, o.bits)?;
        let cb = gpu_cluster_bits(o)?;
        let b = self.prepare(mesh, o.bits, Some((cb, o.bins)), o.max_leaf, true)?;
        self.record_pending(rec, mesh, quantizer, b)
    }

    /// The staged HLBVH's top level, on the host: reads back the cluster count, starts and root boxes, builds the
    /// top over the cluster boxes with the CPU reference's function ([`crate::accel::hlbvh::top_tree`]), uploads
    /// it with the parent links (`bvh_parents`) and runs the SAH collapse when there is one (`collapsed`). Pushes
    /// `top_cpu` (host time with the transfers) and the collapse's passes to `timings`; returns the cluster count.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn host_top(
        &self,
        ctx: &Context,
        readback: &Buffer,
        max_clusters: u64,
        (bvh_nodes, parents, counters): (&Buffer, &Buffer, &Buffer),
        collapsed: Option<&(Buffer, Buffer, Buffer, Buffer)>,
        total: u64,
        max_leaf: u32,
        bins: usize,
        timings: &mut Vec<(String, f64)>,
    ) -> std::result::Result<GpuBvhKind, RunError> {
        let t0 = std::time::Instant::now();
        let c: Vec<u32> = readback.read(0, 1)?;
        let c = c[0] as u64;
        if c == 0 || c > max_clusters {
            return Err(GpuError::Buffer(format!("hlbvh: {c} clusters read back")).into());
        }
        let mut timer2 = Timer::new(ctx, 8)?;
        if c > 1 {
            let starts_host: Vec<u32> = readback.read(4, c as usize)?;
            let root_nodes: Vec<BvhNode> = readback.read(4 * (max_clusters + 2), c as usize)?;
            let root_ids: Vec<u32> =
                starts_host.iter().enumerate().map(|(k, &s)| (c as u32 - 1) + 2 * s - k as u32).collect();
            let boxes: Vec<Aabb> = root_nodes.iter().map(|nd| nd.aabb()).collect();
            let mut list: Vec<u32> = (0..c as u32).collect();
            let mut top = Vec::with_capacity(c as usize - 1);
            crate::accel::hlbvh::top_tree(&mut list, &root_ids, &boxes, bins, &mut top);
            let mut staging = ctx.create_buffer("hlbvh top", 32 * top.len() as u64, MemoryKind::Upload)?;
            staging.write(0, &top)?;
            ctx.submit_and_wait(|rec| {
                rec.copy(&staging, 0, bvh_nodes, 0, 32 * top.len() as u64);
                rec.barrier();
                let push = ParentsPush { nodes: bvh_nodes.address(), parents: parents.address(), count: c - 1 };
                // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
                // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
                unsafe {
                    rec.dispatch(&self.parents, &push, rec.groups_for(c - 1, self.parents.workgroup_size() as u64))
                };
                if let Some(cl) = &collapsed {
                    rec.reset_timer(&mut timer2);
                    rec.timestamp_start(&mut timer2);
                    self.record_collapse(rec, bvh_nodes, parents, counters, total, cl, max_leaf, &mut timer2);
                }
                Ok(())
            })?;
        } else if let Some(cl) = &collapsed {
            ctx.submit_and_wait(|rec| {
                rec.reset_timer(&mut timer2);
                rec.timestamp_start(&mut timer2);
                self.record_collapse(rec, bvh_nodes, parents, counters, total, cl, max_leaf, &mut timer2);
                Ok(())
            })?;
        }
        let host_ms = t0.elapsed().as_secs_f64() * 1e3;
        let collapse_ms: Vec<(String, f64)> = if collapsed.is_some() { timer2.read()? } else { Vec::new() };
        let device_ms: f64 = collapse_ms.iter().map(|t| t.1).sum();
        timings.push(("top_cpu".into(), host_ms - device_ms));
        timings.extend(collapse_ms);
        Ok(GpuBvhKind::Hlbvh { clusters: c as u32 })
    }

    /// Records the device top level of an HLBVH (`glsl/hlbvh_top.comp`: its phase 0, the rounds of phase 1, phase 2
    /// over the serial subtrees), which writes the `C - 1` top nodes and their children's parent links. Begins after
    /// the barrier that follows `hlbvh_roots`; ends with the shader writes of phase 2 and no barrier after them.
    pub(super) fn record_top(&self, rec: &mut Recorder<'_>, b: &BuildBuffers, timer: &mut Timer) {
        let bins = b.hl.map_or(2, |(_, bins)| bins);
        let (nb, factor) = crate::accel::hlbvh::top_bins(bins);
        let plan = TopPlan::new(b.max_clusters, nb, self.ctx.caps().device_type == DeviceType::Cpu);
        let wg = self.top.workgroup_size() as u64;
        let mut push = TopPush {
            starts: b.starts.address(),
            roots: b.roots.address(),
            nodes: b.bvh_nodes.address(),
            parents: b.parents.address(),
            work: b.top_work.address(),
            limit: b.max_clusters as u32,
            bins: nb as u32,
            factor,
            task_min: plan.task_min,
            phase: 0,
            round: 0,
        };
        // SAFETY: starts holds max_clusters + 2 words and roots max_clusters nodes (written by hlbvh_scan and
        // hlbvh_roots), nodes and parents 2n - 1 entries (the top nodes and every cluster root are among them), and
        // the work buffer top_work_words(max_clusters) words, the layout the kernel indexes with `limit`.
        unsafe { rec.dispatch(&self.top, &push, rec.groups_for(b.max_clusters, wg)) };
        rec.barrier();
        push.phase = 1;
        for round in 0..plan.rounds {
            push.round = round;
            // SAFETY: as above.
            unsafe { rec.dispatch(&self.top, &push, plan.groups) };
            rec.barrier();
        }
        rec.timestamp(timer, "top_rounds");
        push.phase = 2;
        push.round = plan.rounds;
        // SAFETY: as above.
        unsafe { rec.dispatch(&self.top, &push, rec.groups_for(b.max_clusters / 2 + 1, wg)) };
        rec.timestamp(timer, "top_tasks");
    }

    /// Divides `a / b` for every pair on the device with the correctly rounded division of the HLBVH's top level
    /// (`div_rn` in `glsl/hlbvh_top.comp`, integer arithmetic, round to nearest even), which gives the bin scales
    /// their host values: a check of the kernel's arithmetic against the host's `/`. Every `a` is positive and
    /// finite, every `b` positive (finite, subnormal or infinite); other pairs, or more than 2^28 of them, give
    /// [`GpuError::Buffer`].
    #[cfg(test)]
    pub(crate) fn device_divide(&self, pairs: &[(f32, f32)]) -> Result<Vec<f32>> {
        if pairs.is_empty() {
            return Ok(Vec::new());
        }
        if pairs.len() > 1 << 28 {
            return Err(GpuError::Buffer(format!("device_divide: {} pairs (at most 2^28)", pairs.len())));
        }
        if let Some(&(a, b)) = pairs.iter().find(|&&(a, b)| !(a > 0.0 && a.is_finite() && b > 0.0)) {
            return Err(GpuError::Buffer(format!("device_divide: {a} / {b} is outside the division's domain")));
        }
        let l = pairs.len() as u64;
        let mut words: Vec<u32> = pairs.iter().flat_map(|&(a, b)| [a.to_bits(), b.to_bits()]).collect();
        words.resize(3 * pairs.len(), 0);
        let work = self.ctx.upload("hlbvh top division", &words)?;
        let push = TopPush { work: work.address(), limit: l as u32, bins: 2, phase: 3, ..TopPush::default() };
        self.ctx.submit_and_wait(|rec| {
            rec.barrier();
            // SAFETY: phase 3 reads 2 l words of `work` and writes l more after them (3 l in all); it touches no
            // other address.
            unsafe { rec.dispatch(&self.top, &push, rec.groups_for(l, self.top.workgroup_size() as u64)) };
            rec.barrier();
            Ok(())
        })?;
        let q: Vec<u32> = self.ctx.read_buffer(&work, 8 * l, pairs.len())?;
        Ok(q.into_iter().map(f32::from_bits).collect())
    }
}

/// The cluster width of an HLBVH build on the device: [`GpuError::Limit`] above [`MAX_GPU_CLUSTER_BITS`].
pub(super) fn gpu_cluster_bits(o: &HlbvhOptions) -> Result<u32> {
    let cb = o.cluster_bits.min(o.bits.total());
    if cb > MAX_GPU_CLUSTER_BITS {
        return Err(GpuError::Limit {
            what: "HLBVH cluster bits on the GPU".into(),
            requested: cb as u64,
            limit: MAX_GPU_CLUSTER_BITS as u64,
        });
    }
    Ok(cb)
}
