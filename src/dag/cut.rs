//! The DAG's selection rule (selection.md §9) on the build's structure: which nodes a viewer shows
//! at a threshold τ of projected error, and under budgets. The rule itself is
//! [`crate::stream::dag`]'s, which the streamer runs on a file's skeleton.
//!
//! A node is shown iff its source group's projected error is at most τ (or it is at level 0) and
//! its consumer's is above τ (or it is at the top). The outputs of one group pass the first test
//! together and the children of one group the second, so a group is either wholly replaced by its
//! outputs or not at all; and since a group's projected error is never below that of a group it
//! was made from, two shown nodes that border each other share their border edge for edge.

use super::{Dag, Node, NONE};
use crate::camera::Camera;
use crate::stream::dag::{self as rule, Graph};
use crate::stream::refine::{sees_bounds, Limits, Priority};
use glam::Vec3;
use std::ops::Range;

impl Graph for Dag {
    fn node_count(&self) -> usize {
        self.nodes.len()
    }
    fn group_count(&self) -> usize {
        self.groups.len()
    }
    fn top(&self) -> Range<u32> {
        self.level_nodes(self.levels.len().saturating_sub(1))
    }
    fn source(&self, n: u32) -> u32 {
        self.nodes[n as usize].source
    }
    fn consumer(&self, n: u32) -> u32 {
        self.nodes[n as usize].consumer
    }
    fn outputs(&self, g: u32) -> Range<u32> {
        self.groups[g as usize].outputs.clone()
    }
    fn children(&self, g: u32) -> &[u32] {
        self.children.get(g as usize)
    }
    fn group_bounds(&self, g: u32) -> (f32, Vec3, f32) {
        let r = &self.groups[g as usize];
        (r.error, r.center, r.radius)
    }
    fn numbered_up(&self) -> bool {
        true
    }
}

/// Projected error in pixels of each group from `camera`, raised where needed to the largest of
/// the groups its children came from (selection.md §9.1).
pub fn projected_errors(dag: &Dag, camera: &Camera) -> Vec<f32> {
    rule::projected_errors(dag, camera)
}

/// Whether `node` is shown at threshold `tau`, given the groups' projected errors `p`.
pub fn shown(node: &Node, p: &[f32], tau: f32) -> bool {
    (node.source == NONE || p[node.source as usize] <= tau) && (node.consumer == NONE || p[node.consumer as usize] > tau)
}

/// Whether `node` can show anything from `camera`: inside the frustum and not back-facing by its
/// cone.
pub fn sees(node: &Node, camera: &Camera) -> bool {
    sees_bounds(&node.cone, node.center, node.radius, camera)
}

/// A cut: the threshold and the nodes shown at it that the camera sees.
#[derive(Clone, Debug, PartialEq)]
pub struct Cut {
    pub tau: f32,
    pub nodes: Vec<u32>,
}

/// The nodes shown at `tau` that `camera` sees (selection.md §9.2).
pub fn cut(dag: &Dag, camera: &Camera, tau: f32) -> Cut {
    let p = projected_errors(dag, camera);
    let nodes = (0..dag.nodes.len() as u32).filter(|&n| shown(&dag.nodes[n as usize], &p, tau) && sees(&dag.nodes[n as usize], camera));
    Cut { tau, nodes: nodes.collect() }
}

/// A selection under budgets: the nodes of the cut the camera sees (`shown`, ascending), those it
/// does not (`culled`, ascending), and the faces shown.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Selection {
    pub shown: Vec<u32>,
    pub culled: Vec<u32>,
    pub faces: usize,
}

/// The cut a viewer refines to under a face budget (selection.md §9.3): from the top level down,
/// groups are opened (their outputs replaced by their children) largest projected error first,
/// equal errors by group number, while their error is above `tau`, the faces shown stay within
/// `face_budget` and `held` does not hold them (a viewer holds a group whose children it has not
/// loaded). A group is opened only once all its outputs are in the cut, so every cut this returns
/// is one of the DAG's cuts, crack-free; without a budget or held groups it is [`cut`]'s at `tau`.
pub fn select(dag: &Dag, camera: &Camera, tau: f32, face_budget: Option<usize>, held: &dyn Fn(u32) -> bool) -> Selection {
    let p = projected_errors(dag, camera);
    let limits = Limits { pixel_error: tau, max_faces: face_budget.map(|b| b as u64), max_bytes: None, priority: Priority::Error };
    let seen = |n: u32| sees(&dag.nodes[n as usize], camera);
    let cost = |n: u32| (dag.nodes[n as usize].faces.len() as u64, 0);
    let c = rule::select(dag, &p, &seen, &cost, &limits, held);
    Selection { shown: c.shown, culled: c.culled, faces: c.faces as usize }
}
