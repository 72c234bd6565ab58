//! Check a whole strata file: every chunk's frame, CRC and padding, every node's geometry, and the
//! structural rules of the spec (tree shape, breadth-first numbering, neighbour symmetry, bounds and
//! cones that contain what they claim, level 0 covering every input face exactly once).

use super::chunk::{self, HEADER_BYTES, TRAILER_BYTES};
use super::{id, Reader, MINOR, NO_PARENT};
use crate::error::{Error, Result};
use crate::mesh::triangle_cross;
use glam::Vec3;
use std::collections::HashSet;
use std::fs::File;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::io::{Read, Seek};
use std::path::Path;

/// Problems recorded before verification stops listing them.
pub const MAX_PROBLEMS: usize = 100;

/// Angle tolerance, in radians, of cone containment checks (rounding of stored f32 values).
const ANGLE_TOLERANCE: f64 = 1e-5;

/// The outcome of [`verify`].
#[derive(Debug, Default)]
pub struct Verification {
    /// The first [`MAX_PROBLEMS`] problems found, in file order as far as possible.
    pub problems: Vec<Error>,
    /// Top-level chunks walked and nodes whose geometry was read.
    pub chunks: usize,
    pub nodes: usize,
}

impl Verification {
    /// No problem found.
    pub fn is_sound(&self) -> bool {
        self.problems.is_empty()
    }

    fn push(&mut self, e: Error) {
        if self.problems.len() < MAX_PROBLEMS {
            self.problems.push(e);
        }
    }
}

/// Verify the file at `path`.
pub fn verify_path(path: &Path) -> Verification {
    match File::open(path) {
        Ok(f) => verify(f, path),
        Err(e) => Verification { problems: vec![Error::io(path, e)], ..Verification::default() },
    }
}

/// Verify a file read from `r`; errors name it `name`. Never fails: problems are listed.
pub fn verify<R: Read + Seek>(r: R, name: &Path) -> Verification {
    let mut v = Verification::default();
    let mut rd = match Reader::open_named(r, name) {
        Ok(rd) => rd,
        Err(e) => {
            v.push(e);
            return v;
        }
    };
    walk(&mut rd, &mut v);
    let boxes = match rd.node_boxes() {
        Ok(b) => b,
        Err(e) => {
            v.push(e);
            return v;
        }
    };
    structure(&rd, &boxes, &mut v);
    geometry(&mut rd, &boxes, &mut v);
    v
}

/// Walk the top-level chunks: frames, padding, unknown chunks' CRCs, and the `GEOM` chunks being
/// exactly the node table's, in node order.
fn walk<R: Read + Seek>(rd: &mut Reader<R>, v: &mut Verification) {
    let path = rd.path().to_path_buf();
    let chunks = match rd.chunks() {
        Ok(c) => c,
        Err(e) => return v.push(e),
    };
    v.chunks = chunks.len();
    let strict = rd.header().minor.cmp(&MINOR).is_le();
    let mut geoms = Vec::new();
    let mut seen_skel = false;
    for (k, c) in chunks.iter().enumerate() {
        let here = |msg: String| Error::at_byte(&path, c.offset, format!("chunk {} at offset {}: {msg}", c.id, c.offset));
        let end = c.offset + HEADER_BYTES + c.size + TRAILER_BYTES;
        let known = [id::HEAD, id::SKEL, id::GEOM].iter().any(|i| chunk::id_str(i) == c.id);
        if known && c.flags != 0 && strict {
            v.push(here(format!("flags {:#x} should be 0", c.flags)));
        }
        let pad = chunk::padding(end).min(rd.file_size().saturating_sub(end));
        match rd.read_at(end, pad) {
            Ok(b) if b.iter().any(|&x| x != 0) => v.push(here("padding is not zero".into())),
            Ok(_) => {}
            Err(e) => v.push(e),
        }
        if c.id == "HEAD" && k != 0 {
            v.push(here("a second HEAD".into()));
        } else if c.id == "SKEL" {
            if seen_skel {
                v.push(here("a second SKEL".into()));
            }
            seen_skel = true;
        } else if c.id == "GEOM" {
            geoms.push((c.offset, HEADER_BYTES + c.size + TRAILER_BYTES));
        } else if !known {
            if let Err(e) = crc_of(rd, &c.id, c.offset, c.size) {
                v.push(e);
            }
        }
    }
    if let Some(last) = chunks.last() {
        let end = last.offset + HEADER_BYTES + last.size + TRAILER_BYTES;
        if end + chunk::padding(end) != rd.file_size() {
            v.push(Error::at_byte(&path, end, format!("the last chunk's padding does not end the {}-byte file", rd.file_size())));
        }
    }
    let table: Vec<(u64, u64)> = rd.nodes().iter().map(|n| (n.offset, n.size as u64)).collect();
    if geoms != table {
        let k = geoms.iter().zip(&table).position(|(a, b)| a != b).unwrap_or(geoms.len().min(table.len()));
        v.push(Error::at_element(
            &path,
            format!("node {k}"),
            format!("the file holds {} GEOM chunks but the node table lists {}, first differing at node {k}", geoms.len(), table.len()),
        ));
    }
}

