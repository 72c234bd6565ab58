//! The collapse state: flat per-vertex and per-face records, their construction from the input
//! (quadrics, locks, vertex kinds), the queries every other part uses, and the output mesh.

use super::quadric::Quadric;
use super::{Simplified, SimplifyOptions};
use crate::mesh::{Mesh, VertexFaces, NO_FACE};
use glam::{DVec3, Vec2, Vec3};
use rayon::prelude::*;

/// Classification of a vertex from its feature edges.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    Unknown,
    Free,
    Line,
    Corner,
}

/// The faces on an edge (one for a border edge, two otherwise) and their third vertices.
#[derive(Clone, Copy, Debug)]
pub(super) struct EdgeFaces {
    pub(super) f: [u32; 2],
    pub(super) x: [u32; 2],
    pub(super) n: usize,
}

/// The small per-vertex data the inner loops touch (its quadric is kept apart), 32 bytes aligned
/// to 32 so that a record spans one cache line.
#[derive(Clone, Copy, Debug)]
#[repr(align(32))]
pub(super) struct Vertex {
    pub(super) pos: Vec3,
    /// Its faces: `face_lists[start..start + len]`.
    pub(super) start: u32,
    pub(super) len: u32,
    /// Cached classification, `Unknown` when it must be recomputed.
    pub(super) kind: Kind,
    /// Never collapsed: non-manifold, unused or removed.
    pub(super) locked: bool,
}

/// A face: its vertices and what the checks need with them, in one 32-byte record so that a
/// face costs one cache line at most.
#[derive(Clone, Copy, Debug)]
#[repr(align(32))]
pub(super) struct Face {
    /// Its vertices, `DEAD` once collapsed away.
    pub(super) v: [u32; 3],
    pub(super) group: u32,
    /// Unit normal in the input: turns are measured from it, so they cannot add up.
    pub(super) normal: Vec3,
}

pub(super) const DEAD: u32 = u32::MAX;

pub(super) struct State {
    pub(super) verts: Vec<Vertex>,
    pub(super) quadrics: Vec<Quadric>,
    pub(super) faces: Vec<Face>,
    /// Per corner: the first corner of the vertex with the same attributes, material and group
    /// (kept consistent as corners move), so corners of one vertex compare by one integer.
    pub(super) wedges: Vec<[u32; 3]>,
    /// Per vertex, bumped whenever it changes; invalidates its queue entries. Kept apart from
    /// `verts` so that checking an entry touches a small array.
    pub(super) version: Vec<u32>,
    /// The per-vertex face lists; a list that changes is appended, the arena compacted now and then.
    pub(super) face_lists: Vec<u32>,
    pub(super) compact_at: usize,
    pub(super) face_materials: Vec<u32>,
    pub(super) normals: Vec<Vec3>,
    pub(super) uvs: Vec<Vec2>,
    pub(super) colors: Vec<[u8; 4]>,
    /// Entries of the current pass (see `entry`), in a vector while it is filled.
    pub(super) entries: Vec<u128>,
    pub(super) faces_left: usize,
    pub(super) error_sq: f64,
    pub(super) cos_turn: f64,
    pub(super) min_quality: f64,
    pub(super) scratch_edges: Vec<u64>,
    pub(super) scratch_r: Vec<u32>,
    pub(super) scratch_k: Vec<u32>,
    /// Topology changes are made (see [`SimplifyOptions::topology`]); with groups only where all
    /// faces around are of one group.
    pub(super) topology: bool,
    /// Vertices that never move or go, and that no collapse joins by a new edge (empty: none;
    /// see [`super::simplify_pinned`]).
    pub(super) pinned: Vec<bool>,
    pub(super) grouped: bool,
    /// Live faces per group (with topology changes and groups only, else empty): a tetrahedron
    /// is dropped only from a group that keeps other faces.
    pub(super) group_faces: Vec<u32>,
    /// Per group (same sizing), the largest squared error of what it lost whole: a dropped
    /// tetrahedron's spread and its vertices' errors, which no surviving vertex carries.
    pub(super) group_lost_sq: Vec<f64>,
    /// Faces of the input; faces past them are caps.
    pub(super) input_faces: usize,
    /// Per cap, the input face whose attributes it took.
    pub(super) cap_source: Vec<u32>,
}

