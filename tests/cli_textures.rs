//! Textured models through the CLI (issue 16): the shipped textured globe and every textured glTF
//! sample of ../shared/meshes convert; the `.strata` file alone, copied to an empty folder, renders
//! textured (and close to the source model's own render); a missing image is a warning naming it
//! and the model still converts; OBJ map statements bring their images along.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use strata::texture::{decode, ImageCodec, Rgba8};

fn strata(args: &[&str]) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().expect("run strata");
    assert!(out.status.success(), "strata {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("strata-cli-tex-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn render(input: &Path, out: &Path, color: &str) -> Rgba8 {
    strata(&[
        "render",
        &input.display().to_string(),
        "-o",
        &out.display().to_string(),
        "--width",
        "256",
        "--height",
        "256",
        "--color",
        color,
    ]);
    decode(ImageCodec::Png, &std::fs::read(out).unwrap()).unwrap()
}

const BACKGROUND: [u8; 4] = strata::render::BACKGROUND;

/// Distinct colors among covered pixels, and the mean absolute difference per channel between two
/// images over the pixels both cover.
fn compare(a: &Rgba8, b: &Rgba8) -> (usize, f64) {
    let mut colors = std::collections::HashSet::new();
    let (mut diff, mut n) = (0u64, 0u64);
    for (p, q) in a.pixels.chunks_exact(4).zip(b.pixels.chunks_exact(4)) {
        if p != BACKGROUND {
            colors.insert([p[0], p[1], p[2]]);
        }
        if p != BACKGROUND && q != BACKGROUND {
            diff += (0..3).map(|k| (p[k] as i64 - q[k] as i64).unsigned_abs()).sum::<u64>();
            n += 3;
        }
    }
    (colors.len(), diff as f64 / n.max(1) as f64)
}

/// Convert `model`, copy the `.strata` file alone to an empty folder and render it there, textured
/// and plain; returns (distinct colors textured, mean difference textured vs plain, vs the source).
fn converts_and_renders_alone(model: &Path, name: &str) -> (usize, f64, f64) {
    let dir = temp_dir(name);
    let converted = dir.join("model.strata");
    strata(&["convert", "-q", &model.display().to_string(), &converted.display().to_string()]);
    strata(&["verify", &converted.display().to_string()]);
    let alone = temp_dir(&format!("{name}-alone"));
    let file = alone.join("model.strata");
    std::fs::copy(&converted, &file).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let textured = render(&file, &alone.join("textured.png"), "auto");
    let plain = render(&file, &alone.join("plain.png"), "plain");
    let source = render(model, &alone.join("source.png"), "auto");
    let (colors, vs_plain) = compare(&textured, &plain);
    let (_, vs_source) = compare(&textured, &source);
    std::fs::remove_dir_all(&alone).unwrap();
    (colors, vs_plain, vs_source)
}

#[test]
fn the_textured_globe_renders_textured_from_its_file_alone() {
    let globe = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/textured_globe.glb");
    let (colors, vs_plain, vs_source) = converts_and_renders_alone(&globe, "globe");
    assert!(colors > 200, "{colors} distinct colors: not textured");
    assert!(vs_plain > 20.0, "textured and plain renders differ by only {vs_plain:.1} per channel");
    assert!(vs_source < 6.0, "the file's render differs from the source's by {vs_source:.1} per channel");
}

#[test]
fn every_textured_gltf_sample_converts_and_renders_textured() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes/gltf");
    if !root.exists() {
        eprintln!("skipping: ../shared/meshes/gltf not found");
        return;
    }
    let mut samples = Vec::new();
    let mut stack = vec![root];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "gltf" || x == "glb") && !p.to_string_lossy().contains("Draco") {
                let text = String::from_utf8_lossy(&std::fs::read(&p).unwrap()).into_owned();
                if text.contains("\"images\"") && text.contains("baseColorTexture") {
                    samples.push(p);
                }
            }
        }
    }
    samples.sort();
    assert!(samples.len() >= 10, "{samples:?}");
    for (k, s) in samples.iter().enumerate() {
        let (colors, vs_plain, vs_source) = converts_and_renders_alone(s, &format!("sample{k}"));
        eprintln!("{}: {colors} colors, {vs_plain:.1} from plain, {vs_source:.1} from the source's render", s.display());
        assert!(colors > 8 && vs_plain > 1.0, "{}: not textured ({colors} colors, {vs_plain:.1} from plain)", s.display());
        assert!(vs_source < 12.0, "{}: {vs_source:.1} per channel from the source's render", s.display());
    }
}

