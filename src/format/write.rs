//! The writer as a node sink: a build hands it finished nodes in any order (finest first, one
//! partition cell at a time, …); it encodes each node's geometry at once (or takes it encoded by a
//! [`Preparer`], which a build runs on every core) and keeps it aside, in a
//! spill per level (memory, or an unlinked temporary file in a folder of the caller's choice), and
//! at [`Writer::finish`] numbers the nodes breadth-first from the top (spec §6), builds `HEAD` and
//! `SKEL`, and writes the file front to back: prologue, skeleton, then every node's `GEOM` chunk,
//! coarsest level first.
//!
//! The writer decides nothing about bounds, cones or errors: the build computes them (rounded
//! outward with [`codes::store_cone`](super::codes::store_cone) and friends) and the writer stores
//! them as given.

use super::chunk;
use super::geom::rans::EncodeTable;
use super::geom::v2::{self, GeometryCodes};
use super::geom::v3;
use super::georef::{self, Georef};
use super::planes::{self, PlaneEntry, Planes, Support};
use super::skeleton::{encode_head, encode_skel, geometry_layout, DagCodes, GroupCodes, NodeCodes};
use super::texture::{self, ImageIn};
use super::{
    angle_decode, id, Attributes, ByteSource, Cone, Grid, Header, HierarchyParams, LevelRecord, Material, NodeRecord, MAGIC, MAJOR4,
    MAX_TOOL_BYTES, MINOR, MINOR3, MINOR4, NO_PARENT,
};
use crate::error::{Error, Result};
use glam::Vec3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

/// What the file records besides its nodes.
#[derive(Clone, Debug, PartialEq)]
pub struct WriterOptions {
    /// Metres per model unit, 0 when unknown.
    pub metres_per_unit: f64,
    /// Parameters the hierarchy was built with.
    pub params: HierarchyParams,
    /// Target ratio of faces between a level and the one below.
    pub level_ratio: f32,
    /// Name and version of the writing program, at most 1024 bytes.
    pub tool: String,
    pub grid: Grid,
    /// The corner attributes every node carries.
    pub attributes: Attributes,
    pub materials: Vec<Material>,
    /// Vertices of the input mesh (level 0, welded by position).
    pub input_vertices: u64,
    /// Number of levels, at least 1.
    pub levels: u32,
    /// Where the model sits on Earth; a file with it is format 2.1 (spec §5.2).
    pub georef: Option<Georef>,
    /// The major format version to write: 2 (fixed-width arrays) or 3 (compressed node geometry).
    pub major: u16,
    /// The images the materials' maps index, each as its levels, finest first; a file with images
    /// is format 2.2 (spec §7.5).
    pub images: std::sync::Arc<Vec<ImageIn>>,
}

/// One finished node.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeIn {
    /// 0 = full detail.
    pub level: u32,
    /// The node's id among its level's nodes, as the build numbers them; unique per level. Nodes
    /// with the same parent are stored in the order of their keys.
    pub key: u32,
    /// The parent's key in level `level + 1`, or [`NO_PARENT`] at the top level. Format 4: the key
    /// of its consumer group among level `level + 1`'s groups ([`Writer::add_group`]).
    pub parent: u32,
    /// Format 4: the key of the group of its level that made it; [`NO_PARENT`] at level 0 and in
    /// other formats. A group's outputs are stored in the order of their keys.
    pub source: u32,
    /// Keys of same-level neighbours, in any order (duplicates and the node's own key are dropped).
    pub neighbors: Vec<u32>,
    /// Stored bounds and cone, containing its geometry's and its children's.
    pub codes: NodeCodes,
    /// Geometric error in model units, not below any child's.
    pub error: f32,
    /// UV units per model unit over its textured faces, 0 without (spec §7.5).
    pub uv_density: f32,
    pub geometry: GeometryCodes,
}

/// Format 4: a group of the DAG (strata-v4.md §1), which made the nodes of `level` that name it
/// as their source from nodes of `level − 1` that name it as their consumer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupIn {
    /// The level of its outputs, at least 1.
    pub level: u32,
    /// Its id among its level's groups; groups are stored in the order of their keys.
    pub key: u32,
    /// Geometric error, model units, not below any child's.
    pub error: f32,
    /// Sphere center (a grid point) and radius code, holding its children's spheres and their
    /// sources' spheres.
    pub center: [u32; 3],
    pub radius: u16,
}

/// What one level of the written file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct LevelSummary {
    pub level: u32,
    pub nodes: u32,
    pub faces: u64,
    pub vertices: u64,
    /// Bytes of the level's geometry chunks.
    pub bytes: u64,
}

/// What was written.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct WriteSummary {
    pub file_bytes: u64,
    /// Bytes a reader reads to open the file: prologue, `HEAD` and `SKEL`.
    pub skeleton_bytes: u64,
    pub input_faces: u64,
    pub nodes: u32,
    pub clusters: u32,
    /// Finest level first.
    pub levels: Vec<LevelSummary>,
    /// Format 3: bits of node geometry by kind ([`v3::STAT_NAMES`]), over all nodes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub geometry_bits: Option<Vec<f64>>,
    /// Bytes of the images' `TEXL` chunks, padding included.
    pub image_bytes: u64,
}

impl WriteSummary {
    /// File bytes per face of the input mesh.
    pub fn bytes_per_face(&self) -> f64 {
        self.file_bytes as f64 / self.input_faces.max(1) as f64
    }
}

/// Spilled node models read at once to be coded on every core (format 3's last step).
const CODING_BATCH_BYTES: u64 = 16 << 20;

/// Where a level's encoded chunks wait for [`Writer::finish`].
enum Spill {
    Memory(Vec<u8>),
    /// An unlinked temporary file: nothing is left behind, whatever ends the process.
    File {
        file: File,
        len: u64,
    },
}

