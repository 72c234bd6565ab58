//! Quadric-error edge collapse, optionally keeping every group of a face partition a connected,
//! non-empty patch (METHOD.md §4).
//!
//! Garland–Heckbert: each vertex carries a quadric, the area-weighted sum of the squared distances to
//! the planes of its original faces, plus perpendicular planes along open borders and attribute or
//! group seams so those lines keep their shape. Edges are collapsed cheapest first from a binary heap
//! whose stale entries are recognised by per-vertex version counters.
//!
//! Every edge end is classified from its current faces. An edge is a *feature edge* when it is an
//! open border, or when its two faces differ in material, group, or the normal/UV/color of a shared
//! corner. A vertex with no feature edge is *free*; one with exactly two is on a *feature line* (a
//! border, a UV seam, a hard edge, a material or group border); any other vertex is a *corner* and
//! never moves. Vertices on non-manifold edges and non-manifold (bow-tie) vertices are never touched.
//! - Free–free collapses place the survivor at the quadric optimum (solved in f64; when the system
//!   is ill-conditioned or the optimum is far from the edge, the cheapest of the two ends and the
//!   midpoint), and its corner attributes are interpolated along the edge at the projection of the
//!   new position.
//! - Otherwise the collapse is a half-edge collapse onto an existing vertex, which keeps its place
//!   and its corner attributes: a free vertex onto a feature-line vertex, or a feature-line vertex
//!   along one of its own two feature edges onto the next vertex of the same line. Corners that
//!   follow the removed vertex take the survivor's corner values on their side of the line, so
//!   seams and material borders keep their topology and borders stay where they were.
//!
//! A collapse is also rejected when it breaks the link condition (the mesh stays manifold and no
//! face is duplicated), turns a face normal by more than `max_normal_turn` from its input normal, or
//! creates a degenerate or sliver face.
//!
//! Groups: group borders are feature lines, so a group's outline moves only along itself and the
//! removed vertex of any collapse touches at most two groups (the method's condition 2). The
//! method's condition 1 is applied in the form that is sufficient for connectivity: when both
//! removed faces lie in one group, the removed vertex is free or on an attribute seam, so its
//! closed one-group fan keeps the group connected; when they lie in different groups (a collapse
//! along a group border or an open border), each removed face must keep an edge neighbour in its
//! own group. Removing a face f from its group can only split the group through f, and the faces
//! across f's two other edges become edge neighbours after the collapse, so the group neither
//! splits nor vanishes. This also lets group outlines simplify, as the method asks.

use crate::mesh::{Adjacency, Mesh, VertexFaces, NO_FACE};
use glam::{DVec3, Vec2, Vec3};
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// How far to simplify and which collapses to allow.
#[derive(Clone, Debug, PartialEq)]
pub struct SimplifyOptions {
    /// Stop once at most this many faces remain, as far as the rules allow. Default 0: only
    /// `max_error` (or running out of legal collapses) stops.
    pub target_faces: usize,
    /// Make no collapse whose error estimate (model units) exceeds this. Default none.
    pub max_error: Option<f32>,
    /// Radians. A collapse that leaves any face normal turned by more than this from that face's
    /// normal in the input is rejected. Measured from the input, turns cannot add up over many
    /// collapses into folds. Default 60°: freedom enough to reach 1% on scanned meshes.
    pub max_normal_turn: f32,
    /// Reject a collapse that leaves a face with quality below this and worse than before. Quality
    /// is 4√3·area / (sum of squared edge lengths): 1 for an equilateral triangle, 0 for a
    /// degenerate one. Default 0.05 (a triangle about 30× longer than wide).
    pub min_face_quality: f32,
    /// Weight of the border planes (perpendicular to the face through each open-border edge,
    /// weighted by the squared edge length) against the area-weighted face planes. Default 10:
    /// heavy, so border collapses come late and only where the border is straight.
    pub border_weight: f32,
    /// The same for seam edges (attribute, material and group borders). Default 1.
    pub seam_weight: f32,
}

impl Default for SimplifyOptions {
    fn default() -> Self {
        SimplifyOptions {
            target_faces: 0,
            max_error: None,
            max_normal_turn: 60f32.to_radians(),
            min_face_quality: 0.05,
            border_weight: 10.0,
            seam_weight: 1.0,
        }
    }
}

/// A simplified mesh and how far it may be from its input.
#[derive(Clone, Debug, PartialEq)]
pub struct Simplified {
    /// Compacted (no unused vertices, which keep their input order), faces in input order,
    /// face normals and areas recomputed.
    pub mesh: Mesh,
    /// Input face of each output face (output faces are the surviving input faces, in order).
    pub source_faces: Vec<u32>,
    /// Group label of each output face, copied from the input labels; empty without groups.
    pub face_groups: Vec<u32>,
    /// Per group label, the largest error estimate of a vertex of its faces (0 if untouched);
    /// empty without groups.
    pub group_error: Vec<f32>,
    /// The largest error estimate of any collapse made.
    pub error: f32,
}

/// Simplify `mesh` by quadric-error edge collapses until `opts.target_faces` or `opts.max_error`.
///
/// `groups`: optional face partition (a label per input face, labels `0..n_groups`). When given,
/// every group stays a connected, non-empty patch.
///
/// Error estimates are in model units: a vertex's error is sqrt(quadric cost / accumulated weight),
/// the weighted RMS distance of its position to the planes merged into it. It is an estimate, not a
/// bound on the Hausdorff distance to the input.
///
/// # Panics
/// If `groups` is given with a length other than the face count.
pub fn simplify(mesh: &Mesh, groups: Option<&[u32]>, opts: &SimplifyOptions) -> Simplified {
    if let Some(g) = groups {
        assert_eq!(g.len(), mesh.triangles.len(), "simplify: one group label per face");
    }
    let mut s = State::new(mesh, groups, opts);
    if mesh.triangles.len() > opts.target_faces {
        s.run(opts);
    }
    s.finish(mesh, groups.is_some())
}

/// Classification of a vertex from its feature edges.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Unknown,
    Free,
    Line,
    Corner,
}

/// A symmetric quadric pᵀAp + 2bᵀp + c with its accumulated weights.
#[derive(Clone, Copy, Debug, Default)]
struct Quadric {
    /// xx, xy, xz, yy, yz, zz.
    a: [f64; 6],
    b: [f64; 3],
    c: f64,
    /// Sum of the weights of all planes: Q(p) / w is a mean squared distance (the error estimate).
    w: f64,
    /// Sum of the face areas only: Q(p) / area orders collapses, so that heavily weighted border
    /// and seam planes make those collapses come late.
    area: f64,
}

impl Quadric {
    /// weight · (distance to the plane through `p` with unit normal `n`)².
    fn plane(n: DVec3, p: DVec3, weight: f64) -> Quadric {
        let d = -n.dot(p);
        let wn = n * weight;
        Quadric {
            a: [wn.x * n.x, wn.x * n.y, wn.x * n.z, wn.y * n.y, wn.y * n.z, wn.z * n.z],
            b: [wn.x * d, wn.y * d, wn.z * d],
            c: weight * d * d,
            w: weight,
            area: 0.0,
        }
    }

