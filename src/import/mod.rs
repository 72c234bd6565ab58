//! Import OBJ, glTF/GLB and PLY files into a cleaned [`Mesh`].
//!
//! Each format module reads its file into a raw `Mesh` (positions not yet welded, corner arrays
//! filled or empty); [`import_with`] then welds and cleans it, and reports what cleaning removed.

pub mod gltf;
pub mod obj;
pub mod ply;

use crate::error::{Error, Result};
use crate::mesh::{CleanReport, Mesh};
use std::path::Path;
use std::time::Instant;

/// A mesh file format strata reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Obj,
    Gltf,
    Ply,
}

impl Format {
    /// The format a file name's extension implies (`.gltf` and `.glb` are both glTF).
    pub fn from_path(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "obj" => Some(Format::Obj),
            "gltf" | "glb" => Some(Format::Gltf),
            "ply" => Some(Format::Ply),
            _ => None,
        }
    }
}

/// How to import a file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ImportOptions {
    /// Read as this format whatever the extension.
    pub format: Option<Format>,
    /// Let a glTF file read buffers outside its own folder (an absolute path, or `..` climbing
    /// above the folder, in a buffer uri). Off by default, so that a model from elsewhere cannot
    /// make strata read other files.
    pub allow_outside_files: bool,
}

/// An imported, cleaned mesh and what happened on the way.
#[derive(Clone, Debug)]
pub struct Imported {
    pub mesh: Mesh,
    /// Triangles read from the file, before cleaning.
    pub source_faces: usize,
    pub cleaned: CleanReport,
    /// Things that did not stop the import but that a user should know (a missing .mtl, skipped
    /// point primitives, ...).
    pub warnings: Vec<String>,
    /// Wall-clock time of reading and cleaning, in milliseconds.
    pub import_ms: f64,
}

/// Read a mesh file with default options, choosing the format by extension unless `format` is given.
pub fn import(path: &Path, format: Option<Format>) -> Result<Imported> {
    import_with(path, &ImportOptions { format, ..ImportOptions::default() })
}

/// Read a mesh file, choosing the format by extension unless the options give one.
pub fn import_with(path: &Path, options: &ImportOptions) -> Result<Imported> {
    let start = Instant::now();
    let format = match options.format.or_else(|| Format::from_path(path)) {
        Some(f) => f,
        None => {
            return Err(Error::invalid(path, None, "unknown mesh format: use a .obj, .gltf, .glb or .ply file, or --format"))
        }
    };
    let mut warnings = Vec::new();
    let raw = match format {
        Format::Obj => obj::read(path, &mut warnings)?,
        Format::Gltf => gltf::read(path, options, &mut warnings)?,
        Format::Ply => ply::read(path, &mut warnings)?,
    };
    if let Err(e) = raw.validate() {
        return Err(Error::invalid(path, None, format!("internal import error: {e}")));
    }
    let source_faces = raw.face_count();
    let (mesh, cleaned) = raw.clean().map_err(|e| {
        Error::at_element(path, format!("vertex {}", e.index), "coordinate is NaN or infinite")
    })?;
    if mesh.triangles.is_empty() {
        return Err(Error::invalid(path, None, "no faces left: the file holds no usable triangles"));
    }
    Ok(Imported { mesh, source_faces, cleaned, warnings, import_ms: start.elapsed().as_secs_f64() * 1e3 })
}
