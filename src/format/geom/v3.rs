//! Node geometry of format 3 (spec §8 of strata-v3.md): one bit stream per node.
//!
//! Triangles are coded in order, each against a ring of the 16 edges most recently made
//! ([`EDGE_RING`]): a triangle that shares one of them names it and its third vertex; the third
//! vertex is new, one of the 16 vertices most recently named ([`VERTEX_RING`]), or an index. A new
//! vertex's grid point is predicted by the parallelogram across the shared edge and the residual
//! is Rice-coded; vertices inside the node (no border edge) lie on a coarser lattice of `2^shift`
//! grid steps (the writer snaps them), so their residuals are counted in lattice steps, while
//! border vertices keep the grid and are flagged as such, so that a border vertex two nodes share
//! decodes identically in both whatever their lattices. Normals, after every triangle, are coded against the normal of the decoded surface
//! (area-weighted, in exact integer arithmetic). Material ranges and culling clusters come first.
//!
//! The encoder reorders faces within runs that must stay contiguous (a material range, a cluster)
//! so that each triangle shares an edge with a recent one, and numbers vertices in order of first
//! use; [`encode`] returns the payload and the order it chose.

use super::bits::{BitReader, BitWriter, PrefixCode, Rice};
use super::v2::{base_and_span, ClusterCodes, GeometryCodes};
use super::NodeContext;
use crate::error::{Error, Result};
use crate::format::chunk;
use crate::format::{angle_decode, id, octa, radius_decode, Cluster, Cone, MaterialRange, NodeGeometry};
use glam::Vec2;
use std::sync::OnceLock;

/// Edges a triangle can name.
pub const EDGE_RING: usize = 16;
/// Vertices a triangle's third corner can name.
pub const VERTEX_RING: usize = 16;
/// Bytes before the bit stream: lattice shift, normal bits, UV bits, reserved.
pub const PAYLOAD_HEADER_BYTES: usize = 4;

/// Triangle symbols: `0..16` names an edge of the ring (0 the newest), [`MISS`] none, [`FAR`] an
/// open edge older than the ring, by how many edges back it was made.
const MISS: usize = EDGE_RING;
const FAR: usize = EDGE_RING + 1;
/// How many of the newest edges the encoder searches for a `FAR` one (bounding its cost per
/// triangle); older open edges are left to `MISS`.
const FAR_SCAN: u32 = 1024;
/// Corner symbols: a new vertex inside the node, a new border vertex, the vertex after the shared
/// edge's end along the decoded region's border, the vertex before its start, a ring vertex
/// (`RING..RING+16`, 0 the newest), an index.
const NEW: usize = 0;
const NEW_BORDER: usize = 1;
const RIGHT: usize = 2;
const LEFT: usize = 3;
const RING: usize = 4;
const INDEX: usize = RING + VERTEX_RING;

/// Code lengths of the triangle symbols: Huffman lengths of their frequencies over the bunny, the
/// gargoyle and the CT head (`cargo bench --bench format3` prints them), each mesh weighted alike.
pub const TRIANGLE_CODE: [u8; EDGE_RING + 2] = [1, 2, 5, 4, 6, 6, 7, 6, 8, 7, 8, 7, 8, 8, 8, 8, 5, 5];
/// Code lengths of the corner symbols, made as [`TRIANGLE_CODE`]'s.
pub const CORNER_CODE: [u8; INDEX + 1] = [1, 4, 5, 3, 12, 12, 11, 10, 10, 10, 10, 10, 9, 9, 9, 8, 8, 8, 8, 8, 2];

fn codes() -> &'static (PrefixCode, PrefixCode) {
    static CODES: OnceLock<(PrefixCode, PrefixCode)> = OnceLock::new();
    CODES.get_or_init(|| (PrefixCode::new(&TRIANGLE_CODE), PrefixCode::new(&CORNER_CODE)))
}

/// How a node's codes are quantized beyond the grid: what the writer chose and the payload records.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Lattice {
    /// Vertices inside the node lie on multiples of `2^shift` grid steps.
    pub shift: u32,
    /// Bits of each octahedral normal coordinate (2..=16; scale `2^(bits−1) − 1`), 0 without normals.
    pub normal_bits: u32,
    /// UVs are multiples of `2^−uv_bits`; 0 without UVs.
    pub uv_bits: u32,
}

/// The lattice point nearest `g` for `shift`, kept below `2^bits`.
pub fn snap(g: u32, shift: u32, bits: u32) -> u32 {
    if shift == 0 {
        return g;
    }
    let top = ((1u64 << bits) - 1) >> shift << shift;
    ((((g as u64) + (1 << (shift - 1))) >> shift << shift).min(top)) as u32
}

/// The octahedral code, at `scale`, of the direction `(x, y, z)` given in exact f64 integers: the
/// prediction both the writer and every reader compute bit for bit (spec §8.5).
pub fn predict_octa(x: f64, y: f64, z: f64, scale: i32) -> [i32; 2] {
    let l1 = (x.abs() + y.abs()) + z.abs();
    if l1 == 0.0 {
        return [0, 0];
    }
    let (mut px, mut py) = (x / l1, y / l1);
    if z < 0.0 {
        let sx = if px >= 0.0 { 1.0 } else { -1.0 };
        let sy = if py >= 0.0 { 1.0 } else { -1.0 };
        (px, py) = ((1.0 - py.abs()) * sx, (1.0 - px.abs()) * sy);
    }
    let s = scale as f64;
    [(px * s + 0.5).floor() as i32, (py * s + 0.5).floor() as i32]
}

/// `atan(x)` for `x ≥ 0` from IEEE-exact operations only, within 0.005 rad: the same bits in every
/// reader, unlike a library `atan`.
#[inline]
fn atan_approx(x: f64) -> f64 {
    let f = |t: f64| t * (std::f64::consts::FRAC_PI_4 + 0.273 * (1.0 - t));
    if x <= 1.0 {
        f(x)
    } else {
        std::f64::consts::FRAC_PI_2 - f(1.0 / x)
    }
}

/// Vertex normals of grid points `p` and triangles `t`, each face's normal weighted by its angle at
/// the vertex (as strata computes normals), predicted as octahedral codes at `scale`. The sums use
/// f64 operations in a fixed order (faces in order, corners in order), so every reader gets the
/// same bits.
fn predicted_normals(p: &[[u32; 3]], t: &[u32], scale: i32) -> Vec<[i32; 2]> {
    let mut sum = vec![[0f64; 3]; p.len()];
    for f in t.chunks_exact(3) {
        let q = [f[0], f[1], f[2]].map(|i| p[i as usize].map(|x| x as f64));
        let sub = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
        let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
        // Edge k runs from corner k to corner k + 1.
        let e = [sub(q[1], q[0]), sub(q[2], q[1]), sub(q[0], q[2])];
        let n = [e[0][1] * e[2][2] - e[0][2] * e[2][1], e[0][2] * e[2][0] - e[0][0] * e[2][2], e[0][0] * e[2][1] - e[0][1] * e[2][0]];
        let n = n.map(|c| -c);
        let len = dot(n, n).sqrt();
        if len == 0.0 {
            continue;
        }
        let l = e.map(|x| dot(x, x).sqrt());
        for k in 0..3 {
            // The angle at corner k, between edge k and the reversed edge k − 1, is
            // 2·atan(|n| / (|e_k||e_{k−1}| − e_k·e_{k−1})).
            let before = (k + 2) % 3;
            let den = l[k] * l[before] - dot(e[k], e[before]);
            let angle = if den > 0.0 { 2.0 * atan_approx(len / den) } else { std::f64::consts::PI };
            let w = angle / len;
            let s = &mut sum[f[k] as usize];
            s[0] += n[0] * w;
            s[1] += n[1] * w;
            s[2] += n[2] * w;
        }
    }
    sum.iter().map(|s| predict_octa(s[0], s[1], s[2], scale)).collect()
}

