//! Front-to-back order of a front from the file's separating planes (`selection.md` §5, seed 003):
//! a depth-first walk of the hierarchy from the virtual root, each parent's children taken in the
//! order their planes give for the eye, the nearest box first where no plane decides. No face is
//! sorted; the cost is the front and its ancestors, plus each visited parent's plane entries.

use crate::camera::{Camera, Projection};
use crate::format::planes::{grid_eye, Decision, Eye, Planes};
use crate::format::skeleton::Skeleton;
use glam::DVec3;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

const OFF: u8 = 0;
const SHOWN: u8 = 1;
const ABOVE: u8 = 2;

/// Scratch space for ordering fronts of one file, kept between frames.
#[derive(Clone, Debug, Default)]
pub struct Orderer {
    state: Vec<u8>,
    touched: Vec<u32>,
}

/// The key a child is ordered by where no plane decides: the squared distance from the eye to its
/// box (0 inside), or for an orthographic camera the least depth of its box along the view.
fn key(sk: &Skeleton, node: u32, eye: Eye) -> f64 {
    let (lo, hi) = sk.node_box(node);
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    match eye {
        Eye::At(e) => {
            let d = (lo - e).max(DVec3::ZERO).max(e - hi);
            d.dot(d)
        }
        Eye::Along(f) => (0..3).map(|k| (f[k] * lo[k]).min(f[k] * hi[k])).sum(),
    }
}

/// A total order on f64 keys (they are finite: boxes and eye are checked finite).
#[derive(Clone, Copy)]
struct Key(f64, u32);
impl PartialEq for Key {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o).is_eq()
    }
}
impl Eq for Key {}
impl PartialOrd for Key {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Key {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0).then(self.1.cmp(&o.1))
    }
}

/// What one ordering walk reads: the file, and the eye for the planes and for the keys.
struct View<'a> {
    sk: &'a Skeleton,
    planes: &'a Planes,
    eye: Eye,
    key_eye: Eye,
}

impl Orderer {
    /// `front` (any order) from front to back for `camera`, into `out`, by the file's `planes`
    /// (`Reader::read_planes`; without them the nearest box goes first at every parent).
    pub fn order(&mut self, sk: &Skeleton, planes: &Planes, front: &[u32], camera: &Camera, out: &mut Vec<u32>) {
        out.clear();
        if self.state.len() != sk.nodes.len() {
            self.state = vec![OFF; sk.nodes.len()];
        }
        let eye = match camera.projection {
            Projection::Perspective { .. } => Eye::At(grid_eye(&sk.header.grid, camera.eye)),
            Projection::Orthographic { .. } => Eye::Along(camera.forward().as_dvec3()),
        };
        // Key positions are model units for both; the grid eye serves the planes.
        let key_eye = match eye {
            Eye::At(_) => Eye::At(camera.eye.as_dvec3()),
            along => along,
        };
        for &n in front {
            if let Some(s) = self.state.get_mut(n as usize) {
                *s = SHOWN;
                self.touched.push(n);
            }
        }
        for &n in front {
            let mut p = sk.nodes.get(n as usize).map_or(u32::MAX, |r| r.parent);
            while let Some(s) = self.state.get_mut(p as usize) {
                if *s != OFF {
                    break;
                }
                *s = ABOVE;
                self.touched.push(p);
                p = sk.nodes[p as usize].parent;
            }
        }
        let top = sk.level_nodes(sk.top());
        self.walk(&View { sk, planes, eye, key_eye }, None, top, out);
        for &n in &self.touched {
            self.state[n as usize] = OFF;
        }
        self.touched.clear();
    }

