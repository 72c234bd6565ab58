//! The rules of spec §6 that a file must satisfy, in one place for every reader: each value's range
//! is checked as the skeleton is decoded ([`super::skeleton`]); a node's rules here, which
//! [`Reader`] checks as it decodes the node and stops at the first problem, and
//! [`verify`](super::verify()) checks for every node and lists. What only the whole file can tell
//! (every chunk's frame, unknown chunks' CRCs, duplicate faces across nodes, the cluster count) is
//! `verify`'s alone.
//!
//! [`Reader`]: super::Reader

use super::skeleton::Skeleton;
use super::{NodeGeometry, NodeRecord, NO_PARENT};
use crate::error::Error;
use glam::{DVec3, Vec3};
use std::path::Path;

/// Angle tolerance, in radians, of cone containment checks (rounding of stored f32 values).
pub const ANGLE_TOLERANCE: f64 = 1e-5;
/// Relative tolerance of sphere containment checks.
const RADIUS_TOLERANCE: f32 = 1e-5;

/// Problems found, up to a limit: a reader stops at the first, `verify` lists many.
pub(crate) struct Sink {
    pub problems: Vec<Error>,
    limit: usize,
}

impl Sink {
    pub fn new(limit: usize) -> Sink {
        Sink { problems: Vec::new(), limit: limit.max(1) }
    }

    pub fn push(&mut self, e: Error) {
        if self.problems.len() < self.limit {
            self.problems.push(e);
        }
    }

    pub fn full(&self) -> bool {
        self.problems.len() >= self.limit
    }

    /// The first problem, if any.
    pub fn first(self) -> Option<Error> {
        self.problems.into_iter().next()
    }
}

/// Angle between two directions, in f64.
pub(crate) fn angle(a: Vec3, b: Vec3) -> f64 {
    let (a, b) = (a.as_dvec3(), b.as_dvec3());
    a.cross(b).length().atan2(a.dot(b))
}

/// Whether a cone of half-angle `half` reaches `needed` radians from its axis (a cone of π holds
/// every direction).
pub(crate) fn cone_covers(half: f32, needed: f64) -> bool {
    needed <= half as f64 + ANGLE_TOLERANCE || half as f64 >= std::f64::consts::PI - ANGLE_TOLERANCE
}

/// The squared distance from a sphere's center within which a point lies in it, with the
/// tolerance of the stored radius.
fn sphere_reach(radius: f32) -> f32 {
    let r = radius * (1.0 + RADIUS_TOLERANCE) + 1e-30;
    r * r
}

/// Whether `p` lies in the sphere (center, radius), with the tolerance of the stored radius.
fn in_sphere(center: Vec3, radius: f32, p: Vec3) -> bool {
    center.distance_squared(p) <= sphere_reach(radius)
}

/// A cone tested against many face normals: `angle(axis, d) ≤ half + tolerance`, as
/// `(axis·d)·sin(reach) − |axis × d|·cos(reach) ≥ 0`, which is the sine of `reach − angle` scaled by
/// `|axis|·|d|`: as exact as the angle itself near zero, and without an arc tangent per face.
struct ConeTest {
    axis: DVec3,
    /// (sin, cos) of half + tolerance; `None` when the cone holds every direction.
    reach: Option<(f64, f64)>,
}

impl ConeTest {
    fn new(axis: Vec3, half: f32) -> ConeTest {
        let reach = half as f64 + ANGLE_TOLERANCE;
        let all = half as f64 >= std::f64::consts::PI - ANGLE_TOLERANCE;
        ConeTest { axis: axis.as_dvec3(), reach: (!all).then(|| reach.sin_cos()) }
    }

    /// Whether the cone holds direction `d` (any length; zero holds).
    fn holds(&self, d: DVec3) -> bool {
        self.reach.is_none_or(|(sin, cos)| self.axis.dot(d) * sin - self.axis.cross(d).length() * cos >= 0.0)
    }
}

/// Node `i`'s rules on the skeleton (§6, §7): its cone, box and sphere contain its children's and
/// its error is not below theirs; its neighbour list is strictly ascending, of its own level, without
/// itself, and each neighbour lists it back; at the top level, its box lies inside the `HEAD`
/// bounds. Each value's own range (finite, ordered, not negative) and the level totals are checked
/// as the node table is decoded.
pub(crate) fn relations(path: &Path, s: &Skeleton, i: u32, sink: &mut Sink) {
    let problem = |msg: String| Error::at_element(path, format!("node {i}"), msg);
    let Some(n) = s.nodes.get(i as usize) else { return };
    let (min, max) = s.node_box(i);
    for c in s.children(i) {
        let ch = &s.nodes[c as usize];
        if !cone_covers(n.cone.half_angle, angle(n.cone.axis, ch.cone.axis) + ch.cone.half_angle as f64) {
            sink.push(problem(format!("cone does not contain child {c}'s")));
        }
        let (cmin, cmax) = s.node_box(c);
        if !(min.cmple(cmin).all() && cmax.cmple(max).all()) {
            sink.push(problem(format!("box does not contain child {c}'s")));
        }
        if n.center.distance(ch.center) + ch.radius > n.radius * (1.0 + RADIUS_TOLERANCE) + 1e-30 {
            sink.push(problem(format!("sphere does not contain child {c}'s")));
        }
        if ch.error > n.error {
            sink.push(problem(format!("error {} is smaller than child {c}'s {}", n.error, ch.error)));
        }
    }
    let nb = s.neighbors(i);
    if nb.windows(2).any(|w| w[0] >= w[1]) {
        sink.push(problem("neighbours are not strictly ascending".into()));
    }
    let range = s.level_nodes(n.level);
    for &j in nb {
        if j == i || !range.contains(&j) || s.neighbors(j).binary_search(&i).is_err() {
            sink.push(problem(format!("neighbour {j} is not a different node of level {} listing it back", n.level)));
        }
    }
    if n.level == s.top() && !(s.header.min.cmple(min).all() && max.cmple(s.header.max).all()) {
        sink.push(problem("box lies outside the HEAD bounds".into()));
    }
}

