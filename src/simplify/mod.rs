//! Quadric-error edge collapse, optionally keeping every group of a face partition a connected,
//! non-empty patch (METHOD.md §4).
//!
//! Garland–Heckbert: each vertex carries a quadric (f64), the area-weighted sum of the squared
//! distances to the planes of its input faces, plus planes perpendicular to the surface through open
//! border and seam edges (weighted by the squared edge length) so those lines keep their shape. A
//! collapse is ranked by the larger of its two ends' mean squared distances at the new position
//! (each end's quadric over its own face area, so that a small spike is not hidden by a large
//! neighbour).
//!
//! Collapses run cheapest first, in passes over a sorted queue with lazy invalidation: a collapse
//! bumps the version counters of its two vertices, which makes their other queued edges stale, and
//! the survivor's edges are ranked again for the next pass (see `State::run`). Data are flat arrays:
//! per-vertex records and quadrics, vertex ids per face, and per-vertex face lists in one arena.
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
//! Topology (opt-in, without groups): a noisy scan has many tiny handles and components, each of
//! which keeps a dozen faces that no collapse may remove. When the target is not reached, the
//! simplification runs again, and where a collapse is blocked by the link condition alone the
//! mesh is cut along the triangle of edges that blocks it (a handle or neck) and both sides are
//! capped, or a closed tetrahedron is dropped: genus and components change, manifoldness not.
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

use crate::mesh::{Mesh, VertexFaces, NO_FACE};
use glam::{DVec3, Vec2, Vec3};
use std::cmp::Reverse;
use rayon::prelude::*;
use std::collections::BinaryHeap;

/// How far to simplify and which collapses to allow.
///
/// The default bounds on face turn and shape were chosen by measurement (`cargo bench --bench
/// simplify`): 60° and 0.05 left the CT head at 3% of its faces with 31% more mean distance to the
/// input than 75° and 0.02, and more than meshoptimizer's, while the bunny hardly changed.
#[derive(Clone, Debug, PartialEq)]
pub struct SimplifyOptions {
    /// Stop once at most this many faces remain, as far as the rules allow. Default 0: only
    /// `max_error` (or running out of legal collapses) stops.
    pub target_faces: usize,
    /// Make no collapse whose error estimate (model units) exceeds this. Default none.
    pub max_error: Option<f32>,
    /// Radians. A collapse that leaves any face normal turned by more than this from that face's
    /// normal in the input is rejected. Measured from the input, turns cannot add up over many
    /// collapses into folds. Default 75°.
    pub max_normal_turn: f32,
    /// Reject a collapse that leaves a face with quality below this and worse than before. Quality
    /// is 4√3·area / (sum of squared edge lengths): 1 for an equilateral triangle, 0 for a
    /// degenerate one. Default 0.02 (a triangle about 90× longer than wide).
    pub min_face_quality: f32,
    /// Weight of the border planes (perpendicular to the face through each open-border edge,
    /// weighted by the squared edge length) against the area-weighted face planes. Default 10:
    /// heavy, so border collapses come late and only where the border is straight.
    pub border_weight: f32,
    /// The same for seam edges (attribute, material and group borders). Default 1.
    pub seam_weight: f32,
    /// When the face target cannot be reached otherwise (not when only `max_error` bounds the
    /// simplification, with `target_faces` 0), simplify again allowing changes of topology that
    /// keep the mesh manifold wherever the link condition blocks a collapse: a handle or neck
    /// whose cross-section is a triangle of edges that is not a face is cut there and both sides
    /// capped, and a closed tetrahedron is dropped, each only if it moves the surface by less
    /// than `max_error`; collapses may also remove a component's last faces. The copies of cut vertices come after the others in the output; they
    /// start where their originals are, and where no later collapse moves them, a reader that
    /// welds vertices by position sees the two caps as one doubled face. Without it a mesh of many handles and components (a noisy scan)
    /// stops at a few faces per handle and component. Ignored with groups (a cap would join or
    /// split groups). Default false.
    pub topology: bool,
}

impl Default for SimplifyOptions {
    fn default() -> Self {
        SimplifyOptions {
            target_faces: 0,
            max_error: None,
            max_normal_turn: 75f32.to_radians(),
            min_face_quality: 0.02,
            border_weight: 10.0,
            seam_weight: 1.0,
            topology: false,
        }
    }
}

