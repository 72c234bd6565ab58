//! Streaming against loading the mesh whole, as the method's source reports it (table 1: time to
//! the first frame, time to full detail, memory), shape retention per refinement order under face
//! budgets, and the frame-time controller's trace when the model suddenly enters the view.
//!
//! `cargo bench --bench stream [-- mesh ...]`; without arguments it runs on the bunny and the CT
//! head from ../shared/meshes when present (and says so when not) and on the noisy-sphere fixture.
//! Each mesh is converted with `strata convert` (default options) into a temporary file first.
//! `STRATA_BENCH_BIN=path` also measures the memory rows with another build of strata.

use glam::Vec3;
use std::path::{Path, PathBuf};
use std::time::Instant;
use strata::camera::Camera;
use strata::format::Reader;
use strata::render::{Image, Part};
use strata::stream::budget::MIN_PIXELS;
use strata::stream::{Budgets, Priority, Streamer};

#[path = "common/retention_views.rs"]
mod retention_views;
use retention_views::{Views, SIZE};

const WIDTH: u32 = 640;
const HEIGHT: u32 = 480;
const FOV: f32 = 0.8;

fn ms(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

/// Run the strata binary `bin` with `args`, output discarded; its peak resident set in MB.
#[cfg(unix)]
fn peak_rss_mb(bin: &Path, args: &[&str]) -> Option<f64> {
    use std::process::{Command, Stdio};
    let child = Command::new(bin).args(args).stdout(Stdio::null()).stderr(Stdio::null()).spawn().ok()?;
    let (mut status, mut usage) = (0, unsafe { std::mem::zeroed::<libc::rusage>() });
    // SAFETY: waits for our own child; `status` and `usage` are valid for writes.
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) };
    (pid > 0 && libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0).then(|| usage.ru_maxrss as f64 / 1024.0)
}

#[cfg(not(unix))]
fn peak_rss_mb(_: &Path, _: &[&str]) -> Option<f64> {
    None
}

fn fmt_mb(v: Option<f64>) -> String {
    v.map_or("n/a".into(), |m| format!("{m:.1} MB"))
}

fn view(center: Vec3, radius: f32, from: Vec3) -> Camera {
    Camera::framing(center, radius, from, FOV, WIDTH, HEIGHT)
}

/// Draw a streamer's front into `image`.
fn draw_front<S: strata::format::ByteSource>(s: &Streamer<S>, front: &[u32], camera: &Camera, image: &mut Image) {
    image.clear();
    let parts: Vec<Part> = front
        .iter()
        .filter_map(|&i| {
            let g = s.geometry(i)?;
            Some(Part::new(&g.positions, &g.normals, &g.indices, [200, 200, 200, 255]))
        })
        .collect();
    image.draw_parts(camera, &parts);
}

/// Table 1, time: the whole mesh imported and drawn vs the chunk file opened and streamed.
fn whole_vs_streamed(mesh: &Path, file: &Path) -> strata::error::Result<()> {
    let rd = Reader::open_path(file)?;
    let (center, radius) = ((rd.header().min + rd.header().max) * 0.5, (rd.header().max - rd.header().min).length() * 0.5);
    drop(rd);
    let camera = view(center, radius, Vec3::new(0.3, 0.2, 1.0));

    let start = Instant::now();
    // As strata stream opens: the top level first, the rest of the node table for the second frame.
    let mut s = Streamer::new(Reader::open_top_path(file)?, Budgets { bytes: Some(4_000_000), ..Budgets::default() })?;
    let mut image = Image::new(WIDTH, HEIGHT);
    let rep = s.update(&camera, None)?;
    draw_front(&s, &rep.front, &camera, &mut image);
    let first = ms(start);
    let (faces, read) = (rep.stats.faces, s.reader().bytes_read());

    let start = Instant::now();
    let m = strata::import(mesh, None)?.mesh;
    let indices: Vec<u32> = m.triangles.iter().flatten().copied().collect();
    let (positions, normals, indices): (Vec<Vec3>, Vec<Vec3>, Vec<u32>) = if m.normals.is_empty() {
        (m.positions.clone(), Vec::new(), indices)
    } else {
        (indices.iter().map(|&v| m.positions[v as usize]).collect(), m.normals.clone(), (0..indices.len() as u32).collect())
    };
    image.clear();
    image.draw(&camera, &positions, &normals, &indices, [200, 200, 200, 255]);
    let whole_ms = ms(start);

    println!("  first frame: whole (import + draw) {whole_ms:.1} ms; streamed (open + draw of the top level) {first:.1} ms, {faces} faces, {read} bytes read; ratio {:.3}", first / whole_ms);

    let start = Instant::now();
    let mut s = Streamer::new(Reader::open_path(file)?, Budgets { pixel_error: 0.0, ..Budgets::default() })?;
    let rep = s.update(&camera, None)?;
    draw_front(&s, &rep.front, &camera, &mut image);
    let full = ms(start);
    let levels = rep.stats.levels.iter().skip(1).sum::<u32>();
    println!(
        "  full detail (pixel error 0, no budget): streamed {full:.1} ms, {} faces ({levels} nodes above level 0), {} bytes read; ratio {:.3}",
        rep.stats.faces,
        s.reader().bytes_read(),
        full / whole_ms
    );
    Ok(())
}