impl Spill {
    /// An unlinked file in `dir`, or memory without one.
    fn new(dir: Option<&Path>) -> Result<Spill> {
        Ok(match dir {
            Some(dir) => Spill::File { file: tempfile::tempfile_in(dir).map_err(|e| Error::io(dir, e))?, len: 0 },
            None => Spill::Memory(Vec::new()),
        })
    }

    fn append(&mut self, bytes: &[u8]) -> std::io::Result<u64> {
        match self {
            Spill::Memory(v) => {
                v.extend_from_slice(bytes);
                Ok(v.len() as u64 - bytes.len() as u64)
            }
            Spill::File { file, len } => {
                file.write_all(bytes)?;
                *len += bytes.len() as u64;
                Ok(*len - bytes.len() as u64)
            }
        }
    }

    fn read(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        match self {
            Spill::Memory(v) => v.read_exact_at(offset, buf),
            Spill::File { file, .. } => file.read_exact_at(offset, buf),
        }
    }
}

/// A node waiting to be numbered and written.
struct Pending {
    key: u32,
    parent: u32,
    source: u32,
    neighbors: Vec<u32>,
    codes: NodeCodes,
    error: f32,
    uv_density: u16,
    faces: u32,
    vertices: u32,
    /// Where its chunk (padded) lies in its level's spill, and its span from ID to CRC.
    spill_at: u64,
    padded: u32,
    span: u32,
    crc: u32,
    /// Where its geometry's extent along the plane directions (`ORDR`) lies in the supports'
    /// spill.
    support_at: u64,
}

/// Encodes nodes for one file, on any thread ([`Writer::preparer`]).
#[derive(Clone, Debug)]
pub struct Preparer {
    path: PathBuf,
    major: u16,
    grid_bits: u32,
    attributes: Attributes,
}

/// A node encoded for its file, waiting for [`Writer::add_prepared`].
pub struct Prepared {
    /// The node, its geometry taken out.
    node: NodeIn,
    faces: u32,
    vertices: u32,
    /// Format 3 and 4: the model, to count its symbols, and its normals' and colours' bits.
    model: Option<(v3::Model, u32, u32)>,
    /// What its level's spill keeps: the model (formats 3 and 4) or the whole chunk (format 2).
    bytes: Vec<u8>,
    span: u32,
    crc: u32,
    /// Its [`Support`], before format 4.
    support: Option<Vec<u8>>,
    clusters: u64,
}

impl Preparer {
    /// Check and encode `node`; what depends on the other nodes (coding tables, numbering) waits
    /// for [`Writer::finish`].
    pub fn prepare(&self, mut node: NodeIn) -> Result<Prepared> {
        let bad = |msg: String| Error::invalid(&self.path, None, msg);
        let l = node.level as usize;
        let g = std::mem::take(&mut node.geometry);
        let (faces, vertices) = (g.indices.len() / 3, g.points.len());
        let a = self.attributes;
        let sized = |present: bool, len: usize| if present { len == vertices } else { len == 0 };
        if !(sized(a.normals, g.normals.len()) && sized(a.uvs, g.uvs.len()) && sized(a.colors, g.colors.len())) || g.indices.len() % 3 != 0
        {
            return Err(bad(format!(
                "level {l} node {}: attributes or indices do not match {vertices} vertices and the file's {a:?}",
                node.key
            )));
        }
        if (l == 0) != g.clusters.is_some() {
            return Err(bad(format!("level {l} node {}: level-0 nodes carry clusters, others none", node.key)));
        }
        if faces > (u32::MAX / 3) as usize || vertices > u32::MAX as usize {
            return Err(bad(format!("level {l} node {}: {faces} faces in one node", node.key)));
        }
        let mut vertices = vertices;
        let mut bytes = Vec::new();
        let mut model = None;
        if self.major >= 3 {
            // Modelled now, coded at `finish` once every node's symbols are counted.
            let normal_bits = if a.normals { g.lattice.normal_bits } else { 0 };
            let color_bits = if a.colors { g.lattice.color_bits } else { 0 };
            let (m, order) = v3::model(&g, self.grid_bits, [node.codes.min, node.codes.max], normal_bits)
                .map_err(|m| bad(format!("level {l} node {}: {m}", node.key)))?;
            // Format 3 stores the vertices its faces use.
            vertices = order.vertices.len();
            m.to_bytes(&mut bytes);
            model = Some((m, normal_bits, color_bits));
        }
        let (span, crc) = if self.major == 2 {
            let payload = v2::encode(&g);
            chunk::put(&mut bytes, id::GEOM, 0, &payload);
            (payload.len() as u64 + chunk::HEADER_BYTES + chunk::TRAILER_BYTES, chunk::crc32(&payload))
        } else {
            // Known once coded (`finish`).
            (bytes.len() as u64, 0)
        };
        let span = u32::try_from(span).map_err(|_| bad(format!("level {l} node {}: geometry of {span} bytes exceeds 4 GiB", node.key)))?;
        // Format 4 has no `ORDR`, which is all supports are for.
        let support = (self.major != MAJOR4).then(|| {
            let mut b = Vec::new();
            Support::of(&g.points).to_bytes(&mut b);
            b
        });
        let clusters = g.clusters.as_ref().map_or(0, |c| c.1.len() as u64);
        Ok(Prepared { node, faces: faces as u32, vertices: vertices as u32, model, bytes, span, crc, support, clusters })
    }
}

