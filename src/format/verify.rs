//! Check a whole strata file: every chunk's frame, CRC and padding, the rules of the skeleton and of
//! every node ([`rules`], which every reader checks too), and what only the whole file can tell:
//! chunks laid out as the node table and the image table say, every image level's header, the
//! cluster count, and level 0 covering every input face exactly once.

use super::chunk::{self, HEADER_BYTES, TRAILER_BYTES};
use super::rules::{self, Sink};
use super::{id, ByteSource, Reader};
use crate::error::{Error, Result};
use std::collections::HashSet;
use std::fs::File;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::Path;

/// Problems recorded before verification stops listing them.
pub const MAX_PROBLEMS: usize = 100;

/// The outcome of [`verify`].
#[derive(Debug, Default)]
pub struct Verification {
    /// The first [`MAX_PROBLEMS`] problems found, in file order as far as possible.
    pub problems: Vec<Error>,
    /// Top-level chunks walked and nodes whose geometry was read.
    pub chunks: usize,
    pub nodes: usize,
}

impl Verification {
    /// No problem found.
    pub fn is_sound(&self) -> bool {
        self.problems.is_empty()
    }

    fn push(&mut self, e: Error) {
        if self.problems.len() < MAX_PROBLEMS {
            self.problems.push(e);
        }
    }
}

/// Verify the file at `path`.
pub fn verify_path(path: &Path) -> Verification {
    match File::open(path) {
        Ok(f) => verify(f, path),
        Err(e) => Verification { problems: vec![Error::io(path, e)], ..Verification::default() },
    }
}

/// Verify a file read from `r`; errors name it `name`. Never fails: problems are listed.
pub fn verify<S: ByteSource>(r: S, name: &Path) -> Verification {
    let mut v = Verification::default();
    let rd = match Reader::open_unchecked(r, name) {
        Ok(rd) => rd,
        Err(e) => {
            v.push(e);
            return v;
        }
    };
    walk(&rd, &mut v);
    geometry(&rd, &mut v);
    v
}

