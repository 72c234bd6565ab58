//! Wavefront OBJ import through `tobj`.
//!
//! Polygons are fan-triangulated, every object and group lands in one mesh, `usemtl` names become
//! per-face material ids (a missing or broken .mtl only costs the colors, with a warning), and
//! per-corner normals, UVs (v flipped to glTF's convention, origin at the image's top left) and vertex colors come along when the file has them.
//!
//! tobj reports errors without a line number, takes a zero texture or normal index for a missing
//! one and, in builds with overflow checks, panics on a far-negative one. So the file is first
//! checked line by line here: the first malformed `v`/`vt`/`vn`/`f` line or out-of-range index is reported with
//! its line number, and tobj only ever sees input that passed.

use super::{ImportOptions, Raw};
use crate::error::{Error, Result};
use crate::format::{MapKind, TextureSlot, Wrap};
use crate::mesh::{coordinate_problem, Material, Mesh};
use glam::{Vec2, Vec3};
use std::borrow::Cow;
use std::cell::RefCell;
use std::collections::HashMap;
use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};

/// A material library name no file can have: tobj "loads" it from a leading virtual `mtllib` line,
/// which gives every `usemtl` name its own material id even when no .mtl defines it.
const USEMTL_TABLE: &str = "\0strata-usemtl-names";

/// Read an OBJ file into a raw, uncleaned mesh.
pub fn read(path: &Path, options: &ImportOptions, warnings: &mut Vec<String>) -> Result<Raw> {
    read_mesh(path, options, warnings).map(|mesh| Raw { mesh, metres_per_unit: None, georef: None, grid: None })
}

fn read_mesh(path: &Path, import: &ImportOptions, warnings: &mut Vec<String>) -> Result<Mesh> {
    let bytes = super::read_file(path)?;
    if let Some(why) = super::utf16_hint(&bytes) {
        return Err(Error::invalid(path, None, why));
    }
    let text = String::from_utf8_lossy(&bytes);
    if text.trim().is_empty() {
        return Err(Error::invalid(path, None, "the file holds only whitespace"));
    }
    let scan = scan(&text).map_err(|(line, what)| Error::at_line(path, line, what))?;
    if scan.faces == 0 {
        return Err(Error::invalid(path, None, format!("no faces: {} vertices but no `f` line with 3 or more vertices", scan.positions)));
    }
    scan.warn(warnings);

    let text = tobj_input(text, &scan);
    let prefix = if scan.usemtl_names.is_empty() { String::new() } else { format!("mtllib {USEMTL_TABLE}\n") };
    let mut reader = Cursor::new(prefix.as_bytes()).chain(Cursor::new(text.as_bytes()));

    let mtl_warnings = RefCell::new(Vec::<String>::new());
    // The folder of each loaded library (relative to the model's, as `mtllib` named it) and how
    // many materials it gave, in load order: texture paths are relative to their library's folder.
    let libraries = RefCell::new(Vec::<(PathBuf, usize)>::new());
    let dir = path.parent().unwrap_or(Path::new(""));
    let load_material_library = |lib: &Path| -> tobj::MTLLoadResult {
        if lib == Path::new(USEMTL_TABLE) {
            let materials: Vec<tobj::Material> =
                scan.usemtl_names.iter().map(|n| tobj::Material { name: n.clone(), ..Default::default() }).collect();
            let map = scan.usemtl_names.iter().enumerate().map(|(i, n)| (n.clone(), i)).collect();
            libraries.borrow_mut().push((PathBuf::new(), materials.len()));
            return Ok((materials, map));
        }
        let full = dir.join(lib);
        let result = load_library(&full);
        match &result {
            Err(e) => {
                let w = library_warning(&full, e);
                let mut ws = mtl_warnings.borrow_mut();
                if !ws.contains(&w) {
                    ws.push(w);
                }
            }
            Ok((m, _)) => libraries.borrow_mut().push((lib.parent().unwrap_or(Path::new("")).to_path_buf(), m.len())),
        }
        result
    };
    let options = tobj::LoadOptions { triangulate: true, single_index: false, ignore_points: true, ignore_lines: true };
    let (models, materials) = tobj::load_obj_buf(&mut reader, &options, load_material_library)
        .map_err(|e| Error::invalid(path, None, format!("OBJ parse error: {e}")))?;
    warnings.extend(mtl_warnings.into_inner());
    let materials = materials.unwrap_or_default();
    let (mut mesh, sources) = build_mesh(path, &scan, &models, &materials, warnings)?;
    let folders = libraries.into_inner();
    let folder_of = |tobj_id: usize| {
        let mut first = 0;
        folders.iter().find(|(_, n)| {
            first += n;
            tobj_id < first
        })
    };
    let mut images = super::ImageFiles::default();
    for (out, source) in sources.iter().enumerate() {
        let (Some(id), Some(m)) = (*source, source.and_then(|i| materials.get(i))) else { continue };
        let folder = folder_of(id).map_or(Path::new(""), |(f, _)| f.as_path());
        attach_maps(m, (dir, folder), import.allow_outside_files, &mut images, &mut mesh, out, warnings);
    }
    Ok(mesh)
}

