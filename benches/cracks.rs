//! Cracks in mixed-level fronts (issue 14, METHOD.md §8): along an orbit, the front `Streamer`
//! selects at 1 px is drawn beside the full-detail model from the same camera, and pixels that the
//! full model covers but the front leaves to the background, enclosed by the front's own pixels (not
//! reachable from the picture's edge through background), are counted: pinholes where a node meets
//! a neighbour of another level along a border they do not share. Silhouette differences reach the
//! edge and are not counted. The peer is the full-detail model, drawn in the same run. Fronts of
//! one level cannot crack; what they show (a coarse level's own notches) is printed apart, as the
//! floor of the measure.
//!
//! `cargo bench --bench cracks [-- file.strata ...]`; without arguments the shipped noisy sphere
//! and, when present, the bunny and the CT head of ../shared/meshes, converted with defaults.

use std::path::{Path, PathBuf};
use strata::camera::Camera;
use strata::format::Reader;
use strata::render::{Image, BACKGROUND};
use strata::stream::{session, Budgets, Streamer};

const W: u32 = 640;
const H: u32 = 480;
const FRAMES: usize = 32;

fn convert(input: &Path) -> PathBuf {
    let out =
        std::env::temp_dir().join(format!("strata-cracks-{}-{}.strata", input.file_stem().unwrap().to_string_lossy(), std::process::id()));
    let opts = strata::pipeline::ConvertOptions::default();
    strata::pipeline::convert(input, &Default::default(), &out, &opts, &mut strata::pipeline::Silent).expect("convert");
    out
}

/// Background pixels of `img` not connected to the picture's edge through background.
fn enclosed(img: &Image) -> Vec<bool> {
    let (w, h) = (img.width as usize, img.height as usize);
    let bg: Vec<bool> = img.rgba.chunks_exact(4).map(|p| p == BACKGROUND).collect();
    let mut outside = vec![false; w * h];
    let mut stack: Vec<usize> = (0..w).flat_map(|x| [x, (h - 1) * w + x]).chain((0..h).flat_map(|y| [y * w, y * w + w - 1])).collect();
    while let Some(i) = stack.pop() {
        if outside[i] || !bg[i] {
            continue;
        }
        outside[i] = true;
        let (x, y) = (i % w, i / w);
        if x > 0 {
            stack.push(i - 1);
        }
        if x + 1 < w {
            stack.push(i + 1);
        }
        if y > 0 {
            stack.push(i - w);
        }
        if y + 1 < h {
            stack.push(i + w);
        }
    }
    bg.iter().zip(&outside).map(|(&b, &o)| b && !o).collect()
}

fn draw(camera: &Camera, mesh: &strata::Mesh) -> Image {
    let mut img = Image::new(W, H);
    let positions: Vec<glam::Vec3> = mesh.triangles.iter().flatten().map(|&v| mesh.positions[v as usize]).collect();
    let indices: Vec<u32> = (0..positions.len() as u32).collect();
    img.draw(camera, &positions, &[], &indices, [200, 200, 200, 255]);
    img
}

fn main() {
    let mut files: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if files.is_empty() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        files.push(convert(&root.join("fixtures/noisy_sphere.ply")));
        for shared in ["scans/stanford_bun_zipper.ply", "large/cthead_skin_native.ply"] {
            let p = root.join("../shared/meshes").join(shared);
            if p.exists() {
                files.push(convert(&p));
            } else {
                println!("skipping {}: not found", p.display());
            }
        }
    }
    println!(
        "{:<28} {:>6} {:>6} {:>12} {:>9} {:>13} {:>11} {:>15}",
        "file", "frames", "mixed", "with cracks", "crack px", "max px/frame", "of covered", "one-level px"
    );
    for f in files {
        let rd = Reader::open_path(&f).expect("open");
        let full = strata::assemble::to_mesh(&rd, 0).expect("level 0");
        let h = rd.header().clone();
        let (center, radius) = (0.5 * (h.min + h.max), 0.5 * (h.max - h.min).length());
        let mut streamer = Streamer::new(rd, Budgets::default()).expect("streamer");
        let (mut mixed, mut cracked, mut total, mut worst, mut covered, mut floor) = (0, 0, 0u64, 0u64, 0u64, 0u64);
        for i in 0..FRAMES {
            let camera = session::orbit(center, radius, i, FRAMES, W, H);
            let report = streamer.update(&camera, None).expect("frame");
            let levels = report.stats.levels.iter().filter(|&&n| n > 0).count();
            let front = draw(&camera, &streamer.front_mesh().expect("front"));
            let reference = draw(&camera, &full);
            let holes = enclosed(&front);
            let cracks = holes.iter().zip(reference.depth.iter()).filter(|(&h, d)| h && d.is_finite()).count() as u64;
            if levels < 2 {
                floor += cracks;
                continue;
            }
            mixed += 1;
            cracked += usize::from(cracks > 0);
            total += cracks;
            worst = worst.max(cracks);
            covered += reference.depth.iter().filter(|d| d.is_finite()).count() as u64;
        }
        let name = f.file_name().unwrap().to_string_lossy().replace("strata-cracks-", "");
        println!(
            "{:<28} {:>6} {:>6} {:>12} {:>9} {:>13} {:>10.4}% {:>15}",
            name.split('-').next().unwrap_or(&name),
            FRAMES,
            mixed,
            cracked,
            total,
            worst,
            100.0 * total as f64 / covered.max(1) as f64,
            floor
        );
    }
}
