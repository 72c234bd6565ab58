//! Drawing order and occlusion culling (selection.md §5) against brute force: the planes' order
//! of a front agrees with the nodes' depths on screen wherever a plane separates them, and
//! occlusion culling changes no pixel of a streamed orbit.

use glam::Vec3;
use std::path::{Path, PathBuf};
use strata::camera::{Camera, Projection};
use strata::format::planes::{grid_eye, Decision, Eye};
use strata::format::Reader;
use strata::pipeline::{convert, ConvertOptions, Silent};
use strata::render::Image;
use strata::stream::order::Orderer;
use strata::stream::play::{play, PlayOptions};
use strata::stream::{session, Budgets, Streamer};

fn meshes() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out: Vec<PathBuf> =
        ["noisy_sphere.ply", "cad_part.obj", "textured_globe.glb"].iter().map(|m| root.join("fixtures").join(m)).collect();
    let scan = root.join("../shared/meshes/scans/stanford_bun_zipper.ply");
    if scan.exists() {
        out.push(scan);
    } else {
        eprintln!("note: {} is absent; the order is checked on the fixtures only", scan.display());
    }
    out
}

/// `mesh` converted with `leaf_faces` into a temporary file named after `test` too.
fn converted(test: &str, mesh: &Path, leaf_faces: u32) -> (PathBuf, Reader<std::fs::File>) {
    let name = mesh.file_stem().unwrap().to_string_lossy().into_owned();
    let out = std::env::temp_dir().join(format!("strata-order-{test}-{name}-{leaf_faces}-{}.strata", std::process::id()));
    let mut opts = ConvertOptions::default();
    opts.hierarchy.leaf_faces = leaf_faces;
    convert(mesh, &Default::default(), &out, &opts, &mut Silent).expect("convert");
    let rd = Reader::open_path(&out).expect("open");
    (out, rd)
}

/// A camera looking at the model from a pseudo-random direction and distance.
fn camera(center: Vec3, radius: f32, k: u32) -> Camera {
    let h = |x: u32| ((x.wrapping_mul(2654435761) >> 8) as f32) / (1u32 << 24) as f32;
    let (a, b, d) = (h(3 * k + 1) * std::f32::consts::TAU, h(3 * k + 2) * 2.0 - 1.0, 1.6 + 2.5 * h(3 * k + 3));
    let dir = Vec3::new(a.cos() * (1.0 - b * b).sqrt(), b, a.sin() * (1.0 - b * b).sqrt());
    Camera {
        eye: center + dir * radius * d,
        target: center,
        up: if b.abs() > 0.95 { Vec3::X } else { Vec3::Y },
        projection: Projection::Perspective { fov_y: 45f32.to_radians() },
        width: 96,
        height: 96,
        near: radius * 0.01,
        far: radius * 10.0,
    }
}

/// `node` and its ancestors, from `node` up to its top-level ancestor.
fn ancestors(rd: &Reader<std::fs::File>, node: u32) -> Vec<u32> {
    let mut chain = vec![node];
    while let Some(&p) = chain.last().and_then(|&n| rd.nodes().get(n as usize)).map(|n| &n.parent) {
        if p as usize >= rd.nodes().len() {
            break;
        }
        chain.push(p);
    }
    chain
}

