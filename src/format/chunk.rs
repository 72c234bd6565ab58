//! The chunk frame every part of a strata file shares:
//!
//! ```text
//! id: 4 ASCII bytes | flags: u32 | size: u64 | payload: size bytes | crc: u32 (CRC-32 of payload) | zero padding to a multiple of 8
//! ```
//!
//! Chunks start at file offsets that are multiples of 8; a payload made of sub-chunks is itself a
//! sequence of such frames, its padding included in the parent's payload.

use crate::error::{Error, Result};
use byteorder::{ByteOrder, LittleEndian as LE};
use std::path::Path;

/// Bytes of the frame before the payload: ID, flags, size.
pub const HEADER_BYTES: u64 = 16;
/// Bytes of the CRC after the payload.
pub const TRAILER_BYTES: u64 = 4;
/// Chunks start at multiples of this.
pub const ALIGN: u64 = 8;

/// CRC-32 (ISO-HDLC: zlib, PNG) of `data`.
pub fn crc32(data: &[u8]) -> u32 {
    crc32fast::hash(data)
}

/// Zero bytes needed after `end` to reach the next multiple of [`ALIGN`].
pub fn padding(end: u64) -> u64 {
    (ALIGN - end % ALIGN) % ALIGN
}

/// A chunk ID as text, non-printable bytes escaped.
pub fn id_str(id: &[u8; 4]) -> String {
    id.iter().map(|&b| if b.is_ascii_graphic() || b == b' ' { (b as char).to_string() } else { format!("\\x{b:02x}") }).collect()
}

/// The 16 bytes before a payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame {
    pub id: [u8; 4],
    pub flags: u32,
    pub size: u64,
}

impl Frame {
    pub fn parse(b: &[u8; 16]) -> Frame {
        Frame { id: [b[0], b[1], b[2], b[3]], flags: LE::read_u32(&b[4..8]), size: LE::read_u64(&b[8..16]) }
    }

    pub fn bytes(&self) -> [u8; 16] {
        let mut b = [0u8; 16];
        b[..4].copy_from_slice(&self.id);
        LE::write_u32(&mut b[4..8], self.flags);
        LE::write_u64(&mut b[8..16], self.size);
        b
    }

    /// Bytes from the ID through the CRC, padding excluded; `None` if that overflows.
    pub fn span(&self) -> Option<u64> {
        self.size.checked_add(HEADER_BYTES + TRAILER_BYTES)
    }
}

/// Append a whole chunk (frame, payload, CRC, padding) to `out`, which must start at a multiple of
/// [`ALIGN`] in the file.
pub fn put(out: &mut Vec<u8>, id: [u8; 4], flags: u32, payload: &[u8]) {
    out.extend_from_slice(&Frame { id, flags, size: payload.len() as u64 }.bytes());
    out.extend_from_slice(payload);
    out.extend_from_slice(&crc32(payload).to_le_bytes());
    out.resize(out.len() + padding(out.len() as u64) as usize, 0);
}

/// The message prefix naming a chunk: `chunk NODE at offset 1234`.
pub fn name(id: &[u8; 4], offset: u64) -> String {
    format!("chunk {} at offset {offset}", id_str(id))
}

/// A sub-chunk found inside a payload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Sub {
    pub frame: Frame,
    /// File offset of the sub-chunk's ID.
    pub offset: u64,
    /// Where its payload lies within the parent payload.
    pub start: usize,
    pub end: usize,
}

impl Sub {
    /// File offset of the payload.
    pub fn payload_offset(&self) -> u64 {
        self.offset + HEADER_BYTES
    }
}

