//! `strata convert --dag` writes format 4 (format-spec/strata-v4.md), and its files keep the DAG
//! crack-free through quantization: the noisy sphere fixture, converted, verifies sound, and every
//! cut that selection.md §9's rule makes from the file alone (groups' projected errors raised
//! along the DAG, a node shown iff its source's is at most τ and its consumer's above), decoded
//! from the file, is a closed surface: every edge, by decoded position, is used once each way.
//! The rule is written here again from the spec, apart from `strata::dag::cut`.

use glam::Vec3;
use rustc_hash::FxHashMap;
use std::path::Path;
use strata::camera::Camera;
use strata::format::{NodeGeometry, Reader, NO_PARENT};
use strata::pipeline::{convert, Build, ConvertOptions, Silent};
use strata::render::{crack_pixels, Image};
use strata::stream::{session, Budgets, Streamer};

/// §9.1 and §9.2 from the file alone: the groups' projected errors raised along the DAG, and the
/// nodes whose source's is at most `tau` and whose consumer's is above.
fn threshold_cut(rd: &Reader<std::fs::File>, camera: &Camera, tau: f32) -> Vec<usize> {
    let dag = rd.dag().expect("a DAG");
    // Groups in file order are the top level's first, so a group's children's sources come
    // after it; raise from the last group back.
    let mut p: Vec<f32> = dag.groups.iter().map(|g| camera.projected_error(g.error, g.center, g.radius)).collect();
    for g in (0..dag.groups.len()).rev() {
        let below = dag.children(g as u32).iter().map(|&c| dag.source[c as usize]).filter(|&s| s != NO_PARENT);
        p[g] = below.map(|s| p[s as usize]).fold(p[g], f32::max);
    }
    (0..rd.nodes().len())
        .filter(|&n| {
            let (s, c) = (dag.source[n], dag.consumer[n]);
            (s == NO_PARENT || p[s as usize] <= tau) && (c == NO_PARENT || p[c as usize] > tau)
        })
        .collect()
}

/// The noisy sphere converted with `--dag`: in memory, or partitioned into about ten cells whose
/// borders the cuts cross.
fn converted(name: &str, partitioned: bool) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = std::env::temp_dir().join(format!("strata-format4-{name}-{}.strata", std::process::id()));
    let work = std::env::temp_dir().join(format!("strata-format4-{name}-{}-work", std::process::id()));
    std::fs::create_dir_all(&work).unwrap();
    let opts = match partitioned {
        true => ConvertOptions { dag: true, build: Build::Partitioned, memory: 16 << 20, temp: Some(work.clone()), ..Default::default() },
        false => ConvertOptions { dag: true, build: Build::InCore, ..ConvertOptions::default() },
    };
    let c = convert(&root.join("fixtures/noisy_sphere.ply"), &Default::default(), &out, &opts, &mut Silent).expect("convert");
    assert_eq!(std::fs::read_dir(&work).unwrap().count(), 0, "work files left behind");
    std::fs::remove_dir(&work).ok();
    match partitioned {
        true => assert!(c.cells.is_some_and(|n| n >= 6), "{:?} cells", c.cells),
        false => assert_eq!(c.cells, None),
    }
    out
}

#[test]
fn dag_files_verify_and_every_cut_of_them_is_closed() {
    every_cut_is_closed(converted("cuts", false));
}

#[test]
fn partitioned_dag_files_verify_and_every_cut_of_them_is_closed() {
    every_cut_is_closed(converted("cuts-partitioned", true));
}