impl State {
    pub(super) fn new(mesh: &Mesh, groups: Option<&[u32]>) -> State {
        let nf = mesh.triangles.len();
        let lists = VertexFaces::build(mesh);
        let verts = mesh
            .positions
            .iter()
            .zip(lists.offsets.windows(2))
            .map(|(&pos, w)| Vertex { pos, start: w[0], len: w[1] - w[0], kind: Kind::Unknown, locked: false })
            .collect();
        let faces =
            mesh.triangles.iter().enumerate().map(|(f, &v)| Face { v, group: groups.map_or(0, |g| g[f]), normal: Vec3::ZERO }).collect();
        let wedges = (0..3 * nf as u32).step_by(3).map(|c| [c, c + 1, c + 2]).collect();
        State {
            // Filled by `init`.
            quadrics: Vec::new(),
            wedges,
            version: vec![0; mesh.positions.len()],
            verts,
            faces,
            face_lists: lists.faces,
            compact_at: 2 * 3 * nf.max(1024),
            face_materials: if mesh.face_materials.len() == nf { mesh.face_materials.clone() } else { vec![0; nf] },
            normals: mesh.normals.clone(),
            uvs: mesh.uvs.clone(),
            colors: mesh.colors.clone(),
            entries: Vec::new(),
            faces_left: nf,
            error_sq: 0.0,
            cos_turn: 1.0,
            min_quality: 0.0,
            scratch_edges: Vec::new(),
            scratch_r: Vec::new(),
            scratch_k: Vec::new(),
            topology: false,
            pinned: Vec::new(),
            grouped: groups.is_some(),
            group_faces: Vec::new(),
            group_lost_sq: Vec::new(),
            input_faces: nf,
            cap_source: Vec::new(),
        }
    }

    /// [`SimplifyOptions::normal_seam_angle`]: per vertex, each corner in face-list order joins
    /// the first set whose first normal lies within `angle` of its own (or starts a set), and the
    /// corners of a set holding two or more different normals get their normalized sum. Directions
    /// are compared, not lengths; a set spans at most twice the angle.
    pub(super) fn merge_normal_seams(&mut self, angle: f32) {
        if angle <= 0.0 || self.normals.is_empty() {
            return;
        }
        let cos = angle.cos();
        let bits = |n: Vec3| n.to_array().map(f32::to_bits);
        let mut corners: Vec<usize> = Vec::new();
        // Per set: its first normal's direction and bits, the sum of its directions, and whether
        // it holds another normal.
        let mut sets: Vec<(Vec3, [u32; 3], Vec3, bool)> = Vec::new();
        let mut set_of: Vec<usize> = Vec::new();
        for v in 0..self.verts.len() as u32 {
            corners.clear();
            corners.extend(self.faces_of(v).iter().map(|&f| self.corner(f, v)));
            let Some(&c0) = corners.first() else { continue };
            let first = bits(self.normals[c0]);
            if corners.iter().all(|&c| bits(self.normals[c]) == first) {
                continue;
            }
            sets.clear();
            set_of.clear();
            for &c in &corners {
                let n = self.normals[c];
                let u = n.normalize_or_zero();
                let k = match sets.iter().position(|s| s.0.dot(u) >= cos) {
                    Some(k) => k,
                    None => {
                        sets.push((u, bits(n), Vec3::ZERO, false));
                        sets.len() - 1
                    }
                };
                sets[k].2 += u;
                sets[k].3 |= bits(n) != sets[k].1;
                set_of.push(k);
            }
            for (&c, &k) in corners.iter().zip(&set_of) {
                if let (Some(n), true) = (sets[k].2.try_normalize(), sets[k].3) {
                    self.normals[c] = n;
                }
            }
        }
    }

    pub(super) fn faces_of(&self, v: u32) -> &[u32] {
        let x = &self.verts[v as usize];
        &self.face_lists[x.start as usize..(x.start + x.len) as usize]
    }

