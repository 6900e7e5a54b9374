//! Refit of a device BVH for new vertex positions: leaf boxes, counters reset, bottom-up fit.

use super::*;

impl BvhBuilder {
    /// Records a refit of `bvh` for the positions now in `mesh` (same triangles as at build): leaf boxes, counters
    /// reset, bottom-up fit. A recorded build may be refitted before it is finished (in a later command buffer or
    /// later in the same one), unless it has the SAH collapse, whose node count is known only then.
    ///
    /// Synchronization: begins with [`Recorder::barrier`] (the new positions, written by a transfer or a kernel
    /// before, are visible); ends with the fit's shader writes to [`GpuBvh::nodes`] and no barrier after it: the
    /// caller records one before reading the nodes. `mesh` and `bvh` must stay alive until the command buffer
    /// completes.
    pub fn record_refit(&self, rec: &mut Recorder<'_>, mesh: &GeometryView<'_>, bvh: &GpuBvh) -> Result<()> {
        check_refit(mesh, bvh)?;
        rec.barrier();
        self.record_boxes(rec, mesh, &bvh.ids, &bvh.nodes, &bvh.parents, &bvh.counters, bvh.node_count(), None);
        Ok(())
    }

    /// Refits `bvh` for the positions now in `mesh` (see [`BvhBuilder::record_refit`]); submits and waits, and
    /// stores the pass times in [`GpuBvh::timings`].
    pub fn refit(&self, mesh: &GeometryView<'_>, bvh: &mut GpuBvh) -> Result<()> {
        check_refit(mesh, bvh)?;
        let ctx = self.ctx.clone();
        let mut timer = Timer::new(&ctx, 4)?;
        ctx.submit_and_wait(|rec| {
            rec.reset_timer(&mut timer);
            rec.barrier();
            rec.timestamp_start(&mut timer);
            self.record_boxes(
                rec,
                mesh,
                &bvh.ids,
                &bvh.nodes,
                &bvh.parents,
                &bvh.counters,
                bvh.node_count(),
                Some(&mut timer),
            );
            Ok(())
        })?;
        bvh.timings = timer.read()?;
        Ok(())
    }
}

/// A refit needs the tree's triangles, and a finished tree (a recorded build's node count is known only then).
fn check_refit(mesh: &GeometryView<'_>, bvh: &GpuBvh) -> Result<()> {
    if mesh.triangle_count() != bvh.triangles {
        return Err(GpuError::Buffer(format!(
            "refit: the geometry has {} triangles, the tree {}",
            mesh.triangle_count(),
            bvh.triangles
        )));
    }
    if bvh.pending.as_ref().is_some_and(|p| p.collapsed_count.is_some()) {
        return Err(GpuError::Buffer(
            "refit of a recorded build with the SAH collapse not yet finished (GpuBvh::finish reads its node count)"
                .into(),
        ));
    }
    Ok(())
}