    fn add(&mut self, o: &Quadric) {
        for i in 0..6 {
            self.a[i] += o.a[i];
        }
        for i in 0..3 {
            self.b[i] += o.b[i];
        }
        self.c += o.c;
        self.w += o.w;
        self.area += o.area;
    }

    fn eval(&self, p: DVec3) -> f64 {
        let [xx, xy, xz, yy, yz, zz] = self.a;
        let ap = DVec3::new(xx * p.x + xy * p.y + xz * p.z, xy * p.x + yy * p.y + yz * p.z, xz * p.x + yz * p.y + zz * p.z);
        (p.dot(ap) + 2.0 * (self.b[0] * p.x + self.b[1] * p.y + self.b[2] * p.z) + self.c).max(0.0)
    }

    /// The minimiser, if A is well conditioned: det(A / trace A) above 1e-9.
    fn optimum(&self) -> Option<DVec3> {
        let [xx, xy, xz, yy, yz, zz] = self.a;
        let (c00, c01, c02) = (yy * zz - yz * yz, xz * yz - xy * zz, xy * yz - xz * yy);
        let det = xx * c00 + xy * c01 + xz * c02;
        let trace = xx + yy + zz;
        if !(trace > 0.0) || det <= 1e-9 * trace * trace * trace {
            return None;
        }
        let (c11, c12, c22) = (xx * zz - xz * xz, xy * xz - xx * yz, xx * yy - xy * xy);
        let [bx, by, bz] = self.b;
        let inv = -1.0 / det;
        Some(DVec3::new(
            (c00 * bx + c01 * by + c02 * bz) * inv,
            (c01 * bx + c11 * by + c12 * bz) * inv,
            (c02 * bx + c12 * by + c22 * bz) * inv,
        ))
    }
}

/// The faces on an edge (one for a border edge, two otherwise) and their third vertices.
#[derive(Clone, Copy, Debug)]
struct EdgeFaces {
    f: [u32; 2],
    x: [u32; 2],
    n: usize,
}

/// One way to collapse an edge: `remove` merges into `keep`, which moves to `pos`.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    remove: u32,
    keep: u32,
    pos: DVec3,
    /// Free–free collapse: attributes interpolated from `remove` (0) to `keep` (1) at this parameter.
    lerp: Option<f64>,
    /// Ordering key: quadric cost / face area.
    cost: f64,
    /// Squared error estimate: quadric cost / total weight.
    error_sq: f64,
}

/// The legal candidates of an edge, cheapest first.
#[derive(Clone, Copy, Debug)]
struct Plan {
    e: EdgeFaces,
    c: [Candidate; 4],
    n: usize,
}

/// A heap entry; valid while both vertices still have the versions it was pushed with.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Entry {
    key: f32,
    u: u32,
    v: u32,
    ver_u: u32,
    ver_v: u32,
}

impl Eq for Entry {}

impl Ord for Entry {
    /// Reversed, so that `BinaryHeap` pops the cheapest entry; ties broken by vertex ids.
    fn cmp(&self, o: &Self) -> Ordering {
        o.key.total_cmp(&self.key).then_with(|| (o.u, o.v).cmp(&(self.u, self.v)))
    }
}

impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

const DEAD: u32 = u32::MAX;

struct State {
    pos: Vec<DVec3>,
    tris: Vec<[u32; 3]>,
    mat: Vec<u32>,
    grp: Vec<u32>,
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
    colors: Vec<[u8; 4]>,
    quadrics: Vec<Quadric>,
    /// Unit normal of each face in the input: turns are measured from it, so they cannot add up.
    input_normals: Vec<DVec3>,
    /// Faces of vertex v: `vf[vf_start[v]..][..vf_len[v]]`; lists are appended when they change.
    vf: Vec<u32>,
    vf_start: Vec<u32>,
    vf_len: Vec<u32>,
    /// Arena length that triggers the next compaction.
    vf_compact_at: usize,
    /// Never collapsed: non-manifold, unused or removed.
    locked: Vec<bool>,
    kind: Vec<Kind>,
    ver: Vec<u32>,
    mark: Vec<u32>,
    stamp: u32,
    heap: BinaryHeap<Entry>,
    faces_left: usize,
    error_sq: f64,
    cos_turn: f64,
    min_quality: f64,
    scratch_edges: Vec<(u32, u32, u32)>,
    scratch_r: Vec<u32>,
    scratch_k: Vec<u32>,
}

impl State {
    fn new(mesh: &Mesh, groups: Option<&[u32]>, opts: &SimplifyOptions) -> State {
        let nf = mesh.triangles.len();
        let nv = mesh.positions.len();
        let vfaces = VertexFaces::build(mesh);
        let mut s = State {
            pos: mesh.positions.iter().map(|p| p.as_dvec3()).collect(),
            tris: mesh.triangles.clone(),
            mat: if mesh.face_materials.len() == nf { mesh.face_materials.clone() } else { vec![0; nf] },
            grp: groups.map_or_else(|| vec![0; nf], <[u32]>::to_vec),
            normals: mesh.normals.clone(),
            uvs: mesh.uvs.clone(),
            colors: mesh.colors.clone(),
            quadrics: vec![Quadric::default(); nv],
            input_normals: mesh.triangles.iter().map(|t| crate::mesh::triangle_cross(&mesh.positions, t).normalize_or_zero()).collect(),
            vf_start: vfaces.offsets[..nv].to_vec(),
            vf_len: vfaces.offsets.windows(2).map(|w| w[1] - w[0]).collect(),
            vf: vfaces.faces,
            vf_compact_at: 2 * 3 * nf.max(1024),
            locked: vec![false; nv],
            kind: vec![Kind::Unknown; nv],
            ver: vec![0; nv],
            mark: vec![0; nv.max(nf)],
            stamp: 0,
            heap: BinaryHeap::new(),
            faces_left: nf,
            error_sq: 0.0,
            cos_turn: f64::from(opts.max_normal_turn).cos(),
            min_quality: f64::from(opts.min_face_quality),
            scratch_edges: Vec::new(),
            scratch_r: Vec::new(),
            scratch_k: Vec::new(),
        };
        if nf > opts.target_faces {
            s.init_quadrics_and_locks(mesh, opts);
        }
        s
    }

    fn faces(&self, v: u32) -> &[u32] {
        let start = self.vf_start[v as usize] as usize;
        &self.vf[start..start + self.vf_len[v as usize] as usize]
    }

