//! Triangle meshes and animations: the input of every other module.
//!
//! A [`Mesh`] is a list of f32 vertex positions and a list of `u32` index triples, with an optional object id per
//! triangle (kept when an OBJ file with several objects is merged). An [`Animation`] is an ordered list of frames that
//! share one topology. Loaders live in [`load`]; [`default_scene`] and [`default_teapot`] are compiled into the
//! crate. The test-scene generators, part of the evaluation tools (feature `eval`), are `generate` (synthetic
//! scenes), `families` (whole scenes of a kind: interiors, cities, ...) and `degenerate` (degenerate scenes by
//! name).

#[cfg(any(test, feature = "eval"))]
pub mod degenerate;
mod embedded;
mod error;
#[cfg(any(test, feature = "eval"))]
pub mod families;
#[cfg(any(test, feature = "eval"))]
pub mod generate;
pub mod load;
#[cfg(test)]
pub(crate) mod testing;

pub use embedded::{default_scene, default_teapot};
pub use error::MeshError;
pub use load::{load_animation, load_mesh, load_path, parse_mesh, MeshFormat};

use glam::Vec3;

/// A triangle mesh: f32 positions, `u32` index triples, optional object id per triangle.
///
/// Zero-area triangles are kept: they are real input (the conference scene has 53,627 of them) and every algorithm of
/// this crate must cope with them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// A name for reports, usually the path it was loaded from.
    pub name: String,
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangles as indices into `positions`.
    pub indices: Vec<[u32; 3]>,
    /// Object id of every triangle (same length as `indices`), when the source had several objects.
    pub object_ids: Option<Vec<u32>>,
}

impl Mesh {
    /// Builds a mesh and checks it: every index in range, every coordinate finite.
    pub fn new(name: impl Into<String>, positions: Vec<[f32; 3]>, indices: Vec<[u32; 3]>) -> Result<Self, MeshError> {
        let mesh = Mesh { name: name.into(), positions, indices, object_ids: None };
        mesh.validate()?;
        Ok(mesh)
    }

    /// Builds a mesh from a triangle soup (three vertices per triangle, no sharing).
    pub fn from_triangles(name: impl Into<String>, tris: &[[Vec3; 3]]) -> Result<Self, MeshError> {
        let mut positions = Vec::with_capacity(tris.len() * 3);
        let mut indices = Vec::with_capacity(tris.len());
        for t in tris {
            let base = positions.len() as u32;
            positions.extend(t.iter().map(|v| v.to_array()));
            indices.push([base, base + 1, base + 2]);
        }
        Mesh::new(name, positions, indices)
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// The three vertices of triangle `i`. Panics if `i` is out of range (indices are checked at construction).
    #[inline]
    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        let [a, b, c] = self.indices[i];
        [
            Vec3::from_array(self.positions[a as usize]),
            Vec3::from_array(self.positions[b as usize]),
            Vec3::from_array(self.positions[c as usize]),
        ]
    }

    /// Checks the invariants every consumer relies on: indices in range, finite coordinates, object ids (if any) one
    /// per triangle. The error names the mesh and the offending vertex or triangle.
    pub fn validate(&self) -> Result<(), MeshError> {
        for (i, p) in self.positions.iter().enumerate() {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(MeshError::NonFinite { file: self.name.clone(), vertex: i, value: *p });
            }
        }
        let nv = self.positions.len();
        for (t, tri) in self.indices.iter().enumerate() {
            for &ix in tri {
                if ix as usize >= nv {
                    return Err(MeshError::IndexOutOfRange {
                        file: self.name.clone(),
                        triangle: t,
                        index: ix as u64,
                        vertices: nv,
                    });
                }
            }
        }
        if let Some(ids) = &self.object_ids {
            if ids.len() != self.indices.len() {
                return Err(MeshError::Invalid {
                    file: self.name.clone(),
                    reason: format!("{} object ids for {} triangles", ids.len(), self.indices.len()),
                });
            }
        }
        Ok(())
    }

    /// Number of triangles whose area is exactly zero (computed in f64 from the f32 vertices).
    pub fn zero_area_count(&self) -> usize {
        (0..self.triangle_count())
            .filter(|&i| {
                let [a, b, c] = self.triangle(i);
                let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
                (b - a).cross(c - a).length_squared() == 0.0
            })
            .count()
    }
}

/// An animation: ordered frames with one topology (the same index triples in every frame).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Animation {
    /// A name for reports (the directory or first file).
    pub name: String,
    /// The frames, in order. All have the same `indices`.
    pub frames: Vec<Mesh>,
}

impl Animation {
    /// Builds an animation and checks that every frame has the topology of the first.
    pub fn new(name: impl Into<String>, frames: Vec<Mesh>) -> Result<Self, MeshError> {
        let name = name.into();
        if let Some(first) = frames.first() {
            for f in &frames[1..] {
                if f.indices != first.indices || f.positions.len() != first.positions.len() {
                    return Err(MeshError::TopologyMismatch {
                        first: first.name.clone(),
                        other: f.name.clone(),
                        detail: format!(
                            "{} vertices / {} triangles against {} / {}",
                            f.positions.len(),
                            f.indices.len(),
                            first.positions.len(),
                            first.indices.len()
                        ),
                    });
                }
            }
        }
        Ok(Animation { name, frames })
    }

    /// Whether the scene moves: more than one frame.
    pub fn is_dynamic(&self) -> bool {
        self.frames.len() > 1
    }
}
