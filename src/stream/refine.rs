//! Front selection (METHOD.md §6): which nodes to display for one camera, chosen breadth-first from
//! the top level down as in the paper, so that displayed neighbours differ by at most one level.

use crate::camera::{Camera, Projection};
use crate::cone::{facing_orthographic, facing_perspective, Cone, Facing};
use crate::format::skeleton::Skeleton;
use crate::format::{NodeRecord, NO_PARENT};
use glam::Vec3;
use std::cmp::Ordering;
use std::f32::consts::PI;

/// What bounds a front: refinement stops where a node's projected error is under `pixel_error`,
/// and never makes the displayed faces or resident bytes exceed their budgets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    pub pixel_error: f32,
    pub max_faces: Option<u64>,
    pub max_bytes: Option<u64>,
    pub priority: Priority,
}

/// The order in which a level's refinable nodes claim the budget.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Priority {
    /// Largest projected geometric error (pixels) first: the budget goes where the image is
    /// furthest from full detail. Measured on the bunny, it keeps more of the full-detail image
    /// under a face budget than either order below.
    #[default]
    Error,
    /// The paper's f(g), highest first: silhouette and wide-cone groups first.
    Silhouette,
    /// Plain breadth-first order (node id within the level), for comparison.
    Breadth,
}

/// A node's part in the current cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    /// Neither in the cut nor replaced by its children.
    Off,
    Shown,
    /// Back-facing or outside the frustum: neither drawn nor refined, its subtree skipped.
    Culled,
    /// Replaced by all its children.
    Refined,
}

/// A cut of the hierarchy: every face of the model lies under exactly one shown or culled node.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cut {
    /// Displayed nodes, ascending.
    pub shown: Vec<u32>,
    /// Roots of the culled subtrees, ascending.
    pub culled: Vec<u32>,
    pub faces: u64,
    pub bytes: u64,
}

/// Front selection with its per-node marks kept between frames, so each frame only resets the
/// nodes the previous one touched.
#[derive(Clone, Debug, Default)]
pub struct Refiner {
    marks: Vec<Mark>,
    touched: Vec<u32>,
}

impl Refiner {
    /// The mark of node `i` in the last selected cut.
    pub fn mark(&self, i: u32) -> Mark {
        self.marks.get(i as usize).copied().unwrap_or(Mark::Off)
    }

    /// Select the cut for `camera`: start from the top level; level by level, refine shown nodes
    /// whose projected error is not under the threshold, in `limits.priority` order, when no
    /// same-level neighbour is displayed coarser and the budgets allow all the visible children.
    /// Nodes in `held` (ascending) are not refined. `bytes(i)` is the resident size of node `i`'s
    /// geometry.
    pub fn select(
        &mut self,
        skeleton: &Skeleton,
        camera: &Camera,
        limits: &Limits,
        held: &[u32],
        bytes: &dyn Fn(&NodeRecord) -> u64,
    ) -> Cut {
        let nodes = &skeleton.nodes;
        if self.marks.len() != nodes.len() {
            self.marks = vec![Mark::Off; nodes.len()];
            self.touched.clear();
        }
        for &t in &self.touched {
            self.marks[t as usize] = Mark::Off;
        }
        self.touched.clear();

        let mut cut = Cut::default();
        let top = skeleton.top();
        // A skeleton decoded in part (Reader::open_top) shows its top level alone.
        let complete = skeleton.is_complete();
        let mut level_shown = Vec::new();
        for i in skeleton.level_nodes(top) {
            if self.classify(i, &nodes[i as usize], camera) {
                cut.faces += nodes[i as usize].faces as u64;
                cut.bytes += bytes(&nodes[i as usize]);
                level_shown.push(i);
            }
        }
        for _ in (1..=top).rev() {
            let mut candidates: Vec<(f32, u32)> = level_shown
                .iter()
                .filter_map(|&i| {
                    let n = &nodes[i as usize];
                    let pixels = camera.projected_error(n.error, n.center, n.radius);
                    let refinable = n.child_count > 0 && complete && pixels >= limits.pixel_error && held.binary_search(&i).is_err();
                    refinable.then(|| match limits.priority {
                        Priority::Error => (pixels, i),
                        Priority::Silhouette => (priority(n, camera), i),
                        Priority::Breadth => (0.0, i),
                    })
                })
                .collect();
            candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            let mut next = Vec::new();
            for (_, i) in candidates {
                if skeleton.neighbors(i).iter().any(|&m| self.shown_coarser(nodes, m)) {
                    continue;
                }
                let n = &nodes[i as usize];
                let children = skeleton.children(i);
                let visible: Vec<bool> = children.clone().map(|c| sees(&nodes[c as usize], camera)).collect();
                let (mut faces, mut size) = (cut.faces - n.faces as u64, cut.bytes - bytes(n));
                for (c, _) in children.clone().zip(&visible).filter(|(_, &v)| v) {
                    faces += nodes[c as usize].faces as u64;
                    size += bytes(&nodes[c as usize]);
                }
                if limits.max_faces.is_some_and(|m| faces > m) || limits.max_bytes.is_some_and(|m| size > m) {
                    continue;
                }
                (cut.faces, cut.bytes) = (faces, size);
                self.set(i, Mark::Refined);
                for (c, &v) in children.zip(&visible) {
                    self.set(c, if v { Mark::Shown } else { Mark::Culled });
                    if v {
                        next.push(c);
                    }
                }
            }
            level_shown = next;
        }
        for &t in &self.touched {
            match self.marks[t as usize] {
                Mark::Shown => cut.shown.push(t),
                Mark::Culled => cut.culled.push(t),
                _ => {}
            }
        }
        cut.shown.sort_unstable();
        cut.culled.sort_unstable();
        cut
    }

