//! Front-to-back order of a front from the file's separating planes (`selection.md` §5, seed 003):
//! a depth-first walk of the hierarchy from the virtual root, each parent's children taken in the
//! order their planes give for the eye, the nearest box first where no plane decides. No face is
//! sorted; the cost is the front and its ancestors, plus each visited parent's plane entries.

use crate::camera::{Camera, Projection};
use crate::format::octa;
use crate::format::planes::{grid_eye, Decision, Eye, Planes};
use crate::format::skeleton::Skeleton;
use glam::{DVec3, Vec3};
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Orders fronts of one file: its planes, their directions decoded once, and scratch space kept
/// between frames, so that ordering a front allocates nothing once warm.
#[derive(Clone, Debug, Default)]
pub struct Orderer {
    planes: Planes,
    /// Per entry, what the walk tests (the entries' order).
    tests: Vec<Test>,
    /// Per node, its box: low then high corner.
    boxes: Vec<[f32; 6]>,
    /// Per node: first child, child count (the skeleton's, packed for the walk).
    links: Vec<[u32; 2]>,
    /// Per node, its parent alone, for marking the front's ancestors.
    parents: Vec<u32>,
    /// Per node, the mark of the walk that touched it last: `2·walks + 1` on the front, `2·walks`
    /// above it, anything less neither (earlier walks' marks go stale without being cleared).
    state: Vec<u32>,
    walks: u32,
    /// The walk's stack (nodes, and whether each is on the front), and the working set of a
    /// parent of more than [`SMALL`] children.
    stack: Vec<(u32, bool)>,
    big: Scratch,
}

/// The working set of one parent's children.
#[derive(Clone, Debug, Default)]
struct Scratch {
    live: Vec<u32>,
    local: Vec<u32>,
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

/// A plane entry as the walk reads it: its direction decoded (f32, as the writer measured along
/// it), its bounds, and its two children's offsets modulo 32 (exact below [`SMALL`] children).
#[derive(Clone, Copy, Debug)]
struct Test {
    normal: Vec3,
    second_min: f32,
    first_max: f32,
    first: u8,
    second: u8,
}

/// Children ordered by pairwise masks rather than a heap, up to this many.
const SMALL: usize = 32;

/// The key a child is ordered by where no plane decides: the squared distance from the eye to its
/// box (0 inside), or for an orthographic camera the least depth of its box along the view.
fn key(b: &[f32; 6], eye: Eye) -> f64 {
    let (lo, hi) = (DVec3::new(b[0] as f64, b[1] as f64, b[2] as f64), DVec3::new(b[3] as f64, b[4] as f64, b[5] as f64));
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
            Key(key(&[lo.x, lo.y, lo.z, hi.x, hi.y, hi.z], eye), n)
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
    tests: &'a [Test],
    boxes: &'a [[f32; 6]],
    links: &'a [[u32; 2]],
    state: &'a [u32],
    /// The mark of a node above the front this walk (one more: on the front).
    above: u32,
    eye: Eye,
    key_eye: Eye,
}

impl Orderer {
    /// An orderer for the file of `sk` by its `planes` (`Reader::read_planes`; without any, the
    /// nearest box goes first at every parent).
    pub fn new(sk: &Skeleton, planes: Planes) -> Orderer {
        let tests = planes
            .entries
            .iter()
            .map(|e| Test {
                normal: octa::decode(e.normal),
                second_min: e.second_min,
                first_max: e.first_max,
                first: (e.first % 32) as u8,
                second: (e.second % 32) as u8,
            })
            .collect();
        let boxes = (0..sk.nodes.len() as u32)
            .map(|i| {
                let (lo, hi) = sk.node_box(i);
                [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z]
            })
            .collect();
        let links = sk.nodes.iter().map(|n| [n.first_child, n.child_count]).collect();
        let parents = sk.nodes.iter().map(|n| n.parent).collect();
        Orderer { planes, tests, boxes, links, parents, ..Orderer::default() }
    }

