//! `Mesh`, the one in-memory triangle mesh every stage uses, with welding, cleaning and adjacency.
//!
//! Plain arrays: positions are welded (faces that share a position share a vertex); normals, UVs and
//! colors live on corners (three per face, in face order) so seams and hard edges survive; each face
//! has a material id into `materials`.

use glam::{DVec3, Vec2, Vec3};
use rustc_hash::{FxHashMap, FxHashSet};

/// Marks "no face" in adjacency arrays.
pub const NO_FACE: u32 = u32::MAX;

pub use crate::format::Material;

/// The largest coordinate magnitude strata accepts; importers refuse vertices beyond it.
///
/// Later stages compute in f32 with fourth powers of lengths: the squared length of summed
/// area-weighted normals when grouping, products of dot products when finding closest points for
/// the distance measure. Within ±1e9 on every axis, lengths stay under 2·√3·1e9 ≈ 3.5e9 and their
/// fourth powers under 1.5e38, below f32's 3.4e38. Past about 4e9 they overflow to infinity and
/// grouping and measurement silently change (squared lengths overflow near 1.8e19, where `convert`
/// fails outright). Quadrics are f64 and do not set the limit.
pub const MAX_COORDINATE: f32 = 1e9;

/// Why a vertex position cannot be used, if it cannot: a coordinate that is NaN or infinite, or
/// beyond [`MAX_COORDINATE`]. Takes f64 so that readers can check values before narrowing them.
pub fn coordinate_problem(p: [f64; 3]) -> Option<String> {
    // The common case in one test: NaN fails every comparison.
    if p.iter().all(|c| c.abs() <= f64::from(MAX_COORDINATE)) {
        return None;
    }
    if p.iter().any(|c| !c.is_finite()) {
        return Some("coordinate is NaN or infinite".into());
    }
    let c = p.into_iter().find(|c| c.abs() > f64::from(MAX_COORDINATE))?;
    // A value that came from f32 prints as the f32 it is (1e38, not 9.99999968e37).
    let shown = if f64::from(c as f32) == c { format!("{:e}", c as f32) } else { format!("{c:e}") };
    Some(format!("coordinate {shown} exceeds the largest magnitude strata accepts ({MAX_COORDINATE:e})"))
}

/// A triangle mesh. Corner arrays (`normals`, `uvs`, `colors`) are either empty (attribute absent)
/// or hold exactly `3 * triangles.len()` entries, corner `3 * f + k` belonging to `triangles[f][k]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub normals: Vec<Vec3>,
    pub uvs: Vec<Vec2>,
    pub colors: Vec<[u8; 4]>,
    /// Material id per face, indexing `materials`.
    pub face_materials: Vec<u32>,
    pub materials: Vec<Material>,
    /// The images materials' maps index ([`Material::maps`]), as their source files held them.
    pub images: Vec<crate::texture::SourceImage>,
    /// Unit normal per face (zero for a degenerate face), from the positions.
    pub face_normals: Vec<Vec3>,
    /// Area per face.
    pub face_areas: Vec<f32>,
}

/// What cleaning removed; reported, never silent.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CleanReport {
    /// Input vertices merged into another vertex at the same position.
    pub welded_vertices: usize,
    /// Faces with a repeated vertex or (near) zero area.
    pub degenerate_faces: usize,
    /// Faces with the same three vertices as an earlier face.
    pub duplicate_faces: usize,
    /// Vertices no face uses.
    pub unreferenced_vertices: usize,
}

/// A vertex with a NaN or infinite coordinate; `index` is its position in the input arrays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NonFiniteVertex {
    pub index: usize,
}

