//! Write meshes for other tools: OBJ, PLY (binary, with colors) and GLB, chosen by extension.
//! Every writer goes through [`crate::atomic::AtomicFile`], so no partial file is left behind.

pub mod glb;
pub mod obj;
pub mod ply;

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use std::path::Path;

/// Write `mesh` to `path`, the format chosen by its extension (.obj, .ply, .glb).
pub fn write(path: &Path, _mesh: &Mesh) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        _ => Err(Error::invalid(path, None, "unknown output format: use .obj, .ply or .glb")),
    }
}
