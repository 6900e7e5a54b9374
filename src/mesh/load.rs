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

use super::{Animation, Mesh, MeshError};
use ply_rs_bw::parser::{ParseError, Parser, Reader};
use ply_rs_bw::ply::{ElementDef, Encoding, Header, PropertyAccess, PropertyAccessResult, PropertyType, ScalarType};
use rayon::prelude::*;
use std::io::Read;
use std::path::{Path, PathBuf};

/// The file formats this crate reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MeshFormat {
    /// Wavefront OBJ (text).
    Obj,
    /// Stanford PLY (ascii, binary little endian or binary big endian).
    Ply,
}

/// Peak heap bytes a load may have allocated per byte of input file, on top of [`LOAD_BYTES_FIXED`] (see the module
/// documentation, "Memory"). The worst input the tests build (an OBJ file of one-triangle groups) needs about 76.
pub const LOAD_BYTES_PER_INPUT_BYTE: usize = 96;

/// Fixed part of the memory bound of a load (parser state, small buffers), in bytes.
pub const LOAD_BYTES_FIXED: usize = 1 << 20;

/// Longest reason text kept from a parser message (ascii PLY messages quote the whole offending line, which can be
/// megabytes long for a triangle strip).
const MAX_REASON: usize = 300;

/// Longest name or token quoted from a file in a message.
const MAX_QUOTE: usize = 80;

/// Loads one mesh from an `.obj` or `.ply` file.
///
/// The format comes from the extension (case-insensitive); for any other extension the first bytes decide (see
/// [`detect_format`]). The mesh is named after the path. Every error names the file and, where there is one, the
/// place in it; anything but a regular file is refused before it is opened (see the module documentation).
///
/// A path that does not exist and reads as a generated scene's spec (`family:NAME:TRIANGLES[:SEED]`,
/// `degenerate:NAME:TRIANGLES[:SEED]`) is that scene, named by the spec (see [`generated_scene`]).
pub fn load_mesh(path: &Path) -> Result<Mesh, MeshError> {
    if let Some(generated) = generated_scene(path) {
        return generated;
    }
    let bytes = read_regular_file(path)?;
    let format = detect_format(path, &bytes).ok_or_else(|| MeshError::UnknownFormat { path: path.to_path_buf() })?;
    parse_mesh(&path.display().to_string(), &bytes, format)
}

/// What a file that is not a regular file is, for messages; `None` for a regular file.
fn not_regular(meta: &std::fs::Metadata) -> Option<&'static str> {
    let t = meta.file_type();
    if t.is_file() {
        return None;
    }
    if t.is_dir() {
        return Some("a directory");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return Some("a FIFO (named pipe)");
        }
        if t.is_socket() {
            return Some("a socket");
        }
        if t.is_char_device() {
            return Some("a character device");
        }
        if t.is_block_device() {
            return Some("a block device");
        }
    }
    Some("not a regular file")
}

/// Fails unless `path` (links followed) is a regular file; the error names the path and what it is instead.
fn check_regular_file(path: &Path) -> Result<std::fs::Metadata, MeshError> {
    let io = |source| MeshError::Io { path: path.to_path_buf(), source };
    let meta = std::fs::metadata(path).map_err(io)?;
    match not_regular(&meta) {
        None => Ok(meta),
        Some(what) => {
            Err(io(std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("not a regular file: {what}"))))
        }
    }
}

/// Reads a whole regular file: its metadata is checked before it is opened (a FIFO would block in `open`, a device
/// such as `/dev/zero` never ends) and again on the open handle; at most the length the metadata gives is read, into a
/// buffer reserved once (an allocation failure is an error, not an abort).
fn read_regular_file(path: &Path) -> Result<Vec<u8>, MeshError> {
    let io = |source| MeshError::Io { path: path.to_path_buf(), source };
    check_regular_file(path)?;
    let file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if let Some(what) = not_regular(&meta) {
        return Err(io(std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("not a regular file: {what}"))));
    }
    let len = meta.len();
    let too_big =
        || io(std::io::Error::new(std::io::ErrorKind::OutOfMemory, format!("{len} bytes do not fit in memory")));
    let cap = usize::try_from(len).map_err(|_| too_big())?;
    let mut bytes = Vec::new();
    bytes.try_reserve_exact(cap).map_err(|_| too_big())?;
    file.take(len).read_to_end(&mut bytes).map_err(io)?;
    Ok(bytes)
}

/// Parses a mesh held in memory. `name` names the mesh and is the file named in errors. Like [`load_mesh`], it
/// refuses input without triangles.
pub fn parse_mesh(name: &str, bytes: &[u8], format: MeshFormat) -> Result<Mesh, MeshError> {
    match format {
        MeshFormat::Obj => parse_obj(name, bytes),
        MeshFormat::Ply => parse_ply(name, bytes),
    }
}

/// Runs a parse that calls a third-party parser, turning a panic into [`MeshError::ParserPanic`] naming the file.
fn catch_parser_panic<T>(
    file: &str,
    parser: &'static str,
    f: impl FnOnce() -> Result<T, MeshError>,
) -> Result<T, MeshError> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(payload) => {
            let message = payload
                .downcast_ref::<&str>()
                .map(|s| short_reason(s))
                .or_else(|| payload.downcast_ref::<String>().map(|s| short_reason(s)))
                .unwrap_or_else(|| "no message".to_string());
            Err(MeshError::ParserPanic { file: file.to_string(), parser, message })
        }
    }
}

/// Decides the format of a file: by extension (`.obj`, `.ply`, case-insensitive), otherwise by content: a PLY file
/// starts with the line `ply`; OBJ text is recognised when its first statements (up to 16, blank lines skipped) all
/// start with an OBJ keyword or `#` and at least one of them is not a comment. `None` when neither applies.
pub fn detect_format(path: &Path, bytes: &[u8]) -> Option<MeshFormat> {
    if let Some(ext) = path.extension().and_then(|e| e.to_str()) {
        if ext.eq_ignore_ascii_case("obj") {
            return Some(MeshFormat::Obj);
        }
        if ext.eq_ignore_ascii_case("ply") {
            return Some(MeshFormat::Ply);
        }
    }
    sniff_format(bytes)
}

/// Content-based half of [`detect_format`].
pub fn sniff_format(bytes: &[u8]) -> Option<MeshFormat> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        return Some(MeshFormat::Ply);
    }
    const KEYWORDS: [&str; 13] = ["v", "vt", "vn", "vp", "f", "l", "p", "o", "g", "s", "mtllib", "usemtl", "#"];
    let head = bytes.get(..4096).unwrap_or(bytes);
    // A multi-byte character cut by the 4 KiB window is not a reason to reject the text.
    let text = match std::str::from_utf8(head) {
        Ok(t) => t,
        Err(e) if e.error_len().is_none() => std::str::from_utf8(head.get(..e.valid_up_to())?).ok()?,
        Err(_) => return None,
    };
    let mut statements = 0;
    for line in text.lines().filter(|l| !l.trim().is_empty()).take(16) {
        let first = line.split_whitespace().next()?;
        if first.starts_with('#') {
            continue;
        }
        if !KEYWORDS.contains(&first) {
            return None;
        }
        statements += 1;
    }
    (statements > 0).then_some(MeshFormat::Obj)
}