impl Mesh {
    pub fn face_count(&self) -> usize {
        self.triangles.len()
    }

    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Append `other`'s faces with its vertex `v` as this mesh's `remap[v]` (vertices already
    /// here or pushed by the caller), with their corner attributes, materials and face geometry
    /// (each array as `other` has it: a mesh without one leaves it as it is).
    pub fn append_faces(&mut self, other: &Mesh, remap: &[u32]) {
        self.triangles.extend(other.triangles.iter().map(|t| t.map(|v| remap[v as usize])));
        self.normals.extend_from_slice(&other.normals);
        self.uvs.extend_from_slice(&other.uvs);
        self.colors.extend_from_slice(&other.colors);
        self.face_materials.extend_from_slice(&other.face_materials);
        self.face_normals.extend_from_slice(&other.face_normals);
        self.face_areas.extend_from_slice(&other.face_areas);
    }

    /// Axis-aligned bounds of the positions, or `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        box_of(self.positions.iter().copied())
    }

    /// Length of the bounding box diagonal (0 for an empty mesh).
    pub fn diagonal(&self) -> f32 {
        self.bounds().map_or(0.0, |(lo, hi)| (hi - lo).length())
    }

    /// Recompute `face_normals` and `face_areas` from positions and triangles.
    pub fn compute_face_geometry(&mut self) {
        let (normals, areas) = self
            .triangles
            .iter()
            .map(|t| {
                let c = triangle_cross(&self.positions, t);
                let len = c.length();
                let n = if len > 0.0 { (c / len).as_vec3() } else { Vec3::ZERO };
                (n, (0.5 * len) as f32)
            })
            .unzip();
        self.face_normals = normals;
        self.face_areas = areas;
    }

    /// Check that corner arrays and per-face arrays have the lengths this type promises and that
    /// every index is in range. Importers call it before returning; tests call it on outputs.
    pub fn validate(&self) -> Result<(), String> {
        let f = self.triangles.len();
        let n = self.positions.len() as u64;
        for (name, len) in [("normals", self.normals.len()), ("uvs", self.uvs.len()), ("colors", self.colors.len())] {
            if len != 0 && len != 3 * f {
                return Err(format!("{name} has {len} entries for {f} faces"));
            }
        }
        if self.face_materials.len() != f {
            return Err(format!("face_materials has {} entries for {f} faces", self.face_materials.len()));
        }
        if let Some(i) = self.triangles.iter().position(|t| t.iter().any(|&v| v as u64 >= n)) {
            return Err(format!("face {i} indexes past {n} vertices"));
        }
        if let Some(i) = self.face_materials.iter().position(|&m| m as usize >= self.materials.len()) {
            return Err(format!("face {i} has material {} of {}", self.face_materials[i], self.materials.len()));
        }
        Ok(())
    }

    /// Weld equal positions, drop degenerate and duplicate faces and unreferenced vertices, and
    /// compute face normals and areas. Fails on the first vertex with a non-finite coordinate.
    /// Face order is kept (minus removed faces); vertices are renumbered in order of first use.
    pub fn clean(self) -> Result<(Mesh, CleanReport), NonFiniteVertex> {
        self.clean_known(false)
    }

