//! A DAG of nodes, crack-free by construction (notes/dag.md): the structure Nanite and Nexus build,
//! made with strata's own simplifier.
//!
//! Level 0's nodes are the grouping's level-0 groups (normal cones, METHOD.md), small separate ones
//! joined (`specks.rs`). Each coarser level
//! gathers the nodes of the level below into *groups* of a few adjacent nodes ([`gather`]),
//! simplifies the level to half with every vertex two groups share pinned and every face kept in
//! its group (in batches of near groups, one queue each, so that collapses go where they cost
//! least), and cuts each group's result into nodes of about level 0's size ([`split`]). A node
//! is the child of the one group it was gathered into (its *consumer*) and an output of the group
//! that made it (its *source*); a group has several children and several outputs.
//!
//! A border pinned at one level lies inside a group at the next, where it simplifies, so nothing
//! stays at full resolution; and the selection rule of [`cut`] shows, for any threshold, a set of
//! nodes whose borders meet edge for edge at any level difference.
//!
//! Everything is plain data: level meshes whose faces are ordered by node (a node's faces are a
//! range), nodes and groups as arrays of small records that refer to each other by index.

mod build;
pub mod cut;
mod gather;
mod specks;
mod split;
pub mod write;

pub use build::{build, build_from, median_size, shared_vertices, Bounds, DagParams, Start};

use crate::cone::Cone;
use crate::hierarchy::Lists;
use crate::mesh::Mesh;
use glam::Vec3;
use std::ops::Range;

/// Marks "none": the source of a level-0 node, the consumer of a top node.
pub const NONE: u32 = u32::MAX;

/// A patch of one level mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    pub level: u32,
    /// Its faces in its level's mesh.
    pub faces: Range<u32>,
    /// A sphere holding its vertices.
    pub center: Vec3,
    pub radius: f32,
    /// Holds the normal of each of its faces: a viewer culls the node with it.
    pub cone: Cone,
    /// The group that made it; [`NONE`] at level 0.
    pub source: u32,
    /// The group it was gathered into; [`NONE`] at the top.
    pub consumer: u32,
}

/// A group of adjacent nodes of one level, simplified together into nodes of the next.
#[derive(Clone, Debug, PartialEq)]
pub struct Group {
    /// The level of its outputs (its children are one level finer).
    pub level: u32,
    /// Geometric error in model units: its simplification's estimate plus the largest error of its
    /// children's sources, so never below the error of a group it was made from.
    pub error: f32,
    /// A sphere holding its children's spheres and their sources' spheres, so that its projected
    /// error is never below that of a group it was made from.
    pub center: Vec3,
    pub radius: f32,
    /// Its outputs: the nodes it made, one run of node indices.
    pub outputs: Range<u32>,
}

/// The DAG: level meshes, nodes level by level (level 0 first), groups level by level.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Dag {
    /// Level meshes, finest (the input's faces, reordered by node) first.
    pub levels: Vec<Mesh>,
    pub nodes: Vec<Node>,
    pub groups: Vec<Group>,
    /// Per group, its children (the nodes whose consumer it is), in increasing order.
    pub children: Lists,
    /// The input face of each face of level 0 (its faces are reordered by node).
    pub input_faces: Vec<u32>,
}

impl Dag {
    /// The nodes of `level`, a run of node indices.
    pub fn level_nodes(&self, level: usize) -> Range<u32> {
        let first = self.nodes.partition_point(|n| (n.level as usize) < level) as u32;
        let end = self.nodes.partition_point(|n| (n.level as usize) <= level) as u32;
        first..end
    }

    /// The corner indices of node `n`'s faces, into its level's positions.
    pub fn indices(&self, n: usize) -> impl Iterator<Item = u32> + '_ {
        let node = &self.nodes[n];
        let mesh = &self.levels[node.level as usize];
        mesh.triangles[node.faces.start as usize..node.faces.end as usize].iter().flatten().copied()
    }
}

#[cfg(test)]
mod tests;
