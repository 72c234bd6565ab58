//! The lazy reader: [`Reader::open`] reads and checks the prologue, `HEAD` and `SKEL` only;
//! [`Reader::read_node`] reads one node's `GEOM` chunk, checks it and decodes it.
//!
//! Every count, offset and length is checked against the file size before anything is allocated,
//! every problem is an [`Error`] naming the chunk and the byte offset, and the rules of spec §6 are
//! checked as the skeleton and each node are decoded ([`rules`]). Reads take `&self` and go
//! through a [`ByteSource`], so several threads can read nodes of one file at once.

use super::chunk::{self, Fields, Frame, HEADER_BYTES, TRAILER_BYTES};
use super::geom::{self, NodeContext};
use super::georef::{self, Georef};
use super::planes::{self, Planes};
use super::rules::{self, Sink};
pub use super::skeleton::ChunkInfo;
use super::skeleton::{self, Context, Skeleton};
use super::texture;
use super::{
    id, ByteSource, Header, LevelRecord, Material, NodeGeometry, NodeRecord, Textures, MAGIC, MAJOR, NEWEST_MAJOR, PROLOGUE_BYTES, VERSION,
};
use crate::error::{Error, Result};
use byteorder::{ByteOrder, LittleEndian as LE};
use glam::Vec3;
use std::fs::File;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Largest `HEAD` or `GEOR` payload a reader accepts (newer minor versions may append fields).
const MAX_HEAD_BYTES: u64 = 1 << 16;

/// An open strata file: its header and skeleton in memory, geometry read on demand.
pub struct Reader<S> {
    source: S,
    path: PathBuf,
    len: u64,
    bytes_read: AtomicU64,
    skeleton: Skeleton,
    /// `HEAD`, chunks skipped before `SKEL`, `SKEL` and its sub-chunks.
    skeleton_chunks: Vec<ChunkInfo>,
    /// Offset just after `SKEL` and its padding.
    skeleton_end: u64,
    /// Whether the rules of spec §6 are checked at open and as each node is decoded.
    strict: bool,
    /// With [`Reader::open_top`], what [`Reader::complete`] needs.
    pending: Option<Pending>,
    georef: Option<Georef>,
}

/// What [`Reader::open_top`] leaves for [`Reader::complete`]: the `SKEL` payload (format 2), or
/// the `SKEL` frame to read the rest of it (format 3, whose open read only the top levels' pages),
/// at offset `pos`, of version `version`.
struct Pending {
    payload: Vec<u8>,
    pos: u64,
    version: [u16; 2],
    rest: Option<Frame>,
}

impl Reader<File> {
    /// Open the file at `path`.
    pub fn open_path(path: &Path) -> Result<Reader<File>> {
        let f = File::open(path).map_err(|e| Error::io(path, e))?;
        Reader::open_named(f, path)
    }

    /// Open the file at `path` with [`Reader::open_top`].
    pub fn open_top_path(path: &Path) -> Result<Reader<File>> {
        let f = File::open(path).map_err(|e| Error::io(path, e))?;
        Reader::open_top(f, path)
    }
}

impl<S: ByteSource> Reader<S> {
    /// Open a file from any byte source; errors name it `<input>`.
    pub fn open(source: S) -> Result<Reader<S>> {
        Reader::open_named(source, Path::new("<input>"))
    }

    /// Open a file from any byte source; errors name it `path`. Besides every size, offset and
    /// checksum, each value of the skeleton is checked here, and each node's rules (spec §6) as the
    /// node is read, so that what [`verify`](super::verify()) refuses no reader uses.
    pub fn open_named(source: S, path: &Path) -> Result<Reader<S>> {
        let rd = Reader::open_with(source, path, false)?;
        Ok(Reader { strict: true, ..rd })
    }

    /// Open as [`Reader::open_named`] does, checking the whole skeleton, but decode only the top
    /// two levels' node records (the top's rules are checked against its children):
    /// [`Reader::nodes`] and the node accessors cover those until [`Reader::complete`] decodes the
    /// rest, and only top-level nodes may be read. For a viewer's first frame, which shows the
    /// top level: on a file of 70k nodes this leaves about 9 MB untouched at open.
    pub fn open_top(source: S, path: &Path) -> Result<Reader<S>> {
        let rd = Reader::open_with(source, path, true)?;
        Ok(Reader { strict: true, ..rd })
    }