/// What the decoded geometry predicts of each culling cluster (`counts` faces each, in order):
/// its cone axis, the octahedral code (16 bits) of the sum of its faces' normals, and its center,
/// the mean of its faces' corners relative to the node's base in units of `2^shift` grid steps.
/// Integer arithmetic and exact f64 sums, so every reader predicts the same.
fn cluster_predictions(p: &[[u32; 3]], t: &[u32], counts: &[u32], shift: u32) -> Vec<[i32; 5]> {
    let (base, _) = base_and_span(p);
    let mut out = Vec::with_capacity(counts.len());
    let mut first = 0usize;
    for &n in counts {
        let faces = &t[3 * first..3 * (first + n as usize)];
        first += n as usize;
        let mut normal = [0f64; 3];
        let mut sum = [0u64; 3];
        for f in faces.chunks_exact(3) {
            let q = [f[0], f[1], f[2]].map(|i| p[i as usize].map(|x| x as f64));
            let u = [q[1][0] - q[0][0], q[1][1] - q[0][1], q[1][2] - q[0][2]];
            let v = [q[2][0] - q[0][0], q[2][1] - q[0][1], q[2][2] - q[0][2]];
            normal[0] += u[1] * v[2] - u[2] * v[1];
            normal[1] += u[2] * v[0] - u[0] * v[2];
            normal[2] += u[0] * v[1] - u[1] * v[0];
            for &i in f {
                for k in 0..3 {
                    sum[k] += p[i as usize][k] as u64;
                }
            }
        }
        let axis = predict_octa(normal[0], normal[1], normal[2], i16::MAX as i32);
        let corners = faces.len().max(1) as u64;
        let center: [i32; 3] =
            std::array::from_fn(|k| ((sum[k] / corners).saturating_sub(base[k] as u64) >> shift).min(u16::MAX as u64) as i32);
        out.push([axis[0], axis[1], center[0], center[1], center[2]]);
    }
    out
}

/// Rice states, one per kind of residual, with their first parameters (spec §8.4).
struct States {
    lattice: [Rice; 3],
    border: [Rice; 3],
    jump: [Rice; 3],
    index: Rice,
    far: Rice,
    color: [Rice; 4],
    uv: [Rice; 2],
    /// Normals of vertices inside the node, and of vertices on an open edge, whose prediction
    /// sees only part of their fan.
    normal: [Rice; 2],
    normal_border: [Rice; 2],
    meta: Rice,
    /// Cluster axes and centers against their predictions.
    cluster: [Rice; 3],
}

impl States {
    fn new() -> Self {
        States {
            lattice: [Rice::new(4); 3],
            border: [Rice::new(6); 3],
            jump: [Rice::new(12); 3],
            index: Rice::new(4),
            far: Rice::new(5),
            color: [Rice::new(2); 4],
            uv: [Rice::new(6); 2],
            normal: [Rice::new(1); 2],
            normal_border: [Rice::new(4); 2],
            meta: Rice::new(4),
            cluster: [Rice::new(6), Rice::new(6), Rice::new(2)],
        }
    }
}

/// The order [`encode`] chose: the input face stored k-th is `faces[k]`, its corners rotated left
/// by `rotation[k]`; the input vertex stored k-th is `vertices[k]`.
#[derive(Clone, Debug, Default)]
pub struct Order {
    pub faces: Vec<u32>,
    pub rotation: Vec<u8>,
    pub vertices: Vec<u32>,
}

/// Where a new vertex's prediction comes from, in stored indices.
#[derive(Clone, Copy)]
enum Pred {
    /// The parallelogram `a + b − o` across the shared edge `(a, b)`.
    Edge(u32, u32, u32),
    /// The vertex stored before it, or the origin for the first.
    Jump(Option<u32>),
}

const NONE: u32 = u32::MAX;

/// What both sides keep, in stored indices: the border of the decoded region as loops of open
/// edges (directed edges of decoded triangles whose twin is not decoded, each linked to the next
/// and previous along its loop, as Edgebreaker's front), a ring of the newest open edges and a
/// ring of the newest vertices named.
struct Rings {
    from: Vec<u32>,
    to: Vec<u32>,
    /// The third vertex of the triangle that made the edge: the parallelogram's far corner.
    opp: Vec<u32>,
    next: Vec<u32>,
    prev: Vec<u32>,
    alive: Vec<bool>,
    edges: [u32; EDGE_RING],
    edge_head: usize,
    vertices: [u32; VERTEX_RING],
    vertex_head: usize,
}

impl Rings {
    fn new(faces: usize) -> Self {
        let cap = 3 * faces;
        Rings {
            from: Vec::with_capacity(cap),
            to: Vec::with_capacity(cap),
            opp: Vec::with_capacity(cap),
            next: Vec::with_capacity(cap),
            prev: Vec::with_capacity(cap),
            alive: Vec::with_capacity(cap),
            edges: [NONE; EDGE_RING],
            edge_head: 0,
            vertices: [NONE; VERTEX_RING],
            vertex_head: 0,
        }
    }

    /// The open edge `j` places back in the ring, if it is still open.
    #[inline]
    fn edge(&self, j: usize) -> Option<u32> {
        let e = self.edges[(self.edge_head + EDGE_RING - j) % EDGE_RING];
        (e != NONE && self.alive[e as usize]).then_some(e)
    }

    /// Start, end and far corner of open edge `e`.
    #[inline]
    fn ends(&self, e: u32) -> (u32, u32, u32) {
        let e = e as usize;
        (self.from[e], self.to[e], self.opp[e])
    }

    /// The vertex after edge `e` along its loop (`RIGHT`) and the one before it (`LEFT`).
    #[inline]
    fn sides(&self, e: u32) -> [u32; 2] {
        [self.to[self.next[e as usize] as usize], self.from[self.prev[e as usize] as usize]]
    }

    #[inline]
    fn make(&mut self, a: u32, b: u32, o: u32) -> u32 {
        let e = self.from.len() as u32;
        self.from.push(a);
        self.to.push(b);
        self.opp.push(o);
        self.next.push(NONE);
        self.prev.push(NONE);
        self.alive.push(true);
        self.edge_head = (self.edge_head + 1) % EDGE_RING;
        self.edges[self.edge_head] = e;
        e
    }

