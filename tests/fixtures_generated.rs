//! The committed files in `fixtures/` are exactly what `examples/make_fixtures.rs` writes, so the
//! generator, the writers and the files never drift apart.

use std::path::Path;
use strata::export::{glb, obj, ply};

#[test]
fn committed_fixtures_match_the_generator() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    let readme = std::fs::read_to_string(dir.join("README.md")).expect("fixtures/README.md");
    for f in strata::fixtures::committed() {
        let mut bytes = Vec::new();
        match Path::new(f.file).extension().and_then(|e| e.to_str()) {
            Some("obj") => {
                assert!(!obj::needs_mtl(&f.mesh), "{}: a fixture with a .mtl needs that file checked too", f.file);
                obj::write_obj(&mut bytes, &f.mesh, None).unwrap()
            }
            Some("ply") => ply::write_ply(&mut bytes, &f.mesh).unwrap(),
            Some("glb") => glb::write_glb(&mut bytes, &f.mesh).unwrap(),
            _ => panic!("{}: unknown extension", f.file),
        }
        let committed = std::fs::read(dir.join(f.file)).unwrap_or_else(|e| panic!("{}: {e}", f.file));
        assert!(
            committed == bytes,
            "fixtures/{} differs from the generator ({} bytes committed, {} generated): \
             run `cargo run --release --example make_fixtures` and commit the result",
            f.file,
            committed.len(),
            bytes.len()
        );
        let row = format!("| {} | {} | {} | {} |", f.file, f.mesh.face_count(), f.mesh.vertex_count(), bytes.len());
        assert!(readme.contains(&row), "fixtures/README.md has no row starting {row}");
    }
}
