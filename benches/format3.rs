//! Format 3 (issue 15, in progress) against format 2, converted from the same meshes in the same
//! run: bytes per input face (all levels, as `strata convert` reports), where format 3's bits go,
//! how often each connectivity symbol occurs, and how fast each format's node geometry decodes
//! (one core, positions, normals and indices into arrays, from bytes in memory). The goal of issue
//! 15 is 4.0 bytes per input face and 50M faces/s; Corto (Nexus) reaches 4.48 on the CT head.
//!
//! `cargo bench --bench format3 [-- mesh ...]`; without arguments the bunny, the gargoyle and the
//! CT head of ../shared/meshes when present, else the noisy-sphere fixture. `STRATA_GRID_BITS`,
//! `STRATA_LATTICE`, `STRATA_NORMAL_BITS` and `STRATA_COLOR_BITS` set format 3's precision, and
//! `STRATA_GEOMETRY_NORMALS=A` converts both formats with `--normals geometry --crease-angle A`.

use std::path::{Path, PathBuf};
use std::time::Instant;
use strata::format::geom::{self, v3};
use strata::format::Reader;
use strata::pipeline::{convert, ConvertOptions, Normals, Silent};
use strata::write::{Encoding, Precision};

fn write(input: &Path, encoding: Encoding, normals: Normals, tag: &str) -> (PathBuf, strata::format::WriteSummary) {
    let name = input.file_stem().unwrap().to_string_lossy();
    let out = std::env::temp_dir().join(format!("strata-format3-{name}-{tag}-{}.strata", std::process::id()));
    let opts = ConvertOptions { encoding, normals, ..ConvertOptions::default() };
    let s = convert(input, &Default::default(), &out, &opts, &mut Silent).expect("convert").summary;
    (out, s)
}

/// Decode every node `rounds` times; faces of all levels per second.
fn decode_rate(path: &Path, rounds: usize) -> f64 {
    let rd = Reader::open_path(path).expect("open");
    let chunks: Vec<Vec<u8>> = rd.nodes().iter().map(|n| rd.read_at(n.offset, n.size as u64).expect("read")).collect();
    let faces: u64 = rd.nodes().iter().map(|n| n.faces as u64).sum();
    let start = Instant::now();
    for _ in 0..rounds {
        for (i, bytes) in chunks.iter().enumerate() {
            let ctx = rd.node_context(i as u32, &rd.nodes()[i]);
            std::hint::black_box(geom::decode(&ctx, bytes).expect("decode"));
        }
    }
    (faces * rounds as u64) as f64 / start.elapsed().as_secs_f64()
}

/// The camera of the image measure, from the format-2 file `frame` (the same for both formats:
/// coarse lattices widen format 3's bounds), moved sideways by `shift` pixels: `strata render`'s
/// default view of the whole model, or (`closeup`) the view where a full-detail front is what a
/// 1-pixel error selects: the median node error of level 1 spans a pixel, looking at the level-0
/// vertex farthest toward the default view direction.
fn camera(frame: &Path, size: u32, shift: f32, closeup: bool) -> strata::camera::Camera {
    let rd = Reader::open_path(frame).expect("open");
    let h = rd.header().clone();
    let (center, radius) = ((h.min + h.max) * 0.5, (h.max - h.min).length() * 0.5);
    let fov = 45f32.to_radians();
    let dir = glam::Vec3::new(0.3, 0.4, 1.0).normalize();
    let mut c = strata::camera::Camera::framing(center, radius, dir, fov, size, size);
    if closeup && h.levels > 1 {
        let mut errors: Vec<f32> = rd.level_nodes(1).map(|i| rd.nodes()[i as usize].error).collect();
        errors.sort_by(f32::total_cmp);
        let median = errors[errors.len() / 2];
        let distance = median * size as f32 / (2.0 * (0.5 * fov).tan());
        let front = rd
            .level_nodes(0)
            .flat_map(|i| rd.read_node(i).expect("node").positions)
            .max_by(|a, b| a.dot(dir).total_cmp(&b.dot(dir)))
            .expect("a vertex");
        c.target = front;
        c.eye = front + dir * distance;
        (c.near, c.far) = (distance * 1e-3, distance + 2.0 * radius);
    }
    let pixel = 2.0 * (c.target - c.eye).length() * (0.5 * fov).tan() / size as f32;
    let right = (c.target - c.eye).cross(c.up).normalize();
    c.eye += right * pixel * shift;
    c.target += right * pixel * shift;
    c
}

