//! Rewrite the golden vectors in `format-spec/vectors/`: small chunk files and, for each, what a
//! reader must make of it: the whole file decoded (`format::inspect::dump`) or the words its refusal
//! must contain. `cargo run --release --example make_vectors`; `tests/format_vectors.rs` checks that
//! the Rust reader agrees with every vector, and the viewer's JavaScript reader checks the same files.

use glam::Vec2;
use serde_json::json;
use std::io::Cursor;
use std::path::Path;
use strata::camera::{Camera, Projection};
use strata::format::skeleton::Skeleton;
use strata::format::{self, HierarchyParams, Reader};
use strata::levels::{self, LevelParams};
use strata::mesh::{Adjacency, Material, Mesh};
use strata::stream::cache::record_bytes;
use strata::stream::refine::{Limits, Priority, Refiner};
use strata::stream::session::orbit;
use strata::write::{write_to, Encoding, Precision, WriteOptions};

/// How node geometry is stored: format 2, or format 3 at its default precision.
fn encoding(major: u16) -> Encoding {
    if major == 3 {
        Encoding::V3(Precision::default())
    } else {
        Encoding::V2
    }
}

/// How every vector is written: levels halving, the vectors' tool string, the mesh's own normals.
fn options(
    params: HierarchyParams,
    metres_per_unit: f64,
    georef: Option<format::Georef>,
    major: u16,
    images: std::sync::Arc<Vec<strata::format::texture::ImageIn>>,
) -> WriteOptions {
    WriteOptions {
        metres_per_unit,
        params,
        level_ratio: 0.5,
        tool: "strata vectors".into(),
        georef,
        encoding: encoding(major),
        derive_normals: false,
        images,
    }
}

/// The chunk file of `mesh`, grouped with `params` and simplified per level.
fn convert(mesh: Mesh, params: HierarchyParams, metres_per_unit: f64, major: u16) -> Vec<u8> {
    convert_placed(mesh, params, metres_per_unit, None, major)
}

/// [`convert`] with a georeference (a `GEOR` chunk, format 2.1).
fn convert_placed(mesh: Mesh, params: HierarchyParams, metres_per_unit: f64, georef: Option<format::Georef>, major: u16) -> Vec<u8> {
    let adjacency = Adjacency::build(&mesh);
    let mut h = strata::hierarchy::build(&mesh, &adjacency, &params);
    let lv = levels::build(mesh, &mut h, &LevelParams { ratio: 0.5, top_faces: 16 }, &mut |_| {});
    let mut out = Cursor::new(Vec::new());
    let opts = options(params, metres_per_unit, georef, major, Default::default());
    write_to(&mut out, &h, &lv, &opts).expect("the vector meshes write");
    out.into_inner()
}

/// A unit square of two triangles: one level, one node, no corner attributes.
fn plane(major: u16) -> Vec<u8> {
    let positions = vec![glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::new(1.0, 1.0, 0.0), glam::Vec3::Y];
    let mesh = Mesh { positions, triangles: vec![[0, 1, 2], [0, 2, 3]], ..Mesh::default() }.clean().expect("finite").0;
    convert(mesh, HierarchyParams::default(), 1.0, major)
}

/// A sphere of 80 faces with every corner attribute (normals, UVs, colors) and two materials,
/// grouped small enough for several levels, neighbours and clusters.
fn sphere(major: u16) -> Vec<u8> {
    let mut mesh = strata::fixtures::colored_sphere(1);
    mesh.uvs = mesh.normals.iter().map(|n| Vec2::new(0.5 + 0.5 * n.x, 0.5 + 0.5 * n.y)).collect();
    mesh.materials = vec![
        Material { name: "south".into(), base_color: [0.2, 0.4, 0.8, 1.0], texture: None, ..Material::default() },
        Material { name: "north".into(), base_color: [0.9, 0.5, 0.1, 1.0], texture: Some("north.png".into()), ..Material::default() },
    ];
    mesh.face_materials = mesh.face_normals.iter().map(|n| u32::from(n.z > 0.0)).collect();
    let params = HierarchyParams { cluster_faces: 4, leaf_faces: 10, growth: 2, top_groups: 2, ..HierarchyParams::default() };
    convert(mesh, params, 0.0, major)
}

