//! Node geometry of format 3 (strata-v3.md §5): connectivity by traversal, vertex attributes
//! predicted from it, everything entropy-coded with the file's tables ([`super::rans`]).
//!
//! **Connectivity.** Triangles are decoded by growing a region over the node: its border is a set
//! of loops of directed *open edges*, each remembering the third corner of the triangle that made
//! it. An open edge taken from a queue (the newest edge first, then the others in the order they
//! were made) is a *gate*; one symbol says what lies across it: a new vertex (`VERTEX`), the vertex
//! before or after it along its loop (`LEFT`, `RIGHT`, both: `END`), another decoded vertex by
//! index (`SPLIT`), nothing (`BOUNDARY`), or a triangle of a later run (`SKIP`). Faces must stay
//! in runs (a material range, a culling cluster), so the queue is emptied at each run's start; a
//! run begins from an open edge it skipped earlier or from a new triangle (`START`).
//!
//! **Attributes**, after all connectivity, in vertex order: a vertex made across a gate is
//! predicted by the parallelogram `a + b − c` of the gate's ends and far corner, the others from
//! the vertex before. Vertices on no open edge at the end (inside the node) of a coarse level lie
//! on a lattice of `2^shift` grid steps, and their residuals count lattice steps; the others keep
//! the grid, so that a vertex two nodes share decodes the same in both. Normals are predicted from
//! the decoded surface (face normals summed in f64, in face order) as octahedral codes.
//!
//! [`model`] turns a node into symbols and raw bits (a [`Model`]); the writer counts the symbols
//! of every node, makes the file's tables and codes each model with [`Model::payload`].

use super::bits::{BitReader, BitWriter};
use super::rans::{self, bucket, unbucket, unzigzag, zigzag, DecodeTable, EncodeTable, Freqs, RansReader};
use super::v2::GeometryCodes;
use super::NodeContext;
use crate::error::{Error, Result};
use crate::format::{octa, Cluster, Cone, MaterialRange, NodeGeometry};
use glam::{DVec3, Vec2, Vec3};
use rustc_hash::FxHashMap;

/// Connectivity symbols.
pub mod sym {
    pub const VERTEX: u32 = 0;
    pub const LEFT: u32 = 1;
    pub const RIGHT: u32 = 2;
    pub const END: u32 = 3;
    pub const SPLIT: u32 = 4;
    pub const BOUNDARY: u32 = 5;
    pub const SKIP: u32 = 6;
    /// Symbols of the connectivity alphabets.
    pub const COUNT: usize = 7;
    pub const NAMES: [&str; COUNT] = ["vertex", "left", "right", "end", "split", "boundary", "skip"];
}

/// The file's alphabets (strata-v3.md §4.2), in the order `CODE` stores them.
pub mod alphabet {
    /// Connectivity symbols after each previous symbol (`CONN + s`), and at a node's start
    /// (`CONN + 7`).
    pub const CONN: usize = 0;
    pub const START: usize = 8;
    pub const CORNER: usize = 9;
    pub const SPLIT: usize = 10;
    pub const COUNT: usize = 11;
    pub const SHIFT: usize = 12;
    /// Positions of vertices not made across a gate.
    pub const POS_JUMP: usize = 13;
    pub const NORMAL: usize = 14;
    pub const NORMAL_BORDER: usize = 15;
    /// Colours as luma, the two chroma differences and alpha (YCoCg-R).
    pub const COLOR_Y: usize = 16;
    pub const COLOR_C: usize = 17;
    pub const COLOR_A: usize = 18;
    pub const UV: usize = 19;
    /// Positions of vertices made across a gate, inside the node (`POS_INNER + k`) and on its
    /// border (`POS_BORDER + k`), `k` the bit length of the gate triangle's extent in the units of
    /// the residual (0..=21).
    pub const POS_INNER: usize = 20;
    pub const POS_BORDER: usize = 42;
    pub const ALPHABETS: usize = 64;
    pub const NAMES: [&str; 20] = [
        "conn/vertex",
        "conn/left",
        "conn/right",
        "conn/end",
        "conn/split",
        "conn/boundary",
        "conn/skip",
        "conn/first",
        "start",
        "corner",
        "split",
        "count",
        "shift",
        "pos/jump",
        "normal",
        "normal/border",
        "color/y",
        "color/c",
        "color/a",
        "uv",
    ];
}
use alphabet as a;

/// Categories of [`Stats::bits`].
pub const STAT_NAMES: [&str; 7] = ["connectivity", "indices", "positions", "normals", "colors", "uvs", "meta"];

/// The [`STAT_NAMES`] category of an alphabet.
pub fn category(alphabet: usize) -> usize {
    match alphabet {
        a::POS_INNER.. => 2,
        0..=7 => 0,
        a::START | a::CORNER | a::SPLIT => 1,
        a::POS_JUMP => 2,
        a::NORMAL | a::NORMAL_BORDER => 3,
        a::COLOR_Y | a::COLOR_C | a::COLOR_A => 4,
        a::UV => 5,
        _ => 6,
    }
}

/// The name of alphabet `al`.
pub fn alphabet_name(al: usize) -> String {
    match al {
        a::POS_BORDER.. => format!("pos/border/{}", al - a::POS_BORDER),
        a::POS_INNER.. => format!("pos/inner/{}", al - a::POS_INNER),
        _ => a::NAMES[al].to_string(),
    }
}

/// The position alphabet of a vertex predicted across the gate triangle `(qa, qb, qc)`.
#[inline(always)]
fn position_alphabet(border: bool, lattice: bool, shift: u32, qa: [u32; 3], qb: [u32; 3], qc: [u32; 3]) -> usize {
    let mut extent = 0u32;
    for k in 0..3 {
        let (lo, hi) = (qa[k].min(qb[k]).min(qc[k]), qa[k].max(qb[k]).max(qc[k]));
        extent = extent.max(hi - lo);
    }
    if lattice {
        extent >>= shift;
    }
    let ctx = (32 - extent.leading_zeros()).min(21) as usize;
    if border {
        a::POS_BORDER + ctx
    } else {
        a::POS_INNER + ctx
    }
}

/// Quantized UVs lie strictly within ±2^30 steps.
const UV_LIMIT: i64 = 1 << 30;
/// How far back the encoder looks among skipped edges for one to start a run from.
const START_SCAN: usize = 4096;
const NONE: u32 = u32::MAX;

/// The file's coding tables (`CODE`, strata-v3.md §4.3): bits per normal coordinate and the
/// frequencies of every alphabet.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CodeTables {
    /// Bits of each octahedral normal coordinate (2..=16), 0 without normals.
    pub normal_bits: u32,
    /// Bits of each colour channel (1..=8), 0 without colours.
    pub color_bits: u32,
    pub freqs: Vec<Freqs>,
}

/// [`CodeTables`] ready to decode with.
pub struct Decoder {
    pub normal_bits: u32,
    pub color_bits: u32,
    tables: Vec<DecodeTable>,
}

impl Decoder {
    pub fn new(t: &CodeTables) -> Decoder {
        let mut tables: Vec<DecodeTable> = t.freqs.iter().map(DecodeTable::new).collect();
        tables.resize_with(a::ALPHABETS, || DecodeTable::new(&Freqs::default()));
        Decoder { normal_bits: t.normal_bits, color_bits: t.color_bits, tables }
    }
}

/// The file's tables as stored, and ready to decode with.
pub struct Code {
    pub tables: CodeTables,
    pub decoder: Decoder,
}

impl Code {
    pub fn new(tables: CodeTables) -> Code {
        Code { decoder: Decoder::new(&tables), tables }
    }
}

impl PartialEq for Code {
    fn eq(&self, other: &Code) -> bool {
        self.tables == other.tables
    }
}

