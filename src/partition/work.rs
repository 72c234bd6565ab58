//! The work of the partitioned build of a tree (a DAG's is [`super::dag`], which shares the cells'
//! reading and the rounds' plan from here), in three kinds of piece, each an in-core build of a
//! part of the mesh of at most a cell's size:
//! - a **cell**: its faces from its file, its finest levels built with its border locked;
//! - a **part**: the tops of neighbouring cells (or parts) welded into one mesh, a few more
//!   levels built on it with the part's outer border locked — the old borders inside it are now
//!   free to simplify — while the tops together are larger than a cell;
//! - the **merge**: all the tops, the coarsest levels, borders free.
//!
//! Pieces of one round run on `threads` workers at once (each piece's own steps in parallel
//! inside it) and add their nodes to the one [`Writer`]. Neighbours across pieces are found from
//! their open edges (locked, so the same at every level a piece builds) and linked at the end.

use super::cells::{read_cell, Layout};
use super::tops::{Spilled, Top};
use crate::bounds::NodeBounds;
use crate::error::{Error, Result};
use crate::format::{Attributes, Grid, HierarchyParams, Prepared, WriteSummary, Writer};
use crate::hierarchy::{self, Hierarchy, Level};
use crate::levels::position_key;
use crate::levels::{self, LevelMesh, LevelMeshes, LevelParams};
use crate::mesh::{Adjacency, Mesh};
use crate::pipeline::Progress;
use crate::write::{Looks, Piece, Place, Precision};
use glam::Vec3;
use rustc_hash::{FxHashMap, FxHashSet};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;

/// Positions (as [`position_key`]s) a piece keeps: those it shares with other pieces.
pub(super) type Pins = FxHashSet<[u32; 3]>;

/// A node key of levels a cell or part builds: the piece in the high bits, its group (a DAG's
/// piece: its node or group) in the low ones, so that pieces name their nodes without asking each
/// other.
pub(super) const GROUP_BITS: u32 = 20;
pub(super) const MAX_PIECES: usize = 1 << (32 - GROUP_BITS);

pub(super) fn piece_key(piece: usize, group: u32) -> u32 {
    (piece as u32) << GROUP_BITS | group
}

/// What every piece of work shares.
pub struct Job<'a> {
    /// The input, which errors name.
    pub input: &'a Path,
    pub hierarchy: HierarchyParams,
    pub levels: LevelParams,
    pub grid: Grid,
    pub attributes: Attributes,
    /// Node levels a cell builds below its top.
    pub cell_levels: usize,
    /// Faces a cell holds at most; parts are cut to about as many.
    pub cell_faces: u64,
    pub layout: Layout,
    /// The sums of the shared vertices' face normals, when normals are computed.
    pub shared_sums: Option<&'a super::vertex_normals::SharedSums>,
    /// Per welded input vertex, a bit: whether faces of more than one cell use it. Cells pin
    /// those vertices.
    pub shared: &'a [u64],
    /// Input vertices: cell files' vertex ids lie below.
    pub vertices: u64,
    /// Corners whose face turns more than this from their vertex's normal keep the face's normal.
    pub crease: f32,
    /// Format 3's quantization, `None` for format 2.
    pub precision: Option<Precision>,
    /// The input's materials, which faces index.
    pub materials: &'a [crate::mesh::Material],
    /// Whether the file has images (then nodes get their UV density).
    pub textured: bool,
    /// Whether nodes store normals derived from each level's geometry (the computed ones).
    pub derive_normals: bool,
    /// The folder where tops wait between rounds.
    pub temp: &'a Path,
}

impl Job<'_> {
    /// Keep `top`, piece `p`'s of round `round`, in a file until the next round.
    fn spill(&self, top: Option<Top>, round: usize, p: usize) -> Result<Option<Spilled>> {
        top.map(|t| t.spill(self.temp.join(format!("top-{round}-{p}")))).transpose()
    }

    /// What every piece's nodes store besides positions and faces.
    fn looks(&self) -> Looks {
        Looks { attributes: self.attributes, precision: self.precision, textured: self.textured, derive_normals: self.derive_normals }
    }
}

