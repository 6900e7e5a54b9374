//! The characterization's device passes: the exact quantities of the characterization ([`passes`]: keys and
//! bounds, codes and exact power sums, classes and the histogram, the chi-square numerator) and the scene
//! features ([`features`]: occupied Morton cells and the triangle-size histogram). The host-side meaning of those
//! numbers lives in the parent module; the backend that drives them is [`super::vulkan`].

pub(crate) mod features;
pub(crate) mod passes;