    /// The i-th face of v (for loops that mutate the state while walking v's faces).
    fn face_of(&self, v: u32, i: usize) -> u32 {
        self.face_lists[self.verts[v as usize].start as usize + i]
    }

    pub(super) fn tri(&self, f: u32) -> [u32; 3] {
        self.faces[f as usize].v
    }

    pub(super) fn pos(&self, v: u32) -> DVec3 {
        self.verts[v as usize].pos.as_dvec3()
    }

    /// Corner index of vertex `v` in face `f`.
    pub(super) fn corner(&self, f: u32, v: u32) -> usize {
        let t = self.tri(f);
        3 * f as usize
            + if t[0] == v {
                0
            } else if t[1] == v {
                1
            } else {
                2
            }
    }

    pub(super) fn wedge(&self, c: usize) -> u32 {
        self.wedges[c / 3][c % 3]
    }

    /// Wedge ids, face planes, border and seam planes, locks and kinds. Locks unused vertices,
    /// vertices on non-manifold edges and bow-tie vertices (faces around them not one fan).
    /// `topology`: make topology changes where they unblock a collapse.
    ///
    /// Per-vertex work runs in parallel; each vertex gathers its face planes in face order and the
    /// few border and seam planes are added afterwards in vertex order, so every quadric is summed
    /// in the same order as a sequential scatter would.
    pub(super) fn init(&mut self, opts: &SimplifyOptions, topology: bool) {
        self.cos_turn = f64::from(opts.max_normal_turn).cos();
        self.topology = topology;
        if self.topology && self.grouped {
            let n = self.faces.iter().map(|f| f.group as usize + 1).max().unwrap_or(0);
            self.group_faces = vec![0; n];
            self.group_lost_sq = vec![0.0; n];
            for f in &self.faces {
                self.group_faces[f.group as usize] += 1;
            }
        }
        self.min_quality = f64::from(opts.min_face_quality);
        // A corner's wedge is the first corner of its vertex (in face list order) with the same
        // attributes, as `same_attributes` is an equivalence.
        let mut wedges = std::mem::take(&mut self.wedges);
        let this = &*self;
        let uniform = this.normals.is_empty()
            && this.uvs.is_empty()
            && this.colors.is_empty()
            && this.face_materials.iter().all(|&m| m == this.face_materials[0])
            && this.faces.iter().all(|f| f.group == this.faces[0].group);
        wedges.par_iter_mut().with_min_len(1024).enumerate().for_each(|(f, w)| {
            if uniform {
                // Without corner attributes, one material and one group, all corners are alike.
                *w = [0; 3];
                return;
            }
            *w = std::array::from_fn(|i| {
                let (v, c) = (this.faces[f].v[i], 3 * f + i);
                if this.corner(f as u32, v) != c {
                    // A repeated vertex of a degenerate face: only its first corner is its.
                    return c as u32;
                }
                let first = this.faces_of(v).iter().map(|&g| this.corner(g, v)).find(|&r| this.same_attributes(r, c));
                first.unwrap_or(c) as u32
            });
        });
        self.wedges = wedges;
        // Per face: its unit normal, plane offset and twice its area (0 when degenerate).
        let verts = &self.verts;
        let planes: Vec<(DVec3, f64, f64)> = self
            .faces
            .par_iter_mut()
            .with_min_len(1024)
            .map(|face| {
                let [a, b, c] = face.v.map(|v| verts[v as usize].pos.as_dvec3());
                let cross = (b - a).cross(c - a);
                let len = cross.length();
                if len == 0.0 {
                    return (DVec3::ZERO, 0.0, 0.0);
                }
                let n = cross / len;
                face.normal = n.as_vec3();
                (n, -n.dot(a), len)
            })
            .collect();
        let lists = &self.face_lists;
        self.quadrics = verts
            .par_iter()
            .with_min_len(1024)
            .map(|x| {
                let mut q = Quadric::default();
                for &f in &lists[x.start as usize..(x.start + x.len) as usize] {
                    let (n, d, len) = planes[f as usize];
                    if len != 0.0 {
                        q.add(&Quadric { area: 0.5 * len, ..Quadric::with_offset(n, d, 0.5 * len) });
                    }
                }
                q
            })
            .collect();
        // Per chunk of vertices: each one's lock and kind, then its border and seam planes
        // `(v, other, face, weight)` and the other ends it locks (`face` = DEAD), in order.
        type Classified = (Vec<(bool, Kind)>, Vec<(u32, u32, u32, f32)>);
        let this = &*self;
        let classified: Vec<Classified> = (0..this.verts.len() as u32)
            .into_par_iter()
            .chunks(1024)
            .map_init(
                || (Vec::new(), Vec::new()),
                |(around, parent): &mut (Vec<u64>, Vec<u32>), chunk| {
                    let (mut out, mut events) = (Vec::with_capacity(chunk.len()), Vec::new());
                    for v in chunk {
                        out.push(this.classify(v, opts, around, parent, &mut events));
                    }
                    (out, events)
                },
            )
            .collect();
        let mut v = 0;
        for (out, events) in classified {
            for (locked, kind) in out {
                let x = &mut self.verts[v];
                x.locked |= locked;
                x.kind = kind;
                v += 1;
            }
            for (a, b, f, weight) in events {
                if f == DEAD {
                    self.verts[b as usize].locked = true;
                } else {
                    self.add_edge_plane(f as usize, a, b, weight);
                }
            }
        }
    }