/// A piece's open edges, by their ends' positions (lower first), with the node key on their side
/// at each of the levels `first..first + keys.len()`.
struct Border {
    first: u32,
    edges: Vec<([u32; 6], Vec<u32>)>,
}

/// What the rounds gather besides the tops (a DAG's build gathers no borders).
#[derive(Default)]
pub(super) struct Gathered {
    borders: Vec<Border>,
    pub warnings: Vec<String>,
    /// Degenerate and duplicate faces the cells removed.
    pub removed: (usize, usize),
    /// Level-0 vertices of the cells, and vertices welded away since (shared by two pieces).
    pub vertices: usize,
    pub welded: usize,
    /// Faces of each level-0 node of the cells (a DAG's build; the parts and the merge cut their
    /// nodes to the median).
    pub node_sizes: Vec<u32>,
}

impl Gathered {
    /// Give `writer` the input's vertex count (the cells', less those welded away) and return
    /// the warnings, the faces the cells removed first.
    pub(super) fn finish<W: Write>(mut self, writer: &mut Writer<W>) -> Vec<String> {
        if self.removed.0 + self.removed.1 > 0 {
            self.warnings.insert(0, format!("removed {} degenerate and {} duplicate faces", self.removed.0, self.removed.1));
        }
        writer.set_input_vertices(self.vertices.saturating_sub(self.welded) as u64);
        self.warnings
    }
}

/// Build the file from the cell files `spooled` (file, faces): the cells, parts while the tops
/// are larger than a cell, then the merge, then the links; returns what was written and the
/// warnings of the cells.
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
    let writer = Mutex::new(writer);
    let gathered = Mutex::new(Gathered::default());
    progress.stage("cells", spooled.len() as u64);
    let mut tops: Vec<Spilled> =
        run(spooled.len(), threads, progress, |c| job.spill(cell(job, c, &spooled[c].0, spooled[c].1, &writer, &gathered)?, 0, c))?
            .into_iter()
            .flatten()
            .collect();
    if tops.is_empty() {
        return Err(Error::invalid(job.input, None, "no faces left after removing degenerate and duplicate faces"));
    }
    let mut first = job.cell_levels;
    let mut round = 0;
    while let Some(Round { faces, levels, pins, waiting }) = plan_round(job, &mut tops, round)? {
        writer.lock().map_err(|_| poisoned())?.set_levels((first + levels + 1) as u32)?;
        let parts = waiting.len();
        progress.stage(&format!("parts, round {}", round + 1), parts as u64);
        let waiting = Mutex::new(waiting);
        let next = run(parts, threads, progress, |p| {
            let spilled = waiting.lock().map_err(|_| poisoned())?[p].take().unwrap_or_default();
            let part = spilled.into_iter().map(Spilled::load).collect::<Result<Vec<Top>>>()?;
            // The part's own shared positions: a simplified vertex may land where other parts meet.
            let own: Pins =
                part.iter().flat_map(|t| t.level.mesh.positions.iter().map(|&q| position_key(q))).filter(|k| pins.contains(k)).collect();
            job.spill(merge(job, part, first, Some((p, levels, &own)), &writer, &gathered)?, round + 1, p)
        })?;
        drop(pins);
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
    let tops = tops.into_iter().map(Spilled::load).collect::<Result<Vec<Top>>>()?;
    merge(job, tops, first, None, &writer, &gathered)?;
    let mut writer = writer.into_inner().map_err(|_| poisoned())?;
    let mut g = gathered.into_inner().map_err(|_| poisoned())?;
    link(&mut writer, &std::mem::take(&mut g.borders));
    let warnings = g.finish(&mut writer);
    Ok((writer.finish()?, warnings))
}

/// A round of parts: the faces of the tops it takes, the levels each part builds, the positions
/// two parts share (each part's outer border) and each part's tops.
pub(super) struct Round {
    pub faces: usize,
    pub levels: usize,
    pub pins: Pins,
    pub waiting: Vec<Option<Vec<Spilled>>>,
}

