//! strata: preprocess a huge triangle mesh once into a hierarchical chunk file that a viewer
//! streams coarse-to-fine, reading only what it needs.
//!
//! The pipeline, one module per stage:
//! import ([`import`]) → clean ([`mesh`]) → group by normal cone ([`cone`], [`group`], [`hierarchy`])
//! → simplify per level ([`simplify`]) → write the chunk file ([`format`]) → stream ([`stream`]).

pub mod atomic;
pub mod camera;
pub mod cone;
pub mod culling;
pub mod distance;
pub mod error;
pub mod export;
pub mod fixtures;
pub mod format;
pub mod fuzzing;
pub mod group;
pub mod hierarchy;
pub mod import;
pub mod levels;
pub mod mesh;
pub mod normals;
pub mod pipeline;
pub mod render;
pub mod simplify;
pub mod stream;

pub use error::{Error, Location, Result};
pub use import::{import, Format, Imported};
pub use mesh::{Adjacency, CleanReport, Material, Mesh};
