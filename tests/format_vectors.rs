//! The golden vectors of `format-spec/vectors/`: each file decodes to exactly what its JSON says,
//! or is refused with the words its JSON lists, by the reader and by `verify`. The viewer's
//! JavaScript reader checks itself against the same files.

use std::io::Cursor;
use std::path::Path;
use strata::format::{self, Reader};

#[test]
fn the_reader_agrees_with_every_golden_vector() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("format-spec/vectors");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .expect("format-spec/vectors exists")
        .filter_map(|e| e.ok()?.file_name().to_str()?.strip_suffix(".strata").map(str::to_string))
        .collect();
    names.sort();
    assert!(names.len() >= 4, "{names:?}");
    let (mut valid, mut refused) = (0, 0);
    for name in names {
        let bytes = std::fs::read(dir.join(format!("{name}.strata"))).unwrap();
        let expected: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join(format!("{name}.json"))).unwrap()).unwrap();
        let verified = format::verify(Cursor::new(&bytes), Path::new(&name));
        if let Some(words) = expected.get("refused") {
            let read =
                Reader::open(Cursor::new(&bytes)).and_then(|rd| (0..rd.nodes().len() as u32).try_for_each(|i| rd.read_node(i).map(|_| ())));
            let message = read.expect_err(&name).to_string();
            for w in words.as_array().unwrap() {
                assert!(message.contains(w.as_str().unwrap()), "{name}: {message} lacks {w}");
            }
            assert!(!verified.is_sound(), "{name}: verify accepted it");
            refused += 1;
        } else {
            let rd = Reader::open(Cursor::new(&bytes)).unwrap_or_else(|e| panic!("{name}: {e}"));
            let decoded = format::inspect::dump(&rd).unwrap();
            assert!(decoded == expected, "{name}: the decoded file differs from {name}.json");
            assert!(verified.is_sound(), "{name}: {:?}", verified.problems);
            valid += 1;
        }
    }
    assert!(valid >= 2 && refused >= 2);
}

/// The golden fronts of `format-spec/vectors/fronts.json` are what front selection
/// (format-spec/selection.md) gives for their cameras and limits, in the drawing order of §5.
#[test]
fn front_selection_agrees_with_every_golden_front() {
    use strata::camera::Camera;
    use strata::stream::cache::record_bytes;
    use strata::stream::refine::Refiner;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("format-spec/vectors");
    let fronts: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(dir.join("fronts.json")).unwrap()).unwrap();
    assert!(fronts.len() >= 10);
    let mut levels_seen = std::collections::HashSet::new();
    for (k, f) in fronts.iter().enumerate() {
        let bytes = std::fs::read(dir.join(f["file"].as_str().unwrap())).unwrap();
        let rd = Reader::open(Cursor::new(&bytes)).unwrap();
        let camera = Camera::from_json(&f["camera"]).expect("a camera");
        let limits = limits_of(&f["limits"]);
        let held: Vec<u32> = f["held"].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as u32).collect();
        let attrs = rd.header().attributes;
        let cut = Refiner::default().select(rd.skeleton(), &camera, &limits, &held, &|n| record_bytes(n, attrs));
        let ids = |v: &serde_json::Value| v.as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as u32).collect::<Vec<u32>>();
        assert_eq!(cut.shown, ids(&f["front"]), "front {k}");
        assert_eq!(cut.culled, ids(&f["culled"]), "culled roots {k}");
        let mut order = Vec::new();
        strata::stream::order::Orderer::new(rd.skeleton(), rd.read_planes().unwrap()).order(rd.skeleton(), &cut.shown, &camera, &mut order);
        assert_eq!(order, ids(&f["order"]), "drawing order {k}");
        levels_seen.extend(cut.shown.iter().map(|&i| rd.nodes()[i as usize].level));
    }
    assert!(levels_seen.len() >= 3, "the golden fronts reach several levels: {levels_seen:?}");
}

/// The golden fronts of `format-spec/vectors/fronts-v4.json` are what selection.md §9 gives on the
/// format-4 vector for their cameras and limits, drawn nearest box first; several mix levels.
#[test]
fn dag_selection_agrees_with_every_golden_front() {
    use strata::camera::Camera;
    use strata::stream::cache::record_bytes;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("format-spec/vectors");
    let fronts: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(dir.join("fronts-v4.json")).unwrap()).unwrap();
    assert!(fronts.len() >= 8);
    let mut mixed = 0;
    for (k, f) in fronts.iter().enumerate() {
        let bytes = std::fs::read(dir.join(f["file"].as_str().unwrap())).unwrap();
        let rd = Reader::open(Cursor::new(&bytes)).unwrap();
        assert!(rd.header().is_dag());
        let camera = Camera::from_json(&f["camera"]).expect("a camera");
        let limits = limits_of(&f["limits"]);
        assert_eq!(limits.priority, strata::stream::refine::Priority::Error, "format 4 has one order");
        let attrs = rd.header().attributes;
        let cut = strata::stream::dag::select_skeleton(rd.skeleton(), &camera, &limits, &[], &|n| record_bytes(n, attrs));
        let ids = |v: &serde_json::Value| v.as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as u32).collect::<Vec<u32>>();
        assert_eq!(cut.shown, ids(&f["front"]), "front {k}");
        assert_eq!(cut.culled, ids(&f["culled"]), "culled {k}");
        let mut order = Vec::new();
        strata::stream::order::nearest_box_first(rd.skeleton(), &cut.shown, &camera, &mut order);
        assert_eq!(order, ids(&f["order"]), "drawing order {k}");
        let levels: std::collections::HashSet<u32> = cut.shown.iter().map(|&i| rd.nodes()[i as usize].level).collect();
        mixed += (levels.len() > 1) as usize;
    }
    assert!(mixed >= 2, "{mixed} golden fronts mix levels");
}

/// A golden front's limits.
fn limits_of(l: &serde_json::Value) -> strata::stream::refine::Limits {
    use strata::stream::refine::{Limits, Priority};
    Limits {
        pixel_error: l["pixel_error"].as_f64().unwrap() as f32,
        max_faces: l["max_faces"].as_u64(),
        max_bytes: l["max_bytes"].as_u64(),
        priority: match l["priority"].as_str().unwrap() {
            "error" => Priority::Error,
            "silhouette" => Priority::Silhouette,
            _ => Priority::Breadth,
        },
    }
}
