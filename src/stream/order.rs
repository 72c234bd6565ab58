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

/// Orders fronts of one file: its planes, their directions decoded once, and scratch space kept
/// between frames, so that ordering a front allocates nothing once warm.
#[derive(Clone, Debug, Default)]
pub struct Orderer {
    planes: Planes,
    normals: Vec<DVec3>,
    boxes: Vec<(DVec3, DVec3)>,
    /// Per node: parent, first child, child count (the skeleton's, packed for the walk).
    links: Vec<[u32; 3]>,
    state: Vec<u8>,
    touched: Vec<u32>,
    /// The walk's stack, and the working set of a parent of more than [`SMALL`] children.
    stack: Vec<u32>,
    big: Scratch,
}

/// The working set of one parent's children.
#[derive(Clone, Debug, Default)]
struct Scratch {
    live: Vec<u32>,
    local: Vec<u32>,
    /// Per child, the children that must come before it (at most [`SMALL`] children).
    before: Vec<u32>,
    indegree: Vec<u32>,
    edges: Vec<(u32, u32)>,
    /// The edges' second children grouped by first child, and the groups' starts (and a cursor).
    grouped: Vec<u32>,
    first_edge: Vec<u32>,
    fill: Vec<u32>,
    keys: Vec<Key>,
    ready: BinaryHeap<Reverse<(Key, u32)>>,
    /// Every child by key, for breaking cycles (entries of taken children are skipped).
    all: BinaryHeap<Reverse<(Key, u32)>>,
    done: Vec<bool>,
}

/// Children ordered by pairwise masks rather than a heap, up to this many.
const SMALL: usize = 32;

/// The key a child is ordered by where no plane decides: the squared distance from the eye to its
/// box (0 inside), or for an orthographic camera the least depth of its box along the view.
fn key((lo, hi): (DVec3, DVec3), eye: Eye) -> f64 {
    // + 0.0 makes a −0 key +0, so that ties do not hang on zeros' signs.
    0.0 + match eye {
        Eye::At(e) => {
            let d = (lo - e).max(DVec3::ZERO).max(e - hi);
            d.dot(d)
        }
        Eye::Along(f) => (0..3).map(|k| (f[k] * lo[k]).min(f[k] * hi[k])).sum(),
    }
}

/// `front` sorted by key, nearest box first: §5's order for a front of top-level nodes when no
/// entry of the top level decides, and how a streamer orders a first frame of the top level alone,
/// before it has read the planes (selection.md §6).
pub fn nearest_box_first(sk: &Skeleton, front: &[u32], camera: &Camera, out: &mut Vec<u32>) {
    let eye = key_eye(camera);
    let mut keyed: Vec<Key> = front
        .iter()
        .filter(|&&n| (n as usize) < sk.nodes.len())
        .map(|&n| {
            let (lo, hi) = sk.node_box(n);
            Key(key((lo.as_dvec3(), hi.as_dvec3()), eye), n)
        })
        .collect();
    keyed.sort_unstable();
    out.clear();
    out.extend(keyed.iter().map(|k| k.1));
}

/// The eye keys are measured from (§5): the eye in model units, or the view direction.
fn key_eye(camera: &Camera) -> Eye {
    match camera.projection {
        Projection::Perspective { .. } => Eye::At(camera.eye.as_dvec3()),
        Projection::Orthographic { .. } => Eye::Along(camera.forward().as_dvec3()),
    }
}

/// A total order on f64 keys (they are finite: boxes and eye are checked finite).
#[derive(Clone, Copy, Debug)]
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

/// What one ordering walk reads: the orderer's tables, which nodes are shown or above, and the
/// eye for the planes and for the keys.
struct View<'a> {
    planes: &'a Planes,
    normals: &'a [DVec3],
    boxes: &'a [(DVec3, DVec3)],
    links: &'a [[u32; 3]],
    state: &'a [u8],
    eye: Eye,
    key_eye: Eye,
}

