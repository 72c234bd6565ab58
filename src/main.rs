//! The strata command line: parse arguments, call the library, print results.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use strata::hierarchy::{self, HierarchyParams, Level};
use strata::{culling, format, import_with, mesh, Format, ImportOptions};
use strata::pipeline::Normals;
use std::time::Instant;

#[derive(Parser)]
#[command(name = "strata", version, about = "Make huge triangle meshes viewable on small machines")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert a mesh into a strata chunk file: import, group, simplify per level, write.
    Convert(ConvertArgs),
    /// Import a mesh and print what it holds: counts, attributes, bounds, topology, cleaning.
    Info(InfoArgs),
    /// Simplify a mesh by quadric-error edge collapse (no groups) and write it.
    Simplify(SimplifyArgs),
    /// Group faces by normal cone into a hierarchy and measure hierarchical back-face culling.
    Groups(GroupsArgs),
    /// Show a strata file: header, chunks, levels, and nodes on request.
    Inspect(InspectArgs),
    /// Check every checksum and structural rule of a strata file; exit non-zero on any problem.
    Verify(VerifyArgs),
    /// Write one level of a strata file as a mesh (.obj, .ply or .glb).
    Extract(ExtractArgs),
    /// Play a viewing session over a strata file: per frame, the streamed front, its delta and costs.
    Stream(StreamArgs),
    /// Draw a mesh, or one level of a strata file, to a PNG with the software rasterizer.
    Render(RenderArgs),
}

