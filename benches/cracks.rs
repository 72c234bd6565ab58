//! Cracks in mixed-level fronts (issue 14, METHOD.md §8): along an orbit, the front `Streamer`
//! selects at 1 px is drawn beside the full-detail model from the same camera, and pixels that the
//! full model covers but the front leaves to the background, enclosed by the front's own pixels (not
//! reachable from the picture's edge through background), are counted: pinholes where a node meets
//! a neighbour of another level along a border they do not share. Silhouette differences reach the
//! edge and are not counted. The peer is the full-detail model, drawn in the same run. Fronts of
//! one level cannot crack; what they show (a coarse level's own notches) is printed apart, as the
//! floor of the measure. The same fronts are drawn again with the streamer's seams
//! (`strata::stream::seams`, selection.md §8), which close those slivers.
//!
//! `cargo bench --bench cracks [-- file.strata ...]`; without arguments the shipped noisy sphere
//! and, when present, the bunny and the CT head of ../shared/meshes, converted with defaults as a
//! tree (format 3) and as a DAG (format 4, `strata convert --dag`: `dag-` in the name), and as a DAG
//! built partitioned (`part-dag-`).

#[path = "common/convert.rs"]
mod convert;
use convert::convert_with;

use std::path::{Path, PathBuf};
use strata::camera::Camera;
use strata::format::Reader;
use strata::render::{crack_pixels, Image};
use strata::stream::seams::Seams;
use strata::stream::{session, Budgets, Streamer};

const W: u32 = 640;
const H: u32 = 480;
const FRAMES: usize = 32;

fn draw(camera: &Camera, mesh: &strata::Mesh, seams: Option<&Seams>) -> Image {
    let mut img = Image::new(W, H);
    let positions: Vec<glam::Vec3> = mesh.triangles.iter().flatten().map(|&v| mesh.positions[v as usize]).collect();
    let indices: Vec<u32> = (0..positions.len() as u32).collect();
    img.draw(camera, &positions, &[], &indices, [200, 200, 200, 255]);
    if let Some(s) = seams {
        img.draw(camera, &s.positions, &[], &s.indices, [200, 200, 200, 255]);
    }
    img
}

fn main() {
    let mut files: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if files.is_empty() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut inputs = vec![root.join("fixtures/noisy_sphere.ply")];
        for shared in ["scans/stanford_bun_zipper.ply", "large/cthead_skin_native.ply"] {
            let p = root.join("../shared/meshes").join(shared);
            if p.exists() {
                inputs.push(p);
            } else {
                println!("skipping {}: not found", p.display());
            }
        }
        // Each as a tree (format 3) and as a DAG (format 4, `--dag`), which should need no seams,
        // in memory and partitioned into cells (at 16 MB the small meshes make about ten, at 64 MB
        // the CT head thirteen), whose borders the DAG's fronts cross without cracks too.
        use strata::pipeline::{Build, ConvertOptions};
        for p in &inputs {
            let memory = if p.ends_with("cthead_skin_native.ply") { 64 << 20 } else { 16 << 20 };
            for dag in [false, true] {
                files.push(convert_with(p, "cracks", &ConvertOptions { dag, build: Build::InCore, ..Default::default() }));
            }
            files.push(convert_with(p, "cracks", &ConvertOptions { dag: true, build: Build::Partitioned, memory, ..Default::default() }));
        }
    }
    println!(
        "{:<28} {:>6} {:>6} {:>12} {:>9} {:>13} {:>11} {:>15} {:>16} {:>17}",
        "file",
        "frames",
        "mixed",
        "with cracks",
        "crack px",
        "max px/frame",
        "of covered",
        "one-level px",
        "px with seams",
        "seam faces/frame"
    );
    for f in files {
        let rd = Reader::open_path(&f).expect("open");
        let full = strata::assemble::to_mesh(&rd, 0).expect("level 0");
        let h = rd.header().clone();
        let (center, radius) = (0.5 * (h.min + h.max), 0.5 * (h.max - h.min).length());
        let mut streamer = Streamer::new(rd, Budgets::default()).expect("streamer");
        let (mut mixed, mut cracked, mut total, mut worst, mut covered, mut floor) = (0, 0, 0u64, 0u64, 0u64, 0u64);
        let (mut with_seams, mut seam_faces) = (0u64, 0u64);
        for i in 0..FRAMES {
            let camera = session::orbit(center, radius, i, FRAMES, W, H);
            let report = streamer.update(&camera, None).expect("frame");
            let levels = report.stats.levels.iter().filter(|&&n| n > 0).count();
            let mesh = streamer.front_mesh().expect("front");
            let reference = draw(&camera, &full, None);
            let cracks = crack_pixels(&draw(&camera, &mesh, None), &reference);
            let sealed = crack_pixels(&draw(&camera, &mesh, Some(streamer.seams())), &reference);
            if levels < 2 {
                floor += cracks;
                continue;
            }
            mixed += 1;
            cracked += usize::from(cracks > 0);
            total += cracks;
            worst = worst.max(cracks);
            with_seams += sealed;
            seam_faces += streamer.seams().face_count() as u64;
            covered += reference.depth.iter().filter(|d| d.is_finite()).count() as u64;
        }
        let name = f.file_stem().unwrap().to_string_lossy().replace("strata-cracks-", "");
        println!(
            "{:<28} {:>6} {:>6} {:>12} {:>9} {:>13} {:>10.4}% {:>15} {:>16} {:>17.1}",
            name.rsplit_once('-').map_or(name.as_str(), |n| n.0),
            FRAMES,
            mixed,
            cracked,
            total,
            worst,
            100.0 * total as f64 / covered.max(1) as f64,
            floor,
            with_seams,
            seam_faces as f64 / mixed.max(1) as f64
        );
    }
}
