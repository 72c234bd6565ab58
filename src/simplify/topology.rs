//! Topology changes (`SimplifyOptions::topology`): where the link condition alone blocks a
//! collapse, drop the closed tetrahedron the edge is on, or cut the mesh along the triangle of
//! edges that blocks it and cap both sides.

use super::state::{EdgeFaces, Face, Kind, State, Vertex, DEAD};
use glam::{DVec3, Vec2, Vec3};

impl State {
    /// Make a topology change that unblocks the collapse of edge (u, v), which the link condition
    /// blocks, if there is one that moves the surface by at most `limit` (squared): drop the
    /// closed tetrahedron the edge is on, or cut the mesh along a triangle of edges through it
    /// that is not a face. The collapse itself is tried again afterwards, and may still fail its
    /// shape checks. `out` gets the vertices whose edges must be ranked again.
    pub(super) fn unblock(&mut self, u: u32, v: u32, e: &EdgeFaces, limit: f64, out: &mut Vec<u32>) -> bool {
        out.clear();
        // Pinned vertices keep their faces' edges: no cut through them, no tetrahedron dropped.
        if self.verts[u as usize].locked || self.verts[v as usize].locked || self.is_pinned(u) || self.is_pinned(v) || e.n != 2 {
            return false;
        }
        if self.one_group(&[u, v]) && self.drop_tetrahedron(u, v, e, limit) {
            return true;
        }
        // A third common neighbour y of u and v: (u, v, y) is a cycle of edges but no face.
        let mut around_u: Vec<u32> = self.faces_of(u).iter().flat_map(|&f| self.tri(f)).collect();
        around_u.sort_unstable();
        let third = self
            .faces_of(v)
            .iter()
            .flat_map(|&f| self.tri(f))
            .find(|&y| y != u && y != v && y != e.x[0] && y != e.x[1] && around_u.binary_search(&y).is_ok());
        third.is_some_and(|y| self.spread_sq(&[u, v, y]) <= limit && self.cut([u, v, y], out))
    }

    /// Remove a closed tetrahedron, a component that no collapse can shrink, if (u, v) is on one.
    fn drop_tetrahedron(&mut self, u: u32, v: u32, e: &EdgeFaces, limit: f64) -> bool {
        let corners = [u, v, e.x[0], e.x[1]];
        // With groups, not a group's last faces (all four faces are of one group: `unblock` checked
        // u's and v's, which are all four).
        let group = self.faces[e.f[0] as usize].group as usize;
        if (self.grouped && self.group_faces.get(group).is_none_or(|&n| n <= 4))
            || corners.iter().any(|&w| self.verts[w as usize].len != 3 || self.verts[w as usize].locked || self.is_pinned(w))
        {
            return false;
        }
        let mut faces: Vec<u32> = corners.iter().flat_map(|&w| self.faces_of(w).iter().copied()).collect();
        faces.sort_unstable();
        faces.dedup();
        let spread_sq = self.spread_sq(&corners);
        if faces.len() != 4 || faces.iter().any(|&f| self.tri(f).iter().any(|y| !corners.contains(y))) || spread_sq > limit {
            return false;
        }
        self.error_sq = self.error_sq.max(spread_sq);
        if let Some(lost) = self.group_lost_sq.get(group).copied() {
            let worst = corners.iter().map(|&w| self.vertex_error_sq(w)).fold(spread_sq.max(lost), f64::max);
            self.group_lost_sq[group] = worst;
        }
        for &w in &corners {
            let x = &mut self.verts[w as usize];
            x.len = 0;
            x.locked = true;
            self.version[w as usize] += 1;
        }
        for &f in &faces {
            self.faces[f as usize].v = [DEAD; 3];
        }
        if let Some(n) = self.group_faces.get_mut(group) {
            *n -= 4;
        }
        self.faces_left -= 4;
        true
    }

    /// Whether all faces around the vertices `vs` are of one group (always, without groups): a
    /// change of topology there neither joins groups by a cap nor moves a group border.
    fn one_group(&self, vs: &[u32]) -> bool {
        if !self.grouped {
            return true;
        }
        let mut faces = vs.iter().flat_map(|&w| self.faces_of(w).iter());
        let Some(&first) = faces.next() else { return true };
        let group = self.faces[first as usize].group;
        faces.all(|&f| self.faces[f as usize].group == group)
    }

