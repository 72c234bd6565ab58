//! Seams between displayed nodes of adjacent levels (selection.md §8): where a node borders
//! displayed nodes one level finer, its border is the simplified version of theirs and the two
//! leave slivers of background between them. Nodes share the file's grid, so a vertex both sides
//! keep has the same position on both: the border edges no other displayed node has the other way
//! round close into loops, each a run of the coarser node's border and a run of the finer nodes'
//! between two shared vertices, and a fan of triangles fills each such loop.
//!
//! Only loops with edges of two levels are filled, and only those no wider on average than the
//! coarser node's error: a hole of the model itself (an open border of the input) that lies along
//! a level change is wider than that unless it is too small to see at that level.

use crate::format::NodeGeometry;
use crate::hierarchy::Lists;
use crate::levels::position_key;
use crate::mesh::triangle_cross;
use glam::Vec3;
use rustc_hash::{FxHashMap, FxHashSet};

/// A position as readers match it across nodes: its coordinates' bits (−0 as +0), as welding
/// compares them ([`position_key`]).
type Key = [u32; 3];

/// One border edge of a node, directed as its face runs: its ends, and the position and normal of
/// the first (the normal is zero when the file has none).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Edge {
    from: Key,
    to: Key,
    at: Vec3,
    normal: Vec3,
}

/// A node's open border: the edges of its faces that no other face of the node has the other way
/// round (edges of zero length and edges the node's faces use twice the same way are left out).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Border {
    level: u32,
    error: f32,
    edges: Vec<Edge>,
}

impl Border {
    /// The border of `g`, a node of `level` with geometric error `error`.
    pub fn of(level: u32, error: f32, g: &NodeGeometry) -> Border {
        // Vertices welded by position, then each directed edge between them with how often the
        // faces use it and the first corner it starts at.
        let mut ids: FxHashMap<Key, u32> = FxHashMap::with_capacity_and_hasher(g.positions.len(), Default::default());
        let mut keys: Vec<Key> = Vec::with_capacity(g.positions.len());
        let weld: Vec<u32> = g
            .positions
            .iter()
            .map(|&p| {
                let k = position_key(p);
                *ids.entry(k).or_insert_with(|| {
                    keys.push(k);
                    keys.len() as u32 - 1
                })
            })
            .collect();
        let pair = |a: u32, b: u32| (a as u64) << 32 | b as u64;
        let mut count: FxHashMap<u64, (u32, u32)> = FxHashMap::with_capacity_and_hasher(g.indices.len(), Default::default());
        for f in g.indices.chunks_exact(3) {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                let (wa, wb) = (weld[a as usize], weld[b as usize]);
                if wa != wb {
                    count.entry(pair(wa, wb)).or_insert((0, a)).0 += 1;
                }
            }
        }
        let mut edges: Vec<Edge> = count
            .iter()
            .filter(|&(&e, &(n, _))| n == 1 && !count.contains_key(&e.rotate_right(32)))
            .map(|(&e, &(_, v))| Edge {
                from: keys[(e >> 32) as usize],
                to: keys[e as u32 as usize],
                at: g.positions[v as usize],
                normal: g.normals.get(v as usize).copied().unwrap_or(Vec3::ZERO),
            })
            .collect();
        // In a fixed order, so that seams do not depend on the hash map's.
        edges.sort_unstable_by_key(|e| (e.from, e.to));
        Border { level, error, edges }
    }
}

/// Triangles that fill the seams of a front, as plain arrays; `normals` is empty when the borders
/// carry none.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Seams {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub indices: Vec<u32>,
}

impl Seams {
    pub fn face_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// The triangles' total area (f64).
    pub fn area(&self) -> f64 {
        self.indices.chunks_exact(3).map(|t| 0.5 * triangle_cross(&self.positions, &[t[0], t[1], t[2]]).length()).sum()
    }
}