/// Loads an animation from a list of frame files, in the order given. Frames are read in parallel.
///
/// Every frame must have the topology of the first (same vertex count, same index triples); otherwise the error
/// ([`MeshError::TopologyMismatch`]) names both files. The animation is named after the first file. An empty list is
/// an error: an animation has at least one frame.
pub fn load_animation(paths: &[PathBuf]) -> Result<Animation, MeshError> {
    let Some(first) = paths.first() else {
        return Err(MeshError::Invalid {
            file: "(no frame files)".into(),
            reason: "an animation needs at least one frame file".into(),
        });
    };
    let frames = paths.par_iter().map(|p| load_mesh(p)).collect::<Result<Vec<_>, _>>()?;
    Animation::new(first.display().to_string(), frames)
}

/// Loads a file as a one-frame animation, or a directory of frame files as an animation.
///
/// In a directory, the frames are the entries whose extension is `.obj` or `.ply` (case-insensitive), sorted by file
/// name; other entries are ignored. A directory without such entries is an error naming it, and so is a frame entry
/// that is not a regular file (see [`frame_files`]). The animation is named after the path.
///
/// A path that does not exist and reads as a generated scene's spec is that scene ([`generated_scene`]).
pub fn load_path(path: &Path) -> Result<Animation, MeshError> {
    if let Some(generated) = generated_scene(path) {
        return Animation::new(path.to_string_lossy().to_string(), vec![generated?]);
    }
    if path.is_dir() {
        let frames = frame_files(path)?;
        if frames.is_empty() {
            return Err(MeshError::Invalid {
                file: path.display().to_string(),
                reason: "directory holds no .obj or .ply file".into(),
            });
        }
        let anim = load_animation(&frames)?;
        return Ok(Animation { name: path.display().to_string(), ..anim });
    }
    let m = load_mesh(path)?;
    Animation::new(path.display().to_string(), vec![m])
}

/// The generated scene a path names when it does not exist and reads `family:NAME:TRIANGLES[:SEED]` (a scene family,
/// [`super::families::parse_spec`]) or `degenerate:NAME:TRIANGLES[:SEED]` (a degenerate scene,
/// [`super::degenerate::parse_spec`]), named by the spec; `None` for any other path. Every tool that loads scenes
/// takes them, and a record naming one regenerates the same mesh bit for bit.
pub fn generated_scene(path: &Path) -> Option<Result<Mesh, MeshError>> {
    if path.exists() {
        return None;
    }
    let spec = path.to_string_lossy();
    let invalid = |reason| MeshError::Invalid { file: spec.to_string(), reason };
    let mesh = if let Some(parsed) = super::families::parse_spec(&spec) {
        parsed.map_err(invalid).and_then(|(family, n, seed)| super::families::generate(family, n, seed))
    } else {
        let parsed = super::degenerate::parse_spec(&spec)?;
        parsed.map_err(invalid).and_then(|(kind, n, seed)| super::degenerate::generate(kind, n, seed))
    };
    // Errors name the spec as given.
    Some(
        mesh.map(|mut m| {
            m.name = spec.to_string();
            m
        })
        .map_err(|e| match e {
            MeshError::Invalid { reason, .. } => MeshError::Invalid { file: spec.to_string(), reason },
            other => other,
        }),
    )
}

/// The `.obj` and `.ply` files of a directory, sorted by file name.
///
/// An entry with one of these extensions that is not a regular file once links are followed (a FIFO, a device, a
/// directory, a dangling link) is an error naming it ([`MeshError::Io`]), rather than a frame silently left out.
pub fn frame_files(dir: &Path) -> Result<Vec<PathBuf>, MeshError> {
    let io = |source| MeshError::Io { path: dir.to_path_buf(), source };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let p = entry.path();
        let is_mesh = p
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("obj") || e.eq_ignore_ascii_case("ply"));
        if is_mesh {
            check_regular_file(&p)?;
            files.push(p);
        }
    }
    files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    Ok(files)
}

fn too_many_vertices(name: &str, n: usize) -> MeshError {
    MeshError::Invalid { file: name.to_string(), reason: format!("{n} vertices: more than 32-bit indices address") }
}

/// Keeps a parser message to one short line: whitespace runs become one space, and the text is cut after
/// [`MAX_REASON`] characters with `...` (without first copying a long message whole).
fn short_reason(s: &str) -> String {
    cut_words(s, MAX_REASON)
}

/// Text quoted from a file (a name, a token), cut after [`MAX_QUOTE`] characters with `...`.
fn quote(s: &str) -> String {
    cut_words(s, MAX_QUOTE)
}