/// A file being built node by node.
pub struct Writer<W> {
    out: W,
    path: PathBuf,
    opts: WriterOptions,
    spills: Vec<Spill>,
    /// Every node's [`Support`], which only `finish` reads.
    supports: Spill,
    levels: Vec<Vec<Pending>>,
    clusters: u64,
    preparer: Preparer,
    /// Format 3: symbols per alphabet over every node added, and the normals' bits.
    counts: Vec<Vec<u64>>,
    normal_bits: Option<u32>,
    color_bits: Option<u32>,
    /// Neighbour pairs `(level, key, key)` added after their nodes ([`Writer::link`]).
    links: Vec<(u32, u32, u32)>,
    /// Parents `(level, key, parent)` set after their nodes ([`Writer::set_parent`]).
    parents: Vec<(u32, u32, u32)>,
    /// Format 4: the groups of each level.
    groups: Vec<Vec<GroupIn>>,
    spill_dir: Option<PathBuf>,
}

impl<W: Write> Writer<W> {
    /// Start a file written to `out` (errors name it `path`). Encoded nodes wait in memory, or,
    /// with `spill_dir`, in unlinked temporary files there (the output's folder suits: it has room
    /// for the output).
    pub fn new(out: W, path: &Path, opts: WriterOptions, spill_dir: Option<&Path>) -> Result<Writer<W>> {
        let bad = |msg: String| Error::invalid(path, None, msg);
        if opts.tool.len() as u64 > MAX_TOOL_BYTES {
            return Err(bad(format!("tool string of {} bytes exceeds {MAX_TOOL_BYTES}", opts.tool.len())));
        }
        if !(2..=MAJOR4).contains(&opts.major) {
            return Err(bad(format!("format version {}: this writer writes 2, 3 and 4", opts.major)));
        }
        if opts.levels == 0 || opts.levels == u32::MAX {
            return Err(bad(format!("{} levels", opts.levels)));
        }
        check_images(&opts).map_err(bad)?;
        let spills = (0..opts.levels).map(|_| Spill::new(spill_dir)).collect::<Result<_>>()?;
        let levels = (0..opts.levels).map(|_| Vec::new()).collect();
        let groups = vec![Vec::new(); opts.levels as usize];
        let preparer = Preparer { path: path.to_path_buf(), major: opts.major, grid_bits: opts.grid.bits, attributes: opts.attributes };
        Ok(Writer {
            out,
            path: path.to_path_buf(),
            opts,
            spills,
            supports: Spill::new(spill_dir)?,
            levels,
            clusters: 0,
            preparer,
            counts: vec![Vec::new(); v3::alphabet::ALPHABETS],
            normal_bits: None,
            color_bits: None,
            links: Vec::new(),
            parents: Vec::new(),
            groups,
            spill_dir: spill_dir.map(Path::to_path_buf),
        })
    }

    /// Encode a finished node and keep it for [`finish`](Self::finish).
    pub fn add(&mut self, node: NodeIn) -> Result<()> {
        let prepared = self.preparer.prepare(node)?;
        self.add_prepared(prepared)
    }

    /// What encodes nodes for this file, apart from the writer: so that a build can prepare nodes
    /// on every core and hand them over in order ([`Writer::add_prepared`]).
    pub fn preparer(&self) -> Preparer {
        self.preparer.clone()
    }

    /// Keep a node [`Preparer::prepare`] encoded for [`finish`](Self::finish).
    pub fn add_prepared(&mut self, p: Prepared) -> Result<()> {
        let bad = |msg: String| Error::invalid(&self.path, None, msg);
        let (l, key) = (p.node.level as usize, p.node.key);
        if l >= self.levels.len() {
            return Err(bad(format!("node {key} of level {l}: the file has {} levels", self.levels.len())));
        }
        if let Some((model, normal_bits, color_bits)) = &p.model {
            if *self.normal_bits.get_or_insert(*normal_bits) != *normal_bits {
                return Err(bad(format!("level {l} node {key}: normals at {normal_bits} bits, other nodes at {:?}", self.normal_bits)));
            }
            if *self.color_bits.get_or_insert(*color_bits) != *color_bits {
                return Err(bad(format!("level {l} node {key}: colours at {color_bits} bits, other nodes at {:?}", self.color_bits)));
            }
            model.count(&mut self.counts);
        }
        let spill_at = self.spills[l].append(&p.bytes).map_err(|e| Error::io(&self.path, e))?;
        let support_at = match &p.support {
            Some(bytes) => self.supports.append(bytes).map_err(|e| Error::io(&self.path, e))?,
            None => 0,
        };
        self.clusters += p.clusters;
        let n = p.node;
        self.levels[l].push(Pending {
            key: n.key,
            parent: n.parent,
            source: n.source,
            neighbors: n.neighbors,
            codes: n.codes,
            error: n.error,
            uv_density: texture::density_code(n.uv_density),
            faces: p.faces,
            vertices: p.vertices,
            spill_at,
            padded: p.bytes.len() as u32,
            span: p.span,
            crc: p.crc,
            support_at,
        });
        Ok(())
    }

