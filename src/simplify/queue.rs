//! The order of collapses: queue entries, the ranking of edges (in parallel), and the passes that
//! take them cheapest first.

use super::collapse::{Allowed, Plan};
use super::prefetch::prefetch;
use super::state::{EdgeFaces, Kind, State};
use super::SimplifyOptions;
use crate::mesh::NO_FACE;
use glam::DVec3;
use rayon::prelude::*;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// A queued collapse: `key bits | u | v | versions` in one integer. A non-negative f32 keeps its
/// order in its bits, so entries compare as integers (ties by vertex ids). `versions` is the sum of
/// the two vertex versions when queued: versions only grow, so the entry is current exactly when
/// that sum is unchanged (lazy invalidation).
fn entry(key: f64, [u, v, versions]: [u32; 3]) -> u128 {
    let bits = if key > 0.0 { (key as f32).to_bits() } else { 0 };
    u128::from(bits) << 96 | u128::from(u) << 64 | u128::from(v) << 32 | u128::from(versions)
}

fn entry_key(e: u128) -> f32 {
    f32::from_bits((e >> 96) as u32)
}

pub(super) fn entry_edge(e: u128) -> [u32; 3] {
    [(e >> 64) as u32, (e >> 32) as u32, e as u32]
}

impl State {
    /// The ordering key of the best collapse of edge (u, v) the rules allow, to queue it: at the
    /// optimum of the summed quadric when there is one, else the cheapest of ends and midpoint.
    /// Both ends are unlocked, of kinds `ku` and `kv`.
    fn key(&self, u: u32, v: u32, e: &EdgeFaces, ku: Kind, kv: Kind) -> Option<f64> {
        let allowed = self.allowed_kinds(u, v, e, ku, kv);
        let (pu, pv) = (self.pos(u), self.pos(v));
        let (qu, qv) = (&self.quadrics[u as usize], &self.quadrics[v as usize]);
        let cost = |p: DVec3| (qu.eval(p) / qu.area.max(f64::MIN_POSITIVE)).max(qv.eval(p) / qv.area.max(f64::MIN_POSITIVE));
        match allowed {
            Allowed::Nothing => None,
            Allowed::Anywhere => {
                let mut q = *qu;
                q.add(qv);
                Some(match State::optimum(&q, pu, pv) {
                    Some(p) => cost(p),
                    None => cost(pu).min(cost(pv)).min(cost((0.5 * (pu + pv)).as_vec3().as_dvec3())),
                })
            }
            Allowed::Ends { u_into_v, v_into_u } => {
                let at = |ok: bool, p: DVec3| if ok { cost(p) } else { f64::INFINITY };
                Some(at(u_into_v, pv).min(at(v_into_u, pu)))
            }
        }
    }

    /// The ends of a queued edge, if the entry is current (neither end changed since it was
    /// queued).
    pub(super) fn current_ends(&self, e: u128) -> Option<[u32; 2]> {
        let [u, v, versions] = entry_edge(e);
        (self.versions(u, v) == versions).then_some([u, v])
    }

    fn versions(&self, u: u32, v: u32) -> u32 {
        self.version[u as usize].wrapping_add(self.version[v as usize])
    }

    /// The edges around `v` with their faces and opposite vertices, for ranking: each face's edge
    /// from v to its next vertex is paired with the face whose previous vertex that is. Exact on
    /// consistently oriented manifold fans; elsewhere an edge may be listed with one face only,
    /// which only affects its rank (collapses re-derive their faces).
    fn edge_fans(&self, v: u32, out: &mut Vec<(u32, EdgeFaces)>, ends: &mut Vec<(u32, u32, u32)>) {
        out.clear();
        ends.clear();
        for &f in self.faces_of(v) {
            let t = self.tri(f);
            let i = if t[0] == v {
                0
            } else if t[1] == v {
                1
            } else {
                2
            };
            ends.push((t[(i + 1) % 3], t[(i + 2) % 3], f));
        }
        for &(next, prev, f) in ends.iter() {
            match ends.iter().find(|g| g.1 == next) {
                Some(&(g_next, _, g)) => out.push((next, EdgeFaces { f: [f, g], x: [prev, g_next], n: 2 })),
                None => out.push((next, EdgeFaces { f: [f, NO_FACE], x: [prev, NO_FACE], n: 1 })),
            }
            if !ends.iter().any(|g| g.0 == prev) {
                out.push((prev, EdgeFaces { f: [f, NO_FACE], x: [next, NO_FACE], n: 1 }));
            }
        }
    }

