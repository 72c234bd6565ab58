//! The partitioned build of a DAG (format 4), for meshes larger than memory: the same cells as the
//! tree's ([`super::work`]), each built as a DAG ([`crate::dag`]) of a few levels with the
//! positions it shares with other cells pinned at every level; then parts, each the tops of
//! neighbouring pieces welded at those positions and built a few levels more with only the part's
//! outer border pinned, while the tops are larger than a cell; then the merge of all the tops,
//! built until the top is small.
//!
//! A piece's border is pinned like a group's border, so pieces meet as groups do: the DAG is one
//! DAG, crack-free by construction (selection.md §9), whose groups at a cell's or part's
//! border are the ones that lie inside one piece. A piece writes the nodes and groups it makes,
//! its top nodes among them; the piece that builds on a top sets their consumers. Tops wait in
//! temporary files between rounds, with the grid points their vertices were stored on, so that
//! the next piece keeps those vertices where the file has them.

use super::tops::{DagTop, Spilled};
use super::work::{
    final_merge_warning, load_cell, piece_key, plan_round, poisoned, run, Gathered, Job, Loaded, Pins, Round, GROUP_BITS, MAX_PIECES,
};
use crate::dag::write::{write_levels, Base, Place};
use crate::dag::{build_from, median_size, Bounds, DagParams, Group, Start};
use crate::error::{Error, Result};
use crate::format::{WriteSummary, Writer};
use crate::hierarchy;
use crate::levels::position_key;
use crate::mesh::{Adjacency, Mesh};
use crate::pipeline::Progress;
use rustc_hash::FxHashMap;
use std::io::Write;
use std::path::PathBuf;
use std::sync::Mutex;

/// Build the file from the cell files `spooled` (file, faces) as a DAG: the cells, parts while the
/// tops are larger than a cell, then the merge; returns what was written and the cells' warnings.
pub fn build<W: Write + Send>(
    job: &Job,
    spooled: &[(PathBuf, u64)],
    writer: Writer<W>,
    threads: usize,
    progress: &mut dyn Progress,
) -> Result<(WriteSummary, Vec<String>)> {
    if spooled.len() >= MAX_PIECES {
        return Err(Error::invalid(job.input, None, format!("{} cells: at most {}", spooled.len(), MAX_PIECES - 1)));
    }
    let params = DagParams { ratio: job.levels.ratio, top_faces: job.levels.top_faces };
    let writer = Mutex::new(writer);
    let gathered = Mutex::new(Gathered::default());
    let spill = |top: Option<DagTop>, round: usize, p: usize| -> Result<Option<Spilled>> {
        top.map(|t| t.spill(job.temp.join(format!("dag-top-{round}-{p}")))).transpose()
    };
    progress.stage("cells", spooled.len() as u64);
    let mut tops: Vec<Spilled> =
        run(spooled.len(), threads, progress, |c| spill(cell(job, c, &spooled[c].0, spooled[c].1, &params, &writer, &gathered)?, 0, c))?
            .into_iter()
            .flatten()
            .collect();
    if tops.is_empty() {
        return Err(Error::invalid(job.input, None, "no faces left after removing degenerate and duplicate faces"));
    }
    let sizes = std::mem::take(&mut gathered.lock().map_err(|_| poisoned())?.node_sizes);
    let node_faces = median_size(sizes.into_iter().map(|n| n as usize));
    let mut first = job.cell_levels;
    let mut next_piece = spooled.len();
    let mut round = 0;
    while let Some(Round { faces, levels, pins, waiting }) = plan_round(job, &mut tops, round)? {
        let parts = waiting.len();
        if next_piece + parts >= MAX_PIECES {
            tops = waiting.into_iter().flatten().flatten().collect();
            break;
        }
        progress.stage(&format!("parts, round {}", round + 1), parts as u64);
        let waiting = Mutex::new(waiting);
        let next = run(parts, threads, progress, |p| {
            let spilled = waiting.lock().map_err(|_| poisoned())?[p].take().unwrap_or_default();
            let part = spilled.into_iter().map(Spilled::load_dag).collect::<Result<Vec<DagTop>>>()?;
            // The part's own shared positions (a smaller set to look up), as the tree's parts.
            let own: Pins =
                part.iter().flat_map(|t| t.mesh.positions.iter().map(|&q| position_key(q))).filter(|k| pins.contains(k)).collect();
            let shape = Shape { first, bounds: Bounds { levels: Some(levels), pinned: Some(&own), node_faces } };
            spill(merge(job, part, next_piece + p, shape, &params, &writer, &gathered)?, round + 1, p)
        })?;
        drop(pins);
        next_piece += parts;
        tops = next.into_iter().flatten().collect();
        let after: usize = tops.iter().map(|t| t.faces).sum();
        first += levels;
        round += 1;
        if after * 4 > faces * 3 {
            break;
        }
    }
    if let Some(w) = final_merge_warning(job, &tops) {
        gathered.lock().map_err(|_| poisoned())?.warnings.push(w);
    }
    progress.stage("merge", 0);
    let tops = tops.into_iter().map(Spilled::load_dag).collect::<Result<Vec<DagTop>>>()?;
    merge(job, tops, next_piece, Shape { first, bounds: Bounds { node_faces, ..Bounds::default() } }, &params, &writer, &gathered)?;
    let mut writer = writer.into_inner().map_err(|_| poisoned())?;
    let warnings = gathered.into_inner().map_err(|_| poisoned())?.finish(&mut writer);
    Ok((writer.finish()?, warnings))
}