    /// Format 3: fit the file's coding tables to every node's symbols and code each node's model
    /// into its payload (in a new spill per level); the tables and the bits by kind.
    fn code_models(&mut self) -> Result<(v3::CodeTables, Vec<f64>)> {
        let path = self.path.clone();
        let bad = |msg: String| Error::invalid(&path, None, msg);
        let io = |e: std::io::Error| Error::io(&path, e);
        let tables = v3::CodeTables::fit(self.normal_bits.unwrap_or(0), self.color_bits.unwrap_or(0), &self.counts);
        let enc: Vec<EncodeTable> = tables.freqs.iter().map(EncodeTable::new).collect();
        let costs = v3::symbol_costs(&tables.freqs);
        let mut bits = vec![0f64; v3::alphabet::ALPHABETS];
        // Nodes are coded on every core, a batch of spilled models at a time.
        let code = |spilled: &[u8]| -> std::result::Result<(Vec<f64>, Vec<u8>), String> {
            let (model, _) = v3::Model::from_bytes(spilled).ok_or("a damaged spill")?;
            Ok((model.bits(&costs), model.payload(&enc)?))
        };
        for l in 0..self.levels.len() {
            let mut coded = Spill::new(self.spill_dir.as_deref())?;
            let mut pending = &mut self.levels[l][..];
            while !pending.is_empty() {
                let mut batch_bytes = 0u64;
                let n = pending
                    .iter()
                    .take_while(|p| {
                        batch_bytes += p.padded as u64;
                        batch_bytes <= CODING_BATCH_BYTES
                    })
                    .count()
                    .max(1);
                let (batch, rest) = std::mem::take(&mut pending).split_at_mut(n);
                pending = rest;
                let spilled = batch
                    .iter()
                    .map(|p| {
                        let mut buf = vec![0; p.padded as usize];
                        self.spills[l].read(p.spill_at, &mut buf).map(|_| buf)
                    })
                    .collect::<std::io::Result<Vec<_>>>()
                    .map_err(io)?;
                let results: Vec<_> = spilled.par_iter().map(|b| code(b)).collect();
                drop(spilled);
                for (p, result) in batch.iter_mut().zip(results) {
                    let (node_bits, payload) = result.map_err(|m| bad(format!("level {l} node {}: {m}", p.key)))?;
                    for (b, x) in bits.iter_mut().zip(node_bits) {
                        *b += x;
                    }
                    let size =
                        u32::try_from(payload.len()).map_err(|_| bad(format!("level {l} node {}: {} bytes", p.key, payload.len())))?;
                    p.spill_at = coded.append(&payload).map_err(io)?;
                    (p.padded, p.span, p.crc) = (size, size, chunk::crc32(&payload));
                }
            }
            self.spills[l] = coded;
        }
        Ok((tables, bits))
    }

    /// Format 4: the group records and each node's consumer as stored, for nodes in file order
    /// (`order`: per level, the pending nodes in node order; `group_of`: per level, each group's
    /// number by its key).
    fn dag_codes(&self, order: &[Vec<usize>], group_of: &[FxHashMap<u32, u32>]) -> std::result::Result<DagCodes, String> {
        let nl = self.levels.len();
        let index = |l: usize, key: u32| group_of[l].get(&key).map(|&g| g as usize);
        let mut out = DagCodes { groups: vec![Vec::new(); nl], consumer: Vec::new() };
        let mut outputs: Vec<Vec<u32>> = self.groups.iter().map(|g| vec![0; g.len()]).collect();
        let mut children = outputs.clone();
        for l in (0..nl).rev() {
            for &k in &order[l] {
                let p = &self.levels[l][k];
                if l > 0 {
                    outputs[l][index(l, p.source).ok_or("a source group vanished")?] += 1;
                }
                out.consumer.push(if l + 1 == nl {
                    NO_PARENT
                } else {
                    let g = index(l + 1, p.parent).ok_or("a consumer group vanished")?;
                    children[l + 1][g] += 1;
                    g as u32
                });
            }
        }
        for l in 0..nl {
            if (l == 0) != self.groups[l].is_empty() {
                return Err(format!("level {l} has {} groups; level 0 has none, every other level some", self.groups[l].len()));
            }
            for (i, g) in self.groups[l].iter().enumerate() {
                if outputs[l][i] == 0 || children[l][i] == 0 {
                    return Err(format!("group {} of level {l} has {} outputs and {} children", g.key, outputs[l][i], children[l][i]));
                }
                out.groups[l].push(GroupCodes {
                    outputs: outputs[l][i],
                    children: children[l][i],
                    error: g.error,
                    radius: g.radius,
                    center: g.center,
                });
            }
        }
        Ok(out)
    }

    /// Format 4: add a group of the DAG.
    pub fn add_group(&mut self, group: GroupIn) -> Result<()> {
        let l = group.level as usize;
        if self.opts.major != MAJOR4 || l == 0 || l >= self.groups.len() {
            return Err(Error::invalid(
                &self.path,
                None,
                format!("group {} of level {l}: groups are format 4's, of levels 1 to {}", group.key, self.groups.len().saturating_sub(1)),
            ));
        }
        self.groups[l].push(group);
        Ok(())
    }

    /// Set the input's vertex count the summary reports (the partitioned build knows it last).
    pub fn set_input_vertices(&mut self, n: u64) {
        self.opts.input_vertices = n;
    }

    /// The file's levels so far.
    pub fn levels(&self) -> u32 {
        self.levels.len() as u32
    }

    /// Let the file have `levels` levels (not fewer than it has): the partitioned build knows how
    /// many only once it has merged its cells.
    pub fn set_levels(&mut self, levels: u32) -> Result<()> {
        if (levels as usize) < self.levels.len() || levels == u32::MAX {
            return Err(Error::invalid(&self.path, None, format!("{levels} levels for a file begun with {}", self.levels.len())));
        }
        while self.levels.len() < levels as usize {
            self.spills.push(Spill::new(self.spill_dir.as_deref())?);
            self.levels.push(Vec::new());
            self.groups.push(Vec::new());
        }
        self.opts.levels = levels;
        Ok(())
    }

    /// Make nodes `a` and `b` of `level` neighbours, whether or not they have been added yet (the
    /// partitioned build learns of neighbours across cells only when it merges them).
    pub fn link(&mut self, level: u32, a: u32, b: u32) {
        self.links.push((level, a, b));
    }

    /// Make `parent` the parent (format 4: the consumer group) of node `key` of `level`, whether or
    /// not it has been added yet: a partitioned build knows it only once it builds on the node.
    pub fn set_parent(&mut self, level: u32, key: u32, parent: u32) {
        self.parents.push((level, key, parent));
    }