/// A material library, only if a regular file: tobj reads a device such as /dev/zero without end.
pub(super) fn load_library(full: &Path) -> tobj::MTLLoadResult {
    if std::fs::metadata(full).is_ok_and(|m| !m.is_file()) {
        Err(tobj::LoadError::OpenFileFailed)
    } else {
        tobj::load_mtl(full)
    }
}

pub(super) fn library_warning(full: &Path, e: &tobj::LoadError) -> String {
    format!("material library {} not loaded ({e}); its materials get default colors", full.display())
}

/// The maps of library material `m` on `mesh.materials[out]`: base color, normal and emissive
/// images, named relative to the library's folder (`at.1`, itself relative to the model's folder
/// `at.0`), each file read once into `mesh.images`.
pub(super) fn attach_maps(
    m: &tobj::Material,
    at: (&Path, &Path),
    allow_outside: bool,
    images: &mut super::ImageFiles,
    mesh: &mut Mesh,
    out: usize,
    warnings: &mut Vec<String>,
) {
    let maps = [
        (MapKind::BaseColor, m.diffuse_texture.as_deref()),
        (MapKind::Normal, m.unknown_param.get("norm").map(String::as_str)),
        (MapKind::Emissive, m.unknown_param.get("map_Ke").map(String::as_str)),
    ];
    for (kind, statement) in maps {
        let Some(statement) = statement else { continue };
        let (file, clamp) = texture_file(statement);
        if let Some(image) = images.load(at.0, &at.1.join(&file), allow_outside, mesh, warnings) {
            let wrap = if clamp { Wrap::Clamp } else { Wrap::Repeat };
            mesh.materials[out].maps[kind as usize] = Some(TextureSlot { image, wrap: [wrap; 2] });
        }
    }
}

/// The file name of a map statement's value (`-s 1 1 1 -clamp on dir/file name.png`) and whether
/// it asks for clamping: options and their arguments skipped, backslashes read as separators.
fn texture_file(value: &str) -> (String, bool) {
    let words: Vec<&str> = value.split_ascii_whitespace().collect();
    let mut i = 0;
    let mut clamp = false;
    while i < words.len() && words[i].starts_with('-') && words[i].len() > 1 {
        let option = words[i];
        i += 1;
        // Arguments: numbers, on/off, or a channel letter (-imfchan r).
        let max = match option {
            "-o" | "-s" | "-t" => 3,
            "-mm" => 2,
            _ => 1,
        };
        let mut taken = 0;
        while taken < max && i < words.len() {
            let w = words[i];
            let argument = w.parse::<f64>().is_ok() || matches!(w, "on" | "off") || (option == "-imfchan" && w.len() == 1);
            if !argument {
                break;
            }
            if option == "-clamp" {
                clamp = w == "on";
            }
            i += 1;
            taken += 1;
        }
    }
    (words[i..].join(" ").replace('\\', "/"), clamp)
}

/// The text tobj gets: line elements (`l`), which its fan triangulation would turn into polygons,
/// blanked out, and colors dropped when only some vertices have them (tobj would misalign them).
fn tobj_input<'t>(text: Cow<'t, str>, scan: &Scan) -> Cow<'t, str> {
    let partial_colors = scan.colored > 0 && scan.colored < scan.positions;
    if scan.lines == 0 && !partial_colors {
        return text;
    }
    let mut out = String::with_capacity(text.len());
    for line in text.lines() {
        let mut words = line.split_ascii_whitespace();
        match words.next() {
            Some("l") => {}
            Some("v") if partial_colors => {
                out.push('v');
                for w in words.take(3) {
                    out.push(' ');
                    out.push_str(w);
                }
            }
            _ => out.push_str(line),
        }
        out.push('\n');
    }
    Cow::Owned(out)
}

/// What the line check learned about the file.
#[derive(Debug, Default)]
struct Scan {
    positions: usize,
    texcoords: usize,
    normals: usize,
    /// Vertices that carry an RGB color after their coordinates.
    colored: usize,
    /// `f` lines with at least 3 vertices.
    faces: usize,
    /// `f` lines with 1 or 2 vertices (points, lines), skipped.
    short_faces: usize,
    /// `l` lines, skipped.
    lines: usize,
    /// Face corners without a texture / normal index.
    corners_without_uv: usize,
    corners_without_normal: usize,
    /// Distinct `usemtl` names, in order of first use.
    usemtl_names: Vec<String>,
}

