//! `strata extract`: one level of a chunk file written as a mesh.

use super::open_chunk_file;
use anyhow::Result;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// A .strata file.
    file: PathBuf,
    /// Level to write (0 = full detail).
    #[arg(long, default_value_t = 0)]
    level: u32,
    /// Output mesh: .obj, .ply or .glb.
    #[arg(short, long)]
    output: PathBuf,
}

pub fn run(a: Args) -> Result<()> {
    let rd = open_chunk_file(&a.file)?;
    strata::atomic::check_output(&a.output)?;
    let mesh = strata::assemble::to_mesh(&rd, a.level)?;
    strata::export::write(&a.output, &mesh)?;
    println!("wrote level {} ({} faces, {} vertices) to {}", a.level, mesh.face_count(), mesh.vertex_count(), a.output.display());
    Ok(())
}
