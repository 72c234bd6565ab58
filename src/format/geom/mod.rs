//! A node's `GEOM` chunk, framed and decoded: the frame and checksums here, the payload by the
//! codec of the file's format version (one file per version: [`v2`], [`v3`]). Pure functions over byte
//! slices, so any byte source, thread or second implementation can use them. [`v3`] codes with
//! the tools of [`bits`].

pub mod bits;
pub mod rans;
pub mod v2;
// Parallel arrays indexed by vertex and corner read most clearly as index loops.
#[allow(clippy::needless_range_loop)]
pub mod v3;

use super::chunk::{self, Frame, Sub, HEADER_BYTES};
use super::skeleton::ChunkInfo;
use super::{id, Header, NodeGeometry, NodeRecord};
use crate::error::{Error, Result};
use byteorder::{ByteOrder, LittleEndian as LE};
use std::path::Path;

/// What decoding node `index` needs besides its bytes.
pub struct NodeContext<'a> {
    /// The name errors give the file.
    pub path: &'a Path,
    pub index: u32,
    pub record: &'a NodeRecord,
    pub header: &'a Header,
    /// The node's box, grid points (format 3 predicts its first vertex from the middle).
    pub bounds: [[u32; 3]; 2],
    /// Format 3: the file's coding tables.
    pub code: Option<&'a v3::Code>,
}

impl NodeContext<'_> {
    fn err(&self, at: u64, id: &[u8; 4], msg: impl std::fmt::Display) -> Error {
        Error::at_byte(self.path, at, format!("{}: {msg}", chunk::name(id, self.record.offset)))
    }
}

/// Check the `GEOM` chunk `bytes` (its `size` bytes from ID through CRC, at the record's offset):
/// its ID, its size against the node table, its CRC against the trailer and the table; return its
/// frame and sub-chunks (offsets within `bytes[16..]`). Format 2 only: format 3's node payloads
/// have no frame ([`check_payload`]).
pub fn split(ctx: &NodeContext, bytes: &[u8]) -> Result<(Frame, Vec<Sub>)> {
    let (i, rec) = (ctx.index, ctx.record);
    let at = rec.offset;
    if bytes.len() as u64 != rec.size as u64 || bytes.len() < 20 {
        return Err(ctx.err(at, &id::GEOM, format!("node {i}'s geometry is {} bytes, its record says {}", bytes.len(), rec.size)));
    }
    let mut head = [0u8; 16];
    head.copy_from_slice(&bytes[..16]);
    let frame = Frame::parse(&head);
    if frame.id != id::GEOM {
        return Err(ctx.err(at, &frame.id, format!("node {i}'s geometry should be a GEOM chunk")));
    }
    if frame.span() != Some(rec.size as u64) {
        return Err(ctx.err(at + 8, &frame.id, format!("size {} does not match node {i}'s {} bytes", frame.size, rec.size)));
    }
    let end = bytes.len() - 4;
    let stored = LE::read_u32(&bytes[end..]);
    let actual = chunk::crc32(&bytes[16..end]);
    if stored != actual || stored != rec.crc {
        return Err(ctx.err(at + end as u64, &frame.id, format!("CRC {actual:08x}, stored {stored:08x}, node table {:08x}", rec.crc)));
    }
    let subs = chunk::subs(ctx.path, &id::GEOM, at, &bytes[16..end], at + HEADER_BYTES)?;
    Ok((frame, subs))
}

/// Format 3: check a node's payload (its record's `size` bytes) against the record's size and CRC.
pub fn check_payload(ctx: &NodeContext, bytes: &[u8]) -> Result<()> {
    let (i, rec) = (ctx.index, ctx.record);
    if bytes.len() as u64 != rec.size as u64 {
        return Err(Error::at_byte(
            ctx.path,
            rec.offset,
            format!("node {i}'s geometry is {} bytes, its record says {}", bytes.len(), rec.size),
        ));
    }
    let actual = chunk::crc32(bytes);
    if actual != rec.crc {
        return Err(Error::at_byte(ctx.path, rec.offset, format!("node {i}'s geometry: CRC {actual:08x}, node table {:08x}", rec.crc)));
    }
    Ok(())
}

/// Check and decode node geometry `bytes` (format 2: the `GEOM` chunk; format 3: the payload), by
/// the codec of the file's major version.
pub fn decode(ctx: &NodeContext, bytes: &[u8]) -> Result<NodeGeometry> {
    if ctx.header.major >= 3 {
        check_payload(ctx, bytes)?;
        let code = ctx.code.ok_or_else(|| Error::invalid(ctx.path, None, "format 3 without coding tables"))?;
        return v3::decode(ctx, bytes, &code.decoder);
    }
    let (_, subs) = split(ctx, bytes)?;
    v2::decode(ctx, &bytes[16..bytes.len() - 4], &subs)
}

/// The chunk and its sub-chunks, for listings.
pub fn chunks(ctx: &NodeContext, bytes: &[u8]) -> Result<Vec<ChunkInfo>> {
    if ctx.header.major >= 3 {
        check_payload(ctx, bytes)?;
        return Ok(Vec::new());
    }
    let (frame, subs) = split(ctx, bytes)?;
    let mut out = vec![ChunkInfo::new(&frame, ctx.record.offset, 0)];
    out.extend(subs.iter().map(|s| ChunkInfo::new(&s.frame, s.offset, 1)));
    Ok(out)
}