impl std::fmt::Debug for Code {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.tables.fmt(f)
    }
}

impl CodeTables {
    /// Tables fitted to `counts` (per alphabet, per symbol), as the writer makes them.
    pub fn fit(normal_bits: u32, color_bits: u32, counts: &[Vec<u64>]) -> CodeTables {
        CodeTables {
            normal_bits,
            color_bits,
            freqs: (0..a::ALPHABETS).map(|k| Freqs::from_counts(counts.get(k).map_or(&[][..], |c| c))).collect(),
        }
    }

    /// The `CODE` payload: normal bits, colour bits, two reserved bytes, the alphabet count, then
    /// each alphabet's symbol count (u16) and frequencies (u16 each).
    pub fn encode(&self) -> Vec<u8> {
        let mut out = vec![self.normal_bits as u8, self.color_bits as u8, 0, 0];
        out.extend_from_slice(&(self.freqs.len() as u32).to_le_bytes());
        for f in &self.freqs {
            out.extend_from_slice(&(f.0.len() as u16).to_le_bytes());
            for &x in &f.0 {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        out
    }

    /// Decode and check a `CODE` payload; an error says what and at which byte.
    pub fn decode(p: &[u8], normals: bool, colors: bool) -> std::result::Result<CodeTables, (usize, String)> {
        if p.len() < 8 {
            return Err((0, format!("{} bytes; at least 8", p.len())));
        }
        let normal_bits = p[0] as u32;
        if normals != (normal_bits != 0) || (normals && !(2..=16).contains(&normal_bits)) {
            return Err((
                0,
                format!("normal bits {normal_bits}; the file {} normals (2..=16 bits)", if normals { "has" } else { "has no" }),
            ));
        }
        let color_bits = p[1] as u32;
        if colors != (color_bits != 0) || color_bits > 8 {
            return Err((1, format!("colour bits {color_bits}; the file {} colours (1..=8 bits)", if colors { "has" } else { "has no" })));
        }
        if p[2..4] != [0, 0] {
            return Err((2, "reserved bytes are not zero".into()));
        }
        let n = u32::from_le_bytes(p[4..8].try_into().expect("4 bytes")) as usize;
        if n != a::ALPHABETS {
            return Err((4, format!("{n} alphabets; format 3 has {}", a::ALPHABETS)));
        }
        let mut at = 8usize;
        let mut freqs = Vec::with_capacity(n);
        for k in 0..n {
            let start = at;
            let count = p.get(at..at + 2).map(|b| u16::from_le_bytes([b[0], b[1]]) as usize).ok_or((at, "ends early".to_string()))?;
            at += 2;
            if count > rans::MAX_SYMBOLS {
                return Err((start, format!("alphabet {k} ({}): {count} symbols, at most {}", alphabet_name(k), rans::MAX_SYMBOLS)));
            }
            let bytes = p.get(at..at + 2 * count).ok_or((at, format!("alphabet {k} ({}) ends early", alphabet_name(k))))?;
            let f = Freqs(bytes.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect());
            f.check().map_err(|m| (start, format!("alphabet {k} ({}): {m}", alphabet_name(k))))?;
            at += 2 * count;
            freqs.push(f);
        }
        if at != p.len() {
            return Err((at, format!("{} bytes after the last alphabet", p.len() - at)));
        }
        Ok(CodeTables { normal_bits, color_bits, freqs })
    }
}

/// Per alphabet and symbol, the bits a symbol of frequency `f` costs under `freqs`:
/// `log2(PROB_SCALE / f)` (a symbol of frequency 0 as if it were 1).
pub fn symbol_costs(freqs: &[Freqs]) -> Vec<Vec<f64>> {
    freqs.iter().map(|f| f.0.iter().map(|&x| (rans::PROB_SCALE as f64 / x.max(1) as f64).log2()).collect()).collect()
}

/// A node as symbols and raw bits, before the file's tables code it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Model {
    /// (alphabet, symbol), in the order a reader decodes them.
    pub symbols: Vec<(u8, u8)>,
    /// The raw bits, most significant first, and how many.
    pub raw: Vec<u8>,
    pub raw_bits: u64,
    /// Raw bits by alphabet.
    pub raw_by_alphabet: Vec<u64>,
}

impl Model {
    /// Add this model's symbols to `counts` (per alphabet, per symbol).
    pub fn count(&self, counts: &mut [Vec<u64>]) {
        for &(al, s) in &self.symbols {
            let c = &mut counts[al as usize];
            if c.len() <= s as usize {
                c.resize(s as usize + 1, 0);
            }
            c[s as usize] += 1;
        }
    }

    /// The node's payload: the symbol stream's length (LEB128), the symbol stream, the raw bits.
    pub fn payload(&self, tables: &[EncodeTable]) -> std::result::Result<Vec<u8>, String> {
        let stream = rans::encode(&self.symbols, tables)?;
        let mut out = Vec::with_capacity(stream.len() + self.raw.len() + 5);
        let mut n = stream.len() as u64;
        loop {
            let byte = (n & 0x7F) as u8;
            n >>= 7;
            out.push(if n > 0 { byte | 0x80 } else { byte });
            if n == 0 {
                break;
            }
        }
        out.extend_from_slice(&stream);
        out.extend_from_slice(&self.raw);
        Ok(out)
    }

    /// Bits by alphabet under `costs` ([`symbol_costs`]), plus its raw bits.
    pub fn bits(&self, costs: &[Vec<f64>]) -> Vec<f64> {
        let mut out: Vec<f64> = self.raw_by_alphabet.iter().map(|&b| b as f64).collect();
        out.resize(a::ALPHABETS, 0.0);
        let rarest = (rans::PROB_SCALE as f64).log2();
        for &(al, s) in &self.symbols {
            out[al as usize] += costs[al as usize].get(s as usize).copied().unwrap_or(rarest);
        }
        out
    }

    /// Serialized for a spill file: symbol count, raw bit count, categories, symbols, raw bytes.
    pub fn to_bytes(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&(self.symbols.len() as u64).to_le_bytes());
        out.extend_from_slice(&self.raw_bits.to_le_bytes());
        for k in 0..a::ALPHABETS {
            out.extend_from_slice(&self.raw_by_alphabet.get(k).copied().unwrap_or(0).to_le_bytes());
        }
        for &(al, s) in &self.symbols {
            out.extend_from_slice(&[al, s]);
        }
        out.extend_from_slice(&self.raw);
    }

    /// Read back what [`Model::to_bytes`] wrote at the start of `b`; the bytes it took.
    pub fn from_bytes(b: &[u8]) -> Option<(Model, usize)> {
        let u = |at: usize| b.get(at..at + 8).map(|x| u64::from_le_bytes(x.try_into().expect("8 bytes")));
        let n = u(0)? as usize;
        let raw_bits = u(8)?;
        let mut raw_by_alphabet = vec![0u64; a::ALPHABETS];
        for (k, c) in raw_by_alphabet.iter_mut().enumerate() {
            *c = u(16 + 8 * k)?;
        }
        let at = 16 + 8 * a::ALPHABETS;
        let symbols = b.get(at..at + 2 * n)?.chunks_exact(2).map(|x| (x[0], x[1])).collect();
        let raw_len = raw_bits.div_ceil(8) as usize;
        let raw = b.get(at + 2 * n..at + 2 * n + raw_len)?.to_vec();
        Some((Model { symbols, raw, raw_bits, raw_by_alphabet }, at + 2 * n + raw_len))
    }
}

/// Where the bits of many nodes went, for benches and tuning.
#[derive(Clone, Debug, Default)]
pub struct Stats {
    pub bits: [f64; 7],
    pub connectivity: [u64; sym::COUNT],
    pub starts: u64,
    pub new_triangles: u64,
}

