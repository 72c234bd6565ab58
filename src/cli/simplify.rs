//! `strata simplify`: the plain QEM simplifier (no groups) on a mesh file, written as a mesh.

use super::{load, MeshInput};
use anyhow::Result;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("target").required(true).args(["ratio", "faces", "error"])))]
pub struct Args {
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

pub fn run(a: Args) -> Result<()> {
    let imp = load(&a.input)?;
    strata::atomic::check_output(&a.output)?;
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
        println!(
            "stopped above the target of {} faces: no legal collapse is left (corners, handles, small components){hint}",
            opts.target_faces
        );
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
