//! The skeleton of a file, `HEAD` and `SKEL` (spec §5, §7): decoded from their payloads into a
//! [`Skeleton`], everything a viewer needs before reading any geometry, and encoded back.

use super::chunk::{self, Fields, Frame, Sub, HEADER_BYTES, TRAILER_BYTES};
use super::geom::v3;
use super::texture;
use super::{
    angle_decode, id, octa, pack, radius_decode, unpack, Attributes, Cone, DagTable, Grid, GroupRecord, Header, HierarchyParams,
    LevelRecord, Material, NodeRecord, Textures, GROUP_RECORD_BYTES, HEAD_FIXED_BYTES, LEVEL_RECORD_BYTES, MAX_GRID_BITS, MAX_TOOL_BYTES,
    NODE_RECORD_BYTES, NO_PARENT,
};
use crate::error::{Error, Result};
use byteorder::{ByteOrder, LittleEndian as LE};
use glam::Vec3;
use std::ops::Range;
use std::path::Path;

/// A chunk's place in the file, for listings.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ChunkInfo {
    pub id: String,
    /// File offset of the chunk's ID.
    pub offset: u64,
    pub flags: u32,
    /// Payload bytes.
    pub size: u64,
    /// 0 for top-level chunks, 1 for their sub-chunks.
    pub depth: u32,
}

impl ChunkInfo {
    pub fn new(frame: &Frame, offset: u64, depth: u32) -> ChunkInfo {
        ChunkInfo { id: chunk::id_str(&frame.id), offset, flags: frame.flags, size: frame.size, depth }
    }
}

/// The header and skeleton of a file: levels, the node table, neighbours and materials. Front
/// selection needs nothing else.
#[derive(Clone, Debug, PartialEq)]
pub struct Skeleton {
    pub header: Header,
    /// Per level, finest first: node range, faces, vertices and bytes.
    pub levels: Vec<LevelRecord>,
    /// The node table, in file order (top level first).
    pub nodes: Vec<NodeRecord>,
    /// Every node's neighbour list, end to end in node order ([`NodeRecord::neighbor_first`]).
    pub neighbors: Vec<u32>,
    pub materials: Vec<Material>,
    /// Each node's box as packed grid points (min, max): 16 bytes a node, decoded on demand.
    pub boxes: Vec<[u64; 2]>,
    /// The images the materials use and each node's UV density (`TEXR`); empty without images.
    pub textures: Textures,
    /// Format 3: the coding tables of node geometry (`CODE`).
    pub code: Option<std::sync::Arc<v3::Code>>,
    /// Format 4: the DAG's groups, and each node's consumer and source (strata-v4.md). Its node
    /// records have no children and no neighbours.
    pub dag: Option<DagTable>,
}

impl Skeleton {
    /// Nodes of level `level` (empty past the top).
    pub fn level_nodes(&self, level: u32) -> Range<u32> {
        self.levels.get(level as usize).map_or(0..0, |l| l.first_node..l.first_node + l.nodes)
    }

    /// Whether every node record is decoded (see `decode_skel`'s `top_only`).
    pub fn is_complete(&self) -> bool {
        self.nodes.len() == self.header.nodes as usize
    }

    /// The top level, the one shown first.
    pub fn top(&self) -> u32 {
        self.levels.len().saturating_sub(1) as u32
    }

    /// Children of node `i` (nodes of the level below).
    pub fn children(&self, i: u32) -> Range<u32> {
        self.nodes.get(i as usize).map_or(0..0, |n| n.first_child..n.first_child + n.child_count)
    }

    /// Same-level neighbours of node `i`.
    pub fn neighbors(&self, i: u32) -> &[u32] {
        self.nodes
            .get(i as usize)
            .map_or(&[], |n| &self.neighbors[n.neighbor_first as usize..(n.neighbor_first + n.neighbor_count) as usize])
    }

    /// Node `i`'s bounding box as grid points (min, max).
    pub fn node_box_points(&self, i: u32) -> [[u32; 3]; 2] {
        self.boxes.get(i as usize).map_or([[0; 3]; 2], |b| [unpack(b[0]).unwrap_or_default(), unpack(b[1]).unwrap_or_default()])
    }

    /// Node `i`'s bounding box (min, max).
    pub fn node_box(&self, i: u32) -> (Vec3, Vec3) {
        let grid = self.header.grid;
        let corner = |v: u64| unpack(v).map_or(Vec3::NAN, |g| grid.decode(g));
        self.boxes.get(i as usize).map_or((Vec3::NAN, Vec3::NAN), |b| (corner(b[0]), corner(b[1])))
    }
}

/// Where node geometry lies, given where it starts (right after `SKEL` and its padding) and the
/// bytes the levels' geometry takes (`LEVL`): the first node's offset and the end of the geometry,
/// padding included. Format 2 stores a `GEOM` chunk per node, back to back; format 3 one `GEOS`
/// chunk whose payload is every node's payload back to back.
pub fn geometry_layout(major: u16, start: u64, bytes: u64) -> (u64, u64) {
    if major >= 3 {
        let end = start + HEADER_BYTES + bytes + TRAILER_BYTES;
        (start + HEADER_BYTES, end + chunk::padding(end))
    } else {
        (start, start + bytes)
    }
}

/// What decoding the skeleton needs to know of the file around it.
pub struct Context<'a> {
    /// The name errors give the file.
    pub path: &'a Path,
    /// Version from the prologue.
    pub major: u16,
    pub minor: u16,
    /// Length of the whole file.
    pub file_size: u64,
    /// Where node 0's `GEOM` chunk starts: right after `SKEL` and its padding.
    pub geometry_start: u64,
}

impl Context<'_> {
    fn err(&self, at: u64, id: &[u8; 4], chunk_offset: u64, msg: impl std::fmt::Display) -> Error {
        Error::at_byte(self.path, at, format!("{}: {msg}", chunk::name(id, chunk_offset)))
    }
}

