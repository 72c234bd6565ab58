//! Computed vertex normals of the partitioned build: one octahedral code per input vertex, summed
//! over every face of the input while it streams, so known only once it has ended. They wait in a
//! file, from which each cell reads its own vertices' codes: held in memory, they would grow the
//! build's peak with the input (4 bytes a vertex).

use crate::error::{Error, Result};
use crate::format::{octa, ByteSource};
use glam::Vec3;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;

/// The codes in their file, vertex `i`'s at byte `4 i` (two little-endian i16s).
pub struct VertexNormals {
    file: File,
    path: PathBuf,
    count: u64,
}

/// Vertices encoded at once, on every core.
const CHUNK: usize = 1 << 20;

/// Ids closer than this share one read, of at most `SPAN` codes.
const GAP: u64 = 1024;
const SPAN: u64 = 1 << 16;

impl VertexNormals {
    /// Encode the normalized `sums` (a zero sum gets +Z) into a new file at `path`.
    pub fn write(path: PathBuf, sums: &[Vec3]) -> Result<VertexNormals> {
        use rayon::prelude::*;
        let io = |e| Error::io(&path, e);
        let file = File::options().read(true).write(true).create_new(true).open(&path).map_err(io)?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        let mut bytes = Vec::with_capacity(4 * CHUNK);
        for chunk in sums.chunks(CHUNK) {
            let codes: Vec<[i16; 2]> = chunk.par_iter().map(|n| octa::encode(n.normalize_or(Vec3::Z))).collect();
            bytes.clear();
            bytes.extend(codes.iter().flatten().flat_map(|c| c.to_le_bytes()));
            w.write_all(&bytes).map_err(io)?;
        }
        let file = w.into_inner().map_err(|e| io(e.into_error()))?;
        Ok(VertexNormals { file, path, count: sums.len() as u64 })
    }

    /// The codes of the vertices `ids`, in their order: read in runs of nearby ids.
    pub fn read(&self, ids: &[u32]) -> Result<Vec<[i16; 2]>> {
        let mut order: Vec<u32> = (0..ids.len() as u32).collect();
        order.sort_unstable_by_key(|&k| ids[k as usize]);
        let mut out = vec![[0i16; 2]; ids.len()];
        let mut buf = Vec::new();
        let mut rest = &order[..];
        while let Some(&k) = rest.first() {
            let first = ids[k as usize] as u64;
            let near = |(&a, &b): (&u32, &u32)| {
                let (a, b) = (ids[a as usize] as u64, ids[b as usize] as u64);
                b - a <= GAP && b - first < SPAN
            };
            let run = rest.iter().zip(rest.iter().skip(1)).take_while(|&pair| near(pair)).count() + 1;
            let last = ids[rest[run - 1] as usize] as u64;
            if last >= self.count {
                return Err(Error::invalid(&self.path, None, format!("vertex {last} of {}", self.count)));
            }
            buf.resize(4 * (last - first + 1) as usize, 0);
            self.file.read_exact_at(4 * first, &mut buf).map_err(|e| Error::io(&self.path, e))?;
            for &k in &rest[..run] {
                let at = 4 * (ids[k as usize] as u64 - first) as usize;
                out[k as usize] = [i16::from_le_bytes([buf[at], buf[at + 1]]), i16::from_le_bytes([buf[at + 2], buf[at + 3]])];
            }
            rest = &rest[run..];
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_read_back_by_id_in_any_order() {
        let dir = tempfile::tempdir().unwrap();
        let sums: Vec<Vec3> = (0..5000).map(|i| Vec3::new((i as f32).sin(), (i as f32 * 0.7).cos(), 0.3 * (i % 7) as f32 - 1.0)).collect();
        let mut with_zero = sums.clone();
        with_zero[17] = Vec3::ZERO;
        let file = VertexNormals::write(dir.path().join("n"), &with_zero).unwrap();
        let ids = [4999u32, 3, 17, 3, 2500, 0, 2501, 1200];
        let codes = file.read(&ids).unwrap();
        for (&id, &code) in ids.iter().zip(&codes) {
            let want = if id == 17 { Vec3::Z } else { sums[id as usize].normalize() };
            assert_eq!(code, octa::encode(want), "vertex {id}");
        }
        assert!(file.read(&[]).unwrap().is_empty());
        let e = file.read(&[1, 5000]).unwrap_err();
        assert!(e.to_string().contains("vertex 5000 of 5000"), "{e}");
    }

    #[test]
    fn codes_of_ids_spread_over_many_vertices_read_back_across_spans() {
        let dir = tempfile::tempdir().unwrap();
        let sums: Vec<Vec3> = (0..150_000).map(|i| Vec3::new(1.0, (i % 1000) as f32 * 0.001, (i / 1000) as f32 * 0.01)).collect();
        let file = VertexNormals::write(dir.path().join("n"), &sums).unwrap();
        let ids: Vec<u32> = (0..150_000).rev().step_by(1000).collect();
        let codes = file.read(&ids).unwrap();
        for (&id, &code) in ids.iter().zip(&codes) {
            assert_eq!(code, octa::encode(sums[id as usize].normalize()), "vertex {id}");
        }
    }
}
