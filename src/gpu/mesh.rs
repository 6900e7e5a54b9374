//! Geometry on the device: a mesh's positions and indices ([`MeshBuffers`]), the centroid-key pass that the
//! characterization and the LBVH/HLBVH builders share (`glsl/keys_bounds.comp`, [`KeysPush`]), and the errors of
//! device operations that are about their input.

use crate::gpu::{Buffer, Context, GeometryView, GpuError, IndexType, Indices, Result, Vertices};
use crate::keys::{KeyBounds, KeyError};

pub(crate) use crate::gpu::shaders::keys_bounds::Push as KeysPush;

/// A mesh on the device: positions and indices, addressable by the kernels (and by a host engine).
#[derive(Debug)]
pub struct MeshBuffers {
    /// Vertex positions, f32 xyz.
    pub positions: Buffer,
    /// Triangle indices, u32 triples.
    pub indices: Buffer,
    /// Number of vertices.
    pub vertices: u64,
    /// Number of triangles.
    pub triangles: u64,
}

impl MeshBuffers {
    /// Uploads positions and indices.
    pub fn upload(ctx: &Context, positions: &[[f32; 3]], indices: &[[u32; 3]]) -> Result<Self> {
        let p = if positions.is_empty() { &[[0.0f32; 3]][..] } else { positions };
        let i = if indices.is_empty() { &[[0u32; 3]][..] } else { indices };
        Ok(MeshBuffers {
            positions: ctx.upload("positions", p)?,
            indices: ctx.upload("indices", i)?,
            vertices: positions.len() as u64,
            triangles: indices.len() as u64,
        })
    }

    /// The view of these buffers that every device operation reads: packed positions (stride 12), 32-bit indices.
    pub fn view(&self) -> GeometryView<'_> {
        GeometryView::new(
            Vertices { buffer: &self.positions, offset: 0, stride: 12, count: self.vertices },
            Some(Indices { buffer: &self.indices, offset: 0, index_type: IndexType::U32, base_vertex: 0 }),
            self.triangles,
        )
        .expect("the buffers of an upload hold what their counts say")
    }

    /// Replaces the positions (same vertex count): the next frame of an animation.
    pub fn update_positions(&self, ctx: &Context, positions: &[[f32; 3]]) -> Result<()> {
        if positions.len() as u64 != self.vertices {
            return Err(GpuError::Buffer(format!(
                "frame has {} vertices, the mesh on the device {}",
                positions.len(),
                self.vertices
            )));
        }
        ctx.write_buffer(&self.positions, 0, positions)
    }
}

/// Errors of a device operation that are about its input, not the device.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// Nothing to characterize.
    #[error("no triangles to characterize")]
    Empty,
    /// Centroid keys overflow f32, or their range cannot be quantized in f32 (`hi - lo` or `2^b / (hi - lo)`
    /// overflows).
    #[error("bounds of the centroid keys {lo:?} .. {hi:?} cannot be quantized in f32 (coordinates too large, or an extent below about 1e-35)")]
    Overflow {
        /// Lower bound of the keys.
        lo: [f32; 3],
        /// Upper bound of the keys.
        hi: [f32; 3],
    },
    /// Too many triangles for 32-bit class counts.
    #[error("{0} sampled triangles: at most 2^32 - 1 are supported")]
    TooMany(u64),
    /// The class plan is unusable.
    #[error("class plan: {0}")]
    Plan(String),
}

impl From<KeyError> for InputError {
    /// The device passes see only the bounds of the keys (an overflowing key makes them infinite), so every key
    /// error is [`InputError::Overflow`] of those bounds (of the key itself for [`KeyError::Overflow`]), or
    /// [`InputError::Empty`].
    fn from(e: KeyError) -> Self {
        match e {
            KeyError::Empty => InputError::Empty,
            KeyError::Overflow { key, .. } => InputError::Overflow { lo: key, hi: key },
            KeyError::Extent { lo, hi, .. } => InputError::Overflow { lo, hi },
        }
    }
}

/// The key bounds `glsl/keys_bounds.comp` reduced (six `u32` in [`crate::keys::ordered_bits`] form), read from byte
/// `offset` of a host-visible buffer.
pub(crate) fn bounds_read_back(buffer: &Buffer, offset: u64) -> Result<KeyBounds> {
    use crate::gpu::shaders::layout::{BOUNDS_HI, BOUNDS_LO, BOUNDS_WORDS};
    let u: Vec<u32> = buffer.read(offset, BOUNDS_WORDS as usize)?;
    let corner = |at: u32| -> Result<[u32; 3]> {
        let at = at as usize;
        u.get(at..at + 3)
            .and_then(|c| c.try_into().ok())
            .ok_or_else(|| GpuError::Buffer("key bounds: short read".into()))
    };
    let (lo, hi) = (corner(BOUNDS_LO)?, corner(BOUNDS_HI)?);
    Ok(KeyBounds::from_ordered_bits([lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]]))
}

/// Error of a device operation over a mesh (characterization, feature pass, BVH builds).
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// Device failure.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// Bad input.
    #[error(transparent)]
    Input(#[from] InputError),
}
