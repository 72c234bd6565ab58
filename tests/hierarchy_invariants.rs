//! Invariants of the group hierarchy on fixtures and random meshes: a partition per level, connected
//! groups, nesting, cones that contain what they must, and culling tests that are never wrong.

use glam::Vec3;
use proptest::prelude::*;
use strata::cone::{facing_orthographic, facing_perspective, Facing};
use strata::culling::{measure, sphere_directions};
use strata::fixtures;
use strata::hierarchy::{build, Hierarchy, HierarchyParams, Level, NO_PARENT};
use strata::mesh::{Adjacency, Mesh, NO_FACE};

const TOL: f32 = 1e-4;

fn small_params() -> HierarchyParams {
    HierarchyParams { cluster_faces: 16, leaf_faces: 64, ..HierarchyParams::default() }
}

/// Every partition (clusters and levels) with the partition below it, if any.
fn partitions(h: &Hierarchy) -> Vec<(&Level, Option<&Level>)> {
    let mut v = vec![(&h.clusters, None)];
    v.extend(h.levels.iter().enumerate().map(|(i, l)| (l, Some(h.below(i)))));
    v
}

fn check_partition(mesh: &Mesh, adj: &Adjacency, level: &Level) {
    let nf = mesh.face_count();
    assert_eq!(level.face_group.len(), nf);
    let mut counts = vec![0u32; level.groups.len()];
    for &g in &level.face_group {
        counts[g as usize] += 1;
    }
    for (g, info) in level.groups.iter().enumerate() {
        assert!(counts[g] > 0, "group {g} is empty");
        assert_eq!(counts[g], info.faces, "group {g} face count");
    }
    // Edge-connected: a flood fill from each group's first face reaches all its faces.
    let mut seen = vec![false; nf];
    let mut reached = vec![0u32; level.groups.len()];
    for start in 0..nf {
        let g = level.face_group[start];
        if reached[g as usize] > 0 {
            continue;
        }
        let mut stack = vec![start];
        seen[start] = true;
        while let Some(f) = stack.pop() {
            reached[g as usize] += 1;
            for &n in &adj.face_neighbors[f] {
                if n != NO_FACE && !seen[n as usize] && level.face_group[n as usize] == g {
                    seen[n as usize] = true;
                    stack.push(n as usize);
                }
            }
        }
        assert_eq!(reached[g as usize], counts[g as usize], "group {g} is not edge-connected");
    }
    // Neighbour lists: symmetric, and exactly the groups across a shared edge.
    for f in 0..nf {
        for &n in &adj.face_neighbors[f] {
            let (a, b) = (level.face_group[f], if n == NO_FACE { continue } else { level.face_group[n as usize] });
            if a != b {
                assert!(level.neighbors.get(a as usize).contains(&b), "groups {a} and {b} share an edge but are not neighbours");
            }
        }
    }
    for g in 0..level.groups.len() {
        for &n in level.neighbors.get(g) {
            assert!(level.neighbors.get(n as usize).contains(&(g as u32)), "neighbours {g} and {n} not symmetric");
        }
    }
    // Cones contain every face normal; sphere and box contain every vertex.
    for (f, &g) in level.face_group.iter().enumerate() {
        let info = &level.groups[g as usize];
        assert!(info.cone.contains(mesh.face_normals[f], TOL), "face {f} normal outside the cone of group {g}");
        for &v in &mesh.triangles[f] {
            let p = mesh.positions[v as usize];
            assert!(p.distance(info.center) <= info.radius * (1.0 + 1e-5) + 1e-6, "vertex outside the sphere of group {g}");
            assert!(p.cmpge(info.min).all() && p.cmple(info.max).all(), "vertex outside the box of group {g}");
        }
    }
}

fn check_hierarchy(mesh: &Mesh, h: &Hierarchy) {
    let adj = Adjacency::build(mesh);
    assert!(!h.levels.is_empty());
    for (level, below) in partitions(h) {
        check_partition(mesh, &adj, level);
        let Some(below) = below else { continue };
        // Nesting: a face's group is the parent of its group below; children lists agree.
        for f in 0..mesh.face_count() {
            assert_eq!(level.face_group[f], below.parent[below.face_group[f] as usize], "face {f} breaks nesting");
        }
        for (g, info) in level.groups.iter().enumerate() {
            let children = level.children.get(g);
            assert!(!children.is_empty());
            for &c in children {
                assert_eq!(below.parent[c as usize], g as u32);
                assert!(info.cone.contains_cone(&below.groups[c as usize].cone, TOL), "child cone outside parent {g}");
            }
            assert_eq!(children.iter().map(|&c| below.groups[c as usize].faces).sum::<u32>(), info.faces);
        }
    }
    let top = h.levels.last().unwrap();
    assert!(top.parent.iter().all(|&p| p == NO_PARENT));
}

