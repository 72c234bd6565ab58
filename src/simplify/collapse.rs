//! One collapse: the ways the rules allow to collapse an edge and what each costs, the checks a
//! candidate must pass (link condition, group survival, face shape), and the collapse itself with
//! its corner attributes.

use super::quadric::Quadric;
use super::state::{EdgeFaces, Kind, State, DEAD};
use crate::mesh::NO_FACE;
use glam::{DVec3, Vec3};

/// One way to collapse an edge: `remove` merges into `keep`, which moves to `pos`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Candidate {
    pub(super) remove: u32,
    pub(super) keep: u32,
    /// A position representable in f32, where the vertex is stored.
    pub(super) pos: DVec3,
    /// Free–free collapse: attributes interpolated from `remove` (0) to `keep` (1) at this parameter.
    pub(super) lerp: Option<f64>,
    /// Ordering key: the larger of the two ends' quadric cost / face area.
    pub(super) cost: f64,
    /// Squared error estimate: the larger of the two ends' quadric cost / total weight, and of the
    /// errors already merged into them.
    pub(super) error_sq: f64,
}

/// Which collapses of an edge the rules allow.
#[derive(Clone, Copy, Debug)]
pub(super) enum Allowed {
    Nothing,
    /// Both ends free: anywhere, attributes interpolated.
    Anywhere,
    /// Onto one end or the other.
    Ends {
        u_into_v: bool,
        v_into_u: bool,
    },
}

/// The legal candidates of an edge, cheapest first.
#[derive(Clone, Copy, Debug)]
pub(super) struct Plan {
    pub(super) e: EdgeFaces,
    pub(super) c: [Candidate; 4],
    pub(super) n: usize,
}

impl Plan {
    pub(super) const EMPTY: Plan = Plan {
        e: EdgeFaces { f: [NO_FACE; 2], x: [NO_FACE; 2], n: 0 },
        c: [Candidate { remove: 0, keep: 0, pos: DVec3::ZERO, lerp: None, cost: f64::INFINITY, error_sq: f64::INFINITY }; 4],
        n: 0,
    };
}

/// A face around an end of an edge being checked: its corner positions, which corner moves, and
/// its input normal.
#[derive(Clone, Copy, Debug)]
pub(super) struct Around {
    p: [DVec3; 3],
    moved: usize,
    normal: Vec3,
}

impl State {
    /// Which collapses of edge (u, v) with faces `e` the rules allow.
    fn allowed(&mut self, u: u32, v: u32, e: &EdgeFaces) -> Allowed {
        if self.verts[u as usize].locked || self.verts[v as usize].locked {
            return Allowed::Nothing;
        }
        let (ku, kv) = (self.kind(u), self.kind(v));
        self.allowed_kinds(u, v, e, ku, kv)
    }

    /// `allowed` for two unlocked ends of kinds `ku` and `kv`.
    pub(super) fn allowed_kinds(&self, u: u32, v: u32, e: &EdgeFaces, ku: Kind, kv: Kind) -> Allowed {
        if ku == Kind::Free && kv == Kind::Free {
            return Allowed::Anywhere;
        }
        let feature = self.is_feature(u, v, e);
        let removable = |kr: Kind, k: u32| match kr {
            Kind::Free => true,
            Kind::Line => feature && (e.n == 1 || !self.same_corner(self.corner(e.f[0], k), self.corner(e.f[1], k))),
            _ => false,
        };
        match (removable(ku, v), removable(kv, u)) {
            (false, false) => Allowed::Nothing,
            (u_into_v, v_into_u) => Allowed::Ends { u_into_v, v_into_u },
        }
    }

    /// The quadric optimum of a free–free collapse, when well conditioned and not farther from
    /// the edge's midpoint than the edge is long, rounded to f32.
    pub(super) fn optimum(q: &Quadric, pu: DVec3, pv: DVec3) -> Option<DVec3> {
        let mid = 0.5 * (pu + pv);
        q.optimum().filter(|p| (*p - mid).length_squared() <= (pv - pu).length_squared()).map(|p| p.as_vec3().as_dvec3())
    }