    pub fn planes(&self) -> &Planes {
        &self.planes
    }

    /// `front` (any order) from front to back for `camera`, into `out`.
    pub fn order(&mut self, sk: &Skeleton, front: &[u32], camera: &Camera, out: &mut Vec<u32>) {
        out.clear();
        if self.state.len() != sk.nodes.len() || self.walks >= u32::MAX / 2 - 1 {
            self.state = vec![0; sk.nodes.len()];
            self.walks = 0;
        }
        self.walks += 1;
        let (shown, above) = (2 * self.walks + 1, 2 * self.walks);
        // The grid eye serves the planes; keys are in model units.
        let key_eye = key_eye(camera);
        let eye = match key_eye {
            Eye::At(_) => Eye::At(grid_eye(&sk.header.grid, camera.eye)),
            along => along,
        };
        // A front node met as an ancestor first is marked above, then shown; one met first stops
        // the walks up from below it, as the ancestors it would have marked are marked.
        for &n in front {
            if let Some(s) = self.state.get_mut(n as usize) {
                *s = shown;
            }
            let mut p = self.parents.get(n as usize).copied().unwrap_or(u32::MAX);
            while let Some(s) = self.state.get_mut(p as usize) {
                if *s >= above {
                    break;
                }
                *s = above;
                p = self.parents.get(p as usize).copied().unwrap_or(u32::MAX);
            }
        }
        let top = sk.level_nodes(sk.top());
        let view = View {
            planes: &self.planes,
            tests: &self.tests,
            boxes: &self.boxes,
            links: &self.links,
            state: &self.state,
            above,
            eye,
            key_eye,
        };
        view.walk(top, &mut self.big, &mut self.stack, out);
    }
}

impl View<'_> {
    fn children(&self, c: u32) -> std::ops::Range<u32> {
        let [first, count] = self.links[c as usize];
        first..first + count
    }

    /// The walk, with an explicit stack of nodes (a file may have any number of levels): a parent's
    /// live children are pushed so that the first to take is on top.
    fn walk(&self, kids: std::ops::Range<u32>, big: &mut Scratch, stack: &mut Vec<(u32, bool)>, out: &mut Vec<u32>) {
        stack.clear();
        self.push_children(None, kids, big, stack, out);
        while let Some((c, shown)) = stack.pop() {
            if shown {
                out.push(c);
            } else {
                self.push_children(Some(c), self.children(c), big, stack, out);
            }
        }
    }

    /// Push `parent`'s live children (shown, or above a shown node) onto `stack` in reverse drawing
    /// order; where all of them are shown, append them to `out` instead (they would be popped next).
    fn push_children(
        &self,
        parent: Option<u32>,
        kids: std::ops::Range<u32>,
        big: &mut Scratch,
        stack: &mut Vec<(u32, bool)>,
        out: &mut Vec<u32>,
    ) {
        if kids.len() <= SMALL {
            return self.push_few(parent, kids, stack, out);
        }
        let (state, above) = (self.state, self.above);
        big.live.clear();
        big.live.extend(kids.clone().filter(|&c| state[c as usize] >= above));
        match big.live.len() {
            0 => {}
            1 => stack.push((big.live[0], state[big.live[0] as usize] > above)),
            _ => {
                self.arrange(parent, kids, big);
                stack.extend(big.live.iter().rev().map(|&c| (c, state[c as usize] > above)));
            }
        }
    }

