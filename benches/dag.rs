//! What a DAG of nodes would give (issue 14's "crack-free by construction", notes/dag.md), beside
//! the tree strata builds, in the same run and with the same simplifier.
//!
//! The tree: `hierarchy::build` and `levels::build`, as `strata convert` makes its levels (nodes are
//! the groups of each level). The DAG, as Nanite and Nexus build theirs: level 0's nodes are the
//! tree's level-0 groups; each coarser level gathers adjacent nodes of the level below into groups
//! of about `PER_GROUP` (along their longest shared border; a node with no free neighbour takes its
//! nearest free ones), simplifies the level to half with every vertex shared by two groups pinned
//! and every face kept in its group (topology changes on, away from the pins, as the tree's
//! in-core build has them), and cuts each group's result into nodes of about level 0's
//! median size (bisection at the median face centroid). A border pinned at one level lies inside a
//! group at the next, where it simplifies.
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
use strata::cone::{facing_perspective, smallest_enclosing, Facing};
use strata::format::Cone;
use strata::hierarchy::{self, HierarchyParams};
use strata::levels::{self, position_key, LevelParams};
use strata::mesh::{Adjacency, Mesh};
use strata::render::Image;
use strata::simplify::{simplify_pinned, SimplifyOptions};
use strata::stream::retention::retention;

const PER_GROUP: usize = 4;
const TOP_FACES: usize = 2048;

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

fn centroid(mesh: &Mesh, f: u32) -> glam::Vec3 {
    let t = mesh.triangles[f as usize];
    (mesh.positions[t[0] as usize] + mesh.positions[t[1] as usize] + mesh.positions[t[2] as usize]) / 3.0
}

/// Cut `faces` into `pieces` nodes by bisection at the median centroid along the longest axis.
fn split(mesh: &Mesh, faces: &mut [u32], pieces: usize, out: &mut Vec<Vec<u32>>) {
    if pieces <= 1 || faces.len() < 2 {
        out.push(faces.to_vec());
        return;
    }
    let (mut lo, mut hi) = (glam::Vec3::splat(f32::MAX), glam::Vec3::splat(f32::MIN));
    for &f in faces.iter() {
        lo = lo.min(centroid(mesh, f));
        hi = hi.max(centroid(mesh, f));
    }
    let axis = (hi - lo).max_position();
    let left = pieces / 2;
    let at = faces.len() * left / pieces;
    faces.select_nth_unstable_by(at, |&a, &b| centroid(mesh, a)[axis].total_cmp(&centroid(mesh, b)[axis]));
    let (a, b) = faces.split_at_mut(at);
    split(mesh, a, left, out);
    split(mesh, b, pieces - left, out);
}

/// Groups of about PER_GROUP adjacent nodes: per face and per node (labels of `node`), and how many.
fn group_nodes(mesh: &Mesh, node: &[u32], nodes: usize) -> (Vec<u32>, Vec<u32>, u32) {
    let mut owner: FxHashMap<(u32, u32), u32> = FxHashMap::default();
    let mut shared: FxHashMap<(u32, u32), u32> = FxHashMap::default();
    let mut center = vec![glam::Vec3::ZERO; nodes];
    let mut count = vec![0u32; nodes];
    for (f, t) in mesh.triangles.iter().enumerate() {
        let n = node[f];
        center[n as usize] += centroid(mesh, f as u32);
        count[n as usize] += 1;
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            match owner.get(&(a.min(b), a.max(b))) {
                Some(&m) if m != n => *shared.entry((m.min(n), m.max(n))).or_default() += 1,
                Some(_) => {}
                None => {
                    owner.insert((a.min(b), a.max(b)), n);
                }
            }
        }
    }
    for (c, &k) in center.iter_mut().zip(&count) {
        *c /= k.max(1) as f32;
    }
    let mut nb: Vec<Vec<(u32, u32)>> = vec![Vec::new(); nodes];
    for (&(a, b), &w) in &shared {
        nb[a as usize].push((b, w));
        nb[b as usize].push((a, w));
    }
    for l in &mut nb {
        l.sort_unstable();
    }
    let mut group = vec![u32::MAX; nodes];
    let mut groups = 0u32;
    for s in 0..nodes {
        if group[s] != u32::MAX || count[s] == 0 {
            continue;
        }
        group[s] = groups;
        let mut members = vec![s as u32];
        while members.len() < PER_GROUP {
            let mut best: Option<(u32, u32)> = None;
            for &x in &members {
                for &(y, w) in &nb[x as usize] {
                    if group[y as usize] == u32::MAX && best.is_none_or(|b| w > b.1) {
                        best = Some((y, w));
                    }
                }
            }
            // No free neighbour: the nearest free node (separate components gather too).
            if best.is_none() {
                best = (0..nodes as u32)
                    .filter(|&y| group[y as usize] == u32::MAX && count[y as usize] > 0)
                    .min_by(|&a, &b| center[a as usize].distance(center[s]).total_cmp(&center[b as usize].distance(center[s])))
                    .map(|y| (y, 0));
            }
            match best {
                Some((y, _)) => {
                    group[y as usize] = groups;
                    members.push(y);
                }
                None => break,
            }
        }
        groups += 1;
    }
    (node.iter().map(|&n| group[n as usize]).collect(), group, groups)
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

