//! The example of format-spec/strata-v4.md §4, built by hand from the spec's rules: the unit
//! square as two levels of a DAG. The prologue, `HEAD`, `SKEL` (`LEVL`, `MATL`, `CODE` and the two
//! format-4 `NODL` pages with their group records and consumers) and `GEOS` are this file's own
//! bytes; the three node payloads come from the format-3 codec, which tests/format3_handmade.rs
//! checks byte by byte. strata's reader must read the DAG it describes, `verify` must find it
//! sound, and damage to the skeleton must be refused or leave the DAG as it was.

use std::io::Cursor;
use std::path::Path;
use strata::format::geom::rans::EncodeTable;
use strata::format::geom::v2::{ClusterCodes, GeometryCodes};
use strata::format::geom::v3;
use strata::format::{self, MaterialRange, Reader, NO_PARENT};

/// The grid of strata-v3.md §7: 20 bits, step 2^−19, so 1.0 is grid coordinate 2^19.
const STEP: f64 = 1.0 / (1u64 << 19) as f64;
const ONE: u32 = 1 << 19;
const HALF: u64 = 1 << 18;
/// Radius code of every sphere: 1537 · 2^8 steps, around the square's middle.
const RADIUS: u16 = 1537 | 8 << 11;
/// The square's corners as grid points.
const CORNERS: [[u32; 3]; 4] = [[0, 0, 0], [ONE, 0, 0], [ONE, ONE, 0], [0, ONE, 0]];

/// Level 0's error: the quantization bound √3·s/2 (strata-v3.md §6).
fn quantization() -> f32 {
    (STEP * 3f64.sqrt() / 2.0) as f32
}

/// The group's error `e`, and so node 0's: at least its children's.
fn group_error() -> f32 {
    2.0 * quantization()
}

/// Node 0 (level 1, both triangles, no clusters), nodes 1 and 2 (level 0, one triangle and one
/// cluster each): each node's faces as corners of the square.
const NODES: [&[[usize; 3]]; 3] = [&[[0, 1, 2], [0, 2, 3]], &[[0, 1, 2]], &[[0, 2, 3]]];

/// The payloads of nodes 0, 1 and 2 and their vertex counts, coded with tables fitted to them;
/// the `CODE` payload, written here from the tables' frequencies (strata-v3.md §3).
fn payloads() -> (Vec<(Vec<u8>, u32)>, Vec<u8>) {
    let box_ = [[0, 0, 0], [ONE, ONE, 0]];
    let models: Vec<(v3::Model, u32)> = NODES
        .iter()
        .enumerate()
        .map(|(i, faces)| {
            let mut corners: Vec<usize> = faces.iter().flatten().copied().collect();
            corners.sort_unstable();
            corners.dedup();
            let local = |c: usize| corners.iter().position(|&x| x == c).unwrap() as u32;
            let g = GeometryCodes {
                points: corners.iter().map(|&c| CORNERS[c]).collect(),
                indices: faces.iter().flatten().map(|&c| local(c)).collect(),
                material_ranges: vec![MaterialRange { material: 0, first_index: 0, index_count: 3 * faces.len() as u32 }],
                clusters: (i > 0).then(|| (0, vec![ClusterCodes { faces: faces.len() as u16, ..ClusterCodes::default() }])),
                ..GeometryCodes::default()
            };
            (v3::model(&g, 20, box_, 0).expect("the codec codes the node").0, corners.len() as u32)
        })
        .collect();
    let mut counts = vec![Vec::new(); v3::alphabet::ALPHABETS];
    models.iter().for_each(|(m, _)| m.count(&mut counts));
    let tables = v3::CodeTables::fit(0, 0, &counts);
    let enc: Vec<EncodeTable> = tables.freqs.iter().map(EncodeTable::new).collect();
    let mut code = vec![0u8, 0, 0, 0]; // no normals, no colours, reserved
    code.extend_from_slice(&(tables.freqs.len() as u32).to_le_bytes());
    for f in &tables.freqs {
        code.extend_from_slice(&(f.0.len() as u16).to_le_bytes());
        f.0.iter().for_each(|x| code.extend_from_slice(&x.to_le_bytes()));
    }
    (models.iter().map(|(m, v)| (m.payload(&enc).expect("payload"), *v)).collect(), code)
}

/// A chunk: ID, flags, size, payload, CRC-32, zero padding to a multiple of 8 (strata-v2.md §4.1).
fn chunk(out: &mut Vec<u8>, id: &[u8; 4], flags: u32, payload: &[u8]) {
    out.extend_from_slice(id);
    out.extend_from_slice(&flags.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(payload);
    out.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    out.resize(out.len().next_multiple_of(8), 0);
}

fn put(out: &mut Vec<u8>, values: &[u64], bytes: usize) {
    values.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()[..bytes]));
}