/// The sphere of [`sphere`] as a DAG of nodes (format 4): level-0 nodes of about 4 faces, levels
/// to 10 faces, so that cuts mix up to four levels.
fn sphere_dag() -> Vec<u8> {
    let mut mesh = strata::fixtures::colored_sphere(1);
    mesh.uvs = mesh.normals.iter().map(|n| Vec2::new(0.5 + 0.5 * n.x, 0.5 + 0.5 * n.y)).collect();
    let params = HierarchyParams { cluster_faces: 2, leaf_faces: 4, growth: 2, top_groups: 2, ..HierarchyParams::default() };
    let adjacency = Adjacency::build(&mesh);
    let h = strata::hierarchy::build(&mesh, &adjacency, &params);
    let level0 = h.levels[0].face_group.clone();
    let dag = strata::dag::build(mesh, &level0, &strata::dag::DagParams { ratio: 0.5, top_faces: 16 }, &mut |_, _| {});
    let mut out = Cursor::new(Vec::new());
    let opts = options(params, 1.0, None, 3, Default::default());
    strata::dag::write::write_to(&mut out, &dag, &h.clusters, &opts).expect("the DAG vector writes");
    out.into_inner()
}

/// A textured globe of 96 faces with a 128 × 64 base color image of two levels: format 2.2 with
/// `TEXR` and `TEXL` chunks.
fn textured(major: u16) -> Vec<u8> {
    let mut mesh = strata::fixtures::textured_globe(8, 128);
    let mut warnings = Vec::new();
    let images = strata::texture::pyramid::prepare(&mut mesh.materials, &mesh.images, !mesh.uvs.is_empty(), &mut warnings, &mut || {});
    assert!(warnings.is_empty(), "{warnings:?}");
    let params = HierarchyParams { cluster_faces: 8, leaf_faces: 24, growth: 2, top_groups: 2, ..HierarchyParams::default() };
    let adjacency = Adjacency::build(&mesh);
    let mut h = strata::hierarchy::build(&mesh, &adjacency, &params);
    let lv = levels::build(mesh, &mut h, &LevelParams { ratio: 0.5, top_faces: 16 }, &mut |_| {});
    let mut out = Cursor::new(Vec::new());
    let opts = options(params, 1.0, None, major, images.into());
    write_to(&mut out, &h, &lv, &opts).expect("the textured vector writes");
    out.into_inner()
}

/// A 9 × 7 elevation grid in degrees with one void, as the DEM readers make it: a `GEOR` chunk
/// (local tangent plane) and the file version 2.1.
fn terrain() -> Vec<u8> {
    use strata::import::heightfield::{axis, triangulate, Grid, Placement};
    let (cols, rows) = (9, 7);
    let placement = Placement::Geographic { lon: axis(7.0, 0.01, cols), lat: axis(46.06, -0.01, rows), crs: "EPSG:4326".into() };
    let grid = Grid { cols, rows, placement, metres_per_height_unit: 1.0, z_scale: 1.0 };
    let raw = triangulate(Path::new("terrain"), &grid, &mut Vec::new(), |i, row| {
        for (j, h) in row.iter_mut().enumerate() {
            *h = if (i, j) == (3, 4) { f64::NAN } else { 1000.0 + 40.0 * ((i as f64) * 0.9).sin() * ((j as f64) * 0.7).cos() };
        }
        Ok(())
    })
    .expect("a valid grid");
    let mesh = raw.mesh.clean().expect("finite").0;
    let params = HierarchyParams { cluster_faces: 8, leaf_faces: 24, growth: 2, top_groups: 2, ..HierarchyParams::default() };
    convert_placed(mesh, params, 1.0, raw.georef, 2)
}

/// Offsets of the chunks read at open, by ID.
fn chunk_at(bytes: &[u8], id: &str) -> usize {
    let rd = Reader::open(Cursor::new(bytes)).expect("a valid file");
    rd.skeleton_chunks().iter().find(|c| c.id == id).expect("chunk present").offset as usize
}

fn size_at(bytes: &[u8], at: usize) -> usize {
    u64::from_le_bytes(bytes[at + 8..at + 16].try_into().expect("8 bytes")) as usize
}

/// Recompute the CRC of the chunk at `at`.
fn reseal(bytes: &mut [u8], at: usize) {
    let size = size_at(bytes, at);
    let crc = strata::format::chunk::crc32(&bytes[at + 16..at + 16 + size]);
    bytes[at + 16 + size..at + 20 + size].copy_from_slice(&crc.to_le_bytes());
}

