//! What the fuzz targets share: a heap-counting allocator (for the loaders' documented memory bound), the checks made
//! on every result, and the splitting of one input into the frame files of an animation.
//!
//! Every target asserts that the call returns (libFuzzer's `-timeout` catches hangs, `-rss_limit_mb` runaway memory)
//! without a panic (libfuzzer-sys aborts on any panic, including one `catch_unwind` would catch, so a
//! [`MeshError::ParserPanic`] backstop that fires is a finding too), and then checks the value returned: a mesh that
//! passes [`Mesh::validate`] and has triangles, or an error that is not a caught parser panic and whose message is
//! short and names the file.

use meshchar::mesh::{Animation, Mesh, MeshError, MeshFormat};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The system allocator, counting live heap bytes and their peak.
pub struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grow(n: usize) {
    let now = LIVE.fetch_add(n, Ordering::Relaxed) + n;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

// SAFETY: every call is forwarded to `System` unchanged; the counters only observe sizes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            grow(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            grow(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            // Counted as the loaders' documentation counts it: the new block while the old one is still live.
            grow(new_size);
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }
}

/// Peak heap bytes allocated (through [`Counting`]) while `f` runs, above what was live when it started.
pub fn peak_heap<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let out = f();
    (out, PEAK.load(Ordering::Relaxed).saturating_sub(base))
}

/// With `MESHCHAR_FUZZ_PRINT` set, the targets print what each input gave (to check seeds and crash inputs by hand:
/// `MESHCHAR_FUZZ_PRINT=1 fuzz/target/x86_64-unknown-linux-gnu/release/ply fuzz/seeds/ply/*`).
pub fn report<T, E: std::fmt::Display>(r: &Result<T, E>, summary: impl FnOnce(&T) -> String) {
    if std::env::var_os("MESHCHAR_FUZZ_PRINT").is_some() {
        match r {
            Ok(v) => eprintln!("meshchar-fuzz: ok: {}", summary(v)),
            Err(e) => eprintln!("meshchar-fuzz: error: {e}"),
        }
    }
}

/// Longest error message accepted (the loaders cut quoted text to a few hundred characters).
pub const MAX_MESSAGE: usize = 1024;

/// Checks an error: not a caught parser panic, a short message that names `file`.
pub fn check_error(e: &MeshError, file: &str) {
    assert!(!matches!(e, MeshError::ParserPanic { .. }), "a parser panicked behind the loader's checks: {e}");
    let msg = e.to_string();
    let head: String = msg.chars().take(200).collect();
    assert!(msg.len() <= MAX_MESSAGE, "error message of {} bytes: {head}...", msg.len());
    assert!(msg.contains(file), "error message does not name {file}: {msg}");
}

/// Checks a loaded mesh: valid (indices in range, finite coordinates, object ids per triangle) and not empty.
pub fn check_mesh(m: &Mesh) {
    m.validate().unwrap_or_else(|e| panic!("a loaded mesh fails validation: {e}"));
    assert!(m.triangle_count() > 0, "a loaded mesh has no triangles");
    if let Some(ids) = &m.object_ids {
        assert_eq!(ids.len(), m.triangle_count());
    }
}

/// Parses `data` as `format` in memory and checks the result and the documented memory bound
/// (`LOAD_BYTES_PER_INPUT_BYTE * n + LOAD_BYTES_FIXED`).
pub fn fuzz_parse(data: &[u8], format: MeshFormat) {
    let name = match format {
        MeshFormat::Obj => "fuzz.obj",
        MeshFormat::Ply => "fuzz.ply",
    };
    let (r, peak) = peak_heap(|| meshchar::mesh::parse_mesh(name, data, format));
    let bound = meshchar::mesh::load::LOAD_BYTES_PER_INPUT_BYTE * data.len() + meshchar::mesh::load::LOAD_BYTES_FIXED;
    assert!(peak <= bound, "{} input bytes took {peak} heap bytes at the peak, above the bound {bound}", data.len());
    report(&r, |m| format!("{} vertices, {} triangles, peak heap {peak} bytes", m.positions.len(), m.triangle_count()));
    match &r {
        Ok(m) => check_mesh(m),
        Err(e) => check_error(e, name),
    }
    // The content sniffer sees every input too (it must not panic on any prefix or cut character).
    let _ = meshchar::mesh::load::sniff_format(data);
}

/// Separates the frame files in an animation input.
pub const FRAME_SEPARATOR: &[u8] = b"@@FRAME@@\n";

/// File name extensions a frame file can get, chosen by two bits of the control byte: the loaders' two (in two
/// spellings) and one that [`meshchar::mesh::load_path`] ignores in a directory and that a file list sniffs.
pub const FRAME_EXTENSIONS: [&str; 4] = ["obj", "ply", "Ply", "txt"];

/// How an animation input is laid out: a control byte, then up to three frame files separated by
/// [`FRAME_SEPARATOR`]. Control bits 0-5: the extensions of files 0, 1, 2 ([`FRAME_EXTENSIONS`]); bit 6: the
/// directory also holds a subdirectory named like a frame file; bit 7: load the files as a list
/// ([`meshchar::mesh::load_animation`]) instead of the directory ([`meshchar::mesh::load_path`]).
pub struct AnimationInput<'a> {
    pub files: Vec<(String, &'a [u8])>,
    pub subdirectory: bool,
    pub as_list: bool,
}

impl<'a> AnimationInput<'a> {
    pub fn split(data: &'a [u8]) -> Option<Self> {
        let (&control, rest) = data.split_first()?;
        let mut files = Vec::new();
        let mut rest = rest;
        for k in 0..3 {
            let (part, next) = match find(rest, FRAME_SEPARATOR) {
                Some(at) if k < 2 => (&rest[..at], Some(&rest[at + FRAME_SEPARATOR.len()..])),
                _ => (rest, None),
            };
            let ext = FRAME_EXTENSIONS[usize::from((control >> (2 * k)) & 3)];
            files.push((format!("frame{k}.{ext}"), part));
            match next {
                Some(n) => rest = n,
                None => break,
            }
        }
        Some(AnimationInput { files, subdirectory: control & 0x40 != 0, as_list: control & 0x80 != 0 })
    }

    /// Writes the files into `dir` (emptied first) and returns their paths.
    pub fn write(&self, dir: &Path) -> Vec<PathBuf> {
        let _ = std::fs::remove_dir_all(dir);
        std::fs::create_dir_all(dir).expect("cannot create the fuzz directory");
        let mut paths = Vec::new();
        for (name, bytes) in &self.files {
            let p = dir.join(name);
            std::fs::write(&p, bytes).expect("cannot write a frame file");
            paths.push(p);
        }
        if self.subdirectory {
            std::fs::create_dir(dir.join("zz.obj")).expect("cannot create the subdirectory");
        }
        paths
    }
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Checks a loaded animation: at least one frame, every frame a checked mesh with the first frame's topology.
pub fn check_animation(a: &Animation) {
    let first = a.frames.first().expect("an animation without frames");
    for f in &a.frames {
        check_mesh(f);
        assert_eq!(f.indices, first.indices, "frames of one animation differ in topology");
        assert_eq!(f.positions.len(), first.positions.len(), "frames of one animation differ in vertex count");
    }
}

/// A per-process scratch directory for the animation target, on tmpfs when there is one.
pub fn scratch_dir() -> PathBuf {
    let shm = Path::new("/dev/shm");
    let base = if shm.is_dir() { shm.to_path_buf() } else { std::env::temp_dir() };
    base.join(format!("meshchar-fuzz-{}", std::process::id()))
}