#[test]
fn the_planes_order_agrees_with_depth_where_a_plane_separates() {
    let mut checked = 0u64;
    for mesh in meshes() {
        let (out, rd) = converted("depth", &mesh, 96);
        let sk = rd.skeleton();
        let planes = rd.read_planes().expect("planes");
        assert!(!planes.is_empty(), "{}: no planes", mesh.display());
        let mut orderer = Orderer::new(sk, planes.clone());
        let (min, max) = (rd.header().min, rd.header().max);
        let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
        for level in 0..rd.levels().len().min(3) as u32 {
            let front: Vec<u32> = rd.level_nodes(level).collect();
            let geometry: Vec<_> = front.iter().map(|&i| rd.read_node(i).expect("node")).collect();
            for k in 0..8 {
                let cam = camera(center, radius, k + 100 * level);
                let depth: Vec<Vec<f32>> = geometry
                    .iter()
                    .map(|g| {
                        let mut im = Image::new(cam.width, cam.height);
                        im.draw(&cam, &g.positions, &[], &g.indices, [255; 4]);
                        im.depth
                    })
                    .collect();
                // Each node's covered pixels' bounds, to skip pairs that cannot overlap.
                let w = cam.width as usize;
                let rects: Vec<(usize, usize, usize, usize)> = depth
                    .iter()
                    .map(|d| {
                        let mut r = (usize::MAX, 0, usize::MAX, 0);
                        for (i, _) in d.iter().enumerate().filter(|(_, z)| z.is_finite()) {
                            let (px, py) = (i % w, i / w);
                            r = (r.0.min(px), r.1.max(px), r.2.min(py), r.3.max(py));
                        }
                        r
                    })
                    .collect();
                let mut order = Vec::new();
                orderer.order(sk, &front, &cam, &mut order);
                let at: std::collections::HashMap<u32, usize> = order.iter().enumerate().map(|(k, &n)| (n, k)).collect();
                let grid = Eye::At(grid_eye(&sk.header.grid, cam.eye));
                for x in 0..front.len() {
                    for y in x + 1..front.len() {
                        // Where both cover a pixel, which is nearer.
                        let (rx, ry) = (rects[x], rects[y]);
                        let (x0, x1, y0, y1) = (rx.0.max(ry.0), rx.1.min(ry.1), rx.2.max(ry.2), rx.3.min(ry.3));
                        if x0 > x1 || y0 > y1 {
                            continue;
                        }
                        let (mut x_nearer, mut y_nearer) = (false, false);
                        for row in y0..=y1 {
                            let span = row * w + x0..=row * w + x1;
                            for (&a, &b) in depth[x][span.clone()].iter().zip(&depth[y][span]) {
                                if a.is_finite() && b.is_finite() {
                                    x_nearer |= a < b - 1e-6;
                                    y_nearer |= b < a - 1e-6;
                                }
                            }
                        }
                        if !x_nearer && !y_nearer {
                            continue;
                        }
                        // The siblings holding them, under their lowest common parent.
                        let (cx, cy) = (ancestors(&rd, front[x]), ancestors(&rd, front[y]));
                        let common = cx.iter().find(|a| cy.contains(a)).copied();
                        let below = |chain: &[u32]| match common {
                            Some(c) => chain[chain.iter().position(|&a| a == c).unwrap() - 1],
                            None => *chain.last().unwrap(),
                        };
                        let (sx, sy) = (below(&cx), below(&cy));
                        let first = common.map_or(0, |c| rd.nodes()[c as usize].first_child);
                        let (lx, ly) = (sx - first, sy - first);
                        let Some(e) = planes.of(common).iter().find(|e| (e.first, e.second) == (lx, ly) || (e.first, e.second) == (ly, lx))
                        else {
                            continue;
                        };
                        if e.first_max >= e.second_min {
                            continue; // the slab is not empty: no plane separates them
                        }
                        let x_first = match e.decide(grid) {
                            Decision::FirstBeforeSecond => e.first == lx,
                            Decision::SecondBeforeFirst => e.first == ly,
                            Decision::Undecided => continue,
                        };
                        let (earlier, later_nearer) = if x_first { (x, y_nearer) } else { (y, x_nearer) };
                        assert!(
                            !later_nearer,
                            "{}: level {level} camera {k}: node {} is nearer than {} somewhere though the plane puts it behind",
                            mesh.display(),
                            front[x + y - earlier],
                            front[earlier]
                        );
                        let (px, py) = (at[&front[x]], at[&front[y]]);
                        assert_eq!(
                            px < py,
                            x_first,
                            "{}: level {level} camera {k}: nodes {} and {} out of the plane's order",
                            mesh.display(),
                            front[x],
                            front[y]
                        );
                        checked += 1;
                    }
                }
            }
        }
        let _ = std::fs::remove_file(out);
    }
    eprintln!("{checked} overlapping pairs of nodes a plane separates, checked");
    assert!(checked > 50, "{checked} overlapping, separated pairs checked");
}

