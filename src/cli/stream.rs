//! `strata stream`: play a viewing session over a chunk file and report each frame (text or JSON
//! lines), optionally saving frames, the shape retention and the last front.

use super::open_chunk_file;
use anyhow::{Context, Result};
use std::path::PathBuf;
use std::time::Instant;
use strata::format;
use strata::stream::Priority;

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("session").args(["orbit", "path", "flyover"])))]
pub struct Args {
    /// A .strata file.
    file: PathBuf,
    /// N frames around the model, moving in from far (model ~5% of the view) to a close-up over the
    /// first half; terrain is seen from 45° above the horizon. The default session (64 frames).
    #[arg(long, value_name = "N")]
    orbit: Option<usize>,
    /// N frames flying low over terrain from its south edge to its north edge, looking ahead.
    #[arg(long, value_name = "N")]
    flyover: Option<usize>,
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
    #[arg(long, value_enum, default_value_t = Priority::Error)]
    priority: Priority,
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
    /// With --json, also each frame's camera, the displayed nodes ("front") and the roots of culled
    /// subtrees ("culled_roots"): golden fronts for another implementation of format-spec/selection.md.
    #[arg(long, requires = "json")]
    print_front: bool,
    /// Write each frame as a PNG into this directory (nodes colored by id).
    #[arg(long, value_name = "DIR")]
    frames_dir: Option<PathBuf>,
    /// Write the last front as a mesh (.obj, .ply or .glb).
    #[arg(long, value_name = "OUT")]
    export_cut: Option<PathBuf>,
    /// Draw the front in node order instead of front to back by the file's separating planes.
    #[arg(long)]
    unordered: bool,
    /// Draw every node of the front, also those whose box lies behind what is already drawn (the
    /// pixels are the same; for measuring what occlusion culling saves).
    #[arg(long)]
    no_occlusion: bool,
    /// Also keep the nodes occlusion culling skipped from being refined in the next frame: fewer
    /// reads, but a node coming into view is drawn at its held level for a frame.
    #[arg(long, conflicts_with = "no_occlusion")]
    hold_hidden: bool,
    /// Per frame, also draw the front and the full-detail model (level 0, read once, kept apart
    /// from the session's reader and budgets) in one plain color and report the shape retention.
    #[arg(long)]
    compare_full: bool,
}