/// Where a piece's levels go: its level 0 is file level `first`; it builds on it within `bounds`.
struct Shape<'a> {
    first: usize,
    bounds: Bounds<'a>,
}

/// Build cell `c` from its file as a DAG of [`Job::cell_levels`] levels; `None` when it holds no
/// faces.
fn cell<W: Write>(
    job: &Job,
    c: usize,
    path: &std::path::Path,
    faces: u64,
    params: &DagParams,
    writer: &Mutex<Writer<W>>,
    gathered: &Mutex<Gathered>,
) -> Result<Option<DagTop>> {
    let Some(Loaded { mesh, pinned, removed }) = load_cell(job, c, path, faces)? else {
        return Ok(None);
    };
    {
        let mut g = gathered.lock().map_err(|_| poisoned())?;
        g.removed.0 += removed.0;
        g.removed.1 += removed.1;
        g.vertices += mesh.vertex_count();
    }
    if mesh.face_count() == 0 {
        return Ok(None);
    }
    let adjacency = Adjacency::build(&mesh);
    let h = hierarchy::build_levels(&mesh, &adjacency, &job.hierarchy, Some(1));
    drop(adjacency);
    let start = Start { mesh, labels: h.levels[0].face_group.clone(), made_by: Vec::new() };
    let shape = Shape { first: 0, bounds: Bounds { levels: Some(job.cell_levels), pinned: Some(&pinned), node_faces: None } };
    let bad = |m: String| Error::invalid(job.input, None, format!("cell {c}: {m}"));
    let base = Base::Input { clusters: &h.clusters, pinned: Some(&pinned) };
    piece(job, start, base, c, &[], &shape, params, writer, gathered, &bad)
}

/// Weld `tops` at the positions they share into one mesh and build piece `p` on it; returns its
/// top, or `None` for the merge, whose top is the file's.
fn merge<W: Write>(
    job: &Job,
    tops: Vec<DagTop>,
    p: usize,
    shape: Shape,
    params: &DagParams,
    writer: &Mutex<Writer<W>>,
    gathered: &Mutex<Gathered>,
) -> Result<Option<DagTop>> {
    let mut mesh = Mesh { materials: job.materials.to_vec(), ..Mesh::default() };
    let (mut labels, mut made_by, mut keys, mut stored) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut points: FxHashMap<[u32; 3], [u32; 3]> = FxHashMap::default();
    // Per position, the top that holds it first and its first vertex there: a later top's vertex
    // at that position is welded to it. Within one top, vertices at one position stay apart (a
    // topology change may have cut a vertex in two; never a pinned one, so never one two tops
    // share).
    let mut at: FxHashMap<[u32; 3], (usize, u32)> = FxHashMap::default();
    let mut welded = 0;
    for (t, top) in tops.into_iter().enumerate() {
        let m = &top.mesh;
        let remap: Vec<u32> = m
            .positions
            .iter()
            .zip(&top.points)
            .map(|(&x, &g)| {
                let key = position_key(x);
                points.insert(key, g);
                let next = mesh.positions.len() as u32;
                match at.get(&key) {
                    Some(&(owner, v)) if owner != t => {
                        welded += 1;
                        v
                    }
                    _ => {
                        at.entry(key).or_insert((t, next));
                        mesh.positions.push(x);
                        next
                    }
                }
            })
            .collect();
        mesh.append_faces(m, &remap);
        // Nodes become labels in order; a source's outputs are a run of them.
        let base = keys.len() as u32;
        for (n, &count) in top.faces.iter().enumerate() {
            labels.extend(std::iter::repeat_n(base + n as u32, count as usize));
        }
        // Each source's outputs, a run of nodes (checked as the top was read).
        let mut outputs = vec![0..0; top.sources.len()];
        for (n, &s) in top.source.iter().enumerate() {
            let r = &mut outputs[s as usize];
            *r = if r.start == r.end { n as u32..n as u32 + 1 } else { r.start..n as u32 + 1 };
        }
        for (source, r) in top.sources.iter().zip(outputs) {
            let outputs = base + r.start..base + r.end;
            made_by.push(Group { level: 0, error: source.error, center: source.center, radius: source.radius, outputs });
        }
        keys.extend_from_slice(&top.keys);
        stored.extend_from_slice(&top.stored);
    }
    drop(at);
    if mesh.face_count() == 0 {
        return Ok(None);
    }
    gathered.lock().map_err(|_| poisoned())?.welded += welded;
    mesh.compute_face_geometry();
    let start = Start { mesh, labels, made_by };
    let bad = |m: String| Error::invalid(job.input, None, format!("piece {p}: {m}"));
    let base = Base::Tops { points: &points, stored: &stored };
    piece(job, start, base, p, &keys, &shape, params, writer, gathered, &bad)
}