#[test]
fn occlusion_culling_changes_no_pixel_along_an_orbit() {
    let mut meshes = meshes();
    let ct = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes/large/cthead_skin_native.ply");
    if ct.exists() {
        meshes.push(ct);
    } else {
        eprintln!("note: {} is absent; occlusion culling is checked on the fixtures only", ct.display());
    }
    let mut hidden = 0;
    for mesh in meshes {
        let (out, _) = converted("pixels", &mesh, 256);
        let frames = |occlusion: bool| {
            let rd = Reader::open_path(&out).expect("open");
            let (min, max) = (rd.header().min, rd.header().max);
            let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
            let cameras: Vec<Camera> = (0..12).map(|i| session::orbit(center, radius, i, 12, 160, 120)).collect();
            let mut streamer = Streamer::new(rd, Budgets::default()).expect("streamer");
            let opts =
                PlayOptions { width: 160, height: 120, pixels: true, compare_full: false, ordered: true, occlusion, hold_hidden: false };
            let mut images = Vec::new();
            let mut skipped = 0;
            play(&mut streamer, &cameras, opts, &[], std::time::Instant::now(), |f| {
                images.push(f.rgba.unwrap().to_vec());
                skipped += f.nodes_hidden;
                Ok(())
            })
            .expect("play");
            (images, skipped)
        };
        let ((plain, none), (culled, skipped)) = (frames(false), frames(true));
        assert_eq!(none, 0);
        for (k, (a, b)) in plain.iter().zip(&culled).enumerate() {
            let changed = a.chunks_exact(4).zip(b.chunks_exact(4)).filter(|(p, q)| p != q).count();
            assert_eq!(changed, 0, "{}: frame {k}: occlusion culling changed {changed} pixels", mesh.display());
        }
        hidden += skipped;
        let _ = std::fs::remove_file(out);
    }
    eprintln!("{hidden} nodes skipped by occlusion culling, no pixel changed");
    assert!(hidden > 0, "occlusion culling skipped no node on any mesh");
}

#[test]
fn damaged_planes_cost_only_the_order_and_are_said() {
    let (out, rd) = converted("damaged", &Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/noisy_sphere.ply"), 256);
    let at = rd.planes_offset();
    drop(rd);
    let mut bytes = std::fs::read(&out).unwrap();
    assert!(bytes.len() as u64 > at + 40, "the file ends with its planes");
    let k = bytes.len() - 30;
    bytes[k] ^= 0x5a;
    let rd = Reader::open(std::io::Cursor::new(bytes)).expect("the skeleton is intact");
    let err = rd.read_planes().expect_err("a damaged ORDR is refused").to_string();
    assert!(err.contains("ORDR") && err.contains("CRC"), "{err}");
    let mut streamer = Streamer::new(rd, Budgets::default()).expect("a session without the planes");
    assert!(streamer.take_warnings().is_empty(), "the planes are read once a front leaves the top level");
    let (min, max) = (streamer.reader().header().min, streamer.reader().header().max);
    let top = streamer.reader().levels().len() as u32 - 1;
    let mut refined = false;
    for i in 0..8 {
        let report = streamer.update(&session::orbit((min + max) * 0.5, (max - min).length() * 0.5, i, 8, 256, 256), None).unwrap();
        let mut sorted = report.order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, report.front);
        refined |= report.front.iter().any(|&n| streamer.reader().nodes()[n as usize].level != top);
    }
    assert!(refined, "the session refines");
    let warnings = streamer.take_warnings();
    assert!(warnings.iter().any(|w| w.contains("ORDR") && w.contains("nearest box")), "{warnings:?}");
    let _ = std::fs::remove_file(out);
}

