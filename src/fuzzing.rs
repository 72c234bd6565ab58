//! Arbitrary bytes through every reading path, for the cargo-fuzz targets in `fuzz/` and the
//! bounded mutation test `tests/fuzz_inputs.rs`. Errors are the expected outcome and are ignored;
//! a panic, a hang or an allocation out of proportion to the input is a bug.
//!
//! Nothing else in the library uses this module.

use crate::format::{self, inspect, Reader};
use crate::import::{import, Imported};
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

/// How far [`read_everything`] got.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Reached {
    /// The strict reader opened the bytes.
    pub opened: bool,
    /// Nodes it decoded.
    pub nodes_decoded: usize,
    /// `verify` found no problem.
    pub sound: bool,
}

/// Open `bytes` as a chunk file with the strict reader and use everything it offers: every node's
/// geometry and sub-chunks, every level as one mesh, the chunk walk, `inspect` with each kind of
/// selection, the full dump; then `verify` the same bytes (which reads nodes without their rules and
/// so reaches further into damaged files).
pub fn read_everything(bytes: &[u8]) -> Reached {
    let mut reached = Reached::default();
    if let Ok(rd) = Reader::open(Cursor::new(bytes)) {
        reached.opened = true;
        let nodes = rd.nodes().len() as u32;
        for i in 0..=nodes {
            reached.nodes_decoded += rd.read_node(i).is_ok() as usize;
            let _ = rd.node_chunks(i);
        }
        let levels = rd.levels().len() as u32;
        for l in 0..=levels {
            let _ = crate::assemble::to_mesh(&rd, l);
        }
        for l in &rd.textures().levels {
            if let (Ok(b), Some(im)) = (rd.read_image_level(l.image, l.level), rd.textures().images.get(l.image as usize)) {
                let _ = crate::texture::decode(im.codec, &b);
            }
        }
        // Hostile UVs and images through the textured renderer.
        let all: Vec<u32> = (0..rd.textures().images.len() as u32).collect();
        let chains = crate::texture::draw::read_chains(&rd, &all, &mut Vec::new());
        let (lo, hi) = (rd.header().min, rd.header().max);
        let camera = crate::camera::Camera::framing((lo + hi) * 0.5, (hi - lo).length().max(1e-3), glam::Vec3::ONE, 1.0, 16, 16);
        let mut image = crate::render::Image::new(16, 16);
        for i in 0..nodes.min(64) {
            if let Ok(g) = rd.read_node(i) {
                let parts = crate::texture::draw::node_parts(&g, rd.materials(), &|k| chains.get(k as usize)?.as_ref());
                image.draw_parts(&camera, &parts);
            }
        }
        let _ = rd.chunks();
        let selections = [
            inspect::Selection { depth: Some(u32::MAX), level: None, node: None },
            inspect::Selection { depth: None, level: Some(0), node: Some(0) },
            inspect::Selection { depth: Some(1), level: Some(levels.saturating_sub(1)), node: Some(nodes.saturating_sub(1)) },
            inspect::Selection { depth: None, level: Some(levels), node: Some(nodes) },
        ];
        for select in selections {
            let _ = inspect::inspect(&rd, select);
        }
        let _ = inspect::dump(&rd);
    }
    reached.sound = format::verify(Cursor::new(bytes), Path::new("<fuzz>")).is_sound();
    // Top first (format 3.1: the top pages, then the rest): the same file accepted or refused,
    // and once complete, the same node table.
    let whole = Reader::open(Cursor::new(bytes));
    let top = Reader::open_top(Cursor::new(bytes), Path::new("<fuzz>")).and_then(|mut rd| {
        for i in top_level(&rd) {
            rd.read_node(i)?;
        }
        rd.complete()?;
        Ok(rd)
    });
    match (&whole, &top) {
        (Ok(a), Ok(b)) => assert_eq!(a.nodes(), b.nodes(), "opened whole and top first, the node tables differ"),
        (Ok(_), Err(e)) => {
            // Opened whole, a top-level node may still break its rules (read_node checks them).
            let a = whole.as_ref().unwrap();
            assert!(top_level(a).any(|i| a.read_node(i).is_err()), "opened whole, refused top first: {e}");
        }
        (Err(e), Ok(_)) => panic!("refused whole, opened top first: {e}"),
        (Err(_), Err(_)) => {}
    }
    reached
}

