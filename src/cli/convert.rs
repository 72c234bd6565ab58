//! `strata convert`: import, group, simplify per level and write the chunk file, with progress
//! bars on a terminal and a summary (text or JSON).

use super::{GroupingArgs, LevelArgs, MeshInput};
use anyhow::Result;
use clap::ValueEnum;
use std::path::PathBuf;
use strata::pipeline::{Build, Normals};
use strata::write::{Encoding, Precision};

/// A size in bytes: a number with an optional K, M, G or T (powers of 1024, an optional trailing
/// `B` or `iB`).
fn parse_size(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let t = t.strip_suffix("iB").or_else(|| t.strip_suffix('B')).unwrap_or(t);
    let (digits, shift) = match t.chars().last().map(|c| c.to_ascii_uppercase()) {
        Some('K') => (&t[..t.len() - 1], 10),
        Some('M') => (&t[..t.len() - 1], 20),
        Some('G') => (&t[..t.len() - 1], 30),
        Some('T') => (&t[..t.len() - 1], 40),
        _ => (t, 0),
    };
    let n: f64 = digits.trim().parse().map_err(|_| format!("'{s}' is not a size (like 512M or 2G)"))?;
    if !(n.is_finite() && n > 0.0) {
        return Err(format!("'{s}' is not a positive size"));
    }
    Ok((n * (1u64 << shift) as f64) as u64)
}

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub input: MeshInput,
    /// The .strata file to write (written to a temporary name, renamed when complete).
    pub output: PathBuf,
    #[command(flatten)]
    pub grouping: GroupingArgs,
    #[command(flatten)]
    pub levels: LevelArgs,
    /// Normals to store: the input's, else each level's own smooth ones, sharp at --crease-angle
    /// (auto); only the input's (input); none, for the smallest file drawn flat-shaded (none);
    /// each level's own smooth ones even where the input has normals (geometry). A level's own
    /// normals are stored as readers predict them, almost for free.
    #[arg(long, value_enum, default_value_t = NormalsArg::Auto)]
    pub normals: NormalsArg,
    /// Edges whose faces' normals differ by more than this many degrees stay sharp in computed normals.
    #[arg(long, default_value_t = 60.0)]
    pub crease_angle: f32,
    /// Memory to stay within (bytes, or with K, M, G: 512M, 1G): a PLY or OBJ file whose in-core build
    /// would need more is built partitioned, in cells on disk (as is one of 1M faces or more, where
    /// that is faster). Default: half of this machine's.
    #[arg(long, value_parser = parse_size)]
    pub memory: Option<u64>,
    /// Folder for the partitioned build's cell files (default: the system's temporary folder).
    #[arg(long)]
    pub temp: Option<PathBuf>,
    /// Build partitioned (PLY or OBJ input) whatever its size.
    #[arg(long, conflicts_with = "in_core")]
    pub partitioned: bool,
    /// Build in memory whatever the input's size.
    #[arg(long)]
    pub in_core: bool,
    /// Build a DAG of nodes and write format 4 (format-spec/strata-v4.md): displayed nodes meet
    /// edge for edge at any level difference, in memory or partitioned; every strata reader and
    /// the web viewer read it.
    #[arg(long, conflicts_with = "format_version")]
    pub dag: bool,
    /// Format version to write: 3 compresses node geometry (positions quantized as --grid-bits,
    /// --lattice and --normal-bits say); 2 stores fixed-width arrays on a 20-bit grid.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(2..=3))]
    pub format_version: u16,
    /// Format 3: bits of the position grid over the model's largest side (level 0's precision),
    /// 1..=21; 0 picks them from the mesh (a step of at most a 64th of its median edge).
    #[arg(long, default_value_t = 0)]
    pub grid_bits: u32,
    /// Format 3: vertices inside a coarser level's node lie on a lattice of at most this fraction
    /// of its geometric error or of its median edge, whichever is smaller (0 keeps them on the grid).
    #[arg(long, default_value_t = 0.25)]
    pub lattice: f32,
    /// Format 3: bits of each octahedral normal coordinate, 2..=16.
    #[arg(long, default_value_t = 8)]
    pub normal_bits: u32,
    /// Format 3: bits of each colour channel, 1..=8 (8 keeps colours exactly).
    #[arg(long, default_value_t = 8)]
    pub color_bits: u32,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
    /// Print the summary as one JSON object.
    #[arg(long)]
    pub json: bool,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
pub enum NormalsArg {
    Auto,
    Input,
    None,
    Geometry,
}

