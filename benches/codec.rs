//! How small node geometry can get (issue 15, format 3), measured before a codec is chosen: every
//! node of a file re-encoded with meshoptimizer's index and vertex codecs, positions quantized on a
//! step tied to the node's error (coarse levels coarser) and normals octahedral in 8 + 8 bits, with
//! and without deflate after, against the bytes of the same nodes in the file (format 3 when
//! converted here with default options), in the same run; and
//! how fast meshoptimizer decodes them. Bytes are per input face, all levels, like `strata convert`
//! reports; the goal of issue 15 is 4.0 (Corto: 4.48 on the CT head).
//!
//! A position step is `max(extent / 2^bits, error / 2)`: a stored position moves by at most
//! √3/2 of it, so a node's error grows by at most √3/4 ≈ 0.43 of itself, plus the level-0 floor.
//!
//! `cargo bench --bench codec [-- file.strata ...]`; without arguments the bunny, the gargoyle and
//! the CT head of ../shared/meshes, converted with defaults, when present.

#[path = "common/convert.rs"]
mod convert;
use convert::convert;

use flate2::{write::DeflateEncoder, Compression};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;
use strata::format::{octa, Reader};

fn deflated(bytes: &[u8]) -> usize {
    let mut e = DeflateEncoder::new(Vec::new(), Compression::best());
    e.write_all(bytes).expect("in memory");
    e.finish().expect("in memory").len()
}

/// One node's encoded streams: indices, positions, normals, colors.
struct Encoded {
    streams: [Vec<u8>; 4],
    vertices: usize,
    indices: usize,
}

fn encode(g: &strata::format::NodeGeometry, step: f64) -> Encoded {
    let n = g.positions.len();
    let mut indices = meshopt::optimize_vertex_cache(&g.indices, n);
    let remap = meshopt::optimize_vertex_fetch_remap(&indices, n);
    for i in &mut indices {
        *i = remap[*i as usize];
    }
    let mut order = vec![0usize; n];
    for (old, &new) in remap.iter().enumerate() {
        if (new as usize) < n {
            order[new as usize] = old;
        }
    }
    let min = g.positions.iter().fold(glam::DVec3::splat(f64::MAX), |m, p| m.min(p.as_dvec3()));
    let positions: Vec<[u32; 3]> =
        order.iter().map(|&v| ((g.positions[v].as_dvec3() - min) / step).round().to_array().map(|c| c.max(0.0) as u32)).collect();
    let normals: Vec<[u8; 4]> = if g.normals.is_empty() {
        Vec::new()
    } else {
        order.iter().map(|&v| octa::encode(g.normals[v])).map(|[a, b]| [(a >> 8) as u8, (b >> 8) as u8, 0, 0]).collect()
    };
    let colors: Vec<[u8; 4]> = if g.colors.is_empty() { Vec::new() } else { order.iter().map(|&v| g.colors[v]).collect() };
    let streams = [
        meshopt::encode_index_buffer(&indices, n).expect("indices"),
        meshopt::encode_vertex_buffer(&positions).expect("positions"),
        if normals.is_empty() { Vec::new() } else { meshopt::encode_vertex_buffer(&normals).expect("normals") },
        if colors.is_empty() { Vec::new() } else { meshopt::encode_vertex_buffer(&colors).expect("colors") },
    ];
    Encoded { streams, vertices: n, indices: indices.len() }
}

fn main() {
    let mut files: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if files.is_empty() {
        let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes");
        for m in ["scans/stanford_bun_zipper.ply", "scans/3dhop_gargo.ply", "large/cthead_skin_native.ply"] {
            if shared.join(m).exists() {
                files.push(convert(&shared.join(m), "codec"));
            } else {
                println!("skipping {m}: ../shared/meshes not found");
            }
        }
    }
    println!(
        "{:<22} {:>5} {:>9} {:>12} {:>12} {:>11} {:>11} {:>11} {:>12}",
        "file", "bits", "in file", "meshopt", "+deflate", "indices", "positions", "normals", "decode Mf/s"
    );
    for f in &files {
        let rd = Reader::open_path(f).expect("open");
        let h = rd.header().clone();
        let extent = (h.max - h.min).max_element() as f64;
        let input_faces = h.input_faces as f64;
        let geometries: Vec<_> = (0..rd.nodes().len() as u32).map(|i| (rd.nodes()[i as usize], rd.read_node(i).expect("node"))).collect();
        let in_file: u64 = geometries.iter().map(|(n, _)| n.size as u64).sum();
        let name = f.file_name().unwrap().to_string_lossy().replace("strata-codec-", "");
        let name = name.rsplit_once('-').map_or(name.as_str(), |(a, _)| a).to_string();
        for bits in [14u32, 16] {
            let floor = extent / f64::from(1u32 << bits);
            let encoded: Vec<Encoded> = geometries.iter().map(|(n, g)| encode(g, floor.max(0.5 * f64::from(n.error)))).collect();
            let per = |k: usize| encoded.iter().map(|e| e.streams[k].len()).sum::<usize>() as f64 / input_faces;
            let raw: f64 = (0..4).map(per).sum();
            let packed =
                encoded.iter().map(|e| e.streams.iter().map(|s| if s.is_empty() { 0 } else { deflated(s) }).sum::<usize>()).sum::<usize>()
                    as f64
                    / input_faces;
            // Decode speed: every node's index and vertex streams, faces of all levels per second.
            let start = Instant::now();
            let mut faces = 0usize;
            for e in &encoded {
                let ix: Vec<u32> = meshopt::decode_index_buffer(&e.streams[0], e.indices).expect("decode");
                let p: Vec<[u32; 3]> = meshopt::decode_vertex_buffer(&e.streams[1], e.vertices).expect("decode");
                if !e.streams[2].is_empty() {
                    let nn: Vec<[u8; 4]> = meshopt::decode_vertex_buffer(&e.streams[2], e.vertices).expect("decode");
                    std::hint::black_box(nn);
                }
                faces += ix.len() / 3;
                std::hint::black_box((ix, p));
            }
            let rate = faces as f64 / start.elapsed().as_secs_f64() / 1e6;
            println!(
                "{:<22} {:>5} {:>9.2} {:>12.2} {:>12.2} {:>11.2} {:>11.2} {:>11.2} {:>12.1}",
                name,
                bits,
                in_file as f64 / input_faces,
                raw,
                packed,
                per(0),
                per(1),
                per(2) + per(3),
                rate
            );
        }
    }
}
