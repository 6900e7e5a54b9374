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
//! * A file without triangles loads as a valid mesh with 0 triangles; characterization rejects it later.
//!
//! # OBJ
//!
//! Every object or group of the file becomes one `tobj` model; the models are concatenated in file order, so triangle
//! `i` of the mesh is the `i`-th triangle of the file. When there is more than one model, [`Mesh::object_ids`] holds
//! the model index of every triangle. Each model keeps the vertices its faces use, so the vertex count can differ from
//! the number of `v` statements (unused vertices are dropped, a vertex used by two models appears twice). Polyline
//! statements (`l`) are ignored. Errors name the line (`file:line`): `tobj` reports no position, so on error the
//! text is scanned again to find the offending statement.
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
use ply_rs_bw::ply::{Encoding, Header, PropertyAccess, PropertyAccessResult, PropertyType, ScalarType};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// The file formats this crate reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MeshFormat {
    /// Wavefront OBJ (text).
    Obj,
    /// Stanford PLY (ascii, binary little endian or binary big endian).
    Ply,
}

/// Longest reason text kept from a parser message (ascii PLY messages quote the whole offending line, which can be
/// megabytes long for a triangle strip).
const MAX_REASON: usize = 300;

/// Loads one mesh from an `.obj` or `.ply` file.
///
/// The format comes from the extension (case-insensitive); for any other extension the first bytes decide (see
/// [`detect_format`]). The mesh is named after the path. Every error names the file and, where there is one, the
/// place in it.
pub fn load_mesh(path: &Path) -> Result<Mesh, MeshError> {
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io { path: path.to_path_buf(), source })?;
    let format = detect_format(path, &bytes).ok_or_else(|| MeshError::UnknownFormat { path: path.to_path_buf() })?;
    parse_mesh(&path.display().to_string(), &bytes, format)
}

