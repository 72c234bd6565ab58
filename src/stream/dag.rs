//! Selection over a DAG of nodes (format 4; selection.md §9): groups' projected errors raised along
//! the DAG, and the budgeted refinement that opens groups largest error first once all their
//! outputs are in the cut. One implementation for the file's skeleton ([`Skeleton`], what the
//! streamer selects from) and the build's structure ([`crate::dag::Dag`], through
//! [`crate::dag::cut`]).

use super::refine::{sees, Cut, Limits};
use crate::camera::Camera;
use crate::format::skeleton::Skeleton;
use crate::format::{NodeRecord, NO_PARENT};
use glam::Vec3;
use std::cell::Cell;
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::ops::Range;

/// What §9 needs of a DAG. Node and group numbers are the structure's own; "none" is
/// [`NO_PARENT`].
pub trait Graph {
    fn node_count(&self) -> usize;
    fn group_count(&self) -> usize;
    /// The top level's nodes.
    fn top(&self) -> Range<u32>;
    fn source(&self, n: u32) -> u32;
    fn consumer(&self, n: u32) -> u32;
    fn outputs(&self, g: u32) -> Range<u32>;
    fn children(&self, g: u32) -> &[u32];
    /// A group's error and sphere (center, radius).
    fn group_bounds(&self, g: u32) -> (f32, Vec3, f32);
    /// Whether groups are numbered from level 1 up (the sources of a group's children come
    /// before it), else from the top down (they come after it, as in a file).
    fn numbered_up(&self) -> bool;
}

/// §9.1: each group's projected error from `camera`, raised to the largest of the sources of its
/// children.
pub fn projected_errors(g: &impl Graph, camera: &Camera) -> Vec<f32> {
    let mut p: Vec<f32> = (0..g.group_count() as u32)
        .map(|k| {
            let (error, center, radius) = g.group_bounds(k);
            camera.projected_error(error, center, radius)
        })
        .collect();
    let raise = |p: &mut Vec<f32>, k: u32| {
        let below = g.children(k).iter().map(|&c| g.source(c)).filter(|&s| s != NO_PARENT).map(|s| p[s as usize]);
        p[k as usize] = below.fold(p[k as usize], f32::max);
    };
    if g.numbered_up() {
        (0..g.group_count() as u32).for_each(|k| raise(&mut p, k));
    } else {
        (0..g.group_count() as u32).rev().for_each(|k| raise(&mut p, k));
    }
    p
}

