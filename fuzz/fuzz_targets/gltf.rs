//! Bytes as a glTF file (.glb when they start with the GLB magic, else .gltf), imported from a file
//! in a folder of this process.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;
use strata::fuzzing::{import_gltf, ImportDir};

static DIR: OnceLock<ImportDir> = OnceLock::new();

fuzz_target!(|data: &[u8]| {
    let dir = DIR.get_or_init(|| ImportDir::new().expect("a scratch folder"));
    let _ = import_gltf(dir, data);
});
