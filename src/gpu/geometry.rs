//! Geometry views: how every device operation reads triangles, straight out of a caller's buffers.
//!
//! A [`GeometryView`] names where the positions are (the address of vertex 0's position, the stride between
//! vertices, how many there are), where the indices are and of which type (16-bit, 32-bit, or none for a plain
//! triangle list), how many triangles, and a base vertex added to every index. That covers what engines keep:
//! interleaved vertices (position, normal, uv at a 32-byte stride), 16- or 32-bit indices, several meshes in one
//! buffer at offsets. The kernels read through `glsl/include/geometry.glsl`; a vertex number at or past the view's
//! vertex count reads the last vertex instead, so a bad index in an engine's buffer gives a wrong triangle, never a
//! read outside the view.
//!
//! Two ways to make one: [`GeometryView::new`] over the crate's own [`Buffer`]s, safe (ranges and alignment are
//! checked against the buffers, which the view borrows), and [`GeometryView::from_addresses`] over raw device
//! addresses, `unsafe`. [`MeshBuffers::view`](super::MeshBuffers::view) gives the view of an uploaded mesh.
//!
//! ```no_run
//! use meshchar::gpu::{Context, ContextDesc, GeometryView, IndexType, MemoryKind, Vertices, Indices};
//! let ctx = Context::new(&ContextDesc::default())?;
//! // Interleaved vertices (position, normal, uv: 32 bytes), 16-bit indices, two meshes in one buffer each.
//! let vertices = ctx.create_buffer("vertices", 32 * 1000, MemoryKind::DeviceLocal)?;
//! let indices = ctx.create_buffer("indices", 2 * 3 * 600, MemoryKind::DeviceLocal)?;
//! let second = GeometryView::new(
//!     Vertices { buffer: &vertices, offset: 32 * 400, stride: 32, count: 600 },
//!     Some(Indices { buffer: &indices, offset: 2 * 3 * 200, index_type: IndexType::U16, base_vertex: 0 }),
//!     400,
//! )?;
//! assert_eq!(second.triangle_count(), 400);
//! # Ok::<(), meshchar::gpu::GpuError>(())
//! ```

use super::{Buffer, GpuError, Result};
use std::marker::PhantomData;

/// The type of a view's indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum IndexType {
    /// No index buffer: triangle `t` is vertices `3t`, `3t + 1`, `3t + 2`.
    None,
    /// 16-bit indices (`VK_INDEX_TYPE_UINT16`).
    U16,
    /// 32-bit indices (`VK_INDEX_TYPE_UINT32`).
    U32,
}

impl IndexType {
    /// Bytes per index (0 for [`IndexType::None`]).
    pub fn bytes(self) -> u64 {
        match self {
            IndexType::None => 0,
            IndexType::U16 => 2,
            IndexType::U32 => 4,
        }
    }

    /// The `GEOMETRY_INDEX_*` code of `glsl/include/geometry.glsl`.
    pub fn code(self) -> u32 {
        use super::shaders::layout::{GEOMETRY_INDEX_NONE, GEOMETRY_INDEX_U16, GEOMETRY_INDEX_U32};
        match self {
            IndexType::None => GEOMETRY_INDEX_NONE,
            IndexType::U16 => GEOMETRY_INDEX_U16,
            IndexType::U32 => GEOMETRY_INDEX_U32,
        }
    }
}

/// Where a view's vertex positions are in one of the crate's buffers.
#[derive(Clone, Copy, Debug)]
pub struct Vertices<'a> {
    /// The buffer.
    pub buffer: &'a Buffer,
    /// Byte offset of vertex 0's position (the vertex's offset plus the position's offset inside the vertex).
    pub offset: u64,
    /// Bytes from one vertex to the next (a multiple of 4, at least 12).
    pub stride: u32,
    /// Number of vertices.
    pub count: u64,
}

/// Where a view's indices are in one of the crate's buffers.
#[derive(Clone, Copy, Debug)]
pub struct Indices<'a> {
    /// The buffer.
    pub buffer: &'a Buffer,
    /// Byte offset of the first index (a multiple of the index size).
    pub offset: u64,
    /// [`IndexType::U16`] or [`IndexType::U32`].
    pub index_type: IndexType,
    /// Added to every index before its vertex is read.
    pub base_vertex: u32,
}