    /// `init` for one vertex: whether it is locked and its kind; pushes to `events` its border
    /// and seam planes towards higher ids `(v, other, face, weight)` and the ends of its
    /// non-manifold edges to lock `(v, other, DEAD, 0)`. `around` and `parent` are scratch.
    fn classify(
        &self,
        v: u32,
        opts: &SimplifyOptions,
        around: &mut Vec<u64>,
        parent: &mut Vec<u32>,
        events: &mut Vec<(u32, u32, u32, f32)>,
    ) -> (bool, Kind) {
        let deg = self.verts[v as usize].len as usize;
        if deg == 0 {
            return (true, Kind::Unknown);
        }
        self.edges_around(v, around);
        parent.clear();
        parent.extend(0..deg as u32);
        let mut fans = deg;
        let mut features = 0;
        let mut locked = false;
        for run in around.chunk_by(|a, b| a >> 32 == b >> 32) {
            let other = (run[0] >> 32) as u32;
            match *run {
                [e] => {
                    features += 1;
                    if other > v {
                        let (_, c, _) = self.around_corners(v, e);
                        events.push((v, other, (c / 3) as u32, opts.border_weight));
                    }
                }
                [e0, e1] => {
                    let ((mut a, c0, d0), (mut b, c1, d1)) = (self.around_corners(v, e0), self.around_corners(v, e1));
                    while parent[a] as usize != a {
                        a = parent[a] as usize;
                    }
                    while parent[b] as usize != b {
                        b = parent[b] as usize;
                    }
                    if a != b {
                        parent[a.max(b)] = a.min(b) as u32;
                        fans -= 1;
                    }
                    if !self.same_corner(c0, c1) || !self.same_corner(d0, d1) {
                        features += 1;
                        if other > v {
                            events.push((v, other, (c0 / 3) as u32, 0.5 * opts.seam_weight));
                            events.push((v, other, (c1 / 3) as u32, 0.5 * opts.seam_weight));
                        }
                    }
                }
                _ => {
                    locked = true;
                    events.push((v, other, DEAD, 0.0));
                }
            }
        }
        let kind = match features {
            _ if self.is_pinned(v) => Kind::Corner,
            0 => Kind::Free,
            2 => Kind::Line,
            _ => Kind::Corner,
        };
        (locked || fans != 1, kind)
    }

    /// Adds to both ends of edge (a, b) the plane through the edge perpendicular to face `f`,
    /// weighted by `weight` times the squared edge length.
    fn add_edge_plane(&mut self, f: usize, a: u32, b: u32, weight: f32) {
        let (pa, pb) = (self.pos(a), self.pos(b));
        let along = pb - pa;
        let m = along.cross(self.faces[f].normal.as_dvec3()).normalize_or_zero();
        if m != DVec3::ZERO {
            let q = Quadric::plane(m, pa, f64::from(weight) * along.length_squared());
            self.quadrics[a as usize].add(&q);
            self.quadrics[b as usize].add(&q);
        }
    }

