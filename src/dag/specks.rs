//! Small components leave a group's outputs: the DAG form of the tree's small-component rule
//! ([`crate::small_components`]). A scan's specks, a reconstruction's floating fragments or a soup
//! of separate triangles have nothing to collapse, so without it every level would copy them and the
//! top would never shrink.
//!
//! Within one group (its border pinned; simplified in one queue with near groups), a whole
//! component (faces joined through shared positions) that touches no pinned position and no other
//! group may be dropped from the outputs, its
//! size (the diagonal of the box of the input component it came from) counted in the group's
//! error: a front that draws the outputs instead of the children misses a piece no
//! larger than the error it already claims, and the group's sphere encloses its children's, so
//! the projected error bounds what is missing. Pinned positions stay, so neighbours still meet
//! edge for edge (selection.md §9). A component leaves:
//! - when it is no larger than the group's error after simplification (it costs nothing);
//! - or, when the group stalled (the simplifier ran out of collapses short of its batch's target,
//!   and the group kept most of its faces), smallest first until the group is down to its target.
//!
//! The group's largest component always stays, so a group keeps at least one output.
//!
//! Level 0 has the same problem in another form: its nodes are the grouping's groups, which never
//! span two components, so a soup has a node per triangle and a skeleton larger than its geometry.
//! [`gather`] joins level-0 nodes that share no vertex with another and are smaller than the others
//! into nodes of the others' median size, in the Morton order of their centres, so that near ones
//! join.

use super::build::{median_size, STALLED};
use super::gather::{centre, morton_runs};
use crate::levels::position_key;
use crate::mesh::{components_of, Mesh};
use glam::Vec3;
use rustc_hash::FxHashMap;

/// What a batch of groups was simplified from, as [`leave`] reads it.
pub struct Batch<'a> {
    /// The batch's faces before simplification.
    pub input: &'a Mesh,
    /// The group of each face of `input` (`0..n`).
    pub input_groups: &'a [u32],
    /// The input face of each output face ([`crate::simplify::Simplified::source_faces`]).
    pub source_faces: &'a [u32],
    /// Each group's target face count.
    pub targets: &'a [usize],
    /// The simplifier ended above the batch's target (it ran out of collapses): groups that kept
    /// most of their faces have stalled.
    pub short: bool,
}