impl Orderer {
    /// An orderer for the file of `sk` by its `planes` (`Reader::read_planes`; without any, the
    /// nearest box goes first at every parent).
    pub fn new(sk: &Skeleton, planes: Planes) -> Orderer {
        let normals = planes.entries.iter().map(|e| e.unit_normal()).collect();
        let boxes = (0..sk.nodes.len() as u32)
            .map(|i| {
                let (lo, hi) = sk.node_box(i);
                (lo.as_dvec3(), hi.as_dvec3())
            })
            .collect();
        let links = sk.nodes.iter().map(|n| [n.parent, n.first_child, n.child_count]).collect();
        Orderer { planes, normals, boxes, links, ..Orderer::default() }
    }

    pub fn planes(&self) -> &Planes {
        &self.planes
    }

    /// `front` (any order) from front to back for `camera`, into `out`.
    pub fn order(&mut self, sk: &Skeleton, front: &[u32], camera: &Camera, out: &mut Vec<u32>) {
        out.clear();
        if self.state.len() != sk.nodes.len() {
            self.state = vec![OFF; sk.nodes.len()];
        }
        // The grid eye serves the planes; keys are in model units.
        let key_eye = key_eye(camera);
        let eye = match key_eye {
            Eye::At(_) => Eye::At(grid_eye(&sk.header.grid, camera.eye)),
            along => along,
        };
        for &n in front {
            if let Some(s) = self.state.get_mut(n as usize) {
                *s = SHOWN;
                self.touched.push(n);
            }
        }
        for &n in front {
            let mut p = self.links.get(n as usize).map_or(u32::MAX, |l| l[0]);
            while let Some(s) = self.state.get_mut(p as usize) {
                if *s != OFF {
                    break;
                }
                *s = ABOVE;
                self.touched.push(p);
                p = self.links.get(p as usize).map_or(u32::MAX, |l| l[0]);
            }
        }
        let top = sk.level_nodes(sk.top());
        let view =
            View { planes: &self.planes, normals: &self.normals, boxes: &self.boxes, links: &self.links, state: &self.state, eye, key_eye };
        view.walk(top, &mut self.big, &mut self.stack, out);
        for &n in &self.touched {
            self.state[n as usize] = OFF;
        }
        self.touched.clear();
    }
}

