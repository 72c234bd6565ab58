//! Building the DAG level by level: gather, simplify with group borders pinned, split.

use super::gather::{centre, gather, morton_runs};
use super::specks;
use super::split::split;
use super::{Dag, Group, Node, NONE};
use crate::cone::smallest_enclosing;
use crate::hierarchy::Lists;
use crate::levels::position_key;
use crate::mesh::{box_of, Mesh};
use crate::simplify::{simplify_pinned, SimplifyOptions};
use glam::Vec3;
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};

/// How the DAG's levels are made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DagParams {
    /// Target ratio of faces between a level and the one below.
    pub ratio: f32,
    /// Levels are added while the top has more faces than this (and the last one shrank).
    pub top_faces: usize,
}

impl Default for DagParams {
    fn default() -> Self {
        DagParams { ratio: 0.5, top_faces: 2048 }
    }
}

/// A level that keeps more than this share of the faces below it ends the build: the simplifier
/// has stopped (pins and group rules leave it nothing to collapse). A group that keeps more of its
/// own, in a batch that ran short of its target, lets components leave to its target ([`specks`]).
pub(super) const STALLED: f64 = 0.95;

/// Corner normals of one vertex closer than this (degrees) are one normal at levels 1 and up, as
/// in the tree's levels ([`crate::levels`]).
const NORMAL_SEAM_ANGLE: f32 = 30.0;

/// Build the DAG of `mesh` (cleaned, face geometry computed) whose level-0 nodes are the labels
/// `level0` (one per face, `0..n`; the grouping's level 0). `on_level` is called after each level
/// with its index and face count, for progress reports.
pub fn build(mesh: Mesh, level0: &[u32], p: &DagParams, on_level: &mut dyn FnMut(usize, usize)) -> Dag {
    let start = Start { mesh, labels: level0.to_vec(), made_by: Vec::new() };
    build_from(start, p, &Bounds::default(), on_level)
}

/// Where a build starts: a mesh and its level-0 nodes.
pub struct Start {
    /// Cleaned, face geometry computed.
    pub mesh: Mesh,
    /// Per face, its level-0 node (`0..n`; a label no face has makes no node).
    pub labels: Vec<u32>,
    /// Empty when level 0 is the input. In a piece of a partitioned build whose level 0 holds the
    /// top nodes of earlier pieces: the groups that made them, as stand-ins of level 0 whose
    /// `outputs` are runs of labels (every label in one), with the error and sphere those groups
    /// were stored with. The DAG's groups begin with them.
    pub made_by: Vec<Group>,
}

/// What else bounds a build besides [`DagParams`].
#[derive(Clone, Copy, Debug, Default)]
pub struct Bounds<'a> {
    /// Build exactly this many levels above level 0 (a piece of a partitioned build), whatever
    /// the top's size; `None`: until the top has at most `top_faces` faces or stops shrinking.
    pub levels: Option<usize>,
    /// Positions (as [`position_key`]s) pinned at every level: where a piece meets other pieces.
    pub pinned: Option<&'a FxHashSet<[u32; 3]>>,
    /// Faces per node of the levels built; `None`: the median of level 0's nodes. A piece that
    /// builds on earlier pieces' tops takes the input's level-0 size, which its own level 0 (those
    /// tops, cut to the sizes of the cells that made them) need not have.
    pub node_faces: Option<usize>,
}

