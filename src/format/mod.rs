//! The strata chunk file (METHOD.md §5), specified byte by byte in `format-spec/strata-v2.md`.
//!
//! A 16-byte prologue (magic, version) is followed by chunks: `HEAD` (what the file holds), `SKEL`
//! (the skeleton: levels, node table, neighbours, materials) and one `GEOM` chunk per node, coarsest
//! level first, so that a prefix of the file is a coarse model. A viewer reads the prologue, `HEAD`
//! and `SKEL` at [`Reader::open`] and each node's geometry on demand with [`Reader::read_node`].
//!
//! - [`chunk`]: the frame every chunk shares (ID, flags, size, payload, CRC-32, padding);
//! - [`octa`]: the octahedral normal code;
//! - [`write`](mod@write): [`write`] and [`write_to`] turn a hierarchy and its level meshes into a file;
//! - [`read`]: [`Reader`], the lazy reader;
//! - [`assemble`]: [`to_mesh`], one level of a file as one [`Mesh`](crate::mesh::Mesh);
//! - [`verify`](mod@verify): [`verify`], every checksum and structural rule of a file;
//! - [`inspect`](mod@inspect): [`inspect()`](inspect::inspect), what `strata inspect` shows.

pub mod assemble;
pub mod chunk;
pub mod inspect;
pub mod octa;
pub mod read;
pub mod rules;
pub mod verify;
pub mod write;

pub use assemble::to_mesh;
pub use read::Reader;
pub use verify::{verify, verify_path, Verification};
pub use write::{write, write_to, LevelSummary, WriteOptions, WriteSummary};

use crate::cone::Cone;
use crate::hierarchy::HierarchyParams;
use glam::{DVec3, Vec2, Vec3};

/// Major format version: a reader refuses files with a larger major version.
pub const MAJOR: u16 = 2;
/// Minor format version: a newer minor only adds chunk kinds, which older readers skip.
pub const MINOR: u16 = 0;
/// The format version as the spec writes it.
pub const VERSION: &str = "2.0";

/// The first 8 bytes of every strata file.
pub const MAGIC: [u8; 8] = *b"\x89STRATA\n";
/// Bytes of the prologue: magic, major, minor, CRC-32 of the first 12 bytes.
pub const PROLOGUE_BYTES: u64 = 16;

/// Marks "no parent" in the node table: a top-level node, child of the virtual root.
pub const NO_PARENT: u32 = u32::MAX;

/// Bytes of one node record in the `NODE` chunk.
pub const NODE_RECORD_BYTES: u64 = 56;
/// Bytes of one level record in the `LEVL` chunk.
pub const LEVEL_RECORD_BYTES: u64 = 32;
/// Bytes of the fixed part of the `HEAD` payload (the tool string follows).
pub const HEAD_FIXED_BYTES: u64 = 160;
/// Longest tool string, in bytes.
pub const MAX_TOOL_BYTES: u64 = 1024;
/// Bytes of one cluster record in the `CLUS` chunk.
pub const CLUSTER_RECORD_BYTES: u64 = 16;
/// Bytes of one material range in the `MATR` chunk.
pub const RANGE_RECORD_BYTES: u64 = 12;

/// Chunk IDs.
pub mod id {
    pub const HEAD: [u8; 4] = *b"HEAD";
    pub const SKEL: [u8; 4] = *b"SKEL";
    pub const GEOM: [u8; 4] = *b"GEOM";
    pub const LEVL: [u8; 4] = *b"LEVL";
    pub const NODE: [u8; 4] = *b"NODE";
    pub const NBRS: [u8; 4] = *b"NBRS";
    pub const MATL: [u8; 4] = *b"MATL";
    pub const VPOS: [u8; 4] = *b"VPOS";
    pub const VNRM: [u8; 4] = *b"VNRM";
    pub const VTEX: [u8; 4] = *b"VTEX";
    pub const VCOL: [u8; 4] = *b"VCOL";
    pub const INDX: [u8; 4] = *b"INDX";
    pub const MATR: [u8; 4] = *b"MATR";
    pub const CLUS: [u8; 4] = *b"CLUS";
}

