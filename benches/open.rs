//! Laziness of opening a chunk file: bytes read and resident memory added by `Reader::open_path`,
//! which reads the header and skeleton only.
//!
//! `cargo bench --bench open -- file.strata ...`; without arguments it converts the large mesh in
//! ../shared/meshes (when present) to a temporary file first.

use std::path::{Path, PathBuf};
use strata::format::Reader;

/// Resident set size of this process in bytes, from /proc (Linux); 0 elsewhere.
fn rss() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("VmRSS:")).and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok()))
        .map_or(0, |kb| kb * 1024)
}

fn main() {
    let mut files: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if files.is_empty() {
        let large = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes/large/cthead_skin_native.ply");
        if !large.exists() {
            println!("skipping: ../shared/meshes not found; pass .strata files as arguments");
            return;
        }
        let out = std::env::temp_dir().join(format!("strata-open-bench-{}.strata", std::process::id()));
        let opts = strata::pipeline::ConvertOptions::default();
        strata::pipeline::convert(&large, &Default::default(), &out, &opts, &mut strata::pipeline::Silent).expect("convert");
        files.push(out);
    }
    println!("{:<40} {:>12} {:>12} {:>8} {:>12} {:>9}", "file", "file bytes", "bytes read", "share", "RSS added", "open ms");
    for f in files {
        let size = std::fs::metadata(&f).map(|m| m.len()).unwrap_or(0);
        let before = rss();
        let start = std::time::Instant::now();
        let reader = match Reader::open_path(&f) {
            Ok(r) => r,
            Err(e) => {
                println!("skipping {}: {e}", f.display());
                continue;
            }
        };
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let added = rss().saturating_sub(before);
        println!(
            "{:<40} {:>12} {:>12} {:>7.2}% {:>12} {:>9.2}",
            f.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
            size,
            reader.bytes_read(),
            100.0 * reader.bytes_read() as f64 / size.max(1) as f64,
            added,
            ms
        );
    }
}
