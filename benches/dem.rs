//! Elevation grid import speed against the PLY importer, measured in the same run: grid cells per
//! second (each cell two faces) on the SRTM tile and the ESRI ASCII grid of ../shared/meshes/dem,
//! against faces per second reading the binary PLY CT head of ../shared/meshes/large. Both include
//! cleaning (welding, face normals). The goal: cells/s at least the PLY importer's faces/s.
//!
//! `cargo bench --bench dem`; skipped when the shared meshes are absent.

use std::path::Path;
use std::time::Instant;
use strata::import::{import_with, ImportOptions};

/// Best of `runs` imports of `path`: (milliseconds, faces, grid cells).
fn best(path: &Path, runs: usize) -> (f64, usize, usize) {
    let mut best = f64::INFINITY;
    let (mut faces, mut cells) = (0, 0);
    for _ in 0..runs {
        let start = Instant::now();
        let imported = import_with(path, &ImportOptions::default()).expect("import");
        best = best.min(start.elapsed().as_secs_f64() * 1e3);
        faces = imported.mesh.face_count();
        cells = imported.grid.map_or(0, |g| (g.cols - 1) * (g.rows - 1));
    }
    (best, faces, cells)
}

fn main() {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes");
    let ply = shared.join("large/cthead_skin_native.ply");
    if !ply.exists() {
        println!("skipping: ../shared/meshes not found");
        return;
    }
    let (ms, faces, _) = best(&ply, 5);
    let ply_rate = faces as f64 / ms * 1e3;
    println!("{:<40} {:>9} {:>10} {:>14} {:>8}", "file", "ms", "units", "per second", "vs PLY");
    println!("{:<40} {:>9.1} {:>10} {:>10.2}M f/s {:>8}", "cthead_skin_native.ply (faces)", ms, faces, ply_rate / 1e6, "1.00");
    for name in
        ["dem/riptide_N40W074.hgt", "dem/landlab_SRTMGL3_boulder_758x758.asc", "dem/pysheds_dem.tif", "dem/derived_boulder_758x758_u16.png"]
    {
        let path = shared.join(name);
        if !path.exists() {
            continue;
        }
        let (ms, _, cells) = best(&path, 5);
        let rate = cells as f64 / ms * 1e3;
        println!("{:<40} {:>9.1} {:>10} {:>10.2}M c/s {:>8.2}", format!("{name} (cells)"), ms, cells, rate / 1e6, rate / ply_rate);
    }
}