#[test]
fn a_missing_image_is_a_warning_and_the_model_converts() {
    let dir = temp_dir("missing");
    let gltf = dir.join("m.gltf");
    // One triangle, UVs, a material whose base color texture is a file that is not there.
    let bin: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 1.].iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(dir.join("m.bin"), &bin).unwrap();
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "m.bin", "byteLength": 60}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 24}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}
        ],
        "images": [{"uri": "missing.png"}],
        "textures": [{"source": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}]}],
        "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0
    });
    std::fs::write(&gltf, serde_json::to_vec(&json).unwrap()).unwrap();
    let out = dir.join("m.strata");
    let run = strata(&["convert", "-q", &gltf.display().to_string(), &out.display().to_string()]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("warning") && stderr.contains("missing.png"), "{stderr}");
    strata(&["verify", &out.display().to_string()]);
    let inspected: serde_json::Value = serde_json::from_slice(&strata(&["inspect", "--json", &out.display().to_string()]).stdout).unwrap();
    assert_eq!(inspected["images"], serde_json::json!([]));
    assert_eq!(inspected["version"], strata::format::VERSION3, "format 3 by default");
    let v2 = dir.join("m2.strata");
    strata(&["convert", "-q", "--format-version", "2", &gltf.display().to_string(), &v2.display().to_string()]);
    let inspected: serde_json::Value = serde_json::from_slice(&strata(&["inspect", "--json", &v2.display().to_string()]).stdout).unwrap();
    assert_eq!(inspected["version"], "2.2", "UVs, so 2.2 even without images (one node: no planes)");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn obj_maps_bring_their_images_and_export_beside_the_obj() {
    let dir = temp_dir("obj");
    let globe = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/textured_globe.glb");
    // The globe as OBJ: its MTL and image land beside it.
    let obj = dir.join("globe.obj");
    strata(&["simplify", &globe.display().to_string(), "--ratio", "1", "-o", &obj.display().to_string()]);
    let mtl = std::fs::read_to_string(dir.join("globe.mtl")).unwrap();
    assert!(mtl.contains("map_Kd -clamp on globe_globe.png"), "{mtl}");
    assert!(dir.join("globe_globe.png").exists());
    // Converted from the OBJ, the image is the same file, and the render matches the GLB's.
    let strata_file = dir.join("globe.strata");
    strata(&["convert", "-q", &obj.display().to_string(), &strata_file.display().to_string()]);
    let inspected: serde_json::Value =
        serde_json::from_slice(&strata(&["inspect", "--json", &strata_file.display().to_string()]).stdout).unwrap();
    assert_eq!(inspected["images"].as_array().unwrap().len(), 1);
    assert_eq!(inspected["version"], strata::format::VERSION3);
    let from_obj = render(&strata_file, &dir.join("obj.png"), "auto");
    let from_glb = render(&globe, &dir.join("glb.png"), "auto");
    let (_, diff) = compare(&from_obj, &from_glb);
    assert!(diff < 6.0, "OBJ and GLB renders differ by {diff:.1} per channel: a UV flip gone wrong?");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn jpeg_images_keep_their_codec_through_every_level() {
    // The globe with its image as a JPEG, as photogrammetry delivers textures, through OBJ.
    let dir = temp_dir("jpeg");
    let mut mesh = strata::fixtures::textured_globe(48, 512);
    let pixels = decode(ImageCodec::Png, &mesh.images[0].bytes).unwrap();
    let jpeg = strata::texture::encode(ImageCodec::Jpeg, &pixels, 92).unwrap();
    mesh.images[0] = strata::texture::SourceImage::new("globe.jpg".into(), jpeg.clone()).unwrap();
    let obj = dir.join("globe.obj");
    strata::export::write(&obj, &mesh).unwrap();
    assert!(dir.join("globe_globe.jpg").exists());
    let file = dir.join("globe.strata");
    strata(&["convert", "-q", &obj.display().to_string(), &file.display().to_string()]);
    strata(&["verify", &file.display().to_string()]);
    let rd = strata::format::Reader::open_path(&file).unwrap();
    let t = rd.textures();
    assert_eq!(t.images[0].codec, ImageCodec::Jpeg);
    assert_eq!(rd.read_image_level(0, 0).unwrap(), jpeg, "level 0 is the source file");
    for l in 1..t.level_count(0) {
        let bytes = rd.read_image_level(0, l).unwrap();
        assert_eq!(strata::texture::sniff(&bytes), Some(ImageCodec::Jpeg), "level {l}");
        let im = decode(ImageCodec::Jpeg, &bytes).unwrap();
        let v = t.level(0, l).unwrap();
        assert_eq!((im.width, im.height), (v.width, v.height));
    }
    // Drawn like the PNG original, within JPEG's loss.
    let png_globe = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/textured_globe.glb");
    let a = render(&file, &dir.join("jpeg.png"), "auto");
    let b = render(&png_globe, &dir.join("png.png"), "auto");
    let (colors, diff) = compare(&a, &b);
    assert!(colors > 200 && diff < 8.0, "{colors} colors, {diff:.1} per channel from the PNG globe");
    std::fs::remove_dir_all(&dir).unwrap();
}