/// A 56-byte format-4 node record (strata-v4.md §1): consumer, then v2 §7.2 from offset 4; every
/// node's box is the square, its sphere around the middle, its cone +z with half-angle 0.
fn record(out: &mut Vec<u8>, consumer: u32, error: f32, faces: usize, (payload, vertices): &(Vec<u8>, u32)) {
    out.extend_from_slice(&consumer.to_le_bytes());
    put(out, &[0, 0, 0, RADIUS as u64], 2); // axis +z, half-angle 0, radius
    put(out, &[0, ONE as u64 | (ONE as u64) << 21, HALF | HALF << 21], 8); // box min, max, center
    out.extend_from_slice(&error.to_le_bytes());
    put(out, &[faces as u64, *vertices as u64, payload.len() as u64, crc32fast::hash(payload) as u64], 4);
}

/// The whole file of §4, format 4.0.
fn file() -> Vec<u8> {
    let (nodes, code) = payloads();
    let p = strata::hierarchy::HierarchyParams::default();
    let mut head = Vec::new();
    put(&mut head, &[0], 8); // file size, patched below
    head.extend_from_slice(&1f64.to_le_bytes());
    [0f32, 0.0, 0.0, 1.0, 1.0, 0.0].iter().for_each(|v| head.extend_from_slice(&v.to_le_bytes()));
    put(&mut head, &[0, 2, 3, 1], 4); // attributes, levels, nodes, materials
    put(&mut head, &[4, 2], 8); // input vertices, faces
    put(&mut head, &[2, p.cluster_faces as u64], 4); // clusters: one per level-0 node
    head.extend_from_slice(&p.cluster_angle.to_le_bytes());
    head.extend_from_slice(&p.leaf_faces.to_le_bytes());
    head.extend_from_slice(&p.leaf_angle.to_le_bytes());
    head.extend_from_slice(&p.angle_step.to_le_bytes());
    head.extend_from_slice(&p.growth.to_le_bytes());
    [p.kc, p.ks, p.kn].iter().for_each(|v| head.extend_from_slice(&v.to_le_bytes()));
    head.extend_from_slice(&(p.top_groups as u32).to_le_bytes());
    head.extend_from_slice(&0.5f32.to_le_bytes());
    [0f64, 0.0, 0.0, STEP].iter().for_each(|v| head.extend_from_slice(&v.to_le_bytes()));
    put(&mut head, &[20, 11], 4);
    head.extend_from_slice(b"strata test");

    let mut skel = Vec::new();
    // LEVL, finest first: level 0 is nodes 1..3, level 1 (the top) node 0.
    let mut levl = Vec::new();
    let bytes0 = (nodes[1].0.len() + nodes[2].0.len()) as u64;
    put(&mut levl, &[1, 2], 4);
    put(&mut levl, &[2, (nodes[1].1 + nodes[2].1) as u64, bytes0], 8);
    put(&mut levl, &[0, 1], 4);
    put(&mut levl, &[2, nodes[0].1 as u64, nodes[0].0.len() as u64], 8);
    chunk(&mut skel, b"LEVL", 0, &levl);
    let mut matl = Vec::new();
    put(&mut matl, &[7], 4);
    matl.extend_from_slice(b"default");
    [0.8f32, 0.8, 0.8, 1.0].iter().for_each(|v| matl.extend_from_slice(&v.to_le_bytes()));
    put(&mut matl, &[0], 4);
    chunk(&mut skel, b"MATL", 0, &matl);
    chunk(&mut skel, b"CODE", 0, &code);
    // Level 1's page: G = 1; the group (outputs 1, children 2, error e, sphere); node 0 at the top.
    let mut top = Vec::new();
    put(&mut top, &[1, 1, 2], 4); // G, outputs, children
    top.extend_from_slice(&group_error().to_le_bytes());
    put(&mut top, &[RADIUS as u64, 0], 2); // radius code, reserved
    put(&mut top, &[HALF | HALF << 21], 8); // sphere center
    record(&mut top, NO_PARENT, group_error(), 2, &nodes[0]);
    chunk(&mut skel, b"NODL", 0, &top);
    // Level 0's page: no groups; nodes 1 and 2, children of group 0 of level 1.
    let mut bottom = Vec::new();
    put(&mut bottom, &[0], 4);
    record(&mut bottom, 0, quantization(), 1, &nodes[1]);
    record(&mut bottom, 0, quantization(), 1, &nodes[2]);
    chunk(&mut skel, b"NODL", 0, &bottom);

    let mut out = b"\x89STRATA\n".to_vec();
    put(&mut out, &[4, 0], 2);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    chunk(&mut out, b"HEAD", 0, &head);
    chunk(&mut out, b"SKEL", 0, &skel);
    chunk(&mut out, b"GEOS", 0, &nodes.iter().flat_map(|n| n.0.clone()).collect::<Vec<u8>>());
    let len = out.len() as u64;
    out[32..40].copy_from_slice(&len.to_le_bytes());
    reseal(&mut out);
    out
}

