//! Wavefront OBJ as a stream, for the partitioned build: two passes over the file, line by line.
//! The first holds the vertex positions (and their colors) and the normals; the second hands the
//! faces on in batches, fan-triangulated as the whole-file reader does (`obj.rs`), their indices
//! resolved (positive ones may point further down the file, negative ones count back from their
//! line) and checked, each corner's normal with it. Errors name the line. Texture coordinates and
//! materials (`usemtl`) are refused: the partitioned build does not carry them. Vertices keep the
//! file's order; the whole-file reader's tobj numbers them per object (`o`, `g`), so for a file of
//! several objects the two builds number the same surface's vertices differently.

use super::stream::{refused, Declared, FaceSink, Faces, Vertices, BATCH};
use crate::error::{Error, Result};
use crate::mesh::coordinate_problem;
use glam::Vec3;
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
    let (mut triangles, mut refused_why) = (0u64, None);
    lines(path, |_, line| {
        let mut w = words(line);
        match w.next() {
            Some(b"f") => triangles += (w.count() as u64).saturating_sub(2),
            Some(b"vt") if refused_why.is_none() => refused_why = Some(refused("the file has texture coordinates")),
            Some(b"usemtl") if refused_why.is_none() => refused_why = Some(refused("the file assigns materials (usemtl)")),
            _ => {}
        }
        Ok(())
    })?;
    Ok(Declared { triangles, refused: refused_why })
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
            Some(b"vt") => return Err(Error::invalid(path, None, refused("the file has texture coordinates"))),
            Some(b"usemtl") => return Err(Error::invalid(path, None, refused("the file assigns materials (usemtl)"))),
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
pub fn stream(path: &Path, sink: &mut FaceSink, warnings: &mut Vec<String>) -> Result<()> {
    let held = first_pass(path, warnings)?;
    let vertices = Vertices { positions: &held.positions, normals: &[], colors: &held.colors };
    let with_normals = !held.normals.is_empty();
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(BATCH);
    let mut corner_normals: Vec<[Vec3; 3]> = Vec::with_capacity(if with_normals { BATCH } else { 0 });
    // Vertices and normals defined above the current line, for relative indices.
    let (mut seen_v, mut seen_vn) = (0usize, 0usize);
    let (mut faces, mut short, mut segments, mut without_normal) = (0u64, 0usize, 0usize, 0usize);
    let mut last_normal = held.normals.first().copied().unwrap_or(Vec3::Z);
    let totals = [held.positions.len(), 0, held.normals.len()];
    let mut corners: Vec<(u32, Vec3)> = Vec::new();
    let mut any_text = false;
    lines(path, |n, line| {
        let mut w = words(line);
        let first = w.next();
        any_text |= !String::from_utf8_lossy(line).trim().is_empty();
        match first {
            Some(b"v") => seen_v += 1,
            Some(b"vn") => seen_vn += 1,
            Some(b"l") => segments += 1,
            Some(b"f") => {
                corners.clear();
                let seen = [seen_v, 0, seen_vn];
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
                    corners.push((v as u32, normal));
                }
                match corners.len() {
                    0 => return Err(Error::at_line(path, n, "face with no vertices")),
                    1 | 2 => short += 1,
                    _ => faces += 1,
                }
                for k in 1..corners.len().saturating_sub(1) {
                    let c = [corners[0], corners[k], corners[k + 1]];
                    triangles.push(c.map(|c| c.0));
                    if with_normals {
                        corner_normals.push(c.map(|c| c.1));
                    }
                }
                if triangles.len() >= BATCH {
                    sink(&vertices, &Faces { triangles: &triangles, normals: &corner_normals })?;
                    triangles.clear();
                    corner_normals.clear();
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
        sink(&vertices, &Faces { triangles: &triangles, normals: &corner_normals })?;
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
    Ok(())
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

    /// The whole-file reader's triangles, positions and corner normals, and the stream's.
    #[test]
    fn streams_what_the_whole_file_reader_reads() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
        for name in ["cad_part.obj", "cube.obj", "icosphere.obj", "nonmanifold.obj"] {
            let path = dir.join(name);
            let whole = super::super::obj::read(&path, &Default::default(), &mut Vec::new()).unwrap().mesh;
            let (mut triangles, mut normals, mut positions) = (Vec::new(), Vec::<Vec3>::new(), Vec::new());
            let declared = declared(&path).unwrap();
            stream(
                &path,
                &mut |v, f| {
                    positions = v.positions.to_vec();
                    triangles.extend_from_slice(f.triangles);
                    normals.extend(f.normals.iter().flatten());
                    Ok(())
                },
                &mut Vec::new(),
            )
            .unwrap();
            assert_eq!(declared, Declared { triangles: triangles.len() as u64, refused: None }, "{name}");
            assert_eq!(positions, whole.positions, "{name}");
            assert_eq!(triangles, whole.triangles, "{name}");
            assert_eq!(normals, whole.normals, "{name}");
        }
        // Texture coordinates are refused, before any face is handed on.
        let textured = dir.join("open_grid.obj");
        assert!(declared(&textured).unwrap().refused.is_some());
        let e = stream(&textured, &mut |_, _| panic!("no faces"), &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("open_grid.obj") && e.contains("texture coordinates"), "{e}");
    }
}
