//! Unit tests of the simplifier.

use super::{simplify, simplify_pinned, Simplified, SimplifyOptions};
use crate::fixtures;
use crate::mesh::{Adjacency, Material, Mesh, VertexFaces, NO_FACE};
use glam::{Vec2, Vec3};
use proptest::prelude::*;

/// A deterministic hash in [-0.5, 0.5).
fn noise(i: u64) -> f32 {
    let mut z = i.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 31)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    ((z >> 40) as f32 / (1u64 << 24) as f32) - 0.5
}

/// An icosphere without normals whose vertices move radially by independent white noise of
/// `amount` (peak to peak): neighbours jump independently, which the flip and shape checks must
/// survive. `fixtures::noisy_sphere` is smooth noise over a cube-sphere, a gentler surface.
fn rough_sphere(levels: u32, amount: f32, seed: u64) -> Mesh {
    let mut m = fixtures::icosphere(levels);
    m.normals.clear();
    for (i, p) in m.positions.iter_mut().enumerate() {
        *p *= 1.0 + amount * noise(seed ^ i as u64);
    }
    m.compute_face_geometry();
    m
}

/// An icosphere with smooth normals, a spherical UV map whose seam runs along one meridian,
/// and two materials (upper and lower half).
fn seamed_sphere(levels: u32) -> Mesh {
    let mut m = fixtures::icosphere(levels);
    // Normals of the rotated sphere are set below with the UVs.
    m.normals.clear();
    // Rotate slightly so no vertex sits exactly on the poles' singular meridian.
    for p in &mut m.positions {
        *p = glam::Quat::from_rotation_z(0.1) * *p;
    }
    m.compute_face_geometry();
    let u_of = |p: Vec3| (p.y.atan2(p.x) / std::f32::consts::TAU).rem_euclid(1.0);
    for t in &m.triangles {
        let mut uv = t.map(|v| {
            let p = m.positions[v as usize];
            Vec2::new(u_of(p), p.z.acos() / std::f32::consts::PI)
        });
        let hi = uv.iter().map(|c| c.x).fold(0.0, f32::max);
        for c in &mut uv {
            if hi - c.x > 0.5 {
                c.x += 1.0;
            }
        }
        m.uvs.extend(uv);
        m.normals.extend(t.map(|v| m.positions[v as usize]));
    }
    m.face_materials = m.triangles.iter().map(|t| u32::from(t.iter().map(|&v| m.positions[v as usize].z).sum::<f32>() > 0.0)).collect();
    m.materials = vec![Material::default(), Material { name: "top".into(), ..Material::default() }];
    m
}

/// A grid with a fin: a third face on one interior edge.
fn fin() -> Mesh {
    let mut m = fixtures::open_grid(12);
    let (a, b) = (m.triangles[40][0], m.triangles[40][2]);
    m.positions.push(Vec3::new(0.45, 0.3, 1.0));
    m.triangles.push([a, b, m.positions.len() as u32 - 1]);
    m.face_materials.push(0);
    m.compute_face_geometry();
    // The fin's corners: its own face normal, and UVs (x, y) as on the grid.
    let t = *m.triangles.last().expect("the fin");
    m.normals.extend([*m.face_normals.last().expect("the fin"); 3]);
    m.uvs.extend(t.map(|v| m.positions[v as usize].truncate()));
    m
}

/// Groups as edge-connected patches around `k` seed faces (breadth-first from each seed).
fn patches(mesh: &Mesh, k: usize) -> Vec<u32> {
    let adj = Adjacency::build(mesh);
    let nf = mesh.triangles.len();
    let mut label = vec![u32::MAX; nf];
    let mut queue = std::collections::VecDeque::new();
    for g in 0..k {
        let f = g * nf / k;
        if label[f] == u32::MAX {
            label[f] = g as u32;
            queue.push_back(f);
        }
    }
    while let Some(f) = queue.pop_front() {
        for &nb in &adj.face_neighbors[f] {
            if nb != NO_FACE && label[nb as usize] == u32::MAX {
                label[nb as usize] = label[f];
                queue.push_back(nb as usize);
            }
        }
    }
    // Faces unreachable through manifold edges (a fin) get a group of their own.
    let mut next = k as u32;
    for l in &mut label {
        if *l == u32::MAX {
            *l = next;
            next += 1;
        }
    }
    label
}