    /// The edges around `v`, once per face, as `other end << 32 | index of the face in v's list
    /// << 2 | position of v in the face`, sorted by other end.
    fn edges_around(&self, v: u32, out: &mut Vec<u64>) {
        out.clear();
        for (local, &f) in self.faces_of(v).iter().enumerate() {
            let t = self.tri(f);
            let i = if t[0] == v {
                0
            } else if t[1] == v {
                1
            } else {
                2
            };
            let low = (local as u64) << 2 | i as u64;
            out.push(u64::from(t[(i + 1) % 3]) << 32 | low);
            out.push(u64::from(t[(i + 2) % 3]) << 32 | low);
        }
        out.sort_unstable();
    }

    /// From an `edges_around` record: the face's index in v's list, and the corners of v and of
    /// the other end in that face.
    fn around_corners(&self, v: u32, e: u64) -> (usize, usize, usize) {
        let local = (e as u32 >> 2) as usize;
        let f = self.face_of(v, local);
        (local, 3 * f as usize + (e & 3) as usize, self.corner(f, (e >> 32) as u32))
    }

    /// Whether two corners carry the same attributes, material and group.
    fn same_attributes(&self, c0: usize, c1: usize) -> bool {
        let (f0, f1) = (c0 / 3, c1 / 3);
        self.face_materials[f0] == self.face_materials[f1]
            && self.faces[f0].group == self.faces[f1].group
            && (self.normals.is_empty() || self.normals[c0].to_array().map(f32::to_bits) == self.normals[c1].to_array().map(f32::to_bits))
            && (self.uvs.is_empty() || self.uvs[c0].to_array().map(f32::to_bits) == self.uvs[c1].to_array().map(f32::to_bits))
            && (self.colors.is_empty() || self.colors[c0] == self.colors[c1])
    }

    /// `same_attributes` for two corners of one vertex, by their wedge ids.
    pub(super) fn same_corner(&self, c0: usize, c1: usize) -> bool {
        self.wedge(c0) == self.wedge(c1)
    }

    /// Whether the edge (a, b) with faces `e` is a feature edge.
    pub(super) fn is_feature(&self, a: u32, b: u32, e: &EdgeFaces) -> bool {
        e.n == 1
            || !self.same_corner(self.corner(e.f[0], a), self.corner(e.f[1], a))
            || !self.same_corner(self.corner(e.f[0], b), self.corner(e.f[1], b))
    }

    /// Whether `v` is pinned ([`super::simplify_pinned`]); vertices past the flags (copies made by
    /// cuts, which never run through a pinned vertex) are not.
    pub(super) fn is_pinned(&self, v: u32) -> bool {
        self.pinned.get(v as usize).copied().unwrap_or(false)
    }

    pub(super) fn kind(&mut self, v: u32) -> Kind {
        if self.verts[v as usize].kind != Kind::Unknown {
            return self.verts[v as usize].kind;
        }
        let mut edges = std::mem::take(&mut self.scratch_edges);
        let kind = self.compute_kind(v, &mut edges);
        self.scratch_edges = edges;
        self.verts[v as usize].kind = kind;
        kind
    }

    /// The kind of `v` from its current faces; `edges` is scratch.
    pub(super) fn compute_kind(&self, v: u32, edges: &mut Vec<u64>) -> Kind {
        self.edges_around(v, edges);
        let mut features = 0;
        let mut manifold = true;
        for run in edges.chunk_by(|a, b| a >> 32 == b >> 32) {
            match *run {
                [_] => features += 1,
                [e0, e1] => {
                    let ((_, c0, d0), (_, c1, d1)) = (self.around_corners(v, e0), self.around_corners(v, e1));
                    if !self.same_corner(c0, c1) || !self.same_corner(d0, d1) {
                        features += 1;
                    }
                }
                _ => manifold = false,
            }
        }
        match features {
            _ if self.is_pinned(v) => Kind::Corner,
            0 if manifold => Kind::Free,
            2 if manifold => Kind::Line,
            _ => Kind::Corner,
        }
    }

