//! The worked example of format-spec/strata-v3.md §7, built byte by byte from the spec's rules
//! alone — chunk frames, the coding tables, the rANS coder and the node payload are this file's
//! own code, not the writer's: strata's reader must decode the unit square it describes, `verify`
//! must find it sound, and damage to any byte of the payload must be refused.

use std::io::Cursor;
use strata::format::{self, Reader};

const SPEC: &str = include_str!("../format-spec/strata-v3.md");

/// The example's grid: 20 bits, step 2^−19 (as strata-v2.md §9), so 1.0 is grid coordinate 2^19.
const STEP: f64 = 1.0 / (1u64 << 19) as f64;
const ONE: u64 = 1 << 19;
const HALF: u64 = 1 << 18;
/// Radius code of the node's sphere: 1537 · 2^8 steps (strata-v2.md §9).
const RADIUS: u16 = 1537 | 8 << 11;

/// Alphabets of strata-v3.md §4.2 that the example uses.
const COUNT: usize = 11;
const START: usize = 8;
const CORNER: usize = 9;
const CONN_FIRST: usize = 7;
const CONN_AFTER_BOUNDARY: usize = 5;
const POS_JUMP: usize = 13;
/// `POS_BORDER + 20`: the gate triangle of vertex 3 spans 2^19 steps, 20 bits.
const POS_BORDER_20: usize = 42 + 20;

/// Symbols and raw bits in the order a reader decodes them (§5), with a note each.
#[derive(Default)]
struct Stream {
    symbols: Vec<(usize, u32)>,
    bits: Vec<bool>,
    notes: Vec<String>,
}

impl Stream {
    fn symbol(&mut self, alphabet: usize, s: u32, note: &str) {
        self.symbols.push((alphabet, s));
        self.notes.push(note.to_string());
    }

    /// A value (§4.3): its symbol, then its raw bits, most significant first.
    fn value(&mut self, alphabet: usize, u: u32, note: &str) {
        if u < 4 {
            return self.symbol(alphabet, u, note);
        }
        let b = 32 - u.leading_zeros();
        let top = (u >> (b - 2)) & 1;
        self.symbol(alphabet, 4 + 2 * (b - 3) + top, note);
        for k in (0..b - 2).rev() {
            self.bits.push((u >> k) & 1 == 1);
        }
    }

    fn signed(&mut self, alphabet: usize, v: i32, note: &str) {
        self.value(alphabet, ((v << 1) ^ (v >> 31)) as u32, note);
    }
}

/// Frequencies of the example's tables (§3): each adds up to 2048, none above 2016.
fn tables() -> Vec<Vec<u16>> {
    let mut t = vec![Vec::new(); 64];
    t[COUNT] = vec![2016, 32];
    t[START] = vec![2016, 32];
    t[CORNER] = vec![2016, 32];
    t[CONN_FIRST] = vec![1024, 0, 0, 0, 0, 1024];
    t[CONN_AFTER_BOUNDARY] = vec![1024, 0, 0, 0, 0, 1024];
    let mut jump = vec![0u16; 41];
    (jump[0], jump[37], jump[40]) = (1000, 524, 524);
    t[POS_JUMP] = jump;
    t[POS_BORDER_20] = vec![2016, 32];
    t
}

/// rANS as §4.1 specifies it, written here from the spec: symbols last to first from the state
/// 2^23, bytes pushed out low first while the state is at least `(2^23 >> 11 << 8)·f`; then the
/// final state, and everything reversed, so that a reader finds the state first.
fn rans(symbols: &[(usize, u32)], tables: &[Vec<u16>]) -> Vec<u8> {
    let mut x: u64 = 1 << 23;
    let mut out = Vec::new();
    for &(a, s) in symbols.iter().rev() {
        let f = tables[a][s as usize] as u64;
        let c: u64 = tables[a][..s as usize].iter().map(|&v| v as u64).sum();
        while x >= ((1u64 << 23) >> 11 << 8) * f {
            out.push(x as u8);
            x >>= 8;
        }
        x = (x / f) * 2048 + x % f + c;
    }
    out.extend_from_slice(&(x as u32).to_be_bytes());
    out.reverse();
    out
}

