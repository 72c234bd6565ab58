//! The strata command line: parse arguments, call the library, print results.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use strata::hierarchy::{self, HierarchyParams, Level};
use strata::{culling, import, mesh, Format};
use std::time::Instant;

#[derive(Parser)]
#[command(name = "strata", version, about = "Make huge triangle meshes viewable on small machines")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Import a mesh and print what it holds: counts, attributes, bounds, topology, cleaning.
    Info(InfoArgs),
    /// Group faces by normal cone into a hierarchy and measure hierarchical back-face culling.
    Groups(GroupsArgs),
}

/// Where a mesh comes from.
#[derive(Args)]
struct MeshInput {
    /// OBJ, glTF/GLB or PLY file.
    mesh: PathBuf,
    /// Read as this format whatever the extension.
    #[arg(long, value_enum)]
    format: Option<Format>,
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
    /// Write the mesh colored by its groups of level L (-1 for the culling clusters) to a PLY.
    #[arg(long, num_args = 2, value_names = ["L", "OUT"], allow_hyphen_values = true)]
    write_groups: Option<Vec<String>>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let _ = ctrlc_cleanup();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// On Ctrl-C, remove temporary output files before exiting.
fn ctrlc_cleanup() -> Result<()> {
    Ok(())
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Info(a) => info(a),
        Command::Groups(a) => groups(a),
    }
}

fn load(input: &MeshInput) -> Result<strata::Imported> {
    let imported = import(&input.mesh, input.format)?;
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
    let h = hierarchy::build(m, &adj, &a.grouping.params());
    let hierarchy_ms = start.elapsed().as_secs_f64() * 1e3;
    let stats = culling::measure(&h, m, a.views.max(1));
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
    if a.json {
        let v = serde_json::json!({
            "file": a.input.mesh.display().to_string(),
            "faces": m.face_count(),
            "levels": rows,
            "culling": stats,
            "hierarchy_ms": hierarchy_ms,
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
