//! Device traversal of every structure: the layouts the kernels read ([`DeviceLayout`]), their upload
//! ([`DeviceStructure`]), and the traversal kernel ([`DeviceTracer`], `glsl/trace.comp`).
//!
//! # Layouts
//!
//! One definition, in `glsl/include/trace.glsl` (and `glsl/include/bvh.glsl` for [`BvhNode`]); the Rust types here
//! are generated from its reflection. An engine can traverse an uploaded structure in its own shaders by including
//! those two files:
//!
//! | structure | nodes | records |
//! |---|---|---|
//! | BVH, LBVH, HLBVH | [`BvhNode`] (32 bytes), root 0 | [`TriRecord`] in leaf order |
//! | kd-tree | [`KdNode`] (8 bytes), root 0, children `k + 1` and `k + offset` | [`TriRecord`] in mesh order, leaves list references (`u32`) |
//! | grid | `cells + 1` cell starts (`u32`) into the references | [`TriRecord`] in mesh order, references are mesh indices |
//! | BIH | [`BihNode`] (12 bytes), root 0, children `c` and `c + 1` | [`TriRecord`] in leaf order |
//!
//! Each structure also has a [`TraceScene`] header (scene box, grid resolution and cell size).
//!
//! # Exactness
//!
//! The kernel repeats the CPU tracer's arithmetic operation for operation (`precise`, no contraction; divisions and
//! square roots correctly rounded through f64), its tie rule and its traversal order, so each ray's hit triangle,
//! `t` bits and box and triangle test counts equal [`crate::accel::AccelStructure::intersect`]'s. It needs
//! `shaderFloat64` ([`DeviceTracer::new`] says so when the device lacks it) and a device that does not flush f32
//! denormals in the few places they can occur (a determinant or a distance below 2^-126).
//!
//! # Stack
//!
//! Each invocation keeps its stack in device memory, sized from the tree's depth ([`DeviceStructure::stack_entries`]),
//! and traces rays `g, g + G, ...`; the number of invocations `G` is chosen so that all stacks fit
//! [`STACK_BUDGET_BYTES`]. No tree is too deep for it; a ray whose stack would still overflow reports
//! [`TraceStatus::StackFull`] instead of a wrong hit.

mod kernel;
mod layout;

use super::{AccelError, StructureName};
use crate::geom::{Aabb, Hit, Ray, Triangle};
use crate::gpu::shaders::layout::{TRACE_MISS, TRACE_OK, TRACE_STACK_ENTRY_BYTES, TRACE_STACK_FULL, TRACE_STEP_LIMIT};
use crate::gpu::{shaders, Buffer, Context, GpuError, Kernel, KernelDesc, MemoryKind, Pass, Recorder, Timer};

use glam::Vec3;
pub use kernel::{DeviceTrace, DeviceTracer, SecondaryInputs, TraceBuffers, DEVICE_BUILT_STACK_ENTRIES};
pub use layout::{DeviceLayout, TraceStatus, TraversalKind};

pub(crate) use crate::gpu::shaders::trace::Push as TracePush;
pub(crate) use crate::gpu::shaders::trace_rays::Push as TraceRaysPush;
pub(crate) use crate::gpu::shaders::trace_records::Push as TraceRecordsPush;
pub(crate) use crate::gpu::shaders::trace_secondary::Push as TraceSecondaryPush;
pub use crate::gpu::shaders::{BihNode, BvhNode, KdNode, TraceHit, TraceRay, TraceScene, TriRecord};

/// The most bytes of traversal stacks one dispatch uses (all invocations together): 64 MiB, or less where the
/// device's `maxMemoryAllocationSize` is smaller.
pub const STACK_BUDGET_BYTES: u64 = 64 << 20;

/// Errors of uploading or tracing on the device.
#[derive(Debug, thiserror::Error)]
pub enum DeviceTraceError {
    /// The layout is malformed (an index out of range, nodes that are not one tree).
    #[error(transparent)]
    Layout(#[from] AccelError),
    /// The device failed or lacks what the kernel needs.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The structure has no device layout.
    #[error("{0}: no device traversal for this structure")]
    NoLayout(StructureName),
    /// Some rays stopped short (never on a structure this crate built).
    #[error("{count} rays stopped short, the first ({first}) with {status:?}")]
    Incomplete {
        /// Rays that stopped short.
        count: usize,
        /// The first of them.
        first: usize,
        /// Its status.
        status: TraceStatus,
    },
}

/// A structure uploaded for the traversal kernel.
pub struct DeviceStructure {
    kind: TraversalKind,
    nodes: Buffer,
    records: Buffer,
    refs: Buffer,
    scene: Buffer,
    stack_entries: u32,
    bytes: u64,
    upload_seconds: f64,
}

impl std::fmt::Debug for DeviceStructure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceStructure")
            .field("kind", &self.kind)
            .field("stack_entries", &self.stack_entries)
            .field("bytes", &self.bytes)
            .finish()
    }
}

