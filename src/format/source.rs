//! Where a reader's bytes come from: anything that can read a range at an offset. Reads take
//! `&self`, so one source serves concurrent readers (a file by positional reads; memory; an HTTP
//! client by range requests).

use std::fs::File;
use std::io;

/// Bytes that can be read by range.
pub trait ByteSource {
    /// Size of the whole file in bytes.
    fn size(&self) -> io::Result<u64>;

    /// Fill `buf` with the bytes at `offset`; an error if the range runs past the end.
    fn read_exact_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()>;
}

/// Copy `buf.len()` bytes at `offset` out of `data`.
fn slice_at(data: &[u8], offset: u64, buf: &mut [u8]) -> io::Result<()> {
    let start = usize::try_from(offset).ok().filter(|&s| s <= data.len());
    let range = start.and_then(|s| Some(s..s.checked_add(buf.len()).filter(|&e| e <= data.len())?));
    match range {
        Some(r) => {
            buf.copy_from_slice(&data[r]);
            Ok(())
        }
        None => Err(io::Error::new(
            io::ErrorKind::UnexpectedEof,
            format!("{} bytes at offset {offset} run past the end ({} bytes)", buf.len(), data.len()),
        )),
    }
}

impl ByteSource for [u8] {
    fn size(&self) -> io::Result<u64> {
        Ok(self.len() as u64)
    }
    fn read_exact_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        slice_at(self, offset, buf)
    }
}

impl ByteSource for Vec<u8> {
    fn size(&self) -> io::Result<u64> {
        Ok(self.len() as u64)
    }
    fn read_exact_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        slice_at(self, offset, buf)
    }
}

impl<T: ByteSource + ?Sized> ByteSource for &T {
    fn size(&self) -> io::Result<u64> {
        (**self).size()
    }
    fn read_exact_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        (**self).read_exact_at(offset, buf)
    }
}

impl<T: ByteSource + ?Sized> ByteSource for std::sync::Arc<T> {
    fn size(&self) -> io::Result<u64> {
        (**self).size()
    }
    fn read_exact_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        (**self).read_exact_at(offset, buf)
    }
}

/// In-memory bytes behind a cursor (its position is ignored): what tests and callers holding a
/// `Cursor` already have.
impl<T: AsRef<[u8]>> ByteSource for io::Cursor<T> {
    fn size(&self) -> io::Result<u64> {
        Ok(self.get_ref().as_ref().len() as u64)
    }
    fn read_exact_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        slice_at(self.get_ref().as_ref(), offset, buf)
    }
}

impl ByteSource for File {
    fn size(&self) -> io::Result<u64> {
        Ok(self.metadata()?.len())
    }

    #[cfg(unix)]
    fn read_exact_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        std::os::unix::fs::FileExt::read_exact_at(self, buf, offset)
    }

    #[cfg(windows)]
    fn read_exact_at(&self, mut offset: u64, mut buf: &mut [u8]) -> io::Result<()> {
        use std::os::windows::fs::FileExt;
        while !buf.is_empty() {
            match self.seek_read(buf, offset)? {
                0 => return Err(io::ErrorKind::UnexpectedEof.into()),
                n => {
                    buf = &mut buf[n..];
                    offset += n as u64;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_sources_read_ranges_and_refuse_past_the_end() {
        let data: Vec<u8> = (0..10).collect();
        let mut buf = [0u8; 3];
        data.read_exact_at(7, &mut buf).unwrap();
        assert_eq!(buf, [7, 8, 9]);
        assert!(data.read_exact_at(8, &mut buf).is_err());
        assert!(data.read_exact_at(u64::MAX, &mut buf).is_err());
        let cursor = io::Cursor::new(&data[..]);
        cursor.read_exact_at(0, &mut buf).unwrap();
        assert_eq!((buf, cursor.size().unwrap()), ([0, 1, 2], 10));
    }
}