    /// [`Mesh::clean`] for a mesh whose faces are known to be distinct when no vertex is welded
    /// (an elevation grid's cells): then the search for duplicate faces is skipped.
    pub fn clean_known(mut self, distinct_faces: bool) -> Result<(Mesh, CleanReport), NonFiniteVertex> {
        if let Some(index) = self.positions.iter().position(|p| !p.is_finite()) {
            return Err(NonFiniteVertex { index });
        }
        if self.face_materials.is_empty() && !self.triangles.is_empty() {
            self.face_materials = vec![0; self.triangles.len()];
        }
        if self.materials.is_empty() && !self.triangles.is_empty() {
            self.materials.push(Material::default());
        }
        let mut report = CleanReport::default();

        // Weld: map every input vertex to the first vertex with the same position (+0 == -0).
        let mut first_at: FxHashMap<[u32; 3], u32> = FxHashMap::with_capacity_and_hasher(self.positions.len(), Default::default());
        let weld: Vec<u32> = self
            .positions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let key = [p.x + 0.0, p.y + 0.0, p.z + 0.0].map(f32::to_bits);
                *first_at.entry(key).or_insert(i as u32)
            })
            .collect();
        let no_welds = first_at.len() == self.positions.len();
        drop(first_at);

        // Keep faces that are neither degenerate nor duplicates.
        let check_duplicates = !(distinct_faces && no_welds);
        let capacity = if check_duplicates { self.triangles.len() } else { 0 };
        let mut seen: FxHashSet<[u32; 3]> = FxHashSet::with_capacity_and_hasher(capacity, Default::default());
        let mut keep = Vec::with_capacity(self.triangles.len());
        for (f, t) in self.triangles.iter_mut().enumerate() {
            *t = t.map(|v| weld[v as usize]);
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || is_zero_area(&self.positions, t) {
                report.degenerate_faces += 1;
                continue;
            }
            if check_duplicates {
                let mut key = *t;
                key.sort_unstable();
                if !seen.insert(key) {
                    report.duplicate_faces += 1;
                    continue;
                }
            }
            keep.push(f);
        }
        drop(seen);

        let distinct = weld.iter().enumerate().filter(|&(i, &w)| i as u32 == w).count();
        report.welded_vertices = self.positions.len() - distinct;
        // Face geometry is recomputed, whatever the input held.
        (self.face_normals, self.face_areas) = (Vec::new(), Vec::new());
        let mut mesh = self.subset(&keep);
        report.unreferenced_vertices = distinct - mesh.positions.len();
        mesh.compute_face_geometry();
        Ok((mesh, report))
    }

    /// The faces `keep` (in that order) with their corners and per-face values and the vertices
    /// they use, renumbered in order of first use; materials and images are kept whole.
    pub fn subset(self, keep: &[usize]) -> Mesh {
        let mut remap = vec![u32::MAX; self.positions.len()];
        let mut positions = Vec::new();
        let triangles = keep
            .iter()
            .map(|&f| {
                self.triangles[f].map(|v| {
                    let r = &mut remap[v as usize];
                    if *r == u32::MAX {
                        *r = positions.len() as u32;
                        positions.push(self.positions[v as usize]);
                    }
                    *r
                })
            })
            .collect();
        Mesh {
            positions,
            triangles,
            normals: corners_of(&self.normals, keep),
            uvs: corners_of(&self.uvs, keep),
            colors: corners_of(&self.colors, keep),
            face_materials: faces_of(&self.face_materials, keep),
            materials: self.materials,
            images: self.images,
            face_normals: faces_of(&self.face_normals, keep),
            face_areas: faces_of(&self.face_areas, keep),
        }
    }
}

fn faces_of<T: Copy>(a: &[T], keep: &[usize]) -> Vec<T> {
    if a.is_empty() {
        return Vec::new();
    }
    keep.iter().map(|&f| a[f]).collect()
}

fn corners_of<T: Copy>(a: &[T], keep: &[usize]) -> Vec<T> {
    if a.is_empty() {
        return Vec::new();
    }
    keep.iter().flat_map(|&f| a[3 * f..3 * f + 3].iter().copied()).collect()
}

/// Twice the area vector of triangle `t`, in f64.
pub fn triangle_cross(positions: &[Vec3], t: &[u32; 3]) -> DVec3 {
    let [a, b, c] = t.map(|v| positions[v as usize].as_dvec3());
    (b - a).cross(c - a)
}

/// A face is degenerate when its area is negligible against its longest edge: the sine of its
/// largest angle is below 1e-12, i.e. its corners are collinear to within rounding.
fn is_zero_area(positions: &[Vec3], t: &[u32; 3]) -> bool {
    let [a, b, c] = t.map(|v| positions[v as usize].as_dvec3());
    let longest = (b - a).length_squared().max((c - b).length_squared()).max((a - c).length_squared());
    let cross = (b - a).cross(c - a).length();
    cross <= 1e-12 * longest
}

/// Edge adjacency: for each face and each of its edges, the face across it.
///
/// Edge `k` of face `f` runs from corner `k` to corner `(k + 1) % 3`. An edge used by exactly two
/// faces is manifold and links them; an edge used by one face is a boundary edge; an edge used by
/// three or more faces is non-manifold and links none of them (callers treat it as a border).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Adjacency {
    pub face_neighbors: Vec<[u32; 3]>,
    /// Number of distinct boundary edges.
    pub boundary_edges: usize,
    /// Distinct non-manifold edges, as vertex pairs (lower index first).
    pub nonmanifold_edges: Vec<[u32; 2]>,
}

