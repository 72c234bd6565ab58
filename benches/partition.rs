//! The partitioned build against the in-core build, as trees and as DAGs (`--dag`, format 4),
//! side by side in one run (issue 14): wall time
//! and peak memory of `strata convert` (a child process under `/usr/bin/time`), throughput, each
//! level's sampled distance to the input, the culling cost measured on the file, node sizes
//! (largest node of any level over level 0's median), the top level's faces, the time from
//! opening the file to its first frame (`strata stream`) and the shape retention of fronts under
//! 10 % and 25 % of the input's faces (8 views at 512², the stream bench's measure), also over
//! three layouts (below), whose spread the one layout's figure is read against; then each
//! partitioned build's distance over its in-core build's (tree and DAG), level by level: at the
//! default layout, then over three layouts (`--leaf-faces` a sixteenth below, at and above its
//! default; each level's distances in a geometric mean), with the in-core build's own spread
//! between layouts. On the CT head the coarse levels' distances move by more than the goal's 1.2
//! from one layout to the next (a few long thin components leave at one level or another), so
//! one layout's ratio there says little of the partition.
//!
//! `cargo bench --bench partition [-- --large FACES ...] [-- --memory 1G]`; without arguments the
//! bunny and the CT head of ../shared/meshes (partitioned at budgets that make them several
//! cells) and the shipped noisy sphere. `--large N` also generates an N-face binary PLY (fixtures'
//! `write_bumpy_sphere_ply`) and converts it partitioned within `--memory` (in-core too when it
//! would fit this machine; quality is compared there only, the input being imported whole).

use std::path::{Path, PathBuf};
use std::process::Command;
use strata::cone::{facing_orthographic, Facing};
use strata::format::{Reader, NO_PARENT};

#[path = "common/retention_views.rs"]
mod retention_views;

struct Run {
    seconds: f64,
    peak_kb: Option<u64>,
}

fn convert(input: &Path, output: &Path, args: &[&str]) -> Run {
    let exe = env!("CARGO_BIN_EXE_strata");
    let timed = Path::new("/usr/bin/time").exists();
    let mut cmd = if timed {
        let mut c = Command::new("/usr/bin/time");
        c.args(["-f", "%e %M", exe]);
        c
    } else {
        Command::new(exe)
    };
    cmd.args(["convert", "-q"]).arg(input).arg(output).args(args);
    let start = std::time::Instant::now();
    let out = cmd.output().expect("run strata convert");
    let seconds = start.elapsed().as_secs_f64();
    assert!(out.status.success(), "strata convert {}: {}", input.display(), String::from_utf8_lossy(&out.stderr));
    let peak_kb = timed
        .then(|| String::from_utf8_lossy(&out.stderr).lines().last().and_then(|l| l.split_whitespace().nth(1)?.parse().ok()))
        .flatten();
    Run { seconds, peak_kb }
}