/// A node of the DAG: its level, its faces there, bounds and cone, the group that made it (none at
/// level 0) and the group it went into (none at the top).
struct DagNode {
    level: usize,
    faces: Vec<u32>,
    center: Vec3,
    radius: f32,
    cone: Cone,
    source: Option<usize>,
    consumer: Option<usize>,
}

/// A group: its error (its simplification's plus the largest of its children's sources') and a
/// sphere holding its children's and their sources' spheres, so that a group's projected error is
/// never below that of a group it was made from.
struct DagGroup {
    error: f32,
    center: Vec3,
    radius: f32,
}

/// The DAG's levels: rows (with the share pinned and the borders not kept), meshes, nodes, groups.
struct Dag {
    rows: Vec<(Row, f64, usize)>,
    meshes: Vec<Mesh>,
    nodes: Vec<DagNode>,
    groups: Vec<DagGroup>,
}

/// Nodes of `level` from the face lists `pieces` of `mesh`, made by `source`.
fn nodes_of(mesh: &Mesh, level: usize, pieces: Vec<Vec<u32>>, source: &[Option<usize>]) -> Vec<DagNode> {
    pieces
        .into_iter()
        .zip(source)
        .map(|(faces, &source)| {
            let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
            for &f in &faces {
                for &v in &mesh.triangles[f as usize] {
                    lo = lo.min(mesh.positions[v as usize]);
                    hi = hi.max(mesh.positions[v as usize]);
                }
            }
            let center = (lo + hi) * 0.5;
            let radius = faces
                .iter()
                .flat_map(|&f| mesh.triangles[f as usize])
                .map(|v| mesh.positions[v as usize].distance(center))
                .fold(0.0, f32::max);
            let normals: Vec<Vec3> = faces.iter().map(|&f| face_normal(mesh, f)).filter(|n| *n != Vec3::ZERO).collect();
            DagNode { level, faces, center, radius, cone: smallest_enclosing(&normals), source, consumer: None }
        })
        .collect()
}