/// Check the CRC of an unknown chunk's payload, reading it in pieces.
fn crc_of<R: Read + Seek>(rd: &mut Reader<R>, id: &str, offset: u64, size: u64) -> Result<()> {
    let mut hasher = crc32fast::Hasher::new();
    let mut done = 0u64;
    while done < size {
        let n = (size - done).min(1 << 20);
        hasher.update(&rd.read_at(offset + HEADER_BYTES + done, n)?);
        done += n;
    }
    let stored = rd.read_at(offset + HEADER_BYTES + size, 4)?;
    let stored = u32::from_le_bytes([stored[0], stored[1], stored[2], stored[3]]);
    let actual = hasher.finalize();
    if stored != actual {
        return Err(Error::at_byte(rd.path(), offset, format!("chunk {id} at offset {offset}: CRC {actual:08x} != stored {stored:08x}")));
    }
    Ok(())
}

fn angle(a: Vec3, b: Vec3) -> f64 {
    let (a, b) = (a.as_dvec3(), b.as_dvec3());
    a.cross(b).length().atan2(a.dot(b))
}

/// Whether a cone of half-angle `half` reaches `needed` radians from its axis (a cone of π holds
/// every direction).
fn cone_covers(half: f32, needed: f64) -> bool {
    needed <= half as f64 + ANGLE_TOLERANCE || half as f64 >= std::f64::consts::PI - ANGLE_TOLERANCE
}