    /// Number the nodes, write the whole file and return what it holds.
    pub fn finish(mut self) -> Result<WriteSummary> {
        if self.levels[0].is_empty() {
            return Err(Error::invalid(&self.path, None, "nothing to write: level 0 has no nodes"));
        }
        if !self.parents.is_empty() {
            let mut parents = std::mem::take(&mut self.parents);
            parents.sort_unstable();
            for (l, pending) in self.levels.iter_mut().enumerate() {
                let set = &parents[parents.partition_point(|x| (x.0 as usize) < l)..parents.partition_point(|x| (x.0 as usize) <= l)];
                let mut by_key: Vec<(u32, usize)> = pending.iter().enumerate().map(|(i, p)| (p.key, i)).collect();
                by_key.sort_unstable();
                for &(_, key, parent) in set {
                    match by_key.binary_search_by_key(&key, |x| x.0) {
                        Ok(i) => pending[by_key[i].1].parent = parent,
                        Err(_) => {
                            return Err(Error::invalid(&self.path, None, format!("level {l}: no node {key} to give parent {parent}")))
                        }
                    }
                }
            }
            if let Some(&(l, key, _)) = parents.iter().find(|x| x.0 as usize >= self.levels.len()) {
                return Err(Error::invalid(&self.path, None, format!("a parent for node {key} of level {l}: the file has fewer levels")));
            }
        }
        let code = if self.opts.major >= 3 { Some(self.code_models()?) } else { None };
        let bad = |msg: String| Error::invalid(&self.path, None, msg);
        let io = |e: std::io::Error| Error::io(&self.path, e);
        let nl = self.levels.len();
        if !self.links.is_empty() {
            let mut links = std::mem::take(&mut self.links);
            links.sort_unstable();
            links.dedup();
            for l in 0..nl {
                let at: FxHashMap<u32, usize> = self.levels[l].iter().enumerate().map(|(i, p)| (p.key, i)).collect();
                for &(_, a, b) in links.iter().filter(|x| x.0 as usize == l) {
                    match (at.get(&a), at.get(&b)) {
                        (Some(&ia), Some(&ib)) => {
                            self.levels[l][ia].neighbors.push(b);
                            self.levels[l][ib].neighbors.push(a);
                        }
                        _ => return Err(bad(format!("level {l}: neighbours {a} and {b} are not both nodes"))),
                    }
                }
            }
            if let Some(&(l, a, _)) = links.iter().find(|x| x.0 as usize >= nl) {
                return Err(bad(format!("neighbours at level {l} (node {a}): the file has {nl} levels")));
            }
        }

        // Format 4: each level's groups by key (strata-v4.md §1).
        let dag = self.opts.major == MAJOR4;
        let mut group_of: Vec<FxHashMap<u32, u32>> = vec![FxHashMap::default(); nl];
        for (l, (groups, index)) in self.groups.iter_mut().zip(&mut group_of).enumerate() {
            groups.sort_by_key(|g| g.key);
            for (i, g) in groups.iter().enumerate() {
                if index.insert(g.key, i as u32).is_some() {
                    return Err(bad(format!("level {l}: two groups with key {}", g.key)));
                }
            }
        }
        // Breadth-first numbering (spec §6): the top level by key, then each level by parent, then
        // key. Format 4: each level by source group, then key.
        let mut order: Vec<Vec<usize>> = vec![Vec::new(); nl];
        let mut node_of: Vec<FxHashMap<u32, u32>> = vec![FxHashMap::default(); nl];
        let mut level_first = vec![0u32; nl];
        let mut next = 0u64;
        for l in (0..nl).rev() {
            let pending = &self.levels[l];
            let mut parent_node = Vec::with_capacity(pending.len());
            for p in pending {
                let parent = if l + 1 == nl && p.parent != NO_PARENT {
                    return Err(bad(format!("top-level node {} has parent {}", p.key, p.parent)));
                } else if dag {
                    if l + 1 < nl && !group_of[l + 1].contains_key(&p.parent) {
                        return Err(bad(format!("level {l} node {}: no consumer group {} in level {}", p.key, p.parent, l + 1)));
                    }
                    match (l, group_of[l].get(&p.source)) {
                        (0, _) if p.source == NO_PARENT => 0,
                        (1.., Some(&g)) => g,
                        _ => return Err(bad(format!("level {l} node {}: no source group {} in its level", p.key, p.source))),
                    }
                } else if l + 1 == nl {
                    0
                } else {
                    *node_of[l + 1]
                        .get(&p.parent)
                        .ok_or_else(|| bad(format!("level {l} node {}: no parent {} in level {}", p.key, p.parent, l + 1)))?
                };
                parent_node.push(parent);
            }
            let mut idx: Vec<usize> = (0..pending.len()).collect();
            idx.sort_by_key(|&k| (parent_node[k], pending[k].key));
            level_first[l] = next as u32;
            for (n, &k) in idx.iter().enumerate() {
                if node_of[l].insert(pending[k].key, (next + n as u64) as u32).is_some() {
                    return Err(bad(format!("level {l}: two nodes with key {}", pending[k].key)));
                }
            }
            next += idx.len() as u64;
            if next >= NO_PARENT as u64 {
                return Err(bad(format!("{next} nodes")));
            }
            order[l] = idx;
        }
        let total = next as usize;

        // Records in file order, children ranges and neighbour lists.
        let mut records: Vec<NodeRecord> = Vec::with_capacity(total);
        let mut codes: Vec<NodeCodes> = Vec::with_capacity(total);
        let mut density: Vec<u16> = Vec::with_capacity(total);
        let mut neighbors: Vec<u32> = Vec::new();
        let mut levels = vec![LevelRecord::default(); nl];
        for l in (0..nl).rev() {
            levels[l].first_node = level_first[l];
            levels[l].nodes = self.levels[l].len() as u32;
            for &k in &order[l] {
                let p = &self.levels[l][k];
                let start = neighbors.len();
                neighbors.extend(
                    p.neighbors
                        .iter()
                        .filter(|&&x| x != p.key)
                        .map(|x| node_of[l].get(x).copied().ok_or(*x))
                        .collect::<std::result::Result<Vec<_>, _>>()
                        .map_err(|x| bad(format!("level {l} node {}: no neighbour {x}", p.key)))?,
                );
                neighbors[start..].sort_unstable();
                let mut kept = start;
                for i in start..neighbors.len() {
                    if kept == start || neighbors[i] != neighbors[kept - 1] {
                        neighbors[kept] = neighbors[i];
                        kept += 1;
                    }
                }
                neighbors.truncate(kept);
                let parent = if l + 1 == nl || dag { NO_PARENT } else { node_of[l + 1][&p.parent] };
                let grid = self.opts.grid;
                records.push(NodeRecord {
                    level: l as u32,
                    parent,
                    first_child: 0,
                    child_count: 0,
                    neighbor_first: start as u32,
                    neighbor_count: (neighbors.len() - start) as u32,
                    cone: Cone { axis: super::octa::decode(p.codes.axis), half_angle: angle_decode(p.codes.half_angle) },
                    center: grid.decode(p.codes.center),
                    radius: grid.length(super::radius_decode(p.codes.radius)),
                    error: p.error,
                    faces: p.faces,
                    vertices: p.vertices,
                    offset: 0,
                    size: p.span,
                    crc: p.crc,
                });
                codes.push(p.codes);
                density.push(p.uv_density);
                let level = &mut levels[l];
                level.faces += p.faces as u64;
                level.vertices += p.vertices as u64;
                level.bytes += p.padded as u64;
            }
        }
        for i in 0..total {
            let parent = records[i].parent;
            if parent != NO_PARENT {
                let pr = &mut records[parent as usize];
                if pr.child_count == 0 {
                    pr.first_child = i as u32;
                }
                pr.child_count += 1;
            }
        }
        if let Some(r) = records.iter().find(|r| r.child_count > u16::MAX as u32 || r.neighbor_count > u16::MAX as u32) {
            return Err(bad(format!(
                "a node of level {} has {} children and {} neighbours; at most {} each",
                r.level,
                r.child_count,
                r.neighbor_count,
                u16::MAX
            )));
        }

        let top = level_first[nl - 1] as usize..(level_first[nl - 1] + levels[nl - 1].nodes) as usize;
        let grid = self.opts.grid;
        // Format 3 carries GEOR from its first minor version; 2.1 added it to format 2, 2.2 images
        // and UVs in glTF's orientation (so a file with UVs is 2.2 with or without images).
        let images = &self.opts.images;
        let planes = if dag {
            Planes::default()
        } else {
            let mut bytes = [0u8; Support::BYTES];
            let supports = (0..nl)
                .rev()
                .flat_map(|l| order[l].iter().map(move |&k| (l, k)))
                .map(|(l, k)| self.supports.read(self.levels[l][k].support_at, &mut bytes).map(|_| Support::from_bytes(&bytes)))
                .collect::<std::io::Result<Vec<Support>>>()
                .map_err(|e| Error::io(&self.path, e))?;
            self.supports = Spill::Memory(Vec::new());
            order_planes(&records, &codes, supports, levels[nl - 1].nodes)
        };
        let minor =
            match (self.opts.major, !planes.entries.is_empty(), !images.is_empty() || self.opts.attributes.uvs, self.opts.georef.is_some())
            {
                (2, true, _, _) => MINOR,
                (2, false, true, _) => 2,
                (2, false, false, true) => 1,
                (3, ..) => MINOR3,
                (MAJOR4, ..) => MINOR4,
                _ => 0,
            };
        let mut header = Header {
            major: self.opts.major,
            minor,
            file_size: 0,
            metres_per_unit: self.opts.metres_per_unit,
            min: codes[top.clone()].iter().fold(Vec3::splat(f32::MAX), |m, c| m.min(grid.decode(c.min))),
            max: codes[top].iter().fold(Vec3::splat(f32::MIN), |m, c| m.max(grid.decode(c.max))),
            attributes: self.opts.attributes,
            levels: nl as u32,
            nodes: total as u32,
            materials: self.opts.materials.len() as u32,
            input_vertices: self.opts.input_vertices,
            input_faces: levels[0].faces,
            clusters: u32::try_from(self.clusters).map_err(|_| bad(format!("{} clusters", self.clusters)))?,
            params: self.opts.params,
            grid,
            level_ratio: self.opts.level_ratio,
            tool: self.opts.tool.clone(),
        };
        let image_order = texture::layout_order(images);
        let texr = (!images.is_empty()).then(|| texture::encode_texr(images, &image_order, &self.opts.materials, &density));
        let code_payload = code.as_ref().map(|(t, _)| t.encode());
        let paged = super::paged(header.major, header.minor);
        let dag_codes = if dag { Some(self.dag_codes(&order, &group_of).map_err(bad)?) } else { None };
        let skel = encode_skel(
            &levels,
            &records,
            &codes,
            &neighbors,
            &self.opts.materials,
            texr.as_deref(),
            code_payload.as_deref(),
            paged,
            dag_codes.as_ref(),
        );
        let geor = self.opts.georef.as_ref().map(georef::encode).unwrap_or_default();
        let skeleton_bytes = super::PROLOGUE_BYTES + encode_head(&header).len() as u64 + geor.len() as u64 + skel.len() as u64;
        let image_bytes: u64 = image_order
            .iter()
            .map(|&(i, l)| {
                let end = images[i as usize].levels[l as usize].bytes.len() as u64 + chunk::HEADER_BYTES + chunk::TRAILER_BYTES;
                end + chunk::padding(end)
            })
            .sum();
        let ordr = (!planes.entries.is_empty()).then(|| {
            let (width, payload) = planes::encode_ordr(&planes);
            let mut out = Vec::new();
            chunk::put(&mut out, id::ORDR, width, &payload);
            out
        });
        let ordr = ordr.unwrap_or_default();
        let geometry_bytes = levels.iter().map(|l| l.bytes).sum::<u64>();
        let (first, geometry_end) = geometry_layout(self.opts.major, skeleton_bytes, geometry_bytes);
        header.file_size = geometry_end + image_bytes + ordr.len() as u64;

        let mut prologue = Vec::with_capacity(16);
        prologue.extend_from_slice(&MAGIC);
        prologue.extend_from_slice(&self.opts.major.to_le_bytes());
        prologue.extend_from_slice(&minor.to_le_bytes());
        let crc = chunk::crc32(&prologue);
        prologue.extend_from_slice(&crc.to_le_bytes());
        self.out.write_all(&prologue).map_err(io)?;
        self.out.write_all(&encode_head(&header)).map_err(io)?;
        self.out.write_all(&geor).map_err(io)?;
        self.out.write_all(&skel).map_err(io)?;
        let mut buf = Vec::new();
        let mut crc = crc32fast::Hasher::new();
        if first > skeleton_bytes {
            // Format 3: one GEOS chunk holds every node's payload.
            self.out.write_all(&chunk::Frame { id: id::GEOS, flags: 0, size: geometry_bytes }.bytes()).map_err(io)?;
        }
        for l in (0..nl).rev() {
            for &k in &order[l] {
                let p = &self.levels[l][k];
                buf.resize(p.padded as usize, 0);
                self.spills[l].read(p.spill_at, &mut buf).map_err(io)?;
                self.out.write_all(&buf).map_err(io)?;
                crc.update(&buf);
            }
            self.spills[l] = Spill::Memory(Vec::new());
        }
        if first > skeleton_bytes {
            let end = first + geometry_bytes;
            let mut trailer = crc.finalize().to_le_bytes().to_vec();
            trailer.resize(4 + chunk::padding(end + 4) as usize, 0);
            self.out.write_all(&trailer).map_err(io)?;
        }
        for &(i, l) in &image_order {
            buf.clear();
            chunk::put(&mut buf, id::TEXL, 0, &images[i as usize].levels[l as usize].bytes);
            self.out.write_all(&buf).map_err(io)?;
        }
        self.out.write_all(&ordr).map_err(io)?;
        self.out.flush().map_err(io)?;

        Ok(WriteSummary {
            file_bytes: header.file_size,
            skeleton_bytes,
            input_faces: header.input_faces,
            nodes: header.nodes,
            clusters: header.clusters,
            levels: levels
                .iter()
                .enumerate()
                .map(|(l, r)| LevelSummary { level: l as u32, nodes: r.nodes, faces: r.faces, vertices: r.vertices, bytes: r.bytes })
                .collect(),
            geometry_bits: code.map(|(_, bits)| bits),
            image_bytes,
        })
    }
}

