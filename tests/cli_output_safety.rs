//! No command writes over its input or leaves a temporary file behind, whatever happens to it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn strata() -> Command {
    Command::new(env!("CARGO_BIN_EXE_strata"))
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("strata-outsafe-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

fn refused(out: &Output, what: &str) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{what}: should fail");
    assert!(!err.contains("panicked"), "{what}: {err}");
    err
}

#[test]
fn the_input_is_never_overwritten() {
    let dir = scratch("input");
    let input = dir.join("in.obj");
    std::fs::copy(fixture("cube.obj"), &input).unwrap();
    let original = std::fs::read(&input).unwrap();
    let in_s = input.to_str().unwrap();

    let out = strata().args(["convert", in_s, in_s]).output().unwrap();
    let err = refused(&out, "convert in.obj in.obj");
    assert!(err.contains("in.obj") && err.contains("input"), "{err}");

    let out = strata().args(["simplify", "--ratio", "0.5", "-o", in_s, in_s]).output().unwrap();
    let err = refused(&out, "simplify -o in.obj in.obj");
    assert!(err.contains("input"), "{err}");

    #[cfg(unix)]
    {
        let link = dir.join("link.obj");
        std::os::unix::fs::symlink(&input, &link).unwrap();
        let out = strata().args(["simplify", "--ratio", "0.5", "-o", link.to_str().unwrap(), in_s]).output().unwrap();
        refused(&out, "simplify through a symbolic link");
        let hard = dir.join("hard.obj");
        std::fs::hard_link(&input, &hard).unwrap();
        let out = strata().args(["convert", in_s, hard.to_str().unwrap()]).output().unwrap();
        refused(&out, "convert through a hard link");
    }
    assert_eq!(std::fs::read(&input).unwrap(), original, "the input changed");

    // A chunk file is an input of extract, render and stream.
    let chunk = dir.join("in.strata");
    assert!(strata().args(["convert", in_s, chunk.to_str().unwrap(), "--quiet"]).status().unwrap().success());
    let before = std::fs::read(&chunk).unwrap();
    let c = chunk.to_str().unwrap();
    refused(&strata().args(["extract", c, "-o", c]).output().unwrap(), "extract over its input");
    refused(&strata().args(["render", c, "-o", c]).output().unwrap(), "render over its input");
    refused(&strata().args(["stream", c, "--orbit", "2", "--export-cut", c]).output().unwrap(), "stream --export-cut over its input");
    assert_eq!(std::fs::read(&chunk).unwrap(), before, "the chunk file changed");
    assert!(names(&dir).iter().all(|n| !n.contains("tmp")), "{:?}", names(&dir));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_directory_as_output_is_refused_and_leaves_nothing() {
    let dir = scratch("dir");
    let target = dir.join("some_dir.obj");
    std::fs::create_dir(&target).unwrap();
    let cube = fixture("cube.obj");
    let out = strata().args(["convert", cube.to_str().unwrap(), target.to_str().unwrap()]).output().unwrap();
    let err = refused(&out, "convert into a directory");
    assert!(err.contains("directory"), "{err}");
    let out = strata().args(["simplify", "--ratio", "0.5", "-o", target.to_str().unwrap(), cube.to_str().unwrap()]).output().unwrap();
    refused(&out, "simplify into a directory");
    assert_eq!(names(&dir), ["some_dir.obj"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Start converting the 100k-face fixture into `dir`, and wait until its temporary file appears.
#[cfg(unix)]
fn convert_until_writing(dir: &Path) -> std::process::Child {
    let out = dir.join("out.strata");
    let mut child = strata()
        .args(["convert", fixture("noisy_sphere.ply").to_str().unwrap(), out.to_str().unwrap(), "--quiet"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !names(dir).iter().any(|n| n.ends_with(".strata-tmp")) {
        assert!(child.try_wait().unwrap().is_none(), "convert ended before its temporary file was seen");
        assert!(start.elapsed() < Duration::from_secs(60), "no temporary file after 60 s");
        std::thread::sleep(Duration::from_micros(500));
    }
    child
}

#[cfg(unix)]
#[test]
fn signals_during_the_write_leave_nothing() {
    for (sig, name) in [(libc::SIGTERM, "SIGTERM"), (libc::SIGHUP, "SIGHUP"), (libc::SIGINT, "SIGINT")] {
        let dir = scratch(name);
        let child = convert_until_writing(&dir);
        unsafe { libc::kill(child.id() as libc::pid_t, sig) };
        let out = child.wait_with_output().unwrap();
        assert!(!out.status.success(), "{name}: the conversion should not succeed");
        assert_eq!(names(&dir), Vec::<String>::new(), "{name} left files");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[cfg(unix)]
#[test]
fn what_a_killed_process_left_is_removed_by_the_next_write() {
    let dir = scratch("kill");
    let mut child = convert_until_writing(&dir);
    child.kill().unwrap();
    child.wait().unwrap();
    let left: Vec<String> = names(&dir);
    assert_eq!(left.len(), 1, "SIGKILL cannot be caught: one temporary file stays ({left:?})");
    // Only files untouched for a minute count as stale; age this one.
    let leftover = dir.join(&left[0]);
    let old = std::time::SystemTime::now() - Duration::from_secs(120);
    std::fs::File::options().write(true).open(&leftover).unwrap().set_modified(old).unwrap();
    let out = strata()
        .args(["convert", fixture("cube.obj").to_str().unwrap(), dir.join("cube.strata").to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("removed") && err.contains(&left[0]), "{err}");
    assert_eq!(names(&dir), ["cube.strata"]);
    std::fs::remove_dir_all(&dir).unwrap();
}
