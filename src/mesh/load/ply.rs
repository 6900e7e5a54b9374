//! PLY through `ply-rs-bw`: ascii and binary, face lists and triangle strips, the header checked in full first (see
//! the module documentation of [`super`], "PLY").

use super::guard::{catch_parser_panic, quote, short_reason, too_many_vertices};
use crate::mesh::{Mesh, MeshError};
use ply_rs_bw::parser::{ParseError, Parser, Reader};
use ply_rs_bw::ply::{ElementDef, Encoding, Header, PropertyAccess, PropertyAccessResult, PropertyType, ScalarType};

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
pub(super) fn parse_ply(name: &str, bytes: &[u8]) -> Result<Mesh, MeshError> {
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