/// The order [`model`] chose: the input face stored k-th is `faces[k]`, its corners rotated left
/// by `rotation[k]`; the input vertex stored k-th is `vertices[k]`.
#[derive(Clone, Debug, Default)]
pub struct Order {
    pub faces: Vec<u32>,
    pub rotation: Vec<u8>,
    pub vertices: Vec<u32>,
}

/// How a vertex is predicted, in stored indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pred {
    /// The parallelogram `a + b − c`.
    Para(u32, u32, u32),
    /// The vertex before, or the middle of the node's box for the first.
    Jump(u32),
}

/// The traversal state both sides keep (strata-v3.md §5.3): open edges as loops, each with its
/// ends, far corner and links; whether it is open, closed by a triangle across it, or closed by
/// `BOUNDARY`.
#[derive(Clone, Copy)]
struct Edge {
    v0: u32,
    v1: u32,
    opp: u32,
    prev: u32,
    next: u32,
    state: u8,
}

#[derive(Default)]
struct Front {
    e: Vec<Edge>,
}

const OPEN: u8 = 0;
const ZIPPED: u8 = 1;
const CLOSED: u8 = 2;

impl Front {
    fn with_capacity(n: usize) -> Front {
        Front { e: Vec::with_capacity(n) }
    }

    #[inline(always)]
    fn make(&mut self, v0: u32, v1: u32, opp: u32, prev: u32, next: u32) -> u32 {
        let e = self.e.len() as u32;
        self.e.push(Edge { v0, v1, opp, prev, next, state: OPEN });
        e
    }

    /// A triangle `(a, b, c)` that shares no open edge: a loop of its three edges.
    fn start(&mut self, t: [u32; 3]) -> u32 {
        let e = self.e.len() as u32;
        self.make(t[0], t[1], t[2], e + 2, e + 1);
        self.make(t[1], t[2], t[0], e, e + 2);
        self.make(t[2], t[0], t[1], e + 1, e);
        e
    }

    /// Triangle `(b, a, x)` across gate `e = (a, b)` by `s` (`VERTEX`, `SPLIT`, `LEFT`, `RIGHT`,
    /// `END`); returns the edge to take next (or [`NONE`]) and an edge for the queue (or NONE).
    #[inline(always)]
    fn across(&mut self, e: u32, s: u32, x: u32) -> (u32, u32) {
        let g = &mut self.e[e as usize];
        g.state = ZIPPED;
        let (a, b, p, n) = (g.v0, g.v1, g.prev, g.next);
        match s {
            sym::LEFT => {
                self.e[p as usize].state = ZIPPED;
                let pp = self.e[p as usize].prev;
                let e1 = self.make(x, b, a, pp, n);
                self.e[pp as usize].next = e1;
                self.e[n as usize].prev = e1;
                (e1, NONE)
            }
            sym::RIGHT => {
                self.e[n as usize].state = ZIPPED;
                let nn = self.e[n as usize].next;
                let e1 = self.make(a, x, b, p, nn);
                self.e[p as usize].next = e1;
                self.e[nn as usize].prev = e1;
                (e1, NONE)
            }
            sym::END => {
                self.e[p as usize].state = ZIPPED;
                self.e[n as usize].state = ZIPPED;
                let (pp, nn) = (self.e[p as usize].prev, self.e[n as usize].next);
                self.e[pp as usize].next = nn;
                self.e[nn as usize].prev = pp;
                (NONE, NONE)
            }
            _ => {
                let e1 = self.make(a, x, b, p, NONE);
                let e2 = self.make(x, b, a, e1, n);
                self.e[e1 as usize].next = e2;
                self.e[p as usize].next = e1;
                self.e[n as usize].prev = e2;
                (e1, e2)
            }
        }
    }

    /// Which of `n` vertices lie on an edge not closed by a triangle across it.
    fn border(&self, n: usize) -> Vec<bool> {
        let mut border = vec![false; n];
        for e in &self.e {
            if e.state != ZIPPED {
                border[e.v0 as usize] = true;
                border[e.v1 as usize] = true;
            }
        }
        border
    }
}

/// How a node's codes are quantized beyond the grid, as the writer chose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Lattice {
    /// Vertices inside the node lie on multiples of `2^shift` grid steps.
    pub shift: u32,
    /// Bits of each octahedral normal coordinate (2..=16; scale `2^(bits−1) − 1`), 0 without normals.
    pub normal_bits: u32,
    /// UVs are multiples of `2^−uv_bits`; 0 without UVs.
    pub uv_bits: u32,
    /// Bits of each colour channel (1..=8), 0 without colours.
    pub color_bits: u32,
}

/// A colour channel at `bits` (1..=8): `q = ⌊(c·(2^bits − 1) + 127) / 255⌋`.
#[inline]
pub fn color_quantize(c: u8, bits: u32) -> i64 {
    let m = (1i64 << bits) - 1;
    (c as i64 * m + 127) / 255
}

/// The byte a quantized channel stands for: `⌊(q·255 + ⌊(2^bits − 1)/2⌋) / (2^bits − 1)⌋`.
#[inline]
pub fn color_value(q: i64, bits: u32) -> u8 {
    let m = (1i64 << bits) - 1;
    ((q * 255 + (m >> 1)) / m) as u8
}

/// RGBA (quantized channels) as luma, chroma differences and alpha (YCoCg-R, lossless).
#[inline]
fn ycocg(c: [i64; 4]) -> [i64; 4] {
    let co = c[0] - c[2];
    let t = c[2] + (co >> 1);
    let cg = c[1] - t;
    [t + (cg >> 1), co, cg, c[3]]
}

/// The inverse of [`ycocg`].
#[inline]
fn rgba(y: [i64; 4]) -> [i64; 4] {
    let t = y[0] - (y[2] >> 1);
    let g = y[2] + t;
    let b = t - (y[1] >> 1);
    [b + y[1], g, b, y[3]]
}

/// The lattice point of `shift` nearest `g`, kept below `2^bits`.
pub fn snap(g: u32, shift: u32, bits: u32) -> u32 {
    if shift == 0 {
        return g;
    }
    let top = ((1u64 << bits) - 1) >> shift << shift;
    ((((g as u64) + (1 << (shift - 1))) >> shift << shift).min(top)) as u32
}

/// The lattice point below-or-nearest: `(p + 2^(shift−1)) >> shift`.
#[inline(always)]
fn lattice_of(p: i64, shift: u32) -> i64 {
    (p + ((1i64 << shift) >> 1)) >> shift
}

/// The octahedral code, at `scale`, of the direction `(x, y, z)`: the prediction every reader
/// computes bit for bit (f64, IEEE operations in this order).
#[inline]
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
    [floor(px * s + 0.5), floor(py * s + 0.5)]
}

/// `⌊v⌋` for `|v| < 2^31`, without a library call.
#[inline(always)]
fn floor(v: f64) -> i32 {
    let t = v as i32;
    t - ((t as f64) > v) as i32
}

/// The cross product of a face's edges from its first corner, on the grid, as §5.5 computes it:
/// exact in f64 (components below 2^43 on a 21-bit grid), so the same for any rotation of the
/// corners and any order of summing.
#[inline]
pub fn face_cross(q: [[u32; 3]; 3]) -> [f64; 3] {
    let u = [0, 1, 2].map(|k| q[1][k] as f64 - q[0][k] as f64);
    let w = [0, 1, 2].map(|k| q[2][k] as f64 - q[0][k] as f64);
    [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]]
}