    /// Decode the node records [`Reader::open_top`] left (no-op otherwise). They were checked at
    /// open, so this fails only as open would have.
    pub fn complete(&mut self) -> Result<()> {
        let Some(p) = &self.pending else { return Ok(()) };
        let [major, minor] = p.version;
        let whole = match p.rest {
            Some(frame) => Some(self.payload_at(p.pos, &frame)?),
            None => None,
        };
        let p = self.pending.as_ref().expect("pending");
        if let Some(w) = &whole {
            // The records already in use must be the ones just read: a file rewritten since open is refused.
            if w.get(..p.payload.len()) != Some(&p.payload[..]) {
                return Err(self.err(p.pos, &id::SKEL, p.pos, "changed since the file was opened"));
            }
        }
        let payload = whole.as_deref().unwrap_or(&p.payload);
        let ctx = Context { path: &self.path, major, minor, file_size: self.len, geometry_start: self.skeleton_end };
        let (s, _) = skeleton::decode_skel(&ctx, &self.skeleton.header, payload, p.pos, false, false)?;
        self.pending = None;
        self.skeleton = Skeleton { textures: std::mem::take(&mut self.skeleton.textures), ..s };
        Ok(())
    }

    /// Whether every node record is decoded (see [`Reader::open_top`]).
    pub fn is_complete(&self) -> bool {
        self.skeleton.is_complete()
    }

    /// Open checking the skeleton only; nodes are decoded without their rules.
    /// For [`verify`](super::verify()), which checks the rules itself and lists every problem.
    pub(crate) fn open_unchecked(source: S, path: &Path) -> Result<Reader<S>> {
        Reader::open_with(source, path, false)
    }

    fn open_with(source: S, path: &Path, top_only: bool) -> Result<Reader<S>> {
        let len = source.size().map_err(|e| Error::io(path, e))?;
        let mut rd = Reader {
            source,
            path: path.to_path_buf(),
            len,
            bytes_read: AtomicU64::new(0),
            skeleton: Skeleton {
                header: empty_header(),
                levels: Vec::new(),
                nodes: Vec::new(),
                neighbors: Vec::new(),
                materials: Vec::new(),
                boxes: Vec::new(),
                textures: Default::default(),
                code: None,
                dag: None,
            },
            skeleton_chunks: Vec::new(),
            skeleton_end: 0,
            strict: false,
            pending: None,
            georef: None,
        };
        let (major, minor) = rd.read_prologue()?;
        let mut pos = PROLOGUE_BYTES;
        let head = rd.frame_at(pos)?;
        if head.id != id::HEAD {
            return Err(rd.err(pos, &head.id, pos, "expected the HEAD chunk here"));
        }
        if head.size > MAX_HEAD_BYTES {
            return Err(rd.err(pos + 8, &head.id, pos, format!("size {} exceeds the {MAX_HEAD_BYTES}-byte limit", head.size)));
        }
        let payload = rd.payload_at(pos, &head)?;
        let ctx = Context { path, major, minor, file_size: len, geometry_start: 0 };
        let header = skeleton::decode_head(&ctx, &payload, pos)?;
        rd.skeleton_chunks.push(ChunkInfo::new(&head, pos, 0));
        if header.file_size != len {
            return Err(rd.err(
                pos + HEADER_BYTES,
                &head.id,
                pos,
                format!("the file is {len} bytes but HEAD says {}: truncated or extended", header.file_size),
            ));
        }
        pos = rd.next(pos, &head)?;
        let skel = loop {
            let f = rd.frame_at(pos)?;
            if f.id == id::SKEL {
                break f;
            }
            if f.id == id::HEAD || f.id == id::GEOM || f.id == id::GEOS {
                return Err(rd.err(pos, &f.id, pos, "expected the SKEL chunk before any other known chunk"));
            }
            if f.id == id::GEOR {
                if rd.georef.is_some() {
                    return Err(rd.err(pos, &f.id, pos, "a second GEOR chunk"));
                }
                if f.size > MAX_HEAD_BYTES {
                    return Err(rd.err(pos + 8, &f.id, pos, format!("size {} exceeds the {MAX_HEAD_BYTES}-byte limit", f.size)));
                }
                let payload = rd.payload_at(pos, &f)?;
                rd.georef = Some(georef::decode(path, major, minor, &payload, pos)?);
            }
            rd.skeleton_chunks.push(ChunkInfo::new(&f, pos, 0));
            pos = rd.next(pos, &f)?;
        };
        // Format 3 opened top first reads SKEL only through the top levels' pages (strata-v3.md §1.1).
        let (payload, partial) = if top_only && super::paged(major, minor) {
            rd.skel_prefix(pos, &skel, header.levels)?
        } else {
            (rd.payload_at(pos, &skel)?, false)
        };
        rd.skeleton_chunks.push(ChunkInfo::new(&skel, pos, 0));
        rd.skeleton_end = rd.next(pos, &skel)?;
        let ctx = Context { geometry_start: rd.skeleton_end, ..ctx };
        let (s, subs) = skeleton::decode_skel(&ctx, &header, &payload, pos, top_only, partial)?;
        rd.skeleton = s;
        rd.skeleton_chunks.extend(subs);
        if top_only && rd.skeleton.nodes.len() < header.nodes as usize {
            rd.pending = Some(Pending { payload, pos, version: [major, minor], rest: partial.then_some(skel) });
        }
        Ok(rd)
    }