/// The paper's culling cost on the file, over `views` orthographic directions: cone tests made
/// walking the nodes from the top (and level 0's clusters) plus faces not culled, per face. In a
/// DAG the walk goes by groups, whose region is their outputs' and their children's alike: a group
/// whose outputs all face away culls everything below it; one whose outputs do not all face the
/// same way is opened, its children's source groups walked in turn.
fn culling_cost(rd: &Reader<std::fs::File>, views: usize) -> f64 {
    let nodes = rd.nodes();
    let clusters: Vec<Vec<(strata::format::Cone, u32)>> = (0..nodes.len() as u32)
        .map(|n| {
            if nodes[n as usize].level == 0 {
                rd.read_node(n).expect("node").clusters.iter().map(|c| (c.cone, c.face_count)).collect()
            } else {
                Vec::new()
            }
        })
        .collect();
    let faces = rd.levels()[0].faces as f64;
    let top = rd.levels().len() as u32 - 1;
    // Level-0 faces below a node (tree) or group (DAG), each level-0 node counted once.
    let region = |start: Vec<u32>, dag: bool, seen: &mut Vec<bool>| -> u64 {
        let mut stack = start;
        let mut f = 0;
        while let Some(m) = stack.pop() {
            if dag {
                let d = rd.dag().expect("a DAG");
                for &c in d.children(m) {
                    match d.source[c as usize] {
                        NO_PARENT if !std::mem::replace(&mut seen[c as usize], true) => f += nodes[c as usize].faces as u64,
                        NO_PARENT => {}
                        s => stack.push(s),
                    }
                }
            } else if nodes[m as usize].level == 0 {
                f += nodes[m as usize].faces as u64;
            } else {
                stack.extend(rd.children(m));
            }
        }
        f
    };
    let mut outputs: Vec<Vec<u32>> = vec![Vec::new(); rd.dag().map_or(0, |d| d.groups.len())];
    if let Some(dag) = rd.dag() {
        for (n, &s) in dag.source.iter().enumerate().filter(|(_, &s)| s != NO_PARENT) {
            outputs[s as usize].push(n as u32);
        }
    }
    let mut total = 0.0;
    for d in strata::culling::sphere_directions(views) {
        let (mut tests, mut culled) = (0u64, 0u64);
        let facing = |n: u32| facing_orthographic(&nodes[n as usize].cone, d);
        // A level-0 node: culled whole, or tested cluster by cluster.
        let leaf = |n: u32, tests: &mut u64, culled: &mut u64| match facing(n) {
            Facing::Back => *culled += nodes[n as usize].faces as u64,
            Facing::Front => {}
            Facing::Mixed => {
                for &(cone, count) in &clusters[n as usize] {
                    *tests += 1;
                    if facing_orthographic(&cone, d) == Facing::Back {
                        *culled += count as u64;
                    }
                }
            }
        };
        match rd.dag() {
            Some(dag) if top > 0 => {
                let mut seen = vec![false; nodes.len()];
                let mut opened = vec![false; dag.groups.len()];
                let mut stack: Vec<u32> = rd.level_nodes(top).map(|n| dag.source[n as usize]).collect();
                while let Some(g) = stack.pop() {
                    if std::mem::replace(&mut opened[g as usize], true) {
                        continue;
                    }
                    let outputs = &outputs[g as usize];
                    tests += outputs.len() as u64;
                    let sides: Vec<Facing> = outputs.iter().map(|&n| facing(n)).collect();
                    if sides.iter().all(|f| *f == Facing::Back) {
                        culled += region(vec![g], true, &mut seen);
                    } else if !sides.iter().all(|f| *f == Facing::Front) {
                        for &c in dag.children(g) {
                            match dag.source[c as usize] {
                                NO_PARENT if !std::mem::replace(&mut seen[c as usize], true) => {
                                    tests += 1;
                                    leaf(c, &mut tests, &mut culled);
                                }
                                NO_PARENT => {}
                                s => stack.push(s),
                            }
                        }
                    }
                }
            }
            _ => {
                let mut stack: Vec<u32> = rd.level_nodes(top).collect();
                while let Some(n) = stack.pop() {
                    tests += 1;
                    match facing(n) {
                        Facing::Back => culled += region(vec![n], false, &mut Vec::new()),
                        Facing::Mixed if nodes[n as usize].level > 0 => stack.extend(rd.children(n)),
                        _ => leaf(n, &mut tests, &mut culled),
                    }
                }
            }
        }
        total += (tests as f64 + faces - culled as f64) / faces;
    }
    total / views as f64
}

/// Largest node of any level over the median node of level 0, and the top level's faces.
fn node_sizes(rd: &Reader<std::fs::File>) -> (f64, u64) {
    let mut level0: Vec<u32> = rd.level_nodes(0).map(|n| rd.nodes()[n as usize].faces).collect();
    level0.sort_unstable();
    let median = level0[level0.len() / 2].max(1) as f64;
    let largest = rd.nodes().iter().map(|n| n.faces).max().unwrap_or(0) as f64;
    (largest / median, rd.levels().last().map_or(0, |l| l.faces))
}

/// Milliseconds from opening `file` to its first frame (the top level read and drawn), by
/// `strata stream` in a fresh process, the least of three runs.
fn first_frame_ms(file: &Path) -> Option<f64> {
    (0..3)
        .filter_map(|_| {
            let out = Command::new(env!("CARGO_BIN_EXE_strata")).arg("stream").arg(file).args(["--orbit", "1"]).output().ok()?;
            let text = String::from_utf8_lossy(&out.stdout).into_owned();
            let line = text.lines().find(|l| l.contains("first frame ready"))?;
            line.split_whitespace().nth(3)?.parse::<f64>().ok()
        })
        .min_by(f64::total_cmp)
}

