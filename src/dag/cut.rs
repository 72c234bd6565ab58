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

/// The cut at the least threshold whose seen nodes hold at most `budget` faces (faces fall as τ
/// grows); the coarsest cut when none does. Thresholds are searched among the groups' projected
/// errors, where the cut changes.
pub fn cut_within(dag: &Dag, camera: &Camera, budget: usize) -> Cut {
    let p = projected_errors(dag, camera);
    let seen: Vec<u32> = (0..dag.nodes.len() as u32).filter(|&n| sees(&dag.nodes[n as usize], camera)).collect();
    let faces =
        |tau: f32| -> usize { seen.iter().map(|&n| &dag.nodes[n as usize]).filter(|n| shown(n, &p, tau)).map(|n| n.faces.len()).sum() };
    let mut candidates: Vec<f32> = p.iter().copied().filter(|x| x.is_finite()).collect();
    candidates.push(0.0);
    candidates.sort_unstable_by(f32::total_cmp);
    candidates.dedup();
    let (mut lo, mut hi) = (0usize, candidates.len() - 1);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if faces(candidates[mid]) <= budget {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    let tau = candidates[lo];
    Cut { tau, nodes: seen.into_iter().filter(|&n| shown(&dag.nodes[n as usize], &p, tau)).collect() }
}