/// [`build`] from any [`Start`], within `bounds`.
pub fn build_from(start: Start, p: &DagParams, bounds: &Bounds, on_level: &mut dyn FnMut(usize, usize)) -> Dag {
    let Start { mesh, labels: level0, made_by } = start;
    assert_eq!(level0.len(), mesh.triangles.len(), "dag::build: one level-0 label per face");
    let labels = level0.iter().copied().max().map_or(0, |m| m as usize + 1);
    let mut pieces: Vec<Vec<u32>> = vec![Vec::new(); labels];
    for (f, &n) in level0.iter().enumerate() {
        pieces[n as usize].push(f as u32);
    }
    let mut sources = vec![NONE; pieces.len()];
    for (g, group) in made_by.iter().enumerate() {
        let end = (group.outputs.end as usize).min(sources.len());
        sources[(group.outputs.start as usize).min(end)..end].fill(g as u32);
    }
    let (mut pieces, mut sources): (Vec<Vec<u32>>, Vec<u32>) = pieces.into_iter().zip(sources).filter(|(p, _)| !p.is_empty()).unzip();
    if made_by.is_empty() {
        pieces = specks::gather(&mesh, pieces);
        sources = vec![NONE; pieces.len()];
    }
    let median = bounds.node_faces.or_else(|| median_size(pieces.iter().map(Vec::len))).unwrap_or(1).max(1);
    let mut dag = Dag { input_faces: pieces.iter().flatten().copied().collect(), ..Dag::default() };
    let mut mesh = place(mesh, 0, pieces, &sources, &mut dag.nodes);
    // The stand-ins' outputs, renumbered as placed.
    dag.groups = made_by;
    for g in &mut dag.groups {
        g.outputs = 0..0;
    }
    for (n, node) in dag.nodes.iter().enumerate().filter(|(_, n)| n.source != NONE) {
        let out = &mut dag.groups[node.source as usize].outputs;
        *out = if out.start == out.end { n as u32..n as u32 + 1 } else { out.start..n as u32 + 1 };
    }
    on_level(0, mesh.triangles.len());
    let mut level = 0usize;
    let more = |level: usize, faces: usize| match bounds.levels {
        Some(n) => level < n,
        None => faces > p.top_faces,
    };
    while more(level, mesh.triangles.len()) {
        let here = dag.level_nodes(level);
        let first = here.start as usize;
        let count = here.len();
        let mut node_of_face = vec![0u32; mesh.triangles.len()];
        for (i, n) in dag.nodes[here.start as usize..here.end as usize].iter().enumerate() {
            node_of_face[n.faces.start as usize..n.faces.end as usize].fill(i as u32);
        }
        let (group_of_node, group_count) = gather(&mesh, &node_of_face, count);
        let labels: Vec<u32> = node_of_face.iter().map(|&n| group_of_node[n as usize]).collect();
        let mut pinned = shared_vertices(&mesh, &labels);
        if let Some(keep) = bounds.pinned {
            for (flag, &x) in pinned.iter_mut().zip(&mesh.positions) {
                *flag |= keep.contains(&position_key(x));
            }
        }
        let before = mesh.triangles.len();
        let s = simplify_each(&mesh, &labels, group_count, &pinned, p.ratio.clamp(0.0, 1.0));

        // The groups: errors and spheres from their children and the children's sources.
        let base = dag.groups.len();
        let mut error = vec![0.0f32; group_count];
        let mut spheres: Vec<Vec<(Vec3, f32)>> = vec![Vec::new(); group_count];
        for (i, &g) in group_of_node.iter().enumerate() {
            let node = &mut dag.nodes[first + i];
            node.consumer = (base + g as usize) as u32;
            spheres[g as usize].push((node.center, node.radius));
            if node.source != NONE {
                let src = &dag.groups[node.source as usize];
                error[g as usize] = error[g as usize].max(src.error);
                spheres[g as usize].push((src.center, src.radius));
            }
        }
        let mut by_group: Vec<Vec<u32>> = vec![Vec::new(); group_count];
        for (f, &g) in s.face_groups.iter().enumerate() {
            by_group[g as usize].push(f as u32);
        }
        let (mut pieces, mut sources) = (Vec::new(), Vec::new());
        let mut next_first = dag.nodes.len() as u32;
        for (g, mut faces) in by_group.into_iter().enumerate() {
            let (center, radius) = enclosing(&spheres[g]);
            let made = ((faces.len() as f64 / median as f64).round() as usize).max(1);
            let start = pieces.len();
            if !faces.is_empty() {
                split(&s.mesh, &mut faces, made, &mut pieces);
            }
            let outputs = next_first..next_first + (pieces.len() - start) as u32;
            next_first = outputs.end;
            sources.resize(pieces.len(), (base + g) as u32);
            dag.groups.push(Group {
                level: level as u32 + 1,
                error: error[g] + s.group_error.get(g).copied().unwrap_or(0.0),
                center,
                radius,
                outputs,
            });
        }
        let made = pieces.len();
        level += 1;
        let below = std::mem::replace(&mut mesh, place(s.mesh, level, pieces, &sources, &mut dag.nodes));
        dag.levels.push(below);
        on_level(level, mesh.triangles.len());
        let stalled = mesh.triangles.len() as f64 > STALLED * before as f64 || made <= 1;
        if stalled && bounds.levels.is_none() {
            break;
        }
    }
    dag.levels.push(mesh);
    let consumers: Vec<(u32, u32)> =
        dag.nodes.iter().enumerate().filter(|(_, n)| n.consumer != NONE).map(|(i, n)| (n.consumer, i as u32)).collect();
    dag.children = lists(&consumers, dag.groups.len());
    dag
}