/// Images are consistent: levels halve (rounding up) from the full image, at most
/// [`texture::MAX_LEVELS`] of at most [`texture::MAX_SIDE`] a side, each level's header states its
/// size, and every material slot names an image.
/// Separating planes between the children of every parent (the virtual root first, then nodes in
/// file order): every pair of up to 16 siblings, else each child with its 8 nearest siblings by box
/// gap; a pair gets a plane when one of [`planes::directions`] leaves a slab no thicker than a
/// quarter of the smaller box's diagonal.
fn order_planes(records: &[NodeRecord], codes: &[NodeCodes], supports: Vec<Support>, top: u32) -> Planes {
    let mut subtree = supports;
    for i in (0..records.len()).rev() {
        let p = records[i].parent;
        if p != NO_PARENT {
            let (head, tail) = subtree.split_at_mut(i);
            head[p as usize].union(&tail[0]);
        }
    }
    let diag = |i: usize| {
        let c = &codes[i];
        (0..3).map(|k| (c.max[k] as f64 - c.min[k] as f64).powi(2)).sum::<f64>().sqrt()
    };
    let parents = std::iter::once((0u32, top)).chain(records.iter().map(|r| (r.first_child, r.child_count)));
    let mut out = Planes { starts: vec![0], entries: Vec::new() };
    for (first, count) in parents {
        let kids = first as usize..(first + count) as usize;
        let mut pairs: Vec<(u32, u32)> = Vec::new();
        if count <= 16 {
            for a in 0..count {
                pairs.extend((a + 1..count).map(|b| (a, b)));
            }
        } else {
            for (a, near) in nearest_by_gap(&codes[kids.clone()], 8).into_iter().enumerate() {
                pairs.extend(near.into_iter().map(|b| (a.min(b) as u32, a.max(b) as u32)));
            }
            pairs.sort_unstable();
            pairs.dedup();
        }
        for (a, b) in pairs {
            let (ia, ib) = (first as usize + a as usize, first as usize + b as usize);
            let slack = 0.25 * diag(ia).min(diag(ib));
            if let Some(e) = planes::separate(&subtree[ia], &subtree[ib], slack) {
                let (x, y) = if e.first == 0 { (a, b) } else { (b, a) };
                out.entries.push(PlaneEntry { first: x, second: y, ..e });
            }
        }
        out.starts.push(out.entries.len() as u32);
    }
    out
}

