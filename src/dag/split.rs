//! Cutting a group's simplified faces into nodes of about level 0's size: bisection at the median
//! face centroid along the longest axis, so pieces come out compact and of even size.
//!
//! Measured and not kept (notes/dag.md): cutting by face normal for narrower cones scattered the
//! nodes; cutting with the grouping's cone rounds was mixed.

use crate::mesh::{box_of, Mesh};
use glam::Vec3;

/// Cut `faces` of `mesh` into `pieces` runs of about equal size, appended to `out` as face lists.
pub fn split(mesh: &Mesh, faces: &mut [u32], pieces: usize, out: &mut Vec<Vec<u32>>) {
    let centroid = |f: u32| -> Vec3 {
        let t = mesh.triangles[f as usize];
        (mesh.positions[t[0] as usize] + mesh.positions[t[1] as usize] + mesh.positions[t[2] as usize]) / 3.0
    };
    if pieces <= 1 || faces.len() < 2 {
        out.push(faces.to_vec());
        return;
    }
    let (lo, hi) = box_of(faces.iter().map(|&f| centroid(f))).unwrap_or_default();
    let axis = (hi - lo).max_position();
    let left = pieces / 2;
    let at = faces.len() * left / pieces;
    faces.select_nth_unstable_by(at, |&a, &b| centroid(a)[axis].total_cmp(&centroid(b)[axis]));
    let (a, b) = faces.split_at_mut(at);
    split(mesh, a, left, out);
    split(mesh, b, pieces - left, out);
}