    /// [`View::push_children`] for at most [`SMALL`] children, on the stack, in masks over the
    /// children's offsets: live children, and per child those that must come before it.
    fn push_few(&self, parent: Option<u32>, kids: std::ops::Range<u32>, stack: &mut Vec<(u32, bool)>, out: &mut Vec<u32>) {
        let state = &self.state[kids.start as usize..kids.end as usize];
        let (mut live, mut shown) = (0u32, 0u32);
        for (k, &s) in state.iter().enumerate() {
            live |= ((s >= self.above) as u32) << k;
            shown |= ((s > self.above) as u32) << k;
        }
        if live & live.wrapping_sub(1) == 0 {
            match (live, shown) {
                (0, _) => {}
                (_, 0) => stack.push((kids.start + live.trailing_zeros(), false)),
                _ => out.push(kids.start + live.trailing_zeros()),
            }
            return;
        }
        let tests = &self.tests[self.planes.range(parent)];
        if live.count_ones() == 2 {
            return self.push_two(live, shown, kids.start, tests, stack, out);
        }
        let mut before = [0u32; SMALL];
        for (a, b, e) in live_entries(tests, live) {
            match self.decide(e) {
                Some(true) => before[b as usize] |= 1 << a,
                Some(false) => before[a as usize] |= 1 << b,
                None => {}
            }
        }
        // While the planes leave one child ready at a time, keys cannot change the order.
        let mut order = [0u32; SMALL];
        let (mut taken, mut left) = (0, live);
        let count = state.len();
        while left != 0 {
            let mut ready = 0u32;
            for (k, &b) in before[..count].iter().enumerate() {
                ready |= ((b & left == 0) as u32) << k;
            }
            ready &= left;
            if ready == 0 || ready & (ready - 1) != 0 {
                break;
            }
            order[taken] = ready.trailing_zeros();
            taken += 1;
            left &= !ready;
        }
        let mut m = taken;
        if left != 0 {
            let mut sorted = [(0i64, 0u32); SMALL];
            let mut bits = left;
            let mut undecided = 0;
            while bits != 0 {
                let k = bits.trailing_zeros();
                bits &= bits - 1;
                sorted[undecided] = (ordered_bits(key(&self.boxes[(kids.start + k) as usize], self.key_eye)), k);
                undecided += 1;
            }
            insertion_sort(&mut sorted[..undecided]);
            take_in_order(&sorted[..undecided], &before, &mut order[taken..]);
            m += undecided;
        }
        if shown == live {
            out.extend(order[..m].iter().map(|&k| kids.start + k));
        } else {
            stack.extend(order[..m].iter().rev().map(|&k| (kids.start + k, shown >> k & 1 != 0)));
        }
    }

    /// [`View::push_few`] for exactly two live children (the common case: most parents have two
    /// or three), by the same rule: the planes' entries between the two decide unless they
    /// contradict each other; else the nearer key goes first, the lower offset on a tie.
    fn push_two(&self, live: u32, shown: u32, start: u32, tests: &[Test], stack: &mut Vec<(u32, bool)>, out: &mut Vec<u32>) {
        let (x, y) = (live.trailing_zeros(), 31 - live.leading_zeros());
        let (mut x_first, mut y_first) = (false, false);
        for (a, b, e) in live_entries(tests, live) {
            if let Some(first) = self.decide(e) {
                let winner = if first { a } else { b };
                x_first |= winner == x;
                y_first |= winner == y;
            }
        }
        let x_goes_first = if x_first != y_first {
            x_first
        } else {
            let k = |c: u32| ordered_bits(key(&self.boxes[(start + c) as usize], self.key_eye));
            k(x) <= k(y)
        };
        let (p, q) = if x_goes_first { (x, y) } else { (y, x) };
        if shown == live {
            out.extend([start + p, start + q]);
        } else {
            stack.extend([(start + q, shown >> q & 1 != 0), (start + p, shown >> p & 1 != 0)]);
        }
    }