/// `good` with the last node's geometric error NaN, every checksum recomputed.
fn nan_error(good: &[u8]) -> (Vec<u8>, u32) {
    let mut bytes = good.to_vec();
    let (node, skel) = (chunk_at(good, "NODE"), chunk_at(good, "SKEL"));
    let last = Reader::open(Cursor::new(good)).expect("valid").nodes().len() - 1;
    let field = node + 16 + 56 * last + 36;
    bytes[field..field + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    reseal(&mut bytes, node);
    reseal(&mut bytes, skel);
    (bytes, last as u32)
}

/// `good` with one index of node 0's geometry past its vertices, every checksum recomputed.
fn index_past_vertices(good: &[u8]) -> Vec<u8> {
    let rd = Reader::open(Cursor::new(good)).expect("valid");
    let (n, node, skel) = (rd.nodes()[0], chunk_at(good, "NODE"), chunk_at(good, "SKEL"));
    let mut bytes = good.to_vec();
    let geom = n.offset as usize;
    let (mut at, end) = (geom + 16, geom + 16 + size_at(good, geom));
    while &bytes[at..at + 4] != b"INDX" {
        let after = at + 20 + size_at(&bytes, at);
        at = after + (8 - after % 8) % 8;
        assert!(at < end, "node 0 has an INDX chunk");
    }
    let width = u32::from_le_bytes(bytes[at + 4..at + 8].try_into().expect("4 bytes")) as usize;
    bytes[at + 16..at + 16 + width].copy_from_slice(&n.vertices.to_le_bytes()[..width]);
    reseal(&mut bytes, at);
    reseal(&mut bytes, geom);
    let crc = bytes[end..end + 4].to_vec();
    bytes[node + 16 + 52..node + 16 + 56].copy_from_slice(&crc);
    reseal(&mut bytes, node);
    reseal(&mut bytes, skel);
    bytes
}

/// Format 3: `good` with a byte of node 0's payload changed, every checksum recomputed (the node
/// table's, `GEOS`'s, the top level's `NODL`'s and `SKEL`'s): only the codec's own checks can
/// refuse it.
fn damaged_payload(good: &[u8]) -> Vec<u8> {
    let rd = Reader::open(Cursor::new(good)).expect("valid");
    // Node 0's record opens the first node page (the top level's).
    let (n, node, skel) = (rd.nodes()[0], chunk_at(good, "NODL"), chunk_at(good, "SKEL"));
    let geos = rd.skeleton_end() as usize;
    let mut bytes = good.to_vec();
    let (at, size) = (n.offset as usize, n.size as usize);
    bytes[at + size / 2] ^= 0x10;
    let crc = strata::format::chunk::crc32(&bytes[at..at + size]);
    bytes[node + 16 + 52..node + 16 + 56].copy_from_slice(&crc.to_le_bytes());
    reseal(&mut bytes, geos);
    reseal(&mut bytes, node);
    reseal(&mut bytes, skel);
    bytes
}

/// The front of `skeleton` for `camera` and `limits`: shown and culled nodes (selection.md §3, or
/// §9 for a DAG).
fn front(skeleton: &Skeleton, camera: &Camera, limits: &Limits) -> (Vec<u32>, Vec<u32>) {
    let attrs = skeleton.header.attributes;
    let cut = if skeleton.header.is_dag() {
        strata::stream::dag::select_skeleton(skeleton, camera, limits, &[], &|n| record_bytes(n, attrs))
    } else {
        Refiner::default().select(skeleton, camera, limits, &[], &|n| record_bytes(n, attrs))
    };
    (cut.shown, cut.culled)
}

/// Whether the front of `camera` and `limits` stays the same when the eye, the target and the
/// threshold move slightly: no decision lies within rounding of its threshold.
fn stable(skeleton: &Skeleton, camera: &Camera, limits: &Limits) -> bool {
    let base = front(skeleton, camera, limits);
    let scale = 1e-4 * camera.eye.distance(camera.target).max(1e-3);
    let nudges = [glam::Vec3::X, -glam::Vec3::X, glam::Vec3::Y, -glam::Vec3::Y, glam::Vec3::Z, -glam::Vec3::Z];
    nudges.iter().all(|&d| {
        let mut c = *camera;
        c.eye += d * scale;
        c.target += glam::Vec3::new(d.y, d.z, d.x) * scale;
        front(skeleton, &c, limits) == base
    }) && [0.999, 1.001].iter().all(|k| front(skeleton, camera, &Limits { pixel_error: limits.pixel_error * k, ..*limits }) == base)
}

/// Golden fronts of `file`: orbit cameras from far to near and an orthographic one, under several
/// thresholds, budgets and orders; only those robust to rounding.
fn fronts(file: &str, bytes: &[u8]) -> Vec<serde_json::Value> {
    let rd = Reader::open(Cursor::new(bytes)).expect("valid");
    let skeleton = rd.skeleton();
    let h = &skeleton.header;
    let (center, radius) = ((h.min + h.max) * 0.5, (h.max - h.min).length() * 0.5);
    let top_faces: u64 = skeleton.level_nodes(skeleton.top()).map(|i| skeleton.nodes[i as usize].faces as u64).sum();
    let mut cameras: Vec<Camera> = [0, 6, 10, 13, 16, 24].iter().map(|&i| orbit(center, radius, i, 32, 640, 480)).collect();
    let mut ortho = cameras[5];
    ortho.projection = Projection::Orthographic { height: 2.5 * radius };
    cameras.push(ortho);
    let mut orderer = strata::stream::order::Orderer::new(skeleton, rd.read_planes().expect("planes"));
    let dag = h.is_dag();
    let mut out = Vec::new();
    // Format 4's rule has one order (selection.md §9): thresholds through its levels, and budgets.
    let dag_limits = [0.5, 1.0, 2.0, 4.0, 8.0]
        .map(|t| (t, None, Priority::Error))
        .into_iter()
        .chain([2, 3, 4].map(|k| (0.25, Some(k * top_faces), Priority::Error)));
    for camera in &cameras {
        let tree_limits = [
            (1.0, None, Priority::Error),
            (8.0, None, Priority::Error),
            (0.5, Some(2 * top_faces), Priority::Error),
            (0.5, Some(2 * top_faces), Priority::Silhouette),
            (0.5, Some(2 * top_faces), Priority::Breadth),
        ];
        let limits: Vec<_> = if dag { dag_limits.clone().collect() } else { tree_limits.to_vec() };
        for (pixel_error, max_faces, priority) in limits {
            let limits = Limits { pixel_error, max_faces, max_bytes: None, priority };
            if !stable(skeleton, camera, &limits) {
                continue;
            }
            let (shown, culled) = front(skeleton, camera, &limits);
            let mut order = Vec::new();
            if dag {
                strata::stream::order::nearest_box_first(skeleton, &shown, camera, &mut order);
            } else {
                orderer.order(skeleton, &shown, camera, &mut order);
            }
            let priority = match priority {
                Priority::Error => "error",
                Priority::Silhouette => "silhouette",
                Priority::Breadth => "breadth",
            };
            out.push(json!({
                "file": file,
                "camera": camera.to_json(),
                "limits": { "pixel_error": pixel_error as f64, "max_faces": max_faces, "max_bytes": null, "priority": priority },
                "held": [],
                "front": shown,
                "culled": culled,
                "order": order,
            }));
        }
    }
    out
}

fn main() -> anyhow::Result<()> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("format-spec/vectors");
    std::fs::create_dir_all(&dir)?;
    let (sphere, sphere3) = (sphere(2), sphere(3));
    let (nan, nan_node) = nan_error(&sphere);
    let valid = [
        ("plane", plane(2)),
        ("sphere", sphere.clone()),
        ("terrain", terrain()),
        ("textured", textured(2)),
        ("plane-v3", plane(3)),
        ("sphere-v3", sphere3.clone()),
        ("textured-v3", textured(3)),
        ("sphere-v4", sphere_dag()),
    ];
    let refused = [
        ("refused-nan-error", nan, vec![format!("node {nan_node}"), "error".to_string()]),
        ("refused-index-past-vertices", index_past_vertices(&sphere), vec!["node 0".to_string(), "index".to_string()]),
        ("refused-v3-damaged-payload", damaged_payload(&sphere3), vec!["node 0".to_string()]),
    ];
    for (name, bytes) in valid {
        let rd = Reader::open(Cursor::new(&bytes))?;
        let json = format::inspect::dump(&rd)?;
        std::fs::write(dir.join(format!("{name}.strata")), &bytes)?;
        std::fs::write(dir.join(format!("{name}.json")), serde_json::to_string_pretty(&json)? + "\n")?;
        println!("{name}: {} bytes, {} nodes", bytes.len(), rd.nodes().len());
    }
    let golden = fronts("sphere.strata", &sphere);
    let distinct: std::collections::HashSet<String> = golden.iter().map(|f| f["front"].to_string()).collect();
    std::fs::write(dir.join("fronts.json"), serde_json::to_string_pretty(&golden)? + "\n")?;
    println!("fronts: {} of sphere.strata ({} distinct)", golden.len(), distinct.len());
    let golden = fronts("sphere-v4.strata", &sphere_dag());
    let distinct: std::collections::HashSet<String> = golden.iter().map(|f| f["front"].to_string()).collect();
    std::fs::write(dir.join("fronts-v4.json"), serde_json::to_string_pretty(&golden)? + "\n")?;
    println!("fronts: {} of sphere-v4.strata ({} distinct)", golden.len(), distinct.len());
    for (name, bytes, words) in refused {
        let refusal =
            Reader::open(Cursor::new(&bytes)).and_then(|rd| (0..rd.nodes().len() as u32).try_for_each(|i| rd.read_node(i).map(|_| ())));
        let message = refusal.expect_err("a refused vector is refused").to_string();
        assert!(words.iter().all(|w| message.contains(w)), "{name}: {message}");
        std::fs::write(dir.join(format!("{name}.strata")), &bytes)?;
        std::fs::write(dir.join(format!("{name}.json")), serde_json::to_string_pretty(&serde_json::json!({ "refused": words }))? + "\n")?;
        println!("{name}: refused with \"{message}\"");
    }
    Ok(())
}