#[derive(Args)]
#[command(group(clap::ArgGroup::new("session").args(["orbit", "path"])))]
struct StreamArgs {
    /// A .strata file.
    file: PathBuf,
    /// N frames around the model, moving in from far (model ~5% of the view) to a close-up over the
    /// first half. The default session (64 frames).
    #[arg(long, value_name = "N")]
    orbit: Option<usize>,
    /// Camera path: one camera per line, "ex ey ez tx ty tz" (eye, then target, model units);
    /// blank lines and lines starting with # are skipped.
    #[arg(long, value_name = "FILE")]
    path: Option<PathBuf>,
    /// Most faces displayed at once.
    #[arg(long, value_name = "N")]
    budget_faces: Option<u64>,
    /// Most bytes of resident geometry.
    #[arg(long, value_name = "B")]
    budget_bytes: Option<u64>,
    /// Refine until the projected geometric error is under this many pixels.
    #[arg(long, value_name = "E", default_value_t = 1.0)]
    pixel_error: f32,
    /// Frame time to keep, in ms, by steering the pixel threshold (refine + draw of the last frame).
    #[arg(long, value_name = "T")]
    target_ms: Option<f32>,
    /// Refinement order under the budgets: largest projected error first, silhouette (the paper's
    /// f(g)) or plain breadth-first.
    #[arg(long, value_enum, default_value_t = StreamPriority::Error)]
    priority: StreamPriority,
    /// With --target-ms, only react to measured frame times: no coarse first frame for what comes
    /// into view and no check of a front against the target before it is drawn.
    #[arg(long)]
    no_predict: bool,
    #[arg(long, default_value_t = 640)]
    width: u32,
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// One JSON object per frame (JSON lines).
    #[arg(long)]
    json: bool,
    /// Write each frame as a PNG into this directory (nodes colored by id).
    #[arg(long, value_name = "DIR")]
    frames_dir: Option<PathBuf>,
    /// Write the last front as a mesh (.obj, .ply or .glb).
    #[arg(long, value_name = "OUT")]
    export_cut: Option<PathBuf>,
    /// Per frame, also draw the front and the full-detail model (level 0, read once, kept apart
    /// from the session's reader and budgets) in one plain color and report the shape retention.
    #[arg(long)]
    compare_full: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum StreamPriority {
    Error,
    Silhouette,
    Breadth,
}

#[derive(Clone, Copy, PartialEq, clap::ValueEnum)]
enum NormalsArg {
    Auto,
    Input,
    None,
}

/// How level meshes are made.
#[derive(Args)]
struct LevelArgs {
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

#[derive(Args)]
struct ConvertArgs {
    #[command(flatten)]
    input: MeshInput,
    /// The .strata file to write (written to a temporary name, renamed when complete).
    output: PathBuf,
    #[command(flatten)]
    grouping: GroupingArgs,
    #[command(flatten)]
    levels: LevelArgs,
    /// Normals to store: the input's, else smooth ones computed with --crease-angle (auto); only
    /// the input's (input); none, for the smallest file drawn flat-shaded (none).
    #[arg(long, value_enum, default_value_t = NormalsArg::Auto)]
    normals: NormalsArg,
    /// Edges whose faces' normals differ by more than this many degrees stay sharp in computed normals.
    #[arg(long, default_value_t = 60.0)]
    crease_angle: f32,
    /// No progress bars.
    #[arg(long, short)]
    quiet: bool,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
#[command(group(clap::ArgGroup::new("target").required(true).args(["ratio", "faces", "error"])))]
struct SimplifyArgs {
    #[command(flatten)]
    input: MeshInput,
    /// Keep this fraction of the faces.
    #[arg(long)]
    ratio: Option<f32>,
    /// Keep this many faces.
    #[arg(long)]
    faces: Option<usize>,
    /// Simplify as far as the error estimate stays under this fraction of the bounding-box diagonal.
    #[arg(long)]
    error: Option<f32>,
    /// Output mesh (.obj, .ply or .glb).
    #[arg(short, long)]
    output: PathBuf,
    /// With --ratio or --faces: when the target cannot be reached otherwise, cut handles and drop
    /// closed tetrahedra (the mesh stays manifold; its genus and components change).
    #[arg(long)]
    topology: bool,
    /// Also measure the sampled surface distance between input and output.
    #[arg(long)]
    measure: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct InspectArgs {
    /// A .strata file.
    file: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// List the node tree from the top level down D levels.
    #[arg(long, value_name = "D")]
    depth: Option<u32>,
    /// List every node of level L.
    #[arg(long, value_name = "L")]
    level: Option<u32>,
    /// Show node N and the chunks of its geometry.
    #[arg(long, value_name = "N")]
    node: Option<u32>,
}

#[derive(Args)]
struct VerifyArgs {
    /// A .strata file.
    file: PathBuf,
}

#[derive(Args)]
struct ExtractArgs {
    /// A .strata file.
    file: PathBuf,
    /// Level to write (0 = full detail).
    #[arg(long, default_value_t = 0)]
    level: u32,
    /// Output mesh: .obj, .ply or .glb.
    #[arg(short, long)]
    output: PathBuf,
}

#[derive(Args)]
struct RenderArgs {
    /// A .strata file, or an OBJ, glTF/GLB or PLY mesh.
    input: PathBuf,
    /// The PNG to write.
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long, default_value_t = 512)]
    width: u32,
    #[arg(long, default_value_t = 512)]
    height: u32,
    /// Eye and target as "ex,ey,ez:tx,ty,tz"; default: framing the model from --view-dir.
    #[arg(long, allow_hyphen_values = true)]
    camera: Option<String>,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 45.0)]
    fov: f32,
    /// Direction from the model toward the eye for the default camera, as "x,y,z".
    #[arg(long, default_value = "0.3,0.4,1.0", allow_hyphen_values = true)]
    view_dir: String,
    /// Color by: one plain color, each node (strata files), or the level (strata files).
    #[arg(long, value_enum, default_value_t = RenderColor::Plain)]
    color: RenderColor,
    /// Level of a strata file to draw (0 = full detail).
    #[arg(long, default_value_t = 0)]
    level: u32,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum RenderColor {
    Plain,
    Groups,
    Levels,
}

/// Where a mesh comes from.
#[derive(Args)]
struct MeshInput {
    /// OBJ, glTF/GLB or PLY file.
    mesh: PathBuf,
    /// Read as this format whatever the extension.
    #[arg(long, value_enum)]
    format: Option<Format>,
    /// Let a glTF file read buffers outside its folder (an absolute path or `..` in a buffer uri).
    #[arg(long)]
    allow_outside_files: bool,
}

impl MeshInput {
    fn options(&self) -> ImportOptions {
        ImportOptions { format: self.format, allow_outside_files: self.allow_outside_files }
    }
}

#[derive(Args)]
struct InfoArgs {
    #[command(flatten)]
    input: MeshInput,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// Grouping parameters (METHOD.md §3); angles in degrees.
#[derive(Args)]
struct GroupingArgs {
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

#[derive(Args)]
struct GroupsArgs {
    #[command(flatten)]
    input: MeshInput,
    #[command(flatten)]
    grouping: GroupingArgs,
    /// View directions for the culling measure, spread evenly on the sphere.
    #[arg(long, default_value_t = 256)]
    views: usize,
    /// Also build the level meshes and report each one's faces, error and sampled distance to the input.
    #[arg(long)]
    levels: bool,
    #[command(flatten)]
    level_params: LevelArgs,
    /// Write the mesh colored by its groups of level L (-1 for the culling clusters) to a PLY.
    #[arg(long, num_args = 2, value_names = ["L", "OUT"], allow_hyphen_values = true)]
    write_groups: Option<Vec<String>>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    // Printing into a closed pipe (`strata inspect f | head`) ends the process quietly, as other
    // command-line tools do, instead of panicking.
    #[cfg(unix)]
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    // On Ctrl-C, remove temporary output files before exiting.
    let _ = ctrlc::set_handler(|| {
        strata::atomic::remove_pending();
        std::process::exit(130);
    });
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Convert(a) => convert(a),
        Command::Info(a) => info(a),
        Command::Simplify(a) => simplify(a),
        Command::Groups(a) => groups(a),
        Command::Inspect(a) => inspect(a),
        Command::Verify(a) => verify(a),
        Command::Extract(a) => extract(a),
        Command::Stream(a) => stream(a),
        Command::Render(a) => render(a),
    }
}

fn load(input: &MeshInput) -> Result<strata::Imported> {
    let imported = import_with(&input.mesh, &input.options())?;
    for w in &imported.warnings {
        eprintln!("warning: {}: {w}", input.mesh.display());
    }
    Ok(imported)
}

fn info(a: InfoArgs) -> Result<()> {
    let imp = load(&a.input)?;
    let m = &imp.mesh;
    let adj = mesh::Adjacency::build(m);
    let (components, _) = mesh::components(m);
    let (lo, hi) = m.bounds().context("empty mesh")?;
    let attributes: Vec<&str> = [("normals", !m.normals.is_empty()), ("uvs", !m.uvs.is_empty()), ("colors", !m.colors.is_empty())]
        .into_iter()
        .filter_map(|(n, present)| present.then_some(n))
        .collect();
    if a.json {
        let v = serde_json::json!({
            "file": a.input.mesh.display().to_string(),
            "vertices": m.vertex_count(),
            "faces": m.face_count(),
            "source_faces": imp.source_faces,
            "materials": m.materials.len(),
            "material_names": m.materials.iter().map(|m| m.name.clone()).collect::<Vec<_>>(),
            "attributes": attributes,
            "bounds": { "min": lo.to_array(), "max": hi.to_array() },
            "components": components,
            "boundary_edges": adj.boundary_edges,
            "nonmanifold_edges": adj.nonmanifold_edges.len(),
            "cleaned": imp.cleaned,
            "warnings": imp.warnings,
            "import_ms": imp.import_ms,
        });
        println!("{v}");
        return Ok(());
    }
    println!("file               {}", a.input.mesh.display());
    println!("vertices           {}", m.vertex_count());
    println!("faces              {} (of {} read)", m.face_count(), imp.source_faces);
    println!("materials          {} ({})", m.materials.len(), m.materials.iter().map(|m| m.name.as_str()).collect::<Vec<_>>().join(", "));
    println!("attributes         {}", if attributes.is_empty() { "none".to_string() } else { attributes.join(", ") });
    println!("bounds             [{:.6}, {:.6}, {:.6}] .. [{:.6}, {:.6}, {:.6}]", lo.x, lo.y, lo.z, hi.x, hi.y, hi.z);
    println!("components         {components}");
    println!("boundary edges     {}", adj.boundary_edges);
    println!("non-manifold edges {}", adj.nonmanifold_edges.len());
    let c = imp.cleaned;
    println!(
        "cleaning           welded {} vertices, removed {} degenerate faces, {} duplicate faces, {} unreferenced vertices",
        c.welded_vertices, c.degenerate_faces, c.duplicate_faces, c.unreferenced_vertices
    );
    println!("import time        {:.1} ms", imp.import_ms);
    Ok(())
}

/// Minimum, median and maximum of a list.
fn spread(mut v: Vec<f64>) -> [f64; 3] {
    if v.is_empty() {
        return [0.0; 3];
    }
    v.sort_by(f64::total_cmp);
    [v[0], v[v.len() / 2], v[v.len() - 1]]
}

fn level_summary(name: &str, level: &Level) -> serde_json::Value {
    let faces = spread(level.groups.iter().map(|g| g.faces as f64).collect());
    let angles = spread(level.groups.iter().map(|g| g.cone.half_angle.to_degrees() as f64).collect());
    serde_json::json!({
        "level": name,
        "groups": level.groups.len(),
        "faces_min": faces[0], "faces_median": faces[1], "faces_max": faces[2],
        "cone_deg_min": angles[0], "cone_deg_median": angles[1], "cone_deg_max": angles[2],
        "threshold_deg": level.max_angle.to_degrees(),
        "cap_faces": level.max_faces,
    })
}

fn groups(a: GroupsArgs) -> Result<()> {
    let imp = load(&a.input)?;
    let m = &imp.mesh;
    let start = Instant::now();
    let adj = mesh::Adjacency::build(m);
    let mut h = hierarchy::build(m, &adj, &a.grouping.params());
    let hierarchy_ms = start.elapsed().as_secs_f64() * 1e3;
    let stats = culling::measure(&h, m, a.views.max(1));
    let level_meshes = a.levels.then(|| {
        let start = Instant::now();
        let lv = strata::levels::build(m.clone(), &mut h, &a.level_params.params(), &mut |_| {});
        (lv, start.elapsed().as_secs_f64() * 1e3)
    });
    if let Some(w) = &a.write_groups {
        let level: i64 = w[0].parse().with_context(|| format!("--write-groups: level {:?} is not a number", w[0]))?;
        let partition = match level {
            -1 => &h.clusters,
            l if l >= 0 && (l as usize) < h.levels.len() => &h.levels[l as usize],
            _ => anyhow::bail!("--write-groups: level {level} does not exist (levels -1..{})", h.levels.len() - 1),
        };
        let mut colored = m.clone();
        colored.colors = partition.face_group.iter().flat_map(|&g| [group_color(g); 3]).collect();
        strata::export::write(std::path::Path::new(&w[1]), &colored)?;
    }
    let mut rows = vec![level_summary("clusters", &h.clusters)];
    rows.extend(h.levels.iter().enumerate().map(|(i, l)| level_summary(&i.to_string(), l)));
    if let Some((lv, _)) = &level_meshes {
        for (row, level) in rows.iter_mut().skip(1).zip(&lv.levels) {
            let d = strata::distance::surface_distance(m, &level.mesh, 100_000, 1);
            row["mesh_faces"] = level.mesh.face_count().into();
            row["node_error_max"] = level.group_error.iter().copied().fold(0.0f32, f32::max).into();
            row["distance_max_over_diagonal"] = (d.max / d.diagonal).into();
            row["distance_mean_over_diagonal"] = (d.mean / d.diagonal).into();
        }
    }
    let levels_ms = level_meshes.as_ref().map(|l| l.1);
    if a.json {
        let v = serde_json::json!({
            "file": a.input.mesh.display().to_string(),
            "faces": m.face_count(),
            "levels": rows,
            "culling": stats,
            "hierarchy_ms": hierarchy_ms,
            "level_meshes_ms": levels_ms,
            "import_ms": imp.import_ms,
        });
        println!("{v}");
        return Ok(());
    }
    println!("{} faces, hierarchy built in {hierarchy_ms:.1} ms", m.face_count());
    println!("{:>9} {:>7} {:>21} {:>24}", "level", "groups", "faces min/med/max", "cone deg min/med/max");
    for r in &rows {
        println!(
            "{:>9} {:>7} {:>7}/{:>6}/{:>6} {:>8.1}/{:>6.1}/{:>6.1}",
            r["level"].as_str().unwrap_or(""),
            r["groups"],
            r["faces_min"],
            r["faces_median"],
            r["faces_max"],
            r["cone_deg_min"].as_f64().unwrap_or(0.0),
            r["cone_deg_median"].as_f64().unwrap_or(0.0),
            r["cone_deg_max"].as_f64().unwrap_or(0.0),
        );
    }
    if let Some(ms) = levels_ms {
        println!("level meshes built in {ms:.1} ms");
        println!("{:>9} {:>9} {:>12} {:>14} {:>15}", "level", "faces", "node error", "max dist/diag", "mean dist/diag");
        for r in rows.iter().skip(1) {
            println!(
                "{:>9} {:>9} {:>12.6} {:>14.6} {:>15.6}",
                r["level"].as_str().unwrap_or(""),
                r["mesh_faces"],
                r["node_error_max"].as_f64().unwrap_or(0.0),
                r["distance_max_over_diagonal"].as_f64().unwrap_or(0.0),
                r["distance_mean_over_diagonal"].as_f64().unwrap_or(0.0),
            );
        }
    }
    println!(
        "culling over {} views: cost {:.3} of per-face culling, {:.1}% faces culled of {:.1}% back-facing, {:.0} tests per view",
        stats.views,
        stats.cost_ratio,
        100.0 * stats.faces_culled,
        100.0 * stats.faces_backfacing,
        stats.tests
    );
    Ok(())
}

/// A distinct, stable color per group label.
fn group_color(g: u32) -> [u8; 4] {
    let h = (g as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    [(h >> 16) as u8 | 0x30, (h >> 32) as u8 | 0x30, (h >> 48) as u8 | 0x30, 255]
}

fn inspect(a: InspectArgs) -> Result<()> {
    let mut rd = format::Reader::open_path(&a.file)?;
    let select = format::inspect::Selection { depth: a.depth, level: a.level, node: a.node };
    let v = format::inspect::inspect(&mut rd, select)?;
    if a.json {
        println!("{}", serde_json::to_string(&v)?);
        return Ok(());
    }
    let h = &v.header;
    println!("strata file {} (format {}, {} bytes, written by {})", a.file.display(), v.version, h.file_size, h.tool);
    let units = if h.metres_per_unit > 0.0 { format!("{} m per unit", h.metres_per_unit) } else { "unknown units".into() };
    println!("input     {} vertices, {} faces, {units}", h.input_vertices, h.input_faces);
    println!("bounds    {:?} .. {:?}", h.min, h.max);
    println!("grid      origin {:?}, step {}, {} bits", h.grid.origin, h.grid.step, h.grid.bits);
    println!("contents  {} levels, {} nodes, {} culling clusters, attributes {:?}", h.levels, h.nodes, h.clusters, h.attributes);
    println!("materials {}", h.materials.join(", "));
    println!("chunks");
    for c in &v.chunks {
        println!("  {}{} at {} ({} bytes, flags {})", "  ".repeat(c.depth as usize), c.id, c.offset, c.size, c.flags);
    }
    for l in v.levels.iter().rev() {
        println!("  GEOM x{} level {} at {}..{} ({} bytes)", l.nodes, l.level, l.start, l.end, l.bytes);
    }
    println!("{:>5} {:>6} {:>10} {:>10} {:>11} {:>10} {:>9} {:>10}", "level", "nodes", "faces", "vertices", "bytes", "bytes/face", "cone max", "error max");
    for l in v.levels.iter().rev() {
        println!(
            "{:>5} {:>6} {:>10} {:>10} {:>11} {:>10.2} {:>8.1}° {:>10.4}",
            l.level, l.nodes, l.faces, l.vertices, l.bytes, l.bytes as f64 / l.faces.max(1) as f64, l.cone_deg_max, l.error_max
        );
    }
    if !v.nodes.is_empty() {
        println!("{:>7} {:>5} {:>7} {:>7} {:>8} {:>7} {:>10} {:>9} children", "node", "level", "parent", "faces", "vertices", "cone", "error", "bytes");
    }
    for n in &v.nodes {
        let parent = n.parent.map_or("-".to_string(), |p| p.to_string());
        let children = match (n.children.first(), n.children.last()) {
            (Some(f), Some(l)) => format!("{f}..={l}"),
            _ => "-".into(),
        };
        println!(
            "{}{:>7} {:>5} {:>7} {:>7} {:>8} {:>6.1}° {:>10.4} {:>9} {children}",
            "  ".repeat(n.depth as usize), n.node, n.level, parent, n.faces, n.vertices, n.cone_deg, n.error, n.bytes
        );
        for c in &n.chunks {
            println!("    {}{} at {} ({} bytes, flags {})", "  ".repeat(c.depth as usize), c.id, c.offset, c.size, c.flags);
        }
    }
    Ok(())
}

fn verify(a: VerifyArgs) -> Result<()> {
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

fn extract(a: ExtractArgs) -> Result<()> {
    let mut rd = format::Reader::open_path(&a.file)?;
    let mesh = format::to_mesh(&mut rd, a.level)?;
    strata::export::write(&a.output, &mesh)?;
    println!("wrote level {} ({} faces, {} vertices) to {}", a.level, mesh.face_count(), mesh.vertex_count(), a.output.display());
    Ok(())
}

fn stream(a: StreamArgs) -> Result<()> {
    use strata::stream::{session, Budgets, Priority, Streamer};
    let opened = Instant::now();
    let reader = format::Reader::open_path(&a.file)?;
    let h = reader.header();
    let (center, radius) = (0.5 * (h.min + h.max), 0.5 * (h.max - h.min).length());
    let (width, height) = (a.width.max(1), a.height.max(1));
    let cameras = match &a.path {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            session::parse_path(&text, p, center, radius, width, height)?
        }
        None => {
            let n = a.orbit.unwrap_or(64).max(1);
            (0..n).map(|i| session::orbit(center, radius, i, n, width, height)).collect()
        }
    };
    if let Some(d) = &a.frames_dir {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    let priority = match a.priority {
        StreamPriority::Error => Priority::Error,
        StreamPriority::Silhouette => Priority::Silhouette,
        StreamPriority::Breadth => Priority::Breadth,
    };
    let budgets = Budgets {
        faces: a.budget_faces,
        bytes: a.budget_bytes,
        pixel_error: a.pixel_error,
        target_ms: a.target_ms,
        priority,
        predict: !a.no_predict,
    };
    let full: Vec<format::NodeGeometry> = if a.compare_full {
        let mut rd = format::Reader::open_path(&a.file)?;
        rd.level_nodes(0).map(|i| rd.read_node(i)).collect::<strata::error::Result<_>>()?
    } else {
        Vec::new()
    };
    let mut streamer = Streamer::new(reader, budgets)?;
    // Frames are drawn strip by strip; a whole one is kept only to be written out.
    let mut strips = strata::render::Strips::new(width, height);
    let mut frame_rgba = if a.frames_dir.is_some() { vec![0u8; 4 * width as usize * height as usize] } else { Vec::new() };
    let (mut plain_front, mut plain_full) = (image_if(a.compare_full, width, height), image_if(a.compare_full, width, height));
    let mut last_ms = None;
    for (k, camera) in cameras.iter().enumerate() {
        let rep = streamer.update(camera, last_ms)?;
        let start = Instant::now();
        let parts: Vec<strata::render::Part> = rep
            .front
            .iter()
            .filter_map(|&i| {
                let g = streamer.geometry(i)?;
                Some(strata::render::Part { positions: &g.positions, normals: &g.normals, indices: &g.indices, color: strata::render::palette(i) })
            })
            .collect();
        let row_bytes = 4 * width as usize;
        strips.draw(camera, &parts, |row, rgba| {
            if let Some(out) = frame_rgba.get_mut(row as usize * row_bytes..row as usize * row_bytes + rgba.len()) {
                out.copy_from_slice(rgba);
            }
        });
        let draw_ms = start.elapsed().as_secs_f64() * 1e3;
        if let Some(d) = &a.frames_dir {
            strata::render::write_rgba_png(&d.join(format!("frame{k:05}.png")), width, height, &frame_rgba)?;
        }
        last_ms = Some((rep.stats.refine_ms + draw_ms) as f32);
        let since_open_ms = opened.elapsed().as_secs_f64() * 1e3;
        let retained = match (&mut plain_front, &mut plain_full) {
            (Some(front), Some(whole)) => {
                const PLAIN: [u8; 4] = [200, 200, 200, 255];
                front.clear();
                whole.clear();
                for &i in &rep.front {
                    if let Some(g) = streamer.geometry(i) {
                        front.draw(camera, &g.positions, &g.normals, &g.indices, PLAIN);
                    }
                }
                for g in &full {
                    whole.draw(camera, &g.positions, &g.normals, &g.indices, PLAIN);
                }
                Some(strata::stream::retention::retention(front, whole))
            }
            _ => None,
        };
        let s = &rep.stats;
        if a.json {
            let mut v = serde_json::json!({
                "frame": rep.frame, "faces": s.faces, "nodes": s.nodes, "culled": s.culled, "levels": s.levels,
                "added": rep.added.len(), "removed": rep.removed.len(), "bytes_read": s.bytes_read,
                "resident_bytes": s.resident_bytes, "pixel_error": s.pixel_error,
                "refine_ms": s.refine_ms, "draw_ms": draw_ms, "since_open_ms": since_open_ms,
            });
            if let Some(r) = retained {
                v["retained"] = serde_json::json!(r.shaded);
                v["coverage_retained"] = serde_json::json!(r.coverage);
            }
            println!("{v}");
        } else {
            let levels: Vec<String> = s.levels.iter().map(|c| c.to_string()).collect();
            println!(
                "frame {:>4}  nodes {:>5}  faces {:>8}  levels [{}]  +{} -{}  read {} B  resident {} B  px {:.2}  refine {:.2} ms  draw {:.2} ms",
                rep.frame, s.nodes, s.faces, levels.join(" "), rep.added.len(), rep.removed.len(), s.bytes_read,
                s.resident_bytes, s.pixel_error, s.refine_ms, draw_ms
            );
            if k == 0 {
                println!("           first frame ready {since_open_ms:.1} ms after opening the file");
            }
            if let Some(r) = retained {
                println!("           retained {:.4} (coverage {:.4})", r.shaded, r.coverage);
            }
        }
    }
    if let Some(out) = &a.export_cut {
        let mesh = streamer.front_mesh();
        strata::export::write(out, &mesh)?;
        if !a.json {
            println!("wrote the last front ({} faces) to {}", mesh.face_count(), out.display());
        }
    }
    Ok(())
}

/// A cleared image when `wanted`.
fn image_if(wanted: bool, width: u32, height: u32) -> Option<strata::render::Image> {
    wanted.then(|| strata::render::Image::new(width, height))
}

/// Three comma-separated numbers.
fn parse_vec3(s: &str, what: &str) -> Result<glam::Vec3> {
    let v: Vec<f32> = s.split(',').map(|x| x.trim().parse::<f32>()).collect::<std::result::Result<_, _>>()
        .with_context(|| format!("{what}: {s:?} is not three comma-separated numbers"))?;
    anyhow::ensure!(v.len() == 3 && v.iter().all(|x| x.is_finite()), "{what}: {s:?} is not three comma-separated numbers");
    Ok(glam::Vec3::new(v[0], v[1], v[2]))
}

/// The camera of `strata render`: framing the bounding sphere, or at --camera's eye and target.
fn render_camera(a: &RenderArgs, min: glam::Vec3, max: glam::Vec3) -> Result<strata::camera::Camera> {
    anyhow::ensure!(a.fov > 0.0 && a.fov < 180.0, "--fov must be between 0 and 180 degrees, not {}", a.fov);
    let (center, radius) = ((min + max) * 0.5, ((max - min).length() * 0.5).max(f32::MIN_POSITIVE));
    let fov = a.fov.to_radians();
    let Some(spec) = &a.camera else {
        return Ok(strata::camera::Camera::framing(center, radius, parse_vec3(&a.view_dir, "--view-dir")?, fov, a.width, a.height));
    };
    let (eye, target) = spec.split_once(':').with_context(|| format!("--camera: {spec:?} is not \"ex,ey,ez:tx,ty,tz\""))?;
    let (eye, target) = (parse_vec3(eye, "--camera eye")?, parse_vec3(target, "--camera target")?);
    anyhow::ensure!(eye != target, "--camera: the eye and the target are the same point");
    let mut camera = strata::camera::Camera::framing(center, radius, eye - target, fov, a.width, a.height);
    let distance = eye.distance(center);
    camera.eye = eye;
    camera.target = target;
    camera.near = (distance - radius).max(1e-4 * (distance + radius));
    camera.far = distance + radius;
    Ok(camera)
}

fn render(a: RenderArgs) -> Result<()> {
    use strata::render::{palette, Image};
    anyhow::ensure!(a.width > 0 && a.height > 0, "--width and --height must be positive");
    let plain = [200, 200, 200, 255];
    let mut image = Image::new(a.width, a.height);
    let (mut drawn, mut faces, mut draw_ms) = (0, 0, 0.0);
    let is_strata = a.input.extension().is_some_and(|e| e.eq_ignore_ascii_case("strata"));
    if is_strata {
        let mut rd = format::Reader::open_path(&a.input)?;
        let levels = rd.header().levels;
        anyhow::ensure!(a.level < levels, "--level {}: {} has levels 0..{}", a.level, a.input.display(), levels.saturating_sub(1));
        let camera = render_camera(&a, rd.header().min, rd.header().max)?;
        for node in rd.level_nodes(a.level) {
            let g = rd.read_node(node)?;
            let color = match a.color {
                RenderColor::Plain => plain,
                RenderColor::Groups => palette(node),
                RenderColor::Levels => palette(a.level),
            };
            let start = Instant::now();
            drawn += image.draw(&camera, &g.positions, &g.normals, &g.indices, color);
            draw_ms += start.elapsed().as_secs_f64() * 1e3;
            faces += g.face_count();
        }
    } else {
        anyhow::ensure!(a.color == RenderColor::Plain, "--color groups and levels need a .strata file");
        let m = load(&MeshInput { mesh: a.input.clone(), format: None, allow_outside_files: false })?.mesh;
        let (min, max) = m.bounds().context("empty mesh")?;
        let camera = render_camera(&a, min, max)?;
        // Corner normals become vertices of their own; without them, faces are flat.
        let (positions, normals, indices): (Vec<_>, Vec<_>, Vec<u32>) = if m.normals.is_empty() {
            (m.positions.clone(), Vec::new(), m.triangles.iter().flatten().copied().collect())
        } else {
            let corners = m.triangles.iter().flatten().map(|&v| m.positions.get(v as usize).copied().unwrap_or(glam::Vec3::NAN)).collect();
            (corners, m.normals.clone(), (0..3 * m.triangles.len() as u32).collect())
        };
        let start = Instant::now();
        drawn = image.draw(&camera, &positions, &normals, &indices, plain);
        draw_ms = start.elapsed().as_secs_f64() * 1e3;
        faces = m.face_count();
    }
    image.write_png(&a.output)?;
    println!("drew {drawn} of {faces} faces at {}x{} in {draw_ms:.1} ms, wrote {}", a.width, a.height, a.output.display());
    Ok(())
}

/// Progress bars on a terminal, one per stage; nothing when quiet or piped.
struct Bars {
    visible: bool,
    bar: Option<indicatif::ProgressBar>,
}

impl Bars {
    fn new(quiet: bool) -> Bars {
        use std::io::IsTerminal;
        Bars { visible: !quiet && std::io::stderr().is_terminal(), bar: None }
    }
}

impl strata::pipeline::Progress for Bars {
    fn stage(&mut self, name: &str, steps: u64) {
        if let Some(bar) = self.bar.take() {
            bar.finish();
        }
        if !self.visible {
            return;
        }
        let bar = if steps > 0 {
            let b = indicatif::ProgressBar::new(steps);
            b.set_style(indicatif::ProgressStyle::with_template("{prefix:>9} [{bar:30}] {pos}/{len} {elapsed}").unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()));
            b
        } else {
            let b = indicatif::ProgressBar::new_spinner();
            b.set_style(indicatif::ProgressStyle::with_template("{prefix:>9} {spinner} {elapsed}").unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()));
            b.enable_steady_tick(std::time::Duration::from_millis(100));
            b
        };
        bar.set_prefix(name.to_string());
        self.bar = Some(bar);
    }

    fn step(&mut self) {
        if let Some(bar) = &self.bar {
            bar.inc(1);
        }
    }
}

impl Drop for Bars {
    fn drop(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish();
        }
    }
}

fn convert(a: ConvertArgs) -> Result<()> {
    let opts = strata::pipeline::ConvertOptions { hierarchy: a.grouping.params(),
        levels: a.levels.params(),
        normals: match a.normals {
            NormalsArg::Auto => Normals::Auto { crease_angle: a.crease_angle.to_radians() },
            NormalsArg::Input => Normals::Input,
            NormalsArg::None => Normals::None,
        },
    };
    let mut bars = Bars::new(a.quiet || a.json);
    let c = strata::pipeline::convert(&a.input.mesh, &a.input.options(), &a.output, &opts, &mut bars)?;
    drop(bars);
    for w in &c.warnings {
        eprintln!("warning: {}: {w}", a.input.mesh.display());
    }
    let s = &c.summary;
    if a.json {
        println!("{}", serde_json::json!({ "summary": s, "times": c.times, "bytes_per_face": s.bytes_per_face() }));
        return Ok(());
    }
    println!("wrote {} ({} bytes, {:.1} bytes per input face)", a.output.display(), s.file_bytes, s.bytes_per_face());
    println!("{} input faces, {} levels, {} nodes, {} clusters, skeleton {} bytes", s.input_faces, s.levels.len(), s.nodes, s.clusters, s.skeleton_bytes);
    println!("{:>6} {:>7} {:>9} {:>11}", "level", "nodes", "faces", "bytes");
    for l in s.levels.iter().rev() {
        println!("{:>6} {:>7} {:>9} {:>11}", l.level, l.nodes, l.faces, l.bytes);
    }
    let t = c.times;
    println!(
        "time: import {:.0} ms, group {:.0} ms, simplify {:.0} ms, write {:.0} ms, total {:.0} ms",
        t.import_ms,
        t.group_ms,
        t.simplify_ms,
        t.write_ms,
        t.import_ms + t.group_ms + t.simplify_ms + t.write_ms
    );
    Ok(())
}

fn simplify(a: SimplifyArgs) -> Result<()> {
    let imp = load(&a.input)?;
    let m = &imp.mesh;
    let diagonal = m.diagonal();
    let mut opts = strata::simplify::SimplifyOptions::default();
    if let Some(r) = a.ratio {
        anyhow::ensure!((0.0..=1.0).contains(&r), "--ratio must be between 0 and 1, not {r}");
        opts.target_faces = (m.face_count() as f64 * r as f64).round() as usize;
    }
    if let Some(f) = a.faces {
        opts.target_faces = f;
    }
    if let Some(e) = a.error {
        anyhow::ensure!(e >= 0.0, "--error must not be negative, not {e}");
        opts.max_error = Some(e * diagonal);
    }
    opts.topology = a.topology;
    let start = Instant::now();
    let out = strata::simplify::simplify(m, None, &opts);
    let simplify_ms = start.elapsed().as_secs_f64() * 1e3;
    strata::export::write(&a.output, &out.mesh)?;
    let distance = a.measure.then(|| strata::distance::surface_distance(m, &out.mesh, 200_000, 1));
    if a.json {
        let mut v = serde_json::json!({
            "faces_in": m.face_count(),
            "faces_out": out.mesh.face_count(),
            "target_faces": opts.target_faces,
            "simplify_ms": simplify_ms,
            "error_estimate": out.error,
            "error_estimate_over_diagonal": out.error / diagonal.max(f32::MIN_POSITIVE),
        });
        if let Some(d) = distance {
            v["distance"] = serde_json::json!({
                "max": d.max, "mean": d.mean, "rms": d.rms, "diagonal": d.diagonal,
                "max_over_diagonal": d.max / d.diagonal, "mean_over_diagonal": d.mean / d.diagonal,
            });
        }
        println!("{v}");
        return Ok(());
    }
    println!("{} -> {} faces in {simplify_ms:.1} ms, wrote {}", m.face_count(), out.mesh.face_count(), a.output.display());
    println!("error estimate {:.6} ({:.6} of the diagonal)", out.error, out.error / diagonal.max(f32::MIN_POSITIVE));
    if out.mesh.face_count() > opts.target_faces && opts.max_error.is_none() {
        let hint = if a.topology { "" } else { "; --topology lets handles and small components go" };
        println!("stopped above the target of {} faces: no legal collapse is left (corners, handles, small components){hint}", opts.target_faces);
    }
    if let Some(d) = distance {
        println!(
            "sampled distance: max {:.6} ({:.6} of the diagonal), mean {:.6} ({:.6}), rms {:.6}",
            d.max,
            d.max / d.diagonal,
            d.mean,
            d.mean / d.diagonal,
            d.rms
        );
    }
    Ok(())
}
