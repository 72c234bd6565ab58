//! Import OBJ, glTF/GLB and PLY meshes, and elevation grids (ESRI ASCII, GeoTIFF, SRTM .hgt,
//! heightmap PNG), into a cleaned [`Mesh`].
//!
//! The formats are the rows of [`IMPORTERS`]. Each format module reads its file into a [`Raw`] mesh
//! (positions not yet welded, corner arrays filled or empty, and the file's units if it states
//! them); [`import_with`] then refuses unusable positions (NaN, infinite, or beyond
//! [`crate::mesh::MAX_COORDINATE`]), replaces NaN or infinite normals and UVs with a warning, welds
//! and cleans the mesh, and reports what cleaning removed.

pub mod asc;
pub mod geotiff;
pub mod gltf;
pub mod heightfield;
pub mod heightmap_png;
pub mod hgt;
pub mod obj;
mod obj_stream;
pub mod ply;
pub mod stream;

use crate::error::{Error, Result};
use crate::format::Georef;
use crate::mesh::{coordinate_problem, triangle_cross, CleanReport, Mesh};
use crate::texture::SourceImage;
use glam::{Vec2, Vec3};
pub use heightfield::{DemCrs, DemEncoding, DemOptions, GridSummary};
use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use std::time::Instant;

/// A mesh file format strata reads: its name on the command line, the file name extensions that
/// select it, and its reader. Adding a format is one row of [`IMPORTERS`] and one module.
pub struct Importer {
    /// As `--format` takes it.
    pub name: &'static str,
    /// Lower-case, without the dot.
    pub extensions: &'static [&'static str],
    pub read: fn(&Path, &ImportOptions, &mut Vec<String>) -> Result<Raw>,
    /// Its streaming reader, for the partitioned build, if it has one.
    pub stream: Option<stream::Streaming>,
}

/// Every format strata reads.
pub static IMPORTERS: &[Importer] = &[
    Importer {
        name: "obj",
        extensions: &["obj"],
        read: obj::read,
        stream: Some(stream::Streaming { declared: obj_stream::declared, stream: obj_stream::stream }),
    },
    Importer {
        name: "gltf",
        extensions: &["gltf", "glb"],
        read: gltf::read,
        stream: Some(stream::Streaming { declared: gltf::streaming_declared, stream: gltf::stream }),
    },
    Importer {
        name: "ply",
        extensions: &["ply"],
        read: ply::read,
        stream: Some(stream::Streaming { declared: ply::streaming_declared, stream: ply::stream }),
    },
    Importer { name: "asc", extensions: &["asc"], read: asc::read, stream: None },
    Importer { name: "geotiff", extensions: &["tif", "tiff"], read: geotiff::read, stream: None },
    Importer { name: "hgt", extensions: &["hgt"], read: hgt::read, stream: None },
    Importer { name: "png", extensions: &["png"], read: heightmap_png::read, stream: None },
];

/// What a format's reader makes of a file: the raw mesh (positions not yet welded, corner arrays
/// filled or empty) and what the file says of where the model sits in the world.
#[derive(Clone, Debug)]
pub struct Raw {
    pub mesh: Mesh,
    /// Metres per model unit when the file says (glTF is in metres); `None` when it does not.
    pub metres_per_unit: Option<f64>,
    /// Where the model sits on Earth: elevation grids have one (spec §5.2).
    pub georef: Option<Georef>,
    /// What an elevation grid held.
    pub grid: Option<GridSummary>,
}

/// One of the [`IMPORTERS`].
#[derive(Clone, Copy)]
pub struct Format(&'static Importer);

impl Format {
    /// The format a file name's extension selects (`.gltf` and `.glb` are both glTF).
    pub fn from_path(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        IMPORTERS.iter().find(|i| i.extensions.contains(&ext.as_str())).map(Format)
    }

    /// The format named `name` (`obj`, `gltf`, `ply`).
    pub fn by_name(name: &str) -> Option<Format> {
        IMPORTERS.iter().find(|i| i.name.eq_ignore_ascii_case(name)).map(Format)
    }

    pub fn name(self) -> &'static str {
        self.0.name
    }

    /// Its streaming reader, for the partitioned build, if it has one.
    pub fn streaming(self) -> Option<&'static stream::Streaming> {
        self.0.stream.as_ref()
    }

    /// The names of the formats that have a streaming reader, for messages: `OBJ and PLY`.
    pub fn streaming_list() -> String {
        let names: Vec<String> = IMPORTERS.iter().filter(|i| i.stream.is_some()).map(|i| i.name.to_ascii_uppercase()).collect();
        match names.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
            _ => names.join(""),
        }
    }

    /// The formats' extensions as a list for messages: `.obj, .gltf, .glb or .ply`.
    pub fn extension_list() -> String {
        let all: Vec<String> = IMPORTERS.iter().flat_map(|i| i.extensions.iter().map(|e| format!(".{e}"))).collect();
        match all.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => all.join(""),
        }
    }
}