    #[inline]
    fn link(&mut self, x: u32, y: u32) {
        self.next[x as usize] = y;
        self.prev[y as usize] = x;
    }

    /// After triangle `(b, a, c)` across open edge `e = (a, b)`: `e` closes, and so does the edge
    /// before or after it when `c` is that edge's far end; the triangle's other edges open.
    #[inline]
    fn advance(&mut self, e: u32, c: u32) {
        let (a, b, _) = self.ends(e);
        let (l, r) = (self.prev[e as usize], self.next[e as usize]);
        let right = self.to[r as usize] == c;
        let left = self.from[l as usize] == c;
        self.alive[e as usize] = false;
        match (left, right) {
            (false, false) => {
                let x = self.make(a, c, b);
                let y = self.make(c, b, a);
                self.link(l, x);
                self.link(x, y);
                self.link(y, r);
            }
            (false, true) => {
                self.alive[r as usize] = false;
                let after = self.next[r as usize];
                let x = self.make(a, c, b);
                self.link(l, x);
                self.link(x, if after == e { l } else { after });
            }
            (true, false) => {
                self.alive[l as usize] = false;
                let before = self.prev[l as usize];
                let y = self.make(c, b, a);
                self.link(if before == e { r } else { before }, y);
                self.link(y, r);
            }
            (true, true) => {
                self.alive[l as usize] = false;
                self.alive[r as usize] = false;
                let (before, after) = (self.prev[l as usize], self.next[r as usize]);
                if l != r && before != r && self.alive[before as usize] && self.alive[after as usize] {
                    self.link(before, after);
                }
            }
        }
    }

    /// After a triangle `s` that shares no open edge: a loop of its three edges.
    #[inline]
    fn start(&mut self, s: [u32; 3]) {
        let x = self.make(s[0], s[1], s[2]);
        let y = self.make(s[1], s[2], s[0]);
        let z = self.make(s[2], s[0], s[1]);
        self.link(x, y);
        self.link(y, z);
        self.link(z, x);
    }

    /// Which of `n` vertices lie on an edge still open: once every triangle is decoded, the node's
    /// border (and edges whose twin is missing or doubled).
    fn open_vertices(&self, n: usize) -> Vec<bool> {
        let mut open = vec![false; n];
        for (e, &alive) in self.alive.iter().enumerate() {
            if alive {
                open[self.from[e] as usize] = true;
                open[self.to[e] as usize] = true;
            }
        }
        open
    }

    #[inline]
    fn vertex(&self, j: usize) -> u32 {
        self.vertices[(self.vertex_head + VERTEX_RING - j) % VERTEX_RING]
    }
    #[inline]
    fn push_vertex(&mut self, v: u32) {
        self.vertex_head = (self.vertex_head + 1) % VERTEX_RING;
        self.vertices[self.vertex_head] = v;
    }
}

#[inline]
fn lattice_of(p: i64, shift: u32) -> i64 {
    (p + ((1i64 << shift) >> 1)) >> shift
}

/// What `pred` predicts of an attribute that `get` reads per stored vertex: the parallelogram,
/// clamped to `lo..=hi`, the vertex before, or zero. Encoder and decoder share it.
#[inline]
fn predict<const N: usize>(pred: Pred, get: impl Fn(u32) -> [i64; N], lo: i64, hi: i64) -> [i64; N] {
    match pred {
        Pred::Edge(a, b, o) => parallelogram(get(a), get(b), get(o), lo, hi),
        Pred::Jump(Some(prev)) => get(prev),
        Pred::Jump(None) => [0; N],
    }
}

#[inline]
fn parallelogram<const N: usize>(a: [i64; N], b: [i64; N], o: [i64; N], lo: i64, hi: i64) -> [i64; N] {
    std::array::from_fn(|k| (a[k] + b[k] - o[k]).clamp(lo, hi))
}

/// Where an encoding's bits went, and how often each symbol occurred: for benches and tuning.
#[derive(Clone, Debug, Default)]
pub struct Stats {
    /// Bits of triangle symbols, corner symbols, vertex indices, positions, colors, UVs,
    /// normals, and material ranges with clusters.
    pub bits: [u64; 8],
    pub triangle_symbols: [u64; EDGE_RING + 2],
    pub corner_symbols: [u64; INDEX + 1],
}

/// Names of [`Stats::bits`].
pub const STAT_NAMES: [&str; 8] = ["triangles", "corners", "indices", "positions", "colors", "uvs", "normals", "meta"];

struct Enc<'a> {
    stats: Stats,
    g: &'a GeometryCodes,
    lat: Lattice,
    bits: u32,
    border: Vec<bool>,
    uvq: Vec<[i64; 2]>,
    w: BitWriter,
    st: States,
    stored: Vec<u32>,
    order: Order,
    rings: Rings,
}

impl Enc<'_> {
    fn input(&self, stored: u32) -> usize {
        self.order.vertices[stored as usize] as usize
    }

    /// Code a corner found along the border (`RIGHT` or `LEFT`), stored index `c`.
    fn side(&mut self, symbol: usize, c: u32) -> u32 {
        let mark = self.w.len();
        codes().1.put(&mut self.w, symbol);
        self.stats.corner_symbols[symbol] += 1;
        self.stats.bits[1] += self.w.len() - mark;
        c
    }

    /// Code corner `v` (an input vertex); a new one is predicted by `pred`. Returns its stored index.
    fn corner(&mut self, v: u32, pred: Pred) -> u32 {
        let corner_code = &codes().1;
        let s = self.stored[v as usize];
        let mark = self.w.len();
        if s == NONE {
            let border = self.border[v as usize];
            corner_code.put(&mut self.w, if border { NEW_BORDER } else { NEW });
            self.stats.corner_symbols[if border { NEW_BORDER } else { NEW }] += 1;
            self.stats.bits[1] += self.w.len() - mark;
            let s = self.order.vertices.len() as u32;
            self.stored[v as usize] = s;
            self.order.vertices.push(v);
            self.new_vertex(v as usize, border, pred);
            self.rings.push_vertex(s);
            return s;
        }
        if let Some(j) = (0..VERTEX_RING).find(|&j| self.rings.vertex(j) == s) {
            corner_code.put(&mut self.w, RING + j);
            self.stats.corner_symbols[RING + j] += 1;
            self.stats.bits[1] += self.w.len() - mark;
            return s;
        }
        corner_code.put(&mut self.w, INDEX);
        self.stats.corner_symbols[INDEX] += 1;
        self.stats.bits[1] += self.w.len() - mark;
        let next = self.order.vertices.len() as u32;
        let mark = self.w.len();
        self.st.index.put(&mut self.w, next - 1 - s);
        self.stats.bits[2] += self.w.len() - mark;
        self.rings.push_vertex(s);
        s
    }

    fn new_vertex(&mut self, v: usize, border: bool, pred: Pred) {
        let top = (1i64 << self.bits) - 1;
        let p = predict(pred, |s| self.g.points[self.input(s)].map(|x| x as i64), 0, top);
        let g = self.g.points[v].map(|x| x as i64);
        let mark = self.w.len();
        for k in 0..3 {
            match pred {
                Pred::Jump(_) => self.st.jump[k].put_signed(&mut self.w, (g[k] - p[k]) as i32),
                Pred::Edge(..) if border => self.st.border[k].put_signed(&mut self.w, (g[k] - p[k]) as i32),
                Pred::Edge(..) => {
                    let r = (g[k] >> self.lat.shift) - lattice_of(p[k], self.lat.shift);
                    self.st.lattice[k].put_signed(&mut self.w, r as i32)
                }
            }
        }
        self.stats.bits[3] += self.w.len() - mark;
        let mark = self.w.len();
        if !self.g.colors.is_empty() {
            let pc = predict(pred, |s| self.g.colors[self.input(s)].map(|x| x as i64), 0, 255);
            let c = self.g.colors[v];
            for k in 0..4 {
                self.st.color[k].put_signed(&mut self.w, (c[k] as i64 - pc[k]) as i8 as i32);
            }
        }
        self.stats.bits[4] += self.w.len() - mark;
        let mark = self.w.len();
        if !self.g.uvs.is_empty() {
            let pu = predict(pred, |s| self.uvq[self.input(s)], 1 - UV_LIMIT, UV_LIMIT - 1);
            let q = self.uvq[v];
            for k in 0..2 {
                self.st.uv[k].put_signed(&mut self.w, (q[k] - pu[k]) as i32);
            }
        }
        self.stats.bits[5] += self.w.len() - mark;
    }
}