/// Box gap between two nodes' boxes, in grid steps: the largest separation along an axis, 0 when
/// they overlap.
fn box_gap(x: &NodeCodes, y: &NodeCodes) -> i64 {
    (0..3).map(|k| (x.min[k].max(y.min[k]) as i64 - x.max[k].min(y.max[k]) as i64).max(0)).max().unwrap_or(0)
}

/// For each box, the `k` others smallest by (box gap, index): exactly the brute-force choice, found
/// by sweeping the boxes sorted by their lower bound along the axis where those spread most, each
/// direction stopped once no box further on can have a gap within the `k`-th found (downward, by
/// the largest upper bound among the boxes left).
fn nearest_by_gap(codes: &[NodeCodes], k: usize) -> Vec<Vec<usize>> {
    let n = codes.len();
    let spread = |a: usize| {
        let (lo, hi) = codes.iter().fold((u32::MAX, 0), |(lo, hi), c| (lo.min(c.min[a]), hi.max(c.min[a])));
        hi.saturating_sub(lo)
    };
    let axis = (0..3).max_by_key(|&a| (spread(a), std::cmp::Reverse(a))).unwrap_or(0);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_unstable_by_key(|&i| (codes[i].min[axis], i));
    // Over each prefix of that order, the largest upper bound along the axis.
    let reach: Vec<i64> = order
        .iter()
        .scan(0i64, |m, &i| {
            *m = (*m).max(codes[i].max[axis] as i64);
            Some(*m)
        })
        .collect();
    let mut out = Vec::with_capacity(n);
    let mut best: Vec<(i64, usize)> = Vec::with_capacity(k + 1);
    for (at, &a) in order.iter().enumerate() {
        best.clear();
        let ca = &codes[a];
        let worst = |best: &Vec<(i64, usize)>| if best.len() < k { i64::MAX } else { best[k - 1].0 };
        let offer = |best: &mut Vec<(i64, usize)>, b: usize| {
            let e = (box_gap(ca, &codes[b]), b);
            if best.len() < k || e < best[k - 1] {
                let i = best.partition_point(|x| *x < e);
                best.insert(i, e);
                best.truncate(k);
            }
        };
        // Above: gap ≥ b.min − a.max along the axis, which only grows.
        for &b in &order[at + 1..] {
            if codes[b].min[axis] as i64 - ca.max[axis] as i64 > worst(&best) {
                break;
            }
            offer(&mut best, b);
        }
        // Below: gap ≥ a.min − b.max ≥ a.min − (the prefix's largest max), which only grows.
        for j in (0..at).rev() {
            if ca.min[axis] as i64 - reach[j] > worst(&best) {
                break;
            }
            offer(&mut best, order[j]);
        }
        out.push((a, best.iter().map(|&(_, b)| b).collect::<Vec<usize>>()));
    }
    out.sort_unstable_by_key(|x| x.0);
    out.into_iter().map(|(_, near)| near).collect()
}