/// Per vertex, the open edges leaving it, a queue per level in the order of the open edges:
/// taking the next edge costs the number of levels there, however many edges meet at the vertex.
struct Leaving {
    /// Open edges by vertex, then level, then index.
    order: Vec<u32>,
    /// Runs of `order` of one vertex and level: level, cursor, end.
    queues: Vec<(u32, u32, u32)>,
    /// Per vertex, its queues: `queues[first[v]..first[v + 1]]`.
    first: Vec<u32>,
}

impl Leaving {
    /// The queues of open edges leaving from `from[i]` at `level[i]`, vertices below `vertices`.
    fn new(from: &[u32], level: &[u32], vertices: usize) -> Leaving {
        let Lists { offsets: start, items: mut order } = Lists::from_labels(from, vertices);
        let (mut queues, mut first) = (Vec::new(), Vec::with_capacity(vertices + 1));
        for v in 0..vertices {
            first.push(queues.len() as u32);
            let run = &mut order[start[v] as usize..start[v + 1] as usize];
            run.sort_unstable_by_key(|&i| (level[i as usize], i));
            let mut k = start[v];
            while k < start[v + 1] {
                let l = level[order[k as usize] as usize];
                let mut end = k + 1;
                while end < start[v + 1] && level[order[end as usize] as usize] == l {
                    end += 1;
                }
                queues.push((l, k, end));
                k = end;
            }
        }
        first.push(queues.len() as u32);
        Leaving { order, queues, first }
    }

    /// The first unused edge leaving `v` (by index) of a level other than `level`, else of `level`.
    fn next(&mut self, v: u32, level: u32, used: &[bool]) -> Option<u32> {
        let mut best: Option<(bool, u32)> = None;
        let range = self.first[v as usize] as usize..self.first[v as usize + 1] as usize;
        for (l, cursor, end) in &mut self.queues[range] {
            while *cursor < *end && used[self.order[*cursor as usize] as usize] {
                *cursor += 1;
            }
            if *cursor < *end {
                let candidate = (*l == level, self.order[*cursor as usize]);
                if best.is_none_or(|b| candidate < b) {
                    best = Some(candidate);
                }
            }
        }
        best.map(|(_, x)| x)
    }
}

/// The seams of a front (selection.md §8): `sealing` holds the borders of the displayed nodes
/// with a neighbour of their level not displayed, ascending by node; `shown` the borders of
/// every displayed node an edge of theirs could meet (those nodes and their displayed
/// neighbours; any superset will do).
pub fn seams(sealing: &[&Border], shown: &[&Border]) -> Seams {
    // The sealing edges' ends as small integers for this front, so that edges are pairs of them.
    let total: usize = sealing.iter().map(|b| b.edges.len()).sum();
    let mut ids: FxHashMap<Key, u32> = FxHashMap::with_capacity_and_hasher(2 * total, Default::default());
    let mut id = |k: Key| {
        let n = ids.len() as u32;
        *ids.entry(k).or_insert(n)
    };
    let ends: Vec<(u32, u32)> = sealing.iter().flat_map(|b| &b.edges).map(|e| (id(e.from), id(e.to))).collect();
    let pair = |a: u32, b: u32| (a as u64) << 32 | b as u64;
    let mut present: FxHashSet<u64> = ends.iter().map(|&(a, b)| pair(a, b)).collect();
    for e in shown.iter().flat_map(|b| &b.edges) {
        if let (Some(&a), Some(&b)) = (ids.get(&e.from), ids.get(&e.to)) {
            present.insert(pair(a, b));
        }
    }
    // Edges no displayed node has the other way round, with their node's level and error.
    let mut open: Vec<(&Edge, u32, f32)> = Vec::new();
    let (mut from, mut to, mut level) = (Vec::new(), Vec::new(), Vec::new());
    for ((e, lv, error), &(a, b)) in sealing.iter().flat_map(|x| x.edges.iter().map(move |e| (e, x.level, x.error))).zip(&ends) {
        if !present.contains(&pair(b, a)) {
            open.push((e, lv, error));
            from.push(a);
            to.push(b);
            level.push(lv);
        }
    }
    let mut leaving = Leaving::new(&from, &level, ids.len());
    let with_normals = sealing.iter().any(|b| b.edges.iter().any(|e| e.normal != Vec3::ZERO));
    let mut out = Seams::default();
    let mut used = vec![false; open.len()];
    let mut ring: Vec<u32> = Vec::new();
    for start in 0..open.len() {
        if used[start] {
            continue;
        }
        ring.clear();
        let mut e = start;
        let closed = loop {
            used[e] = true;
            ring.push(e as u32);
            if to[e] == from[start] {
                break true;
            }
            // Where loops touch, a loop turns from one level's run to the other's.
            match leaving.next(to[e], level[e], &used) {
                Some(x) => e = x as usize,
                None => break false,
            }
        };
        if closed {
            fill(&open, &ring, with_normals, &mut out);
        }
    }
    out
}