impl DeviceStructure {
    /// Checks `layout` and uploads it (submits and waits).
    ///
    /// # Errors
    ///
    /// [`DeviceTraceError::Layout`] for a malformed layout, [`DeviceTraceError::Gpu`] when a buffer cannot be made.
    pub fn upload(ctx: &Context, layout: &DeviceLayout<'_>) -> Result<Self, DeviceTraceError> {
        let start = std::time::Instant::now();
        let p = layout.prepare()?;
        let nodes = ctx.upload("trace nodes", &p.nodes)?;
        let records = ctx.upload("trace records", &p.records)?;
        let refs = ctx.upload("trace references", &p.refs)?;
        let scene = ctx.upload("trace scene", std::slice::from_ref(&p.scene))?;
        let bytes = nodes.size() + records.size() + refs.size() + scene.size();
        Ok(DeviceStructure {
            kind: p.kind,
            nodes,
            records,
            refs,
            scene,
            stack_entries: p.stack_entries,
            bytes,
            upload_seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// A grid built on the device ([`crate::accel::gpu::grid::GpuGrid::into_device_structure`]): its cell starts,
    /// records and references, and the scene header.
    pub(crate) fn from_grid_parts(
        cell_start: Buffer,
        records: Buffer,
        refs: Buffer,
        scene: Buffer,
        upload: std::time::Duration,
    ) -> Self {
        let bytes = cell_start.size() + records.size() + refs.size() + scene.size();
        DeviceStructure {
            kind: TraversalKind::Grid,
            nodes: cell_start,
            records,
            refs,
            scene,
            stack_entries: 0,
            bytes,
            upload_seconds: upload.as_secs_f64(),
        }
    }

    /// Which traversal it needs.
    pub fn kind(&self) -> TraversalKind {
        self.kind
    }
    /// Stack entries each invocation needs: the tree's depth plus one (0 for the grid).
    pub fn stack_entries(&self) -> u32 {
        self.stack_entries
    }
    /// Sets the stack entries per invocation (at least 1). Fewer than the tree needs is safe: a trace that fills
    /// the stack is run again with twice as many ([`DeviceTracer::trace`]), which is how a device-built tree of
    /// unknown depth finds its size; more than it needs costs memory only.
    pub fn set_stack_entries(&mut self, entries: u32) {
        self.stack_entries = entries.max(1);
    }
    /// Device bytes of its buffers.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }
    /// Host wall seconds of [`DeviceStructure::upload`] (checks, staging, copies, waits).
    pub fn upload_seconds(&self) -> f64 {
        self.upload_seconds
    }
}

/// A pinhole camera as the primary-ray kernel takes it (the fields of [`crate::geom::Camera`], which converts into
/// it): pixel `(x, y)` of a `w x h` image looks along `forward + right * sx + up * sy`, normalized, with
/// `sx = ((x + 0.5) / w * 2 - 1) * tan_half_fov * w / h` and `sy = (1 - (y + 0.5) / h * 2) * tan_half_fov`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pinhole {
    /// Eye position.
    pub eye: Vec3,
    /// Unit viewing direction.
    pub forward: Vec3,
    /// Unit right vector.
    pub right: Vec3,
    /// Unit up vector.
    pub up: Vec3,
    /// `tan(fov_y / 2)`.
    pub tan_half_fov: f32,
}

impl From<&crate::geom::Camera> for Pinhole {
    fn from(c: &crate::geom::Camera) -> Self {
        Pinhole { eye: c.eye, forward: c.forward, right: c.right, up: c.up, tan_half_fov: c.tan_half_fov }
    }
}

#[cfg(test)]
mod tests {
    use super::layout::tree_depth;
    use super::*;
    use crate::gpu::shaders::layout;

    #[test]
    fn kernel_constants_are_the_host_tracers() {
        assert_eq!(layout::TRACE_SLAB_ROBUST_BITS, crate::geom::SLAB_ROBUST.to_bits());
        assert_eq!(layout::TRACE_KD_WIDEN_BITS, 1e-5f32.to_bits());
        assert_eq!(layout::TRACE_BIH_WIDEN_BITS, 2e-6f32.to_bits());
        assert_eq!(layout::TRACE_GRID_WIDEN_BITS, 1e-5f32.to_bits());
        assert_eq!(layout::TRACE_FLT_EPSILON_BITS, f32::EPSILON.to_bits());
        assert_eq!(TRACE_STACK_ENTRY_BYTES, 12);
    }

    #[test]
    fn layouts_have_the_documented_sizes() {
        assert_eq!(std::mem::size_of::<TriRecord>(), 48);
        assert_eq!(std::mem::size_of::<KdNode>(), 8);
        assert_eq!(std::mem::size_of::<BihNode>(), 12);
        assert_eq!(std::mem::size_of::<TraceScene>(), 64);
        assert_eq!(std::mem::size_of::<TraceRay>(), 32);
        assert_eq!(std::mem::size_of::<TraceHit>(), 32);
    }

    #[test]
    fn depth_of_a_chain_and_refusal_of_a_cycle() {
        // 0 -> (1, 2), 2 -> (3, 4): depth 2.
        let kids = |k: usize| match k {
            0 => Some((1, 2)),
            2 => Some((3, 4)),
            _ => None,
        };
        assert_eq!(tree_depth(5, kids, |_| (0, 1), 1).unwrap(), 2);
        assert!(tree_depth(5, kids, |_| (0, 2), 1).is_err(), "leaf past the records");
        assert!(tree_depth(3, |k| (k == 0).then_some((1, 0)), |_| (0, 0), 0).is_err(), "cycle");
        assert!(tree_depth(2, |k| (k == 0).then_some((1, 5)), |_| (0, 0), 0).is_err(), "child out of range");
        assert_eq!(tree_depth(0, |_| None, |_| (0, 0), 0).unwrap(), 0);
    }
}
