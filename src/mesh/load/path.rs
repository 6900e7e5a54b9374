//! Loading from the file system: one mesh from a file ([`load_mesh`]), an animation from a directory of frames or
//! a list of files ([`load_path`], [`load_animation`]), and the format of a file ([`detect_format`]).

use super::guard::{check_regular_file, read_regular_file};
use super::{obj, ply};
use crate::mesh::{Animation, Mesh, MeshError};
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

/// Loads one mesh from an `.obj` or `.ply` file.
///
/// The format comes from the extension (case-insensitive); for any other extension the first bytes decide (see
/// `detect_format`). The mesh is named after the path. Every error names the file and, where there is one, the
/// place in it; anything but a regular file is refused before it is opened (see the module documentation).
pub fn load_mesh(path: &Path) -> Result<Mesh, MeshError> {
    let bytes = read_regular_file(path)?;
    let format = detect_format(path, &bytes).ok_or_else(|| MeshError::UnknownFormat { path: path.to_path_buf() })?;
    parse_mesh(&path.display().to_string(), &bytes, format)
}

/// Parses a mesh held in memory. `name` names the mesh and is the file named in errors. Like [`load_mesh`], it
/// refuses input without triangles.
pub fn parse_mesh(name: &str, bytes: &[u8], format: MeshFormat) -> Result<Mesh, MeshError> {
    match format {
        MeshFormat::Obj => obj::parse_obj(name, bytes),
        MeshFormat::Ply => ply::parse_ply(name, bytes),
    }
}

/// Decides the format of a file: by extension (`.obj`, `.ply`, case-insensitive), otherwise by content: a PLY file
/// starts with the line `ply`; OBJ text is recognised when its first statements (up to 16, blank lines skipped) all
/// start with an OBJ keyword or `#` and at least one of them is not a comment. `None` when neither applies.
pub(crate) fn detect_format(path: &Path, bytes: &[u8]) -> Option<MeshFormat> {
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

/// Content-based half of `detect_format`.
pub(crate) fn sniff_format(bytes: &[u8]) -> Option<MeshFormat> {
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
/// that is not a regular file (see `frame_files`). The animation is named after the path.
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
///
/// An entry with one of these extensions that is not a regular file once links are followed (a FIFO, a device, a
/// directory, a dangling link) is an error naming it ([`MeshError::Io`]), rather than a frame silently left out.
pub(crate) fn frame_files(dir: &Path) -> Result<Vec<PathBuf>, MeshError> {
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