    /// Face planes, border and seam planes; locks unused vertices, vertices on non-manifold edges
    /// and bow-tie vertices (faces around them not one edge-connected fan).
    fn init_quadrics_and_locks(&mut self, mesh: &Mesh, opts: &SimplifyOptions) {
        let adj = Adjacency::build(mesh);
        for (f, t) in self.tris.iter().enumerate() {
            let [a, b, c] = t.map(|v| self.pos[v as usize]);
            let cross = (b - a).cross(c - a);
            let len = cross.length();
            if len == 0.0 {
                continue;
            }
            let n = cross / len;
            let q = Quadric { area: 0.5 * len, ..Quadric::plane(n, a, 0.5 * len) };
            for &v in t {
                self.quadrics[v as usize].add(&q);
            }
            for k in 0..3 {
                let nb = adj.face_neighbors[f][k];
                let (v0, v1) = (t[k], t[(k + 1) % 3]);
                let weight = if nb == NO_FACE {
                    opts.border_weight
                } else if !self.same_corner(3 * f + k, self.corner(nb, v0)) || !self.same_corner(3 * f + (k + 1) % 3, self.corner(nb, v1)) {
                    0.5 * opts.seam_weight
                } else {
                    continue;
                };
                let (p0, p1) = (self.pos[v0 as usize], self.pos[v1 as usize]);
                let along = p1 - p0;
                let m = along.cross(n).normalize_or_zero();
                if m == DVec3::ZERO {
                    continue;
                }
                let q = Quadric::plane(m, p0, f64::from(weight) * along.length_squared());
                self.quadrics[v0 as usize].add(&q);
                self.quadrics[v1 as usize].add(&q);
            }
        }
        for &[a, b] in &adj.nonmanifold_edges {
            self.locked[a as usize] = true;
            self.locked[b as usize] = true;
        }
        // Bow-tie test: walk the faces around v across edges containing v.
        let mut stack = Vec::new();
        for v in 0..self.pos.len() as u32 {
            let faces = self.faces(v);
            let Some(&first) = faces.first() else {
                self.locked[v as usize] = true;
                continue;
            };
            let total = faces.len();
            self.stamp += 1;
            let stamp = self.stamp;
            self.mark[first as usize] = stamp;
            stack.clear();
            stack.push(first);
            let mut reached = 1;
            while let Some(f) = stack.pop() {
                let t = self.tris[f as usize];
                for k in 0..3 {
                    let nb = adj.face_neighbors[f as usize][k];
                    if (t[k] == v || t[(k + 1) % 3] == v) && nb != NO_FACE && self.mark[nb as usize] != stamp {
                        self.mark[nb as usize] = stamp;
                        reached += 1;
                        stack.push(nb);
                    }
                }
            }
            if reached != total {
                self.locked[v as usize] = true;
            }
        }
    }

    /// Corner index of vertex `v` in face `f`.
    fn corner(&self, f: u32, v: u32) -> usize {
        let t = self.tris[f as usize];
        3 * f as usize + if t[0] == v { 0 } else if t[1] == v { 1 } else { 2 }
    }

    /// Whether two corners carry the same attributes, material and group.
    fn same_corner(&self, c0: usize, c1: usize) -> bool {
        let (f0, f1) = (c0 / 3, c1 / 3);
        self.mat[f0] == self.mat[f1]
            && self.grp[f0] == self.grp[f1]
            && (self.normals.is_empty() || self.normals[c0].to_array().map(f32::to_bits) == self.normals[c1].to_array().map(f32::to_bits))
            && (self.uvs.is_empty() || self.uvs[c0].to_array().map(f32::to_bits) == self.uvs[c1].to_array().map(f32::to_bits))
            && (self.colors.is_empty() || self.colors[c0] == self.colors[c1])
    }

    /// Whether the edge (a, b) with faces `e` is a feature edge.
    fn is_feature(&self, a: u32, b: u32, e: &EdgeFaces) -> bool {
        e.n == 1
            || !self.same_corner(self.corner(e.f[0], a), self.corner(e.f[1], a))
            || !self.same_corner(self.corner(e.f[0], b), self.corner(e.f[1], b))
    }

    fn kind(&mut self, v: u32) -> Kind {
        if self.kind[v as usize] != Kind::Unknown {
            return self.kind[v as usize];
        }
        let mut edges = std::mem::take(&mut self.scratch_edges);
        edges.clear();
        for &f in self.faces(v) {
            let c = self.corner(f, v);
            let (i, base) = (c % 3, c - c % 3);
            let t = self.tris[f as usize];
            for j in [(i + 1) % 3, (i + 2) % 3] {
                edges.push((t[j], c as u32, (base + j) as u32));
            }
        }
        edges.sort_unstable_by_key(|e| e.0);
        let mut features = 0;
        let mut kind = Kind::Free;
        for run in edges.chunk_by(|a, b| a.0 == b.0) {
            match run {
                [_] => features += 1,
                [a, b] => {
                    if !self.same_corner(a.1 as usize, b.1 as usize) || !self.same_corner(a.2 as usize, b.2 as usize) {
                        features += 1;
                    }
                }
                _ => kind = Kind::Corner,
            }
        }
        if kind != Kind::Corner {
            kind = match features {
                0 => Kind::Free,
                2 => Kind::Line,
                _ => Kind::Corner,
            };
        }
        self.scratch_edges = edges;
        self.kind[v as usize] = kind;
        kind
    }