/// Format 4's rules on the DAG (strata-v4.md §2): a node above level 0 has its source group's
/// error; a group's error is at least each child's, and its sphere holds each child's sphere and
/// the sphere of each child's source group. Every group and node of `s` (a whole skeleton).
pub(crate) fn dag(path: &Path, s: &Skeleton, sink: &mut Sink) {
    let Some(d) = &s.dag else { return };
    let holds = |c: Vec3, r: f32, ci: Vec3, ri: f32| {
        c.as_dvec3().distance(ci.as_dvec3()) + ri as f64 <= r as f64 * (1.0 + RADIUS_TOLERANCE as f64) + 1e-30
    };
    for (i, n) in s.nodes.iter().enumerate() {
        match d.source.get(i) {
            Some(&g) if g != NO_PARENT && d.groups[g as usize].error != n.error => sink.push(Error::at_element(
                path,
                format!("node {i}"),
                format!("error {} is not its source group {g}'s {}", n.error, d.groups[g as usize].error),
            )),
            _ => {}
        }
    }
    for (g, group) in d.groups.iter().enumerate() {
        let problem = |msg: String| Error::at_element(path, format!("group {g}"), msg);
        for &c in d.children(g as u32) {
            let Some(child) = s.nodes.get(c as usize) else { continue };
            if child.error > group.error {
                sink.push(problem(format!("error {} is smaller than child {c}'s {}", group.error, child.error)));
            }
            if !holds(group.center, group.radius, child.center, child.radius) {
                sink.push(problem(format!("sphere does not contain child {c}'s")));
            }
            if let Some(&src) = d.source.get(c as usize).filter(|&&x| x != NO_PARENT) {
                let source = &d.groups[src as usize];
                if !holds(group.center, group.radius, source.center, source.radius) {
                    sink.push(problem(format!("sphere does not contain the sphere of child {c}'s source group {src}")));
                }
            }
            if sink.full() {
                return;
            }
        }
    }
}

/// A node's rules on its decoded geometry (§6, §8): UVs finite; every vertex inside the node's box
/// and sphere; every non-degenerate face's normal inside the node's cone; every cluster's faces
/// inside its cone and sphere. Ranges, counts and tiling are checked as the node is decoded.
pub(crate) fn node(path: &Path, i: u32, n: &NodeRecord, bbox: (Vec3, Vec3), g: &NodeGeometry, sink: &mut Sink) {
    let problem = |msg: String| Error::at_element(path, format!("node {i}"), msg);
    if let Some(k) = g.uvs.iter().position(|uv| !uv.is_finite()) {
        sink.push(problem(format!("UV {k} is not finite")));
    }
    let (min, max) = bbox;
    if let Some(k) = g.positions.iter().position(|p| !(min.cmple(*p).all() && p.cmple(max).all())) {
        sink.push(problem(format!("vertex {k} lies outside the node's box")));
    }
    if let Some(k) = g.positions.iter().position(|&p| !in_sphere(n.center, n.radius, p)) {
        sink.push(problem(format!("vertex {k} lies outside the node's sphere")));
    }
    let cross = |t: &[u32]| {
        let [a, b, c] = [t[0], t[1], t[2]].map(|v| g.positions[v as usize].as_dvec3());
        (b - a).cross(c - a)
    };
    let cone = ConeTest::new(n.cone.axis, n.cone.half_angle);
    let mut outside_cone = None;
    if g.clusters.is_empty() {
        outside_cone = g.indices.chunks_exact(3).position(|t| !cone.holds(cross(t)));
    }
    for cl in &g.clusters {
        // A face within a cluster cone that lies inside the node's is within the node's too.
        let nested = angle(n.cone.axis, cl.cone.axis) + cl.cone.half_angle as f64 <= n.cone.half_angle as f64;
        let cl_cone = ConeTest::new(cl.cone.axis, cl.cone.half_angle);
        let (center, reach) = (cl.center, sphere_reach(cl.radius));
        let mut outside = false;
        for (k, t) in g.indices[cl.first_face as usize * 3..(cl.first_face + cl.face_count) as usize * 3].chunks_exact(3).enumerate() {
            let d = cross(t);
            outside |= !cl_cone.holds(d) || t.iter().any(|&x| center.distance_squared(g.positions[x as usize]) > reach);
            if outside_cone.is_none() && !nested && !cone.holds(d) {
                outside_cone = Some(cl.first_face as usize + k);
            }
        }
        if outside {
            sink.push(problem(format!("a face of the cluster at face {} lies outside its cone or sphere", cl.first_face)));
            if sink.full() {
                return;
            }
        }
    }
    if let Some(f) = outside_cone {
        sink.push(problem(format!("face {f}'s normal lies outside the node's cone")));
    }
}
