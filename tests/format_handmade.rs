//! A tiny file built byte by byte from the rules of format-spec/strata-v2.md (with byteorder, not
//! through the writer): it must equal the spec's worked hex example and the writer's output for
//! the same input, read back through the reader, and stay readable with unknown chunks inserted.
//! Version rules: a newer major is refused, a newer minor is read.
//!
//! `STRATA_PRINT_EXAMPLE=1 cargo test --test format_handmade -- --nocapture` prints the annotated
//! dump that the spec quotes.

use byteorder::{LittleEndian as LE, WriteBytesExt};
use glam::Vec3;
use std::io::Cursor;
use strata::cone::Cone;
use strata::format::{self, Reader, MAJOR, MINOR};
use strata::hierarchy::{GroupInfo, Hierarchy, HierarchyParams, Level, Lists, NO_PARENT};
use strata::levels::{LevelMesh, LevelMeshes};
use strata::mesh::{Material, Mesh};
use strata::write::WriteOptions;

const SPEC: &str = include_str!("../format-spec/strata-v2.md");

/// Bytes with a note per field, and the chunks opened so far.
#[derive(Default)]
struct Doc {
    bytes: Vec<u8>,
    notes: Vec<(usize, usize, String)>,
    /// Start of each chunk, in the order they were closed (children before parents).
    closed: Vec<usize>,
    open: Vec<usize>,
}

impl Doc {
    fn note(&mut self, start: usize, label: &str) {
        self.notes.push((start, self.bytes.len(), label.to_string()));
    }
    fn raw(&mut self, b: &[u8], label: &str) {
        let s = self.bytes.len();
        self.bytes.extend_from_slice(b);
        self.note(s, label);
    }
    fn u16(&mut self, v: u16, label: &str) {
        let s = self.bytes.len();
        self.bytes.write_u16::<LE>(v).unwrap();
        self.note(s, label);
    }
    fn u32(&mut self, v: u32, label: &str) {
        let s = self.bytes.len();
        self.bytes.write_u32::<LE>(v).unwrap();
        self.note(s, label);
    }
    fn u16s(&mut self, v: &[u16], label: &str) {
        let s = self.bytes.len();
        for &x in v {
            self.bytes.write_u16::<LE>(x).unwrap();
        }
        self.note(s, label);
    }
    fn u32s(&mut self, v: &[u32], label: &str) {
        let s = self.bytes.len();
        for &x in v {
            self.bytes.write_u32::<LE>(x).unwrap();
        }
        self.note(s, label);
    }
    fn u64(&mut self, v: u64, label: &str) {
        let s = self.bytes.len();
        self.bytes.write_u64::<LE>(v).unwrap();
        self.note(s, label);
    }
    fn f32s(&mut self, v: &[f32], label: &str) {
        let s = self.bytes.len();
        for &x in v {
            self.bytes.write_f32::<LE>(x).unwrap();
        }
        self.note(s, label);
    }
    fn f64(&mut self, v: f64, label: &str) {
        let s = self.bytes.len();
        self.bytes.write_f64::<LE>(v).unwrap();
        self.note(s, label);
    }
    /// Frame of a chunk: ID, flags, size (patched by `end`).
    fn begin(&mut self, id: &[u8; 4], flags: u32) {
        self.open.push(self.bytes.len());
        let name = String::from_utf8_lossy(id).to_string();
        self.raw(id, &format!("{name} id"));
        self.u32(flags, &format!("{name} flags"));
        self.u64(0, &format!("{name} payload size"));
    }
    /// Patch the size, append the CRC (sealed later) and zero padding to a multiple of 8.
    fn end(&mut self) {
        let start = self.open.pop().unwrap();
        let size = (self.bytes.len() - start - 16) as u64;
        self.bytes[start + 8..start + 16].copy_from_slice(&size.to_le_bytes());
        let name = String::from_utf8_lossy(&self.bytes[start..start + 4]).to_string();
        self.u32(0, &format!("{name} CRC-32 of the payload"));
        let pad = (8 - self.bytes.len() % 8) % 8;
        if pad > 0 {
            self.raw(&vec![0; pad], "padding");
        }
        self.closed.push(start);
    }
    fn patch(&mut self, at: usize, b: &[u8]) {
        self.bytes[at..at + b.len()].copy_from_slice(b);
    }
    /// Compute every chunk's CRC, children before parents.
    fn seal(&mut self) {
        for &start in &self.closed.clone() {
            let size = u64::from_le_bytes(self.bytes[start + 8..start + 16].try_into().unwrap()) as usize;
            let crc = crc32fast::hash(&self.bytes[start + 16..start + 16 + size]);
            self.patch(start + 16 + size, &crc.to_le_bytes());
        }
    }
    fn chunk(&mut self, id: &[u8; 4], payload: &[u8]) {
        self.begin(id, 0);
        self.raw(payload, "unknown payload");
        self.end();
    }
    /// The annotated dump quoted by the spec: `offset  bytes | note`.
    fn dump(&self) -> String {
        let mut out = String::new();
        for (s, e, label) in &self.notes {
            for (k, piece) in self.bytes[*s..*e].chunks(16).enumerate() {
                let hex: Vec<String> = piece.iter().map(|b| format!("{b:02x}")).collect();
                let note = if k == 0 { label.as_str() } else { "" };
                out += &format!("{:08x}  {:<47} | {note}\n", s + 16 * k, hex.join(" "));
            }
        }
        out
    }
}