/// The node codes the `NODE` table stores besides counts: box corners and sphere center on the
/// grid, cone axis and half-angle, radius (spec §7.2).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NodeCodes {
    pub min: [u32; 3],
    pub max: [u32; 3],
    pub center: [u32; 3],
    pub axis: [i16; 2],
    pub half_angle: u16,
    pub radius: u16,
}

/// Decode the `HEAD` payload of the chunk at `pos`.
pub fn decode_head(ctx: &Context, payload: &[u8], pos: u64) -> Result<Header> {
    let mut f = Fields::new(ctx.path, &id::HEAD, pos, payload, pos + HEADER_BYTES);
    if (payload.len() as u64) < HEAD_FIXED_BYTES {
        return Err(f.error(format!("{} bytes, fewer than the {HEAD_FIXED_BYTES} of its fixed fields", payload.len())));
    }
    let newer = ctx.minor > super::known_minor(ctx.major);
    let file_size = f.u64()?;
    let at = f.offset();
    let metres_per_unit = f.f64()?;
    if !(metres_per_unit.is_finite() && metres_per_unit >= 0.0) {
        return Err(f.error_at(at, format!("metres per unit {metres_per_unit}")));
    }
    let at = f.offset();
    let (min, max) = (f.vec3()?, f.vec3()?);
    if !(min.is_finite() && max.is_finite()) {
        return Err(f.error_at(at, "bounds are not finite"));
    }
    let at = f.offset();
    let bits = f.u32()?;
    if bits & !7 != 0 && !newer {
        return Err(f.error_at(at, format!("unknown attribute bits {bits:#x}")));
    }
    let at = f.offset();
    let (levels, nodes, materials) = (f.u32()?, f.u32()?, f.u32()?);
    if levels == 0 || nodes < levels || nodes == NO_PARENT {
        return Err(f.error_at(at, format!("{levels} levels and {nodes} nodes")));
    }
    let (input_vertices, input_faces, clusters) = (f.u64()?, f.u64()?, f.u32()?);
    let params = HierarchyParams {
        cluster_faces: f.u32()?,
        cluster_angle: f.f32()?,
        leaf_faces: f.u32()?,
        leaf_angle: f.f32()?,
        angle_step: f.f32()?,
        growth: f.u32()?,
        kc: f.f32()?,
        ks: f.f32()?,
        kn: f.f32()?,
        top_groups: f.u32()? as usize,
    };
    let level_ratio = f.f32()?;
    let at = f.offset();
    let grid = Grid { origin: [f.f64()?, f.f64()?, f.f64()?], step: f.f64()?, bits: f.u32()? };
    let sane = grid.origin.iter().all(|x| x.is_finite())
        && grid.step.is_finite()
        && grid.step > 0.0
        && (1..=MAX_GRID_BITS).contains(&grid.bits)
        && grid.decode([0; 3]).is_finite()
        && grid.decode([grid.last(); 3]).is_finite();
    if !sane {
        return Err(f.error_at(at, format!("grid origin {:?}, step {}, {} bits", grid.origin, grid.step, grid.bits)));
    }
    let at = f.offset();
    let tool_len = f.u32()?;
    if tool_len as u64 > MAX_TOOL_BYTES {
        return Err(f.error_at(at, format!("tool string of {tool_len} bytes exceeds {MAX_TOOL_BYTES}")));
    }
    let tool = f.string(tool_len)?;
    if f.remaining() > 0 && !newer {
        return Err(f.error(format!("{} bytes after the tool string", f.remaining())));
    }
    Ok(Header {
        major: ctx.major,
        minor: ctx.minor,
        file_size,
        metres_per_unit,
        min,
        max,
        attributes: Attributes::from_bits(bits),
        levels,
        nodes,
        materials,
        input_vertices,
        input_faces,
        clusters,
        params,
        grid,
        level_ratio,
        tool,
    })
}

