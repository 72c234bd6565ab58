//! Drawing order and occlusion culling (issue 17) along `strata stream --orbit`'s session.
//!
//! The ideal: the faces of the displayed front that face the camera and lie in the frustum (what
//! back-face and frustum culling leave to draw), those of them that reach a pixel of the final
//! image (from an id buffer of the front), and so the faces drawn for nothing. Then what culling
//! whole nodes, or whole culling clusters of level-0 nodes, could remove of that ideal if it knew
//! exactly which are hidden (the bound of any node- or cluster-level test), and what the strip
//! renderer's occlusion test removes of it, drawing the front in the separating planes' order.
//! Against drawing in node order without the test: faces drawn, fragments shaded per covered
//! pixel (overdraw) and draw time, the images compared pixel for pixel; and the cost of ordering
//! a front, also for the whole level 0 of the mesh converted with smaller leaves (over 5,000 nodes
//! on the CT head).
//!
//! `cargo bench --bench occlusion [-- mesh ...]`; without arguments the noisy-sphere fixture and
//! the bunny and CT head of ../shared/meshes when present.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::Instant;
use strata::camera::Camera;
use strata::format::{NodeGeometry, Reader};
use strata::pipeline::{convert, ConvertOptions, Silent};
use strata::render::{palette, DrawStats, Image, Part, Strips, BACKGROUND};
use strata::stream::order::Orderer;
use strata::stream::{session, Budgets, Streamer};

