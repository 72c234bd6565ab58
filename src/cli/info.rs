//! `strata info`: import a mesh and print what it holds: counts, attributes, bounds, topology,
//! what cleaning removed.

use super::{load, MeshInput};
use anyhow::{Context, Result};
use strata::mesh;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub input: MeshInput,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> Result<()> {
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
            "metres_per_unit": imp.metres_per_unit,
            "material_names": m.materials.iter().map(|m| m.name.clone()).collect::<Vec<_>>(),
            "attributes": attributes,
            "images": m.images.iter().map(|i| serde_json::json!({ "name": i.name, "codec": i.codec, "bytes": i.bytes.len() })).collect::<Vec<_>>(),
            "bounds": { "min": lo.to_array(), "max": hi.to_array() },
            "components": components,
            "boundary_edges": adj.boundary_edges,
            "nonmanifold_edges": adj.nonmanifold_edges.len(),
            "cleaned": imp.cleaned,
            "grid": imp.grid,
            "georef": imp.georef,
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
    if !m.images.is_empty() {
        let bytes: usize = m.images.iter().map(|i| i.bytes.len()).sum();
        println!(
            "images             {} ({bytes} bytes: {})",
            m.images.len(),
            m.images.iter().map(|i| i.name.as_str()).collect::<Vec<_>>().join(", ")
        );
    }
    println!("units              {}", imp.metres_per_unit.map_or("not stated by the file".to_string(), |m| format!("{m} m per unit")));
    println!("bounds             [{:.6}, {:.6}, {:.6}] .. [{:.6}, {:.6}, {:.6}]", lo.x, lo.y, lo.z, hi.x, hi.y, hi.z);
    println!("components         {components}");
    println!("boundary edges     {}", adj.boundary_edges);
    println!("non-manifold edges {}", adj.nonmanifold_edges.len());
    let c = imp.cleaned;
    println!(
        "cleaning           welded {} vertices, removed {} degenerate faces, {} duplicate faces, {} unreferenced vertices",
        c.welded_vertices, c.degenerate_faces, c.duplicate_faces, c.unreferenced_vertices
    );
    if let Some(g) = &imp.grid {
        println!(
            "grid               {} × {} samples, {} without data, heights {} .. {} m",
            g.cols, g.rows, g.voids, g.min_height, g.max_height
        );
    }
    if let Some(g) = &imp.georef {
        let frame = match g.frame {
            strata::format::GeoFrame::Unplaced => "placed nowhere (the file does not say where)".to_string(),
            strata::format::GeoFrame::LocalTangent => {
                format!("local tangent plane (x east, y up, z south) at {:.6}°, {:.6}° on WGS 84", g.origin[0], g.origin[1])
            }
            strata::format::GeoFrame::Projected => format!("x east, y up, z south from ({}, {}) of the CRS", g.origin[0], g.origin[1]),
        };
        println!("georeference       {frame}{}", if g.crs.is_empty() { String::new() } else { format!("; source CRS {}", g.crs) });
    }
    println!("import time        {:.1} ms", imp.import_ms);
    Ok(())
}
