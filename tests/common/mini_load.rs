//! A tiny OBJ (`v`/`f` only) and ASCII PLY reader for tests, benches and the `evaluate` example, used until the
//! crate's loaders (`meshchar::mesh::load_*`) are merged. Polygons are fan-triangulated.
#![allow(dead_code)]

use meshchar::mesh::Mesh;
use std::path::Path;

/// Reads an `.obj` or ASCII `.ply` file.
pub fn load(path: &Path) -> Result<Mesh, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let name = path.display().to_string();
    match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
        Some("obj") => obj(&name, &text),
        Some("ply") => ply(&name, &text),
        _ => Err(format!("{name}: not .obj or .ply")),
    }
}

fn obj(name: &str, text: &str) -> Result<Mesh, String> {
    let mut pos: Vec<[f32; 3]> = Vec::new();
    let mut idx: Vec<[u32; 3]> = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let mut p = [0f32; 3];
                for c in &mut p {
                    *c = it
                        .next()
                        .and_then(|s| s.parse().ok())
                        .ok_or_else(|| format!("{name}:{}: bad vertex", ln + 1))?;
                }
                pos.push(p);
            }
            Some("f") => {
                let mut poly = Vec::new();
                for tok in it {
                    let first = tok.split('/').next().unwrap_or("");
                    let i: i64 = first.parse().map_err(|_| format!("{name}:{}: bad face", ln + 1))?;
                    let i = if i < 0 { pos.len() as i64 + i } else { i - 1 };
                    if i < 0 {
                        return Err(format!("{name}:{}: bad index", ln + 1));
                    }
                    poly.push(i as u32);
                }
                for k in 1..poly.len().saturating_sub(1) {
                    idx.push([poly[0], poly[k], poly[k + 1]]);
                }
            }
            _ => {}
        }
    }
    Mesh::new(name, pos, idx).map_err(|e| e.to_string())
}

fn ply(name: &str, text: &str) -> Result<Mesh, String> {
    let mut lines = text.lines();
    let (mut nv, mut nf) = (0usize, 0usize);
    let mut vprops: Vec<String> = Vec::new();
    let mut in_vertex = false;
    for line in lines.by_ref() {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["format", f, ..] if *f != "ascii" => return Err(format!("{name}: only ASCII PLY")),
            ["element", "vertex", n] => {
                nv = n.parse().map_err(|_| format!("{name}: bad header"))?;
                in_vertex = true;
            }
            ["element", "face", n] => {
                nf = n.parse().map_err(|_| format!("{name}: bad header"))?;
                in_vertex = false;
            }
            ["element", ..] => in_vertex = false,
            ["property", .., p] if in_vertex => vprops.push(p.to_string()),
            ["end_header"] => break,
            _ => {}
        }
    }
    let col = |n: &str| vprops.iter().position(|p| p == n).ok_or_else(|| format!("{name}: no {n}"));
    let (cx, cy, cz) = (col("x")?, col("y")?, col("z")?);
    let mut pos = Vec::with_capacity(nv);
    for _ in 0..nv {
        let l = lines.next().ok_or_else(|| format!("{name}: truncated"))?;
        let v: Vec<f32> = l.split_whitespace().map(|s| s.parse().unwrap_or(f32::NAN)).collect();
        let g = |c: usize| v.get(c).copied().ok_or_else(|| format!("{name}: short vertex"));
        pos.push([g(cx)?, g(cy)?, g(cz)?]);
    }
    let mut idx = Vec::with_capacity(nf);
    for _ in 0..nf {
        let l = lines.next().ok_or_else(|| format!("{name}: truncated"))?;
        let v: Vec<u32> = l.split_whitespace().filter_map(|s| s.parse().ok()).collect();
        let k = *v.first().ok_or_else(|| format!("{name}: empty face"))? as usize;
        if v.len() < k + 1 {
            return Err(format!("{name}: short face"));
        }
        for j in 1..k.saturating_sub(1) {
            idx.push([v[1], v[1 + j], v[2 + j]]);
        }
    }
    Mesh::new(name, pos, idx).map_err(|e| e.to_string())
}

/// `<CARGO_MANIFEST_DIR>/../shared/meshes/<rel>`; panics naming the path when it is missing.
pub fn shared_mesh(rel: &str) -> std::path::PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes").join(rel);
    assert!(p.exists(), "shared mesh {} is missing (tests need ../shared/meshes beside the checkout)", p.display());
    p
}