/// Quantized UVs lie strictly within ±2^30 steps.
const UV_LIMIT: i64 = 1 << 30;

/// Encode a node's geometry at lattice `lat` on a grid of `bits` bits. Vertices on multiples of
/// `2^shift` grid steps are coded on the lattice, others (the node's border, which the writer
/// leaves on the grid) as grid points; normals must lie within the scale of `normal_bits` and UVs
/// on multiples of `2^−uv_bits`. Faces keep their runs of material and cluster, in an order of
/// the encoder's choosing, returned with the payload.
pub fn encode(g: &GeometryCodes, lat: Lattice, bits: u32) -> std::result::Result<(Vec<u8>, Order), String> {
    encode_with_stats(g, lat, bits).map(|(p, o, _)| (p, o))
}

/// [`encode`], also saying where the bits went.
pub fn encode_with_stats(g: &GeometryCodes, lat: Lattice, bits: u32) -> std::result::Result<(Vec<u8>, Order, Stats), String> {
    let n = g.points.len();
    let nf = g.indices.len() / 3;
    if lat.shift >= bits.max(1) {
        return Err(format!("lattice shift {} on a {bits}-bit grid", lat.shift));
    }
    if (lat.normal_bits > 0) == g.normals.is_empty() || (lat.normal_bits > 0 && !(2..=16).contains(&lat.normal_bits)) {
        return Err(format!("{} normals at {} bits (2..=16 with normals, 0 without)", g.normals.len(), lat.normal_bits));
    }
    if (lat.uv_bits > 0) == g.uvs.is_empty() || lat.uv_bits > 24 {
        return Err(format!("{} UVs at {} bits (1..=24 with UVs, 0 without)", g.uvs.len(), lat.uv_bits));
    }
    let mut next = 0u64;
    for r in &g.material_ranges {
        if r.first_index as u64 != next || r.index_count == 0 || r.index_count % 3 != 0 {
            return Err(format!("material range {r:?} does not continue at index {next} with whole faces"));
        }
        next += r.index_count as u64;
    }
    if next != g.indices.len() as u64 || g.indices.len() % 3 != 0 {
        return Err(format!("material ranges cover {next} of {} indices", g.indices.len()));
    }
    if let Some((_, records)) = &g.clusters {
        let covered: u64 = records.iter().map(|c| c.faces as u64).sum();
        if records.is_empty() || records.iter().any(|c| c.faces == 0) || covered != nf as u64 {
            return Err(format!("clusters cover {covered} of {nf} faces"));
        }
    }
    let mask = (1u32 << lat.shift) - 1;
    let border: Vec<bool> = g.points.iter().map(|p| p.iter().any(|&x| x & mask != 0)).collect();
    if lat.normal_bits > 0 {
        let scale = octa::scale(lat.normal_bits);
        if let Some(v) = g.normals.iter().position(|q| q.iter().any(|&c| (c as i32).abs() > scale)) {
            return Err(format!("normal {v} exceeds the {}-bit scale", lat.normal_bits));
        }
    }
    let s = (1u64 << lat.uv_bits) as f64;
    let mut uvq = Vec::with_capacity(g.uvs.len());
    for (v, uv) in g.uvs.iter().enumerate() {
        let q = uv.map(|b| f32::from_bits(b) as f64 * s);
        if q.iter().any(|&x| x.fract() != 0.0 || x.is_nan() || x.abs() >= UV_LIMIT as f64) {
            return Err(format!("UV {v} is not a multiple of 2^-{} within ±2^30 of them", lat.uv_bits));
        }
        uvq.push(q.map(|x| x as i64));
    }

    let mut e = Enc {
        stats: Stats::default(),
        g,
        lat,
        bits,
        border,
        uvq,
        w: BitWriter::default(),
        st: States::new(),
        stored: vec![NONE; n],
        order: Order { faces: Vec::with_capacity(nf), rotation: Vec::with_capacity(nf), vertices: Vec::with_capacity(n) },
        rings: Rings::new(nf),
    };

    e.st.meta.put(&mut e.w, g.material_ranges.len() as u32);
    let mut cuts = vec![0usize, nf];
    let mut last_material = 0i64;
    for r in &g.material_ranges {
        e.st.meta.put_signed(&mut e.w, (r.material as i64 - last_material) as i32);
        e.st.meta.put(&mut e.w, r.index_count / 3);
        last_material = r.material as i64;
        cuts.push(r.first_index as usize / 3);
    }
    match &g.clusters {
        None => e.st.meta.put(&mut e.w, 0),
        Some((shift, records)) => {
            e.st.meta.put(&mut e.w, records.len() as u32);
            e.st.meta.put(&mut e.w, *shift);
            let mut first = 0usize;
            for c in records {
                cuts.push(first);
                first += c.faces as usize;
                e.st.meta.put(&mut e.w, c.faces as u32);
            }
        }
    }
    cuts.sort_unstable();
    cuts.dedup();
    e.stats.bits[7] = e.w.len();

    let mut directed: Vec<(u64, u32)> = Vec::with_capacity(3 * nf);
    for (f, t) in g.indices.chunks_exact(3).enumerate() {
        for k in 0..3 {
            directed.push((((t[k] as u64) << 32) | t[(k + 1) % 3] as u64, f as u32));
        }
    }
    directed.sort_unstable();
    let mut done = vec![false; nf];
    let triangle_code = &codes().0;

    for run in cuts.windows(2) {
        let (start, end) = (run[0], run[1]);
        let mut cursor = start;
        for _ in start..end {
            let mut hit: Option<(usize, u32, u32)> = None;
            let mut best = 3;
            let across = |e: &Enc, edge: u32| {
                let (a, b, _) = e.rings.ends(edge);
                let key = ((e.input(b) as u64) << 32) | e.input(a) as u64;
                let from = directed.partition_point(|x| x.0 < key);
                directed[from..]
                    .iter()
                    .take_while(|x| x.0 == key)
                    .find(|x| (start..end).contains(&(x.1 as usize)) && !done[x.1 as usize])
                    .map(|x| x.1)
            };
            for j in 0..EDGE_RING {
                let Some(edge) = e.rings.edge(j) else { continue };
                if let Some(f) = across(&e, edge) {
                    let (a, b, _) = e.rings.ends(edge);
                    let t = &g.indices[3 * f as usize..3 * f as usize + 3];
                    let third = t.iter().copied().find(|&v| v != e.input(a) as u32 && v != e.input(b) as u32).unwrap_or(t[0]);
                    let c = e.stored[third as usize];
                    // Rank: closing against the border (0), a new vertex (1), any other (2).
                    let rank = if c == NONE {
                        1
                    } else if e.rings.sides(edge).contains(&c) {
                        0
                    } else {
                        2
                    };
                    if hit.is_none() || rank < best {
                        hit = Some((j, f, edge));
                        best = rank;
                    }
                    if rank == 0 {
                        break;
                    }
                }
            }
            if hit.is_none() {
                let made = e.rings.from.len() as u32;
                for edge in (made.saturating_sub(FAR_SCAN)..made).rev() {
                    if e.rings.alive[edge as usize] {
                        if let Some(f) = across(&e, edge) {
                            hit = Some((FAR, f, edge));
                            break;
                        }
                    }
                }
            }
            match hit {
                Some((j, f, edge)) => {
                    let (a, b, o) = e.rings.ends(edge);
                    let mark = e.w.len();
                    triangle_code.put(&mut e.w, j);
                    if j == FAR {
                        e.st.far.put(&mut e.w, e.rings.from.len() as u32 - 1 - edge);
                    }
                    e.stats.bits[0] += e.w.len() - mark;
                    e.stats.triangle_symbols[j] += 1;
                    let t = &g.indices[3 * f as usize..3 * f as usize + 3];
                    let b_in = e.input(b) as u32;
                    let k = (0..3).find(|&k| t[k] == b_in && t[(k + 1) % 3] == e.input(a) as u32).expect("the edge's face holds it");
                    let third = t[(k + 2) % 3];
                    let c = e.stored[third as usize];
                    let [right, left] = e.rings.sides(edge);
                    let c = if c != NONE && c == right {
                        e.side(RIGHT, c)
                    } else if c != NONE && c == left {
                        e.side(LEFT, c)
                    } else {
                        e.corner(third, Pred::Edge(a, b, o))
                    };
                    e.rings.advance(edge, c);
                    done[f as usize] = true;
                    e.order.faces.push(f);
                    e.order.rotation.push(k as u8);
                }
                None => {
                    while done[cursor] {
                        cursor += 1;
                    }
                    let f = cursor;
                    let mark = e.w.len();
                    triangle_code.put(&mut e.w, MISS);
                    e.stats.bits[0] += e.w.len() - mark;
                    e.stats.triangle_symbols[MISS] += 1;
                    let t = &g.indices[3 * f..3 * f + 3];
                    let mut s = [0u32; 3];
                    for k in 0..3 {
                        let prev = if k > 0 { Some(s[k - 1]) } else { (e.order.vertices.len() as u32).checked_sub(1) };
                        s[k] = e.corner(t[k], Pred::Jump(prev));
                    }
                    e.rings.start(s);
                    done[f] = true;
                    e.order.faces.push(f as u32);
                    e.order.rotation.push(0);
                }
            }
        }
    }

    let mark = e.w.len();
    let points: Vec<[u32; 3]> = e.order.vertices.iter().map(|&v| g.points[v as usize]).collect();
    let tris = stored_indices(g, &e.order, &e.stored);
    if let Some((shift, records)) = &g.clusters {
        let counts: Vec<u32> = records.iter().map(|c| c.faces as u32).collect();
        let pred = cluster_predictions(&points, &tris, &counts, *shift);
        let mut prev = [0i32; 2];
        for (c, p) in records.iter().zip(&pred) {
            let actual = [c.axis[0] as i32, c.axis[1] as i32, c.center[0] as i32, c.center[1] as i32, c.center[2] as i32];
            for k in 0..5 {
                e.st.cluster[k.min(2)].put_signed(&mut e.w, actual[k] - p[k]);
            }
            e.st.meta.put_signed(&mut e.w, c.half_angle as i32 - prev[0]);
            e.st.meta.put_signed(&mut e.w, c.radius as i32 - prev[1]);
            prev = [c.half_angle as i32, c.radius as i32];
        }
    }
    e.stats.bits[7] += e.w.len() - mark;
    let mark = e.w.len();
    if lat.normal_bits > 0 {
        let pred = predicted_normals(&points, &tris, octa::scale(lat.normal_bits));
        let open = e.rings.open_vertices(points.len());
        for (s, &v) in e.order.vertices.iter().enumerate() {
            let q = g.normals[v as usize];
            let states = if open[s] { &mut e.st.normal_border } else { &mut e.st.normal };
            for k in 0..2 {
                states[k].put_signed(&mut e.w, q[k] as i32 - pred[s][k]);
            }
        }
    }
    e.stats.bits[6] = e.w.len() - mark;
    let mut payload = vec![lat.shift as u8, lat.normal_bits as u8, lat.uv_bits as u8, 0];
    payload.extend(e.w.finish());
    Ok((payload, e.order, e.stats))
}

