//! The crate's layers point one way: a top-level module imports only modules of lower layers (README, "Layout").
//! This test reads every source file under `src/`, finds every `crate::<module>` path outside comments (in `use`
//! declarations, `use crate::{a::.., b::..}` groups, and qualified paths), and fails on any that goes upward or
//! sideways, naming the file and the line.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Layers from the bottom: a module may import modules of strictly lower layers only.
const LAYERS: &[&[&str]] = &[
    &["geom", "keys", "rng", "stats"],
    &["gpu", "mesh"],
    &["accel"],
    &["trace"],
    &["characterize"],
    &["cost"],
    &["select"],
    &["eval"],
];

fn layer(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&module))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("read src") {
        let p = e.expect("dir entry").path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The source without comments (line comments, doc comments and block comments), string contents kept.
fn strip_comments(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    let mut in_str = false;
    while i < b.len() {
        let c = b[i];
        if in_str {
            out.push(c as char);
            if c == b'\\' && i + 1 < b.len() {
                out.push(b[i + 1] as char);
                i += 2;
                continue;
            }
            if c == b'"' {
                in_str = false;
            }
            i += 1;
        } else if c == b'"' {
            in_str = true;
            out.push('"');
            i += 1;
        } else if c == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if c == b'/' && b.get(i + 1) == Some(&b'*') {
            while i + 1 < b.len() && !(b[i] == b'*' && b[i + 1] == b'/') {
                if b[i] == b'\n' {
                    out.push('\n');
                }
                i += 1;
            }
            i += 2;
        } else {
            out.push(c as char);
            i += 1;
        }
    }
    out
}

/// `(line, module)` for every `crate::module` reference in `src` (comments stripped).
fn crate_references(src: &str) -> Vec<(usize, String)> {
    let text = strip_comments(src);
    let mut out = Vec::new();
    let ident = |s: &str| s.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect::<String>();
    let mut from = 0;
    while let Some(pos) = text[from..].find("crate::") {
        let at = from + pos;
        from = at + 7;
        // `$crate::` inside a macro names the crate from outside: still a crate path.
        let before = text[..at].chars().last();
        if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_') {
            continue;
        }
        let line = text[..at].matches('\n').count() + 1;
        let rest = &text[from..];
        if let Some(group) = rest.strip_prefix('{') {
            // `crate::{a::x, b::{y, z}}`: the first segment of each top-level item.
            let mut depth = 0;
            let mut item_start = true;
            for (k, ch) in group.char_indices() {
                match ch {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => item_start = true,
                    c if item_start && (c.is_ascii_alphabetic() || c == '_') => {
                        out.push((line, ident(&group[k..])));
                        item_start = false;
                    }
                    _ => {}
                }
            }
        } else {
            out.push((line, ident(rest)));
        }
    }
    out
}

#[test]
fn no_module_imports_one_above_it() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut seen_modules = BTreeSet::new();
    let mut violations = Vec::new();
    let mut references = 0;
    for f in &files {
        let rel = f.strip_prefix(&src).expect("under src");
        let top = rel
            .components()
            .next()
            .expect("a component")
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string();
        if top == "lib" {
            continue;
        }
        seen_modules.insert(top.clone());
        let Some(own) = layer(&top) else {
            violations.push(format!(
                "{}: module `{top}` is in no layer of this test (add it to LAYERS and the README)",
                rel.display()
            ));
            continue;
        };
        let text = std::fs::read_to_string(f).expect("read source");
        for (line, module) in crate_references(&text) {
            if module == top || layer(&module).is_none() {
                // Same module, or a crate-root item (a macro such as `push_layout!`).
                continue;
            }
            references += 1;
            let theirs = layer(&module).expect("checked");
            if theirs >= own {
                violations.push(format!(
                    "{}:{line}: `{top}` (layer {own}) imports `{module}` (layer {theirs}): imports must go down",
                    rel.display()
                ));
            }
        }
    }
    assert!(violations.is_empty(), "layer violations:\n{}", violations.join("\n"));
    // The check saw the crate: every layer's modules exist, and cross-module references were found.
    for m in LAYERS.iter().flat_map(|l| l.iter()) {
        assert!(seen_modules.contains(*m), "module `{m}` of LAYERS does not exist under src/");
    }
    assert!(references > 50, "only {references} cross-module references found: is the parser broken?");
}

#[test]
fn the_checker_catches_an_upward_import() {
    let refs = crate_references(
        "use crate::eval::oracle;\n// use crate::select::X;\nuse crate::{geom::Ray, mesh::{Mesh, load}};\nlet s = \"crate::x\";\nfn f() { crate::cost::fit(); }",
    );
    let modules: Vec<&str> = refs.iter().map(|(_, m)| m.as_str()).collect();
    assert_eq!(modules, ["eval", "geom", "mesh", "x", "cost"]);
    assert_eq!(refs[0].0, 1);
    assert_eq!(refs[4].0, 5);
    // `accel` importing `eval` is reported.
    assert!(layer("eval").unwrap() > layer("accel").unwrap());
}
