//! Simplification, strata's quadric edge collapse against meshoptimizer's `simplify`, on the same
//! welded mesh: median time of several runs, input triangles per second, and the sampled Hausdorff
//! and mean surface distance to the input over the bounding box diagonal.
//!
//! `cargo bench --bench simplify [-- --synthetic] [-- mesh ...]`; without mesh arguments it runs on
//! the bunny (OBJ and PLY) and the large CT head in ../shared/meshes when they can be imported (and
//! says so when not); `--synthetic` (or `STRATA_BENCH_SYNTHETIC=1`) adds a procedural noisy sphere.

use std::path::{Path, PathBuf};
use std::time::Instant;
use strata::distance::{surface_distance, Distance};
use strata::mesh::Mesh;
use strata::simplify::{simplify, SimplifyOptions};

const RATIOS: [f64; 4] = [0.5, 0.1, 0.03, 0.01];
const RUNS: usize = 5;
const SAMPLES: usize = 200_000;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median wall time in seconds of `RUNS` calls, and the last result.
fn timed<T>(mut f: impl FnMut() -> T) -> (f64, T) {
    let mut times = Vec::with_capacity(RUNS);
    let mut out = None;
    for _ in 0..RUNS {
        let start = Instant::now();
        out = Some(f());
        times.push(start.elapsed().as_secs_f64());
    }
    (median(times), out.expect("RUNS > 0"))
}

/// meshoptimizer's result as a compacted positions-only mesh.
fn meshopt_simplify(mesh: &Mesh, target_faces: usize) -> Mesh {
    let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let bytes: Vec<u8> = mesh.positions.iter().flat_map(|p| p.to_array()).flat_map(f32::to_ne_bytes).collect();
    let adapter = meshopt::VertexDataAdapter::new(&bytes, 12, 0).expect("positions adapter");
    let out = meshopt::simplify(&indices, &adapter, 3 * target_faces, 1.0, meshopt::SimplifyOptions::None, None);
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    let mut positions = Vec::new();
    let triangles = out
        .chunks_exact(3)
        .map(|t| {
            [t[0], t[1], t[2]].map(|v| {
                if remap[v as usize] == u32::MAX {
                    remap[v as usize] = positions.len() as u32;
                    positions.push(mesh.positions[v as usize]);
                }
                remap[v as usize]
            })
        })
        .collect();
    let mut m = Mesh { positions, triangles, ..Mesh::default() };
    m.compute_face_geometry();
    m
}

fn bench(name: &str, mesh: &Mesh) {
    let faces = mesh.face_count();
    println!("\n{name}: {faces} triangles, {} vertices", mesh.vertex_count());
    println!(
        "{:>5} | {:>7} {:>7} | {:>8} {:>8} {:>5} | {:>7} {:>7} | {:>9} {:>9} {:>5} | {:>9} {:>9} {:>5}",
        "ratio",
        "faces S",
        "faces M",
        "ms S",
        "ms M",
        "S/M",
        "Mtri/s S",
        "Mtri/s M",
        "H/diag S",
        "H/diag M",
        "S/M",
        "mean S",
        "mean M",
        "S/M"
    );
    for ratio in RATIOS {
        let target = (faces as f64 * ratio) as usize;
        let (tm, m) = timed(|| meshopt_simplify(mesh, target));
        let dm = surface_distance(mesh, &m, SAMPLES, 1);
        let opts = SimplifyOptions { target_faces: target, ..SimplifyOptions::default() };
        let (ts, s) = timed(|| simplify(mesh, None, &opts).mesh);
        row(&ratio.to_string(), mesh, (ts, &s), (tm, &m, &dm));
        if s.face_count() > target {
            // Stopped short by topology: again with topology changes allowed.
            let opts = SimplifyOptions { topology: true, ..opts };
            let (ts, s) = timed(|| simplify(mesh, None, &opts).mesh);
            row(&format!("{ratio}t"), mesh, (ts, &s), (tm, &m, &dm));
        }
    }
}

/// One line of the table: strata's result `s` in `ts` seconds against meshoptimizer's.
fn row(label: &str, mesh: &Mesh, (ts, s): (f64, &Mesh), (tm, m, dm): (f64, &Mesh, &Distance)) {
    let faces = mesh.face_count() as f64;
    let ds = surface_distance(mesh, s, SAMPLES, 1);
    let (hs, hm) = (ds.max / ds.diagonal, dm.max / dm.diagonal);
    let (ms, mm) = (ds.mean / ds.diagonal, dm.mean / dm.diagonal);
    println!(
        "{label:>5} | {:>7} {:>7} | {:>8.1} {:>8.1} {:>5.2} | {:>7.2} {:>7.2} | {hs:>9.2e} {hm:>9.2e} {:>5.2} | {ms:>9.2e} {mm:>9.2e} {:>5.2}",
        s.face_count(),
        m.face_count(),
        ts * 1e3,
        tm * 1e3,
        ts / tm,
        faces / ts / 1e6,
        faces / tm / 1e6,
        hs / hm,
        ms / mm,
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--bench")).collect();
    let synthetic = args.iter().any(|a| a == "--synthetic") || std::env::var_os("STRATA_BENCH_SYNTHETIC").is_some();
    let mut paths: Vec<PathBuf> = args.iter().filter(|a| !a.starts_with("--")).map(PathBuf::from).collect();
    if paths.is_empty() {
        let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes");
        if shared.is_dir() {
            let names = ["scans/ajc_stanford-bunny.obj", "scans/stanford_bun_zipper.ply", "large/cthead_skin_native.ply"];
            paths = names.iter().map(|p| shared.join(p)).collect();
        } else {
            println!("skipping: ../shared/meshes not found");
        }
    }
    println!("S = strata::simplify (no groups, default options), M = meshopt::simplify (default options, no error limit)");
    println!("a ratio marked t: S stopped above the target and ran again with topology changes allowed");
    println!("times: median of {RUNS} runs; distances: {SAMPLES} samples per mesh plus vertices, both ways");
    for path in &paths {
        match strata::import::import(path, None) {
            Ok(imported) => bench(&path.display().to_string(), &imported.mesh),
            Err(e) => println!("\nskipping {}: {e}", path.display()),
        }
    }
    if synthetic {
        bench("synthetic noisy sphere (fixtures::noisy_sphere(91, 0.05, 7))", &strata::fixtures::noisy_sphere(91, 0.05, 7));
    }
}
