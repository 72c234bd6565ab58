//! The lazy reader: [`Reader::open`] reads and checks the prologue, `HEAD` and `SKEL` only;
//! [`Reader::read_node`] seeks to one node's `GEOM` chunk, checks it and decodes it.
//!
//! Every count, offset and length is checked against the file size before anything is allocated,
//! and every problem is an [`Error`] naming the chunk and the byte offset.

use super::chunk::{self, Fields, Frame, Sub, HEADER_BYTES, TRAILER_BYTES};
use super::rules::{self, Sink};
use super::{
    angle_decode, id, octa, radius_decode, unpack, Attributes, Cluster, Grid, Header, LevelRecord, MaterialRange, NodeGeometry,
    NodeRecord, CLUSTER_RECORD_BYTES, HEAD_FIXED_BYTES, LEVEL_RECORD_BYTES, MAGIC, MAJOR, MAX_GRID_BITS, MAX_TOOL_BYTES, MINOR,
    NODE_RECORD_BYTES, NO_PARENT, PROLOGUE_BYTES, RANGE_RECORD_BYTES, VERSION,
};
use crate::cone::Cone;
use crate::error::{Error, Result};
use crate::hierarchy::HierarchyParams;
use crate::mesh::Material;
use byteorder::{ByteOrder, LittleEndian as LE};
use glam::{Vec2, Vec3};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Largest `HEAD` payload a reader accepts (newer minor versions may append fields).
const MAX_HEAD_BYTES: u64 = 1 << 16;

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
    fn new(frame: &Frame, offset: u64, depth: u32) -> ChunkInfo {
        ChunkInfo { id: chunk::id_str(&frame.id), offset, flags: frame.flags, size: frame.size, depth }
    }
}

/// An open strata file: its header and skeleton in memory, geometry read on demand.
pub struct Reader<R> {
    r: R,
    path: PathBuf,
    len: u64,
    bytes_read: u64,
    header: Header,
    levels: Vec<LevelRecord>,
    nodes: Vec<NodeRecord>,
    neighbors: Vec<u32>,
    materials: Vec<Material>,
    /// `HEAD`, chunks skipped before `SKEL`, `SKEL` and its sub-chunks.
    skeleton_chunks: Vec<ChunkInfo>,
    /// Offset just after `SKEL` and its padding.
    skeleton_end: u64,
    /// The last node chunk read, kept so that reading a node allocates only its geometry.
    scratch: Vec<u8>,
    /// Each node's box as packed grid points (min, max): 16 bytes a node, decoded on demand.
    boxes: Vec<[u64; 2]>,
    /// Whether the rules of spec §6 are checked at open and as each node is decoded.
    strict: bool,
}

impl Reader<File> {
    /// Open the file at `path`.
    pub fn open_path(path: &Path) -> Result<Reader<File>> {
        crate::atomic::protect(path);
        let f = File::open(path).map_err(|e| Error::io(path, e))?;
        Reader::open_named(f, path)
    }
}

impl<R: Read + Seek> Reader<R> {
    /// Open a file from any seekable reader; errors name it `<input>`.
    pub fn open(r: R) -> Result<Reader<R>> {
        Reader::open_named(r, Path::new("<input>"))
    }

    /// Open a file from any seekable reader; errors name it `path`. Besides every size, offset and
    /// checksum, the skeleton's rules (spec §6) are checked here and each node's as it is read, so
    /// that a file [`verify`](super::verify()) refuses is refused by every reader too.
    pub fn open_named(r: R, path: &Path) -> Result<Reader<R>> {
        let rd = Reader::open_unchecked(r, path)?;
        let mut sink = Sink::new(1);
        rules::skeleton(&rd.path, &rd.header, &rd.levels, &rd.nodes, &rd.neighbors, &rd.node_boxes(), &mut sink);
        match sink.first() {
            Some(e) => Err(e),
            None => Ok(Reader { strict: true, ..rd }),
        }
    }

