//! Invariants of streamed fronts on a converted fixture.

use super::refine::sees;
use super::session::orbit;
use super::*;
use crate::camera::Projection;
use crate::cone::{facing_perspective, Facing};
use crate::format::NO_PARENT;
use crate::hierarchy::HierarchyParams;
use crate::pipeline::{convert, ConvertOptions, Silent};
use glam::Vec3;
use std::collections::BTreeSet;
use std::fs::File;
use std::path::PathBuf;
use std::sync::OnceLock;

/// The icosphere converted with small groups, so that it has several levels; built once.
fn fixture() -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("strata-stream-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("icosphere.strata");
        let input = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/icosphere.obj"));
        let hierarchy = HierarchyParams { cluster_faces: 4, leaf_faces: 16, top_groups: 2, ..HierarchyParams::default() };
        convert(&input, &Default::default(), &out, &ConvertOptions { hierarchy, ..ConvertOptions::default() }, &mut Silent).unwrap();
        out
    })
}

fn open() -> Reader<File> {
    Reader::open_path(fixture()).unwrap()
}

fn sphere(r: &Reader<File>) -> (Vec3, f32) {
    let h = r.header();
    (0.5 * (h.min + h.max), 0.5 * (h.max - h.min).length())
}

/// Ancestors of `i`, itself first.
fn lineage(nodes: &[NodeRecord], i: u32) -> Vec<u32> {
    let mut out = vec![i];
    while nodes[*out.last().unwrap() as usize].parent != NO_PARENT {
        out.push(nodes[*out.last().unwrap() as usize].parent);
    }
    out
}

/// The invariants every frame must keep.
fn check(s: &Streamer<File>, rep: &FrameReport, camera: &Camera, budgets: &Budgets) {
    let r = s.reader();
    let nodes = r.nodes();
    let shown: BTreeSet<u32> = rep.front.iter().copied().collect();
    let culled: BTreeSet<u32> = rep.culled.iter().copied().collect();
    assert!(shown.is_disjoint(&culled));
    // A valid cut: every level-0 node (hence every face) lies under exactly one shown or culled node.
    for leaf in r.level_nodes(0) {
        let hits = lineage(nodes, leaf).iter().filter(|a| shown.contains(a) || culled.contains(a)).count();
        assert_eq!(hits, 1, "frame {} leaf {leaf}", rep.frame);
    }
    for &i in &rep.front {
        let n = &nodes[i as usize];
        assert!(sees(n, camera), "frame {}: node {i} is culled but shown", rep.frame);
        let g = s.geometry(i).expect("displayed geometry is resident");
        assert_eq!(g.face_count() as u32, n.faces);
        // Displayed neighbours differ by at most one level.
        for &m in r.neighbors(i) {
            for a in lineage(nodes, m).into_iter().skip(1) {
                if shown.contains(&a) {
                    assert!(nodes[a as usize].level <= n.level + 1, "frame {}: {i} next to {a}", rep.frame);
                }
            }
        }
    }
    for &c in &rep.culled {
        assert!(!sees(&nodes[c as usize], camera));
    }
    let faces: u64 = rep.front.iter().map(|&i| nodes[i as usize].faces as u64).sum();
    assert_eq!(faces, rep.stats.faces);
    assert_eq!(s.front_mesh().unwrap().face_count() as u64, faces);
    assert!(budgets.faces.is_none_or(|b| faces <= b), "frame {}: {faces} faces", rep.frame);
    assert!(budgets.bytes.is_none_or(|b| rep.stats.resident_bytes <= b), "frame {}", rep.frame);
}

/// Play an orbit, checking every frame and replaying the deltas; returns the reports.
fn play(budgets: Budgets, frames: usize) -> Vec<FrameReport> {
    let r = open();
    let (c, rad) = sphere(&r);
    let mut s = Streamer::new(r, budgets).unwrap();
    let mut replay = BTreeSet::new();
    let mut reports = Vec::new();
    for i in 0..frames {
        let cam = orbit(c, rad, i, frames, 256, 256);
        let rep = s.update(&cam, Some(5.0)).unwrap();
        check(&s, &rep, &cam, &budgets);
        for a in &rep.added {
            assert!(replay.insert(*a));
        }
        for x in &rep.removed {
            assert!(replay.remove(x));
        }
        assert_eq!(replay.iter().copied().collect::<Vec<_>>(), rep.front);
        reports.push(rep);
    }
    reports
}

