//! Mesh loaders: OBJ (through `tobj`) and PLY (through `ply-rs-bw`: ascii and binary, face lists and triangle strips),
//! and animations from a directory or a list of frame files.
//!
//! # What a loaded mesh contains
//!
//! * Positions only. Normals, texture coordinates, colours and any extra PLY vertex property are ignored.
//! * Polygons are split into triangles as a fan around their first corner: a polygon `(v0, v1, ..., vk)` gives
//!   `(v0, v1, v2), (v0, v2, v3), ..., (v0, vk-1, vk)`, so a face of `n >= 3` corners gives `n - 2` triangles.
//! * Faces with fewer than 3 corners (points and segments) describe no triangle and give none. This is not an error,
//!   and it is what the fan rule gives for them (`max(n - 2, 0)` triangles).
//! * Zero-area triangles are kept: they are real input (see [`Mesh::zero_area_count`]).
//! * At least one triangle: a file that describes none (empty, comments or vertices only, points and segments only,
//!   triangle strips of restart markers only, text that merely has an `.obj` name) is refused with
//!   [`MeshError::NoTriangles`].
//!
//! # What a load refuses
//!
//! Every error is a [`MeshError`] that names the file and, where there is one, the place in it (`file:line`, a
//! `line N`, a PLY `element 'name' i` or `header line N`). No input makes a loader panic, hang or succeed on nothing:
//!
//! * Only regular files are read (symbolic links are followed). A directory, FIFO, socket or device (`/dev/zero`)
//!   is refused from its metadata, before it is opened, as a [`MeshError::Io`] saying what it is; [`load_path`]
//!   checks the `.obj` and `.ply` entries of a directory in the same way.
//! * OBJ text is scanned before `tobj` sees it: every face corner's vertex, texture and normal index (1-based or
//!   negative, relative) must parse and lie within the statements of its kind (texture and normal indices are only
//!   checked when the file has `vt` or `vn` statements, since they are ignored otherwise).
//! * A PLY header is checked in full before the payload is read: no element or property name twice, no element with
//!   items but no properties, integer list counts, format version 1, and a payload at least as long as the header
//!   requires (its minimum byte size is computed from the counts and types; counts that cannot fit in the file are
//!   refused). Every binary list count is checked against the bytes left before the list is read.
//! * `tobj` and `ply-rs-bw` run under [`std::panic::catch_unwind`]: should one of them panic on input the checks
//!   above missed, the load returns [`MeshError::ParserPanic`] naming the file (the panic message still goes to the
//!   panic hook, by default standard error). This backstop needs the default `panic = "unwind"`.
//! * Messages stay short: text quoted from the file (names, tokens, parser messages) is cut to a few hundred
//!   characters and ends with `...` when cut.
//!
//! # Memory
//!
//! Loading a file of `n` bytes has at most [`LOAD_BYTES_PER_INPUT_BYTE`]` * n + `[`LOAD_BYTES_FIXED`] heap bytes
//! allocated at its peak, the file's own bytes and the returned mesh included (a reallocation counts as a new block
//! while the old one is still live). The test suite checks this on inputs built to maximise memory per byte, at
//! sizes where growing vectors are nearly half empty: the worst are OBJ files of one-triangle groups (about 76 bytes
//! per byte: `tobj` keeps a model of some 250 bytes for every 10-byte `g`/`f` pair), long OBJ polygons with texture
//! and normal indices (about 50) and PLY triangle strips of one-byte indices (about 36); real meshes need far less.
//! No buffer is sized from a count in the file before the file is known to hold that many items (a PLY header that
//! promises more than the file holds is refused before anything is reserved), and the file itself is read into one
//! buffer of exactly its length.
//!
//! # OBJ
//!
//! Every object or group of the file becomes one `tobj` model; the models are concatenated in file order, so triangle
//! `i` of the mesh is the `i`-th triangle of the file. When there is more than one model, [`Mesh::object_ids`] holds
//! the model index of every triangle. Each model keeps the vertices its faces use, so the vertex count can differ from
//! the number of `v` statements (unused vertices are dropped, a vertex used by two models appears twice). Polyline
//! statements (`l`) and faces of 1 or 2 corners are ignored, so a group holding only those is no object, like an
//! empty group. Errors name the line (`file:line` or `line N`): the pre-scan knows it, and for the
//! errors only `tobj` finds the text is scanned again to find the offending statement.
//!
//! # PLY
//!
//! The `vertex` element must have `x`, `y` and `z` properties of any scalar type (converted to f32). Triangles come
//! from a `face` element (list property `vertex_indices` or `vertex_index`, any integer count and index types,
//! polygons fan-triangulated) and from a `tristrips` element (list property `vertex_indices`; `-1` ends a strip and
//! starts another; the winding alternates along a strip, so the `j`-th triangle of a strip is `(s[j], s[j+1], s[j+2])`
//! for even `j` and `(s[j+1], s[j], s[j+2])` for odd `j`). Other elements are read and ignored. Errors name the
//! element and its index, and for ascii files the line (`file:line`).
//!
//! [`Mesh::object_ids`]: crate::mesh::Mesh::object_ids
//! [`Mesh::zero_area_count`]: crate::mesh::Mesh::zero_area_count
//! [`MeshError`]: crate::mesh::MeshError
//! [`MeshError::Io`]: crate::mesh::MeshError::Io
//! [`MeshError::NoTriangles`]: crate::mesh::MeshError::NoTriangles
//! [`MeshError::ParserPanic`]: crate::mesh::MeshError::ParserPanic

mod guard;
mod obj;
mod path;
mod ply;

pub use path::{load_animation, load_mesh, load_path, parse_mesh, MeshFormat};
pub use ply::MAX_PLY_HEADER_BYTES;

/// Peak heap bytes a load may have allocated per byte of input file, on top of [`LOAD_BYTES_FIXED`] (see the module
/// documentation, "Memory"). The worst input the tests build (an OBJ file of one-triangle groups) needs about 76.
pub const LOAD_BYTES_PER_INPUT_BYTE: usize = 96;

/// Fixed part of the memory bound of a load (parser state, small buffers), in bytes.
pub const LOAD_BYTES_FIXED: usize = 1 << 20;
