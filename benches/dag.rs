//! The DAG of nodes (`strata::dag`, issue 14's "crack-free by construction", notes/dag.md) beside
//! the tree strata builds, in the same run and with the same simplifier.
//!
//! The tree: `hierarchy::build` and `levels::build`, as `strata convert` makes its levels (nodes are
//! the groups of each level). The DAG: `dag::build` from the tree's level-0 groups.
//!
//! Printed per mesh and level: faces and the ratio to the level below, nodes, the largest node,
//! for both; for the DAG the share of vertices pinned, and the group borders of the level below
//! that its result does not keep edge for edge (0: displayed nodes meet finer neighbours without a
//! crack). Then the top level, and the largest node of any level over
//! level 0's median (issue 14's goal: at most 4); and shape retention at 10 % and 25 % of the
//! input's faces over the 8 views of `retention_views`: the tree as strata streams its converted
//! file, the DAG's cut in memory (per view the least threshold whose cut of visible nodes fits;
//! float positions, each level's smooth normals).
//!
//! `cargo bench --bench dag [-- mesh ...]`; without arguments the shipped noisy sphere and, when
//! present, the bunny, the gargoyle and the CT head of ../shared/meshes.

#[path = "common/convert.rs"]
mod convert;
use convert::convert;

#[path = "common/retention_views.rs"]
mod retention_views;

use glam::Vec3;
use rustc_hash::{FxHashMap, FxHashSet};
use std::path::{Path, PathBuf};
use strata::dag::{self, cut::select, Dag, DagParams};
use strata::hierarchy::{self, HierarchyParams};
use strata::levels::{self, position_key, LevelParams};
use strata::mesh::{Adjacency, Mesh};
use strata::render::Image;
use strata::stream::retention::retention;

/// One level of either build: faces, and faces per node.
struct Row {
    faces: usize,
    nodes: Vec<u32>,
}

impl Row {
    fn largest(&self) -> u32 {
        self.nodes.iter().copied().max().unwrap_or(0)
    }
}

fn sizes(labels: &[u32]) -> Vec<u32> {
    let n = labels.iter().copied().max().map_or(0, |m| m as usize + 1);
    let mut s = vec![0u32; n];
    for &l in labels {
        s[l as usize] += 1;
    }
    s.retain(|&x| x > 0);
    s
}

/// Per face of level `l` of the DAG, the group its node went into.
fn consumer_labels(d: &Dag, l: usize) -> Vec<u32> {
    d.nodes[d.level_nodes(l).start as usize..d.level_nodes(l).end as usize]
        .iter()
        .flat_map(|n| std::iter::repeat_n(n.consumer, n.faces.len()))
        .collect()
}

/// The edges (as position keys, undirected) between faces of two groups.
fn group_borders(mesh: &Mesh, labels: &[u32]) -> FxHashSet<([u32; 3], [u32; 3])> {
    let mut first: FxHashMap<(u32, u32), u32> = FxHashMap::default();
    let mut out = FxHashSet::default();
    for (f, t) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
            match first.get(&(a, b)) {
                Some(&g) if g != labels[f] => {
                    let (ka, kb) = (position_key(mesh.positions[a as usize]), position_key(mesh.positions[b as usize]));
                    out.insert((ka.min(kb), ka.max(kb)));
                }
                Some(_) => {}
                None => {
                    first.insert((a, b), labels[f]);
                }
            }
        }
    }
    out
}

fn edges_of(mesh: &Mesh) -> FxHashSet<([u32; 3], [u32; 3])> {
    let mut out = FxHashSet::default();
    for t in &mesh.triangles {
        for k in 0..3 {
            let (ka, kb) = (position_key(mesh.positions[t[k] as usize]), position_key(mesh.positions[t[(k + 1) % 3] as usize]));
            out.insert((ka.min(kb), ka.max(kb)));
        }
    }
    out
}

/// Per level of the DAG: its row, the share of the level below's vertices that two groups shared
/// (pinned while it was made), and the group borders of the level below it does not keep.
fn dag_rows(d: &Dag) -> Vec<(Row, f64, usize)> {
    (0..d.levels.len())
        .map(|l| {
            let r = d.level_nodes(l);
            let row = Row {
                faces: d.levels[l].triangles.len(),
                nodes: d.nodes[r.start as usize..r.end as usize].iter().map(|n| n.faces.len() as u32).collect(),
            };
            if l == 0 {
                return (row, 0.0, 0);
            }
            let below = &d.levels[l - 1];
            let labels = consumer_labels(d, l - 1);
            let pinned = dag::shared_vertices(below, &labels);
            let share = pinned.iter().filter(|&&p| p).count() as f64 / below.positions.len().max(1) as f64;
            let kept = edges_of(&d.levels[l]);
            let lost = group_borders(below, &labels).iter().filter(|e| !kept.contains(e)).count();
            (row, share, lost)
        })
        .collect()
}

/// Smooth vertex normals of `mesh` (area-weighted face normals).
fn smooth_normals(mesh: &Mesh) -> Vec<Vec3> {
    let mut n = vec![Vec3::ZERO; mesh.positions.len()];
    for t in &mesh.triangles {
        let p = t.map(|v| mesh.positions[v as usize]);
        let c = (p[1] - p[0]).cross(p[2] - p[0]);
        for &v in t {
            n[v as usize] += c;
        }
    }
    n.iter().map(|v| v.normalize_or_zero()).collect()
}