#[test]
fn fixture_has_several_levels() {
    let r = open();
    assert!(r.levels().len() >= 3, "{} levels", r.levels().len());
}

#[test]
fn first_frame_shows_the_top_level() {
    let r = open();
    let top = r.levels().len() as u32 - 1;
    let (c, rad) = sphere(&r);
    let expected: Vec<u32> = r.level_nodes(top).collect();
    let at_open = r.bytes_read();
    let mut s = Streamer::new(r, Budgets { pixel_error: f32::INFINITY, ..Budgets::default() }).unwrap();
    let cam = Camera::framing(c, rad, Vec3::Z, 1.0, 64, 64);
    let rep = s.update(&cam, None).unwrap();
    let mut all = rep.front.clone();
    all.extend(&rep.culled);
    all.sort_unstable();
    assert_eq!(all, expected);
    assert_eq!(rep.added, rep.front);
    let geometry: u64 = rep.front.iter().map(|&i| s.reader().nodes()[i as usize].size as u64).sum();
    assert_eq!(rep.stats.bytes_read, at_open + geometry, "the skeleton and the top level's geometry, not the planes");
}

#[test]
fn orbit_without_budgets_keeps_the_invariants() {
    let reps = play(Budgets::default(), 24);
    let finest = |rep: &FrameReport| rep.stats.levels.iter().position(|&c| c > 0).unwrap();
    assert!(finest(reps.last().unwrap()) < finest(&reps[0]), "the approach refines");
}

#[test]
fn face_budget_is_never_exceeded() {
    let top_faces: u64 = {
        let r = open();
        let top = r.levels().len() as u32 - 1;
        r.level_nodes(top).map(|i| r.nodes()[i as usize].faces as u64).sum()
    };
    let budget = top_faces * 3;
    let reps = play(Budgets { faces: Some(budget), pixel_error: 0.0, ..Budgets::default() }, 16);
    assert!(reps.iter().any(|r| r.stats.faces > top_faces), "the budget leaves room to refine");
}

#[test]
fn memory_budget_is_never_exceeded() {
    let r = open();
    let attrs = r.header().attributes;
    let top = r.levels().len() as u32 - 1;
    let top_bytes: u64 = r.level_nodes(top).map(|i| cache::record_bytes(&r.nodes()[i as usize], attrs)).sum();
    let budget = top_bytes * 2 + top_bytes / 2;
    let reps = play(Budgets { bytes: Some(budget), pixel_error: 0.0, ..Budgets::default() }, 16);
    assert!(reps.iter().any(|r| r.stats.nodes > r.stats.levels[top as usize] as usize));
}

#[test]
fn budgets_below_the_top_level_are_refused() {
    assert!(Streamer::new(open(), Budgets { faces: Some(1), ..Budgets::default() }).is_err());
    assert!(Streamer::new(open(), Budgets { bytes: Some(1), ..Budgets::default() }).is_err());
}

#[test]
fn zero_threshold_and_a_wide_far_view_reach_every_front_facing_leaf() {
    let r = open();
    let (c, rad) = sphere(&r);
    let mut cam = Camera::framing(c, rad, Vec3::new(0.3, 0.5, 1.0), 2.0, 128, 128);
    cam.eye = c + (cam.eye - c) * 10.0;
    cam.far *= 20.0;
    assert!(matches!(cam.projection, Projection::Perspective { .. }));
    let nodes = r.nodes().to_vec();
    let expected: Vec<u32> = r
        .level_nodes(0)
        .filter(|&i| {
            lineage(&nodes, i).iter().all(|&a| {
                let n = &nodes[a as usize];
                facing_perspective(&n.cone, n.center, n.radius, cam.eye) != Facing::Back
            })
        })
        .collect();
    assert!(!expected.is_empty() && expected.len() < r.level_nodes(0).len());
    let budgets = Budgets { pixel_error: 0.0, ..Budgets::default() };
    let mut s = Streamer::new(r, budgets).unwrap();
    let rep = s.update(&cam, None).unwrap();
    check(&s, &rep, &cam, &budgets);
    assert_eq!(rep.front, expected);
}

