//! The strata command line: parse arguments, call the library, print results.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use strata::{import, mesh, Format};

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