/// The node table's rules: tree shape, breadth-first numbering, neighbours, bounds, cones, errors.
fn structure<R: Read + Seek>(rd: &Reader<R>, boxes: &[(Vec3, Vec3)], v: &mut Verification) {
    let path = rd.path();
    let nodes = rd.nodes();
    let nl = rd.levels().len() as u32;
    let problem = |i: usize, msg: String| Error::at_element(path, format!("node {i}"), msg);
    let mut last_offset = 0u64;
    for l in (0..nl).rev() {
        let range = rd.level_nodes(l);
        let below = if l > 0 { rd.level_nodes(l - 1) } else { 0..0 };
        let above = rd.level_nodes(l + 1);
        let mut next_child = below.start;
        for i in range.clone() {
            let n = &nodes[i as usize];
            let i = i as usize;
            if n.offset <= last_offset {
                v.push(problem(i, format!("geometry offset {} does not follow the previous node's", n.offset)));
            }
            last_offset = n.offset;
            if l + 1 == nl {
                if n.parent != NO_PARENT {
                    v.push(problem(i, format!("top-level node has parent {}", n.parent)));
                }
            } else if !above.contains(&n.parent) || !rd.children(n.parent).contains(&(i as u32)) {
                v.push(problem(i, format!("parent {} is not a node of level {} listing it as a child", n.parent, l + 1)));
            }
            if n.child_count == 0 {
                if n.first_child != 0 {
                    v.push(problem(i, format!("no children but first child {}", n.first_child)));
                }
            } else if l == 0 {
                v.push(problem(i, format!("level-0 node has {} children", n.child_count)));
            } else if n.first_child != next_child {
                v.push(problem(i, format!("children start at {}, breadth-first order needs {next_child}", n.first_child)));
            }
            next_child = next_child.max(n.first_child) + n.child_count;
            let (min, max) = boxes[i];
            let finite = n.cone.axis.is_finite() && n.center.is_finite() && min.is_finite() && max.is_finite();
            let sane = finite
                && (n.cone.axis.length() - 1.0).abs() < 1e-3
                && (0.0..=std::f32::consts::PI).contains(&n.cone.half_angle)
                && n.radius >= 0.0
                && min.cmple(max).all()
                && n.error.is_finite();
            if !sane {
                v.push(problem(i, "cone, bounds or error out of range".into()));
                continue;
            }
            for c in rd.children(i as u32) {
                let ch = &nodes[c as usize];
                if !cone_covers(n.cone.half_angle, angle(n.cone.axis, ch.cone.axis) + ch.cone.half_angle as f64) {
                    v.push(problem(i, format!("cone does not contain child {c}'s")));
                }
                let (cmin, cmax) = boxes[c as usize];
                if !(min.cmple(cmin).all() && cmax.cmple(max).all()) {
                    v.push(problem(i, format!("box does not contain child {c}'s")));
                }
                if n.center.distance(ch.center) + ch.radius > n.radius * (1.0 + 1e-5) + 1e-30 {
                    v.push(problem(i, format!("sphere does not contain child {c}'s")));
                }
                if ch.error > n.error {
                    v.push(problem(i, format!("error {} is smaller than child {c}'s {}", n.error, ch.error)));
                }
            }
            let nb = rd.neighbors(i as u32);
            if nb.windows(2).any(|w| w[0] >= w[1]) {
                v.push(problem(i, "neighbours are not strictly ascending".into()));
            }
            for &j in nb {
                if j as usize == i || !range.contains(&j) || !rd.neighbors(j).contains(&(i as u32)) {
                    v.push(problem(i, format!("neighbour {j} is not a different node of level {l} listing it back")));
                }
            }
        }
        if l > 0 && next_child != below.end {
            v.push(Error::at_element(path, format!("level {l}"), format!("children cover nodes {}..{next_child}, not {}..{}", below.start, below.start, below.end)));
        }
    }
    let h = rd.header();
    let top = rd.level_nodes(nl - 1);
    for i in top {
        let (min, max) = boxes[i as usize];
        if !(h.min.cmple(min).all() && max.cmple(h.max).all()) {
            v.push(problem(i as usize, "box lies outside the HEAD bounds".into()));
        }
    }
}