/// A deterministic pseudo-random unit vector stream.
fn directions(seed: u64, n: usize) -> Vec<Vec3> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let z = 2.0 * next() - 1.0;
            let phi = std::f64::consts::TAU * next();
            let r = (1.0 - z * z).sqrt();
            Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32)
        })
        .collect()
}

fn check_culling_is_conservative(mesh: &Mesh, h: &Hierarchy, seed: u64) {
    let (lo, hi) = mesh.bounds().unwrap();
    let (center, size) = (0.5 * (lo + hi), (hi - lo).length());
    let dirs = directions(seed, 24);
    for (level, _) in partitions(h) {
        for &d in &dirs {
            let eye = center + d * size * 0.8;
            for (f, &g) in level.face_group.iter().enumerate() {
                let info = &level.groups[g as usize];
                let n = mesh.face_normals[f];
                match facing_orthographic(&info.cone, d) {
                    Facing::Back => assert!(n.dot(d) <= 0.0, "orthographic: culled group {g} has a front-facing face"),
                    Facing::Front => assert!(n.dot(d) > 0.0, "orthographic: front group {g} has a back-facing face"),
                    Facing::Mixed => {}
                }
                let facing = facing_perspective(&info.cone, info.center, info.radius, eye);
                for &v in &mesh.triangles[f] {
                    let s = n.dot(eye - mesh.positions[v as usize]);
                    match facing {
                        Facing::Back => assert!(s <= 0.0, "perspective: culled group {g} has a front-facing face"),
                        Facing::Front => assert!(s > 0.0, "perspective: front group {g} has a back-facing face"),
                        Facing::Mixed => {}
                    }
                }
            }
        }
    }
    let stats = measure(h, mesh, 64);
    assert!(stats.faces_culled <= stats.faces_backfacing + 1e-9);
    assert!(stats.cost_ratio > 0.0);
}

#[test]
fn fixtures_satisfy_invariants() {
    let meshes = [
        ("cube", fixtures::cube()),
        ("icosphere", fixtures::icosphere(3)),
        ("noisy_sphere", fixtures::noisy_sphere(16, 0.05, 7)),
        ("cad_part", fixtures::cad_part()),
        ("open_grid", fixtures::open_grid(24)),
        ("nonmanifold", fixtures::nonmanifold()),
    ];
    for (name, mesh) in meshes {
        let adj = Adjacency::build(&mesh);
        let h = build(&mesh, &adj, &small_params());
        eprintln!("{name}: {} faces, {} clusters, {} levels", mesh.face_count(), h.clusters.groups.len(), h.levels.len());
        check_hierarchy(&mesh, &h);
        check_culling_is_conservative(&mesh, &h, 1);
    }
}

#[test]
fn top_level_reaches_the_requested_count_on_a_connected_mesh() {
    let mesh = fixtures::noisy_sphere(30, 0.05, 3);
    let adj = Adjacency::build(&mesh);
    let p = HierarchyParams { top_groups: 8, ..small_params() };
    let h = build(&mesh, &adj, &p);
    assert!(h.levels.last().unwrap().groups.len() <= 8);
    assert!(h.levels.len() >= 2);
}

#[test]
fn groups_never_span_components() {
    // Two spheres, far apart: no group may hold faces of both.
    let a = fixtures::icosphere(2);
    let mut mesh = a.clone();
    let offset = mesh.positions.len() as u32;
    mesh.positions.extend(a.positions.iter().map(|p| *p + Vec3::new(10.0, 0.0, 0.0)));
    mesh.triangles.extend(a.triangles.iter().map(|t| t.map(|v| v + offset)));
    mesh.face_materials.extend(a.face_materials.iter());
    mesh.normals.extend(a.normals.iter());
    mesh.uvs.extend(a.uvs.iter());
    mesh.colors.extend(a.colors.iter());
    mesh.compute_face_geometry();
    let adj = Adjacency::build(&mesh);
    let h = build(&mesh, &adj, &HierarchyParams { top_groups: 1, ..small_params() });
    let half = a.face_count();
    for level in &h.levels {
        for f in 0..half {
            for g in half..mesh.face_count() {
                assert_ne!(level.face_group[f], level.face_group[g]);
            }
        }
    }
    assert_eq!(h.levels.last().unwrap().groups.len(), 2);
}

#[test]
fn views_cover_the_sphere() {
    let dirs = sphere_directions(256);
    assert_eq!(dirs.len(), 256);
    assert!(dirs.iter().all(|d| (d.length() - 1.0).abs() < 1e-5));
    let mean: Vec3 = dirs.iter().copied().sum::<Vec3>() / 256.0;
    assert!(mean.length() < 0.01);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]
    #[test]
    fn random_meshes_satisfy_invariants(seed in 0u64..10_000, faces in 200usize..3000) {
        let mesh = fixtures::random_blob(seed, faces);
        let adj = Adjacency::build(&mesh);
        let h = build(&mesh, &adj, &small_params());
        check_hierarchy(&mesh, &h);
        check_culling_is_conservative(&mesh, &h, seed);
    }
}