fn cut_words(s: &str, max: usize) -> String {
    let mut out = String::new();
    let mut chars = 0usize;
    for word in s.split_whitespace() {
        if !out.is_empty() {
            out.push(' ');
            chars += 1;
        }
        for c in word.chars() {
            if chars >= max {
                out.push_str("...");
                return out;
            }
            out.push(c);
            chars += 1;
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------------------------
// OBJ
// ---------------------------------------------------------------------------------------------------------------

/// Parses OBJ text (see the module documentation for what is kept and what is refused).
pub fn parse_obj(name: &str, bytes: &[u8]) -> Result<Mesh, MeshError> {
    catch_parser_panic(name, "OBJ", || parse_obj_checked(name, bytes))
}

fn parse_obj_checked(name: &str, bytes: &[u8]) -> Result<Mesh, MeshError> {
    // Check every index before tobj sees it (tobj multiplies indices without overflow checks and can index out of
    // bounds), and hide from it the statements that give no triangle: polylines (`l`, which tobj would read as faces)
    // and faces of 1 or 2 corners (tobj keeps 104 bytes for each, and a group holding one becomes a model of about
    // 250 bytes, so that a file of `g` and `f 1` lines would cost some 80 bytes per byte). Hidden lines become
    // comments, so that line numbers are kept.
    let scan = scan_obj(name, bytes, None)?;
    let filtered;
    let text: &[u8] = if scan.hidden > 0 {
        let mut out = Vec::new();
        out.try_reserve_exact(bytes.len() + scan.hidden).map_err(|_| MeshError::Invalid {
            file: name.to_string(),
            reason: format!("no memory for a filtered copy of its {} bytes", bytes.len()),
        })?;
        scan_obj(name, bytes, Some(&mut out))?;
        filtered = out;
        &filtered
    } else {
        bytes
    };
    // The struct update covers the fields that optional tobj features add.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let mut reader = text;
    let (models, _materials) = tobj::load_obj_buf(&mut reader, &options, |_| Err(tobj::LoadError::OpenFileFailed))
        .map_err(|e| obj_error(name, text, e))?;

    let nv: usize = models.iter().map(|m| m.mesh.positions.len() / 3).sum();
    let nt: usize = models.iter().map(|m| m.mesh.indices.len() / 3).sum();
    if u32::try_from(nv).is_err() {
        return Err(too_many_vertices(name, nv));
    }
    if nt == 0 {
        return Err(MeshError::NoTriangles {
            file: name.to_string(),
            detail: format!(
                "no face of 3 or more corners ({} vertex statements, {} faces of fewer corners, {} polylines)",
                scan.vertices, scan.short_faces, scan.polylines
            ),
        });
    }
    // Both sizes come from what tobj read, not from a count written in the file.
    let mut positions: Vec<[f32; 3]> = Vec::with_capacity(nv);
    let mut indices: Vec<[u32; 3]> = Vec::with_capacity(nt);
    let mut object_ids: Vec<u32> = Vec::new();
    if models.len() > 1 {
        object_ids.reserve(nt);
    }
    for (k, model) in models.iter().enumerate() {
        // nv fits u32, so every base does.
        let base = positions.len() as u32;
        positions.extend(model.mesh.positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        let before = indices.len();
        for t in model.mesh.indices.chunks_exact(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| base.saturating_add(i));
            indices.push([a, b, c]);
        }
        if models.len() > 1 {
            object_ids.extend(std::iter::repeat_n(k as u32, indices.len() - before));
        }
    }
    if positions.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(obj_non_finite(name, text));
    }
    let mesh =
        Mesh { name: name.to_string(), positions, indices, object_ids: (models.len() > 1).then_some(object_ids) };
    mesh.validate()?;
    Ok(mesh)
}

/// What [`scan_obj`] found in a file that passed it.
struct ObjScan {
    /// `v` statements.
    vertices: usize,
    /// Faces of 1 or 2 corners (points and segments).
    short_faces: usize,
    /// Polyline statements.
    polylines: usize,
    /// Lines to hide from tobj.
    hidden: usize,
}

/// One index of a face corner as written: `None` when the slot is empty or absent.
type CornerIndices = [Option<i64>; 3];

/// Parses a face corner `v`, `v/vt`, `v//vn` or `v/vt/vn` as tobj does (slots separated by `/`, each empty or an
/// integer that fits `isize`, no non-empty slot after the third); `None` when tobj would reject it.
fn parse_corner(corner: &str) -> Option<CornerIndices> {
    let mut out = [None; 3];
    for (k, part) in corner.split('/').enumerate() {
        // Like tobj, empty slots are skipped before the slot count is checked: `1/2/3/` passes, `1/2/3/4` does not.
        if !part.is_empty() {
            *out.get_mut(k)? = Some(i64::try_from(part.parse::<isize>().ok()?).ok()?);
        }
    }
    Some(out)
}

/// The OBJ pre-scan: checks every line, in order, for what would make tobj fail or panic on indices, and counts.
///
/// * A line must be UTF-8 (tobj reads lines as strings).
/// * Every face corner must parse (see [`parse_corner`]); a face needs at least one corner.
/// * In faces of 3 or more corners (the others give no triangle and tobj ignores them), the vertex index is required
///   and, like the texture and normal indices when the file has statements of their kind, it must not be 0, a
///   positive index must not exceed the number of statements of its kind in the file, and a negative (relative) one
///   must not reach before the first statement read so far.
///
/// With `out`, the text is also copied into it with the lines tobj must not see (polylines, points and segments)
/// turned into comments.
fn scan_obj(name: &str, bytes: &[u8], mut out: Option<&mut Vec<u8>>) -> Result<ObjScan, MeshError> {
    // Totals per kind (`v`, `vt`, `vn`), for the forward bound of positive indices.
    let mut totals = [0usize; 3];
    for raw in bytes.split(|&c| c == b'\n') {
        // Tokens as tobj splits them; a line that is not UTF-8 is reported by the second loop.
        match std::str::from_utf8(raw).ok().and_then(|t| t.split_whitespace().next()) {
            Some("v") => totals[0] += 1,
            Some("vt") => totals[1] += 1,
            Some("vn") => totals[2] += 1,
            _ => {}
        }
    }
    let mut counts = [0usize; 3];
    let mut scan = ObjScan { vertices: 0, short_faces: 0, polylines: 0, hidden: 0 };
    let mut triangles = 0usize;
    for (i, raw) in bytes.split(|&c| c == b'\n').enumerate() {
        let number = i + 1;
        let line = raw.strip_suffix(b"\r").unwrap_or(raw);
        let Ok(text) = std::str::from_utf8(line) else {
            return Err(obj_parse_error(name, Some(number), "not UTF-8 text"));
        };
        let mut words = text.split_whitespace();
        let mut hide = false;
        match words.next() {
            Some("v") => counts[0] += 1,
            Some("vt") => counts[1] += 1,
            Some("vn") => counts[2] += 1,
            Some("l") => {
                scan.polylines += 1;
                hide = true;
            }
            Some("f") => {
                let mut corners = 0usize;
                for corner in words.clone() {
                    if parse_corner(corner).is_none() {
                        return Err(obj_parse_error(
                            name,
                            Some(number),
                            format!("cannot read the face's vertex indices: corner '{}'", quote(corner)),
                        ));
                    }
                    corners += 1;
                }
                if corners == 0 {
                    return Err(obj_parse_error(name, Some(number), "face without vertices"));
                }
                if corners < 3 {
                    scan.short_faces += 1;
                    hide = true;
                } else {
                    for (j, corner) in words.enumerate() {
                        let indices = parse_corner(corner).unwrap_or_default();
                        check_corner(name, number, j, corner, indices, &counts, &totals, triangles)?;
                    }
                    triangles += corners - 2;
                }
            }
            _ => {}
        }
        if let Some(out) = out.as_deref_mut() {
            if i > 0 {
                out.push(b'\n');
            }
            if hide {
                out.push(b'#');
            }
            out.extend_from_slice(raw);
        }
        scan.hidden += usize::from(hide);
    }
    scan.vertices = totals[0];
    Ok(scan)
}

/// Checks the indices of corner `j` of a face of 3 or more corners on line `number` (see [`scan_obj`]).
#[allow(clippy::too_many_arguments)]
fn check_corner(
    name: &str,
    number: usize,
    j: usize,
    corner: &str,
    indices: CornerIndices,
    counts: &[usize; 3],
    totals: &[usize; 3],
    triangles: usize,
) -> Result<(), MeshError> {
    const WHAT: [&str; 3] = ["vertex", "texture coordinate", "normal"];
    for (slot, written) in indices.into_iter().enumerate() {
        let Some(written) = written else {
            if slot == 0 {
                let reason = format!("face corner {} ('{}') has no vertex index", j + 1, quote(corner));
                return Err(obj_parse_error(name, Some(number), reason));
            }
            continue;
        };
        // tobj ignores texture and normal indices when the file has no statement of their kind.
        if slot > 0 && totals[slot] == 0 {
            continue;
        }
        let (what, count, total) = (WHAT[slot], counts[slot], totals[slot]);
        let reason = if written == 0 {
            format!("{what} index 0 (OBJ indices start at 1)")
        } else if written < 0 {
            if written.unsigned_abs() <= count as u64 {
                continue;
            }
            format!("relative {what} index {written} reaches before the first {what} ({count} so far)")
        } else {
            if written as u64 <= total as u64 {
                continue;
            }
            if slot == 0 {
                return Err(MeshError::IndexOutOfRange {
                    file: format!("{name}:{number}"),
                    triangle: triangles + j.saturating_sub(2),
                    index: written as u64,
                    vertices: total,
                });
            }
            format!("{what} index {written} is out of range ({total} defined)")
        };
        return Err(obj_parse_error(name, Some(number), reason));
    }
    Ok(())
}

/// One statement of an OBJ file as the error scan sees it.
struct ObjLine<'a> {
    /// 1-based line number.
    number: usize,
    /// The text, `None` when the line is not UTF-8.
    text: Option<&'a str>,
}

fn obj_lines(bytes: &[u8]) -> impl Iterator<Item = ObjLine<'_>> {
    bytes.split(|&c| c == b'\n').enumerate().map(|(i, raw)| {
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        ObjLine { number: i + 1, text: std::str::from_utf8(raw).ok() }
    })
}