/// The next round of parts over `tops` (taken from it), or `None` when the tops are down to
/// about a cell's faces (or rounds run out) and go to the merge as they are.
pub(super) fn plan_round(job: &Job, tops: &mut Vec<Spilled>, round: usize) -> Result<Option<Round>> {
    let faces: usize = tops.iter().map(|t| t.faces).sum();
    let parts = faces.div_ceil(job.cell_faces.max(1) as usize);
    if parts <= 1 || tops.len() < 2 || round == MAX_ROUNDS {
        return Ok(None);
    }
    // Consecutive tops are neighbouring cells (the kd-tree's leaf order): runs of them of about a
    // cell's faces make the parts.
    let runs = runs(tops, parts);
    let mut part_of: FxHashMap<[u32; 3], u32> = FxHashMap::default();
    for (p, r) in runs.iter().enumerate() {
        for t in &tops[r.clone()] {
            for q in t.positions()? {
                let e = part_of.entry(position_key(q)).or_insert(p as u32);
                if *e != p as u32 {
                    *e = u32::MAX;
                }
            }
        }
    }
    // Each top's positions are read here and again when its part loads it.
    let pins: Pins = part_of.into_iter().filter(|&(_, p)| p == u32::MAX).map(|(k, _)| k).collect();
    let mut rest = std::mem::take(tops).into_iter();
    let waiting = runs.iter().map(|r| Some(rest.by_ref().take(r.len()).collect())).collect();
    Ok(Some(Round { faces, levels: part_levels(faces / parts), pins, waiting }))
}

/// The warning for a final merge of `tops` that memory may not hold.
pub(super) fn final_merge_warning(job: &Job, tops: &[Spilled]) -> Option<String> {
    let faces: u64 = tops.iter().map(|t| t.faces as u64).sum();
    (faces > 2 * job.cell_faces).then(|| {
        format!(
            "the final merge holds {faces} faces, more than twice a cell's {}: the mesh simplifies little at its cells' borders \
             (many separate pieces?), and memory may go past --memory",
            job.cell_faces
        )
    })
}

/// Rounds of parts at most: each makes the tops smaller by a few levels.
const MAX_ROUNDS: usize = 16;

pub(super) fn poisoned() -> Error {
    Error::invalid(Path::new("partitioned build"), None, "a worker thread panicked")
}

/// Run `work(i)` for `i in 0..n` on `threads` workers, results in order; the first error stops
/// the rest. Progress steps on this thread as pieces finish.
pub(super) fn run<T: Send>(
    n: usize,
    threads: usize,
    progress: &mut dyn Progress,
    work: impl Fn(usize) -> Result<T> + Sync,
) -> Result<Vec<T>> {
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let (tx, rx) = std::sync::mpsc::channel::<(usize, Result<T>)>();
    let mut out: Vec<Option<T>> = (0..n).map(|_| None).collect();
    let mut failure = None;
    std::thread::scope(|s| {
        for _ in 0..threads.max(1).min(n.max(1)) {
            let tx = tx.clone();
            let (next, stop, work) = (&next, &stop, &work);
            s.spawn(move || loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= n || stop.load(Ordering::Relaxed) {
                    break;
                }
                let r = work(i);
                super::release_memory();
                if r.is_err() {
                    stop.store(true, Ordering::Relaxed);
                }
                let _ = tx.send((i, r));
            });
        }
        drop(tx);
        for (i, r) in rx {
            progress.step();
            match r {
                Ok(t) => out[i] = Some(t),
                Err(e) => {
                    failure.get_or_insert(e);
                }
            }
        }
    });
    match failure {
        Some(e) => Err(e),
        None => Ok(out.into_iter().map(|t| t.expect("every piece ran")).collect()),
    }
}

/// Split `tops` into `parts` runs of consecutive tops with about equal faces.
fn runs(tops: &[Spilled], parts: usize) -> Vec<std::ops::Range<usize>> {
    let total: usize = tops.iter().map(|t| t.faces).sum();
    let mut out = Vec::with_capacity(parts);
    let (mut start, mut sum) = (0, 0);
    for (i, t) in tops.iter().enumerate() {
        sum += t.faces;
        if sum * parts >= total * (out.len() + 1) && i + 1 > start {
            out.push(start..i + 1);
            start = i + 1;
        }
    }
    if start < tops.len() {
        out.push(start..tops.len());
    }
    out
}