/// The quad of the example: two triangles in the z = 0 plane.
fn quad() -> Mesh {
    let mut m = Mesh {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        face_materials: vec![0, 0],
        materials: vec![Material::default()],
        ..Mesh::default()
    };
    m.compute_face_geometry();
    m
}

fn group() -> GroupInfo {
    GroupInfo {
        cone: Cone { axis: Vec3::Z, half_angle: 0.0 },
        center: Vec3::new(0.5, 0.5, 0.0),
        radius: 0.75,
        min: Vec3::ZERO,
        max: Vec3::new(1.0, 1.0, 0.0),
        faces: 2,
        area: 1.0,
        area_normal: Vec3::Z,
    }
}

/// The example's hierarchy: one culling cluster, one level with one group.
fn hierarchy() -> Hierarchy {
    let empty = Lists { offsets: vec![0, 0], items: vec![] };
    let clusters = Level { face_group: vec![0, 0], groups: vec![group()], parent: vec![0], neighbors: empty.clone(), ..Level::default() };
    let level = Level {
        face_group: vec![0, 0],
        groups: vec![group()],
        children: Lists { offsets: vec![0, 1], items: vec![0] },
        parent: vec![NO_PARENT],
        neighbors: empty,
        max_angle: 1.0,
        max_faces: 512,
    };
    Hierarchy { clusters, levels: vec![level] }
}

/// The build parameters the spec's example records: fixed here, so that changing the defaults
/// does not change the example.
fn example_params() -> HierarchyParams {
    HierarchyParams {
        cluster_faces: 64,
        cluster_angle: 40f32.to_radians(),
        leaf_faces: 512,
        leaf_angle: 75f32.to_radians(),
        angle_step: 30f32.to_radians(),
        growth: 4,
        kc: 1.0,
        ks: 0.25,
        kn: 0.1,
        top_groups: 8,
    }
}

fn options() -> WriteOptions {
    WriteOptions {
        metres_per_unit: 1.0,
        params: example_params(),
        level_ratio: 0.5,
        tool: "strata test".into(),
        georef: None,
        encoding: strata::write::Encoding::V2,
        derive_normals: false,
        images: Default::default(),
    }
}

