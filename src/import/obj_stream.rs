//! Wavefront OBJ as a stream, for the partitioned build: two passes over the file, line by line.
//! The first holds the vertex positions (and their colors), the normals and the texture
//! coordinates, and notes the material libraries (`mtllib`) and material names (`usemtl`); the
//! second hands the faces on in batches, fan-triangulated as the whole-file reader does (`obj.rs`),
//! their indices resolved (positive ones may point further down the file, negative ones count back
//! from their line) and checked, each corner's normal and texture coordinates and each face's
//! material with it. Errors name the line. Materials are numbered in the order faces first use
//! them, with their maps' images read as the whole-file reader reads them; a name several
//! libraries define takes the last one's definition. Where the whole-file reader (tobj) differs:
//! it resolves a `usemtl` against the libraries loaded above it (a name used before its
//! `mtllib` line is undefined there, and a second material after it), and it starts the
//! fallbacks of corners without a normal or texture index again at each object and material run,
//! where the stream reuses the previous corner's across them. Vertices keep the file's order; the
//! whole-file reader's tobj numbers them per object (`o`, `g`), so for a file of several objects
//! the two builds number the same surface's vertices differently.

use super::stream::{Declared, FaceSink, Faces, Looks, Vertices, BATCH};
use super::ImportOptions;
use crate::error::{Error, Result};
use crate::mesh::{coordinate_problem, Material, Mesh};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::io::BufRead;
use std::path::Path;

/// Longest line read: a polygon of a million corners fits.
const MAX_LINE: u64 = 16 << 20;

/// Call `each` with every line of `path` (1-based number, bytes without the line end), after the
/// checks the whole-file reader makes first: not empty, not UTF-16.
fn lines(path: &Path, mut each: impl FnMut(usize, &[u8]) -> Result<()>) -> Result<()> {
    use std::io::Read as _;
    let (file, len) = super::open_regular(path)?;
    if len == 0 {
        return Err(Error::invalid(path, None, super::EMPTY));
    }
    let mut file = std::io::BufReader::with_capacity(1 << 20, file);
    let head = file.fill_buf().map_err(|e| Error::io(path, e))?;
    if let Some(why) = super::utf16_hint(&head[..head.len().min(1024)]) {
        return Err(Error::invalid(path, None, why));
    }
    let mut line = Vec::with_capacity(256);
    let mut n = 0;
    loop {
        line.clear();
        let read = (&mut file).take(MAX_LINE + 1).read_until(b'\n', &mut line).map_err(|e| Error::io(path, e))?;
        if read == 0 {
            return Ok(());
        }
        n += 1;
        if read as u64 > MAX_LINE {
            let cr = if line.contains(&b'\r') { " (its lines may end in CR alone, as old Mac files do)" } else { "" };
            return Err(Error::at_line(path, n, format!("a line longer than {} MiB{cr}", MAX_LINE >> 20)));
        }
        while line.last().is_some_and(|&b| b == b'\n' || b == b'\r') {
            line.pop();
        }
        each(n, &line)?;
    }
}

fn words(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace()).filter(|w| !w.is_empty())
}

fn text(word: &[u8]) -> std::borrow::Cow<'_, str> {
    String::from_utf8_lossy(word)
}

/// One number of a `v`/`vn` line, or what was expected.
fn number<T: std::str::FromStr>(word: Option<&[u8]>, element: &str, expected: &str) -> std::result::Result<T, String> {
    let w = word.ok_or_else(|| format!("{element} needs {expected}"))?;
    std::str::from_utf8(w).ok().and_then(|s| s.parse().ok()).ok_or_else(|| format!("{element}: '{}' is not a number", text(w)))
}

/// Faces of `f` lines with three or more corners make `corners − 2` triangles each.
pub fn declared(path: &Path) -> Result<Declared> {
    let mut triangles = 0u64;
    lines(path, |_, line| {
        let mut w = words(line);
        if w.next() == Some(b"f") {
            triangles += (w.count() as u64).saturating_sub(2);
        }
        Ok(())
    })?;
    Ok(Declared { triangles, refused: None })
}

/// What follows a statement's keyword as tobj reads it: everything after the line's first space
/// (not tab), trimmed (file and material names may hold spaces).
fn rest(line: &[u8]) -> String {
    String::from_utf8_lossy(line).split_once(' ').map_or("", |(_, r)| r).trim().to_string()
}