/// Each vertex's predicted normal: the sum over faces, in face order, of [`face_cross`], added
/// to each corner in turn (f64).
fn normal_sums(p: &[[u32; 3]], t: &[u32]) -> Vec<[f64; 3]> {
    let mut sum = vec![[0f64; 3]; p.len()];
    for f in t.chunks_exact(3) {
        let n = face_cross([p[f[0] as usize], p[f[1] as usize], p[f[2] as usize]]);
        for &i in f {
            let s = &mut sum[i as usize];
            s[0] += n[0];
            s[1] += n[1];
            s[2] += n[2];
        }
    }
    sum
}

/// What decoding a payload needs from outside it.
#[derive(Clone, Copy, Debug)]
pub struct Expect {
    pub level: u32,
    pub faces: u32,
    pub vertices: u32,
    /// Grid bits.
    pub bits: u32,
    pub materials: u32,
    pub normals: bool,
    pub uvs: bool,
    pub colors: bool,
    /// The node's box, grid points.
    pub min: [u32; 3],
    pub max: [u32; 3],
}

/// A node's decoded codes, before positions and normals become floats.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Decoded {
    pub shift: u32,
    pub uv_bits: u32,
    pub points: Vec<[u32; 3]>,
    /// Octahedral codes at the file's normal scale.
    pub normals: Vec<[i32; 2]>,
    /// UVs in steps of `2^−uv_bits`.
    pub uvs: Vec<[i64; 2]>,
    pub colors: Vec<[u8; 4]>,
    pub indices: Vec<u32>,
    pub material_ranges: Vec<MaterialRange>,
    /// Level 0: each culling cluster's face count.
    pub clusters: Vec<u32>,
}

/// A decoding failure: what, and at which byte of the payload.
pub type Fault = (usize, String);

struct In<'a> {
    r: RansReader<'a>,
    raw: BitReader<'a>,
    d: &'a Decoder,
    base: usize,
}

impl In<'_> {
    #[inline(always)]
    fn sym(&mut self, al: usize) -> u32 {
        self.r.get(&self.d.tables[al])
    }

    /// A value of a residual alphabet.
    #[inline(always)]
    fn value(&mut self, al: usize) -> std::result::Result<u32, Fault> {
        let s = self.sym(al);
        if s as usize >= rans::BUCKETS {
            return Err(self.fault(format!("symbol {s} of alphabet {} is not a value", alphabet_name(al))));
        }
        let raw = &mut self.raw;
        Ok(unbucket(s, |k| raw.get_any(k)))
    }

    #[inline(always)]
    fn signed(&mut self, al: usize) -> std::result::Result<i32, Fault> {
        Ok(unzigzag(self.value(al)?))
    }

    fn fault(&self, msg: String) -> Fault {
        (self.base + self.r.position().min(usize::MAX - self.base), msg)
    }
}

