//! Hostile input through the CLI binary: files built to mislead the importers (strides that overlap
//! elements, buffers outside the model's folder, cut or overlong ascii PLY lines, coordinates that
//! overflow later stages, UTF-16 text, empty files). Each ends in a clear error naming the file and
//! where it went wrong, or imports with a warning, and never panics.

use base64::Engine;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A fresh directory for one test, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("strata-hostile-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn write(&self, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
        let path = self.0.join(name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).unwrap();
        }
        std::fs::write(&path, bytes).unwrap();
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Run the binary; returns success, stdout and stderr.
fn strata(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().unwrap();
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (out.status.success(), text(&out.stdout), text(&out.stderr))
}

fn info(path: &Path, extra: &[&str]) -> (bool, String, String) {
    let mut args = vec!["info", path.to_str().unwrap(), "--json"];
    args.extend_from_slice(extra);
    strata(&args)
}

/// `strata info` on `path` fails without panicking, and its error names the file and holds every
/// one of `expect`.
#[track_caller]
fn assert_refused(path: &Path, extra: &[&str], expect: &[&str]) -> String {
    let (ok, stdout, stderr) = info(path, extra);
    assert!(!ok, "{} imported: {stdout}", path.display());
    assert!(!stderr.contains("panicked"), "{stderr}");
    let name = path.file_name().unwrap().to_str().unwrap();
    assert!(stderr.contains(name), "error does not name {name}: {stderr}");
    for e in expect {
        assert!(stderr.contains(e), "error lacks {e:?}: {stderr}");
    }
    stderr
}

/// `strata info --json` on `path` succeeds; returns the parsed summary.
#[track_caller]
fn assert_imports(path: &Path, extra: &[&str]) -> serde_json::Value {
    let (ok, stdout, stderr) = info(path, extra);
    assert!(ok, "{} failed: {stderr}", path.display());
    serde_json::from_str(&stdout).unwrap()
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// One triangle at (0,0,0), (1,0,0), (0,1,0), tightly packed.
fn triangle_bytes() -> Vec<u8> {
    f32_bytes(&[0., 0., 0., 1., 0., 0., 0., 1., 0.])
}

fn data_uri(bytes: &[u8]) -> String {
    format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes))
}

/// A glTF document with one buffer and one triangle primitive whose POSITION is accessor 0.
fn gltf(buffer_uri: &str, byte_length: usize, views: &str, accessors: &str) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"uri":"{buffer_uri}","byteLength":{byte_length}}}],
"bufferViews":{views},"accessors":{accessors},
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],"nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}],"scene":0}}"#
    )
}

const POSITIONS: &str = r#""componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]"#;

