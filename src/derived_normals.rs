//! Normals derived from a level's own geometry exactly as format 3's readers predict them
//! (strata-v3.md §5.5): for meshes without normals, and for `--normals geometry`.
//!
//! A reader predicts a vertex's normal from the sum, over the node's faces at that vertex, of the
//! cross products of their edges on the grid. Where a node holds every face of a vertex's smooth
//! class (its corners sharing one carried normal: creases split a vertex into classes), storing
//! the octahedral code of the same sum over the level makes the residual zero, and the normal costs
//! a few hundredths of a bit. Where a class's faces lie in several nodes, each stores that same
//! level-wide code (a residual against its own partial sum), so neighbouring nodes shade their
//! shared vertices alike. The carried normal stays where the level cannot see a vertex's whole
//! fan: on an edge without exactly two faces, and at a vertex the caller keeps (a piece of a
//! partitioned build sees only its own side of the vertices it shares with other pieces). A class
//! whose faces all vanish on the grid gets the reader's prediction for a zero sum, (0, 0): its
//! faces cover no pixel, so the cheapest code is as good as any.

use crate::format::geom::v3::{face_cross, predict_octa};
use crate::format::octa;
use crate::mesh::Mesh;
use rayon::prelude::*;

/// The derived code of each corner of one level mesh, `None` where the carried normal stays.
pub struct DerivedNormals {
    /// Per corner (`3f + k`), its class.
    class: Vec<u32>,
    /// Per class, its code; [`KEEP`] for the carried normal.
    codes: Vec<[i16; 2]>,
}

/// A class whose corners keep their carried normal (no octahedral code reaches −32768).
const KEEP: [i16; 2] = [i16::MIN, i16::MIN];

