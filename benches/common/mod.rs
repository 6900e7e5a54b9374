//! Helpers shared by the benches.
#![allow(dead_code)]

use meshchar::mesh::{load_mesh, Mesh};
use std::path::PathBuf;

/// The shared meshes, `<CARGO_MANIFEST_DIR>/../shared/meshes` (the `shared/` folder beside the checkout).
pub fn shared_meshes() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("shared").join("meshes")
}

/// Loads a shared mesh by its path relative to [`shared_meshes`]; panics naming the file when it is missing or
/// broken (a bench never runs on a substitute).
pub fn load_shared(rel: &str) -> Mesh {
    let p = shared_meshes().join(rel);
    load_mesh(&p).unwrap_or_else(|e| {
        panic!(
            "benchmark mesh {} is missing or broken ({e}); the shared meshes belong beside the checkout",
            p.display()
        )
    })
}
