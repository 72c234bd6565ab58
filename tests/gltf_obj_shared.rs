//! Every OBJ and glTF/GLB file of the shared test meshes imports with the triangle count
//! `CATALOG.md` lists for it, or fails with the error the catalog implies (compressed geometry).
//!
//! Reads `../shared/meshes` (or `$STRATA_SHARED/meshes`); skips when it is absent.

use std::path::{Path, PathBuf};
use strata::import::import;

fn shared_meshes() -> Option<PathBuf> {
    let root = std::env::var_os("STRATA_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared")));
    let meshes = root.join("meshes");
    if meshes.join("CATALOG.md").is_file() {
        Some(meshes)
    } else {
        println!("skipping: ../shared/meshes not found");
        None
    }
}

#[derive(Debug, PartialEq)]
enum Expected {
    Faces(usize),
    /// Import fails with an error naming this required extension.
    Fails(String),
}

/// The leading unsigned integer of `s`.
fn leading_number(s: &str) -> Option<usize> {
    let digits: String = s.trim().chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

/// What importing each OBJ, glTF and GLB file of the catalog should give, by relative path.
///
/// OBJ rows give the fan-triangulated count in the `triangles` column. glTF rows give
/// `tris (scene tris)`: the scene count applies, except for files using EXT_mesh_gpu_instancing,
/// which strata imports without instancing (the plain count), and files requiring Draco, which
/// must fail naming the extension.
fn catalog(meshes: &Path) -> Vec<(String, Expected)> {
    let text = std::fs::read_to_string(meshes.join("CATALOG.md")).expect("CATALOG.md readable");
    let mut header: Vec<String> = Vec::new();
    let mut out = Vec::new();
    for line in text.lines() {
        let cells: Vec<&str> = line.trim().trim_matches('|').split('|').map(str::trim).collect();
        if cells.first() == Some(&"file") {
            header = cells.iter().map(|c| c.to_string()).collect();
            continue;
        }
        let Some(file) = cells.first().and_then(|c| c.strip_prefix('`')).and_then(|c| c.strip_suffix('`')) else {
            continue;
        };
        if !(file.ends_with(".obj") || file.ends_with(".gltf") || file.ends_with(".glb")) {
            continue;
        }
        let column = |prefix: &str| header.iter().position(|h| h.starts_with(prefix)).and_then(|i| cells.get(i)).copied();
        let expected = if file.ends_with(".obj") {
            Expected::Faces(leading_number(column("triangles").expect("triangles column")).expect("OBJ triangle count"))
        } else {
            let tris = column("tris").expect("tris column");
            let extras = column("extras").unwrap_or("");
            if extras.contains("KHR_draco_mesh_compression") {
                Expected::Fails("KHR_draco_mesh_compression".into())
            } else if extras.contains("EXT_mesh_gpu_instancing") {
                Expected::Faces(leading_number(tris).expect("plain triangle count"))
            } else {
                let scene = tris.split_once('(').map(|(_, s)| s).expect("scene tris in parentheses");
                Expected::Faces(leading_number(scene).expect("scene triangle count"))
            }
        };
        out.push((file.to_string(), expected));
    }
    out
}

/// Files under `dir` (recursively) whose names end with one of `extensions`, relative to `base`.
fn files(base: &Path, dir: &Path, extensions: &[&str], out: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            files(base, &path, extensions, out);
        } else if extensions.iter().any(|e| path.extension().is_some_and(|x| x == *e)) {
            out.push(path.strip_prefix(base).unwrap().to_string_lossy().replace('\\', "/"));
        }
    }
}