impl View<'_> {
    fn children(&self, c: u32) -> std::ops::Range<u32> {
        let [_, first, count] = self.links[c as usize];
        first..first + count
    }

    /// The walk, with an explicit stack of nodes (a file may have any number of levels): a parent's
    /// live children are pushed so that the first to take is on top.
    fn walk(&self, kids: std::ops::Range<u32>, big: &mut Scratch, stack: &mut Vec<u32>, out: &mut Vec<u32>) {
        stack.clear();
        self.push_children(None, kids, big, stack);
        while let Some(c) = stack.pop() {
            if self.state[c as usize] == SHOWN {
                out.push(c);
            } else {
                self.push_children(Some(c), self.children(c), big, stack);
            }
        }
    }

    /// Push `parent`'s live children (shown, or above a shown node) onto `stack` in reverse drawing
    /// order.
    fn push_children(&self, parent: Option<u32>, kids: std::ops::Range<u32>, big: &mut Scratch, stack: &mut Vec<u32>) {
        if kids.len() <= SMALL {
            return self.push_few(parent, kids, stack);
        }
        let state = self.state;
        big.live.clear();
        big.live.extend(kids.clone().filter(|&c| state[c as usize] != OFF));
        match big.live.len() {
            0 => {}
            1 => stack.push(big.live[0]),
            _ => {
                self.arrange(parent, kids, big);
                stack.extend(big.live.iter().rev());
            }
        }
    }

    /// [`View::push_children`] for at most [`SMALL`] children, on the stack: each taken child is
    /// the least key among those whose predecessors are all taken (or among all left, on a cycle),
    /// found by scanning masks of predecessors.
    fn push_few(&self, parent: Option<u32>, kids: std::ops::Range<u32>, stack: &mut Vec<u32>) {
        let state = &self.state[kids.start as usize..kids.end as usize];
        let mut found = state.iter().enumerate().filter(|(_, &s)| s != OFF);
        match (found.next(), found.next()) {
            (None, _) => return,
            (Some((k, _)), None) => return stack.push(kids.start + k as u32),
            _ => {}
        }
        let mut live = [0u32; SMALL];
        let mut local = [u8::MAX; SMALL];
        let mut n = 0;
        for (k, &s) in state.iter().enumerate() {
            if s != OFF {
                local[k] = n as u8;
                live[n] = kids.start + k as u32;
                n += 1;
            }
        }
        let mut before = [0u32; SMALL];
        let range = self.planes.range(parent);
        for (e, &normal) in self.planes.entries[range.clone()].iter().zip(&self.normals[range]) {
            let (Some(&a), Some(&b)) = (local.get(e.first as usize), local.get(e.second as usize)) else { continue };
            if a == u8::MAX || b == u8::MAX {
                continue;
            }
            match e.decide_with(normal, self.eye) {
                Decision::FirstBeforeSecond => before[b as usize] |= 1 << a,
                Decision::SecondBeforeFirst => before[a as usize] |= 1 << b,
                Decision::Undecided => {}
            }
        }
        let mut keys = [Key(0.0, 0); SMALL];
        for k in 0..n {
            keys[k] = Key(key(self.boxes[live[k] as usize], self.key_eye), live[k]);
        }
        let mut order = [0u32; SMALL];
        take_in_order(&keys[..n], &before[..n], &mut order);
        stack.extend(order[..n].iter().rev().map(|&k| live[k as usize]));
    }

    /// Put `s.live` (two or more children of `parent`, ascending) in drawing order.
    fn arrange(&self, parent: Option<u32>, kids: std::ops::Range<u32>, s: &mut Scratch) {
        let n = s.live.len();
        // Local index of each live child, edges "a before b" from the planes that decide.
        s.local.clear();
        s.local.resize(kids.len(), u32::MAX);
        for (k, &c) in s.live.iter().enumerate() {
            s.local[(c - kids.start) as usize] = k as u32;
        }
        s.indegree.clear();
        s.indegree.resize(n, 0);
        s.edges.clear();
        let range = self.planes.range(parent);
        for (e, &normal) in self.planes.entries[range.clone()].iter().zip(&self.normals[range]) {
            let (Some(&a), Some(&b)) = (s.local.get(e.first as usize), s.local.get(e.second as usize)) else { continue };
            if a == u32::MAX || b == u32::MAX {
                continue;
            }
            let edge = match e.decide_with(normal, self.eye) {
                Decision::FirstBeforeSecond => (a, b),
                Decision::SecondBeforeFirst => (b, a),
                Decision::Undecided => continue,
            };
            s.indegree[edge.1 as usize] += 1;
            s.edges.push(edge);
        }
        s.keys.clear();
        s.keys.extend(s.live.iter().map(|&c| Key(key(self.boxes[c as usize], self.key_eye), c)));
        if n <= SMALL {
            return small(s);
        }
        // Edges grouped by their first child (a counting sort), each group's start in `first_edge`.
        s.first_edge.clear();
        s.first_edge.resize(n + 1, 0);
        for &(a, _) in &s.edges {
            s.first_edge[a as usize + 1] += 1;
        }
        for k in 0..n {
            s.first_edge[k + 1] += s.first_edge[k];
        }
        s.grouped.clear();
        s.grouped.resize(s.edges.len(), 0);
        s.fill.clear();
        s.fill.extend_from_slice(&s.first_edge[..n]);
        for &(a, b) in &s.edges {
            s.grouped[s.fill[a as usize] as usize] = b;
            s.fill[a as usize] += 1;
        }
        s.ready.clear();
        for k in 0..n as u32 {
            if s.indegree[k as usize] == 0 {
                s.ready.push(Reverse((s.keys[k as usize], k)));
            }
        }
        s.all.clear();
        s.done.clear();
        s.done.resize(n, false);
        // The order is written over `local`'s first n slots, then copied back as node numbers.
        let mut taken = 0;
        while taken < n {
            let k = loop {
                match s.ready.pop() {
                    Some(Reverse((_, k))) if !s.done[k as usize] => break k,
                    Some(_) => continue,
                    // A cycle: the nearest child left goes next, its remaining predecessors ignored.
                    None => {
                        if s.all.is_empty() {
                            s.all.extend((0..n as u32).filter(|&k| !s.done[k as usize]).map(|k| Reverse((s.keys[k as usize], k))));
                        }
                        match std::iter::from_fn(|| s.all.pop()).find(|Reverse((_, k))| !s.done[*k as usize]) {
                            Some(Reverse((_, k))) => break k,
                            None => return,
                        }
                    }
                }
            };
            s.done[k as usize] = true;
            for &b in &s.grouped[s.first_edge[k as usize] as usize..s.first_edge[k as usize + 1] as usize] {
                let d = &mut s.indegree[b as usize];
                *d = d.saturating_sub(1);
                if *d == 0 && !s.done[b as usize] {
                    s.ready.push(Reverse((s.keys[b as usize], b)));
                }
            }
            s.local[taken] = k;
            taken += 1;
        }
        for k in 0..n {
            s.local[k] = s.live[s.local[k] as usize];
        }
        s.live.clear();
        s.live.extend_from_slice(&s.local[..n]);
    }
}