/// Peak resident sets of `strata info` (importing the mesh whole) and of `strata stream` (a
/// 32-frame orbit under a 4 MB geometry budget), each its own process, with this build of strata
/// and, when `STRATA_BENCH_BIN` names one, with that build too (the README's lean build, say:
/// shared libraries count in a process's RSS). Run while this process is still small: a child's
/// peak counts the parent's pages at the time it was spawned.
fn memory(mesh: &Path, file: &Path) -> String {
    let (mesh_arg, file_arg) = (mesh.to_string_lossy(), file.to_string_lossy());
    let mut bins = vec![("this build".to_string(), PathBuf::from(env!("CARGO_BIN_EXE_strata")))];
    if let Some(other) = std::env::var_os("STRATA_BENCH_BIN") {
        bins.push((format!("STRATA_BENCH_BIN={}", other.to_string_lossy()), PathBuf::from(other)));
    }
    let mut out = Vec::new();
    for (name, bin) in bins {
        let whole = peak_rss_mb(&bin, &["info", &mesh_arg]);
        let streamed = peak_rss_mb(&bin, &["stream", &file_arg, "--orbit", "32", "--budget-bytes", "4000000", "--json"]);
        let ratio = match (streamed, whole) {
            (Some(s), Some(w)) => format!("; ratio {:.3}", s / w),
            _ => String::new(),
        };
        out.push(format!(
            "  peak RSS ({name}): strata info {}; strata stream, 4 MB budget, 32-frame orbit {}{ratio}",
            fmt_mb(whole),
            fmt_mb(streamed)
        ));
    }
    out.join("\n")
}

/// Shape retention over 8 views around the model, per face budget and refinement order.
fn retention_table(file: &Path) -> strata::error::Result<()> {
    let views = Views::of(file)?;
    let input_faces = Reader::open_path(file)?.header().input_faces;
    let orders = [("error", Priority::Error), ("silhouette", Priority::Silhouette), ("breadth", Priority::Breadth)];
    println!("  shape retention at {SIZE}x{SIZE}, 8 views, pixel error 0; shaded (coverage), mean over views");
    print!("  {:>8} {:>8}", "budget", "faces");
    for (name, _) in &orders {
        print!(" {name:>18}");
    }
    println!();
    for share in [0.10, 0.25, 0.50] {
        let budget = (input_faces as f64 * share) as u64;
        print!("  {:>7.0}% {budget:>8}", share * 100.0);
        for (_, priority) in orders {
            match views.retention(file, budget, priority)? {
                Some((shaded, coverage)) => print!(" {:>18}", format!("{shaded:.3} ({coverage:.4})")),
                None => print!(" {:>18}", "top too large"),
            }
        }
        println!();
    }
    Ok(())
}

