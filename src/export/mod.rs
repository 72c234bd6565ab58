//! Write meshes for other tools: OBJ, PLY (binary, with colors) and GLB, chosen by extension.
//! Every writer goes through [`crate::atomic::AtomicFile`], so no partial file is left behind, and
//! each also writes to any `impl Write`. Output is deterministic: the same mesh gives the same bytes.
//!
//! A [`Mesh`] holds UVs in glTF's convention (v down the image): GLB writes them as they are, OBJ
//! and PLY with v flipped, as those formats count it. GLB embeds the images materials' maps use;
//! OBJ writes them beside it.

pub mod glb;
pub mod obj;
pub mod ply;

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use std::collections::HashMap;
use std::io;
use std::path::Path;

/// Write `mesh` to `path`, the format chosen by its extension (.obj, .ply, .glb).
pub fn write(path: &Path, mesh: &Mesh) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("obj") => obj::write(path, mesh),
        Some("ply") => ply::write(path, mesh),
        Some("glb") => glb::write(path, mesh),
        _ => Err(Error::invalid(path, None, "unknown output format: use .obj, .ply or .glb")),
    }
}

/// Refuse a mesh whose arrays disagree or whose positions are not finite: writers index freely
/// and a file with NaN coordinates is of no use to anyone.
fn check(mesh: &Mesh) -> io::Result<()> {
    mesh.validate().map_err(|e| invalid_mesh(format!("mesh to write is inconsistent: {e}")))?;
    if let Some(i) = mesh.positions.iter().position(|p| !p.is_finite()) {
        return Err(invalid_mesh(format!("vertex {i} has a NaN or infinite coordinate")));
    }
    Ok(())
}

fn invalid_mesh(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

/// Vertices for formats that keep attributes per vertex: one per distinct (position, normal, UV,
/// color) tuple among the corners of `faces`, numbered in order of first use.
struct Split {
    /// Output vertex of each corner of `faces`, three per face, in the order of `faces`.
    corner_vertex: Vec<u32>,
    /// A corner (index into the mesh's corner arrays) carrying each output vertex's attributes.
    vertex_corner: Vec<u32>,
}

fn split_vertices(mesh: &Mesh, faces: impl Iterator<Item = usize>) -> Split {
    let bits = |v: &[f32]| -> [u32; 3] { [0, 1, 2].map(|i| v.get(i).map_or(0, |x| x.to_bits())) };
    let mut index: HashMap<[u32; 7], u32> = HashMap::new();
    let mut corner_vertex = Vec::new();
    let mut vertex_corner = Vec::new();
    for f in faces {
        for k in 0..3 {
            let c = 3 * f + k;
            let n = mesh.normals.get(c).map_or([0; 3], |n| bits(&n.to_array()));
            let uv = mesh.uvs.get(c).map_or([0; 3], |t| bits(&t.to_array()));
            let color = mesh.colors.get(c).map_or(0, |&rgba| u32::from_le_bytes(rgba));
            let key = [mesh.triangles[f][k], n[0], n[1], n[2], uv[0], uv[1], color];
            let next = vertex_corner.len() as u32;
            let v = *index.entry(key).or_insert(next);
            if v == next {
                vertex_corner.push(c as u32);
            }
            corner_vertex.push(v);
        }
    }
    Split { corner_vertex, vertex_corner }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures;

    #[test]
    fn dispatch_by_extension() {
        let dir = std::env::temp_dir().join(format!("strata-export-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cube = fixtures::cube();
        for name in ["c.obj", "c.PLY", "c.glb"] {
            write(&dir.join(name), &cube).unwrap();
            assert!(std::fs::metadata(dir.join(name)).unwrap().len() > 100, "{name}");
        }
        let err = write(&dir.join("c.stl"), &cube).unwrap_err().to_string();
        assert!(err.contains("c.stl") && err.contains("unknown output format"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn rejects_inconsistent_mesh() {
        let mut m = fixtures::cube();
        m.normals.pop();
        let mut out = Vec::new();
        assert_eq!(ply::write_ply(&mut out, &m).unwrap_err().kind(), io::ErrorKind::InvalidInput);
        let mut m = fixtures::cube();
        m.positions[3].x = f32::NAN;
        assert!(obj::write_obj(&mut out, &m, None).unwrap_err().to_string().contains("vertex 3"));
    }

    #[test]
    fn split_keeps_one_vertex_per_distinct_tuple() {
        // The cube's 8 corners each meet 3 faces with different normals.
        let cube = fixtures::cube();
        let s = split_vertices(&cube, 0..cube.face_count());
        assert_eq!(s.vertex_corner.len(), 24);
        assert_eq!(s.corner_vertex.len(), 36);
        for (c, &v) in s.corner_vertex.iter().enumerate() {
            let rep = s.vertex_corner[v as usize] as usize;
            assert_eq!(cube.triangles[c / 3][c % 3], cube.triangles[rep / 3][rep % 3]);
            assert_eq!(cube.normals[c], cube.normals[rep]);
        }
        let smooth = fixtures::icosphere(1);
        assert_eq!(split_vertices(&smooth, 0..smooth.face_count()).vertex_corner.len(), smooth.vertex_count());
    }
}
