//! `strata verify`: every checksum and rule of a chunk file; exit non-zero listing the first
//! problems.

use anyhow::Result;
use std::path::PathBuf;
use strata::format;

#[derive(clap::Args)]
pub struct Args {
    /// A .strata file.
    file: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let v = format::verify_path(&a.file);
    if v.is_sound() {
        println!("{}: sound ({} chunks, {} nodes checked)", a.file.display(), v.chunks, v.nodes);
        return Ok(());
    }
    for p in v.problems.iter().take(20) {
        eprintln!("problem: {p}");
    }
    let more = if v.problems.len() >= format::verify::MAX_PROBLEMS { " or more" } else { "" };
    anyhow::bail!("{}: {} problem(s){more} found", a.file.display(), v.problems.len())
}
