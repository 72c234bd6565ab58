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

/// The score of `u` as a merged group, or `None` when it breaks the round's limits.
fn evaluate(u: &Unit, p: &RoundParams) -> Option<f32> {
    if u.cone.half_angle > p.max_angle || u.faces > p.max_faces {
        return None;
    }
    let vc = (PI - u.cone.half_angle) / PI;
    let circle = PI * u.radius * u.radius;
    let vs = if circle > 0.0 { (u.area_normal.dot(u.cone.axis) / circle).clamp(0.0, 1.0) } else { 1.0 };
    let vn = (p.max_faces - u.faces) as f32 / p.max_faces as f32;
    Some(p.kc * vc + p.ks * vs + p.kn * vn)
}

#[derive(PartialEq)]
struct Candidate {
    score: f32,
    a: u32,
    b: u32,
    stamp_a: u32,
    stamp_b: u32,
}

impl Eq for Candidate {}

impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        // Highest score first; ties broken by unit indices so the result is deterministic.
        self.score.total_cmp(&other.score).then_with(|| other.a.cmp(&self.a)).then_with(|| other.b.cmp(&self.b))
    }
}

impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Run one round over `units` whose adjacency is `pairs` (each unordered pair once, any order).
/// Returns a group label per unit, labels numbered 0.. in order of each group's lowest unit.
pub fn group_round(units: &[Unit], pairs: &[[u32; 2]], p: &RoundParams) -> Vec<u32> {
    let n = units.len();
    let mut summary = units.to_vec();
    let mut stamp = vec![0u32; n];
    // Merged units point at the unit that absorbed them (a union-find forest, always to a lower index).
    let mut parent: Vec<u32> = (0..n as u32).collect();
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

    let mut heap = BinaryHeap::with_capacity(pairs.len());
    for &[a, b] in pairs {
        let (a, b) = (a.min(b), a.max(b));
        if a == b {
            continue;
        }
        if let Some(score) = evaluate(&summary[a as usize].merge(&summary[b as usize]), p) {
            heap.push(Candidate { score, a, b, stamp_a: 0, stamp_b: 0 });
        }
    }

    while let Some(c) = heap.pop() {
        let (a, b) = (c.a as usize, c.b as usize);
        if parent[a] != c.a || parent[b] != c.b || stamp[a] != c.stamp_a || stamp[b] != c.stamp_b {
            continue;
        }
        // Absorb b into a (a < b), then re-evaluate a against its neighbours.
        summary[a] = summary[a].merge(&summary[b]);
        parent[b] = c.a;
        stamp[a] += 1;
        let moved = std::mem::take(&mut neighbors[b]);
        for &x in &moved {
            if x as usize == a {
                continue;
            }
            let list = &mut neighbors[x as usize];
            list.retain(|&y| y != c.b);
            if !list.contains(&c.a) {
                list.push(c.a);
            }
        }
        let mut merged = std::mem::take(&mut neighbors[a]);
        merged.retain(|&y| y != c.b);
        for x in moved {
            if x != c.a && !merged.contains(&x) {
                merged.push(x);
            }
        }
        for &x in &merged {
            let (lo, hi) = (c.a.min(x), c.a.max(x));
            let (sl, sh) = (stamp[lo as usize], stamp[hi as usize]);
            if let Some(score) = evaluate(&summary[lo as usize].merge(&summary[hi as usize]), p) {
                heap.push(Candidate { score, a: lo, b: hi, stamp_a: sl, stamp_b: sh });
            }
        }
        neighbors[a] = merged;
    }

    // Parents always have lower indices, so one forward pass resolves every chain.
    let mut label = vec![0u32; n];
    let mut count = 0u32;
    for i in 0..n {
        let r = parent[i] as usize;
        if r == i {
            label[i] = count;
            count += 1;
        } else {
            label[i] = label[r];
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
