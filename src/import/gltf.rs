//! gltf import (placeholder until the reader lands).

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use std::path::Path;

/// Read a gltf file into a raw, uncleaned mesh.
pub fn read(path: &Path, _warnings: &mut Vec<String>) -> Result<Mesh> {
    Err(Error::invalid(path, None, "gltf import is not implemented yet"))
}