fn parse_floats(words: std::str::SplitWhitespace<'_>) -> Vec<Option<f32>> {
    words.map(|w| w.parse::<f32>().ok()).collect()
}

/// The position a `v` statement gives (after the optional `w` division), if it parses.
fn obj_vertex(words: std::str::SplitWhitespace<'_>) -> Option<[f32; 3]> {
    let vals = parse_floats(words);
    let (x, y, z) = (vals.first().copied()??, vals.get(1).copied()??, vals.get(2).copied()??);
    match vals.len() {
        4 => {
            let w = vals.get(3).copied()??;
            Some([x / w, y / w, z / w])
        }
        _ => Some([x, y, z]),
    }
}

/// Resolves an OBJ index as written (1-based, or negative relative to the `count` items so far) to a 0-based index;
/// `None` for 0 or a relative index before the first item.
fn resolve_obj_index(written: i64, count: usize) -> Option<usize> {
    match written {
        0 => None,
        w if w > 0 => usize::try_from(w - 1).ok(),
        w => usize::try_from(count as i64 + w).ok(),
    }
}

fn obj_parse_error(name: &str, line: Option<usize>, reason: impl Into<String>) -> MeshError {
    MeshError::Parse {
        file: name.to_string(),
        place: line.map_or_else(|| "an unknown line".to_string(), |l| format!("line {l}")),
        reason: reason.into(),
    }
}

/// Which index of a face corner (`v/vt/vn`) a scan checks.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Slot {
    Position = 0,
    Texcoord = 1,
    Normal = 2,
}

/// Turns a `tobj` error into one that names the line, by scanning the text for the statement that caused it.
fn obj_error(name: &str, text: &[u8], err: tobj::LoadError) -> MeshError {
    use tobj::LoadError as E;
    let reason = err.to_string();
    let first_line = |pred: &dyn Fn(&str, &mut std::str::SplitWhitespace<'_>) -> bool| -> Option<usize> {
        obj_lines(text).find_map(|l| {
            let t = l.text?;
            let mut words = t.split_whitespace();
            let kw = words.next()?;
            pred(kw, &mut words).then_some(l.number)
        })
    };
    match err {
        E::ReadError => {
            let line = obj_lines(text).find(|l| l.text.is_none()).map(|l| l.number);
            obj_parse_error(name, line, "not UTF-8 text")
        }
        E::PositionParseError => {
            let line = first_line(&|kw, w| {
                kw == "v" && {
                    let vals = parse_floats(w.clone());
                    vals.len() < 3 || vals.iter().take(3).any(|v| v.is_none()) || (vals.len() == 4 && vals[3].is_none())
                }
            });
            obj_parse_error(name, line, "cannot read the vertex position")
        }
        E::ScalingByZeroError => {
            let line = first_line(&|kw, w| {
                kw == "v" && {
                    let vals = parse_floats(w.clone());
                    vals.len() == 4 && vals[3] == Some(0.0)
                }
            });
            obj_parse_error(name, line, "vertex weight w is 0")
        }
        E::ColorParseError => {
            let line = first_line(&|kw, w| kw == "v" && matches!(w.clone().count(), 5 | 7..));
            obj_parse_error(name, line, "a vertex has 5 or more than 6 numbers")
        }
        E::TexcoordParseError | E::NormalParseError => {
            let (key, n) = if err == E::TexcoordParseError { ("vt", 2) } else { ("vn", 3) };
            let line = first_line(&|kw, w| {
                kw == key && {
                    let vals = parse_floats(w.clone());
                    vals.len() < n || vals.iter().take(n).any(|v| v.is_none())
                }
            });
            obj_parse_error(name, line, reason)
        }
        E::FaceParseError => {
            let line = first_line(&|kw, w| {
                kw == "f"
                    && w.clone().any(|corner| {
                        let parts: Vec<&str> = corner.split('/').collect();
                        parts.len() > 3 || parts.iter().any(|p| !p.is_empty() && p.parse::<isize>().is_err())
                    })
            });
            obj_parse_error(name, line, "cannot read the face's vertex indices")
        }
        E::InvalidPolygon => {
            let line = first_line(&|kw, w| kw == "f" && w.clone().next().is_none());
            obj_parse_error(name, line, "face without vertices")
        }
        E::MaterialParseError => {
            let line = first_line(&|kw, w| kw == "usemtl" && w.clone().next().is_none());
            obj_parse_error(name, line, "usemtl without a material name")
        }
        E::FaceVertexOutOfBounds => obj_index_error(name, text, Slot::Position),
        E::FaceTexCoordOutOfBounds => obj_index_error(name, text, Slot::Texcoord),
        E::FaceNormalOutOfBounds => obj_index_error(name, text, Slot::Normal),
        E::FaceColorOutOfBounds => {
            // Colours are given for some vertices and not for others: name the first vertex whose colour presence
            // differs from the first vertex's.
            let coloured = |w: &mut std::str::SplitWhitespace<'_>| w.clone().count() == 6;
            let first = obj_lines(text).find_map(|l| {
                let mut w = l.text?.split_whitespace();
                (w.next()? == "v").then(|| coloured(&mut w))
            });
            let line = first_line(&|kw, w| kw == "v" && Some(coloured(w)) != first);
            obj_parse_error(name, line, "vertex colours are given for some vertices only")
        }
        _ => obj_parse_error(name, None, reason),
    }
}