/// Which corner attributes every vertex of the file carries besides its position.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Attributes {
    pub normals: bool,
    pub uvs: bool,
    pub colors: bool,
}

impl Attributes {
    /// The `HEAD` attribute bits: 1 normals, 2 UVs, 4 colors.
    pub fn bits(self) -> u32 {
        self.normals as u32 | (self.uvs as u32) << 1 | (self.colors as u32) << 2
    }

    pub fn from_bits(bits: u32) -> Attributes {
        Attributes { normals: bits & 1 != 0, uvs: bits & 2 != 0, colors: bits & 4 != 0 }
    }
}

/// The `HEAD` chunk: what the file holds and how it was built.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    pub major: u16,
    pub minor: u16,
    /// Size of the whole file in bytes.
    pub file_size: u64,
    /// Metres per model unit; 0 when the unit is unknown.
    pub metres_per_unit: f64,
    /// Bounds of every level's geometry.
    pub min: Vec3,
    pub max: Vec3,
    pub attributes: Attributes,
    pub levels: u32,
    pub nodes: u32,
    pub materials: u32,
    /// Vertices and faces of the input mesh (level 0).
    pub input_vertices: u64,
    pub input_faces: u64,
    /// Culling clusters over all level-0 nodes.
    pub clusters: u32,
    /// Parameters the hierarchy was built with.
    pub params: HierarchyParams,
    /// The grid every position, box and sphere center lies on.
    pub grid: Grid,
    /// Target ratio of faces between a level and the one below.
    pub level_ratio: f32,
    /// Name and version of the program that wrote the file.
    pub tool: String,
}

/// One entry of the `LEVL` chunk: level ℓ's nodes are `first_node .. first_node + nodes`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LevelRecord {
    pub first_node: u32,
    pub nodes: u32,
    /// Faces and vertices over the level's nodes.
    pub faces: u64,
    pub vertices: u64,
    /// Bytes of the level's `GEOM` chunks, padding included.
    pub bytes: u64,
}

/// One entry of the node table. Nodes are numbered in file order: top level first, and within a
/// level by parent, so a node's children are consecutive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodeRecord {
    /// Level ℓ (0 = full detail); not stored, implied by the `LEVL` ranges.
    pub level: u32,
    /// Parent node, or [`NO_PARENT`] for a top-level node.
    pub parent: u32,
    /// Children are nodes `first_child .. first_child + child_count` of level ℓ − 1.
    pub first_child: u32,
    pub child_count: u32,
    /// Neighbours are `neighbors[neighbor_first .. neighbor_first + neighbor_count]`; `neighbor_first`
    /// is not stored, the lists follow one another in node order.
    pub neighbor_first: u32,
    pub neighbor_count: u32,
    /// Contains every face normal of this node and every cone of its descendants.
    pub cone: Cone,
    /// Bounding sphere of this node's vertices and of its descendants' spheres. The file also
    /// holds a bounding box, which only verification needs: [`Reader::node_boxes`] reads it.
    pub center: Vec3,
    pub radius: f32,
    /// Geometric error in model units, never smaller than a child's; includes the position
    /// quantization bound [`Grid::error`].
    pub error: f32,
    pub faces: u32,
    pub vertices: u32,
    /// Where the node's `GEOM` chunk starts (not stored: chunks follow the skeleton in node order),
    /// its bytes from ID to CRC (padding excluded), and the CRC-32 of its payload.
    pub offset: u64,
    pub size: u32,
    pub crc: u32,
}

/// A run of indices drawn with one material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaterialRange {
    pub material: u32,
    pub first_index: u32,
    pub index_count: u32,
}

