//! Smooth per-corner normals for meshes that come without any, as scanners' PLY files often do
//! (seed 000: members without smooth shading normals are flat shaded and lose most of the image).
//!
//! The simplifier carries them down to every level. Where they are computed (not the input's),
//! the writer stores instead each level's own smooth normals as readers predict them
//! ([`crate::derived_normals`]), which cost almost nothing; the computed ones still decide where
//! a vertex splits at creases, and stay at vertices on open edges.

use crate::mesh::{Mesh, VertexFaces};
use glam::Vec3;
use rayon::prelude::*;

/// One normal per corner (corner `3f + k` belongs to `mesh.triangles[f][k]`): around each vertex,
/// the faces are split into fans at crease edges — edges whose two faces' normals differ by more
/// than `crease_angle` radians — and each fan gets the average of its face normals weighted by the
/// angle of each face at the vertex. A vertex without creases gets one normal, bit for bit the same
/// at all its corners, so the simplifier sees no seam there. Needs `mesh.face_normals`.
pub fn smooth_normals(mesh: &Mesh, crease_angle: f32) -> Vec<Vec3> {
    let vf = VertexFaces::build(mesh);
    let cos_crease = crease_angle.clamp(0.0, std::f32::consts::PI).cos();
    let per_vertex: Vec<Vec<(u32, Vec3)>> = (0..mesh.positions.len())
        .into_par_iter()
        .map(|v| vertex_corners(mesh, v as u32, &vf.faces[vf.offsets[v] as usize..vf.offsets[v + 1] as usize], cos_crease))
        .collect();
    let mut normals = vec![Vec3::ZERO; 3 * mesh.triangles.len()];
    for (corner, n) in per_vertex.into_iter().flatten() {
        normals[corner as usize] = n;
    }
    normals
}

/// The corners of vertex `v` in `faces` with their normals.
fn vertex_corners(mesh: &Mesh, v: u32, faces: &[u32], cos_crease: f32) -> Vec<(u32, Vec3)> {
    let corner = |f: u32| 3 * f + mesh.triangles[f as usize].iter().position(|&w| w == v).unwrap_or(0) as u32;
    let others = |f: u32| {
        let t = mesh.triangles[f as usize];
        let k = t.iter().position(|&w| w == v).unwrap_or(0);
        [t[(k + 1) % 3], t[(k + 2) % 3]]
    };
    let mut fan: Vec<usize> = (0..faces.len()).collect();
    fn root(fan: &mut [usize], mut i: usize) -> usize {
        while fan[i] != i {
            fan[i] = fan[fan[i]];
            i = fan[i];
        }
        i
    }
    for i in 0..faces.len() {
        let (fi, oi) = (faces[i], others(faces[i]));
        for (j, &fj) in faces.iter().enumerate().skip(i + 1) {
            let oj = others(fj);
            let share_edge = oi.iter().any(|w| oj.contains(w));
            let smooth = mesh.face_normals[fi as usize].dot(mesh.face_normals[fj as usize]) >= cos_crease;
            if share_edge && smooth {
                let (a, b) = (root(&mut fan, i), root(&mut fan, j));
                fan[a.max(b)] = a.min(b);
            }
        }
    }
    let mut sums = vec![Vec3::ZERO; faces.len()];
    for (i, &f) in faces.iter().enumerate() {
        let r = root(&mut fan, i);
        let [a, b] = others(f).map(|w| mesh.positions[w as usize] - mesh.positions[v as usize]);
        let angle = a.angle_between(b);
        if angle.is_finite() {
            sums[r] += mesh.face_normals[f as usize] * angle;
        }
    }
    faces
        .iter()
        .enumerate()
        .map(|(i, &f)| {
            let r = root(&mut fan, i);
            (corner(f), sums[r].try_normalize().unwrap_or(mesh.face_normals[f as usize]))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures;

    #[test]
    fn a_sphere_gets_radial_normals_shared_by_all_corners_of_a_vertex() {
        let mut m = fixtures::icosphere(3);
        m.normals.clear();
        let n = smooth_normals(&m, 60f32.to_radians());
        assert_eq!(n.len(), 3 * m.face_count());
        let mut first = vec![None; m.positions.len()];
        for (c, &normal) in n.iter().enumerate() {
            let v = m.triangles[c / 3][c % 3] as usize;
            let radial = m.positions[v].normalize();
            assert!(normal.dot(radial) > 0.999, "corner {c}: {normal} vs {radial}");
            let bits = normal.to_array().map(f32::to_bits);
            assert_eq!(*first[v].get_or_insert(bits), bits, "vertex {v} has one normal");
        }
    }

    #[test]
    fn a_cube_keeps_its_edges_as_creases_unless_the_angle_allows_smoothing() {
        let m = fixtures::cube();
        let creased = smooth_normals(&m, 60f32.to_radians());
        for (c, n) in creased.iter().enumerate() {
            assert!(n.dot(m.face_normals[c / 3]) > 0.9999, "corner {c} keeps its face's normal");
        }
        let smooth = smooth_normals(&m, 100f32.to_radians());
        for (c, n) in smooth.iter().enumerate() {
            let corner = m.positions[m.triangles[c / 3][c % 3] as usize].normalize();
            assert!(n.dot(corner) > 0.9999, "corner {c}: {n} points along the cube's diagonal {corner}");
        }
    }
}