/// Levels a part of `faces` faces builds: as for a cell, but its border is already long (it is
/// made of the borders of the pieces it holds), so fewer.
fn part_levels(faces: usize) -> usize {
    (super::cell_levels(faces as u64) / 2).max(1)
}

/// Build cell `c` from its file; `None` when it holds no faces.
fn cell<W: Write>(
    job: &Job,
    c: usize,
    path: &Path,
    faces: u64,
    writer: &Mutex<Writer<W>>,
    gathered: &Mutex<Gathered>,
) -> Result<Option<Top>> {
    let Some(Loaded { mesh, pinned, removed }) = load_cell(job, c, path, faces)? else {
        return Ok(None);
    };
    {
        let mut g = gathered.lock().map_err(|_| poisoned())?;
        g.removed.0 += removed.0;
        g.removed.1 += removed.1;
    }
    if mesh.face_count() == 0 {
        return Ok(None);
    }
    let vertices = mesh.vertex_count();
    let adjacency = Adjacency::build(&mesh);
    let k = job.cell_levels;
    let mut h = hierarchy::build_levels(&mesh, &adjacency, &job.hierarchy, Some(k + 1));
    drop(adjacency);
    let p = LevelParams { top_faces: usize::MAX, ..job.levels };
    let first = LevelMesh { face_group: h.levels[0].face_group.clone(), group_error: vec![0.0; h.levels[0].groups.len()], mesh };
    let lv = levels::build_from(first, &mut h, &p, Some(&pinned), &mut |_| {});
    let bad = |m: String| Error::invalid(job.input, None, format!("cell {c}: {m}"));
    let keys = |_: usize, g: u32| piece_key(c, g);
    let top = finish_piece(job, h, lv, Base::Input, &pinned, 0, k, &keys, writer, gathered, &bad)?;
    gathered.lock().map_err(|_| poisoned())?.vertices += vertices;
    Ok(top)
}

/// A cell read back: its mesh cleaned, the positions it shares with other cells, and the
/// degenerate and duplicate faces cleaning removed.
pub(super) struct Loaded {
    pub mesh: Mesh,
    pub pinned: Pins,
    pub removed: (usize, usize),
}

/// Read cell `c` (`faces` faces in the file at `path`, which goes once read), with its computed
/// normals when normals are computed; `None` when it holds no faces.
pub(super) fn load_cell(job: &Job, c: usize, path: &Path, faces: u64) -> Result<Option<Loaded>> {
    if faces == 0 {
        return Ok(None);
    }
    let (mut mesh, ids) = read_cell(path, faces, job.layout, job.vertices, job.materials.len())?;
    mesh.materials = job.materials.to_vec();
    let _ = std::fs::remove_file(path);
    if let Some(sums) = job.shared_sums {
        mesh.compute_face_geometry();
        let cos = job.crease.cos();
        let smooth = super::vertex_normals::smooth(&mesh.positions, &mesh.triangles, &ids, job.shared, sums);
        mesh.normals = (0..3 * mesh.triangles.len())
            .map(|i| {
                let n = smooth[mesh.triangles[i / 3][i % 3] as usize];
                let f = mesh.face_normals[i / 3];
                if f == Vec3::ZERO || n.dot(f) >= cos {
                    n
                } else {
                    f
                }
            })
            .collect();
    }
    let pinned: Pins =
        ids.iter().zip(&mesh.positions).filter(|(&i, _)| super::is_shared(job.shared, i)).map(|(_, &p)| position_key(p)).collect();
    drop(ids);
    let (mesh, report) = mesh.clean().map_err(|_| Error::invalid(job.input, None, format!("cell {c}: a vertex is not finite")))?;
    Ok(Some(Loaded { mesh, pinned, removed: (report.degenerate_faces, report.duplicate_faces) }))
}