/// Read every node's geometry: CRCs and ranges (by the reader), then bounds, cones, counts per
/// level, and level 0 covering every input face exactly once.
fn geometry<R: Read + Seek>(rd: &mut Reader<R>, boxes: &[(Vec3, Vec3)], v: &mut Verification) {
    let path = rd.path().to_path_buf();
    let nl = rd.levels().len();
    let mut faces = vec![0u64; nl];
    let mut vertices = vec![0u64; nl];
    let mut bytes = vec![0u64; nl];
    let mut clusters = 0u64;
    let mut seen: HashSet<u128> = HashSet::new();
    let mut duplicates = 0u64;
    for i in 0..rd.nodes().len() as u32 {
        let n = rd.nodes()[i as usize];
        let l = n.level as usize;
        let end = n.offset + n.size as u64;
        bytes[l] += n.size as u64 + chunk::padding(end);
        faces[l] += n.faces as u64;
        vertices[l] += n.vertices as u64;
        let g = match rd.read_node(i) {
            Ok(g) => g,
            Err(e) => {
                v.push(e);
                continue;
            }
        };
        v.nodes += 1;
        let problem = |msg: String| Error::at_element(&path, format!("node {i}"), msg);
        clusters += g.clusters.len() as u64;
        let (min, max) = boxes[i as usize];
        if let Some(k) = g.positions.iter().position(|p| !(min.cmple(*p).all() && p.cmple(max).all())) {
            v.push(problem(format!("vertex {k} lies outside the node's box")));
        }
        if let Some(k) = g.positions.iter().position(|p| n.center.distance(*p) > n.radius * (1.0 + 1e-5) + 1e-30) {
            v.push(problem(format!("vertex {k} lies outside the node's sphere")));
        }
        for (f, t) in g.indices.chunks_exact(3).enumerate() {
            let c = triangle_cross(&g.positions, &[t[0], t[1], t[2]]);
            if c.length_squared() > 0.0 && !cone_covers(n.cone.half_angle, angle(n.cone.axis, c.normalize().as_vec3())) {
                v.push(problem(format!("face {f}'s normal lies outside the node's cone")));
                break;
            }
        }
        for cl in &g.clusters {
            let range = cl.first_face as usize * 3..(cl.first_face + cl.face_count) as usize * 3;
            for t in g.indices[range].chunks_exact(3) {
                let c = triangle_cross(&g.positions, &[t[0], t[1], t[2]]);
                let outside_cone = c.length_squared() > 0.0 && !cone_covers(cl.cone.half_angle, angle(cl.cone.axis, c.normalize().as_vec3()));
                let outside_sphere = t.iter().any(|&x| cl.center.distance(g.positions[x as usize]) > cl.radius * (1.0 + 1e-5) + 1e-30);
                if outside_cone || outside_sphere {
                    v.push(problem(format!("a face of the cluster at face {} lies outside its cone or sphere", cl.first_face)));
                    break;
                }
            }
        }
        if l == 0 {
            for t in g.indices.chunks_exact(3) {
                let mut key: Vec<[u32; 3]> = t.iter().map(|&x| g.positions[x as usize].to_array().map(f32::to_bits)).collect();
                key.sort_unstable();
                if !seen.insert(fingerprint(&key)) {
                    duplicates += 1;
                }
            }
        }
    }
    if duplicates > 0 {
        v.push(Error::at_element(&path, "level 0", format!("{duplicates} faces appear more than once")));
    }
    let h = rd.header().clone();
    for (l, rec) in rd.levels().iter().enumerate() {
        if (rec.faces, rec.vertices, rec.bytes) != (faces[l], vertices[l], bytes[l]) {
            v.push(Error::at_element(
                &path,
                format!("level {l}"),
                format!("LEVL says {} faces, {} vertices, {} bytes; the nodes hold {}, {}, {}", rec.faces, rec.vertices, rec.bytes, faces[l], vertices[l], bytes[l]),
            ));
        }
    }
    if faces[0] != h.input_faces {
        v.push(Error::at_element(&path, "level 0", format!("nodes hold {} faces, HEAD says the input has {}", faces[0], h.input_faces)));
    }
    if clusters != h.clusters as u64 {
        v.push(Error::at_element(&path, "level 0", format!("nodes hold {clusters} clusters, HEAD says {}", h.clusters)));
    }
}

/// A 128-bit fingerprint of a face's sorted corner positions.
fn fingerprint(key: &[[u32; 3]]) -> u128 {
    let mut a = DefaultHasher::new();
    key.hash(&mut a);
    let mut b = DefaultHasher::new();
    (key, 0x5bd1_e995u32).hash(&mut b);
    (a.finish() as u128) << 64 | b.finish() as u128
}