/// The example's grid step: the smallest power of two with 1 / step ≤ 2^20 − 1.
const STEP: f64 = 1.0 / (1u64 << 19) as f64;
/// Grid coordinates of 1 and 0.5.
const ONE: u64 = 1 << 19;
const HALF: u64 = 1 << 18;
/// Radius code of both spheres: the needed 0.75 (the hierarchy's radius) is 393,216 steps, times
/// the writer's 1 + 10⁻⁶ margin, rounded up to 11 bits of mantissa: 1537 · 2^8 = 393,472 steps.
const RADIUS: u16 = 1537 | 8 << 11;

/// Build the example file by hand; `extra` inserts unknown chunks at every level of nesting.
fn handmade(major: u16, minor: u16, extra: bool) -> Doc {
    build(major, minor, extra, false, None)
}

/// The image of the textured example: a 2 × 2 PNG and its 1 × 1 level, as files.
struct Texturing {
    full: Vec<u8>,
    half: Vec<u8>,
}

impl Texturing {
    fn new() -> Texturing {
        use strata::texture::{encode, ImageCodec, Rgba8};
        let full = Rgba8 { width: 2, height: 2, pixels: vec![255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 255, 255, 255, 255] };
        let half = strata::texture::pyramid::downsample(&full, strata::texture::pyramid::Filter::Srgb);
        Texturing { full: encode(ImageCodec::Png, &full, 90).unwrap(), half: encode(ImageCodec::Png, &half, 90).unwrap() }
    }
}

