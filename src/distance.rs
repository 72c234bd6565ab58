//! Sampled symmetric surface distance between two meshes, for tests and benchmarks.
