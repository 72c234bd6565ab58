//! Malformed input through the CLI binary: every case ends with a clear error naming the file and
//! where it went wrong, a non-zero exit, and no panic.

use std::path::{Path, PathBuf};
use std::process::Command;

struct Case {
    name: &'static str,
    bytes: Vec<u8>,
    /// Substrings the error message must contain (besides the file name).
    expect: &'static [&'static str],
}

fn binary_ply(vertices: u32, faces: u32, body_vertices: usize, index: i32) -> Vec<u8> {
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    .into_bytes();
    for i in 0..body_vertices {
        for c in [i as f32, (i * i) as f32, 1.0] {
            b.extend_from_slice(&c.to_le_bytes());
        }
    }
    b.push(3);
    for v in [0, 1, index] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

fn cases() -> Vec<Case> {
    let good_ply = binary_ply(3, 1, 3, 2);
    vec![
        Case { name: "empty.ply", bytes: vec![], expect: &[] },
        Case { name: "empty.obj", bytes: vec![], expect: &[] },
        Case { name: "empty.glb", bytes: vec![], expect: &[] },
        Case { name: "empty.gltf", bytes: vec![], expect: &[] },
        Case { name: "truncated.ply", bytes: good_ply[..good_ply.len() - 7].to_vec(), expect: &["byte offset"] },
        Case { name: "lying_header.ply", bytes: binary_ply(1_000_000_000, 1, 3, 2), expect: &[] },
        Case { name: "index_out_of_range.ply", bytes: binary_ply(3, 1, 3, 7), expect: &["face 0"] },
        Case {
            name: "point_cloud.ply",
            bytes: b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 1 1\n".to_vec(),
            expect: &["point cloud"],
        },
        Case {
            name: "bad_ascii.ply",
            bytes: b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 one 0\n3 0 1 2\n".to_vec(),
            expect: &["line 12"],
        },
        Case { name: "bad_line.obj", bytes: b"v 0 0 0\nv 1 0 0\nv 0 x 0\nf 1 2 3\n".to_vec(), expect: &["line 3"] },
        Case { name: "index_out_of_range.obj", bytes: b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n".to_vec(), expect: &["line 4"] },
        Case { name: "nan.obj", bytes: b"v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n".to_vec(), expect: &[] },
        Case {
            name: "missing_buffer.gltf",
            bytes: br#"{"asset":{"version":"2.0"},"buffers":[{"uri":"nowhere.bin","byteLength":36}],
                "bufferViews":[{"buffer":0,"byteLength":36}],
                "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}],
                "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}],"scene":0}"#
                .to_vec(),
            expect: &["nowhere.bin"],
        },
        Case { name: "garbage.glb", bytes: b"glTF\x02\x00\x00\x00\xff\xff\xff\x7f".to_vec(), expect: &[] },
        Case { name: "unknown.xyz", bytes: b"hello".to_vec(), expect: &["format"] },
    ]
}

/// A work folder of this process for one test: tests run in parallel, so none shares another's.
fn temp_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("strata-bad-input-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn run_info(path: &Path) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_strata")).arg("info").arg(path).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// What is wrong with how a run handled `case`: it succeeded, panicked, did not name the file or
/// say what `case` expects, or left an output.
fn problems(case: &Case, ok: bool, stderr: &str, left_output: bool) -> Vec<String> {
    [
        (ok, "exited 0".to_string()),
        (stderr.contains("panicked"), "panicked".to_string()),
        (!stderr.contains(case.name), "error does not name the file".to_string()),
        (left_output, "left an output".to_string()),
    ]
    .into_iter()
    .filter_map(|(bad, what)| bad.then_some(what))
    .chain(case.expect.iter().filter(|e| !stderr.contains(*e)).map(|e| format!("error lacks {e:?}")))
    .collect()
}

#[test]
fn malformed_files_fail_cleanly() {
    let dir = temp_dir("info");
    let mut failures = Vec::new();
    for case in cases() {
        let path = dir.join(case.name);
        std::fs::write(&path, &case.bytes).unwrap();
        let (ok, stderr) = run_info(&path);
        let problems = problems(&case, ok, &stderr, false);
        if !problems.is_empty() {
            failures.push(format!("{}: {} — stderr: {}", case.name, problems.join(", "), stderr.trim()));
        }
    }
    std::fs::remove_dir_all(&dir).ok();
    assert!(failures.is_empty(), "bad input not handled:\n{}", failures.join("\n"));
}

#[test]
fn missing_file_fails_cleanly() {
    let (ok, stderr) = run_info(Path::new("/nonexistent/strata/mesh.obj"));
    assert!(!ok);
    assert!(stderr.contains("/nonexistent/strata/mesh.obj"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// The PLY and OBJ cases through the partitioned build's streaming readers (`convert
/// --partitioned`, as a tree and as a DAG), and hostile face indices: the same clear errors, and
/// no output left.
#[test]
fn malformed_files_fail_cleanly_when_streamed() {
    let dir = temp_dir("streamed");
    let extra = [
        Case { name: "far_relative.obj", bytes: b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -9223372036854775808 1 2\n".to_vec(), expect: &["line 4"] },
        Case { name: "huge_index.obj", bytes: b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n".to_vec(), expect: &["line 4"] },
        Case { name: "non_utf8.obj", bytes: b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 \xff\n".to_vec(), expect: &["line 4"] },
    ];
    let mut failures = Vec::new();
    for case in cases().into_iter().chain(extra).filter(|c| c.name.ends_with(".ply") || c.name.ends_with(".obj")) {
        let path = dir.join(case.name);
        std::fs::write(&path, &case.bytes).unwrap();
        for dag in [&[][..], &["--dag"][..]] {
            let out_file = dir.join(format!("{}.strata", case.name));
            let out = Command::new(env!("CARGO_BIN_EXE_strata"))
                .args(["convert", "--partitioned", "--memory", "16M", "--temp"])
                .arg(&dir)
                .args(dag)
                .arg(&path)
                .arg(&out_file)
                .output()
                .unwrap();
            let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
            let problems = problems(&case, out.status.success(), &stderr, out_file.exists());
            if !problems.is_empty() {
                failures.push(format!("{} {dag:?}: {} — stderr: {}", case.name, problems.join(", "), stderr.trim()));
            }
        }
    }
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().flatten().filter(|e| e.path().is_dir()).collect();
    std::fs::remove_dir_all(&dir).ok();
    assert!(failures.is_empty(), "bad input not handled when streamed:\n{}", failures.join("\n"));
    assert!(left.is_empty(), "work folders left behind: {left:?}");
}