    /// Queue the edges of the vertices `vs`, ranked in parallel: for each v, the edges (v, y)
    /// with y above v or, given `changed`, with y not changed (a changed y queues its own), so
    /// every edge once. Ends of unknown kind get it computed and cached, as ranking the edges one
    /// by one would: ranking changes nothing else, so the order of ranking does not matter.
    fn rank(&mut self, vs: &[u32], changed: Option<&[bool]>) {
        let this = &*self;
        // Per chunk: its entries, and the kinds it found.
        type Ranked = (Vec<u128>, Vec<(u32, Kind)>);
        let ranked: Vec<Ranked> = vs
            .par_chunks(256)
            .map_init(
                || (Vec::new(), Vec::new(), Vec::new()),
                |(fans, ends, edges), chunk| {
                    let (mut out, mut found) = (Vec::new(), Vec::<(u32, Kind)>::new());
                    let mut kind = |w: u32| match this.verts[w as usize].kind {
                        Kind::Unknown => match found.iter().find(|f| f.0 == w) {
                            Some(&(_, k)) => k,
                            None => {
                                let k = this.compute_kind(w, edges);
                                found.push((w, k));
                                k
                            }
                        },
                        k => k,
                    };
                    for (i, &v) in chunk.iter().enumerate() {
                        if let Some(&w) = chunk.get(i + 8) {
                            prefetch(&this.verts[w as usize]);
                        }
                        if let Some(&w) = chunk.get(i + 6) {
                            this.prefetch_list(w);
                        }
                        if let Some(&w) = chunk.get(i + 4) {
                            this.prefetch_faces_of(w);
                        }
                        if let Some(&w) = chunk.get(i + 2) {
                            for &f in this.faces_of(w) {
                                for y in this.tri(f) {
                                    this.prefetch_vertex(y);
                                }
                            }
                        }
                        if this.verts[v as usize].locked {
                            continue;
                        }
                        this.edge_fans(v, fans, ends);
                        for &(y, e) in fans.iter() {
                            if y < v && changed.is_none_or(|c| c[y as usize]) || this.verts[y as usize].locked {
                                continue;
                            }
                            let (kv, ky) = (kind(v), kind(y));
                            if let Some(key) = this.key(v, y, &e, kv, ky) {
                                out.push(entry(key, [v, y, this.versions(v, y)]));
                            }
                        }
                    }
                    (out, found)
                },
            )
            .collect();
        for (out, found) in ranked {
            self.entries.extend_from_slice(&out);
            for (w, k) in found {
                self.verts[w as usize].kind = k;
            }
        }
    }

