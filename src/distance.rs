//! Sampled symmetric surface distance between two meshes, for tests and benchmarks.
//!
//! Points are sampled on each mesh (stratified by area, deterministic for a seed, plus every
//! vertex) and their exact distance to the other mesh's surface is found by a best-first descent
//! of a BVH over its triangles.

use crate::mesh::Mesh;
use glam::Vec3A;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::time::Duration;

/// Distances between two surfaces, in model units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Distance {
    /// Largest distance of any sample to the other surface: the sampled Hausdorff distance.
    pub max: f32,
    /// Mean of the two one-sided mean distances.
    pub mean: f32,
    /// Root of the mean of the two one-sided mean squared distances.
    pub rms: f32,
    /// Bounding box diagonal of `a`, to express the others relative to the model's size.
    pub diagonal: f32,
}

/// Symmetric distance between the surfaces of `a` and `b`: `samples_per_mesh` area-stratified
/// points plus the vertices of `a`, measured against `b`, and the same from `b` against `a`.
/// The same seed gives the same result. If one mesh has faces and the other has none, the
/// distances are infinite; two empty meshes are at distance 0.
pub fn surface_distance(a: &Mesh, b: &Mesh, samples_per_mesh: usize, seed: u64) -> Distance {
    let diagonal = a.diagonal();
    if a.triangles.is_empty() || b.triangles.is_empty() {
        let d = if a.triangles.is_empty() && b.triangles.is_empty() { 0.0 } else { f32::INFINITY };
        return Distance { max: d, mean: d, rms: d, diagonal };
    }
    let ab = one_sided(&sample_points(a, samples_per_mesh, seed), b);
    let ba = one_sided(&sample_points(b, samples_per_mesh, seed ^ 0x9e37_79b9_7f4a_7c15), a);
    Distance {
        max: ab.max.max(ba.max) as f32,
        mean: (0.5 * (ab.mean + ba.mean)) as f32,
        rms: (0.5 * (ab.mean_sq + ba.mean_sq)).sqrt() as f32,
        diagonal,
    }
}

/// Distances from a point set to a surface.
#[derive(Clone, Copy, Debug)]
struct OneSided {
    max: f64,
    mean: f64,
    mean_sq: f64,
}

/// `n` points stratified by area (point i falls in the i-th of n equal slices of the cumulative
/// area, uniformly inside its triangle), then every vertex used by a face.
fn sample_points(mesh: &Mesh, n: usize, seed: u64) -> Vec<Vec3A> {
    let mut cumulative = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0f64;
    for t in &mesh.triangles {
        total += 0.5 * crate::mesh::triangle_cross(&mesh.positions, t).length();
        cumulative.push(total);
    }
    let mut rng = SplitMix(seed);
    let mut points = Vec::with_capacity(n + mesh.positions.len());
    if total > 0.0 {
        for i in 0..n {
            let x = (i as f64 + rng.unit()) / n as f64 * total;
            let f = cumulative.partition_point(|&c| c <= x).min(mesh.triangles.len() - 1);
            let [a, b, c] = mesh.triangles[f].map(|v| mesh.positions[v as usize]);
            let (r1, r2) = (rng.unit().sqrt() as f32, rng.unit() as f32);
            points.push(Vec3A::from(a * (1.0 - r1) + b * (r1 * (1.0 - r2)) + c * (r1 * r2)));
        }
    }
    let mut used = vec![false; mesh.positions.len()];
    for t in &mesh.triangles {
        for &v in t {
            if !std::mem::replace(&mut used[v as usize], true) {
                points.push(Vec3A::from(mesh.positions[v as usize]));
            }
        }
    }
    points
}

/// Distances from `points` (at least one) to the surface of `mesh` (at least one face).
fn one_sided(points: &[Vec3A], mesh: &Mesh) -> OneSided {
    let tris: Vec<Triangle> = mesh
        .triangles
        .iter()
        .map(|t| {
            let [v0, v1, v2] = t.map(|v| Vec3A::from(mesh.positions[v as usize]));
            Triangle { v0, v1, v2 }
        })
        .collect();
    let bvh = build_bvh2_from_tris(&tris, BvhBuildParams::medium_build(), &mut Duration::default());
    let d: Vec<f32> = points.par_iter().map_init(BinaryHeap::new, |queue, &p| closest_distance_sq(&bvh, &tris, p, queue).sqrt()).collect();
    let n = d.len() as f64;
    OneSided {
        max: f64::from(d.iter().copied().fold(0.0, f32::max)),
        mean: d.iter().map(|&x| f64::from(x)).sum::<f64>() / n,
        mean_sq: d.iter().map(|&x| f64::from(x) * f64::from(x)).sum::<f64>() / n,
    }
}