#[test]
fn moving_away_coarsens() {
    let r = open();
    let (c, rad) = sphere(&r);
    let budgets = Budgets::default();
    let mut s = Streamer::new(r, budgets).unwrap();
    let near = orbit(c, rad, 15, 20, 256, 256);
    let mut far = near;
    far.eye = c + (near.eye - c) * 8.0;
    far.far = far.eye.distance(c) + rad;
    let a = s.update(&near, None).unwrap();
    let b = s.update(&far, None).unwrap();
    check(&s, &b, &far, &budgets);
    assert!(b.stats.faces < a.stats.faces);
    assert!(!b.removed.is_empty());
    // Every node that appears is an ancestor of a removed one: children collapsed into parents.
    let nodes = s.reader().nodes();
    let removed_lineages: BTreeSet<u32> = b.removed.iter().flat_map(|&x| lineage(nodes, x)).collect();
    let uncovered = b.added.iter().filter(|a| !removed_lineages.contains(a)).count();
    assert!(uncovered < b.added.len(), "some added nodes are parents of removed ones");
}

#[test]
fn frame_time_target_steers_the_threshold() {
    let r = open();
    let (c, rad) = sphere(&r);
    let mut s = Streamer::new(r, Budgets { target_ms: Some(1.0), ..Budgets::default() }).unwrap();
    let cam = orbit(c, rad, 15, 20, 256, 256);
    let first = s.update(&cam, None).unwrap();
    let mut last = first.clone();
    for _ in 0..5 {
        last = s.update(&cam, Some(100.0)).unwrap();
    }
    assert!(last.stats.pixel_error > first.stats.pixel_error);
    assert!(last.stats.faces <= first.stats.faces);
}

#[test]
fn refinement_order_changes_fronts_under_a_face_budget_only() {
    let frames = 16;
    let fronts = |budgets: Budgets| -> Vec<Vec<u32>> {
        let r = open();
        let (c, rad) = sphere(&r);
        let mut s = Streamer::new(r, budgets).unwrap();
        (0..frames)
            .map(|i| {
                let cam = orbit(c, rad, i, frames, 256, 256);
                let rep = s.update(&cam, None).unwrap();
                check(&s, &rep, &cam, &budgets);
                rep.front
            })
            .collect()
    };
    let free = Budgets { pixel_error: 0.5, ..Budgets::default() };
    for other in [Priority::Silhouette, Priority::Breadth] {
        assert_eq!(fronts(free), fronts(Budgets { priority: other, ..free }));
    }
    let top_faces: u64 = {
        let r = open();
        let top = r.levels().len() as u32 - 1;
        r.level_nodes(top).map(|i| r.nodes()[i as usize].faces as u64).sum()
    };
    for other in [Priority::Silhouette, Priority::Breadth] {
        let differ = (2..8).any(|k| {
            let tight = Budgets { faces: Some(top_faces * k / 2), pixel_error: 0.0, ..Budgets::default() };
            fronts(tight) != fronts(Budgets { priority: other, ..tight })
        });
        assert!(differ, "some face budget makes {other:?} choose a different front than {:?}", Priority::default());
    }
}

