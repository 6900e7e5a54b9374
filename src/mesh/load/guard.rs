//! What every load shares: only regular files are read, into one buffer of their size; a third-party parser's
//! panic becomes an error naming the file; text quoted from a file in a message is cut short.

use crate::mesh::MeshError;
use std::io::Read;
use std::path::Path;

/// Longest reason text kept from a parser message (ascii PLY messages quote the whole offending line, which can be
/// megabytes long for a triangle strip).
const MAX_REASON: usize = 300;

/// Longest name or token quoted from a file in a message.
const MAX_QUOTE: usize = 80;

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
pub(super) fn check_regular_file(path: &Path) -> Result<std::fs::Metadata, MeshError> {
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
pub(super) fn read_regular_file(path: &Path) -> Result<Vec<u8>, MeshError> {
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

/// Runs a parse that calls a third-party parser, turning a panic into [`MeshError::ParserPanic`] naming the file.
pub(super) fn catch_parser_panic<T>(
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

pub(super) fn too_many_vertices(name: &str, n: usize) -> MeshError {
    MeshError::Invalid { file: name.to_string(), reason: format!("{n} vertices: more than 32-bit indices address") }
}

/// Keeps a parser message to one short line: whitespace runs become one space, and the text is cut after
/// [`MAX_REASON`] characters with `...` (without first copying a long message whole).
pub(super) fn short_reason(s: &str) -> String {
    cut_words(s, MAX_REASON)
}

/// Text quoted from a file (a name, a token), cut after [`MAX_QUOTE`] characters with `...`.
pub(super) fn quote(s: &str) -> String {
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
}