/// A BVH node waiting in the best-first queue, nearest first.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Pending {
    dist_sq: f32,
    node: u32,
}

impl Eq for Pending {}

impl Ord for Pending {
    fn cmp(&self, o: &Self) -> Ordering {
        o.dist_sq.total_cmp(&self.dist_sq).then(o.node.cmp(&self.node))
    }
}

impl PartialOrd for Pending {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

/// Squared distance from `p` to the nearest triangle: nodes are opened nearest box first, and the
/// search ends when the nearest unopened box is farther than the best triangle found.
fn closest_distance_sq(bvh: &Bvh2, tris: &[Triangle], p: Vec3A, queue: &mut BinaryHeap<Pending>) -> f32 {
    let box_dist_sq = |node: u32| {
        let aabb = &bvh.nodes[node as usize].aabb;
        (aabb.min - p).max(p - aabb.max).max(Vec3A::ZERO).length_squared()
    };
    let mut best = f32::INFINITY;
    queue.clear();
    if bvh.nodes.is_empty() {
        return best;
    }
    queue.push(Pending { dist_sq: box_dist_sq(0), node: 0 });
    while let Some(Pending { dist_sq, node }) = queue.pop() {
        if dist_sq >= best {
            break;
        }
        let n = &bvh.nodes[node as usize];
        if n.prim_count > 0 {
            for i in n.first_index..n.first_index + n.prim_count {
                let t = &tris[bvh.primitive_indices[i as usize] as usize];
                best = best.min((closest_on_triangle(p, t) - p).length_squared());
            }
        } else {
            for child in [n.first_index, n.first_index + 1] {
                let d = box_dist_sq(child);
                if d < best {
                    queue.push(Pending { dist_sq: d, node: child });
                }
            }
        }
    }
    best
}

/// The point of triangle `t` nearest to `p`, by the Voronoi region of `p`: a corner, an edge, or
/// the interior (barycentric projection). Degenerate triangles fall back to their nearest edge.
fn closest_on_triangle(p: Vec3A, t: &Triangle) -> Vec3A {
    let (a, b, c) = (t.v0, t.v1, t.v2);
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let sum = va + vb + vc;
    if sum > 0.0 {
        return a + ab * (vb / sum) + ac * (vc / sum);
    }
    [(a, b), (b, c), (c, a)]
        .map(|(s, e)| {
            let d = e - s;
            let len_sq = d.length_squared();
            let u = if len_sq > 0.0 { ((p - s).dot(d) / len_sq).clamp(0.0, 1.0) } else { 0.0 };
            s + d * u
        })
        .into_iter()
        .min_by(|x, y| (*x - p).length_squared().total_cmp(&(*y - p).length_squared()))
        .unwrap_or(a)
}

/// SplitMix64: a small, fast, well-mixed deterministic generator.
struct SplitMix(u64);

impl SplitMix {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn sphere(n: u32, r: f32) -> Mesh {
        // A UV sphere: n rings by 2n segments, poles welded.
        let mut positions = vec![Vec3::new(0.0, 0.0, r)];
        for i in 1..n {
            let th = std::f32::consts::PI * i as f32 / n as f32;
            for j in 0..2 * n {
                let ph = std::f32::consts::PI * j as f32 / n as f32;
                positions.push(r * Vec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()));
            }
        }
        positions.push(Vec3::new(0.0, 0.0, -r));
        let ring = |i: u32, j: u32| 1 + (i - 1) * 2 * n + j % (2 * n);
        let south = positions.len() as u32 - 1;
        let mut triangles = Vec::new();
        for j in 0..2 * n {
            triangles.push([0, ring(1, j), ring(1, j + 1)]);
            triangles.push([south, ring(n - 1, j + 1), ring(n - 1, j)]);
            for i in 1..n - 1 {
                triangles.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
                triangles.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
            }
        }
        Mesh { positions, triangles, ..Default::default() }.clean().expect("finite").0
    }

