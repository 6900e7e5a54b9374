use std::path::PathBuf;

/// Everything that can go wrong reading or checking a mesh. Every variant names the file (or mesh) and the place.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The file's extension or content is not a format this crate reads.
    #[error("{path}: unknown mesh format (expected .obj or .ply)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
    /// The file could not be parsed.
    #[error("{file}: parse error at {place}: {reason}")]
    Parse {
        /// The file.
        file: String,
        /// Where (line, element, face ...).
        place: String,
        /// What the parser said.
        reason: String,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error("{file}: triangle {triangle} refers to vertex {index}, but there are only {vertices} vertices")]
    IndexOutOfRange {
        /// The file or mesh name; loaders append `:line` when the file is text (OBJ, ascii PLY).
        file: String,
        /// The triangle (its index in the loaded mesh, after polygons are split into triangles).
        triangle: usize,
        /// The bad index, as written in the file (1-based for OBJ, 0-based for PLY and meshes).
        index: u64,
        /// How many vertices exist.
        vertices: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("{file}: vertex {vertex} has a non-finite coordinate {value:?}")]
    NonFinite {
        /// The file or mesh name; loaders append `:line` when the file is text (OBJ, ascii PLY).
        file: String,
        /// The vertex, counted from 0 in file order (for OBJ, the `v` statements).
        vertex: usize,
        /// Its position.
        value: [f32; 3],
    },
    /// Frames of an animation do not share one topology.
    #[error("{other}: topology differs from the first frame {first}: {detail}")]
    TopologyMismatch {
        /// The first frame.
        first: String,
        /// The frame that differs.
        other: String,
        /// What differs.
        detail: String,
    },
    /// The file was read without error but holds no triangle: an empty or comment-only file, vertices only, faces
    /// of fewer than 3 corners only, triangle strips of restart markers only. Loaders refuse such a file rather than
    /// return an empty mesh.
    #[error("{file}: no triangles: {detail}")]
    NoTriangles {
        /// The file or mesh name.
        file: String,
        /// What the file holds instead (vertex and face counts, the elements read).
        detail: String,
    },
    /// A third-party parser (`tobj`, `ply-rs-bw`) panicked on the file. The loaders check their input so that this
    /// should not happen; the panic is caught and reported as an error instead of unwinding into the caller.
    #[error("{file}: the {parser} parser failed on this file (internal panic: {message})")]
    ParserPanic {
        /// The file or mesh name.
        file: String,
        /// Which parser (`OBJ` or `PLY`).
        parser: &'static str,
        /// The panic message, shortened.
        message: String,
    },
    /// Anything else that makes a mesh unusable.
    #[error("{file}: {reason}")]
    Invalid {
        /// The file or mesh name.
        file: String,
        /// Why.
        reason: String,
    },
}
