//! The tree passes of the device builders: codes, sort, the Karras radix tree, leaf boxes and the bottom-up fit, the
//! SAH collapse; the LBVH's build and recording, and the staged build shared with the HLBVH.

use super::hlbvh::top_error_word;
use super::*;

impl BvhBuilder {
    /// Builds the LBVH of the geometry on the device (two submissions: the bounds, then the tree).
    pub fn build_lbvh(&mut self, mesh: &GeometryView<'_>, o: &LbvhOptions) -> std::result::Result<GpuBvh, RunError> {
        self.build(mesh, o.bits, None, o.max_leaf)
    }

    /// Records an LBVH build into `rec` with a quantizer given in advance (no host round trip: in an animation, the
    /// quantizer of the previous frame's bounds, or of a characterization recorded before), then
    /// [`GpuBvh::finish`] once the command buffer has completed. A key outside the quantizer's bounds gets the code
    /// of the nearest cell (docs/spec.md, "Planned characterization"); with the quantizer of the geometry's own
    /// bounds the tree equals [`BvhBuilder::build_lbvh`]'s and the CPU reference's.
    ///
    /// Recording contract: the first access to the geometry is a compute-shader read (`keys_bounds`, `leaves`),
    /// the caller records a barrier before that makes its geometry writes visible to compute-shader reads; the
    /// last accesses are compute-shader writes to [`GpuBvh::nodes`], [`GpuBvh::parents`] and [`GpuBvh::ids`]
    /// (and, after the collapse, a transfer write of the node count to a readback buffer of the tree's own); the
    /// caller records a barrier before reading the tree. The tree and the builder must stay alive until the
    /// command buffer completes.
    pub fn record_lbvh(
        &mut self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        quantizer: &Quantizer,
        o: &LbvhOptions,
    ) -> std::result::Result<GpuBvh, RunError> {
        check_quantizer(quantizer, o.bits)?;
        let b = self.prepare(mesh, o.bits, None, o.max_leaf, false)?;
        self.record_pending(rec, mesh, quantizer, b)
    }