/// A culling cluster inside a level-0 node: faces `first_face .. first_face + face_count` of the
/// node (`first_face` is not stored: clusters follow one another), all facing within `cone`, all
/// inside the sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cluster {
    pub cone: Cone,
    pub center: Vec3,
    pub radius: f32,
    pub first_face: u32,
    pub face_count: u32,
}

/// One node's geometry, decoded: node-local vertices and triangles over them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeGeometry {
    pub positions: Vec<Vec3>,
    /// Unit normals per vertex, or empty when the file has none.
    pub normals: Vec<Vec3>,
    pub uvs: Vec<Vec2>,
    pub colors: Vec<[u8; 4]>,
    /// Three per face, each below `positions.len()`.
    pub indices: Vec<u32>,
    /// Consecutive runs covering `indices`.
    pub material_ranges: Vec<MaterialRange>,
    /// Level-0 nodes only: consecutive runs covering the faces.
    pub clusters: Vec<Cluster>,
}

impl NodeGeometry {
    pub fn face_count(&self) -> usize {
        self.indices.len() / 3
    }
}

/// Largest number of grid bits per axis: three coordinates pack into the low 63 bits of a u64.
pub const MAX_GRID_BITS: u32 = 21;
/// Grid bits the writer uses: a millionth of the model's extent, and most nodes' offsets fit u16.
pub const GRID_BITS: u32 = 20;

/// The global position grid (spec §5.1): grid point `g` is at `origin + g·step` per axis,
/// `0 ≤ g < 2^bits`, computed in f64 and rounded to f32 once, so that a grid point decodes to the
/// same f32 everywhere.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Grid {
    pub origin: [f64; 3],
    pub step: f64,
    pub bits: u32,
}

impl Grid {
    /// The writer's grid for a model with bounds `min..max`: origin `min`, step the smallest power
    /// of two that spans the largest extent with `2^bits − 1` steps (1 for a flat point).
    pub fn fit(min: Vec3, max: Vec3, bits: u32) -> Grid {
        let extent = (max - min).as_dvec3().max_element();
        let cells = ((1u64 << bits) - 1) as f64;
        let mut step = 1.0f64;
        if extent > 0.0 {
            while extent / step > cells {
                step *= 2.0;
            }
            while extent / (step / 2.0) <= cells {
                step /= 2.0;
            }
        }
        Grid { origin: min.as_dvec3().to_array(), step, bits }
    }

    /// Largest grid coordinate.
    pub fn last(&self) -> u32 {
        ((1u64 << self.bits) - 1) as u32
    }

    /// The grid point nearest `p`, clamped to the grid.
    pub fn encode(&self, p: Vec3) -> [u32; 3] {
        let g = ((p.as_dvec3() - DVec3::from(self.origin)) / self.step).round();
        g.to_array().map(|x| x.clamp(0.0, self.last() as f64) as u32)
    }

    /// Grid coordinates of the cell corner at or below (`up` false) or at or above (`up` true) `p`.
    pub fn bound(&self, p: Vec3, up: bool) -> [u32; 3] {
        let g = (p.as_dvec3() - DVec3::from(self.origin)) / self.step;
        let g = if up { g.ceil() } else { g.floor() };
        g.to_array().map(|x| x.clamp(0.0, self.last() as f64) as u32)
    }

    /// The position of grid point `g`.
    pub fn decode(&self, g: [u32; 3]) -> Vec3 {
        (DVec3::from(self.origin) + DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64) * self.step).as_vec3()
    }

    /// A length of `steps` grid steps, in model units.
    pub fn length(&self, steps: f64) -> f32 {
        (steps * self.step) as f32
    }

    /// The distance bound between a position and its grid point that every node's geometric error
    /// includes: half a step per axis, √3/2 steps in all.
    pub fn error(&self) -> f32 {
        (self.step * 3f64.sqrt() / 2.0) as f32
    }
}

