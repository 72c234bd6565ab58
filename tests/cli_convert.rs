//! The main job through the CLI: convert a shipped fixture, verify it, extract its full-detail
//! level and compare it with the input; a failing conversion leaves nothing behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn strata(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().expect("run strata")
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("strata-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn fixture(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name).display().to_string()
}

#[test]
fn convert_verify_extract_round_trip() {
    let dir = temp_dir("roundtrip");
    let out = dir.join("cad.strata");
    let extracted = dir.join("level0.ply");
    let input = fixture("cad_part.obj");
    // Format 2: level 0 is the input exactly, on a 20-bit grid (format 3's quantized level 0 is
    // checked in tests/format3_roundtrip.rs).
    let o = strata(&["convert", &input, out.to_str().unwrap(), "--json", "--format-version", "2"]);
    assert!(o.status.success(), "convert failed: {}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    assert!(summary["summary"]["levels"].as_array().is_some_and(|l| !l.is_empty()));
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "only the output file is left");

    let o = strata(&["verify", out.to_str().unwrap()]);
    assert!(o.status.success(), "verify failed: {}", String::from_utf8_lossy(&o.stderr));

    let o = strata(&["extract", out.to_str().unwrap(), "--level", "0", "-o", extracted.to_str().unwrap()]);
    assert!(o.status.success(), "extract failed: {}", String::from_utf8_lossy(&o.stderr));
    let original = strata::import(Path::new(&input), None).unwrap().mesh;
    let back = strata::import(&extracted, None).unwrap().mesh;
    assert_eq!(back.face_count(), original.face_count());
    let key = |m: &strata::Mesh| {
        let mut faces: Vec<[[u32; 3]; 3]> = m
            .triangles
            .iter()
            .map(|t| {
                let mut f = t.map(|v| m.positions[v as usize].to_array().map(f32::to_bits));
                let first = (0..3).min_by_key(|&k| f[k]).unwrap();
                f.rotate_left(first);
                f
            })
            .collect();
        faces.sort_unstable();
        faces
    };
    let (a, b) = (key(&original), key(&back));
    let differing = a.iter().zip(&b).filter(|(x, y)| x != y).count();
    let positions_exact = differing == 0;
    if !positions_exact {
        // A format that quantizes positions states its bound; the faces must still match within it.
        let diag = original.diagonal();
        let mut pa: Vec<[f32; 3]> = original.positions.iter().map(|p| p.to_array()).collect();
        let mut pb: Vec<[f32; 3]> = back.positions.iter().map(|p| p.to_array()).collect();
        pa.sort_by(|x, y| x.partial_cmp(y).unwrap());
        pb.sort_by(|x, y| x.partial_cmp(y).unwrap());
        assert_eq!(pa.len(), pb.len());
        let worst = pa.iter().zip(&pb).map(|(x, y)| (0..3).map(|k| (x[k] - y[k]).abs()).fold(0.0, f32::max)).fold(0.0, f32::max);
        assert!(worst <= 1e-5 * diag, "positions moved by {worst} on a diagonal of {diag}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn failed_convert_leaves_nothing() {
    let dir = temp_dir("fail");
    let bad = dir.join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nf 1 2 3\n").unwrap();
    let out = dir.join("out.strata");
    let o = strata(&["convert", bad.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("bad.obj") && stderr.contains("line 3"), "{stderr}");
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 1, "only the input remains: {left:?}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn convert_to_an_unwritable_place_fails_cleanly() {
    let o = strata(&["convert", &fixture("cube.obj"), "/nonexistent/dir/out.strata"]);
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("/nonexistent/dir/out.strata"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn a_mesh_without_normals_gets_smooth_ones_with_sharp_creases_unless_told_otherwise() {
    let dir = temp_dir("normals");
    let mut part = strata::fixtures::cad_part();
    part.normals.clear();
    let input = dir.join("part.ply").display().to_string();
    strata::export::write(Path::new(&input), &part).unwrap();
    let (auto, none) = (dir.join("auto.strata"), dir.join("none.strata"));
    for (out, extra) in [(&auto, None), (&none, Some("none"))] {
        // Format 2, whose positions are exact: a sliver that format 3's coarser grid turns over
        // would fail the test below for reasons of quantization, not of normals.
        let mut args = vec!["convert", &input, out.to_str().unwrap(), "--quiet", "--format-version", "2"];
        if let Some(mode) = extra {
            args.extend(["--normals", mode]);
        }
        let o = strata(&args);
        assert!(o.status.success(), "convert failed: {}", String::from_utf8_lossy(&o.stderr));
    }
    let rd = strata::format::Reader::open_path(&auto).unwrap();
    assert!(rd.header().attributes.normals);
    let (mut smooth, mut sharp) = (0, 0);
    for i in rd.level_nodes(0) {
        let g = rd.read_node(i).unwrap();
        for t in g.indices.chunks_exact(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|v| g.positions[v as usize]);
            let face = (b - a).cross(c - a).normalize();
            for &v in t {
                let n = g.normals[v as usize];
                assert!(n.dot(face) > 0.0, "a computed normal points away from its face");
                if n.dot(face) > 0.999 {
                    sharp += 1;
                } else {
                    smooth += 1;
                }
            }
        }
    }
    assert!(sharp > 0 && smooth > 0, "the part has both flat faces along creases ({sharp}) and curved parts ({smooth})");
    assert!(!strata::format::Reader::open_path(&none).unwrap().header().attributes.normals);
    std::fs::remove_dir_all(&dir).ok();
}

/// A CT-like isosurface whose vertices crowd closer than the position grid's step (spec §5.1):
/// every input face stays distinct in the file, which passes `verify`, and level 0 holds as many
/// distinct positions as the input.
#[test]
fn crowded_isosurface_vertices_stay_distinct() {
    let dir = temp_dir("crowded");
    let input = strata::fixtures::isosurface(32, 7);
    let (lo, hi) = input.bounds().unwrap();
    let grid = strata::format::Grid::fit(lo, hi, strata::format::GRID_BITS);
    let on_grid: std::collections::HashSet<[u32; 3]> = input.positions.iter().map(|&p| grid.encode(p)).collect();
    assert!(on_grid.len() < input.vertex_count(), "the fixture should crowd vertices onto shared grid points");
    let ply = dir.join("iso.ply");
    strata::export::write(&ply, &input).unwrap();
    let out = dir.join("iso.strata");
    let o = strata(&["convert", ply.to_str().unwrap(), out.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = strata(&["verify", out.to_str().unwrap()]);
    assert!(o.status.success(), "verify: {}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    let rd = strata::format::Reader::open_path(&out).unwrap();
    let mut distinct = std::collections::HashSet::new();
    let mut faces = 0;
    for i in rd.level_nodes(0) {
        let g = rd.read_node(i).unwrap();
        faces += g.face_count();
        distinct.extend(g.positions.iter().map(|p| p.to_array().map(f32::to_bits)));
        assert!(rd.nodes()[i as usize].error >= rd.header().grid.error());
    }
    assert_eq!(faces, input.face_count());
    assert_eq!(distinct.len(), input.vertex_count());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn normals_of_the_geometry_make_a_smaller_file_that_verifies() {
    let dir = temp_dir("geometry-normals");
    let input = fixture("noisy_sphere.ply");
    let size = |args: &[&str], name: &str| {
        let out = dir.join(name);
        let mut all = vec!["convert", &input, out.to_str().unwrap(), "--quiet"];
        all.extend_from_slice(args);
        let o = strata(&all);
        assert!(o.status.success(), "convert {args:?} failed: {}", String::from_utf8_lossy(&o.stderr));
        let o = strata(&["verify", out.to_str().unwrap()]);
        assert!(o.status.success(), "verify failed: {}", String::from_utf8_lossy(&o.stdout));
        std::fs::metadata(&out).unwrap().len()
    };
    let input_normals = size(&[], "input.strata");
    let geometry = size(&["--normals", "geometry"], "geometry.strata");
    assert!(geometry < input_normals, "--normals geometry: {geometry} bytes, the input's normals {input_normals}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_growth_follows_the_level_ratio_unless_given() {
    let dir = temp_dir("growth");
    let input = fixture("icosphere.obj");
    let growth = |args: &[&str]| -> u64 {
        let out = dir.join("ico.strata");
        let o = strata(&[&["convert", "-q", input.as_str(), out.to_str().unwrap()], args].concat());
        assert!(o.status.success(), "convert {args:?}: {}", String::from_utf8_lossy(&o.stderr));
        let o = strata(&["inspect", "--json", out.to_str().unwrap()]);
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
        v["header"]["params"]["growth"].as_u64().expect("the recorded growth")
    };
    assert_eq!(growth(&[]), 2, "the default ratio 0.5");
    assert_eq!(growth(&["--level-ratio", "0.25"]), 4);
    assert_eq!(growth(&["--level-ratio", "0.3"]), 3);
    assert_eq!(growth(&["--level-ratio", "0.8"]), 2);
    assert_eq!(growth(&["--level-ratio", "0.25", "--growth", "2"]), 2);
    let _ = std::fs::remove_dir_all(&dir);
}
