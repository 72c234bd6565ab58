//! Write binary little-endian PLY.
//!
//! PLY keeps attributes per vertex, so a position whose corners differ in normal, color or UV is
//! written once per distinct combination; positions are copied bit for bit. Vertex properties are
//! `x y z`, then when present `nx ny nz`, `red green blue alpha` (uchar) and `s t`; faces are
//! `list uchar int vertex_indices`. Materials are not stored: PLY has no standard way to.

use super::{check, invalid_mesh, split_vertices};
use crate::atomic::write_file;
use crate::error::Result;
use crate::mesh::Mesh;
use std::io::{self, Write};
use std::path::Path;

/// Write `mesh` to `path` as binary PLY.
pub fn write(path: &Path, mesh: &Mesh) -> Result<()> {
    write_file(path, |w| write_ply(w, mesh))
}

/// Write the PLY bytes of `mesh`.
pub fn write_ply<W: Write>(mut out: W, mesh: &Mesh) -> io::Result<()> {
    check(mesh)?;
    let split = split_vertices(mesh, 0..mesh.face_count());
    if split.vertex_corner.len() > i32::MAX as usize {
        return Err(invalid_mesh(format!("{} vertices exceed PLY's int indices", split.vertex_corner.len())));
    }
    let (normals, colors, uvs) = (!mesh.normals.is_empty(), !mesh.colors.is_empty(), !mesh.uvs.is_empty());

    let mut header = String::from("ply\nformat binary_little_endian 1.0\ncomment written by strata\n");
    header += &format!("element vertex {}\nproperty float x\nproperty float y\nproperty float z\n", split.vertex_corner.len());
    if normals {
        header += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    if colors {
        header += "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n";
    }
    if uvs {
        header += "property float s\nproperty float t\n";
    }
    header += &format!("element face {}\nproperty list uchar int vertex_indices\nend_header\n", mesh.face_count());
    out.write_all(header.as_bytes())?;

    let mut record = Vec::with_capacity(36);
    for &c in &split.vertex_corner {
        let c = c as usize;
        record.clear();
        let p = mesh.positions[mesh.triangles[c / 3][c % 3] as usize];
        record.extend(p.to_array().map(f32::to_le_bytes).as_flattened());
        if normals {
            record.extend(mesh.normals[c].to_array().map(f32::to_le_bytes).as_flattened());
        }
        if colors {
            record.extend(mesh.colors[c]);
        }
        if uvs {
            record.extend([mesh.uvs[c].x, 1.0 - mesh.uvs[c].y].map(f32::to_le_bytes).as_flattened());
        }
        out.write_all(&record)?;
    }
    for face in split.corner_vertex.chunks_exact(3) {
        record.clear();
        record.push(3);
        for &v in face {
            record.extend((v as i32).to_le_bytes());
        }
        out.write_all(&record)?;
    }
    out.flush()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures;

    /// The header lines and the binary body.
    fn parts(bytes: &[u8]) -> (Vec<String>, &[u8]) {
        let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let header = std::str::from_utf8(&bytes[..end]).unwrap().lines().map(String::from).collect();
        (header, &bytes[end..])
    }

    fn count(header: &[String], element: &str) -> usize {
        let prefix = format!("element {element} ");
        header.iter().find_map(|l| l.strip_prefix(&prefix)).unwrap().parse().unwrap()
    }

    fn f32_at(body: &[u8], at: usize) -> f32 {
        f32::from_le_bytes(body[at..at + 4].try_into().unwrap())
    }

    #[test]
    fn header_matches_data_length() {
        for (mesh, stride, props) in [
            (fixtures::icosphere(2), 24, 6),
            (fixtures::colored_sphere(1), 28, 10),
            (fixtures::two_material_box(), 32, 8),
            (fixtures::nonmanifold(), 12, 3),
        ] {
            let mut out = Vec::new();
            write_ply(&mut out, &mesh).unwrap();
            let (header, body) = parts(&out);
            assert_eq!(&header[..2], ["ply", "format binary_little_endian 1.0"]);
            assert_eq!(header.iter().filter(|l| l.starts_with("property ") && !l.contains("list")).count(), props);
            let (nv, nf) = (count(&header, "vertex"), count(&header, "face"));
            assert_eq!(nf, mesh.face_count());
            assert_eq!(body.len(), nv * stride + nf * 13);
        }
    }

    #[test]
    fn hard_edges_split_vertices_and_positions_stay_exact() {
        let cube = fixtures::cube();
        let mut out = Vec::new();
        write_ply(&mut out, &cube).unwrap();
        let (header, body) = parts(&out);
        let nv = count(&header, "vertex");
        assert_eq!(nv, 24);
        let faces = &body[nv * 24..];
        for f in 0..cube.face_count() {
            assert_eq!(faces[13 * f], 3);
            for k in 0..3 {
                let v = i32::from_le_bytes(faces[13 * f + 1 + 4 * k..][..4].try_into().unwrap()) as usize;
                assert!(v < nv);
                let p = [0, 1, 2].map(|i| f32_at(body, 24 * v + 4 * i).to_bits());
                let n = [0, 1, 2].map(|i| f32_at(body, 24 * v + 12 + 4 * i));
                assert_eq!(p, cube.positions[cube.triangles[f][k] as usize].to_array().map(f32::to_bits));
                assert_eq!(n, cube.normals[3 * f + k].to_array());
            }
        }
    }

    #[test]
    fn colors_written_as_uchar() {
        let m = fixtures::colored_sphere(1);
        let mut out = Vec::new();
        write_ply(&mut out, &m).unwrap();
        let (header, body) = parts(&out);
        assert!(header.contains(&"property uchar alpha".to_string()));
        let nv = count(&header, "vertex");
        let first_face_v0 = i32::from_le_bytes(body[nv * 28 + 1..][..4].try_into().unwrap()) as usize;
        assert_eq!(body[28 * first_face_v0 + 24..][..4], m.colors[0]);
    }
}
