//! The built example binaries the integration tests run: `target/<profile>/examples/<name>`, beside the test's own
//! `target/<profile>/deps/`. A missing binary, or one older than a source it was built from, fails the test (build
//! them first: `cargo build --release --examples`, as `scripts/test` does; `cargo test --examples` builds test
//! harnesses, not these binaries).

use std::path::{Path, PathBuf};

/// The example binary `name`, checked as the module docs say.
pub fn path(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("the test's own path");
    let dir = exe.parent().and_then(Path::parent).expect("target/<profile>");
    let path = dir.join("examples").join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    assert!(
        path.is_file(),
        "example binary {} not found: build the examples first (`cargo build --release --examples`; \
         `cargo test --examples` builds test harnesses, not these binaries)",
        path.display()
    );
    let built = std::fs::metadata(&path).and_then(|m| m.modified()).expect("the binary's time");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // What cargo relinks the example for: the sources its dep-info file beside it lists (a test-only module of the
    // library is not among them), else its own source, the shared support code and the library.
    let sources = dep_info_sources(&path.with_extension("d")).unwrap_or_else(|| {
        vec![root.join("examples").join(format!("{name}.rs")), root.join("examples/support"), root.join("src")]
    });
    if let Some(newer) = newest_source(&sources, built) {
        panic!(
            "example binary {} is older than {}: rebuild the examples (`cargo build --release --examples`)",
            path.display(),
            newer.display()
        );
    }
    path
}

/// The sources a cargo dep-info file (`target: dep dep ...`, spaces in a path escaped by a backslash) lists.
fn dep_info_sources(file: &Path) -> Option<Vec<PathBuf>> {
    let text = std::fs::read_to_string(file).ok()?;
    let deps = text.lines().next()?.split_once(": ")?.1;
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut chars = deps.chars();
    while let Some(c) = chars.next() {
        match c {
            '\\' => cur.extend(chars.next()),
            ' ' => {
                if !cur.is_empty() {
                    out.push(PathBuf::from(std::mem::take(&mut cur)));
                }
            }
            c => cur.push(c),
        }
    }
    if !cur.is_empty() {
        out.push(PathBuf::from(cur));
    }
    (!out.is_empty()).then_some(out)
}

/// A file under `paths` modified after `time`, if any.
fn newest_source(paths: &[PathBuf], time: std::time::SystemTime) -> Option<PathBuf> {
    for p in paths {
        let Ok(meta) = std::fs::metadata(p) else { continue };
        if meta.is_dir() {
            let entries: Vec<PathBuf> =
                std::fs::read_dir(p).into_iter().flatten().flatten().map(|e| e.path()).collect();
            if let Some(f) = newest_source(&entries, time) {
                return Some(f);
            }
        } else if meta.modified().is_ok_and(|m| m > time) {
            return Some(p.clone());
        }
    }
    None
}
