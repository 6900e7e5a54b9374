//! The committed seed corpora of the fuzz targets (`fuzz/seeds/`, written by `fuzz/make_seeds.py`) load as the
//! targets expect, so that a change of the loaders that turns a seed into an error is noticed here rather than as a
//! silently weaker corpus. Inputs that crash a fuzz target become regression tests beside these, with their files in
//! `tests/data/fuzz/` (README, "Fuzzing").

use meshchar::cost::CostModel;
use meshchar::mesh::{parse_mesh, MeshFormat};
use std::path::{Path, PathBuf};

fn seeds(target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz").join("seeds").join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no seeds in {}", dir.display());
    files
}

#[test]
fn mesh_seeds_load_with_triangles() {
    for (target, format) in [("obj", MeshFormat::Obj), ("ply", MeshFormat::Ply)] {
        for p in seeds(target) {
            let bytes = std::fs::read(&p).unwrap();
            let name = p.display().to_string();
            let m = parse_mesh(&name, &bytes, format).unwrap_or_else(|e| panic!("{e}"));
            assert!(m.triangle_count() > 0 && m.validate().is_ok(), "{name}");
        }
    }
}

#[test]
fn calibration_seeds_parse() {
    for p in seeds("calibration") {
        let m = CostModel::from_json(&std::fs::read_to_string(&p).unwrap())
            .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        assert!(!m.structures.is_empty(), "{}", p.display());
    }
}
