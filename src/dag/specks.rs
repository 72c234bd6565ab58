//! Small components leave a group's outputs: the DAG form of the tree's small-component rule
//! ([`crate::small_components`]). A scan's specks, a reconstruction's floating fragments or a soup
//! of separate triangles have nothing to collapse, so without it every level would copy them and the
//! top would never shrink.
//!
//! Within one group (simplified on its own, its border pinned), a whole component that touches no
//! pinned position may be dropped from the outputs, its size (the diagonal of its box) counted in
//! the group's error: a front that draws the outputs instead of the children misses a piece no
//! larger than the error it already claims, and the group's sphere encloses its children's, so
//! the projected error bounds what is missing. Pinned positions stay, so neighbours still meet
//! edge for edge (selection.md §9). A component leaves:
//! - when it is no larger than the group's error after simplification (it costs nothing);
//! - or, when the group did not shrink (the simplifier stalled), smallest first until the group is
//!   down to its target.
//!
//! The group's largest component always stays, so a group keeps at least one output.
//!
//! Level 0 has the same problem in another form: its nodes are the grouping's groups, which never
//! span two components, so a soup has a node per triangle and a skeleton larger than its geometry.
//! [`gather`] joins level-0 nodes that share no vertex with another and are smaller than the others
//! into nodes of the others' median size, in the Morton order of their centres, so that near ones
//! join.

use super::gather::morton;
use crate::mesh::{components, Mesh};
use glam::Vec3;

/// A group stalled when it kept more than this share of its faces.
const STALLED: f64 = 0.95;

/// Drop from `mesh` (one group's simplified faces, which had `before` faces and aim at `target`)
/// the components that may leave it, by the rules above; `pinned` says whether a vertex at a
/// position is pinned. Returns the group's error: `error`, raised to the largest component dropped.
pub fn leave(mesh: &mut Mesh, before: usize, target: usize, error: f32, pinned: &dyn Fn(Vec3) -> bool) -> f32 {
    let (count, label) = components(mesh);
    if count < 2 {
        return error;
    }
    let mut faces = vec![0usize; count];
    let mut lo = vec![Vec3::splat(f32::MAX); count];
    let mut hi = vec![Vec3::splat(f32::MIN); count];
    let mut held = vec![false; count];
    for (t, &c) in mesh.triangles.iter().zip(&label) {
        let c = c as usize;
        faces[c] += 1;
        for &v in t {
            let p = mesh.positions[v as usize];
            lo[c] = lo[c].min(p);
            hi[c] = hi[c].max(p);
            held[c] |= pinned(p);
        }
    }
    let size: Vec<f32> = (0..count).map(|c| lo[c].distance(hi[c])).collect();
    let largest = (0..count).max_by(|&a, &b| size[a].total_cmp(&size[b]).then(b.cmp(&a))).unwrap_or(0);
    let mut order: Vec<usize> = (0..count).filter(|&c| !held[c] && c != largest).collect();
    order.sort_by(|&a, &b| size[a].total_cmp(&size[b]).then(a.cmp(&b)));
    let stalled = mesh.triangles.len() as f64 > STALLED * before as f64;
    let mut left = mesh.triangles.len();
    let mut error = error;
    let mut gone = vec![false; count];
    for c in order {
        if !(size[c] <= error || (stalled && left > target)) {
            break;
        }
        gone[c] = true;
        left -= faces[c];
        error = error.max(size[c]);
    }
    if left < mesh.triangles.len() {
        let keep: Vec<usize> = (0..mesh.triangles.len()).filter(|&f| !gone[label[f] as usize]).collect();
        *mesh = std::mem::take(mesh).subset(&keep);
    }
    error
}

/// The size of the nodes specks join into when nothing else sets it: half the grouping's default
/// leaf.
const SPECK_NODE_FACES: usize = 256;