/// Decode the `SKEL` payload of the chunk at `pos`, checking every table against `header` and the
/// file (spec §10, steps 4 and 5); also the sub-chunks found, for listings. With `top_only`, every
/// record is still checked, but only the top two levels' nodes are decoded into the [`Skeleton`]
/// with their boxes and neighbour lists: a viewer that shows the top level first need not touch
/// the memory of the rest (104 bytes a node and the lists) before its first frame. With
/// `partial`, `payload` is the first part of a format-3.1 SKEL, through at least the top two
/// levels' pages (strata-v3.md §1.1), and only those are checked.
pub fn decode_skel(
    ctx: &Context,
    header: &Header,
    payload: &[u8],
    pos: u64,
    top_only: bool,
    partial: bool,
) -> Result<(Skeleton, Vec<ChunkInfo>)> {
    let base = pos + HEADER_BYTES;
    let subs = chunk::subs(ctx.path, &id::SKEL, pos, payload, base)?;
    let infos = subs.iter().map(|s| ChunkInfo::new(&s.frame, s.offset, 1)).collect();
    let find = |want: [u8; 4]| -> Result<&Sub> {
        let mut found = subs.iter().filter(|s| s.frame.id == want);
        let first = found.next().ok_or_else(|| ctx.err(pos, &id::SKEL, pos, format!("has no {} chunk", chunk::id_str(&want))))?;
        if let Some(dup) = found.next() {
            return Err(ctx.err(dup.offset, &id::SKEL, pos, format!("has a second {} chunk", chunk::id_str(&want))));
        }
        Ok(first)
    };
    let (levl, matl) = (find(id::LEVL)?, find(id::MATL)?);
    let fields = |s: &Sub| Fields::new(ctx.path, &s.frame.id, s.offset, &payload[s.start..s.end], s.payload_offset());
    let h = header;

    // LEVL
    let mut f = fields(levl);
    let want = h.levels as u64 * LEVEL_RECORD_BYTES;
    if levl.frame.size != want {
        return Err(f.error(format!("holds {} bytes; {} levels need {want}", levl.frame.size, h.levels)));
    }
    let mut levels = Vec::with_capacity(h.levels as usize);
    for _ in 0..h.levels {
        levels.push(LevelRecord { first_node: f.u32()?, nodes: f.u32()?, faces: f.u64()?, vertices: f.u64()?, bytes: f.u64()? });
    }
    let mut expect = 0u64;
    for (l, rec) in levels.iter().enumerate().rev() {
        if rec.first_node as u64 != expect || rec.nodes == 0 {
            let at = levl.payload_offset() + l as u64 * LEVEL_RECORD_BYTES;
            return Err(f.error_at(
                at,
                format!("level {l} has nodes {}..+{}; expected a non-empty range from {expect}", rec.first_node, rec.nodes),
            ));
        }
        expect += rec.nodes as u64;
    }
    if expect != h.nodes as u64 {
        return Err(f.error(format!("levels hold {expect} nodes, HEAD says {}", h.nodes)));
    }
    // Every node has a 56-byte record inside SKEL, which ends before the geometry (strata-v3.md §1.1).
    let room = ctx.geometry_start.saturating_sub(pos + HEADER_BYTES + TRAILER_BYTES);
    if expect * NODE_RECORD_BYTES > room {
        return Err(f.error(format!("{expect} nodes need {} bytes of node records; SKEL holds at most {room}", expect * NODE_RECORD_BYTES)));
    }

    // The node records and neighbour lists, as pages from the top level down: format 2's NODE and
    // NBRS hold every level; format 3 has one NODL per level (strata-v3.md §1.1), of which a
    // reader that opens top first has read the first few.
    let paged = super::paged(ctx.major, ctx.minor);
    let nodl = subs.iter().find(|s| s.frame.id == id::NODL);
    if let Some(s) = nodl.filter(|_| ctx.major >= 3 && !paged) {
        return Err(ctx.err(s.offset, &id::SKEL, pos, "holds a NODL page: format 3.0 keeps nodes in NODE and NBRS"));
    }
    let pages = if paged {
        pages_paged(ctx, pos, payload, &subs, &levels, partial)?
    } else {
        pages_whole(ctx, payload, find(id::NODE)?, find(id::NBRS)?, h, &levels)?
    };
    let decoded = pages.len();
    // The top level, and the level below, which the top nodes' rules are checked against.
    let keep: u32 = if top_only { levels.iter().rev().take(2).map(|l| l.nodes).sum() } else { h.nodes };
    let grid = h.grid;
    let mut boxes: Vec<[u64; 2]> = Vec::with_capacity(keep as usize);
    let mut nodes: Vec<NodeRecord> = Vec::with_capacity(keep as usize);
    let mut neighbor_first = 0u64;
    let mut offset = geometry_layout(ctx.major, ctx.geometry_start, 0).0;
    let v3 = ctx.major >= 3;
    let dag_file = h.is_dag();
    // Format 4: each decoded node's consumer as stored (relative to the level above's groups).
    let mut consumers: Vec<u32> = Vec::new();
    // Children of the levels above are consecutive: node i's are those after its predecessors'.
    let mut next_child = 0u64;
    // Per level: faces, vertices and bytes (to check LEVL against) and its neighbour entries.
    let mut totals = vec![(0u64, 0u64, 0u64); levels.len()];
    let mut level_entries = vec![0..0u64; levels.len()];
    for (page, (l, lev)) in pages.iter().zip(levels.iter().enumerate().rev()) {
        let f = Fields::new(ctx.path, &page.id, page.chunk_at, &[], page.records_at);
        let end = lev.first_node as u64 + lev.nodes as u64;
        if l + 1 < levels.len() && next_child != end && !dag_file {
            return Err(f.error(format!("the children of level {} cover nodes up to {next_child}, level {l} ends at {end}", l + 1)));
        }
        next_child = end;
        let level_first_entry = neighbor_first;
        for (k, r) in page.records.chunks_exact(NODE_RECORD_BYTES as usize).enumerate() {
            let i = lev.first_node + k as u32;
            let at = page.records_at + k as u64 * NODE_RECORD_BYTES;
            let u16_at = |k: usize| LE::read_u16(&r[k..]);
            let u32_at = |k: usize| LE::read_u32(&r[k..]);
            // Format 4: the consumer group; no children, no neighbours (strata-v4.md §1).
            let (child_count, neighbor_count) = if dag_file { (0, 0) } else { (u16_at(0) as u32, u16_at(2) as u32) };
            if dag_file {
                consumers.push(u32_at(0));
            }
            let axis = octa::decode([u16_at(4) as i16, u16_at(6) as i16]);
            let (half, radius_code) = (u16_at(8), u16_at(10));
            let (lo_bits, hi_bits) = (LE::read_u64(&r[12..]), LE::read_u64(&r[20..]));
            let (lo, hi, center) = (unpack(lo_bits), unpack(hi_bits), unpack(LE::read_u64(&r[28..])));
            let (error, faces, vertices, size, crc) = (LE::read_f32(&r[36..]), u32_at(40), u32_at(44), u32_at(48), u32_at(52));
            let bad = |msg: String| f.error_at(at, format!("node {i}: {msg}"));
            let first_child = if child_count > 0 { next_child as u32 } else { 0 };
            if l == 0 && child_count > 0 {
                return Err(bad(format!("a level-0 node with {child_count} children")));
            }
            next_child += child_count as u64;
            if l > 0 && next_child > end + levels[l - 1].nodes as u64 {
                return Err(bad(format!("children {first_child}..+{child_count} run past level {}", l - 1)));
            }
            if neighbor_first + neighbor_count as u64 > page.entry_base + page.entry_count {
                return Err(bad(format!("neighbours run past the {} of {}", page.entry_count, chunk::id_str(&page.id))));
            }
            let on_grid = |g: Option<[u32; 3]>| g.filter(|g| g.iter().all(|&x| x <= grid.last()));
            let (Some(lo), Some(hi), Some(center)) = (on_grid(lo), on_grid(hi), on_grid(center)) else {
                return Err(bad(format!("box or sphere center off the {}-bit grid", grid.bits)));
            };
            if (0..3).any(|k| lo[k] > hi[k]) {
                return Err(bad(format!("box min {lo:?} lies above its max {hi:?}")));
            }
            let radius = grid.length(radius_decode(radius_code));
            if !((0.0..=f32::MAX).contains(&error) && radius <= f32::MAX) {
                return Err(bad(format!("geometric error {error} and radius {radius} must be finite, the error not negative")));
            }
            let end = offset + size as u64;
            let padded = if v3 { size as u64 } else { size as u64 + chunk::padding(end) };
            let total = &mut totals[l];
            *total = (total.0 + faces as u64, total.1 + vertices as u64, total.2 + padded);
            let least = if v3 { 1 } else { HEADER_BYTES + TRAILER_BYTES };
            let in_file = size as u64 >= least && offset.checked_add(size as u64).is_some_and(|e| e <= ctx.file_size);
            if !in_file {
                return Err(bad(format!("geometry {size} bytes at offset {offset} runs past the end of the {}-byte file", ctx.file_size)));
            }
            if i < keep {
                boxes.push([lo_bits, hi_bits]);
                nodes.push(NodeRecord {
                    level: l as u32,
                    parent: NO_PARENT,
                    first_child,
                    child_count,
                    neighbor_first: neighbor_first as u32,
                    neighbor_count,
                    cone: Cone { axis, half_angle: angle_decode(half) },
                    center: grid.decode(center),
                    radius,
                    error,
                    faces,
                    vertices,
                    offset,
                    size,
                    crc,
                });
            }
            neighbor_first += neighbor_count as u64;
            offset += padded;
        }
        level_entries[l] = level_first_entry..neighbor_first;
    }
    let complete = decoded == levels.len();
    if complete && offset > ctx.file_size {
        return Err(ctx.err(pos, &id::SKEL, pos, format!("geometry ends at {offset}, past the end of the {}-byte file", ctx.file_size)));
    }
    for (l, (rec, t)) in levels.iter().zip(&totals).enumerate().filter(|(l, _)| *l + decoded >= levels.len()) {
        if (rec.faces, rec.vertices, rec.bytes) != *t {
            let at = levl.payload_offset() + l as u64 * LEVEL_RECORD_BYTES;
            return Err(fields(levl).error_at(
                at,
                format!(
                    "level {l}: LEVL says {} faces, {} vertices, {} bytes; the nodes hold {}, {}, {}",
                    rec.faces, rec.vertices, rec.bytes, t.0, t.1, t.2
                ),
            ));
        }
    }
    if complete && totals[0].0 != h.input_faces {
        return Err(fields(levl).error(format!("level 0's nodes hold {} faces, HEAD says the input has {}", totals[0].0, h.input_faces)));
    }
    for (page, (l, _)) in pages.iter().zip(levels.iter().enumerate().rev()) {
        let used = level_entries[l].end - level_entries[l].start;
        let holds = if paged { page.entry_count } else { neighbor_first };
        let uses = if paged { used } else { page.entry_count };
        if holds != uses && (paged || complete) {
            let f = Fields::new(ctx.path, &page.id, page.chunk_at, &[], page.entries_at);
            return Err(f.error(if paged {
                format!("holds {holds} neighbour entries, the level's nodes use {uses}")
            } else {
                format!("holds {uses} neighbours, the nodes use {holds}")
            }));
        }
        if !paged {
            break;
        }
    }
    // Levels from the top, so that the first bad entry in node order is the one named.
    for (page, (l, lev)) in pages.iter().zip(levels.iter().enumerate().rev()) {
        if let Some(k) = level_entries[l].clone().find(|&k| page.entry(k) >= lev.nodes) {
            let at = page.entries_at + page.width * (k - page.entry_base);
            // The node whose list holds entry k, for the message.
            let mut upto = level_entries[l].start;
            let lister = (0..lev.nodes as usize)
                .find(|&n| {
                    upto += LE::read_u16(&page.records[n * NODE_RECORD_BYTES as usize + 2..]) as u64;
                    k < upto
                })
                .map_or(lev.first_node, |n| lev.first_node + n as u32);
            let f = Fields::new(ctx.path, &page.id, page.chunk_at, &[], page.entries_at);
            return Err(f.error_at(at, format!("node {lister}: neighbour {} of the {} nodes of level {l}", page.entry(k), lev.nodes)));
        }
    }
    let neighbors: Vec<u32> = nodes
        .iter()
        .flat_map(|n| {
            let (base, page) = (levels[n.level as usize].first_node, &pages[levels.len() - 1 - n.level as usize]);
            (n.neighbor_first..n.neighbor_first + n.neighbor_count).map(move |k| page.entry(k as u64) + base)
        })
        .collect();
    for i in 0..nodes.len() {
        let n = nodes[i];
        for c in n.first_child..(n.first_child + n.child_count).min(nodes.len() as u32) {
            nodes[c as usize].parent = i as u32;
        }
    }
    let dag = if dag_file { Some(decode_dag(ctx, h.grid, &pages, &levels, &consumers, nodes.len())?) } else { None };

    // MATL
    let mut f = fields(matl);
    let mut materials = Vec::new();
    for m in 0..h.materials {
        let at = f.offset();
        let len = f.u32()?;
        let name =
            f.string(len).map_err(|_| f.error_at(at, format!("material {m}: name of {len} bytes runs past the chunk or is not UTF-8")))?;
        let base_color = [f.f32()?, f.f32()?, f.f32()?, f.f32()?];
        let at = f.offset();
        let len = f.u32()?;
        let tex = f
            .string(len)
            .map_err(|_| f.error_at(at, format!("material {m}: texture of {len} bytes runs past the chunk or is not UTF-8")))?;
        materials.push(Material { name, base_color, texture: (!tex.is_empty()).then_some(tex), ..Material::default() });
    }
    if f.remaining() > 0 && h.minor_known() {
        return Err(f.error(format!("{} bytes after {} materials", f.remaining(), h.materials)));
    }

    // TEXR (2.2), optional.
    let mut found = subs.iter().filter(|s| s.frame.id == id::TEXR);
    let textures = match (found.next(), found.next()) {
        (_, Some(dup)) => return Err(ctx.err(dup.offset, &id::SKEL, pos, "has a second TEXR chunk")),
        (None, None) => Textures::default(),
        (Some(texr), None) => {
            let levels_start = geometry_layout(ctx.major, ctx.geometry_start, levels.iter().map(|l| l.bytes).sum::<u64>()).1;
            let cx = texture::TexrContext { nodes: h.nodes, levels_start, file_size: ctx.file_size };
            texture::decode_texr(&mut fields(texr), &cx, &mut materials)?
        }
    };

    // CODE (format 3): the coding tables, required.
    let mut found = subs.iter().filter(|s| s.frame.id == id::CODE);
    let code = match (found.next(), found.next(), ctx.major >= 3) {
        (_, Some(dup), _) => return Err(ctx.err(dup.offset, &id::SKEL, pos, "has a second CODE chunk")),
        (None, None, true) => return Err(ctx.err(pos, &id::SKEL, pos, "has no CODE chunk: format 3 needs its coding tables")),
        (Some(c), None, true) => {
            let tables = v3::CodeTables::decode(&payload[c.start..c.end], h.attributes.normals, h.attributes.colors)
                .map_err(|(at, m)| fields(c).error_at(c.payload_offset() + at as u64, m))?;
            Some(std::sync::Arc::new(v3::Code::new(tables)))
        }
        (_, None, false) => None,
    };

    Ok((Skeleton { header: header.clone(), levels, nodes, neighbors, materials, boxes, textures, code, dag }, infos))
}