/// `--leaf-faces` of the other layouts: a sixteenth below and above the default.
fn leaf_faces_spread() -> [String; 2] {
    let leaf = strata::hierarchy::HierarchyParams::default().leaf_faces;
    [leaf - leaf / 16, leaf + leaf / 16].map(|n| n.to_string())
}

/// Each level's sampled distance from `file` to `input`.
fn level_distances(file: &Path, input: &strata::Mesh) -> Vec<f32> {
    let rd = Reader::open_path(file).expect("open");
    (0..rd.levels().len() as u32)
        .map(|l| strata::distance::surface_distance(&strata::assemble::to_mesh(&rd, l).expect("level"), input, 20_000, 7).mean)
        .collect()
}

/// `a`'s distances over `b`'s at levels 1 and up present in both.
fn level_ratios(a: &[f32], b: &[f32]) -> Vec<f64> {
    a.iter().zip(b).skip(1).filter(|(_, &b)| b > 0.0).map(|(&a, &b)| a as f64 / b as f64).collect()
}

/// Shaded retention of `file`'s fronts under 10 % and 25 % of its input faces over the 8 views;
/// `None` where the top level alone exceeds the budget.
fn shaded_retentions(file: &Path) -> [Option<f64>; 2] {
    let input_faces = Reader::open_path(file).expect("open").header().input_faces as f64;
    let views = retention_views::Views::of(file).expect("views");
    let priority = strata::stream::Budgets::default().priority;
    [0.10, 0.25].map(|share| views.retention(file, (input_faces * share) as u64, priority).expect("retention").map(|(shaded, _)| shaded))
}

/// Per level that every layout has, the geometric mean of the layouts' distances.
fn geometric_means(layouts: &[Vec<f32>]) -> Vec<f32> {
    let levels = layouts.iter().map(Vec::len).min().unwrap_or(0);
    (0..levels).map(|l| (layouts.iter().map(|d| (d[l] as f64).ln()).sum::<f64>() / layouts.len() as f64).exp() as f32).collect()
}

fn listed(ratios: &[f64]) -> String {
    ratios.iter().map(|r| format!("{r:.2}")).collect::<Vec<_>>().join(", ")
}