    pub(super) fn edge_faces(&self, u: u32, v: u32) -> Option<EdgeFaces> {
        let mut e = EdgeFaces { f: [NO_FACE; 2], x: [NO_FACE; 2], n: 0 };
        for &f in self.faces_of(u) {
            let t = self.tri(f);
            if t.contains(&v) {
                if e.n == 2 {
                    return None;
                }
                e.f[e.n] = f;
                e.x[e.n] = t[0] ^ t[1] ^ t[2] ^ u ^ v;
                e.n += 1;
            }
        }
        (e.n > 0).then_some(e)
    }

    /// A vertex's squared error estimate: its own mean squared distance to its planes, or the
    /// largest of the collapses (and cuts) merged into it.
    pub(super) fn vertex_error_sq(&self, v: u32) -> f64 {
        let q = self.quadrics.get(v as usize).copied().unwrap_or_default();
        let pos = self.verts[v as usize].pos;
        let own = if q.w > 0.0 { q.eval(pos.as_dvec3()) / q.w } else { 0.0 };
        own.max(q.err_sq)
    }

    pub(super) fn finish(self, mesh: &Mesh, with_groups: bool) -> Simplified {
        let alive: Vec<usize> = (0..self.faces.len()).filter(|&f| self.faces[f].v[0] != DEAD).collect();
        let mut used = vec![false; self.verts.len()];
        for &f in &alive {
            for v in self.faces[f].v {
                used[v as usize] = true;
            }
        }
        let mut remap = vec![u32::MAX; self.verts.len()];
        let mut positions = Vec::new();
        let mut vertex_error = Vec::new();
        for (v, x) in self.verts.iter().enumerate() {
            if used[v] {
                remap[v] = positions.len() as u32;
                positions.push(x.pos);
                vertex_error.push(self.vertex_error_sq(v as u32).sqrt() as f32);
            }
        }
        fn corners<T: Copy>(a: &[T], alive: &[usize]) -> Vec<T> {
            if a.is_empty() {
                return Vec::new();
            }
            alive.iter().flat_map(|&f| a[3 * f..3 * f + 3].iter().copied()).collect()
        }
        let mut out = Mesh {
            positions,
            triangles: alive.iter().map(|&f| self.faces[f].v.map(|v| remap[v as usize])).collect(),
            normals: corners(&self.normals, &alive),
            uvs: corners(&self.uvs, &alive),
            colors: corners(&self.colors, &alive),
            face_materials: if mesh.face_materials.is_empty() {
                Vec::new()
            } else {
                alive.iter().map(|&f| self.face_materials[f]).collect()
            },
            materials: mesh.materials.clone(),
            images: mesh.images.clone(),
            face_normals: Vec::new(),
            face_areas: Vec::new(),
        };
        out.compute_face_geometry();
        let (face_groups, group_error) = if with_groups {
            let face_groups: Vec<u32> = alive.iter().map(|&f| self.faces[f].group).collect();
            let n_groups = self.faces.iter().map(|f| f.group).max().map_or(0, |g| g as usize + 1);
            let mut group_error: Vec<f32> = (0..n_groups).map(|g| self.group_lost_sq.get(g).map_or(0.0, |e| e.sqrt() as f32)).collect();
            for (t, &g) in out.triangles.iter().zip(&face_groups) {
                for &v in t {
                    group_error[g as usize] = group_error[g as usize].max(vertex_error[v as usize]);
                }
            }
            (face_groups, group_error)
        } else {
            (Vec::new(), Vec::new())
        };
        let source_faces =
            alive.iter().map(|&f| if f < self.input_faces { f as u32 } else { self.cap_source[f - self.input_faces] }).collect();
        Simplified { mesh: out, source_faces, face_groups, group_error, error: self.error_sq.sqrt() as f32 }
    }
}
