//! A mesh converted with default options into the temporary folder, for the benches that read
//! `.strata` files: `strata-{bench}-{stem}-{pid}.strata`.

use std::path::{Path, PathBuf};

#[allow(dead_code)]
pub fn convert(input: &Path, bench: &str) -> PathBuf {
    convert_with(input, bench, &strata::pipeline::ConvertOptions::default())
}

/// [`convert`] with `opts`; a DAG (format 4) is named `strata-{bench}-dag-{stem}-{pid}.strata`,
/// and one built partitioned `…-part-…`.
#[allow(dead_code)]
pub fn convert_with(input: &Path, bench: &str, opts: &strata::pipeline::ConvertOptions) -> PathBuf {
    let stem = input.file_stem().unwrap().to_string_lossy();
    let part = if opts.build == strata::pipeline::Build::Partitioned { "part-" } else { "" };
    let kind = format!("{part}{}", if opts.dag { "dag-" } else { "" });
    let out = std::env::temp_dir().join(format!("strata-{bench}-{kind}{stem}-{}.strata", std::process::id()));
    strata::pipeline::convert(input, &Default::default(), &out, opts, &mut strata::pipeline::Silent).expect("convert");
    out
}
