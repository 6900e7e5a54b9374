//! Mesh support of the crate's unit tests: the shared test meshes (the integration tests have the same helpers in
//! `tests/common`).

use std::path::PathBuf;

/// The shared test meshes, `<CARGO_MANIFEST_DIR>/../shared/meshes`. Panics (the test fails, it never skips) when the
/// folder is missing.
pub(crate) fn shared_meshes() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("shared").join("meshes");
    assert!(
        dir.is_dir(),
        "the shared test meshes are missing: expected the folder {} (shared/ beside the checkout)",
        dir.display()
    );
    dir
}

/// A shared mesh file by its path relative to [`shared_meshes`]; panics naming it when it is missing.
pub(crate) fn shared_mesh(rel: &str) -> PathBuf {
    let p = shared_meshes().join(rel);
    assert!(p.is_file(), "shared test mesh missing: {}", p.display());
    p
}