/// One level's node records and neighbour entries, where they lie in the file.
struct Page<'a> {
    /// The sub-chunk they are read from (`NODE` and `NBRS` in format 2, `NODL` in format 3), for errors.
    id: [u8; 4],
    chunk_at: u64,
    records: &'a [u8],
    records_at: u64,
    entries: &'a [u8],
    entries_at: u64,
    /// Entry width in bytes, the number of entries, and the number of the first (entries are
    /// numbered over all levels, as node records count them).
    width: u64,
    entry_count: u64,
    entry_base: u64,
    /// Format 4: the page's group records, and where they start.
    groups: &'a [u8],
    groups_at: u64,
}

impl Page<'_> {
    /// Entry `k` (numbered over all levels).
    fn entry(&self, k: u64) -> u32 {
        let at = ((k - self.entry_base) * self.width) as usize;
        if self.width == 2 {
            LE::read_u16(&self.entries[at..]) as u32
        } else {
            LE::read_u32(&self.entries[at..])
        }
    }
}

/// The pages of a node table in `NODE` and `NBRS` (format 2 and 3.0): every level's slice of
/// `NODE`, each reading the whole `NBRS`.
fn pages_whole<'a>(ctx: &Context, payload: &'a [u8], node: &Sub, nbrs: &Sub, h: &Header, levels: &[LevelRecord]) -> Result<Vec<Page<'a>>> {
    let nf = Fields::new(ctx.path, &nbrs.frame.id, nbrs.offset, &[], nbrs.payload_offset());
    let width = nbrs.frame.flags as u64;
    if width != 2 && width != 4 {
        return Err(nf.error_at(nbrs.offset + 4, format!("entry width {width}; must be 2 or 4")));
    }
    if nbrs.frame.size % width != 0 {
        return Err(nf.error(format!("size {} is not a multiple of {width}", nbrs.frame.size)));
    }
    let want = h.nodes as u64 * NODE_RECORD_BYTES;
    if node.frame.size != want {
        let f = Fields::new(ctx.path, &node.frame.id, node.offset, &[], node.payload_offset());
        return Err(f.error(format!("holds {} bytes; {} nodes need {want}", node.frame.size, h.nodes)));
    }
    // The size is checked: records are read from fixed 56-byte slices.
    let bytes = NODE_RECORD_BYTES as usize;
    Ok(levels
        .iter()
        .rev()
        .map(|l| {
            let first = node.start + bytes * l.first_node as usize;
            Page {
                id: id::NODE,
                chunk_at: node.offset,
                records: &payload[first..first + bytes * l.nodes as usize],
                records_at: node.payload_offset() + NODE_RECORD_BYTES * l.first_node as u64,
                entries: &payload[nbrs.start..nbrs.end],
                entries_at: nbrs.payload_offset(),
                width,
                entry_count: nbrs.frame.size / width,
                entry_base: 0,
                groups: &[],
                groups_at: 0,
            }
        })
        .collect())
}