/// Build piece `p` from `start` and write it: nodes of levels above its base and their groups,
/// its base's consumers (its level 0 too when that is the input). `base_keys`: the keys of the
/// base's nodes when they were written already.
#[allow(clippy::too_many_arguments)]
fn piece<W: Write>(
    job: &Job,
    start: Start,
    base: Base,
    p: usize,
    base_keys: &[u32],
    shape: &Shape,
    params: &DagParams,
    writer: &Mutex<Writer<W>>,
    gathered: &Mutex<Gathered>,
    bad: &(dyn Fn(String) -> Error + Sync),
) -> Result<Option<DagTop>> {
    let mut dag = build_from(start, params, &shape.bounds, &mut |_, _| {});
    if shape.first == 0 {
        // A cell: its level-0 node sizes set the size of the nodes built on the cells' tops.
        let sizes = dag.level_nodes(0).map(|n| dag.nodes[n as usize].faces.len() as u32);
        gathered.lock().map_err(|_| poisoned())?.node_sizes.extend(sizes);
    }
    if dag.nodes.len().max(dag.groups.len()) >= 1 << GROUP_BITS {
        return Err(bad(format!("{} nodes and {} groups in one piece, at most {}", dag.nodes.len(), dag.groups.len(), 1 << GROUP_BITS)));
    }
    let base_nodes = base_keys.len() as u32;
    let node_key = |n: u32| if n < base_nodes { base_keys[n as usize] } else { piece_key(p, n) };
    let group_key = |g: u32| piece_key(p, g);
    let preparer = {
        let mut w = writer.lock().map_err(|_| poisoned())?;
        let levels = (shape.first + dag.levels.len()) as u32;
        if w.levels() < levels {
            w.set_levels(levels)?;
        }
        w.preparer()
    };
    let place = Place {
        grid: job.grid,
        precision: job.precision.ok_or_else(|| bad("a DAG stores node geometry as format 3 does".into()))?,
        attributes: job.attributes,
        derive_normals: job.derive_normals,
        textured: job.textured,
        first: shape.first as u32,
        node_key: &node_key,
        group_key: &group_key,
        base,
        preparer: &preparer,
    };
    let written = write_levels(&dag, &place, &mut |r| r.add_to(&mut *writer.lock().map_err(|_| poisoned())?), bad)?;
    if shape.bounds.levels.is_none() {
        return Ok(None);
    }
    // The top, for the next round.
    let top = dag.level_nodes(dag.levels.len() - 1);
    let nodes = &dag.nodes[top.start as usize..top.end as usize];
    // A group's outputs are a run of nodes: each run is one source.
    let mut sources: Vec<u32> = Vec::new();
    let mut source = Vec::with_capacity(nodes.len());
    for n in nodes {
        if sources.last() != Some(&n.source) {
            sources.push(n.source);
        }
        source.push(sources.len() as u32 - 1);
    }
    let faces = nodes.iter().map(|n| n.faces.len() as u32).collect();
    Ok(Some(DagTop {
        points: written.points,
        faces,
        keys: top.map(node_key).collect(),
        stored: written.nodes,
        source,
        sources: sources.iter().map(|&s| written.groups.get(s as usize).copied().unwrap_or_default()).collect(),
        mesh: dag.levels.pop().unwrap_or_default(),
    }))
}
