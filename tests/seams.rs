//! Mixed-level fronts drawn with their seams (selection.md §8) leave no crack: along an orbit that
//! moves in from far, the front the streamer selects at 1 px, drawn with the software renderer,
//! leaves no pixel the full model covers to an enclosed background (`render::crack_pixels`); drawn
//! without its seams, it does. Holes of the model itself stay open.

use std::path::{Path, PathBuf};
use strata::format::Reader;
use strata::mesh::Mesh;
use strata::pipeline::{convert, ConvertOptions, Silent};
use strata::render::{crack_pixels, Image};
use strata::stream::{session, Budgets, Streamer};

const W: u32 = 640;
const H: u32 = 480;
const FRAMES: usize = 32;

fn converted(mesh: &Path, name: &str) -> PathBuf {
    let out = std::env::temp_dir().join(format!("strata-seams-{name}-{}.strata", std::process::id()));
    convert(mesh, &Default::default(), &out, &ConvertOptions::default(), &mut Silent).expect("convert");
    out
}

fn draw(camera: &strata::camera::Camera, parts: &[(&[glam::Vec3], &[u32])]) -> Image {
    let mut img = Image::new(W, H);
    for (p, i) in parts {
        img.draw(camera, p, &[], i, [200, 200, 200, 255]);
    }
    img
}

/// Over the orbit: crack pixels without and with seams, frames of more than one level, and the
/// largest area of a frame's seams as a share of the model's.
fn orbit(file: &Path) -> (u64, u64, usize, f64) {
    let rd = Reader::open_path(file).expect("open");
    let full = strata::assemble::to_mesh(&rd, 0).expect("level 0");
    let h = rd.header().clone();
    let (center, radius) = (0.5 * (h.min + h.max), 0.5 * (h.max - h.min).length());
    let full_indices: Vec<u32> = full.triangles.iter().flatten().copied().collect();
    let mut s = Streamer::new(rd, Budgets::default()).expect("streamer");
    let area = |p: &[glam::Vec3], t: &[u32]| -> f64 {
        t.chunks_exact(3)
            .map(|f| 0.5 * (p[f[1] as usize] - p[f[0] as usize]).cross(p[f[2] as usize] - p[f[0] as usize]).length() as f64)
            .sum()
    };
    let model = area(&full.positions, &full_indices);
    let (mut open, mut sealed, mut mixed, mut widest) = (0, 0, 0, 0.0f64);
    for i in 0..FRAMES {
        let camera = session::orbit(center, radius, i, FRAMES, W, H);
        let report = s.update(&camera, None).expect("frame");
        if report.stats.levels.iter().filter(|&&n| n > 0).count() > 1 {
            mixed += 1;
        }
        let mut parts: Vec<(&[glam::Vec3], &[u32])> =
            s.front().iter().filter_map(|&n| s.geometry(n)).map(|g| (&g.positions[..], &g.indices[..])).collect();
        let reference = draw(&camera, &[(&full.positions, &full_indices)]);
        let alone = draw(&camera, &parts);
        parts.push((&s.seams().positions, &s.seams().indices));
        let with = draw(&camera, &parts);
        open += crack_pixels(&alone, &reference);
        sealed += crack_pixels(&with, &reference);
        widest = widest.max(area(&s.seams().positions, &s.seams().indices) / model);
    }
    (open, sealed, mixed, widest)
}

#[test]
fn seams_close_the_cracks_of_mixed_fronts() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let file = converted(&root.join("fixtures/noisy_sphere.ply"), "sphere");
    let (open, sealed, mixed, widest) = orbit(&file);
    let _ = std::fs::remove_file(&file);
    eprintln!("noisy sphere: {open} crack pixels, {sealed} with seams; seams at most {widest:.2e} of the area");
    assert!(mixed >= FRAMES / 2, "{mixed} fronts of several levels: the orbit should mostly show mixed fronts");
    assert!(open > 0, "without seams the measure finds cracks (it can fail)");
    assert_eq!(sealed, 0, "crack pixels with seams ({open} without)");
}

#[test]
fn seams_leave_holes_of_the_model_open() {
    // The noisy sphere with a cap cut away: a hole much wider than any level's error.
    let mut m: Mesh = strata::fixtures::noisy_sphere(40, 0.05, 7);
    m.compute_face_geometry();
    let keep: Vec<usize> =
        (0..m.face_count()).filter(|&f| m.triangles[f].iter().all(|&v| m.positions[v as usize].normalize().z < 0.8)).collect();
    let m = m.subset(&keep);
    let input = std::env::temp_dir().join(format!("strata-seams-holed-{}.ply", std::process::id()));
    strata::export::write(&input, &m).expect("write");
    let file = converted(&input, "holed");
    let (open, sealed, mixed, widest) = orbit(&file);
    let _ = (std::fs::remove_file(&file), std::fs::remove_file(&input));
    eprintln!("holed sphere: {open} crack pixels, {sealed} with seams; seams at most {widest:.2e} of the area");
    assert!(mixed > 0);
    assert_eq!(sealed, 0);
    // The hole is a tenth of the sphere's area: filled, it would be more than the seams' 2 %.
    assert!(widest < 0.02, "seams of {widest} of the model's area: the hole was filled");
}
