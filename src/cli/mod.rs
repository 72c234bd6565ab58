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
    /// OBJ, glTF/GLB or PLY mesh, or elevation grid (.asc, .tif, .hgt, heightmap .png).
    mesh: PathBuf,
    /// Read as this format whatever the extension.
    #[arg(long, value_parser = format_parser())]
    format: Option<Format>,
    /// Let a glTF file read buffers outside its folder (an absolute path or `..` in a buffer uri).
    #[arg(long)]
    allow_outside_files: bool,
    #[command(flatten)]
    dem: DemArgs,
}

/// How elevation grids (.asc, .tif, .hgt, heightmap .png) are read.
#[derive(clap::Args, Clone, Default)]
#[command(next_help_heading = "Elevation grids")]
pub struct DemArgs {
    /// How a PNG stores heights: 16-bit grey values (default), Mapbox Terrain-RGB or Terrarium colours.
    #[arg(long, value_enum)]
    dem_encoding: Option<DemEncodingArg>,
    /// Whether grid coordinates are degrees or projected, when the file does not say.
    #[arg(long, value_enum, default_value_t = DemCrsArg::Auto)]
    dem_crs: DemCrsArg,
    /// Multiply heights by this (vertical exaggeration; recorded in the file).
    #[arg(long, default_value_t = 1.0)]
    z_scale: f64,
    /// Metres between samples of a grid that says nothing of where it lies.
    #[arg(long)]
    dem_cell_size: Option<f64>,
    /// The PNG is this Web Mercator tile, "z/x/y".
    #[arg(long, value_parser = parse_tile)]
    dem_tile: Option<[u32; 3]>,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum DemEncodingArg {
    Grey16,
    TerrainRgb,
    Terrarium,
}

#[derive(Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
enum DemCrsArg {
    #[default]
    Auto,
    Degrees,
    Projected,
}

fn parse_tile(s: &str) -> std::result::Result<[u32; 3], String> {
    let v: Vec<u32> =
        s.split('/').map(|x| x.trim().parse::<u32>()).collect::<std::result::Result<_, _>>().map_err(|_| format!("{s:?} is not z/x/y"))?;
    <[u32; 3]>::try_from(v).map_err(|_| format!("{s:?} is not z/x/y"))
}

impl DemArgs {
    fn options(&self) -> anyhow::Result<strata::import::DemOptions> {
        use strata::import::{DemCrs, DemEncoding};
        anyhow::ensure!(self.z_scale.is_finite() && self.z_scale > 0.0, "--z-scale must be a positive number, not {}", self.z_scale);
        if let Some(c) = self.dem_cell_size {
            anyhow::ensure!(c.is_finite() && c > 0.0, "--dem-cell-size must be a positive number of metres, not {c}");
        }
        Ok(strata::import::DemOptions {
            encoding: self.dem_encoding.map(|e| match e {
                DemEncodingArg::Grey16 => DemEncoding::Grey16,
                DemEncodingArg::TerrainRgb => DemEncoding::TerrainRgb,
                DemEncodingArg::Terrarium => DemEncoding::Terrarium,
            }),
            crs: match self.dem_crs {
                DemCrsArg::Auto => DemCrs::Auto,
                DemCrsArg::Degrees => DemCrs::Degrees,
                DemCrsArg::Projected => DemCrs::Projected,
            },
            z_scale: self.z_scale,
            cell_size: self.dem_cell_size,
            tile: self.dem_tile,
        })
    }
}

/// `--format`: the names of the importer table.
fn format_parser() -> impl clap::builder::TypedValueParser<Value = Format> {
    use clap::builder::TypedValueParser;
    let names = strata::import::IMPORTERS.iter().map(|i| clap::builder::PossibleValue::new(i.name));
    clap::builder::PossibleValuesParser::new(names).map(|name: String| Format::by_name(&name).expect("a listed name"))
}

impl MeshInput {
    fn options(&self) -> anyhow::Result<ImportOptions> {
        Ok(ImportOptions { format: self.format, allow_outside_files: self.allow_outside_files, dem: self.dem.options()? })
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
    /// Size cap growth factor per level [default: the inverse of --level-ratio, rounded, at
    /// least 2, so that nodes keep their size from level to level: 2 at the default ratio]
    #[arg(long)]
    growth: Option<u32>,
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
    /// The grouping's parameters for levels made at `level_ratio`.
    fn params(&self, level_ratio: f32) -> HierarchyParams {
        HierarchyParams {
            cluster_faces: self.cluster_faces.max(1),
            cluster_angle: self.cluster_angle.to_radians(),
            leaf_faces: self.leaf_faces.max(1),
            leaf_angle: self.leaf_angle.to_radians(),
            angle_step: self.angle_step.to_radians(),
            growth: self.growth.unwrap_or_else(|| HierarchyParams::growth_for(level_ratio)),
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
    let imported = import_with(&input.mesh, &input.options()?)?;
    for w in &imported.warnings {
        eprintln!("warning: {}: {w}", input.mesh.display());
    }
    Ok(imported)
}