/// The stored index array of `order`.
fn stored_indices(g: &GeometryCodes, order: &Order, stored: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(3 * order.faces.len());
    for (&f, &r) in order.faces.iter().zip(&order.rotation) {
        let t = &g.indices[3 * f as usize..3 * f as usize + 3];
        for k in 0..3 {
            out.push(stored[t[(k + r as usize) % 3] as usize]);
        }
    }
    out
}

/// The decoded codes of a node, before positions and normals become floats.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Decoded {
    pub lattice: Lattice,
    pub points: Vec<[u32; 3]>,
    /// Octahedral codes at the lattice's normal scale.
    pub normals: Vec<[i32; 2]>,
    /// UVs in steps of `2^−uv_bits`.
    pub uvs: Vec<[i64; 2]>,
    pub colors: Vec<[u8; 4]>,
    pub indices: Vec<u32>,
    pub material_ranges: Vec<MaterialRange>,
    pub cluster_shift: u32,
    pub clusters: Vec<ClusterCodes>,
}

/// What decoding needs from outside the payload.
#[derive(Clone, Copy, Debug)]
pub struct Expect {
    pub faces: u32,
    pub vertices: u32,
    pub bits: u32,
    pub materials: u32,
    pub normals: bool,
    pub uvs: bool,
    pub colors: bool,
    pub clusters: bool,
}