/// Drop from `out` (a batch's simplified faces, `out_groups` naming each face's group) the
/// components that may leave, by the rules above, group by group; `errors[g]` is group `g`'s
/// error, raised to the largest component it dropped. `pinned` says whether a vertex at a
/// position is pinned. A component's size is that of the input component it came from. A
/// component with faces of two groups stays (it could only join them through an unpinned
/// position they share).
pub fn leave(out: &mut Mesh, out_groups: &mut Vec<u32>, errors: &mut [f32], batch: &Batch, pinned: &dyn Fn(Vec3) -> bool) {
    let Batch { input, input_groups, source_faces, targets, short } = *batch;
    let (count, label) = components_by_position(out);
    if count < 2 {
        return;
    }
    let groups = errors.len();
    let (before, before_label) = components_by_position(input);
    let mut lo = vec![Vec3::splat(f32::MAX); before];
    let mut hi = vec![Vec3::splat(f32::MIN); before];
    for (t, &c) in input.triangles.iter().zip(&before_label) {
        for &v in t {
            lo[c as usize] = lo[c as usize].min(input.positions[v as usize]);
            hi[c as usize] = hi[c as usize].max(input.positions[v as usize]);
        }
    }
    let mut input_faces = vec![0usize; groups];
    for &g in input_groups {
        input_faces[g as usize] += 1;
    }
    let mut left = vec![0usize; groups];
    let mut faces = vec![0usize; count];
    let mut size = vec![0.0f32; count];
    let mut held = vec![false; count];
    let mut group = vec![u32::MAX; count];
    for (f, (t, &c)) in out.triangles.iter().zip(&label).enumerate() {
        let (c, g) = (c as usize, out_groups[f]);
        left[g as usize] += 1;
        faces[c] += 1;
        let from = source_faces.get(f).and_then(|&s| before_label.get(s as usize)).map(|&b| b as usize);
        size[c] = size[c].max(match from {
            Some(b) => lo[b].distance(hi[b]),
            // Not from the input (never, by `Simplified`'s contract): too large to leave.
            None => f32::INFINITY,
        });
        held[c] |= t.iter().any(|&v| pinned(out.positions[v as usize])) || (group[c] != u32::MAX && group[c] != g);
        group[c] = g;
    }
    // Each group's largest component stays.
    let mut largest = vec![usize::MAX; groups];
    for c in 0..count {
        let l = &mut largest[group[c] as usize];
        if *l == usize::MAX || size[c] > size[*l] {
            *l = c;
        }
    }
    let mut order: Vec<usize> = (0..count).filter(|&c| !held[c] && largest[group[c] as usize] != c && size[c].is_finite()).collect();
    order.sort_by(|&a, &b| size[a].total_cmp(&size[b]).then(a.cmp(&b)));
    let stalled: Vec<bool> = (0..groups).map(|g| short && left[g] as f64 > STALLED * input_faces[g] as f64).collect();
    let error = errors.to_vec();
    let mut done = vec![false; groups];
    let mut gone = vec![false; count];
    for c in order {
        let g = group[c] as usize;
        if done[g] {
            continue;
        }
        if !(size[c] <= error[g] || (stalled[g] && left[g] > targets[g])) {
            done[g] = true;
            continue;
        }
        gone[c] = true;
        left[g] -= faces[c];
        errors[g] = errors[g].max(size[c]);
    }
    if gone.iter().any(|&g| g) {
        let keep: Vec<usize> = (0..out.triangles.len()).filter(|&f| !gone[label[f] as usize]).collect();
        *out_groups = keep.iter().map(|&f| out_groups[f]).collect();
        *out = std::mem::take(out).subset(&keep);
    }
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
    let touching = pieces.iter().zip(&touches).filter(|(_, &t)| t).map(|(p, _)| p.len());
    let size = median_size(touching).unwrap_or(SPECK_NODE_FACES).max(1);
    let bounds = mesh.bounds().unwrap_or_default();
    let (mut kept, mut specks) = (Vec::new(), Vec::new());
    for (p, faces) in pieces.into_iter().enumerate() {
        if touches[p] || faces.len() >= size {
            kept.push(faces);
        } else {
            specks.push(faces);
        }
    }
    let items: Vec<(Vec3, usize)> = specks.iter().map(|faces| (centre(mesh, faces), faces.len())).collect();
    for run in morton_runs(&items, bounds, size) {
        kept.push(run.into_iter().flat_map(|i| std::mem::take(&mut specks[i])).collect());
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`leave`] for one group, stalled when it kept over 95 % of `input`; returns its error.
    fn alone(out: &mut Mesh, source_faces: &[u32], input: &Mesh, target: usize, error: f32, pinned: &dyn Fn(Vec3) -> bool) -> f32 {
        let (mut groups, mut errors) = (vec![0; out.triangles.len()], [error]);
        let short = out.triangles.len() > target;
        let input_groups = vec![0; input.triangles.len()];
        let batch = Batch { input, input_groups: &input_groups, source_faces, targets: &[target], short };
        leave(out, &mut groups, &mut errors, &batch, pinned);
        assert_eq!(groups.len(), out.triangles.len());
        errors[0]
    }

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
        let error = alone(&mut m, &[0, 1, 2, 3, 4, 5, 6, 7], &input, 4, 0.0, &|_| false);
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
        let error = alone(&mut m, &[0, 1, 2, 3, 4, 5], &input, 3, 4.3, &pinned);
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
        alone(&mut m, &[0, 1, 2], &input, 1, 0.0, &|_| false);
        assert_eq!(m.triangles.len(), 2);
        assert!(!m.positions.contains(&Vec3::new(10.0, 0.0, 0.0)));
    }

    #[test]
    fn groups_of_a_batch_leave_on_their_own_and_only_when_it_ran_short() {
        // Six separate triangles, groups 0 0 0 1 1 1, every face kept, target 1 each; then two
        // more faces sharing a vertex, one in each group.
        let mut input = soup(6);
        let b = input.positions.len() as u32;
        input.positions.extend([Vec3::new(100.0, 0.0, 0.0), Vec3::new(100.5, 0.0, 0.0), Vec3::new(100.0, 0.5, 0.0)]);
        input.positions.extend([Vec3::new(99.5, 0.0, 0.0), Vec3::new(100.0, -0.5, 0.0)]);
        input.triangles.extend([[b, b + 1, b + 2], [b, b + 3, b + 4]]);
        input.compute_face_geometry();
        let groups = [0, 0, 0, 1, 1, 1, 0, 1];
        let source: Vec<u32> = (0..8).collect();
        let run = |short: bool| {
            let (mut m, mut g, mut errors) = (input.clone(), groups.to_vec(), [0.0f32, 0.0]);
            let batch = Batch { input: &input, input_groups: &groups, source_faces: &source, targets: &[1, 1], short };
            leave(&mut m, &mut g, &mut errors, &batch, &|_| false);
            (m, g, errors)
        };
        // Not short: the batch reached its target elsewhere, so nothing has stalled.
        assert_eq!(run(false).0.triangles.len(), 8);
        // Short: each group keeps its largest component; the pair across the groups stays whole.
        let (m, g, errors) = run(true);
        assert_eq!(m.triangles.len(), 4);
        assert_eq!(g.iter().filter(|&&x| x == 0).count(), 2);
        assert!(m.positions.contains(&Vec3::new(20.0, 3.0, 0.0)) && m.positions.contains(&Vec3::new(50.0, 6.0, 0.0)));
        assert!(m.positions.contains(&Vec3::new(99.5, 0.0, 0.0)));
        assert!((errors[0] - 8f32.sqrt()).abs() < 1e-5 && (errors[1] - 50f32.sqrt()).abs() < 1e-5, "{errors:?}");
    }

    #[test]
    fn the_largest_component_always_stays() {
        let input = soup(3);
        let mut m = input.clone();
        alone(&mut m, &[0, 1, 2], &input, 0, 100.0, &|_| false);
        assert_eq!(m.triangles.len(), 1);
        assert!(m.positions.contains(&Vec3::new(20.0, 3.0, 0.0)));
    }
}