impl Adjacency {
    /// Build adjacency in linear time by bucketing edges by their lower vertex.
    pub fn build(mesh: &Mesh) -> Adjacency {
        let nv = mesh.positions.len();
        let mut start = vec![0u32; nv + 1];
        for t in &mesh.triangles {
            for k in 0..3 {
                start[t[k].min(t[(k + 1) % 3]) as usize + 1] += 1;
            }
        }
        for i in 0..nv {
            start[i + 1] += start[i];
        }
        // entries[start[v]..start[v+1]] = (upper vertex, half-edge id) of edges whose lower vertex is v.
        let mut fill = start.clone();
        let mut entries = vec![(0u32, 0u32); 3 * mesh.triangles.len()];
        for (f, t) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let slot = &mut fill[a.min(b) as usize];
                entries[*slot as usize] = (a.max(b), (3 * f + k) as u32);
                *slot += 1;
            }
        }
        let mut face_neighbors = vec![[NO_FACE; 3]; mesh.triangles.len()];
        let mut boundary_edges = 0;
        let mut nonmanifold_edges = Vec::new();
        for v in 0..nv {
            let bucket = &mut entries[start[v] as usize..start[v + 1] as usize];
            bucket.sort_unstable();
            let mut i = 0;
            while i < bucket.len() {
                let mut j = i + 1;
                while j < bucket.len() && bucket[j].0 == bucket[i].0 {
                    j += 1;
                }
                match j - i {
                    1 => boundary_edges += 1,
                    2 => {
                        let (h0, h1) = (bucket[i].1 as usize, bucket[i + 1].1 as usize);
                        face_neighbors[h0 / 3][h0 % 3] = (h1 / 3) as u32;
                        face_neighbors[h1 / 3][h1 % 3] = (h0 / 3) as u32;
                    }
                    _ => nonmanifold_edges.push([v as u32, bucket[i].0]),
                }
                i = j;
            }
        }
        Adjacency { face_neighbors, boundary_edges, nonmanifold_edges }
    }
}

/// Faces around each vertex, as offsets into a flat list: the faces of vertex `v` are
/// `faces[offsets[v]..offsets[v + 1]]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VertexFaces {
    pub offsets: Vec<u32>,
    pub faces: Vec<u32>,
}