/// A decoding failure: what, and at which byte of the payload.
pub type Fault = (usize, String);

/// Decode a node's payload into codes.
pub fn decode_codes(payload: &[u8], x: Expect) -> std::result::Result<Decoded, Fault> {
    if payload.len() < PAYLOAD_HEADER_BYTES {
        return Err((0, format!("{} bytes; the payload header alone is {PAYLOAD_HEADER_BYTES}", payload.len())));
    }
    let lat = Lattice { shift: payload[0] as u32, normal_bits: payload[1] as u32, uv_bits: payload[2] as u32 };
    if lat.shift > x.bits {
        return Err((0, format!("lattice shift {} exceeds the {}-bit grid", lat.shift, x.bits)));
    }
    if (lat.normal_bits > 0) != x.normals || (x.normals && !(2..=16).contains(&lat.normal_bits)) {
        return Err((
            1,
            format!("normal bits {}; the file {} normals (2..=16 bits)", lat.normal_bits, if x.normals { "has" } else { "has no" }),
        ));
    }
    if (lat.uv_bits > 0) != x.uvs || lat.uv_bits > 24 {
        return Err((2, format!("UV bits {}; the file {} UVs (1..=24 bits)", lat.uv_bits, if x.uvs { "has" } else { "has no" })));
    }
    if payload[3] != 0 {
        return Err((3, format!("reserved byte {}; must be 0", payload[3])));
    }
    let data = &payload[PAYLOAD_HEADER_BYTES..];
    // Every face and every vertex takes at least one bit: a count beyond that is refused before
    // anything is allocated for it.
    let bits = 8 * data.len() as u64;
    if x.faces as u64 > bits || x.vertices as u64 > bits || x.faces > u32::MAX / 3 {
        return Err((0, format!("{} faces and {} vertices cannot fit in {} bytes", x.faces, x.vertices, data.len())));
    }
    let mut r = BitReader::new(data);
    // The payload byte a reader has reached, for errors.
    let at = |r: &BitReader| (PAYLOAD_HEADER_BYTES + (r.consumed() / 8) as usize).min(payload.len());
    let mut st = States::new();
    let (nf, nv, top) = (x.faces as usize, x.vertices as usize, (1i64 << x.bits) - 1);
    let mut d = Decoded { lattice: lat, ..Decoded::default() };

    let ranges = st.meta.get(&mut r) as usize;
    if ranges > nf.max(1) {
        return Err((at(&r), format!("{ranges} material ranges for {nf} faces")));
    }
    let (mut material, mut first) = (0i64, 0u64);
    for k in 0..ranges {
        material += st.meta.get_signed(&mut r) as i64;
        let faces = st.meta.get(&mut r) as u64;
        if material < 0 || material >= x.materials as i64 || faces == 0 || first + faces > nf as u64 {
            return Err((
                at(&r),
                format!("material range {k} (material {material}, {faces} faces) is not a run of a known material within the {nf} faces"),
            ));
        }
        d.material_ranges.push(MaterialRange { material: material as u32, first_index: 3 * first as u32, index_count: 3 * faces as u32 });
        first += faces;
    }
    if first != nf as u64 {
        return Err((at(&r), format!("material ranges cover {first} of {nf} faces")));
    }
    let count = st.meta.get(&mut r) as usize;
    if (count > 0) != x.clusters || count > nf {
        return Err((
            at(&r),
            format!("{count} culling clusters in a node of {nf} faces {}", if x.clusters { "at level 0" } else { "above level 0" }),
        ));
    }
    if count > 0 {
        d.cluster_shift = st.meta.get(&mut r);
        if d.cluster_shift > x.bits {
            return Err((at(&r), format!("cluster shift {} exceeds the {} grid bits", d.cluster_shift, x.bits)));
        }
        let mut total = 0u64;
        for k in 0..count {
            let faces = st.meta.get(&mut r) as u64;
            if faces == 0 || faces > u16::MAX as u64 {
                return Err((at(&r), format!("cluster {k} has {faces} faces")));
            }
            total += faces;
            d.clusters.push(ClusterCodes { faces: faces as u16, ..ClusterCodes::default() });
        }
        if total != nf as u64 {
            return Err((at(&r), format!("clusters cover {total} of {nf} faces")));
        }
    }

    let (triangle_code, corner_code) = codes();
    // Sized for what the bytes can hold at a few bits per face; the vectors grow if needed.
    let (nv_hint, nf_hint) = (nv.min(data.len()), nf.min(2 * data.len()));
    let mut rings = Rings::new(nf_hint);
    d.points.reserve(nv_hint);
    d.indices.reserve(3 * nf_hint);
    if x.colors {
        d.colors.reserve(nv_hint);
    }
    if x.uvs {
        d.uvs.reserve(nv_hint);
    }
    let shift = lat.shift;
    for _ in 0..nf {
        if r.overrun() {
            return Err((payload.len(), "the bit stream ends early".into()));
        }
        let t = triangle_code.get(&mut r);
        let corner = |d: &mut Decoded,
                      r: &mut BitReader,
                      rings: &mut Rings,
                      st: &mut States,
                      pred: Pred,
                      sides: [u32; 2]|
         -> std::result::Result<u32, Fault> {
            let c = corner_code.get(r);
            let fault = |r: &BitReader, m: String| (at(r), m);
            if c <= NEW_BORDER {
                let s = d.points.len() as u32;
                if s as usize >= nv {
                    return Err(fault(r, format!("more than the node's {nv} vertices")));
                }
                let p = predict(pred, |s| d.points[s as usize].map(|v| v as i64), 0, top);
                let mut g = [0i64; 3];
                for k in 0..3 {
                    g[k] = match pred {
                        Pred::Jump(_) => p[k] + st.jump[k].get_signed(r) as i64,
                        Pred::Edge(..) if c == NEW_BORDER => p[k] + st.border[k].get_signed(r) as i64,
                        Pred::Edge(..) => (lattice_of(p[k], shift) + st.lattice[k].get_signed(r) as i64) << shift,
                    };
                }
                if g.iter().any(|&v| v < 0 || v > top) {
                    return Err(fault(r, format!("vertex {s} lies off the grid")));
                }
                d.points.push(g.map(|v| v as u32));
                if x.colors {
                    let pc = predict(pred, |s| d.colors[s as usize].map(|v| v as i64), 0, 255);
                    let mut col = [0u8; 4];
                    for k in 0..4 {
                        let residual = st.color[k].get_signed(r);
                        if !(-128..=127).contains(&residual) {
                            return Err(fault(r, format!("vertex {s}: color residual {residual} beyond a byte")));
                        }
                        col[k] = (pc[k] + residual as i64) as u8;
                    }
                    d.colors.push(col);
                }
                if x.uvs {
                    let pu = predict(pred, |s| d.uvs[s as usize], 1 - UV_LIMIT, UV_LIMIT - 1);
                    let mut uv = [0i64; 2];
                    for k in 0..2 {
                        uv[k] = pu[k] + st.uv[k].get_signed(r) as i64;
                        if uv[k].abs() >= UV_LIMIT {
                            return Err(fault(r, format!("vertex {s}: UV beyond ±2^30 steps")));
                        }
                    }
                    d.uvs.push(uv);
                }
                rings.push_vertex(s);
                return Ok(s);
            }
            if c == RIGHT || c == LEFT {
                let s = sides[c - RIGHT];
                if s == NONE {
                    return Err(fault(r, "a border corner with no border vertex there".into()));
                }
                return Ok(s);
            }
            if c < INDEX {
                let s = rings.vertex(c - RING);
                if s == NONE {
                    return Err(fault(r, format!("corner names vertex ring slot {} before it is filled", c - RING)));
                }
                return Ok(s);
            }
            let back = st.index.get(r) as u64;
            let next = d.points.len() as u64;
            if back + 1 > next {
                return Err(fault(r, format!("corner names vertex {} back of {next}", back + 1)));
            }
            let s = (next - 1 - back) as u32;
            rings.push_vertex(s);
            Ok(s)
        };
        if t != MISS {
            let edge = if t == FAR {
                let back = st.far.get(&mut r) as usize;
                let made = rings.from.len();
                match made.checked_sub(back + 1) {
                    Some(edge) if rings.alive[edge] => edge as u32,
                    _ => {
                        return Err((
                            at(&r),
                            format!("triangle names the open edge made {} edges back of {made}, which is not open", back + 1),
                        ))
                    }
                }
            } else {
                let Some(edge) = rings.edge(t) else {
                    return Err((at(&r), format!("triangle names edge ring slot {t}, which holds no open edge")));
                };
                edge
            };
            let (a, b, o) = rings.ends(edge);
            let sides = rings.sides(edge);
            let c = corner(&mut d, &mut r, &mut rings, &mut st, Pred::Edge(a, b, o), sides)?;
            d.indices.extend_from_slice(&[b, a, c]);
            rings.advance(edge, c);
        } else {
            let mut s = [0u32; 3];
            for k in 0..3 {
                let prev = if k > 0 { Some(s[k - 1]) } else { (d.points.len() as u32).checked_sub(1) };
                s[k] = corner(&mut d, &mut r, &mut rings, &mut st, Pred::Jump(prev), [NONE; 2])?;
            }
            d.indices.extend_from_slice(&s);
            rings.start(s);
        }
    }
    if d.points.len() != nv {
        return Err((at(&r), format!("{} vertices decoded; the node has {nv}", d.points.len())));
    }
    if !d.clusters.is_empty() {
        let counts: Vec<u32> = d.clusters.iter().map(|c| c.faces as u32).collect();
        let pred = cluster_predictions(&d.points, &d.indices, &counts, d.cluster_shift);
        let base = base_and_span(&d.points).0;
        let mut prev = [0i64; 2];
        for (k, p) in pred.iter().enumerate() {
            let mut f = [0i64; 5];
            for (i, v) in f.iter_mut().enumerate() {
                *v = p[i] as i64 + st.cluster[i.min(2)].get_signed(&mut r) as i64;
            }
            let half_angle = prev[0] + st.meta.get_signed(&mut r) as i64;
            let radius = prev[1] + st.meta.get_signed(&mut r) as i64;
            prev = [half_angle, radius];
            let i16s = |v: i64| (i16::MIN as i64..=i16::MAX as i64).contains(&v);
            let u16s = |v: i64| (0..=u16::MAX as i64).contains(&v);
            if !(i16s(f[0]) && i16s(f[1]) && f[2..].iter().all(|&v| u16s(v)) && u16s(half_angle) && u16s(radius)) {
                return Err((at(&r), format!("cluster {k}: a field out of range")));
            }
            let c = &mut d.clusters[k];
            c.axis = [f[0] as i16, f[1] as i16];
            c.center = [f[2] as u16, f[3] as u16, f[4] as u16];
            c.half_angle = half_angle as u16;
            c.radius = radius as u16;
            if (0..3).any(|a| base[a] as u64 + ((c.center[a] as u64) << d.cluster_shift) > top as u64) {
                return Err((at(&r), format!("cluster {k}'s center lies off the {}-bit grid", x.bits)));
            }
        }
    }
    if x.normals {
        let scale = octa::scale(lat.normal_bits);
        let pred = predicted_normals(&d.points, &d.indices, scale);
        let open = rings.open_vertices(nv);
        d.normals.reserve(nv);
        for (v, p) in pred.iter().enumerate() {
            let states = if open[v] { &mut st.normal_border } else { &mut st.normal };
            let q = [p[0] as i64 + states[0].get_signed(&mut r) as i64, p[1] as i64 + states[1].get_signed(&mut r) as i64];
            if q.iter().any(|c| c.abs() > scale as i64) {
                return Err((at(&r), format!("normal {v} exceeds the {}-bit scale", lat.normal_bits)));
            }
            d.normals.push(q.map(|c| c as i32));
        }
    }
    if r.overrun() {
        return Err((payload.len(), "the bit stream ends early".into()));
    }
    let used = PAYLOAD_HEADER_BYTES + r.consumed().div_ceil(8) as usize;
    if used != payload.len() {
        return Err((used, format!("{} bytes after the bit stream's end", payload.len() - used)));
    }
    Ok(d)
}

