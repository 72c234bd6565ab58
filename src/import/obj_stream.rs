//! Wavefront OBJ as a stream, for the partitioned build: two passes over the file, line by line.
//! The first holds the vertex positions (and their colors) and the normals; the second hands the
//! faces on in batches, fan-triangulated as the whole-file reader does (`obj.rs`), their indices
//! resolved (positive ones may point further down the file, negative ones count back from their
//! line) and checked, each corner's normal with it. Errors name the line. Texture coordinates and
//! materials (`usemtl`) are refused: the partitioned build does not carry them.

use super::stream::{refused, Declared, FaceSink, Faces, Vertices, BATCH};
use crate::error::{Error, Result};
use crate::mesh::coordinate_problem;
use glam::Vec3;
use std::io::BufRead;
use std::path::Path;

/// Call `each` with every line of `path` (1-based number, bytes without the line end).
fn lines(path: &Path, mut each: impl FnMut(usize, &[u8]) -> Result<()>) -> Result<()> {
    let (file, _) = super::open_regular(path)?;
    let mut file = std::io::BufReader::with_capacity(1 << 20, file);
    let mut line = Vec::with_capacity(256);
    let mut n = 0;
    loop {
        line.clear();
        if file.read_until(b'\n', &mut line).map_err(|e| Error::io(path, e))? == 0 {
            return Ok(());
        }
        n += 1;
        while line.last().is_some_and(|&b| b == b'\n' || b == b'\r') {
            line.pop();
        }
        if n == 1 {
            if let Some(why) = super::utf16_hint(&line) {
                return Err(Error::invalid(path, None, why));
            }
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
fn number(word: Option<&[u8]>, element: &str, expected: &str) -> std::result::Result<f32, String> {
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
    normals: Vec<Vec3>,
}

fn first_pass(path: &Path, warnings: &mut Vec<String>) -> Result<Held> {
    let mut h = Held::default();
    lines(path, |n, line| {
        let mut w = words(line);
        let bad = |e: String| Error::at_line(path, n, e);
        match w.next() {
            Some(b"v") => {
                let mut p = [0f32; 3];
                for c in &mut p {
                    *c = number(w.next(), "v", "3 coordinates").map_err(bad)?;
                }
                if let Some(problem) = coordinate_problem(p.map(f64::from)) {
                    return Err(bad(problem));
                }
                let rest: Vec<&[u8]> = w.collect();
                match rest[..] {
                    [] => h.colors.push([0, 0, 0, 255]),
                    [weight] => {
                        if number(Some(weight), "v", "a w weight").map_err(bad)? == 0.0 {
                            return Err(bad("vertex weight w is 0".into()));
                        }
                        h.colors.push([0, 0, 0, 255]);
                    }
                    [r, g, b] => {
                        let mut c = [0u8, 0, 0, 255];
                        for (slot, word) in c.iter_mut().zip([r, g, b]) {
                            *slot = super::obj::unit_to_u8(number(Some(word), "v", "an RGB color").map_err(bad)?);
                        }
                        h.colors.push(c);
                        h.colored += 1;
                    }
                    _ => return Err(bad(format!("v has {} numbers; expected 3, 4 (x y z w) or 6 (x y z r g b)", 3 + rest.len()))),
                }
                h.positions.push(Vec3::from_array(p));
            }
            Some(b"vn") => {
                let mut v = [0f32; 3];
                for c in &mut v {
                    *c = number(w.next(), "vn", "3 components").map_err(bad)?;
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
        any_text |= first.is_some();
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
                    let mut index = [None::<usize>; 3];
                    for (kind, part) in p.iter().enumerate() {
                        let Some(part) = part.filter(|p| !p.is_empty()) else { continue };
                        index[kind] = Some(resolve(part, kind, seen[kind], totals[kind]).map_err(|e| Error::at_line(path, n, e))?);
                    }
                    let Some(v) = index[0] else {
                        return Err(Error::at_line(path, n, format!("face vertex '{}' has no position index", text(token))));
                    };
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

const KIND_NAMES: [&str; 3] = ["vertex", "texture coordinate", "normal"];
const KIND_PLURALS: [&str; 3] = ["vertices", "texture coordinates", "normals"];

/// A face index of `kind` as a 0-based index into its array of `total`, `seen` of which lie above
/// its line.
fn resolve(part: &[u8], kind: usize, seen: usize, total: usize) -> std::result::Result<usize, String> {
    let what = KIND_NAMES[kind];
    let index: i64 = std::str::from_utf8(part)
        .ok()
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| format!("face {what} index '{}' is not an integer", text(part)))?;
    if index == 0 {
        return Err(format!("face {what} index 0 (OBJ indices start at 1)"));
    }
    if index < 0 {
        let back = index.unsigned_abs();
        if back > seen as u64 {
            return Err(format!("relative {what} index {index} reaches before the first of {seen} so far"));
        }
        return Ok(seen - back as usize);
    }
    if index as u64 > total as u64 {
        let counted = if total == 1 { what } else { KIND_PLURALS[kind] };
        return Err(format!("face {what} index {index} out of range: the file has {total} {counted}"));
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