impl Scan {
    fn warn(&self, warnings: &mut Vec<String>) {
        if self.short_faces > 0 {
            warnings.push(format!("{} faces with fewer than 3 vertices skipped", self.short_faces));
        }
        if self.lines > 0 {
            warnings.push(format!("{} line elements (`l`) skipped", self.lines));
        }
        if self.colored > 0 && self.colored < self.positions {
            warnings.push(format!("only {} of {} vertices have colors; vertex colors ignored", self.colored, self.positions));
        }
        if self.texcoords > 0 && self.corners_without_uv > 0 {
            warnings.push(format!("{} face corners have no texture index and reuse the previous corner's UV", self.corners_without_uv));
        }
        if self.normals > 0 && self.corners_without_normal > 0 {
            warnings
                .push(format!("{} face corners have no normal index and reuse the previous corner's normal", self.corners_without_normal));
        }
    }
}

/// A face index that points past the end of its array, found before the array's final length
/// is known (OBJ allows positive indices to vertices defined further down).
struct ForwardRef {
    line: usize,
    kind: usize,
    index: usize,
}

const KIND_NAMES: [&str; 3] = ["vertex", "texture coordinate", "normal"];
const KIND_PLURALS: [&str; 3] = ["vertices", "texture coordinates", "normals"];

/// A face index of `kind` (0 position, 1 texture coordinate, 2 normal) as written: an integer, not
/// 0, and when negative (relative) not reaching before the first of the `seen` above its line.
pub(super) fn face_index(part: &[u8], kind: usize, seen: usize) -> std::result::Result<i64, String> {
    let what = KIND_NAMES[kind];
    let index: i64 = std::str::from_utf8(part)
        .ok()
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| format!("face {what} index '{}' is not an integer", String::from_utf8_lossy(part)))?;
    if index == 0 {
        return Err(format!("face {what} index 0 (OBJ indices start at 1)"));
    }
    if index < 0 && index.unsigned_abs() > seen as u64 {
        return Err(format!("relative {what} index {index} reaches before the first of {seen} so far"));
    }
    Ok(index)
}

/// The message for a positive face `index` of `kind` past the file's `total`.
pub(super) fn out_of_range(kind: usize, index: i64, total: usize) -> String {
    let what = KIND_NAMES[kind];
    let counted = if total == 1 { what } else { KIND_PLURALS[kind] };
    format!("face {what} index {index} out of range: the file has {total} {counted}")
}

/// Check every line tobj would act on; on the first bad one return its 1-based number and what
/// is wrong with it.
fn scan(text: &str) -> std::result::Result<Scan, (usize, String)> {
    let mut s = Scan::default();
    let mut forward = Vec::<ForwardRef>::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let mut words = line.split_ascii_whitespace();
        match words.next() {
            Some("v") => {
                let mut xyz = [0f64; 3];
                for c in &mut xyz {
                    *c = number(words.next(), "v", "3 coordinates").map_err(|e| (n, e))?;
                }
                if let Some(problem) = coordinate_problem(xyz) {
                    return Err((n, problem));
                }
                let rest = [words.next(), words.next(), words.next(), words.next()];
                match rest {
                    [None, ..] => {}
                    [Some(w), None, ..] => {
                        if number::<f32>(Some(w), "v", "a w weight").map_err(|e| (n, e))? == 0.0 {
                            return Err((n, "vertex weight w is 0".into()));
                        }
                    }
                    [Some(r), Some(g), Some(b), None] => {
                        for c in [r, g, b] {
                            number::<f32>(Some(c), "v", "an RGB color").map_err(|e| (n, e))?;
                        }
                        s.colored += 1;
                    }
                    _ => {
                        let k = 3 + rest.iter().flatten().count() + words.count();
                        return Err((n, format!("v has {k} numbers; expected 3, 4 (x y z w) or 6 (x y z r g b)")));
                    }
                }
                s.positions += 1;
            }
            Some("vt") => {
                for _ in 0..2 {
                    number::<f32>(words.next(), "vt", "2 coordinates").map_err(|e| (n, e))?;
                }
                s.texcoords += 1;
            }
            Some("vn") => {
                for _ in 0..3 {
                    number::<f32>(words.next(), "vn", "3 components").map_err(|e| (n, e))?;
                }
                s.normals += 1;
            }
            Some("f") => {
                let counts = [s.positions, s.texcoords, s.normals];
                let mut corners = 0;
                for token in words {
                    let mut split = token.split('/');
                    let parts = [split.next(), split.next(), split.next()];
                    if split.next().is_some() {
                        return Err((n, format!("face vertex '{token}' has more than 3 '/'-separated indices")));
                    }
                    if parts[0].is_none_or(str::is_empty) {
                        return Err((n, format!("face vertex '{token}' has no position index")));
                    }
                    for (kind, part) in parts.iter().enumerate() {
                        let Some(part) = part.filter(|p| !p.is_empty()) else { continue };
                        let index = face_index(part.as_bytes(), kind, counts[kind]).map_err(|e| (n, e))?;
                        if index > 0 && index as u64 > counts[kind] as u64 {
                            forward.push(ForwardRef { line: n, kind, index: index as usize });
                        }
                    }
                    s.corners_without_uv += usize::from(parts[1].is_none_or(str::is_empty));
                    s.corners_without_normal += usize::from(parts[2].is_none_or(str::is_empty));
                    corners += 1;
                }
                match corners {
                    0 => return Err((n, "face with no vertices".into())),
                    1 | 2 => s.short_faces += 1,
                    _ => s.faces += 1,
                }
            }
            Some("l") => s.lines += 1,
            Some("usemtl") => {
                // The name as tobj reads it: everything after the line's first space.
                let name = line.split_once(' ').map_or("", |(_, rest)| rest).trim();
                if name.is_empty() {
                    return Err((n, "usemtl without a material name".into()));
                }
                if !s.usemtl_names.iter().any(|m| m == name) {
                    s.usemtl_names.push(name.to_string());
                }
            }
            _ => {}
        }
    }
    let totals = [s.positions, s.texcoords, s.normals];
    if let Some(f) = forward.iter().find(|f| f.index > totals[f.kind]) {
        return Err((f.line, out_of_range(f.kind, f.index as i64, totals[f.kind])));
    }
    Ok(s)
}

