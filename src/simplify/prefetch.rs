//! Prefetching on x86_64: hints that start fetching into the cache what ranking and the passes
//! will soon need. Hints only: they change nothing but timing, and are no-ops elsewhere.

use super::queue::entry_edge;
use super::state::State;

/// A hint to start fetching `x` into the cache, for data the queue will soon need; none off x86_64.
#[inline(always)]
pub(super) fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is only a hint: it never faults, reads nothing into the program and
    // writes nothing; the pointer comes from a live reference anyway.
    #[allow(unused_unsafe)]
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>((x as *const T).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

impl State {
    /// Start fetching what ranking an edge needs of its end `w`: record, version and quadric.
    pub(super) fn prefetch_vertex(&self, w: u32) {
        let w = w as usize;
        prefetch(&self.verts[w]);
        prefetch(&self.version[w]);
        let q = &self.quadrics[w];
        prefetch(&q.a[0]);
        prefetch(&q.area);
    }

    /// Start fetching what planning a queued edge needs of its ends.
    pub(super) fn prefetch_ends(&self, e: u128) {
        let [u, v, _] = entry_edge(e);
        for w in [u, v] {
            self.prefetch_vertex(w);
        }
    }

    /// Start fetching the face lists of a current queued edge's ends (records fetched earlier).
    pub(super) fn prefetch_lists(&self, e: u128) {
        for w in self.current_ends(e).into_iter().flatten() {
            self.prefetch_list(w);
        }
    }

    pub(super) fn prefetch_list(&self, w: u32) {
        if let Some(f) = self.face_lists.get(self.verts[w as usize].start as usize) {
            prefetch(f);
        }
    }

    /// Start fetching the faces of a current queued edge's ends (lists fetched earlier).
    pub(super) fn prefetch_faces(&self, e: u128) {
        for w in self.current_ends(e).into_iter().flatten() {
            self.prefetch_faces_of(w);
        }
    }

    /// Start fetching what checking and collapsing a current queued edge needs of the faces
    /// around it (faces fetched earlier): their vertices' records and their corners.
    pub(super) fn prefetch_around(&self, e: u128) {
        for w in self.current_ends(e).into_iter().flatten() {
            for &f in self.faces_of(w) {
                let f = f as usize;
                for y in self.faces[f].v {
                    if let Some(x) = self.verts.get(y as usize) {
                        prefetch(x);
                    }
                }
                prefetch(&self.wedges[f]);
                if let Some(n) = self.normals.get(3 * f) {
                    prefetch(n);
                }
                if let Some(uv) = self.uvs.get(3 * f) {
                    prefetch(uv);
                }
            }
        }
    }

    /// Start fetching the face lists of the vertices opposite a current queued edge, which its
    /// collapse edits (their records fetched earlier).
    pub(super) fn prefetch_opposite(&self, e: u128) {
        if let Some([u, v]) = self.current_ends(e) {
            for &f in self.faces_of(u) {
                let t = self.tri(f);
                if t.contains(&v) {
                    self.prefetch_list(t[0] ^ t[1] ^ t[2] ^ u ^ v);
                }
            }
        }
    }

    pub(super) fn prefetch_faces_of(&self, w: u32) {
        for &f in self.faces_of(w) {
            prefetch(&self.faces[f as usize]);
        }
    }
}