    #[test]
    fn identical_meshes_are_at_zero() {
        let m = sphere(12, 1.0);
        let d = surface_distance(&m, &m, 5000, 1);
        assert!(d.max < 1e-5 && d.mean < 1e-6, "{d:?}");
        assert!((d.diagonal - 12f32.sqrt()).abs() < 1e-3);
    }

    #[test]
    fn translated_copy_is_at_the_translation() {
        // A flat square and its copy lifted along its normal: every sample is exactly 0.25 away.
        let p = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        let a = Mesh {
            positions: vec![p(0., 0., 0.), p(1., 0., 0.), p(1., 1., 0.), p(0., 1., 0.)],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        };
        let mut b = a.clone();
        b.positions.iter_mut().for_each(|q| q.z += 0.25);
        let d = surface_distance(&a, &b, 1000, 7);
        for x in [d.max, d.mean, d.rms] {
            assert!((x - 0.25).abs() < 1e-6, "{d:?}");
        }
        // Sideways, the distance of each point depends on where it lies; the far edge is 0.25 away.
        let mut c = a.clone();
        c.positions.iter_mut().for_each(|q| q.x += 0.25);
        let d = surface_distance(&a, &c, 1000, 7);
        assert!((d.max - 0.25).abs() < 1e-6 && d.mean < 0.25 && d.mean > 0.0, "{d:?}");
    }

    #[test]
    fn bvh_descent_matches_brute_force() {
        let a = sphere(10, 1.0);
        let mut b = sphere(7, 1.1);
        b.positions.iter_mut().enumerate().for_each(|(i, q)| *q += Vec3::splat(0.05 * ((i * 7919 % 13) as f32 / 13.0 - 0.5)));
        let points = sample_points(&a, 2000, 3);
        let tris: Vec<Triangle> = b
            .triangles
            .iter()
            .map(|t| {
                let [v0, v1, v2] = t.map(|v| Vec3A::from(b.positions[v as usize]));
                Triangle { v0, v1, v2 }
            })
            .collect();
        let bvh = build_bvh2_from_tris(&tris, BvhBuildParams::medium_build(), &mut Duration::default());
        let mut queue = BinaryHeap::new();
        for &p in &points {
            let brute = tris.iter().map(|t| (closest_on_triangle(p, t) - p).length_squared()).fold(f32::INFINITY, f32::min);
            let fast = closest_distance_sq(&bvh, &tris, p, &mut queue);
            assert_eq!(brute, fast, "at {p}");
        }
        assert!(points.len() == 2000 + a.vertex_count());
    }

    #[test]
    fn closest_point_regions() {
        let t = Triangle { v0: Vec3A::ZERO, v1: Vec3A::X, v2: Vec3A::Y };
        let at = |x: f32, y: f32, z: f32| closest_on_triangle(Vec3A::new(x, y, z), &t);
        assert_eq!(at(-1.0, -1.0, 0.0), Vec3A::ZERO);
        assert_eq!(at(2.0, -0.5, 1.0), Vec3A::X);
        assert_eq!(at(0.5, -1.0, 0.0), Vec3A::new(0.5, 0.0, 0.0));
        assert_eq!(at(0.25, 0.25, 3.0), Vec3A::new(0.25, 0.25, 0.0));
        assert_eq!(at(1.0, 1.0, 0.0), Vec3A::new(0.5, 0.5, 0.0));
        let line = Triangle { v0: Vec3A::ZERO, v1: Vec3A::X, v2: Vec3A::X * 2.0 };
        assert_eq!(closest_on_triangle(Vec3A::new(1.5, 1.0, 0.0), &line), Vec3A::new(1.5, 0.0, 0.0));
    }

    #[test]
    fn empty_meshes() {
        let m = sphere(4, 1.0);
        assert_eq!(surface_distance(&m, &Mesh::default(), 10, 0).max, f32::INFINITY);
        assert_eq!(surface_distance(&Mesh::default(), &Mesh::default(), 10, 0).max, 0.0);
    }
}