    /// The header and skeleton: everything front selection needs.
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// The `HEAD` chunk.
    pub fn header(&self) -> &Header {
        &self.skeleton.header
    }

    /// Where the model sits on Earth (`GEOR`, spec §5.2), for a file made from an elevation grid.
    pub fn georef(&self) -> Option<&Georef> {
        self.georef.as_ref()
    }

    /// The node table, in file order (top level first); opened with [`Reader::open_top`], the
    /// top two levels until [`Reader::complete`] (the level ranges and child ranges still
    /// count every node).
    pub fn nodes(&self) -> &[NodeRecord] {
        &self.skeleton.nodes
    }

    /// Per level, finest first: node range, faces, vertices and bytes.
    pub fn levels(&self) -> &[LevelRecord] {
        &self.skeleton.levels
    }

    /// Nodes of level `level` (empty past the top).
    pub fn level_nodes(&self, level: u32) -> Range<u32> {
        self.skeleton.level_nodes(level)
    }

    /// Children of node `i` (nodes of the level below).
    pub fn children(&self, i: u32) -> Range<u32> {
        self.skeleton.children(i)
    }

    /// Format 4: the DAG's groups and how nodes refer to them (strata-v4.md); `None` in formats 2
    /// and 3, whose nodes form a tree.
    pub fn dag(&self) -> Option<&super::DagTable> {
        self.skeleton.dag.as_ref()
    }

    /// Same-level neighbours of node `i`.
    pub fn neighbors(&self, i: u32) -> &[u32] {
        self.skeleton.neighbors(i)
    }

    pub fn materials(&self) -> &[Material] {
        &self.skeleton.materials
    }

    /// The images the materials use, their levels and each node's UV density (spec §7.5).
    pub fn textures(&self) -> &Textures {
        &self.skeleton.textures
    }

    /// Read level `level` (0 = full) of image `image`: the `TEXL` chunk is checked (ID, size,
    /// CRC, the image header's size); returns the image file's bytes (PNG or JPEG).
    pub fn read_image_level(&self, image: u32, level: u32) -> Result<Vec<u8>> {
        if !self.is_complete() {
            // TEXL offsets rest on every level's byte count, checked with the rest of the node table.
            return Err(Error::at_element(
                &self.path,
                format!("image {image} level {level}"),
                "read before the node table is complete (Reader::complete)",
            ));
        }
        let t = &self.skeleton.textures;
        let (Some(rec), Some(lv)) = (t.images.get(image as usize), t.level(image, level)) else {
            return Err(Error::at_element(
                &self.path,
                format!("image {image} level {level}"),
                format!("no such image level; the file has {} images", t.images.len()),
            ));
        };
        let mut bytes = self.read_at(lv.offset, lv.size as u64)?;
        let payload = texture::check_level(lv, rec.codec, &bytes).map_err(|(at, m)| {
            Error::at_byte(&self.path, at, format!("image {image} level {level}: {}: {m}", chunk::name(&id::TEXL, lv.offset)))
        })?;
        let range =
            payload.as_ptr() as usize - bytes.as_ptr() as usize..payload.as_ptr() as usize - bytes.as_ptr() as usize + payload.len();
        bytes.truncate(range.end);
        bytes.drain(..range.start);
        Ok(bytes)
    }