/// §9.3: the cut under `limits` (its pixel threshold, face and byte budgets; priority is always
/// the projected error), given the groups' projected errors `p`, which nodes the camera sees,
/// each node's faces and bytes, and the groups `held` back (children not loaded).
pub fn select(
    g: &impl Graph,
    p: &[f32],
    seen: &dyn Fn(u32) -> bool,
    cost: &dyn Fn(u32) -> (u64, u64),
    limits: &Limits,
    held: &dyn Fn(u32) -> bool,
) -> Cut {
    // Whether the camera sees a node, asked only of nodes that enter the cut or would (0: not
    // asked yet).
    let memo: Vec<Cell<u8>> = vec![Cell::new(0); g.node_count()];
    let seen = |n: u32| {
        let m = &memo[n as usize];
        if m.get() == 0 {
            m.set(1 + seen(n) as u8);
        }
        m.get() == 2
    };
    let cost = |n: u32| if seen(n) { cost(n) } else { (0, 0) };
    let mut in_cut = vec![false; g.node_count()];
    // Every node that entered the cut (each enters at most once: it has one consumer).
    let mut entered: Vec<u32> = Vec::new();
    // Outputs of each group not yet in the cut; a group becomes a candidate at 0.
    let mut waiting: Vec<u32> = (0..g.group_count() as u32).map(|k| g.outputs(k).len() as u32).collect();
    let mut heap: BinaryHeap<(u32, Reverse<u32>)> = BinaryHeap::new();
    let tau = limits.pixel_error;
    let mut enter = |n: u32, heap: &mut BinaryHeap<(u32, Reverse<u32>)>, in_cut: &mut Vec<bool>| {
        in_cut[n as usize] = true;
        entered.push(n);
        let s = g.source(n);
        if s != NO_PARENT {
            waiting[s as usize] -= 1;
            if waiting[s as usize] == 0 && p[s as usize] > tau && !held(s) {
                // Projected errors are not negative, so their bits order as they do.
                heap.push((p[s as usize].to_bits(), Reverse(s)));
            }
        }
    };
    let (mut faces, mut bytes) = (0u64, 0u64);
    for n in g.top() {
        let (f, b) = cost(n);
        (faces, bytes) = (faces + f, bytes + b);
        enter(n, &mut heap, &mut in_cut);
    }
    while let Some((_, Reverse(k))) = heap.pop() {
        let (mut f, mut b) = (faces, bytes);
        for o in g.outputs(k) {
            let (of, ob) = cost(o);
            (f, b) = (f - of, b - ob);
        }
        for &c in g.children(k) {
            let (cf, cb) = cost(c);
            (f, b) = (f + cf, b + cb);
        }
        if limits.max_faces.is_some_and(|m| f > m) || limits.max_bytes.is_some_and(|m| b > m) {
            continue;
        }
        (faces, bytes) = (f, b);
        for o in g.outputs(k) {
            in_cut[o as usize] = false;
        }
        for &c in g.children(k) {
            enter(c, &mut heap, &mut in_cut);
        }
    }
    entered.retain(|&n| in_cut[n as usize]);
    entered.sort_unstable();
    let (shown, culled): (Vec<u32>, Vec<u32>) = entered.into_iter().partition(|&n| seen(n));
    Cut { shown, culled, faces, bytes }
}

/// A format-4 skeleton, decoded whole, as §9 sees it.
impl Graph for Skeleton {
    fn node_count(&self) -> usize {
        self.nodes.len()
    }
    fn group_count(&self) -> usize {
        self.dag.as_ref().map_or(0, |d| d.groups.len())
    }
    fn top(&self) -> Range<u32> {
        self.level_nodes(Skeleton::top(self))
    }
    fn source(&self, n: u32) -> u32 {
        self.dag.as_ref().and_then(|d| d.source.get(n as usize).copied()).unwrap_or(NO_PARENT)
    }
    fn consumer(&self, n: u32) -> u32 {
        self.dag.as_ref().and_then(|d| d.consumer.get(n as usize).copied()).unwrap_or(NO_PARENT)
    }
    fn outputs(&self, g: u32) -> Range<u32> {
        self.dag.as_ref().map_or(0..0, |d| d.outputs(g))
    }
    fn children(&self, g: u32) -> &[u32] {
        self.dag.as_ref().map_or(&[], |d| d.children(g))
    }
    fn group_bounds(&self, g: u32) -> (f32, Vec3, f32) {
        self.dag.as_ref().and_then(|d| d.groups.get(g as usize)).map_or((0.0, Vec3::ZERO, 0.0), |r| (r.error, r.center, r.radius))
    }
    fn numbered_up(&self) -> bool {
        false
    }
}

/// The streamer's cut of a format-4 skeleton: §9.3 with the nodes `sees` (§2) and `bytes` of each.
/// A skeleton decoded in part (the top pages only) shows its top level: nothing below is held
/// open.
pub fn select_skeleton(s: &Skeleton, camera: &Camera, limits: &Limits, held: &[u32], bytes: &dyn Fn(&NodeRecord) -> u64) -> Cut {
    let p = projected_errors(s, camera);
    let complete = s.is_complete();
    let seen = |n: u32| sees(&s.nodes[n as usize], camera);
    let cost = |n: u32| (s.nodes[n as usize].faces as u64, bytes(&s.nodes[n as usize]));
    // A group is held when one of its outputs is (the streamer holds nodes), or the skeleton is
    // not whole yet.
    let held = |k: u32| !complete || s.outputs(k).any(|o| held.binary_search(&o).is_ok());
    select(s, &p, &seen, &cost, limits, &held)
}
