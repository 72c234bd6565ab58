//! Resident geometry: the decoded geometry of the displayed nodes, plus recently displayed ones kept
//! while memory allows, evicted least recently used first.

use crate::error::Result;
use crate::format::{Attributes, ByteSource, NodeGeometry, NodeRecord, Reader};
use std::collections::{BTreeSet, HashMap};

/// Resident bytes of a node's geometry as the record announces it: its vertex attributes and
/// indices (what [`geometry_bytes`] measures once it is decoded; the reader checks they agree).
pub fn record_bytes(n: &NodeRecord, a: Attributes) -> u64 {
    let per_vertex = 12 + 12 * a.normals as u64 + 8 * a.uvs as u64 + 4 * a.colors as u64;
    n.vertices as u64 * per_vertex + 12 * n.faces as u64
}

/// Resident bytes of decoded geometry: vertex attributes and indices.
pub fn geometry_bytes(g: &NodeGeometry) -> u64 {
    (12 * (g.positions.len() + g.normals.len()) + 8 * g.uvs.len() + 4 * (g.colors.len() + g.indices.len())) as u64
}

struct Entry {
    geometry: NodeGeometry,
    bytes: u64,
    /// When it stopped being displayed (for LRU order); meaningless while displayed.
    stamp: u64,
    displayed: bool,
}

/// Loaded node geometry. With a budget, resident bytes never exceed it (provided the displayed
/// nodes fit, which front selection guarantees); without one, the nodes no longer displayed are
/// kept up to as many bytes as the displayed ones.
#[derive(Default)]
pub struct Cache {
    entries: HashMap<u32, Entry>,
    /// Entries not displayed, by (stamp, node): the least recently used first.
    idle: BTreeSet<(u64, u32)>,
    resident: u64,
    displayed: u64,
    budget: Option<u64>,
    clock: u64,
}

impl Cache {
    pub fn new(budget: Option<u64>) -> Cache {
        Cache { budget, ..Cache::default() }
    }

    /// Bytes of all loaded geometry.
    pub fn resident_bytes(&self) -> u64 {
        self.resident
    }

    /// Geometry of a displayed node.
    pub fn get(&self, node: u32) -> Option<&NodeGeometry> {
        self.entries.get(&node).filter(|e| e.displayed).map(|e| &e.geometry)
    }

    /// Whether a node's geometry is loaded, displayed or not.
    pub fn contains(&self, node: u32) -> bool {
        self.entries.contains_key(&node)
    }

    /// Make the displayed set `front` (after dropping `removed` from display, ahead of `added`):
    /// removed nodes become evictable, added ones are taken from the cache or read.
    pub fn update<S: ByteSource>(&mut self, added: &[u32], removed: &[u32], reader: &Reader<S>) -> Result<()> {
        self.clock += 1;
        for r in removed {
            if let Some(e) = self.entries.get_mut(r).filter(|e| e.displayed) {
                e.displayed = false;
                e.stamp = self.clock;
                self.displayed -= e.bytes;
                self.idle.insert((e.stamp, *r));
            }
        }
        for &a in added {
            if let Some(e) = self.entries.get_mut(&a) {
                if !e.displayed {
                    self.idle.remove(&(e.stamp, a));
                    e.displayed = true;
                    self.displayed += e.bytes;
                }
                continue;
            }
            // Make room before reading, so that the new node does not come on top of a full budget.
            if let Some(b) = self.budget {
                let rec = reader.nodes().get(a as usize).copied();
                let expected = rec.map_or(0, |n| record_bytes(&n, reader.header().attributes));
                self.evict_to(b.saturating_sub(expected));
            }
            let mut geometry = reader.read_node(a)?;
            if reader.header().major >= 3 {
                super::face_order::morton(&mut geometry);
            }
            let bytes = geometry_bytes(&geometry);
            self.resident += bytes;
            self.displayed += bytes;
            self.entries.insert(a, Entry { geometry, bytes, stamp: 0, displayed: true });
        }
        let cap = self.budget.unwrap_or(2 * self.displayed);
        self.evict_to(cap);
        Ok(())
    }

    /// Bytes of the displayed nodes' geometry.
    pub fn displayed_bytes(&self) -> u64 {
        self.displayed
    }

    /// Evict idle entries, least recently used first, until at most `limit` bytes are resident
    /// (never displayed ones).
    pub fn evict_to(&mut self, limit: u64) {
        while self.resident > limit {
            let Some((_, node)) = self.idle.pop_first() else { return };
            if let Some(e) = self.entries.remove(&node) {
                self.resident -= e.bytes;
            }
        }
    }
}