/// Decode a node's payload into codes.
pub fn decode_codes(payload: &[u8], x: Expect, dec: &Decoder) -> std::result::Result<Decoded, Fault> {
    let (nf, nv) = (x.faces as usize, x.vertices as usize);
    // LEB128 length of the symbol stream.
    let mut len = 0u64;
    let mut at = 0usize;
    loop {
        let b = *payload.get(at).ok_or((at, "the payload ends in its symbol stream's length".to_string()))?;
        if at == 9 {
            return Err((at, "the symbol stream's length runs past 10 bytes".into()));
        }
        len |= ((b & 0x7F) as u64) << (7 * at);
        at += 1;
        if b & 0x80 == 0 {
            break;
        }
    }
    let end = (at as u64)
        .checked_add(len)
        .filter(|&e| e <= payload.len() as u64)
        .ok_or((0, format!("a symbol stream of {len} bytes runs past the payload's {}", payload.len())))? as usize;
    // Each face takes at least one symbol, and a symbol at least 1/44 bit (rans::MAX_FREQ): bound
    // the work by the bytes before allocating.
    let most = rans::MAX_SYMBOLS_PER_BYTE * (len + 4);
    if (nf > 0 && nv == 0) || nv > 3 * nf || nf as u64 > most {
        return Err((0, format!("{nf} faces and {nv} vertices cannot fit in {} bytes", payload.len())));
    }
    let mut input = In { r: RansReader::new(&payload[at..end]), raw: BitReader::new(&payload[end..]), d: dec, base: at };
    let top = (1i64 << x.bits) - 1;
    let mut d = Decoded::default();

    // Header: lattice shift, UV bits, material ranges, clusters.
    if x.level > 0 {
        d.shift = input.sym(a::SHIFT);
        if d.shift >= x.bits {
            return Err(input.fault(format!("lattice shift {} on a {}-bit grid", d.shift, x.bits)));
        }
    }
    if x.uvs {
        d.uv_bits = input.value(a::COUNT)?;
        if !(1..=24).contains(&d.uv_bits) {
            return Err(input.fault(format!("UV bits {} (1..=24)", d.uv_bits)));
        }
    }
    let ranges = input.value(a::COUNT)? as u64 + 1;
    if ranges > nf.max(1) as u64 {
        return Err(input.fault(format!("{ranges} material ranges for {nf} faces")));
    }
    let mut first = 0u64;
    for k in 0..ranges {
        let material = input.value(a::COUNT)?;
        if material >= x.materials {
            return Err(input.fault(format!("material {material} of {}", x.materials)));
        }
        let faces = if k + 1 == ranges { nf as u64 - first } else { input.value(a::COUNT)? as u64 + 1 };
        if first + faces > nf as u64 || faces == 0 {
            return Err(input.fault(format!("material ranges cover more than {nf} faces")));
        }
        d.material_ranges.push(MaterialRange { material, first_index: 3 * first as u32, index_count: 3 * faces as u32 });
        first += faces;
    }
    if x.level == 0 {
        let count = input.value(a::COUNT)? as u64 + 1;
        if count > nf.max(1) as u64 {
            return Err(input.fault(format!("{count} clusters for {nf} faces")));
        }
        let mut covered = 0u64;
        for k in 0..count {
            let faces = if k + 1 == count { nf as u64 - covered } else { input.value(a::COUNT)? as u64 + 1 };
            if covered + faces > nf as u64 || faces == 0 {
                return Err(input.fault(format!("clusters cover more than {nf} faces")));
            }
            d.clusters.push(faces as u32);
            covered += faces;
        }
    }
    // Runs: the faces between consecutive boundaries of material ranges and clusters.
    let mut cuts: Vec<u32> = d.material_ranges.iter().map(|r| r.first_index / 3).collect();
    let mut c = 0u32;
    for &n in &d.clusters {
        cuts.push(c);
        c += n;
    }
    cuts.push(nf as u32);
    cuts.sort_unstable();
    cuts.dedup();

    // Connectivity.
    let mut front = Front::with_capacity(2 * nf + 8);
    let mut preds: Vec<Pred> = Vec::with_capacity(nv);
    let mut indices: Vec<u32> = Vec::with_capacity(3 * nf);
    let mut queue: Vec<u32> = Vec::with_capacity(nf + 8);
    let mut skipped: Vec<u32> = Vec::new();
    let mut ctx = 7usize;
    for w in cuts.windows(2) {
        let mut left = w[1] - w[0];
        queue.clear();
        let (mut head, mut pending) = (0usize, NONE);
        while left > 0 {
            let e = if pending != NONE {
                std::mem::replace(&mut pending, NONE)
            } else if head < queue.len() {
                head += 1;
                queue[head - 1]
            } else {
                let s = input.value(a::START)?;
                if s == 0 {
                    let mut t = [0u32; 3];
                    for k in 0..3 {
                        let c = input.value(a::CORNER)?;
                        t[k] = if c == 0 {
                            let v = preds.len() as u32;
                            if v as usize >= nv {
                                return Err(input.fault(format!("more than {nv} vertices")));
                            }
                            preds.push(Pred::Jump(v.wrapping_sub(1)));
                            v
                        } else {
                            let back = c - 1;
                            if back as usize >= preds.len() {
                                return Err(input.fault(format!("a corner {back} vertices back of {}", preds.len())));
                            }
                            preds.len() as u32 - 1 - back
                        };
                    }
                    let e = front.start(t);
                    queue.extend_from_slice(&[e, e + 1, e + 2]);
                    indices.extend_from_slice(&t);
                    left -= 1;
                    continue;
                }
                let k = (s - 1) as usize;
                let e =
                    *skipped.iter().rev().nth(k).ok_or_else(|| input.fault(format!("start from skipped edge {k} of {}", skipped.len())))?;
                if front.e[e as usize].state != OPEN {
                    return Err(input.fault("start from an edge that is closed".to_string()));
                }
                // The gate must make a triangle: read its symbol here.
                let s = input.sym(a::CONN + ctx);
                if !matches!(s, sym::VERTEX..=sym::SPLIT) {
                    return Err(input.fault(format!("a run starts with {}", sym::NAMES.get(s as usize).unwrap_or(&"an unknown symbol"))));
                }
                ctx = s as usize;
                let (next, q) = gate(&mut front, &mut input, &mut preds, &mut indices, e, s, nv)?;
                pending = next;
                if q != NONE {
                    queue.push(q);
                }
                left -= 1;
                continue;
            };
            if front.e[e as usize].state != OPEN {
                continue;
            }
            let s = input.sym(a::CONN + ctx);
            match s {
                sym::BOUNDARY => {
                    front.e[e as usize].state = CLOSED;
                }
                sym::SKIP => skipped.push(e),
                sym::VERTEX..=sym::SPLIT => {
                    let (next, q) = gate(&mut front, &mut input, &mut preds, &mut indices, e, s, nv)?;
                    pending = next;
                    if q != NONE {
                        queue.push(q);
                    }
                    left -= 1;
                }
                _ => return Err(input.fault(format!("connectivity symbol {s}"))),
            }
            ctx = s as usize;
        }
    }
    if preds.len() != nv {
        return Err(input.fault(format!("{} vertices, the node record says {nv}", preds.len())));
    }
    let border = front.border(nv);
    drop(front);

    // Positions.
    let shift = d.shift;
    let mid = [0, 1, 2].map(|k| (x.min[k] as i64 + x.max[k] as i64) >> 1);
    let mut points: Vec<[u32; 3]> = Vec::with_capacity(nv);
    for v in 0..nv {
        let (p, al, lattice) = match preds[v] {
            Pred::Para(pa, pb, pc) => {
                let (qa, qb, qc) = (points[pa as usize], points[pb as usize], points[pc as usize]);
                let p = [0, 1, 2].map(|k| (qa[k] as i64 + qb[k] as i64 - qc[k] as i64).clamp(0, top));
                let inner = shift > 0 && !border[v];
                (p, position_alphabet(border[v], inner, shift, qa, qb, qc), inner)
            }
            Pred::Jump(prev) => {
                let p = if prev == NONE { mid } else { points[prev as usize].map(|c| c as i64) };
                (p, a::POS_JUMP, shift > 0 && !border[v])
            }
        };
        let mut q = [0u32; 3];
        for k in 0..3 {
            let r = input.signed(al)? as i64;
            let c = if lattice { (lattice_of(p[k], shift) + r) << shift } else { p[k] + r };
            if !(0..=top).contains(&c) {
                return Err(input.fault(format!("vertex {v} lies off the {}-bit grid", x.bits)));
            }
            q[k] = c as u32;
        }
        points.push(q);
    }

    // Normals.
    if x.normals {
        let scale = octa::scale(dec.normal_bits);
        let sums = normal_sums(&points, &indices);
        d.normals.reserve(nv);
        for v in 0..nv {
            let s = sums[v];
            let p = predict_octa(s[0], s[1], s[2], scale);
            let al = if border[v] { a::NORMAL_BORDER } else { a::NORMAL };
            let q = [p[0] as i64 + input.signed(al)? as i64, p[1] as i64 + input.signed(al)? as i64];
            if q.iter().any(|c| c.abs() > scale as i64) {
                return Err(input.fault(format!("normal {v} exceeds the {}-bit scale", dec.normal_bits)));
            }
            d.normals.push(q.map(|c| c as i32));
        }
    }
    if x.colors {
        let cb = dec.color_bits;
        let m = (1i64 << cb) - 1;
        let mut ys: Vec<[i64; 4]> = Vec::with_capacity(nv);
        d.colors.reserve(nv);
        for v in 0..nv {
            let p = predict(preds[v], |i| ys[i as usize], [0; 4], -m, m);
            let mut y = [0i64; 4];
            for k in 0..4 {
                let al = [a::COLOR_Y, a::COLOR_C, a::COLOR_C, a::COLOR_A][k];
                y[k] = p[k] + input.signed(al)? as i64;
            }
            let c = rgba(y);
            if c.iter().any(|&q| !(0..=m).contains(&q)) || y[1].abs() > m || y[2].abs() > m {
                return Err(input.fault(format!("colour of vertex {v} beyond {cb} bits")));
            }
            ys.push(y);
            d.colors.push(c.map(|q| color_value(q, cb)));
        }
    }
    if x.uvs {
        d.uvs.reserve(nv);
        for v in 0..nv {
            let p = predict(preds[v], |i| d.uvs[i as usize], [0; 2], 1 - UV_LIMIT, UV_LIMIT - 1);
            let q = [p[0] + input.signed(a::UV)? as i64, p[1] + input.signed(a::UV)? as i64];
            if q.iter().any(|c| c.abs() >= UV_LIMIT) {
                return Err(input.fault(format!("UV {v} exceeds ±2^30 steps")));
            }
            d.uvs.push(q);
        }
    }
    input.r.finish().map_err(|m| (end, m))?;
    let used = input.raw.consumed().div_ceil(8) as usize;
    if input.raw.overrun() || used != payload.len() - end {
        return Err((payload.len(), format!("raw bits end at byte {} of {}", end + used, payload.len())));
    }
    d.points = points;
    d.indices = indices;
    Ok(d)
}

/// What `pred` predicts of an attribute `get` reads per stored vertex: the parallelogram clamped
/// to `lo..=hi`, the vertex before, or `first`.
#[inline(always)]
fn predict<const N: usize>(pred: Pred, get: impl Fn(u32) -> [i64; N], first: [i64; N], lo: i64, hi: i64) -> [i64; N] {
    match pred {
        Pred::Para(x, y, z) => {
            let (p, q, r) = (get(x), get(y), get(z));
            std::array::from_fn(|k| (p[k] + q[k] - r[k]).clamp(lo, hi))
        }
        Pred::Jump(NONE) => first,
        Pred::Jump(v) => get(v),
    }
}

