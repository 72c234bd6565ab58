//! One level of a strata file as one [`Mesh`], for `strata extract` and for tests: every node of the
//! level is read and its node-local vertices are welded back by exact position.

use crate::error::{Error, Result};
use crate::format::{ByteSource, Reader};
use crate::mesh::Mesh;
use std::collections::HashMap;

/// All nodes of `level` assembled into one mesh: positions welded by exact bits, attributes on
/// corners, face materials from the material ranges, the file's material table.
pub fn to_mesh<S: ByteSource>(reader: &Reader<S>, level: u32) -> Result<Mesh> {
    let levels = reader.levels().len() as u32;
    if level >= levels {
        return Err(Error::invalid(
            reader.path(),
            None,
            format!("level {level} does not exist (the file has levels 0..{})", levels.saturating_sub(1)),
        ));
    }
    let attrs = reader.header().attributes;
    let mut mesh = Mesh { materials: reader.materials().to_vec(), ..Mesh::default() };
    let mut welded: HashMap<[u32; 3], u32> = HashMap::new();
    for i in reader.level_nodes(level) {
        let g = reader.read_node(i)?;
        let global: Vec<u32> = g
            .positions
            .iter()
            .map(|p| {
                let next = mesh.positions.len() as u32;
                *welded.entry(p.to_array().map(f32::to_bits)).or_insert_with(|| {
                    mesh.positions.push(*p);
                    next
                })
            })
            .collect();
        for r in &g.material_ranges {
            let faces = r.first_index as usize / 3..(r.first_index + r.index_count) as usize / 3;
            for f in faces {
                let c = &g.indices[3 * f..3 * f + 3];
                mesh.triangles.push([global[c[0] as usize], global[c[1] as usize], global[c[2] as usize]]);
                mesh.face_materials.push(r.material);
                for &v in c {
                    let v = v as usize;
                    if attrs.normals {
                        mesh.normals.push(g.normals[v]);
                    }
                    if attrs.uvs {
                        mesh.uvs.push(g.uvs[v]);
                    }
                    if attrs.colors {
                        mesh.colors.push(g.colors[v]);
                    }
                }
            }
        }
    }
    mesh.compute_face_geometry();
    Ok(mesh)
}
