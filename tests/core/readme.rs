//! The README's Rust examples are the crate page's doctests: each ```rust block of README.md equals, line for line,
//! one example of `src/lib.rs`'s docs with its hidden (`# `) lines left out, so that what a reader copies compiles.

use std::path::Path;

/// The fenced blocks of `text` whose opening fence names one of `langs` (first word before a comma; "" for a
/// bare fence), as lists of lines.
fn blocks(text: &str, langs: &[&str]) -> Vec<Vec<String>> {
    // `None` outside a block; `Some((keep, lines))` inside one.
    let mut out = Vec::new();
    let mut inside: Option<(bool, Vec<String>)> = None;
    for line in text.lines() {
        let fence = line.trim_start().starts_with("```");
        inside = match inside {
            None if fence => {
                let lang = line.trim_start().trim_start_matches('`');
                Some((langs.contains(&lang.split(',').next().unwrap_or("")), Vec::new()))
            }
            None => None,
            Some((keep, b)) if fence => {
                if keep {
                    out.push(b);
                }
                None
            }
            Some((keep, mut b)) => {
                b.push(line.to_string());
                Some((keep, b))
            }
        };
    }
    out
}

fn crate_docs() -> String {
    let lib = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs")).expect("src/lib.rs");
    lib.lines()
        .filter_map(|l| l.strip_prefix("//!"))
        .map(|l| l.strip_prefix(' ').unwrap_or(l))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn every_rust_block_of_the_readme_is_a_doctest_of_the_crate_page() {
    let readme = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md")).expect("README.md");
    let ours = blocks(&readme, &["rust"]);
    assert!(ours.len() >= 2, "the README shows the main job and an engine's frame: {} rust blocks", ours.len());
    let doctests: Vec<Vec<String>> = blocks(&crate_docs(), &["", "rust", "no_run"])
        .into_iter()
        .map(|b| b.into_iter().filter(|l| !(l.starts_with("# ") || l == "#")).collect())
        .collect();
    for block in &ours {
        assert!(
            doctests.contains(block),
            "this README block is not a doctest of src/lib.rs (hidden lines aside):\n{}",
            block.join("\n")
        );
    }
    let lines = readme.lines().count();
    assert!(lines <= 300, "README.md has {lines} lines, at most 300");
}