/// Level-0 nodes `pieces` (faces of `mesh` per node) with the small separate ones joined: a node
/// that shares no vertex with another and has fewer faces than the median of the others (or
/// [`SPECK_NODE_FACES`] when all are separate) joins the next such nodes in the Morton order of
/// their centres until it has that many. The others stay as they are, in their order; the joined
/// ones follow.
pub fn gather(mesh: &Mesh, pieces: Vec<Vec<u32>>) -> Vec<Vec<u32>> {
    let mut owner = vec![u32::MAX; mesh.positions.len()];
    let mut touches = vec![false; pieces.len()];
    for (p, faces) in pieces.iter().enumerate() {
        for &f in faces {
            for &v in &mesh.triangles[f as usize] {
                let o = &mut owner[v as usize];
                if *o == u32::MAX {
                    *o = p as u32;
                } else if *o != p as u32 {
                    touches[*o as usize] = true;
                    touches[p] = true;
                }
            }
        }
    }
    let mut sizes: Vec<usize> = pieces.iter().zip(&touches).filter(|(_, &t)| t).map(|(p, _)| p.len()).collect();
    sizes.sort_unstable();
    let size = sizes.get(sizes.len() / 2).copied().unwrap_or(SPECK_NODE_FACES).max(1);
    let (lo, hi) = mesh.positions.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    let scale = 1023.0 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let centre = |faces: &[u32]| {
        let sum: Vec3 = faces.iter().flat_map(|&f| mesh.triangles[f as usize]).map(|v| mesh.positions[v as usize]).sum();
        sum / (3 * faces.len().max(1)) as f32
    };
    let (mut kept, mut specks) = (Vec::new(), Vec::new());
    for (p, faces) in pieces.into_iter().enumerate() {
        if touches[p] || faces.len() >= size {
            kept.push(faces);
        } else {
            let c = ((centre(&faces) - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(1023.0)).as_uvec3();
            specks.push((morton(c.to_array()), p, faces));
        }
    }
    specks.sort_unstable_by_key(|s| (s.0, s.1));
    let mut run: Vec<u32> = Vec::new();
    for (_, _, faces) in specks {
        run.extend(faces);
        if run.len() >= size {
            kept.push(std::mem::take(&mut run));
        }
    }
    if !run.is_empty() {
        kept.push(run);
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` separate triangles of growing size along x, each with face geometry.
    fn soup(n: usize) -> Mesh {
        let mut m = Mesh::default();
        for i in 0..n {
            let (x, s) = (i as f32 * 10.0, 1.0 + i as f32);
            let b = m.positions.len() as u32;
            m.positions.extend([Vec3::new(x, 0.0, 0.0), Vec3::new(x + s, 0.0, 0.0), Vec3::new(x, s, 0.0)]);
            m.triangles.push([b, b + 1, b + 2]);
        }
        m.compute_face_geometry();
        m
    }

    #[test]
    fn a_stalled_group_drops_its_smallest_components_to_its_target() {
        let mut m = soup(8);
        let error = leave(&mut m, 8, 4, 0.0, &|_| false);
        assert_eq!(m.triangles.len(), 4);
        // The four largest stay; the error is the largest dropped (the fourth, legs of 4).
        assert!(m.positions.iter().all(|p| p.x >= 40.0));
        assert!((error - 32f32.sqrt()).abs() < 1e-5, "{error}");
    }

    #[test]
    fn components_no_larger_than_the_error_leave_for_free_and_pinned_ones_stay() {
        let mut m = soup(6);
        // Not stalled (it had 12 faces), the error covers legs up to 3: the first three could go,
        // but the second is pinned.
        let pinned = |p: Vec3| p == Vec3::new(10.0, 0.0, 0.0);
        let error = leave(&mut m, 12, 3, 4.3, &pinned);
        assert_eq!(m.triangles.len(), 4);
        assert!(m.positions.contains(&Vec3::new(10.0, 0.0, 0.0)));
        assert!(!m.positions.contains(&Vec3::new(0.0, 0.0, 0.0)) && !m.positions.contains(&Vec3::new(20.0, 0.0, 0.0)));
        assert_eq!(error, 4.3);
    }

    #[test]
    fn separate_small_nodes_join_and_the_others_stay() {
        // Eight separate triangles, and a strip of four faces sharing vertices, two nodes of two.
        let mut m = soup(8);
        let b = m.positions.len() as u32;
        m.positions.extend((0..6).map(|i| Vec3::new((i / 2) as f32, (i % 2) as f32, 50.0)));
        m.triangles.extend([[b, b + 1, b + 2], [b + 1, b + 3, b + 2], [b + 2, b + 3, b + 4], [b + 3, b + 5, b + 4]]);
        m.compute_face_geometry();
        let mut pieces: Vec<Vec<u32>> = (0..8).map(|f| vec![f]).collect();
        pieces.extend([vec![8, 9], vec![10, 11]]);
        let joined = gather(&m, pieces);
        // The strip's nodes stay; the triangles join in runs of the strip nodes' median, 2.
        assert_eq!(&joined[..2], &[vec![8, 9], vec![10, 11]]);
        assert_eq!(joined.len(), 6);
        let mut all: Vec<u32> = joined.iter().flatten().copied().collect();
        all.sort_unstable();
        assert_eq!(all, (0..12).collect::<Vec<u32>>());
        assert!(joined[2..].iter().all(|p| p.len() == 2));
        // All separate: runs of the default size.
        let joined = gather(&soup(600), (0..600).map(|f| vec![f]).collect());
        assert_eq!(joined.iter().map(Vec::len).collect::<Vec<_>>(), vec![SPECK_NODE_FACES, SPECK_NODE_FACES, 600 - 2 * SPECK_NODE_FACES]);
    }

    #[test]
    fn the_largest_component_always_stays() {
        let mut m = soup(3);
        leave(&mut m, 3, 0, 100.0, &|_| false);
        assert_eq!(m.triangles.len(), 1);
        assert!(m.positions.contains(&Vec3::new(20.0, 3.0, 0.0)));
    }
}