/// Parse one number of a `v`/`vt`/`vn` line, or say what was expected.
fn number<T: std::str::FromStr>(word: Option<&str>, element: &str, expected: &str) -> std::result::Result<T, String> {
    match word {
        None => Err(format!("{element} needs {expected}")),
        Some(w) => w.parse().map_err(|_| format!("{element}: '{w}' is not a number")),
    }
}

/// Concatenate tobj's models into one mesh, checking every index tobj produced.
/// The mesh, and for each of its materials the tobj material it came from.
fn build_mesh(
    path: &Path,
    scan: &Scan,
    models: &[tobj::Model],
    materials: &[tobj::Material],
    warnings: &mut Vec<String>,
) -> Result<(Mesh, Vec<Option<usize>>)> {
    let bad =
        |model: &str, what: &str| Error::at_element(path, format!("object '{model}'"), format!("inconsistent {what} from the OBJ parser"));
    let faces: usize = models.iter().map(|m| m.mesh.indices.len() / 3).sum();
    let with_normals = scan.normals > 0;
    let with_uvs = scan.texcoords > 0;
    let with_colors = scan.colored > 0 && scan.colored == scan.positions;
    let mut mesh = Mesh {
        triangles: Vec::with_capacity(faces),
        normals: Vec::with_capacity(if with_normals { 3 * faces } else { 0 }),
        uvs: Vec::with_capacity(if with_uvs { 3 * faces } else { 0 }),
        colors: Vec::with_capacity(if with_colors { 3 * faces } else { 0 }),
        face_materials: Vec::with_capacity(faces),
        ..Mesh::default()
    };
    // Output material id per tobj material id (None = no usemtl), in order of first use.
    let mut material_ids: HashMap<Option<usize>, u32> = HashMap::new();
    let mut sources = Vec::new();
    let mut undefined = Vec::<&str>::new();

    for model in models {
        let m = &model.mesh;
        let name = model.name.as_str();
        if m.indices.len() % 3 != 0 || m.positions.len() % 3 != 0 {
            return Err(bad(name, "triangle list"));
        }
        let vertex_count = m.positions.len() / 3;
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(m.positions.chunks_exact(3).map(Vec3::from_slice));
        for t in m.indices.chunks_exact(3) {
            if t.iter().any(|&v| v as usize >= vertex_count) {
                return Err(bad(name, "vertex index"));
            }
            mesh.triangles.push([base + t[0], base + t[1], base + t[2]]);
        }
        if with_normals {
            if m.normal_indices.len() != m.indices.len() {
                return Err(bad(name, "normal indices"));
            }
            for &k in &m.normal_indices {
                let k = 3 * k as usize;
                let n = m.normals.get(k..k + 3).ok_or_else(|| bad(name, "normal index"))?;
                mesh.normals.push(Vec3::from_slice(n));
            }
        }
        if with_uvs {
            if m.texcoord_indices.len() != m.indices.len() {
                return Err(bad(name, "texture coordinate indices"));
            }
            for &k in &m.texcoord_indices {
                let k = 2 * k as usize;
                let uv = m.texcoords.get(k..k + 2).ok_or_else(|| bad(name, "texture coordinate index"))?;
                mesh.uvs.push(Vec2::new(uv[0], 1.0 - uv[1]));
            }
        }
        if with_colors {
            for &v in &m.indices {
                let k = 3 * v as usize;
                let c = m.vertex_color.get(k..k + 3).ok_or_else(|| bad(name, "vertex colors"))?;
                mesh.colors.push([unit_to_u8(c[0]), unit_to_u8(c[1]), unit_to_u8(c[2]), 255]);
            }
        }

        let next = material_ids.len() as u32;
        let id = *material_ids.entry(m.material_id).or_insert_with(|| {
            let material = match m.material_id.and_then(|i| materials.get(i)) {
                None => Material::default(),
                Some(t) => {
                    if m.material_id.is_some_and(|i| i < scan.usemtl_names.len()) {
                        undefined.push(&t.name);
                    }
                    material_from(t)
                }
            };
            mesh.materials.push(material);
            sources.push(m.material_id.filter(|&i| i < materials.len()));
            next
        });
        mesh.face_materials.extend(std::iter::repeat_n(id, m.indices.len() / 3));
    }
    if !undefined.is_empty() {
        warnings.push(format!("materials without a definition in any loaded .mtl: {}", undefined.join(", ")));
    }
    Ok((mesh, sources))
}

