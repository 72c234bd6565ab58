//! Streaming readers, for the partitioned build (`crate::partition`): the vertex arrays are held,
//! the faces are handed on in batches and never held whole. A format that has one names it in its
//! row of [`super::IMPORTERS`].

use super::ImportOptions;
use crate::error::Result;
use crate::mesh::Material;
use crate::texture::SourceImage;
use glam::{Vec2, Vec3};
use std::path::Path;

/// The vertex arrays a batch of faces indexes; `normals` and `colors` are empty or one per vertex.
pub struct Vertices<'a> {
    pub positions: &'a [Vec3],
    pub normals: &'a [Vec3],
    pub colors: &'a [[u8; 4]],
}

/// A batch of triangles, and their corners' normals where the file gives normals per face corner
/// (OBJ's `f v//vn`) rather than per vertex: then `normals[t]` holds triangle `t`'s three,
/// otherwise it is empty. The same for texture coordinates (`uvs`, in glTF's convention: v down),
/// and `materials[t]` is triangle `t`'s index into [`Looks::materials`] (empty: all 0). A file
/// gives each for every batch or for none.
pub struct Faces<'a> {
    pub triangles: &'a [[u32; 3]],
    pub normals: &'a [[Vec3; 3]],
    pub uvs: &'a [[Vec2; 3]],
    pub materials: &'a [u32],
}

/// What a stream gives besides its faces, once it has ended: the materials its faces name (empty:
/// one default material) and the images their maps index.
#[derive(Clone, Debug, Default)]
pub struct Looks {
    pub materials: Vec<Material>,
    pub images: Vec<SourceImage>,
}

/// Where a streaming reader hands its batches.
pub type FaceSink<'a> = dyn FnMut(&Vertices, &Faces) -> Result<()> + 'a;

/// Triangles per batch handed to a [`FaceSink`].
pub const BATCH: usize = 1 << 16;

/// What a file declares or a quick pass over it finds, before it is streamed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Declared {
    /// About how many triangles its faces make.
    pub triangles: u64,
    /// Why the partitioned build cannot stream it, if so.
    pub refused: Option<String>,
}

/// A format's streaming reader: what a file declares, and the stream itself, which fails with the
/// file and the line, byte or element on bad input, as the format's whole-file reader does, and
/// reads the files a model names (material libraries, images) under the same options.
pub struct Streaming {
    pub declared: fn(&Path) -> Result<Declared>,
    pub stream: fn(&Path, &ImportOptions, &mut FaceSink, &mut Vec<String>) -> Result<Looks>,
}