/// The pages of format 3.1 on (strata-v3.md §1.1): one `NODL` per level from the top, after every other
/// sub-chunk. All of them, or with `prefix` the first ones read (at least the top two levels').
fn pages_paged<'a>(
    ctx: &Context,
    pos: u64,
    payload: &'a [u8],
    subs: &[Sub],
    levels: &[LevelRecord],
    prefix: bool,
) -> Result<Vec<Page<'a>>> {
    let first = subs.iter().position(|s| s.frame.id == id::NODL).unwrap_or(subs.len());
    if let Some(s) = subs.iter().find(|s| s.frame.id == id::NODE || s.frame.id == id::NBRS) {
        return Err(ctx.err(
            s.offset,
            &id::SKEL,
            pos,
            format!("holds a {} chunk: format 3 keeps nodes in NODL pages", chunk::id_str(&s.frame.id)),
        ));
    }
    if let Some(s) = subs[first..].iter().find(|s| s.frame.id != id::NODL) {
        return Err(ctx.err(s.offset, &id::SKEL, pos, format!("has a {} chunk after the node pages", chunk::id_str(&s.frame.id))));
    }
    let count = subs.len() - first;
    let least = if prefix { levels.len().min(2) } else { levels.len() };
    if count < least || count > levels.len() {
        return Err(ctx.err(pos, &id::SKEL, pos, format!("holds {count} node pages (NODL) for {} levels", levels.len())));
    }
    let mut base = 0u64;
    let mut out = Vec::with_capacity(count);
    for (s, lev) in subs[first..].iter().zip(levels.iter().rev()) {
        let f = Fields::new(ctx.path, &s.frame.id, s.offset, &[], s.payload_offset());
        if ctx.major == super::MAJOR4 {
            out.push(dag_page(&f, s, payload, lev)?);
            continue;
        }
        let width = s.frame.flags as u64;
        if width != 2 && width != 4 {
            return Err(f.error_at(s.offset + 4, format!("entry width {width}; must be 2 or 4")));
        }
        let records = NODE_RECORD_BYTES * lev.nodes as u64;
        if s.frame.size < records || (s.frame.size - records) % width != 0 {
            return Err(
                f.error(format!("holds {} bytes: {} node records and whole {width}-byte entries do not fill it", s.frame.size, lev.nodes))
            );
        }
        let entry_count = (s.frame.size - records) / width;
        out.push(Page {
            id: id::NODL,
            chunk_at: s.offset,
            records: &payload[s.start..s.start + records as usize],
            records_at: s.payload_offset(),
            entries: &payload[s.start + records as usize..s.end],
            entries_at: s.payload_offset() + records,
            width,
            entry_count,
            entry_base: base,
            groups: &[],
            groups_at: 0,
        });
        base += entry_count;
    }
    Ok(out)
}