/// [`handmade`], with a `GEOR` chunk after `HEAD` when `geor` (spec §5.2): frame 2, UTM zone 13N;
/// with UVs, an image and its chunks when `texturing` (§7.5).
fn build(major: u16, minor: u16, extra: bool, geor: bool, texturing: Option<&Texturing>) -> Doc {
    let mut d = Doc::default();
    let p = example_params();
    // Prologue.
    d.raw(b"\x89STRATA\n", "magic");
    d.u16(major, "major version");
    d.u16(minor, "minor version");
    let crc = crc32fast::hash(&d.bytes[..12]);
    d.u32(crc, "CRC-32 of bytes 0..12");

    // HEAD.
    d.begin(b"HEAD", 0);
    let file_size_at = d.bytes.len();
    d.u64(0, "file size");
    d.f64(1.0, "metres per unit");
    d.f32s(&[0.0, 0.0, 0.0], "bounds min");
    d.f32s(&[1.0, 1.0, 0.0], "bounds max");
    if texturing.is_some() {
        d.u32(2, "attributes (UVs)");
    } else {
        d.u32(0, "attributes (none)");
    }
    d.u32(1, "levels");
    d.u32(1, "nodes");
    d.u32(1, "materials");
    d.u64(4, "input vertices");
    d.u64(2, "input faces");
    d.u32(1, "culling clusters");
    d.u32(p.cluster_faces, "params: cluster_faces");
    d.f32s(&[p.cluster_angle], "params: cluster_angle");
    d.u32(p.leaf_faces, "params: leaf_faces");
    d.f32s(&[p.leaf_angle, p.angle_step], "params: leaf_angle, angle_step");
    d.u32(p.growth, "params: growth");
    d.f32s(&[p.kc, p.ks, p.kn], "params: kc, ks, kn");
    d.u32(p.top_groups as u32, "params: top_groups");
    d.f32s(&[0.5], "level ratio");
    d.f64(0.0, "grid origin x");
    d.f64(0.0, "grid origin y");
    d.f64(0.0, "grid origin z");
    d.f64(STEP, "grid step (2^-19)");
    d.u32(20, "grid bits");
    d.u32(11, "tool length");
    d.raw(b"strata test", "tool");
    d.end();

    if geor {
        d.begin(b"GEOR", 0);
        d.u32(2, "frame: projected CRS");
        d.u32(0, "reserved");
        d.f64(480_000.0, "origin: easting");
        d.f64(4_400_000.0, "origin: northing");
        d.f64(1500.0, "origin: height");
        d.f64(1.0, "metres per CRS unit");
        d.f64(2.0, "z scale");
        d.u32(10, "CRS length");
        d.raw(b"EPSG:32613", "CRS");
        d.end();
    }

    if extra {
        d.chunk(b"XTRA", b"skip me");
    }

    // SKEL.
    d.begin(b"SKEL", 0);
    d.begin(b"LEVL", 0);
    d.u32(0, "level 0: first node");
    d.u32(1, "level 0: nodes");
    d.u64(2, "level 0: faces");
    d.u64(4, "level 0: vertices");
    let level_bytes_at = d.bytes.len();
    d.u64(0, "level 0: geometry bytes");
    d.end();
    if extra {
        d.chunk(b"xsub", b"unknown sub-chunk");
    }
    d.begin(b"NODE", 0);
    d.u16(0, "node 0: child count");
    d.u16(0, "node 0: neighbour count");
    d.u16s(&[0, 0], "node 0: cone axis (+z)");
    d.u16(0, "node 0: cone half-angle (0)");
    d.u16(RADIUS, "node 0: sphere radius (1537·2^8 steps)");
    d.u64(0, "node 0: box min (0, 0, 0)");
    d.u64(ONE | ONE << 21, "node 0: box max (2^19, 2^19, 0)");
    d.u64(HALF | HALF << 21, "node 0: sphere center (2^18, 2^18, 0)");
    d.f32s(&[(STEP * 3f64.sqrt() / 2.0) as f32], "node 0: geometric error (√3/2 step)");
    d.u32(2, "node 0: faces");
    d.u32(4, "node 0: vertices");
    let node_geom_at = d.bytes.len();
    d.u32(0, "node 0: GEOM bytes (ID to CRC)");
    d.u32(0, "node 0: GEOM CRC-32");
    d.end();
    d.begin(b"NBRS", 2);
    d.end();
    d.begin(b"MATL", 0);
    d.u32(7, "material 0: name length");
    d.raw(b"default", "material 0: name");
    d.f32s(&[0.8, 0.8, 0.8, 1.0], "material 0: base color");
    d.u32(0, "material 0: texture length (none)");
    d.end();
    if let Some(t) = texturing {
        // §7.5: one image of two levels; entries by pixel count, so the 1 × 1 level first.
        d.begin(b"TEXR", 0);
        d.u32(1, "images");
        d.u32(2, "level entries");
        d.u32(5, "image 0: name length");
        d.raw(b"t.png", "image 0: name");
        d.raw(&[1, 2, 0, 0], "image 0: codec PNG, 2 levels, reserved");
        d.u32s(&[0, 1, 1, 1], "entry 0: image 0 level 1, 1 × 1");
        d.u32((20 + t.half.len()) as u32, "entry 0: TEXL bytes");
        d.u32(crc32fast::hash(&t.half), "entry 0: TEXL CRC-32");
        d.u32s(&[0, 0, 2, 2], "entry 1: image 0 level 0, 2 × 2");
        d.u32((20 + t.full.len()) as u32, "entry 1: TEXL bytes");
        d.u32(crc32fast::hash(&t.full), "entry 1: TEXL CRC-32");
        d.u32(0, "material 0: base color image 0");
        d.raw(&[0, 0, 0, 0], "material 0: base color wrap repeat, repeat");
        for kind in ["normal", "metallic-roughness", "occlusion", "emissive"] {
            d.u32(0xFFFF_FFFF, &format!("material 0: no {kind} map"));
            d.raw(&[0, 0, 0, 0], "wrap, reserved");
        }
        d.u16(32768, "node 0: UV density code (1 UV unit per model unit)");
        d.end();
    }
    d.end();

    // GEOM of node 0.
    let geom = d.bytes.len();
    d.begin(b"GEOM", 0);
    if extra {
        d.chunk(b"VTAN", b"a future attribute");
    }
    d.begin(b"VPOS", 3);
    d.u32s(&[0, 0, 0], "base");
    for (k, p) in [[0, 0, 0], [ONE, 0, 0], [ONE, ONE, 0], [0, ONE, 0]].iter().enumerate() {
        let s = d.bytes.len();
        for x in p {
            d.bytes.write_u24::<LE>(*x as u32).unwrap();
        }
        d.note(s, &format!("vertex {k} (u24 offsets)"));
    }
    d.end();
    if texturing.is_some() {
        d.begin(b"VTEX", 0);
        d.f32s(&[0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0], "UVs of vertices 0..4");
        d.end();
    }
    d.begin(b"INDX", 2);
    let s = d.bytes.len();
    for i in [0u16, 1, 2, 0, 2, 3] {
        d.bytes.write_u16::<LE>(i).unwrap();
    }
    d.note(s, "indices (u16)");
    d.end();
    d.begin(b"MATR", 0);
    d.u32(0, "range 0: material");
    d.u32(0, "range 0: first index");
    d.u32(6, "range 0: index count");
    d.end();
    d.begin(b"CLUS", 4);
    d.u16s(&[0, 0], "cluster 0: cone axis (+z)");
    d.u16(0, "cluster 0: cone half-angle (0)");
    d.u16(2, "cluster 0: face count");
    d.u16s(&[1 << 14, 1 << 14, 0], "cluster 0: sphere center (units of 2^4 steps)");
    d.u16(RADIUS, "cluster 0: sphere radius");
    d.end();
    d.end();
    let geom_span = 16 + u64::from_le_bytes(d.bytes[geom + 8..geom + 16].try_into().unwrap()) + 4;
    let geom_end = d.bytes.len() as u64;
    if let Some(t) = texturing {
        d.begin(b"TEXL", 0);
        d.raw(&t.half, "image 0 level 1 (PNG)");
        d.end();
        d.begin(b"TEXL", 0);
        d.raw(&t.full, "image 0 level 0 (PNG)");
        d.end();
    }

    if extra {
        d.chunk(b"XEND", b"trailing unknown chunk");
    }

    let len = d.bytes.len() as u64;
    d.patch(file_size_at, &len.to_le_bytes());
    d.patch(level_bytes_at, &(geom_end - geom as u64).to_le_bytes());
    d.patch(node_geom_at, &(geom_span as u32).to_le_bytes());
    d.seal();
    let payload_end = geom + geom_span as usize - 4;
    let geom_crc = crc32fast::hash(&d.bytes[geom + 16..payload_end]);
    d.patch(node_geom_at + 4, &geom_crc.to_le_bytes());
    d.seal();
    d
}