    /// Open checking sizes, offsets and checksums only; nodes are decoded without their rules.
    /// For [`verify`](super::verify()), which checks the rules itself and lists every problem.
    pub(crate) fn open_unchecked(mut r: R, path: &Path) -> Result<Reader<R>> {
        let len = r.seek(SeekFrom::End(0)).map_err(|e| Error::io(path, e))?;
        let mut rd = Reader {
            r,
            path: path.to_path_buf(),
            len,
            bytes_read: 0,
            header: empty_header(),
            levels: Vec::new(),
            nodes: Vec::new(),
            neighbors: Vec::new(),
            materials: Vec::new(),
            skeleton_chunks: Vec::new(),
            skeleton_end: 0,
            scratch: Vec::new(),
            boxes: Vec::new(),
            strict: false,
        };
        rd.read_prologue()?;
        let mut pos = PROLOGUE_BYTES;
        let head = rd.frame_at(pos)?;
        if head.id != id::HEAD {
            return Err(rd.err(pos, &head.id, pos, "expected the HEAD chunk here"));
        }
        if head.size > MAX_HEAD_BYTES {
            return Err(rd.err(pos + 8, &head.id, pos, format!("size {} exceeds the {MAX_HEAD_BYTES}-byte limit", head.size)));
        }
        let payload = rd.payload_at(pos, &head)?;
        rd.header = rd.parse_head(&payload, pos)?;
        rd.skeleton_chunks.push(ChunkInfo::new(&head, pos, 0));
        if rd.header.file_size != len {
            return Err(rd.err(
                pos + HEADER_BYTES,
                &head.id,
                pos,
                format!("the file is {len} bytes but HEAD says {}: truncated or extended", rd.header.file_size),
            ));
        }
        pos = rd.next(pos, &head)?;
        let skel = loop {
            let f = rd.frame_at(pos)?;
            if f.id == id::SKEL {
                break f;
            }
            if f.id == id::HEAD || f.id == id::GEOM {
                return Err(rd.err(pos, &f.id, pos, "expected the SKEL chunk before any other known chunk"));
            }
            rd.skeleton_chunks.push(ChunkInfo::new(&f, pos, 0));
            pos = rd.next(pos, &f)?;
        };
        let payload = rd.payload_at(pos, &skel)?;
        rd.skeleton_chunks.push(ChunkInfo::new(&skel, pos, 0));
        rd.skeleton_end = rd.next(pos, &skel)?;
        rd.parse_skel(&payload, pos)?;
        Ok(rd)
    }

    /// The `HEAD` chunk.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The node table, in file order (top level first).
    pub fn nodes(&self) -> &[NodeRecord] {
        &self.nodes
    }

    /// Per level, finest first: node range, faces, vertices and bytes.
    pub fn levels(&self) -> &[LevelRecord] {
        &self.levels
    }

    /// Nodes of level `level` (empty past the top).
    pub fn level_nodes(&self, level: u32) -> Range<u32> {
        self.levels.get(level as usize).map_or(0..0, |l| l.first_node..l.first_node + l.nodes)
    }

    /// Children of node `i` (nodes of the level below).
    pub fn children(&self, i: u32) -> Range<u32> {
        self.nodes.get(i as usize).map_or(0..0, |n| n.first_child..n.first_child + n.child_count)
    }

    /// Same-level neighbours of node `i`.
    pub fn neighbors(&self, i: u32) -> &[u32] {
        self.nodes.get(i as usize).map_or(&[], |n| {
            &self.neighbors[n.neighbor_first as usize..(n.neighbor_first + n.neighbor_count) as usize]
        })
    }

    /// Every node's neighbour list, end to end in node order ([`NodeRecord::neighbor_first`]).
    pub fn all_neighbors(&self) -> &[u32] {
        &self.neighbors
    }

    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// Bytes read from the underlying reader so far.
    pub fn bytes_read(&self) -> u64 {
        self.bytes_read
    }

    pub fn file_size(&self) -> u64 {
        self.len
    }

    /// The name used in errors.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Where the skeleton ends: the first byte after `SKEL` and its padding.
    pub fn skeleton_end(&self) -> u64 {
        self.skeleton_end
    }

    /// The chunks read at open: `HEAD`, any skipped ones, `SKEL` and its sub-chunks.
    pub fn skeleton_chunks(&self) -> &[ChunkInfo] {
        &self.skeleton_chunks
    }