/// Finds the first face corner whose `slot` index is out of range and reports it with its line; for positions the
/// error is [`MeshError::IndexOutOfRange`] with the triangle index and the index as written.
fn obj_index_error(name: &str, text: &[u8], slot: Slot) -> MeshError {
    let keyword = match slot {
        Slot::Position => "v",
        Slot::Texcoord => "vt",
        Slot::Normal => "vn",
    };
    let total = obj_lines(text).filter(|l| l.text.and_then(|t| t.split_whitespace().next()) == Some(keyword)).count();
    // Two passes: indices beyond the whole file first; otherwise (tobj checks a group's faces against the vertices
    // read when the group ends) the first reference to a vertex that is not yet defined.
    for forward_only in [false, true] {
        let mut count = 0usize;
        let mut triangles = 0usize;
        for l in obj_lines(text) {
            let Some(t) = l.text else { continue };
            let mut words = t.split_whitespace();
            match words.next() {
                Some(k) if k == keyword => count += 1,
                Some("f") => {
                    let corners: Vec<&str> = words.collect();
                    for (j, corner) in corners.iter().enumerate() {
                        let Some(part) = corner.split('/').nth(slot as usize).filter(|p| !p.is_empty()) else {
                            continue;
                        };
                        let Ok(written) = part.parse::<i64>() else { continue };
                        let limit = if forward_only { count } else { total };
                        let bad = resolve_obj_index(written, count).is_none_or(|i| i >= limit);
                        if !bad {
                            continue;
                        }
                        if corners.len() < 3 {
                            // Points and segments are ignored, their indices too.
                            break;
                        }
                        if slot == Slot::Position && written > 0 {
                            return MeshError::IndexOutOfRange {
                                file: format!("{name}:{}", l.number),
                                triangle: triangles + j.saturating_sub(2),
                                index: written as u64,
                                vertices: limit,
                            };
                        }
                        let what = match slot {
                            Slot::Position => "vertex",
                            Slot::Texcoord => "texture coordinate",
                            Slot::Normal => "normal",
                        };
                        let reason = if written == 0 {
                            format!("{what} index 0 (OBJ indices start at 1)")
                        } else if written < 0 {
                            format!("relative {what} index {written} reaches before the first {what} ({count} so far)")
                        } else {
                            format!("{what} index {written} is out of range ({limit} defined)")
                        };
                        return obj_parse_error(name, Some(l.number), reason);
                    }
                    if corners.len() >= 3 {
                        triangles += corners.len() - 2;
                    }
                }
                _ => {}
            }
        }
    }
    obj_parse_error(name, None, "face index out of range")
}

/// Names the first `v` statement with a non-finite position.
fn obj_non_finite(name: &str, text: &[u8]) -> MeshError {
    let mut vertex = 0usize;
    for l in obj_lines(text) {
        let Some(t) = l.text else { continue };
        let mut words = t.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        if let Some(p) = obj_vertex(words) {
            if !p.iter().all(|c| c.is_finite()) {
                return MeshError::NonFinite { file: format!("{name}:{}", l.number), vertex, value: p };
            }
        }
        vertex += 1;
    }
    MeshError::Invalid { file: name.to_string(), reason: "a vertex position is not finite".into() }
}

// ---------------------------------------------------------------------------------------------------------------
// PLY
// ---------------------------------------------------------------------------------------------------------------

/// A PLY vertex: the position, whatever the scalar type of `x`, `y`, `z`.
#[derive(Default)]
struct PlyVertex([f32; 3]);

impl PlyVertex {
    fn set(&mut self, name: &str, v: f64) -> PropertyAccessResult {
        let slot = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return PropertyAccessResult::Ignored,
        };
        // A double beyond the f32 range becomes infinite here and is reported as a non-finite coordinate.
        self.0[slot] = v as f32;
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }
    fn set_char(&mut self, n: &str, v: i8) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_uchar(&mut self, n: &str, v: u8) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_short(&mut self, n: &str, v: i16) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_ushort(&mut self, n: &str, v: u16) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_int(&mut self, n: &str, v: i32) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_uint(&mut self, n: &str, v: u32) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_float(&mut self, n: &str, v: f32) -> PropertyAccessResult {
        self.set(n, v.into())
    }
    fn set_double(&mut self, n: &str, v: f64) -> PropertyAccessResult {
        self.set(n, v)
    }
}

/// An index list as stored in the file, without conversion.
enum IndexList {
    I8(Vec<i8>),
    U8(Vec<u8>),
    I16(Vec<i16>),
    U16(Vec<u16>),
    I32(Vec<i32>),
    U32(Vec<u32>),
}

impl IndexList {
    fn len(&self) -> usize {
        match self {
            IndexList::I8(v) => v.len(),
            IndexList::U8(v) => v.len(),
            IndexList::I16(v) => v.len(),
            IndexList::U16(v) => v.len(),
            IndexList::I32(v) => v.len(),
            IndexList::U32(v) => v.len(),
        }
    }
    fn get(&self, i: usize) -> Option<i64> {
        match self {
            IndexList::I8(v) => v.get(i).map(|&x| x.into()),
            IndexList::U8(v) => v.get(i).map(|&x| x.into()),
            IndexList::I16(v) => v.get(i).map(|&x| x.into()),
            IndexList::U16(v) => v.get(i).map(|&x| x.into()),
            IndexList::I32(v) => v.get(i).map(|&x| x.into()),
            IndexList::U32(v) => v.get(i).map(|&x| x.into()),
        }
    }
}

/// A PLY face or triangle strip: its index list (the first of `vertex_indices` / `vertex_index`).
#[derive(Default)]
struct PlyIndices(Option<IndexList>);

fn is_index_property(name: &str) -> bool {
    name == "vertex_indices" || name == "vertex_index"
}

impl PlyIndices {
    fn set(&mut self, name: &str, list: impl FnOnce() -> IndexList) -> PropertyAccessResult {
        if !is_index_property(name) {
            return PropertyAccessResult::Ignored;
        }
        if self.0.is_none() {
            self.0 = Some(list());
        }
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for PlyIndices {
    fn new() -> Self {
        Self::default()
    }
    fn set_list_char(&mut self, n: &str, v: Vec<i8>) -> PropertyAccessResult {
        self.set(n, || IndexList::I8(v))
    }
    fn set_list_uchar(&mut self, n: &str, v: Vec<u8>) -> PropertyAccessResult {
        self.set(n, || IndexList::U8(v))
    }
    fn set_list_short(&mut self, n: &str, v: Vec<i16>) -> PropertyAccessResult {
        self.set(n, || IndexList::I16(v))
    }
    fn set_list_ushort(&mut self, n: &str, v: Vec<u16>) -> PropertyAccessResult {
        self.set(n, || IndexList::U16(v))
    }
    fn set_list_int(&mut self, n: &str, v: Vec<i32>) -> PropertyAccessResult {
        self.set(n, || IndexList::I32(v))
    }
    fn set_list_uint(&mut self, n: &str, v: Vec<u32>) -> PropertyAccessResult {
        self.set(n, || IndexList::U32(v))
    }
    fn set_list_float(&mut self, n: &str, _: Vec<f32>) -> PropertyAccessResult {
        if is_index_property(n) {
            PropertyAccessResult::UnsupportedType
        } else {
            PropertyAccessResult::Ignored
        }
    }
    fn set_list_double(&mut self, n: &str, _: Vec<f64>) -> PropertyAccessResult {
        self.set_list_float(n, Vec::new())
    }
}

/// An element this loader does not use: read and dropped.
struct PlySkip;

impl PropertyAccess for PlySkip {
    fn new() -> Self {
        PlySkip
    }
}

/// Where in a PLY payload an element lies, for error messages.
struct PlyPlace<'a> {
    name: &'a str,
    ascii: bool,
    /// Ascii: the file line of the element's first item.
    start_line: usize,
}

impl PlyPlace<'_> {
    /// The file as named in errors about item `i`: `name:line` for ascii files.
    fn file(&self, file: &str, i: usize) -> String {
        if self.ascii {
            format!("{file}:{}", self.start_line + i)
        } else {
            file.to_string()
        }
    }
    fn describe(&self, i: usize) -> String {
        if self.ascii {
            format!("element '{}' {i} (line {})", quote(self.name), self.start_line + i)
        } else {
            format!("element '{}' {i}", quote(self.name))
        }
    }
}

