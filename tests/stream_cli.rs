//! `strata stream` end to end: convert a fixture, play an orbit and a camera path through the CLI.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn strata(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().unwrap()
}

fn converted(dir: &Path) -> PathBuf {
    let input = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/icosphere.obj");
    let out = dir.join("ico.strata");
    let o = strata(&["convert", input, out.to_str().unwrap(), "-q", "--leaf-faces", "16", "--cluster-faces", "4", "--top-groups", "2"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("strata-stream-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn orbit_prints_json_lines_within_budget_and_writes_frames_and_cut() {
    let dir = scratch("orbit");
    let file = converted(&dir);
    let (frames, cut) = (dir.join("frames"), dir.join("cut.obj"));
    let o = strata(&[
        "stream",
        file.to_str().unwrap(),
        "--orbit",
        "8",
        "--json",
        "--budget-faces",
        "900",
        "--pixel-error",
        "0.5",
        "--width",
        "96",
        "--height",
        "72",
        "--frames-dir",
        frames.to_str().unwrap(),
        "--export-cut",
        cut.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let lines: Vec<serde_json::Value> = String::from_utf8(o.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 8);
    let mut read = 0;
    for (k, v) in lines.iter().enumerate() {
        assert_eq!(v["frame"], k as u64);
        for key in ["faces", "nodes", "added", "removed", "bytes_read", "resident_bytes", "refine_ms", "draw_ms"] {
            assert!(v[key].is_number(), "{key} in {v}");
        }
        assert!(v["faces"].as_u64().unwrap() <= 900);
        assert!(v["bytes_read"].as_u64().unwrap() >= read);
        read = v["bytes_read"].as_u64().unwrap();
    }
    assert!(lines.last().unwrap()["faces"].as_u64().unwrap() > lines[0]["faces"].as_u64().unwrap());
    assert_eq!(std::fs::read_dir(&frames).unwrap().count(), 8);
    let obj = std::fs::read_to_string(&cut).unwrap();
    let faces = obj.lines().filter(|l| l.starts_with("f ")).count() as u64;
    assert_eq!(faces, lines.last().unwrap()["faces"].as_u64().unwrap());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn camera_path_plays_and_a_bad_line_is_named() {
    let dir = scratch("path");
    let file = converted(&dir);
    let path = dir.join("cams.txt");
    std::fs::write(&path, "# eye then target\n0 0 30 0 0 0\n0 0 3 0 0 0\n").unwrap();
    let o = strata(&["stream", file.to_str().unwrap(), "--path", path.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(String::from_utf8(o.stdout).unwrap().lines().filter(|l| l.starts_with("frame")).count(), 2);
    std::fs::write(&path, "0 0 30 0 0 0\n0 0 3 0 0\n").unwrap();
    let o = strata(&["stream", file.to_str().unwrap(), "--path", path.to_str().unwrap()]);
    let err = String::from_utf8(o.stderr).unwrap();
    assert!(!o.status.success() && err.contains("cams.txt") && err.contains("line 2"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// `--print-front` adds each frame's camera (which reads back exactly), its displayed nodes, whose
/// faces add up to the frame's count, and the roots of culled subtrees, none shown.
#[test]
fn print_front_gives_camera_front_and_culled_roots() {
    use strata::camera::Camera;
    let dir = scratch("print-front");
    let file = converted(&dir);
    let o = strata(&["stream", file.to_str().unwrap(), "--orbit", "6", "--json", "--print-front", "--width", "96", "--height", "72"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rd = strata::format::Reader::open(std::fs::File::open(&file).unwrap()).unwrap();
    let ids = |v: &serde_json::Value| v.as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as u32).collect::<Vec<u32>>();
    let lines: Vec<serde_json::Value> = String::from_utf8(o.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 6);
    for v in &lines {
        let camera = Camera::from_json(&v["camera"]).expect("a camera");
        assert_eq!(camera.to_json(), v["camera"]);
        let (front, culled) = (ids(&v["front"]), ids(&v["culled_roots"]));
        assert_eq!(front.len() as u64, v["nodes"].as_u64().unwrap());
        let faces: u64 = front.iter().map(|&i| rd.nodes()[i as usize].faces as u64).sum();
        assert_eq!(faces, v["faces"].as_u64().unwrap());
        assert_eq!(culled.len() as u64, v["culled"].as_u64().unwrap());
        assert!(culled.iter().all(|c| !front.contains(c)));
    }
    let o = strata(&["stream", file.to_str().unwrap(), "--orbit", "2", "--print-front"]);
    assert!(!o.status.success(), "--print-front without --json is refused");
    std::fs::remove_dir_all(&dir).ok();
}