    /// Read, check and decode node `i`'s geometry.
    pub fn read_node(&mut self, i: u32) -> Result<NodeGeometry> {
        let mut buf = std::mem::take(&mut self.scratch);
        let out = self.node_subs(i, &mut buf).and_then(|(rec, _, payload, subs)| self.decode(i, &rec, &buf[payload], &subs));
        self.scratch = buf;
        let g = out?;
        if self.strict {
            let mut sink = Sink::new(1);
            rules::node(&self.path, i, &self.nodes[i as usize], self.node_box(i), &g, &mut sink);
            if let Some(e) = sink.first() {
                return Err(e);
            }
        }
        Ok(g)
    }

    /// The sub-chunks of node `i`'s `GEOM` chunk (read and checked).
    pub fn node_chunks(&mut self, i: u32) -> Result<Vec<ChunkInfo>> {
        let mut buf = std::mem::take(&mut self.scratch);
        let read = self.node_subs(i, &mut buf);
        self.scratch = buf;
        let (rec, frame, _, subs) = read?;
        let mut out = vec![ChunkInfo::new(&frame, rec.offset, 0)];
        out.extend(subs.iter().map(|s| ChunkInfo::new(&s.frame, s.offset, 1)));
        Ok(out)
    }

    /// Walk the top-level chunk frames from the end of the prologue to the end of the file,
    /// reading 16 bytes per chunk.
    pub fn chunks(&mut self) -> Result<Vec<ChunkInfo>> {
        let mut out = Vec::new();
        let mut pos = PROLOGUE_BYTES;
        while pos < self.len {
            let f = self.frame_at(pos)?;
            out.push(ChunkInfo::new(&f, pos, 0));
            pos = self.next(pos, &f)?;
        }
        Ok(out)
    }

    /// Node `i`'s bounding box (min, max). The node records leave it out, since only the checks of
    /// a node's geometry need it; it is kept packed, 16 bytes a node.
    pub fn node_box(&self, i: u32) -> (Vec3, Vec3) {
        let grid = self.header.grid;
        let corner = |v: u64| unpack(v).map_or(Vec3::NAN, |g| grid.decode(g));
        self.boxes.get(i as usize).map_or((Vec3::NAN, Vec3::NAN), |b| (corner(b[0]), corner(b[1])))
    }

    /// Every node's bounding box, in node order.
    pub fn node_boxes(&self) -> Vec<(Vec3, Vec3)> {
        (0..self.nodes.len() as u32).map(|i| self.node_box(i)).collect()
    }

    /// Read `len` bytes at `offset`, which the caller has checked lie in the file.
    pub(crate) fn read_at(&mut self, offset: u64, len: u64) -> Result<Vec<u8>> {
        let mut buf = Vec::new();
        self.read_into(offset, len, &mut buf)?;
        Ok(buf)
    }

    /// `read_at` into `buf`, reusing its allocation.
    fn read_into(&mut self, offset: u64, len: u64, buf: &mut Vec<u8>) -> Result<()> {
        let end = offset.checked_add(len).filter(|&e| e <= self.len);
        if end.is_none() {
            return Err(Error::at_byte(&self.path, offset, format!("{len} bytes at offset {offset} run past the end of the file ({} bytes)", self.len)));
        }
        buf.clear();
        buf.resize(len as usize, 0);
        self.r.seek(SeekFrom::Start(offset)).map_err(|e| Error::io(&self.path, e))?;
        self.r.read_exact(buf).map_err(|e| Error::io(&self.path, e))?;
        self.bytes_read += len;
        Ok(())
    }

    fn err(&self, at: u64, id: &[u8; 4], chunk_offset: u64, msg: impl std::fmt::Display) -> Error {
        Error::at_byte(&self.path, at, format!("{}: {msg}", chunk::name(id, chunk_offset)))
    }