    /// Fill `plan` with the legal ways to collapse edge (u, v) with faces `e`, cheapest first;
    /// false if there is none.
    pub(super) fn plan(&mut self, u: u32, v: u32, e: EdgeFaces, plan: &mut Plan) -> bool {
        plan.e = e;
        plan.n = 0;
        let allowed = self.allowed(u, v, &e);
        let mut q = self.quadrics[u as usize];
        q.add(&self.quadrics[v as usize]);
        let (pu, pv) = (self.pos(u), self.pos(v));
        let (qu, qv) = (&self.quadrics[u as usize], &self.quadrics[v as usize]);
        let (eu, ev) = (qu.err_sq, qv.err_sq);
        let mut add = |remove: u32, keep: u32, pos: DVec3, lerp: Option<f64>| {
            let (cu, cv) = (qu.eval(pos), qv.eval(pos));
            let cost = (cu / qu.area.max(f64::MIN_POSITIVE)).max(cv / qv.area.max(f64::MIN_POSITIVE));
            let error_sq = (cu / qu.w.max(f64::MIN_POSITIVE)).max(cv / qv.w.max(f64::MIN_POSITIVE)).max(eu).max(ev);
            plan.c[plan.n] = Candidate { remove, keep, pos, lerp, cost, error_sq };
            plan.n += 1;
        };
        match allowed {
            Allowed::Nothing => return false,
            Allowed::Anywhere => {
                let d = pv - pu;
                let len2 = d.length_squared();
                let mut at = |p: DVec3| {
                    let t = if len2 > 0.0 { ((p - pu).dot(d) / len2).clamp(0.0, 1.0) } else { 0.5 };
                    add(u, v, p, Some(t));
                };
                if let Some(p) = State::optimum(&q, pu, pv) {
                    at(p);
                }
                at(pu);
                at(pv);
                at((0.5 * (pu + pv)).as_vec3().as_dvec3());
            }
            Allowed::Ends { u_into_v, v_into_u } => {
                if u_into_v {
                    add(u, v, pv, None);
                }
                if v_into_u {
                    add(v, u, pu, None);
                }
            }
        }
        plan.c[..plan.n].sort_unstable_by(|a, b| a.cost.total_cmp(&b.cost));
        true
    }

    /// Link condition and group survival for collapsing edge (u, v) with faces `e`. Both are
    /// symmetric in the two ends, so they hold for every candidate of the edge or for none.
    pub(super) fn topology_ok(&self, u: u32, v: u32, e: &EdgeFaces, around: &mut Vec<u32>) -> bool {
        let (x0, x1) = (e.x[0], if e.n == 2 { e.x[1] } else { e.x[0] });
        // Link condition: the common neighbours of u and v are exactly the opposite vertices.
        around.clear();
        for &f in self.faces_of(u) {
            around.extend(self.tri(f));
        }
        let mut seen = [false; 2];
        for &f in self.faces_of(v) {
            for y in self.tri(f) {
                if y != v && y != u && around.contains(&y) {
                    if y != x0 && y != x1 {
                        return false;
                    }
                    seen[usize::from(y != x0)] = true;
                }
            }
        }
        if usize::from(seen[0]) + usize::from(seen[1]) != e.n {
            return false;
        }
        // Pins: a vertex merged into a pinned one must not join it to another pinned vertex by a
        // new edge. A piece built alone cannot see whether its neighbour makes the same edge, and
        // two pieces that both did would meet in an edge of four faces.
        let ends = match (self.is_pinned(u), self.is_pinned(v)) {
            (true, false) => Some((u, v)),
            (false, true) => Some((v, u)),
            _ => None,
        };
        if let Some((b, r)) = ends {
            let joined = |y: u32| self.faces_of(b).iter().any(|&f| self.tri(f).contains(&y));
            for &f in self.faces_of(r) {
                for y in self.tri(f) {
                    if y != u && y != v && self.is_pinned(y) && !joined(y) {
                        return false;
                    }
                }
            }
        }
        if e.n == 2 {
            let spans =
                |w: u32| self.faces_of(w).iter().any(|&f| !e.f.contains(&f) && self.tri(f).contains(&x0) && self.tri(f).contains(&x1));
            if spans(u) && spans(v) {
                return false;
            }
        }
        // Group survival for collapses that remove faces of two groups (or one border face).
        // Without groups it keeps components from vanishing, which topology changes allow.
        if self.topology && !self.grouped {
            return true;
        }
        for i in 0..e.n {
            let (f, other) = (e.f[i], if e.n == 2 { e.f[1 - i] } else { NO_FACE });
            let g = self.faces[f as usize].group;
            if other != NO_FACE && self.faces[other as usize].group == g {
                continue;
            }
            let kept = |w: u32| {
                self.faces_of(w).iter().any(|&h| h != f && h != other && self.faces[h as usize].group == g && self.tri(h).contains(&e.x[i]))
            };
            if !kept(u) && !kept(v) {
                return false;
            }
        }
        true
    }