/// The nodes of `rd`'s top level (none without levels).
fn top_level<S: crate::format::ByteSource>(rd: &Reader<S>) -> std::ops::Range<u32> {
    rd.levels().len().checked_sub(1).map_or(0..0, |t| rd.level_nodes(t as u32))
}

/// [`reseal`] the bytes, then [`read_everything`].
pub fn read_everything_resealed(bytes: &[u8]) -> Reached {
    let mut b = bytes.to_vec();
    reseal(&mut b);
    read_everything(&b)
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at.checked_add(8)?)?.try_into().ok()?))
}

/// The chunk at `at` (ID, flags, size, payload, CRC): its payload range, if it lies in `b`.
fn payload(b: &[u8], at: usize) -> Option<(usize, usize)> {
    let size = usize::try_from(u64_at(b, at + 8)?).ok()?;
    let start = at + 16;
    let end = start.checked_add(size)?;
    (end.checked_add(4)? <= b.len()).then_some((start, end))
}

/// Recompute the CRC of the chunk at `at`; its payload range.
fn reseal_chunk(b: &mut [u8], at: usize) -> Option<(usize, usize)> {
    let (s, e) = payload(b, at)?;
    let crc = crc32fast::hash(&b[s..e]);
    b[e..e + 4].copy_from_slice(&crc.to_le_bytes());
    Some((s, e))
}

/// The chunks inside a payload (sub-chunks), by offset.
fn subs(b: &[u8], (start, end): (usize, usize)) -> Vec<usize> {
    let mut out = Vec::new();
    let mut at = start;
    while at + 20 <= end {
        let Some((_, e)) = payload(b, at) else { break };
        if e + 4 > end {
            break;
        }
        out.push(at);
        let after = e + 4;
        at = after + (8 - after % 8) % 8;
    }
    out
}

