//! The rules of spec §6 that a file must satisfy, in one place for every reader: [`Reader`]
//! checks the skeleton's rules when it opens a file and a node's rules when it decodes the node,
//! and stops at the first problem; [`verify`](super::verify()) runs the same functions over the
//! whole file and lists what they find. What only the whole file can tell (every chunk's frame,
//! unknown chunks' CRCs, duplicate faces across nodes, the cluster count) is `verify`'s alone.
//!
//! [`Reader`]: super::Reader

use super::{Header, LevelRecord, NodeGeometry, NodeRecord, NO_PARENT};
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

/// Whether `p` lies in the sphere (center, radius), with the tolerance of the stored radius.
fn in_sphere(center: Vec3, radius: f32, p: Vec3) -> bool {
    center.distance(p) <= radius * (1.0 + RADIUS_TOLERANCE) + 1e-30
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

/// The skeleton's rules (§6, §7): each node's values in range; its cone, box and sphere containing
/// its children's; errors finite, not negative and never below a child's; neighbour lists ascending,
/// of the same level and symmetric; the top level's boxes inside the `HEAD` bounds; the `LEVL`
/// totals and `HEAD` input faces matching the node table. `boxes` are the nodes' boxes; the tree
/// shape itself is checked as the node table is parsed.
pub(crate) fn skeleton(
    path: &Path,
    header: &Header,
    levels: &[LevelRecord],
    nodes: &[NodeRecord],
    neighbors: &[u32],
    boxes: &[(Vec3, Vec3)],
    sink: &mut Sink,
) {
    let problem = |i: usize, msg: String| Error::at_element(path, format!("node {i}"), msg);
    let list = |i: usize| {
        let n = &nodes[i];
        &neighbors[n.neighbor_first as usize..(n.neighbor_first + n.neighbor_count) as usize]
    };
    let mut totals = vec![(0u64, 0u64, 0u64); levels.len()];
    // Each node's own values first, so that a bad value is named at its node, not at its parent's.
    let mut sane = vec![false; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        let t = &mut totals[n.level as usize];
        let end = n.offset + n.size as u64;
        *t = (t.0 + n.faces as u64, t.1 + n.vertices as u64, t.2 + n.size as u64 + super::chunk::padding(end));
        let (min, max) = boxes[i];
        sane[i] = n.cone.axis.is_finite()
            && (n.cone.axis.length() - 1.0).abs() < 1e-3
            && (0.0..=std::f32::consts::PI).contains(&n.cone.half_angle)
            && n.center.is_finite()
            && n.radius.is_finite()
            && n.radius >= 0.0
            && min.is_finite()
            && max.is_finite()
            && min.cmple(max).all()
            && n.error.is_finite()
            && n.error >= 0.0;
        if !sane[i] {
            sink.push(problem(i, format!("cone, bounds or error out of range (error {}, radius {})", n.error, n.radius)));
        }
    }
    for (i, n) in nodes.iter().enumerate() {
        if sink.full() {
            return;
        }
        if !sane[i] {
            continue;
        }
        let (min, max) = boxes[i];
        for c in (n.first_child..n.first_child + n.child_count).filter(|&c| sane[c as usize]) {
            let ch = &nodes[c as usize];
            if !cone_covers(n.cone.half_angle, angle(n.cone.axis, ch.cone.axis) + ch.cone.half_angle as f64) {
                sink.push(problem(i, format!("cone does not contain child {c}'s")));
            }
            let (cmin, cmax) = boxes[c as usize];
            if !(min.cmple(cmin).all() && cmax.cmple(max).all()) {
                sink.push(problem(i, format!("box does not contain child {c}'s")));
            }
            if n.center.distance(ch.center) + ch.radius > n.radius * (1.0 + RADIUS_TOLERANCE) + 1e-30 {
                sink.push(problem(i, format!("sphere does not contain child {c}'s")));
            }
            if ch.error > n.error {
                sink.push(problem(i, format!("error {} is smaller than child {c}'s {}", n.error, ch.error)));
            }
        }
        let nb = list(i);
        if nb.windows(2).any(|w| w[0] >= w[1]) {
            sink.push(problem(i, "neighbours are not strictly ascending".into()));
        }
        let level = &levels[n.level as usize];
        let range = level.first_node..level.first_node + level.nodes;
        for &j in nb {
            if j as usize == i || !range.contains(&j) || list(j as usize).binary_search(&(i as u32)).is_err() {
                sink.push(problem(i, format!("neighbour {j} is not a different node of level {} listing it back", n.level)));
            }
        }
        if n.parent == NO_PARENT && !(header.min.cmple(min).all() && max.cmple(header.max).all()) {
            sink.push(problem(i, "box lies outside the HEAD bounds".into()));
        }
    }
    for (l, (rec, t)) in levels.iter().zip(&totals).enumerate() {
        if (rec.faces, rec.vertices, rec.bytes) != *t {
            sink.push(Error::at_element(
                path,
                format!("level {l}"),
                format!("LEVL says {} faces, {} vertices, {} bytes; the nodes hold {}, {}, {}", rec.faces, rec.vertices, rec.bytes, t.0, t.1, t.2),
            ));
        }
    }
    if let Some(t) = totals.first().filter(|t| t.0 != header.input_faces) {
        sink.push(Error::at_element(path, "level 0", format!("nodes hold {} faces, HEAD says the input has {}", t.0, header.input_faces)));
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
    if let Some(f) = g.indices.chunks_exact(3).position(|t| !cone.holds(cross(t))) {
        sink.push(problem(format!("face {f}'s normal lies outside the node's cone")));
    }
    for cl in &g.clusters {
        let cone = ConeTest::new(cl.cone.axis, cl.cone.half_angle);
        let range = cl.first_face as usize * 3..(cl.first_face + cl.face_count) as usize * 3;
        let outside = g.indices[range].chunks_exact(3).any(|t| {
            !cone.holds(cross(t)) || t.iter().any(|&x| !in_sphere(cl.center, cl.radius, g.positions[x as usize]))
        });
        if outside {
            sink.push(problem(format!("a face of the cluster at face {} lies outside its cone or sphere", cl.first_face)));
            if sink.full() {
                return;
            }
        }
    }
}