/// Decode a triangle across gate `e` by symbol `s`.
#[inline(always)]
fn gate(
    front: &mut Front,
    input: &mut In,
    preds: &mut Vec<Pred>,
    indices: &mut Vec<u32>,
    e: u32,
    s: u32,
    nv: usize,
) -> std::result::Result<(u32, u32), Fault> {
    let ei = e as usize;
    let (va, vb) = (front.e[ei].v0, front.e[ei].v1);
    let x = match s {
        sym::VERTEX => {
            let v = preds.len() as u32;
            if v as usize >= nv {
                return Err(input.fault(format!("more than {nv} vertices")));
            }
            preds.push(Pred::Para(va, vb, front.e[ei].opp));
            v
        }
        sym::SPLIT => {
            let back = input.value(a::SPLIT)?;
            if back as usize >= preds.len() {
                return Err(input.fault(format!("a split {back} vertices back of {}", preds.len())));
            }
            preds.len() as u32 - 1 - back
        }
        sym::LEFT => {
            let p = front.e[ei].prev as usize;
            if front.e[p].state != OPEN || p == ei {
                return Err(input.fault("LEFT of a closed edge".into()));
            }
            front.e[p].v0
        }
        sym::RIGHT => {
            let n = front.e[ei].next as usize;
            if front.e[n].state != OPEN || n == ei {
                return Err(input.fault("RIGHT of a closed edge".into()));
            }
            front.e[n].v1
        }
        _ => {
            let (p, n) = (front.e[ei].prev as usize, front.e[ei].next as usize);
            if front.e[p].state != OPEN || front.e[n].state != OPEN || p == n || p == ei || front.e[p].v0 != front.e[n].v1 {
                return Err(input.fault("END where the loop does not close".into()));
            }
            front.e[p].v0
        }
    };
    if x == va || x == vb {
        return Err(input.fault(format!("a triangle across edge ({va}, {vb}) repeats a corner")));
    }
    indices.extend_from_slice(&[vb, va, x]);
    Ok(front.across(e, s, x))
}

/// Check and decode a node's format-3 payload.
pub fn decode(ctx: &NodeContext, payload: &[u8], dec: &Decoder) -> Result<NodeGeometry> {
    let (rec, h) = (ctx.record, ctx.header);
    let x = Expect {
        level: rec.level,
        faces: rec.faces,
        vertices: rec.vertices,
        bits: h.grid.bits,
        materials: h.materials,
        normals: h.attributes.normals,
        uvs: h.attributes.uvs,
        colors: h.attributes.colors,
        min: ctx.bounds[0],
        max: ctx.bounds[1],
    };
    let d = decode_codes(payload, x, dec)
        .map_err(|(at, msg)| Error::at_byte(ctx.path, rec.offset + at as u64, format!("node {}'s geometry: {msg}", ctx.index)))?;
    Ok(geometry(d, ctx, dec.normal_bits))
}

/// Decoded codes as floats; culling clusters with the node's cone and sphere.
pub fn geometry(d: Decoded, ctx: &NodeContext, normal_bits: u32) -> NodeGeometry {
    let grid = ctx.header.grid;
    let positions: Vec<Vec3> = d.points.iter().map(|&p| grid.decode(p)).collect();
    let mut g = NodeGeometry { material_ranges: d.material_ranges, colors: d.colors, ..NodeGeometry::default() };
    if !d.normals.is_empty() {
        let scale = octa::scale(normal_bits) as f32;
        g.normals = d.normals.iter().map(|&q| octa::decode_at(q, scale)).collect();
    }
    if d.uv_bits > 0 {
        let s = (1u64 << d.uv_bits) as f64;
        g.uvs = d.uvs.iter().map(|q| Vec2::new((q[0] as f64 / s) as f32, (q[1] as f64 / s) as f32)).collect();
    }
    // Format 3 stores no cluster bounds: each cluster gets the node's cone and sphere, which hold
    // it; [`cluster_bounds`] computes tight ones for a reader that culls by cluster.
    let mut first = 0u32;
    let node_cone = ctx.record.cone;
    for &n in &d.clusters {
        g.clusters.push(Cluster {
            cone: node_cone,
            center: ctx.record.center,
            radius: ctx.record.radius,
            first_face: first,
            face_count: n,
        });
        first += n;
    }
    g.positions = positions;
    g.indices = d.indices;
    g
}

/// A cone and sphere holding faces `t` (format 3 stores only clusters' face counts): the axis
/// along the sum of their unit normals, the half-angle to the farthest normal, the sphere around
/// the middle of their box; widened a little so that f32 checks hold.
pub fn cluster_bounds(p: &[Vec3], t: &[u32], first_face: u32) -> Cluster {
    let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
    let mut normals = Vec::with_capacity(t.len() / 3);
    let mut sum = DVec3::ZERO;
    for f in t.chunks_exact(3) {
        let q = [f[0], f[1], f[2]].map(|i| p[i as usize].as_dvec3());
        for c in q {
            lo = lo.min(c);
            hi = hi.max(c);
        }
        let n = (q[1] - q[0]).cross(q[2] - q[0]);
        let len = n.length();
        if len > 0.0 && len.is_finite() {
            normals.push(n / len);
            sum += n / len;
        }
    }
    let axis = sum.try_normalize().unwrap_or(DVec3::Z);
    let nearest = normals.iter().map(|n| n.dot(axis)).fold(1f64, f64::min);
    let half_angle = if normals.is_empty() { 0.0 } else { (nearest.clamp(-1.0, 1.0).acos() + 1e-6).min(std::f64::consts::PI) as f32 };
    let center = (lo + hi) * 0.5;
    let radius = t.iter().map(|&i| p[i as usize].as_dvec3().distance(center)).fold(0f64, f64::max);
    Cluster {
        cone: Cone { axis: axis.as_vec3(), half_angle },
        center: center.as_vec3(),
        radius: (radius * (1.0 + 1e-6) + 1e-30) as f32 * (1.0 + 1e-6),
        first_face,
        face_count: (t.len() / 3) as u32,
    }
}

// ---------------------------------------------------------------------------------------------
// Encoding

struct Out {
    m: Model,
    w: BitWriter,
}

impl Out {
    #[inline]
    fn sym(&mut self, al: usize, s: u32) {
        self.m.symbols.push((al as u8, s as u8));
    }

    fn value(&mut self, al: usize, u: u32) {
        let (s, n, v) = bucket(u);
        self.sym(al, s as u32);
        if n > 0 {
            self.w.put(v, n);
            self.m.raw_by_alphabet[al] += n as u64;
        }
    }

    fn signed(&mut self, al: usize, v: i64) -> std::result::Result<(), String> {
        let v = i32::try_from(v).map_err(|_| format!("residual {v} beyond 32 bits"))?;
        self.value(al, zigzag(v));
        Ok(())
    }
}

/// The faces of a node, as the encoder walks them.
struct Mesh<'a> {
    t: &'a [u32],
    /// The face across each face's edge `k` (from corner `k` to `k + 1`), or NONE.
    twin: Vec<u32>,
    run: Vec<u32>,
}

impl Mesh<'_> {
    #[inline]
    fn corner(&self, f: u32, k: usize) -> u32 {
        self.t[3 * f as usize + k]
    }

    /// The face across the directed edge `a → b` of face `f`.
    fn across(&self, f: u32, a: u32, b: u32) -> u32 {
        (0..3).find(|&k| self.corner(f, k) == a && self.corner(f, (k + 1) % 3) == b).map_or(NONE, |k| self.twin[3 * f as usize + k])
    }
}

/// Build each edge's twin: the face holding `b → a` when exactly one face holds it and exactly
/// one holds `a → b`; none for edges in `cut` (either direction) or of faces with a repeated corner.
fn twins(t: &[u32], cut: &rustc_hash::FxHashSet<(u32, u32)>) -> Vec<u32> {
    let nf = t.len() / 3;
    let mut count: FxHashMap<(u32, u32), (u32, u32)> = FxHashMap::with_capacity_and_hasher(3 * nf, Default::default());
    let proper = |f: usize| t[3 * f] != t[3 * f + 1] && t[3 * f + 1] != t[3 * f + 2] && t[3 * f] != t[3 * f + 2];
    for f in 0..nf {
        if !proper(f) {
            continue;
        }
        for k in 0..3 {
            let e = count.entry((t[3 * f + k], t[3 * f + (k + 1) % 3])).or_insert((0, f as u32));
            e.0 += 1;
        }
    }
    let mut twin = vec![NONE; 3 * nf];
    for f in 0..nf {
        if !proper(f) {
            continue;
        }
        for k in 0..3 {
            let (x, y) = (t[3 * f + k], t[3 * f + (k + 1) % 3]);
            if cut.contains(&(x.min(y), x.max(y))) {
                continue;
            }
            if let (Some(&(1, _)), Some(&(1, g))) = (count.get(&(x, y)), count.get(&(y, x))) {
                twin[3 * f + k] = g;
            }
        }
    }
    twin
}