pub fn run(a: Args) -> Result<()> {
    let opts = strata::pipeline::ConvertOptions {
        hierarchy: a.grouping.params(a.levels.level_ratio),
        levels: a.levels.params(),
        normals: match a.normals {
            NormalsArg::Auto => Normals::Auto { crease_angle: a.crease_angle.to_radians() },
            NormalsArg::Input => Normals::Input,
            NormalsArg::None => Normals::None,
            NormalsArg::Geometry => Normals::Geometry { crease_angle: a.crease_angle.to_radians() },
        },
        build: if a.partitioned {
            Build::Partitioned
        } else if a.in_core {
            Build::InCore
        } else {
            Build::Auto
        },
        memory: a.memory.unwrap_or(0),
        temp: a.temp.clone(),
        dag: a.dag,
        encoding: match a.format_version {
            3 => Encoding::V3(Precision {
                grid_bits: a.grid_bits,
                lattice: a.lattice,
                normal_bits: a.normal_bits,
                color_bits: a.color_bits,
                ..Precision::default()
            }),
            _ => Encoding::V2,
        },
    };
    let mut bars = Bars::new(a.quiet || a.json);
    let c = strata::pipeline::convert(&a.input.mesh, &a.input.options()?, &a.output, &opts, &mut bars)?;
    drop(bars);
    for w in &c.warnings {
        eprintln!("warning: {}: {w}", a.input.mesh.display());
    }
    let s = &c.summary;
    if a.json {
        println!("{}", serde_json::json!({ "summary": s, "times": c.times, "cells": c.cells, "bytes_per_face": s.bytes_per_face() }));
        return Ok(());
    }
    println!("wrote {} ({} bytes, {:.1} bytes per input face)", a.output.display(), s.file_bytes, s.bytes_per_face());
    println!(
        "{} input faces, {} levels, {} nodes, {} clusters, skeleton {} bytes",
        s.input_faces,
        s.levels.len(),
        s.nodes,
        s.clusters,
        s.skeleton_bytes
    );
    println!("{:>6} {:>7} {:>9} {:>11}", "level", "nodes", "faces", "bytes");
    for l in s.levels.iter().rev() {
        println!("{:>6} {:>7} {:>9} {:>11}", l.level, l.nodes, l.faces, l.bytes);
    }
    if s.image_bytes > 0 {
        println!(
            "images: {} bytes in their levels, {:.1} % of the file",
            s.image_bytes,
            100.0 * s.image_bytes as f64 / s.file_bytes.max(1) as f64
        );
    }
    if let Some(cells) = c.cells {
        println!("built partitioned in {cells} cell{}", if cells == 1 { "" } else { "s" });
    }
    let t = c.times;
    println!(
        "time: import {:.0} ms, textures {:.0} ms, group {:.0} ms, simplify {:.0} ms, write {:.0} ms, total {:.0} ms",
        t.import_ms,
        t.texture_ms,
        t.group_ms,
        t.simplify_ms,
        t.write_ms,
        t.import_ms + t.texture_ms + t.group_ms + t.simplify_ms + t.write_ms
    );
    Ok(())
}

/// Progress bars on a terminal, one per stage; nothing when quiet or piped.
struct Bars {
    visible: bool,
    bar: Option<indicatif::ProgressBar>,
}

impl Bars {
    fn new(quiet: bool) -> Bars {
        use std::io::IsTerminal;
        Bars { visible: !quiet && std::io::stderr().is_terminal(), bar: None }
    }
}

impl strata::pipeline::Progress for Bars {
    fn stage(&mut self, name: &str, steps: u64) {
        if let Some(bar) = self.bar.take() {
            bar.finish();
        }
        if !self.visible {
            return;
        }
        let bar = if steps > 0 {
            let b = indicatif::ProgressBar::new(steps);
            b.set_style(
                indicatif::ProgressStyle::with_template("{prefix:>9} [{bar:30}] {pos}/{len} {elapsed}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        } else {
            let b = indicatif::ProgressBar::new_spinner();
            b.set_style(
                indicatif::ProgressStyle::with_template("{prefix:>9} {spinner} {elapsed}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
            );
            b.enable_steady_tick(std::time::Duration::from_millis(100));
            b
        };
        bar.set_prefix(name.to_string());
        self.bar = Some(bar);
    }

    fn step(&mut self) {
        if let Some(bar) = &self.bar {
            bar.inc(1);
        }
    }
}

impl Drop for Bars {
    fn drop(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish();
        }
    }
}
