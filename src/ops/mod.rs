//! GPU operations built on [`crate::gpu`]: each one owns its kernels, records into a [`Recorder`](crate::gpu::Recorder)
//! the engine may own, and has a convenience path that submits and waits.

mod bounds;
pub mod characterize;
pub mod features;
pub mod lbvh;
pub mod sort;

pub use bounds::{BoundsPush, PointBounds};
pub use sort::{KeyBits, RadixSort, SortBuffers, SortConfig, SortMemory, SortedIn};