/// A level (or one batch of its groups) simplified: its mesh, each face's group, each group's error.
struct Simplified {
    mesh: Mesh,
    face_groups: Vec<u32>,
    group_error: Vec<f32>,
}

/// Simplify the groups of `mesh` (`labels` per face, `groups` of them) to `ratio` of their faces,
/// the `pinned` vertices kept, in batches of near groups ([`batches`]) on every core: each batch
/// is one queue, so its collapses go where they cost least, across its groups. Then join the
/// results, welding the pinned vertices (they never move, so each keeps its position in every
/// batch that has it). A group meets its neighbours only at pinned vertices, so simplifying it
/// apart from some of them changes nothing of theirs. Whole small components touching no pinned
/// vertex and no other group may leave a group ([`specks::leave`]).
fn simplify_each(mesh: &Mesh, labels: &[u32], groups: usize, pinned: &[bool], ratio: f32) -> Simplified {
    let faces = Lists::from_labels(labels, groups);
    let kept: FxHashSet<[u32; 3]> = mesh.positions.iter().zip(pinned).filter(|(_, &p)| p).map(|(&x, _)| position_key(x)).collect();
    let results: Vec<(Vec<usize>, Simplified)> = batches(mesh, &faces)
        .into_par_iter()
        .map(|batch| {
            let members: Vec<u32> = batch.iter().flat_map(|&g| faces.get(g).iter().copied()).collect();
            let local: Vec<u32> = batch.iter().enumerate().flat_map(|(i, &g)| std::iter::repeat_n(i as u32, faces.get(g).len())).collect();
            let (sub, sub_pinned) = part(mesh, &members, pinned);
            // Each group's target, at least its pinned vertices (what a fan inside a pinned
            // border keeps), so that groups the pins hold do not push the others below theirs.
            let mut floor = vec![0usize; batch.len()];
            let mut seen = vec![u32::MAX; sub.positions.len()];
            for (t, &g) in sub.triangles.iter().zip(&local) {
                for &v in t {
                    if sub_pinned[v as usize] && seen[v as usize] != g {
                        seen[v as usize] = g;
                        floor[g as usize] += 1;
                    }
                }
            }
            let targets: Vec<usize> =
                batch.iter().zip(&floor).map(|(&g, &p)| (((faces.get(g).len() as f64) * ratio as f64).round() as usize).max(p)).collect();
            let opts = SimplifyOptions {
                target_faces: targets.iter().sum(),
                normal_seam_angle: NORMAL_SEAM_ANGLE.to_radians(),
                topology: true,
                ..SimplifyOptions::default()
            };
            let mut s = simplify_pinned(&sub, Some(&local), &sub_pinned, &opts);
            let short = s.mesh.triangles.len() > opts.target_faces;
            let mut errors = s.group_error.clone();
            errors.resize(batch.len(), 0.0);
            let from = specks::Batch { input: &sub, input_groups: &local, source_faces: &s.source_faces, targets: &targets, short };
            specks::leave(&mut s.mesh, &mut s.face_groups, &mut errors, &from, &|x| kept.contains(&position_key(x)));
            let face_groups = s.face_groups.iter().map(|&i| batch[i as usize] as u32).collect();
            (batch, Simplified { mesh: s.mesh, face_groups, group_error: errors })
        })
        .collect();
    let mut out = Mesh { materials: mesh.materials.clone(), images: mesh.images.clone(), ..Mesh::default() };
    let mut welded: FxHashMap<[u32; 3], u32> = FxHashMap::default();
    let (mut face_groups, mut group_error) = (Vec::new(), vec![0.0; groups]);
    for (batch, Simplified { mesh: m, face_groups: batch_groups, group_error: errors }) in results {
        let index: Vec<u32> = m
            .positions
            .iter()
            .map(|&x| {
                let key = position_key(x);
                let new = out.positions.len() as u32;
                let i = if kept.contains(&key) { *welded.entry(key).or_insert(new) } else { new };
                if i == new {
                    out.positions.push(x);
                }
                i
            })
            .collect();
        out.append_faces(&m, &index);
        face_groups.extend(batch_groups);
        for (&g, e) in batch.iter().zip(errors) {
            group_error[g] = e;
        }
    }
    Simplified { mesh: out, face_groups, group_error }
}

