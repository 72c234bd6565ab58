//! Cells of a partitioned build: a kd-tree over the input's vertices cut into cells of about the
//! same number of faces, faces written to one temporary file per cell (by their centroid's cell),
//! and a cell read back as a mesh.
//!
//! A face is stored as its three corners, each the input vertex id, the position and, when the
//! input has them, the normal, texture coordinates and color, then its material when the input
//! has several: a cell file is the whole of its faces, so cells are built without the input.

use crate::error::{Error, Result};
use crate::mesh::{box_of, Mesh};
use glam::{Vec2, Vec3};
use rustc_hash::FxHashMap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// The cut of space into cells: a kd-tree whose leaves are cells.
#[derive(Clone, Debug, Default)]
pub struct Cells {
    /// Inner nodes: split axis, split value, children (a child `>= nodes.len()` is leaf
    /// `child − nodes.len()`).
    nodes: Vec<(u8, f32, [u32; 2])>,
    pub count: usize,
}

/// Vertices sampled to place the splits, at most.
const SAMPLES: usize = 1 << 20;

impl Cells {
    /// Cells of about `cell_faces` faces each for `faces` faces on the vertices `positions`
    /// (splits of a sample along the longest side of each box, at the quantile that gives each
    /// side its share of the cells).
    pub fn split(positions: &[Vec3], faces: u64, cell_faces: u64) -> Cells {
        let stride = (positions.len() / SAMPLES).max(1);
        let mut sample: Vec<Vec3> = positions.iter().step_by(stride).copied().collect();
        let mut cells = Cells::default();
        let leaves = faces.div_ceil(cell_faces.max(1)).max(1);
        if leaves <= 1 || sample.len() < 2 {
            cells.count = 1;
            return cells;
        }
        let n = sample.len();
        cells.build(&mut sample[..n], leaves.min(n as u64) as usize);
        // Leaves were numbered as they were made; inner links were offset by a provisional count.
        let inner = cells.nodes.len() as u32;
        for node in &mut cells.nodes {
            for c in &mut node.2 {
                if *c & LEAF != 0 {
                    *c = inner + (*c & !LEAF);
                }
            }
        }
        cells
    }

    /// Split `pts` into `leaves` cells: at the quantile that gives each side its share of them.
    fn build(&mut self, pts: &mut [Vec3], leaves: usize) -> u32 {
        if leaves <= 1 || pts.len() < 2 {
            let leaf = self.count as u32;
            self.count += 1;
            return LEAF | leaf;
        }
        let (lo, hi) = box_of(pts.iter().copied()).unwrap_or_default();
        let e = hi - lo;
        let axis = if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        };
        let left = leaves / 2;
        let mid = (pts.len() * left / leaves).clamp(1, pts.len() - 1);
        pts.select_nth_unstable_by(mid, |a, b| a[axis].total_cmp(&b[axis]));
        let value = pts[mid][axis];
        let me = self.nodes.len();
        self.nodes.push((axis as u8, value, [0, 0]));
        let (left_pts, right_pts) = pts.split_at_mut(mid);
        let a = self.build(left_pts, left);
        let b = self.build(right_pts, leaves - left);
        self.nodes[me].2 = [a, b];
        me as u32
    }

    /// The cell of point `p`.
    pub fn of(&self, p: Vec3) -> usize {
        if self.nodes.is_empty() {
            return 0;
        }
        let inner = self.nodes.len() as u32;
        let mut at = 0u32;
        loop {
            let (axis, value, children) = self.nodes[at as usize];
            at = children[(p[axis as usize] >= value) as usize];
            if at >= inner {
                return (at - inner) as usize;
            }
        }
    }
}

const LEAF: u32 = 1 << 31;

/// Which corner attributes cell files carry, and whether faces carry a material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    pub normals: bool,
    pub uvs: bool,
    pub colors: bool,
    pub materials: bool,
}

impl Layout {
    fn corner_bytes(self) -> usize {
        16 + if self.normals { 12 } else { 0 } + if self.uvs { 8 } else { 0 } + if self.colors { 4 } else { 0 }
    }

    fn face_bytes(self) -> usize {
        3 * self.corner_bytes() + if self.materials { 4 } else { 0 }
    }
}