/// Triangles in device memory, as the kernels read them (see the module docs). Cheap to copy; it borrows the
/// buffers it was made from (lifetime `'a`), or nothing when made from raw addresses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GeometryView<'a> {
    positions: u64,
    vertex_stride: u32,
    vertex_count: u64,
    indices: u64,
    index_type: IndexType,
    base_vertex: u32,
    triangle_count: u64,
    _buffers: PhantomData<&'a Buffer>,
}

fn bad(what: String) -> GpuError {
    GpuError::Buffer(format!("geometry view: {what}"))
}

impl<'a> GeometryView<'a> {
    /// A view over the crate's buffers: `triangles` triangles, indexed when `indices` is given (else a triangle
    /// list over the vertices). Checks that every byte the kernels read lies inside the buffers (a 16-bit index
    /// range is rounded up to the 32-bit word that holds its last index), the alignment (positions and stride to
    /// 4 bytes, indices to their size), and the counts (vertices for a triangle list; at least one vertex for
    /// triangles).
    pub fn new(vertices: Vertices<'a>, indices: Option<Indices<'a>>, triangles: u64) -> Result<Self> {
        let Vertices { buffer, offset, stride, count } = vertices;
        check_layout(buffer.address().wrapping_add(offset), stride, count, triangles)?;
        if count > 0 {
            let end = (count - 1)
                .checked_mul(stride as u64)
                .and_then(|b| b.checked_add(offset)?.checked_add(12))
                .ok_or_else(|| bad(format!("{count} vertices at stride {stride} overflow")))?;
            if end > buffer.size() {
                return Err(bad(format!(
                    "{count} vertices at offset {offset}, stride {stride} need {end} bytes; {} has {}",
                    buffer.name(),
                    buffer.size()
                )));
            }
        }
        let (address, index_type, base_vertex) = match indices {
            None => {
                check_list(count, triangles)?;
                (0, IndexType::None, 0)
            }
            Some(Indices { buffer: ib, offset: io, index_type, base_vertex }) => {
                if index_type == IndexType::None {
                    return Err(bad("an index buffer with index type None".into()));
                }
                let bytes = triangles
                    .checked_mul(3 * index_type.bytes())
                    .and_then(|b| b.checked_add(io))
                    .ok_or_else(|| bad(format!("{triangles} triangles of indices overflow")))?;
                let end = if triangles == 0 { 0 } else { bytes.next_multiple_of(4) };
                if end > ib.size() {
                    return Err(bad(format!(
                        "{triangles} triangles of {:?} indices at offset {io} need {end} bytes; {} has {}",
                        index_type,
                        ib.name(),
                        ib.size()
                    )));
                }
                let address = ib.address().wrapping_add(io);
                check_index_alignment(address, index_type)?;
                (address, index_type, base_vertex)
            }
        };
        Ok(GeometryView {
            positions: buffer.address() + offset,
            vertex_stride: stride,
            vertex_count: count,
            indices: address,
            index_type,
            base_vertex,
            triangle_count: triangles,
            _buffers: PhantomData,
        })
    }
}