/// The node payload of §7: the unit square's two triangles, four vertices.
fn payload() -> (Vec<u8>, Stream) {
    let mut s = Stream::default();
    s.value(COUNT, 0, "one material range");
    s.value(COUNT, 0, "material 0");
    s.value(COUNT, 0, "one cluster");
    s.value(START, 0, "a new triangle");
    for k in 0..3 {
        s.value(CORNER, 0, &format!("corner {k}: new vertex {k}"));
    }
    s.symbol(CONN_FIRST, 5, "gate 0→1: BOUNDARY");
    s.symbol(CONN_AFTER_BOUNDARY, 5, "gate 1→2: BOUNDARY");
    s.symbol(CONN_AFTER_BOUNDARY, 0, "gate 2→0: VERTEX 3, triangle (0, 2, 3)");
    let half = HALF as i32;
    let one = ONE as i32;
    // Vertex 0 from the middle of the box, 1 from 0, 2 from 1; 3 by the parallelogram 2 + 0 − 1.
    for (v, r, alphabet) in
        [(0, [-half, -half, 0], POS_JUMP), (1, [one, 0, 0], POS_JUMP), (2, [0, one, 0], POS_JUMP), (3, [0, 0, 0], POS_BORDER_20)]
    {
        for (k, axis) in ["x", "y", "z"].iter().enumerate() {
            s.signed(alphabet, r[k], &format!("vertex {v} {axis} residual {}", r[k]));
        }
    }
    let stream = rans(&s.symbols, &tables());
    let mut p = vec![];
    let mut n = stream.len();
    loop {
        let b = (n & 0x7F) as u8;
        n >>= 7;
        p.push(if n > 0 { b | 0x80 } else { b });
        if n == 0 {
            break;
        }
    }
    p.extend_from_slice(&stream);
    let mut raw = vec![0u8; s.bits.len().div_ceil(8)];
    for (k, &bit) in s.bits.iter().enumerate() {
        raw[k / 8] |= (bit as u8) << (7 - k % 8);
    }
    p.extend_from_slice(&raw);
    (p, s)
}