/// A format-4 page (strata-v4.md §1): the group count, the group records, the node records; no
/// neighbour entries.
fn dag_page<'a>(f: &Fields, s: &Sub, payload: &'a [u8], lev: &LevelRecord) -> Result<Page<'a>> {
    if s.frame.flags != 0 {
        return Err(f.error_at(s.offset + 4, format!("flags {}; a format-4 page has 0", s.frame.flags)));
    }
    let bytes = &payload[s.start..s.end];
    if bytes.len() < 4 {
        return Err(f.error(format!("holds {} bytes, too few for its group count", bytes.len())));
    }
    let groups = LE::read_u32(bytes) as u64;
    let want = 4 + GROUP_RECORD_BYTES * groups + NODE_RECORD_BYTES * lev.nodes as u64;
    if s.frame.size != want {
        return Err(f.error(format!("holds {} bytes; {groups} group records and {} node records need {want}", s.frame.size, lev.nodes)));
    }
    let records_at = 4 + (GROUP_RECORD_BYTES * groups) as usize;
    Ok(Page {
        id: id::NODL,
        chunk_at: s.offset,
        records: &bytes[records_at..],
        records_at: s.payload_offset() + records_at as u64,
        entries: &[],
        entries_at: s.payload_offset() + bytes.len() as u64,
        width: 2,
        entry_count: 0,
        entry_base: 0,
        groups: &bytes[4..records_at],
        groups_at: s.payload_offset() + 4,
    })
}

