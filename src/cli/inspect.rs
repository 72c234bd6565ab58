//! `strata inspect`: the header, chunk tree, levels and, on request, nodes of a chunk file.

use super::open_chunk_file;
use anyhow::Result;
use std::path::PathBuf;
use strata::format;

#[derive(clap::Args)]
pub struct Args {
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

pub fn run(a: Args) -> Result<()> {
    let rd = open_chunk_file(&a.file)?;
    let select = format::inspect::Selection { depth: a.depth, level: a.level, node: a.node };
    let v = format::inspect::inspect(&rd, select)?;
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
    // Format 3 keeps node payloads in one GEOS chunk; format 2 gives each node a GEOM chunk.
    let (geos, indent, what) = if v.version.starts_with('3') { (true, "    ", "payloads") } else { (false, "  ", "GEOM") };
    if geos {
        let (start, end) = (v.levels.iter().map(|l| l.start).min().unwrap_or(0), v.levels.iter().map(|l| l.end).max().unwrap_or(0));
        println!("  GEOS at {} ({} bytes of node payloads)", start.saturating_sub(16), end - start);
    }
    for l in v.levels.iter().rev() {
        println!("{indent}{what} x{} level {} at {}..{} ({} bytes)", l.nodes, l.level, l.start, l.end, l.bytes);
    }
    let texl: usize = v.images.iter().map(|i| i.levels.len()).sum();
    if texl > 0 {
        let (start, end) = (v.images.iter().map(|i| i.start).min().unwrap_or(0), v.images.iter().map(|i| i.end).max().unwrap_or(0));
        println!("  TEXL x{texl} ({} images) at {start}..{end}", v.images.len());
    }
    if let Some(p) = &v.planes {
        println!("  ORDR at {} ({} bytes): {} separating planes under {} parents", p.offset, p.bytes, p.entries, p.parents);
    }
    println!(
        "{:>5} {:>6} {:>10} {:>10} {:>11} {:>10} {:>9} {:>10}",
        "level", "nodes", "faces", "vertices", "bytes", "bytes/face", "cone max", "error max"
    );
    for l in v.levels.iter().rev() {
        println!(
            "{:>5} {:>6} {:>10} {:>10} {:>11} {:>10.2} {:>8.1}° {:>10.4}",
            l.level,
            l.nodes,
            l.faces,
            l.vertices,
            l.bytes,
            l.bytes as f64 / l.faces.max(1) as f64,
            l.cone_deg_max,
            l.error_max
        );
    }
    for im in &v.images {
        let sizes: Vec<String> = im.levels.iter().map(|l| format!("{}×{}", l[0], l[1])).collect();
        let bytes: u64 = im.levels.iter().map(|l| l[2]).sum();
        println!(
            "image {:>3} {:?} {} levels {} ({} bytes) used by {}",
            im.image,
            im.name,
            im.codec.extension(),
            sizes.join(" "),
            bytes,
            if im.uses.is_empty() { "nothing".into() } else { im.uses.join(", ") }
        );
    }
    if !v.nodes.is_empty() {
        println!(
            "{:>7} {:>5} {:>7} {:>7} {:>8} {:>7} {:>10} {:>9} children",
            "node", "level", "parent", "faces", "vertices", "cone", "error", "bytes"
        );
    }
    for n in &v.nodes {
        let parent = n.parent.map_or("-".to_string(), |p| p.to_string());
        let children = match (n.children.first(), n.children.last()) {
            (Some(f), Some(l)) => format!("{f}..={l}"),
            _ => "-".into(),
        };
        println!(
            "{}{:>7} {:>5} {:>7} {:>7} {:>8} {:>6.1}° {:>10.4} {:>9} {children}",
            "  ".repeat(n.depth as usize),
            n.node,
            n.level,
            parent,
            n.faces,
            n.vertices,
            n.cone_deg,
            n.error,
            n.bytes
        );
        for c in &n.chunks {
            println!("    {}{} at {} ({} bytes, flags {})", "  ".repeat(c.depth as usize), c.id, c.offset, c.size, c.flags);
        }
    }
    Ok(())
}