/// The bytes of the spec's ```hex block.
fn spec_bytes() -> Vec<u8> {
    let start = SPEC.find("```hex\n").expect("the spec has a ```hex block") + 7;
    let end = start + SPEC[start..].find("```").expect("closed block");
    let mut out = Vec::new();
    for line in SPEC[start..end].lines() {
        let data = line.split('|').next().unwrap_or("");
        let mut tokens = data.split_whitespace();
        let offset = usize::from_str_radix(tokens.next().unwrap_or(""), 16).expect("offset");
        assert_eq!(offset, out.len(), "spec dump offset");
        out.extend(tokens.map(|t| u8::from_str_radix(t, 16).expect("hex byte")));
    }
    out
}

#[test]
fn handmade_file_matches_spec_and_writer() {
    let d = handmade(MAJOR, 0, false);
    if std::env::var_os("STRATA_PRINT_EXAMPLE").is_some() {
        print!("{}", d.dump());
    }
    assert_eq!(spec_bytes(), d.bytes, "the spec's worked example is the handmade file");
    let mesh = quad();
    let lv = LevelMeshes { levels: vec![LevelMesh { mesh, face_group: vec![0, 0], group_error: vec![0.0] }] };
    let mut cur = Cursor::new(Vec::new());
    strata::write::write_to(&mut cur, &hierarchy(), &lv, &options()).expect("write");
    assert_eq!(cur.into_inner(), d.bytes, "the writer follows the spec");
    assert!(SPEC.contains(&format!("version {}", format::VERSION)), "the spec names the version the code writes");
    assert_eq!(format::VERSION, format!("{MAJOR}.{MINOR}"));
}