pub(super) fn material_from(t: &tobj::Material) -> Material {
    let default = Material::default();
    let [r, g, b] = t.diffuse.unwrap_or([default.base_color[0], default.base_color[1], default.base_color[2]]);
    Material {
        name: t.name.clone(),
        base_color: [r, g, b, t.dissolve.unwrap_or(1.0)],
        texture: t.diffuse_texture.clone(),
        ..Material::default()
    }
}

pub(super) fn unit_to_u8(c: f32) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0).round() as u8
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Location;
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A fresh directory under the system temp dir holding `files` (name, contents); removed on drop.
    struct TempDir(PathBuf);

    impl TempDir {
        fn with(files: &[(&str, &str)]) -> Self {
            static NEXT: AtomicUsize = AtomicUsize::new(0);
            let dir = std::env::temp_dir().join(format!("strata-obj-test-{}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)));
            std::fs::create_dir_all(&dir).unwrap();
            for (name, text) in files {
                std::fs::write(dir.join(name), text).unwrap();
            }
            TempDir(dir)
        }

        fn read(&self, name: &str) -> (Result<Mesh>, Vec<String>) {
            let mut warnings = Vec::new();
            let mesh = read_mesh(&self.0.join(name), &ImportOptions::default(), &mut warnings);
            (mesh, warnings)
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    fn read_str(text: &str) -> (Result<Mesh>, Vec<String>) {
        TempDir::with(&[("m.obj", text)]).read("m.obj")
    }

    fn ok(text: &str) -> Mesh {
        let mesh = read_str(text).0.unwrap();
        mesh.validate().unwrap();
        mesh
    }

    fn error_line(text: &str) -> (usize, String) {
        match read_str(text).0 {
            Err(e @ Error::Invalid { .. }) => match e.location() {
                Some(Location::Line(n)) => (*n, e.to_string()),
                _ => panic!("error without a line: {e}"),
            },
            other => panic!("expected an error, got {other:?}"),
        }
    }

    /// The corner positions of every triangle, so tests need not know tobj's vertex order.
    fn corners(mesh: &Mesh) -> Vec<[[f32; 3]; 3]> {
        mesh.triangles.iter().map(|t| t.map(|v| mesh.positions[v as usize].to_array())).collect()
    }

    const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 1.5 0\n";

    #[test]
    fn quads_and_ngons_are_fan_triangulated() {
        let mesh = ok(&format!("{SQUARE}f 1 2 3 4\nf 1 2 3 5 4\n"));
        let p = |i: usize| {
            let v: Vec<f32> = SQUARE.lines().nth(i - 1).unwrap()[2..].split(' ').map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        };
        let expected = vec![[p(1), p(2), p(3)], [p(1), p(3), p(4)], [p(1), p(2), p(3)], [p(1), p(3), p(5)], [p(1), p(5), p(4)]];
        assert_eq!(corners(&mesh), expected);
        assert!(mesh.normals.is_empty() && mesh.uvs.is_empty() && mesh.colors.is_empty());
    }

    #[test]
    fn negative_indices_are_relative_to_the_vertices_so_far() {
        let relative = ok(&format!("{SQUARE}f -5 -4 -3 -2\nv 9 9 9\nf -1 -6 -5\n"));
        let absolute = ok(&format!("{SQUARE}f 1 2 3 4\nv 9 9 9\nf 6 1 2\n"));
        assert_eq!(corners(&relative), corners(&absolute));
        assert_eq!(relative.face_count(), 3);
    }

    #[test]
    fn objects_and_groups_merge_into_one_mesh() {
        let mesh = ok(&format!("{SQUARE}o first\nf 1 2 3\ng second\nf 1 3 4\no third\ng\nf 2 3 5\n"));
        assert_eq!(mesh.face_count(), 3);
        assert_eq!(corners(&mesh)[2], [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.5, 1.5, 0.0]]);
    }

    #[test]
    fn faces_may_come_before_their_vertices() {
        let mesh = ok(&format!("f 1 2 3\n{SQUARE}"));
        assert_eq!(corners(&mesh), vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]]);
    }

    #[test]
    fn corner_normals_uvs_and_colors() {
        let text = "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nvn 0 0 -1\n\
                    f 1/1/1 2/2/1 3/3/2\nf 3/1/2 2/3/1 1/2/1\n";
        let mesh = ok(text);
        assert_eq!(mesh.face_count(), 2);
        let z = Vec3::Z;
        assert_eq!(mesh.normals, vec![z, z, -z, -z, z, z]);
        // v flipped: OBJ's runs up the image, strata's (glTF's) down.
        let uv = |u, v: f32| Vec2::new(u, 1.0 - v);
        assert_eq!(mesh.uvs, vec![uv(0., 0.), uv(1., 0.), uv(0., 1.), uv(0., 0.), uv(0., 1.), uv(1., 0.)]);
        let (r, g, b) = ([255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]);
        assert_eq!(mesh.colors, vec![r, g, b, b, g, r]);
    }

    #[test]
    fn colors_on_only_some_vertices_are_dropped() {
        let (mesh, warnings) = read_str("v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0 0 0 1\nf 1 2 3\n");
        let mesh = mesh.unwrap();
        assert!(mesh.colors.is_empty());
        assert_eq!(mesh.positions, vec![Vec3::ZERO, Vec3::X, Vec3::Y]);
        assert!(warnings[0].contains("only 2 of 3 vertices have colors"), "{warnings:?}");
    }

    #[test]
    fn usemtl_with_mtl_gives_colors_and_textures() {
        let mtl = "newmtl red\nKd 1 0 0\nmap_Kd tex/red skin.png\nnewmtl blue\nKd 0 0 1\nd 0.5\n";
        let obj = format!("mtllib m.mtl\n{SQUARE}f 1 2 3\nusemtl red\nf 1 3 4\nusemtl blue\nf 2 3 5\nusemtl red\nf 1 2 5\n");
        let (mesh, warnings) = TempDir::with(&[("m.obj", &obj), ("m.mtl", mtl)]).read("m.obj");
        let mesh = mesh.unwrap();
        mesh.validate().unwrap();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].contains("texture left out") && warnings[0].contains("red skin.png"), "{warnings:?}");
        let names: Vec<&str> = mesh.face_materials.iter().map(|&m| mesh.materials[m as usize].name.as_str()).collect();
        assert_eq!(names, ["default", "red", "blue", "red"]);
        let red = &mesh.materials[mesh.face_materials[1] as usize];
        assert_eq!(red.base_color, [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(red.texture.as_deref(), Some("tex/red skin.png"));
        assert!(red.maps.iter().all(Option::is_none), "the missing image maps nothing");
        assert_eq!(mesh.materials[mesh.face_materials[2] as usize].base_color, [0.0, 0.0, 1.0, 0.5]);
    }

    #[test]
    fn map_statements_read_images_beside_the_library() {
        let png = crate::texture::encode(crate::texture::ImageCodec::Png, &crate::texture::Rgba8::new(4, 2), 90).unwrap();
        let mtl = "newmtl a\nmap_Kd -s 1 1 1 -clamp on tex\\a b.png\nnorm n.png\nnewmtl b\nmap_Kd tex/a b.png\nmap_Ke gone.png\n";
        let obj = format!("mtllib lib/m.mtl\n{SQUARE}usemtl a\nf 1 2 3\nusemtl b\nf 1 3 4\n");
        let dir = TempDir::with(&[("m.obj", &obj)]);
        std::fs::create_dir_all(dir.0.join("lib/tex")).unwrap();
        std::fs::write(dir.0.join("lib/m.mtl"), mtl).unwrap();
        std::fs::write(dir.0.join("lib/tex/a b.png"), &png).unwrap();
        std::fs::write(dir.0.join("lib/n.png"), b"not an image").unwrap();
        let (mesh, warnings) = dir.read("m.obj");
        let mesh = mesh.unwrap();
        assert_eq!(mesh.images.len(), 1, "one image, read once for both materials");
        assert_eq!(mesh.images[0].name, "lib/tex/a b.png");
        assert_eq!(&mesh.images[0].bytes[..], &png[..]);
        let (a, b) = (&mesh.materials[0], &mesh.materials[1]);
        assert_eq!(a.map(MapKind::BaseColor), Some(TextureSlot { image: 0, wrap: [Wrap::Clamp; 2] }));
        assert_eq!(b.map(MapKind::BaseColor), Some(TextureSlot { image: 0, wrap: [Wrap::Repeat; 2] }));
        assert_eq!((a.map(MapKind::Normal), b.map(MapKind::Emissive)), (None, None));
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(warnings.iter().any(|w| w.contains("n.png") && w.contains("neither a PNG nor a JPEG")), "{warnings:?}");
        assert!(warnings.iter().any(|w| w.contains("gone.png")), "{warnings:?}");
    }

    #[test]
    fn a_library_outside_the_folder_does_not_bring_images_from_there() {
        let png = crate::texture::encode(crate::texture::ImageCodec::Png, &crate::texture::Rgba8::new(2, 2), 90).unwrap();
        let dir = TempDir::with(&[]);
        std::fs::create_dir_all(dir.0.join("model")).unwrap();
        std::fs::create_dir_all(dir.0.join("secret")).unwrap();
        std::fs::write(dir.0.join("secret/lib.mtl"), "newmtl a\nmap_Kd secret.png\n").unwrap();
        std::fs::write(dir.0.join("secret/secret.png"), &png).unwrap();
        let obj = format!("mtllib ../secret/lib.mtl\n{SQUARE}usemtl a\nf 1 2 3\n");
        std::fs::write(dir.0.join("model/m.obj"), obj).unwrap();
        let (mesh, warnings) = dir.read("model/m.obj");
        let mesh = mesh.unwrap();
        assert!(mesh.images.is_empty());
        assert!(warnings.iter().any(|w| w.contains("outside the model's folder")), "{warnings:?}");
        let mut allowed = Vec::new();
        let opts = ImportOptions { allow_outside_files: true, ..ImportOptions::default() };
        let mesh = read_mesh(&dir.0.join("model/m.obj"), &opts, &mut allowed).unwrap();
        assert_eq!(mesh.images.len(), 1, "{allowed:?}");
    }

    #[test]
    fn map_options_are_skipped() {
        assert_eq!(texture_file("a.png"), ("a.png".into(), false));
        assert_eq!(texture_file("-bm 0.3 -o 0 0 -clamp on my file.jpg"), ("my file.jpg".into(), true));
        assert_eq!(texture_file("-imfchan r maps\\h.png"), ("maps/h.png".into(), false));
    }

    #[test]
    fn usemtl_without_mtl_keeps_materials_apart_and_warns() {
        for header in ["mtllib missing.mtl\n", ""] {
            let (mesh, warnings) = read_str(&format!("{header}{SQUARE}usemtl a\nf 1 2 3\nusemtl b\nf 1 3 4\nusemtl a\nf 2 3 5\n"));
            let mesh = mesh.unwrap();
            mesh.validate().unwrap();
            let names: Vec<&str> = mesh.face_materials.iter().map(|&m| mesh.materials[m as usize].name.as_str()).collect();
            assert_eq!(names, ["a", "b", "a"]);
            assert!(warnings.iter().any(|w| w.contains("a, b")), "{warnings:?}");
            if !header.is_empty() {
                assert!(warnings.iter().any(|w| w.contains("missing.mtl")), "{warnings:?}");
            }
        }
    }

    #[test]
    fn broken_mtl_is_a_warning() {
        let obj = format!("mtllib m.mtl\n{SQUARE}usemtl a\nf 1 2 3\n");
        let (mesh, warnings) = TempDir::with(&[("m.obj", &obj), ("m.mtl", "newmtl a\nKd 1 zero 0\n")]).read("m.obj");
        let mesh = mesh.unwrap();
        assert_eq!(mesh.materials[0].name, "a");
        assert!(warnings.iter().any(|w| w.contains("m.mtl")), "{warnings:?}");
    }

    #[test]
    fn lines_and_points_are_skipped_with_a_warning() {
        let (mesh, warnings) = read_str(&format!("{SQUARE}l 1 2 3 4\nf 1 2\nf 1 2 3\n"));
        assert_eq!(mesh.unwrap().face_count(), 1);
        assert_eq!(warnings.len(), 2, "{warnings:?}");
    }

    #[test]
    fn bad_lines_are_reported_with_their_line_number() {
        let cases: &[(&str, usize, &str)] = &[
            ("v 0 0 0\nv 1 0\nf 1 2 1\n", 2, "3 coordinates"),
            ("v 0 0 0\nv 1 0 zero\n", 2, "'zero' is not a number"),
            ("v 0 0 0\nv 1 0 0 0\n", 2, "weight w is 0"),
            ("v 0 0 0\nv 1 0 0 1 1\n", 2, "5 numbers"),
            ("v 0 0 0\nv nan 0 0\n", 2, "NaN"),
            ("# c\nvt 0.5\n", 2, "vt needs 2"),
            ("vn 0 1\n", 1, "vn needs 3"),
            (&format!("{SQUARE}f 1 2 0\n"), 6, "index 0"),
            (&format!("{SQUARE}f 1 2 x\n"), 6, "'x' is not an integer"),
            (&format!("{SQUARE}f 1 2 3\nf 1 2 9\nf 1 2 10\n"), 7, "vertex index 9 out of range"),
            (&format!("{SQUARE}f -6 1 2\n"), 6, "relative vertex index -6"),
            (&format!("{SQUARE}vt 0 0\nf 1/1 2/2 3/1\n"), 7, "texture coordinate index 2"),
            (&format!("{SQUARE}vt 0 0\nf 1/0 2/1 3/1\n"), 7, "texture coordinate index 0"),
            (&format!("{SQUARE}vt 0 0\nf 1/-2 2/1 3/1\n"), 7, "relative texture coordinate index -2"),
            (&format!("{SQUARE}vt 0 0\nf 1/-3 2/1 3/1\n"), 7, "relative texture coordinate index -3"),
            (&format!("{SQUARE}vn 0 0 1\nf 1//1 2//-9 3//1\n"), 7, "relative normal index -9"),
            (&format!("{SQUARE}vn 0 0 1\nf 1//1 2//1 3//0\n"), 7, "normal index 0"),
            (&format!("{SQUARE}f 1/1/1/1 2 3\n"), 6, "more than 3"),
            (&format!("{SQUARE}f /1 2 3\n"), 6, "no position index"),
            (&format!("{SQUARE}f\n"), 6, "no vertices"),
            (&format!("{SQUARE}usemtl\nf 1 2 3\n"), 6, "usemtl without"),
        ];
        for (text, line, what) in cases {
            let (got, message) = error_line(text);
            assert_eq!(got, *line, "{message}");
            assert!(message.contains(what), "{message} should mention {what}");
            assert!(message.contains("m.obj"), "{message}");
        }
    }

    #[test]
    fn empty_files_and_files_without_faces_are_errors() {
        for (text, what) in [("", "empty"), ("  \n# nothing\n", "no faces"), (SQUARE, "no faces")] {
            let e = read_str(text).0.unwrap_err().to_string();
            assert!(e.contains(what), "{e}");
        }
        let e = read_mesh(Path::new("/nonexistent/strata.obj"), &ImportOptions::default(), &mut Vec::new()).unwrap_err();
        assert!(matches!(e, Error::Io { .. }));
    }

    /// One face corner: a position index and optional texture and normal indices.
    fn corner() -> impl proptest::strategy::Strategy<Value = String> {
        use proptest::strategy::Strategy;
        let index = || proptest::sample::select(vec!["1", "2", "3", "-1", "-3", "-5", "0", "4", "x"]);
        (index(), index(), index(), 0..4usize).prop_map(|(v, t, n, form)| match form {
            0 => v.to_string(),
            1 => format!("{v}/{t}"),
            2 => format!("{v}//{n}"),
            _ => format!("{v}/{t}/{n}"),
        })
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(500))]

        /// Faces with arbitrary index combinations, after three vertices, two texture coordinates
        /// and a normal, never panic; what imports is a valid mesh.
        #[test]
        fn arbitrary_faces_never_panic(
            faces in proptest::collection::vec(proptest::collection::vec(corner(), 0..6), 1..4),
            other in proptest::sample::select(vec!["", "l 1 2 3", "v 1 2", "vt 0.5 0.5", "usemtl m", "o x", "f 1 2"]),
        ) {
            let body: String = faces.iter().map(|f| format!("f {}\n", f.join(" "))).collect();
            let text = format!("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 1\nvn 0 0 1\n{other}\n{body}");
            if let (Ok(mesh), _) = read_str(&text) {
                proptest::prop_assert!(mesh.validate().is_ok());
                proptest::prop_assert!(mesh.face_count() > 0);
            }
        }
    }
}
