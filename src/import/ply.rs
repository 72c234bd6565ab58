//! ply import (placeholder until the reader lands).

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use std::path::Path;

/// Read a ply file into a raw, uncleaned mesh.
pub fn read(path: &Path, _warnings: &mut Vec<String>) -> Result<Mesh> {
    Err(Error::invalid(path, None, "ply import is not implemented yet"))
}
