//! Damaged files: every flipped byte is reported by `verify`, every truncation is an error, counts
//! and sizes set to huge values are refused before anything that large is allocated, and no damage
//! makes the reader, the assembler or `inspect` panic.

mod common;

use common::{icosphere, written_as};
use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Cursor;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use strata::format::{self, inspect, Reader};
use strata::hierarchy::HierarchyParams;
use strata::write::{Encoding, Precision};

/// Records the largest single allocation of the test process.
struct Watch;

static LARGEST: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Watch {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        LARGEST.fetch_max(l.size(), Ordering::Relaxed);
        unsafe { System.alloc(l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        LARGEST.fetch_max(l.size(), Ordering::Relaxed);
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        unsafe { System.realloc(p, l, new_size) }
    }
}

#[global_allocator]
static WATCH: Watch = Watch;

/// No allocation in these tests needs more than this.
const ALLOCATION_LIMIT: usize = 64 << 20;

/// A small file with every attribute, several levels and nodes, in the format of `encoding`.
fn small_file(encoding: Encoding) -> Vec<u8> {
    let params = HierarchyParams { cluster_faces: 6, leaf_faces: 20, growth: 2, top_groups: 2, ..HierarchyParams::default() };
    let (bytes, summary) = written_as(&icosphere(1), &params, encoding);
    assert!(summary.levels.len() >= 2 && summary.nodes >= 6, "{summary:?}");
    bytes
}

/// The small file, and the terrain and textured golden vectors, whose `GEOR` chunk (format 2.1)
/// and `TEXR` and `TEXL` chunks (2.2) get the same damage.
fn damage_targets() -> Vec<(&'static str, Vec<u8>)> {
    let vector = |name: &str| std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("format-spec/vectors").join(name)).expect(name);
    vec![
        ("small", small_file(Encoding::V2)),
        ("small-v3", small_file(Encoding::V3(Precision::default()))),
        ("terrain", vector("terrain.strata")),
        ("textured", vector("textured.strata")),
    ]
}

/// Open with the skeleton decoded in part (`Reader::open_top`), read the top level's nodes and
/// try the others (refused where their records or their children's are not decoded yet), then
/// complete it and read every node.
fn read_top_first(bytes: &[u8]) -> strata::error::Result<()> {
    let mut rd = Reader::open_top(Cursor::new(bytes), Path::new("top first"))?;
    let top = rd.level_nodes(rd.levels().len() as u32 - 1);
    for i in 0..rd.skeleton().header.nodes {
        let read = rd.read_node(i);
        let decoded = (i as usize) < rd.nodes().len() && rd.skeleton().children(i).end as usize <= rd.nodes().len();
        if top.contains(&i) {
            read?;
        } else if !decoded {
            assert!(read.is_err(), "node {i} read before its records were decoded");
        }
    }
    rd.complete()?;
    (0..rd.nodes().len() as u32).try_for_each(|i| rd.read_node(i).map(|_| ()))
}

/// Exercise every reading path; results are ignored, panics are not.
fn read_everything(bytes: &[u8]) {
    let _ = read_top_first(bytes);
    if let Ok(rd) = Reader::open(Cursor::new(bytes)) {
        for i in 0..rd.nodes().len() as u32 {
            let _ = rd.read_node(i);
            let _ = rd.node_chunks(i);
        }
        for l in 0..rd.levels().len() as u32 {
            let _ = strata::assemble::to_mesh(&rd, l);
        }
        for l in &rd.textures().levels {
            let _ = rd.read_image_level(l.image, l.level);
        }
        let all: Vec<u32> = (0..rd.textures().images.len() as u32).collect();
        let _ = strata::texture::draw::read_chains(&rd, &all, &mut Vec::new());
        let _ = rd.chunks();
        let select = inspect::Selection { depth: Some(9), level: Some(0), node: Some(0) };
        let _ = inspect::inspect(&rd, select);
    }
}