/// Walk the top-level chunks: frames, padding, unknown chunks' CRCs, and the `GEOM` chunks being
/// exactly the node table's, in node order.
fn walk<S: ByteSource>(rd: &Reader<S>, v: &mut Verification) {
    let path = rd.path().to_path_buf();
    let chunks = match rd.chunks() {
        Ok(c) => c,
        Err(e) => return v.push(e),
    };
    v.chunks = chunks.len();
    let strict = rd.header().minor_known();
    let mut geoms = Vec::new();
    let mut geos = Vec::new();
    let mut texls = Vec::new();
    let mut seen_skel = false;
    for (k, c) in chunks.iter().enumerate() {
        let here = |msg: String| Error::at_byte(&path, c.offset, format!("chunk {} at offset {}: {msg}", c.id, c.offset));
        let end = c.offset + HEADER_BYTES + c.size + TRAILER_BYTES;
        let known = [id::HEAD, id::GEOR, id::SKEL, id::GEOM, id::GEOS, id::TEXL, id::ORDR].iter().any(|i| chunk::id_str(i) == c.id);
        if known && c.id != "ORDR" && c.flags != 0 && strict {
            v.push(here(format!("flags {:#x} should be 0", c.flags)));
        }
        let pad = chunk::padding(end).min(rd.file_size().saturating_sub(end));
        match rd.read_at(end, pad) {
            Ok(b) if b.iter().any(|&x| x != 0) => v.push(here("padding is not zero".into())),
            Ok(_) => {}
            Err(e) => v.push(e),
        }
        if c.id == "HEAD" && k != 0 {
            v.push(here("a second HEAD".into()));
        } else if c.id == "SKEL" {
            if seen_skel {
                v.push(here("a second SKEL".into()));
            }
            seen_skel = true;
        } else if c.id == "GEOR" {
            if seen_skel {
                v.push(here("GEOR after SKEL: it belongs between HEAD and SKEL".into()));
            }
        } else if c.id == "GEOM" {
            if !texls.is_empty() {
                v.push(here("a GEOM chunk after TEXL chunks: images follow the geometry".into()));
            }
            geoms.push((c.offset, HEADER_BYTES + c.size + TRAILER_BYTES));
        } else if c.id == "GEOS" {
            if !texls.is_empty() {
                v.push(here("GEOS after TEXL chunks: images follow the geometry".into()));
            }
            geos.push((c.offset, c.size));
            if let Err(e) = crc_of(rd, &c.id, c.offset, c.size) {
                v.push(e);
            }
        } else if c.id == "TEXL" {
            texls.push((c.offset, HEADER_BYTES + c.size + TRAILER_BYTES));
        } else if c.id == "ORDR" {
            if rd.header().minor < 3 && rd.header().major == 2 {
                v.push(here(format!("an ORDR chunk in a format 2.{} file: separating planes are 2.3 (spec §7.6)", rd.header().minor)));
            }
            if c.offset != rd.planes_offset() {
                v.push(here(format!("ORDR belongs right after the geometry and images, at offset {}", rd.planes_offset())));
            }
            if let Err(e) = rd.read_planes() {
                v.push(e);
            }
        } else if !known {
            if let Err(e) = crc_of(rd, &c.id, c.offset, c.size) {
                v.push(e);
            }
            // From 2.3 a file of a version this reader knows holds only the chunks of spec §2: a
            // GEOR whose ID was damaged must not pass as an unknown chunk (2.3 does not say, as
            // 2.1 did, that the file has one).
            if strict && rd.header().has_planes_version() {
                v.push(here(format!("an unknown chunk in a format {}.{} file (spec §4.3)", rd.header().major, rd.header().minor)));
            }
        }
    }
    // 2.1 adds only GEOR, and writers write 2.1 only for a file that has one (spec §0, §5.2): a
    // 2.1 file without it lost it (its ID damaged into an unknown chunk's, say). Likewise 2.2 and
    // images (§7.5).
    if rd.header().major == 2 && rd.header().minor == 1 && !chunks.iter().any(|c| c.id == "GEOR") {
        v.push(Error::invalid(&path, None, "format 2.1 without a GEOR chunk: 2.1 is written only for a file with one (spec §5.2)"));
    }
    let (major, minor) = (rd.header().major, rd.header().minor);
    if major == 2 && minor == 2 && rd.textures().is_empty() && !rd.header().attributes.uvs {
        v.push(Error::invalid(&path, None, "format 2.2 without images or UVs: 2.2 is written only for a file with them (spec §0, §7.5)"));
    }
    if major == 2 && minor < 2 && !rd.textures().is_empty() {
        v.push(Error::invalid(&path, None, format!("a TEXR chunk in a format 2.{minor} file: images are 2.2 (spec §7.5)")));
    }
    let levels: Vec<(u64, u64)> = rd.textures().levels.iter().map(|l| (l.offset, l.size as u64)).collect();
    if texls != levels {
        let k = texls.iter().zip(&levels).position(|(a, b)| a != b).unwrap_or(texls.len().min(levels.len()));
        v.push(Error::at_element(
            &path,
            format!("image level entry {k}"),
            format!("the file holds {} TEXL chunks but TEXR lists {}, first differing at entry {k}", texls.len(), levels.len()),
        ));
    }
    // Every level read, checked and decoded: a file whose images a renderer cannot decode is not
    // sound, whatever its checksums.
    for l in &rd.textures().levels {
        let Some(rec) = rd.textures().images.get(l.image as usize) else { continue };
        match rd.read_image_level(l.image, l.level) {
            Ok(b) => {
                if let Err(e) = super::image::decode(rec.codec, &b) {
                    v.push(Error::at_byte(&path, l.offset, format!("image {} level {}: {e}", l.image, l.level)));
                }
            }
            Err(e) => v.push(e),
        }
    }
    if let Some(last) = chunks.last() {
        let end = last.offset + HEADER_BYTES + last.size + TRAILER_BYTES;
        if end + chunk::padding(end) != rd.file_size() {
            v.push(Error::at_byte(&path, end, format!("the last chunk's padding does not end the {}-byte file", rd.file_size())));
        }
    }
    if rd.header().major >= 3 {
        // Format 3: one GEOS chunk right after SKEL, its payload every node's, back to back.
        let bytes = rd.levels().iter().map(|l| l.bytes).sum::<u64>();
        let want = [(rd.skeleton_end(), bytes)];
        if geos != want || !geoms.is_empty() {
            v.push(Error::at_byte(
                &path,
                rd.skeleton_end(),
                format!(
                    "format 3 holds one GEOS chunk of {bytes} bytes at offset {} and no GEOM; the file has {geos:?} and {} GEOM",
                    rd.skeleton_end(),
                    geoms.len()
                ),
            ));
        }
        return;
    }
    let table: Vec<(u64, u64)> = rd.nodes().iter().map(|n| (n.offset, n.size as u64)).collect();
    if geoms != table {
        let k = geoms.iter().zip(&table).position(|(a, b)| a != b).unwrap_or(geoms.len().min(table.len()));
        v.push(Error::at_element(
            &path,
            format!("node {k}"),
            format!("the file holds {} GEOM chunks but the node table lists {}, first differing at node {k}", geoms.len(), table.len()),
        ));
    }
}

