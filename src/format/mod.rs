//! The strata chunk file (METHOD.md §5), specified byte by byte in `format-spec/strata-v2.md`.
//!
//! This layer is the format alone: it depends on nothing of the build (only on [`crate::error`]),
//! so a server, a viewer or a second implementation can stand on it. It decodes from byte slices
//! and reads through a [`ByteSource`] (a file by positional reads, memory; later HTTP ranges), so
//! reads can run concurrently.
//!
//! A 16-byte prologue (magic, version) is followed by chunks: `HEAD` (what the file holds), `SKEL`
//! (the skeleton: levels, node table, neighbours, materials) and one `GEOM` chunk per node, coarsest
//! level first, so that a prefix of the file is a coarse model. A viewer reads the prologue, `HEAD`
//! and `SKEL` at [`Reader::open`] and each node's geometry on demand with [`Reader::read_node`].
//!
//! - [`records`]: the decoded records (header, levels, nodes, clusters, geometry) as plain data;
//! - [`chunk`]: the frame every chunk shares (ID, flags, size, payload, CRC-32, padding);
//! - [`codes`]: the position grid and the u16 codes of angles and radii; [`octa`]: normals;
//! - [`skeleton`]: `HEAD` and `SKEL`, encoded and decoded; [`georef`]: `GEOR`, where terrain sits;
//!   [`texture`]: `TEXR` and `TEXL`, the images materials use, as pyramids of resolutions;
//!   [`image`]: the PNG and JPEG files of their levels decoded into pixels; [`planes`]: `ORDR`,
//!   separating planes between siblings for drawing front to back;
//! - [`geom`]: a node's geometry, one codec per format version ([`geom::v2`]);
//! - [`source`]: [`ByteSource`], where bytes come from;
//! - [`read`]: [`Reader`], the lazy reader; [`rules`]: what every reader checks (spec §10);
//! - [`write`](mod@write): [`Writer`], which takes finished nodes in any order and assembles the
//!   file coarsest level first;
//! - [`verify`](mod@verify): [`verify`], every checksum and rule of a whole file;
//! - [`inspect`](mod@inspect): [`inspect()`](inspect::inspect), what `strata inspect` shows.

pub mod chunk;
pub mod codes;
pub mod geom;
pub mod georef;
pub mod image;
pub mod inspect;
pub mod octa;
pub mod planes;
pub mod read;
pub mod records;
pub mod rules;
pub mod skeleton;
pub mod source;
pub mod texture;
pub mod verify;
pub mod write;

pub use codes::{angle_code, angle_decode, pack, radius_code, radius_decode, unpack, Grid, GRID_BITS, MAX_GRID_BITS};
pub use georef::{GeoFrame, Georef};
pub use read::Reader;
pub use records::{
    Attributes, Cluster, Cone, DagTable, GroupRecord, Header, HierarchyParams, ImageCodec, ImageLevel, ImageRecord, LevelRecord, MapKind,
    Material, MaterialRange, NodeGeometry, NodeRecord, TextureSlot, Textures, Wrap, MAP_KINDS,
};
pub use source::ByteSource;
pub use verify::{verify, verify_path, Verification};
pub use write::{GroupIn, LevelSummary, NodeIn, Prepared, Preparer, WriteSummary, Writer, WriterOptions};

/// Major format version writers write by default: 2. Readers read 2 and 3 ([`NEWEST_MAJOR`]) and
/// refuse larger ones.
pub const MAJOR: u16 = 2;
/// The newest major version this reader reads: 4, whose node table is a DAG
/// (format-spec/strata-v4.md).
pub const NEWEST_MAJOR: u16 = 4;
/// Minor format version this reader knows: a newer minor only adds chunk kinds, which older readers
/// skip. Writers write the lowest minor that holds what a file carries: 3 with separating planes
/// (`ORDR`), 2 with images (`TEXR`, `TEXL`) or UVs, 1 with a `GEOR` chunk, else 0.
pub const MINOR: u16 = 3;
/// The format version as the spec writes it.
pub const VERSION: &str = "2.3";
/// Minor version of format 3 this reader knows, and writers write: 1, the node table in pages
/// (strata-v3.md §1.1); 3.0 files, whose node table is `NODE` and `NBRS` as in format 2, are read.
pub const MINOR3: u16 = 1;
/// Format 3's version as its spec writes it.
pub const VERSION3: &str = "3.1";
/// Format 4: format 3.1 with the node table as a DAG of nodes and groups (strata-v4.md).
pub const MAJOR4: u16 = 4;
/// Minor version of format 4 this reader knows, and writers write.
pub const MINOR4: u16 = 0;
/// Format 4's version as its spec writes it.
pub const VERSION4: &str = "4.0";

/// Whether a file of this version keeps its node table in `NODL` pages, one per level (3.1 on),
/// rather than in `NODE` and `NBRS`.
pub fn paged(major: u16, minor: u16) -> bool {
    (major, minor) >= (3, 1)
}

/// The newest minor version of `major` this reader knows: a file of a newer minor may carry
/// fields and chunks it skips.
pub fn known_minor(major: u16) -> u16 {
    match major {
        MAJOR4 => MINOR4,
        3 => MINOR3,
        _ => MINOR,
    }
}

/// The first 8 bytes of every strata file.
pub const MAGIC: [u8; 8] = *b"\x89STRATA\n";
/// Bytes of the prologue: magic, major, minor, CRC-32 of the first 12 bytes.
pub const PROLOGUE_BYTES: u64 = 16;

/// Marks "no parent" in the node table: a top-level node, child of the virtual root.
pub const NO_PARENT: u32 = u32::MAX;

/// Bytes of one node record in the `NODE` chunk.
pub const NODE_RECORD_BYTES: u64 = 56;
/// Bytes of a group record in a format-4 page (strata-v4.md §1).
pub const GROUP_RECORD_BYTES: u64 = 24;
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
    pub const GEOR: [u8; 4] = *b"GEOR";
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
    pub const TEXR: [u8; 4] = *b"TEXR";
    pub const TEXL: [u8; 4] = *b"TEXL";
    pub const ORDR: [u8; 4] = *b"ORDR";
    pub const GEOS: [u8; 4] = *b"GEOS";
    pub const CODE: [u8; 4] = *b"CODE";
    pub const NODL: [u8; 4] = *b"NODL";
}
