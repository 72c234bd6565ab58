//! The DAG's selection rule: which nodes a viewer shows at a threshold τ of projected error.
//!
//! A node is shown iff its source group's projected error is at most τ (or it is at level 0) and
//! its consumer's is above τ (or it is at the top). The outputs of one group pass the first test
//! together and the children of one group the second, so a group is either wholly replaced by its
//! outputs or not at all; and since a group's projected error is never below that of a group it
//! was made from, two shown nodes that border each other share their border edge for edge
//! (notes/dag.md has the argument).

use super::{Dag, Node, NONE};
use crate::camera::{Camera, Projection};
use crate::cone::{facing_orthographic, facing_perspective, Facing};

/// Projected error in pixels of each group from `camera`, raised where needed to the largest of
/// the groups its children came from, so that it never decreases from a group to one made from
/// its outputs, whatever rounding did to the stored spheres.
pub fn projected_errors(dag: &Dag, camera: &Camera) -> Vec<f32> {
    let mut p: Vec<f32> = Vec::with_capacity(dag.groups.len());
    for (g, group) in dag.groups.iter().enumerate() {
        let own = camera.projected_error(group.error, group.center, group.radius);
        let below = dag.children.get(g).iter().map(|&c| dag.nodes[c as usize].source).filter(|&s| s != NONE).map(|s| p[s as usize]);
        p.push(below.fold(own, f32::max));
    }
    p
}

/// Whether `node` is shown at threshold `tau`, given the groups' projected errors `p`.
pub fn shown(node: &Node, p: &[f32], tau: f32) -> bool {
    (node.source == NONE || p[node.source as usize] <= tau) && (node.consumer == NONE || p[node.consumer as usize] > tau)
}

/// Whether `node` can show anything from `camera`: inside the frustum and not back-facing by its
/// cone.
pub fn sees(node: &Node, camera: &Camera) -> bool {
    let facing = match camera.projection {
        Projection::Perspective { .. } => facing_perspective(&node.cone, node.center, node.radius, camera.eye),
        Projection::Orthographic { .. } => facing_orthographic(&node.cone, -camera.forward()),
    };
    facing != Facing::Back && camera.sees_sphere(node.center, node.radius)
}

/// A cut: the threshold and the nodes shown at it that the camera sees.
#[derive(Clone, Debug, PartialEq)]
pub struct Cut {
    pub tau: f32,
    pub nodes: Vec<u32>,
}

/// The nodes shown at `tau` that `camera` sees.
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

/// The cut a viewer refines to under a face budget (selection.md §9): from the top level down,
/// groups are opened (their outputs replaced by their children) largest projected error first,
/// equal errors by group number, while their error is above `tau`, the faces shown stay within
/// `face_budget` and `held` does not hold them (a viewer holds a group whose children it has not
/// loaded). A group is opened only once all its outputs are in the cut, so every cut this returns
/// is one of the DAG's cuts, crack-free; without a budget or held groups it is [`cut`]'s at `tau`.
pub fn select(dag: &Dag, camera: &Camera, tau: f32, face_budget: Option<usize>, held: &dyn Fn(u32) -> bool) -> Selection {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let p = projected_errors(dag, camera);
    let seen: Vec<bool> = dag.nodes.iter().map(|n| sees(n, camera)).collect();
    let cost = |n: u32| if seen[n as usize] { dag.nodes[n as usize].faces.len() } else { 0 };
    let mut in_cut = vec![false; dag.nodes.len()];
    // Outputs of each group not yet in the cut; a group becomes a candidate at 0.
    let mut waiting: Vec<u32> = dag.groups.iter().map(|g| g.outputs.len() as u32).collect();
    let mut heap: BinaryHeap<(u32, Reverse<u32>)> = BinaryHeap::new();
    let mut enter = |n: u32, heap: &mut BinaryHeap<(u32, Reverse<u32>)>, in_cut: &mut Vec<bool>| {
        in_cut[n as usize] = true;
        let s = dag.nodes[n as usize].source;
        if s != NONE {
            waiting[s as usize] -= 1;
            if waiting[s as usize] == 0 && p[s as usize] > tau && !held(s) {
                // Projected errors are not negative, so their bits order as they do.
                heap.push((p[s as usize].to_bits(), Reverse(s)));
            }
        }
    };
    let mut faces = 0usize;
    let top = dag.levels.len().saturating_sub(1);
    for n in dag.level_nodes(top) {
        faces += cost(n);
        enter(n, &mut heap, &mut in_cut);
    }
    while let Some((_, Reverse(g))) = heap.pop() {
        let outputs = dag.groups[g as usize].outputs.clone();
        let children = dag.children.get(g as usize);
        let after = faces - outputs.clone().map(cost).sum::<usize>() + children.iter().map(|&c| cost(c)).sum::<usize>();
        if face_budget.is_some_and(|b| after > b) {
            continue;
        }
        faces = after;
        for o in outputs {
            in_cut[o as usize] = false;
        }
        for &c in children {
            enter(c, &mut heap, &mut in_cut);
        }
    }
    let (shown, culled): (Vec<u32>, Vec<u32>) =
        (0..dag.nodes.len() as u32).filter(|&n| in_cut[n as usize]).partition(|&n| seen[n as usize]);
    Selection { shown, culled, faces }
}