/// Number of edge-connected pieces of each group.
fn group_pieces(mesh: &Mesh, groups: &[u32]) -> Vec<usize> {
    let adj = Adjacency::build(mesh);
    let n = groups.iter().max().map_or(0, |&g| g as usize + 1);
    let mut seen = vec![false; groups.len()];
    let mut pieces = vec![0; n];
    for f in 0..groups.len() {
        if seen[f] {
            continue;
        }
        pieces[groups[f] as usize] += 1;
        seen[f] = true;
        let mut stack = vec![f];
        while let Some(g) = stack.pop() {
            for &nb in &adj.face_neighbors[g] {
                if nb != NO_FACE && !seen[nb as usize] && groups[nb as usize] == groups[f] {
                    seen[nb as usize] = true;
                    stack.push(nb as usize);
                }
            }
        }
    }
    pieces
}

fn bowtie_vertices(mesh: &Mesh) -> usize {
    let adj = Adjacency::build(mesh);
    let vf = VertexFaces::build(mesh);
    (0..mesh.vertex_count() as u32)
        .filter(|&v| {
            let faces = vf.of(v);
            let Some(&first) = faces.first() else { return false };
            let mut seen = vec![first];
            let mut stack = vec![first];
            while let Some(f) = stack.pop() {
                let t = mesh.triangles[f as usize];
                for k in 0..3 {
                    let nb = adj.face_neighbors[f as usize][k];
                    if (t[k] == v || t[(k + 1) % 3] == v) && nb != NO_FACE && !seen.contains(&nb) {
                        seen.push(nb);
                        stack.push(nb);
                    }
                }
            }
            seen.len() != faces.len()
        })
        .count()
}

fn euler(mesh: &Mesh) -> i64 {
    let adj = Adjacency::build(mesh);
    let interior = adj.face_neighbors.iter().flatten().filter(|&&n| n != NO_FACE).count() / 2;
    let edges = interior + adj.boundary_edges;
    mesh.vertex_count() as i64 - edges as i64 + mesh.face_count() as i64
}

/// Properties every output must have: valid arrays, no degenerate or duplicate face, no new
/// non-manifold edge or vertex, same Euler characteristic and border count on manifold input.
fn check(input: &Mesh, out: &Simplified) {
    check_manifold(input, out);
    if Adjacency::build(input).nonmanifold_edges.is_empty() {
        assert_eq!(euler(&out.mesh), euler(input), "topology changed");
    }
}

/// Valid, no repeated or degenerate faces, no more non-manifold edges or vertices than the input.
fn check_manifold(input: &Mesh, out: &Simplified) {
    let m = &out.mesh;
    assert_eq!(m.validate(), Ok(()));
    let mut keys: Vec<[u32; 3]> = m
        .triangles
        .iter()
        .map(|t| {
            let mut k = *t;
            k.sort_unstable();
            k
        })
        .collect();
    assert!(keys.iter().all(|k| k[0] != k[1] && k[1] != k[2]), "face with a repeated vertex");
    keys.sort_unstable();
    keys.dedup();
    assert_eq!(keys.len(), m.face_count(), "duplicate faces");
    assert!(m.face_areas.iter().all(|&a| a > 0.0), "degenerate face");
    let (ai, ao) = (Adjacency::build(input), Adjacency::build(m));
    assert!(ao.nonmanifold_edges.len() <= ai.nonmanifold_edges.len());
    assert!(bowtie_vertices(m) <= bowtie_vertices(input));
    let used = m.triangles.iter().flatten().collect::<std::collections::HashSet<_>>().len();
    assert_eq!(used, m.vertex_count(), "unused vertices");
    assert!(out.error.is_finite() && out.error >= 0.0);
}