    /// Whether the faces along the cycle of edges a → b → c → a are all of one group (or there are
    /// no groups). A cut there separates faces of that group only and caps both sides with it;
    /// other groups' faces around the cycle's vertices keep their edges, only moving to a copy
    /// of the vertex at the same place, so no group gains or loses a border.
    fn cycle_in_one_group(&self, cycle: [u32; 3]) -> bool {
        if !self.grouped {
            return true;
        }
        let mut group = None;
        for i in 0..3 {
            let (a, b) = (cycle[i], cycle[(i + 1) % 3]);
            for &f in self.faces_of(a) {
                if self.tri(f).contains(&b) {
                    let g = self.faces[f as usize].group;
                    if *group.get_or_insert(g) != g {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// The largest squared distance of the vertices `vs` from their centroid: how far a cap over
    /// them, or their removal, moves the surface.
    fn spread_sq(&self, vs: &[u32]) -> f64 {
        let center = vs.iter().map(|&w| self.pos(w)).sum::<DVec3>() / vs.len() as f64;
        vs.iter().map(|&w| (self.pos(w) - center).length_squared()).fold(0.0, f64::max)
    }

    /// Cut the mesh along the cycle of edges a → b → c → a, which is no face, and cap both sides:
    /// each vertex keeps its faces on the left of the cycle and a new copy takes those on the
    /// right. Only where every fan around the cycle is closed and manifold. A handle through the
    /// cycle is removed, or the component split in two at a neck; the mesh stays manifold.
    fn cut(&mut self, cycle: [u32; 3], out: &mut Vec<u32>) -> bool {
        if cycle.iter().any(|&w| self.verts[w as usize].locked || self.is_pinned(w)) || !self.cycle_in_one_group(cycle) {
            return false;
        }
        let mut sides = Vec::with_capacity(3);
        for i in 0..3 {
            let (v, next, prev) = (cycle[i], cycle[(i + 1) % 3], cycle[(i + 2) % 3]);
            let (Some(left), Some(right)) = (self.arc(v, next, prev), self.arc(v, prev, next)) else { return false };
            let mut all: Vec<u32> = left.iter().chain(&right).copied().collect();
            all.sort_unstable();
            all.dedup();
            if all.len() != self.verts[v as usize].len as usize || left.len() + right.len() != all.len() {
                return false;
            }
            sides.push((left, right));
        }
        // Not where a side is the three faces of one vertex (a spike, which a collapse removes
        // under the shape checks), nor with a degenerate cap.
        for side in [0, 1] {
            let mut faces: Vec<u32> = sides.iter().flat_map(|s| if side == 0 { &s.0 } else { &s.1 }).copied().collect();
            faces.sort_unstable();
            faces.dedup();
            if faces.len() <= 3 {
                return false;
            }
        }
        let p = cycle.map(|w| self.pos(w));
        if (p[1] - p[0]).cross(p[2] - p[0]).length_squared() == 0.0 {
            return false;
        }
        let spread_sq = self.spread_sq(&cycle);
        self.error_sq = self.error_sq.max(spread_sq);
        // The cap's move counts in the error of the group the cut runs through, not in that of
        // other groups whose faces touch the cycle's vertices.
        let cut_group = self.faces[sides[0].0[0] as usize].group as usize;
        if let Some(lost) = self.group_lost_sq.get_mut(cut_group) {
            *lost = lost.max(spread_sq);
        }
        let copies: [u32; 3] = std::array::from_fn(|i| self.verts.len() as u32 + i as u32);
        for (i, &v) in cycle.iter().enumerate() {
            let x = self.verts[v as usize];
            self.verts.push(Vertex { len: 0, kind: Kind::Unknown, ..x });
            self.quadrics.push(self.quadrics[v as usize]);
            self.version.push(0);
            for &f in &sides[i].1 {
                for w in &mut self.faces[f as usize].v {
                    if *w == v {
                        *w = copies[i];
                    }
                }
            }
        }
        // The left side is closed by the cycle reversed, the right side by the copies in order.
        let first = self.faces.len() as u32;
        for (side, order) in [[0, 2, 1], [0, 1, 2]].into_iter().enumerate() {
            let f = self.faces.len();
            let cap = order.map(|i| if side == 0 { cycle[i] } else { copies[i] });
            let p = cap.map(|w| self.pos(w));
            let normal = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero().as_vec3();
            let source = if side == 0 { sides[0].0[0] } else { sides[0].1[0] };
            let group = self.faces[source as usize].group;
            self.faces.push(Face { v: cap, group, normal });
            if let Some(n) = self.group_faces.get_mut(group as usize) {
                *n += 1;
            }
            self.wedges.push([0; 3]);
            self.face_materials.push(self.face_materials[source as usize]);
            self.cap_source.push(if (source as usize) < self.input_faces {
                source
            } else {
                self.cap_source[source as usize - self.input_faces]
            });
            // Corner attributes, copied below from the fans' corners.
            if !self.normals.is_empty() {
                self.normals.extend([Vec3::ZERO; 3]);
            }
            if !self.uvs.is_empty() {
                self.uvs.extend([Vec2::ZERO; 3]);
            }
            if !self.colors.is_empty() {
                self.colors.extend([[0; 4]; 3]);
            }
            for (k, (&i, &w)) in order.iter().zip(&cap).enumerate() {
                let arc = if side == 0 { &sides[i].0 } else { &sides[i].1 };
                let from = self.corner(arc[0], w);
                self.copy_corner(from, 3 * f + k);
            }
        }
        self.faces_left += 2;
        for (i, &v) in cycle.iter().enumerate() {
            for (w, arc, cap) in [(v, &sides[i].0, first), (copies[i], &sides[i].1, first + 1)] {
                let start = self.face_lists.len() as u32;
                self.face_lists.extend_from_slice(arc);
                self.face_lists.push(cap);
                let x = &mut self.verts[w as usize];
                x.start = start;
                x.len = arc.len() as u32 + 1;
                x.kind = Kind::Unknown;
            }
            self.version[v as usize] += 1;
        }
        out.extend(cycle.iter().chain(&copies));
        true
    }

    /// The faces around `v` from the one where `from` follows `v` on to the one where `to`
    /// precedes it, turning the way faces are wound; None if the fan is open or not manifold.
    fn arc(&self, v: u32, from: u32, to: u32) -> Option<Vec<u32>> {
        let after = |w: u32| {
            self.faces_of(v).iter().copied().find(|&f| {
                let t = self.tri(f);
                (0..3).any(|i| t[i] == v && t[(i + 1) % 3] == w)
            })
        };
        let mut f = after(from)?;
        let mut out = Vec::new();
        for _ in 0..self.verts[v as usize].len {
            out.push(f);
            let t = self.tri(f);
            let i = t.iter().position(|&w| w == v)?;
            let prev = t[(i + 2) % 3];
            if prev == to {
                return Some(out);
            }
            f = after(prev)?;
        }
        None
    }
}