impl PartialEq for Format {
    fn eq(&self, other: &Format) -> bool {
        std::ptr::eq(self.0, other.0)
    }
}

impl Eq for Format {}

impl std::fmt::Debug for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.0.name)
    }
}

impl std::str::FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Format, String> {
        Format::by_name(s).ok_or_else(|| {
            let names: Vec<&str> = IMPORTERS.iter().map(|i| i.name).collect();
            format!("unknown format '{s}': strata reads {}", names.join(", "))
        })
    }
}

/// How to import a file.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImportOptions {
    /// Read as this format whatever the extension.
    pub format: Option<Format>,
    /// Let a glTF file read buffers outside its own folder (an absolute path, or `..` climbing
    /// above the folder, in a buffer uri). Off by default, so that a model from elsewhere cannot
    /// make strata read other files.
    pub allow_outside_files: bool,
    /// How elevation grids are read.
    pub dem: DemOptions,
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
    /// Metres per model unit when the file says; `None` when it does not (OBJ, PLY).
    pub metres_per_unit: Option<f64>,
    /// Where the model sits on Earth, for an elevation grid.
    pub georef: Option<Georef>,
    /// What an elevation grid held: size, voids, height range.
    pub grid: Option<GridSummary>,
    /// Wall-clock time of reading and cleaning, in milliseconds.
    pub import_ms: f64,
}

/// The regular file at `path`, open, and its length. Devices, pipes and folders are refused:
/// `/dev/zero` never ends and a pipe may never answer.
fn open_regular_io(path: &Path) -> std::io::Result<(std::fs::File, u64)> {
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a regular file"));
    }
    Ok((file, meta.len()))
}

/// [`open_regular_io`] for readers that stream a file: errors name `path`.
fn open_regular(path: &Path) -> Result<(std::fs::File, u64)> {
    open_regular_io(path).map_err(|e| Error::io(path, e))
}