/// Make a damaged chunk file consistent again where that is easy, so that the damage reaches the
/// decoding behind the checksums (the `reader_sealed` fuzz target, `tests/fuzz_inputs.rs`): the
/// prologue CRC, `HEAD`'s file size, every sub-chunk's, `GEOM` chunk's and top-level chunk's CRC,
/// and the node table's copies of the `GEOM` CRCs (format 3: of each node's payload in `GEOS`, as
/// the node table's sizes lay them out). Best effort: stops where a frame runs past the end.
pub fn reseal(b: &mut [u8]) {
    if b.len() < 16 {
        return;
    }
    let crc = crc32fast::hash(&b[..12]);
    b[12..16].copy_from_slice(&crc.to_le_bytes());
    let mut tops = Vec::new();
    let mut at = 16;
    while let Some((_, e)) = payload(b, at) {
        tops.push(at);
        let after = e + 4;
        at = after + (8 - after % 8) % 8;
    }
    // Where each node's record starts, in node order: in NODE (format 2), or in the NODL pages, each
    // as many records as LEVL gives its level, from the top (format 3).
    let mut records: Vec<usize> = Vec::new();
    let mut geom_crcs = Vec::new();
    let mut geos = None;
    for &top in &tops {
        let Some(range) = payload(b, top) else { continue };
        let id = [b[top], b[top + 1], b[top + 2], b[top + 3]];
        if &id == b"HEAD" && range.1 - range.0 >= 8 {
            let len = b.len() as u64;
            b[range.0..range.0 + 8].copy_from_slice(&len.to_le_bytes());
        }
        if &id == b"SKEL" || &id == b"GEOM" {
            let mut counts: Vec<usize> = Vec::new();
            for sub in subs(b, range) {
                let (sid, p) = (&b[sub..sub + 4], payload(b, sub));
                match (&id, sid, p) {
                    (b"SKEL", b"LEVL", Some((s, e))) => {
                        counts = (s..e.saturating_sub(31)).step_by(32).map(|r| u32_at(b, r + 4) as usize).collect()
                    }
                    (b"SKEL", b"NODE", Some((s, e))) => records.extend((s..e.saturating_sub(55)).step_by(56)),
                    (b"SKEL", b"NODL", Some((s, e))) => {
                        let n = counts.pop().unwrap_or(0);
                        records.extend((s..e.saturating_sub(55)).step_by(56).take(n));
                    }
                    _ => {}
                }
                reseal_chunk(b, sub);
            }
        }
        reseal_chunk(b, top);
        if &id == b"GEOM" {
            geom_crcs.push(b[range.1..range.1 + 4].to_vec());
        }
        if &id == b"GEOS" {
            geos = Some(range);
        }
    }
    if let Some((g, g_end)) = geos {
        let mut at = g;
        for &field in &records {
            let size = u32_at(b, field + 48) as usize;
            let Some(end) = at.checked_add(size).filter(|&x| x <= g_end) else { break };
            geom_crcs.push(crc32fast::hash(&b[at..end]).to_le_bytes().to_vec());
            at = end;
        }
    }
    if !records.is_empty() {
        for (&field, crc) in records.iter().zip(&geom_crcs) {
            b[field + 52..field + 56].copy_from_slice(crc);
        }
        // The node table changed: reseal NODE or the NODL pages, and SKEL, again.
        for &top in &tops {
            if &b[top..top + 4] != b"SKEL" {
                continue;
            }
            if let Some(range) = payload(b, top) {
                for sub in subs(b, range) {
                    if &b[sub..sub + 4] == b"NODE" || &b[sub..sub + 4] == b"NODL" {
                        reseal_chunk(b, sub);
                    }
                }
                reseal_chunk(b, top);
            }
        }
    }
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// A folder of this process for mesh files to import: in `/dev/shm` when it exists, else in the
/// temporary folder. Removed when dropped; folders of dead processes are removed when a new one is
/// made.
pub struct ImportDir {
    dir: PathBuf,
}

/// Extensions [`ImportDir::import`] writes.
const EXTENSIONS: [&str; 8] = ["obj", "ply", "gltf", "glb", "asc", "tif", "hgt", "png"];

impl ImportDir {
    pub fn new() -> std::io::Result<ImportDir> {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let shm = Path::new("/dev/shm");
        let base = if shm.is_dir() { shm.to_path_buf() } else { std::env::temp_dir() };
        remove_stale(&base);
        let pid = std::process::id();
        let dir = base.join(format!("strata-fuzz-{pid}-{}", NEXT.fetch_add(1, Ordering::Relaxed)));
        std::fs::create_dir_all(&dir)?;
        Ok(ImportDir { dir })
    }

    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// Write `bytes` to `input.<ext>` in the folder and import it with [`import`] (format by
    /// extension). The other `input.*` files are left empty, so that a file naming one of them (a
    /// glTF buffer URI, an OBJ material library) reads the same thing on every run; files are
    /// overwritten in place rather than created anew, so that the importer's list of protected
    /// inputs ([`crate::atomic::protect`]) does not grow.
    pub fn import(&self, bytes: &[u8], ext: &str) -> crate::Result<Imported> {
        for other in EXTENSIONS.iter().filter(|&&e| e != ext) {
            let p = self.dir.join(format!("input.{other}"));
            if std::fs::metadata(&p).is_ok_and(|m| m.len() > 0) {
                std::fs::write(&p, b"").map_err(|e| crate::Error::io(&p, e))?;
            }
        }
        let path = self.dir.join(format!("input.{ext}"));
        std::fs::write(&path, bytes).map_err(|e| crate::Error::io(&path, e))?;
        import(&path, None)
    }
}

impl Drop for ImportDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Remove `strata-fuzz-<pid>-<n>` folders in `base` whose process is gone (Linux: no `/proc/<pid>`).
fn remove_stale(base: &Path) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(base) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix("strata-fuzz-")) else { continue };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else { continue };
        if !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// Import `bytes` as a glTF file: `.glb` when they start with the GLB magic, else `.gltf`.
pub fn import_gltf(dir: &ImportDir, bytes: &[u8]) -> crate::Result<Imported> {
    dir.import(bytes, if bytes.starts_with(b"glTF") { "glb" } else { "gltf" })
}