/// One face as a cell file holds it: its corners' vertex ids, positions and attributes (those
/// the layout leaves out are ignored), and its material.
pub struct FaceRecord {
    pub ids: [u32; 3],
    pub positions: [Vec3; 3],
    pub normals: [Vec3; 3],
    pub uvs: [Vec2; 3],
    pub colors: [[u8; 4]; 3],
    pub material: u32,
}

/// One temporary file per cell, faces appended.
pub struct Spool {
    files: Vec<(PathBuf, BufWriter<File>, u64)>,
    layout: Layout,
    buf: Vec<u8>,
}

impl Spool {
    pub fn create(dir: &Path, count: usize, layout: Layout) -> Result<Spool> {
        let mut files = Vec::with_capacity(count);
        for c in 0..count {
            let path = dir.join(format!("cell-{c}.faces"));
            let f = File::create(&path).map_err(|e| Error::io(&path, e))?;
            files.push((path, BufWriter::with_capacity(1 << 16, f), 0));
        }
        Ok(Spool { files, layout, buf: Vec::with_capacity(128) })
    }

    /// Append a face to cell `cell`.
    pub fn push(&mut self, cell: usize, face: &FaceRecord) -> Result<()> {
        self.buf.clear();
        for k in 0..3 {
            self.buf.extend_from_slice(&face.ids[k].to_le_bytes());
            for x in face.positions[k].to_array() {
                self.buf.extend_from_slice(&x.to_le_bytes());
            }
            if self.layout.normals {
                for x in face.normals[k].to_array() {
                    self.buf.extend_from_slice(&x.to_le_bytes());
                }
            }
            if self.layout.uvs {
                for x in face.uvs[k].to_array() {
                    self.buf.extend_from_slice(&x.to_le_bytes());
                }
            }
            if self.layout.colors {
                self.buf.extend_from_slice(&face.colors[k]);
            }
        }
        if self.layout.materials {
            self.buf.extend_from_slice(&face.material.to_le_bytes());
        }
        let (path, w, n) = &mut self.files[cell];
        w.write_all(&self.buf).map_err(|e| Error::io(path, e))?;
        *n += 1;
        Ok(())
    }

    /// Close every file; each cell's path and face count.
    pub fn finish(self) -> Result<Vec<(PathBuf, u64)>> {
        let mut out = Vec::with_capacity(self.files.len());
        for (path, w, n) in self.files {
            w.into_inner().map_err(|e| Error::io(&path, e.into_error()))?;
            out.push((path, n));
        }
        Ok(out)
    }
}

/// A cell's faces as an uncleaned mesh, one vertex per welded input vertex it uses (the first
/// corner's position: corners of a vertex differ at most in the sign of a zero; [`Mesh::clean`]
/// welds by position), with the input vertex id of each vertex. Its materials are left empty:
/// they are the input's, which the caller holds; a face's material is checked below `materials`,
/// each vertex id below `vertices`.
pub fn read_cell(path: &Path, faces: u64, layout: Layout, vertices: u64, materials: usize) -> Result<(Mesh, Vec<u32>)> {
    let corner = layout.corner_bytes();
    let mut r = open_cell(path, faces, layout)?;
    let n = faces as usize * 3;
    let mut mesh =
        Mesh { triangles: Vec::with_capacity(faces as usize), face_materials: Vec::with_capacity(faces as usize), ..Mesh::default() };
    // About half a vertex per face on a closed surface.
    let mut ids = Vec::with_capacity(faces as usize / 2);
    mesh.positions.reserve(faces as usize / 2);
    let mut local: FxHashMap<u32, u32> = FxHashMap::with_capacity_and_hasher(faces as usize / 2, Default::default());
    let mut rec = vec![0u8; corner];
    let mut t = [0u32; 3];
    for c in 0..n {
        r.read_exact(&mut rec).map_err(|e| Error::io(path, e))?;
        let id = vertex_id(path, &rec, c, vertices)?;
        t[c % 3] = *local.entry(id).or_insert_with(|| {
            ids.push(id);
            mesh.positions.push(corner_position(&rec));
            ids.len() as u32 - 1
        });
        let mut at = 16;
        if layout.normals {
            mesh.normals.push(Vec3::new(f32_at(&rec, at), f32_at(&rec, at + 4), f32_at(&rec, at + 8)));
            at += 12;
        }
        if layout.uvs {
            mesh.uvs.push(Vec2::new(f32_at(&rec, at), f32_at(&rec, at + 4)));
            at += 8;
        }
        if layout.colors {
            mesh.colors.push(rec[at..at + 4].try_into().unwrap());
        }
        if c % 3 == 2 {
            mesh.triangles.push(t);
            let mut material = 0;
            if layout.materials {
                let mut b = [0u8; 4];
                r.read_exact(&mut b).map_err(|e| Error::io(path, e))?;
                material = u32::from_le_bytes(b);
                if material as usize >= materials {
                    let face = mesh.triangles.len() - 1;
                    return Err(Error::invalid(path, None, format!("face {face} has material {material} of {materials}")));
                }
            }
            mesh.face_materials.push(material);
        }
    }
    Ok((mesh, ids))
}

