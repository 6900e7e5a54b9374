//! Brute force: every ray against every triangle. The reference of the tests.

use super::{bytes_of, prepare, AccelError, AccelStats, AccelStructure, StructureName};
use crate::geom::Triangle;
use crate::geom::{intersect_triangle, Hit, Ray, TraceCounters};
use crate::mesh::Mesh;

/// Tests every triangle, in mesh order, keeping the closest hit (the first of equal distances).
#[derive(Clone, Debug, Default)]
pub struct BruteForce {
    tris: Vec<Triangle>,
}

impl AccelStructure for BruteForce {
    fn build(mesh: &Mesh) -> Result<Self, AccelError> {
        let (tris, _) = prepare(mesh, "brute")?;
        Ok(BruteForce { tris })
    }
    fn name(&self) -> StructureName {
        StructureName::Brute
    }
    fn triangle_count(&self) -> usize {
        self.tris.len()
    }
    fn intersect(&self, ray: &Ray, c: &mut TraceCounters) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut tmax = ray.tmax;
        for (i, tri) in self.tris.iter().enumerate() {
            c.prim_tests += 1;
            if let Some((t, u, v)) = intersect_triangle(tri, ray.origin, ray.dir, ray.tmin, tmax) {
                tmax = t;
                best = Some(Hit { t, triangle: i as u32, u, v });
            }
        }
        best
    }
    fn occluded(&self, ray: &Ray, c: &mut TraceCounters) -> bool {
        for tri in &self.tris {
            c.prim_tests += 1;
            if intersect_triangle(tri, ray.origin, ray.dir, ray.tmin, ray.tmax).is_some() {
                return true;
            }
        }
        false
    }
    fn validate(&self) -> Result<AccelStats, AccelError> {
        let n = self.tris.len();
        Ok(AccelStats {
            triangles: n,
            nodes: usize::from(n > 0),
            leaves: usize::from(n > 0),
            empty_leaves: 0,
            max_depth: 0,
            references: n,
            bytes: self.memory_bytes(),
            reference_levels: n,
            copies: 0,
        })
    }
    fn memory_bytes(&self) -> usize {
        bytes_of(&self.tris)
    }
    fn sah_cost(&self) -> Option<f64> {
        Some(self.tris.len() as f64 * super::SAH_INTERSECTION_COST)
    }
}
