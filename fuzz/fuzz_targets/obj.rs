//! Bytes as a .obj file, imported (read, welded, cleaned) from a file in a folder of this process.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;
use strata::fuzzing::ImportDir;

static DIR: OnceLock<ImportDir> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let dir = DIR.get_or_init(|| ImportDir::new().expect("a scratch folder"));
    let _ = dir.import(data, "obj");
});
