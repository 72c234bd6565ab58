//! A chunk file whose checksums were recomputed after its values were changed is refused by every
//! command that reads it, as `verify` refuses it, with the node named.

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::process::Command;
use strata::format::Reader;

fn strata(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().expect("run strata")
}

fn reseal(bytes: &mut [u8], at: usize) {
    let size = u64::from_le_bytes(bytes[at + 8..at + 16].try_into().unwrap()) as usize;
    let crc = crc32fast::hash(&bytes[at + 16..at + 16 + size]);
    bytes[at + 16 + size..at + 20 + size].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn a_nan_node_error_is_refused_by_every_command() {
    let dir: PathBuf = std::env::temp_dir().join(format!("strata-hostile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let good = dir.join("good.strata");
    let cube = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icosphere.obj");
    assert!(strata(&["convert", cube.to_str().unwrap(), good.to_str().unwrap(), "--quiet"]).status.success());
    let mut bytes = std::fs::read(&good).unwrap();
    let rd = Reader::open(Cursor::new(&bytes)).unwrap();
    // Format 3.1 keeps the node table in pages, one per level from the top: the last node is the
    // last record of the last page (level 0's).
    let at = |id: &str| rd.skeleton_chunks().iter().rev().find(|c| c.id == id).unwrap().offset as usize;
    let (node, skel) = (at("NODL"), at("SKEL"));
    let last = rd.nodes().len() - 1;
    let level0 = rd.nodes().iter().filter(|n| n.level == 0).count();
    drop(rd);
    // The last node's geometric error (record offset 36) becomes NaN.
    let field = node + 16 + 56 * (level0 - 1) + 36;
    bytes[field..field + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    reseal(&mut bytes, node);
    reseal(&mut bytes, skel);
    let bad = dir.join("bad.strata");
    std::fs::write(&bad, &bytes).unwrap();
    let b = bad.to_str().unwrap();
    let png = dir.join("out.png");
    let ply = dir.join("out.ply");
    for args in [
        vec!["verify", b],
        vec!["render", b, "-o", png.to_str().unwrap()],
        vec!["stream", b, "--orbit", "4"],
        vec!["extract", b, "--level", "0", "-o", ply.to_str().unwrap()],
        vec!["inspect", b],
    ] {
        let o = strata(&args);
        let err = String::from_utf8_lossy(&o.stderr).into_owned() + &String::from_utf8_lossy(&o.stdout);
        assert!(!o.status.success(), "{} accepted a NaN error: {err}", args[0]);
        assert!(err.contains(&format!("node {last}")) && err.contains("error"), "{}: {err}", args[0]);
    }
    assert!(!png.exists() && !ply.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
