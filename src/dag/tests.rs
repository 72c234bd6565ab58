use super::cut::{cut, projected_errors, select, shown};
use super::*;
use crate::camera::Camera;
use crate::hierarchy::{self, HierarchyParams};
use crate::levels::position_key;
use crate::mesh::Adjacency;
use rustc_hash::FxHashMap;

fn built(mesh: Mesh, top_faces: usize) -> Dag {
    let adj = Adjacency::build(&mesh);
    let h = hierarchy::build(&mesh, &adj, &HierarchyParams::default());
    let level0 = h.levels[0].face_group.clone();
    build(mesh, &level0, &DagParams { top_faces, ..DagParams::default() }, &mut |_, _| {})
}

fn sphere() -> Dag {
    built(crate::fixtures::noisy_sphere(70, 0.08, 1), 600)
}

/// Directed edges (as position keys) of the faces of `nodes` that no face of them runs the other
/// way: 0 for a closed surface without cracks.
fn open_edges(dag: &Dag, nodes: &[u32]) -> usize {
    let mut count: FxHashMap<([u32; 3], [u32; 3]), i32> = FxHashMap::default();
    for &n in nodes {
        let node = &dag.nodes[n as usize];
        let mesh = &dag.levels[node.level as usize];
        for t in &mesh.triangles[node.faces.start as usize..node.faces.end as usize] {
            for k in 0..3 {
                let (a, b) = (position_key(mesh.positions[t[k] as usize]), position_key(mesh.positions[t[(k + 1) % 3] as usize]));
                if a < b {
                    *count.entry((a, b)).or_default() += 1;
                } else {
                    *count.entry((b, a)).or_default() -= 1;
                }
            }
        }
    }
    count.values().map(|c| c.unsigned_abs() as usize).sum()
}

#[test]
fn the_dag_keeps_its_records_consistent() {
    let dag = sphere();
    let levels = dag.levels.len();
    assert!(levels >= 4, "{levels} levels");
    assert!(dag.levels[levels - 1].triangles.len() <= 600);
    for (l, mesh) in dag.levels.iter().enumerate() {
        let r = dag.level_nodes(l);
        let mut next = 0;
        for n in &dag.nodes[r.start as usize..r.end as usize] {
            assert_eq!(n.faces.start, next, "level {l}: nodes cover the faces in order");
            assert!(!n.faces.is_empty());
            next = n.faces.end;
            assert_eq!(n.source == NONE, l == 0);
            assert_eq!(n.consumer == NONE, l == levels - 1);
        }
        assert_eq!(next as usize, mesh.triangles.len(), "level {l}: nodes cover every face");
    }
    for (g, group) in dag.groups.iter().enumerate() {
        assert!(!group.outputs.is_empty(), "group {g} made nothing");
        for o in group.outputs.clone() {
            assert_eq!(dag.nodes[o as usize].source, g as u32);
            assert_eq!(dag.nodes[o as usize].level, group.level);
        }
        assert!(!dag.children.get(g).is_empty());
        for &c in dag.children.get(g) {
            let child = &dag.nodes[c as usize];
            assert_eq!(child.consumer, g as u32);
            assert_eq!(child.level + 1, group.level);
            assert!(child.center.distance(group.center) + child.radius <= group.radius * (1.0 + 1e-5));
            if child.source != NONE {
                assert!(dag.groups[child.source as usize].error <= group.error, "errors grow along the DAG");
            }
        }
    }
    let mut sizes: Vec<usize> =
        dag.nodes[dag.level_nodes(0).start as usize..dag.level_nodes(0).end as usize].iter().map(|n| n.faces.len()).collect();
    sizes.sort_unstable();
    let largest = dag.nodes.iter().map(|n| n.faces.len()).max().unwrap();
    assert!(largest <= 4 * sizes[sizes.len() / 2], "largest node {largest}, level-0 median {}", sizes[sizes.len() / 2]);
}