    /// Where the `ORDR` chunk (2.3) starts if the file has one: right after the last `GEOM` or
    /// `TEXL` chunk and its padding (spec §2).
    pub fn planes_offset(&self) -> u64 {
        let bytes = self.skeleton.levels.iter().map(|l| l.bytes).sum::<u64>();
        let geometry = skeleton::geometry_layout(self.header().major, self.skeleton_end, bytes).1;
        self.skeleton
            .textures
            .levels
            .iter()
            .map(|l| l.offset + l.size as u64 + chunk::padding(l.offset + l.size as u64))
            .fold(geometry, u64::max)
    }

    /// Read and check the separating planes (`ORDR`, spec §7.6), not read at open: a viewer needs
    /// them only to order what it draws. Empty for a file without them.
    pub fn read_planes(&self) -> Result<Planes> {
        if !self.is_complete() {
            return Err(Error::invalid(&self.path, None, "the separating planes need the whole node table (Reader::complete)"));
        }
        let at = self.planes_offset();
        if at >= self.len {
            return Ok(Planes::default());
        }
        if self.header().is_dag() {
            // Format 4: separating planes are between a tree's siblings; a file has none (strata-v4.md §0).
            if self.read_at(at, 4.min(self.len - at))?[..] == id::ORDR {
                return Err(Error::at_byte(&self.path, at, "an ORDR chunk in a format-4 file, which has no separating planes"));
            }
            return Ok(Planes::default());
        }
        if !self.header().has_planes_version() {
            return Ok(Planes::default());
        }
        // The frame, then the chunk alone (chunks of a newer minor may follow it). Anything but
        // ORDR there means no planes: `verify` reports it, a viewer only loses the order.
        let here = |msg: String| Error::at_byte(&self.path, at, format!("{}: {msg}", chunk::name(&id::ORDR, at)));
        let frame = self.read_at(at, HEADER_BYTES.min(self.len - at))?;
        let mut head = [0u8; 16];
        head.copy_from_slice(
            frame.get(..16).ok_or_else(|| here(format!("{} bytes after the geometry, too few for a chunk", frame.len())))?,
        );
        let f = Frame::parse(&head);
        if f.id != id::ORDR {
            return Ok(Planes::default());
        }
        let end = f.span().filter(|&s| s <= self.len - at).ok_or_else(|| here(format!("size {} runs past the end of the file", f.size)))?;
        let bytes = self.read_at(at, end)?;
        let payload = &bytes[HEADER_BYTES as usize..(HEADER_BYTES + f.size) as usize];
        let stored = LE::read_u32(&bytes[(HEADER_BYTES + f.size) as usize..end as usize]);
        let actual = chunk::crc32(payload);
        if stored != actual {
            return Err(Error::at_byte(
                &self.path,
                at + HEADER_BYTES + f.size,
                format!("{}: CRC {actual:08x} != stored {stored:08x}", chunk::name(&id::ORDR, at)),
            ));
        }
        let mut fields = Fields::new(&self.path, &id::ORDR, at, payload, at + HEADER_BYTES);
        let sk = &self.skeleton;
        let top = sk.levels.last().map_or(0, |l| l.nodes);
        planes::decode_ordr(&mut fields, f.flags as u64, sk.nodes.len() as u32, |p| if p == 0 { top } else { sk.nodes[p - 1].child_count })
    }

    /// Node `i`'s bounding box (min, max).
    pub fn node_box(&self, i: u32) -> (Vec3, Vec3) {
        self.skeleton.node_box(i)
    }

