//! The command line: one module per subcommand, each with its arguments and a `run`; what several
//! share (mesh input, grouping and level options, opening files) is here.

mod convert;
mod extract;
mod groups;
mod info;
mod inspect;
mod render;
mod serve;
mod simplify;
mod stream;
mod verify;

use anyhow::Result;
use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
use strata::hierarchy::HierarchyParams;
use strata::{format, import_with, Format, ImportOptions};

#[derive(Parser)]
#[command(name = "strata", version, about = "Make huge triangle meshes viewable on small machines")]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert a mesh into a strata chunk file: import, group, simplify per level, write.
    Convert(convert::Args),
    /// Import a mesh and print what it holds: counts, attributes, bounds, topology, cleaning.
    Info(info::Args),
    /// Simplify a mesh by quadric-error edge collapse (no groups) and write it.
    Simplify(simplify::Args),
    /// Group faces by normal cone into a hierarchy and measure hierarchical back-face culling.
    Groups(groups::Args),
    /// Show a strata file: header, chunks, levels, and nodes on request.
    Inspect(inspect::Args),
    /// Check every checksum and structural rule of a strata file; exit non-zero on any problem.
    Verify(verify::Args),
    /// Write one level of a strata file as a mesh (.obj, .ply or .glb).
    Extract(extract::Args),
    /// Play a viewing session over a strata file: per frame, the streamed front, its delta and costs.
    Stream(stream::Args),
    /// Draw a mesh, or one level of a strata file, to a PNG with the software rasterizer.
    Render(render::Args),
    /// Serve strata files and the web viewer over HTTP (byte ranges, CORS) for a browser.
    Serve(serve::Args),
}

impl Cli {
    /// What a signal (Ctrl-C) ending the command prints, and the exit code: the usual end of a
    /// server, or another command cut short before writing its output.
    pub fn on_interrupt(&self) -> (&'static str, i32) {
        match self.command {
            Command::Serve(_) => ("stopped", 0),
            _ => ("interrupted: no output written", 130),
        }
    }
}

/// Run the command line's subcommand.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Convert(a) => convert::run(a),
        Command::Info(a) => info::run(a),
        Command::Simplify(a) => simplify::run(a),
        Command::Groups(a) => groups::run(a),
        Command::Inspect(a) => inspect::run(a),
        Command::Verify(a) => verify::run(a),
        Command::Extract(a) => extract::run(a),
        Command::Stream(a) => stream::run(a),
        Command::Render(a) => render::run(a),
        Command::Serve(a) => serve::run(a),
    }
}

/// Where a mesh comes from.
#[derive(clap::Args)]
pub struct MeshInput {
    /// OBJ, glTF/GLB or PLY file.
    mesh: PathBuf,
    /// Read as this format whatever the extension.
    #[arg(long, value_parser = format_parser())]
    format: Option<Format>,
    /// Let a glTF file read buffers outside its folder (an absolute path or `..` in a buffer uri).
    #[arg(long)]
    allow_outside_files: bool,
}

/// `--format`: the names of the importer table.
fn format_parser() -> impl clap::builder::TypedValueParser<Value = Format> {
    use clap::builder::TypedValueParser;
    let names = strata::import::IMPORTERS.iter().map(|i| clap::builder::PossibleValue::new(i.name));
    clap::builder::PossibleValuesParser::new(names).map(|name: String| Format::by_name(&name).expect("a listed name"))
}

impl MeshInput {
    fn options(&self) -> ImportOptions {
        ImportOptions { format: self.format, allow_outside_files: self.allow_outside_files }
    }
}

/// Grouping parameters (METHOD.md §3); angles in degrees.
#[derive(clap::Args)]
pub struct GroupingArgs {
    /// Faces per culling cluster, at most.
    #[arg(long, default_value_t = HierarchyParams::default().cluster_faces)]
    cluster_faces: u32,
    /// Cone half-angle threshold of a culling cluster, degrees.
    #[arg(long, default_value_t = HierarchyParams::default().cluster_angle.to_degrees().round())]
    cluster_angle: f32,
    /// Faces per level-0 group (a streamed leaf node), at most.
    #[arg(long, default_value_t = HierarchyParams::default().leaf_faces)]
    leaf_faces: u32,
    /// Cone half-angle threshold of a level-0 group, degrees.
    #[arg(long, default_value_t = HierarchyParams::default().leaf_angle.to_degrees().round())]
    leaf_angle: f32,
    /// Threshold relaxation per level, degrees.
    #[arg(long, default_value_t = HierarchyParams::default().angle_step.to_degrees().round())]
    angle_step: f32,
    /// Size cap growth factor per level.
    #[arg(long, default_value_t = HierarchyParams::default().growth)]
    growth: u32,
    /// Weight of cone tightness in the evaluation function.
    #[arg(long, default_value_t = HierarchyParams::default().kc)]
    kc: f32,
    /// Weight of patch compactness.
    #[arg(long, default_value_t = HierarchyParams::default().ks)]
    ks: f32,
    /// Weight of size balance.
    #[arg(long, default_value_t = HierarchyParams::default().kn)]
    kn: f32,
    /// Stop adding levels at this many groups or fewer.
    #[arg(long, default_value_t = HierarchyParams::default().top_groups)]
    top_groups: usize,
}

impl GroupingArgs {
    fn params(&self) -> HierarchyParams {
        HierarchyParams {
            cluster_faces: self.cluster_faces.max(1),
            cluster_angle: self.cluster_angle.to_radians(),
            leaf_faces: self.leaf_faces.max(1),
            leaf_angle: self.leaf_angle.to_radians(),
            angle_step: self.angle_step.to_radians(),
            growth: self.growth,
            kc: self.kc,
            ks: self.ks,
            kn: self.kn,
            top_groups: self.top_groups.max(1),
        }
    }
}

/// How level meshes are made.
#[derive(clap::Args)]
pub struct LevelArgs {
    /// Target ratio of faces between a level mesh and the one below.
    #[arg(long, default_value_t = 0.5)]
    level_ratio: f32,
    /// Faces the top level (shown first) should not exceed: levels with the top's groups are added
    /// above the grouping while each still coarsens.
    #[arg(long, default_value_t = 2048)]
    top_faces: usize,
}

impl LevelArgs {
    fn params(&self) -> strata::levels::LevelParams {
        strata::levels::LevelParams { ratio: self.level_ratio, top_faces: self.top_faces }
    }
}

/// Open a chunk file, which no output of this command may then replace.
fn open_chunk_file(path: &Path) -> strata::error::Result<format::Reader<std::fs::File>> {
    strata::atomic::protect(path);
    format::Reader::open_path(path)
}

fn load(input: &MeshInput) -> Result<strata::Imported> {
    let imported = import_with(&input.mesh, &input.options())?;
    for w in &imported.warnings {
        eprintln!("warning: {}: {w}", input.mesh.display());
    }
    Ok(imported)
}