#[test]
fn a_model_coming_into_view_is_drawn_coarse_first_then_refined_as_predicted() {
    // Far, then looking away (nothing shown), then near, then near again; every frame is
    // reported to take the target time.
    let run = |predict: bool| -> (Vec<FrameReport>, Streamer<File>) {
        let r = open();
        let (c, rad) = sphere(&r);
        let budgets = Budgets { target_ms: Some(10.0), predict, ..Budgets::default() };
        let mut s = Streamer::new(r, budgets).unwrap();
        let far = orbit(c, rad, 0, 20, 256, 256);
        let near = orbit(c, rad, 15, 20, 256, 256);
        let mut away = near;
        away.target = 2.0 * near.eye - c;
        let reports = vec![
            s.update(&far, None).unwrap(),
            s.update(&away, Some(10.0)).unwrap(),
            s.update(&near, Some(10.0)).unwrap(),
            s.update(&near, Some(10.0)).unwrap(),
        ];
        (reports, s)
    };
    let (reactive, _) = run(false);

    assert_eq!(reactive[1].stats.faces, 0, "looking away shows nothing");
    assert!(
        reactive[2].stats.faces as f32 > 1.5 * reactive[0].stats.faces as f32,
        "{} vs {}",
        reactive[2].stats.faces,
        reactive[0].stats.faces
    );
    assert_eq!(reactive[3].stats.pixel_error, 1.0, "in the dead band the reactive controller keeps the threshold");

    let (predictive, s) = run(true);
    let top = s.reader().levels().len() as u32 - 1;
    let entering = &predictive[2];
    assert!(!entering.front.is_empty());
    assert!(entering.front.iter().all(|&i| s.reader().nodes()[i as usize].level == top), "what comes into view is not refined at once");
    let next = &predictive[3];
    assert!(next.stats.pixel_error >= budget::STEP, "the predicted step coarsens before drawing: {}", next.stats.pixel_error);
    assert!(next.stats.faces > entering.stats.faces, "{} faces after {} entering", next.stats.faces, entering.stats.faces);
    // Coarser everywhere than the reactive front at 1 px: no node of it lies below one of the
    // reactive front's. (Drawn faces need not be fewer: a finer front culls back faces more
    // tightly.)
    let nodes = s.reader().nodes();
    let reactive_front: BTreeSet<u32> = reactive[3].front.iter().copied().collect();
    for &i in &next.front {
        assert!(lineage(nodes, i)[1..].iter().all(|a| !reactive_front.contains(a)), "node {i} is finer than the reactive front");
    }
    assert!(next.front != reactive[3].front, "the predicted step shows another front");
}

/// The textured globe fixture converted with small groups; built once.
fn textured() -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("strata-stream-tex-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("globe.strata");
        let input = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/textured_globe.glb"));
        let hierarchy = HierarchyParams { cluster_faces: 8, leaf_faces: 64, top_groups: 2, ..HierarchyParams::default() };
        convert(&input, &Default::default(), &out, &ConvertOptions { hierarchy, ..ConvertOptions::default() }, &mut Silent).unwrap();
        out
    })
}

#[test]
fn needed_levels_follow_texels_per_pixel() {
    let r = Reader::open_path(textured()).unwrap();
    let t = r.textures();
    // 512 × 256, 256 × 128, 128 × 64, 64 × 32: geometric-mean sides 362, 181, 90.5, 45.3.
    assert_eq!(t.level_count(0), 4);
    let need = |texels_per_uv: f32| images::needed_level(t, 0, texels_per_uv, 1.0);
    assert_eq!(need(1000.0), 0, "nothing finer than the full image");
    assert_eq!(need(362.0), 0);
    assert_eq!(need(363.0), 0);
    assert_eq!(need(181.0), 1);
    assert_eq!(need(100.0), 1);
    assert_eq!(need(90.0), 2);
    assert_eq!(need(45.0), 3);
    assert_eq!(need(1.0), 3);
    // Density scales the need: twice the UV units per model unit, half the pixels per UV unit.
    assert_eq!(images::needed_level(t, 0, 200.0, 2.0), need(100.0));
}

#[test]
fn images_stream_coarse_first_within_the_budget() {
    let r = Reader::open_path(textured()).unwrap();
    let t = r.textures().clone();
    let coarsest = t.level(0, 3).unwrap();
    let (center, radius) = sphere(&r);
    let top = r.level_nodes(r.levels().len() as u32 - 1);
    let top_bytes: u64 = top.map(|i| cache::record_bytes(&r.nodes()[i as usize], r.header().attributes)).sum();
    // Room for the top level, the coarsest level and a little more, but not the full image.
    let budget = top_bytes + coarsest.decoded_bytes() + 300_000;
    let budgets = Budgets { bytes: Some(budget), ..Budgets::default() };
    let mut s = Streamer::new(r, budgets).unwrap();
    let mut finest = u32::MAX;
    for i in 0..24 {
        let camera = orbit(center, radius, i, 24, 800, 600);
        let rep = s.update(&camera, None).unwrap();
        let st = &rep.stats;
        if i == 0 {
            assert_eq!(st.texture_bytes_read, coarsest.size as u64 - 20, "the first frame reads the coarsest level alone");
            assert_eq!(st.texture_levels, vec![[0, st.texture_levels[0][1], 3]]);
        }
        assert!(
            st.resident_bytes + st.texture_resident_bytes <= budget,
            "frame {i}: {} + {} > {budget}",
            st.resident_bytes,
            st.texture_resident_bytes
        );
        for &[image, wanted, drawn] in &st.texture_levels {
            assert_eq!(image, 0);
            assert!(drawn >= wanted, "never finer than wanted");
            let chain = s.image(0).unwrap();
            assert_eq!(chain.first_level, drawn);
            finest = finest.min(drawn);
        }
    }
    assert!(finest < 3, "the orbit's close-ups draw a finer level than the coarsest");
    assert!(finest > 0, "the budget keeps the full image out");
    // Cameras jumping near and far: held levels give way when the displayed geometry grows.
    let mut seed = 7u64;
    let mut next = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 33) as f32 / (1u64 << 31) as f32
    };
    for i in 0..60 {
        let dir = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize_or(Vec3::Z);
        let distance = radius * (1.2 + 6.0 * next());
        let mut camera = orbit(center, radius, i, 60, 800, 600);
        camera.eye = center + dir * distance;
        camera.target = center + Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * radius;
        let st = s.update(&camera, None).unwrap().stats;
        assert!(
            st.resident_bytes + st.texture_resident_bytes <= budget,
            "jump {i}: {} + {} > {budget}",
            st.resident_bytes,
            st.texture_resident_bytes
        );
    }
}

