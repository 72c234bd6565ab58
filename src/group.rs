//! One grouping round: adjacent units (faces, or the groups of the previous round) merge greedily by
//! the evaluation function `v = kc·vc + ks·vs + kn·vn`, never past the round's cone threshold or size
//! cap (METHOD.md §3).
//!
//! Every candidate merge is evaluated in O(1) from per-group summaries: the cone of two cones, the
//! sum of area-weighted normals (whose projection on the axis is the projected area), and a
//! bounding sphere (whose radius bounds the circle enclosing the projection). A binary heap with
//! per-group version stamps invalidates stale candidates lazily.

use crate::cone::Cone;
use glam::Vec3;
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::f32::consts::PI;

/// What a grouping round knows of a unit (a face, or a group of the previous round).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Unit {
    /// A cone containing every face normal of the unit.
    pub cone: Cone,
    /// Sum of face area × unit face normal.
    pub area_normal: Vec3,
    /// A sphere containing every vertex of the unit.
    pub center: Vec3,
    pub radius: f32,
    /// Faces of the original mesh in the unit.
    pub faces: u32,
}

impl Unit {
    /// The summary of two units taken together; the cone and sphere enclose both (not minimal).
    pub fn merge(&self, other: &Unit) -> Unit {
        let (center, radius) = merge_spheres(self.center, self.radius, other.center, other.radius);
        Unit {
            cone: self.cone.merge(&other.cone),
            area_normal: self.area_normal + other.area_normal,
            center,
            radius,
            faces: self.faces + other.faces,
        }
    }
}

/// The smallest sphere enclosing two spheres.
pub fn merge_spheres(c0: Vec3, r0: f32, c1: Vec3, r1: f32) -> (Vec3, f32) {
    let d = c0.distance(c1);
    if d + r1 <= r0 {
        return (c0, r0);
    }
    if d + r0 <= r1 {
        return (c1, r1);
    }
    let r = 0.5 * (d + r0 + r1);
    let c = if d > 0.0 { c0 + (c1 - c0) * ((r - r0) / d) } else { c0 };
    // Rounding could leave an input sphere a hair outside; grow by a relative epsilon.
    (c, r * (1.0 + 1e-6))
}

/// The limits and weights of one round.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoundParams {
    /// No merged group's cone half-angle may exceed this (radians).
    pub max_angle: f32,
    /// No merged group may hold more original faces than this.
    pub max_faces: u32,
    /// Weight of cone tightness `vc = (π − angle) / π`.
    pub kc: f32,
    /// Weight of compactness `vs` = projected area over the area of its enclosing circle.
    pub ks: f32,
    /// Weight of size balance `vn = (cap − n) / cap`. The method's `N` is the mesh's face count;
    /// on a large mesh that makes `vn` constant, so strata measures size against the round's cap.
    pub kn: f32,
}

/// The score of merging `a` and `b` without building the merged summary: the merged cone's
/// half-angle is exact for the cone of two cones, and the projected area is taken along the merged
/// area-weighted normal, which is within a few degrees of the merged cone's axis for any group the
/// thresholds allow.
fn evaluate_pair(a: &Unit, b: &Unit, p: &RoundParams) -> Option<f32> {
    let faces = a.faces + b.faces;
    if faces > p.max_faces {
        return None;
    }
    let d = a.cone.axis.dot(b.cone.axis).clamp(-1.0, 1.0).acos();
    let (ra, rb) = (a.cone.half_angle, b.cone.half_angle);
    let half_angle = if d + rb <= ra {
        ra
    } else if d + ra <= rb {
        rb
    } else {
        (0.5 * (d + ra + rb)).min(PI)
    };
    if half_angle > p.max_angle {
        return None;
    }
    let (_, radius) = merge_spheres(a.center, a.radius, b.center, b.radius);
    let circle = PI * radius * radius;
    let projected = (a.area_normal + b.area_normal).length();
    let vc = (PI - half_angle) / PI;
    let vs = if circle > 0.0 { (projected / circle).min(1.0) } else { 1.0 };
    let vn = (p.max_faces - faces) as f32 / p.max_faces as f32;
    Some(p.kc * vc + p.ks * vs + p.kn * vn)
}

/// A group's best merge, as a heap entry: valid while the group's stamp is unchanged.
#[derive(PartialEq)]
struct Candidate {
    score: f32,
    group: u32,
    stamp: u32,
}

impl Eq for Candidate {}

impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        // Highest score first; ties broken by index so the result is deterministic.
        self.score.total_cmp(&other.score).then_with(|| other.group.cmp(&self.group))
    }
}

impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Mutable state of a round. Each live group keeps its best partner; the heap holds one entry per
/// group. The globally best pair is the best of both its groups, so it is always in the heap.
struct Round<'a> {
    p: &'a RoundParams,
    summary: Vec<Unit>,
    /// Bumped whenever a group's summary or best partner changes; stale heap entries are skipped.
    stamp: Vec<u32>,
    /// Bumped whenever a group's summary changes, to detect a partner that changed since.
    version: Vec<u32>,
    best: Vec<(u32, u32)>,
    /// Merged groups point at the group that absorbed them, always a lower index.
    parent: Vec<u32>,
    neighbors: Vec<Vec<u32>>,
    heap: BinaryHeap<Candidate>,
}