#[test]
fn every_flipped_byte_is_reported() {
    for (name, good) in damage_targets() {
        assert!(format::verify(Cursor::new(&good), Path::new("good")).is_sound(), "{name}");
        let mut bytes = good.clone();
        for at in 0..good.len() {
            for mask in [0xFFu8, 0x01] {
                bytes[at] ^= mask;
                let v = format::verify(Cursor::new(&bytes), Path::new("flipped"));
                assert!(!v.is_sound(), "{name}: flipping byte {at} with {mask:#x} went unnoticed");
                read_everything(&bytes);
                bytes[at] ^= mask;
            }
        }
    }
    assert!(LARGEST.load(Ordering::Relaxed) < ALLOCATION_LIMIT);
}

#[test]
fn every_truncation_is_an_error() {
    for (name, good) in damage_targets() {
        for len in 0..good.len() {
            let cut = &good[..len];
            assert!(Reader::open(Cursor::new(cut)).is_err(), "{name}: truncated to {len} bytes and still opened");
            assert!(Reader::open_top(Cursor::new(cut), Path::new("cut")).is_err(), "{name}: truncated to {len} bytes, opened top first");
            assert!(!format::verify(Cursor::new(cut), Path::new("cut")).is_sound(), "{name}");
            read_everything(cut);
        }
    }
}

/// Recompute the CRC of the chunk whose ID is at `at`.
fn reseal(bytes: &mut [u8], at: usize) {
    let size = u64::from_le_bytes(bytes[at + 8..at + 16].try_into().expect("8 bytes")) as usize;
    let crc = crc32fast::hash(&bytes[at + 16..at + 16 + size]);
    bytes[at + 16 + size..at + 20 + size].copy_from_slice(&crc.to_le_bytes());
}

/// Offsets of the chunks read at open, by ID.
fn offsets(bytes: &[u8]) -> impl Fn(&str) -> usize {
    let rd = Reader::open(Cursor::new(bytes)).expect("open");
    let chunks = rd.skeleton_chunks().to_vec();
    move |id: &str| chunks.iter().find(|c| c.id == id).expect("chunk present").offset as usize
}