/// Cell file `path` for reading, once its length is checked against `faces` faces.
fn open_cell(path: &Path, faces: u64, layout: Layout) -> Result<BufReader<File>> {
    let expect = faces * layout.face_bytes() as u64;
    let len = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
    if len != expect {
        return Err(Error::invalid(path, None, format!("cell file of {len} bytes, {expect} expected for {faces} faces")));
    }
    Ok(BufReader::with_capacity(1 << 20, File::open(path).map_err(|e| Error::io(path, e))?))
}

/// The little-endian f32 at byte `i` of `b`.
fn f32_at(b: &[u8], i: usize) -> f32 {
    f32::from_le_bytes(b[i..i + 4].try_into().unwrap())
}

/// The position a corner record `rec` holds after its vertex id.
fn corner_position(rec: &[u8]) -> Vec3 {
    Vec3::new(f32_at(rec, 4), f32_at(rec, 8), f32_at(rec, 12))
}

/// The vertex id a corner record `rec` (corner `c` of the file) starts with, checked below
/// `vertices`.
fn vertex_id(path: &Path, rec: &[u8], c: usize, vertices: u64) -> Result<u32> {
    let id = u32::from_le_bytes(rec[0..4].try_into().unwrap());
    if id as u64 >= vertices {
        return Err(Error::invalid(path, None, format!("face {} corner {}: vertex {id} of {vertices}", c / 3, c % 3)));
    }
    Ok(id)
}

/// Call `f` with each face's vertex ids (checked below `vertices`) and corner positions in cell
/// file `path` (of `faces` faces), in the order they were written; the file stays.
pub fn scan_cell(path: &Path, faces: u64, layout: Layout, vertices: u64, mut f: impl FnMut([u32; 3], [Vec3; 3])) -> Result<()> {
    let (corner, size) = (layout.corner_bytes(), layout.face_bytes());
    let mut r = open_cell(path, faces, layout)?;
    let mut rec = vec![0u8; size];
    for face in 0..faces as usize {
        r.read_exact(&mut rec).map_err(|e| Error::io(path, e))?;
        let at = |k: usize| &rec[k * corner..];
        let mut ids = [0; 3];
        for (k, id) in ids.iter_mut().enumerate() {
            *id = vertex_id(path, at(k), 3 * face + k, vertices)?;
        }
        let positions = [0, 1, 2].map(|k| corner_position(at(k)));
        f(ids, positions);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_split_points_evenly_and_locate_them() {
        let pts: Vec<Vec3> = (0..4096).map(|i| Vec3::new((i % 64) as f32, (i / 64) as f32, ((i * 7) % 13) as f32)).collect();
        let cells = Cells::split(&pts, 8192, 1024);
        assert_eq!(cells.count, 8);
        let six = Cells::split(&pts, 6 * 1024, 1024);
        assert_eq!(six.count, 6);
        let mut n6 = vec![0; 6];
        for &p in &pts {
            n6[six.of(p)] += 1;
        }
        assert!(n6.iter().all(|&c| (560..=810).contains(&c)), "{n6:?}");
        let mut count = vec![0; cells.count];
        for &p in &pts {
            count[cells.of(p)] += 1;
        }
        assert!(count.iter().all(|&c| (400..=620).contains(&c)), "{count:?}");
    }
}
