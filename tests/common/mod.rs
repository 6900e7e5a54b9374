//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The shared test meshes, `<CARGO_MANIFEST_DIR>/../shared/meshes`. Panics (the test fails, it never skips) when the
/// folder is missing.
pub fn shared_meshes() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("shared").join("meshes");
    assert!(
        dir.is_dir(),
        "the shared test meshes are missing: expected the folder {} (shared/ beside the checkout)",
        dir.display()
    );
    dir
}

/// A shared mesh file by its path relative to [`shared_meshes`]; panics naming it when it is missing.
pub fn shared_mesh(rel: &str) -> PathBuf {
    let p = shared_meshes().join(rel);
    assert!(p.is_file(), "shared test mesh missing: {}", p.display());
    p
}

/// A fresh, empty directory under the system temp dir, unique to this process and call.
pub fn temp_dir(label: &str) -> PathBuf {
    static COUNTER: AtomicUsize = AtomicUsize::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let nanos =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.subsec_nanos()).unwrap_or(0);
    let dir = std::env::temp_dir().join(format!("meshchar-test-{}-{label}-{n}-{nanos}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Writes `bytes` to `name` in a fresh temp directory and returns the file's path.
pub fn temp_file(name: &str, bytes: &[u8]) -> PathBuf {
    let p = temp_dir(name).join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// The degenerate scenes the device tests run (coincident, collinear, zero-area, fans, a lattice, a teapot in a
/// stadium, flat, tiny and huge coordinates), each with its name; the bunny copies are of the lowest-resolution
/// Stanford bunny.
pub fn degenerate_scenes() -> Vec<(&'static str, meshchar::mesh::Mesh)> {
    use meshchar::mesh::generate;
    let bunny = meshchar::mesh::load::load_mesh(&shared_mesh("stanford-bunny/bun_zipper_res4.ply")).unwrap();
    vec![
        ("single", generate::single_triangle()),
        ("two", generate::two_triangles()),
        ("all equal", generate::all_equal(300)),
        ("collinear centroids", generate::collinear_centroids(500)),
        ("zero area", generate::zero_area(400, 3)),
        ("overlapping large", generate::overlapping_large(200, 4)),
        ("long thin", generate::long_thin_triangle()),
        ("fan", generate::fan_polygon(600)),
        ("lattice", generate::lattice_with_diagonal(20, 4)),
        ("teapot in stadium", generate::teapot_in_stadium(5)),
        ("flat", generate::flat(2000, 6)),
        ("soup", generate::random_soup(3000, 7)),
        ("clustered", generate::clustered(3000, 5, 8)),
        ("duplicated bunny", generate::duplicated(&bunny, 3).unwrap()),
        ("tiny bunny", generate::scaled(&bunny, 1e-6).unwrap()),
        ("huge bunny", generate::scaled(&bunny, 1e6).unwrap()),
    ]
}