impl DerivedNormals {
    /// The codes at `bits` per octahedral coordinate for `mesh`, whose vertex `v` lies at grid
    /// point `points[v]` (as the file stores it: a coarse level's inner vertices on their lattice);
    /// vertices for which `keep` holds keep their carried normal.
    pub fn new(mesh: &Mesh, points: &[[u32; 3]], bits: u32, keep: impl Fn(u32) -> bool) -> DerivedNormals {
        let nv = mesh.positions.len();
        let corners = 3 * mesh.triangles.len();
        // Vertices on an edge without exactly two faces: sort the edges, count the runs.
        let mut edges: Vec<u64> = mesh
            .triangles
            .par_iter()
            .flat_map_iter(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]) as u64) << 32 | t[k].max(t[(k + 1) % 3]) as u64))
            .collect();
        edges.par_sort_unstable();
        let mut open = vec![false; nv];
        for run in edges.chunk_by(|a, b| a == b) {
            if run.len() != 2 {
                open[(run[0] >> 32) as usize] = true;
                open[(run[0] & 0xFFFF_FFFF) as usize] = true;
            }
        }
        drop(edges);
        // Corners by vertex (a counting sort), then classes: a vertex's corners with the same
        // carried normal, numbered in order of first corner.
        let mut start = vec![0u32; nv + 1];
        for t in &mesh.triangles {
            for &v in t {
                start[v as usize + 1] += 1;
            }
        }
        for v in 0..nv {
            start[v + 1] += start[v];
        }
        let mut by_vertex = vec![0u32; corners];
        let mut fill = start.clone();
        for (c, &v) in mesh.triangles.iter().flatten().enumerate() {
            by_vertex[fill[v as usize] as usize] = c as u32;
            fill[v as usize] += 1;
        }
        drop(fill);
        let normal = |c: u32| mesh.normals.get(c as usize).map_or([0; 3], |n| n.to_array().map(f32::to_bits));
        let mut class = vec![0u32; corners];
        let mut kept = Vec::new();
        for v in 0..nv {
            let fan = &by_vertex[start[v] as usize..start[v + 1] as usize];
            for (i, &c) in fan.iter().enumerate() {
                let same = fan[..i].iter().find(|&&d| normal(d) == normal(c));
                class[c as usize] = match same {
                    Some(&d) => class[d as usize],
                    None => {
                        kept.push(open[v] || keep(v as u32));
                        kept.len() as u32 - 1
                    }
                };
            }
        }
        drop((by_vertex, start, open));
        let mut sums = vec![[0f64; 3]; kept.len()];
        for (f, t) in mesh.triangles.iter().enumerate() {
            let n = face_cross(t.map(|v| points[v as usize]));
            for k in 0..3 {
                let s = &mut sums[class[3 * f + k] as usize];
                s[0] += n[0];
                s[1] += n[1];
                s[2] += n[2];
            }
        }
        let scale = octa::scale(bits);
        let codes = sums
            .iter()
            .zip(kept)
            .map(|(s, kept)| if kept { KEEP } else { predict_octa(s[0], s[1], s[2], scale).map(|c| c as i16) })
            .collect();
        DerivedNormals { class, codes }
    }

    /// The code of corner `corner` (`3f + k`); `None` where its carried normal stays.
    pub fn code(&self, corner: usize) -> Option<[i16; 2]> {
        let code = self.codes[*self.class.get(corner)? as usize];
        (code != KEEP).then_some(code)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

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
        let d = DerivedNormals::new(&mesh, &points, 8, |_| false);
        // The apex (corner 0 of every face) sums to a vertical normal: code (0, 0), the top.
        for f in 0..4 {
            assert_eq!(d.code(3 * f), Some([0, 0]));
            assert_eq!(d.code(3 * f + 1), None, "rim corner of face {f}");
        }
        // A vertex the caller keeps keeps its normal.
        assert_eq!(DerivedNormals::new(&mesh, &points, 8, |v| v == 0).code(0), None);
    }

    #[test]
    fn a_crease_splits_a_vertex_into_classes_each_of_its_own_faces() {
        let (mut mesh, points) = pyramid();
        // Two faces of the apex carry another normal: two classes, each the sum of its two faces.
        for f in [0, 1] {
            mesh.normals[3 * f] = Vec3::X;
        }
        let d = DerivedNormals::new(&mesh, &points, 8, |_| false);
        let scale = octa::scale(8);
        let sum = |faces: [usize; 2]| {
            let s = faces.map(|f| face_cross(mesh.triangles[f].map(|v| points[v as usize])));
            predict_octa(s[0][0] + s[1][0], s[0][1] + s[1][1], s[0][2] + s[1][2], scale).map(|c| c as i16)
        };
        assert_eq!(d.code(0), Some(sum([0, 1])));
        assert_eq!(d.code(3), Some(sum([0, 1])));
        assert_eq!(d.code(6), Some(sum([2, 3])));
        assert_ne!(d.code(0), d.code(6));
    }

    #[test]
    fn the_code_is_the_prediction_of_the_same_faces_in_any_corner_order() {
        let (mut mesh, points) = pyramid();
        let before = DerivedNormals::new(&mesh, &points, 10, |_| false).code(0);
        for t in &mut mesh.triangles {
            t.rotate_left(1);
        }
        // The apex is now each face's corner 2.
        assert_eq!(DerivedNormals::new(&mesh, &points, 10, |_| false).code(2), before);
    }

    #[test]
    fn an_edge_of_three_faces_keeps_its_ends_normals() {
        let (mut mesh, mut points) = pyramid();
        // A fin on edge (0, 1): that edge now has three faces.
        points.push([5, 5, 30]);
        mesh.positions.push(Vec3::new(5.0, 5.0, 30.0));
        mesh.triangles.push([0, 1, 5]);
        mesh.normals.extend([Vec3::Z; 3]);
        let d = DerivedNormals::new(&mesh, &points, 8, |_| false);
        assert_eq!(d.code(0), None, "the apex lies on the fin's edge");
    }
}