/// Weld `tops` (whose level is file level `first`) into one mesh and build on it: with
/// `part: Some((p, levels, pinned))`, `levels` more levels with the vertices at `pinned` (its
/// outer border) kept, returning the new top; without, the coarsest levels of the file.
fn merge<W: Write>(
    job: &Job,
    tops: Vec<Top>,
    first: usize,
    part: Option<(usize, usize, &FxHashSet<[u32; 3]>)>,
    writer: &Mutex<Writer<W>>,
    gathered: &Mutex<Gathered>,
) -> Result<Option<Top>> {
    let mut mesh = Mesh { materials: job.materials.to_vec(), ..Mesh::default() };
    let (mut face_group, mut group_error, mut groups, mut bounds, mut keys) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut at: FxHashMap<[u32; 3], u32> = FxHashMap::default();
    let (mut max_angle, mut max_faces, mut before) = (0f32, 0u32, 0usize);
    for t in tops {
        let base = groups.len() as u32;
        let m = &t.level.mesh;
        let remap: Vec<u32> = m
            .positions
            .iter()
            .map(|&p| {
                let next = mesh.positions.len() as u32;
                *at.entry(position_key(p)).or_insert_with(|| {
                    mesh.positions.push(p);
                    next
                })
            })
            .collect();
        mesh.append_faces(m, &remap);
        face_group.extend(t.level.face_group.iter().map(|&g| base + g));
        group_error.extend_from_slice(&t.level.group_error);
        keys.extend_from_slice(&t.keys);
        groups.extend(t.groups);
        bounds.extend(t.bounds);
        (max_angle, max_faces) = (max_angle.max(t.max_angle), max_faces.max(t.max_faces));
        before += m.vertex_count();
    }
    drop(at);
    if mesh.face_count() == 0 {
        return Ok(None);
    }
    gathered.lock().map_err(|_| poisoned())?.welded += before - mesh.vertex_count();
    mesh.compute_face_geometry();
    let base = Level {
        face_group: face_group.clone(),
        groups,
        parent: Vec::new(),
        children: Default::default(),
        neighbors: Default::default(),
        max_angle,
        max_faces,
    };
    let adjacency = Adjacency::build(&mesh);
    let mut h = hierarchy::extend(&mesh, &adjacency, base, &job.hierarchy, part.map(|(_, n, _)| n + 1));
    drop(adjacency);
    let first_level = LevelMesh { mesh, face_group, group_error };
    let bad = |m: String| Error::invalid(job.input, None, format!("merging cells: {m}"));
    match part {
        Some((p, n, pinned)) => {
            let lp = LevelParams { top_faces: usize::MAX, ..job.levels };
            let lv = levels::build_from(first_level, &mut h, &lp, Some(pinned), &mut |_| {});
            let key = |l: usize, g: u32| if l == 0 { keys[g as usize] } else { piece_key(p, g) };
            finish_piece(job, h, lv, Base::Tops(bounds), pinned, first, n, &key, writer, gathered, &bad)
        }
        None => {
            let lv = levels::build_from(first_level, &mut h, &job.levels, None, &mut |_| {});
            let piece = Piece::new(&h, &lv, &job.grid, job.precision, Some(bounds), &[], lv.levels.len()).map_err(bad)?;
            let file_levels = first + h.levels.len();
            let mut w = writer.lock().map_err(|_| poisoned())?;
            w.set_levels(file_levels as u32)?;
            let preparer = w.preparer();
            let place = Place {
                offset: first,
                levels: 0..h.levels.len(),
                file_levels,
                key: &|l, g| if l == 0 { keys[g as usize] } else { g },
                shared: None,
            };
            piece.add(&preparer, &mut |n| w.add_prepared(n), &bad, &h, &lv, &job.grid, job.looks(), &place)?;
            Ok(None)
        }
    }
}

/// What a piece's level 0 is: the input (a cell), or tops whose bounds are known (a part).
enum Base {
    Input,
    Tops(Vec<NodeBounds>),
}