/// Three grid coordinates in one u64: x in bits 0..21, y in 21..42, z in 42..63.
pub fn pack(g: [u32; 3]) -> u64 {
    g[0] as u64 | (g[1] as u64) << 21 | (g[2] as u64) << 42
}

/// The inverse of [`pack`]; `None` when bit 63 is set.
pub fn unpack(v: u64) -> Option<[u32; 3]> {
    let m = (1u64 << 21) - 1;
    (v >> 63 == 0).then_some([(v & m) as u32, (v >> 21 & m) as u32, (v >> 42 & m) as u32])
}

/// A cone half-angle as a u16: `k·π/65535`, rounded up from `angle` radians (π and above: 65535).
pub fn angle_code(angle: f64) -> u16 {
    let mut k = (angle / std::f64::consts::PI * 65535.0).ceil().clamp(0.0, 65535.0) as u16;
    while k < u16::MAX && (angle_decode(k) as f64) < angle {
        k += 1;
    }
    k
}

/// The half-angle, in radians, of code `k`.
pub fn angle_decode(k: u16) -> f32 {
    (k as f64 * std::f64::consts::PI / 65535.0) as f32
}

/// A radius in grid steps as a u16 float, rounded up: mantissa `k & 0x7FF`, exponent `k >> 11`,
/// value `mantissa · 2^exponent` steps.
pub fn radius_code(steps: f64) -> u16 {
    let mut e = 0u32;
    while e < 31 && (steps / (1u64 << e) as f64).ceil() > 2047.0 {
        e += 1;
    }
    let m = (steps / (1u64 << e) as f64).ceil().clamp(0.0, 2047.0) as u16;
    m | (e as u16) << 11
}

/// The radius in grid steps of code `k`.
pub fn radius_decode(k: u16) -> f64 {
    ((k & 0x7FF) as u64) as f64 * (1u64 << (k >> 11)) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_up_and_stay_close() {
        for i in 0..=2000 {
            let a = i as f64 * std::f64::consts::PI / 2000.0;
            let k = angle_code(a);
            assert!(angle_decode(k) as f64 >= a || k == u16::MAX, "angle {a} coded as {k}");
            assert!((angle_decode(k) as f64) < a + 1e-4, "angle {a} widened to {}", angle_decode(k));
        }
        assert_eq!(angle_code(10.0), u16::MAX);
        for steps in [0.0, 0.5, 1.0, 2047.0, 2047.5, 2048.0, 123_456.7, 3e6, 1e12] {
            let r = radius_decode(radius_code(steps));
            assert!(r >= steps && r <= steps * (1.0 + 1.0 / 1024.0) + 1.0, "{steps} steps coded as {r}");
        }
    }

    #[test]
    fn grid_points_pack_and_decode_within_half_a_step() {
        let g = [(1 << 21) - 1, 12345, 0];
        assert_eq!(unpack(pack(g)), Some(g));
        assert_eq!(unpack(1 << 63), None);
        let (min, max) = (Vec3::new(-3.0, 1000.0, 0.25), Vec3::new(5.0, 1001.0, 0.5));
        let grid = Grid::fit(min, max, GRID_BITS);
        assert!(8.0 / grid.step <= grid.last() as f64 && 8.0 / (grid.step / 2.0) > grid.last() as f64);
        for k in 0..1000 {
            let t = k as f32 / 999.0;
            let p = min + (max - min) * Vec3::new(t, t * t, 1.0 - t);
            let q = grid.decode(grid.encode(p));
            for a in 0..3 {
                let ulp = (p[a].abs().max(q[a].abs()) * f32::EPSILON) as f64;
                assert!(((q[a] - p[a]) as f64).abs() <= grid.step / 2.0 + ulp / 2.0, "{p} → {q}");
            }
            assert!(grid.decode(grid.bound(p, false)).cmple(p).all() && p.cmple(grid.decode(grid.bound(p, true))).all());
        }
    }
}
