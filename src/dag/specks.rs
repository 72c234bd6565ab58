//! Small components leave a group's outputs: the DAG form of the tree's small-component rule
//! ([`crate::small_components`]). A scan's specks, a reconstruction's floating fragments or a soup
//! of separate triangles have nothing to collapse, so without it every level would copy them and the
//! top would never shrink.
//!
//! Within one group (simplified on its own, its border pinned), a whole component (faces joined
//! through shared positions) that touches no pinned position may be dropped from the outputs, its
//! size (the diagonal of the box of the input component it came from) counted in the group's
//! error: a front that draws the outputs instead of the children misses a piece no
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

use super::build::STALLED;
use super::gather::morton_runs;
use crate::levels::position_key;
use crate::mesh::{components_of, Mesh};
use glam::Vec3;
use rustc_hash::FxHashMap;

/// Drop from `out` (one group's simplified faces, made from `input`: `source_faces` names the input
/// face of each, [`crate::simplify::Simplified::source_faces`]) the components that may leave it,
/// by the rules above, `target` being the group's target face count; `pinned` says whether a
/// vertex at a position is pinned. A component's size is that of the input component it came
/// from. Returns the group's error: `error`, raised to the largest component dropped.
pub fn leave(out: &mut Mesh, source_faces: &[u32], input: &Mesh, target: usize, error: f32, pinned: &dyn Fn(Vec3) -> bool) -> f32 {
    let (count, label) = components_by_position(out);
    if count < 2 {
        return error;
    }
    let (before, before_label) = components_by_position(input);
    let mut lo = vec![Vec3::splat(f32::MAX); before];
    let mut hi = vec![Vec3::splat(f32::MIN); before];
    for (t, &c) in input.triangles.iter().zip(&before_label) {
        for &v in t {
            lo[c as usize] = lo[c as usize].min(input.positions[v as usize]);
            hi[c as usize] = hi[c as usize].max(input.positions[v as usize]);
        }
    }
    let mut faces = vec![0usize; count];
    let mut size = vec![0.0f32; count];
    let mut held = vec![false; count];
    for (f, (t, &c)) in out.triangles.iter().zip(&label).enumerate() {
        let c = c as usize;
        faces[c] += 1;
        let from = source_faces.get(f).and_then(|&s| before_label.get(s as usize)).map(|&b| b as usize);
        size[c] = size[c].max(match from {
            Some(b) => lo[b].distance(hi[b]),
            // Not from the input (never, by `Simplified`'s contract): too large to leave.
            None => f32::INFINITY,
        });
        held[c] |= t.iter().any(|&v| pinned(out.positions[v as usize]));
    }
    let largest = (0..count).max_by(|&a, &b| size[a].total_cmp(&size[b]).then(b.cmp(&a))).unwrap_or(0);
    let mut order: Vec<usize> = (0..count).filter(|&c| !held[c] && c != largest && size[c].is_finite()).collect();
    order.sort_by(|&a, &b| size[a].total_cmp(&size[b]).then(a.cmp(&b)));
    let stalled = out.triangles.len() as f64 > STALLED * input.triangles.len() as f64;
    let mut left = out.triangles.len();
    let mut raised = error;
    let mut gone = vec![false; count];
    for c in order {
        if !(size[c] <= error || (stalled && left > target)) {
            break;
        }
        gone[c] = true;
        left -= faces[c];
        raised = raised.max(size[c]);
    }
    if left < out.triangles.len() {
        let keep: Vec<usize> = (0..out.triangles.len()).filter(|&f| !gone[label[f] as usize]).collect();
        *out = std::mem::take(out).subset(&keep);
    }
    raised
}

/// Components of `mesh`'s faces joined through shared positions (a topology change may have cut a
/// vertex in two at one position: what touches there is one piece, whose removal would open a
/// hole): their count and each face's.
fn components_by_position(mesh: &Mesh) -> (usize, Vec<u32>) {
    let mut first: FxHashMap<[u32; 3], u32> = FxHashMap::default();
    let at: Vec<u32> =
        (0..mesh.positions.len() as u32).map(|v| *first.entry(position_key(mesh.positions[v as usize])).or_insert(v)).collect();
    let joined: Vec<[u32; 3]> = mesh.triangles.iter().map(|t| t.map(|v| at[v as usize])).collect();
    components_of(mesh.positions.len(), &joined)
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
    let bounds = mesh.positions.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    let centre = |faces: &[u32]| {
        let sum: Vec3 = faces.iter().flat_map(|&f| mesh.triangles[f as usize]).map(|v| mesh.positions[v as usize]).sum();
        sum / (3 * faces.len().max(1)) as f32
    };
    let (mut kept, mut specks) = (Vec::new(), Vec::new());
    for (p, faces) in pieces.into_iter().enumerate() {
        if touches[p] || faces.len() >= size {
            kept.push(faces);
        } else {
            specks.push(faces);
        }
    }
    let items: Vec<(Vec3, usize)> = specks.iter().map(|faces| (centre(faces), faces.len())).collect();
    for run in morton_runs(&items, bounds, size) {
        kept.push(run.into_iter().flat_map(|i| std::mem::take(&mut specks[i])).collect());
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
        let input = soup(8);
        let mut m = input.clone();
        let error = leave(&mut m, &[0, 1, 2, 3, 4, 5, 6, 7], &input, 4, 0.0, &|_| false);
        assert_eq!(m.triangles.len(), 4);
        // The four largest stay; the error is the largest dropped (the fourth, legs of 4).
        assert!(m.positions.iter().all(|p| p.x >= 40.0));
        assert!((error - 32f32.sqrt()).abs() < 1e-5, "{error}");
    }

    #[test]
    fn components_no_larger_than_the_error_leave_for_free_and_pinned_ones_stay() {
        // Not stalled (six of twelve faces kept), the error covers legs up to 3: the first three
        // could go, but the second is pinned.
        let input = soup(12);
        let mut m = input.clone().subset(&[0, 1, 2, 3, 4, 5]);
        let pinned = |p: Vec3| p == Vec3::new(10.0, 0.0, 0.0);
        let error = leave(&mut m, &[0, 1, 2, 3, 4, 5], &input, 3, 4.3, &pinned);
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
    fn pieces_touching_at_a_position_are_one_component() {
        // Triangles 0 and 1 meet at (1, 0, 0) through two vertices there (a topology change's cut);
        // triangle 2 is apart. Stalled at a target of 1: only triangle 2 may leave, and the
        // touching pair, the largest piece, stays whole.
        let mut input = Mesh::default();
        input.positions.extend([
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::X,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(1.5, 1.0, 0.0),
            Vec3::new(10.0, 0.0, 0.0),
            Vec3::new(10.5, 0.0, 0.0),
            Vec3::new(10.0, 0.5, 0.0),
        ]);
        input.triangles.extend([[0, 1, 2], [3, 4, 5], [6, 7, 8]]);
        input.compute_face_geometry();
        let mut m = input.clone();
        leave(&mut m, &[0, 1, 2], &input, 1, 0.0, &|_| false);
        assert_eq!(m.triangles.len(), 2);
        assert!(!m.positions.contains(&Vec3::new(10.0, 0.0, 0.0)));
    }

    #[test]
    fn the_largest_component_always_stays() {
        let input = soup(3);
        let mut m = input.clone();
        leave(&mut m, &[0, 1, 2], &input, 0, 100.0, &|_| false);
        assert_eq!(m.triangles.len(), 1);
        assert!(m.positions.contains(&Vec3::new(20.0, 3.0, 0.0)));
    }
}
