//! Scenes by name: a file, a directory of frames, or a generated scene's spec (`family:NAME:TRIANGLES[:SEED]`,
//! `degenerate:NAME:TRIANGLES[:SEED]`). Every tool that loads scenes takes all three, and a record naming a spec
//! regenerates the same mesh bit for bit. The loaders of [`crate::mesh`] read files only.
//!
//! ```
//! use meshchar::eval::scene::load_scene;
//! let scene = load_scene(std::path::Path::new("family:city:1000:5"))?;
//! assert_eq!((scene.name.as_str(), scene.frames.len()), ("family:city:1000:5", 1));
//! assert_eq!(scene.frames[0].triangle_count(), 1000);
//! # Ok::<(), meshchar::mesh::MeshError>(())
//! ```

use crate::mesh::{degenerate, families, load_mesh, load_path, Animation, Mesh, MeshError};
use std::path::Path;

/// The generated scene a path names when it does not exist and reads `family:NAME:TRIANGLES[:SEED]` (a scene family,
/// [`families::parse_spec`]) or `degenerate:NAME:TRIANGLES[:SEED]` (a degenerate scene, [`degenerate::parse_spec`]),
/// named by the spec; `None` for any other path.
pub fn generated_scene(path: &Path) -> Option<Result<Mesh, MeshError>> {
    if path.exists() {
        return None;
    }
    let spec = path.to_string_lossy();
    let invalid = |reason| MeshError::Invalid { file: spec.to_string(), reason };
    let mesh = if let Some(parsed) = families::parse_spec(&spec) {
        parsed.map_err(invalid).and_then(|(family, n, seed)| families::generate(family, n, seed))
    } else {
        let parsed = degenerate::parse_spec(&spec)?;
        parsed.map_err(invalid).and_then(|(kind, n, seed)| degenerate::generate(kind, n, seed))
    };
    // Errors name the spec as given.
    Some(
        mesh.map(|mut m| {
            m.name = spec.to_string();
            m
        })
        .map_err(|e| match e {
            MeshError::Invalid { reason, .. } => MeshError::Invalid { file: spec.to_string(), reason },
            other => other,
        }),
    )
}

/// [`load_path`], or the generated scene a spec names ([`generated_scene`]) as a one-frame animation named by the
/// spec.
pub fn load_scene(path: &Path) -> Result<Animation, MeshError> {
    match generated_scene(path) {
        Some(generated) => Animation::new(path.to_string_lossy().to_string(), vec![generated?]),
        None => load_path(path),
    }
}

/// [`load_mesh`], or the generated scene a spec names ([`generated_scene`]).
pub fn load_scene_mesh(path: &Path) -> Result<Mesh, MeshError> {
    generated_scene(path).unwrap_or_else(|| load_mesh(path))
}