    /// §5's test of entry `e` for the eye: whether its first child goes first (`Some(true)`), its
    /// second, or neither. One comparison per side: for an orthographic camera the eye is the
    /// reversed view direction and both bounds 0 (the same f64 products, negated exactly).
    fn decide(&self, e: &Test) -> Option<bool> {
        let (g, along) = match self.eye {
            Eye::At(g) => (g, false),
            Eye::Along(d) => (-d, true),
        };
        let n = e.normal;
        let s = (n.x as f64 * g.x + n.y as f64 * g.y) + n.z as f64 * g.z;
        let (low, high) = if along { (0.0, 0.0) } else { (e.second_min as f64, e.first_max as f64) };
        (s < low).then_some(true).or((s > high).then_some(false))
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
        for (e, t) in self.planes.entries[range.clone()].iter().zip(&self.tests[range]) {
            let (Some(&a), Some(&b)) = (s.local.get(e.first as usize), s.local.get(e.second as usize)) else { continue };
            if a == u32::MAX || b == u32::MAX {
                continue;
            }
            let edge = match e.decide_with(t.normal.as_dvec3(), self.eye) {
                Decision::FirstBeforeSecond => (a, b),
                Decision::SecondBeforeFirst => (b, a),
                Decision::Undecided => continue,
            };
            s.indegree[edge.1 as usize] += 1;
            s.edges.push(edge);
        }
        s.keys.clear();
        s.keys.extend(s.live.iter().map(|&c| Key(key(&self.boxes[c as usize], self.key_eye), c)));
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
    let mut before = [0u32; SMALL];
    for &(a, b) in &s.edges {
        before[b as usize] |= 1 << a;
    }
    let mut sorted = [(0i64, 0u32); SMALL];
    for (k, key) in s.keys.iter().enumerate() {
        sorted[k] = (ordered_bits(key.0), k as u32);
    }
    insertion_sort(&mut sorted[..n]);
    let mut order = [0u32; SMALL];
    take_in_order(&sorted[..n], &before, &mut order);
    s.local.clear();
    s.local.extend(order[..n].iter().map(|&k| s.live[k as usize]));
    std::mem::swap(&mut s.live, &mut s.local);
}

/// §5's choice among at most [`SMALL`] children, `sorted` by key (then offset) and with
/// predecessors `before` (a mask over offsets each): repeatedly the least key among those whose
/// predecessors are all taken, or among all left on a cycle. Their offsets in drawing order go to
/// `order`.
fn take_in_order(sorted: &[(i64, u32)], before: &[u32; SMALL], order: &mut [u32]) {
    let mut left = sorted.iter().fold(0u32, |m, &(_, k)| m | 1 << k);
    // Positions in `sorted` not yet taken.
    let mut rest = ((1u64 << sorted.len()) - 1) as u32;
    for slot in order.iter_mut().take(sorted.len()) {
        let mut bits = rest;
        let mut at = rest.trailing_zeros();
        while bits != 0 {
            let p = bits.trailing_zeros();
            if before[sorted[p as usize].1 as usize] & left == 0 {
                at = p;
                break;
            }
            bits &= bits - 1;
        }
        let k = sorted[at as usize].1;
        rest &= !(1 << at);
        left &= !(1 << k);
        *slot = k;
    }
}

/// The entries of `tests` (a parent's of at most [`SMALL`] children) between two children live in
/// `live` (a mask over offsets), with their first and second child's offsets.
fn live_entries(tests: &[Test], live: u32) -> impl Iterator<Item = (u32, u32, &Test)> {
    tests
        .iter()
        .map(|e| (e.first as u32 % SMALL as u32, e.second as u32 % SMALL as u32, e))
        .filter(move |&(a, b, _)| (live >> a) & (live >> b) & 1 != 0)
}

/// Sort a few keyed children (faster than the library's sort at this size).
fn insertion_sort(v: &mut [(i64, u32)]) {
    for i in 1..v.len() {
        let x = v[i];
        let mut j = i;
        while j > 0 && v[j - 1] > x {
            v[j] = v[j - 1];
            j -= 1;
        }
        v[j] = x;
    }
}

/// `x`'s bits as an integer that orders like `f64::total_cmp`.
fn ordered_bits(x: f64) -> i64 {
    let b = x.to_bits() as i64;
    b ^ (((b >> 63) as u64) >> 1) as i64
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