fn opts(target_faces: usize) -> SimplifyOptions {
    SimplifyOptions { target_faces, ..SimplifyOptions::default() }
}

#[test]
fn same_face_count_changes_nothing() {
    for m in [fixtures::icosphere(2), seamed_sphere(2), fixtures::open_grid(6), fin()] {
        let out = simplify(&m, None, &opts(m.face_count()));
        assert_eq!(out.mesh, m);
        assert_eq!(out.error, 0.0);
        let groups = patches(&m, 5);
        let out = simplify(&m, Some(&groups), &opts(m.face_count() + 10));
        assert_eq!((out.mesh, out.face_groups), (m, groups));
        assert!(out.group_error.iter().all(|&e| e == 0.0));
    }
}

#[test]
fn sphere_reaches_target_without_flips() {
    let m = rough_sphere(4, 0.02, 3);
    for target in [m.face_count() / 2, m.face_count() / 10, m.face_count() / 100] {
        let out = simplify(&m, None, &opts(target));
        check(&m, &out);
        assert!(out.mesh.face_count() <= target && out.mesh.face_count() + 2 >= target, "{} for {target}", out.mesh.face_count());
        // No face turned beyond the bound from its input face; none faces inward (no folds).
        let cos_turn = SimplifyOptions::default().max_normal_turn.cos();
        for ((t, n), &f) in out.mesh.triangles.iter().zip(&out.mesh.face_normals).zip(&out.source_faces) {
            assert!(n.dot(m.face_normals[f as usize]) >= cos_turn - 1e-5, "face {f} turned to {n}");
            let c = t.iter().map(|&v| out.mesh.positions[v as usize]).sum::<Vec3>();
            assert!(n.dot(c.normalize()) > 0.0, "face {f} faces inward: {n} at {c}");
        }
        let d = crate::distance::surface_distance(&m, &out.mesh, 20_000, 1);
        assert!(d.max < 0.2 && out.error < 0.2, "{d:?} {}", out.error);
    }
    // A smooth sphere at 512 faces: a polyhedron that fine is about 0.01 from the sphere.
    let smooth = fixtures::icosphere(4);
    let out = simplify(&smooth, None, &opts(smooth.face_count() / 10));
    let d = crate::distance::surface_distance(&smooth, &out.mesh, 20_000, 1);
    assert!(d.max < 0.03 && d.mean < 0.006, "{d:?}");
}

#[test]
fn borders_stay_in_place() {
    let m = fixtures::open_grid(24);
    let out = simplify(&m, None, &opts(m.face_count() / 20));
    check(&m, &out);
    let on_input_border = |p: Vec3| p.x == 0.0 || p.x == 1.0 || p.y == 0.0 || p.y == 1.0;
    let ao = Adjacency::build(&out.mesh);
    let input_positions: std::collections::HashSet<[u32; 3]> = m.positions.iter().map(|p| p.to_array().map(f32::to_bits)).collect();
    for (f, t) in out.mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            if ao.face_neighbors[f][k] == NO_FACE {
                let (p, q) = (out.mesh.positions[t[k] as usize], out.mesh.positions[t[(k + 1) % 3] as usize]);
                assert!(on_input_border(p) && input_positions.contains(&p.to_array().map(f32::to_bits)), "border vertex moved to {p}");
                // Both ends on the same side of the square.
                assert!(
                    p.x == q.x && (p.x == 0.0 || p.x == 1.0) || p.y == q.y && (p.y == 0.0 || p.y == 1.0),
                    "border edge {p} {q} cuts a corner"
                );
            }
        }
    }
    assert!(out.mesh.face_count() <= m.face_count() / 20);
    // Interior vertices never land on the border line.
    let mut border = std::collections::HashSet::new();
    for (f, t) in out.mesh.triangles.iter().enumerate() {
        for k in (0..3).filter(|&k| ao.face_neighbors[f][k] == NO_FACE) {
            border.extend([t[k], t[(k + 1) % 3]]);
        }
    }
    for v in 0..out.mesh.vertex_count() as u32 {
        if !border.contains(&v) {
            assert!(!on_input_border(out.mesh.positions[v as usize]));
        }
    }
}