/// `spread`: per build named in `runs`, the files of the same build at [`leaf_faces_spread`].
fn report(name: &str, faces: u64, input: Option<&strata::Mesh>, runs: &[(&str, &Path, Run)], spread: &[(&str, Vec<PathBuf>)]) {
    println!("\n## {name} ({faces} input faces)");
    println!(
        "| build | s | M faces/s | peak MB | bytes/face | nodes | levels | top faces | largest node / level-0 median | culling cost | first frame ms | retention 10 % | 25 % |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut distances: Vec<Vec<f32>> = Vec::new();
    // Per build, its retention at 10 % and 25 % in each layout (the default first).
    let mut retentions: Vec<(&str, Vec<[Option<f64>; 2]>)> = Vec::new();
    for (build, file, run) in runs {
        let rd = Reader::open_path(file).expect("open");
        assert!(strata::format::verify_path(file).is_sound(), "{} does not verify", file.display());
        let (ratio, top) = node_sizes(&rd);
        let peak = run.peak_kb.map_or("–".to_string(), |k| format!("{:.0}", k as f64 / 1024.0));
        let layouts: Vec<[Option<f64>; 2]> = std::iter::once(*file)
            .chain(spread.iter().filter(|s| s.0 == *build).flat_map(|s| s.1.iter().map(PathBuf::as_path)))
            .map(shaded_retentions)
            .collect();
        let retention = |k: usize| layouts[0][k].map_or("top too large".to_string(), |r| format!("{r:.3}"));
        println!(
            "| {build} | {:.2} | {:.3} | {peak} | {:.1} | {} | {} | {top} | {ratio:.1} | {:.4} | {} | {} | {} |",
            run.seconds,
            faces as f64 / run.seconds / 1e6,
            std::fs::metadata(file).map_or(0, |m| m.len()) as f64 / faces.max(1) as f64,
            rd.nodes().len(),
            rd.levels().len(),
            culling_cost(&rd, 64),
            first_frame_ms(file).map_or("–".to_string(), |ms| format!("{ms:.1}")),
            retention(0),
            retention(1),
        );
        retentions.push((build, layouts));
        if let Some(m) = input {
            distances.push(level_distances(file, m));
        }
    }
    if retentions.iter().any(|(_, l)| l.len() > 1) {
        println!(
            "\nretention at 10 % and 25 % over three layouts (the default and --leaf-faces {}): mean (least–most)",
            leaf_faces_spread().join(", ")
        );
        for (build, layouts) in &retentions {
            let summary = |k: usize| -> String {
                let r: Vec<f64> = layouts.iter().filter_map(|l| l[k]).collect();
                if r.len() < layouts.len() {
                    return "top too large in a layout".into();
                }
                let (lo, hi) = r.iter().fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
                format!("{:.3} ({lo:.3}–{hi:.3})", r.iter().sum::<f64>() / r.len() as f64)
            };
            println!("{build}: {}; {}", summary(0), summary(1));
        }
    }
    if distances.len() >= 2 {
        println!("\nmean sampled distance to the input, per level (fraction of the diagonal), and each build's over the first's:");
        let diag = input.map_or(1.0, |m| m.diagonal());
        let levels = distances.iter().map(Vec::len).max().unwrap_or(0);
        for l in 0..levels {
            let first = distances[0].get(l).copied();
            let cells: Vec<String> = runs
                .iter()
                .zip(&distances)
                .map(|((build, ..), d)| match (d.get(l), first) {
                    (Some(x), Some(f)) if f > 0.0 => format!("{build} {:.2e} ({:.2})", x / diag, x / f),
                    (Some(x), _) => format!("{build} {:.2e}", x / diag),
                    (None, _) => format!("{build} –"),
                })
                .collect();
            println!("level {l}: {}", cells.join("  "));
        }
        // Issue 14's measure: each partitioned build against the in-core build of its kind.
        let at = |name: &str| runs.iter().position(|r| r.0 == name).and_then(|i| distances.get(i));
        for (part, core) in [("partitioned", "in-core"), ("partitioned DAG", "in-core DAG")] {
            let (Some(p), Some(c)) = (at(part), at(core)) else { continue };
            let ratios = level_ratios(p, c);
            if ratios.is_empty() {
                println!("{part} over {core}: no level above 0 in both");
                continue;
            }
            let worst = ratios.iter().copied().fold(0.0, f64::max);
            println!("{part} over {core}, levels 1–{}: {} (worst {worst:.2}; the goal: at most 1.2)", ratios.len(), listed(&ratios));
            let layouts = |build: &str, default: &[f32]| -> Option<Vec<Vec<f32>>> {
                let ((_, files), m) = (spread.iter().find(|s| s.0 == build)?, input?);
                Some(std::iter::once(default.to_vec()).chain(files.iter().map(|f| level_distances(f, m))).collect())
            };
            let (Some(ps), Some(cs)) = (layouts(part, p), layouts(core, c)) else { continue };
            let ratios = level_ratios(&geometric_means(&ps), &geometric_means(&cs));
            let leaves = leaf_faces_spread().join(", ");
            if ratios.is_empty() {
                println!("  over three layouts (the default and --leaf-faces {leaves}): no level above 0 in every layout");
            } else {
                let worst = ratios.iter().copied().fold(0.0, f64::max);
                println!(
                    "  over three layouts (the default and --leaf-faces {leaves}), levels 1–{}: {} (worst {worst:.2})",
                    ratios.len(),
                    listed(&ratios)
                );
            }
            for (leaf, d) in leaf_faces_spread().iter().zip(&cs[1..]) {
                let ratios = level_ratios(d, c);
                println!("  {core}'s own spread, at --leaf-faces {leaf} over the default, levels 1–{}: {}", ratios.len(), listed(&ratios));
            }
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let value = |flag: &str| args.iter().position(|a| a == flag).and_then(|i| args.get(i + 1).cloned());
    let memory = value("--memory").unwrap_or_else(|| "1G".into());
    let large: Vec<u64> = args.windows(2).filter(|w| w[0] == "--large").filter_map(|w| w[1].parse().ok()).collect();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let tmp = std::env::temp_dir().join(format!("strata-bench-partition-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let out = |n: &str| -> PathBuf { tmp.join(n) };

    // A soup of separate triangles (specks, fragments, an unwelded export): nothing to collapse,
    // so only a rule that lets small components leave makes its levels shrink.
    let soup = out("soup.obj");
    let mut w = std::io::BufWriter::new(std::fs::File::create(&soup).unwrap());
    strata::fixtures::write_soup_obj(&mut w, 60_000).expect("write the soup");
    drop(w);
    let mut inputs: Vec<(PathBuf, &str)> = vec![(root.join("fixtures/noisy_sphere.ply"), "16M"), (soup, "16M")];
    for (mesh, budget) in [("scans/stanford_bun_zipper.ply", "16M"), ("large/cthead_skin_native.ply", "256M")] {
        let path = root.join("../shared/meshes").join(mesh);
        if path.exists() {
            inputs.push((path, budget));
        } else {
            println!("skipping {}: not found", path.display());
        }
    }
    for (input, budget) in &inputs {
        let mesh = strata::import::import(input, None).expect("import").mesh;
        let builds = [
            ("in-core", "incore.strata", vec!["--in-core"]),
            ("partitioned", "part.strata", vec!["--partitioned", "--memory", budget]),
            ("in-core DAG", "incore-dag.strata", vec!["--in-core", "--dag"]),
            ("partitioned DAG", "part-dag.strata", vec!["--partitioned", "--dag", "--memory", budget]),
        ];
        let files: Vec<PathBuf> = builds.iter().map(|b| out(b.1)).collect();
        let runs: Vec<(&str, &Path, Run)> = builds.iter().zip(&files).map(|(b, f)| (b.0, f.as_path(), convert(input, f, &b.2))).collect();
        let spread: Vec<(&str, Vec<PathBuf>)> = builds
            .iter()
            .map(|(build, _, args)| {
                let files = leaf_faces_spread()
                    .iter()
                    .map(|leaf| {
                        let f = out(&format!("{}-leaf-{leaf}.strata", build.replace(' ', "-")));
                        convert(input, &f, &[args.as_slice(), &["--leaf-faces", leaf.as_str()]].concat());
                        f
                    })
                    .collect();
                (*build, files)
            })
            .collect();
        let name = format!("{} (partitioned at --memory {budget})", input.file_name().unwrap().to_string_lossy());
        report(&name, mesh.face_count() as u64, Some(&mesh), &runs, &spread);
    }
    for n in large {
        let ply = out(&format!("bumpy-{n}.ply"));
        let mut w = std::io::BufWriter::new(std::fs::File::create(&ply).unwrap());
        let (faces, _) = strata::fixtures::write_bumpy_sphere_ply(&mut w, n, 1, &mut |_| {}).unwrap();
        drop(w);
        let (part, dag) = (out("large.strata"), out("large-dag.strata"));
        let b = convert(&ply, &part, &["--partitioned", "--memory", &memory]);
        let c = convert(&ply, &dag, &["--partitioned", "--dag", "--memory", &memory]);
        let name = format!("generated bumpy sphere (partitioned at --memory {memory})");
        if faces.saturating_mul(strata::partition::IN_CORE_BYTES_PER_FACE) <= strata::partition::default_memory() {
            let incore = out("large-incore.strata");
            let a = convert(&ply, &incore, &["--in-core"]);
            let mesh = strata::import::import(&ply, None).expect("import").mesh;
            report(&name, faces, Some(&mesh), &[("in-core", &incore, a), ("partitioned", &part, b), ("partitioned DAG", &dag, c)], &[]);
        } else {
            report(&name, faces, None, &[("partitioned", &part, b), ("partitioned DAG", &dag, c)], &[]);
        }
        let _ = std::fs::remove_file(&ply);
    }
    let _ = std::fs::remove_dir_all(&tmp);
}