/// §5 of selection.md read literally, one parent at a time: its live children, the edges its
/// entries decide, then repeatedly the least key among the children whose predecessors are taken
/// (among all left on a cycle).
fn order_by_the_rule(
    sk: &strata::format::skeleton::Skeleton,
    planes: &strata::format::planes::Planes,
    front: &[u32],
    cam: &Camera,
) -> Vec<u32> {
    let n = sk.nodes.len();
    let (mut shown, mut live) = (vec![false; n], vec![false; n]);
    for &f in front {
        shown[f as usize] = true;
        let mut p = f;
        while (p as usize) < n && !live[p as usize] {
            live[p as usize] = true;
            p = sk.nodes[p as usize].parent;
        }
    }
    let (eye, key_eye) = match cam.projection {
        Projection::Perspective { .. } => (Eye::At(grid_eye(&sk.header.grid, cam.eye)), Eye::At(cam.eye.as_dvec3())),
        Projection::Orthographic { .. } => (Eye::Along(cam.forward().as_dvec3()), Eye::Along(cam.forward().as_dvec3())),
    };
    let key = |i: u32| -> f64 {
        let (lo, hi) = sk.node_box(i);
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        match key_eye {
            Eye::At(e) => {
                let d = (lo - e).max(glam::DVec3::ZERO).max(e - hi);
                0.0 + d.dot(d)
            }
            Eye::Along(d) => {
                let corners = (0..8).map(|c| {
                    let x = glam::DVec3::new(
                        if c & 1 == 0 { lo.x } else { hi.x },
                        if c & 2 == 0 { lo.y } else { hi.y },
                        if c & 4 == 0 { lo.z } else { hi.z },
                    );
                    (d.x * x.x + d.y * x.y) + d.z * x.z
                });
                0.0 + corners.fold(f64::INFINITY, f64::min)
            }
        }
    };
    let mut out = Vec::new();
    fn visit(
        parent: Option<u32>,
        sk: &strata::format::skeleton::Skeleton,
        planes: &strata::format::planes::Planes,
        eye: Eye,
        key: &dyn Fn(u32) -> f64,
        (shown, live): (&[bool], &[bool]),
        out: &mut Vec<u32>,
    ) {
        let kids: Vec<u32> = match parent {
            None => sk.level_nodes(sk.top()).collect(),
            Some(p) => {
                let r = &sk.nodes[p as usize];
                (r.first_child..r.first_child + r.child_count).collect()
            }
        };
        let first = kids.first().copied().unwrap_or(0);
        let mut left: Vec<u32> = kids.iter().copied().filter(|&c| live[c as usize]).collect();
        let edges: Vec<(u32, u32)> = planes
            .of(parent)
            .iter()
            .filter_map(|e| {
                let (a, b) = (first + e.first, first + e.second);
                if !left.contains(&a) || !left.contains(&b) {
                    return None;
                }
                match e.decide(eye) {
                    Decision::FirstBeforeSecond => Some((a, b)),
                    Decision::SecondBeforeFirst => Some((b, a)),
                    Decision::Undecided => None,
                }
            })
            .collect();
        let least = |c: &[u32]| c.iter().copied().min_by(|&x, &y| key(x).total_cmp(&key(y)).then(x.cmp(&y)));
        while !left.is_empty() {
            let ready: Vec<u32> = left.iter().copied().filter(|&c| !edges.iter().any(|&(a, b)| b == c && left.contains(&a))).collect();
            let next = least(&ready).or_else(|| least(&left)).unwrap();
            left.retain(|&c| c != next);
            if shown[next as usize] {
                out.push(next);
            } else {
                visit(Some(next), sk, planes, eye, key, (shown, live), out);
            }
        }
    }
    visit(None, sk, planes, eye, &key, (&shown, &live), &mut out);
    out
}