/// A simplified mesh and how far it may be from its input.
#[derive(Clone, Debug, PartialEq)]
pub struct Simplified {
    /// Compacted (no unused vertices, which keep their input order), faces in input order,
    /// face normals and areas recomputed.
    pub mesh: Mesh,
    /// Input face of each output face: output faces are the surviving input faces, in order,
    /// then the caps of topology changes, each with the input face it took its material from.
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
/// Error estimates are in model units. A collapse's error is the larger of its two ends'
/// sqrt(quadric cost / accumulated weight): the weighted RMS distance of the new position to the
/// planes (face, border and seam planes) merged into each end. A vertex's error is its own such
/// distance, or the largest error of the collapses merged into it if larger. These are estimates,
/// not bounds on the Hausdorff distance to the input.
///
/// # Panics
/// If `groups` is given with a length other than the face count.
pub fn simplify(mesh: &Mesh, groups: Option<&[u32]>, opts: &SimplifyOptions) -> Simplified {
    if let Some(g) = groups {
        assert_eq!(g.len(), mesh.triangles.len(), "simplify: one group label per face");
    }
    let mut s = State::new(mesh, groups);
    if mesh.triangles.len() > opts.target_faces {
        s.init(opts, false);
        s.run(opts);
        let face_target = opts.target_faces > 0 || opts.max_error.is_none();
        if opts.topology && face_target && s.faces_left > opts.target_faces && groups.is_none() {
            s = State::new(mesh, groups);
            s.init(opts, true);
            s.run(opts);
        }
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
/// 96 bytes aligned to 32, so that a vertex's quadric spans two cache lines, never three.
#[derive(Clone, Copy, Debug, Default)]
#[repr(align(32))]
struct Quadric {
    /// xx, xy, xz, yy, yz, zz.
    a: [f64; 6],
    b: [f64; 3],
    c: f64,
    /// Sum of the weights of all planes: Q(p) / w is a mean squared distance (the error estimate).
    w: f64,
    /// Sum of the face areas only: Q(p) / area ranks collapses, so that heavily weighted border
    /// and seam planes make those collapses come late.
    area: f64,
    /// Not a sum (`add` leaves it): in a vertex's quadric, the largest squared error estimate of
    /// the collapses merged into it, kept here because every read of it also reads the quadric.
    err_sq: f64,
}

impl Quadric {
    /// weight · (distance to the plane through `p` with unit normal `n`)².
    fn plane(n: DVec3, p: DVec3, weight: f64) -> Quadric {
        Quadric::with_offset(n, -n.dot(p), weight)
    }

    /// `plane` given the plane's offset `d = -n·p`.
    fn with_offset(n: DVec3, d: f64, weight: f64) -> Quadric {
        let wn = n * weight;
        Quadric {
            a: [wn.x * n.x, wn.x * n.y, wn.x * n.z, wn.y * n.y, wn.y * n.z, wn.z * n.z],
            b: [wn.x * d, wn.y * d, wn.z * d],
            c: weight * d * d,
            w: weight,
            area: 0.0,
            err_sq: 0.0,
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
        // Also when the trace is NaN.
        if trace.is_nan() || trace <= 0.0 || det <= 1e-9 * trace * trace * trace {
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
    /// A position representable in f32, where the vertex is stored.
    pos: DVec3,
    /// Free–free collapse: attributes interpolated from `remove` (0) to `keep` (1) at this parameter.
    lerp: Option<f64>,
    /// Ordering key: the larger of the two ends' quadric cost / face area.
    cost: f64,
    /// Squared error estimate: the larger of the two ends' quadric cost / total weight, and of the
    /// errors already merged into them.
    error_sq: f64,
}

/// Which collapses of an edge the rules allow.
#[derive(Clone, Copy, Debug)]
enum Allowed {
    Nothing,
    /// Both ends free: anywhere, attributes interpolated.
    Anywhere,
    /// Onto one end or the other.
    Ends { u_into_v: bool, v_into_u: bool },
}

/// The legal candidates of an edge, cheapest first.
#[derive(Clone, Copy, Debug)]
struct Plan {
    e: EdgeFaces,
    c: [Candidate; 4],
    n: usize,
}

impl Plan {
    const EMPTY: Plan = Plan {
        e: EdgeFaces { f: [NO_FACE; 2], x: [NO_FACE; 2], n: 0 },
        c: [Candidate { remove: 0, keep: 0, pos: DVec3::ZERO, lerp: None, cost: f64::INFINITY, error_sq: f64::INFINITY }; 4],
        n: 0,
    };
}

/// A queued collapse: `key bits | u | v | versions` in one integer. A non-negative f32 keeps its
/// order in its bits, so entries compare as integers (ties by vertex ids). `versions` is the sum of
/// the two vertex versions when queued: versions only grow, so the entry is current exactly when
/// that sum is unchanged (lazy invalidation).
fn entry(key: f64, [u, v, versions]: [u32; 3]) -> u128 {
    let bits = if key > 0.0 { (key as f32).to_bits() } else { 0 };
    u128::from(bits) << 96 | u128::from(u) << 64 | u128::from(v) << 32 | u128::from(versions)
}

fn entry_key(e: u128) -> f32 {
    f32::from_bits((e >> 96) as u32)
}

fn entry_edge(e: u128) -> [u32; 3] {
    [(e >> 64) as u32, (e >> 32) as u32, e as u32]
}

/// The small per-vertex data the inner loops touch (its quadric is kept apart), 32 bytes aligned
/// to 32 so that a record spans one cache line.
#[derive(Clone, Copy, Debug)]
#[repr(align(32))]
struct Vertex {
    pos: Vec3,
    /// Its faces: `face_lists[start..start + len]`.
    start: u32,
    len: u32,
    /// Cached classification, `Unknown` when it must be recomputed.
    kind: Kind,
    /// Never collapsed: non-manifold, unused or removed.
    locked: bool,
}

/// A face: its vertices and what the checks need with them, in one 32-byte record so that a
/// face costs one cache line at most.
#[derive(Clone, Copy, Debug)]
#[repr(align(32))]
struct Face {
    /// Its vertices, `DEAD` once collapsed away.
    v: [u32; 3],
    group: u32,
    /// Unit normal in the input: turns are measured from it, so they cannot add up.
    normal: Vec3,
}

/// A face around an end of an edge being checked: its corner positions, which corner moves, and
/// its input normal.
#[derive(Clone, Copy, Debug)]
struct Around {
    p: [DVec3; 3],
    moved: usize,
    normal: Vec3,
}

const DEAD: u32 = u32::MAX;

/// A hint to start fetching `x` into the cache, for data the queue will soon need; none off x86_64.
#[inline(always)]
fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is only a hint: it never faults, reads nothing into the program and
    // writes nothing; the pointer comes from a live reference anyway.
    #[allow(unused_unsafe)]
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>((x as *const T).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

struct State {
    verts: Vec<Vertex>,
    quadrics: Vec<Quadric>,
    faces: Vec<Face>,
    /// Per corner: the first corner of the vertex with the same attributes, material and group
    /// (kept consistent as corners move), so corners of one vertex compare by one integer.
    wedges: Vec<[u32; 3]>,
    /// Per vertex, bumped whenever it changes; invalidates its queue entries. Kept apart from
    /// `verts` so that checking an entry touches a small array.
    version: Vec<u32>,
    /// The per-vertex face lists; a list that changes is appended, the arena compacted now and then.
    face_lists: Vec<u32>,
    compact_at: usize,
    face_materials: Vec<u32>,
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
    colors: Vec<[u8; 4]>,
    /// Entries of the current pass (see `entry`), in a vector while it is filled.
    entries: Vec<u128>,
    faces_left: usize,
    error_sq: f64,
    cos_turn: f64,
    min_quality: f64,
    scratch_edges: Vec<u64>,
    scratch_r: Vec<u32>,
    scratch_k: Vec<u32>,
    /// Topology changes are made (see [`SimplifyOptions::topology`]); never with groups.
    topology: bool,
    grouped: bool,
    /// Faces of the input; faces past them are caps.
    input_faces: usize,
    /// Per cap, the input face whose attributes it took.
    cap_source: Vec<u32>,
}

impl State {
    fn new(mesh: &Mesh, groups: Option<&[u32]>) -> State {
        let nf = mesh.triangles.len();
        let lists = VertexFaces::build(mesh);
        let verts = mesh
            .positions
            .iter()
            .zip(lists.offsets.windows(2))
            .map(|(&pos, w)| Vertex {
                pos,
                start: w[0],
                len: w[1] - w[0],
                kind: Kind::Unknown,
                locked: false,
            })
            .collect();
        let faces = mesh.triangles.iter().enumerate().map(|(f, &v)| Face { v, group: groups.map_or(0, |g| g[f]), normal: Vec3::ZERO }).collect();
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
            grouped: groups.is_some(),
            input_faces: nf,
            cap_source: Vec::new(),
        }
    }

    fn faces_of(&self, v: u32) -> &[u32] {
        let x = &self.verts[v as usize];
        &self.face_lists[x.start as usize..(x.start + x.len) as usize]
    }

    /// The i-th face of v (for loops that mutate the state while walking v's faces).
    fn face_of(&self, v: u32, i: usize) -> u32 {
        self.face_lists[self.verts[v as usize].start as usize + i]
    }

    fn tri(&self, f: u32) -> [u32; 3] {
        self.faces[f as usize].v
    }

    fn pos(&self, v: u32) -> DVec3 {
        self.verts[v as usize].pos.as_dvec3()
    }

    /// Corner index of vertex `v` in face `f`.
    fn corner(&self, f: u32, v: u32) -> usize {
        let t = self.tri(f);
        3 * f as usize + if t[0] == v { 0 } else if t[1] == v { 1 } else { 2 }
    }

    fn wedge(&self, c: usize) -> u32 {
        self.wedges[c / 3][c % 3]
    }

    /// Wedge ids, face planes, border and seam planes, locks and kinds. Locks unused vertices,
    /// vertices on non-manifold edges and bow-tie vertices (faces around them not one fan).
    /// `topology`: make topology changes where they unblock a collapse.
    ///
    /// Per-vertex work runs in parallel; each vertex gathers its face planes in face order and the
    /// few border and seam planes are added afterwards in vertex order, so every quadric is summed
    /// in the same order as a sequential scatter would.
    fn init(&mut self, opts: &SimplifyOptions, topology: bool) {
        self.cos_turn = f64::from(opts.max_normal_turn).cos();
        self.topology = topology && !self.grouped;
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
    fn classify(&self, v: u32, opts: &SimplifyOptions, around: &mut Vec<u64>, parent: &mut Vec<u32>, events: &mut Vec<(u32, u32, u32, f32)>) -> (bool, Kind) {
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
            let i = if t[0] == v { 0 } else if t[1] == v { 1 } else { 2 };
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
    fn same_corner(&self, c0: usize, c1: usize) -> bool {
        self.wedge(c0) == self.wedge(c1)
    }

    /// Whether the edge (a, b) with faces `e` is a feature edge.
    fn is_feature(&self, a: u32, b: u32, e: &EdgeFaces) -> bool {
        e.n == 1
            || !self.same_corner(self.corner(e.f[0], a), self.corner(e.f[1], a))
            || !self.same_corner(self.corner(e.f[0], b), self.corner(e.f[1], b))
    }

    fn kind(&mut self, v: u32) -> Kind {
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
    fn compute_kind(&self, v: u32, edges: &mut Vec<u64>) -> Kind {
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
            0 if manifold => Kind::Free,
            2 if manifold => Kind::Line,
            _ => Kind::Corner,
        }
    }

    fn edge_faces(&self, u: u32, v: u32) -> Option<EdgeFaces> {
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

    /// Which collapses of edge (u, v) with faces `e` the rules allow.
    fn allowed(&mut self, u: u32, v: u32, e: &EdgeFaces) -> Allowed {
        if self.verts[u as usize].locked || self.verts[v as usize].locked {
            return Allowed::Nothing;
        }
        let (ku, kv) = (self.kind(u), self.kind(v));
        self.allowed_kinds(u, v, e, ku, kv)
    }

    /// `allowed` for two unlocked ends of kinds `ku` and `kv`.
    fn allowed_kinds(&self, u: u32, v: u32, e: &EdgeFaces, ku: Kind, kv: Kind) -> Allowed {
        if ku == Kind::Free && kv == Kind::Free {
            return Allowed::Anywhere;
        }
        let feature = self.is_feature(u, v, e);
        let removable = |kr: Kind, k: u32| match kr {
            Kind::Free => true,
            Kind::Line => feature && (e.n == 1 || !self.same_corner(self.corner(e.f[0], k), self.corner(e.f[1], k))),
            _ => false,
        };
        match (removable(ku, v), removable(kv, u)) {
            (false, false) => Allowed::Nothing,
            (u_into_v, v_into_u) => Allowed::Ends { u_into_v, v_into_u },
        }
    }

    /// The quadric optimum of a free–free collapse, when well conditioned and not farther from
    /// the edge's midpoint than the edge is long, rounded to f32.
    fn optimum(q: &Quadric, pu: DVec3, pv: DVec3) -> Option<DVec3> {
        let mid = 0.5 * (pu + pv);
        q.optimum().filter(|p| (*p - mid).length_squared() <= (pv - pu).length_squared()).map(|p| p.as_vec3().as_dvec3())
    }

    /// The ordering key of the best collapse of edge (u, v) the rules allow, to queue it: at the
    /// optimum of the summed quadric when there is one, else the cheapest of ends and midpoint.
    /// Both ends are unlocked, of kinds `ku` and `kv`.
    fn key(&self, u: u32, v: u32, e: &EdgeFaces, ku: Kind, kv: Kind) -> Option<f64> {
        let allowed = self.allowed_kinds(u, v, e, ku, kv);
        let (pu, pv) = (self.pos(u), self.pos(v));
        let (qu, qv) = (&self.quadrics[u as usize], &self.quadrics[v as usize]);
        let cost = |p: DVec3| (qu.eval(p) / qu.area.max(f64::MIN_POSITIVE)).max(qv.eval(p) / qv.area.max(f64::MIN_POSITIVE));
        match allowed {
            Allowed::Nothing => None,
            Allowed::Anywhere => {
                let mut q = *qu;
                q.add(qv);
                Some(match State::optimum(&q, pu, pv) {
                    Some(p) => cost(p),
                    None => cost(pu).min(cost(pv)).min(cost((0.5 * (pu + pv)).as_vec3().as_dvec3())),
                })
            }
            Allowed::Ends { u_into_v, v_into_u } => {
                let at = |ok: bool, p: DVec3| if ok { cost(p) } else { f64::INFINITY };
                Some(at(u_into_v, pv).min(at(v_into_u, pu)))
            }
        }
    }

    /// Fill `plan` with the legal ways to collapse edge (u, v) with faces `e`, cheapest first;
    /// false if there is none.
    fn plan(&mut self, u: u32, v: u32, e: EdgeFaces, plan: &mut Plan) -> bool {
        plan.e = e;
        plan.n = 0;
        let allowed = self.allowed(u, v, &e);
        let mut q = self.quadrics[u as usize];
        q.add(&self.quadrics[v as usize]);
        let (pu, pv) = (self.pos(u), self.pos(v));
        let (qu, qv) = (&self.quadrics[u as usize], &self.quadrics[v as usize]);
        let (eu, ev) = (qu.err_sq, qv.err_sq);
        let mut add = |remove: u32, keep: u32, pos: DVec3, lerp: Option<f64>| {
            let (cu, cv) = (qu.eval(pos), qv.eval(pos));
            let cost = (cu / qu.area.max(f64::MIN_POSITIVE)).max(cv / qv.area.max(f64::MIN_POSITIVE));
            let error_sq = (cu / qu.w.max(f64::MIN_POSITIVE)).max(cv / qv.w.max(f64::MIN_POSITIVE)).max(eu).max(ev);
            plan.c[plan.n] = Candidate { remove, keep, pos, lerp, cost, error_sq };
            plan.n += 1;
        };
        match allowed {
            Allowed::Nothing => return false,
            Allowed::Anywhere => {
                let d = pv - pu;
                let len2 = d.length_squared();
                let mut at = |p: DVec3| {
                    let t = if len2 > 0.0 { ((p - pu).dot(d) / len2).clamp(0.0, 1.0) } else { 0.5 };
                    add(u, v, p, Some(t));
                };
                if let Some(p) = State::optimum(&q, pu, pv) {
                    at(p);
                }
                at(pu);
                at(pv);
                at((0.5 * (pu + pv)).as_vec3().as_dvec3());
            }
            Allowed::Ends { u_into_v, v_into_u } => {
                if u_into_v {
                    add(u, v, pv, None);
                }
                if v_into_u {
                    add(v, u, pu, None);
                }
            }
        }
        plan.c[..plan.n].sort_unstable_by(|a, b| a.cost.total_cmp(&b.cost));
        true
    }

    /// Start fetching what ranking an edge needs of its end `w`: record, version and quadric.
    fn prefetch_vertex(&self, w: u32) {
        let w = w as usize;
        prefetch(&self.verts[w]);
        prefetch(&self.version[w]);
        let q = &self.quadrics[w];
        prefetch(&q.a[0]);
        prefetch(&q.area);
    }

    /// Start fetching what planning a queued edge needs of its ends.
    fn prefetch_ends(&self, e: u128) {
        let [u, v, _] = entry_edge(e);
        for w in [u, v] {
            self.prefetch_vertex(w);
        }
    }

    /// The ends of a queued edge, if the entry is current (neither end changed since it was
    /// queued).
    fn current_ends(&self, e: u128) -> Option<[u32; 2]> {
        let [u, v, versions] = entry_edge(e);
        (self.versions(u, v) == versions).then_some([u, v])
    }

    /// Start fetching the face lists of a current queued edge's ends (records fetched earlier).
    fn prefetch_lists(&self, e: u128) {
        for w in self.current_ends(e).into_iter().flatten() {
            self.prefetch_list(w);
        }
    }

    fn prefetch_list(&self, w: u32) {
        if let Some(f) = self.face_lists.get(self.verts[w as usize].start as usize) {
            prefetch(f);
        }
    }

    /// Start fetching the faces of a current queued edge's ends (lists fetched earlier).
    fn prefetch_faces(&self, e: u128) {
        for w in self.current_ends(e).into_iter().flatten() {
            self.prefetch_faces_of(w);
        }
    }

    /// Start fetching what checking and collapsing a current queued edge needs of the faces
    /// around it (faces fetched earlier): their vertices' records and their corners.
    fn prefetch_around(&self, e: u128) {
        for w in self.current_ends(e).into_iter().flatten() {
            for &f in self.faces_of(w) {
                let f = f as usize;
                for y in self.faces[f].v {
                    if let Some(x) = self.verts.get(y as usize) {
                        prefetch(x);
                    }
                }
                prefetch(&self.wedges[f]);
                if let Some(n) = self.normals.get(3 * f) {
                    prefetch(n);
                }
                if let Some(uv) = self.uvs.get(3 * f) {
                    prefetch(uv);
                }
            }
        }
    }

    /// Start fetching the face lists of the vertices opposite a current queued edge, which its
    /// collapse edits (their records fetched earlier).
    fn prefetch_opposite(&self, e: u128) {
        if let Some([u, v]) = self.current_ends(e) {
            for &f in self.faces_of(u) {
                let t = self.tri(f);
                if t.contains(&v) {
                    self.prefetch_list(t[0] ^ t[1] ^ t[2] ^ u ^ v);
                }
            }
        }
    }

    fn prefetch_faces_of(&self, w: u32) {
        for &f in self.faces_of(w) {
            prefetch(&self.faces[f as usize]);
        }
    }

    fn versions(&self, u: u32, v: u32) -> u32 {
        self.version[u as usize].wrapping_add(self.version[v as usize])
    }

    /// The edges around `v` with their faces and opposite vertices, for ranking: each face's edge
    /// from v to its next vertex is paired with the face whose previous vertex that is. Exact on
    /// consistently oriented manifold fans; elsewhere an edge may be listed with one face only,
    /// which only affects its rank (collapses re-derive their faces).
    fn edge_fans(&self, v: u32, out: &mut Vec<(u32, EdgeFaces)>, ends: &mut Vec<(u32, u32, u32)>) {
        out.clear();
        ends.clear();
        for &f in self.faces_of(v) {
            let t = self.tri(f);
            let i = if t[0] == v { 0 } else if t[1] == v { 1 } else { 2 };
            ends.push((t[(i + 1) % 3], t[(i + 2) % 3], f));
        }
        for &(next, prev, f) in ends.iter() {
            match ends.iter().find(|g| g.1 == next) {
                Some(&(g_next, _, g)) => out.push((next, EdgeFaces { f: [f, g], x: [prev, g_next], n: 2 })),
                None => out.push((next, EdgeFaces { f: [f, NO_FACE], x: [prev, NO_FACE], n: 1 })),
            }
            if !ends.iter().any(|g| g.0 == prev) {
                out.push((prev, EdgeFaces { f: [f, NO_FACE], x: [next, NO_FACE], n: 1 }));
            }
        }
    }

    /// Queue the edges of the vertices `vs`, ranked in parallel: for each v, the edges (v, y)
    /// with y above v or, given `changed`, with y not changed (a changed y queues its own), so
    /// every edge once. Ends of unknown kind get it computed and cached, as ranking the edges one
    /// by one would: ranking changes nothing else, so the order of ranking does not matter.
    fn rank(&mut self, vs: &[u32], changed: Option<&[bool]>) {
        let this = &*self;
        // Per chunk: its entries, and the kinds it found.
        type Ranked = (Vec<u128>, Vec<(u32, Kind)>);
        let ranked: Vec<Ranked> = vs
            .par_chunks(256)
            .map_init(
                || (Vec::new(), Vec::new(), Vec::new()),
                |(fans, ends, edges), chunk| {
                    let (mut out, mut found) = (Vec::new(), Vec::<(u32, Kind)>::new());
                    let mut kind = |w: u32| match this.verts[w as usize].kind {
                        Kind::Unknown => match found.iter().find(|f| f.0 == w) {
                            Some(&(_, k)) => k,
                            None => {
                                let k = this.compute_kind(w, edges);
                                found.push((w, k));
                                k
                            }
                        },
                        k => k,
                    };
                    for (i, &v) in chunk.iter().enumerate() {
                        if let Some(&w) = chunk.get(i + 8) {
                            prefetch(&this.verts[w as usize]);
                        }
                        if let Some(&w) = chunk.get(i + 6) {
                            this.prefetch_list(w);
                        }
                        if let Some(&w) = chunk.get(i + 4) {
                            this.prefetch_faces_of(w);
                        }
                        if let Some(&w) = chunk.get(i + 2) {
                            for &f in this.faces_of(w) {
                                for y in this.tri(f) {
                                    this.prefetch_vertex(y);
                                }
                            }
                        }
                        if this.verts[v as usize].locked {
                            continue;
                        }
                        this.edge_fans(v, fans, ends);
                        for &(y, e) in fans.iter() {
                            if y < v && changed.is_none_or(|c| c[y as usize]) || this.verts[y as usize].locked {
                                continue;
                            }
                            let (kv, ky) = (kind(v), kind(y));
                            if let Some(key) = this.key(v, y, &e, kv, ky) {
                                out.push(entry(key, [v, y, this.versions(v, y)]));
                            }
                        }
                    }
                    (out, found)
                },
            )
            .collect();
        for (out, found) in ranked {
            self.entries.extend_from_slice(&out);
            for (w, k) in found {
                self.verts[w as usize].kind = k;
            }
        }
    }

    /// Passes of collapses, cheapest first, until the target, the error limit, or no legal
    /// collapse is left. Each pass sorts the queued edges (in parallel) and takes them in order,
    /// merged with a small heap of the edges it re-ranks upwards; a collapse makes the
    /// entries of its two vertices stale, and the edges of the survivor are ranked again for the
    /// next pass, together with the entries the pass did not reach. A pass ends once its keys
    /// exceed 1.5× the key of the edge that would reach the target if every collapse succeeded
    /// (after at least a sixth of that), so that collapses stay close to cheapest-first order.
    /// An edge found illegal is tried again in the next pass only if a collapse touched its ends
    /// or their neighbours; otherwise it waits until the queue runs dry, and is then tried once
    /// more.
    ///
    /// Measured alternatives (CT head at 10%): ranking a survivor's edges right after its
    /// collapse, sequentially while its data is in cache, was slower than this parallel
    /// ranking after the pass (pass 1: 182 ms against 122 + 27 ms), and slower still when those
    /// edges joined the current pass through the heap (306 ms); a 3× window instead of 1.5×
    /// made the bunny's Hausdorff distance up to 25% worse for at most 10% less time. Changing
    /// which failed edges are retried when is not neutral either: retrying blocked edges as soon
    /// as a collapse touches them, or leaving link-condition failures to the final retry, made
    /// the CT head's mean distance at 1% 4-7% worse (the latter also the bunny's Hausdorff at 1%
    /// 7% worse); taking a pass's edges in vertex order within octaves of key did not help.
    fn run(&mut self, opts: &SimplifyOptions) {
        let limit = opts.max_error.map_or(f64::INFINITY, |e| f64::from(e).powi(2));
        let mut changed = vec![false; self.verts.len()];
        let mut touched = vec![0u32; self.verts.len()];
        let (mut survivors, mut retry, mut blocked) = (Vec::new(), Vec::new(), Vec::new());
        let mut plan = Plan::EMPTY;
        let mut unblocked = Vec::new();
        let (mut around_u, mut around_v, mut link) = (Vec::new(), Vec::new(), Vec::new());
        let mut revived = false;
        self.entries.clear();
        let all: Vec<u32> = (0..self.verts.len() as u32).filter(|&v| !self.verts[v as usize].locked).collect();
        self.rank(&all, None);
        for pass in 1u32.. {
            if self.faces_left <= opts.target_faces {
                return;
            }
            if self.entries.is_empty() {
                if revived || blocked.is_empty() {
                    return;
                }
                revived = true;
                self.entries.append(&mut blocked);
            }
            let goal = self.faces_left - opts.target_faces;
            let nth = (goal / 2).min(self.entries.len() - 1);
            let goal_key = 1.5 * entry_key(*self.entries.select_nth_unstable(nth).1);
            // Sort only the entries the pass will likely reach; the rest joins if it gets there.
            let mut split = nth + 1;
            for j in nth + 1..self.entries.len() {
                if entry_key(self.entries[j]) <= goal_key {
                    self.entries.swap(split, j);
                    split += 1;
                }
            }
            let mut rest = self.entries.split_off(split);
            // The queue: `sorted[next..]` merged with a small heap of re-ranked edges.
            let mut sorted = std::mem::take(&mut self.entries);
            sorted.par_sort_unstable();
            let mut next = 0;
            let mut pushed = BinaryHeap::new();
            let before = self.faces_left;
            loop {
                let e = match (sorted.get(next), pushed.peek()) {
                    (Some(&a), Some(&Reverse(b))) if b < a => pushed.pop().map_or(b, |r| r.0),
                    (Some(&a), _) => {
                        // Each step fetches what the next needs, for entries ever closer.
                        if let Some(&e) = sorted.get(next + 12) {
                            self.prefetch_ends(e);
                        }
                        if let Some(&e) = sorted.get(next + 8) {
                            self.prefetch_lists(e);
                        }
                        if let Some(&e) = sorted.get(next + 5) {
                            self.prefetch_faces(e);
                        }
                        if let Some(&e) = sorted.get(next + 3) {
                            self.prefetch_around(e);
                        }
                        if let Some(&e) = sorted.get(next + 1) {
                            self.prefetch_opposite(e);
                        }
                        next += 1;
                        a
                    }
                    (None, Some(&Reverse(b))) => pushed.pop().map_or(b, |r| r.0),
                    (None, None) if rest.is_empty() => break,
                    (None, None) => {
                        sorted = std::mem::take(&mut rest);
                        sorted.par_sort_unstable();
                        next = 0;
                        continue;
                    }
                };
                if self.faces_left <= opts.target_faces {
                    return;
                }
                if entry_key(e) > goal_key && 6 * before.saturating_sub(self.faces_left) > goal {
                    pushed.push(Reverse(e));
                    break;
                }
                let Some([u, v]) = self.current_ends(e) else { continue };
                let Some(edge) = self.edge_faces(u, v) else { continue };
                if !self.plan(u, v, edge, &mut plan) {
                    continue;
                }
                let within = plan.c[..plan.n].iter().any(|c| c.error_sq <= limit);
                let topology_ok = within && self.topology_ok(u, v, &plan.e, &mut link);
                let found = if topology_ok {
                    self.gather(u, &plan.e, &mut around_u);
                    self.gather(v, &plan.e, &mut around_v);
                    plan.c[..plan.n].iter().find(|c| c.error_sq <= limit && self.shapes_ok(u, c, &around_u, &around_v))
                } else {
                    None
                };
                match found {
                    // Cheaper candidates were illegal: rank the edge by the legal one.
                    Some(&c) if c.cost as f32 > entry_key(e) => pushed.push(Reverse(entry(c.cost, entry_edge(e)))),
                    Some(&c) => {
                        self.collapse(&plan.e, c);
                        if !std::mem::replace(&mut changed[c.keep as usize], true) {
                            survivors.push(c.keep);
                        }
                        for &f in self.faces_of(c.keep) {
                            for y in self.tri(f) {
                                touched[y as usize] = pass;
                            }
                        }
                    }
                    None if self.topology && within && !topology_ok && self.unblock(u, v, &plan.e, limit, &mut unblocked) => {
                        changed.resize(self.verts.len(), false);
                        touched.resize(self.verts.len(), 0);
                        for &w in &unblocked {
                            if !std::mem::replace(&mut changed[w as usize], true) {
                                survivors.push(w);
                            }
                            touched[w as usize] = pass;
                        }
                        if !self.verts[u as usize].locked {
                            pushed.push(Reverse(entry(f64::from(entry_key(e)), [u, v, self.versions(u, v)])));
                        }
                    }
                    None => retry.push(e),
                }
            }
            if self.faces_left < before {
                revived = false;
            }
            sorted.drain(..next);
            let mut entries = sorted;
            entries.extend(pushed.into_iter().map(|r| r.0));
            entries.append(&mut rest);
            for e in retry.drain(..) {
                let [u, v, _] = entry_edge(e);
                if touched[u as usize] == pass || touched[v as usize] == pass {
                    entries.push(e);
                } else {
                    blocked.push(e);
                }
            }
            let current = |&e: &u128| self.current_ends(e).is_some();
            entries.retain(current);
            blocked.retain(current);
            self.entries = entries;
            // In id order, neighbouring survivors share cache lines.
            survivors.sort_unstable();
            self.rank(&survivors, Some(&changed));
            for k in survivors.drain(..) {
                changed[k as usize] = false;
            }
        }
    }

    /// Link condition and group survival for collapsing edge (u, v) with faces `e`. Both are
    /// symmetric in the two ends, so they hold for every candidate of the edge or for none.
    fn topology_ok(&self, u: u32, v: u32, e: &EdgeFaces, around: &mut Vec<u32>) -> bool {
        let (x0, x1) = (e.x[0], if e.n == 2 { e.x[1] } else { e.x[0] });
        // Link condition: the common neighbours of u and v are exactly the opposite vertices.
        around.clear();
        for &f in self.faces_of(u) {
            around.extend(self.tri(f));
        }
        let mut seen = [false; 2];
        for &f in self.faces_of(v) {
            for y in self.tri(f) {
                if y != v && y != u && around.contains(&y) {
                    if y != x0 && y != x1 {
                        return false;
                    }
                    seen[usize::from(y != x0)] = true;
                }
            }
        }
        if usize::from(seen[0]) + usize::from(seen[1]) != e.n {
            return false;
        }
        if e.n == 2 {
            let spans = |w: u32| self.faces_of(w).iter().any(|&f| !e.f.contains(&f) && self.tri(f).contains(&x0) && self.tri(f).contains(&x1));
            if spans(u) && spans(v) {
                return false;
            }
        }
        // Group survival for collapses that remove faces of two groups (or one border face).
        // Without groups it keeps components from vanishing, which topology changes allow.
        if self.topology {
            return true;
        }
        for i in 0..e.n {
            let (f, other) = (e.f[i], if e.n == 2 { e.f[1 - i] } else { NO_FACE });
            let g = self.faces[f as usize].group;
            if other != NO_FACE && self.faces[other as usize].group == g {
                continue;
            }
            let kept = |w: u32| {
                self.faces_of(w).iter().any(|&h| h != f && h != other && self.faces[h as usize].group == g && self.tri(h).contains(&e.x[i]))
            };
            if !kept(u) && !kept(v) {
                return false;
            }
        }
        true
    }

    /// The faces around `w` other than the edge's faces `e`, with their corner positions, for
    /// `shape_ok` of every candidate of the edge.
    fn gather(&self, w: u32, e: &EdgeFaces, out: &mut Vec<Around>) {
        out.clear();
        for &f in self.faces_of(w) {
            if !e.f.contains(&f) {
                let t = self.tri(f);
                let moved = if t[0] == w { 0 } else if t[1] == w { 1 } else { 2 };
                out.push(Around { p: t.map(|y| self.pos(y)), moved, normal: self.faces[f as usize].normal });
            }
        }
    }

    /// Face shape for one candidate of the edge (u, v) whose faces around u and v, other than
    /// the edge's own, are `around_u` and `around_v`: no flip beyond the bound, no degenerate or
    /// new sliver face.
    fn shapes_ok(&self, u: u32, c: &Candidate, around_u: &[Around], around_v: &[Around]) -> bool {
        let (at_r, at_k) = if c.remove == u { (around_u, around_v) } else { (around_v, around_u) };
        if !at_r.iter().all(|a| self.shape_ok(a, c.pos)) {
            return false;
        }
        c.pos == self.pos(c.keep) || at_k.iter().all(|a| self.shape_ok(a, c.pos))
    }

    /// Whether face `a` with its moving corner at `to` keeps its orientation and shape.
    fn shape_ok(&self, a: &Around, to: DVec3) -> bool {
        let old = a.p;
        let mut new = old;
        new[a.moved] = to;
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
        let n_input = a.normal.as_dvec3();
        n_input == DVec3::ZERO || n_input.dot(n_new) >= self.cos_turn * len_new
    }

    /// Make a topology change that unblocks the collapse of edge (u, v), which the link condition
    /// blocks, if there is one that moves the surface by at most `limit` (squared): drop the
    /// closed tetrahedron the edge is on, or cut the mesh along a triangle of edges through it
    /// that is not a face. The collapse itself is tried again afterwards, and may still fail its
    /// shape checks. `out` gets the vertices whose edges must be ranked again.
    fn unblock(&mut self, u: u32, v: u32, e: &EdgeFaces, limit: f64, out: &mut Vec<u32>) -> bool {
        out.clear();
        if self.verts[u as usize].locked || self.verts[v as usize].locked || e.n != 2 {
            return false;
        }
        if self.drop_tetrahedron(u, v, e, limit) {
            return true;
        }
        // A third common neighbour y of u and v: (u, v, y) is a cycle of edges but no face.
        let mut around_u: Vec<u32> = self.faces_of(u).iter().flat_map(|&f| self.tri(f)).collect();
        around_u.sort_unstable();
        let third = self.faces_of(v).iter().flat_map(|&f| self.tri(f)).find(|&y| {
            y != u && y != v && y != e.x[0] && y != e.x[1] && around_u.binary_search(&y).is_ok()
        });
        third.is_some_and(|y| self.spread_sq(&[u, v, y]) <= limit && self.cut([u, v, y], out))
    }

    /// Remove a closed tetrahedron, a component that no collapse can shrink, if (u, v) is on one.
    fn drop_tetrahedron(&mut self, u: u32, v: u32, e: &EdgeFaces, limit: f64) -> bool {
        let corners = [u, v, e.x[0], e.x[1]];
        if corners.iter().any(|&w| self.verts[w as usize].len != 3 || self.verts[w as usize].locked) {
            return false;
        }
        let mut faces: Vec<u32> = corners.iter().flat_map(|&w| self.faces_of(w).iter().copied()).collect();
        faces.sort_unstable();
        faces.dedup();
        let spread_sq = self.spread_sq(&corners);
        if faces.len() != 4 || faces.iter().any(|&f| self.tri(f).iter().any(|y| !corners.contains(y))) || spread_sq > limit {
            return false;
        }
        self.error_sq = self.error_sq.max(spread_sq);
        for &w in &corners {
            let x = &mut self.verts[w as usize];
            x.len = 0;
            x.locked = true;
            self.version[w as usize] += 1;
        }
        for &f in &faces {
            self.faces[f as usize].v = [DEAD; 3];
        }
        self.faces_left -= 4;
        true
    }

    /// The largest squared distance of the vertices `vs` from their centroid: how far a cap over
    /// them, or their removal, moves the surface.
    fn spread_sq(&self, vs: &[u32]) -> f64 {
        let center = vs.iter().map(|&w| self.pos(w)).sum::<DVec3>() / vs.len() as f64;
        vs.iter().map(|&w| (self.pos(w) - center).length_squared()).fold(0.0, f64::max)
    }

    /// Cut the mesh along the cycle of edges a → b → c → a, which is no face, and cap both sides:
    /// each vertex keeps its faces on the left of the cycle and a new copy takes those on the
    /// right. Only where every fan around the cycle is closed and manifold. A handle through the
    /// cycle is removed, or the component split in two at a neck; the mesh stays manifold.
    fn cut(&mut self, cycle: [u32; 3], out: &mut Vec<u32>) -> bool {
        if cycle.iter().any(|&w| self.verts[w as usize].locked) {
            return false;
        }
        let mut sides = Vec::with_capacity(3);
        for i in 0..3 {
            let (v, next, prev) = (cycle[i], cycle[(i + 1) % 3], cycle[(i + 2) % 3]);
            let (Some(left), Some(right)) = (self.arc(v, next, prev), self.arc(v, prev, next)) else { return false };
            let mut all: Vec<u32> = left.iter().chain(&right).copied().collect();
            all.sort_unstable();
            all.dedup();
            if all.len() != self.verts[v as usize].len as usize || left.len() + right.len() != all.len() {
                return false;
            }
            sides.push((left, right));
        }
        // Not where a side is the three faces of one vertex (a spike, which a collapse removes
        // under the shape checks), nor with a degenerate cap.
        for side in [0, 1] {
            let mut faces: Vec<u32> = sides.iter().flat_map(|s| if side == 0 { &s.0 } else { &s.1 }).copied().collect();
            faces.sort_unstable();
            faces.dedup();
            if faces.len() <= 3 {
                return false;
            }
        }
        let p = cycle.map(|w| self.pos(w));
        if (p[1] - p[0]).cross(p[2] - p[0]).length_squared() == 0.0 {
            return false;
        }
        self.error_sq = self.error_sq.max(self.spread_sq(&cycle));
        let copies: [u32; 3] = std::array::from_fn(|i| self.verts.len() as u32 + i as u32);
        for (i, &v) in cycle.iter().enumerate() {
            let x = self.verts[v as usize];
            self.verts.push(Vertex { len: 0, kind: Kind::Unknown, ..x });
            self.quadrics.push(self.quadrics[v as usize]);
            self.version.push(0);
            for &f in &sides[i].1 {
                for w in &mut self.faces[f as usize].v {
                    if *w == v {
                        *w = copies[i];
                    }
                }
            }
        }
        // The left side is closed by the cycle reversed, the right side by the copies in order.
        let first = self.faces.len() as u32;
        for (side, order) in [[0, 2, 1], [0, 1, 2]].into_iter().enumerate() {
            let f = self.faces.len();
            let cap = order.map(|i| if side == 0 { cycle[i] } else { copies[i] });
            let p = cap.map(|w| self.pos(w));
            let normal = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero().as_vec3();
            let source = if side == 0 { sides[0].0[0] } else { sides[0].1[0] };
            self.faces.push(Face { v: cap, group: 0, normal });
            self.wedges.push([0; 3]);
            self.face_materials.push(self.face_materials[source as usize]);
            self.cap_source.push(if (source as usize) < self.input_faces { source } else { self.cap_source[source as usize - self.input_faces] });
            // Corner attributes, copied below from the fans' corners.
            if !self.normals.is_empty() {
                self.normals.extend([Vec3::ZERO; 3]);
            }
            if !self.uvs.is_empty() {
                self.uvs.extend([Vec2::ZERO; 3]);
            }
            if !self.colors.is_empty() {
                self.colors.extend([[0; 4]; 3]);
            }
            for (k, (&i, &w)) in order.iter().zip(&cap).enumerate() {
                let arc = if side == 0 { &sides[i].0 } else { &sides[i].1 };
                let from = self.corner(arc[0], w);
                self.copy_corner(from, 3 * f + k);
            }
        }
        self.faces_left += 2;
        for (i, &v) in cycle.iter().enumerate() {
            for (w, arc, cap) in [(v, &sides[i].0, first), (copies[i], &sides[i].1, first + 1)] {
                let start = self.face_lists.len() as u32;
                self.face_lists.extend_from_slice(arc);
                self.face_lists.push(cap);
                let x = &mut self.verts[w as usize];
                x.start = start;
                x.len = arc.len() as u32 + 1;
                x.kind = Kind::Unknown;
            }
            self.version[v as usize] += 1;
        }
        out.extend(cycle.iter().chain(&copies));
        true
    }

    /// The faces around `v` from the one where `from` follows `v` on to the one where `to`
    /// precedes it, turning the way faces are wound; None if the fan is open or not manifold.
    fn arc(&self, v: u32, from: u32, to: u32) -> Option<Vec<u32>> {
        let after = |w: u32| {
            self.faces_of(v).iter().copied().find(|&f| {
                let t = self.tri(f);
                (0..3).any(|i| t[i] == v && t[(i + 1) % 3] == w)
            })
        };
        let mut f = after(from)?;
        let mut out = Vec::new();
        for _ in 0..self.verts[v as usize].len {
            out.push(f);
            let t = self.tri(f);
            let i = t.iter().position(|&w| w == v)?;
            let prev = t[(i + 2) % 3];
            if prev == to {
                return Some(out);
            }
            f = after(prev)?;
        }
        None
    }

    fn copy_corner(&mut self, from: usize, to: usize) {
        self.wedges[to / 3][to % 3] = self.wedge(from);
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
        for _ in 0..self.verts[r as usize].len {
            let t = self.tri(cur);
            let y = t[0] ^ t[1] ^ t[2] ^ r ^ prev;
            let Some(&g) = self.faces_of(r).iter().find(|&&g| g != cur && self.tri(g).contains(&y)) else { return };
            if self.is_feature(r, y, &EdgeFaces { f: [cur, g], x: [NO_FACE; 2], n: 2 }) {
                return;
            }
            out.push(g);
            cur = g;
            prev = y;
        }
    }

    fn collapse(&mut self, e: &EdgeFaces, c: Candidate) {
        let (r, k) = (c.remove, c.keep);
        let mut rf = std::mem::take(&mut self.scratch_r);
        let mut kf = std::mem::take(&mut self.scratch_k);
        rf.clear();
        kf.clear();
        rf.extend(self.faces_of(r).iter().copied().filter(|f| !e.f.contains(f)));
        kf.extend(self.faces_of(k).iter().copied().filter(|f| !e.f.contains(f)));

        // Corners that follow r take the survivor's values (wedge and attributes) on their side.
        if let Some(t) = c.lerp {
            let (cr, ck) = (self.corner(e.f[0], r), self.corner(e.f[0], k));
            self.lerp_corner(cr, ck, t as f32);
            for (&f, v) in kf.iter().map(|f| (f, k)).chain(rf.iter().map(|f| (f, r))) {
                let to = self.corner(f, v);
                self.copy_corner(cr, to);
            }
        } else {
            let split = e.n == 2 && self.verts[r as usize].kind == Kind::Line;
            let mut side = Vec::new();
            if split {
                self.sector(r, e.f[0], k, &mut side);
            }
            let (c0, c1) = (self.corner(e.f[0], k), if split { self.corner(e.f[1], k) } else { 0 });
            for &f in &rf {
                let from = if split && !side.contains(&f) { c1 } else { c0 };
                let to = self.corner(f, r);
                self.copy_corner(from, to);
            }
        }

        for &f in &e.f[..e.n] {
            self.faces[f as usize].v = [DEAD; 3];
        }
        self.faces_left -= e.n;
        for &f in &rf {
            for v in &mut self.faces[f as usize].v {
                if *v == r {
                    *v = k;
                }
            }
        }
        // Only k and the opposite vertices can change kind: every other edge keeps its faces and,
        // corners being copied per side, its feature status. A free–free collapse changes none: all
        // edges at r and k are plain, and so are the edges they merge into.
        for &x in &e.x[..e.n] {
            let (start, len) = (self.verts[x as usize].start as usize, self.verts[x as usize].len as usize);
            let mut kept = 0;
            for i in 0..len {
                let f = self.face_lists[start + i];
                if !e.f.contains(&f) {
                    self.face_lists[start + kept] = f;
                    kept += 1;
                }
            }
            let xv = &mut self.verts[x as usize];
            xv.len = kept as u32;
            if c.lerp.is_none() {
                xv.kind = Kind::Unknown;
            }
        }

        if self.face_lists.len() > self.compact_at {
            self.compact_face_lists();
            self.compact_at = 2 * self.face_lists.len().max(1024);
        }
        let start = self.face_lists.len() as u32;
        self.face_lists.extend_from_slice(&kf);
        self.face_lists.extend_from_slice(&rf);
        let qr = self.quadrics[r as usize];
        self.quadrics[k as usize].add(&qr);
        let kv = &mut self.verts[k as usize];
        kv.start = start;
        kv.len = (kf.len() + rf.len()) as u32;
        kv.pos = c.pos.as_vec3();
        if c.lerp.is_none() {
            kv.kind = Kind::Unknown;
        }
        let rv = &mut self.verts[r as usize];
        rv.len = 0;
        rv.locked = true;
        self.version[k as usize] += 1;
        self.version[r as usize] += 1;
        self.error_sq = self.error_sq.max(c.error_sq);
        self.quadrics[k as usize].err_sq = c.error_sq;

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
        let mut lists = Vec::with_capacity(3 * self.faces_left + 1024);
        for x in &mut self.verts {
            let start = x.start as usize;
            x.start = lists.len() as u32;
            lists.extend_from_slice(&self.face_lists[start..start + x.len as usize]);
        }
        self.face_lists = lists;
    }

    fn finish(self, mesh: &Mesh, with_groups: bool) -> Simplified {
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
                let q = self.quadrics.get(v).copied().unwrap_or_default();
                remap[v] = positions.len() as u32;
                positions.push(x.pos);
                let own = if q.w > 0.0 { q.eval(x.pos.as_dvec3()) / q.w } else { 0.0 };
                vertex_error.push(own.max(q.err_sq).sqrt() as f32);
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
            face_materials: if mesh.face_materials.is_empty() { Vec::new() } else { alive.iter().map(|&f| self.face_materials[f]).collect() },
            materials: mesh.materials.clone(),
            face_normals: Vec::new(),
            face_areas: Vec::new(),
        };
        out.compute_face_geometry();
        let (face_groups, group_error) = if with_groups {
            let face_groups: Vec<u32> = alive.iter().map(|&f| self.faces[f].group).collect();
            let n_groups = self.faces.iter().map(|f| f.group).max().map_or(0, |g| g as usize + 1);
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
        let source_faces = alive.iter().map(|&f| if f < self.input_faces { f as u32 } else { self.cap_source[f - self.input_faces] }).collect();
        Simplified { mesh: out, source_faces, face_groups, group_error, error: self.error_sq.sqrt() as f32 }
    }
}

#[cfg(test)]
mod tests;
