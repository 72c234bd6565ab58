//! How much occlusion culling could remove (issue 17, groundwork): along `strata stream --orbit`'s
//! session, the faces of the displayed front that face the camera and lie in the frustum
//! (what back-face and frustum culling leave to draw), those of them that reach a pixel of the
//! final image (from an id buffer of the front), and so the ideal: faces drawn for nothing. Then
//! what culling whole nodes, or whole culling clusters of level-0 nodes, could remove of that
//! ideal if it knew exactly which are hidden: the bound of any node- or cluster-level occlusion
//! test, against which a real one (a hierarchical depth test) is to be measured.
//!
//! `cargo bench --bench occlusion [-- mesh ...]`; without arguments the noisy-sphere fixture and
//! the bunny and CT head of ../shared/meshes when present.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use strata::camera::Camera;
use strata::format::{NodeGeometry, Reader};
use strata::pipeline::{convert, ConvertOptions, Silent};
use strata::render::{Image, Part, BACKGROUND};
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
}

fn main() {
    println!(
        "{:<26} {:>10} {:>11} {:>10} {:>9} {:>13} {:>15}",
        "mesh", "faces", "front+frus", "visible", "ideal", "nodes of it", "clusters of it"
    );
    for mesh in meshes() {
        let name = mesh.file_stem().unwrap().to_string_lossy().into_owned();
        let out = std::env::temp_dir().join(format!("strata-occlusion-{name}-{}.strata", std::process::id()));
        convert(&mesh, &Default::default(), &out, &ConvertOptions::default(), &mut Silent).expect("convert");
        let rd = Reader::open_path(&out).expect("open");
        let (min, max) = (rd.header().min, rd.header().max);
        let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
        let mut streamer = Streamer::new(rd, Budgets::default()).expect("streamer");
        let (w, h, n) = (640, 480, 32);
        let mut sums = Sums::default();
        let mut image = Image::new(w, h);
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
            let seen: HashSet<u32> = image
                .rgba
                .chunks_exact(4)
                .filter(|px| *px != BACKGROUND)
                .map(|px| u32::from_le_bytes([px[0], px[1], px[2], px[3]]))
                .collect();
            for (g, &f) in geometries.iter().zip(&first) {
                let mut node_candidates = 0u64;
                let mut node_visible = 0u64;
                let cluster = |range: std::ops::Range<usize>| {
                    let (mut c, mut v) = (0u64, 0u64);
                    for k in range {
                        let t = &g.indices[3 * k..3 * k + 3];
                        if candidate(g, t, &camera, &planes, &vp) {
                            c += 1;
                            v += seen.contains(&(f + k as u32)) as u64;
                        }
                    }
                    (c, v)
                };
                let clusters: Vec<std::ops::Range<usize>> = if g.clusters.is_empty() {
                    std::iter::once(0..g.face_count()).collect()
                } else {
                    g.clusters.iter().map(|c| c.first_face as usize..(c.first_face + c.face_count) as usize).collect()
                };
                for r in clusters {
                    let (c, v) = cluster(r);
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
            "{:<26} {:>10.0} {:>11.0} {:>10.0} {:>8.1}% {:>12.1}% {:>14.1}%",
            name,
            per(sums.faces),
            per(sums.candidates),
            per(sums.visible),
            100.0 * ideal as f64 / sums.candidates.max(1) as f64,
            100.0 * sums.node_removable as f64 / ideal.max(1) as f64,
            100.0 * sums.cluster_removable as f64 / ideal.max(1) as f64,
        );
        let _ = std::fs::remove_file(&out);
    }
    println!("faces: of the front, mean per frame (32-frame orbit at 640x480, 1 px); front+frus: facing the camera, in the frustum,");
    println!("covering a pixel center if drawn alone;");
    println!("visible: of those, reaching a pixel of the image (id buffer of the front); ideal: hidden share of front+frus;");
    println!("nodes / clusters of it: share of the ideal in nodes (clusters at level 0) none of whose faces is visible.");
}