/// The DAG of a format-4 file from its decoded pages (top first) and each decoded node's stored
/// consumer: its groups and how nodes refer to them, checked (strata-v4.md §1). Nodes past `kept`
/// are checked but not kept.
fn decode_dag(ctx: &Context, grid: Grid, pages: &[Page], levels: &[LevelRecord], consumers: &[u32], kept: usize) -> Result<DagTable> {
    let top = levels.len() - 1;
    let mut dag = DagTable { level_groups: vec![0..0; levels.len()], ..DagTable::default() };
    // Groups in file order, and the node each run of outputs starts at.
    for (page, (l, lev)) in pages.iter().zip(levels.iter().enumerate().rev()) {
        let f = Fields::new(ctx.path, &page.id, page.chunk_at, &[], page.groups_at);
        let count = page.groups.len() / GROUP_RECORD_BYTES as usize;
        if (l == 0) != (count == 0) {
            return Err(
                f.error_at(page.groups_at - 4, format!("level {l} has {count} groups; level 0 has none and every other level some"))
            );
        }
        let first = dag.groups.len() as u32;
        let mut next = lev.first_node as u64;
        for (k, r) in page.groups.chunks_exact(GROUP_RECORD_BYTES as usize).enumerate() {
            let at = page.groups_at + k as u64 * GROUP_RECORD_BYTES;
            let bad = |msg: String| f.error_at(at, format!("group {k} of level {l}: {msg}"));
            let (outputs, children, error) = (LE::read_u32(r), LE::read_u32(&r[4..]), LE::read_f32(&r[8..]));
            let (radius_code, reserved, center) = (LE::read_u16(&r[12..]), LE::read_u16(&r[14..]), unpack(LE::read_u64(&r[16..])));
            if outputs == 0 || children == 0 || reserved != 0 {
                return Err(bad(format!(
                    "{outputs} outputs, {children} children, reserved {reserved}: outputs and children must be at least 1, reserved 0"
                )));
            }
            let Some(center) = center.filter(|g| g.iter().all(|&x| x <= grid.last())) else {
                return Err(bad(format!("sphere center off the {}-bit grid", grid.bits)));
            };
            let radius = grid.length(radius_decode(radius_code));
            if !((0.0..=f32::MAX).contains(&error) && radius <= f32::MAX) {
                return Err(bad(format!("geometric error {error} and radius {radius} must be finite, the error not negative")));
            }
            if next + outputs as u64 > lev.first_node as u64 + lev.nodes as u64 {
                return Err(bad(format!("outputs {next}..+{outputs} run past the level's {} nodes", lev.nodes)));
            }
            dag.groups.push(GroupRecord {
                level: l as u32,
                first_output: next as u32,
                outputs,
                children,
                error,
                center: grid.decode(center),
                radius,
            });
            next += outputs as u64;
        }
        if next != lev.first_node as u64 + lev.nodes as u64 && l > 0 {
            return Err(f.error(format!(
                "the outputs of level {l}'s groups cover nodes up to {next}; the level ends at {}",
                lev.first_node + lev.nodes
            )));
        }
        dag.level_groups[l] = first..dag.groups.len() as u32;
    }
    // Consumers, as global group numbers; sources from the output runs.
    let decoded: u32 = levels.iter().rev().take(pages.len()).map(|l| l.nodes).sum();
    let mut consumer = vec![NO_PARENT; decoded as usize];
    let mut named = vec![0u32; dag.groups.len()];
    for (page, (l, lev)) in pages.iter().zip(levels.iter().enumerate().rev()) {
        let f = Fields::new(ctx.path, &page.id, page.chunk_at, &[], page.records_at);
        let above = if l == top { 0..0 } else { dag.level_groups[l + 1].clone() };
        for k in 0..lev.nodes {
            let i = lev.first_node + k;
            let stored = consumers[i as usize];
            let at = page.records_at + k as u64 * NODE_RECORD_BYTES;
            let ok = if l == top { stored == NO_PARENT } else { (stored as u64) < above.len() as u64 };
            if !ok {
                return Err(f.error_at(
                    at,
                    if l == top {
                        format!("node {i}: consumer {stored}; a top-level node has none (0xFFFFFFFF)")
                    } else {
                        format!("node {i}: consumer {stored}; level {} has {} groups", l + 1, above.len())
                    },
                ));
            }
            if l != top {
                consumer[i as usize] = above.start + stored;
                named[(above.start + stored) as usize] += 1;
            }
        }
    }
    // Children counts, for every level whose page below was read.
    for (g, r) in dag.groups.iter().enumerate() {
        if (r.level as usize) + pages.len() > levels.len() && named[g] != r.children {
            let page = &pages[levels.len() - 1 - r.level as usize];
            let k = g as u32 - dag.level_groups[r.level as usize].start;
            let f = Fields::new(ctx.path, &page.id, page.chunk_at, &[], page.groups_at);
            return Err(f.error_at(
                page.groups_at + k as u64 * GROUP_RECORD_BYTES,
                format!("group {k} of level {}: {} children stored, {} nodes name it", r.level, r.children, named[g]),
            ));
        }
    }
    let mut source = vec![NO_PARENT; decoded as usize];
    for (g, r) in dag.groups.iter().enumerate() {
        source[r.first_output as usize..(r.first_output + r.outputs) as usize].fill(g as u32);
    }
    let mut offsets = vec![0u32; dag.groups.len() + 1];
    for &c in consumer.iter().filter(|&&c| c != NO_PARENT) {
        offsets[c as usize + 1] += 1;
    }
    for g in 0..dag.groups.len() {
        offsets[g + 1] += offsets[g];
    }
    let mut fill = offsets.clone();
    let mut items = vec![0u32; offsets[dag.groups.len()] as usize];
    for (i, &c) in consumer.iter().enumerate().filter(|(_, &c)| c != NO_PARENT) {
        items[fill[c as usize] as usize] = i as u32;
        fill[c as usize] += 1;
    }
    consumer.truncate(kept);
    source.truncate(kept);
    dag.consumer = consumer;
    dag.source = source;
    dag.child_offsets = offsets;
    dag.child_items = items;
    Ok(dag)
}

/// Format 4's group records as stored, per level (finest first, in group order), and each node's
/// consumer as stored: the group's number within the level above, `NO_PARENT` at the top.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DagCodes {
    pub groups: Vec<Vec<GroupCodes>>,
    pub consumer: Vec<u32>,
}

/// One group record of a format-4 page (strata-v4.md §1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupCodes {
    pub outputs: u32,
    pub children: u32,
    pub error: f32,
    pub radius: u16,
    pub center: [u32; 3],
}

/// The `HEAD` chunk.
pub fn encode_head(h: &Header) -> Vec<u8> {
    let mut p = Vec::with_capacity(160);
    p.extend_from_slice(&h.file_size.to_le_bytes());
    p.extend_from_slice(&h.metres_per_unit.to_le_bytes());
    for x in h.min.to_array().into_iter().chain(h.max.to_array()) {
        p.extend_from_slice(&x.to_le_bytes());
    }
    for x in [h.attributes.bits(), h.levels, h.nodes, h.materials] {
        p.extend_from_slice(&x.to_le_bytes());
    }
    p.extend_from_slice(&h.input_vertices.to_le_bytes());
    p.extend_from_slice(&h.input_faces.to_le_bytes());
    p.extend_from_slice(&h.clusters.to_le_bytes());
    let q = &h.params;
    p.extend_from_slice(&q.cluster_faces.to_le_bytes());
    p.extend_from_slice(&q.cluster_angle.to_le_bytes());
    p.extend_from_slice(&q.leaf_faces.to_le_bytes());
    p.extend_from_slice(&q.leaf_angle.to_le_bytes());
    p.extend_from_slice(&q.angle_step.to_le_bytes());
    p.extend_from_slice(&q.growth.to_le_bytes());
    for x in [q.kc, q.ks, q.kn] {
        p.extend_from_slice(&x.to_le_bytes());
    }
    p.extend_from_slice(&(q.top_groups.min(u32::MAX as usize) as u32).to_le_bytes());
    p.extend_from_slice(&h.level_ratio.to_le_bytes());
    for x in h.grid.origin.into_iter().chain([h.grid.step]) {
        p.extend_from_slice(&x.to_le_bytes());
    }
    p.extend_from_slice(&h.grid.bits.to_le_bytes());
    p.extend_from_slice(&(h.tool.len() as u32).to_le_bytes());
    p.extend_from_slice(h.tool.as_bytes());
    let mut out = Vec::with_capacity(p.len() + 32);
    chunk::put(&mut out, id::HEAD, 0, &p);
    out
}