/// Split `payload` (starting at file offset `base`, inside chunk `parent` at `parent_offset`) into
/// its sub-chunks, checking each one's bounds, CRC and padding.
pub fn subs(path: &Path, parent: &[u8; 4], parent_offset: u64, payload: &[u8], base: u64) -> Result<Vec<Sub>> {
    let mut out = Vec::new();
    let mut pos = 0usize;
    let len = payload.len();
    while pos < len {
        let at = base + pos as u64;
        let err = |off: u64, msg: String| Error::at_byte(path, off, format!("{}: {msg}", name(parent, parent_offset)));
        let rest = len - pos;
        if (rest as u64) < HEADER_BYTES + TRAILER_BYTES {
            return Err(err(at, format!("{rest} bytes left at offset {at}, too few for a sub-chunk")));
        }
        let mut head = [0u8; 16];
        head.copy_from_slice(&payload[pos..pos + 16]);
        let frame = Frame::parse(&head);
        let room = rest as u64 - HEADER_BYTES - TRAILER_BYTES;
        if frame.size > room {
            return Err(err(at + 8, format!("{} says {} bytes but its parent has {room} left", name(&frame.id, at), frame.size)));
        }
        let start = pos + 16;
        let end = start + frame.size as usize;
        let stored = LE::read_u32(&payload[end..end + 4]);
        let actual = crc32(&payload[start..end]);
        if stored != actual {
            return Err(err(end as u64 + base, format!("{}: CRC {actual:08x} != stored {stored:08x}", name(&frame.id, at))));
        }
        let after = end + 4;
        let pad = padding(base + after as u64) as usize;
        if pad > len - after {
            return Err(err(base + after as u64, format!("{}: padding runs past its parent", name(&frame.id, at))));
        }
        if payload[after..after + pad].iter().any(|&b| b != 0) {
            return Err(err(base + after as u64, format!("{}: padding is not zero", name(&frame.id, at))));
        }
        out.push(Sub { frame, offset: at, start, end });
        pos = after + pad;
    }
    Ok(out)
}

/// Reads little-endian fields from a payload, failing with the chunk's name and the byte offset
/// instead of running past its end.
pub struct Fields<'a> {
    data: &'a [u8],
    pos: usize,
    /// File offset of `data[0]`.
    base: u64,
    chunk: String,
    path: &'a Path,
}

impl<'a> Fields<'a> {
    /// Fields of `data`, which starts at file offset `base` inside chunk `id` at `chunk_offset`.
    pub fn new(path: &'a Path, id: &[u8; 4], chunk_offset: u64, data: &'a [u8], base: u64) -> Fields<'a> {
        Fields { data, pos: 0, base, chunk: name(id, chunk_offset), path }
    }

    /// File offset of the next field.
    pub fn offset(&self) -> u64 {
        self.base + self.pos as u64
    }

    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// An error at the next field.
    pub fn error(&self, msg: impl std::fmt::Display) -> Error {
        self.error_at(self.offset(), msg)
    }

    /// An error at file offset `at`.
    pub fn error_at(&self, at: u64, msg: impl std::fmt::Display) -> Error {
        Error::at_byte(self.path, at, format!("{}: {msg}", self.chunk))
    }

    pub fn bytes(&mut self, n: usize) -> Result<&'a [u8]> {
        if n > self.remaining() {
            return Err(self.error(format!("needs {n} more bytes, {} left", self.remaining())));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    pub fn u16(&mut self) -> Result<u16> {
        self.bytes(2).map(LE::read_u16)
    }

    pub fn u32(&mut self) -> Result<u32> {
        self.bytes(4).map(LE::read_u32)
    }

    pub fn u64(&mut self) -> Result<u64> {
        self.bytes(8).map(LE::read_u64)
    }

    pub fn f32(&mut self) -> Result<f32> {
        self.bytes(4).map(LE::read_f32)
    }

    pub fn f64(&mut self) -> Result<f64> {
        self.bytes(8).map(LE::read_f64)
    }

    pub fn vec3(&mut self) -> Result<glam::Vec3> {
        Ok(glam::Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }

    /// A UTF-8 string of `len` bytes.
    pub fn string(&mut self, len: u32) -> Result<String> {
        let at = self.offset();
        let b = self.bytes(len as usize)?;
        String::from_utf8(b.to_vec()).map_err(|_| self.error_at(at, "string is not UTF-8"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_is_the_zlib_crc() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn put_pads_and_subs_finds() {
        let mut out = Vec::new();
        put(&mut out, *b"ABCD", 7, &[1, 2, 3]);
        assert_eq!(out.len(), 24);
        put(&mut out, *b"EFGH", 0, &[]);
        assert_eq!(out.len(), 48);
        let found = subs(Path::new("t"), b"PRNT", 0, &out, 16).unwrap();
        assert_eq!(found.len(), 2);
        assert_eq!(found[0].frame, Frame { id: *b"ABCD", flags: 7, size: 3 });
        assert_eq!(&out[found[0].start..found[0].end], &[1, 2, 3]);
        out[17] ^= 1;
        assert!(subs(Path::new("t"), b"PRNT", 0, &out, 16).is_err());
    }
}
