//! The level meshes M0 … ML: M0 is the input; Mℓ is Mℓ−1 simplified while every group of level ℓ
//! stays a connected, non-empty patch (METHOD.md §4). A node — group g of level ℓ — owns the faces
//! of Mℓ labelled g.
//!
//! A node's geometric error bounds, in model units, how far its surface may lie from the input:
//! each level adds the simplifier's estimate for the group (an RMS distance to the planes the
//! group's vertices replaced, see [`crate::simplify`]) to the largest error of its children. The
//! estimate is area-weighted, not a Hausdorff bound; [`crate::distance`] measures the real thing.

use crate::hierarchy::Hierarchy;
use crate::mesh::Mesh;
use crate::simplify::{simplify, SimplifyOptions};

/// One level's mesh and what each of its faces belongs to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelMesh {
    pub mesh: Mesh,
    /// Group of level ℓ of each face of `mesh`.
    pub face_group: Vec<u32>,
    /// Per group of level ℓ: geometric error in model units, never smaller than its children's.
    pub group_error: Vec<f32>,
}

/// Level meshes, finest (the input, level 0) first.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelMeshes {
    pub levels: Vec<LevelMesh>,
}

/// Build every level mesh of `h` from `mesh`, each aiming at `ratio` of the faces of the level
/// below. `mesh` becomes level 0 (taken, not copied: it is the largest of them). `on_level` is
/// called after each level with its index, for progress reports.
pub fn build(mesh: Mesh, h: &Hierarchy, ratio: f32, on_level: &mut dyn FnMut(usize)) -> LevelMeshes {
    let first = LevelMesh {
        mesh,
        face_group: h.levels[0].face_group.clone(),
        group_error: vec![0.0; h.levels[0].groups.len()],
    };
    let mut levels = vec![first];
    on_level(0);
    for l in 1..h.levels.len() {
        let below = &levels[l - 1];
        let parent = &h.levels[l - 1].parent;
        let labels: Vec<u32> = below.face_group.iter().map(|&g| parent[g as usize]).collect();
        let target = ((below.mesh.face_count() as f64) * ratio.clamp(0.0, 1.0) as f64).round() as usize;
        let opts = SimplifyOptions { target_faces: target, ..SimplifyOptions::default() };
        let s = simplify(&below.mesh, Some(&labels), &opts);
        let groups = &h.levels[l];
        let group_error = (0..groups.groups.len())
            .map(|g| {
                let children = groups.children.get(g).iter().map(|&c| below.group_error[c as usize]).fold(0.0, f32::max);
                children + s.group_error.get(g).copied().unwrap_or(0.0)
            })
            .collect();
        levels.push(LevelMesh { mesh: s.mesh, face_group: s.face_groups, group_error });
        on_level(l);
    }
    LevelMeshes { levels }
}