    fn read_prologue(&mut self) -> Result<()> {
        if self.len < PROLOGUE_BYTES {
            return Err(Error::at_byte(&self.path, 0, format!("a file of {} bytes is too short for a strata file", self.len)));
        }
        let p = self.read_at(0, PROLOGUE_BYTES)?;
        if p[..8] != MAGIC {
            return Err(Error::at_byte(&self.path, 0, "not a strata file (the first 8 bytes are not the strata magic)"));
        }
        let (major, minor) = (LE::read_u16(&p[8..10]), LE::read_u16(&p[10..12]));
        if major > MAJOR {
            return Err(Error::at_byte(
                &self.path,
                8,
                format!("format version {major}.{minor} is newer than this reader's {VERSION}: a newer strata is needed"),
            ));
        }
        if major < MAJOR {
            return Err(Error::at_byte(&self.path, 8, format!("format version {major}.{minor} is not supported (this reader reads {MAJOR}.x)")));
        }
        let (stored, actual) = (LE::read_u32(&p[12..16]), chunk::crc32(&p[..12]));
        if stored != actual {
            return Err(Error::at_byte(&self.path, 12, format!("prologue CRC {actual:08x} != stored {stored:08x}")));
        }
        self.header.major = major;
        self.header.minor = minor;
        Ok(())
    }

    /// The frame at `pos`; there must be room for it and a CRC.
    fn frame_at(&mut self, pos: u64) -> Result<Frame> {
        if pos.checked_add(HEADER_BYTES + TRAILER_BYTES).is_none_or(|e| e > self.len) {
            return Err(Error::at_byte(&self.path, pos, format!("a chunk at offset {pos} runs past the end of the file ({} bytes)", self.len)));
        }
        let b = self.read_at(pos, HEADER_BYTES)?;
        let mut head = [0u8; 16];
        head.copy_from_slice(&b);
        Ok(Frame::parse(&head))
    }

    /// Offset of the chunk after the one at `pos`; its span must lie in the file.
    fn next(&self, pos: u64, f: &Frame) -> Result<u64> {
        let end = f.span().and_then(|s| pos.checked_add(s)).filter(|&e| e <= self.len);
        match end {
            Some(e) => Ok(e + chunk::padding(e)),
            None => Err(self.err(pos + 8, &f.id, pos, format!("size {} runs past the end of the file ({} bytes)", f.size, self.len))),
        }
    }

    /// The payload of the chunk at `pos`, its CRC checked.
    fn payload_at(&mut self, pos: u64, f: &Frame) -> Result<Vec<u8>> {
        self.next(pos, f)?;
        let mut buf = self.read_at(pos + HEADER_BYTES, f.size + TRAILER_BYTES)?;
        let crc_at = buf.len() - 4;
        let stored = LE::read_u32(&buf[crc_at..]);
        buf.truncate(crc_at);
        let actual = chunk::crc32(&buf);
        if stored != actual {
            return Err(self.err(pos + HEADER_BYTES + f.size, &f.id, pos, format!("CRC {actual:08x} != stored {stored:08x}")));
        }
        Ok(buf)
    }

    fn parse_head(&self, payload: &[u8], pos: u64) -> Result<Header> {
        let mut f = Fields::new(&self.path, &id::HEAD, pos, payload, pos + HEADER_BYTES);
        if (payload.len() as u64) < HEAD_FIXED_BYTES {
            return Err(f.error(format!("{} bytes, fewer than the {HEAD_FIXED_BYTES} of its fixed fields", payload.len())));
        }
        let newer = self.header.minor > MINOR;
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
            major: self.header.major,
            minor: self.header.minor,
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

    fn parse_skel(&mut self, payload: &[u8], pos: u64) -> Result<()> {
        let base = pos + HEADER_BYTES;
        let subs = chunk::subs(&self.path, &id::SKEL, pos, payload, base)?;
        self.skeleton_chunks.extend(subs.iter().map(|s| ChunkInfo::new(&s.frame, s.offset, 1)));
        let find = |want: [u8; 4]| -> Result<&Sub> {
            let mut found = subs.iter().filter(|s| s.frame.id == want);
            let first = found.next().ok_or_else(|| self.err(pos, &id::SKEL, pos, format!("has no {} chunk", chunk::id_str(&want))))?;
            if let Some(dup) = found.next() {
                return Err(self.err(dup.offset, &id::SKEL, pos, format!("has a second {} chunk", chunk::id_str(&want))));
            }
            Ok(first)
        };
        let (levl, node, nbrs, matl) = (find(id::LEVL)?, find(id::NODE)?, find(id::NBRS)?, find(id::MATL)?);
        let fields = |s: &Sub| Fields::new(&self.path, &s.frame.id, s.offset, &payload[s.start..s.end], s.payload_offset());
        let h = &self.header;

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
                return Err(f.error_at(at, format!("level {l} has nodes {}..+{}; expected a non-empty range from {expect}", rec.first_node, rec.nodes)));
            }
            expect += rec.nodes as u64;
        }
        if expect != h.nodes as u64 {
            return Err(f.error(format!("levels hold {expect} nodes, HEAD says {}", h.nodes)));
        }