    /// Passes of collapses, cheapest first, until the target, the error limit, or no legal
    /// collapse is left. Each pass sorts the queued edges (in parallel) and takes them in order,
    /// merged with a small heap of the edges it re-ranks upwards; a collapse makes the
    /// entries of its two vertices stale, and the edges of the survivor are ranked again for the
    /// next pass, together with the entries the pass did not reach. A pass ends once its keys
    /// exceed 1.5× the key of the edge that would reach the target if every collapse succeeded
    /// (after at least a sixth of that), so that collapses stay close to cheapest-first order.
    /// An edge found illegal is tried again in the next pass only if a collapse touched its ends
    /// or their neighbours; otherwise it waits until the queue runs dry, and is then tried once
    /// more.
    // Alternatives to this order that were measured and lost: notes/simplify.md.
    pub(super) fn run(&mut self, opts: &SimplifyOptions) {
        let limit = opts.max_error.map_or(f64::INFINITY, |e| f64::from(e).powi(2));
        let mut changed = vec![false; self.verts.len()];
        let mut touched = vec![0u32; self.verts.len()];
        let (mut survivors, mut retry, mut blocked) = (Vec::new(), Vec::new(), Vec::new());
        let mut plan = Plan::EMPTY;
        let mut unblocked = Vec::new();
        let (mut around_u, mut around_v, mut link) = (Vec::new(), Vec::new(), Vec::new());
        let mut revived = false;
        self.entries.clear();
        let all: Vec<u32> = (0..self.verts.len() as u32).filter(|&v| !self.verts[v as usize].locked).collect();
        self.rank(&all, None);
        for pass in 1u32.. {
            if self.faces_left <= opts.target_faces {
                return;
            }
            if self.entries.is_empty() {
                if revived || blocked.is_empty() {
                    return;
                }
                revived = true;
                self.entries.append(&mut blocked);
            }
            let goal = self.faces_left - opts.target_faces;
            let nth = (goal / 2).min(self.entries.len() - 1);
            let goal_key = 1.5 * entry_key(*self.entries.select_nth_unstable(nth).1);
            // Sort only the entries the pass will likely reach; the rest joins if it gets there.
            let mut split = nth + 1;
            for j in nth + 1..self.entries.len() {
                if entry_key(self.entries[j]) <= goal_key {
                    self.entries.swap(split, j);
                    split += 1;
                }
            }
            let mut rest = self.entries.split_off(split);
            // The queue: `sorted[next..]` merged with a small heap of re-ranked edges.
            let mut sorted = std::mem::take(&mut self.entries);
            sorted.par_sort_unstable();
            let mut next = 0;
            let mut pushed = BinaryHeap::new();
            let before = self.faces_left;
            loop {
                let e = match (sorted.get(next), pushed.peek()) {
                    (Some(&a), Some(&Reverse(b))) if b < a => pushed.pop().map_or(b, |r| r.0),
                    (Some(&a), _) => {
                        // Each step fetches what the next needs, for entries ever closer.
                        if let Some(&e) = sorted.get(next + 12) {
                            self.prefetch_ends(e);
                        }
                        if let Some(&e) = sorted.get(next + 8) {
                            self.prefetch_lists(e);
                        }
                        if let Some(&e) = sorted.get(next + 5) {
                            self.prefetch_faces(e);
                        }
                        if let Some(&e) = sorted.get(next + 3) {
                            self.prefetch_around(e);
                        }
                        if let Some(&e) = sorted.get(next + 1) {
                            self.prefetch_opposite(e);
                        }
                        next += 1;
                        a
                    }
                    (None, Some(&Reverse(b))) => pushed.pop().map_or(b, |r| r.0),
                    (None, None) if rest.is_empty() => break,
                    (None, None) => {
                        sorted = std::mem::take(&mut rest);
                        sorted.par_sort_unstable();
                        next = 0;
                        continue;
                    }
                };
                if self.faces_left <= opts.target_faces {
                    return;
                }
                if entry_key(e) > goal_key && 6 * before.saturating_sub(self.faces_left) > goal {
                    pushed.push(Reverse(e));
                    break;
                }
                let Some([u, v]) = self.current_ends(e) else { continue };
                let Some(edge) = self.edge_faces(u, v) else { continue };
                if !self.plan(u, v, edge, &mut plan) {
                    continue;
                }
                let within = plan.c[..plan.n].iter().any(|c| c.error_sq <= limit);
                let topology_ok = within && self.topology_ok(u, v, &plan.e, &mut link);
                let found = if topology_ok {
                    self.gather(u, &plan.e, &mut around_u);
                    self.gather(v, &plan.e, &mut around_v);
                    plan.c[..plan.n].iter().find(|c| c.error_sq <= limit && self.shapes_ok(u, c, &around_u, &around_v))
                } else {
                    None
                };
                match found {
                    // Cheaper candidates were illegal: rank the edge by the legal one.
                    Some(&c) if c.cost as f32 > entry_key(e) => pushed.push(Reverse(entry(c.cost, entry_edge(e)))),
                    Some(&c) => {
                        self.collapse(&plan.e, c);
                        if !std::mem::replace(&mut changed[c.keep as usize], true) {
                            survivors.push(c.keep);
                        }
                        for &f in self.faces_of(c.keep) {
                            for y in self.tri(f) {
                                touched[y as usize] = pass;
                            }
                        }
                    }
                    None if self.topology && within && !topology_ok && self.unblock(u, v, &plan.e, limit, &mut unblocked) => {
                        changed.resize(self.verts.len(), false);
                        touched.resize(self.verts.len(), 0);
                        for &w in &unblocked {
                            if !std::mem::replace(&mut changed[w as usize], true) {
                                survivors.push(w);
                            }
                            touched[w as usize] = pass;
                        }
                        if !self.verts[u as usize].locked {
                            pushed.push(Reverse(entry(f64::from(entry_key(e)), [u, v, self.versions(u, v)])));
                        }
                    }
                    None => retry.push(e),
                }
            }
            if self.faces_left < before {
                revived = false;
            }
            sorted.drain(..next);
            let mut entries = sorted;
            entries.extend(pushed.into_iter().map(|r| r.0));
            entries.append(&mut rest);
            for e in retry.drain(..) {
                let [u, v, _] = entry_edge(e);
                if touched[u as usize] == pass || touched[v as usize] == pass {
                    entries.push(e);
                } else {
                    blocked.push(e);
                }
            }
            let current = |&e: &u128| self.current_ends(e).is_some();
            entries.retain(current);
            blocked.retain(current);
            self.entries = entries;
            // In id order, neighbouring survivors share cache lines.
            survivors.sort_unstable();
            self.rank(&survivors, Some(&changed));
            for k in survivors.drain(..) {
                changed[k as usize] = false;
            }
        }
    }
}