impl Round<'_> {
    /// Find `g`'s best partner and queue it.
    fn refresh(&mut self, g: u32) {
        self.stamp[g as usize] += 1;
        let mine = &self.summary[g as usize];
        let mut best: Option<(f32, u32)> = None;
        for &x in &self.neighbors[g as usize] {
            if let Some(score) = evaluate_pair(mine, &self.summary[x as usize], self.p) {
                if best.is_none_or(|(s, b)| score > s || (score == s && x < b)) {
                    best = Some((score, x));
                }
            }
        }
        if let Some((score, x)) = best {
            self.best[g as usize] = (x, self.version[x as usize]);
            self.heap.push(Candidate { score, group: g, stamp: self.stamp[g as usize] });
        }
    }

    /// Absorb group `b` into group `a` (a < b).
    fn merge(&mut self, a: u32, b: u32) {
        let (ai, bi) = (a as usize, b as usize);
        self.summary[ai] = self.summary[ai].merge(&self.summary[bi]);
        self.parent[bi] = a;
        self.version[ai] += 1;
        self.stamp[bi] += 1;
        let moved = std::mem::take(&mut self.neighbors[bi]);
        let mut merged = std::mem::take(&mut self.neighbors[ai]);
        merged.retain(|&y| y != b);
        for &x in &moved {
            if x == a {
                continue;
            }
            let list = &mut self.neighbors[x as usize];
            list.retain(|&y| y != b);
            if !list.contains(&a) {
                list.push(a);
            }
            if !merged.contains(&x) {
                merged.push(x);
            }
        }
        self.neighbors[ai] = merged;
        self.refresh(a);
    }
}

/// Run one round over `units` whose adjacency is `pairs` (each unordered pair once, any order).
/// Returns a group label per unit, labels numbered 0.. in order of each group's lowest unit.
pub fn group_round(units: &[Unit], pairs: &[[u32; 2]], p: &RoundParams) -> Vec<u32> {
    let n = units.len();
    let mut neighbors: Vec<Vec<u32>> = vec![Vec::new(); n];
    for &[a, b] in pairs {
        if a != b {
            neighbors[a as usize].push(b);
            neighbors[b as usize].push(a);
        }
    }
    for list in &mut neighbors {
        list.sort_unstable();
        list.dedup();
    }
    let mut r = Round {
        p,
        summary: units.to_vec(),
        stamp: vec![0; n],
        version: vec![0; n],
        best: vec![(0, 0); n],
        parent: (0..n as u32).collect(),
        neighbors,
        heap: BinaryHeap::with_capacity(n),
    };
    for g in 0..n as u32 {
        r.refresh(g);
    }
    while let Some(c) = r.heap.pop() {
        let g = c.group;
        if r.parent[g as usize] != g || r.stamp[g as usize] != c.stamp {
            continue;
        }
        let (x, seen_version) = r.best[g as usize];
        if r.parent[x as usize] != x || r.version[x as usize] != seen_version {
            r.refresh(g);
            continue;
        }
        r.merge(g.min(x), g.max(x));
    }

    // Parents always have lower indices, so one forward pass resolves every chain.
    let mut label = vec![0u32; n];
    let mut count = 0u32;
    for i in 0..n {
        let root = r.parent[i] as usize;
        if root == i {
            label[i] = count;
            count += 1;
        } else {
            label[i] = label[root];
        }
    }
    label
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat_unit(n: Vec3, x: f32) -> Unit {
        Unit { cone: Cone::from_normal(n), area_normal: n, center: Vec3::new(x, 0.0, 0.0), radius: 0.6, faces: 1 }
    }

    fn params(max_angle_deg: f32, max_faces: u32) -> RoundParams {
        RoundParams { max_angle: max_angle_deg.to_radians(), max_faces, kc: 1.0, ks: 0.2, kn: 0.1 }
    }

    #[test]
    fn strip_splits_at_the_crease() {
        // A strip of 6 units: three facing +Z, three facing +X, adjacent in a chain.
        let units: Vec<Unit> = (0..6).map(|i| flat_unit(if i < 3 { Vec3::Z } else { Vec3::X }, i as f32)).collect();
        let pairs: Vec<[u32; 2]> = (0..5).map(|i| [i, i + 1]).collect();
        let labels = group_round(&units, &pairs, &params(30.0, 100));
        assert_eq!(labels, vec![0, 0, 0, 1, 1, 1]);
        // Without a threshold the whole chain merges.
        let labels = group_round(&units, &pairs, &params(180.0, 100));
        assert_eq!(labels, vec![0; 6]);
        // The cap stops growth.
        let labels = group_round(&units, &pairs, &params(30.0, 2));
        assert!(labels.iter().all(|&l| labels.iter().filter(|&&m| m == l).count() <= 2));
    }

    #[test]
    fn units_without_adjacency_never_merge() {
        let units: Vec<Unit> = (0..4).map(|i| flat_unit(Vec3::Z, i as f32 * 10.0)).collect();
        let labels = group_round(&units, &[[0, 1]], &params(180.0, 100));
        assert_eq!(labels, vec![0, 0, 1, 2]);
    }

    #[test]
    fn merged_sphere_contains_both() {
        let (c, r) = merge_spheres(Vec3::ZERO, 1.0, Vec3::new(3.0, 0.0, 0.0), 0.5);
        assert!(c.distance(Vec3::ZERO) + 1.0 <= r + 1e-5);
        assert!(c.distance(Vec3::new(3.0, 0.0, 0.0)) + 0.5 <= r + 1e-5);
        assert!((r - 2.25).abs() < 1e-4);
    }
}