/// Most faces a batch of groups gathers: batches are the unit of parallel work, and within one the
/// simplifier spends its collapses where they cost least.
const BATCH_FACES: usize = 65_536;

/// The groups (`faces` of `mesh` per group) in batches of near ones: runs along the Morton order of
/// their centres, as few as hold at most about [`BATCH_FACES`] faces each, of even size so that
/// they keep the cores evenly busy.
fn batches(mesh: &Mesh, faces: &Lists) -> Vec<Vec<usize>> {
    let items: Vec<(Vec3, usize)> = (0..faces.len()).map(|g| (centre(mesh, faces.get(g)), faces.get(g).len())).collect();
    let bounds = box_of(items.iter().map(|i| i.0)).unwrap_or_default();
    let total: usize = items.iter().map(|i| i.1).sum();
    let runs = total.div_ceil(BATCH_FACES).max(1);
    morton_runs(&items, bounds, total.div_ceil(runs))
}

/// The faces `faces` of `mesh` as a mesh of their own (images left out), and which of its vertices
/// are `pinned`.
fn part(mesh: &Mesh, faces: &[u32], pinned: &[bool]) -> (Mesh, Vec<bool>) {
    let mut remap = FxHashMap::default();
    let mut out = Mesh { materials: mesh.materials.clone(), ..Mesh::default() };
    let mut flags = Vec::new();
    let corners = |present: bool, f: u32| if present { 3 * f as usize..3 * f as usize + 3 } else { 0..0 };
    for &f in faces {
        let t = mesh.triangles[f as usize].map(|v| {
            *remap.entry(v).or_insert_with(|| {
                out.positions.push(mesh.positions[v as usize]);
                flags.push(pinned[v as usize]);
                out.positions.len() as u32 - 1
            })
        });
        out.triangles.push(t);
        out.normals.extend_from_slice(&mesh.normals[corners(!mesh.normals.is_empty(), f)]);
        out.uvs.extend_from_slice(&mesh.uvs[corners(!mesh.uvs.is_empty(), f)]);
        out.colors.extend_from_slice(&mesh.colors[corners(!mesh.colors.is_empty(), f)]);
        if !mesh.face_materials.is_empty() {
            out.face_materials.push(mesh.face_materials[f as usize]);
        }
        out.face_normals.push(mesh.face_normals[f as usize]);
        out.face_areas.push(mesh.face_areas[f as usize]);
    }
    (out, flags)
}

/// The vertices of `mesh` used by faces of two groups (`labels` per face): pinned while the level
/// simplifies, so that each group's result meets its neighbours' edge for edge.
pub fn shared_vertices(mesh: &Mesh, labels: &[u32]) -> Vec<bool> {
    let mut first = vec![u32::MAX; mesh.positions.len()];
    let mut pinned = vec![false; mesh.positions.len()];
    for (t, &g) in mesh.triangles.iter().zip(labels) {
        for &v in t {
            let f = &mut first[v as usize];
            if *f == u32::MAX {
                *f = g;
            } else if *f != g {
                pinned[v as usize] = true;
            }
        }
    }
    pinned
}

/// The median of node sizes `sizes` (the upper one of an even count; `None` when there are none).
pub fn median_size(sizes: impl Iterator<Item = usize>) -> Option<usize> {
    let mut sizes: Vec<usize> = sizes.collect();
    sizes.sort_unstable();
    sizes.get(sizes.len() / 2).copied()
}