/// Turn a node's geometry into a [`Model`] for a grid of `bits` bits and a box `bounds`. Vertices
/// off the lattice `g.lattice.shift` must be on the node's border; the encoder closes edges
/// around any that the traversal would find inside. Faces keep their runs (material ranges,
/// clusters); normals must be codes at `normal_bits`, UVs multiples of `2^−uv_bits`.
pub fn model(g: &GeometryCodes, bits: u32, bounds: [[u32; 3]; 2], normal_bits: u32) -> std::result::Result<(Model, Order), String> {
    let nf = g.indices.len() / 3;
    let shift = g.lattice.shift;
    if shift >= bits.max(1) {
        return Err(format!("lattice shift {shift} on a {bits}-bit grid"));
    }
    if g.normals.is_empty() != (normal_bits == 0) || (normal_bits > 0 && !(2..=16).contains(&normal_bits)) {
        return Err(format!("{} normals at {normal_bits} bits", g.normals.len()));
    }
    if !g.colors.is_empty() && !(1..=8).contains(&g.lattice.color_bits) {
        return Err(format!("colours at {} bits (1..=8)", g.lattice.color_bits));
    }
    if !g.uvs.is_empty() && !(1..=24).contains(&g.lattice.uv_bits) {
        return Err(format!("UVs at {} bits (1..=24)", g.lattice.uv_bits));
    }
    if g.indices.iter().any(|&i| i as usize >= g.points.len()) || g.indices.len() % 3 != 0 || nf == 0 {
        return Err(format!("{} indices over {} vertices", g.indices.len(), g.points.len()));
    }
    let mut next = 0u64;
    for r in &g.material_ranges {
        if r.first_index as u64 != next || r.index_count == 0 || r.index_count % 3 != 0 {
            return Err(format!("material range {r:?} does not continue at index {next} with whole faces"));
        }
        next += r.index_count as u64;
    }
    if next != g.indices.len() as u64 {
        return Err(format!("material ranges cover {next} of {} indices", g.indices.len()));
    }
    let clusters: Vec<u32> = g.clusters.as_ref().map(|(_, c)| c.iter().map(|c| c.faces as u32).collect()).unwrap_or_default();
    if g.clusters.is_some()
        && (clusters.is_empty() || clusters.contains(&0) || clusters.iter().map(|&c| c as u64).sum::<u64>() != nf as u64)
    {
        return Err(format!("clusters {clusters:?} do not tile {nf} faces"));
    }
    let scale = if normal_bits > 0 { octa::scale(normal_bits) } else { 0 };
    if g.normals.iter().any(|n| n.iter().any(|&c| (c as i32).abs() > scale)) {
        return Err(format!("a normal beyond the {normal_bits}-bit scale"));
    }
    let uvq: Vec<[i64; 2]> =
        g.uvs.iter().map(|uv| uv.map(|b| (f32::from_bits(b) as f64 * (1u64 << g.lattice.uv_bits) as f64).round() as i64)).collect();
    if uvq.iter().any(|q| q.iter().any(|c| c.abs() >= UV_LIMIT)) {
        return Err(format!("a UV beyond ±2^30 steps of 2^−{}", g.lattice.uv_bits));
    }
    let on_lattice = |p: [u32; 3]| shift == 0 || p.iter().all(|&c| c & ((1 << shift) - 1) == 0);

    let mut cut = rustc_hash::FxHashSet::default();
    for _ in 0..32 {
        let (m, order, border) = walk(g, &clusters, &cut, bits, bounds, normal_bits, &uvq)?;
        let off: Vec<u32> =
            order.vertices.iter().enumerate().filter(|&(s, &v)| !border[s] && !on_lattice(g.points[v as usize])).map(|(_, &v)| v).collect();
        if off.is_empty() {
            return Ok((m, order));
        }
        let off: rustc_hash::FxHashSet<u32> = off.into_iter().collect();
        for f in g.indices.chunks_exact(3) {
            for k in 0..3 {
                let (x, y) = (f[k], f[(k + 1) % 3]);
                if off.contains(&x) || off.contains(&y) {
                    cut.insert((x.min(y), x.max(y)));
                }
            }
        }
    }
    Err("vertices off the lattice stay inside the node".into())
}

