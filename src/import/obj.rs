//! obj import (placeholder until the reader lands).

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use std::path::Path;

/// Read a obj file into a raw, uncleaned mesh.
pub fn read(path: &Path, _warnings: &mut Vec<String>) -> Result<Mesh> {
    Err(Error::invalid(path, None, "obj import is not implemented yet"))
}
