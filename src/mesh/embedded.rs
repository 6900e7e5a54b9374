//! Meshes compiled into the crate: the default scene (a low-resolution Stanford bunny) and the Utah teapot.
//!
//! Both are public-domain conversions (npm packages `bunny@1.0.1` and `teapot@1.0.0`); `assets/README.md` gives
//! their source. They let the tools and tests run with no mesh file at hand.

use super::load::{parse_mesh, MeshFormat};
use super::Mesh;

const BUNNY_OBJ: &str = include_str!("../../assets/bunny-lowres-pd.obj");
const TEAPOT_OBJ: &str = include_str!("../../assets/teapot-pd.obj");

fn embedded(name: &str, text: &str) -> Mesh {
    match parse_mesh(name, text.as_bytes(), MeshFormat::Obj) {
        Ok(m) => m,
        // The assets are fixed at compile time and a test loads both, so this cannot happen in a released build.
        Err(e) => panic!("embedded asset {name} does not parse: {e}"),
    }
}

/// The default scene: the low-resolution Stanford bunny (3,674 triangles, 1,839 vertices, one object), parsed from
/// the OBJ text embedded in the crate. Its name is `bunny-lowres-pd.obj (embedded)`.
pub fn default_scene() -> Mesh {
    embedded("bunny-lowres-pd.obj (embedded)", BUNNY_OBJ)
}

/// The Utah teapot (992 triangles, 792 vertices, one object, extent about 32 x 16 x 20 units), parsed from the OBJ
/// text embedded in the crate. Its name is `teapot-pd.obj (embedded)`.
pub fn default_teapot() -> Mesh {
    embedded("teapot-pd.obj (embedded)", TEAPOT_OBJ)
}