/// One traversal of the node, with the edges of `cut` closed; the model, the order and which
/// stored vertices are on the border.
#[allow(clippy::too_many_arguments)]
fn walk(
    g: &GeometryCodes,
    clusters: &[u32],
    cut: &rustc_hash::FxHashSet<(u32, u32)>,
    bits: u32,
    bounds: [[u32; 3]; 2],
    normal_bits: u32,
    uvq: &[[i64; 2]],
) -> std::result::Result<(Model, Order, Vec<bool>), String> {
    let nf = g.indices.len() / 3;
    let nv_in = g.points.len();
    let shift = g.lattice.shift;
    let mut out = Out { m: Model { raw_by_alphabet: vec![0; a::ALPHABETS], ..Model::default() }, w: BitWriter::default() };

    // Header.
    if g.clusters.is_none() {
        out.sym(a::SHIFT, shift);
    }
    if !g.uvs.is_empty() {
        out.value(a::COUNT, g.lattice.uv_bits);
    }
    out.value(a::COUNT, g.material_ranges.len() as u32 - 1);
    for (k, r) in g.material_ranges.iter().enumerate() {
        out.value(a::COUNT, r.material);
        if k + 1 < g.material_ranges.len() {
            out.value(a::COUNT, r.index_count / 3 - 1);
        }
    }
    if g.clusters.is_some() {
        out.value(a::COUNT, clusters.len() as u32 - 1);
        for &c in &clusters[..clusters.len() - 1] {
            out.value(a::COUNT, c - 1);
        }
    }
    let mut cuts: Vec<u32> = g.material_ranges.iter().map(|r| r.first_index / 3).collect();
    let mut c = 0u32;
    for &n in clusters {
        cuts.push(c);
        c += n;
    }
    cuts.push(nf as u32);
    cuts.sort_unstable();
    cuts.dedup();
    let mut run = vec![0u32; nf];
    for (r, w) in cuts.windows(2).enumerate() {
        run[w[0] as usize..w[1] as usize].fill(r as u32);
    }
    let mesh = Mesh { t: &g.indices, twin: twins(&g.indices, cut), run };

    // Connectivity, in input vertex numbers; `stored` numbers them as the reader will.
    let mut stored = vec![NONE; nv_in];
    let mut order = Order { faces: Vec::with_capacity(nf), rotation: Vec::with_capacity(nf), vertices: Vec::with_capacity(nv_in) };
    let mut preds: Vec<Pred> = Vec::with_capacity(nv_in);
    let mut done = vec![false; nf];
    let mut front = Front::with_capacity(2 * nf + 8);
    // The face across each open edge.
    let mut across: Vec<u32> = Vec::with_capacity(2 * nf + 8);
    let mut queue: Vec<u32> = Vec::new();
    let mut skipped: Vec<u32> = Vec::new();
    let mut ctx = 7usize;
    let emit = |order: &mut Order, f: u32, first: u32| {
        let r = (0..3).find(|&k| mesh.corner(f, k) == first).expect("a corner of the face");
        order.faces.push(f);
        order.rotation.push(r as u8);
    };
    for (r, w) in cuts.windows(2).enumerate() {
        let r = r as u32;
        let mut left = w[1] - w[0];
        let mut cursor = w[0];
        queue.clear();
        let (mut head, mut pending) = (0usize, NONE);
        while left > 0 {
            let e = if pending != NONE {
                std::mem::replace(&mut pending, NONE)
            } else if head < queue.len() {
                head += 1;
                queue[head - 1]
            } else {
                let usable = |e: u32| {
                    let f = across[e as usize];
                    front.e[e as usize].state == OPEN && f != NONE && !done[f as usize] && mesh.run[f as usize] == r
                };
                match skipped.iter().rev().take(START_SCAN).position(|&e| usable(e)) {
                    Some(k) => {
                        out.value(a::START, k as u32 + 1);
                        skipped[skipped.len() - 1 - k]
                    }
                    None => {
                        out.value(a::START, 0);
                        while done[cursor as usize] {
                            cursor += 1;
                        }
                        let f = cursor;
                        let mut t = [0u32; 3];
                        for k in 0..3 {
                            let v = mesh.corner(f, k);
                            if stored[v as usize] == NONE {
                                out.value(a::CORNER, 0);
                                preds.push(Pred::Jump((order.vertices.len() as u32).wrapping_sub(1)));
                                stored[v as usize] = order.vertices.len() as u32;
                                order.vertices.push(v);
                            } else {
                                out.value(a::CORNER, 1 + (order.vertices.len() as u32 - 1 - stored[v as usize]));
                            }
                            t[k] = v;
                        }
                        let e = front.start(t);
                        for k in 0..3 {
                            across.push(mesh.across(f, t[k], t[(k + 1) % 3]));
                        }
                        queue.extend_from_slice(&[e, e + 1, e + 2]);
                        done[f as usize] = true;
                        emit(&mut order, f, t[0]);
                        left -= 1;
                        continue;
                    }
                }
            };
            if front.e[e as usize].state != OPEN {
                continue;
            }
            let ei = e as usize;
            let f = across[ei];
            let s = if f == NONE || done[f as usize] {
                sym::BOUNDARY
            } else if mesh.run[f as usize] != r {
                sym::SKIP
            } else {
                let (va, vb) = (front.e[ei].v0, front.e[ei].v1);
                let x = (0..3).map(|k| mesh.corner(f, k)).find(|&c| c != va && c != vb).expect("a proper face");
                if stored[x as usize] == NONE {
                    sym::VERTEX
                } else {
                    let (p, n) = (front.e[ei].prev as usize, front.e[ei].next as usize);
                    let left_ok = p != ei && front.e[p].state == OPEN && front.e[p].v0 == x && across[p] == f;
                    let right_ok = n != ei && front.e[n].state == OPEN && front.e[n].v1 == x && across[n] == f;
                    match (left_ok, right_ok) {
                        (true, true) if p != n => sym::END,
                        (true, _) => sym::LEFT,
                        (_, true) => sym::RIGHT,
                        _ => sym::SPLIT,
                    }
                }
            };
            out.sym(a::CONN + ctx, s);
            ctx = s as usize;
            match s {
                sym::BOUNDARY => front.e[ei].state = CLOSED,
                sym::SKIP => skipped.push(e),
                _ => {
                    let (va, vb) = (front.e[ei].v0, front.e[ei].v1);
                    let x = (0..3).map(|k| mesh.corner(f, k)).find(|&c| c != va && c != vb).expect("a proper face");
                    if s == sym::VERTEX {
                        stored[x as usize] = order.vertices.len() as u32;
                        preds.push(Pred::Para(stored[va as usize], stored[vb as usize], stored[front.e[ei].opp as usize]));
                        order.vertices.push(x);
                    } else if s == sym::SPLIT {
                        out.value(a::SPLIT, order.vertices.len() as u32 - 1 - stored[x as usize]);
                    }
                    let (n1, q) = front.across(e, s, x);
                    // One `across` entry per edge, in the order the edges were made.
                    for new in [n1, q].into_iter().filter(|&e| e != NONE) {
                        across.push(mesh.across(f, front.e[new as usize].v0, front.e[new as usize].v1));
                    }
                    pending = n1;
                    if q != NONE {
                        queue.push(q);
                    }
                    done[f as usize] = true;
                    emit(&mut order, f, vb);
                    left -= 1;
                }
            }
        }
    }
    let nv = order.vertices.len();
    let border_in = front.border(nv_in);
    let border: Vec<bool> = order.vertices.iter().map(|&v| border_in[v as usize]).collect();
    let points: Vec<[u32; 3]> = order.vertices.iter().map(|&v| g.points[v as usize]).collect();

    // Positions.
    let top = (1i64 << bits) - 1;
    let mid = [0, 1, 2].map(|k| (bounds[0][k] as i64 + bounds[1][k] as i64) >> 1);
    for v in 0..nv {
        let (p, al) = match preds[v] {
            Pred::Para(pa, pb, pc) => {
                let (qa, qb, qc) = (points[pa as usize], points[pb as usize], points[pc as usize]);
                let p = [0, 1, 2].map(|k| (qa[k] as i64 + qb[k] as i64 - qc[k] as i64).clamp(0, top));
                (p, position_alphabet(border[v], shift > 0 && !border[v], shift, qa, qb, qc))
            }
            Pred::Jump(prev) => (if prev == NONE { mid } else { points[prev as usize].map(|c| c as i64) }, a::POS_JUMP),
        };
        let lattice = shift > 0 && !border[v];
        for k in 0..3 {
            let c = points[v][k] as i64;
            let r = if lattice { (c >> shift) - lattice_of(p[k], shift) } else { c - p[k] };
            out.signed(al, r)?;
        }
    }
    // Indices of the stored faces.
    let mut indices = Vec::with_capacity(3 * nf);
    for (&f, &rot) in order.faces.iter().zip(&order.rotation) {
        for k in 0..3 {
            indices.push(stored[mesh.corner(f, (k + rot as usize) % 3) as usize]);
        }
    }
    if !g.normals.is_empty() {
        let scale = octa::scale(normal_bits);
        let sums = normal_sums(&points, &indices);
        for v in 0..nv {
            let s = sums[v];
            let p = predict_octa(s[0], s[1], s[2], scale);
            let n = g.normals[order.vertices[v] as usize];
            let al = if border[v] { a::NORMAL_BORDER } else { a::NORMAL };
            out.signed(al, n[0] as i64 - p[0] as i64)?;
            out.signed(al, n[1] as i64 - p[1] as i64)?;
        }
    }
    if !g.colors.is_empty() {
        let cb = g.lattice.color_bits;
        let m = (1i64 << cb) - 1;
        let ys: Vec<[i64; 4]> = order.vertices.iter().map(|&v| ycocg(g.colors[v as usize].map(|c| color_quantize(c, cb)))).collect();
        for v in 0..nv {
            let p = predict(preds[v], |i| ys[i as usize], [0; 4], -m, m);
            for k in 0..4 {
                let al = [a::COLOR_Y, a::COLOR_C, a::COLOR_C, a::COLOR_A][k];
                out.signed(al, ys[v][k] - p[k])?;
            }
        }
    }
    if !g.uvs.is_empty() {
        let uvs: Vec<[i64; 2]> = order.vertices.iter().map(|&v| uvq[v as usize]).collect();
        for v in 0..nv {
            let p = predict(preds[v], |i| uvs[i as usize], [0; 2], 1 - UV_LIMIT, UV_LIMIT - 1);
            for k in 0..2 {
                out.signed(a::UV, uvs[v][k] - p[k])?;
            }
        }
    }
    out.m.raw_bits = out.w.len();
    out.m.raw = out.w.finish();
    Ok((out.m, order, border))
}
