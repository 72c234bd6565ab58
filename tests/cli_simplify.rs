//! The standalone simplifier through the CLI: targets, measured distance, JSON, bad arguments.

use std::path::Path;
use std::process::{Command, Output};

fn strata(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().expect("run strata")
}

fn fixture(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name).display().to_string()
}

#[test]
fn simplify_reaches_its_target_and_measures_the_distance() {
    let out = std::env::temp_dir().join(format!("strata-cli-simplify-{}.ply", std::process::id()));
    let o = strata(&["simplify", &fixture("noisy_sphere.ply"), "--ratio", "0.1", "--measure", "--json", "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    let (faces_in, faces_out, target) =
        (v["faces_in"].as_u64().unwrap(), v["faces_out"].as_u64().unwrap(), v["target_faces"].as_u64().unwrap());
    assert_eq!(target, (faces_in as f64 * 0.1).round() as u64);
    assert!(faces_out <= target && faces_out + 2 >= target, "{faces_out} faces for {target}");
    let mean = v["distance"]["mean_over_diagonal"].as_f64().unwrap();
    assert!(mean > 0.0 && mean < 0.005, "mean distance {mean} of the diagonal");
    let back = strata::import(&out, None).expect("the output imports");
    std::fs::remove_file(&out).ok();
    assert_eq!(back.mesh.face_count() as u64, faces_out);
}

#[test]
fn simplify_says_when_it_stops_above_the_target() {
    let out = std::env::temp_dir().join(format!("strata-cli-simplify-cad-{}.obj", std::process::id()));
    let o = strata(&["simplify", &fixture("cad_part.obj"), "--faces", "4", "-o", out.to_str().unwrap()]);
    std::fs::remove_file(&out).ok();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("stopped above the target of 4 faces") && text.contains("--topology"), "{text}");
}

#[test]
fn bad_ratio_is_an_error() {
    let out = std::env::temp_dir().join(format!("strata-cli-simplify-bad-{}.obj", std::process::id()));
    let o = strata(&["simplify", &fixture("cube.obj"), "--ratio", "2", "-o", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--ratio"), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!out.exists(), "no output on error");
}