    /// Every node's bounding box, in node order.
    pub fn node_boxes(&self) -> Vec<(Vec3, Vec3)> {
        (0..self.skeleton.nodes.len() as u32).map(|i| self.node_box(i)).collect()
    }

    /// Bytes read from the source so far.
    pub fn bytes_read(&self) -> u64 {
        self.bytes_read.load(Ordering::Relaxed)
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
    pub fn read_node(&self, i: u32) -> Result<NodeGeometry> {
        if self.skeleton.children(i).end as usize > self.skeleton.nodes.len() {
            return Err(Error::invalid(&self.path, None, format!("node {i}: its children are not decoded yet (Reader::complete)")));
        }
        let (rec, bytes) = self.node_bytes(i)?;
        let ctx = self.node_context(i, &rec);
        let g = geom::decode(&ctx, &bytes)?;
        if self.strict {
            let mut sink = Sink::new(1);
            rules::relations(&self.path, &self.skeleton, i, &mut sink);
            rules::node(&self.path, i, &rec, self.node_box(i), &g, &mut sink);
            if let Some(e) = sink.first() {
                return Err(e);
            }
        }
        Ok(g)
    }

    /// The sub-chunks of node `i`'s `GEOM` chunk (read and checked).
    pub fn node_chunks(&self, i: u32) -> Result<Vec<ChunkInfo>> {
        let (rec, bytes) = self.node_bytes(i)?;
        geom::chunks(&self.node_context(i, &rec), &bytes)
    }

    /// What decoding node `i` (record `rec`) needs besides its bytes.
    pub fn node_context<'a>(&'a self, i: u32, rec: &'a NodeRecord) -> NodeContext<'a> {
        NodeContext {
            path: &self.path,
            index: i,
            record: rec,
            header: self.header(),
            bounds: self.skeleton.node_box_points(i),
            code: self.skeleton.code.as_deref(),
        }
    }

    /// Node `i`'s record and the bytes of its `GEOM` chunk.
    fn node_bytes(&self, i: u32) -> Result<(NodeRecord, Vec<u8>)> {
        let nodes = &self.skeleton.nodes;
        let rec = *nodes.get(i as usize).ok_or_else(|| {
            let msg = match self.skeleton.header.nodes {
                n if i < n => "not decoded yet (Reader::complete)".to_string(),
                n => format!("no such node; the file has {n}"),
            };
            Error::at_element(&self.path, format!("node {i}"), msg)
        })?;
        Ok((rec, self.read_at(rec.offset, rec.size as u64)?))
    }

    /// Walk the top-level chunk frames from the end of the prologue to the end of the file,
    /// reading 16 bytes per chunk.
    pub fn chunks(&self) -> Result<Vec<ChunkInfo>> {
        let mut out = Vec::new();
        let mut pos = PROLOGUE_BYTES;
        while pos < self.len {
            let f = self.frame_at(pos)?;
            out.push(ChunkInfo::new(&f, pos, 0));
            pos = self.next(pos, &f)?;
        }
        Ok(out)
    }

    /// Read `len` bytes at `offset`; an error naming the file if they do not lie in it.
    pub fn read_at(&self, offset: u64, len: u64) -> Result<Vec<u8>> {
        let end = offset.checked_add(len).filter(|&e| e <= self.len);
        if end.is_none() {
            return Err(Error::at_byte(
                &self.path,
                offset,
                format!("{len} bytes at offset {offset} run past the end of the file ({} bytes)", self.len),
            ));
        }
        let mut buf = vec![0u8; len as usize];
        self.source.read_exact_at(offset, &mut buf).map_err(|e| Error::io(&self.path, e))?;
        self.bytes_read.fetch_add(len, Ordering::Relaxed);
        Ok(buf)
    }

    fn err(&self, at: u64, id: &[u8; 4], chunk_offset: u64, msg: impl std::fmt::Display) -> Error {
        Error::at_byte(&self.path, at, format!("{}: {msg}", chunk::name(id, chunk_offset)))
    }

    /// Check the prologue (spec §3); its version.
    fn read_prologue(&self) -> Result<(u16, u16)> {
        if self.len < PROLOGUE_BYTES {
            return Err(Error::at_byte(&self.path, 0, format!("a file of {} bytes is too short for a strata file", self.len)));
        }
        let p = self.read_at(0, PROLOGUE_BYTES)?;
        if p[..8] != MAGIC {
            return Err(Error::at_byte(&self.path, 0, "not a strata file (the first 8 bytes are not the strata magic)"));
        }
        let (major, minor) = (LE::read_u16(&p[8..10]), LE::read_u16(&p[10..12]));
        if major > NEWEST_MAJOR {
            return Err(Error::at_byte(
                &self.path,
                8,
                format!("format version {major}.{minor} is newer than this reader's {VERSION}: a newer strata is needed"),
            ));
        }
        if major < MAJOR {
            return Err(Error::at_byte(
                &self.path,
                8,
                format!("format version {major}.{minor} is not supported (this reader reads {MAJOR}.x)"),
            ));
        }
        let (stored, actual) = (LE::read_u32(&p[12..16]), chunk::crc32(&p[..12]));
        if stored != actual {
            return Err(Error::at_byte(&self.path, 12, format!("prologue CRC {actual:08x} != stored {stored:08x}")));
        }
        Ok((major, minor))
    }

    /// The frame at `pos`; there must be room for it and a CRC.
    fn frame_at(&self, pos: u64) -> Result<Frame> {
        if pos.checked_add(HEADER_BYTES + TRAILER_BYTES).is_none_or(|e| e > self.len) {
            return Err(Error::at_byte(
                &self.path,
                pos,
                format!("a chunk at offset {pos} runs past the end of the file ({} bytes)", self.len),
            ));
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

    /// The first sub-chunks of the `SKEL` chunk at `pos` (frame `skel`), each whole with its
    /// padding, through the node page of the level below the top (or the top's, for one level):
    /// what a format-3 reader needs for the top level. Their CRCs are checked as they are decoded;
    /// `SKEL`'s own once the rest is read ([`Reader::complete`]). Where those are every page (one
    /// or two levels) or all of SKEL, the whole payload instead, its CRC checked; the flag says
    /// whether the payload is a prefix.
    fn skel_prefix(&self, pos: u64, skel: &Frame, levels: u32) -> Result<(Vec<u8>, bool)> {
        self.next(pos, skel)?;
        let payload_end = pos + HEADER_BYTES + skel.size;
        let (mut at, mut pages, mut out) = (pos + HEADER_BYTES, 0u32, Vec::new());
        while pages < levels.clamp(1, 2) {
            if at + HEADER_BYTES + TRAILER_BYTES > payload_end {
                return Err(self.err(at, &id::SKEL, pos, format!("ends after {pages} node pages (NODL); {levels} levels need them")));
            }
            let f = self.frame_at(at)?;
            let span = f.span().and_then(|s| at.checked_add(s)).filter(|&e| e <= payload_end);
            let Some(after) = span else {
                return Err(self.err(at + 8, &f.id, at, format!("size {} runs past its parent SKEL", f.size)));
            };
            let next = (after + chunk::padding(after)).min(payload_end);
            out.extend_from_slice(&self.read_at(at, next - at)?);
            pages += (f.id == id::NODL) as u32;
            at = next;
        }
        if at == payload_end || pages >= levels {
            // Every page read, or all of SKEL: the whole payload, whose CRC and end are checked now.
            return Ok((self.payload_at(pos, skel)?, false));
        }
        Ok((out, true))
    }

    /// The payload of the chunk at `pos`, its CRC checked.
    fn payload_at(&self, pos: u64, f: &Frame) -> Result<Vec<u8>> {
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
}

fn empty_header() -> Header {
    Header {
        major: 0,
        minor: 0,
        file_size: 0,
        metres_per_unit: 0.0,
        min: Vec3::ZERO,
        max: Vec3::ZERO,
        attributes: super::Attributes::default(),
        levels: 0,
        nodes: 0,
        materials: 0,
        input_vertices: 0,
        input_faces: 0,
        clusters: 0,
        params: super::HierarchyParams::default(),
        grid: super::Grid { origin: [0.0; 3], step: 1.0, bits: 1 },
        level_ratio: 0.0,
        tool: String::new(),
    }
}
