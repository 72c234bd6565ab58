//! The web viewer's JavaScript tests (tests/js/*.test.mjs), run with Node's test runner from
//! `cargo test`: its reader against the golden vectors, its front selection against strata's, and
//! the page in headless Chromium. Skips with a line saying what is missing where Node is absent;
//! the browser tests skip themselves, with such a line, where Chromium or playwright-core is.

use std::path::Path;
use std::process::Command;

#[test]
fn javascript_tests_pass() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    if Command::new("node").arg("--version").output().is_err() {
        eprintln!("skipping: node not found; the viewer's JavaScript tests need Node.js 20 or newer");
        return;
    }
    let mut files: Vec<String> = std::fs::read_dir(root.join("tests/js"))
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().to_str().filter(|n| n.ends_with(".test.mjs")).map(|n| format!("tests/js/{n}")))
        .collect();
    files.sort();
    assert!(files.len() >= 3, "{files:?}");
    let scratch = tempfile::tempdir().unwrap();
    let out = Command::new("node")
        .args(["--test", "--test-concurrency=1", "--test-reporter=spec"])
        .args(&files)
        .current_dir(root)
        .env("STRATA_BIN", env!("CARGO_BIN_EXE_strata"))
        .env("STRATA_TEST_DIR", scratch.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    for line in stdout.lines().filter(|l| l.contains("skipping") || l.trim_start().starts_with('ℹ')) {
        eprintln!("{}", line.trim());
    }
    assert!(out.status.success(), "node --test failed:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
}