/// Patch `value` at `at`, reseal the chunks at `seal` (innermost first), and return the error of
/// opening the file and reading every node.
fn damaged(good: &[u8], at: usize, value: &[u8], seal: &[usize]) -> String {
    let mut bytes = good.to_vec();
    bytes[at..at + value.len()].copy_from_slice(value);
    for &s in seal {
        reseal(&mut bytes, s);
    }
    let before = LARGEST.load(Ordering::Relaxed);
    let result = Reader::open(Cursor::new(&bytes)).and_then(|rd| {
        for i in 0..rd.nodes().len() as u32 {
            rd.read_node(i)?;
        }
        Ok(())
    });
    assert!(LARGEST.load(Ordering::Relaxed) < ALLOCATION_LIMIT.max(before), "a huge allocation was attempted");
    match result {
        Ok(()) => panic!("patching {value:?} at {at} went unnoticed"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn huge_counts_and_sizes_are_refused_without_huge_allocations() {
    let good = small_file(Encoding::V2);
    let at = offsets(&good);
    let (head, skel, node, nbrs) = (at("HEAD"), at("SKEL"), at("NODE"), at("NBRS"));
    let max16 = u16::MAX.to_le_bytes();
    let max32 = u32::MAX.to_le_bytes();
    let max64 = u64::MAX.to_le_bytes();
    let hp = head + 16;
    // (what, where, new bytes, chunks to reseal, expected in the message)
    type Case = (&'static str, usize, Vec<u8>, Vec<usize>, &'static str);
    let cases: Vec<Case> = vec![
        ("HEAD levels", hp + 44, max32.to_vec(), vec![head], "levels"),
        ("HEAD nodes", hp + 48, max32.to_vec(), vec![head], "nodes"),
        ("HEAD nodes - 1", hp + 48, (u32::MAX - 1).to_le_bytes().to_vec(), vec![head], "HEAD says"),
        ("HEAD materials", hp + 52, max32.to_vec(), vec![head], "MATL"),
        ("HEAD tool length", hp + 156, max32.to_vec(), vec![head], "tool string"),
        ("HEAD grid bits", hp + 152, max32.to_vec(), vec![head], "grid"),
        ("HEAD size", head + 8, max64.to_vec(), vec![], "HEAD"),
        ("SKEL size", skel + 8, max64.to_vec(), vec![], "SKEL"),
        ("NODE size", node + 8, max64.to_vec(), vec![skel], "NODE"),
        ("NBRS size", nbrs + 8, (u32::MAX as u64).to_le_bytes().to_vec(), vec![skel], "NBRS"),
        ("node 0 child count", node + 16, max16.to_vec(), vec![node, skel], "children"),
        ("node 0 neighbour count", node + 16 + 2, max16.to_vec(), vec![node, skel], "neighbours"),
        ("node 0 box min", node + 16 + 12, max64.to_vec(), vec![node, skel], "grid"),
        ("node 0 faces", node + 16 + 40, max32.to_vec(), vec![node, skel], "LEVL says"),
        ("node 0 vertices", node + 16 + 44, max32.to_vec(), vec![node, skel], "LEVL says"),
        ("node 0 size", node + 16 + 48, max32.to_vec(), vec![node, skel], "geometry"),
    ];
    for (what, pos, value, seal, expect) in cases {
        let msg = damaged(&good, pos, &value, &seal);
        assert!(msg.contains(expect), "{what}: {msg}");
        let located = msg.contains("byte offset") || msg.contains("level ");
        assert!(located, "{what}: the error names no byte offset or level: {msg}");
    }

    // A sub-chunk of node 0's geometry claiming a huge size: GEOM and the node table resealed.
    let rd = Reader::open(Cursor::new(&good)).expect("open");
    let geom = rd.nodes()[0].offset as usize;
    let mut bytes = good.clone();
    bytes[geom + 16 + 8..geom + 16 + 16].copy_from_slice(&max64);
    reseal(&mut bytes, geom);
    let size = u64::from_le_bytes(bytes[geom + 8..geom + 16].try_into().expect("8 bytes")) as usize;
    let crc = bytes[geom + 16 + size..geom + 20 + size].to_vec();
    let msg = damaged(&bytes, node + 16 + 52, &crc, &[node, skel]);
    assert!(msg.contains("VPOS") && msg.contains("parent has"), "{msg}");
}

/// A node box that is on the grid but too small to hold its children's is refused by the reader
/// as it reads the node, and listed by `verify`.
#[test]
fn a_shrunken_node_box_is_refused_by_the_reader_and_verify() {
    let good = small_file(Encoding::V2);
    let at = offsets(&good);
    let (skel, node) = (at("SKEL"), at("NODE"));
    let mut bytes = good.clone();
    let min = bytes[node + 16 + 12..node + 16 + 20].to_vec();
    bytes[node + 16 + 20..node + 16 + 28].copy_from_slice(&min);
    reseal(&mut bytes, node);
    reseal(&mut bytes, skel);
    let rd = Reader::open(Cursor::new(&bytes)).expect("a box on the grid opens");
    let e = rd.read_node(0).expect_err("the reader checks node 0's box as it reads node 0").to_string();
    assert!(e.contains("node 0") && e.contains("box"), "{e}");
    let v = format::verify(Cursor::new(&bytes), Path::new("shrunk"));
    assert!(v.problems.iter().any(|e| e.to_string().contains("node 0") && e.to_string().contains("box")), "{:?}", v.problems);
}

/// Recompute every CRC of a file whose payload bytes (not frames) were changed: sub-chunks, then
/// `GEOM` chunks and the node table's copies of their CRCs, then `NODE` and `SKEL`.
fn reseal_all(bytes: &mut [u8], good: &Reader<Cursor<&Vec<u8>>>) {
    let frame_size = |b: &[u8], at: usize| u64::from_le_bytes(b[at + 8..at + 16].try_into().expect("8 bytes")) as usize;
    let subs = |b: &mut [u8], parent: usize| {
        let (start, end) = (parent + 16, parent + 16 + frame_size(b, parent));
        let mut at = start;
        while at < end {
            reseal(b, at);
            let after = at + 20 + frame_size(b, at);
            at = after + (8 - after % 8) % 8;
        }
    };
    let node_at = good.skeleton_chunks().iter().find(|c| c.id == "NODE").expect("NODE").offset as usize;
    let skel_at = good.skeleton_chunks().iter().find(|c| c.id == "SKEL").expect("SKEL").offset as usize;
    for (i, n) in good.nodes().iter().enumerate() {
        let at = n.offset as usize;
        subs(bytes, at);
        reseal(bytes, at);
        let size = frame_size(bytes, at);
        let crc: [u8; 4] = bytes[at + 16 + size..at + 20 + size].try_into().expect("4 bytes");
        let field = node_at + 16 + 56 * i + 52;
        bytes[field..field + 4].copy_from_slice(&crc);
    }
    reseal(bytes, node_at);
    reseal(bytes, skel_at);
}

/// Whether a problem is one only the whole file can show (spec §6, `format::rules`).
fn whole_file_only(problem: &str) -> bool {
    ["appear more than once", "clusters, HEAD says"].iter().any(|p| problem.contains(p))
}

/// With every checksum recomputed, any change to a node record or to a node's geometry that
/// `verify` refuses is refused by the reader as it opens the file or decodes the node, and the
/// reader refuses nothing that `verify` accepts.
#[test]
fn readers_refuse_what_verify_refuses_node_by_node() {
    let good = small_file(Encoding::V2);
    let rd = Reader::open(Cursor::new(&good)).expect("open");
    let node_at = rd.skeleton_chunks().iter().find(|c| c.id == "NODE").expect("NODE").offset as usize;
    let mut targets: Vec<usize> = (node_at + 16..node_at + 16 + 56 * rd.nodes().len()).collect();
    for n in rd.nodes() {
        let (start, end) = (n.offset as usize + 16, n.offset as usize + n.size as usize - 4);
        let mut at = start;
        while at < end {
            let size = u64::from_le_bytes(good[at + 8..at + 16].try_into().unwrap()) as usize;
            targets.extend(at + 16..at + 16 + size);
            let after = at + 20 + size;
            at = after + (8 - after % 8) % 8;
        }
    }
    let (mut refused, mut accepted) = (0, 0);
    for &at in &targets {
        for mask in [0x01u8, 0x80, 0xFF] {
            let mut bytes = good.clone();
            bytes[at] ^= mask;
            reseal_all(&mut bytes, &rd);
            let v = format::verify(Cursor::new(&bytes), Path::new("mutated"));
            let node_rules: Vec<String> = v.problems.iter().map(|e| e.to_string()).filter(|p| !whole_file_only(p)).collect();
            let strict =
                Reader::open(Cursor::new(&bytes)).and_then(|r| (0..r.nodes().len() as u32).try_for_each(|i| r.read_node(i).map(|_| ())));
            let top_first = read_top_first(&bytes);
            assert_eq!(top_first.is_ok(), strict.is_ok(), "byte {at} ^ {mask:#x}: top first {top_first:?}, whole {strict:?}");
            match (&strict, node_rules.is_empty()) {
                (Ok(()), false) => panic!("byte {at} ^ {mask:#x}: verify found {node_rules:?} but the reader accepted the file"),
                (Err(e), true) => panic!("byte {at} ^ {mask:#x}: the reader refused ({e}) what verify accepts ({:?})", v.problems),
                (Err(_), false) => refused += 1,
                (Ok(()), true) => accepted += 1,
            }
        }
    }
    println!("{refused} refused, {accepted} accepted");
    assert!(refused > 1000 && accepted > 100, "{refused} refused, {accepted} accepted of {} changes", 3 * targets.len());
}