#[test]
fn shared_obj_and_gltf_files_import_with_catalog_counts() {
    let Some(meshes) = shared_meshes() else { return };
    let catalog = catalog(&meshes);
    assert!(catalog.iter().filter(|(f, _)| f.ends_with(".obj")).count() >= 5, "catalog parsing found too few OBJ rows");
    assert!(catalog.iter().filter(|(f, _)| !f.ends_with(".obj")).count() >= 30, "catalog parsing found too few glTF rows");

    let mut all = Vec::new();
    files(&meshes, &meshes.join("scans"), &["obj"], &mut all);
    files(&meshes, &meshes.join("misc"), &["obj"], &mut all);
    files(&meshes, &meshes.join("gltf"), &["gltf", "glb"], &mut all);
    all.sort();
    let mut failures = Vec::new();
    for file in &all {
        let expected = catalog.iter().find(|(f, _)| f == file).map(|(_, e)| e);
        let result = import(&meshes.join(file), None);
        let ok = match (expected, &result) {
            (Some(Expected::Faces(n)), Ok(imp)) => imp.source_faces == *n,
            (Some(Expected::Fails(ext)), Err(e)) => e.to_string().contains(ext.as_str()),
            (None, Ok(_)) => true,
            _ => false,
        };
        let got = match &result {
            Ok(imp) => format!("{} faces", imp.source_faces),
            Err(e) => format!("error: {e}"),
        };
        println!("{file}: {got}");
        if !ok {
            failures.push(format!("{file}: expected {expected:?}, got {got}"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Faces whose corner normals, on average, point away from the face's winding normal.
fn flipped_faces(mesh: &strata::Mesh) -> usize {
    (0..mesh.face_count())
        .filter(|&f| {
            let mean = mesh.normals[3 * f] + mesh.normals[3 * f + 1] + mesh.normals[3 * f + 2];
            mesh.face_normals[f].dot(mean) < 0.0
        })
        .count()
}

#[test]
fn gltf_transforms_keep_normals_and_winding_consistent() {
    let Some(meshes) = shared_meshes() else { return };
    for file in
        ["NegativeScaleTest/glTF/NegativeScaleTest.gltf", "Duck/glTF-Quantized/Duck.gltf", "CesiumMilkTruck/glTF/CesiumMilkTruck.gltf"]
    {
        let mesh = import(&meshes.join("gltf/khronos").join(file), None).unwrap().mesh;
        assert!(!mesh.normals.is_empty(), "{file}");
        let flipped = flipped_faces(&mesh);
        assert!(flipped * 100 < mesh.face_count(), "{file}: {flipped} of {} faces disagree with their normals", mesh.face_count());
    }
}

#[test]
fn quantized_duck_matches_the_float_duck() {
    let Some(meshes) = shared_meshes() else { return };
    let duck = |variant: &str| import(&meshes.join(format!("gltf/khronos/Duck/{variant}/Duck.gltf")), None).unwrap().mesh;
    let (plain, quantized) = (duck("glTF"), duck("glTF-Quantized"));
    let (lo, hi) = plain.bounds().unwrap();
    let (qlo, qhi) = quantized.bounds().unwrap();
    let tolerance = 1e-3 * plain.diagonal();
    assert!((lo - qlo).abs().max_element() < tolerance && (hi - qhi).abs().max_element() < tolerance, "{lo} {hi} vs {qlo} {qhi}");
    let uv_bounds = |m: &strata::Mesh| m.uvs.iter().fold((glam::Vec2::MAX, glam::Vec2::MIN), |(a, b), &uv| (a.min(uv), b.max(uv)));
    let ((ulo, uhi), (qulo, quhi)) = (uv_bounds(&plain), uv_bounds(&quantized));
    assert!((ulo - qulo).abs().max_element() < 1e-3 && (uhi - quhi).abs().max_element() < 1e-3, "{ulo} {uhi} vs {qulo} {quhi}");
    assert!(quantized.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-3));
}

#[test]
fn sparse_accessor_values_are_applied() {
    let Some(meshes) = shared_meshes() else { return };
    let mesh = import(&meshes.join("gltf/khronos/SimpleSparseAccessor/glTF/SimpleSparseAccessor.gltf"), None).unwrap().mesh;
    // The base positions reach y = 1; the three sparse substitutes lift vertices to y = 2, 3 and 4.
    assert_eq!(mesh.bounds().unwrap().1.y, 4.0);
}

#[test]
fn obj_attributes_and_polygons() {
    let Some(meshes) = shared_meshes() else { return };
    let beast = import(&meshes.join("misc/ajc_beast.obj"), None).unwrap();
    assert!(!beast.mesh.uvs.is_empty() && beast.mesh.normals.is_empty());
    let suzanne = import(&meshes.join("misc/ajc_suzanne.obj"), None).unwrap();
    assert!(!suzanne.mesh.normals.is_empty());
    assert!(suzanne.mesh.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-3));
}