fn check_reads(bytes: &[u8]) {
    let rd = Reader::open(Cursor::new(bytes)).expect("open");
    let h = rd.header().clone();
    assert_eq!((h.levels, h.nodes, h.materials, h.input_faces, h.clusters), (1, 1, 1, 2, 1));
    assert_eq!(h.tool, "strata test");
    assert_eq!(h.metres_per_unit, 1.0);
    assert_eq!(h.max, Vec3::new(1.0, 1.0, 0.0));
    assert_eq!(rd.materials(), &[Material::default()]);
    let n = rd.nodes()[0];
    assert_eq!((n.parent, n.faces, n.vertices, n.radius), (format::NO_PARENT, 2, 4, 393_472.0 / ONE as f32));
    let g = rd.read_node(0).expect("node");
    assert_eq!(g.positions, quad().positions);
    assert_eq!(g.indices, vec![0, 1, 2, 0, 2, 3]);
    assert_eq!(g.material_ranges, vec![format::MaterialRange { material: 0, first_index: 0, index_count: 6 }]);
    assert_eq!(g.clusters.len(), 1);
    assert_eq!((g.clusters[0].first_face, g.clusters[0].face_count), (0, 2));
    let m = strata::assemble::to_mesh(&rd, 0).expect("level 0");
    assert_eq!(m.triangles, quad().triangles);
    let v = format::verify(Cursor::new(bytes), std::path::Path::new("handmade"));
    assert!(v.is_sound(), "{:?}", v.problems);
}

#[test]
fn handmade_file_reads() {
    check_reads(&handmade(MAJOR, 0, false).bytes);
}

/// A file with `GEOR` built from spec §5.2 reads as the spec says, equals the writer's output for
/// the same georeference, and is version 2.1; the writer writes 2.0 without it.
#[test]
fn georeference_chunk_follows_the_spec() {
    let d = build(MAJOR, 1, false, true, None);
    check_reads(&d.bytes);
    let rd = Reader::open(Cursor::new(&d.bytes)).expect("open");
    let expect = format::Georef {
        frame: format::GeoFrame::Projected,
        origin: [480_000.0, 4_400_000.0, 1500.0],
        metres_per_crs_unit: 1.0,
        z_scale: 2.0,
        crs: "EPSG:32613".into(),
    };
    assert_eq!(rd.georef(), Some(&expect));
    assert_eq!((rd.header().major, rd.header().minor), (2, 1));
    let mesh = quad();
    let lv = LevelMeshes { levels: vec![LevelMesh { mesh, face_group: vec![0, 0], group_error: vec![0.0] }] };
    let mut cur = Cursor::new(Vec::new());
    let opts = WriteOptions { georef: Some(expect), ..options() };
    strata::write::write_to(&mut cur, &hierarchy(), &lv, &opts).expect("write");
    assert_eq!(cur.into_inner(), d.bytes, "the writer follows §5.2");
    assert_eq!(Reader::open(Cursor::new(handmade(MAJOR, 0, false).bytes)).expect("open").georef(), None);
    // A second GEOR, and a broken one, are refused.
    let twice = {
        let one = &d.bytes;
        let at = one.windows(4).position(|w| w == b"GEOR").expect("GEOR");
        let size = u64::from_le_bytes(one[at + 8..at + 16].try_into().unwrap()) as usize;
        let len = (20 + size + 7) & !7;
        let mut b = one[..at + len].to_vec();
        b.extend_from_slice(&one[at..]);
        // HEAD's file size, then its CRC.
        let file_size = b.len() as u64;
        b[32..40].copy_from_slice(&file_size.to_le_bytes());
        let head = u64::from_le_bytes(b[24..32].try_into().unwrap()) as usize;
        let crc = crc32fast::hash(&b[32..32 + head]);
        b[32 + head..36 + head].copy_from_slice(&crc.to_le_bytes());
        b
    };
    let e = Reader::open(Cursor::new(twice)).err().expect("refused").to_string();
    assert!(e.contains("a second GEOR"), "{e}");
    let mut bad = d.bytes.clone();
    let at = bad.windows(4).position(|w| w == b"GEOR").expect("GEOR") + 16;
    bad[at..at + 4].copy_from_slice(&9u32.to_le_bytes());
    let crc = crc32fast::hash(&bad[at..at + 62]);
    bad[at + 62..at + 66].copy_from_slice(&crc.to_le_bytes());
    let e = Reader::open(Cursor::new(bad)).err().expect("refused").to_string();
    assert!(e.contains("chunk GEOR") && e.contains("unknown frame 9"), "{e}");
}

