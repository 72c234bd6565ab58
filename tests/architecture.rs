//! What each part of the code may touch, checked on the source text: the format layer depends on
//! nothing of the build, and the library on none of the command line's crates.

use std::path::{Path, PathBuf};

fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// Lines of `file` that are code (not comments), numbered from 1.
fn code_lines(file: &Path) -> Vec<(usize, String)> {
    let text = std::fs::read_to_string(file).unwrap();
    text.lines().enumerate().filter(|(_, l)| !l.trim_start().starts_with("//")).map(|(i, l)| (i + 1, l.to_string())).collect()
}

#[test]
fn the_format_layer_depends_on_nothing_of_the_build() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut found = Vec::new();
    for file in rust_files(&src.join("format")) {
        for (n, line) in code_lines(&file) {
            let mut rest = line.as_str();
            while let Some(at) = rest.find("crate::") {
                let path = &rest[at + 7..];
                if !(path.starts_with("error") || path.starts_with("format")) {
                    found.push(format!("{}:{n}: {}", file.display(), line.trim()));
                }
                rest = &rest[at + 7..];
            }
        }
    }
    assert!(found.is_empty(), "src/format may use crate::error and itself only:\n{}", found.join("\n"));
}

#[test]
fn the_library_compiles_without_the_command_line_crates() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut found = Vec::new();
    for file in rust_files(&src) {
        if file.ends_with("main.rs") || file.starts_with(src.join("cli")) {
            continue;
        }
        for (n, line) in code_lines(&file) {
            let gated = line.contains("cfg_attr(feature = \"cli\"");
            if !gated && ["clap::", "indicatif::", "ctrlc::", "anyhow::"].iter().any(|c| line.contains(c)) {
                found.push(format!("{}:{n}: {}", file.display(), line.trim()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "only the command line (src/main.rs, src/cli/) uses clap, indicatif, ctrlc and anyhow:\n{}",
        found.join("\n")
    );
}

#[test]
fn every_subcommand_is_a_module_of_its_own() {
    let cli = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/cli");
    let text = std::fs::read_to_string(cli.join("mod.rs")).unwrap();
    let commands: Vec<&str> = text.lines().filter_map(|l| l.trim().strip_prefix("Command::")?.split('(').next()).collect();
    assert!(commands.len() >= 9, "{commands:?}");
    for c in commands {
        assert!(cli.join(format!("{}.rs", c.to_lowercase())).exists(), "subcommand {c} has no src/cli/{}.rs", c.to_lowercase());
    }
    let main = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/main.rs")).unwrap();
    assert!(main.lines().count() < 60, "src/main.rs stays thin");
}