/// The most bytes a PLY header may take, `end_header` line included: 1 MiB. Headers are a few hundred bytes (a few
/// kilobytes with comments); the header parser copies a line whole, more than once, so a file of gigabytes whose
/// header never ends would otherwise be copied into memory several times over before any error.
pub const MAX_PLY_HEADER_BYTES: usize = 1 << 20;

/// Refuses a PLY file whose `end_header` line does not end within its first [`MAX_PLY_HEADER_BYTES`]; a shorter file
/// without one is left to the header parser, which names what is missing.
fn check_ply_header_length(file: &str, bytes: &[u8]) -> Result<(), MeshError> {
    if bytes.len() <= MAX_PLY_HEADER_BYTES {
        return Ok(());
    }
    let head = bytes.get(..MAX_PLY_HEADER_BYTES).unwrap_or_default();
    let mut lines = head.split(|&c| c == b'\n');
    // The last piece has no line end within the limit: it is not a whole line.
    lines.next_back();
    if lines.any(|l| l.strip_suffix(b"\r").unwrap_or(l).trim_ascii() == b"end_header") {
        return Ok(());
    }
    Err(ply_header_error(file, format!("no end_header line within the first {MAX_PLY_HEADER_BYTES} bytes")))
}

/// The message of a `ply-rs-bw` error without its `Line N:` prefix (the place is given separately).
fn ply_message(e: &ParseError) -> String {
    let s = e.to_string();
    let s = match e.line() {
        Some(l) => s.strip_prefix(&format!("Line {l}: ")).map(str::to_string).unwrap_or(s),
        None => s,
    };
    short_reason(&s)
}

fn ply_header_error(file: &str, reason: impl Into<String>) -> MeshError {
    MeshError::Parse { file: file.to_string(), place: "header".into(), reason: reason.into() }
}