    fn walk(&self, v: &View, parent: Option<u32>, kids: std::ops::Range<u32>, out: &mut Vec<u32>) {
        let sk = v.sk;
        let live: Vec<u32> = kids.clone().filter(|&c| self.state[c as usize] != OFF).collect();
        let visit = |c: u32, out: &mut Vec<u32>| {
            if self.state[c as usize] == SHOWN {
                out.push(c);
            } else {
                self.walk(v, Some(c), sk.children(c), out);
            }
        };
        if live.len() <= 1 {
            if let Some(&c) = live.first() {
                visit(c, out);
            }
            return;
        }
        // Local index of each live child, edges "a before b" from the planes that decide.
        let mut local = vec![u32::MAX; kids.len()];
        for (k, &c) in live.iter().enumerate() {
            local[(c - kids.start) as usize] = k as u32;
        }
        let mut indegree = vec![0u32; live.len()];
        let mut edges: Vec<(u32, u32)> = Vec::new();
        for e in v.planes.of(parent) {
            let (Some(&a), Some(&b)) = (local.get(e.first as usize), local.get(e.second as usize)) else { continue };
            if a == u32::MAX || b == u32::MAX {
                continue;
            }
            let edge = match e.decide(v.eye) {
                Decision::FirstBeforeSecond => (a, b),
                Decision::SecondBeforeFirst => (b, a),
                Decision::Undecided => continue,
            };
            indegree[edge.1 as usize] += 1;
            edges.push(edge);
        }
        edges.sort_unstable();
        let mut first_edge = vec![0u32; live.len() + 1];
        for &(a, _) in &edges {
            first_edge[a as usize + 1] += 1;
        }
        for k in 0..live.len() {
            first_edge[k + 1] += first_edge[k];
        }
        let keys: Vec<Key> = live.iter().map(|&c| Key(key(sk, c, v.key_eye), c)).collect();
        let mut ready: BinaryHeap<Reverse<(Key, u32)>> =
            (0..live.len() as u32).filter(|&k| indegree[k as usize] == 0).map(|k| Reverse((keys[k as usize], k))).collect();
        let mut done = vec![false; live.len()];
        for _ in 0..live.len() {
            let k = loop {
                match ready.pop() {
                    Some(Reverse((_, k))) if !done[k as usize] => break k,
                    Some(_) => continue,
                    // A cycle: the nearest child left goes next, its remaining predecessors ignored.
                    None => break (0..live.len() as u32).filter(|&k| !done[k as usize]).min_by_key(|&k| keys[k as usize]).unwrap(),
                }
            };
            done[k as usize] = true;
            for &(_, b) in &edges[first_edge[k as usize] as usize..first_edge[k as usize + 1] as usize] {
                let d = &mut indegree[b as usize];
                *d = d.saturating_sub(1);
                if *d == 0 && !done[b as usize] {
                    ready.push(Reverse((keys[b as usize], b)));
                }
            }
            visit(live[k as usize], out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::Reader;
    use glam::Vec3;

    /// Whether the edges "a before b" close a cycle (repeatedly drop nodes with no predecessor).
    fn has_cycle(edges: &[(u32, u32)]) -> bool {
        let mut left = edges.to_vec();
        loop {
            let before = left.len();
            let targets: std::collections::HashSet<u32> = left.iter().map(|e| e.1).collect();
            left.retain(|e| targets.contains(&e.0));
            if left.is_empty() {
                return false;
            }
            if left.len() == before {
                return true;
            }
        }
    }

    /// On the golden sphere, for cameras all around: each front comes out once per node, and
    /// wherever a plane at the top level decides between two shown nodes, they come in its order.
    #[test]
    fn fronts_come_out_whole_and_in_the_planes_order() {
        let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/format-spec/vectors/sphere.strata")).unwrap();
        let rd = Reader::open(std::io::Cursor::new(bytes)).unwrap();
        let planes = rd.read_planes().unwrap();
        assert!(!planes.entries.is_empty());
        let sk = rd.skeleton();
        let mut orderer = Orderer::default();
        let mut out = Vec::new();
        let (mut decided, mut cyclic) = (0, 0);
        for k in 0..64 {
            let a = k as f32 * 0.7;
            let eye = Vec3::new(a.cos() * 4.0, (k as f32 * 0.3).sin() * 3.0, a.sin() * 4.0);
            let camera = Camera::framing(Vec3::ZERO, 1.0, eye, 1.0, 64, 64);
            for level in 0..sk.levels.len() as u32 {
                let front: Vec<u32> = sk.level_nodes(level).collect();
                orderer.order(sk, &planes, &front, &camera, &mut out);
                let mut sorted = out.clone();
                sorted.sort_unstable();
                assert_eq!(sorted, front, "level {level}: every node once");
                let at = |n: u32| out.iter().position(|&x| x == n).unwrap();
                // The children of one parent on this level: where the planes that decide form no
                // cycle among them, the front takes every one of those decisions.
                for p in std::iter::once(None).chain((0..sk.nodes.len() as u32).map(Some)) {
                    let first = p.map_or(0, |i| sk.nodes[i as usize].first_child);
                    let grid = Eye::At(grid_eye(&sk.header.grid, camera.eye));
                    let edges: Vec<(u32, u32)> = planes
                        .of(p)
                        .iter()
                        .filter(|e| sk.nodes[(first + e.first) as usize].level == level)
                        .filter_map(|e| match e.decide(grid) {
                            Decision::FirstBeforeSecond => Some((first + e.first, first + e.second)),
                            Decision::SecondBeforeFirst => Some((first + e.second, first + e.first)),
                            Decision::Undecided => None,
                        })
                        .collect();
                    if has_cycle(&edges) {
                        cyclic += 1;
                        continue;
                    }
                    for &(x, y) in &edges {
                        assert!(at(x) < at(y), "level {level}: {x} before {y} in {out:?}");
                        decided += 1;
                    }
                }
            }
        }
        assert!(cyclic * 10 < decided, "{cyclic} parents with cycles, {decided} decisions checked");
        assert!(decided > 100, "{decided} decisions checked");
    }
}
