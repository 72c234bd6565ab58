//! Bounds that hold what they claim (spec §6, §11): the stored box, sphere, cone and error of every
//! node and culling cluster, computed on the quantized positions and rounded outward, so that
//! culling a node or a cluster by them never hides a face it holds or a descendant holds.
//!
//! Bottom-up: each node starts from its group's bounds and cone in the hierarchy, grows to cover
//! its own (simplified, quantized) faces and its children's stored bounds, and its error is the
//! level's error plus the quantization bound, raised to its children's.

use crate::format::codes::{angle, store_cone, store_radius};
use crate::format::geom::v2::ClusterCodes;
use crate::format::skeleton::NodeCodes;
use crate::format::{Cone, Grid};
use crate::hierarchy::{Hierarchy, Lists};
use crate::levels::LevelMeshes;
use crate::mesh::{triangle_cross, Mesh};
use crate::quantize::Quantized;
use glam::Vec3;
use rayon::prelude::*;

/// A node's stored bounds, and the values they decode to (for its parent to cover).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodeBounds {
    pub codes: NodeCodes,
    pub cone: Cone,
    pub center: Vec3,
    pub radius: f32,
    pub error: f32,
}

/// The bounds of every group of every level, `[level][group]`. `faces[l]` lists each group's
/// faces of level mesh `l`; `quant[l]` its quantized positions. `base`, when given, is level 0's
/// bounds, already known (the partitioned build's cell tops).
pub fn nodes(
    h: &Hierarchy,
    lv: &LevelMeshes,
    faces: &[Lists],
    grid: &Grid,
    quant: &[Quantized],
    base: Option<Vec<NodeBounds>>,
) -> Result<Vec<Vec<NodeBounds>>, String> {
    let mut out: Vec<Vec<NodeBounds>> = Vec::with_capacity(h.levels.len());
    let skip = match base {
        Some(b) if b.len() != h.levels.first().map_or(0, |l| l.groups.len()) => {
            return Err(format!("{} level-0 bounds for {} groups", b.len(), h.levels[0].groups.len()))
        }
        Some(b) => {
            out.push(b);
            1
        }
        None => 0,
    };
    for (l, (hl, q)) in h.levels.iter().zip(quant).enumerate().skip(skip) {
        let mesh = &lv.levels[l].mesh;
        let children = (l > 0).then(|| Lists::from_labels(&h.levels[l - 1].parent, hl.groups.len()));
        // Each group on its own, on every core; the first error in group order is reported.
        let node = |(g, info): (usize, &crate::hierarchy::GroupInfo)| -> Result<NodeBounds, String> {
            if !(info.min.is_finite() && info.max.is_finite() && info.center.is_finite() && info.radius.is_finite()) {
                return Err(format!("level {l} group {g}: bounds are not finite"));
            }
            let below: Vec<&NodeBounds> =
                children.as_ref().map_or(Vec::new(), |c| c.get(g).iter().map(|&k| &out[l - 1][k as usize]).collect());
            let own = faces[l].get(g);
            let (mut lo, mut hi) = (grid.bound(info.min, false), grid.bound(info.max, true));
            let mut grow = |p: [u32; 3]| {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            };
            for &f in own {
                for &v in &mesh.triangles[f as usize] {
                    grow(q.points[v as usize]);
                }
            }
            for c in &below {
                grow(c.codes.min);
                grow(c.codes.max);
            }

            let center = grid.encode(info.center);
            let dc = grid.decode(center).as_dvec3();
            let mut needed = info.radius as f64 + dc.distance(info.center.as_dvec3());
            for &f in own {
                for &v in &mesh.triangles[f as usize] {
                    needed = needed.max(dc.distance(q.positions[v as usize].as_dvec3()));
                }
            }
            let mut error = lv.levels[l].group_error[g] + q.error(grid, mesh, own);
            for c in &below {
                needed = needed.max(dc.distance(c.center.as_dvec3()) + c.radius as f64);
                error = error.max(c.error);
            }
            let (radius_code, radius) = store_radius(grid, needed);

            let normals = face_normals(mesh, q, own);
            let axis = info.cone.axis.normalize_or(Vec3::Z);
            let (axis_code, half_angle, cone) = store_cone(axis, |d| {
                let mut need = info.cone.half_angle as f64 + angle(axis, d);
                for &nrm in &normals {
                    need = need.max(angle(d, nrm));
                }
                for c in &below {
                    need = need.max(angle(d, c.cone.axis) + c.cone.half_angle as f64);
                }
                need
            });
            let codes = NodeCodes { min: lo, max: hi, center, axis: axis_code, half_angle, radius: radius_code };
            Ok(NodeBounds { codes, cone, center: grid.decode(center), radius, error })
        };
        let level: Vec<Result<NodeBounds, String>> = hl.groups.par_iter().enumerate().map(node).collect();
        let level = level.into_iter().collect::<Result<Vec<NodeBounds>, String>>()?;
        out.push(level);
    }
    Ok(out)
}