impl VertexFaces {
    pub fn build(mesh: &Mesh) -> VertexFaces {
        let mut offsets = vec![0u32; mesh.positions.len() + 1];
        for t in &mesh.triangles {
            for &v in t {
                offsets[v as usize + 1] += 1;
            }
        }
        for i in 0..mesh.positions.len() {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut faces = vec![0u32; 3 * mesh.triangles.len()];
        for (f, t) in mesh.triangles.iter().enumerate() {
            for &v in t {
                faces[fill[v as usize] as usize] = f as u32;
                fill[v as usize] += 1;
            }
        }
        VertexFaces { offsets, faces }
    }

    pub fn of(&self, v: u32) -> &[u32] {
        &self.faces[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize]
    }
}

/// The box (min, max) of `points`; `None` when there are none.
pub fn box_of(points: impl IntoIterator<Item = Vec3>) -> Option<(Vec3, Vec3)> {
    let mut points = points.into_iter();
    let first = points.next()?;
    Some(points.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
}

/// Connected components, faces being connected when they share a vertex. Returns the count and a
/// component label per face.
pub fn components(mesh: &Mesh) -> (usize, Vec<u32>) {
    components_of(mesh.positions.len(), &mesh.triangles)
}

/// [`components`] of `triangles` over `vertices` vertices.
pub fn components_of(vertices: usize, triangles: &[[u32; 3]]) -> (usize, Vec<u32>) {
    let mut parent: Vec<u32> = (0..vertices as u32).collect();
    fn find(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            let p = parent[parent[x as usize] as usize];
            parent[x as usize] = p;
            x = p;
        }
        x
    }
    for t in triangles {
        let r0 = find(&mut parent, t[0]);
        for &v in &t[1..] {
            let r = find(&mut parent, v);
            if r != r0 {
                let (lo, hi) = (r.min(r0), r.max(r0));
                parent[hi as usize] = lo;
            }
        }
    }
    let mut label_of_root = vec![u32::MAX; vertices];
    let mut count = 0u32;
    let labels = triangles
        .iter()
        .map(|t| {
            let r = find(&mut parent, t[0]) as usize;
            if label_of_root[r] == u32::MAX {
                label_of_root[r] = count;
                count += 1;
            }
            label_of_root[r]
        })
        .collect();
    (count as usize, labels)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad_with_extras() -> Mesh {
        // Two triangles of a unit square given with duplicated corner vertices, plus a degenerate
        // face, a duplicate face and an unused vertex.
        let p = |x: f32, y: f32| Vec3::new(x, y, 0.0);
        Mesh {
            positions: vec![p(0., 0.), p(1., 0.), p(1., 1.), p(0., 0.), p(1., 1.), p(0., 1.), p(5., 5.)],
            triangles: vec![[0, 1, 2], [3, 4, 5], [0, 1, 1], [2, 0, 1]],
            ..Default::default()
        }
    }

    #[test]
    fn clean_welds_and_reports() {
        let (m, r) = quad_with_extras().clean().unwrap();
        assert_eq!(m.vertex_count(), 4);
        assert_eq!(m.face_count(), 2);
        assert_eq!(r, CleanReport { welded_vertices: 2, degenerate_faces: 1, duplicate_faces: 1, unreferenced_vertices: 1 });
        assert_eq!(m.validate(), Ok(()));
        assert!((m.face_areas.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert!(m.face_normals.iter().all(|n| (n.z - 1.0).abs() < 1e-6));
    }

    #[test]
    fn clean_ignores_stale_face_geometry() {
        // Face normals and areas for one face of the four: cleaning computes its own.
        let mut m = quad_with_extras();
        m.face_normals = vec![Vec3::X];
        m.face_areas = vec![7.0];
        let (m, _) = m.clean().unwrap();
        assert_eq!((m.face_normals.len(), m.face_areas.len()), (2, 2));
        assert!(m.face_normals.iter().all(|n| (n.z - 1.0).abs() < 1e-6));
    }

    #[test]
    fn clean_rejects_nan() {
        let mut m = quad_with_extras();
        m.positions[4].y = f32::NAN;
        assert_eq!(m.clean().unwrap_err(), NonFiniteVertex { index: 4 });
    }

    #[test]
    fn coordinate_problems_name_the_value() {
        assert_eq!(coordinate_problem([0.0, -1e9, 1e9]), None);
        assert_eq!(coordinate_problem([0.0, f64::NAN, 1e30]).unwrap(), "coordinate is NaN or infinite");
        let e = coordinate_problem([1.0, f64::from(1e38f32), -2e300]).unwrap();
        assert_eq!(e, "coordinate 1e38 exceeds the largest magnitude strata accepts (1e9)");
        assert!(coordinate_problem([-2e300, 0.0, 0.0]).unwrap().contains("-2e300"));
        assert!(coordinate_problem([0.1 + 1e9, 0.0, 0.0]).unwrap().contains("1.0000000001e9"));
    }

    #[test]
    fn adjacency_of_square_and_fin() {
        let (mut m, _) = quad_with_extras().clean().unwrap();
        let a = Adjacency::build(&m);
        assert_eq!(a.boundary_edges, 4);
        assert!(a.nonmanifold_edges.is_empty());
        assert_eq!(a.face_neighbors.iter().flatten().filter(|&&n| n != NO_FACE).count(), 2);
        // A third face on the diagonal makes it non-manifold.
        m.positions.push(Vec3::new(0.5, 0.5, 1.0));
        m.triangles.push([0, 2, 4]);
        m.face_materials.push(0);
        let a = Adjacency::build(&m);
        assert_eq!(a.nonmanifold_edges.len(), 1);
        assert_eq!(a.face_neighbors.iter().flatten().filter(|&&n| n != NO_FACE).count(), 0);
        assert_eq!(components(&m).0, 1);
    }
}