/// What the first pass holds.
#[derive(Default)]
struct Held {
    positions: Vec<Vec3>,
    colors: Vec<[u8; 4]>,
    /// Vertices with a color after their coordinates.
    colored: usize,
    /// Whether a vertex without a color came (then `colors` stops growing).
    uncolored: bool,
    normals: Vec<Vec3>,
    /// Texture coordinates, v flipped to glTF's convention as the whole-file reader does.
    uvs: Vec<Vec2>,
    /// `mtllib` names in file order.
    libraries: Vec<String>,
    /// Whether any `usemtl` line assigns a material.
    assigns: bool,
}

fn first_pass(path: &Path, warnings: &mut Vec<String>) -> Result<Held> {
    let mut h = Held::default();
    lines(path, |n, line| {
        let mut w = words(line);
        let bad = |e: String| Error::at_line(path, n, e);
        match w.next() {
            Some(b"v") => {
                // Checked in f64 as the whole-file reader checks them, stored as f32 parsed directly
                // as its reader (tobj) parses them.
                let xyz = [w.next(), w.next(), w.next()];
                let mut p = [0f32; 3];
                let mut check = [0f64; 3];
                for ((c, k), word) in p.iter_mut().zip(&mut check).zip(xyz) {
                    *k = number(word, "v", "3 coordinates").map_err(bad)?;
                    *c = number(word, "v", "3 coordinates").map_err(bad)?;
                }
                if let Some(problem) = coordinate_problem(check) {
                    return Err(bad(problem));
                }
                let rest = [w.next(), w.next(), w.next(), w.next()];
                match rest {
                    [None, ..] => h.uncolored = true,
                    [Some(weight), None, ..] => {
                        if number::<f32>(Some(weight), "v", "a w weight").map_err(bad)? == 0.0 {
                            return Err(bad("vertex weight w is 0".into()));
                        }
                        h.uncolored = true;
                    }
                    [Some(r), Some(g), Some(b), None] => {
                        let mut c = [0u8, 0, 0, 255];
                        for (slot, word) in c.iter_mut().zip([r, g, b]) {
                            *slot = super::obj::unit_to_u8(number(Some(word), "v", "an RGB color").map_err(bad)?);
                        }
                        // Colors are kept while every vertex so far has one.
                        if !h.uncolored {
                            h.colors.push(c);
                        }
                        h.colored += 1;
                    }
                    _ => {
                        let k = 3 + rest.iter().flatten().count() + w.count();
                        return Err(bad(format!("v has {k} numbers; expected 3, 4 (x y z w) or 6 (x y z r g b)")));
                    }
                }
                h.positions.push(Vec3::from_array(p));
            }
            Some(b"vn") => {
                let mut v = [0f32; 3];
                for c in &mut v {
                    *c = number::<f32>(w.next(), "vn", "3 components").map_err(bad)?;
                }
                h.normals.push(Vec3::from_array(v));
            }
            Some(b"vt") => {
                let u = number::<f32>(w.next(), "vt", "2 coordinates").map_err(bad)?;
                let v = number::<f32>(w.next(), "vt", "2 coordinates").map_err(bad)?;
                h.uvs.push(Vec2::new(u, 1.0 - v));
            }
            Some(b"usemtl") => h.assigns = true,
            Some(b"mtllib") => {
                let name = rest(line);
                // Every occurrence, as tobj loads each: a name's last definition wins.
                if !name.is_empty() {
                    h.libraries.push(name);
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    if h.colored < h.positions.len() {
        if h.colored > 0 {
            warnings.push(format!("only {} of {} vertices have colors; vertex colors ignored", h.colored, h.positions.len()));
        }
        h.colors = Vec::new();
    }
    Ok(h)
}

/// Read an OBJ file as a stream into `sink` (the module's doc says how), with the checks and
/// warnings of the whole-file reader.
pub fn stream(path: &Path, import: &ImportOptions, sink: &mut FaceSink, warnings: &mut Vec<String>) -> Result<Looks> {
    let held = first_pass(path, warnings)?;
    let vertices = Vertices { positions: &held.positions, normals: &[], colors: &held.colors };
    let with_normals = !held.normals.is_empty();
    let with_uvs = !held.uvs.is_empty();
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(BATCH);
    let mut corner_normals: Vec<[Vec3; 3]> = Vec::with_capacity(if with_normals { BATCH } else { 0 });
    let mut corner_uvs: Vec<[Vec2; 3]> = Vec::with_capacity(if with_uvs { BATCH } else { 0 });
    let mut face_materials: Vec<u32> = Vec::with_capacity(BATCH);
    // Vertices, texture coordinates and normals defined above the current line, for relative indices.
    let (mut seen_v, mut seen_vt, mut seen_vn) = (0usize, 0usize, 0usize);
    let (mut faces, mut short, mut segments, mut without_normal, mut without_uv) = (0u64, 0usize, 0usize, 0usize, 0usize);
    let mut last_normal = held.normals.first().copied().unwrap_or(Vec3::Z);
    let mut last_uv = held.uvs.first().copied().unwrap_or(Vec2::ZERO);
    let totals = [held.positions.len(), held.uvs.len(), held.normals.len()];
    let mut corners: Vec<(u32, Vec3, Vec2)> = Vec::new();
    let mut any_text = false;
    // Materials by first use: the name of each (None: faces before any `usemtl`), and the current one.
    let mut used: Vec<Option<String>> = Vec::new();
    let mut by_name: HashMap<Option<String>, u32> = HashMap::new();
    let mut current: Option<String> = None;
    let mut material = None::<u32>;
    lines(path, |n, line| {
        let mut w = words(line);
        let first = w.next();
        any_text |= !String::from_utf8_lossy(line).trim().is_empty();
        match first {
            Some(b"v") => seen_v += 1,
            Some(b"vt") => seen_vt += 1,
            Some(b"vn") => seen_vn += 1,
            Some(b"l") => segments += 1,
            Some(b"usemtl") => {
                let name = rest(line);
                if name.is_empty() {
                    return Err(Error::at_line(path, n, "usemtl without a material name"));
                }
                if current.as_ref() != Some(&name) {
                    current = Some(name);
                    material = None;
                }
            }
            Some(b"f") => {
                corners.clear();
                let seen = [seen_v, seen_vt, seen_vn];
                for token in w {
                    let mut parts = token.split(|&b| b == b'/');
                    let p = [parts.next(), parts.next(), parts.next()];
                    if parts.next().is_some() {
                        return Err(Error::at_line(
                            path,
                            n,
                            format!("face vertex '{}' has more than 3 '/'-separated indices", text(token)),
                        ));
                    }
                    if p[0].is_none_or(<[u8]>::is_empty) {
                        return Err(Error::at_line(path, n, format!("face vertex '{}' has no position index", text(token))));
                    }
                    let mut index = [None::<usize>; 3];
                    for (kind, part) in p.iter().enumerate() {
                        let Some(part) = part.filter(|p| !p.is_empty()) else { continue };
                        index[kind] = Some(resolve(part, kind, seen[kind], totals[kind]).map_err(|e| Error::at_line(path, n, e))?);
                    }
                    let v = index[0].unwrap_or(0);
                    let normal = match index[2] {
                        Some(k) => held.normals[k],
                        None => {
                            without_normal += 1;
                            last_normal
                        }
                    };
                    last_normal = normal;
                    let uv = match index[1] {
                        Some(k) => held.uvs[k],
                        None => {
                            without_uv += 1;
                            last_uv
                        }
                    };
                    last_uv = uv;
                    corners.push((v as u32, normal, uv));
                }
                match corners.len() {
                    0 => return Err(Error::at_line(path, n, "face with no vertices")),
                    1 | 2 => short += 1,
                    _ => faces += 1,
                }
                let id = *material.get_or_insert_with(|| {
                    *by_name.entry(current.clone()).or_insert_with(|| {
                        used.push(current.clone());
                        used.len() as u32 - 1
                    })
                });
                for k in 1..corners.len().saturating_sub(1) {
                    let c = [corners[0], corners[k], corners[k + 1]];
                    triangles.push(c.map(|c| c.0));
                    if with_normals {
                        corner_normals.push(c.map(|c| c.1));
                    }
                    if with_uvs {
                        corner_uvs.push(c.map(|c| c.2));
                    }
                    if held.assigns {
                        face_materials.push(id);
                    }
                }
                if triangles.len() >= BATCH {
                    sink(
                        &vertices,
                        &Faces { triangles: &triangles, normals: &corner_normals, uvs: &corner_uvs, materials: &face_materials },
                    )?;
                    triangles.clear();
                    corner_normals.clear();
                    corner_uvs.clear();
                    face_materials.clear();
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    if !any_text {
        return Err(Error::invalid(path, None, "the file holds only whitespace"));
    }
    if faces == 0 {
        return Err(Error::invalid(
            path,
            None,
            format!("no faces: {} vertices but no `f` line with 3 or more vertices", held.positions.len()),
        ));
    }
    if !triangles.is_empty() {
        sink(&vertices, &Faces { triangles: &triangles, normals: &corner_normals, uvs: &corner_uvs, materials: &face_materials })?;
    }
    if short > 0 {
        warnings.push(format!("{short} faces with fewer than 3 vertices skipped"));
    }
    if segments > 0 {
        warnings.push(format!("{segments} line elements (`l`) skipped"));
    }
    if with_normals && without_normal > 0 {
        warnings.push(format!("{without_normal} face corners have no normal index and reuse the previous corner's normal"));
    }
    if with_uvs && without_uv > 0 {
        warnings.push(format!("{without_uv} face corners have no texture index and reuse the previous corner's UV"));
    }
    Ok(looks(path, import, &held.libraries, &used, warnings))
}

/// The materials `used` names, in that order (None: the default material), from the libraries
/// `libraries` (relative to the model's folder), with their maps' images.
fn looks(path: &Path, import: &ImportOptions, libraries: &[String], used: &[Option<String>], warnings: &mut Vec<String>) -> Looks {
    let dir = path.parent().unwrap_or(Path::new(""));
    // Each name's definition and the folder of its library: the last library defining it wins.
    let mut defined: HashMap<String, (tobj::Material, std::path::PathBuf)> = HashMap::new();
    for lib in libraries {
        let full = dir.join(lib);
        match super::obj::load_library(&full) {
            Ok((materials, _)) => {
                let folder = Path::new(lib).parent().unwrap_or(Path::new("")).to_path_buf();
                for m in materials {
                    defined.insert(m.name.clone(), (m, folder.clone()));
                }
            }
            Err(e) => {
                let w = super::obj::library_warning(&full, &e);
                if !warnings.contains(&w) {
                    warnings.push(w);
                }
            }
        }
    }
    let mut holder = Mesh::default();
    let mut images = super::ImageFiles::default();
    let mut undefined = Vec::new();
    for (out, name) in used.iter().enumerate() {
        let definition = name.as_ref().and_then(|n| defined.get(n));
        holder.materials.push(match (name, definition) {
            (None, _) => Material::default(),
            (Some(_), Some((m, _))) => super::obj::material_from(m),
            (Some(n), None) => {
                undefined.push(n.as_str());
                Material { name: n.clone(), ..Material::default() }
            }
        });
        if let Some((m, folder)) = definition {
            super::obj::attach_maps(m, (dir, folder), import.allow_outside_files, &mut images, &mut holder, out, warnings);
        }
    }
    if !undefined.is_empty() {
        warnings.push(format!("materials without a definition in any loaded .mtl: {}", undefined.join(", ")));
    }
    Looks { materials: holder.materials, images: holder.images }
}

/// A face index of `kind` as a 0-based index into its array of `total`, `seen` of which lie above
/// its line; checked as the whole-file reader checks it.
fn resolve(part: &[u8], kind: usize, seen: usize, total: usize) -> std::result::Result<usize, String> {
    let index = super::obj::face_index(part, kind, seen)?;
    if index < 0 {
        return Ok(seen - index.unsigned_abs() as usize);
    }
    if index as u64 > total as u64 {
        return Err(super::obj::out_of_range(kind, index, total));
    }
    Ok(index as usize - 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the stream hands on of `path`: positions, triangles, corner normals and UVs, each
    /// face's material name, the materials' maps and the images, as a mesh.
    fn streamed(path: &Path) -> Mesh {
        let mut m = Mesh::default();
        let (mut normals, mut uvs, mut materials) = (Vec::new(), Vec::new(), Vec::new());
        let looks = stream(
            path,
            &Default::default(),
            &mut |v, f| {
                m.positions = v.positions.to_vec();
                m.triangles.extend_from_slice(f.triangles);
                normals.extend(f.normals.iter().flatten());
                uvs.extend(f.uvs.iter().flatten());
                materials.extend_from_slice(f.materials);
                Ok(())
            },
            &mut Vec::new(),
        )
        .unwrap();
        (m.normals, m.uvs, m.face_materials, m.materials, m.images) = (normals, uvs, materials, looks.materials, looks.images);
        m
    }

    /// The whole-file reader's positions, triangles, corner normals and UVs, materials and images,
    /// and the stream's, for the OBJ fixtures and exported textured and two-material meshes.
    #[test]
    fn streams_what_the_whole_file_reader_reads() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
        let mut paths: Vec<_> =
            ["cad_part.obj", "cube.obj", "icosphere.obj", "nonmanifold.obj", "open_grid.obj"].map(|n| dir.join(n)).into();
        let tmp = std::env::temp_dir().join(format!("strata-obj-stream-{}", std::process::id()));
        std::fs::create_dir_all(&tmp).unwrap();
        for (name, mesh) in [("globe.obj", crate::fixtures::textured_globe(24, 64)), ("box.obj", crate::fixtures::two_material_box())] {
            crate::export::obj::write(&tmp.join(name), &mesh).unwrap();
            paths.push(tmp.join(name));
        }
        // A library loaded again after another takes precedence again; corners without a texture
        // index reuse the previous corner's UV; names hold spaces.
        std::fs::write(tmp.join("a.mtl"), "newmtl m\nKd 1 0 0\nnewmtl other one\nKd 0 1 0\n").unwrap();
        std::fs::write(tmp.join("b.mtl"), "newmtl m\nKd 0 0 1\n").unwrap();
        let square = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n";
        let text =
            format!("mtllib a.mtl\nmtllib b.mtl\nmtllib a.mtl\n{square}f 1 2 3\nusemtl m\nf 1/1 2/2 3\nusemtl other one\nf 1/1 3/3 4\n");
        std::fs::write(tmp.join("libraries.obj"), text).unwrap();
        paths.push(tmp.join("libraries.obj"));
        for path in &paths {
            let name = path.display();
            let whole = super::super::obj::read(path, &Default::default(), &mut Vec::new()).unwrap().mesh;
            let m = streamed(path);
            assert_eq!(declared(path).unwrap(), Declared { triangles: m.triangles.len() as u64, refused: None }, "{name}");
            // tobj numbers vertices per object and material run: the same corners, by position.
            let corners = |mesh: &Mesh| mesh.triangles.iter().map(|t| t.map(|v| mesh.positions[v as usize])).collect::<Vec<_>>();
            assert_eq!(corners(&m), corners(&whole), "{name}");
            assert_eq!(m.normals, whole.normals, "{name}");
            assert_eq!(m.uvs, whole.uvs, "{name}");
            let named = |mesh: &Mesh| mesh.face_materials.iter().map(|&k| mesh.materials[k as usize].clone()).collect::<Vec<_>>();
            let faces = if m.face_materials.is_empty() { vec![Material::default(); m.triangles.len()] } else { named(&m) };
            assert_eq!(faces, named(&whole), "{name}");
            assert_eq!(m.images.len(), whole.images.len(), "{name}");
            assert!(m.images.iter().zip(&whole.images).all(|(a, b)| a.name == b.name && a.bytes == b.bytes), "{name}");
        }
        assert!(streamed(&tmp.join("globe.obj")).images.len() == 1, "the globe's texture streams");
        let m = streamed(&tmp.join("libraries.obj"));
        let names: Vec<(&str, [f32; 4])> = m.materials.iter().map(|m| (m.name.as_str(), m.base_color)).collect();
        assert_eq!(names[1..], [("m", [1.0, 0.0, 0.0, 1.0]), ("other one", [0.0, 1.0, 0.0, 1.0])]);
        assert_eq!(m.uvs[5], m.uvs[4], "a corner without a texture index reuses the previous one's");
        std::fs::remove_dir_all(&tmp).ok();
    }
}
