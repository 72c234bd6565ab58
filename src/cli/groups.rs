//! `strata groups`: build the group hierarchy of a mesh and measure hierarchical back-face
//! culling; optionally the level meshes and a PLY colored by groups.

use super::{load, GroupingArgs, LevelArgs, MeshInput};
use anyhow::{Context, Result};
use std::time::Instant;
use strata::hierarchy::{self, Level};
use strata::{culling, mesh};

#[derive(clap::Args)]
pub struct Args {
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

pub fn run(a: Args) -> Result<()> {
    let imp = load(&a.input)?;
    let m = &imp.mesh;
    let start = Instant::now();
    let adj = mesh::Adjacency::build(m);
    let mut h = hierarchy::build(m, &adj, &a.grouping.params(a.level_params.level_ratio));
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
        colored.colors = partition.face_group.iter().flat_map(|&g| [strata::render::palette(g); 3]).collect();
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
