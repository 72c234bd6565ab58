//! Hierarchical back-face culling over the group hierarchy, and the method's cost measure.
//!
//! For one view the top groups are tested; a group that is back-facing by its cone is culled with
//! its whole subtree, a fully front-facing one is drawn without testing its children, and a mixed
//! one passes the test down to its children, ending at the culling clusters. The cost of a view is
//! the number of group tests plus the faces in groups that were not culled; per-face culling costs
//! one test per face, so cost / faces = 1 is no gain and about 0.5 is the floor for a closed mesh.

use crate::cone::{facing_orthographic, Facing};
use crate::hierarchy::Hierarchy;
use crate::mesh::Mesh;
use glam::Vec3;
use rayon::prelude::*;

/// The culling measure averaged over many views.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CullingStats {
    pub views: usize,
    /// (group tests + faces in groups not culled) / faces.
    pub cost_ratio: f64,
    /// Share of faces culled by their groups' cones.
    pub faces_culled: f64,
    /// Share of faces that are truly back-facing (the most any culling could remove).
    pub faces_backfacing: f64,
    /// Group tests per view.
    pub tests: f64,
}

/// `n` unit directions spread evenly over the sphere (a Fibonacci lattice), deterministic.
pub fn sphere_directions(n: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * i as f64;
            Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32)
        })
        .collect()
}

/// One view's counts: (tests, faces culled).
fn cull_view(h: &Hierarchy, to_viewer: Vec3) -> (u64, u64) {
    let (mut tests, mut culled) = (0u64, 0u64);
    let Some(top) = h.levels.last() else { return (0, 0) };
    let mut stack: Vec<(usize, u32)> = (0..top.groups.len() as u32).map(|g| (h.levels.len(), g)).collect();
    // Entries are (depth, group): depth d > 0 is node level d − 1, depth 0 is a cluster.
    while let Some((depth, g)) = stack.pop() {
        let level = if depth == 0 { &h.clusters } else { &h.levels[depth - 1] };
        let info = &level.groups[g as usize];
        tests += 1;
        match facing_orthographic(&info.cone, to_viewer) {
            Facing::Back => culled += info.faces as u64,
            Facing::Front => {}
            Facing::Mixed if depth > 0 => stack.extend(level.children.get(g as usize).iter().map(|&c| (depth - 1, c))),
            Facing::Mixed => {}
        }
    }
    (tests, culled)
}

/// The cost measure over `views` orthographic view directions spread over the sphere.
pub fn measure(h: &Hierarchy, mesh: &Mesh, views: usize) -> CullingStats {
    let dirs = sphere_directions(views);
    let faces = mesh.face_count() as f64;
    let (tests, culled, back) = dirs
        .par_iter()
        .map(|&d| {
            let (t, c) = cull_view(h, d);
            let back = mesh.face_normals.iter().filter(|n| n.dot(d) < 0.0).count() as u64;
            (t, c, back)
        })
        .reduce(|| (0, 0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
    let v = views.max(1) as f64;
    let (tests, culled, back) = (tests as f64 / v, culled as f64 / v, back as f64 / v);
    CullingStats {
        views,
        cost_ratio: (tests + faces - culled) / faces,
        faces_culled: culled / faces,
        faces_backfacing: back / faces,
        tests,
    }
}
