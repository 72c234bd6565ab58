//! Invariants of the level meshes: every group of level ℓ is a non-empty, edge-connected patch of
//! Mℓ, no level adds non-manifold edges, faces roughly halve, node errors grow up the tree, and
//! levels added above the grouping repeat its top partition only while the top is too large.

use strata::fixtures;
use strata::hierarchy::{build, HierarchyParams};
use strata::levels::{self, LevelParams};
use strata::mesh::{Adjacency, Mesh, NO_FACE};

fn check(name: &str, mesh: &Mesh) {
    let adj = Adjacency::build(mesh);
    let params = HierarchyParams { cluster_faces: 16, leaf_faces: 96, growth: 3, top_groups: 2, ..HierarchyParams::default() };
    let mut h = build(mesh, &adj, &params);
    let grouped = h.levels.len();
    let top_faces = 60;
    let lv = levels::build(mesh.clone(), &mut h, &LevelParams { ratio: 0.5, top_faces }, &mut |_| {});
    assert_eq!(lv.levels.len(), h.levels.len(), "{name}: one mesh per level");
    for l in grouped..h.levels.len() {
        assert!(lv.levels[l - 1].mesh.face_count() > top_faces, "{name} level {l} added below a small enough top");
        let (top, below) = (&h.levels[l], &h.levels[l - 1]);
        assert_eq!(top.groups.len(), below.groups.len(), "{name} level {l} repeats the partition");
        assert!((0..top.groups.len()).all(|g| top.children.get(g) == [g as u32] && below.parent[g] == g as u32));
    }
    if name == "noisy_sphere" {
        assert!(h.levels.len() > grouped, "{name}: a 10k-face mesh gets levels above its grouping");
    }
    assert!(h.levels.last().is_some_and(|t| t.parent.iter().all(|&p| p == strata::hierarchy::NO_PARENT)));
    let input_nonmanifold = adj.nonmanifold_edges.len();
    for (l, level) in lv.levels.iter().enumerate() {
        let m = &level.mesh;
        assert_eq!(m.validate(), Ok(()), "{name} level {l}");
        assert_eq!(level.face_group.len(), m.face_count());
        let groups = h.levels[l].groups.len();
        let a = Adjacency::build(m);
        assert!(a.nonmanifold_edges.len() <= input_nonmanifold, "{name} level {l} adds non-manifold edges");
        // Non-empty and edge-connected.
        let mut count = vec![0usize; groups];
        for &g in &level.face_group {
            count[g as usize] += 1;
        }
        assert!(count.iter().all(|&c| c > 0), "{name} level {l}: a group vanished");
        let mut reached = vec![false; groups];
        let mut seen = vec![false; m.face_count()];
        for start in 0..m.face_count() {
            let g = level.face_group[start] as usize;
            if reached[g] {
                continue;
            }
            reached[g] = true;
            let (mut stack, mut size) = (vec![start], 0);
            seen[start] = true;
            while let Some(f) = stack.pop() {
                size += 1;
                for &n in &a.face_neighbors[f] {
                    if n != NO_FACE && !seen[n as usize] && level.face_group[n as usize] as usize == g {
                        seen[n as usize] = true;
                        stack.push(n as usize);
                    }
                }
            }
            assert_eq!(size, count[g], "{name} level {l}: group {g} split");
        }
        if l > 0 {
            let below = &lv.levels[l - 1];
            assert!(m.face_count() < below.mesh.face_count(), "{name} level {l} is not coarser");
            for g in 0..groups {
                for &c in h.levels[l].children.get(g) {
                    assert!(level.group_error[g] >= below.group_error[c as usize], "{name} level {l}: error shrinks up the tree");
                }
            }
        }
    }
}

#[test]
fn level_meshes_keep_groups_as_patches() {
    check("noisy_sphere", &fixtures::noisy_sphere(30, 0.05, 3));
    check("cad_part", &fixtures::cad_part());
    check("open_grid", &fixtures::open_grid(40));
    check("two_material_box", &fixtures::two_material_box());
    for seed in 0..4 {
        check("random_blob", &fixtures::random_blob(seed, 4000));
    }
}