impl GeometryView<'static> {
    /// A view over raw device addresses (an engine's buffers): `positions` is the address of vertex 0's position,
    /// `indices` the address of the first index and its type (ignored for [`IndexType::None`]). The alignment and
    /// counts are checked as in [`GeometryView::new`]; the ranges cannot be.
    ///
    /// # Safety
    ///
    /// - Every address must belong to a buffer created with `VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT` on the
    ///   device of the context the view is used with.
    /// - The buffers must hold what the counts say: `vertex_count` vertices of at least 12 bytes at `stride` from
    ///   `positions`, and `3 * triangles` indices from `indices` (for 16-bit indices, the 32-bit word holding the
    ///   last one must lie inside the buffer too).
    /// - The buffers must stay alive, and their contents unchanged by anything not ordered before the work by the
    ///   caller's own barriers, until every command recorded with the view has completed.
    pub unsafe fn from_addresses(
        positions: u64,
        stride: u32,
        vertex_count: u64,
        indices: Option<(u64, IndexType, u32)>,
        triangles: u64,
    ) -> Result<Self> {
        check_layout(positions, stride, vertex_count, triangles)?;
        let (address, index_type, base_vertex) = match indices {
            None | Some((_, IndexType::None, _)) => {
                check_list(vertex_count, triangles)?;
                (0, IndexType::None, 0)
            }
            Some((a, t, b)) => {
                check_index_alignment(a, t)?;
                if a == 0 && triangles > 0 {
                    return Err(bad("a null index address".into()));
                }
                (a, t, b)
            }
        };
        Ok(GeometryView {
            positions,
            vertex_stride: stride,
            vertex_count,
            indices: address,
            index_type,
            base_vertex,
            triangle_count: triangles,
            _buffers: PhantomData,
        })
    }
}

fn check_layout(positions: u64, stride: u32, count: u64, triangles: u64) -> Result<()> {
    if stride < 12 || stride % 4 != 0 {
        return Err(bad(format!("vertex stride {stride}: it must be a multiple of 4 and at least 12")));
    }
    if positions % 4 != 0 {
        return Err(bad(format!("position address 0x{positions:x} is not 4-byte aligned")));
    }
    if triangles > 0 && count == 0 {
        return Err(bad(format!("{triangles} triangles over no vertices")));
    }
    if triangles > 0 && positions == 0 {
        return Err(bad("a null position address".into()));
    }
    Ok(())
}

fn check_list(vertices: u64, triangles: u64) -> Result<()> {
    if triangles.checked_mul(3).is_none_or(|v| v > vertices) {
        return Err(bad(format!(
            "a list of {triangles} triangles needs {} vertices; the view has {vertices}",
            3 * triangles as u128
        )));
    }
    Ok(())
}

fn check_index_alignment(address: u64, index_type: IndexType) -> Result<()> {
    if address % index_type.bytes().max(1) != 0 {
        return Err(bad(format!("{index_type:?} index address 0x{address:x} is not aligned to its size")));
    }
    Ok(())
}

impl GeometryView<'_> {
    /// Number of triangles.
    pub fn triangle_count(&self) -> u64 {
        self.triangle_count
    }
    /// Number of vertices addressable from [`GeometryView::positions`].
    pub fn vertex_count(&self) -> u64 {
        self.vertex_count
    }
    /// Device address of vertex 0's position.
    pub fn positions(&self) -> u64 {
        self.positions
    }
    /// Bytes between vertices.
    pub fn vertex_stride(&self) -> u32 {
        self.vertex_stride
    }
    /// Device address of the first index (0 for a triangle list).
    pub fn indices(&self) -> u64 {
        self.indices
    }
    /// The index type.
    pub fn index_type(&self) -> IndexType {
        self.index_type
    }
    /// Added to every index.
    pub fn base_vertex(&self) -> u32 {
        self.base_vertex
    }
    /// The same view over its first `triangles` triangles (at most its own count): for sampled or partial work.
    pub fn first_triangles(&self, triangles: u64) -> Self {
        GeometryView { triangle_count: triangles.min(self.triangle_count), ..*self }
    }
}

/// Fills the geometry members (`glsl/include/geometry.glsl`) of a generated push-constant struct from a view:
/// `geometry_push!(KeysPush, view, { keys: .., result: .., count: .., stride: .. })`.
macro_rules! geometry_push {
    ($push:ident, $view:expr, { $($field:ident : $value:expr),* $(,)? }) => {{
        let v: &$crate::gpu::GeometryView<'_> = $view;
        $push {
            positions: v.positions(),
            indices: v.indices(),
            vertex_count: v.vertex_count(),
            vertex_stride: v.vertex_stride(),
            index_type: v.index_type().code(),
            base_vertex: v.base_vertex(),
            geometry_pad: 0,
            $($field: $value),*
        }
    }};
}
pub(crate) use geometry_push;
