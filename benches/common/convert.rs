//! A mesh converted with default options into the temporary folder, for the benches that read
//! `.strata` files: `strata-{bench}-{stem}-{pid}.strata`.

use std::path::{Path, PathBuf};

pub fn convert(input: &Path, bench: &str) -> PathBuf {
    let stem = input.file_stem().unwrap().to_string_lossy();
    let out = std::env::temp_dir().join(format!("strata-{bench}-{stem}-{}.strata", std::process::id()));
    let opts = strata::pipeline::ConvertOptions::default();
    strata::pipeline::convert(input, &Default::default(), &out, &opts, &mut strata::pipeline::Silent).expect("convert");
    out
}