/// The frame-time controller on a path that looks away for 12 frames and then turns to the model.
fn controller_trace(file: &Path, target_ms: f32) -> strata::error::Result<()> {
    let rd = Reader::open_path(file)?;
    let (center, radius) = ((rd.header().min + rd.header().max) * 0.5, (rd.header().max - rd.header().min).length() * 0.5);
    drop(rd);
    // The smallest of these sizes at which the finest front the controller may ask for (its
    // smallest threshold) takes well over the target, so that it has to hold detail back: on a
    // fast machine that front may fit in the target, and the controller rightly stops there.
    let finest_ms = |width: u32, height: u32| -> strata::error::Result<f64> {
        let cam = Camera::framing(center, radius, Vec3::new(0.0, 0.3, 1.0), FOV, width, height);
        let mut s = Streamer::new(Reader::open_path(file)?, Budgets { pixel_error: MIN_PIXELS, ..Budgets::default() })?;
        s.update(&cam, None)?;
        // A second update from the same view: refinement without reading, as in the trace.
        let rep = s.update(&cam, None)?;
        let mut image = Image::new(width, height);
        draw_front(&s, &rep.front, &cam, &mut image);
        let start = Instant::now();
        draw_front(&s, &rep.front, &cam, &mut image);
        Ok(rep.stats.refine_ms + ms(start))
    };
    let mut size = (1280, 960, 0.0);
    for (w, h) in [(1280, 960), (1920, 1440), (2560, 1920), (3840, 2880)] {
        size = (w, h, finest_ms(w, h)?);
        if size.2 >= 1.5 * target_ms as f64 {
            break;
        }
    }
    let (width, height, finest) = size;
    let on = Camera::framing(center, radius, Vec3::new(0.0, 0.3, 1.0), FOV, width, height);
    let mut away = on;
    away.target = on.eye + (on.eye - on.target);
    let path: Vec<&Camera> = (0..30).map(|k| if k < 12 { &away } else { &on }).collect();
    println!("  frame-time controller at {width}x{height} (finest front, {MIN_PIXELS} px: {finest:.1} ms), target {target_ms} ms, 12 frames looking away, then the model: frame ms (faces)");
    for predict in [true, false] {
        let budgets = Budgets { target_ms: Some(target_ms), predict, ..Budgets::default() };
        let mut s = Streamer::new(Reader::open_path(file)?, budgets)?;
        let mut image = Image::new(width, height);
        let mut last = None;
        let mut trace = Vec::new();
        for cam in &path {
            let rep = s.update(cam, last)?;
            let start = Instant::now();
            draw_front(&s, &rep.front, cam, &mut image);
            let frame = rep.stats.refine_ms + ms(start);
            last = Some(frame as f32);
            trace.push(format!("{frame:.1} ({})", rep.stats.faces));
        }
        println!("  {:>10}: {}", if predict { "predictive" } else { "reactive" }, trace[11..].join(" "));
    }
    Ok(())
}

fn shared(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes").join(rel)
}

fn main() {
    let args: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).map(PathBuf::from).collect();
    let meshes: Vec<PathBuf> = if args.is_empty() {
        let mut v = Vec::new();
        for rel in ["scans/ajc_stanford-bunny.obj", "large/cthead_skin_native.ply"] {
            let p = shared(rel);
            if p.exists() {
                v.push(p);
            } else {
                println!("skipping {rel}: ../shared/meshes not found");
            }
        }
        v.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/noisy_sphere.ply"));
        v
    } else {
        args
    };
    let largest = meshes.iter().max_by_key(|p| std::fs::metadata(p).map_or(0, |m| m.len())).cloned();
    let dir = std::env::temp_dir().join(format!("strata-bench-stream-{}", std::process::id()));
    if let Err(e) = std::fs::create_dir_all(&dir) {
        println!("{}: {e}", dir.display());
        return;
    }
    let mut converted = Vec::new();
    for (k, mesh) in meshes.iter().enumerate() {
        let file = dir.join(format!("{k}.strata"));
        let start = Instant::now();
        let ok = std::process::Command::new(env!("CARGO_BIN_EXE_strata"))
            .args(["convert", "--quiet", &mesh.to_string_lossy(), &file.to_string_lossy()])
            .stdout(std::process::Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if ok {
            let line = format!("{}: converted by `strata convert` in {:.0} ms", mesh.display(), ms(start));
            converted.push((mesh, file.clone(), line, memory(mesh, &file)));
        } else {
            println!("{}: strata convert failed", mesh.display());
        }
    }
    for (mesh, file, line, memory) in &converted {
        println!("{line}\n{memory}");
        let run = || -> strata::error::Result<()> {
            whole_vs_streamed(mesh, file)?;
            retention_table(file)?;
            if largest.as_ref() == Some(*mesh) {
                controller_trace(file, 20.0)?;
            }
            Ok(())
        };
        if let Err(e) = run() {
            println!("  {e}");
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}