/// [`Orderer::arrange`]'s rule for a few children: each taken child is the least key among those
/// whose predecessors are all taken (or among all left, on a cycle), found by scanning masks.
fn small(s: &mut Scratch) {
    let n = s.live.len();
    s.before.clear();
    s.before.resize(n, 0);
    for &(a, b) in &s.edges {
        s.before[b as usize] |= 1 << a;
    }
    take_in_order(&s.keys, &s.before, &mut s.local[..n]);
    for k in 0..n {
        s.local[k] = s.live[s.local[k] as usize];
    }
    s.live.clear();
    s.live.extend_from_slice(&s.local[..n]);
}

/// §5's choice among at most [`SMALL`] children with keys `keys` and predecessors `before` (a
/// mask each): repeatedly the least key among those whose predecessors are all taken, or among all
/// left on a cycle. Their local indices in drawing order go to `order`.
fn take_in_order(keys: &[Key], before: &[u32], order: &mut [u32]) {
    let mut done = 0u32;
    for slot in order.iter_mut().take(keys.len()) {
        let (mut ready, mut any) = (None::<usize>, None::<usize>);
        for k in (0..keys.len()).filter(|&k| done & (1 << k) == 0) {
            let less = |best: Option<usize>| best.is_none_or(|b| keys[k] < keys[b]);
            if less(any) {
                any = Some(k);
            }
            if before[k] & !done == 0 && less(ready) {
                ready = Some(k);
            }
        }
        let k = ready.or(any).unwrap_or(0);
        done |= 1 << k;
        *slot = k as u32;
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
        let mut orderer = Orderer::new(sk, planes.clone());
        let mut out = Vec::new();
        let (mut decided, mut cyclic) = (0, 0);
        for k in 0..64 {
            let a = k as f32 * 0.7;
            let eye = Vec3::new(a.cos() * 4.0, (k as f32 * 0.3).sin() * 3.0, a.sin() * 4.0);
            let camera = Camera::framing(Vec3::ZERO, 1.0, eye, 1.0, 64, 64);
            for level in 0..sk.levels.len() as u32 {
                let front: Vec<u32> = sk.level_nodes(level).collect();
                orderer.order(sk, &front, &camera, &mut out);
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
