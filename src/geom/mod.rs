//! Geometry shared by every structure and the tracer: boxes, triangles, rays, hits, the slab and ray-triangle
//! tests, and work counters. It is the bottom layer beside `mesh`: it imports nothing from the crate.
//!
//! The ray-triangle test is Möller and Trumbore 1997 in f32 on precomputed edges ([`Triangle`]).
//! It is not watertight: a ray through a shared edge may report either neighbour (both at the same `t`), and in
//! rare cases neither. All structures use this one test, so they agree triangle for triangle; a ray is counted as
//! a hit when `tmin < t < tmax`, `u >= 0`, `v >= 0`, `u + v <= 1` and the determinant is non-zero and finite.
//! Zero-area triangles have zero edges, a zero determinant, and are never hit.
//!
//! Ray-box tests are slab tests (Kay and Kajiya 1986) with the exit distance scaled by `1 + 2 gamma(3)` as Ize 2013
//! recommends, so that rounding never culls a box a ray really touches. A zero direction component gets an inverse
//! of `f32::MAX` instead of infinity, so that no slab test ever computes `0 * inf`.

mod aabb;
pub mod camera;
mod clip;
pub(crate) mod ray;
mod triangle;

pub use aabb::Aabb;
pub use camera::Camera;
pub(crate) use clip::Polygon;
pub(crate) use ray::RayInv;
#[cfg(test)]
pub(crate) use ray::SLAB_ROBUST;
pub use ray::{Hit, Ray, TraceCounters, WorkloadKind};
pub(crate) use triangle::{closer_hit, cull_bound, tie_margin};
pub use triangle::{hits_agree, intersect_triangle, Triangle};