#[test]
fn faces_mapped_without_uv_extent_want_the_full_image() {
    // A palette texture: every face of the globe samples one UV point.
    let dir = std::env::temp_dir().join(format!("strata-stream-palette-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut mesh = crate::fixtures::textured_globe(16, 128);
    for uv in &mut mesh.uvs {
        *uv = glam::Vec2::splat(0.3);
    }
    let input = dir.join("palette.glb");
    crate::export::glb::write(&input, &mesh).unwrap();
    let out = dir.join("palette.strata");
    convert(&input, &Default::default(), &out, &ConvertOptions::default(), &mut Silent).unwrap();
    let r = Reader::open_path(&out).unwrap();
    assert!(r.textures().uv_density.iter().all(|&d| d > 0.0 && d <= f32::MIN_POSITIVE), "{:?}", r.textures().uv_density);
    let (center, radius) = sphere(&r);
    let mut s = Streamer::new(r, Budgets::default()).unwrap();
    let far = orbit(center, radius, 0, 8, 320, 240);
    s.update(&far, None).unwrap();
    let st = s.update(&far, None).unwrap().stats;
    assert_eq!(st.texture_levels, vec![[0, 0, 0]], "from far too, the full image");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_skeleton_decoded_top_first_streams_the_same_from_the_second_frame() {
    let full = open();
    let top = Reader::open_top(File::open(fixture()).unwrap(), fixture()).unwrap();
    assert!(!top.is_complete());
    let kept: usize = full.levels().iter().rev().take(2).map(|l| l.nodes as usize).sum();
    assert!(kept < full.nodes().len());
    assert_eq!(top.nodes(), &full.nodes()[..kept]);
    assert_eq!(top.skeleton().neighbors[..], full.skeleton().neighbors[..top.skeleton().neighbors.len()]);
    assert_eq!(top.node_box(kept as u32 - 1), full.node_box(kept as u32 - 1));

    // Close up first, where a whole skeleton refines at once.
    let (c, rad) = sphere(&full);
    let frames = 12;
    let cameras: Vec<Camera> = (0..frames).map(|i| orbit(c, rad, (frames - 1 + i) % frames, frames, 256, 256)).collect();
    let mut whole = Streamer::new(full, Budgets::default()).unwrap();
    let mut lazy = Streamer::new(top, Budgets::default()).unwrap();
    let top_level = whole.reader().levels().len() as u32 - 1;
    for (k, cam) in cameras.iter().enumerate() {
        let (a, b) = (whole.update(cam, None).unwrap(), lazy.update(cam, None).unwrap());
        if k == 0 {
            assert!(a.front.iter().any(|&i| whole.reader().nodes()[i as usize].level < top_level), "the close-up refines");
            assert!(b.front.iter().chain(&b.culled).all(|&i| lazy.reader().nodes()[i as usize].level == top_level));
            assert!(!b.front.is_empty());
        } else {
            assert_eq!((&a.front, &a.culled, &a.order), (&b.front, &b.culled, &b.order), "frame {k}");
            check(&lazy, &b, cam, &Budgets::default());
        }
    }
    assert!(lazy.reader().is_complete());
    assert_eq!(lazy.reader().skeleton(), whole.reader().skeleton());
}
