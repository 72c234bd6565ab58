//! Elevation grids through the command line: each DEM in ../shared/meshes/dem (when present)
//! imports with the size and height range CATALOG.md lists and its georeference, converts,
//! verifies and renders as terrain; bad grids get errors that name the file and what is wrong,
//! and leave no output.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const DEM: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/meshes/dem");

fn strata(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strata")).args(args).output().expect("run strata")
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("strata-dem-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The DEM rows of CATALOG.md: file → (cols, rows, lowest, highest).
fn catalog() -> Vec<(String, usize, usize, f64, f64)> {
    let text = std::fs::read_to_string(Path::new(DEM).join("../CATALOG.md")).expect("CATALOG.md");
    text.lines()
        .filter_map(|line| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let file = cells.get(1)?.strip_prefix("`dem/")?.strip_suffix('`')?;
            let (cols, rows) = cells.get(4)?.split_once('x')?;
            let (lo, hi) = cells.get(5)?.split_once("..")?;
            Some((file.to_string(), cols.parse().ok()?, rows.parse().ok()?, lo.trim().parse().ok()?, hi.trim().parse().ok()?))
        })
        .collect()
}

/// What each shared grid needs on the command line, and where its georeference puts it:
/// (frame, longitude and latitude of the centre, or none; voids).
fn expected(file: &str) -> (Vec<&'static str>, &'static str, Option<(f64, f64)>, u64) {
    match file {
        // The .asc header's corner plus half its 758 cells of 0.000833333333°.
        "landlab_SRTMGL3_boulder_758x758.asc" | "derived_boulder_758x758_u16.png" => {
            (vec![], "local_tangent", Some((-105.816250000017 + 379.0 * 0.000833333333, 39.834583333338 + 379.0 * 0.000833333333)), 0)
        }
        "martini_fuji_terrainrgb.png" => (vec!["--dem-encoding", "terrain-rgb", "--dem-cell-size", "30"], "unplaced", None, 0),
        "pysheds_dem.tif" => (vec![], "local_tangent", Some((-97.33, 32.67)), 0),
        // N40W074: the tile's centre; its 1051 voids.
        "riptide_N40W074.hgt" => (vec![], "local_tangent", Some((-73.5, 40.5)), 1051),
        other => panic!("no expectations for {other}"),
    }
}

#[test]
fn shared_grids_import_convert_verify_and_render_as_terrain() {
    if !Path::new(DEM).is_dir() {
        println!("skipped: {DEM} is absent (the shared test meshes are not on this machine)");
        return;
    }
    let rows = catalog();
    assert_eq!(rows.len(), 5, "CATALOG.md lists five grids");
    let dir = temp_dir("shared");
    for (file, cols, nrows, lo, hi) in rows {
        let path = Path::new(DEM).join(&file).display().to_string();
        let (extra, frame, centre, voids) = expected(&file);
        let with = |args: &[&str]| -> Vec<String> { args.iter().chain(&extra).map(|s| s.to_string()).collect() };

        let args = with(&["info", "--json", &path]);
        let o = strata(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(o.status.success(), "{file}: {}", String::from_utf8_lossy(&o.stderr));
        let info: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let g = &info["grid"];
        assert_eq!((g["cols"].as_u64(), g["rows"].as_u64()), (Some(cols as u64), Some(nrows as u64)), "{file}");
        assert_eq!(g["voids"].as_u64(), Some(voids), "{file}");
        assert_eq!(info["vertices"].as_u64(), Some((cols * nrows) as u64 - voids), "{file}: one vertex per sample with data");
        let (min_h, max_h) = (g["min_height"].as_f64().unwrap(), g["max_height"].as_f64().unwrap());
        assert!((min_h - lo).abs() < 0.05 && (max_h - hi).abs() < 0.05, "{file}: heights {min_h}..{max_h}, catalog {lo}..{hi}");
        let georef = &info["georef"];
        assert_eq!(georef["frame"], frame, "{file}");
        if let Some((lon, lat)) = centre {
            let o = &georef["origin"];
            assert!((o[0].as_f64().unwrap() - lon).abs() < 0.01 && (o[1].as_f64().unwrap() - lat).abs() < 0.01, "{file}: origin {o}");
        }
        // No spikes: nothing stands above the highest sample, nor below the lowest by more than
        // the Earth's curvature across the model (d²/2R at its corners).
        let b = |k: &str, i: usize| info["bounds"][k][i].as_f64().unwrap();
        let (ymin, ymax) = (b("min", 1), b("max", 1));
        let corner = b("min", 0).abs().max(b("max", 0).abs()).hypot(b("min", 2).abs().max(b("max", 2).abs()));
        let drop = corner * corner / (2.0 * 6.35e6) + 0.01;
        assert!(ymax <= hi + 0.01 && ymin >= lo - drop, "{file}: y {ymin}..{ymax}, curvature {drop:.1} m");

        let out = dir.join(format!("{file}.strata"));
        let args = with(&["convert", "-q", &path, out.to_str().unwrap()]);
        let o = strata(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(o.status.success(), "{file}: {}", String::from_utf8_lossy(&o.stderr));
        let o = strata(&["verify", out.to_str().unwrap()]);
        assert!(o.status.success(), "{file}: {}", String::from_utf8_lossy(&o.stdout));
        let o = strata(&["inspect", "--json", out.to_str().unwrap()]);
        let ins: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(ins["version"], strata::format::VERSION3, "{file}: strata convert writes format 3 by default");
        assert_eq!(ins["georef"], *georef, "{file}: the file keeps the georeference");
        let png = dir.join(format!("{file}.png"));
        let o = strata(&["render", out.to_str().unwrap(), "-o", png.to_str().unwrap(), "--width", "128", "--height", "128"]);
        assert!(o.status.success(), "{file}: {}", String::from_utf8_lossy(&o.stderr));
        let covered = covered_fraction(&png);
        assert!(covered > 0.3, "{file}: the default terrain view shows the surface ({covered:.2} of the picture)");
    }
}

/// Share of a rendered picture's pixels that are not the background colour.
fn covered_fraction(png: &Path) -> f64 {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(png).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let px: Vec<&[u8]> = buf[..info.buffer_size()].chunks(info.color_type.samples()).collect();
    let background = px[0];
    px.iter().filter(|p| **p != background).count() as f64 / px.len() as f64
}

/// Run `convert` on a bad grid: it fails naming the file and `words`, and writes nothing.
fn refused(dir: &Path, input: &Path, extra: &[&str], words: &[&str]) {
    let out = dir.join("out.strata");
    let mut args = vec!["convert", "-q", input.to_str().unwrap(), out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let o = strata(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{}: accepted", input.display());
    assert!(err.contains(input.file_name().unwrap().to_str().unwrap()), "{err}");
    for w in words {
        assert!(err.contains(w), "expected {w:?} in: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    assert!(std::fs::read_dir(dir).unwrap().all(|e| e.unwrap().path() != out), "no output");
}

#[test]
fn bad_grids_get_clear_errors() {
    let dir = temp_dir("bad");
    // A .hgt cut short: not 2·n² bytes.
    let hgt = dir.join("N40W074.hgt");
    std::fs::write(&hgt, vec![0u8; 2 * 1201 * 1201 - 2]).unwrap();
    refused(&dir, &hgt, &[], &["2884800 bytes is not a tile", "truncated"]);

    // An ASCII grid whose header promises more rows than it holds, and one with more values.
    let asc = dir.join("short.asc");
    std::fs::write(&asc, "ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 10\n1 2 3\n4 5 6\n").unwrap();
    refused(&dir, &asc, &[], &["line 7", "the data ends at value 1 of row 3", "wrong about the size"]);
    let asc = dir.join("long.asc");
    std::fs::write(&asc, "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 10\n1 2\n3 4\n5 6\n").unwrap();
    refused(&dir, &asc, &[], &["line 8", "\"5\" follows the header's 2 rows of 2 values"]);

    // A GeoTIFF of complex samples.
    let tif = dir.join("complex.tif");
    {
        use tiff::encoder::{colortype, TiffEncoder};
        let mut enc = TiffEncoder::new(std::fs::File::create(&tif).unwrap()).unwrap();
        enc.write_image::<colortype::Gray32Float>(2, 2, &[1.0, 2.0, 3.0, 4.0]).unwrap();
    }
    let mut bytes = std::fs::read(&tif).unwrap();
    let at = bytes.windows(10).position(|w| w == [0x53, 0x01, 3, 0, 1, 0, 0, 0, 3, 0]).expect("SampleFormat = float");
    bytes[at + 8] = 6;
    std::fs::write(&tif, bytes).unwrap();
    refused(&dir, &tif, &[], &["complex floating-point samples (SampleFormat 6) are not supported"]);

    // A PNG of 8-bit grey, and one in colour without --dem-encoding.
    let write_png = |name: &str, color: png::ColorType, data: &[u8]| {
        let p = dir.join(name);
        let mut enc = png::Encoder::new(std::fs::File::create(&p).unwrap(), 2, 2);
        enc.set_color(color);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header().unwrap().write_image_data(data).unwrap();
        p
    };
    let grey8 = write_png("grey8.png", png::ColorType::Grayscale, &[1, 2, 3, 4]);
    refused(&dir, &grey8, &[], &["Grayscale PNG of 8 bits", "16-bit greyscale"]);
    let rgb = write_png("rgb.png", png::ColorType::Rgb, &[0; 12]);
    refused(&dir, &rgb, &[], &["--dem-encoding terrain-rgb"]);
    // --z-scale must be positive.
    let o = strata(&["convert", "-q", asc.to_str().unwrap(), dir.join("z.strata").to_str().unwrap(), "--z-scale", "0"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--z-scale must be a positive number"));
}

#[test]
fn a_small_grid_streams_with_a_terrain_view() {
    let dir = temp_dir("stream");
    let asc = dir.join("hill.asc");
    let mut text = String::from("ncols 40\nnrows 30\nxllcorner 500000\nyllcorner 4000000\ncellsize 25\nNODATA_value -9999\n");
    for i in 0..30 {
        let row: Vec<String> = (0..40)
            .map(|j| {
                if (i, j) == (10, 10) {
                    "-9999".into()
                } else {
                    format!("{:.1}", 300.0 + 80.0 * (-(((i - 15) * (i - 15) + (j - 20) * (j - 20)) as f64) / 120.0).exp())
                }
            })
            .collect();
        text += &(row.join(" ") + "\n");
    }
    std::fs::write(&asc, text).unwrap();
    let out = dir.join("hill.strata");
    let o = strata(&["convert", "-q", asc.to_str().unwrap(), out.to_str().unwrap(), "--leaf-faces", "128"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("metres of a projected CRS"), "the guess is said");
    for session in [&["--orbit", "8"][..], &["--flyover", "8"][..]] {
        let mut args = vec!["stream", out.to_str().unwrap(), "--json", "--width", "160", "--height", "120"];
        args.extend_from_slice(session);
        let o = strata(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let frames: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        assert_eq!(frames.len(), 8);
        assert!(frames.iter().all(|f| f["faces"].as_u64().unwrap() > 0), "{session:?}: every frame sees terrain");
    }
}