/// A file with an image built from spec §7.5 reads as the spec says, equals the writer's output for
/// the same mesh and image, and is version 2.2; damage to its image levels is found.
#[test]
fn images_follow_the_spec() {
    let t = Texturing::new();
    let d = build(MAJOR, 2, false, false, Some(&t));
    let rd = Reader::open(Cursor::new(&d.bytes)).expect("open");
    assert_eq!((rd.header().major, rd.header().minor), (2, 2));
    let tx = rd.textures();
    assert_eq!(tx.images.len(), 1);
    assert_eq!((tx.images[0].name.as_str(), tx.images[0].codec), ("t.png", format::ImageCodec::Png));
    assert_eq!(tx.uv_density, vec![1.0]);
    assert_eq!((tx.level(0, 0).unwrap().width, tx.level(0, 1).unwrap().width), (2, 1));
    assert!(tx.level(0, 1).unwrap().offset < tx.level(0, 0).unwrap().offset, "the coarse level first");
    assert_eq!(rd.read_image_level(0, 0).unwrap(), t.full);
    assert_eq!(rd.read_image_level(0, 1).unwrap(), t.half);
    let slot = format::TextureSlot { image: 0, wrap: [format::Wrap::Repeat; 2] };
    assert_eq!(rd.materials()[0].map(format::MapKind::BaseColor), Some(slot));
    assert_eq!(rd.materials()[0].map(format::MapKind::Normal), None);
    let g = rd.read_node(0).expect("node");
    assert_eq!(g.uvs, vec![glam::Vec2::ZERO, glam::Vec2::X, glam::Vec2::ONE, glam::Vec2::Y]);
    let v = format::verify(Cursor::new(&d.bytes), std::path::Path::new("textured"));
    assert!(v.is_sound(), "{:?}", v.problems);

    let mut mesh = quad();
    mesh.uvs = [0, 1, 2, 0, 2, 3].iter().map(|&v| g.uvs[v]).collect();
    mesh.materials[0].maps[0] = Some(slot);
    let lv = LevelMeshes { levels: vec![LevelMesh { mesh, face_group: vec![0, 0], group_error: vec![0.0] }] };
    let level = |b: &[u8], w: u32| strata::format::texture::LevelIn { width: w, height: w, bytes: b.to_vec() };
    let image = strata::format::texture::ImageIn {
        name: "t.png".into(),
        codec: format::ImageCodec::Png,
        levels: vec![level(&t.full, 2), level(&t.half, 1)],
    };
    let mut cur = Cursor::new(Vec::new());
    let opts = WriteOptions { images: vec![image].into(), ..options() };
    strata::write::write_to(&mut cur, &hierarchy(), &lv, &opts).expect("write");
    assert_eq!(cur.into_inner(), d.bytes, "the writer follows §7.5");

    // Images are 2.2: the same file marked 2.1 reads (a 2.1 reader skips TEXR) but verify reports it.
    let older = build(MAJOR, 1, false, false, Some(&t));
    assert!(Reader::open(Cursor::new(&older.bytes)).is_ok());
    let v = format::verify(Cursor::new(&older.bytes), std::path::Path::new("older"));
    assert!(v.problems.iter().any(|p| p.to_string().contains("TEXR chunk in a format 2.1 file")), "{:?}", v.problems);

    // A level whose header says 3 pixels wide, every checksum resealed, so that only the rule
    // against the entry catches it.
    let mut bad = d.bytes.clone();
    let start = bad.windows(8).rposition(|w| w == b"\x89PNG\r\n\x1a\n").expect("the full level");
    bad[start + 19] = 3;
    let end = start + t.full.len();
    let (old, new) = (crc32fast::hash(&t.full), crc32fast::hash(&bad[start..end]));
    bad[end..end + 4].copy_from_slice(&new.to_le_bytes());
    let entry = bad.windows(4).position(|w| w == old.to_le_bytes()).expect("the entry's CRC");
    bad[entry..entry + 4].copy_from_slice(&new.to_le_bytes());
    reseal_skeleton(&mut bad);
    let rd = Reader::open(Cursor::new(&bad)).expect("the skeleton opens");
    let e = rd.read_image_level(0, 0).unwrap_err().to_string();
    assert!(e.contains("chunk TEXL") && e.contains("the image is 3 × 2, the entry says 2 × 2"), "{e}");
    let v = format::verify(Cursor::new(&bad), std::path::Path::new("bad"));
    assert!(v.problems.iter().any(|p| p.to_string().contains("the image is 3 × 2")), "{:?}", v.problems);
}