/// The `SKEL` chunk: levels, node records, neighbour lists, materials, images (`TEXR`) and, in
/// format 3 (`code` given), the coding tables; with `paged` (format 3.1 on) the node records and
/// neighbour lists as one `NODL` page per level, top first (strata-v3.md §1.1), else as `NODE` and
/// `NBRS`.
#[allow(clippy::too_many_arguments)]
pub fn encode_skel(
    levels: &[LevelRecord],
    records: &[NodeRecord],
    codes: &[NodeCodes],
    neighbors: &[u32],
    materials: &[Material],
    texr: Option<&[u8]>,
    code: Option<&[u8]>,
    paged: bool,
    dag: Option<&DagCodes>,
) -> Vec<u8> {
    let mut payload = Vec::new();
    let mut p = Vec::with_capacity(levels.len() * 32);
    for l in levels {
        p.extend_from_slice(&l.first_node.to_le_bytes());
        p.extend_from_slice(&l.nodes.to_le_bytes());
        p.extend_from_slice(&l.faces.to_le_bytes());
        p.extend_from_slice(&l.vertices.to_le_bytes());
        p.extend_from_slice(&l.bytes.to_le_bytes());
    }
    chunk::put(&mut payload, id::LEVL, 0, &p);

    let record = |p: &mut Vec<u8>, i: usize, r: &NodeRecord, c: &NodeCodes| {
        match dag {
            Some(d) => p.extend_from_slice(&d.consumer[i].to_le_bytes()),
            None => {
                p.extend_from_slice(&(r.child_count as u16).to_le_bytes());
                p.extend_from_slice(&(r.neighbor_count as u16).to_le_bytes());
            }
        }
        p.extend(c.axis.iter().flat_map(|x| x.to_le_bytes()));
        p.extend_from_slice(&c.half_angle.to_le_bytes());
        p.extend_from_slice(&c.radius.to_le_bytes());
        for g in [c.min, c.max, c.center] {
            p.extend_from_slice(&pack(g).to_le_bytes());
        }
        p.extend_from_slice(&r.error.to_le_bytes());
        for x in [r.faces, r.vertices, r.size, r.crc] {
            p.extend_from_slice(&x.to_le_bytes());
        }
    };
    // Each node's list, relative to the first node of its level.
    let lists = |p: &mut Vec<u8>, nodes: std::ops::Range<usize>, next: &mut std::slice::Iter<u32>, width: usize| {
        for r in &records[nodes] {
            let first = levels[r.level as usize].first_node;
            for &x in next.by_ref().take(r.neighbor_count as usize) {
                p.extend_from_slice(&(x - first).to_le_bytes()[..width]);
            }
        }
    };
    let mut materials_and_tables = Vec::new();
    p.clear();
    for m in materials {
        p.extend_from_slice(&(m.name.len() as u32).to_le_bytes());
        p.extend_from_slice(m.name.as_bytes());
        for x in m.base_color {
            p.extend_from_slice(&x.to_le_bytes());
        }
        let tex = m.texture.as_deref().unwrap_or("");
        p.extend_from_slice(&(tex.len() as u32).to_le_bytes());
        p.extend_from_slice(tex.as_bytes());
    }
    chunk::put(&mut materials_and_tables, id::MATL, 0, &p);
    if let Some(t) = texr {
        chunk::put(&mut materials_and_tables, id::TEXR, 0, t);
    }

    let mut next = neighbors.iter();
    match code.filter(|_| paged) {
        None => {
            p.clear();
            for (i, (r, c)) in records.iter().zip(codes).enumerate() {
                record(&mut p, i, r, c);
            }
            chunk::put(&mut payload, id::NODE, 0, &p);
            p.clear();
            let width = if levels.iter().all(|l| l.nodes <= 1 << 16) { 2 } else { 4 };
            lists(&mut p, 0..records.len(), &mut next, width);
            chunk::put(&mut payload, id::NBRS, width as u32, &p);
            payload.extend_from_slice(&materials_and_tables);
            if let Some(c) = code {
                chunk::put(&mut payload, id::CODE, 0, c);
            }
        }
        Some(c) => {
            payload.extend_from_slice(&materials_and_tables);
            chunk::put(&mut payload, id::CODE, 0, c);
            for (level, l) in levels.iter().enumerate().rev() {
                let nodes = l.first_node as usize..(l.first_node + l.nodes) as usize;
                p.clear();
                if let Some(d) = dag {
                    let groups = &d.groups[level];
                    p.extend_from_slice(&(groups.len() as u32).to_le_bytes());
                    for g in groups {
                        p.extend_from_slice(&g.outputs.to_le_bytes());
                        p.extend_from_slice(&g.children.to_le_bytes());
                        p.extend_from_slice(&g.error.to_le_bytes());
                        p.extend_from_slice(&g.radius.to_le_bytes());
                        p.extend_from_slice(&0u16.to_le_bytes());
                        p.extend_from_slice(&pack(g.center).to_le_bytes());
                    }
                }
                for (i, (r, c)) in records[nodes.clone()].iter().zip(&codes[nodes.clone()]).enumerate() {
                    record(&mut p, nodes.start + i, r, c);
                }
                let width = if dag.is_some() {
                    0
                } else {
                    let width = if l.nodes <= 1 << 16 { 2 } else { 4 };
                    lists(&mut p, nodes, &mut next, width);
                    width
                };
                chunk::put(&mut payload, id::NODL, width as u32, &p);
            }
        }
    }

    let mut out = Vec::with_capacity(payload.len() + 24);
    chunk::put(&mut out, id::SKEL, 0, &payload);
    out
}