#[test]
fn seams_and_material_borders_keep_their_topology() {
    let m = seamed_sphere(4);
    let mat_border_edges = |mesh: &Mesh| {
        let adj = Adjacency::build(mesh);
        let mut count = vec![0u32; mesh.vertex_count()];
        let mut edges = 0;
        for (f, t) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let nb = adj.face_neighbors[f][k];
                if nb != NO_FACE && (f as u32) < nb && mesh.face_materials[f] != mesh.face_materials[nb as usize] {
                    edges += 1;
                    count[t[k] as usize] += 1;
                    count[t[(k + 1) % 3] as usize] += 1;
                }
            }
        }
        (edges, count)
    };
    let out = simplify(&m, None, &opts(m.face_count() / 20));
    check(&m, &out);
    let o = &out.mesh;
    assert!(o.face_count() <= m.face_count() / 10, "only reached {}", o.face_count());
    // The material border is still one closed loop.
    let (edges, count) = mat_border_edges(o);
    assert!(edges >= 3 && count.iter().all(|&c| c == 0 || c == 2), "{edges}");
    let loop_vertices = count.iter().filter(|&&c| c == 2).count();
    assert_eq!(loop_vertices, edges);
    assert!(edges < mat_border_edges(&m).0, "the border was simplified too");
    // Materials: both still present, each an edge-connected region.
    assert_eq!(group_pieces(o, &o.face_materials), vec![1, 1]);
    // Across every interior edge, corners agree except across the UV seam, where u jumps by 1.
    let adj = Adjacency::build(o);
    let mut seam_edges = 0;
    for (f, t) in o.triangles.iter().enumerate() {
        for k in 0..3 {
            let nb = adj.face_neighbors[f][k] as usize;
            if nb == NO_FACE as usize || o.face_materials[f] != o.face_materials[nb] {
                continue;
            }
            let mut jump = false;
            for v in [t[k], t[(k + 1) % 3]] {
                let (c0, c1) =
                    (3 * f + (0..3).position(|i| t[i] == v).unwrap(), 3 * nb + (0..3).position(|i| o.triangles[nb][i] == v).unwrap());
                assert_eq!(o.normals[c0], o.normals[c1]);
                let d = o.uvs[c0] - o.uvs[c1];
                assert!(d.y == 0.0 && (d.x == 0.0 || (d.x.abs() - 1.0).abs() < 1e-6), "uv torn: {d}");
                jump |= d.x != 0.0;
            }
            seam_edges += usize::from(jump);
        }
    }
    assert!(seam_edges > 0, "the UV seam vanished");
    // Interpolated corners still roughly follow the spherical map, away from poles and seam.
    for (c, uv) in o.uvs.iter().enumerate() {
        let p = o.positions[o.triangles[c / 3][c % 3] as usize];
        if p.z.abs() < 0.8 {
            let v = p.z.clamp(-1.0, 1.0).acos() / std::f32::consts::PI;
            assert!((uv.y - v).abs() < 0.05, "uv {uv} at {p}");
        }
    }
}