/// Offset and payload size of the chunk frame at `at`.
fn frame(b: &[u8], at: usize) -> (usize, usize) {
    (at, u64::from_le_bytes(b[at + 8..at + 16].try_into().unwrap()) as usize)
}

/// The `SKEL` chunk, and the payload offsets of its `NODL` pages (level 1's, level 0's).
fn skel_and_pages(b: &[u8]) -> ((usize, usize), Vec<usize>) {
    let head = frame(b, 16);
    let skel = frame(b, (head.0 + 20 + head.1).next_multiple_of(8));
    assert_eq!(&b[skel.0..skel.0 + 4], b"SKEL");
    let (mut sub, mut pages) = (skel.0 + 16, vec![]);
    while sub < skel.0 + 16 + skel.1 {
        let s = frame(b, sub).1;
        if &b[sub..sub + 4] == b"NODL" {
            pages.push(sub + 16);
        }
        sub = (sub + 20 + s).next_multiple_of(8);
    }
    (skel, pages)
}

/// Recompute the CRCs of every top-level chunk and of SKEL's sub-chunks after an edit.
fn reseal(b: &mut [u8]) {
    let mut pos = 16usize;
    while pos + 16 <= b.len() {
        let size = frame(b, pos).1;
        if &b[pos..pos + 4] == b"SKEL" {
            let mut sub = pos + 16;
            while sub < pos + 16 + size {
                let s = frame(b, sub).1;
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

/// Open whole and top first (`Reader::open_top`, then `complete`); each reads node 0.
fn both_opens(b: &[u8]) -> [Result<Reader<Cursor<&[u8]>>, String>; 2] {
    fn read<S: format::ByteSource>(r: strata::error::Result<Reader<S>>) -> Result<Reader<S>, String> {
        r.and_then(|r| r.read_node(0).map(|_| r)).map_err(|e| e.to_string())
    }
    let whole = read(Reader::open(Cursor::new(b)));
    let top = read(Reader::open_top(Cursor::new(b), Path::new("top")).and_then(|mut r| r.complete().map(|_| r)));
    [whole, top]
}

/// The DAG's structure: groups' levels, outputs and children, each node's consumer and source.
type Structure = (Vec<(u32, std::ops::Range<u32>, Vec<u32>)>, Vec<u32>, Vec<u32>);

fn structure<S: format::ByteSource>(rd: &Reader<S>) -> Structure {
    let d = rd.dag().expect("a format-4 file has a DAG");
    let groups = (0..d.groups.len() as u32).map(|g| (d.groups[g as usize].level, d.outputs(g), d.children(g).to_vec())).collect();
    (groups, d.consumer.clone(), d.source.clone())
}

/// A face as its corners' positions, turned so that the smallest comes first.
fn faces(g: &format::NodeGeometry) -> Vec<[[f32; 3]; 3]> {
    let mut out: Vec<[[f32; 3]; 3]> = g
        .indices
        .chunks_exact(3)
        .map(|t| {
            let p = [0, 1, 2].map(|k| g.positions[t[k] as usize].to_array());
            let first = (0..3).min_by(|&a, &b| p[a].partial_cmp(&p[b]).unwrap()).unwrap();
            [0, 1, 2].map(|k| p[(first + k) % 3])
        })
        .collect();
    out.sort_by(|a, b| a.partial_cmp(b).unwrap());
    out
}

#[test]
fn the_v4_example_of_the_spec_reads_as_its_dag() {
    let bytes = file();
    let square = CORNERS.map(|c| c.map(|x| (x as f64 * STEP) as f32));
    for rd in both_opens(&bytes) {
        let rd = rd.expect("the example opens");
        assert_eq!((rd.header().major, rd.header().minor), (4, 0));
        assert_eq!(rd.levels().len(), 2);
        assert!(rd.is_complete() && rd.nodes().len() == 3);
        let d = rd.dag().expect("a DAG");
        assert_eq!(d.groups.len(), 1);
        let g = d.groups[0];
        assert_eq!((g.level, g.first_output, g.outputs, g.children, g.error), (1, 0, 1, 2, group_error()));
        assert_eq!((g.center.to_array(), g.radius), ([0.5, 0.5, 0.0], rd.nodes()[0].radius));
        assert!(d.level_groups.len() == 2 && d.level_groups[0].is_empty() && d.level_groups[1] == (0..1));
        assert_eq!((d.outputs(0), d.children(0)), (0..1, &[1u32, 2][..]));
        assert_eq!(d.consumer, [NO_PARENT, 0, 0]);
        assert_eq!(d.source, [0, NO_PARENT, NO_PARENT]);
        let errors: Vec<f32> = rd.nodes().iter().map(|n| n.error).collect();
        assert_eq!(errors, [group_error(), quantization(), quantization()]);
        assert!(rd.nodes().iter().all(|n| n.child_count == 0 && n.neighbor_count == 0));
        for (i, corners) in NODES.iter().enumerate() {
            let g = rd.read_node(i as u32).expect("node decodes");
            let want = format::NodeGeometry {
                positions: corners.iter().flatten().map(|&c| square[c].into()).collect(),
                indices: (0..3 * corners.len() as u32).collect(),
                ..Default::default()
            };
            assert_eq!(faces(&g), faces(&want), "node {i}");
            assert_eq!(g.positions.len(), if i == 0 { 4 } else { 3 }, "node {i}");
            let clusters: Vec<_> = g.clusters.iter().map(|c| (c.first_face, c.face_count)).collect();
            assert_eq!(clusters, if i == 0 { vec![] } else { vec![(0, 1)] }, "node {i}");
        }
    }
    let v = format::verify(Cursor::new(&bytes), Path::new("example"));
    assert!(v.is_sound(), "{:?}", v.problems);
    assert_eq!(v.nodes, 3);
}

#[test]
fn broken_dag_rules_are_refused() {
    let damaged = |edit: &dyn Fn(&mut Vec<u8>, usize, usize)| {
        let mut b = file();
        let (_, pages) = skel_and_pages(&b);
        edit(&mut b, pages[0], pages[1]);
        reseal(&mut b);
        b
    };
    // (a) Node 1 names group 1 of level 1, which has one group.
    let b = damaged(&|b, _, bottom| b[bottom + 4..bottom + 8].copy_from_slice(&1u32.to_le_bytes()));
    for e in both_opens(&b) {
        let e = e.err().expect("a consumer past the level above's groups");
        assert!(e.contains("consumer 1"), "{e}");
    }
    // (b) The group says 3 children; two nodes name it.
    let b = damaged(&|b, top, _| b[top + 8..top + 12].copy_from_slice(&3u32.to_le_bytes()));
    for e in both_opens(&b) {
        let e = e.err().expect("a children count no node list matches");
        assert!(e.contains("3 children stored, 2 nodes name it"), "{e}");
    }
    // (c) The group's error (and so node 0's) below its children's.
    let low = quantization() / 2.0;
    let b = damaged(&|b, top, _| {
        b[top + 12..top + 16].copy_from_slice(&low.to_le_bytes());
        b[top + 4 + 24 + 36..top + 4 + 24 + 40].copy_from_slice(&low.to_le_bytes());
    });
    let v = format::verify(Cursor::new(&b), Path::new("low"));
    let said: Vec<String> = v.problems.iter().map(|e| e.to_string()).collect();
    assert!(said.len() == 2 && said.iter().all(|e| e.contains("group 0") && e.contains("is smaller than child")), "{said:?}");
}

#[test]
fn every_damaged_skeleton_byte_is_refused() {
    let bytes = file();
    let ((skel, size), _) = skel_and_pages(&bytes);
    let end = (skel + 20 + size).next_multiple_of(8);
    for k in skel..end {
        for bit in 0..8 {
            let mut b = bytes.clone();
            b[k] ^= 1 << bit;
            let opened = both_opens(&b).map(|r| r.is_ok());
            // SKEL's flags and padding are not the reader's to check (strata-v2.md §4.3): verify's.
            if (skel + 4..skel + 8).contains(&k) || k >= skel + 20 + size {
                assert!(!format::verify(Cursor::new(&b), Path::new("flipped")).is_sound(), "byte {k} bit {bit}");
            } else {
                assert_eq!(opened, [false; 2], "byte {k} bit {bit}");
            }
        }
    }
}

#[test]
fn a_resealed_damaged_page_is_refused_or_keeps_the_dag() {
    // With every CRC made right, the page's own checks must refuse any change to the DAG's
    // structure; a changed value (error, sphere, box, cone) may open, and verify judges it.
    let bytes = file();
    let want = structure(&Reader::open(Cursor::new(&bytes[..])).unwrap());
    let (_, pages) = skel_and_pages(&bytes);
    for k in pages.iter().flat_map(|&at| at..at + frame(&bytes, at - 16).1) {
        for bit in 0..8 {
            let mut b = bytes.clone();
            b[k] ^= 1 << bit;
            reseal(&mut b);
            if let Ok(rd) = Reader::open(Cursor::new(&b[..])) {
                assert_eq!(structure(&rd), want, "byte {k} bit {bit}");
            }
            format::verify(Cursor::new(&b), Path::new("resealed"));
        }
    }
}