/// The unit normals of the non-degenerate faces `faces` of `mesh`, on its quantized positions.
fn face_normals(mesh: &Mesh, q: &Quantized, faces: &[u32]) -> Vec<Vec3> {
    faces
        .iter()
        .map(|&f| triangle_cross(&q.positions, &mesh.triangles[f as usize]))
        .filter(|c| c.length_squared() > 0.0)
        .map(|c| c.normalize().as_vec3())
        .collect()
}

/// The stored box, sphere (around `center`) and cone (around `axis`) of the faces `faces` of
/// `mesh` alone, on its quantized positions, rounded outward; and the sphere they decode to. A
/// DAG's node bounds its own geometry only (strata-v4.md §2).
pub fn of_faces(mesh: &Mesh, q: &Quantized, grid: &Grid, faces: &[u32], center: Vec3, axis: Vec3) -> (NodeCodes, Vec3, f32) {
    let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
    let center = grid.encode(center);
    let dc = grid.decode(center).as_dvec3();
    let mut needed = 0f64;
    for &f in faces {
        for &v in &mesh.triangles[f as usize] {
            let p = q.points[v as usize];
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
            needed = needed.max(dc.distance(q.positions[v as usize].as_dvec3()));
        }
    }
    let (radius_code, radius) = store_radius(grid, needed);
    let normals = face_normals(mesh, q, faces);
    let axis = axis.normalize_or(Vec3::Z);
    let (axis_code, half_angle, _) = store_cone(axis, |d| normals.iter().map(|&n| angle(d, n)).fold(0.0, f64::max));
    (NodeCodes { min: lo, max: hi, center, axis: axis_code, half_angle, radius: radius_code }, grid.decode(center), radius)
}

/// The stored record of a culling cluster of faces `run` of `mesh`, starting from the hierarchy's
/// sphere and cone for it (`seed`: center, radius, cone), widened to cover the quantized faces.
/// `node` is where the cluster's node stores positions: its base grid point, largest offset and
/// cluster shift.
pub fn cluster(mesh: &Mesh, q: &Quantized, grid: &Grid, run: &[u32], seed: (Vec3, f32, Cone), node: ([u32; 3], u32, u32)) -> ClusterCodes {
    let (center, radius, cone) = seed;
    let (base, span, shift) = node;
    let target = grid.encode(center);
    let c: [u32; 3] = std::array::from_fn(|k| (target[k].saturating_sub(base[k]).min(span) >> shift).min(u16::MAX as u32));
    let dc = grid.decode(std::array::from_fn(|k| base[k] + (c[k] << shift))).as_dvec3();
    let mut needed = radius as f64 + dc.distance(center.as_dvec3());
    let mut normals = Vec::new();
    for &f in run {
        let t = &mesh.triangles[f as usize];
        for &v in t {
            needed = needed.max(dc.distance(q.positions[v as usize].as_dvec3()));
        }
        let n = triangle_cross(&q.positions, t);
        if n.length_squared() > 0.0 {
            normals.push(n.normalize().as_vec3());
        }
    }
    let (radius, _) = store_radius(grid, needed);
    let axis = cone.axis.normalize_or(Vec3::Z);
    let (axis_code, half_angle, _) =
        store_cone(axis, |d| normals.iter().fold(cone.half_angle as f64 + angle(axis, d), |m, &n| m.max(angle(d, n))));
    ClusterCodes { axis: axis_code, half_angle, faces: 0, center: c.map(|x| x as u16), radius }
}