/// Recompute the CRCs of `SKEL`'s sub-chunks and of `SKEL` itself (the chunk after `HEAD`).
fn reseal_skeleton(b: &mut [u8]) {
    let size = |b: &[u8], at: usize| u64::from_le_bytes(b[at + 8..at + 16].try_into().unwrap()) as usize;
    let skel = (16 + 20 + size(b, 16) + 7) & !7;
    assert_eq!(&b[skel..skel + 4], b"SKEL");
    let end = skel + 16 + size(b, skel);
    let mut at = skel + 16;
    while at < end {
        let n = size(b, at);
        let crc = crc32fast::hash(&b[at + 16..at + 16 + n]);
        b[at + 16 + n..at + 20 + n].copy_from_slice(&crc.to_le_bytes());
        at = (at + 20 + n + 7) & !7;
    }
    let crc = crc32fast::hash(&b[skel + 16..end]);
    b[end..end + 4].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn unknown_chunks_are_skipped() {
    let d = handmade(MAJOR, 0, true);
    check_reads(&d.bytes);
    let rd = Reader::open(Cursor::new(&d.bytes)).expect("open");
    let ids: Vec<&str> = rd.skeleton_chunks().iter().map(|c| c.id.as_str()).collect();
    assert_eq!(ids, ["HEAD", "XTRA", "SKEL", "LEVL", "xsub", "NODE", "NBRS", "MATL"]);
    let rd = Reader::open(Cursor::new(&d.bytes)).expect("open");
    let top: Vec<String> = rd.chunks().expect("chunks").iter().map(|c| c.id.clone()).collect();
    assert_eq!(top, ["HEAD", "XTRA", "SKEL", "GEOM", "XEND"]);
}

#[test]
fn newer_major_is_refused_newer_minor_is_read() {
    let err = Reader::open(Cursor::new(handmade(format::NEWEST_MAJOR + 1, 0, false).bytes)).err().expect("refused");
    let msg = err.to_string();
    assert!(msg.contains(&format!("version {}.0 is newer", format::NEWEST_MAJOR + 1)), "{msg}");
    assert_eq!(err.location(), Some(&strata::Location::Byte(8)));
    check_reads(&handmade(MAJOR, MINOR + 1, true).bytes);
    let err = Reader::open(Cursor::new(handmade(MAJOR - 1, 0, false).bytes)).err().expect("a 1.0 file is refused");
    assert!(err.to_string().contains(&format!("version {}.0 is not supported", MAJOR - 1)), "{err}");
}
