//! OBJ text through `tobj`, every face corner checked first (see the module documentation of [`super`], "OBJ").

use super::guard::{catch_parser_panic, quote, too_many_vertices};
use crate::mesh::{Mesh, MeshError};

/// Parses OBJ text (see the module documentation for what is kept and what is refused).
pub(super) fn parse_obj(name: &str, bytes: &[u8]) -> Result<Mesh, MeshError> {
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
