//! The chunk files strata writes do not change by accident: every shipped fixture, and every mesh of
//! ../shared/meshes when present, converts with the default options to exactly the bytes recorded in
//! `tests/output_hashes.txt` (the first 8 bytes of SHA-256, and the length). A change to the writer's output is deliberate:
//! rerun with `STRATA_BLESS=1` to record the new files, and say in the commit why they changed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use strata::pipeline::{convert, ConvertOptions, Silent};
use strata::ImportOptions;

fn inputs() -> Vec<(String, PathBuf)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = Vec::new();
    let push_dir = |prefix: &str, dir: &Path, out: &mut Vec<(String, PathBuf)>| {
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            let Ok(entries) = std::fs::read_dir(&d) else { continue };
            for e in entries.flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else if strata::Format::from_path(&p).is_some_and(|f| f.name() != "png" || d.ends_with("dem")) {
                    // PNGs elsewhere are textures, not heightmaps.
                    let rel = p.strip_prefix(dir).unwrap().to_string_lossy().replace('\\', "/");
                    out.push((format!("{prefix}{rel}"), p));
                }
            }
        }
    };
    push_dir("fixtures/", &root.join("fixtures"), &mut out);
    let shared = root.join("../shared/meshes");
    if shared.exists() {
        push_dir("shared/", &shared, &mut out);
    } else {
        println!("skipping the shared meshes: ../shared/meshes not found");
    }
    out.sort();
    out
}

#[test]
fn converted_files_are_byte_identical_to_the_recorded_ones() {
    let record = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/output_hashes.txt");
    let recorded: BTreeMap<String, String> = std::fs::read_to_string(&record)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .filter_map(|l| l.split_once(' ').map(|(h, name)| (name.to_string(), h.to_string())))
        .collect();
    let dir = std::env::temp_dir().join(format!("strata-stable-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("out.strata");
    let mut now = BTreeMap::new();
    for (name, path) in inputs() {
        let hash = match convert(&path, &ImportOptions::default(), &out, &ConvertOptions::default(), &mut Silent) {
            Ok(_) => {
                let bytes = std::fs::read(&out).unwrap();
                // Not CRC-32: the chunks carry their own CRC-32s, and a payload replaced by another
                // of the same length with its CRC leaves the whole file's CRC-32 unchanged.
                use sha2::Digest;
                let digest = sha2::Sha256::digest(&bytes);
                format!("{}:{}", digest[..8].iter().map(|b| format!("{b:02x}")).collect::<String>(), bytes.len())
            }
            Err(_) => "refused".to_string(),
        };
        now.insert(name, hash);
    }
    std::fs::remove_dir_all(&dir).ok();
    if std::env::var_os("STRATA_BLESS").is_some() {
        let mut text = String::from("# sha256[..8]:length of `strata convert <input>` with default options; see tests/output_stable.rs\n");
        let merged: BTreeMap<&String, &String> = recorded.iter().chain(now.iter()).collect();
        for (name, hash) in merged {
            text.push_str(&format!("{hash} {name}\n"));
        }
        std::fs::write(&record, text).unwrap();
        return;
    }
    let mut differ = Vec::new();
    for (name, hash) in &now {
        match recorded.get(name) {
            Some(r) if r == hash => {}
            Some(r) => differ.push(format!("{name}: recorded {r}, now {hash}")),
            None => differ.push(format!("{name}: not recorded (now {hash})")),
        }
    }
    assert!(differ.is_empty(), "converted files changed (STRATA_BLESS=1 records them):\n{}", differ.join("\n"));
    assert!(now.keys().filter(|k| k.starts_with("fixtures/")).count() >= 8);
}