fn face_normal(mesh: &Mesh, f: u32) -> Vec3 {
    let t = mesh.triangles[f as usize].map(|v| mesh.positions[v as usize]);
    (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero()
}

fn dag(mut mesh: Mesh, level0: &[u32]) -> Dag {
    let mut node = level0.to_vec();
    let mut s0 = sizes(&node);
    s0.sort_unstable();
    let median0 = s0[s0.len() / 2] as usize;
    let mut rows = vec![(Row { faces: mesh.triangles.len(), nodes: sizes(&node) }, 0.0, 0)];
    let mut pieces0: Vec<Vec<u32>> = vec![Vec::new(); node.iter().copied().max().map_or(0, |m| m as usize + 1)];
    for (f, &n) in node.iter().enumerate() {
        pieces0[n as usize].push(f as u32);
    }
    let mut nodes = nodes_of(&mesh, 0, pieces0.clone(), &vec![None; pieces0.len()]);
    let (mut groups, mut meshes): (Vec<DagGroup>, Vec<Mesh>) = (Vec::new(), Vec::new());
    let mut level_first = 0usize;
    while mesh.triangles.len() > TOP_FACES {
        let count_here = node.iter().copied().max().map_or(0, |m| m as usize + 1);
        let (labels, group_of, group_count) = group_nodes(&mesh, &node, count_here);
        let mut first = vec![u32::MAX; mesh.positions.len()];
        let mut pinned = vec![false; mesh.positions.len()];
        for (f, t) in mesh.triangles.iter().enumerate() {
            for &v in t {
                if first[v as usize] == u32::MAX {
                    first[v as usize] = labels[f];
                } else if first[v as usize] != labels[f] {
                    pinned[v as usize] = true;
                }
            }
        }
        let borders = group_borders(&mesh, &labels);
        let before = mesh.triangles.len();
        let opts = SimplifyOptions {
            target_faces: before / 2,
            normal_seam_angle: 60f32.to_radians(),
            topology: true,
            ..SimplifyOptions::default()
        };
        let s = simplify_pinned(&mesh, Some(&labels), &pinned, &opts);
        let kept = edges_of(&s.mesh);
        let lost = borders.iter().filter(|e| !kept.contains(e)).count();
        // This step's groups: errors and spheres from their children.
        let base = groups.len();
        let mut g_err = vec![0.0f32; group_count as usize];
        let mut g_spheres: Vec<Vec<(Vec3, f32)>> = vec![Vec::new(); group_count as usize];
        for n in 0..count_here {
            let g = group_of[n];
            if g == u32::MAX {
                continue;
            }
            let d = &mut nodes[level_first + n];
            d.consumer = Some(base + g as usize);
            g_spheres[g as usize].push((d.center, d.radius));
            if let Some(src) = d.source {
                g_err[g as usize] = g_err[g as usize].max(groups[src].error);
                g_spheres[g as usize].push((groups[src].center, groups[src].radius));
            }
        }
        for (g, spheres) in g_spheres.iter().enumerate() {
            let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
            for &(c, r) in spheres {
                lo = lo.min(c - r);
                hi = hi.max(c + r);
            }
            let center = (lo + hi) * 0.5;
            let radius = spheres.iter().map(|&(c, r)| c.distance(center) + r).fold(0.0, f32::max);
            let error = g_err[g] + s.group_error.get(g).copied().unwrap_or(0.0);
            groups.push(DagGroup { error, center, radius });
        }
        let mut by_group: Vec<Vec<u32>> = vec![Vec::new(); group_count as usize];
        for (f, &g) in s.face_groups.iter().enumerate() {
            by_group[g as usize].push(f as u32);
        }
        let mut next = vec![0u32; s.mesh.triangles.len()];
        let (mut pieces, mut sources) = (Vec::new(), Vec::new());
        for (g, mut faces) in by_group.into_iter().enumerate().filter(|(_, f)| !f.is_empty()) {
            let count = ((faces.len() as f64 / median0 as f64).round() as usize).max(1);
            let mut out = Vec::new();
            split(&s.mesh, &mut faces, count, &mut out);
            for piece in out {
                for &f in &piece {
                    next[f as usize] = pieces.len() as u32;
                }
                pieces.push(piece);
                sources.push(Some(base + g));
            }
        }
        let share = pinned.iter().filter(|&&p| p).count() as f64 / mesh.positions.len().max(1) as f64;
        let stalled = s.mesh.triangles.len() as f64 > 0.95 * before as f64;
        let count = pieces.len();
        level_first = nodes.len();
        nodes.extend(nodes_of(&s.mesh, meshes.len() + 1, pieces, &sources));
        meshes.push(std::mem::replace(&mut mesh, s.mesh));
        node = next;
        rows.push((Row { faces: mesh.triangles.len(), nodes: sizes(&node) }, share, lost));
        if stalled || count <= 1 {
            break;
        }
    }
    meshes.push(mesh);
    Dag { rows, meshes, nodes, groups }
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

/// Mean shaded retention over the 8 views of the DAG's cut under `budget` faces: per view the
/// least threshold τ whose cut (a node shown iff its source group's projected error is at most τ
/// and its consumer's above) has at most `budget` faces in nodes that face the camera and meet
/// the frustum, drawn against level 0.
fn dag_retention(d: &Dag, budget: usize) -> f64 {
    let normals: Vec<Vec<Vec3>> = d.meshes.iter().map(smooth_normals).collect();
    let indices = |level: usize, faces: &mut dyn Iterator<Item = u32>| -> Vec<u32> {
        faces.flat_map(|f| d.meshes[level].triangles[f as usize]).collect()
    };
    let full = indices(0, &mut (0..d.meshes[0].triangles.len() as u32));
    let mut total = 0.0;
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for &p in &d.meshes[0].positions {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let views = retention_views::cameras(lo, hi);
    for cam in &views {
        let mut reference = Image::new(retention_views::SIZE, retention_views::SIZE);
        reference.draw(cam, &d.meshes[0].positions, &normals[0], &full, [200, 200, 200, 255]);
        let p: Vec<f32> = d.groups.iter().map(|g| cam.projected_error(g.error, g.center, g.radius)).collect();
        let visible: Vec<bool> = d
            .nodes
            .iter()
            .map(|n| facing_perspective(&n.cone, n.center, n.radius, cam.eye) != Facing::Back && cam.sees_sphere(n.center, n.radius))
            .collect();
        let shown = |tau: f32, n: &DagNode| n.source.is_none_or(|s| p[s] <= tau) && n.consumer.is_none_or(|c| p[c] > tau);
        let faces =
            |tau: f32| -> usize { d.nodes.iter().zip(&visible).filter(|&(n, &v)| v && shown(tau, n)).map(|(n, _)| n.faces.len()).sum() };
        let mut candidates: Vec<f32> = p.iter().copied().filter(|x| x.is_finite()).collect();
        candidates.push(0.0);
        candidates.sort_unstable_by(f32::total_cmp);
        // The least candidate whose cut fits (faces fall as τ grows), else the largest.
        let (mut lo, mut hi) = (0usize, candidates.len() - 1);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if faces(candidates[mid]) <= budget {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        let tau = candidates[lo];
        let mut img = Image::new(retention_views::SIZE, retention_views::SIZE);
        for (n, _) in d.nodes.iter().zip(&visible).filter(|&(n, &v)| v && shown(tau, n)) {
            let ix = indices(n.level, &mut n.faces.iter().copied());
            img.draw(cam, &d.meshes[n.level].positions, &normals[n.level], &ix, [200, 200, 200, 255]);
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
        let built = dag(mesh.clone(), &level0);
        let dag_rows = &built.rows;
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