/// Checks the header for what the loader needs: `x`, `y`, `z` in `vertex`, an integer index list in `face` and
/// `tristrips`.
fn check_ply_header(file: &str, header: &Header) -> Result<(), MeshError> {
    for (_, el) in &header.elements {
        match el.name.as_str() {
            "vertex" if el.count > 0 => {
                for axis in ["x", "y", "z"] {
                    match el.properties.get(axis).map(|p| &p.data_type) {
                        Some(PropertyType::Scalar(_)) => {}
                        Some(PropertyType::List(..)) => {
                            return Err(ply_header_error(file, format!("vertex property '{axis}' is a list")));
                        }
                        None => {
                            return Err(ply_header_error(file, format!("vertex element has no property '{axis}'")));
                        }
                    }
                }
            }
            "face" | "tristrips" => {
                let list = el.properties.values().find(|p| is_index_property(&p.name));
                match list.map(|p| &p.data_type) {
                    Some(PropertyType::List(_, t)) if !matches!(t, ScalarType::Float | ScalarType::Double) => {}
                    Some(_) => {
                        return Err(ply_header_error(
                            file,
                            format!(
                                "{} property '{}' is not a list of integers",
                                el.name,
                                list.map_or("", |p| &p.name)
                            ),
                        ));
                    }
                    None if el.count == 0 => {}
                    None => {
                        return Err(ply_header_error(
                            file,
                            format!("{} element has no list property 'vertex_indices' or 'vertex_index'", el.name),
                        ));
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// Byte size of a binary PLY scalar.
fn scalar_size(t: &ScalarType) -> usize {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// The header line numbers of the elements, in header order, after the checks `ply-rs-bw` does not make: no element
/// declared twice, no property declared twice in an element (the parser keeps the last one and would then read the
/// payload out of step), format version 1, integer list counts, no element with items but no properties (a binary
/// reader would loop over them without reading a byte).
fn scan_ply_header(file: &str, header_text: &[u8], header: &Header) -> Result<Vec<usize>, MeshError> {
    let at = |line: usize, reason: String| MeshError::Parse {
        file: file.to_string(),
        place: format!("header line {line}"),
        reason,
    };
    let text = String::from_utf8_lossy(header_text);
    let mut element_lines: Vec<usize> = Vec::new();
    let mut elements: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    let mut properties: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    let mut current: Option<&str> = None;
    let mut format_line = 1;
    for (i, line) in text.split('\n').enumerate() {
        let number = i + 1;
        let words: Vec<&str> = line.split_whitespace().take(6).collect();
        match words.first().copied() {
            Some("format") => format_line = number,
            Some("element") => {
                let name = words.get(1).copied().unwrap_or_default();
                if let Some(first) = elements.insert(name, number) {
                    return Err(at(
                        number,
                        format!("element '{}' is declared twice (first at header line {first})", quote(name)),
                    ));
                }
                element_lines.push(number);
                current = Some(name);
                properties.clear();
            }
            Some("property") => {
                let name = line.split_whitespace().next_back().unwrap_or_default();
                if let Some(first) = properties.insert(name, number) {
                    return Err(at(
                        number,
                        format!(
                            "element '{}' declares property '{}' twice (first at header line {first})",
                            quote(current.unwrap_or_default()),
                            quote(name)
                        ),
                    ));
                }
            }
            _ => {}
        }
    }
    if header.version.major != 1 {
        return Err(at(
            format_line,
            format!(
                "format version {}.{} is not 1.x, the only PLY version",
                header.version.major, header.version.minor
            ),
        ));
    }
    if element_lines.len() != header.elements.len() {
        // Cannot happen after the checks above; refuse rather than report places out of step.
        return Err(ply_header_error(file, "the element declarations could not be matched to the header lines"));
    }
    for (el, &line) in header.elements.values().zip(&element_lines) {
        if el.count > 0 && el.properties.is_empty() {
            return Err(at(line, format!("element '{}' has {} items but no properties", quote(&el.name), el.count)));
        }
        for p in el.properties.values() {
            if let PropertyType::List(ScalarType::Float | ScalarType::Double, _) = p.data_type {
                return Err(at(
                    line,
                    format!(
                        "element '{}': list property '{}' has a floating-point count type (counts are integers)",
                        quote(&el.name),
                        quote(&p.name)
                    ),
                ));
            }
        }
    }
    Ok(element_lines)
}

/// The fewest bytes an item of `el` takes in the payload: binary, the sum of its scalar sizes and list count sizes
/// (lists may be empty); ascii, one character and one separator or line end per property.
fn min_item_bytes(el: &ElementDef, ascii: bool) -> u64 {
    if ascii {
        return 2 * el.properties.len() as u64;
    }
    el.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) | PropertyType::List(t, _) => scalar_size(t) as u64,
        })
        .sum()
}

/// Refuses a payload shorter than the header requires: element by element, the declared count times the minimum item
/// size must fit in what is left of the file. The error names the first item that cannot fit (binary) or the
/// element and its header line (ascii, where items are lines of varying length).
fn check_ply_sizes(
    file: &str,
    header: &Header,
    element_lines: &[usize],
    payload_bytes: usize,
    ascii: bool,
) -> Result<(), MeshError> {
    // Ascii: the last line may lack its line end.
    let mut left = payload_bytes as u128 + u128::from(ascii);
    for (el, &line) in header.elements.values().zip(element_lines) {
        let min = u128::from(min_item_bytes(el, ascii));
        let need = el.count as u128 * min;
        if need <= left {
            left -= need;
            continue;
        }
        let name = quote(&el.name);
        let (place, reason) = if ascii {
            (
                format!("element '{name}' (header line {line})"),
                format!(
                    "the header declares {} items, lines of at least {min} bytes each, but only {} bytes of the file \
                     are left for them",
                    el.count,
                    left.saturating_sub(1)
                ),
            )
        } else {
            (
                format!("element '{name}' {}", left / min.max(1)),
                format!(
                    "the file ends within this item: the header declares {} items of at least {min} bytes each, and \
                     only {left} bytes of the file are left for them",
                    el.count
                ),
            )
        };
        return Err(MeshError::Parse { file: file.to_string(), place, reason });
    }
    Ok(())
}

/// Parses a PLY file held in memory (see the module documentation for what is kept and what is refused).
pub fn parse_ply(name: &str, bytes: &[u8]) -> Result<Mesh, MeshError> {
    catch_parser_panic(name, "PLY", || parse_ply_checked(name, bytes))
}

/// The payload of a PLY file, read one item at a time.
struct PlyPayload<'a> {
    file: &'a str,
    bytes: &'a [u8],
    /// Where the next item starts.
    offset: usize,
    encoding: Encoding,
    /// Ascii: the line number of the next item.
    line: usize,
}

impl<'a> PlyPayload<'a> {
    fn error(&self, place: &PlyPlace<'_>, i: usize, reason: impl Into<String>) -> MeshError {
        MeshError::Parse { file: self.file.to_string(), place: place.describe(i), reason: reason.into() }
    }

    /// The next ascii line, with its line end.
    fn next_line(&mut self, place: &PlyPlace<'_>, i: usize) -> Result<&'a str, MeshError> {
        let rest = self.bytes.get(self.offset..).unwrap_or_default();
        if rest.is_empty() {
            return Err(self.error(place, i, "the file ends before this item"));
        }
        let len = rest.iter().position(|&c| c == b'\n').map_or(rest.len(), |p| p + 1);
        let raw = rest.get(..len).unwrap_or_default();
        self.offset += len;
        self.line += 1;
        std::str::from_utf8(raw).map_err(|_| self.error(place, i, "not UTF-8 text"))
    }

    /// The bytes of the next binary item of `el`; its list counts are read and checked against the bytes left.
    fn next_binary(&mut self, el: &ElementDef, place: &PlyPlace<'_>, i: usize) -> Result<&'a [u8], MeshError> {
        let rest = self.bytes.get(self.offset..).unwrap_or_default();
        let big = self.encoding == Encoding::BinaryBigEndian;
        let mut at = 0usize;
        for p in el.properties.values() {
            match &p.data_type {
                PropertyType::Scalar(t) => at += scalar_size(t),
                PropertyType::List(count_type, item_type) => {
                    let cs = scalar_size(count_type);
                    let Some(raw) = rest.get(at..at + cs) else {
                        return Err(self.error(
                            place,
                            i,
                            format!("the file ends before the count of list '{}'", quote(&p.name)),
                        ));
                    };
                    let count = binary_count(raw, count_type, big).ok_or_else(|| {
                        self.error(place, i, format!("list '{}' has a negative count", quote(&p.name)))
                    })?;
                    at += cs;
                    let left = rest.len().saturating_sub(at);
                    let size = scalar_size(item_type);
                    if count as u128 * size as u128 > left as u128 {
                        return Err(self.error(
                            place,
                            i,
                            format!(
                                "list '{}' declares {count} entries of {size} bytes, but only {left} bytes are left in \
                                 the file",
                                quote(&p.name)
                            ),
                        ));
                    }
                    at += count as usize * size;
                }
            }
        }
        let Some(item) = rest.get(..at) else {
            return Err(self.error(
                place,
                i,
                format!("the file ends within this item ({at} bytes, {} left)", rest.len()),
            ));
        };
        self.offset += at;
        Ok(item)
    }

    /// Reads item `i` of `el` into an `E`.
    fn read<E: PropertyAccess>(&mut self, el: &ElementDef, place: &PlyPlace<'_>, i: usize) -> Result<E, MeshError> {
        let parser = Parser::<E>::new();
        let r = match self.encoding {
            Encoding::Ascii => {
                let line = self.next_line(place, i)?;
                parser.read_ascii_element(line, el)
            }
            Encoding::BinaryLittleEndian => parser.read_little_endian_element(&mut self.next_binary(el, place, i)?, el),
            Encoding::BinaryBigEndian => parser.read_big_endian_element(&mut self.next_binary(el, place, i)?, el),
        };
        r.map_err(|e| self.error(place, i, ply_message(&e)))
    }

    /// Goes past item `i` of an element the loader does not use (ascii lines are still parsed, so that a malformed
    /// line is an error wherever it is).
    fn skip(&mut self, el: &ElementDef, place: &PlyPlace<'_>, i: usize) -> Result<(), MeshError> {
        match self.encoding {
            Encoding::Ascii => self.read::<PlySkip>(el, place, i).map(|_| ()),
            _ => self.next_binary(el, place, i).map(|_| ()),
        }
    }
}

/// A binary list count; `None` when negative. Counts of floating-point type are refused with the header.
fn binary_count(raw: &[u8], t: &ScalarType, big: bool) -> Option<u64> {
    let word = |n: usize| -> u64 {
        let b = raw.iter().take(n);
        if big {
            b.fold(0u64, |acc, &x| (acc << 8) | u64::from(x))
        } else {
            b.rev().fold(0u64, |acc, &x| (acc << 8) | u64::from(x))
        }
    };
    match t {
        ScalarType::UChar => Some(word(1)),
        ScalarType::UShort => Some(word(2)),
        ScalarType::UInt => Some(word(4)),
        ScalarType::Char => u64::try_from(word(1) as u8 as i8).ok(),
        ScalarType::Short => u64::try_from(word(2) as u16 as i16).ok(),
        ScalarType::Int => u64::try_from(word(4) as u32 as i32).ok(),
        ScalarType::Float | ScalarType::Double => None,
    }
}

fn parse_ply_checked(name: &str, bytes: &[u8]) -> Result<Mesh, MeshError> {
    check_ply_header_length(name, bytes)?;
    let mut reader = Reader::new(bytes);
    let header = Parser::<PlySkip>::new().read_header(&mut reader).map_err(|e| MeshError::Parse {
        file: name.to_string(),
        place: e.line().map_or_else(|| "header".to_string(), |l| format!("header line {l}")),
        reason: ply_message(&e),
    })?;
    let payload_start = bytes.len() - reader.get_ref().len();
    let header_text = bytes.get(..payload_start).unwrap_or_default();
    let element_lines = scan_ply_header(name, header_text, &header)?;
    check_ply_header(name, &header)?;
    let ascii = header.encoding == Encoding::Ascii;
    check_ply_sizes(name, &header, &element_lines, bytes.len() - payload_start, ascii)?;
    let nv = header.elements.get("vertex").map_or(0, |e| e.count);
    if u32::try_from(nv).is_err() {
        return Err(too_many_vertices(name, nv));
    }

    let header_lines = header_text.iter().filter(|&&c| c == b'\n').count();
    let mut payload =
        PlyPayload { file: name, bytes, offset: payload_start, encoding: header.encoding, line: header_lines + 1 };
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut indices: Vec<[u32; 3]> = Vec::new();
    // For the message when no triangle comes out: (element, items read).
    let mut sources: Vec<(&str, usize)> = Vec::new();
    for el in header.elements.values() {
        let place = PlyPlace { name: &el.name, ascii, start_line: payload.line };
        match el.name.as_str() {
            "vertex" => {
                // The size check bounds the count by the file length (at least 3 bytes a vertex).
                positions.reserve_exact(el.count);
                for i in 0..el.count {
                    let p = payload.read::<PlyVertex>(el, &place, i)?.0;
                    if !p.iter().all(|c| c.is_finite()) {
                        return Err(MeshError::NonFinite { file: place.file(name, i), vertex: i, value: p });
                    }
                    positions.push(p);
                }
            }
            "face" => {
                sources.push(("face", el.count));
                for fi in 0..el.count {
                    let face = payload.read::<PlyIndices>(el, &place, fi)?;
                    let Some(list) = &face.0 else { continue };
                    let n = list.len();
                    if n < 3 {
                        continue;
                    }
                    let base = indices.len();
                    let corner = |j: usize| -> Result<u32, MeshError> {
                        let raw = list.get(j).unwrap_or(-1);
                        ply_index(name, &place, fi, raw, nv, base + j.saturating_sub(2))
                    };
                    let first = corner(0)?;
                    let mut prev = corner(1)?;
                    for j in 2..n {
                        let next = corner(j)?;
                        indices.push([first, prev, next]);
                        prev = next;
                    }
                }
            }
            "tristrips" => {
                sources.push(("tristrips", el.count));
                for si in 0..el.count {
                    let strip = payload.read::<PlyIndices>(el, &place, si)?;
                    let Some(list) = &strip.0 else { continue };
                    decode_strip(name, &place, si, list, nv, &mut indices)?;
                }
            }
            _ => {
                for i in 0..el.count {
                    payload.skip(el, &place, i)?;
                }
            }
        }
    }
    if indices.is_empty() {
        let detail = if sources.is_empty() {
            format!("{nv} vertices and no 'face' or 'tristrips' element")
        } else {
            let parts: Vec<String> = sources
                .iter()
                .map(|&(el, n)| match el {
                    "face" => format!("element 'face' has {n} faces, none of 3 or more corners"),
                    _ => format!("element 'tristrips' has {n} strips, none with 3 indices between restarts (-1)"),
                })
                .collect();
            format!("{nv} vertices; {}", parts.join("; "))
        };
        return Err(MeshError::NoTriangles { file: name.to_string(), detail });
    }
    // Without a vertex element every index is already rejected, so positions and nv agree.
    let mesh = Mesh { name: name.to_string(), positions, indices, object_ids: None };
    mesh.validate()?;
    Ok(mesh)
}

/// Checks one index read from a face or strip: negative indices are a parse error, indices past the vertex count an
/// [`MeshError::IndexOutOfRange`] for the triangle being built.
fn ply_index(
    file: &str,
    place: &PlyPlace<'_>,
    item: usize,
    raw: i64,
    nv: usize,
    triangle: usize,
) -> Result<u32, MeshError> {
    if raw < 0 {
        return Err(MeshError::Parse {
            file: file.to_string(),
            place: place.describe(item),
            reason: format!("negative vertex index {raw}"),
        });
    }
    match u32::try_from(raw) {
        Ok(i) if (i as usize) < nv => Ok(i),
        _ => {
            Err(MeshError::IndexOutOfRange { file: place.file(file, item), triangle, index: raw as u64, vertices: nv })
        }
    }
}

/// Decodes one triangle-strip list: `-1` restarts the strip; winding alternates.
fn decode_strip(
    file: &str,
    place: &PlyPlace<'_>,
    item: usize,
    list: &IndexList,
    nv: usize,
    out: &mut Vec<[u32; 3]>,
) -> Result<(), MeshError> {
    let mut run = 0usize;
    let (mut a, mut b) = (0u32, 0u32);
    for j in 0..list.len() {
        let raw = list.get(j).unwrap_or(-1);
        if raw == -1 {
            run = 0;
            continue;
        }
        let c = ply_index(file, place, item, raw, nv, out.len())?;
        if run >= 2 {
            // The run's triangle number is run - 2: even keeps (a, b, c), odd flips to (b, a, c).
            out.push(if run & 1 == 0 { [a, b, c] } else { [b, a, c] });
        }
        a = b;
        b = c;
        run += 1;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parser_panic_becomes_an_error_naming_the_file() {
        let e =
            catch_parser_panic::<()>("x.obj", "OBJ", || panic!("index out of bounds: the len is 3 but the index is 7"))
                .unwrap_err();
        assert!(matches!(e, MeshError::ParserPanic { parser: "OBJ", .. }), "{e:?}");
        assert_eq!(
            e.to_string(),
            "x.obj: the OBJ parser failed on this file (internal panic: index out of bounds: the len is 3 but the index \
             is 7)"
        );
        let long = "y".repeat(100_000);
        let e = catch_parser_panic::<()>("big.ply", "PLY", || panic!("{long}")).unwrap_err();
        let msg = e.to_string();
        assert!(msg.len() < 400 && msg.ends_with("...)"), "{msg}");
        assert_eq!(catch_parser_panic("ok", "PLY", || Ok(5)).unwrap(), 5);
    }

    #[test]
    fn quoted_text_is_cut_with_an_ellipsis() {
        assert_eq!(quote("a  b\n c"), "a b c");
        let q = quote(&"z".repeat(1000));
        assert_eq!(q.len(), MAX_QUOTE + 3);
        assert!(q.ends_with("..."));
        assert_eq!(short_reason(&"w ".repeat(10_000)).chars().count(), MAX_REASON + 3);
        assert_eq!(quote(&"é".repeat(MAX_QUOTE)), "é".repeat(MAX_QUOTE));
    }

    #[test]
    fn binary_counts_by_type_and_endianness() {
        assert_eq!(binary_count(&[0xff], &ScalarType::UChar, false), Some(255));
        assert_eq!(binary_count(&[0xff], &ScalarType::Char, false), None);
        assert_eq!(binary_count(&[1, 2], &ScalarType::UShort, false), Some(0x0201));
        assert_eq!(binary_count(&[1, 2], &ScalarType::UShort, true), Some(0x0102));
        assert_eq!(binary_count(&[0xff, 0xff, 0xff, 0x7f], &ScalarType::Int, false), Some(0x7fff_ffff));
        assert_eq!(binary_count(&[0xff, 0xff, 0xff, 0xff], &ScalarType::Int, true), None);
        assert_eq!(binary_count(&[0xff, 0xff, 0xff, 0xff], &ScalarType::UInt, true), Some(u64::from(u32::MAX)));
    }
}