    pub(super) fn build(
        &mut self,
        mesh: &GeometryView<'_>,
        bits: MortonBits,
        hl: Option<(u32, usize)>,
        max_leaf: u32,
    ) -> std::result::Result<GpuBvh, RunError> {
        let b = self.prepare(mesh, bits, hl, max_leaf, false)?;
        let ctx = self.ctx.clone();
        let mut timer_owned = Timer::new(&ctx, 32)?;
        let timer = &mut timer_owned;
        let scratch = b.scratch.clone();

        // Submission 1: keys and their bounds.
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(timer);
            self.record_keys(rec, mesh, &b, timer);
            rec.dependency(Pass::Compute, Pass::Transfer);
            rec.copy(&scratch.bounds, 0, &scratch.bounds_readback, 0, 4 * BOUNDS_WORDS as u64);
            rec.host_read_barrier();
            Ok(())
        })?;
        let q = Quantizer::new(&bounds_read_back(&scratch.bounds_readback, 0)?, bits).map_err(InputError::from)?;

        // Submission 2: codes, sort, (clusters), tree, boxes.
        ctx.submit_and_wait(|rec| self.record_tree(rec, mesh, &b, q.lo(), q.scale(), timer))?;
        let BuildBuffers {
            n,
            total,
            max_leaf,
            collapsed,
            max_clusters,
            readback,
            bvh_nodes,
            bvh_ids,
            parents,
            counters,
            ..
        } = b;
        let mut timings: Vec<(String, f64)> = timer_owned.read()?;
        let kind = match hl {
            None => GpuBvhKind::Lbvh,
            Some((_, bins)) => self.host_top(
                &ctx,
                &readback,
                max_clusters,
                (&bvh_nodes, &parents, &counters),
                collapsed.as_ref(),
                total,
                max_leaf,
                bins,
                &mut timings,
            )?,
        };
        let (nodes, parents, node_count) = match collapsed {
            Some((out_nodes, out_parents, _, readback)) => {
                let size: Vec<u32> = readback.read(0, 1)?;
                let size = size[0] as u64;
                if size == 0 || size > total {
                    return Err(GpuError::Buffer(format!("collapse: {size} nodes read back")).into());
                }
                (out_nodes, out_parents, size)
            }
            None => (bvh_nodes, parents, total),
        };
        Ok(GpuBvh { kind, triangles: n, node_count, nodes, ids: bvh_ids, parents, counters, timings, pending: None })
    }

    /// Records codes, sort, (clusters), tree, boxes (and the collapse of an LBVH; the cluster roots' readback of an
    /// HLBVH) with the quantizer `lo`, `scale`.
    pub(super) fn record_tree(
        &self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        b: &BuildBuffers,
        lo: [f32; 3],
        scale: [f32; 3],
        timer: &mut Timer,
    ) -> Result<()> {
        let BuildBuffers {
            n,
            total,
            bits,
            hl,
            max_leaf,
            ref scratch,
            ref bvh_nodes,
            ref bvh_ids,
            ref parents,
            ref counters,
            ref collapsed,
            table_entries,
            max_clusters,
            ref table,
            ref starts,
            ref roots,
            ref top_work,
            device_top,
            ref readback,
        } = *b;
        let per_group = self.keys.workgroup_size() as u64 * ITEMS as u64;
        let b63 = usize::from(bits == MortonBits::Bits63);
        let shift = hl.map_or(0, |(cb, _)| bits.total() - cb);
        let key_bits = if b63 == 1 { KeyBits::U64 } else { KeyBits::U32 };
        rec.timestamp_start(timer);
        let (codes_buf, ids_buf) = match &scratch.sort.payload {
            Some((p, _)) => (&scratch.sort.keys, p),
            None => return Err(GpuError::Buffer("sort payload".into())),
        };
        let push = CodesPush {
            keys: scratch.keys.address(),
            codes: codes_buf.address(),
            ids: ids_buf.address(),
            count: n,
            lo_x: lo[0],
            lo_y: lo[1],
            lo_z: lo[2],
            scale_x: scale[0],
            scale_y: scale[1],
            scale_z: scale[2],
        };
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.codes[b63], &push, rec.groups_for(n, per_group)) };
        rec.timestamp(timer, "codes");
        let sorted_in = self.sort.record(rec, &scratch.sort.buffers(), n, key_bits)?;
        let (codes_buf, ids_buf) = match scratch.sort.result(sorted_in) {
            (k, Some(p)) => (k, p),
            (_, None) => return Err(GpuError::Buffer("sort payload".into())),
        };
        debug_assert_eq!(sorted_in, SortedIn::Input);
        rec.barrier();
        rec.timestamp(timer, "sort");
        if hl.is_some() {
            rec.fill(table, 0, None, u32::MAX);
            rec.barrier();
            let push = HeadsPush { codes: codes_buf.address(), table: table.address(), count: n, shift, pad: 0 };
            // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
            // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
            unsafe {
                rec.dispatch(&self.heads[b63], &push, rec.groups_for(n, self.heads[b63].workgroup_size() as u64))
            };
            rec.barrier();
            let push = ScanPush {
                table: table.address(),
                starts: starts.address(),
                nodes: bvh_nodes.address(),
                entries: table_entries,
                count: n as u32,
                pad: 0,
            };
            // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
            // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
            unsafe { rec.dispatch(&self.scan, &push, 1) };
            rec.timestamp(timer, "clusters");
        }
        rec.fill(parents, 0, None, u32::MAX);
        rec.barrier();
        let push = KarrasPush {
            codes: codes_buf.address(),
            ids: ids_buf.address(),
            nodes: bvh_nodes.address(),
            parents: parents.address(),
            table: table.address(),
            starts: starts.address(),
            count: n,
            shift,
            pad: 0,
        };
        let h = usize::from(hl.is_some());
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.karras[b63][h], &push, rec.groups_for(n, per_group)) };
        rec.timestamp(timer, "karras");
        rec.barrier();
        rec.copy(ids_buf, 0, bvh_ids, 0, 4 * n);
        self.record_boxes(rec, mesh, ids_buf, bvh_nodes, parents, counters, total, Some(timer));
        if let (None, Some(cl)) = (hl, &collapsed) {
            self.record_collapse(rec, bvh_nodes, parents, counters, total, cl, max_leaf, timer);
        }
        if hl.is_some() {
            rec.barrier();
            let push = RootsPush {
                starts: starts.address(),
                nodes: bvh_nodes.address(),
                roots: roots.address(),
                limit: max_clusters,
            };
            // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
            // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
            unsafe {
                rec.dispatch(&self.roots, &push, rec.groups_for(max_clusters, self.roots.workgroup_size() as u64))
            };
            rec.timestamp(timer, "roots");
            rec.barrier();
            if device_top {
                self.record_top(rec, b, timer);
                if let Some(cl) = &collapsed {
                    self.record_collapse(rec, bvh_nodes, parents, counters, total, cl, max_leaf, timer);
                }
                rec.barrier();
                rec.copy(starts, 0, readback, 0, 4);
                rec.copy(top_work, 4 * top_error_word(max_clusters), readback, 4, 4);
                rec.host_read_barrier();
            } else {
                rec.copy(starts, 0, readback, 0, 4 * (max_clusters + 2));
                rec.copy(roots, 0, readback, 4 * (max_clusters + 2), 32 * max_clusters);
                rec.host_read_barrier();
            }
        }
        Ok(())
    }

    /// Records the SAH collapse (`bvh_collapse_cost`, `bvh_compact`) of the `count` nodes of a fitted tree with
    /// one record per leaf into `out = (nodes, parents, info, readback)`, and copies the root's surviving node
    /// count to `readback` (begins with the barrier it needs after the fit).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn record_collapse(
        &self,
        rec: &mut Recorder<'_>,
        nodes: &Buffer,
        parents: &Buffer,
        counters: &Buffer,
        count: u64,
        out: &(Buffer, Buffer, Buffer, Buffer),
        max_leaf: u32,
        timer: &mut Timer,
    ) {
        let (out_nodes, out_parents, info, readback) = out;
        rec.barrier();
        rec.fill(counters, 0, Some(4 * count), 0);
        rec.barrier();
        let push = CollapseCostPush {
            nodes: nodes.address(),
            parents: parents.address(),
            counters: counters.address(),
            info: info.address(),
            count,
            max_leaf,
            pad: 0,
        };
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe {
            rec.dispatch(&self.collapse_cost, &push, rec.groups_for(count, self.collapse_cost.workgroup_size() as u64))
        };
        rec.timestamp(timer, "collapse_cost");
        rec.barrier();
        let push = CompactPush {
            nodes: nodes.address(),
            parents: parents.address(),
            info: info.address(),
            out_nodes: out_nodes.address(),
            out_parents: out_parents.address(),
            count,
        };
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.compact, &push, rec.groups_for(count, self.compact.workgroup_size() as u64)) };
        rec.timestamp(timer, "compact");
        rec.barrier();
        rec.copy(info, 4 * COLLAPSE_SIZE as u64, readback, 0, 4);
        rec.host_read_barrier();
    }

    /// Records the leaf boxes and the bottom-up fit of `count` nodes (begins with the barrier it needs after the
    /// tree's topology was written).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn record_boxes(
        &self,
        rec: &mut Recorder<'_>,
        mesh: &GeometryView<'_>,
        ids: &Buffer,
        nodes: &Buffer,
        parents: &Buffer,
        counters: &Buffer,
        count: u64,
        mut timer: Option<&mut Timer>,
    ) {
        let per_group = self.leaves.workgroup_size() as u64 * ITEMS as u64;
        rec.fill(counters, 0, Some(4 * count), 0);
        rec.barrier();
        let push = geometry_push!(LeavesPush, mesh, { ids: ids.address(), nodes: nodes.address(), count: count });
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.leaves, &push, rec.groups_for(count, per_group)) };
        if let Some(t) = timer.as_deref_mut() {
            rec.timestamp(t, "leaves");
        }
        rec.barrier();
        let push = FitPush { nodes: nodes.address(), parents: parents.address(), counters: counters.address(), count };
        // SAFETY: every address is a buffer of this build, sized in `prepare` for its n triangles and 2n - 1 nodes
        // (or of the tree being refitted, of the same sizes), and the view's triangles are valid per its constructor.
        unsafe { rec.dispatch(&self.fit, &push, rec.groups_for(count, self.fit.workgroup_size() as u64)) };
        if let Some(t) = timer {
            rec.timestamp(t, "fit");
        }
    }
}