/// Check and decode a node's format-3 payload (the `GEOM` chunk's bytes between frame and CRC).
pub fn decode(ctx: &NodeContext, payload: &[u8]) -> Result<NodeGeometry> {
    let (rec, h) = (ctx.record, ctx.header);
    let x = Expect {
        faces: rec.faces,
        vertices: rec.vertices,
        bits: h.grid.bits,
        materials: h.materials,
        normals: h.attributes.normals,
        uvs: h.attributes.uvs,
        colors: h.attributes.colors,
        clusters: rec.level == 0,
    };
    let d = decode_codes(payload, x).map_err(|(at, msg)| {
        Error::at_byte(
            ctx.path,
            rec.offset + chunk::HEADER_BYTES + at as u64,
            format!("{}: node {}: {msg}", chunk::name(&id::GEOM, rec.offset), ctx.index),
        )
    })?;
    Ok(geometry(d, ctx))
}

/// Decoded codes as floats.
fn geometry(d: Decoded, ctx: &NodeContext) -> NodeGeometry {
    let grid = ctx.header.grid;
    let lat = d.lattice;
    let mut g = NodeGeometry {
        positions: d.points.iter().map(|&p| grid.decode(p)).collect(),
        indices: d.indices,
        material_ranges: d.material_ranges,
        colors: d.colors,
        ..NodeGeometry::default()
    };
    if lat.normal_bits > 0 {
        let scale = octa::scale(lat.normal_bits);
        g.normals = d.normals.iter().map(|&q| octa::decode_at(q, scale as f32)).collect();
    }
    if lat.uv_bits > 0 {
        let s = (1u64 << lat.uv_bits) as f64;
        g.uvs = d.uvs.iter().map(|q| Vec2::new((q[0] as f64 / s) as f32, (q[1] as f64 / s) as f32)).collect();
    }
    if !d.clusters.is_empty() {
        let (base, _) = base_and_span(&d.points);
        let mut first = 0u32;
        for c in &d.clusters {
            // On the grid: decode_codes checked it.
            let center: [u32; 3] = std::array::from_fn(|a| base[a] + ((c.center[a] as u32) << d.cluster_shift));
            g.clusters.push(Cluster {
                cone: Cone { axis: octa::decode(c.axis), half_angle: angle_decode(c.half_angle) },
                center: grid.decode(center),
                radius: grid.length(radius_decode(c.radius)),
                first_face: first,
                face_count: c.faces as u32,
            });
            first += c.faces as u32;
        }
    }
    g
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bumpy grid of `n`² vertices with every attribute, two materials and two clusters.
    fn sample(n: u32, shift: u32) -> (GeometryCodes, Lattice) {
        let lat = Lattice { shift, normal_bits: 10, uv_bits: 12 };
        let mut g = GeometryCodes { lattice: lat, ..GeometryCodes::default() };
        let scale = octa::scale(lat.normal_bits);
        for y in 0..n {
            for x in 0..n {
                let inner = x > 0 && y > 0 && x + 1 < n && y + 1 < n;
                let z = 4000 + ((x * 7 + y * 13) % 29) * 37;
                let p = [x * 300 + 1000, y * 300 + 2000, z];
                g.points.push(if inner { p.map(|c| snap(c, shift, 16)) } else { p });
                g.normals.push([((x as i32 * 37) % (2 * scale)) - scale, ((y as i32 * 11) % scale) as i16 as i32].map(|c| c as i16));
                g.uvs.push([x as f32 / 64.0, y as f32 / 32.0].map(f32::to_bits));
                g.colors.push([x as u8 * 9, y as u8 * 5, 200, 255]);
            }
        }
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = y * n + x;
                g.indices.extend_from_slice(&[v, v + 1, v + n + 1, v, v + n + 1, v + n]);
            }
        }
        let f = g.indices.len() as u32 / 3;
        let half = f / 2;
        g.material_ranges = vec![
            MaterialRange { material: 1, first_index: 0, index_count: 3 * half },
            MaterialRange { material: 0, first_index: 3 * half, index_count: 3 * (f - half) },
        ];
        let c = |faces: u32, k: u16| ClusterCodes {
            axis: [100, -200],
            half_angle: 300 + k,
            faces: faces as u16,
            center: [k, 2, 3],
            radius: 40,
        };
        g.clusters = Some((2, vec![c(half, 0), c(f - half, 9)]));
        (g, lat)
    }

    fn expect(g: &GeometryCodes) -> Expect {
        Expect {
            faces: g.indices.len() as u32 / 3,
            vertices: g.points.len() as u32,
            bits: 16,
            materials: 2,
            normals: true,
            uvs: true,
            colors: true,
            clusters: true,
        }
    }

    #[test]
    fn codes_round_trip_in_the_encoders_order() {
        for shift in [0, 3] {
            let (g, lat) = sample(17, shift);
            let (payload, order) = encode(&g, lat, 16).unwrap();
            let d = decode_codes(&payload, expect(&g)).unwrap();
            assert_eq!(d.points, order.vertices.iter().map(|&v| g.points[v as usize]).collect::<Vec<_>>());
            assert_eq!(d.colors, order.vertices.iter().map(|&v| g.colors[v as usize]).collect::<Vec<_>>());
            let normals: Vec<[i32; 2]> = order.vertices.iter().map(|&v| g.normals[v as usize].map(|c| c as i32)).collect();
            assert_eq!(d.normals, normals);
            let uvs: Vec<[i64; 2]> =
                order.vertices.iter().map(|&v| g.uvs[v as usize].map(|b| (f32::from_bits(b) * 4096.0) as i64)).collect();
            assert_eq!(d.uvs, uvs);
            let mut stored = vec![0u32; g.points.len()];
            for (s, &v) in order.vertices.iter().enumerate() {
                stored[v as usize] = s as u32;
            }
            assert_eq!(d.indices, stored_indices(&g, &order, &stored));
            assert_eq!(d.material_ranges, g.material_ranges);
            assert_eq!((d.cluster_shift, d.clusters.clone()), g.clusters.clone().unwrap());
            // Faces stay within their runs: the first half (material 1, cluster 0) first.
            let half = g.indices.len() / 6;
            assert!(order.faces[..half].iter().all(|&f| (f as usize) < half));
            if shift > 0 {
                let position_bits = |g: &GeometryCodes, lat| encode_with_stats(g, lat, 16).unwrap().2.bits[3];
                let (fine, fine_lat) = sample(17, 0);
                assert!(position_bits(&g, lat) < position_bits(&fine, fine_lat), "a coarser lattice costs fewer bits");
            }
        }
    }

    #[test]
    fn damaged_payloads_are_errors_not_panics() {
        let (g, lat) = sample(9, 2);
        let (payload, _) = encode(&g, lat, 16).unwrap();
        let x = expect(&g);
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut errors = 0;
        for round in 0..4000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let mut p = payload.clone();
            let at = (state % p.len() as u64) as usize;
            p[at] ^= 1 << (round % 8);
            if round % 5 == 0 {
                p.truncate(at.max(1));
            }
            if decode_codes(&p, x).is_err() {
                errors += 1;
            }
        }
        assert!(errors > 2000, "{errors} of 4000 damaged payloads refused");
        let huge = Expect { faces: u32::MAX, vertices: u32::MAX, ..x };
        assert!(decode_codes(&payload, huge).unwrap_err().1.contains("cannot fit"));
        // As many faces as bits: zeros read past the end would decode as faces; refused at the end.
        let many = Expect { faces: 8 * (payload.len() as u32 - 4), vertices: 8 * (payload.len() as u32 - 4), ..x };
        let (at, _) = decode_codes(&payload, many).unwrap_err();
        assert!(at <= payload.len());
    }

    #[test]
    fn a_normal_beyond_i32_is_refused() {
        // Found by review: a residual taking a normal to i32::MIN wrapped past the range check.
        let payload = [
            0x00, 0x0a, 0x00, 0x00, 0x8c, 0x26, 0x36, 0x80, 0x04, 0x00, 0x20, 0x00, 0x8c, 0x88, 0x00, 0x80, 0x04, 0x63, 0xc6, 0x44, 0x00,
            0x00, 0x00, 0x07, 0xff, 0xff, 0xff, 0xfc, 0x20, 0x00, 0x00, 0x11, 0x00, 0x00, 0x00, 0x80,
        ];
        let x = Expect { faces: 1, vertices: 3, bits: 16, materials: 1, normals: true, uvs: false, colors: false, clusters: false };
        assert!(decode_codes(&payload, x).is_err());
    }
}
