//! Deterministic procedural meshes for fixtures, tests and benchmarks.
