//! Hierarchical cone culling, strata's group hierarchy against meshoptimizer's meshlet cones, with
//! the same views and the same cost definition (tests + faces in groups not culled, over faces).
//!
//! `cargo bench --bench culling [-- mesh ...]`; without arguments it runs on the scans and the large
//! mesh in ../shared/meshes (when present) and on the shipped fixture.

use glam::Vec3;
use std::path::{Path, PathBuf};
use std::time::Instant;
use strata::culling::{measure, sphere_directions};
use strata::hierarchy::{build, HierarchyParams};
use strata::mesh::{Adjacency, Mesh};

const VIEWS: usize = 256;

/// (cost ratio, faces culled share) of meshoptimizer meshlets with the given cone weight.
fn meshlet_cost(mesh: &Mesh, cone_weight: f32) -> (f64, f64, usize) {
    let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let bytes: Vec<u8> = mesh.positions.iter().flat_map(|p| p.to_array()).flat_map(f32::to_ne_bytes).collect();
    let adapter = meshopt::VertexDataAdapter::new(&bytes, 12, 0).expect("positions adapter");
    let meshlets = meshopt::build_meshlets(&indices, &adapter, 64, 124, cone_weight);
    let bounds: Vec<(Vec3, f32, usize)> = meshlets
        .iter()
        .map(|m| {
            let b = meshopt::compute_meshlet_bounds(m, &adapter);
            (Vec3::from_array(b.cone_axis), b.cone_cutoff, m.triangles.len() / 3)
        })
        .collect();
    let faces = mesh.face_count() as f64;
    let (mut cost, mut culled) = (0.0, 0.0);
    for to_viewer in sphere_directions(VIEWS) {
        let view = -to_viewer;
        let c: usize = bounds.iter().filter(|(axis, cutoff, _)| view.dot(*axis) >= *cutoff).map(|b| b.2).sum();
        cost += (bounds.len() as f64 + faces - c as f64) / faces;
        culled += c as f64 / faces;
    }
    (cost / VIEWS as f64, culled / VIEWS as f64, meshlets.len())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut inputs: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if inputs.is_empty() {
        let shared = root.join("../shared/meshes");
        if shared.exists() {
            for name in [
                "scans/ajc_stanford-bunny.obj",
                "scans/3dhop_gargo.ply",
                "scans/ajc_horse.ply",
                "scans/oded_nefertiti-lowres.obj",
                "scans/stanford_bun_zipper.ply",
                "large/cthead_skin_native.ply",
            ] {
                inputs.push(shared.join(name));
            }
        } else {
            println!("skipping the real meshes: ../shared/meshes not found");
        }
        inputs.push(root.join("fixtures/noisy_sphere.ply"));
    }
    println!("{VIEWS} orthographic views on the sphere; cost = (tests + faces not culled) / faces, lower is better");
    println!(
        "{:<28} {:>8} | {:>7} {:>7} {:>6} {:>8} | {:>7} {:>7} {:>6} | {:>7} {:>7} | {:>6} {:>5}",
        "mesh", "faces", "strata", "culled", "tests", "build ms", "mo w0", "culled", "mlets", "mo w.25", "culled", "ratio", "back"
    );
    for path in inputs {
        let imported = match strata::import(&path, None) {
            Ok(i) => i,
            Err(e) => {
                println!("skipping {}: {e}", path.display());
                continue;
            }
        };
        let mesh = imported.mesh;
        let params = HierarchyParams::default();
        let mut times = Vec::new();
        let mut hierarchy = None;
        for _ in 0..5 {
            let start = Instant::now();
            let adj = Adjacency::build(&mesh);
            hierarchy = Some(build(&mesh, &adj, &params));
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
        let h = hierarchy.expect("built");
        let s = measure(&h, &mesh, VIEWS);
        let (mo0, mo0_culled, mlets) = meshlet_cost(&mesh, 0.0);
        let (mo25, mo25_culled, _) = meshlet_cost(&mesh, 0.25);
        println!(
            "{:<28} {:>8} | {:>7.3} {:>6.1}% {:>6.0} {:>8.1} | {:>7.3} {:>6.1}% {:>6} | {:>7.3} {:>6.1}% | {:>6.3} {:>4.1}%",
            path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
            mesh.face_count(),
            s.cost_ratio,
            100.0 * s.faces_culled,
            s.tests,
            median(times),
            mo0,
            100.0 * mo0_culled,
            mlets,
            mo25,
            100.0 * mo25_culled,
            s.cost_ratio / mo0.min(mo25),
            100.0 * s.faces_backfacing,
        );
    }
    println!("ratio = strata cost / best meshoptimizer cost (< 1: strata culls cheaper)");
}