fn every_cut_is_closed(out: std::path::PathBuf) {
    let v = strata::format::verify_path(&out);
    assert!(v.problems.is_empty(), "{:?}", v.problems);
    let rd = Reader::open_path(&out).expect("open");
    std::fs::remove_file(&out).ok();
    assert_eq!(rd.header().major, 4);
    assert_eq!(rd.header().input_faces, 99_372);
    assert_eq!(rd.header().input_vertices, 49_688, "vertices counted once across cells");
    let nodes = rd.nodes().to_vec();
    let geometry: Vec<NodeGeometry> = (0..nodes.len() as u32).map(|i| rd.read_node(i).expect("node")).collect();

    let mut mixed = 0;
    for (i, dir) in [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, Vec3::new(1.0, 1.0, 1.0), Vec3::new(-1.0, 0.5, -0.3)].into_iter().enumerate() {
        let mut camera = Camera::framing(Vec3::ZERO, 1.1, dir, 50f32.to_radians(), 640, 480);
        camera.eye = dir.normalize() * (1.15 + 0.5 * i as f32);
        camera.near = 0.01;
        for tau in (0..12).map(|k| 0.25 * 1.6f32.powi(k)) {
            let cut = threshold_cut(&rd, &camera, tau);
            let levels: std::collections::BTreeSet<u32> = cut.iter().map(|&n| nodes[n].level).collect();
            assert!(!cut.is_empty(), "view {i}, τ {tau}: an empty cut");
            mixed += (levels.len() > 2) as usize;
            let mut count: FxHashMap<([u32; 3], [u32; 3]), i32> = FxHashMap::default();
            for &n in &cut {
                let g = &geometry[n];
                let key = |k: u32| g.positions[k as usize].to_array().map(f32::to_bits);
                for t in g.indices.chunks_exact(3) {
                    for k in 0..3 {
                        let (a, b) = (key(t[k]), key(t[(k + 1) % 3]));
                        if a < b {
                            *count.entry((a, b)).or_default() += 1;
                        } else {
                            *count.entry((b, a)).or_default() -= 1;
                        }
                    }
                }
            }
            let open: i32 = count.values().map(|c| c.abs()).sum();
            assert_eq!(open, 0, "view {i}, τ {tau}: levels {levels:?}");
        }
    }
    assert!(mixed >= 3, "{mixed} cuts span three levels or more");
}

/// The streamer selects from a format-4 file by selection.md §9: without budgets its front is the
/// threshold cut's nodes it sees; and the fronts of the orbit the seams test uses, drawn from the
/// file with no seams, leave no crack pixel though most mix levels.
#[test]
fn the_streamer_shows_dag_cuts_without_cracks() {
    streamed_without_cracks(converted("stream", false));
}

#[test]
fn the_streamer_shows_partitioned_dag_cuts_without_cracks() {
    streamed_without_cracks(converted("stream-partitioned", true));
}

fn streamed_without_cracks(out: std::path::PathBuf) {
    const W: u32 = 640;
    const H: u32 = 480;
    const FRAMES: usize = 32;
    let rd = Reader::open_path(&out).expect("open");
    let full = strata::assemble::to_mesh(&rd, 0).expect("level 0");
    let full_indices: Vec<u32> = full.triangles.iter().flatten().copied().collect();
    let h = rd.header().clone();
    let (center, radius) = (0.5 * (h.min + h.max), 0.5 * (h.max - h.min).length());
    let mut s = Streamer::new(Reader::open_path(&out).expect("open"), Budgets::default()).expect("streamer");
    std::fs::remove_file(&out).ok();
    let (mut cracks, mut mixed) = (0, 0);
    for i in 0..FRAMES {
        let camera = session::orbit(center, radius, i, FRAMES, W, H);
        let report = s.update(&camera, None).expect("frame");
        let mut expected: Vec<u32> = threshold_cut(&rd, &camera, 1.0)
            .into_iter()
            .map(|n| n as u32)
            .filter(|&n| strata::stream::refine::sees(&rd.nodes()[n as usize], &camera))
            .collect();
        expected.sort_unstable();
        assert_eq!(report.front, expected, "frame {i}");
        mixed += (report.stats.levels.iter().filter(|&&n| n > 0).count() > 1) as usize;
        let mut img = Image::new(W, H);
        for &n in &report.front {
            let g = s.geometry(n).expect("resident");
            img.draw(&camera, &g.positions, &[], &g.indices, [200, 200, 200, 255]);
        }
        let mut reference = Image::new(W, H);
        reference.draw(&camera, &full.positions, &[], &full_indices, [200, 200, 200, 255]);
        cracks += crack_pixels(&img, &reference);
        assert_eq!(report.stats.seam_faces, 0);
    }
    eprintln!("format 4 noisy sphere: {mixed} of {FRAMES} fronts mix levels, {cracks} crack pixels");
    assert!(mixed >= FRAMES / 2, "{mixed} mixed fronts");
    assert_eq!(cracks, 0);
}