    /// The faces around `w` other than the edge's faces `e`, with their corner positions, for
    /// `shape_ok` of every candidate of the edge.
    pub(super) fn gather(&self, w: u32, e: &EdgeFaces, out: &mut Vec<Around>) {
        out.clear();
        for &f in self.faces_of(w) {
            if !e.f.contains(&f) {
                let t = self.tri(f);
                let moved = if t[0] == w {
                    0
                } else if t[1] == w {
                    1
                } else {
                    2
                };
                out.push(Around { p: t.map(|y| self.pos(y)), moved, normal: self.faces[f as usize].normal });
            }
        }
    }

    /// Face shape for one candidate of the edge (u, v) whose faces around u and v, other than
    /// the edge's own, are `around_u` and `around_v`: no flip beyond the bound, no degenerate or
    /// new sliver face.
    pub(super) fn shapes_ok(&self, u: u32, c: &Candidate, around_u: &[Around], around_v: &[Around]) -> bool {
        let (at_r, at_k) = if c.remove == u { (around_u, around_v) } else { (around_v, around_u) };
        if !at_r.iter().all(|a| self.shape_ok(a, c.pos)) {
            return false;
        }
        c.pos == self.pos(c.keep) || at_k.iter().all(|a| self.shape_ok(a, c.pos))
    }

    /// Whether face `a` with its moving corner at `to` keeps its orientation and shape.
    fn shape_ok(&self, a: &Around, to: DVec3) -> bool {
        let old = a.p;
        let mut new = old;
        new[a.moved] = to;
        let n_old = (old[1] - old[0]).cross(old[2] - old[0]);
        let n_new = (new[1] - new[0]).cross(new[2] - new[0]);
        let len_new = n_new.length();
        let quality = |p: &[DVec3; 3], len: f64| {
            let l2 = (p[1] - p[0]).length_squared() + (p[2] - p[1]).length_squared() + (p[0] - p[2]).length_squared();
            if l2 > 0.0 {
                2.0 * 3f64.sqrt() * len / l2
            } else {
                0.0
            }
        };
        let q_new = quality(&new, len_new);
        if q_new <= 1e-6 || (q_new < self.min_quality && q_new < quality(&old, n_old.length())) {
            return false;
        }
        let n_input = a.normal.as_dvec3();
        n_input == DVec3::ZERO || n_input.dot(n_new) >= self.cos_turn * len_new
    }

    pub(super) fn copy_corner(&mut self, from: usize, to: usize) {
        self.wedges[to / 3][to % 3] = self.wedge(from);
        if !self.normals.is_empty() {
            self.normals[to] = self.normals[from];
        }
        if !self.uvs.is_empty() {
            self.uvs[to] = self.uvs[from];
        }
        if !self.colors.is_empty() {
            self.colors[to] = self.colors[from];
        }
    }

    /// Faces of the sector around `r` that starts at `start` (on edge (r, from)) and ends at the
    /// next feature edge, excluding `start`.
    fn sector(&self, r: u32, start: u32, from: u32, out: &mut Vec<u32>) {
        out.clear();
        let (mut cur, mut prev) = (start, from);
        for _ in 0..self.verts[r as usize].len {
            let t = self.tri(cur);
            let y = t[0] ^ t[1] ^ t[2] ^ r ^ prev;
            let Some(&g) = self.faces_of(r).iter().find(|&&g| g != cur && self.tri(g).contains(&y)) else { return };
            if self.is_feature(r, y, &EdgeFaces { f: [cur, g], x: [NO_FACE; 2], n: 2 }) {
                return;
            }
            out.push(g);
            cur = g;
            prev = y;
        }
    }

