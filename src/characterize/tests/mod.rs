//! Tests of the characterization's internals: the host math against exact rational arithmetic (`host_math`) and
//! the device passes against a direct CPU computation of the same exact quantities (`gpu_passes`).

pub(crate) mod exact;
mod features_definition;
mod gpu_passes;
mod host_math;