    fn edge_faces(&self, u: u32, v: u32) -> Option<EdgeFaces> {
        let mut e = EdgeFaces { f: [NO_FACE; 2], x: [NO_FACE; 2], n: 0 };
        for &f in self.faces(u) {
            let t = self.tris[f as usize];
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

    /// The legal ways to collapse edge (u, v), cheapest first, or `None`.
    fn plan(&mut self, u: u32, v: u32) -> Option<Plan> {
        if self.locked[u as usize] || self.locked[v as usize] {
            return None;
        }
        let e = self.edge_faces(u, v)?;
        let (ku, kv) = (self.kind(u), self.kind(v));
        let mut q = self.quadrics[u as usize];
        q.add(&self.quadrics[v as usize]);
        let inv_area = if q.area > 0.0 { 1.0 / q.area } else { 1.0 };
        let inv_w = if q.w > 0.0 { 1.0 / q.w } else { 1.0 };
        let (pu, pv) = (self.pos[u as usize], self.pos[v as usize]);
        let none = Candidate { remove: u, keep: v, pos: pv, lerp: None, cost: f64::INFINITY, error_sq: f64::INFINITY };
        let mut plan = Plan { e, c: [none; 4], n: 0 };
        let mut add = |c: Candidate| {
            plan.c[plan.n] = c;
            plan.n += 1;
        };
        if ku == Kind::Free && kv == Kind::Free {
            let d = pv - pu;
            let len2 = d.length_squared();
            let mut at = |p: DVec3| {
                let t = if len2 > 0.0 { ((p - pu).dot(d) / len2).clamp(0.0, 1.0) } else { 0.5 };
                let e = q.eval(p);
                add(Candidate { remove: u, keep: v, pos: p, lerp: Some(t), cost: e * inv_area, error_sq: e * inv_w });
            };
            let mid = 0.5 * (pu + pv);
            if let Some(p) = q.optimum().filter(|p| (*p - mid).length_squared() <= len2) {
                at(p);
            }
            at(pu);
            at(pv);
            at(mid);
        } else {
            let feature = self.is_feature(u, v, &e);
            for (r, k, kr, pk) in [(u, v, ku, pv), (v, u, kv, pu)] {
                let removable = match kr {
                    Kind::Free => true,
                    Kind::Line => {
                        feature && (e.n == 1 || !self.same_corner(self.corner(e.f[0], k), self.corner(e.f[1], k)))
                    }
                    _ => false,
                };
                if removable {
                    let e = q.eval(pk);
                    add(Candidate { remove: r, keep: k, pos: pk, lerp: None, cost: e * inv_area, error_sq: e * inv_w });
                }
            }
        }
        plan.c[..plan.n].sort_unstable_by(|a, b| a.cost.total_cmp(&b.cost));
        (plan.n > 0).then_some(plan)
    }

    fn push(&mut self, u: u32, v: u32) {
        if let Some(plan) = self.plan(u, v) {
            let (ver_u, ver_v) = (self.ver[u as usize], self.ver[v as usize]);
            self.heap.push(Entry { key: plan.c[0].cost as f32, u, v, ver_u, ver_v });
        }
    }

    /// Fill the heap with every edge of the current mesh.
    fn fill_heap(&mut self) {
        let mut entries = std::mem::take(&mut self.heap).into_vec();
        entries.clear();
        let mut nbrs = Vec::new();
        for a in 0..self.pos.len() as u32 {
            if self.locked[a as usize] {
                continue;
            }
            self.stamp += 1;
            nbrs.clear();
            for i in 0..self.vf_len[a as usize] as usize {
                let f = self.vf[self.vf_start[a as usize] as usize + i];
                for y in self.tris[f as usize] {
                    if y > a && self.mark[y as usize] != self.stamp {
                        self.mark[y as usize] = self.stamp;
                        nbrs.push(y);
                    }
                }
            }
            for &b in &nbrs {
                if let Some(plan) = self.plan(a, b) {
                    entries.push(Entry { key: plan.c[0].cost as f32, u: a, v: b, ver_u: self.ver[a as usize], ver_v: self.ver[b as usize] });
                }
            }
        }
        self.heap = BinaryHeap::from(entries);
    }

    fn run(&mut self, opts: &SimplifyOptions) {
        let max_error_sq = opts.max_error.map(|e| f64::from(e).powi(2));
        loop {
            self.fill_heap();
            let mut collapsed = 0usize;
            while self.faces_left > opts.target_faces {
                let Some(entry) = self.heap.pop() else { break };
                let (u, v) = (entry.u, entry.v);
                if self.ver[u as usize] != entry.ver_u || self.ver[v as usize] != entry.ver_v {
                    continue;
                }
                let Some(plan) = self.plan(u, v) else { continue };
                let best = plan.c[0].cost as f32;
                if best > entry.key {
                    self.heap.push(Entry { key: best, ..entry });
                    continue;
                }
                let limit = max_error_sq.unwrap_or(f64::INFINITY);
                if let Some(c) = plan.c[..plan.n].iter().find(|c| c.error_sq <= limit && self.legal(&plan.e, c)) {
                    self.collapse(&plan.e, *c);
                    collapsed += 1;
                }
            }
            if self.faces_left <= opts.target_faces || collapsed == 0 {
                return;
            }
        }
    }

    /// Link condition, group survival and face shape for one candidate.
    fn legal(&mut self, e: &EdgeFaces, c: &Candidate) -> bool {
        let (r, k) = (c.remove, c.keep);
        let (x0, x1) = (e.x[0], if e.n == 2 { e.x[1] } else { e.x[0] });
        // Link condition: the common neighbours of r and k are exactly the opposite vertices.
        self.stamp += 2;
        let s = self.stamp;
        for i in 0..self.vf_len[r as usize] as usize {
            let f = self.vf[self.vf_start[r as usize] as usize + i];
            for y in self.tris[f as usize] {
                self.mark[y as usize] = s;
            }
        }
        let mut common = 0;
        for i in 0..self.vf_len[k as usize] as usize {
            let f = self.vf[self.vf_start[k as usize] as usize + i];
            for y in self.tris[f as usize] {
                if y != k && y != r && self.mark[y as usize] == s {
                    if y != x0 && y != x1 {
                        return false;
                    }
                    self.mark[y as usize] = s + 1;
                    common += 1;
                }
            }
        }
        if common != e.n {
            return false;
        }
        if e.n == 2 {
            let spans = |v: u32| self.faces(v).iter().any(|&f| !e.f.contains(&f) && { let t = self.tris[f as usize]; t.contains(&x0) && t.contains(&x1) });
            if spans(r) && spans(k) {
                return false;
            }
        }
        // Group survival for collapses that remove faces of two groups (or one border face).
        for i in 0..e.n {
            let (f, other) = (e.f[i], if e.n == 2 { e.f[1 - i] } else { NO_FACE });
            if other != NO_FACE && self.grp[other as usize] == self.grp[f as usize] {
                continue;
            }
            let g = self.grp[f as usize];
            let kept = |v: u32| {
                self.faces(v).iter().any(|&h| h != f && h != other && self.grp[h as usize] == g && self.tris[h as usize].contains(&e.x[i]))
            };
            if !kept(r) && !kept(k) {
                return false;
            }
        }
        // Shape: no flip beyond the bound, no degenerate or new sliver face.
        for &f in self.faces(r) {
            if !e.f.contains(&f) && !self.shape_ok(f, (r, c.pos)) {
                return false;
            }
        }
        if c.pos != self.pos[k as usize] {
            for &f in self.faces(k) {
                if !e.f.contains(&f) && !self.shape_ok(f, (k, c.pos)) {
                    return false;
                }
            }
        }
        true
    }

    /// Whether face `f` with vertex `moved.0` at `moved.1` keeps its orientation and shape.
    fn shape_ok(&self, f: u32, moved: (u32, DVec3)) -> bool {
        let t = self.tris[f as usize];
        let old = t.map(|v| self.pos[v as usize]);
        let new = t.map(|v| if v == moved.0 { moved.1 } else { self.pos[v as usize] });
        let n_old = (old[1] - old[0]).cross(old[2] - old[0]);
        let n_new = (new[1] - new[0]).cross(new[2] - new[0]);
        let len_new = n_new.length();
        let quality = |p: &[DVec3; 3], len: f64| {
            let l2 = (p[1] - p[0]).length_squared() + (p[2] - p[1]).length_squared() + (p[0] - p[2]).length_squared();
            if l2 > 0.0 { 2.0 * 3f64.sqrt() * len / l2 } else { 0.0 }
        };
        let q_new = quality(&new, len_new);
        if q_new <= 1e-6 || (q_new < self.min_quality && q_new < quality(&old, n_old.length())) {
            return false;
        }
        let n_input = self.input_normals[f as usize];
        n_input == DVec3::ZERO || n_input.dot(n_new) >= self.cos_turn * len_new
    }

    fn copy_corner(&mut self, from: usize, to: usize) {
        if !self.normals.is_empty() {
            self.normals[to] = self.normals[from];
        }
        if !self.uvs.is_empty() {
            self.uvs[to] = self.uvs[from];
        }
        if !self.colors.is_empty() {
            self.colors[to] = self.colors[from];
        }
    }

    /// Faces of the sector around `r` that starts at `start` (on edge (r, from)) and ends at the
    /// next feature edge, excluding `start`.
    fn sector(&self, r: u32, start: u32, from: u32, out: &mut Vec<u32>) {
        out.clear();
        let (mut cur, mut prev) = (start, from);
        for _ in 0..self.vf_len[r as usize] {
            let t = self.tris[cur as usize];
            let y = t[0] ^ t[1] ^ t[2] ^ r ^ prev;
            let mut next = None;
            for &g in self.faces(r) {
                if g != cur && self.tris[g as usize].contains(&y) {
                    next = Some(g);
                }
            }
            let Some(g) = next else { return };
            let e = EdgeFaces { f: [cur, g], x: [NO_FACE; 2], n: 2 };
            if self.is_feature(r, y, &e) {
                return;
            }
            out.push(g);
            cur = g;
            prev = y;
        }
    }

    fn collapse(&mut self, e: &EdgeFaces, c: Candidate) {
        let (r, k) = (c.remove, c.keep);
        let has_attributes = !self.normals.is_empty() || !self.uvs.is_empty() || !self.colors.is_empty();
        let mut rf = std::mem::take(&mut self.scratch_r);
        let mut kf = std::mem::take(&mut self.scratch_k);
        rf.clear();
        kf.clear();
        rf.extend(self.faces(r).iter().copied().filter(|f| !e.f.contains(f)));
        kf.extend(self.faces(k).iter().copied().filter(|f| !e.f.contains(f)));

        if has_attributes {
            if let Some(t) = c.lerp {
                let (cr, ck) = (self.corner(e.f[0], r), self.corner(e.f[0], k));
                self.lerp_corner(cr, ck, t as f32);
                for &f in &kf {
                    let to = self.corner(f, k);
                    self.copy_corner(cr, to);
                }
                for &f in &rf {
                    let to = self.corner(f, r);
                    self.copy_corner(cr, to);
                }
            } else {
                let mut side = Vec::new();
                if e.n == 2 && self.kind[r as usize] == Kind::Line {
                    self.sector(r, e.f[0], k, &mut side);
                }
                let (c0, c1) = (self.corner(e.f[0], k), if e.n == 2 { self.corner(e.f[1], k) } else { 0 });
                for &f in &rf {
                    let from = if e.n == 2 && self.kind[r as usize] == Kind::Line && !side.contains(&f) { c1 } else { c0 };
                    let to = self.corner(f, r);
                    self.copy_corner(from, to);
                }
            }
        }

        for &f in e.f[..e.n].iter() {
            self.tris[f as usize] = [DEAD; 3];
        }
        self.faces_left -= e.n;
        for &f in &rf {
            for v in &mut self.tris[f as usize] {
                if *v == r {
                    *v = k;
                }
            }
            for v in self.tris[f as usize] {
                self.kind[v as usize] = Kind::Unknown;
            }
        }
        for &x in &e.x[..e.n] {
            self.kind[x as usize] = Kind::Unknown;
            let start = self.vf_start[x as usize] as usize;
            let mut len = 0;
            for i in 0..self.vf_len[x as usize] as usize {
                let f = self.vf[start + i];
                if !e.f.contains(&f) {
                    self.vf[start + len] = f;
                    len += 1;
                }
            }
            self.vf_len[x as usize] = len as u32;
        }
        self.kind[k as usize] = Kind::Unknown;

        // New face list of k, appended; the arena is compacted when it has grown too much.
        if self.vf.len() > self.vf_compact_at {
            self.compact_face_lists();
            self.vf_compact_at = 2 * self.vf.len().max(1024);
        }
        let start = self.vf.len();
        self.vf.extend_from_slice(&kf);
        self.vf.extend_from_slice(&rf);
        self.vf_start[k as usize] = start as u32;
        self.vf_len[k as usize] = (kf.len() + rf.len()) as u32;
        self.vf_len[r as usize] = 0;

        self.pos[k as usize] = c.pos;
        let qr = self.quadrics[r as usize];
        self.quadrics[k as usize].add(&qr);
        self.ver[k as usize] += 1;
        self.ver[r as usize] += 1;
        self.locked[r as usize] = true;
        self.error_sq = self.error_sq.max(c.error_sq);

        // Re-queue the edges of k.
        kf.clear();
        self.stamp += 1;
        for i in 0..self.vf_len[k as usize] as usize {
            let f = self.vf[self.vf_start[k as usize] as usize + i];
            for y in self.tris[f as usize] {
                if y != k && self.mark[y as usize] != self.stamp {
                    self.mark[y as usize] = self.stamp;
                    kf.push(y);
                }
            }
        }
        for &y in &kf {
            self.push(k, y);
        }
        self.scratch_r = rf;
        self.scratch_k = kf;
    }

    /// Set corner `cr` to its attributes interpolated towards corner `ck` at `t`.
    fn lerp_corner(&mut self, cr: usize, ck: usize, t: f32) {
        if !self.normals.is_empty() {
            let n = self.normals[cr].lerp(self.normals[ck], t);
            self.normals[cr] = n.try_normalize().unwrap_or(n);
        }
        if !self.uvs.is_empty() {
            self.uvs[cr] = self.uvs[cr].lerp(self.uvs[ck], t);
        }
        if !self.colors.is_empty() {
            let (a, b) = (self.colors[cr], self.colors[ck]);
            self.colors[cr] = std::array::from_fn(|i| (f32::from(a[i]) + (f32::from(b[i]) - f32::from(a[i])) * t).round() as u8);
        }
    }

    fn compact_face_lists(&mut self) {
        let mut vf = Vec::with_capacity(3 * self.faces_left + 1024);
        for v in 0..self.pos.len() {
            let start = self.vf_start[v] as usize;
            let len = self.vf_len[v] as usize;
            self.vf_start[v] = vf.len() as u32;
            vf.extend_from_slice(&self.vf[start..start + len]);
        }
        self.vf = vf;
    }

    fn finish(self, mesh: &Mesh, with_groups: bool) -> Simplified {
        let alive: Vec<usize> = (0..self.tris.len()).filter(|&f| self.tris[f][0] != DEAD).collect();
        let mut used = vec![false; self.pos.len()];
        for &f in &alive {
            for v in self.tris[f] {
                used[v as usize] = true;
            }
        }
        let mut remap = vec![u32::MAX; self.pos.len()];
        let mut positions = Vec::new();
        let mut vertex_error = Vec::new();
        for v in 0..self.pos.len() {
            if used[v] {
                remap[v] = positions.len() as u32;
                positions.push(self.pos[v].as_vec3());
                let q = &self.quadrics[v];
                vertex_error.push(if q.w > 0.0 { (q.eval(self.pos[v]) / q.w).sqrt() as f32 } else { 0.0 });
            }
        }
        fn corners<T: Copy>(a: &[T], alive: &[usize]) -> Vec<T> {
            if a.is_empty() {
                return Vec::new();
            }
            alive.iter().flat_map(|&f| a[3 * f..3 * f + 3].iter().copied()).collect()
        }
        let triangles: Vec<[u32; 3]> = alive.iter().map(|&f| self.tris[f].map(|v| remap[v as usize])).collect();
        let mut out = Mesh {
            positions,
            normals: corners(&self.normals, &alive),
            uvs: corners(&self.uvs, &alive),
            colors: corners(&self.colors, &alive),
            face_materials: if mesh.face_materials.is_empty() { Vec::new() } else { alive.iter().map(|&f| self.mat[f]).collect() },
            materials: mesh.materials.clone(),
            triangles,
            face_normals: Vec::new(),
            face_areas: Vec::new(),
        };
        out.compute_face_geometry();
        let (face_groups, group_error) = if with_groups {
            let face_groups: Vec<u32> = alive.iter().map(|&f| self.grp[f]).collect();
            let n_groups = self.grp.iter().max().map_or(0, |&g| g as usize + 1);
            let mut group_error = vec![0f32; n_groups];
            for (t, &g) in out.triangles.iter().zip(&face_groups) {
                for &v in t {
                    group_error[g as usize] = group_error[g as usize].max(vertex_error[v as usize]);
                }
            }
            (face_groups, group_error)
        } else {
            (Vec::new(), Vec::new())
        };
        let source_faces = alive.iter().map(|&f| f as u32).collect();
        Simplified { mesh: out, source_faces, face_groups, group_error, error: self.error_sq.sqrt() as f32 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Material;
    use proptest::prelude::*;
    use std::collections::HashMap;

    fn icosphere(levels: u32) -> Mesh {
        let t = (1.0 + 5f32.sqrt()) / 2.0;
        let mut positions: Vec<Vec3> = [
            (-1., t, 0.), (1., t, 0.), (-1., -t, 0.), (1., -t, 0.), (0., -1., t), (0., 1., t),
            (0., -1., -t), (0., 1., -t), (t, 0., -1.), (t, 0., 1.), (-t, 0., -1.), (-t, 0., 1.),
        ]
        .iter()
        .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
        .collect();
        let mut triangles: Vec<[u32; 3]> = vec![
            [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
            [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
            [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
        ];
        for _ in 0..levels {
            let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
            let mut next = Vec::new();
            for [a, b, c] in triangles {
                let mut m = |x: u32, y: u32| {
                    *mid.entry((x.min(y), x.max(y))).or_insert_with(|| {
                        positions.push((positions[x as usize] + positions[y as usize]).normalize());
                        positions.len() as u32 - 1
                    })
                };
                let (ab, bc, ca) = (m(a, b), m(b, c), m(c, a));
                next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            triangles = next;
        }
        Mesh { positions, triangles, ..Default::default() }.clean().expect("finite").0
    }

    /// A deterministic hash in [-0.5, 0.5).
    fn noise(i: u64) -> f32 {
        let mut z = i.wrapping_mul(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 31)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        ((z >> 40) as f32 / (1u64 << 24) as f32) - 0.5
    }

    fn noisy_sphere(levels: u32, amount: f32, seed: u64) -> Mesh {
        let mut m = icosphere(levels);
        for (i, p) in m.positions.iter_mut().enumerate() {
            *p *= 1.0 + amount * noise(seed ^ i as u64);
        }
        m.compute_face_geometry();
        m
    }

    /// An n×n open grid on a gentle bump, one border loop.
    fn grid(n: u32) -> Mesh {
        let mut positions = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
                positions.push(Vec3::new(x, y, 0.2 * (3.0 * x).sin() * (2.0 * y).cos()));
            }
        }
        let at = |i: u32, j: u32| j * (n + 1) + i;
        let mut triangles = Vec::new();
        for j in 0..n {
            for i in 0..n {
                triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        Mesh { positions, triangles, ..Default::default() }.clean().expect("finite").0
    }

    /// An icosphere with smooth normals, a spherical UV map whose seam runs along one meridian,
    /// and two materials (upper and lower half).
    fn seamed_sphere(levels: u32) -> Mesh {
        let mut m = icosphere(levels);
        // Rotate slightly so no vertex sits exactly on the poles' singular meridian.
        for p in &mut m.positions {
            *p = glam::Quat::from_rotation_z(0.1) * *p;
        }
        m.compute_face_geometry();
        let u_of = |p: Vec3| (p.y.atan2(p.x) / std::f32::consts::TAU).rem_euclid(1.0);
        for t in &m.triangles {
            let mut uv = t.map(|v| {
                let p = m.positions[v as usize];
                Vec2::new(u_of(p), p.z.acos() / std::f32::consts::PI)
            });
            let hi = uv.iter().map(|c| c.x).fold(0.0, f32::max);
            for c in &mut uv {
                if hi - c.x > 0.5 {
                    c.x += 1.0;
                }
            }
            m.uvs.extend(uv);
            m.normals.extend(t.map(|v| m.positions[v as usize]));
        }
        m.face_materials = m.triangles.iter().map(|t| u32::from(t.iter().map(|&v| m.positions[v as usize].z).sum::<f32>() > 0.0)).collect();
        m.materials = vec![Material::default(), Material { name: "top".into(), ..Material::default() }];
        m
    }

    /// A grid with a fin: a third face on one interior edge.
    fn fin() -> Mesh {
        let mut m = grid(12);
        let (a, b) = (m.triangles[40][0], m.triangles[40][2]);
        m.positions.push(Vec3::new(0.45, 0.3, 1.0));
        m.triangles.push([a, b, m.positions.len() as u32 - 1]);
        m.face_materials.push(0);
        m.compute_face_geometry();
        m
    }

    /// Groups as edge-connected patches around `k` seed faces (breadth-first from each seed).
    fn patches(mesh: &Mesh, k: usize) -> Vec<u32> {
        let adj = Adjacency::build(mesh);
        let nf = mesh.triangles.len();
        let mut label = vec![u32::MAX; nf];
        let mut queue = std::collections::VecDeque::new();
        for g in 0..k {
            let f = g * nf / k;
            if label[f] == u32::MAX {
                label[f] = g as u32;
                queue.push_back(f);
            }
        }
        while let Some(f) = queue.pop_front() {
            for &nb in &adj.face_neighbors[f] {
                if nb != NO_FACE && label[nb as usize] == u32::MAX {
                    label[nb as usize] = label[f];
                    queue.push_back(nb as usize);
                }
            }
        }
        // Faces unreachable through manifold edges (a fin) get a group of their own.
        let mut next = k as u32;
        for l in &mut label {
            if *l == u32::MAX {
                *l = next;
                next += 1;
            }
        }
        label
    }

    /// Number of edge-connected pieces of each group.
    fn group_pieces(mesh: &Mesh, groups: &[u32]) -> Vec<usize> {
        let adj = Adjacency::build(mesh);
        let n = groups.iter().max().map_or(0, |&g| g as usize + 1);
        let mut seen = vec![false; groups.len()];
        let mut pieces = vec![0; n];
        for f in 0..groups.len() {
            if seen[f] {
                continue;
            }
            pieces[groups[f] as usize] += 1;
            seen[f] = true;
            let mut stack = vec![f];
            while let Some(g) = stack.pop() {
                for &nb in &adj.face_neighbors[g] {
                    if nb != NO_FACE && !seen[nb as usize] && groups[nb as usize] == groups[f] {
                        seen[nb as usize] = true;
                        stack.push(nb as usize);
                    }
                }
            }
        }
        pieces
    }

    fn bowtie_vertices(mesh: &Mesh) -> usize {
        let adj = Adjacency::build(mesh);
        let vf = VertexFaces::build(mesh);
        (0..mesh.vertex_count() as u32)
            .filter(|&v| {
                let faces = vf.of(v);
                let Some(&first) = faces.first() else { return false };
                let mut seen = vec![first];
                let mut stack = vec![first];
                while let Some(f) = stack.pop() {
                    let t = mesh.triangles[f as usize];
                    for k in 0..3 {
                        let nb = adj.face_neighbors[f as usize][k];
                        if (t[k] == v || t[(k + 1) % 3] == v) && nb != NO_FACE && !seen.contains(&nb) {
                            seen.push(nb);
                            stack.push(nb);
                        }
                    }
                }
                seen.len() != faces.len()
            })
            .count()
    }

    fn euler(mesh: &Mesh) -> i64 {
        let adj = Adjacency::build(mesh);
        let interior = adj.face_neighbors.iter().flatten().filter(|&&n| n != NO_FACE).count() / 2;
        let edges = interior + adj.boundary_edges;
        mesh.vertex_count() as i64 - edges as i64 + mesh.face_count() as i64
    }

    /// Properties every output must have: valid arrays, no degenerate or duplicate face, no new
    /// non-manifold edge or vertex, same Euler characteristic and border count on manifold input.
    fn check(input: &Mesh, out: &Simplified) {
        let m = &out.mesh;
        assert_eq!(m.validate(), Ok(()));
        let mut keys: Vec<[u32; 3]> = m.triangles.iter().map(|t| { let mut k = *t; k.sort_unstable(); k }).collect();
        assert!(keys.iter().all(|k| k[0] != k[1] && k[1] != k[2]), "face with a repeated vertex");
        keys.sort_unstable();
        keys.dedup();
        assert_eq!(keys.len(), m.face_count(), "duplicate faces");
        assert!(m.face_areas.iter().all(|&a| a > 0.0), "degenerate face");
        let (ai, ao) = (Adjacency::build(input), Adjacency::build(m));
        assert!(ao.nonmanifold_edges.len() <= ai.nonmanifold_edges.len());
        assert!(bowtie_vertices(m) <= bowtie_vertices(input));
        if ai.nonmanifold_edges.is_empty() {
            assert_eq!(euler(m), euler(input), "topology changed");
        }
        let used = m.triangles.iter().flatten().collect::<std::collections::HashSet<_>>().len();
        assert_eq!(used, m.vertex_count(), "unused vertices");
        assert!(out.error.is_finite() && out.error >= 0.0);
    }

    fn opts(target_faces: usize) -> SimplifyOptions {
        SimplifyOptions { target_faces, ..SimplifyOptions::default() }
    }

    #[test]
    fn same_face_count_changes_nothing() {
        for m in [icosphere(2), seamed_sphere(2), grid(6), fin()] {
            let out = simplify(&m, None, &opts(m.face_count()));
            assert_eq!(out.mesh, m);
            assert_eq!(out.error, 0.0);
            let groups = patches(&m, 5);
            let out = simplify(&m, Some(&groups), &opts(m.face_count() + 10));
            assert_eq!((out.mesh, out.face_groups), (m, groups));
            assert!(out.group_error.iter().all(|&e| e == 0.0));
        }
    }

    #[test]
    fn sphere_reaches_target_without_flips() {
        let m = noisy_sphere(4, 0.02, 3);
        for target in [m.face_count() / 2, m.face_count() / 10, m.face_count() / 100] {
            let out = simplify(&m, None, &opts(target));
            check(&m, &out);
            assert!(out.mesh.face_count() <= target && out.mesh.face_count() + 2 >= target, "{} for {target}", out.mesh.face_count());
            // No face turned beyond the bound from its input face; none faces inward (no folds).
            let cos_turn = SimplifyOptions::default().max_normal_turn.cos();
            for ((t, n), &f) in out.mesh.triangles.iter().zip(&out.mesh.face_normals).zip(&out.source_faces) {
                assert!(n.dot(m.face_normals[f as usize]) >= cos_turn - 1e-5, "face {f} turned to {n}");
                let c = t.iter().map(|&v| out.mesh.positions[v as usize]).sum::<Vec3>();
                assert!(n.dot(c.normalize()) > 0.0, "face {f} faces inward: {n} at {c}");
            }
            let d = crate::distance::surface_distance(&m, &out.mesh, 20_000, 1);
            assert!(d.max < 0.2 && out.error < 0.2, "{d:?} {}", out.error);
        }
        // A smooth sphere at 512 faces: a polyhedron that fine is about 0.01 from the sphere.
        let smooth = icosphere(4);
        let out = simplify(&smooth, None, &opts(smooth.face_count() / 10));
        let d = crate::distance::surface_distance(&smooth, &out.mesh, 20_000, 1);
        assert!(d.max < 0.03 && d.mean < 0.006, "{d:?}");
    }

    #[test]
    fn borders_stay_in_place() {
        let m = grid(24);
        let out = simplify(&m, None, &opts(m.face_count() / 20));
        check(&m, &out);
        let on_input_border = |p: Vec3| p.x == 0.0 || p.x == 1.0 || p.y == 0.0 || p.y == 1.0;
        let ao = Adjacency::build(&out.mesh);
        let input_positions: std::collections::HashSet<[u32; 3]> = m.positions.iter().map(|p| p.to_array().map(f32::to_bits)).collect();
        for (f, t) in out.mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                if ao.face_neighbors[f][k] == NO_FACE {
                    let (p, q) = (out.mesh.positions[t[k] as usize], out.mesh.positions[t[(k + 1) % 3] as usize]);
                    assert!(on_input_border(p) && input_positions.contains(&p.to_array().map(f32::to_bits)), "border vertex moved to {p}");
                    // Both ends on the same side of the square.
                    assert!(p.x == q.x && (p.x == 0.0 || p.x == 1.0) || p.y == q.y && (p.y == 0.0 || p.y == 1.0), "border edge {p} {q} cuts a corner");
                }
            }
        }
        assert!(out.mesh.face_count() <= m.face_count() / 20);
        // Interior vertices never land on the border line.
        let mut border = std::collections::HashSet::new();
        for (f, t) in out.mesh.triangles.iter().enumerate() {
            for k in (0..3).filter(|&k| ao.face_neighbors[f][k] == NO_FACE) {
                border.extend([t[k], t[(k + 1) % 3]]);
            }
        }
        for v in 0..out.mesh.vertex_count() as u32 {
            if !border.contains(&v) {
                assert!(!on_input_border(out.mesh.positions[v as usize]));
            }
        }
    }

    #[test]
    fn seams_and_material_borders_keep_their_topology() {
        let m = seamed_sphere(4);
        let mat_border_edges = |mesh: &Mesh| {
            let adj = Adjacency::build(mesh);
            let mut count = vec![0u32; mesh.vertex_count()];
            let mut edges = 0;
            for (f, t) in mesh.triangles.iter().enumerate() {
                for k in 0..3 {
                    let nb = adj.face_neighbors[f][k];
                    if nb != NO_FACE && (f as u32) < nb && mesh.face_materials[f] != mesh.face_materials[nb as usize] {
                        edges += 1;
                        count[t[k] as usize] += 1;
                        count[t[(k + 1) % 3] as usize] += 1;
                    }
                }
            }
            (edges, count)
        };
        let out = simplify(&m, None, &opts(m.face_count() / 20));
        check(&m, &out);
        let o = &out.mesh;
        assert!(o.face_count() <= m.face_count() / 10, "only reached {}", o.face_count());
        // The material border is still one closed loop.
        let (edges, count) = mat_border_edges(o);
        assert!(edges >= 3 && count.iter().all(|&c| c == 0 || c == 2), "{edges}");
        let loop_vertices = count.iter().filter(|&&c| c == 2).count();
        assert_eq!(loop_vertices, edges);
        assert!(edges < mat_border_edges(&m).0, "the border was simplified too");
        // Materials: both still present, each an edge-connected region.
        assert_eq!(group_pieces(o, &o.face_materials), vec![1, 1]);
        // Across every interior edge, corners agree except across the UV seam, where u jumps by 1.
        let adj = Adjacency::build(o);
        let mut seam_edges = 0;
        for (f, t) in o.triangles.iter().enumerate() {
            for k in 0..3 {
                let nb = adj.face_neighbors[f][k] as usize;
                if nb == NO_FACE as usize || o.face_materials[f] != o.face_materials[nb] {
                    continue;
                }
                let mut jump = false;
                for v in [t[k], t[(k + 1) % 3]] {
                    let (c0, c1) = (3 * f + (0..3).position(|i| t[i] == v).unwrap(), 3 * nb + (0..3).position(|i| o.triangles[nb][i] == v).unwrap());
                    assert_eq!(o.normals[c0], o.normals[c1]);
                    let d = o.uvs[c0] - o.uvs[c1];
                    assert!(d.y == 0.0 && (d.x == 0.0 || (d.x.abs() - 1.0).abs() < 1e-6), "uv torn: {d}");
                    jump |= d.x != 0.0;
                }
                seam_edges += usize::from(jump);
            }
        }
        assert!(seam_edges > 0, "the UV seam vanished");
        // Interpolated corners still roughly follow the spherical map, away from poles and seam.
        for (c, uv) in o.uvs.iter().enumerate() {
            let p = o.positions[o.triangles[c / 3][c % 3] as usize];
            if p.z.abs() < 0.8 {
                let v = p.z.clamp(-1.0, 1.0).acos() / std::f32::consts::PI;
                assert!((uv.y - v).abs() < 0.05, "uv {uv} at {p}");
            }
        }
    }

    #[test]
    fn non_manifold_fin_is_left_alone() {
        let m = fin();
        let out = simplify(&m, None, &opts(m.face_count() / 10));
        check(&m, &out);
        let ai = Adjacency::build(&m);
        let ao = Adjacency::build(&out.mesh);
        assert_eq!(ao.nonmanifold_edges.len(), 1);
        let ends = |mesh: &Mesh, e: [u32; 2]| e.map(|v| mesh.positions[v as usize]);
        let (mut a, mut b) = (ends(&m, ai.nonmanifold_edges[0]), ends(&out.mesh, ao.nonmanifold_edges[0]));
        a.sort_by(|x, y| x.x.total_cmp(&y.x));
        b.sort_by(|x, y| x.x.total_cmp(&y.x));
        assert_eq!(a, b);
        assert!(out.mesh.face_count() < m.face_count() / 4);
    }

    #[test]
    fn groups_stay_connected_when_simplified_hard() {
        let cases = [(noisy_sphere(4, 0.05, 9), 40), (grid(40), 25), (seamed_sphere(4), 30), (fin(), 6)];
        for (m, k) in cases {
            let groups = patches(&m, k);
            let n_groups = groups.iter().max().map_or(0, |&g| g as usize + 1);
            assert!(group_pieces(&m, &groups).iter().all(|&p| p == 1));
            let out = simplify(&m, Some(&groups), &opts(m.face_count() / 100));
            check(&m, &out);
            assert_eq!(out.face_groups.len(), out.mesh.face_count());
            assert_eq!(out.group_error.len(), n_groups);
            let pieces = group_pieces(&out.mesh, &out.face_groups);
            assert_eq!(pieces.len(), n_groups);
            assert!(pieces.iter().all(|&p| p == 1), "a group split or vanished: {pieces:?}");
            assert!(out.mesh.face_count() < m.face_count() / 3, "{} of {}", out.mesh.face_count(), m.face_count());
            assert!(out.group_error.iter().all(|&e| e.is_finite() && e >= 0.0) && out.group_error.iter().any(|&e| e > 0.0));
        }
    }

    #[test]
    fn max_error_stops_early() {
        let m = noisy_sphere(4, 0.05, 1);
        let free = simplify(&m, None, &opts(0));
        let bounded = simplify(&m, None, &SimplifyOptions { max_error: Some(0.01), ..opts(0) });
        check(&m, &bounded);
        assert!(bounded.error <= 0.01 && free.error > 0.01);
        assert!(bounded.mesh.face_count() > free.mesh.face_count());
    }

    #[test]
    fn deterministic() {
        let m = seamed_sphere(3);
        let groups = patches(&m, 7);
        let a = simplify(&m, Some(&groups), &opts(100));
        let b = simplify(&m, Some(&groups), &opts(100));
        assert_eq!(a, b);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]
        #[test]
        fn random_meshes_keep_invariants(seed in 0u64..1000, levels in 1u32..4, amount in 0.0f32..0.3, k in 1usize..20, ratio in 0.0f64..1.0, open in any::<bool>()) {
            let mut m = noisy_sphere(levels, amount, seed);
            if open {
                // Cut a cap away so the mesh has a border.
                let keep: Vec<usize> = (0..m.face_count()).filter(|&f| m.triangles[f].iter().any(|&v| m.positions[v as usize].z < 0.5)).collect();
                m.triangles = keep.iter().map(|&f| m.triangles[f]).collect();
                m = Mesh { face_materials: Vec::new(), ..m }.clean().expect("finite").0;
            }
            let groups = patches(&m, k);
            let target = (m.face_count() as f64 * ratio) as usize;
            let out = simplify(&m, Some(&groups), &opts(target));
            check(&m, &out);
            let pieces = group_pieces(&out.mesh, &out.face_groups);
            prop_assert!(pieces.iter().all(|&p| p == 1), "{:?}", pieces);
            let plain = simplify(&m, None, &opts(target));
            check(&m, &plain);
        }
    }
}