fn meshes() -> Vec<PathBuf> {
    let args: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if !args.is_empty() {
        return args;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = vec![root.join("fixtures/noisy_sphere.ply")];
    for m in ["scans/stanford_bun_zipper.ply", "large/cthead_skin_native.ply"] {
        let p = root.join("../shared/meshes").join(m);
        if p.exists() {
            out.push(p);
        }
    }
    out
}

/// Whether face `t` of `g` faces the camera, has a corner inside the view frustum and, drawn
/// alone, would cover a pixel center: a face an occlusion test could have spared the renderer
/// (a face too small to reach any pixel is not hidden, only small).
fn candidate(g: &NodeGeometry, t: &[u32], camera: &Camera, planes: &[strata::camera::Plane; 6], vp: &glam::Mat4) -> bool {
    let p = [0, 1, 2].map(|k| g.positions[t[k] as usize]);
    let n = (p[1] - p[0]).cross(p[2] - p[0]);
    if n.dot(camera.eye - p[0]) <= 0.0 {
        return false;
    }
    // A triangle is outside when all its corners lie outside one plane.
    if !planes.iter().all(|pl| p.iter().any(|&q| pl.normal.dot(q) + pl.d >= 0.0)) {
        return false;
    }
    let clip = p.map(|q| *vp * q.extend(1.0));
    if clip.iter().any(|c| c.w <= 0.0) {
        return true;
    }
    let (w, h) = (camera.width as f32, camera.height as f32);
    let s = clip.map(|c| glam::Vec2::new((c.x / c.w + 1.0) * 0.5 * w, (1.0 - c.y / c.w) * 0.5 * h));
    let (lo, hi) = (s[0].min(s[1]).min(s[2]), s[0].max(s[1]).max(s[2]));
    if (hi - lo).max_element() > 64.0 {
        return true;
    }
    let edge = |a: glam::Vec2, b: glam::Vec2, q: glam::Vec2| (b - a).perp_dot(q - a);
    let area = edge(s[0], s[1], s[2]);
    for y in (lo.y - 0.5).ceil() as i32..=(hi.y - 0.5).floor() as i32 {
        for x in (lo.x - 0.5).ceil() as i32..=(hi.x - 0.5).floor() as i32 {
            let q = glam::Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let e = [edge(s[0], s[1], q), edge(s[1], s[2], q), edge(s[2], s[0], q)];
            if e.iter().all(|&v| v * area >= 0.0) {
                return true;
            }
        }
    }
    false
}

#[derive(Default)]
struct Sums {
    frames: usize,
    faces: u64,
    candidates: u64,
    visible: u64,
    node_removable: u64,
    cluster_removable: u64,
    /// Candidates among the faces the occlusion test skipped.
    occlusion_removed: u64,
    unordered: DrawStats,
    ordered: DrawStats,
    culled: DrawStats,
    ordered_ms: f64,
    culled_ms: f64,
    order_us: f64,
    max_front: usize,
    changed_pixels: u64,
    /// The session that does not refine what was hidden the frame before: pixels differing from
    /// the plain session's, frames with any, and bytes read by each session.
    held_changed_pixels: u64,
    held_changed_frames: usize,
    held_bytes: u64,
    plain_bytes: u64,
    held_faces: u64,
}

/// Draw `parts` with `strips`, the image's rows into `rgba`; the stats and the time taken.
fn draw(strips: &mut Strips, camera: &Camera, parts: &[Part], rgba: &mut [u8]) -> (DrawStats, f64) {
    let row = 4 * camera.width as usize;
    let start = Instant::now();
    strips.draw(camera, parts, |y, line| rgba[y as usize * row..y as usize * row + line.len()].copy_from_slice(line));
    (strips.stats(), start.elapsed().as_secs_f64() * 1e3)
}

/// Mean time to order `front` for `camera`, in µs, over enough repetitions to time.
fn order_time(orderer: &mut Orderer, rd: &Reader<std::fs::File>, front: &[u32], camera: &Camera) -> f64 {
    order_times(orderer, rd, front, camera).0
}

/// The mean and the least time of 50 orderings of `front` for `camera`, in µs (the least is the
/// cost without what else the machine did meanwhile).
fn order_times(orderer: &mut Orderer, rd: &Reader<std::fs::File>, front: &[u32], camera: &Camera) -> (f64, f64) {
    let mut out = Vec::new();
    orderer.order(rd.skeleton(), front, camera, &mut out);
    let reps = 50;
    let (mut total, mut least) = (0.0, f64::MAX);
    for _ in 0..reps {
        let start = Instant::now();
        orderer.order(rd.skeleton(), front, camera, &mut out);
        let us = start.elapsed().as_secs_f64() * 1e6;
        total += us;
        least = least.min(us);
    }
    (total / reps as f64, least)
}

fn main() {
    println!(
        "{:<26} {:>10} {:>11} {:>10} {:>9} {:>13} {:>15} {:>14}",
        "mesh", "faces", "front+frus", "visible", "ideal", "nodes of it", "clusters of it", "culled of it"
    );
    let mut rows = Vec::new();
    for mesh in meshes() {
        let name = mesh.file_stem().unwrap().to_string_lossy().into_owned();
        let out = std::env::temp_dir().join(format!("strata-occlusion-{name}-{}.strata", std::process::id()));
        convert(&mesh, &Default::default(), &out, &ConvertOptions::default(), &mut Silent).expect("convert");
        let rd = Reader::open_path(&out).expect("open");
        let (min, max) = (rd.header().min, rd.header().max);
        let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
        let mut streamer = Streamer::new(rd, Budgets::default()).expect("streamer");
        let mut holding = Streamer::new(Reader::open_path(&out).expect("open"), Budgets::default()).expect("streamer");
        let mut held_rgba = vec![0u8; 4 * 640 * 480];
        let mut orderer = Orderer::new(streamer.reader().skeleton(), streamer.reader().read_planes().expect("planes"));
        let (w, h, n) = (640, 480, 32);
        let mut sums = Sums::default();
        let mut image = Image::new(w, h);
        let mut strips = Strips::new(w, h);
        let (mut plain, mut culled) = (vec![0u8; 4 * (w * h) as usize], vec![0u8; 4 * (w * h) as usize]);
        for i in 0..n {
            let camera = session::orbit(center, radius, i, n, w, h);
            let report = streamer.update(&camera, None).expect("frame");
            let planes = camera.frustum();
            let vp = camera.view_projection();
            // Ids: node k of the front owns ids first[k] .. first[k] + faces.
            let geometries: Vec<&NodeGeometry> = report.front.iter().filter_map(|&i| streamer.geometry(i)).collect();
            let mut first = Vec::with_capacity(geometries.len());
            let mut next = 0u32;
            for g in &geometries {
                first.push(next);
                next += g.face_count() as u32;
            }
            image.clear();
            let parts: Vec<Part> =
                geometries.iter().zip(&first).map(|(g, &f)| Part::new(&g.positions, &[], &g.indices, [0; 4]).with_ids(f)).collect();
            image.draw_parts(&camera, &parts);
            // The front drawn three ways: node order, the planes' order, and that with occlusion culling.
            let colored = |nodes: &[u32]| -> Vec<Part> {
                nodes
                    .iter()
                    .filter_map(|&i| {
                        let g = streamer.geometry(i)?;
                        let (lo, hi) = streamer.reader().node_box(i);
                        Some(Part::new(&g.positions, &g.normals, &g.indices, palette(i)).with_bounds(lo, hi))
                    })
                    .collect()
            };
            let (by_node, by_planes) = (colored(&report.front), colored(&report.order));
            strips.set_occlusion(false);
            let (unordered, _) = draw(&mut strips, &camera, &by_node, &mut plain);
            let (ordered, ordered_ms) = draw(&mut strips, &camera, &by_planes, &mut plain);
            strips.set_occlusion(true);
            let (culled_stats, culled_ms) = draw(&mut strips, &camera, &by_planes, &mut culled);
            // Per node with any face the occlusion test skipped: which.
            let hidden: HashMap<u32, Vec<bool>> = report
                .order
                .iter()
                .enumerate()
                .filter_map(|(k, &i)| {
                    let faces = streamer.geometry(i)?.face_count();
                    let skipped: Vec<bool> = (0..faces).map(|f| strips.face_hidden(k, f)).collect();
                    skipped.contains(&true).then_some((i, skipped))
                })
                .collect();
            sums.changed_pixels += plain.chunks_exact(4).zip(culled.chunks_exact(4)).filter(|(a, b)| a != b).count() as u64;
            // The same frame from the session that holds what was hidden the frame before.
            let held_report = holding.update(&camera, None).expect("frame");
            let held_parts: Vec<Part> = held_report
                .order
                .iter()
                .filter_map(|&i| {
                    let g = holding.geometry(i)?;
                    let (lo, hi) = holding.reader().node_box(i);
                    Some(Part::new(&g.positions, &g.normals, &g.indices, palette(i)).with_bounds(lo, hi))
                })
                .collect();
            let (held_stats, _) = draw(&mut strips, &camera, &held_parts, &mut held_rgba);
            let held_hidden: Vec<u32> =
                held_report.order.iter().enumerate().filter(|&(k, _)| strips.part_hidden(k)).map(|(_, &i)| i).collect();
            holding.hold_hidden(&held_hidden);
            let differing = held_rgba.chunks_exact(4).zip(plain.chunks_exact(4)).filter(|(a, b)| a != b).count() as u64;
            sums.held_changed_pixels += differing;
            sums.held_changed_frames += (differing > 0) as usize;
            sums.held_faces += held_stats.faces as u64;
            sums.held_bytes = holding.reader().bytes_read();
            sums.plain_bytes = streamer.reader().bytes_read();
            sums.unordered = sums.unordered + unordered;
            sums.ordered = sums.ordered + ordered;
            sums.culled = sums.culled + culled_stats;
            sums.ordered_ms += ordered_ms;
            sums.culled_ms += culled_ms;
            sums.order_us += order_time(&mut orderer, streamer.reader(), &report.front, &camera);
            sums.max_front = sums.max_front.max(report.front.len());
            let seen: HashSet<u32> = image
                .rgba
                .chunks_exact(4)
                .filter(|px| *px != BACKGROUND)
                .map(|px| u32::from_le_bytes([px[0], px[1], px[2], px[3]]))
                .collect();
            let shown: Vec<u32> = report.front.iter().copied().filter(|&i| streamer.geometry(i).is_some()).collect();
            for ((g, &f), node) in geometries.iter().zip(&first).zip(shown) {
                let mut node_candidates = 0u64;
                let mut node_visible = 0u64;
                let skipped = hidden.get(&node);
                let cluster = |range: std::ops::Range<usize>| {
                    let (mut c, mut v, mut h) = (0u64, 0u64, 0u64);
                    for k in range {
                        let t = &g.indices[3 * k..3 * k + 3];
                        if candidate(g, t, &camera, &planes, &vp) {
                            c += 1;
                            v += seen.contains(&(f + k as u32)) as u64;
                            h += skipped.is_some_and(|s| s[k]) as u64;
                        }
                    }
                    (c, v, h)
                };
                let clusters: Vec<std::ops::Range<usize>> = if g.clusters.is_empty() {
                    std::iter::once(0..g.face_count()).collect()
                } else {
                    g.clusters.iter().map(|c| c.first_face as usize..(c.first_face + c.face_count) as usize).collect()
                };
                for r in clusters {
                    let (c, v, h) = cluster(r);
                    sums.occlusion_removed += h;
                    node_candidates += c;
                    node_visible += v;
                    if v == 0 {
                        sums.cluster_removable += c;
                    }
                }
                if node_visible == 0 {
                    sums.node_removable += node_candidates;
                }
                sums.candidates += node_candidates;
                sums.visible += node_visible;
                sums.faces += g.face_count() as u64;
            }
            sums.frames += 1;
        }
        let per = |x: u64| x as f64 / sums.frames as f64;
        let ideal = sums.candidates - sums.visible;
        println!(
            "{:<26} {:>10.0} {:>11.0} {:>10.0} {:>8.1}% {:>12.1}% {:>14.1}% {:>13.1}%",
            name,
            per(sums.faces),
            per(sums.candidates),
            per(sums.visible),
            100.0 * ideal as f64 / sums.candidates.max(1) as f64,
            100.0 * sums.node_removable as f64 / ideal.max(1) as f64,
            100.0 * sums.cluster_removable as f64 / ideal.max(1) as f64,
            100.0 * sums.occlusion_removed as f64 / ideal.max(1) as f64,
        );
        assert_eq!(sums.changed_pixels, 0, "{name}: occlusion culling changed pixels");
        let _ = std::fs::remove_file(&out);
        rows.push((name.clone(), sums, level0_order(&mesh, &name)));
    }
    println!();
    println!(
        "{:<26} {:>12} {:>12} {:>9} {:>9} {:>9} {:>9} {:>9} {:>10} {:>18}",
        "mesh", "drawn", "drawn culled", "ratio", "px shade", "ordered", "draw ms", "culled ms", "order µs", "level-0 µs"
    );
    for (name, s, level0) in &rows {
        let per = |x: u64| x as f64 / s.frames as f64;
        println!(
            "{:<26} {:>12.0} {:>12.0} {:>9.3} {:>9.3} {:>9.3} {:>9.2} {:>9.2} {:>10.1} {:>18}",
            name,
            per(s.ordered.faces as u64),
            per(s.culled.faces as u64),
            s.culled.faces as f64 / s.ordered.faces.max(1) as f64,
            s.unordered.writes_per_pixel(),
            s.ordered.writes_per_pixel(),
            s.ordered_ms / s.frames as f64,
            s.culled_ms / s.frames as f64,
            s.order_us / s.frames as f64,
            level0.map_or("-".into(), |(nodes, mean, least)| format!("{mean:.0} / {least:.0} ({nodes})")),
        );
    }
    println!();
    println!(
        "{:<26} {:>12} {:>12} {:>12} {:>14} {:>16}",
        "mesh", "bytes read", "held: bytes", "held: drawn", "held: frames≠", "held: pixels≠"
    );
    for (name, s, _) in &rows {
        println!(
            "{:<26} {:>12} {:>12} {:>12.0} {:>11}/{:<2} {:>15.4}%",
            name,
            s.plain_bytes,
            s.held_bytes,
            s.held_faces as f64 / s.frames as f64,
            s.held_changed_frames,
            s.frames,
            100.0 * s.held_changed_pixels as f64 / (s.frames as f64 * 640.0 * 480.0),
        );
    }
    println!("faces: of the front, mean per frame (32-frame orbit at 640x480, 1 px); front+frus: facing the camera, in the frustum,");
    println!("covering a pixel center if drawn alone;");
    println!("visible: of those, reaching a pixel of the image (id buffer of the front); ideal: hidden share of front+frus;");
    println!("nodes / clusters of it: share of the ideal in nodes (clusters at level 0) none of whose faces is visible;");
    println!(
        "culled of it: share of the ideal in the faces the renderer's occlusion test skipped (nodes' boxes, {}-face blocks' rectangles, then faces' where a block's first or last is hidden, per {}-row strip).",
        strata::render::BLOCK_FACES,
        strata::render::STRIP_ROWS
    );
    println!("drawn: faces drawn per frame in the planes' order without and with occlusion culling (ratio: with / without);");
    println!("px shade: fragments shaded per covered pixel in node order, ordered: in the planes' order; draw ms: strip renderer,");
    println!("ordered, without and with culling (identical images, checked); order µs: ordering each frame's front, mean;");
    println!(
        "level-0 µs: ordering the whole level 0 (nodes) of the mesh converted with 96-face leaves, over 32 cameras: the mean of 50 runs per camera, and the least (the cost without the machine's other work), each averaged over the cameras."
    );
    println!("held: a second session whose nodes found hidden are not refined in the next frame (Streamer::hold_hidden): bytes read");
    println!("over the orbit by each, faces it draws per frame, and its frames and pixels that differ from the first session's.");
}

/// The node count of the whole level 0 of `mesh` converted with small leaves, and the mean and the
/// least time to order it, averaged over the orbit's cameras; None for the fixture.
fn level0_order(mesh: &Path, name: &str) -> Option<(usize, f64, f64)> {
    if !mesh.starts_with(Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared")) {
        return None;
    }
    let out = std::env::temp_dir().join(format!("strata-occlusion-{name}-small-{}.strata", std::process::id()));
    let mut opts = ConvertOptions::default();
    opts.hierarchy.leaf_faces = 96;
    convert(mesh, &Default::default(), &out, &opts, &mut Silent).expect("convert");
    let rd = Reader::open_path(&out).expect("open");
    // Let the convert's thread pool go idle first: its workers spin for a while after their last
    // job, sharing the two cores with the ordering being timed (measured: 189 µs against 165).
    std::thread::sleep(std::time::Duration::from_millis(200));
    let mut orderer = Orderer::new(rd.skeleton(), rd.read_planes().expect("planes"));
    let front: Vec<u32> = rd.level_nodes(0).collect();
    let (min, max) = (rd.header().min, rd.header().max);
    let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
    let n = 32;
    let (mut mean, mut least) = (0.0, 0.0);
    for i in 0..n {
        let (m, l) = order_times(&mut orderer, &rd, &front, &session::orbit(center, radius, i, n, 640, 480));
        mean += m / n as f64;
        least += l / n as f64;
    }
    let _ = std::fs::remove_file(&out);
    Some((front.len(), mean, least))
}