fn check_images(opts: &WriterOptions) -> std::result::Result<(), String> {
    if opts.images.len() > u32::MAX as usize - 1 {
        return Err(format!("{} images", opts.images.len()));
    }
    for (i, im) in opts.images.iter().enumerate() {
        let name = &im.name;
        if im.levels.is_empty() || im.levels.len() > texture::MAX_LEVELS as usize || name.len() > texture::MAX_NAME_BYTES as usize {
            return Err(format!("image {i} ({name}): {} levels, name of {} bytes", im.levels.len(), name.len()));
        }
        for (l, v) in im.levels.iter().enumerate() {
            if v.width == 0
                || v.height == 0
                || v.width > texture::MAX_SIDE
                || v.height > texture::MAX_SIDE
                || v.width as u64 * v.height as u64 > texture::MAX_PIXELS
            {
                return Err(format!("image {i} ({name}) level {l}: {} × {}", v.width, v.height));
            }
            if l > 0 {
                let p = &im.levels[l - 1];
                if v.width != texture::half(p.width) || v.height != texture::half(p.height) || (p.width == 1 && p.height == 1) {
                    return Err(format!("image {i} ({name}) level {l} does not halve level {}", l - 1));
                }
            }
            match texture::image_size(im.codec, &v.bytes) {
                Ok(s) if s == (v.width, v.height) => {}
                Ok((w, h)) => return Err(format!("image {i} ({name}) level {l}: the file is {w} × {h}, not {} × {}", v.width, v.height)),
                Err(m) => return Err(format!("image {i} ({name}) level {l}: {m}")),
            }
            if v.bytes.len() as u64 + chunk::HEADER_BYTES + chunk::TRAILER_BYTES > u32::MAX as u64 {
                return Err(format!("image {i} ({name}) level {l}: {} bytes", v.bytes.len()));
            }
        }
    }
    for (m, mat) in opts.materials.iter().enumerate() {
        if let Some(s) = mat.maps.iter().flatten().find(|s| s.image as usize >= opts.images.len()) {
            return Err(format!("material {m} names image {} of {}", s.image, opts.images.len()));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sweep picks exactly what comparing every pair picks, ties included.
    #[test]
    fn nearest_by_gap_is_the_brute_force_choice() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = |n: u32| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % n as u64) as u32
        };
        for (n, span, size) in [(17, 40, 5), (60, 1000, 80), (300, 30, 3), (500, 100_000, 20_000), (40, 4, 4)] {
            let codes: Vec<NodeCodes> = (0..n)
                .map(|_| {
                    let min = [next(span), next(span / 3 + 1), next(span)];
                    let max = min.map(|m| m + next(size));
                    NodeCodes { min, max, ..NodeCodes::default() }
                })
                .collect();
            let fast = nearest_by_gap(&codes, 8);
            for a in 0..codes.len() {
                let mut near: Vec<(i64, usize)> =
                    (0..codes.len()).filter(|&b| b != a).map(|b| (box_gap(&codes[a], &codes[b]), b)).collect();
                near.sort_unstable();
                let mut want: Vec<usize> = near.iter().take(8).map(|x| x.1).collect();
                let mut got = fast[a].clone();
                want.sort_unstable();
                got.sort_unstable();
                assert_eq!(got, want, "{n} boxes, box {a}");
            }
        }
    }
}