/// Fill loop `ring` (edges of `open`) when it joins two levels and is thin: a fan from its
/// lowest vertex (by [`Key`]), wound against the loop, which runs the way its nodes' faces do
/// around a gap.
fn fill(open: &[(&Edge, u32, f32)], ring: &[u32], with_normals: bool, out: &mut Seams) {
    let edges: Vec<&Edge> = ring.iter().map(|&i| open[i as usize].0).collect();
    let levels = ring.iter().map(|&i| open[i as usize].1);
    let (lo, hi) = levels.clone().fold((u32::MAX, 0), |(lo, hi), l| (lo.min(l), hi.max(l)));
    if edges.len() < 3 || lo == hi {
        return;
    }
    let error = ring.iter().map(|&i| open[i as usize].2 as f64).fold(0.0, f64::max);
    let p0 = edges[0].at.as_dvec3();
    let (mut area, mut perimeter) = (glam::DVec3::ZERO, 0.0f64);
    for (k, e) in edges.iter().enumerate() {
        let (a, b) = (e.at.as_dvec3(), edges[(k + 1) % edges.len()].at.as_dvec3());
        area += (a - p0).cross(b - p0);
        perimeter += a.distance(b);
    }
    // Mean width, the area over half the perimeter, at most the error; not filled where the sums
    // are not finite.
    let thin = (0.5 * area.length()).partial_cmp(&(error * 0.5 * perimeter));
    if !matches!(thin, Some(std::cmp::Ordering::Less | std::cmp::Ordering::Equal)) {
        return;
    }
    let first = (0..edges.len()).min_by_key(|&k| edges[k].from).unwrap_or(0);
    let base = out.positions.len() as u32;
    let n = edges.len();
    for k in 0..n {
        let e = edges[(first + k) % n];
        out.positions.push(e.at);
        if with_normals {
            out.normals.push(e.normal);
        }
    }
    for k in 1..n as u32 - 1 {
        out.indices.extend_from_slice(&[base, base + k + 1, base + k]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry(positions: &[[f32; 3]], indices: &[u32]) -> NodeGeometry {
        NodeGeometry {
            positions: positions.iter().map(|&p| Vec3::from_array(p)).collect(),
            indices: indices.to_vec(),
            ..Default::default()
        }
    }

    /// A coarse node of one triangle whose lower edge runs straight, beside a finer node whose
    /// upper edge has a vertex below the middle of it: a sliver between them.
    fn pair(dip: f32) -> (NodeGeometry, NodeGeometry) {
        let coarse = geometry(&[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 1.0, 0.0]], &[0, 1, 2]);
        let fine = geometry(&[[0.0, 0.0, 0.0], [1.0, -dip, 0.0], [2.0, 0.0, 0.0], [1.0, -1.0, 0.0]], &[0, 3, 1, 1, 3, 2]);
        (coarse, fine)
    }

    #[test]
    fn a_sliver_between_levels_is_filled_against_its_loop() {
        let (coarse, fine) = pair(0.05);
        let (a, b) = (Border::of(1, 0.1, &coarse), Border::of(0, 0.0, &fine));
        let s = seams(&[&a, &b], &[]);
        assert_eq!(s.face_count(), 1);
        let t: Vec<Vec3> = s.indices.iter().map(|&i| s.positions[i as usize]).collect();
        assert!((t[1] - t[0]).cross(t[2] - t[0]).z > 0.0, "wound as the faces around it: {t:?}");
        assert!(t.contains(&Vec3::new(1.0, -0.05, 0.0)));
    }

    #[test]
    fn nodes_of_one_level_a_wide_gap_and_matching_borders_get_no_seam() {
        let (coarse, fine) = pair(0.05);
        let (a, b) = (Border::of(1, 0.1, &coarse), Border::of(1, 0.1, &fine));
        assert_eq!(seams(&[&a, &b], &[]).face_count(), 0, "one level");
        let (coarse, fine) = pair(0.5);
        let (a, b) = (Border::of(1, 0.1, &coarse), Border::of(0, 0.0, &fine));
        assert_eq!(seams(&[&a, &b], &[]).face_count(), 0, "wider than the error");
        let (_, fine) = pair(0.0);
        let straight = geometry(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 1.0, 0.0]], &[0, 1, 3, 1, 2, 3]);
        let (a, b) = (Border::of(1, 0.1, &straight), Border::of(0, 0.0, &fine));
        assert_eq!(seams(&[&a, &b], &[]).face_count(), 0, "shared border");
        assert_eq!(seams(&[&a], &[]).face_count(), 0, "a node alone");
        let (coarse, mut fine) = pair(0.05);
        fine.positions[1] = Vec3::new(1.0, f32::NAN, 0.0);
        let (a, b) = (Border::of(1, 0.1, &coarse), Border::of(0, 0.0, &fine));
        assert_eq!(seams(&[&a, &b], &[]).face_count(), 0, "a loop whose width is not a number");
    }

    #[test]
    fn many_slivers_meeting_at_one_vertex_are_each_filled_once() {
        // 48 coarse triangles and 48 finer pairs around the origin, each pair one sliver: 96 open
        // edges leave the origin, two levels there.
        let k = 48;
        let turn = |i: usize, x: f32, y: f32| {
            let a = std::f32::consts::TAU * i as f32 / k as f32;
            [x * a.cos() - y * a.sin(), x * a.sin() + y * a.cos(), 0.0]
        };
        let (mut coarse, mut fine) = (geometry(&[], &[]), geometry(&[], &[]));
        for i in 0..k {
            let (c, f) = (coarse.positions.len() as u32, fine.positions.len() as u32);
            coarse.positions.extend([[0.0; 3], turn(i, 2.0, 0.0), turn(i, 1.0, 1.0)].map(Vec3::from_array));
            coarse.indices.extend([c, c + 1, c + 2]);
            fine.positions.extend([[0.0; 3], turn(i, 1.0, -0.05), turn(i, 2.0, 0.0), turn(i, 1.0, -1.0)].map(Vec3::from_array));
            fine.indices.extend([f, f + 3, f + 1, f + 1, f + 3, f + 2]);
        }
        let (a, b) = (Border::of(1, 0.1, &coarse), Border::of(0, 0.0, &fine));
        assert_eq!(seams(&[&a, &b], &[]).face_count(), k);
    }

    #[test]
    fn a_neighbour_that_takes_no_part_still_closes_the_edges_it_shares() {
        // The finer pair's edge to a third node of its level: open unless that node's border,
        // given as shown, has it the other way round.
        let (coarse, fine) = pair(0.05);
        let below = geometry(&[[0.0, 0.0, 0.0], [1.0, -1.0, 0.0], [0.0, -2.0, 0.0]], &[0, 2, 1]);
        let (a, b, c) = (Border::of(1, 0.1, &coarse), Border::of(0, 0.0, &fine), Border::of(0, 0.0, &below));
        let open = |shown: &[&Border]| {
            let present: FxHashSet<(Key, Key)> =
                shown.iter().copied().chain([&b]).flat_map(|x| x.edges.iter().map(|e| (e.from, e.to))).collect();
            b.edges.iter().filter(|e| !present.contains(&(e.to, e.from))).count()
        };
        assert_eq!(open(&[]) - open(&[&c]), 1);
        assert_eq!(seams(&[&a, &b], &[&c]).face_count(), 1, "the sliver, still");
    }
}