/// Write the levels `0..n` of a cell or part (piece level `l` is file level `first + l`, keys
/// from `key`; `pinned`, the positions it shares with other pieces), record its open edges, and
/// return its top (level `n`).
#[allow(clippy::too_many_arguments)]
fn finish_piece<W: Write>(
    job: &Job,
    mut h: Hierarchy,
    lv: LevelMeshes,
    base: Base,
    pinned: &Pins,
    first: usize,
    n: usize,
    key: &(dyn Fn(usize, u32) -> u32 + Sync),
    writer: &Mutex<Writer<W>>,
    gathered: &Mutex<Gathered>,
    bad: &(dyn Fn(String) -> Error + Sync),
) -> Result<Option<Top>> {
    if let Some(g) = h.levels.iter().map(|l| l.groups.len()).find(|&g| g >= 1 << GROUP_BITS) {
        return Err(bad(format!("{g} groups in one level, at most {}", 1 << GROUP_BITS)));
    }
    let piece = match base {
        Base::Input => {
            // The input's vertices it shares with other cells keep their grid points exactly.
            Piece::new(&h, &lv, &job.grid, job.precision, None, &levels::pinned_flags(&lv.levels[0].mesh, pinned), n)
        }
        Base::Tops(bounds) => Piece::new(&h, &lv, &job.grid, job.precision, Some(bounds), &[], n),
    }
    .map_err(bad)?;
    let border = Border { first: first as u32, edges: border_edges(&lv.levels[..n], &|l, g| key(l, g)) };
    let place = Place { offset: first, levels: 0..n, file_levels: usize::MAX, key, shared: Some(pinned) };
    let preparer = writer.lock().map_err(|_| poisoned())?.preparer();
    let mut add = |node: Prepared| writer.lock().map_err(|_| poisoned())?.add_prepared(node);
    piece.add(&preparer, &mut add, bad, &h, &lv, &job.grid, job.looks(), &place)?;
    gathered.lock().map_err(|_| poisoned())?.borders.push(border);
    let mut levels = lv.levels;
    let level = levels.swap_remove(n);
    let top = h.levels.swap_remove(n);
    let bounds = piece.bounds.into_iter().nth(n).unwrap_or_default();
    let keys = (0..top.groups.len() as u32).map(|g| key(n, g)).collect();
    Ok(Some(Top { level, groups: top.groups, bounds, keys, max_angle: top.max_angle, max_faces: top.max_faces }))
}

/// The open edges of `levels[0]`, by their ends' positions, with the key of the node on their
/// side at every level of `levels`. Edges between pieces join pinned vertices, so every level has
/// them; edges of the input's own holes may simplify away, and an edge some level lacks is
/// dropped (no other piece has it).
fn border_edges(levels: &[LevelMesh], key: &dyn Fn(usize, u32) -> u32) -> Vec<([u32; 6], Vec<u32>)> {
    let open = |m: &Mesh, face_group: &[u32]| -> FxHashMap<[u32; 6], u32> {
        let mut count: FxHashMap<u64, (u32, u32)> = FxHashMap::default();
        for (f, t) in m.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
                let e = count.entry((a as u64) << 32 | b as u64).or_insert((0, f as u32));
                e.0 += 1;
            }
        }
        count
            .into_iter()
            .filter(|(_, (n, _))| *n == 1)
            .map(|(e, (_, f))| {
                let (a, b) = (position_key(m.positions[(e >> 32) as usize]), position_key(m.positions[e as u32 as usize]));
                let (a, b) = if a <= b { (a, b) } else { (b, a) };
                ([a[0], a[1], a[2], b[0], b[1], b[2]], face_group[f as usize])
            })
            .collect()
    };
    let per_level: Vec<FxHashMap<[u32; 6], u32>> = levels.iter().map(|l| open(&l.mesh, &l.face_group)).collect();
    let Some(first) = per_level.first() else { return Vec::new() };
    let mut out: Vec<([u32; 6], Vec<u32>)> = first
        .keys()
        .filter_map(|e| {
            let groups: Option<Vec<u32>> = per_level.iter().enumerate().map(|(l, m)| m.get(e).map(|&g| key(l, g))).collect();
            groups.map(|g| (*e, g))
        })
        .collect();
    out.sort_unstable_by_key(|a| a.0);
    out
}

/// Link the nodes on the two sides of every open edge two pieces of the same round share.
fn link<W: Write>(writer: &mut Writer<W>, borders: &[Border]) {
    let mut seen: FxHashMap<(u32, [u32; 6]), &[u32]> = FxHashMap::default();
    for b in borders {
        for (e, keys) in &b.edges {
            if let Some(other) = seen.insert((b.first, *e), keys) {
                for (l, (&x, &y)) in other.iter().zip(keys).enumerate() {
                    writer.link(b.first + l as u32, x, y);
                }
            }
        }
    }
}