/// `n` tori side by side, each a ring of `ring` triangular cross-sections: thin handles.
fn tori(n: u32, ring: u32) -> Mesh {
    let mut m = Mesh::default();
    for k in 0..n {
        let base = m.positions.len() as u32;
        for i in 0..ring {
            let phi = i as f32 / ring as f32 * std::f32::consts::TAU;
            for j in 0..3 {
                let theta = j as f32 / 3.0 * std::f32::consts::TAU;
                let r = 1.0 + 0.1 * theta.cos();
                m.positions.push(Vec3::new(3.0 * k as f32 + r * phi.cos(), r * phi.sin(), 0.1 * theta.sin()));
            }
        }
        let id = |i: u32, j: u32| base + (i % ring) * 3 + j % 3;
        for i in 0..ring {
            for j in 0..3 {
                m.triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                m.triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
    }
    m.face_materials = vec![0; m.triangles.len()];
    m.materials = vec![Material::default()];
    m.compute_face_geometry();
    m
}

/// The pairs of groups (lower label first) that share an edge.
fn group_pairs(mesh: &Mesh, groups: &[u32]) -> std::collections::BTreeSet<(u32, u32)> {
    let adj = Adjacency::build(mesh);
    let mut pairs = std::collections::BTreeSet::new();
    for (f, around) in adj.face_neighbors.iter().enumerate() {
        for &nb in around.iter().filter(|&&nb| nb != NO_FACE) {
            let (a, b) = (groups[f], groups[nb as usize]);
            if a != b {
                pairs.insert((a.min(b), a.max(b)));
            }
        }
    }
    pairs
}

#[test]
fn topology_changes_reach_targets_that_handles_block() {
    let m = tori(3, 40);
    assert_eq!(Adjacency::build(&m).boundary_edges, 0);
    let kept = simplify(&m, None, &opts(12));
    check(&m, &kept);
    assert!(kept.mesh.face_count() > 12, "a torus keeps more than 4 faces: {}", kept.mesh.face_count());
    for target in [60, 12, 0] {
        let changed = simplify(&m, None, &SimplifyOptions { topology: true, ..opts(target) });
        check_manifold(&m, &changed);
        assert!(changed.mesh.face_count() <= target, "{} faces for {target}", changed.mesh.face_count());
        let a = Adjacency::build(&changed.mesh);
        assert_eq!((a.boundary_edges, a.nonmanifold_edges.len()), (0, 0), "still closed and manifold");
        assert_eq!(changed.source_faces.len(), changed.mesh.face_count());
        assert!(changed.source_faces.iter().all(|&f| (f as usize) < m.face_count()));
    }
    // A target the rules reach without changing topology is reached the same way with the option.
    let easy = opts(m.face_count() / 2);
    assert_eq!(simplify(&m, None, &easy), simplify(&m, None, &SimplifyOptions { topology: true, ..easy.clone() }));
    // An error limit holds for topology changes too: the tori's tubes are 0.1 across.
    let limited = simplify(&m, None, &SimplifyOptions { topology: true, max_error: Some(0.01), ..opts(12) });
    check(&m, &limited);
    assert!(limited.error <= 0.01, "{}", limited.error);
    // Groups that meet (two per torus): cuts only where every face around is of one group, so
    // groups still meet where they met and nowhere else, keep faces, and caps take their labels.
    let groups = patches(&m, 6);
    assert!((0..6).all(|g| groups.contains(&g)));
    let grouped = simplify(&m, Some(&groups), &opts(12));
    check(&m, &grouped);
    let meeting = simplify(&m, Some(&groups), &SimplifyOptions { topology: true, ..opts(12) });
    check_manifold(&m, &meeting);
    assert!(
        meeting.mesh.face_count() < grouped.mesh.face_count(),
        "{} faces, {} without cuts",
        meeting.mesh.face_count(),
        grouped.mesh.face_count()
    );
    assert_eq!(group_pairs(&meeting.mesh, &meeting.face_groups), group_pairs(&m, &groups));
    for (f, &g) in meeting.face_groups.iter().enumerate() {
        assert_eq!(groups[meeting.source_faces[f] as usize], g, "face {f} has its source's group");
    }
    // Groups that are whole components (one torus each) allow it: cuts, but no group loses its
    // last faces (a tetrahedron goes only from a group with more), and caps take their group's label.
    let groups = patches(&m, 3);
    let whole = simplify(&m, Some(&groups), &SimplifyOptions { topology: true, ..opts(12) });
    check_manifold(&m, &whole);
    assert!(
        whole.mesh.face_count() < grouped.mesh.face_count(),
        "{} faces, {} without cuts",
        whole.mesh.face_count(),
        grouped.mesh.face_count()
    );
    for g in 0..3u32 {
        assert!(whole.face_groups.contains(&g), "group {g} kept faces");
    }
    for (f, &g) in whole.face_groups.iter().enumerate() {
        assert_eq!(groups[whole.source_faces[f] as usize], g, "face {f} has its source's group");
    }
    assert!(whole.group_error.iter().all(|&e| e > 0.0));
    // Every error lands in some group, dropped tetrahedra's too.
    for target in [12, 0] {
        let s = simplify(&m, Some(&groups), &SimplifyOptions { topology: true, ..opts(target) });
        let most = s.group_error.iter().copied().fold(0.0f32, f32::max);
        assert!(most >= s.error * 0.999, "target {target}: groups claim {most}, the simplification {}", s.error);
    }
}

#[test]
fn non_manifold_fin_is_left_alone() {
    let m = fin();
    let out = simplify(&m, None, &opts(m.face_count() / 10));
    check(&m, &out);
    let ai = Adjacency::build(&m);
    let ao = Adjacency::build(&out.mesh);
    assert_eq!(ao.nonmanifold_edges.len(), 1);
    let ends = |mesh: &Mesh, e: [u32; 2]| e.map(|v| mesh.positions[v as usize]);
    let (mut a, mut b) = (ends(&m, ai.nonmanifold_edges[0]), ends(&out.mesh, ao.nonmanifold_edges[0]));
    a.sort_by(|x, y| x.x.total_cmp(&y.x));
    b.sort_by(|x, y| x.x.total_cmp(&y.x));
    assert_eq!(a, b);
    assert!(out.mesh.face_count() < m.face_count() / 4);
}

#[test]
fn groups_stay_connected_when_simplified_hard() {
    let cases = [(rough_sphere(4, 0.05, 9), 40), (fixtures::open_grid(40), 25), (seamed_sphere(4), 30), (fin(), 6)];
    for (m, k) in cases {
        let groups = patches(&m, k);
        let n_groups = groups.iter().max().map_or(0, |&g| g as usize + 1);
        assert!(group_pieces(&m, &groups).iter().all(|&p| p == 1));
        let out = simplify(&m, Some(&groups), &opts(m.face_count() / 100));
        check(&m, &out);
        assert_eq!(out.face_groups.len(), out.mesh.face_count());
        assert_eq!(out.group_error.len(), n_groups);
        let pieces = group_pieces(&out.mesh, &out.face_groups);
        assert_eq!(pieces.len(), n_groups);
        assert!(pieces.iter().all(|&p| p == 1), "a group split or vanished: {pieces:?}");
        assert!(out.mesh.face_count() < m.face_count() / 3, "{} of {}", out.mesh.face_count(), m.face_count());
        assert!(out.group_error.iter().all(|&e| e.is_finite() && e >= 0.0) && out.group_error.iter().any(|&e| e > 0.0));
    }
}

#[test]
fn max_error_stops_early() {
    let m = rough_sphere(4, 0.05, 1);
    let free = simplify(&m, None, &opts(0));
    let bounded = simplify(&m, None, &SimplifyOptions { max_error: Some(0.01), ..opts(0) });
    check(&m, &bounded);
    assert!(bounded.error <= 0.01 && free.error > 0.01);
    assert!(bounded.mesh.face_count() > free.mesh.face_count());
}

#[test]
fn deterministic() {
    let m = seamed_sphere(3);
    let groups = patches(&m, 7);
    let a = simplify(&m, Some(&groups), &opts(100));
    let b = simplify(&m, Some(&groups), &opts(100));
    assert_eq!(a, b);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn random_meshes_keep_invariants(seed in 0u64..1000, levels in 1u32..4, amount in 0.0f32..0.3, k in 1usize..20, ratio in 0.0f64..1.0, open in any::<bool>()) {
        let mut m = rough_sphere(levels, amount, seed);
        if open {
            // Cut a cap away so the mesh has a border.
            let keep: Vec<usize> = (0..m.face_count()).filter(|&f| m.triangles[f].iter().any(|&v| m.positions[v as usize].z < 0.5)).collect();
            m.triangles = keep.iter().map(|&f| m.triangles[f]).collect();
            m = Mesh { face_materials: Vec::new(), ..m }.clean().expect("finite").0;
        }
        let groups = patches(&m, k);
        let target = (m.face_count() as f64 * ratio) as usize;
        let out = simplify(&m, Some(&groups), &opts(target));
        check(&m, &out);
        let pieces = group_pieces(&out.mesh, &out.face_groups);
        prop_assert!(pieces.iter().all(|&p| p == 1), "{:?}", pieces);
        let plain = simplify(&m, None, &opts(target));
        check(&m, &plain);
        let free = simplify(&m, None, &SimplifyOptions { topology: true, ..opts(target) });
        check_manifold(&m, &free);
        prop_assert!(free.mesh.face_count() <= plain.mesh.face_count().max(target));
    }
}

/// A flat grid whose corners carry one of two normals `degrees` apart, at random, as a scanner's
/// split vertices welded on import do (at a few vertices there; here at all of them).
fn jittered_normals_grid(n: u32, degrees: f32) -> Mesh {
    let mut m = fixtures::open_grid(n);
    let half = 0.5 * degrees.to_radians();
    m.normals = (0..3 * m.face_count() as u64)
        .map(|c| {
            let side = if noise(c) < 0.0 { -1.0 } else { 1.0 };
            Vec3::new(side * half.sin(), 0.0, half.cos())
        })
        .collect();
    m
}

#[test]
fn near_equal_normals_are_one_seam_free_normal_within_the_angle() {
    let m = jittered_normals_grid(12, 4.0);
    let target = m.face_count() / 8;
    // Exact comparison: every interior vertex is a seam of two normals, and the grid barely
    // simplifies.
    let exact = simplify(&m, None, &opts(target));
    assert!(exact.mesh.face_count() > 2 * target, "{} faces", exact.mesh.face_count());
    // Within 5°: one normal per vertex, the target reached, and every vertex's corners alike.
    let merged = simplify(&m, None, &SimplifyOptions { normal_seam_angle: 5f32.to_radians(), ..opts(target) });
    check(&m, &merged);
    assert!(merged.mesh.face_count() <= target, "{} faces", merged.mesh.face_count());
    let mut first: Vec<Option<Vec3>> = vec![None; merged.mesh.positions.len()];
    for (f, t) in merged.mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let n = merged.mesh.normals[3 * f + k];
            assert!((n.length() - 1.0).abs() < 1e-5);
            assert_eq!(*first[t[k] as usize].get_or_insert(n), n, "vertex {} keeps a seam", t[k]);
        }
    }
    // A seam wider than the angle stays a seam.
    let wide = simplify(&m, None, &SimplifyOptions { normal_seam_angle: 3f32.to_radians(), ..opts(target) });
    assert_eq!(wide.mesh.face_count(), exact.mesh.face_count());
}