/// Parses a mesh held in memory. `name` names the mesh and is the file named in errors.
pub fn parse_mesh(name: &str, bytes: &[u8], format: MeshFormat) -> Result<Mesh, MeshError> {
    match format {
        MeshFormat::Obj => parse_obj(name, bytes),
        MeshFormat::Ply => parse_ply(name, bytes),
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
/// ([`MeshError::TopologyMismatch`]) names both files. The animation is named after the first file.
pub fn load_animation(paths: &[PathBuf]) -> Result<Animation, MeshError> {
    let frames = paths.par_iter().map(|p| load_mesh(p)).collect::<Result<Vec<_>, _>>()?;
    Animation::new(paths.first().map(|p| p.display().to_string()).unwrap_or_default(), frames)
}

/// Loads a file as a one-frame animation, or a directory of frame files as an animation.
///
/// In a directory, the frames are the files whose extension is `.obj` or `.ply` (case-insensitive), sorted by file
/// name; other files are ignored. A directory without such files is an error naming it. The animation is named after
/// the path.
pub fn load_path(path: &Path) -> Result<Animation, MeshError> {
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

/// The `.obj` and `.ply` files of a directory, sorted by file name.
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
        if is_mesh && p.is_file() {
            files.push(p);
        }
    }
    files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    Ok(files)
}

fn too_many_vertices(name: &str, n: usize) -> MeshError {
    MeshError::Invalid { file: name.to_string(), reason: format!("{n} vertices: more than 32-bit indices address") }
}

/// Keeps a parser message to one short line.
fn short_reason(s: &str) -> String {
    let one_line: String = s.split_whitespace().collect::<Vec<_>>().join(" ");
    if one_line.chars().count() > MAX_REASON {
        let cut: String = one_line.chars().take(MAX_REASON).collect();
        format!("{cut}...")
    } else {
        one_line
    }
}

// ---------------------------------------------------------------------------------------------------------------
// OBJ
// ---------------------------------------------------------------------------------------------------------------

/// Parses OBJ text (see the module documentation for what is kept).
pub fn parse_obj(name: &str, bytes: &[u8]) -> Result<Mesh, MeshError> {
    // tobj reads `l` (polyline) statements as faces; blank them (keeping line numbers) so that a polyline of three
    // points does not become a triangle.
    let filtered;
    let text: &[u8] = if has_polyline(bytes) {
        filtered = blank_polylines(bytes);
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

fn is_polyline_statement(line: &[u8]) -> bool {
    let t = line.trim_ascii_start();
    t.starts_with(b"l") && t.get(1).is_none_or(|c| c.is_ascii_whitespace())
}

fn has_polyline(bytes: &[u8]) -> bool {
    bytes.split(|&c| c == b'\n').any(is_polyline_statement)
}

/// Turns every polyline statement into a comment of the same length.
fn blank_polylines(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(bytes.len());
    for (i, line) in bytes.split(|&c| c == b'\n').enumerate() {
        if i > 0 {
            out.push(b'\n');
        }
        if is_polyline_statement(line) {
            out.push(b'#');
        }
        out.extend_from_slice(line);
    }
    out
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
    /// Parser line number of the element's first item (for ascii files, the file line).
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
            format!("element '{}' {i} (line {})", self.name, self.start_line + i)
        } else {
            format!("element '{}' {i}", self.name)
        }
    }
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

fn ply_payload_error(file: &str, place: &PlyPlace<'_>, e: &ParseError) -> MeshError {
    let where_ = match e.line() {
        Some(l) if l >= place.start_line => place.describe(l - place.start_line),
        _ => format!("element '{}'", place.name),
    };
    MeshError::Parse { file: file.to_string(), place: where_, reason: ply_message(e) }
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

/// Parses a PLY file held in memory (see the module documentation for what is kept).
pub fn parse_ply(name: &str, bytes: &[u8]) -> Result<Mesh, MeshError> {
    let mut reader = Reader::new(bytes);
    let header = Parser::<PlySkip>::new().read_header(&mut reader).map_err(|e| MeshError::Parse {
        file: name.to_string(),
        place: e.line().map_or_else(|| "header".to_string(), |l| format!("header line {l}")),
        reason: ply_message(&e),
    })?;
    check_ply_header(name, &header)?;
    let ascii = header.encoding == Encoding::Ascii;
    let nv = header.elements.get("vertex").map_or(0, |e| e.count);
    if u32::try_from(nv).is_err() {
        return Err(too_many_vertices(name, nv));
    }

    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut indices: Vec<[u32; 3]> = Vec::new();
    for (_, el) in &header.elements {
        let place = PlyPlace { name: &el.name, ascii, start_line: reader.line() };
        let payload_error = |e: ParseError| ply_payload_error(name, &place, &e);
        match el.name.as_str() {
            "vertex" => {
                let verts = Parser::<PlyVertex>::new()
                    .read_payload_for_element(&mut reader, el, &header)
                    .map_err(payload_error)?;
                positions = verts.into_iter().map(|v| v.0).collect();
                if let Some((i, p)) = positions.iter().enumerate().find(|(_, p)| !p.iter().all(|c| c.is_finite())) {
                    return Err(MeshError::NonFinite { file: place.file(name, i), vertex: i, value: *p });
                }
            }
            "face" => {
                let faces = Parser::<PlyIndices>::new()
                    .read_payload_for_element(&mut reader, el, &header)
                    .map_err(payload_error)?;
                indices.reserve(faces.len());
                for (fi, face) in faces.iter().enumerate() {
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
                let strips = Parser::<PlyIndices>::new()
                    .read_payload_for_element(&mut reader, el, &header)
                    .map_err(payload_error)?;
                for (si, strip) in strips.iter().enumerate() {
                    let Some(list) = &strip.0 else { continue };
                    decode_strip(name, &place, si, list, nv, &mut indices)?;
                }
            }
            _ => {
                Parser::<PlySkip>::new().read_payload_for_element(&mut reader, el, &header).map_err(payload_error)?;
            }
        }
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