/// Read at most `max_len` bytes of the regular file at `path` (see [`open_regular_io`]).
pub(crate) fn read_regular_file(path: &Path, max_len: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let (file, len) = open_regular_io(path)?;
    let mut bytes = Vec::with_capacity(len.min(max_len) as usize);
    file.take(max_len).read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Read a whole mesh file. An empty one is an error that says so, rather than whatever its
/// format's parser makes of no bytes.
fn read_file(path: &Path) -> Result<Vec<u8>> {
    let bytes = read_regular_file(path, u64::MAX).map_err(|e| Error::io(path, e))?;
    if bytes.is_empty() {
        return Err(Error::invalid(path, None, EMPTY));
    }
    Ok(bytes)
}

pub(super) const EMPTY: &str = "the file is empty (0 bytes)";

/// If `bytes` look like UTF-16 text, an error message saying so: they start with a UTF-16 byte
/// order mark, or have NUL in every other byte, as ASCII text saved as UTF-16 without a mark does.
/// Text formats are read as UTF-8 (or ASCII), where neither can occur.
fn utf16_hint(bytes: &[u8]) -> Option<String> {
    let why = match bytes {
        [0xff, 0xfe, ..] => "it starts with the UTF-16 little-endian byte order mark FF FE".to_string(),
        [0xfe, 0xff, ..] => "it starts with the UTF-16 big-endian byte order mark FE FF".to_string(),
        _ => {
            let sample = &bytes[..bytes.len().min(1024) & !1];
            let pairs = sample.len() / 2;
            let nul = |parity: usize| sample.iter().skip(parity).step_by(2).filter(|&&b| b == 0).count();
            let (even, odd) = (nul(0), nul(1));
            if pairs < 2 || even.min(odd) * 4 > pairs || even.max(odd) * 4 < 3 * pairs {
                return None;
            }
            format!("{} of its first {} bytes are NUL, every other one", even + odd, sample.len())
        }
    };
    Some(format!("the file looks UTF-16 encoded ({why}); strata reads text as UTF-8: re-save it as UTF-8"))
}

/// Read a mesh file with default options, choosing the format by extension unless `format` is given.
pub fn import(path: &Path, format: Option<Format>) -> Result<Imported> {
    import_with(path, &ImportOptions { format, ..ImportOptions::default() })
}

/// Read a mesh file, choosing the format by extension unless the options give one.
pub fn import_with(path: &Path, options: &ImportOptions) -> Result<Imported> {
    let start = Instant::now();
    crate::atomic::protect(path);
    let Some(format) = options.format.or_else(|| Format::from_path(path)) else {
        return Err(Error::invalid(path, None, format!("unknown mesh format: use a {} file, or --format", Format::extension_list())));
    };
    let mut warnings = Vec::new();
    let Raw { mesh: mut raw, metres_per_unit, georef, grid } = (format.0.read)(path, options, &mut warnings)?;
    if let Err(e) = raw.validate() {
        return Err(Error::invalid(path, None, format!("internal import error: {e}")));
    }
    // Readers check positions where they can name a line or primitive; this catches the rest.
    for (i, p) in raw.positions.iter().enumerate() {
        if let Some(problem) = coordinate_problem(p.as_dvec3().to_array()) {
            return Err(Error::at_element(path, format!("vertex {i}"), problem));
        }
    }
    replace_unusable_corners(&mut raw, &mut warnings);
    let source_faces = raw.face_count();
    let (mesh, cleaned) = raw
        .clean_known(grid.is_some())
        .map_err(|e| Error::at_element(path, format!("vertex {}", e.index), "coordinate is NaN or infinite"))?;
    if mesh.triangles.is_empty() {
        return Err(Error::invalid(path, None, "no faces left: the file holds no usable triangles"));
    }
    Ok(Imported { mesh, source_faces, cleaned, warnings, metres_per_unit, georef, grid, import_ms: start.elapsed().as_secs_f64() * 1e3 })
}

/// The largest UV coordinate kept, in magnitude: from 2^24 on an f32 holds even integers alone,
/// which place nothing within a texture, and the format's UV steps end not far beyond.
pub(crate) const MAX_UV: f32 = 16_777_216.0;

/// Whether a UV places a texture: finite and below [`MAX_UV`] in magnitude.
pub(crate) fn usable_uv(uv: Vec2) -> bool {
    uv.is_finite() && uv.abs().max_element() < MAX_UV
}

/// Replace NaN or infinite corner normals by their face's normal and unusable UVs (see
/// [`usable_uv`]) by (0, 0), with a warning per attribute. Unlike a position, neither shapes the
/// mesh: a normal follows from the positions (writers emit NaN ones for degenerate faces), and a UV
/// only places a texture, so the file stays usable, and the warning says what changed.
fn replace_unusable_corners(mesh: &mut Mesh, warnings: &mut Vec<String>) {
    let (mut normals, mut uvs) = (0, 0);
    for (f, t) in mesh.triangles.iter().enumerate() {
        let corners = 3 * f..3 * f + 3;
        let n = mesh.normals.get_mut(corners.clone()).unwrap_or_default();
        let (a, b) = replace_unusable_face_corners(&mesh.positions, t, n, mesh.uvs.get_mut(corners).unwrap_or_default());
        (normals, uvs) = (normals + a, uvs + b);
    }
    replaced_corners_warnings(normals, uvs, warnings);
}

/// [`replace_unusable_corners`] for the corners of one face `t`: its `normals` and `uvs` (each
/// three, or none); returns how many of each it replaced.
pub(crate) fn replace_unusable_face_corners(positions: &[Vec3], t: &[u32; 3], normals: &mut [Vec3], uvs: &mut [Vec2]) -> (u64, u64) {
    let (mut replaced_normals, mut replaced_uvs) = (0, 0);
    if normals.iter().any(|n| !n.is_finite()) {
        let face = triangle_cross(positions, t).normalize_or_zero().as_vec3();
        for n in normals.iter_mut().filter(|n| !n.is_finite()) {
            *n = face;
            replaced_normals += 1;
        }
    }
    for uv in uvs.iter_mut().filter(|uv| !usable_uv(**uv)) {
        *uv = Vec2::ZERO;
        replaced_uvs += 1;
    }
    (replaced_normals, replaced_uvs)
}

/// The warnings for `normals` corner normals and `uvs` corner UVs replaced on import.
pub(crate) fn replaced_corners_warnings(normals: u64, uvs: u64, warnings: &mut Vec<String>) {
    match normals {
        0 => {}
        1 => warnings.push("1 corner normal was NaN or infinite and got its face's normal".into()),
        n => warnings.push(format!("{n} corner normals were NaN or infinite and got their face's normal")),
    }
    match uvs {
        0 => {}
        1 => warnings.push("1 corner UV was NaN, infinite or at least 2^24 in magnitude and got UV (0, 0)".into()),
        n => warnings.push(format!("{n} corner UVs were NaN, infinite or at least 2^24 in magnitude and got UV (0, 0)")),
    }
}

/// Whether a relative file name stays inside the folder it is resolved against, by its text alone:
/// no root or drive, and no `..` that climbs above the folder. Links inside the folder are
/// followed: placing them there is the folder owner's choice.
pub(crate) fn stays_inside(name: &Path) -> bool {
    let mut depth = 0usize;
    for part in name.components() {
        match part {
            Component::Prefix(_) | Component::RootDir => return false,
            Component::ParentDir => match depth.checked_sub(1) {
                Some(d) => depth = d,
                None => return false,
            },
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
        }
    }
    true
}

/// Image files importers have read, by resolved path, each into a mesh's images once.
#[derive(Default)]
pub(crate) struct ImageFiles {
    by_path: HashMap<PathBuf, Option<u32>>,
}

impl ImageFiles {
    /// The image `file` (relative to the model's folder `dir`: a library's folder joined with the
    /// map's path) names, read once into `mesh.images`; a warning and `None` when it is missing,
    /// unreadable, outside the model's folder without `allow_outside`, or neither PNG nor JPEG.
    pub(crate) fn load(
        &mut self,
        dir: &Path,
        file: &Path,
        allow_outside: bool,
        mesh: &mut Mesh,
        warnings: &mut Vec<String>,
    ) -> Option<u32> {
        file.file_name()?;
        let path = dir.join(file);
        if let Some(&known) = self.by_path.get(&path) {
            return known;
        }
        crate::atomic::protect(&path);
        let name = file.to_string_lossy().replace('\\', "/");
        let result = if !allow_outside && !stays_inside(file) {
            Err(format!("{name} lies outside the model's folder (--allow-outside-files reads it)"))
        } else {
            read_regular_file(&path, 1 << 30)
                .map_err(|e| format!("{}: {e}", path.display()))
                .and_then(|b| SourceImage::new(name.clone(), b).map_err(|e| format!("{}: {e}", path.display())))
        };
        let index = match result {
            Ok(image) => {
                mesh.images.push(image);
                Some(mesh.images.len() as u32 - 1)
            }
            Err(e) => {
                warnings.push(format!("texture left out: {e}"));
                None
            }
        };
        self.by_path.insert(path, index);
        index
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn utf16(text: &str, big: bool) -> Vec<u8> {
        text.encode_utf16().flat_map(|u| if big { u.to_be_bytes() } else { u.to_le_bytes() }).collect()
    }

    #[test]
    fn utf16_text_is_recognised_and_utf8_is_not() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        let marked = [[0xff, 0xfe].as_slice(), &utf16(text, false)].concat();
        assert!(utf16_hint(&marked).unwrap().contains("FF FE"));
        assert!(utf16_hint(&[0xfe, 0xff, 0, b'v']).unwrap().contains("FE FF"));
        for big in [false, true] {
            assert!(utf16_hint(&utf16(text, big)).unwrap().contains("NUL"), "{big}");
        }
        for plain in [text.as_bytes(), "ply\nformat ascii 1.0\n".as_bytes(), b"\0\0", b"", &[0u8; 64], &[7u8; 64]] {
            assert_eq!(utf16_hint(plain), None, "{plain:?}");
        }
    }

    #[test]
    fn unusable_normals_and_uvs_are_replaced_and_reported() {
        let mut mesh = Mesh {
            positions: vec![glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::Y],
            triangles: vec![[0, 1, 2], [0, 2, 1]],
            normals: vec![glam::Vec3::NAN, glam::Vec3::Z, glam::Vec3::Z, glam::Vec3::Z, glam::Vec3::INFINITY, glam::Vec3::X],
            uvs: vec![Vec2::ONE, Vec2::new(f32::NAN, 0.0), Vec2::ONE, Vec2::new(0.5, -1e20), Vec2::splat(16_777_215.0), Vec2::ONE],
            ..Mesh::default()
        };
        let mut warnings = Vec::new();
        replace_unusable_corners(&mut mesh, &mut warnings);
        assert_eq!(mesh.normals[0], glam::Vec3::Z);
        assert_eq!(mesh.normals[4], -glam::Vec3::Z);
        assert_eq!(mesh.normals[5], glam::Vec3::X);
        assert_eq!(mesh.uvs[1..5], [Vec2::ZERO, Vec2::ONE, Vec2::ZERO, Vec2::splat(16_777_215.0)]);
        assert_eq!(
            warnings,
            [
                "2 corner normals were NaN or infinite and got their face's normal",
                "2 corner UVs were NaN, infinite or at least 2^24 in magnitude and got UV (0, 0)",
            ]
        );
    }
}