        // NBRS
        let nf = fields(nbrs);
        let width = nbrs.frame.flags as u64;
        if width != 2 && width != 4 {
            return Err(nf.error_at(nbrs.offset + 4, format!("entry width {width}; must be 2 or 4")));
        }
        if nbrs.frame.size % width != 0 {
            return Err(nf.error(format!("size {} is not a multiple of {width}", nbrs.frame.size)));
        }
        let mut neighbors: Vec<u32> = payload[nbrs.start..nbrs.end].chunks_exact(width as usize).map(|c| LE::read_uint(c, c.len()) as u32).collect();

        // NODE
        let mut f = fields(node);
        let want = h.nodes as u64 * NODE_RECORD_BYTES;
        if node.frame.size != want {
            return Err(f.error(format!("holds {} bytes; {} nodes need {want}", node.frame.size, h.nodes)));
        }
        let grid = h.grid;
        let mut boxes: Vec<[u64; 2]> = Vec::with_capacity(h.nodes as usize);
        let mut nodes: Vec<NodeRecord> = Vec::with_capacity(h.nodes as usize);
        let mut neighbor_first = 0u64;
        let mut offset = self.skeleton_end;
        // Children of the levels above are consecutive: node i's are those after its predecessors'.
        let mut next_child = 0u64;
        for (l, lev) in levels.iter().enumerate().rev() {
            let end = lev.first_node as u64 + lev.nodes as u64;
            if l + 1 < levels.len() && next_child != end {
                return Err(f.error(format!("the children of level {} cover nodes up to {next_child}, level {l} ends at {end}", l + 1)));
            }
            next_child = end;
            for i in lev.first_node..lev.first_node + lev.nodes {
                let at = f.offset();
                let (child_count, neighbor_count) = (f.u16()? as u32, f.u16()? as u32);
                let axis = octa::decode([f.u16()? as i16, f.u16()? as i16]);
                let (half, radius_code) = (f.u16()?, f.u16()?);
                let (lo_bits, hi_bits) = (f.u64()?, f.u64()?);
                let (lo, hi, center) = (unpack(lo_bits), unpack(hi_bits), unpack(f.u64()?));
                let (error, faces, vertices, size, crc) = (f.f32()?, f.u32()?, f.u32()?, f.u32()?, f.u32()?);
                let bad = |msg: String| f.error_at(at, format!("node {i}: {msg}"));
                let first_child = if child_count > 0 { next_child as u32 } else { 0 };
                if l == 0 && child_count > 0 {
                    return Err(bad(format!("a level-0 node with {child_count} children")));
                }
                next_child += child_count as u64;
                if l > 0 && next_child > (lev.first_node + lev.nodes) as u64 + levels[l - 1].nodes as u64 {
                    return Err(bad(format!("children {first_child}..+{child_count} run past level {}", l - 1)));
                }
                if neighbor_first + neighbor_count as u64 > neighbors.len() as u64 {
                    return Err(bad(format!("neighbours run past the {} of NBRS", neighbors.len())));
                }
                let on_grid = |g: Option<[u32; 3]>| g.filter(|g| g.iter().all(|&x| x <= grid.last()));
                let (Some(_), Some(_), Some(center)) = (on_grid(lo), on_grid(hi), on_grid(center)) else {
                    return Err(bad(format!("box or sphere center off the {}-bit grid", grid.bits)));
                };
                let in_file = size as u64 >= HEADER_BYTES + TRAILER_BYTES && offset.checked_add(size as u64).is_some_and(|e| e <= self.len);
                if !in_file {
                    return Err(bad(format!("geometry {size} bytes at offset {offset} runs past the end of the {}-byte file", self.len)));
                }
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
                    radius: grid.length(radius_decode(radius_code)),
                    error,
                    faces,
                    vertices,
                    offset,
                    size,
                    crc,
                });
                neighbor_first += neighbor_count as u64;
                let end = offset + size as u64;
                offset = end + chunk::padding(end);
            }
        }
        for i in 0..nodes.len() {
            let n = nodes[i];
            for c in n.first_child..n.first_child + n.child_count {
                nodes[c as usize].parent = i as u32;
            }
        }
        if offset > self.len {
            return Err(fields(node).error(format!("geometry chunks end at {offset}, past the end of the {}-byte file", self.len)));
        }
        if neighbor_first != neighbors.len() as u64 {
            return Err(nf.error(format!("holds {} neighbours, the nodes use {neighbor_first}", neighbors.len())));
        }
        for (i, n) in nodes.iter().enumerate() {
            let lev = &levels[n.level as usize];
            for k in n.neighbor_first..n.neighbor_first + n.neighbor_count {
                let x = &mut neighbors[k as usize];
                if *x >= lev.nodes {
                    let at = nbrs.payload_offset() + width * k as u64;
                    return Err(nf.error_at(at, format!("node {i}: neighbour {} of the {} nodes of level {}", *x, lev.nodes, n.level)));
                }
                *x += lev.first_node;
            }
        }

        // MATL
        let mut f = fields(matl);
        let mut materials = Vec::new();
        for m in 0..h.materials {
            let at = f.offset();
            let len = f.u32()?;
            let name = f.string(len).map_err(|_| f.error_at(at, format!("material {m}: name of {len} bytes runs past the chunk or is not UTF-8")))?;
            let base_color = [f.f32()?, f.f32()?, f.f32()?, f.f32()?];
            let at = f.offset();
            let len = f.u32()?;
            let tex = f.string(len).map_err(|_| f.error_at(at, format!("material {m}: texture of {len} bytes runs past the chunk or is not UTF-8")))?;
            materials.push(Material { name, base_color, texture: (!tex.is_empty()).then_some(tex) });
        }
        if f.remaining() > 0 && h.minor.cmp(&MINOR).is_le() {
            return Err(f.error(format!("{} bytes after {} materials", f.remaining(), h.materials)));
        }

        self.levels = levels;
        self.nodes = nodes;
        self.neighbors = neighbors;
        self.boxes = boxes;
        self.materials = materials;
        Ok(())
    }

    /// Node `i`'s record, `GEOM` payload and sub-chunks, CRC checked against the trailer and the
    /// node table.
    /// Read node `i`'s chunk into `buf` and check it: its record, frame, the range of its payload
    /// in `buf`, and the payload's sub-chunks.
    fn node_subs(&mut self, i: u32, buf: &mut Vec<u8>) -> Result<(NodeRecord, Frame, std::ops::Range<usize>, Vec<Sub>)> {
        let rec = *self
            .nodes
            .get(i as usize)
            .ok_or_else(|| Error::at_element(&self.path, format!("node {i}"), format!("no such node; the file has {}", self.nodes.len())))?;
        self.read_into(rec.offset, rec.size as u64, buf)?;
        let mut head = [0u8; 16];
        head.copy_from_slice(&buf[..16]);
        let frame = Frame::parse(&head);
        let at = rec.offset;
        if frame.id != id::GEOM {
            return Err(self.err(at, &frame.id, at, format!("node {i}'s geometry should be a GEOM chunk")));
        }
        if frame.span() != Some(rec.size as u64) {
            return Err(self.err(at + 8, &frame.id, at, format!("size {} does not match node {i}'s {} bytes", frame.size, rec.size)));
        }
        let end = buf.len() - 4;
        let stored = LE::read_u32(&buf[end..]);
        let actual = chunk::crc32(&buf[16..end]);
        if stored != actual || stored != rec.crc {
            return Err(self.err(
                at + end as u64,
                &frame.id,
                at,
                format!("CRC {actual:08x}, stored {stored:08x}, node table {:08x}", rec.crc),
            ));
        }
        let subs = chunk::subs(&self.path, &id::GEOM, at, &buf[16..end], at + HEADER_BYTES)?;
        Ok((rec, frame, 16..end, subs))
    }

    fn decode(&self, i: u32, rec: &NodeRecord, payload: &[u8], subs: &[Sub]) -> Result<NodeGeometry> {
        let at = rec.offset;
        let err = |off: u64, msg: String| self.err(off, &id::GEOM, at, format!("node {i}: {msg}"));
        let mut found: [Option<&Sub>; 7] = [None; 7];
        let kinds = [id::VPOS, id::VNRM, id::VTEX, id::VCOL, id::INDX, id::MATR, id::CLUS];
        for s in subs {
            if let Some(k) = kinds.iter().position(|&x| x == s.frame.id) {
                if found[k].is_some() {
                    return Err(err(s.offset, format!("a second {} chunk", chunk::id_str(&s.frame.id))));
                }
                found[k] = Some(s);
            }
        }
        let attrs = self.header.attributes;
        let wanted = [true, attrs.normals, attrs.uvs, attrs.colors, true, true, rec.level == 0];
        for k in 0..7 {
            if found[k].is_some() != wanted[k] {
                let what = if wanted[k] { "lacks" } else { "should not have" };
                return Err(err(at, format!("{what} a {} chunk", chunk::id_str(&kinds[k]))));
            }
        }
        let v = rec.vertices as u64;
        let data = |s: &Sub, per: u64, what: &str| -> Result<&[u8]> {
            if s.frame.size != v * per {
                return Err(err(s.offset + 8, format!("{} holds {} bytes; {v} vertices need {} for {what}", chunk::id_str(&s.frame.id), s.frame.size, v * per)));
            }
            Ok(&payload[s.start..s.end])
        };
        let mut g = NodeGeometry::default();
        if let Some(s) = found[0] {
            let width = s.frame.flags as u64;
            if width != 2 && width != 3 {
                return Err(err(s.offset + 4, format!("position width {width}; must be 2 or 3")));
            }
            if s.frame.size != 12 + v * 3 * width {
                return Err(err(s.offset + 8, format!("VPOS holds {} bytes; {v} vertices need {} for positions", s.frame.size, 12 + v * 3 * width)));
            }
            let b = &payload[s.start..s.end];
            let base = [LE::read_u32(&b[0..4]), LE::read_u32(&b[4..8]), LE::read_u32(&b[8..12])];
            let grid = self.header.grid;
            let offsets: Vec<u32> = b[12..].chunks_exact(width as usize).map(|c| LE::read_uint(c, c.len()) as u32).collect();
            g.positions.reserve(v as usize);
            for (k, q) in offsets.chunks_exact(3).enumerate() {
                let p: [u64; 3] = std::array::from_fn(|a| base[a] as u64 + q[a] as u64);
                if p.iter().any(|&x| x > grid.last() as u64) {
                    return Err(err(s.payload_offset() + 12 + 3 * width * k as u64, format!("vertex {k} lies off the {}-bit grid", grid.bits)));
                }
                g.positions.push(grid.decode(p.map(|x| x as u32)));
            }
        }
        if let Some(s) = found[1] {
            g.normals = data(s, 4, "normals")?.chunks_exact(4).map(|c| octa::decode([LE::read_i16(&c[0..2]), LE::read_i16(&c[2..4])])).collect();
        }
        if let Some(s) = found[2] {
            g.uvs = data(s, 8, "UVs")?.chunks_exact(8).map(|c| Vec2::new(LE::read_f32(&c[0..4]), LE::read_f32(&c[4..8]))).collect();
        }
        if let Some(s) = found[3] {
            g.colors = data(s, 4, "colors")?.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
        }
        let n_idx = 3 * rec.faces as u64;
        if let Some(s) = found[4] {
            let width = s.frame.flags as u64;
            if width != 2 && width != 4 {
                return Err(err(s.offset + 4, format!("index width {width}; must be 2 or 4")));
            }
            if s.frame.size != n_idx * width {
                return Err(err(s.offset + 8, format!("INDX holds {} bytes; {} faces need {}", s.frame.size, rec.faces, n_idx * width)));
            }
            let b = &payload[s.start..s.end];
            g.indices = if width == 2 {
                b.chunks_exact(2).map(|c| LE::read_u16(c) as u32).collect()
            } else {
                b.chunks_exact(4).map(LE::read_u32).collect()
            };
            if let Some(k) = g.indices.iter().position(|&x| x as u64 >= v) {
                return Err(err(s.payload_offset() + width * k as u64, format!("index {k} is {} of {v} vertices", g.indices[k])));
            }
        }
        if let Some(s) = found[5] {
            if s.frame.size % RANGE_RECORD_BYTES != 0 {
                return Err(err(s.offset + 8, format!("MATR size {} is not a multiple of {RANGE_RECORD_BYTES}", s.frame.size)));
            }
            let mut next = 0u64;
            for (k, c) in payload[s.start..s.end].chunks_exact(12).enumerate() {
                let r = MaterialRange { material: LE::read_u32(&c[0..4]), first_index: LE::read_u32(&c[4..8]), index_count: LE::read_u32(&c[8..12]) };
                if r.first_index as u64 != next || r.index_count == 0 || r.index_count % 3 != 0 || r.material >= self.header.materials {
                    return Err(err(
                        s.payload_offset() + 12 * k as u64,
                        format!("material range {k} ({}, {}, {}) does not continue at index {next} with a whole number of faces of a known material", r.material, r.first_index, r.index_count),
                    ));
                }
                next += r.index_count as u64;
                g.material_ranges.push(r);
            }
            if next != n_idx {
                return Err(err(s.offset, format!("material ranges cover {next} of {n_idx} indices")));
            }
        }
        if let Some(s) = found[6] {
            if s.frame.size % CLUSTER_RECORD_BYTES != 0 {
                return Err(err(s.offset + 8, format!("CLUS size {} is not a multiple of {CLUSTER_RECORD_BYTES}", s.frame.size)));
            }
            let grid = self.header.grid;
            let shift = s.frame.flags;
            if shift > grid.bits {
                return Err(err(s.offset + 4, format!("CLUS shift {shift} exceeds the {} grid bits", grid.bits)));
            }
            let base = found[0].map_or([0; 3], |p| {
                let b = &payload[p.start..p.end];
                [LE::read_u32(&b[0..4]), LE::read_u32(&b[4..8]), LE::read_u32(&b[8..12])]
            });
            let mut next = 0u64;
            for (k, c) in payload[s.start..s.end].chunks_exact(16).enumerate() {
                let u = |o: usize| LE::read_u16(&c[o..o + 2]);
                let face_count = u(6) as u32;
                let center: [u64; 3] = std::array::from_fn(|a| base[a] as u64 + ((u(8 + 2 * a) as u64) << shift));
                let rec_at = s.payload_offset() + 16 * k as u64;
                if face_count == 0 {
                    return Err(err(rec_at, format!("cluster {k} has no faces")));
                }
                if center.iter().any(|&x| x > grid.last() as u64) {
                    return Err(err(rec_at, format!("cluster {k}'s center lies off the {}-bit grid", grid.bits)));
                }
                g.clusters.push(Cluster {
                    cone: Cone { axis: octa::decode([u(0) as i16, u(2) as i16]), half_angle: angle_decode(u(4)) },
                    center: grid.decode(center.map(|x| x as u32)),
                    radius: grid.length(radius_decode(u(14))),
                    first_face: next as u32,
                    face_count,
                });
                next += face_count as u64;
            }
            if next != rec.faces as u64 {
                return Err(err(s.offset, format!("clusters cover {next} of {} faces", rec.faces)));
            }
        }
        Ok(g)
    }
}

fn empty_header() -> Header {
    Header {
        major: 0,
        minor: 0,
        file_size: 0,
        metres_per_unit: 0.0,
        min: Vec3::ZERO,
        max: Vec3::ZERO,
        attributes: Attributes::default(),
        levels: 0,
        nodes: 0,
        materials: 0,
        input_vertices: 0,
        input_faces: 0,
        clusters: 0,
        params: HierarchyParams::default(),
        grid: Grid { origin: [0.0; 3], step: 1.0, bits: 1 },
        level_ratio: 0.0,
        tool: String::new(),
    }
}