/// A cut may pass through vertices that faces of other groups touch, as long as the faces along
/// its cycle are of one group: those other faces keep their edges.
#[test]
fn cuts_pass_by_other_groups_at_a_vertex() {
    let m = tori(1, 40);
    // One face of group 1 on each tenth cross-section, touching its ring at one vertex only: the
    // ring's own edges lie between faces of group 0.
    let ring = |i: u32, j: u32| (i % 40) * 3 + j % 3;
    let mut groups = vec![0u32; m.face_count()];
    for i in (0..40).step_by(4) {
        let f = m.triangles.iter().position(|t| *t == [ring(i, 1), ring(i + 1, 1), ring(i + 1, 2)]).expect("face");
        groups[f] = 1 + i / 4;
    }
    let out = simplify(&m, Some(&groups), &SimplifyOptions { topology: true, ..opts(0) });
    check_manifold(&m, &out);
    assert_eq!(group_pairs(&out.mesh, &out.face_groups), group_pairs(&m, &groups));
    for g in 0..11u32 {
        assert!(out.face_groups.contains(&g), "group {g} kept faces");
    }
    // 72 when every face around a cut's vertices had to be of one group.
    assert!(out.mesh.face_count() <= 56, "{} faces", out.mesh.face_count());
}

#[test]
fn topology_changes_leave_pinned_vertices_and_their_edges() {
    // Every fifth ring of cross-sections pinned around each tube, as a cell or DAG level pins its
    // borders: cuts and dropped tetrahedra still shrink the handles between them, but no cut
    // runs through a pinned vertex (it would leave two vertices where the pin is), none goes, and
    // every edge between pinned vertices stays.
    // A closed tetrahedron beside them, one corner pinned: it stays whole.
    let mut m = tori(3, 40);
    let tori_vertices = m.positions.len();
    let base = tori_vertices as u32;
    m.positions.extend([Vec3::new(0.0, 0.0, 2.0), Vec3::new(0.1, 0.0, 2.0), Vec3::new(0.0, 0.1, 2.0), Vec3::new(0.0, 0.0, 2.1)]);
    m.triangles.extend([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]].map(|t| t.map(|i| base + i)));
    m.face_materials.resize(m.triangles.len(), 0);
    m.compute_face_geometry();
    let pinned: Vec<bool> =
        (0..m.positions.len()).map(|v| if v < tori_vertices { (v / 3) % 40 % 5 == 0 } else { v == tori_vertices }).collect();
    let without = simplify_pinned(&m, None, &pinned, &opts(0));
    let with = simplify_pinned(&m, None, &pinned, &SimplifyOptions { topology: true, ..opts(0) });
    check_manifold(&m, &with);
    assert!(
        with.mesh.face_count() < without.mesh.face_count(),
        "{} faces, {} without cuts",
        with.mesh.face_count(),
        without.mesh.face_count()
    );
    let key = |mesh: &Mesh, v: usize| mesh.positions[v].to_array().map(f32::to_bits);
    let pins: std::collections::HashSet<[u32; 3]> = (0..m.positions.len()).filter(|&v| pinned[v]).map(|v| key(&m, v)).collect();
    for k in &pins {
        let copies = (0..with.mesh.positions.len()).filter(|&v| key(&with.mesh, v) == *k).count();
        assert_eq!(copies, 1, "a pinned vertex is {copies} vertices");
    }
    let edges = |mesh: &Mesh| -> std::collections::HashSet<([u32; 3], [u32; 3])> {
        let t = mesh.triangles.iter().flat_map(|t| (0..3).map(move |k| (t[k] as usize, t[(k + 1) % 3] as usize)));
        t.map(|(a, b)| (key(mesh, a).min(key(mesh, b)), key(mesh, a).max(key(mesh, b)))).collect()
    };
    let kept = edges(&with.mesh);
    let between: Vec<_> = edges(&m).into_iter().filter(|(a, b)| pins.contains(a) && pins.contains(b)).collect();
    assert!(!between.is_empty());
    assert!(between.iter().all(|e| kept.contains(e)), "an edge between pinned vertices is gone");
}