    fn set(&mut self, i: u32, mark: Mark) {
        if self.marks[i as usize] == Mark::Off {
            self.touched.push(i);
        }
        self.marks[i as usize] = mark;
    }

    /// Mark node `i` shown or culled; true when shown.
    fn classify(&mut self, i: u32, n: &NodeRecord, camera: &Camera) -> bool {
        let v = sees(n, camera);
        self.set(i, if v { Mark::Shown } else { Mark::Culled });
        v
    }

    /// Whether the nearest cut node at or above `m` is displayed at a coarser level than `m`.
    fn shown_coarser(&self, nodes: &[NodeRecord], m: u32) -> bool {
        let mut j = m;
        loop {
            match self.marks[j as usize] {
                Mark::Shown => return j != m,
                Mark::Culled | Mark::Refined => return false,
                Mark::Off => match nodes[j as usize].parent {
                    NO_PARENT => return false,
                    p => j = p,
                },
            }
        }
    }
}

/// Whether a node can show anything: inside the frustum and not back-facing by its cone.
pub fn sees(n: &NodeRecord, camera: &Camera) -> bool {
    sees_bounds(&n.cone, n.center, n.radius, camera)
}

/// Whether anything with normals in `cone` and inside the sphere (`center`, `radius`) can show:
/// the sphere meets the frustum and the cone is not back-facing (selection.md §2).
pub fn sees_bounds(cone: &Cone, center: Vec3, radius: f32, camera: &Camera) -> bool {
    let facing = match camera.projection {
        Projection::Perspective { .. } => facing_perspective(cone, center, radius, camera.eye),
        Projection::Orthographic { .. } => facing_orthographic(cone, -camera.forward()),
    };
    facing != Facing::Back && camera.sees_sphere(center, radius)
}

/// The paper's refinement priority f(g) = (1 − cos(angle(e, n) + c)) / 2 when angle(e, n) + c < π,
/// else 1: silhouette groups and wide-cone groups first.
pub fn priority(n: &NodeRecord, camera: &Camera) -> f32 {
    let e = match camera.projection {
        Projection::Perspective { .. } => (camera.eye - n.center).normalize_or_zero(),
        Projection::Orthographic { .. } => -camera.forward(),
    };
    let axis = n.cone.axis.normalize_or_zero();
    let a = e.dot(axis).clamp(-1.0, 1.0).acos() + n.cone.half_angle;
    match a.partial_cmp(&PI) {
        Some(Ordering::Less) => (1.0 - a.cos()) / 2.0,
        _ => 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cone::Cone;
    use glam::Vec3;

    fn node(axis: Vec3, half_angle: f32) -> NodeRecord {
        NodeRecord {
            level: 1,
            parent: NO_PARENT,
            first_child: 0,
            child_count: 0,
            neighbor_first: 0,
            neighbor_count: 0,
            cone: Cone { axis, half_angle },
            center: Vec3::ZERO,
            radius: 0.1,
            error: 0.01,
            faces: 1,
            vertices: 3,
            offset: 0,
            size: 0,
            crc: 0,
        }
    }

    #[test]
    fn silhouette_and_wide_cones_come_first() {
        let cam = Camera::framing(Vec3::ZERO, 1.0, Vec3::Z, 1.0, 64, 64);
        let facing = priority(&node(Vec3::Z, 0.1), &cam);
        let silhouette = priority(&node(Vec3::X, 0.1), &cam);
        let wide = priority(&node(Vec3::Z, 1.2), &cam);
        assert!(silhouette > facing && wide > facing);
        assert!((facing - (1.0 - 0.1f32.cos()) / 2.0).abs() < 1e-4);
        assert_eq!(priority(&node(-Vec3::Z, 0.5), &cam), 1.0);
    }
}