#[test]
fn gltf_stride_smaller_than_the_element_is_refused() {
    let dir = TempDir::new("stride");
    let bin = triangle_bytes();
    let doc = gltf(
        &data_uri(&bin),
        bin.len(),
        r#"[{"buffer":0,"byteLength":36,"byteStride":4}]"#,
        &format!(r#"[{{"bufferView":0,{POSITIONS}}}]"#),
    );
    let path = dir.write("stride.gltf", doc);
    assert_refused(&path, &[], &["accessor 0", "buffer view 0", "byteStride 4", "12-byte"]);
}

#[test]
fn gltf_element_straddling_its_stride_is_refused() {
    let dir = TempDir::new("straddle");
    // Stride 12 and byteOffset 4: every element runs 4 bytes into the next record.
    let mut bin = vec![0u8; 4];
    bin.extend(triangle_bytes());
    let doc = gltf(
        &data_uri(&bin),
        bin.len(),
        r#"[{"buffer":0,"byteLength":40,"byteStride":12}]"#,
        &format!(r#"[{{"bufferView":0,"byteOffset":4,{POSITIONS}}}]"#),
    );
    let path = dir.write("straddle.gltf", doc);
    assert_refused(&path, &[], &["accessor 0", "buffer view 0", "byteOffset 4", "byteStride 12"]);
    // Skipping whole records is fine: byteOffset 12 over stride 12 starts at the second element.
    let mut bin = vec![0u8; 12];
    bin.extend(triangle_bytes());
    let doc = gltf(
        &data_uri(&bin),
        bin.len(),
        r#"[{"buffer":0,"byteLength":48,"byteStride":12}]"#,
        &format!(r#"[{{"bufferView":0,"byteOffset":12,{POSITIONS}}}]"#),
    );
    let summary = assert_imports(&dir.write("skip.gltf", doc), &[]);
    assert_eq!(summary["faces"], 1);
}

#[test]
fn gltf_strided_sparse_and_index_views_are_refused() {
    let dir = TempDir::new("sparse-stride");
    // Base triangle, then one sparse index (u32) and one sparse value stored every 16 bytes.
    let mut bin = triangle_bytes();
    bin.extend(2u32.to_le_bytes());
    bin.extend(f32_bytes(&[0., 5., 0., 0.]));
    let views = r#"[{"buffer":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":4},
        {"buffer":0,"byteOffset":40,"byteLength":16,"byteStride":16}]"#;
    let sparse = r#""sparse":{"count":1,"indices":{"bufferView":1,"componentType":5125},"values":{"bufferView":2}}"#;
    let doc = gltf(&data_uri(&bin), bin.len(), views, &format!(r#"[{{"bufferView":0,{POSITIONS},{sparse}}}]"#));
    let path = dir.write("sparse.gltf", doc);
    assert_refused(&path, &[], &["accessor 0", "sparse values", "buffer view 2", "byteStride 16"]);

    // Indices are tightly packed in glTF: a u16 index view with byteStride 4 is not honoured.
    let mut bin = triangle_bytes();
    bin.extend([0u16, 9, 1, 9, 2, 9].iter().flat_map(|i| i.to_le_bytes()));
    let views = r#"[{"buffer":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":12,"byteStride":4}]"#;
    let accessors = format!(r#"[{{"bufferView":0,{POSITIONS}}},{{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}}]"#);
    let doc = gltf(&data_uri(&bin), bin.len(), views, &accessors)
        .replace(r#""attributes":{"POSITION":0}"#, r#""attributes":{"POSITION":0},"indices":1"#);
    let path = dir.write("indices.gltf", doc);
    assert_refused(&path, &[], &["accessor 1", "buffer view 1", "byteStride 4"]);
}

#[test]
fn gltf_buffers_outside_the_model_folder_need_the_flag() {
    let dir = TempDir::new("outside");
    let bin = triangle_bytes();
    let secret = dir.write("secret.bin", &bin);
    dir.write("model/inside.bin", &bin);
    let views = r#"[{"buffer":0,"byteLength":36}]"#;
    let accessors = format!(r#"[{{"bufferView":0,{POSITIONS}}}]"#);
    let absolute = secret.to_str().unwrap().to_string();
    std::fs::create_dir_all(dir.0.join("model/sub")).unwrap();
    for uri in ["../secret.bin", "%2E%2E/secret.bin", "sub/../../secret.bin", absolute.as_str()] {
        let path = dir.write("model/m.gltf", gltf(uri, bin.len(), views, &accessors));
        let e = assert_refused(&path, &[], &["buffer 0", uri, "--allow-outside-files"]);
        assert!(e.contains("outside"), "{e}");
        assert_eq!(assert_imports(&path, &["--allow-outside-files"])["faces"], 1, "{uri}");
    }
    // Inside the folder, `..` that does not climb above it is fine.
    let path = dir.write("model/m.gltf", gltf("sub/../inside.bin", bin.len(), views, &accessors));
    assert_eq!(assert_imports(&path, &[])["faces"], 1);
    // A link inside the folder is the user's own doing: followed.
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(&secret, dir.0.join("model/link.bin")).unwrap();
        let path = dir.write("model/m.gltf", gltf("link.bin", bin.len(), views, &accessors));
        assert_eq!(assert_imports(&path, &[])["faces"], 1);
    }
}

const ASCII_PLY_HEADER: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n";

#[test]
fn ascii_ply_cut_inside_its_last_number_is_refused() {
    let dir = TempDir::new("ply-cut");
    // As if "3 1 3 2\n" had lost its line end, or "3 1 3 21\n" its last digit and line end.
    let body = "0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 2";
    let cut = dir.write("cut.ply", format!("{ASCII_PLY_HEADER}{body}"));
    assert_refused(&cut, &[], &["line 15", "'2'", "cut"]);
    // The same file with a line end, or trailing blanks, after the last value imports.
    for tail in ["\n", "\r\n", " ", " \n\n"] {
        let path = dir.write("whole.ply", format!("{ASCII_PLY_HEADER}{body}{tail}"));
        assert_eq!(assert_imports(&path, &[])["faces"], 2, "{tail:?}");
    }
}

#[test]
fn ascii_ply_line_with_extra_values_names_the_line() {
    let dir = TempDir::new("ply-extra");
    let path = dir.write("extra.ply", format!("{ASCII_PLY_HEADER}0 0 0\n1 0 0 7\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 2\n"));
    assert_refused(&path, &[], &["line 11", "vertex 1", "3 properties", "4 values"]);
    let path = dir.write("extra_face.ply", format!("{ASCII_PLY_HEADER}0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2 3\n3 1 3 2\n"));
    assert_refused(&path, &[], &["line 14", "face 0", "1 property", "5 values"]);
    // A record cut short by its line end is named too, rather than read on into the next line.
    let path = dir.write("short.ply", format!("{ASCII_PLY_HEADER}0 0 0\n1 0\n0 0 1 0\n1 1 0\n3 0 1 2\n3 1 3 2\n"));
    assert_refused(&path, &[], &["line 11", "vertex 1"]);
}

#[test]
fn huge_coordinates_are_refused_at_import() {
    let dir = TempDir::new("huge");
    let obj = dir.write("huge.obj", "v 0 0 0\nv 1e38 0 0\nv 0 1e38 0\nf 1 2 3\n");
    assert_refused(&obj, &[], &["line 2", "1e38", "exceeds"]);
    let simplified = dir.0.join("simplified.obj");
    let (ok, _, stderr) = strata(&["simplify", obj.to_str().unwrap(), "--ratio", "0.5", "-o", simplified.to_str().unwrap()]);
    assert!(!ok && stderr.contains("line 2") && stderr.contains("exceeds"), "{stderr}");
    let out = dir.0.join("huge.strata");
    let (ok, _, stderr) = strata(&["convert", obj.to_str().unwrap(), out.to_str().unwrap(), "-q"]);
    assert!(!ok && stderr.contains("huge.obj") && stderr.contains("exceeds"), "{stderr}");

    let ply = dir.write("huge.ply", format!("{ASCII_PLY_HEADER}0 0 0\n1 0 0\n0 1 0\n-3e20 -3e20 0\n3 0 1 2\n3 1 3 2\n"));
    assert_refused(&ply, &[], &["vertex 3", "-3e20", "exceeds"]);

    let bin = f32_bytes(&[0., 0., 0., 2e19, 0., 0., 0., 2e19, 0.]);
    let doc = gltf(&data_uri(&bin), bin.len(), r#"[{"buffer":0,"byteLength":36}]"#, &format!(r#"[{{"bufferView":0,{POSITIONS}}}]"#));
    let gltf = dir.write("huge.gltf", doc);
    assert_refused(&gltf, &[], &["mesh 0 primitive 0", "vertex 1", "2e19", "exceeds"]);
}

#[test]
fn non_finite_normals_and_uvs_are_replaced_with_a_warning() {
    let dir = TempDir::new("nan-attributes");
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt nan 1\nvn 0 0 1\nvn nan 0 inf\nf 1/1/1 2/2/2 3/1/1\n";
    let summary = assert_imports(&dir.write("nan.obj", obj), &[]);
    let warnings = summary["warnings"].to_string();
    assert!(warnings.contains("1 corner normal") && warnings.contains("face"), "{warnings}");
    assert!(warnings.contains("1 corner UV") && warnings.contains("(0, 0)"), "{warnings}");
}

#[test]
fn huge_and_non_finite_uvs_and_normals_are_replaced_by_both_builds() {
    let dir = TempDir::new("huge-uvs");
    let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
               property float nx\nproperty float ny\nproperty float nz\nproperty float s\nproperty float t\n\
               element face 2\nproperty list uchar int vertex_indices\nend_header\n\
               0 0 0 0 0 1 0 0\n1 0 0 0 0 1 1e20 0\n1 1 0 nan 0 1 1 1\n0 1 0 0 0 1 0 -inf\n3 0 1 2\n3 0 2 3\n";
    let input = dir.write("huge.ply", ply);
    for build in ["--in-core", "--partitioned"] {
        let output = dir.0.join(format!("huge{build}.strata"));
        let (ok, _, stderr) = strata(&["convert", build, input.to_str().unwrap(), output.to_str().unwrap()]);
        assert!(ok, "{build}: {stderr}");
        assert!(stderr.contains("2 corner normals were NaN or infinite and got their face's normal"), "{build}: {stderr}");
        assert!(stderr.contains("2 corner UVs were NaN, infinite or at least 2^24 in magnitude and got UV (0, 0)"), "{build}: {stderr}");
        let (ok, _, stderr) = strata(&["verify", output.to_str().unwrap()]);
        assert!(ok, "{build}: {stderr}");
    }
}

#[test]
fn utf16_text_is_recognised() {
    let dir = TempDir::new("utf16");
    let utf16 = |text: &str, bom: bool, big: bool| -> Vec<u8> {
        let mut out = if !bom {
            vec![]
        } else if big {
            vec![0xfe, 0xff]
        } else {
            vec![0xff, 0xfe]
        };
        for unit in text.encode_utf16() {
            out.extend(if big { unit.to_be_bytes() } else { unit.to_le_bytes() });
        }
        out
    };
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    for (name, bom, big) in [("le.obj", true, false), ("be.obj", true, true), ("nobom.obj", false, false)] {
        assert_refused(&dir.write(name, utf16(obj, bom, big)), &[], &["UTF-16", "UTF-8"]);
    }
    let ply = format!("{ASCII_PLY_HEADER}0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 2\n");
    assert_refused(&dir.write("utf16.ply", utf16(&ply, true, false)), &[], &["UTF-16", "UTF-8"]);
    let bin = triangle_bytes();
    let doc = gltf(&data_uri(&bin), bin.len(), r#"[{"buffer":0,"byteLength":36}]"#, &format!(r#"[{{"bufferView":0,{POSITIONS}}}]"#));
    assert_refused(&dir.write("utf16.gltf", utf16(&doc, true, false)), &[], &["UTF-16", "UTF-8"]);
}

#[test]
fn empty_files_say_they_are_empty() {
    let dir = TempDir::new("empty");
    for name in ["empty.obj", "empty.ply", "empty.glb", "empty.gltf"] {
        let e = assert_refused(&dir.write(name, b""), &[], &["empty (0 bytes)"]);
        assert!(!e.contains("JSON"), "{e}");
    }
}

#[test]
fn obj_index_errors_count_in_proper_plurals() {
    let dir = TempDir::new("plural");
    let cases = [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "the file has 3 vertices"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n", "the file has 1 texture coordinate"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 1\nf 1//1 2//3 3//1\n", "the file has 2 normals"),
    ];
    for (text, expect) in cases {
        let e = assert_refused(&dir.write("index.obj", text), &[], &[]);
        assert!(e.trim_end().ends_with(expect), "{e}");
    }
}

/// A device named as a glTF buffer (allowed outside the folder) or as an OBJ material library is
/// not read: /dev/zero never ends.
#[cfg(unix)]
#[test]
fn devices_are_not_read_as_buffers_or_material_libraries() {
    let dir = std::env::temp_dir().join(format!("strata-devices-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/regressions");
    let gltf = root.join("gltf/buffer_uri_dev_zero.gltf");
    let out = Command::new(env!("CARGO_BIN_EXE_strata")).args(["info", gltf.to_str().unwrap(), "--allow-outside-files"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("/dev/zero") && err.contains("not a regular file"), "{err}");
    let obj = root.join("obj/mtllib_dev_zero.obj");
    let out = Command::new(env!("CARGO_BIN_EXE_strata")).args(["info", obj.to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && err.contains("material library"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
