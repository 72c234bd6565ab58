//! Normals derived from a level's own geometry exactly as format 3's readers predict them
//! (strata-v3.md §5.5), for `--normals geometry`.
//!
//! A reader predicts a vertex's normal from the sum, over the node's faces at that vertex, of the
//! cross products of their edges on the grid. Where a node holds every face of a vertex's smooth
//! class (its corners sharing one normal: creases split a vertex into classes), storing the
//! octahedral code of the same sum over the level makes the residual zero, and the normal costs a
//! few hundredths of a bit. Where a class's faces lie in several nodes, each stores that same
//! level-wide code (a residual against its own partial sum), so neighbouring nodes shade their
//! shared vertices alike. Vertices on an edge without exactly two faces keep the normal the
//! mesh carries: a piece of a partitioned build sees only its own side of its border, and its
//! neighbour must store the same code there.

use crate::format::geom::v3::predict_octa;
use crate::format::octa;
use crate::mesh::Mesh;
use glam::Vec3;
use rustc_hash::{FxHashMap, FxHashSet};

/// The derived codes of one level mesh, by vertex and the normal its corner carries.
pub struct DerivedNormals {
    codes: FxHashMap<(u32, [u32; 3]), [i16; 2]>,
}

impl DerivedNormals {
    /// The codes at `bits` per octahedral coordinate for `mesh`, whose vertex `v` lies at grid
    /// point `points[v]` (as the file stores it: a coarse level's inner vertices on their lattice).
    pub fn new(mesh: &Mesh, points: &[[u32; 3]], bits: u32) -> DerivedNormals {
        let mut edges: FxHashMap<(u32, u32), u32> = FxHashMap::default();
        for t in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        let open: FxHashSet<u32> = edges.iter().filter(|&(_, &n)| n != 2).flat_map(|(&(a, b), _)| [a, b]).collect();
        drop(edges);
        let mut sums: FxHashMap<(u32, [u32; 3]), [f64; 3]> = FxHashMap::default();
        for (f, t) in mesh.triangles.iter().enumerate() {
            let n = face_cross(t.map(|v| points[v as usize]));
            for (k, &v) in t.iter().enumerate() {
                if open.contains(&v) {
                    continue;
                }
                let s = sums.entry((v, mesh.normals[3 * f + k].to_array().map(f32::to_bits))).or_default();
                s[0] += n[0];
                s[1] += n[1];
                s[2] += n[2];
            }
        }
        let scale = octa::scale(bits);
        let codes = sums.into_iter().map(|(key, s)| (key, predict_octa(s[0], s[1], s[2], scale).map(|c| c as i16))).collect();
        DerivedNormals { codes }
    }

    /// The code of vertex `v` at a corner carrying `normal`; `None` where the carried normal is
    /// to be kept (a vertex on an open or non-manifold edge).
    pub fn code(&self, v: u32, normal: Vec3) -> Option<[i16; 2]> {
        self.codes.get(&(v, normal.to_array().map(f32::to_bits))).copied()
    }
}

/// The cross product of a face's edges from its first corner, on the grid, as a reader computes
/// it (exact in f64 below 2^42, and the same for any rotation of the corners).
fn face_cross(q: [[u32; 3]; 3]) -> [f64; 3] {
    let u = [0, 1, 2].map(|k| q[1][k] as f64 - q[0][k] as f64);
    let w = [0, 1, 2].map(|k| q[2][k] as f64 - q[0][k] as f64);
    [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square pyramid without a base: four faces around an apex, its rim open.
    fn pyramid() -> (Mesh, Vec<[u32; 3]>) {
        let points = vec![[10, 10, 20], [0, 0, 0], [20, 0, 0], [20, 20, 0], [0, 20, 0]];
        let mut mesh = Mesh {
            positions: points.iter().map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32)).collect(),
            triangles: vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]],
            ..Mesh::default()
        };
        mesh.normals = vec![Vec3::Z; 12];
        (mesh, points)
    }

    #[test]
    fn a_closed_fan_gets_the_readers_prediction_and_an_open_rim_keeps_its_normal() {
        let (mesh, points) = pyramid();
        let d = DerivedNormals::new(&mesh, &points, 8);
        // The apex's faces sum to a vertical normal: code (0, 0), the octahedron's top.
        assert_eq!(d.code(0, Vec3::Z), Some([0, 0]));
        for v in 1..5 {
            assert_eq!(d.code(v, Vec3::Z), None, "rim vertex {v}");
        }
        // Corners carrying another normal are another class, absent here.
        assert_eq!(d.code(0, Vec3::X), None);
    }

    #[test]
    fn the_code_is_the_prediction_of_the_same_faces_in_any_corner_order() {
        let (mut mesh, points) = pyramid();
        let before = DerivedNormals::new(&mesh, &points, 10).code(0, Vec3::Z);
        for t in &mut mesh.triangles {
            t.rotate_left(1);
        }
        assert_eq!(DerivedNormals::new(&mesh, &points, 10).code(0, Vec3::Z), before);
    }
}
