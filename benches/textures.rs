//! Textured models streamed (issue 16): for each textured model, the share of the file its images
//! take, the image bytes a viewer reads before its first textured frame against the coarsest levels
//! of the images that frame uses (the goal: no more), and the image bytes read per frame along an
//! orbit moving in from far, all against the peer in the same run: a plain glTF viewer, which reads
//! every image whole before its first textured frame (the source files' image bytes).
//!
//! `cargo bench --bench textures [-- model ...]`; without arguments the shipped textured globe and
//! FlightHelmet and every textured sample of ../shared/meshes/gltf when present.

use std::path::{Path, PathBuf};
use strata::format::Reader;
use strata::pipeline::{convert, ConvertOptions, Silent};
use strata::stream::{session, Budgets, Streamer};

fn models() -> Vec<PathBuf> {
    let args: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if !args.is_empty() {
        return args;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = vec![root.join("fixtures/textured_globe.glb")];
    let shared = root.join("../shared/meshes/gltf");
    for m in ["bevy_FlightHelmet/FlightHelmet.gltf", "khronos/CesiumMilkTruck/glTF/CesiumMilkTruck.gltf", "khronos/Duck/glTF/Duck.gltf"] {
        if shared.join(m).exists() {
            out.push(shared.join(m));
        }
    }
    if out.len() == 1 {
        println!("skipping the shared models: ../shared/meshes/gltf not found");
    }
    out
}

fn main() {
    println!(
        "{:<22} {:>9} {:>7} {:>12} {:>12} {:>9} {:>12} {:>8} {:>12} {:>12}",
        "model", "file KB", "images", "1st frame B", "coarsest B", "ratio", "glTF imgs B", "vs glTF", "per frame B", "resident KB"
    );
    for model in models() {
        let name = model.file_stem().unwrap().to_string_lossy().into_owned();
        let out = std::env::temp_dir().join(format!("strata-textures-{name}-{}.strata", std::process::id()));
        let c = convert(&model, &Default::default(), &out, &ConvertOptions::default(), &mut Silent).expect("convert");
        let s = &c.summary;
        let rd = Reader::open_path(&out).expect("open");
        let t = rd.textures().clone();
        if t.is_empty() {
            println!("{name}: no images");
            continue;
        }
        // The peer: the images as the source holds them, all read before a first textured frame.
        let source: u64 = t.images.iter().enumerate().map(|(i, _)| t.level(i as u32, 0).map_or(0, |l| l.size as u64 - 20)).sum();
        let (min, max) = (rd.header().min, rd.header().max);
        let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
        let mut streamer = Streamer::new(rd, Budgets::default()).expect("streamer");
        let n = 64;
        let mut per_frame = Vec::new();
        let (mut first, mut coarsest, mut resident_max, mut last) = (0, 0, 0, 0);
        for i in 0..n {
            let camera = session::orbit(center, radius, i, n, 1280, 720);
            let r = streamer.update(&camera, None).expect("frame");
            let read = r.stats.texture_bytes_read;
            if i == 0 {
                first = read;
                coarsest = r
                    .stats
                    .texture_levels
                    .iter()
                    .map(|&[image, ..]| t.level(image, t.level_count(image) - 1).map_or(0, |l| l.size as u64 - 20))
                    .sum();
            }
            per_frame.push(read - last);
            last = read;
            resident_max = resident_max.max(r.stats.texture_resident_bytes);
        }
        let mean = per_frame.iter().sum::<u64>() as f64 / n as f64;
        println!(
            "{:<22} {:>9.0} {:>6.1}% {:>12} {:>12} {:>9.2} {:>12} {:>8.3} {:>12.0} {:>12.0}",
            name,
            s.file_bytes as f64 / 1024.0,
            100.0 * s.image_bytes as f64 / s.file_bytes as f64,
            first,
            coarsest,
            first as f64 / coarsest.max(1) as f64,
            source,
            first as f64 / source.max(1) as f64,
            mean,
            resident_max as f64 / 1024.0
        );
        let _ = std::fs::remove_file(&out);
    }
    println!("1st frame B: image file bytes read before the first frame; coarsest B: the coarsest levels of the images it uses;");
    println!("glTF imgs B: what a glTF viewer reads first (every image whole); per frame B: mean image bytes read per frame over");
    println!("a 64-frame orbit at 1280x720 moving in from far; resident KB: most image levels held as RGBA8.");
}