/// Level 0 of a file drawn with `camera`.
fn level0_image(path: &Path, camera: &strata::camera::Camera) -> strata::render::Image {
    let rd = Reader::open_path(path).expect("open");
    let mut image = strata::render::Image::new(camera.width, camera.height);
    for node in rd.level_nodes(0) {
        let g = rd.read_node(node).expect("node");
        image.draw(camera, &g.positions, &g.normals, &g.indices, [200, 200, 200, 255]);
    }
    image
}

/// The symbols of the connectivity alphabets, from the file's tables: each symbol's share.
fn connectivity(path: &Path) -> Vec<(String, f64)> {
    let rd = Reader::open_path(path).expect("open");
    let Some(code) = &rd.skeleton().code else { return Vec::new() };
    let mut shares = [0f64; v3::sym::COUNT];
    for c in 0..8 {
        for (s, &f) in code.tables.freqs[v3::alphabet::CONN + c].0.iter().enumerate() {
            if s < shares.len() {
                shares[s] += f as f64;
            }
        }
    }
    let total: f64 = shares.iter().sum();
    v3::sym::NAMES.iter().zip(shares).map(|(n, x)| (n.to_string(), x / total)).collect()
}

fn main() {
    let mut inputs: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if inputs.is_empty() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let shared = root.join("../shared/meshes");
        for m in ["scans/stanford_bun_zipper.ply", "scans/3dhop_gargo.ply", "large/cthead_skin_native.ply"] {
            if shared.join(m).exists() {
                inputs.push(shared.join(m));
            }
        }
        if inputs.is_empty() {
            println!("../shared/meshes not found: the noisy-sphere fixture only");
            inputs.push(root.join("fixtures/noisy_sphere.ply"));
        }
    }
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f32>().ok());
    let d = Precision::default();
    let p = Precision {
        grid_bits: env("STRATA_GRID_BITS").map_or(d.grid_bits, |v| v as u32),
        lattice: env("STRATA_LATTICE").unwrap_or(d.lattice),
        normal_bits: env("STRATA_NORMAL_BITS").map_or(d.normal_bits, |v| v as u32),
        uv_bits: d.uv_bits,
        color_bits: env("STRATA_COLOR_BITS").map_or(d.color_bits, |v| v as u32),
    };
    // `--normals geometry` at this crease angle (degrees).
    let geometry_normals = env("STRATA_GEOMETRY_NORMALS");
    println!(
        "format 3 at grid {} bits, lattice {} of the error, normals {} bits{}, UVs {} bits",
        p.grid_bits,
        p.lattice,
        p.normal_bits,
        geometry_normals.map_or(String::new(), |a| format!(" of each level's geometry, creases at {a}°")),
        p.uv_bits
    );
    for input in &inputs {
        let name = input.file_name().unwrap().to_string_lossy();
        let normals = geometry_normals.map_or(ConvertOptions::default().normals, |a| Normals::Geometry { crease_angle: a.to_radians() });
        let (f2, s2) = write(input, Encoding::V2, normals, "2");
        let (f3, s3) = write(input, Encoding::V3(p), normals, "3");
        let faces = s3.input_faces as f64;
        let bits = Reader::open_path(&f3).expect("open").header().grid.bits;
        println!("\n{name}: {} input faces, {} nodes, format 3 grid {bits} bits", s3.input_faces, s3.nodes);
        println!(
            "  bytes per input face: format 2 {:.2}, format 3 {:.2} ({:.2}×; skeleton {:.2})",
            s2.bytes_per_face(),
            s3.bytes_per_face(),
            s2.bytes_per_face() / s3.bytes_per_face(),
            s3.skeleton_bytes as f64 / faces
        );
        if let Some(by_alphabet) = s3.geometry_bits {
            let mut bits = [0f64; v3::STAT_NAMES.len()];
            for (al, b) in by_alphabet.iter().enumerate() {
                bits[v3::category(al)] += b;
            }
            let parts: Vec<String> =
                v3::STAT_NAMES.iter().zip(bits).filter(|(_, b)| *b > 0.0).map(|(n, b)| format!("{n} {:.2}", b / 8.0 / faces)).collect();
            println!("  format 3 geometry, bytes per input face: {}", parts.join(", "));
            let parts: Vec<String> = (0..v3::alphabet::ALPHABETS)
                .zip(by_alphabet)
                .filter(|(_, b)| *b > 0.0)
                .map(|(n, b)| format!("{} {:.3}", v3::alphabet_name(n), b / 8.0 / faces))
                .collect();
            println!("  by alphabet: {}", parts.join(", "));
        }
        // The image measure: level 0 of format 3 against format 2's from the same camera, and, as
        // the yardstick of what cannot be told apart, format 2's against itself seen from a
        // quarter of a pixel to the side; over the whole model, and close up where level 0 is
        // what a 1-pixel error selects.
        for closeup in [false, true] {
            let (c, moved) = (camera(&f2, 1024, 0.0, closeup), camera(&f2, 1024, 0.25, closeup));
            let (i2, i3, i2m) = (level0_image(&f2, &c), level0_image(&f3, &c), level0_image(&f2, &moved));
            let share = |a, b, t| 100.0 * strata::render::changed_share(a, b, t);
            println!(
                "  level 0 {}, covered pixels changed by more than 8 and 32 of 255: format 3 {:.3} % and {:.3} %; format 2 a quarter pixel aside {:.3} % and {:.3} %",
                if closeup { "close up at 1 px" } else { "whole at 1024²" },
                share(&i2, &i3, 8),
                share(&i2, &i3, 32),
                share(&i2, &i2m, 8),
                share(&i2, &i2m, 32)
            );
        }
        // Sampled surface distance (fractions of the bounding-box diagonal, mean and largest):
        // level 0 of each format to the input, and each level of format 3 to the same level of
        // format 2, whose positions are the grid's without the lattices' and the codec's rounding.
        let input_mesh = strata::import::import(input, None).expect("import").mesh;
        let (rd2, rd3) = (Reader::open_path(&f2).expect("open"), Reader::open_path(&f3).expect("open"));
        let level = |rd: &Reader<std::fs::File>, l: u32| strata::assemble::to_mesh(rd, l).expect("level");
        let diag = input_mesh.diagonal();
        let d = |a: &strata::mesh::Mesh, b: &strata::mesh::Mesh| {
            let d = strata::distance::surface_distance(a, b, 20_000, 7);
            format!("{:.2e} / {:.2e}", d.mean / diag, d.max / diag)
        };
        println!(
            "  sampled distance / diagonal (mean / max), level 0 to the input: format 2 {}, format 3 {}",
            d(&level(&rd2, 0), &input_mesh),
            d(&level(&rd3, 0), &input_mesh)
        );
        let per_level: Vec<String> =
            (0..rd3.levels().len() as u32).map(|l| format!("{l}: {}", d(&level(&rd3, l), &level(&rd2, l)))).collect();
        println!("  each level of format 3 to its format-2 self: {}", per_level.join(", "));
        drop((rd2, rd3));
        let rounds = (2_000_000.0 / faces).ceil().max(1.0) as usize;
        let (r2, r3) = (decode_rate(&f2, rounds), decode_rate(&f3, rounds));
        println!("  decode, M faces/s (one core): format 2 {:.1}, format 3 {:.1}", r2 / 1e6, r3 / 1e6);
        let shares: Vec<String> = connectivity(&f3).iter().map(|(n, x)| format!("{n} {:.1} %", 100.0 * x)).collect();
        println!("  connectivity symbols (table shares, all contexts summed): {}", shares.join(", "));
        let _ = (std::fs::remove_file(&f2), std::fs::remove_file(&f3));
    }
}