/// The orderer gives exactly §5's order on mixed fronts (random cuts of the hierarchy), for
/// perspective and orthographic cameras all around, on files whose parents have few children and
/// more than 32 (the orderer's two ways of taking them).
#[test]
fn the_orderer_follows_the_rule_on_mixed_fronts() {
    let h = |x: u32| (x.wrapping_mul(2654435761) >> 8) as f32 / (1u32 << 24) as f32;
    let (mut fronts, mut many) = (0, 0);
    // A sphere with 400 separate specks above it: specks leave coarse levels into the groups that
    // take them in, which then have many children.
    let specked = std::env::temp_dir().join(format!("strata-order-specked-{}.ply", std::process::id()));
    let mut mesh = strata::fixtures::noisy_sphere(48, 0.05, 3);
    mesh.normals.clear();
    let speck = strata::fixtures::icosphere(0);
    for i in 0..400 {
        let y = 1.0 - 2.0 * (i as f32 + 0.5) / 400.0;
        let phi = i as f32 * 2.399_963;
        let center = Vec3::new((1.0 - y * y).sqrt() * phi.cos(), y, (1.0 - y * y).sqrt() * phi.sin()) * 1.15;
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(speck.positions.iter().map(|&p| center + p * 0.004));
        mesh.triangles.extend(speck.triangles.iter().map(|t| t.map(|v| v + base)));
        mesh.face_materials.extend(std::iter::repeat_n(0, speck.face_count()));
    }
    mesh.compute_face_geometry();
    let mut bytes = Vec::new();
    strata::export::ply::write_ply(&mut bytes, &mesh).unwrap();
    std::fs::write(&specked, bytes).unwrap();
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    for (mesh, leaf) in [
        (fixtures.join("noisy_sphere.ply"), 96),
        (fixtures.join("noisy_sphere.ply"), 16),
        (fixtures.join("cad_part.obj"), 32),
        (specked.clone(), 64),
    ] {
        let (out, rd) = converted("rule", &mesh, leaf);
        let mesh = mesh.display();
        let sk = rd.skeleton();
        let planes = rd.read_planes().expect("planes");
        let mut orderer = Orderer::new(sk, planes.clone());
        let (min, max) = (rd.header().min, rd.header().max);
        let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
        many += (sk.level_nodes(sk.top()).len() > 32) as u32 + sk.nodes.iter().filter(|n| n.child_count > 32).count() as u32;
        eprintln!("{mesh}: most children {:?}", sk.nodes.iter().map(|n| n.child_count).max());
        for k in 0..24u32 {
            // A cut: each node opened into its children with a probability of its own.
            let mut front = Vec::new();
            let mut todo: Vec<u32> = sk.level_nodes(sk.top()).collect();
            while let Some(n) = todo.pop() {
                let r = &sk.nodes[n as usize];
                if r.child_count > 0 && h(n * 31 + k * 7 + 1) < 0.75 {
                    todo.extend(r.first_child..r.first_child + r.child_count);
                } else {
                    front.push(n);
                }
            }
            let mut cam = camera(center, radius, k);
            if k % 3 == 2 {
                cam.projection = Projection::Orthographic { height: 2.5 * radius };
            }
            let mut order = Vec::new();
            orderer.order(sk, &front, &cam, &mut order);
            assert_eq!(order, order_by_the_rule(sk, &planes, &front, &cam), "{mesh} (leaves of {leaf}), front {k}");
            fronts += 1;
        }
        let _ = std::fs::remove_file(out);
    }
    let _ = std::fs::remove_file(specked);
    assert!(many > 0, "no parent of more than 32 children was ordered");
    eprintln!("{fronts} mixed fronts ordered as §5 says");
}