/// Check the CRC of an unknown chunk's payload, reading it in pieces.
fn crc_of<S: ByteSource>(rd: &Reader<S>, id: &str, offset: u64, size: u64) -> Result<()> {
    let mut hasher = crc32fast::Hasher::new();
    let mut done = 0u64;
    while done < size {
        let n = (size - done).min(1 << 20);
        hasher.update(&rd.read_at(offset + HEADER_BYTES + done, n)?);
        done += n;
    }
    let stored = rd.read_at(offset + HEADER_BYTES + size, 4)?;
    let stored = u32::from_le_bytes([stored[0], stored[1], stored[2], stored[3]]);
    let actual = hasher.finalize();
    if stored != actual {
        return Err(Error::at_byte(rd.path(), offset, format!("chunk {id} at offset {offset}: CRC {actual:08x} != stored {stored:08x}")));
    }
    Ok(())
}

/// Read every node's geometry: CRCs, ranges and tiling (by the reader), the node's rules
/// ([`rules::node`]), the cluster count, and level 0 covering every input face exactly once.
fn geometry<S: ByteSource>(rd: &Reader<S>, v: &mut Verification) {
    let path = rd.path().to_path_buf();
    let mut clusters = 0u64;
    let mut seen: HashSet<u128> = HashSet::new();
    let mut duplicates = 0u64;
    let mut sink = Sink::new(MAX_PROBLEMS);
    rules::dag(&path, rd.skeleton(), &mut sink);
    sink.problems.into_iter().for_each(|e| v.push(e));
    for i in 0..rd.nodes().len() as u32 {
        let n = rd.nodes()[i as usize];
        let g = match rd.read_node(i) {
            Ok(g) => g,
            Err(e) => {
                v.push(e);
                continue;
            }
        };
        v.nodes += 1;
        clusters += g.clusters.len() as u64;
        let mut sink = Sink::new(MAX_PROBLEMS);
        rules::relations(&path, rd.skeleton(), i, &mut sink);
        rules::node(&path, i, &n, rd.node_box(i), &g, &mut sink);
        sink.problems.into_iter().for_each(|e| v.push(e));
        if n.level == 0 {
            for t in g.indices.chunks_exact(3) {
                let mut key: Vec<[u32; 3]> = t.iter().map(|&x| g.positions[x as usize].to_array().map(f32::to_bits)).collect();
                key.sort_unstable();
                if !seen.insert(fingerprint(&key)) {
                    duplicates += 1;
                }
            }
        }
    }
    if duplicates > 0 {
        v.push(Error::at_element(&path, "level 0", format!("{duplicates} faces appear more than once")));
    }
    if clusters != rd.header().clusters as u64 {
        v.push(Error::at_element(&path, "level 0", format!("nodes hold {clusters} clusters, HEAD says {}", rd.header().clusters)));
    }
}

/// A 128-bit fingerprint of a face's sorted corner positions.
fn fingerprint(key: &[[u32; 3]]) -> u128 {
    let mut a = DefaultHasher::new();
    key.hash(&mut a);
    let mut b = DefaultHasher::new();
    (key, 0x5bd1_e995u32).hash(&mut b);
    (a.finish() as u128) << 64 | b.finish() as u128
}