/// A chunk: ID, flags, size, payload, CRC-32, zero padding to a multiple of 8.
fn chunk(out: &mut Vec<u8>, id: &[u8; 4], flags: u32, payload: &[u8]) {
    out.extend_from_slice(id);
    out.extend_from_slice(&flags.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(payload);
    out.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    out.resize(out.len().next_multiple_of(8), 0);
}

/// The whole file of §7, of minor version 1 (or with `minor` 0, its node table as format 3.0's
/// `NODE` and `NBRS`, §0).
fn file() -> Vec<u8> {
    file_of(1)
}

fn file_of(minor: u16) -> Vec<u8> {
    file_with(minor, None)
}

/// [`file_of`] with one more sub-chunk of SKEL at its end, after the node table.
fn file_with(minor: u16, last: Option<(&[u8; 4], u32, &[u8])>) -> Vec<u8> {
    let (node, _) = payload();
    let p = strata::hierarchy::HierarchyParams::default();
    let mut head = Vec::new();
    head.extend_from_slice(&0u64.to_le_bytes()); // file size, patched below
    head.extend_from_slice(&1f64.to_le_bytes());
    for v in [0f32, 0.0, 0.0, 1.0, 1.0, 0.0] {
        head.extend_from_slice(&v.to_le_bytes());
    }
    for v in [0u32, 1, 1, 1] {
        head.extend_from_slice(&v.to_le_bytes()); // attributes, levels, nodes, materials
    }
    head.extend_from_slice(&4u64.to_le_bytes());
    head.extend_from_slice(&2u64.to_le_bytes());
    head.extend_from_slice(&1u32.to_le_bytes()); // clusters
    head.extend_from_slice(&p.cluster_faces.to_le_bytes());
    head.extend_from_slice(&p.cluster_angle.to_le_bytes());
    head.extend_from_slice(&p.leaf_faces.to_le_bytes());
    head.extend_from_slice(&p.leaf_angle.to_le_bytes());
    head.extend_from_slice(&p.angle_step.to_le_bytes());
    head.extend_from_slice(&p.growth.to_le_bytes());
    for v in [p.kc, p.ks, p.kn] {
        head.extend_from_slice(&v.to_le_bytes());
    }
    head.extend_from_slice(&(p.top_groups as u32).to_le_bytes());
    head.extend_from_slice(&0.5f32.to_le_bytes());
    for v in [0f64, 0.0, 0.0, STEP] {
        head.extend_from_slice(&v.to_le_bytes());
    }
    head.extend_from_slice(&20u32.to_le_bytes());
    head.extend_from_slice(&11u32.to_le_bytes());
    head.extend_from_slice(b"strata test");

    let mut skel = Vec::new();
    let mut levl = Vec::new();
    for v in [0u32, 1] {
        levl.extend_from_slice(&v.to_le_bytes());
    }
    for v in [2u64, 4, node.len() as u64] {
        levl.extend_from_slice(&v.to_le_bytes());
    }
    chunk(&mut skel, b"LEVL", 0, &levl);
    let mut rec = Vec::new();
    for v in [0u16, 0, 0, 0, 0, RADIUS] {
        rec.extend_from_slice(&v.to_le_bytes()); // children, neighbours, axis +z, half-angle 0, radius
    }
    for v in [0u64, ONE | ONE << 21, HALF | HALF << 21] {
        rec.extend_from_slice(&v.to_le_bytes()); // box min, box max, sphere center
    }
    rec.extend_from_slice(&((STEP * 3f64.sqrt() / 2.0) as f32).to_le_bytes());
    for v in [2u32, 4, node.len() as u32, crc32fast::hash(&node)] {
        rec.extend_from_slice(&v.to_le_bytes());
    }
    if minor == 0 {
        chunk(&mut skel, b"NODE", 0, &rec);
        chunk(&mut skel, b"NBRS", 2, &[]);
    }
    let mut matl = Vec::new();
    matl.extend_from_slice(&7u32.to_le_bytes());
    matl.extend_from_slice(b"default");
    for v in [0.8f32, 0.8, 0.8, 1.0] {
        matl.extend_from_slice(&v.to_le_bytes());
    }
    matl.extend_from_slice(&0u32.to_le_bytes());
    chunk(&mut skel, b"MATL", 0, &matl);
    let mut code = vec![0u8, 0, 0, 0]; // no normals, no colours, reserved
    code.extend_from_slice(&64u32.to_le_bytes());
    for t in tables() {
        code.extend_from_slice(&(t.len() as u16).to_le_bytes());
        for f in t {
            code.extend_from_slice(&f.to_le_bytes());
        }
    }
    chunk(&mut skel, b"CODE", 0, &code);
    if minor >= 1 {
        // The one level's page (§1.1): its node record, then no neighbour entries (width 2).
        chunk(&mut skel, b"NODL", 2, &rec);
    }
    if let Some((id, flags, payload)) = last {
        chunk(&mut skel, id, flags, payload);
    }

    let mut out = b"\x89STRATA\n".to_vec();
    out.extend_from_slice(&3u16.to_le_bytes());
    out.extend_from_slice(&minor.to_le_bytes());
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    chunk(&mut out, b"HEAD", 0, &head);
    chunk(&mut out, b"SKEL", 0, &skel);
    chunk(&mut out, b"GEOS", 0, &node);
    let len = out.len() as u64;
    out[32..40].copy_from_slice(&len.to_le_bytes());
    // HEAD's CRC again, now that it holds the file size.
    let head_size = u64::from_le_bytes(out[24..32].try_into().unwrap()) as usize;
    let crc = crc32fast::hash(&out[32..32 + head_size]);
    out[32 + head_size..36 + head_size].copy_from_slice(&crc.to_le_bytes());
    out
}

#[test]
fn the_v3_example_of_the_spec_decodes_to_the_unit_square() {
    let bytes = file();
    let rd = Reader::open(Cursor::new(&bytes)).expect("the example opens");
    assert_eq!((rd.header().major, rd.header().minor), (3, 1));
    let g = rd.read_node(0).expect("node 0 decodes");
    let square = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    assert_eq!(g.positions.iter().map(|p| p.to_array()).collect::<Vec<_>>(), square);
    assert_eq!(g.indices, [0, 1, 2, 0, 2, 3]);
    assert_eq!(g.material_ranges, [format::MaterialRange { material: 0, first_index: 0, index_count: 6 }]);
    assert_eq!(g.clusters.iter().map(|c| (c.first_face, c.face_count)).collect::<Vec<_>>(), [(0, 2)]);
    let v = format::verify(Cursor::new(&bytes), std::path::Path::new("example"));
    assert!(v.is_sound(), "{:?}", v.problems);
    // The spec quotes the payload's bytes.
    let (p, _) = payload();
    let hex = |b: &[u8]| b.iter().map(|x| format!("{x:02x}")).collect::<Vec<_>>().join(" ");
    let quoted =
        format!("`{}` (the symbol stream's length), the stream `{}`, and the\nraw bits `{}`", hex(&p[..1]), hex(&p[1..7]), hex(&p[7..]));
    assert!(SPEC.contains(&quoted), "strata-v3.md §7 should quote {quoted}");
    if std::env::var("STRATA_PRINT_EXAMPLE").is_ok() {
        let (p, s) = payload();
        println!("payload ({} bytes): {:02x?}", p.len(), p);
        for ((a, sym), note) in s.symbols.iter().zip(&s.notes) {
            println!("alphabet {a:2} symbol {sym:2}  {note}");
        }
    }
}

#[test]
fn a_format_3_0_file_with_node_and_nbrs_reads_as_3_1() {
    let (new, old) = (file_of(1), file_of(0));
    let read = |b: &[u8]| {
        let rd = Reader::open(Cursor::new(b)).expect("opens");
        assert_eq!(rd.nodes().len(), 1);
        rd.read_node(0).expect("node 0 decodes")
    };
    let (a, b) = (read(&new), read(&old));
    assert_eq!((a.positions, a.indices), (b.positions, b.indices));
    assert!(format::verify(Cursor::new(&old), std::path::Path::new("3.0")).is_sound());
    // Each version's node table is its own: 3.1 with NODE and NBRS, or 3.0 with NODL, is refused.
    let mut swapped = old.clone();
    swapped[10] = 1;
    let crc = crc32fast::hash(&swapped[..12]);
    swapped[12..16].copy_from_slice(&crc.to_le_bytes());
    let e = Reader::open(Cursor::new(&swapped)).err().expect("3.1 with NODE refused").to_string();
    assert!(e.contains("NODE") && e.contains("NODL"), "{e}");
    let mut swapped = new.clone();
    swapped[10] = 0;
    let crc = crc32fast::hash(&swapped[..12]);
    swapped[12..16].copy_from_slice(&crc.to_le_bytes());
    let e = Reader::open(Cursor::new(&swapped)).err().expect("3.0 without NODE refused").to_string();
    assert!(e.contains("holds a NODL page"), "{e}");
}

/// Both ways of opening: whole, and top first (`Reader::open_top`, then `complete` and a node read).
fn both_opens(b: &[u8]) -> [std::result::Result<(), String>; 2] {
    let whole = Reader::open(Cursor::new(b)).and_then(|r| r.read_node(0).map(|_| ())).map_err(|e| e.to_string());
    let top = Reader::open_top(Cursor::new(b), std::path::Path::new("top"))
        .and_then(|mut r| {
            r.complete()?;
            r.read_node(0).map(|_| ())
        })
        .map_err(|e| e.to_string());
    [whole, top]
}

#[test]
fn opened_top_first_a_file_whose_pages_are_all_of_skel_is_checked_whole() {
    // One level: its page is every page, so open_top reads all of SKEL and checks what follows it
    // and SKEL's CRC, as open does.
    let [whole, top] = both_opens(&file_with(1, Some((b"JUNK", 0, &[1, 2, 3]))));
    for e in [whole, top] {
        let e = e.expect_err("a chunk after the node pages");
        assert!(e.contains("JUNK chunk after the node pages"), "{e}");
    }
    let mut bad = file();
    let skel = bad.windows(4).position(|w| w == b"SKEL").unwrap();
    let size = u64::from_le_bytes(bad[skel + 8..skel + 16].try_into().unwrap()) as usize;
    bad[skel + 16 + size] ^= 1;
    for e in both_opens(&bad) {
        let e = e.expect_err("SKEL's CRC");
        assert!(e.contains("CRC"), "{e}");
    }
    // A 3.0 file keeps its nodes in NODE and NBRS: a NODL page as well is refused (§0).
    let [whole, top] = both_opens(&file_with(0, Some((b"NODL", 2, &[0u8; 56]))));
    for e in [whole, top] {
        let e = e.expect_err("3.0 with a NODL page");
        assert!(e.contains("NODL"), "{e}");
    }
}

#[test]
fn a_file_with_fewer_pages_than_levels_is_refused_whichever_way_it_is_opened() {
    // The golden sphere (several levels) with its top two pages only, every size and CRC made
    // right: the prefix reaches SKEL's end, so it is the whole table, and it lacks pages.
    let mut b = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/format-spec/vectors/sphere-v3.strata")).unwrap();
    let rd = Reader::open(Cursor::new(&b)).unwrap();
    assert!(rd.levels().len() >= 3 && rd.header().nodes > 0);
    drop(rd);
    let skel = b.windows(4).position(|w| w == b"SKEL").unwrap();
    let size = u64::from_le_bytes(b[skel + 8..skel + 16].try_into().unwrap()) as usize;
    let (mut sub, mut pages, mut last) = (skel + 16, 0, None);
    while sub < skel + 16 + size {
        let s = u64::from_le_bytes(b[sub + 8..sub + 16].try_into().unwrap()) as usize;
        pages += (&b[sub..sub + 4] == b"NODL") as usize;
        if pages == 3 && last.is_none() {
            last = Some(sub);
        }
        sub = (sub + 20 + s).next_multiple_of(8);
    }
    // SKEL ends where its last page began: its CRC, padding, then the geometry as before.
    let (last, end) = (last.unwrap(), skel + 16 + size);
    let rest = b.split_off((end + 4).next_multiple_of(8));
    b.truncate(last);
    b.extend_from_slice(&[0; 4]);
    b.resize(b.len().next_multiple_of(8), 0);
    b.extend_from_slice(&rest);
    b[skel + 8..skel + 16].copy_from_slice(&((last - skel - 16) as u64).to_le_bytes());
    let len = b.len() as u64;
    b[32..40].copy_from_slice(&len.to_le_bytes());
    let head_size = u64::from_le_bytes(b[24..32].try_into().unwrap()) as usize;
    let crc = crc32fast::hash(&b[32..32 + head_size]);
    b[32 + head_size..36 + head_size].copy_from_slice(&crc.to_le_bytes());
    reseal(&mut b);
    for e in both_opens(&b) {
        let e = e.expect_err("a page missing");
        assert!(e.contains("node pages (NODL) for"), "{e}");
    }
    let e = Reader::open_top(Cursor::new(&b), std::path::Path::new("top")).err().expect("refused at open");
    assert!(e.to_string().contains("holds 2 node pages (NODL)"), "{e}");
}

#[test]
fn every_damaged_payload_byte_is_refused() {
    let bytes = file();
    let rd = Reader::open(Cursor::new(&bytes)).unwrap();
    let node = rd.nodes()[0];
    let (at, size) = (node.offset as usize, node.size as usize);
    drop(rd);
    for k in at..at + size {
        for bit in 0..8 {
            let mut b = bytes.clone();
            b[k] ^= 1 << bit;
            // The payload's CRC in the node table catches it; recompute that CRC and every
            // checksum around it, and the codec's own checks must catch it instead.
            let read = |b: &[u8]| Reader::open(Cursor::new(b)).and_then(|r| r.read_node(0));
            assert!(read(&b).is_err(), "byte {k} bit {bit}");
            let crc = crc32fast::hash(&b[at..at + size]);
            let table = bytes.windows(4).position(|w| w == crc32fast::hash(&bytes[at..at + size]).to_le_bytes()).unwrap();
            b[table..table + 4].copy_from_slice(&crc.to_le_bytes());
            reseal(&mut b);
            let decoded = read(&b);
            if let Ok(g) = decoded {
                // A change the codec cannot see must still decode to a sound node.
                let v = format::verify(Cursor::new(&b), std::path::Path::new("resealed"));
                assert!(g.positions.len() == 4 || !v.is_sound(), "byte {k} bit {bit}");
            }
        }
    }
}

/// Recompute the CRCs of NODE, SKEL and GEOS after an edit.
fn reseal(b: &mut [u8]) {
    let mut pos = 16usize;
    while pos + 16 <= b.len() {
        let id: [u8; 4] = b[pos..pos + 4].try_into().unwrap();
        let size = u64::from_le_bytes(b[pos + 8..pos + 16].try_into().unwrap()) as usize;
        if &id == b"SKEL" {
            let mut sub = pos + 16;
            while sub < pos + 16 + size {
                let s = u64::from_le_bytes(b[sub + 8..sub + 16].try_into().unwrap()) as usize;
                let crc = crc32fast::hash(&b[sub + 16..sub + 16 + s]);
                b[sub + 16 + s..sub + 20 + s].copy_from_slice(&crc.to_le_bytes());
                sub = (sub + 20 + s).next_multiple_of(8);
            }
        }
        let crc = crc32fast::hash(&b[pos + 16..pos + 16 + size]);
        b[pos + 16 + size..pos + 20 + size].copy_from_slice(&crc.to_le_bytes());
        pos = (pos + 20 + size).next_multiple_of(8);
    }
}

/// `strata stream` opens top first: the damage open_top now checks is reported by the command,
/// naming the file and the byte, without a panic.
#[test]
fn the_cli_opening_top_first_names_what_follows_the_pages() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("junk-after-pages.strata");
    std::fs::write(&path, file_with(1, Some((b"JUNK", 0, &[1, 2, 3])))).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_strata")).args(["stream", path.to_str().unwrap(), "--json"]).output().unwrap();
    let said = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(!out.status.success() && out.status.code().is_some(), "{said}");
    assert!(
        said.contains("junk-after-pages.strata") && said.contains("byte") && said.contains("JUNK chunk after the node pages"),
        "{said}"
    );
}
