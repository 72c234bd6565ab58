//! Shared helpers of the format tests: small procedural meshes, their hierarchy, and level meshes
//! that reuse the input at every level (valid, if unsimplified).

#![allow(dead_code)]

use glam::{Vec2, Vec3};
use strata::hierarchy::{self, Hierarchy, HierarchyParams};
use strata::levels::{LevelMesh, LevelMeshes};
use strata::mesh::{Adjacency, Material, Mesh};

/// An icosphere of radius 1 subdivided `depth` times (20·4^depth faces), with smooth normals,
/// spherical UVs, colors from the position, and two materials split at z = 0.
pub fn icosphere(depth: u32) -> Mesh {
    let mut mesh = strata::fixtures::icosphere(depth);
    let corners: Vec<Vec3> = mesh.triangles.iter().flat_map(|t| t.map(|v| mesh.positions[v as usize])).collect();
    mesh.uvs = corners.iter().map(|p| Vec2::new(p.y.atan2(p.x), p.z.clamp(-1.0, 1.0).acos())).collect();
    mesh.colors =
        corners.iter().map(|p| [(p.x * 127.0 + 128.0) as u8, (p.y * 127.0 + 128.0) as u8, (p.z * 127.0 + 128.0) as u8, 255]).collect();
    mesh.face_materials =
        mesh.triangles.iter().map(|t| (t.iter().map(|&v| mesh.positions[v as usize].z).sum::<f32>() > 0.0) as u32).collect();
    mesh.materials = vec![
        Material { name: "north".into(), base_color: [0.9, 0.2, 0.1, 1.0], texture: Some("north.png".into()), ..Material::default() },
        Material { name: "south".into(), base_color: [0.1, 0.2, 0.9, 1.0], texture: None, ..Material::default() },
    ];
    mesh
}

/// A wavy `n`×`n`-cell grid (2n² faces), open, without corner attributes.
pub fn grid(n: u32) -> Mesh {
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
            positions.push(Vec3::new(x, y, 0.1 * (6.0 * x).sin() * (4.0 * y).cos()));
        }
    }
    let mut triangles = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let v = j * (n + 1) + i;
            triangles.push([v, v + 1, v + n + 2]);
            triangles.push([v, v + n + 2, v + n + 1]);
        }
    }
    Mesh { positions, triangles, ..Mesh::default() }.clean().expect("finite").0
}

/// Hierarchy parameters small enough for several levels on a few thousand faces.
pub fn small_params() -> HierarchyParams {
    HierarchyParams { cluster_faces: 16, leaf_faces: 96, growth: 3, top_groups: 2, ..HierarchyParams::default() }
}

/// The hierarchy of `mesh` and level meshes that reuse `mesh` at every level, with errors growing
/// by level.
pub fn build(mesh: &Mesh, params: &HierarchyParams) -> (Hierarchy, LevelMeshes) {
    let adj = Adjacency::build(mesh);
    let h = hierarchy::build(mesh, &adj, params);
    let levels = h
        .levels
        .iter()
        .enumerate()
        .map(|(l, level)| LevelMesh {
            mesh: mesh.clone(),
            face_group: level.face_group.clone(),
            group_error: vec![0.01 * l as f32; level.groups.len()],
        })
        .collect();
    (h, LevelMeshes { levels })
}

/// Bytes of a file written from `mesh` with `params`, in memory.
pub fn written(mesh: &Mesh, params: &HierarchyParams) -> (Vec<u8>, strata::format::WriteSummary) {
    written_as(mesh, params, strata::write::WriteOptions::default().encoding)
}

/// [`written`] in the format of `encoding`.
pub fn written_as(mesh: &Mesh, params: &HierarchyParams, encoding: strata::write::Encoding) -> (Vec<u8>, strata::format::WriteSummary) {
    let (h, lv) = build(mesh, params);
    let mut cur = std::io::Cursor::new(Vec::new());
    let opts = strata::write::WriteOptions { params: *params, tool: "strata test".into(), encoding, ..Default::default() };
    let summary = strata::write::write_to(&mut cur, &h, &lv, &opts).expect("write");
    (cur.into_inner(), summary)
}

/// An edge as the positions of its ends (bit patterns), lower first: the same for both
/// directions and for every copy of its vertices.
pub type Edge = ([u32; 3], [u32; 3]);

/// The [`Edge`] from `a` to `b`.
pub fn edge(a: Vec3, b: Vec3) -> Edge {
    let (a, b) = (a.to_array().map(f32::to_bits), b.to_array().map(f32::to_bits));
    if a <= b {
        (a, b)
    } else {
        (b, a)
    }
}

/// A face as the positions of its corners (bit patterns), rotated to start at the smallest while
/// keeping the winding; and its corner order under that rotation.
pub fn face_key(mesh: &Mesh, f: usize) -> ([[u32; 3]; 3], [usize; 3]) {
    let p = mesh.triangles[f].map(|v| mesh.positions[v as usize].to_array().map(f32::to_bits));
    let s = (0..3).min_by_key(|&k| p[k]).unwrap_or(0);
    let order = [s, (s + 1) % 3, (s + 2) % 3];
    (order.map(|k| p[k]), order)
}
