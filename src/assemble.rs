//! One level of a strata file as one [`Mesh`], for `strata extract` and for tests: every node of the
//! level is read and its node-local vertices are welded back by exact position.

use crate::error::{Error, Result};
use crate::format::{Attributes, ByteSource, NodeGeometry, Reader};
use crate::mesh::Mesh;
use std::collections::HashMap;

/// Every image of the file as its full level: the source's image file as it was imported.
pub fn images<S: ByteSource>(reader: &Reader<S>) -> Result<Vec<crate::texture::SourceImage>> {
    let t = reader.textures();
    (0..t.images.len() as u32)
        .map(|i| {
            let rec = &t.images[i as usize];
            let bytes = reader.read_image_level(i, 0)?;
            Ok(crate::texture::SourceImage { name: rec.name.clone(), codec: rec.codec, bytes: bytes.into() })
        })
        .collect()
}

/// All nodes of `level` assembled into one mesh: positions welded by exact bits, attributes on
/// corners, face materials from the material ranges, the file's material table and images.
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
    let mut mesh = Mesh { materials: reader.materials().to_vec(), images: images(reader)?, ..Mesh::default() };
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
        append_faces(&mut mesh, &g, &global, attrs);
    }
    mesh.compute_face_geometry();
    Ok(mesh)
}

/// Append the faces of node geometry `g` to `mesh`, its vertex `v` becoming `mesh` vertex
/// `vertex[v]`: triangles, face materials from its material ranges, and the corner attributes
/// `attrs` says it has.
pub fn append_faces(mesh: &mut Mesh, g: &NodeGeometry, vertex: &[u32], attrs: Attributes) {
    for r in &g.material_ranges {
        let faces = r.first_index as usize / 3..(r.first_index + r.index_count) as usize / 3;
        for f in faces {
            let c = &g.indices[3 * f..3 * f + 3];
            mesh.triangles.push([vertex[c[0] as usize], vertex[c[1] as usize], vertex[c[2] as usize]]);
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
