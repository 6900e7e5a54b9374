//! Synthetic scenes for tests, benchmarks and the failure study.
