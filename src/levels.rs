//! The level meshes M0 … ML: M0 is the input; Mℓ is Mℓ−1 simplified while every group of level ℓ
//! stays a connected, non-empty patch (METHOD.md §4). A node — group g of level ℓ — owns the faces
//! of Mℓ labelled g.

use crate::mesh::Mesh;

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