#[test]
fn every_cut_is_closed_and_a_wrong_one_is_not() {
    let dag = sphere();
    // Any threshold, from any side: the shown nodes form a closed surface.
    let mut mixed = 0;
    for (i, dir) in crate::culling::sphere_directions(10).into_iter().enumerate() {
        // From close by (the near side much finer than the far side) to far away.
        let mut camera = Camera::framing(glam::Vec3::ZERO, 1.1, dir, 50f32.to_radians(), 640, 480);
        camera.eye = dir * (1.12 + 0.1 * i as f32);
        (camera.near, camera.far) = (0.01, 100.0);
        let p = projected_errors(&dag, &camera);
        for tau in (0..15).map(|k| 0.25 * 1.5f32.powi(k)) {
            let all: Vec<u32> = (0..dag.nodes.len() as u32).filter(|&n| shown(&dag.nodes[n as usize], &p, tau)).collect();
            let levels: std::collections::BTreeSet<u32> = all.iter().map(|&n| dag.nodes[n as usize].level).collect();
            mixed += (levels.len() > 2) as usize;
            assert_eq!(open_edges(&dag, &all), 0, "view {i}, τ {tau}: levels {levels:?}");
            assert!(!cut(&dag, &camera, tau).nodes.is_empty());
        }
    }
    assert!(mixed >= 3, "{mixed} cuts span three levels or more");
    // The control: one group of level 2 shown directly beside level 0 cracks.
    let g = dag.groups.iter().position(|g| g.level == 2).unwrap();
    let inside: rustc_hash::FxHashSet<u32> =
        dag.children.get(g).iter().flat_map(|&c| dag.children.get(dag.nodes[c as usize].source as usize).iter().copied()).collect();
    let mut wrong: Vec<u32> = dag.level_nodes(0).filter(|n| !inside.contains(n)).collect();
    wrong.extend(dag.groups[g].outputs.clone());
    assert!(open_edges(&dag, &wrong) > 0, "level 2 beside level 0 without the DAG's rule should crack");
}

#[test]
fn selection_under_budgets_gives_cuts_of_the_dag() {
    let dag = sphere();
    let mut rng = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let total = dag.levels[0].triangles.len();
    let mut limited = 0;
    for (i, dir) in crate::culling::sphere_directions(4).into_iter().enumerate() {
        let mut camera = Camera::framing(glam::Vec3::ZERO, 1.1, dir, 50f32.to_radians(), 640, 480);
        camera.eye = dir * (1.2 + 0.8 * i as f32);
        (camera.near, camera.far) = (0.01, 100.0);
        for tau in [0.5f32, 2.0, 8.0] {
            // No budget, nothing held: the threshold's cut.
            let free = select(&dag, &camera, tau, None, &|_| false);
            assert_eq!(free.shown, cut(&dag, &camera, tau).nodes, "view {i}, τ {tau}");
            for _ in 0..6 {
                let budget = (next() % total as u64) as usize;
                let held: rustc_hash::FxHashSet<u32> = (0..dag.groups.len() as u32).filter(|_| next() % 8 == 0).collect();
                let s = select(&dag, &camera, tau, Some(budget), &|g| held.contains(&g));
                let all: Vec<u32> = s.shown.iter().chain(&s.culled).copied().collect();
                assert_eq!(open_edges(&dag, &all), 0, "view {i}, τ {tau}, budget {budget}");
                let top = dag.level_nodes(dag.levels.len() - 1);
                assert!(s.faces <= budget || all.iter().all(|n| top.contains(n)), "{} faces over {budget}", s.faces);
                assert_eq!(s.faces, s.shown.iter().map(|&n| dag.nodes[n as usize].faces.len()).sum::<usize>());
                limited += (s.shown != free.shown) as usize;
            }
        }
    }
    assert!(limited > 20, "{limited} selections changed by budgets or held groups");
}

/// Level 0 cut into small nodes: the next level's nodes take their size from level 0's median,
/// unless `Bounds::node_faces` names the size (a partitioned build's merge, whose level 0 is the
/// cells' tops).
#[test]
fn nodes_take_the_size_the_bounds_name() {
    let mut mesh = crate::fixtures::noisy_sphere(70, 0.08, 1);
    mesh.compute_face_geometry();
    let faces = mesh.triangles.len();
    let labels: Vec<u32> = (0..faces as u32).map(|f| f / 24).collect();
    let level1 = |node_faces: Option<usize>| {
        let start = Start { mesh: mesh.clone(), labels: labels.clone(), made_by: Vec::new() };
        let dag = build_from(start, &DagParams::default(), &Bounds { levels: Some(1), pinned: None, node_faces }, &mut |_, _| {});
        let nodes = dag.level_nodes(1);
        let level_faces: usize = nodes.clone().map(|n| dag.nodes[n as usize].faces.len()).sum();
        (nodes.len(), level_faces)
    };
    let (median, faces_1) = level1(None);
    let (named, named_faces) = level1(Some(240));
    assert!(faces_1 > faces / 3 && named_faces > faces / 3, "{faces} faces: {faces_1}, {named_faces} at level 1");
    // A group of eight 24-face nodes keeps about 96 faces: four nodes of the median's size, one
    // of the size named.
    assert!(faces_1 / median <= 30, "level 0's median, 24 faces: {median} nodes of {faces_1} faces");
    assert!(named * 3 <= median && named_faces / named >= 72, "240 named: {named} nodes of {named_faces} faces, against {median}");
    // Two nodes of 48 faces from each group.
    let (small, small_faces) = level1(Some(48));
    assert!((34..=67).contains(&(small_faces / small)), "48 named: {small} nodes of {small_faces} faces");
}