pub fn run(a: Args) -> Result<()> {
    use strata::stream::{play, session, Budgets, Streamer};
    let opened = Instant::now();
    strata::atomic::protect(&a.file);
    // The first frame shows the top level: the rest of the node table is decoded for the second.
    let reader = format::Reader::open_top_path(&a.file)?;
    if let Some(out) = &a.export_cut {
        strata::atomic::check_output(out)?;
    }
    let h = reader.header();
    let (center, radius) = (0.5 * (h.min + h.max), 0.5 * (h.max - h.min).length());
    let (width, height) = (a.width.max(1), a.height.max(1));
    let cameras = match (&a.path, a.flyover) {
        (Some(p), _) => {
            strata::atomic::protect(p);
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            session::parse_path(&text, p, center, radius, width, height)?
        }
        (None, Some(n)) => {
            let n = n.max(2);
            (0..n).map(|i| session::flyover(h.min, h.max, i, n, width, height)).collect()
        }
        (None, None) => {
            let n = a.orbit.unwrap_or(64).max(1);
            let orbit = if reader.georef().is_some() { session::terrain_orbit } else { session::orbit };
            (0..n).map(|i| orbit(center, radius, i, n, width, height)).collect()
        }
    };
    if let Some(d) = &a.frames_dir {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    let budgets = Budgets {
        faces: a.budget_faces,
        bytes: a.budget_bytes,
        pixel_error: a.pixel_error,
        target_ms: a.target_ms,
        priority: a.priority,
        predict: !a.no_predict,
    };
    let full: Vec<format::NodeGeometry> = if a.compare_full {
        let rd = open_chunk_file(&a.file)?;
        rd.level_nodes(0).map(|i| rd.read_node(i)).collect::<strata::error::Result<_>>()?
    } else {
        Vec::new()
    };
    let textured = !reader.textures().is_empty();
    let mut streamer = Streamer::new(reader, budgets)?;
    let opts = play::PlayOptions {
        width,
        height,
        pixels: a.frames_dir.is_some(),
        compare_full: a.compare_full,
        ordered: !a.unordered,
        occlusion: !a.no_occlusion,
        hold_hidden: a.hold_hidden,
    };
    play::play(&mut streamer, &cameras, opts, &full, opened, |f| {
        let (rep, s, d) = (&f.report, &f.report.stats, &f.draw);
        if let (Some(d), Some(rgba)) = (&a.frames_dir, f.rgba) {
            strata::render::write_rgba_png(&d.join(format!("frame{:05}.png", rep.frame)), width, height, rgba)?;
        }
        if a.json {
            let mut v = serde_json::json!({
                "frame": rep.frame, "faces": s.faces, "nodes": s.nodes, "culled": s.culled, "levels": s.levels,
                "added": rep.added.len(), "removed": rep.removed.len(), "bytes_read": s.bytes_read,
                "resident_bytes": s.resident_bytes, "pixel_error": s.pixel_error,
                "refine_ms": s.refine_ms, "order_ms": s.order_ms, "seams_ms": s.seams_ms, "seam_faces": s.seam_faces, "seam_area": s.seam_area, "draw_ms": f.draw_ms, "since_open_ms": f.since_open_ms,
                "faces_drawn": d.faces, "fragments": d.fragments, "shaded": d.writes, "covered_pixels": d.covered,
                "depth_failures_per_pixel": d.failures_per_pixel(), "shaded_per_pixel": d.writes_per_pixel(),
                "nodes_hidden": f.nodes_hidden, "faces_hidden": d.faces_hidden,
            });
            if let Some(r) = f.retained {
                v["retained"] = serde_json::json!(r.shaded);
                v["coverage_retained"] = serde_json::json!(r.coverage);
            }
            if textured {
                v["texture_bytes_read"] = serde_json::json!(s.texture_bytes_read);
                v["texture_resident_bytes"] = serde_json::json!(s.texture_resident_bytes);
                v["texture_levels"] = serde_json::json!(s.texture_levels);
            }
            if a.print_front {
                v["camera"] = cameras[rep.frame as usize].to_json();
                v["front"] = serde_json::json!(rep.front);
                v["order"] = serde_json::json!(rep.order);
                v["culled_roots"] = serde_json::json!(rep.culled);
            }
            println!("{v}");
        } else {
            let levels: Vec<String> = s.levels.iter().map(|c| c.to_string()).collect();
            println!(
                "frame {:>4}  nodes {:>5}  faces {:>8}  levels [{}]  +{} -{}  read {} B  resident {} B  px {:.2}  refine {:.2} ms  draw {:.2} ms",
                rep.frame, s.nodes, s.faces, levels.join(" "), rep.added.len(), rep.removed.len(), s.bytes_read,
                s.resident_bytes, s.pixel_error, s.refine_ms, f.draw_ms
            );
            if textured {
                let levels: Vec<String> = s.texture_levels.iter().map(|[i, w, d]| format!("{i}:{d}/{w}")).collect();
                println!(
                    "           images read {} B  resident {} B  levels drawn/wanted [{}]",
                    s.texture_bytes_read,
                    s.texture_resident_bytes,
                    levels.join(" ")
                );
            }
            println!(
                "           drawn {} faces, {:.2} shaded and {:.2} rejected fragments per pixel, {} nodes ({} faces) hidden, order {:.3} ms, seams {:.3} ms",
                d.faces,
                d.writes_per_pixel(),
                d.failures_per_pixel(),
                f.nodes_hidden,
                d.faces_hidden,
                s.order_ms,
                s.seams_ms
            );
            if rep.frame == 0 {
                println!("           first frame ready {:.1} ms after opening the file", f.since_open_ms);
            }
            if let Some(r) = f.retained {
                println!("           retained {:.4} (coverage {:.4})", r.shaded, r.coverage);
            }
        }
        Ok(())
    })?;
    for w in streamer.take_warnings() {
        eprintln!("warning: {w}");
    }
    if let Some(out) = &a.export_cut {
        let mesh = streamer.front_mesh()?;
        strata::export::write(out, &mesh)?;
        if !a.json {
            println!("wrote the last front ({} faces) to {}", mesh.face_count(), out.display());
        }
    }
    Ok(())
}