/// A soup of separate triangles (specks, fragments, an unwelded export) has nothing to collapse:
/// without the DAG's small-component rule (`dag/specks.rs`) each triangle was a node at every
/// level and the top kept every face. In memory and partitioned, the file verifies, its levels
/// halve down to the top budget, and its nodes hold hundreds of faces each.
#[test]
fn a_soup_of_separate_triangles_shrinks_level_by_level() {
    const TRIANGLES: usize = 12_000;
    let dir = std::env::temp_dir().join(format!("strata-format4-soup-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("work")).unwrap();
    let input = dir.join("soup.obj");
    let mut obj = std::io::BufWriter::new(std::fs::File::create(&input).unwrap());
    strata::fixtures::write_soup_obj(&mut obj, TRIANGLES).unwrap();
    drop(obj);
    let top_faces = 1000;
    for partitioned in [false, true] {
        let mut opts = match partitioned {
            true => ConvertOptions { build: Build::Partitioned, memory: 8 << 20, temp: Some(dir.join("work")), ..Default::default() },
            false => ConvertOptions { build: Build::InCore, ..Default::default() },
        };
        opts.dag = true;
        opts.levels.top_faces = top_faces;
        let out = dir.join(format!("soup-{partitioned}.strata"));
        let c = convert(&input, &Default::default(), &out, &opts, &mut Silent).expect("convert");
        if partitioned {
            assert!(c.cells.is_some_and(|n| n >= 3), "{:?} cells", c.cells);
        }
        let s = &c.summary;
        let faces: Vec<u64> = s.levels.iter().map(|l| l.faces).collect();
        assert_eq!(faces[0], TRIANGLES as u64);
        assert!(*faces.last().unwrap() <= top_faces as u64, "partitioned {partitioned}: faces per level {faces:?}");
        for w in faces.windows(2) {
            assert!(w[1] * 10 <= w[0] * 6, "partitioned {partitioned}: a level kept over 60 % of the one below: {faces:?}");
        }
        assert!((s.nodes as usize) * 100 <= TRIANGLES, "partitioned {partitioned}: {} nodes for {TRIANGLES} faces", s.nodes);
        assert!(s.bytes_per_face() < 40.0, "partitioned {partitioned}: {:.1} bytes per face", s.bytes_per_face());
        let v = strata::format::verify_path(&out);
        assert!(v.problems.is_empty(), "partitioned {partitioned}: {:?}", v.problems);
        assert!(!c.warnings.iter().any(|w| w.contains("top level holds")), "{:?}", c.warnings);
    }
    // The tree cannot shrink a soup (its groups never join two pieces): it converts, and says so.
    let mut opts = ConvertOptions { build: Build::InCore, ..Default::default() };
    opts.levels.top_faces = top_faces;
    let c = convert(&input, &Default::default(), &dir.join("soup-tree.strata"), &opts, &mut Silent).expect("convert");
    let said = c.warnings.iter().find(|w| w.contains("top level holds")).expect("a warning");
    assert!(said.contains(&format!("{TRIANGLES} faces")) && said.contains("--dag"), "{said}");
    std::fs::remove_dir_all(&dir).ok();
}
