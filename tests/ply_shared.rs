//! Every PLY file in the shared test meshes reads with the vertex and triangle counts and the
//! attributes that ../shared/meshes/CATALOG.md lists for it.

use std::path::{Path, PathBuf};
use strata::import::ply;

const SHARED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared");

/// A catalog row: file (relative to meshes/), vertices, triangles, attributes column.
fn catalog_rows(meshes: &Path) -> Vec<(String, usize, usize, String)> {
    let catalog = std::fs::read_to_string(meshes.join("CATALOG.md")).expect("CATALOG.md is readable");
    catalog
        .lines()
        .filter_map(|line| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            // | file | size | format | vertices | triangles | faces | attributes | ...
            let file = cells.get(1)?.strip_prefix('`')?.strip_suffix(".ply`")?;
            let count = |i: usize| cells.get(i).and_then(|c| c.parse::<usize>().ok());
            Some((format!("{file}.ply"), count(4)?, count(5)?, cells.get(7)?.to_string()))
        })
        .collect()
}

fn ply_files(meshes: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for dir in ["scans", "misc", "ply_edge", "large"] {
        let Ok(entries) = std::fs::read_dir(meshes.join(dir)) else { continue };
        for entry in entries {
            let path = entry.expect("directory entry").path();
            if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply")) {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

#[test]
fn shared_ply_files_match_the_catalog() {
    let meshes = Path::new(SHARED).join("meshes");
    if !meshes.exists() {
        println!("skipping: ../shared/meshes not found");
        return;
    }
    let rows = catalog_rows(&meshes);
    let files = ply_files(&meshes);
    assert!(files.len() >= 12, "expected the catalog's PLY files, found {files:?}");
    for path in files {
        let name = path.strip_prefix(&meshes).unwrap().to_string_lossy().replace('\\', "/");
        let (_, vertices, triangles, attributes) =
            rows.iter().find(|r| r.0 == name).unwrap_or_else(|| panic!("{name} is not in CATALOG.md"));
        let mut warnings = Vec::new();
        let result = ply::read(&path, &Default::default(), &mut warnings).map(|raw| raw.mesh);
        if *triangles == 0 {
            let e = result.expect_err("a file without faces must fail");
            assert!(e.to_string().contains(&format!("point cloud: {vertices} vertices and no faces")), "{name}: {e}");
            continue;
        }
        let mesh = result.unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(mesh.validate(), Ok(()), "{name}");
        assert_eq!(mesh.positions.len(), *vertices, "{name} vertices");
        assert_eq!(mesh.triangles.len(), *triangles, "{name} triangles");
        assert_eq!(!mesh.normals.is_empty(), attributes.contains("normals"), "{name} normals");
        assert_eq!(!mesh.colors.is_empty(), attributes.contains("colors"), "{name} colors");
        assert_eq!(!mesh.uvs.is_empty(), attributes.contains("uv"), "{name} uvs");
        if name.ends_with("float-color.ply") {
            // Float colors 0 0 1 1 on every vertex.
            assert_eq!(mesh.colors, vec![[0, 0, 255, 255]; 3]);
        }
        assert!(mesh.positions.iter().all(|p| p.is_finite()), "{name}");
    }
}
