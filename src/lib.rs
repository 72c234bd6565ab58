//! strata: preprocess a huge triangle mesh once into a hierarchical chunk file that a viewer
//! streams coarse-to-fine, reading only what it needs.
//!
//! Three layers, each using only those before it:
//!
//! 1. **The format** ([`mod@format`]): the chunk file alone — records, codecs, the lazy [`format::Reader`]
//!    over any [`format::ByteSource`], the rules every reader checks, `verify`, and the
//!    [`format::Writer`] that takes finished nodes. It depends on nothing of the build.
//! 2. **The build**, read top-down in [`pipeline`]: import ([`mod@import`]) → clean ([`mesh`]) → group by
//!    normal cone ([`cone`], [`group`], [`hierarchy`]) → simplify per level ([`levels`],
//!    [`simplify`]) → quantize ([`quantize`]), bound ([`bounds`]) and hand nodes to the writer
//!    ([`mod@write`]).
//! 3. **Viewing**: front selection, budgets and sessions over a file's skeleton ([`stream`]), the
//!    software renderer ([`render`]), one level back as a mesh ([`assemble`]), exports ([`export`]).
//!
//! The command line (`src/main.rs`, `src/cli/`) sits on top, behind the default `cli` feature.

pub mod assemble;
pub mod atomic;
pub mod bounds;
pub mod camera;
pub mod cone;
pub mod culling;
pub mod dag;
pub mod derived_normals;
pub mod distance;
pub mod error;
pub mod export;
pub mod fixtures;
pub mod format;
pub mod fuzzing;
pub mod geodesy;
pub mod group;
pub mod hierarchy;
pub mod import;
pub mod levels;
pub mod mesh;
pub mod normals;
pub mod partition;
pub mod pipeline;
pub mod quantize;
pub mod render;
pub mod simplify;
pub mod small_components;
pub mod stream;
pub mod texture;
pub mod write;

pub use error::{Error, Location, Result};
pub use import::{import, import_with, Format, ImportOptions, Imported};
pub use mesh::{Adjacency, CleanReport, Material, Mesh};
