//! Small components leave coarse levels (src/small_components.rs): a sphere with specks floating
//! off its surface keeps every speck at level 0, drops a speck from a level only where the node that
//! takes it in already claims an error of at least the speck's size, and writes a file that
//! verifies.

use glam::Vec3;
use strata::format::{self, Reader};
use strata::hierarchy::{self, HierarchyParams};
use strata::levels::{self, LevelParams};
use strata::mesh::{Adjacency, Mesh};
use strata::write::{write_to, WriteOptions};

/// The noisy sphere fixture (radius 1) and `n` closed specks (icospheres of `radius`) 0.1 above it.
fn specked_sphere(n: usize, radius: f32) -> (Mesh, Vec<(Vec3, f32)>) {
    let mut mesh = strata::fixtures::noisy_sphere(91, 0.08, 1);
    mesh.normals.clear();
    let speck = strata::fixtures::icosphere(1);
    let mut specks = Vec::new();
    for i in 0..n {
        // Spread evenly on the sphere (a Fibonacci lattice).
        let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let phi = i as f32 * 2.399_963;
        let dir = Vec3::new((1.0 - y * y).sqrt() * phi.cos(), y, (1.0 - y * y).sqrt() * phi.sin());
        let center = dir * 1.2;
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(speck.positions.iter().map(|&p| center + p * radius));
        mesh.triangles.extend(speck.triangles.iter().map(|t| t.map(|v| v + base)));
        mesh.face_materials.extend(std::iter::repeat_n(0, speck.face_count()));
        specks.push((center, radius));
    }
    mesh.compute_face_geometry();
    (mesh, specks)
}

/// The faces of `m` whose centroid lies within `reach` of `center`.
fn faces_near(m: &Mesh, center: Vec3, reach: f32) -> Vec<usize> {
    (0..m.face_count())
        .filter(|&f| {
            let c = m.triangles[f].iter().map(|&v| m.positions[v as usize]).sum::<Vec3>() / 3.0;
            c.distance(center) <= reach
        })
        .collect()
}

#[test]
fn specks_leave_coarse_levels_within_their_absorbers_error() {
    let (mesh, specks) = specked_sphere(64, 0.004);
    let faces0 = mesh.face_count();
    let speck_faces: Vec<usize> = specks.iter().map(|&(c, r)| faces_near(&mesh, c, 2.0 * r)[0]).collect();
    let adjacency = Adjacency::build(&mesh);
    let mut h = hierarchy::build(&mesh, &adjacency, &HierarchyParams::default());
    let lv = levels::build(mesh, &mut h, &LevelParams::default(), &mut |_| {});
    assert_eq!(lv.levels[0].mesh.face_count(), faces0, "level 0 is the input, specks included");

    let mut left = 0;
    for (s, &(center, radius)) in specks.iter().enumerate() {
        for l in 1..lv.levels.len() {
            let here = faces_near(&lv.levels[l].mesh, center, 2.0 * radius);
            let below = faces_near(&lv.levels[l - 1].mesh, center, 2.0 * radius);
            if !here.is_empty() || below.is_empty() {
                continue;
            }
            left += 1;
            // It left level l: its input faces' group there is its absorber, whose error covers it.
            let m = &lv.levels[l - 1].mesh;
            let (lo, hi) = below
                .iter()
                .flat_map(|&f| m.triangles[f])
                .map(|v| m.positions[v as usize])
                .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(p), hi.max(p)));
            let absorber = h.levels[l].face_group[speck_faces[s]] as usize;
            let error = lv.levels[l].group_error[absorber];
            // Measured one level down: simplifying a speck into level l may shrink its box a little.
            assert!(
                error >= (hi - lo).length() * 0.9,
                "speck {s} left level {l} with size {} > its absorber's error {error}",
                (hi - lo).length()
            );
            let info = &h.levels[l].groups[absorber];
            assert!(info.center.distance(center) + radius <= info.radius * 1.001, "the absorber's sphere holds the speck");
        }
    }
    assert!(left >= specks.len() / 2, "only {left} of {} specks left a level", specks.len());
    let top = lv.levels.last().expect("levels");
    assert!(top.group_error.len() < specks.len(), "{} top nodes for {} specks", top.group_error.len(), specks.len());

    // The hierarchy still nests: every level's groups are unions of the level below's.
    for l in 1..h.levels.len() {
        for (f, &g) in h.levels[l - 1].face_group.iter().enumerate() {
            assert_eq!(h.levels[l - 1].parent[g as usize], h.levels[l].face_group[f], "level {l} face {f}");
        }
    }

    let mut bytes = Vec::new();
    write_to(&mut bytes, &h, &lv, &WriteOptions::default()).expect("write");
    let report = format::verify(bytes.as_slice(), std::path::Path::new("specks.strata"));
    assert!(report.is_sound(), "{:?}", report.problems);
    let rd = Reader::open(bytes.as_slice()).expect("open");
    assert_eq!(rd.levels()[0].faces as usize, faces0);
}