/// Reorder `mesh`'s faces so that each of `pieces` is a run, and append the pieces as nodes of
/// `level` made by `sources`.
fn place(mesh: Mesh, level: usize, pieces: Vec<Vec<u32>>, sources: &[u32], nodes: &mut Vec<Node>) -> Mesh {
    let order: Vec<usize> = pieces.iter().flatten().map(|&f| f as usize).collect();
    let mesh = mesh.subset(&order);
    let mut start = 0u32;
    for (piece, &source) in pieces.iter().zip(sources) {
        let faces = start..start + piece.len() as u32;
        start = faces.end;
        let tris = &mesh.triangles[faces.start as usize..faces.end as usize];
        let (lo, hi) = box_of(tris.iter().flatten().map(|&v| mesh.positions[v as usize])).unwrap_or_default();
        let center = (lo + hi) * 0.5;
        let radius = tris.iter().flatten().map(|&v| mesh.positions[v as usize].distance(center)).fold(0.0, f32::max);
        let normals: Vec<Vec3> =
            mesh.face_normals[faces.start as usize..faces.end as usize].iter().copied().filter(|n| *n != Vec3::ZERO).collect();
        nodes.push(Node { level: level as u32, faces, center, radius, cone: smallest_enclosing(&normals), source, consumer: NONE });
    }
    mesh
}

/// A sphere holding every sphere of `spheres`.
fn enclosing(spheres: &[(Vec3, f32)]) -> (Vec3, f32) {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for &(c, r) in spheres {
        lo = lo.min(c - r);
        hi = hi.max(c + r);
    }
    let center = (lo + hi) * 0.5;
    (center, spheres.iter().map(|&(c, r)| c.distance(center) + r).fold(0.0, f32::max))
}

/// Lists `0..n` of the items of `(list, item)` pairs, items in increasing order within a list.
fn lists(pairs: &[(u32, u32)], n: usize) -> Lists {
    let labels: Vec<u32> = pairs.iter().map(|p| p.0).collect();
    let by = Lists::from_labels(&labels, n);
    Lists { offsets: by.offsets, items: by.items.iter().map(|&i| pairs[i as usize].1).collect() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_batch_spends_its_collapses_where_they_cost_least() {
        // A height field, flat where x < 0.5 and rough beyond, in two groups split there: halving
        // the two together keeps more of the rough one than half, and less of the flat one.
        let mut mesh = crate::fixtures::open_grid(40);
        for p in &mut mesh.positions {
            if p.x < 0.5 {
                p.z = 0.0;
            }
        }
        mesh.normals.clear();
        mesh.uvs.clear();
        mesh.compute_face_geometry();
        let labels: Vec<u32> =
            mesh.triangles.iter().map(|t| u32::from(t.iter().map(|&v| mesh.positions[v as usize].x).sum::<f32>() > 1.5)).collect();
        let pinned = shared_vertices(&mesh, &labels);
        let s = simplify_each(&mesh, &labels, 2, &pinned, 0.5);
        let before = |g: u32| labels.iter().filter(|&&l| l == g).count();
        let after = |g: u32| s.face_groups.iter().filter(|&&l| l == g).count();
        assert_eq!(s.face_groups.len(), s.mesh.triangles.len());
        assert!(s.mesh.triangles.len() <= mesh.triangles.len() / 2 + 1, "{} faces left", s.mesh.triangles.len());
        assert!(2 * after(0) < before(0), "flat: {} of {}", after(0), before(0));
        assert!(2 * after(1) > before(1), "rough: {} of {}", after(1), before(1));
        // Their border stays where it was, vertex for vertex.
        let border = |m: &Mesh, p: &[bool]| {
            let mut keys: Vec<[u32; 3]> = m.positions.iter().zip(p).filter(|(_, &p)| p).map(|(&x, _)| position_key(x)).collect();
            keys.sort_unstable();
            keys
        };
        let out_pinned = shared_vertices(&s.mesh, &s.face_groups);
        assert_eq!(border(&mesh, &pinned), border(&s.mesh, &out_pinned));
    }
}