    pub(super) fn collapse(&mut self, e: &EdgeFaces, c: Candidate) {
        let (r, k) = (c.remove, c.keep);
        let mut rf = std::mem::take(&mut self.scratch_r);
        let mut kf = std::mem::take(&mut self.scratch_k);
        rf.clear();
        kf.clear();
        rf.extend(self.faces_of(r).iter().copied().filter(|f| !e.f.contains(f)));
        kf.extend(self.faces_of(k).iter().copied().filter(|f| !e.f.contains(f)));

        // Corners that follow r take the survivor's values (wedge and attributes) on their side.
        if let Some(t) = c.lerp {
            let (cr, ck) = (self.corner(e.f[0], r), self.corner(e.f[0], k));
            self.lerp_corner(cr, ck, t as f32);
            for (&f, v) in kf.iter().map(|f| (f, k)).chain(rf.iter().map(|f| (f, r))) {
                let to = self.corner(f, v);
                self.copy_corner(cr, to);
            }
        } else {
            let split = e.n == 2 && self.verts[r as usize].kind == Kind::Line;
            let mut side = Vec::new();
            if split {
                self.sector(r, e.f[0], k, &mut side);
            }
            let (c0, c1) = (self.corner(e.f[0], k), if split { self.corner(e.f[1], k) } else { 0 });
            for &f in &rf {
                let from = if split && !side.contains(&f) { c1 } else { c0 };
                let to = self.corner(f, r);
                self.copy_corner(from, to);
            }
        }

        for &f in &e.f[..e.n] {
            self.faces[f as usize].v = [DEAD; 3];
            if let Some(n) = self.group_faces.get_mut(self.faces[f as usize].group as usize) {
                *n -= 1;
            }
        }
        self.faces_left -= e.n;
        for &f in &rf {
            for v in &mut self.faces[f as usize].v {
                if *v == r {
                    *v = k;
                }
            }
        }
        // Only k and the opposite vertices can change kind: every other edge keeps its faces and,
        // corners being copied per side, its feature status. A free–free collapse changes none: all
        // edges at r and k are plain, and so are the edges they merge into.
        for &x in &e.x[..e.n] {
            let (start, len) = (self.verts[x as usize].start as usize, self.verts[x as usize].len as usize);
            let mut kept = 0;
            for i in 0..len {
                let f = self.face_lists[start + i];
                if !e.f.contains(&f) {
                    self.face_lists[start + kept] = f;
                    kept += 1;
                }
            }
            let xv = &mut self.verts[x as usize];
            xv.len = kept as u32;
            if c.lerp.is_none() {
                xv.kind = Kind::Unknown;
            }
        }

        if self.face_lists.len() > self.compact_at {
            self.compact_face_lists();
            self.compact_at = 2 * self.face_lists.len().max(1024);
        }
        let start = self.face_lists.len() as u32;
        self.face_lists.extend_from_slice(&kf);
        self.face_lists.extend_from_slice(&rf);
        let qr = self.quadrics[r as usize];
        self.quadrics[k as usize].add(&qr);
        let kv = &mut self.verts[k as usize];
        kv.start = start;
        kv.len = (kf.len() + rf.len()) as u32;
        kv.pos = c.pos.as_vec3();
        if c.lerp.is_none() {
            kv.kind = Kind::Unknown;
        }
        let rv = &mut self.verts[r as usize];
        rv.len = 0;
        rv.locked = true;
        self.version[k as usize] += 1;
        self.version[r as usize] += 1;
        self.error_sq = self.error_sq.max(c.error_sq);
        self.quadrics[k as usize].err_sq = c.error_sq;

        self.scratch_r = rf;
        self.scratch_k = kf;
    }

    /// Set corner `cr` to its attributes interpolated towards corner `ck` at `t`.
    fn lerp_corner(&mut self, cr: usize, ck: usize, t: f32) {
        if !self.normals.is_empty() {
            let n = self.normals[cr].lerp(self.normals[ck], t);
            self.normals[cr] = n.try_normalize().unwrap_or(n);
        }
        if !self.uvs.is_empty() {
            self.uvs[cr] = self.uvs[cr].lerp(self.uvs[ck], t);
        }
        if !self.colors.is_empty() {
            let (a, b) = (self.colors[cr], self.colors[ck]);
            self.colors[cr] = std::array::from_fn(|i| (f32::from(a[i]) + (f32::from(b[i]) - f32::from(a[i])) * t).round() as u8);
        }
    }

    fn compact_face_lists(&mut self) {
        let mut lists = Vec::with_capacity(3 * self.faces_left + 1024);
        for x in &mut self.verts {
            let start = x.start as usize;
            x.start = lists.len() as u32;
            lists.extend_from_slice(&self.face_lists[start..start + x.len as usize]);
        }
        self.face_lists = lists;
    }
}