/// Mean shaded retention over the 8 views of the DAG's cut under `budget` faces
/// ([`select`] at 0 px: groups opened largest projected error first while the budget holds), drawn
/// against level 0.
fn dag_retention(d: &Dag, budget: usize) -> f64 {
    let normals: Vec<Vec<Vec3>> = d.levels.iter().map(smooth_normals).collect();
    let full: Vec<u32> = d.levels[0].triangles.iter().flatten().copied().collect();
    let (lo, hi) = d.levels[0].bounds().expect("bounds");
    let views = retention_views::cameras(lo, hi);
    let mut total = 0.0;
    for cam in &views {
        let mut reference = Image::new(retention_views::SIZE, retention_views::SIZE);
        reference.draw(cam, &d.levels[0].positions, &normals[0], &full, [200, 200, 200, 255]);
        let mut img = Image::new(retention_views::SIZE, retention_views::SIZE);
        for n in select(d, cam, 0.0, Some(budget), &|_| false).shown {
            let level = d.nodes[n as usize].level as usize;
            let ix: Vec<u32> = d.indices(n as usize).collect();
            img.draw(cam, &d.levels[level].positions, &normals[level], &ix, [200, 200, 200, 255]);
        }
        total += retention(&img, &reference).shaded / views.len() as f64;
    }
    total
}

fn main() {
    let mut inputs: Vec<PathBuf> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).map(PathBuf::from).collect();
    if inputs.is_empty() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        inputs.push(root.join("fixtures/noisy_sphere.ply"));
        for m in ["scans/stanford_bun_zipper.ply", "scans/3dhop_gargo.ply", "large/cthead_skin_native.ply"] {
            let p = root.join("../shared/meshes").join(m);
            if p.exists() {
                inputs.push(p);
            } else {
                println!("skipping {m}: ../shared/meshes not found");
            }
        }
    }
    for input in &inputs {
        let mesh = strata::import::import(input, None).expect("import").mesh;
        let adj = Adjacency::build(&mesh);
        let mut h = hierarchy::build(&mesh, &adj, &HierarchyParams::default());
        drop(adj);
        let level0 = h.levels[0].face_group.clone();
        let start = std::time::Instant::now();
        let built = dag::build(mesh.clone(), &level0, &DagParams::default(), &mut |_, _| {});
        let dag_rows = &dag_rows(&built);
        let dag_s = start.elapsed().as_secs_f64();
        let start = std::time::Instant::now();
        let tree = levels::build(mesh, &mut h, &LevelParams::default(), &mut |_| {});
        let tree_s = start.elapsed().as_secs_f64();
        let tree_rows: Vec<Row> = tree.levels.iter().map(|l| Row { faces: l.mesh.triangles.len(), nodes: sizes(&l.face_group) }).collect();
        let mut s0 = tree_rows[0].nodes.clone();
        s0.sort_unstable();
        let median0 = s0[s0.len() / 2] as f64;
        println!("\n{} (level 0: {} faces, median node {median0})", input.file_name().unwrap().to_string_lossy(), tree_rows[0].faces);
        println!(
            "{:>5} | {:>9} {:>5} {:>6} {:>8} | {:>9} {:>5} {:>6} {:>8} {:>7} {:>14}",
            "level", "tree", "ratio", "nodes", "largest", "DAG", "ratio", "nodes", "largest", "pinned", "borders lost"
        );
        for l in 0..tree_rows.len().max(dag_rows.len()) {
            let cell = |rows: &[&Row]| match rows.get(l) {
                Some(r) => {
                    let ratio = if l == 0 { String::from("-") } else { format!("{:.2}", r.faces as f64 / rows[l - 1].faces as f64) };
                    format!("{:>9} {:>5} {:>6} {:>8}", r.faces, ratio, r.nodes.len(), r.largest())
                }
                None => format!("{:>9} {:>5} {:>6} {:>8}", "", "", "", ""),
            };
            let t: Vec<&Row> = tree_rows.iter().collect();
            let d: Vec<&Row> = dag_rows.iter().map(|r| &r.0).collect();
            let extra = match dag_rows.get(l) {
                Some((_, share, lost)) if l > 0 => format!("{:>6.1}% {:>14}", 100.0 * share, lost),
                _ => String::new(),
            };
            println!("{l:>5} | {} | {} {extra}", cell(&t), cell(&d));
        }
        let largest = |rows: &mut dyn Iterator<Item = &Row>| rows.map(|r| r.largest()).max().unwrap_or(0) as f64 / median0;
        println!(
            "top level: tree {} faces, DAG {} faces; largest node / level-0 median: tree {:.1}, DAG {:.1}; levels built in {tree_s:.2} s (tree), {dag_s:.2} s (DAG)",
            tree_rows.last().unwrap().faces,
            dag_rows.last().unwrap().0.faces,
            largest(&mut tree_rows.iter()),
            largest(&mut dag_rows.iter().map(|r| &r.0)),
        );
        // Shape retention at 10 % and 25 % of the input's faces: the tree as strata streams its
        // file (benches/common/retention_views.rs), the DAG's cut in memory, same 8 views.
        let file = convert(input, "dag");
        let views = retention_views::Views::of(&file).expect("views");
        let input_faces = tree_rows[0].faces;
        let mut line = String::from("shape retention at 10 % / 25 % of the faces:");
        for share in [10, 4] {
            let tree =
                views.retention(&file, (input_faces / share) as u64, Default::default()).expect("retention").map_or(f64::NAN, |r| r.0);
            let dag = dag_retention(&built, input_faces / share);
            line += &format!(" {}: tree {tree:.3}, DAG {dag:.3};", if share == 10 { "10 %" } else { "25 %" });
        }
        println!("{line}");
        std::fs::remove_file(&file).ok();
    }
}
