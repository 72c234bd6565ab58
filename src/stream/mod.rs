//! Streaming for display (METHOD.md §6): per frame, the front of the hierarchy a camera needs, its
//! delta from the last frame, and the geometry of its nodes, read lazily from a chunk file.
//!
//! - [`refine`]: front selection, breadth-first with the neighbour rule, largest projected error or
//!   the paper's priority first;
//! - [`cache`]: resident geometry under a memory budget, LRU;
//! - [`face_order`]: a format-3 node's faces put in Morton order as it is read, for the renderer's
//!   occlusion test;
//! - [`images`]: which image levels the front needs, and those held (selection.md §4);
//! - [`order`]: the front from front to back, by the file's separating planes (selection.md §5);
//! - [`budget`]: the frame-time controller on the pixel-error threshold;
//! - [`retention`]: shape retention of a front's image against the full-detail one;
//! - [`seams`]: triangles that close the slivers between displayed nodes of adjacent levels;
//! - [`session`]: cameras to play: an orbit moving in from far, or a path file's lines;
//! - [`play`]: a viewing session played frame by frame, drawn with the software renderer.

pub mod budget;
pub mod cache;
pub mod dag;
pub mod face_order;
pub mod images;
pub mod order;
pub mod play;
pub mod refine;
pub mod retention;
pub mod seams;
pub mod session;
#[cfg(test)]
mod tests;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::format::planes::Planes;
use crate::format::{ByteSource, NodeGeometry, NodeRecord, Reader};
use crate::mesh::{Material, Mesh};
use budget::FrameTime;
use cache::{record_bytes, Cache};
use images::ImageCache;
use order::Orderer;
pub use refine::Priority;
use refine::{Limits, Mark, Refiner};
use serde::Serialize;
use std::time::Instant;

/// What bounds the front; each budget is optional and they combine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Budgets {
    /// Most faces displayed at once (the paper's N_T = R / v).
    pub faces: Option<u64>,
    /// Most bytes of resident geometry (see [`cache::geometry_bytes`]).
    pub bytes: Option<u64>,
    /// Refinement stops where a node's projected geometric error is under this many pixels.
    pub pixel_error: f32,
    /// Frame time to keep, in milliseconds, by steering the pixel threshold from `pixel_error` on.
    pub target_ms: Option<f32>,
    /// Refinement order under the face and memory budgets.
    pub priority: Priority,
    /// Whether the frame-time controller also acts ahead (else it only reacts to measured times,
    /// for comparison): what comes into view is drawn coarse at first, and a front that adds
    /// faces is checked against the target before it is drawn.
    pub predict: bool,
}

impl Default for Budgets {
    fn default() -> Self {
        Budgets { faces: None, bytes: None, pixel_error: 1.0, target_ms: None, priority: Priority::Error, predict: true }
    }
}

/// Figures of one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    pub faces: u64,
    pub nodes: usize,
    /// Roots of culled subtrees (back-facing or outside the frustum).
    pub culled: usize,
    /// Displayed nodes per level, finest first.
    pub levels: Vec<u32>,
    /// Bytes read from the file so far, skeleton included.
    pub bytes_read: u64,
    pub resident_bytes: u64,
    /// The pixel-error threshold this frame was refined with.
    pub pixel_error: f32,
    /// Time to select the front and load its geometry and image levels.
    pub refine_ms: f64,
    /// Of that, the time to put the front in drawing order.
    pub order_ms: f64,
    /// Of that, the time to find the seams between levels (selection.md §8).
    pub seams_ms: f64,
    /// Triangles that fill those seams, and their area.
    pub seam_faces: u64,
    pub seam_area: f64,
    /// Bytes of image level files read so far, and image levels held as RGBA8 (counted in the
    /// memory budget with the geometry).
    pub texture_bytes_read: u64,
    pub texture_resident_bytes: u64,
    /// Per image the front draws: [image, wanted level, drawn level] (0 = full resolution).
    pub texture_levels: Vec<[u32; 3]>,
}

/// One frame's front and what changed since the previous frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FrameReport {
    /// Counts from 0.
    pub frame: u64,
    /// Displayed nodes, ascending.
    pub front: Vec<u32>,
    /// The same nodes from front to back for the camera (selection.md §5): the order to draw them
    /// in, nearest surfaces first, so that the depth test rejects what lies behind.
    pub order: Vec<u32>,
    /// Nodes displayed now and not in the previous frame, ascending.
    pub added: Vec<u32>,
    /// Nodes displayed in the previous frame and not now, ascending.
    pub removed: Vec<u32>,
    /// Roots of culled subtrees, ascending.
    pub culled: Vec<u32>,
    pub stats: Stats,
}

/// A viewing session over one chunk file.
pub struct Streamer<S> {
    reader: Reader<S>,
    budgets: Budgets,
    refiner: Refiner,
    cache: Cache,
    controller: Option<FrameTime>,
    front: Vec<u32>,
    culled: Vec<u32>,
    faces: u64,
    frame: u64,
    images: ImageCache,
    /// Decoded bytes of every image's coarsest level, kept out of the geometry's share of the budget.
    pinned: u64,
    /// Built with the separating planes after the first frame, or for it when it shows more than
    /// the top level: a first frame of the top level alone goes nearest box first (selection.md §6).
    orderer: Option<Orderer>,
    warnings: Vec<String>,
    /// Nodes the renderer found hidden in the last frame, ascending: not refined in the next.
    hidden: Vec<u32>,
    /// The open border of each displayed node, and the seams of the front between levels with
    /// the nodes they were made from (taking part, and their displayed neighbours).
    borders: rustc_hash::FxHashMap<u32, seams::Border>,
    seams: seams::Seams,
    seam_nodes: (Vec<u32>, Vec<u32>),
}

impl<S: ByteSource> Streamer<S> {
    /// Start a session. Budgets must admit the whole top level, which the first frame shows. The
    /// separating planes (`ORDR`, a file's last chunk) are read for the drawing order by the second
    /// [`Streamer::update`], or by the first when its front shows more than the top level; when they
    /// are damaged, fronts are ordered without them and [`Streamer::take_warnings`] says so. A
    /// reader opened with [`Reader::open_top`] shows the top level in the first frame and is
    /// completed by the second update.
    pub fn new(reader: Reader<S>, budgets: Budgets) -> Result<Streamer<S>> {
        let attrs = reader.header().attributes;
        let top = reader.levels().len().saturating_sub(1) as u32;
        let top_nodes = &reader.nodes()[reader.level_nodes(top).start as usize..reader.level_nodes(top).end as usize];
        let faces: u64 = top_nodes.iter().map(|n| n.faces as u64).sum();
        let bytes: u64 = top_nodes.iter().map(|n| record_bytes(n, attrs)).sum();
        let pinned = ImageCache::pinned_bytes(reader.textures(), reader.materials());
        let bytes = bytes + pinned;
        if budgets.faces.is_some_and(|b| b < faces) {
            return Err(Error::invalid(reader.path(), None, format!("the face budget is below the top level's {faces} faces")));
        }
        if budgets.bytes.is_some_and(|b| b < bytes) {
            return Err(Error::invalid(
                reader.path(),
                None,
                format!("the memory budget is below the top level's {bytes} bytes (images' coarsest levels included)"),
            ));
        }
        if budgets.pixel_error.is_nan() || budgets.pixel_error < 0.0 {
            return Err(Error::invalid(reader.path(), None, "the pixel-error threshold must be zero or more"));
        }
        Ok(Streamer {
            warnings: Vec::new(),
            hidden: Vec::new(),
            borders: Default::default(),
            seams: Default::default(),
            seam_nodes: Default::default(),
            orderer: None,
            cache: Cache::new(budgets.bytes.map(|b| b - pinned)),
            images: ImageCache::default(),
            pinned,
            controller: budgets.target_ms.map(|t| FrameTime::new(t, budgets.pixel_error)),
            reader,
            budgets,
            refiner: Refiner::default(),
            front: Vec::new(),
            culled: Vec::new(),
            faces: 0,
            frame: 0,
        })
    }

    pub fn reader(&self) -> &Reader<S> {
        &self.reader
    }

    /// The displayed nodes, ascending.
    pub fn front(&self) -> &[u32] {
        &self.front
    }

    /// Geometry of a displayed node.
    pub fn geometry(&self, node: u32) -> Option<&NodeGeometry> {
        self.cache.get(node)
    }

    /// Image levels that could not be read or decoded since the last call, each said once: they are
    /// drawn at a coarser level or untextured, not fatal; and damaged separating planes.
    pub fn take_warnings(&mut self) -> Vec<String> {
        let mut w = std::mem::take(&mut self.warnings);
        w.extend(self.images.take_warnings());
        w
    }

    /// What a renderer samples for image `image` this frame: its drawn level.
    pub fn image(&self, image: u32) -> Option<&crate::texture::sample::MipChain> {
        self.images.chain(image)
    }

    /// Compute the front for `camera`, load what it adds and report it. `frame_ms` is the time
    /// the previous frame took, fed to the frame-time controller when there is one.
    pub fn update(&mut self, camera: &Camera, frame_ms: Option<f32>) -> Result<FrameReport> {
        let start = Instant::now();
        if self.frame > 0 {
            self.reader.complete()?;
        }
        if let (Some(c), Some(ms)) = (self.controller.as_mut(), frame_ms) {
            c.measured(ms, self.faces);
        }
        let threshold = self.controller.map_or(self.budgets.pixel_error, |c| c.threshold());
        let mut limits = Limits {
            pixel_error: threshold,
            max_faces: self.budgets.faces,
            max_bytes: self.budgets.bytes.map(|b| b - self.pinned),
            priority: self.budgets.priority,
        };
        let attrs = self.reader.header().attributes;
        let bytes = |n: &NodeRecord| record_bytes(n, attrs);
        // Seed 000 §6: what comes into view is drawn coarse at first (the roots culled last frame
        // are not refined), and a front that adds faces is checked against the target before it
        // is drawn, from the last frame's cost per face: when it would overrun, it is selected
        // again with the predicted threshold.
        let predictive = self.budgets.predict && self.controller.is_some();
        let mut held: Vec<u32> = if predictive { self.culled.clone() } else { Vec::new() };
        if !self.hidden.is_empty() {
            held.extend(std::mem::take(&mut self.hidden));
            held.sort_unstable();
            held.dedup();
        }
        let held = &held[..];
        // Format 4: selection.md §9 over the DAG, else §3 over the tree.
        let dag = self.reader.header().is_dag();
        let select = |refiner: &mut Refiner, s: &crate::format::skeleton::Skeleton, limits: &Limits| {
            if dag {
                dag::select_skeleton(s, camera, limits, held, &bytes)
            } else {
                refiner.select(s, camera, limits, held, &bytes)
            }
        };
        let mut cut = select(&mut self.refiner, self.reader.skeleton(), &limits);
        let (mut added, mut removed) = diff(&self.front, &cut.shown);
        if let Some(c) = self.controller.as_mut().filter(|_| predictive) {
            let nodes = self.reader.nodes();
            let new_faces = added.iter().map(|&a| nodes[a as usize].faces as u64).sum();
            c.predict(cut.faces, new_faces);
            if c.threshold() != limits.pixel_error {
                limits.pixel_error = c.threshold();
                cut = select(&mut self.refiner, self.reader.skeleton(), &limits);
                (added, removed) = diff(&self.front, &cut.shown);
            }
        }
        self.cache.update(&added, &removed, &self.reader)?;
        // Image levels wait for the whole node table (strata-v3.md §1.1): their offsets rest on it.
        if !self.reader.textures().is_empty() && self.reader.is_complete() {
            let (cache, materials) = (&self.cache, self.reader.materials());
            let wanted = images::wanted(self.reader.skeleton(), camera, &cut.shown, &|i| {
                cache.get(i).map(|g| images::base_color_images(g, materials))
            });
            let room = self.budgets.bytes.map(|b| b.saturating_sub(self.cache.displayed_bytes()));
            self.images.update(&self.reader, &wanted, room)?;
            if let Some(b) = self.budgets.bytes {
                self.cache.evict_to(b.saturating_sub(self.images.resident_bytes()));
            }
        }

        let top = self.reader.levels().len().saturating_sub(1) as u32;
        let nodes = self.reader.nodes();
        // Format 4 has no separating planes: nearest box first.
        if !dag && self.orderer.is_none() && (self.frame > 0 || cut.shown.iter().any(|&i| nodes[i as usize].level != top)) {
            let planes = self.reader.read_planes().unwrap_or_else(|e| {
                self.warnings.push(format!("{e}; fronts are drawn nearest box first, without the separating planes"));
                Planes::default()
            });
            self.orderer = Some(Orderer::new(self.reader.skeleton(), planes));
        }
        let ordered = Instant::now();
        let mut order = Vec::with_capacity(cut.shown.len());
        match &mut self.orderer {
            Some(o) => o.order(self.reader.skeleton(), &cut.shown, camera, &mut order),
            None => order::nearest_box_first(self.reader.skeleton(), &cut.shown, camera, &mut order),
        }
        let order_ms = ordered.elapsed().as_secs_f64() * 1e3;
        let sealing = Instant::now();
        self.update_seams(&cut.shown);
        let seams_ms = sealing.elapsed().as_secs_f64() * 1e3;
        let mut levels = vec![0u32; self.reader.levels().len()];
        for &i in &cut.shown {
            levels[self.reader.nodes()[i as usize].level as usize] += 1;
        }
        let stats = Stats {
            faces: cut.faces,
            nodes: cut.shown.len(),
            culled: cut.culled.len(),
            levels,
            bytes_read: self.reader.bytes_read(),
            resident_bytes: self.cache.resident_bytes(),
            pixel_error: limits.pixel_error,
            refine_ms: start.elapsed().as_secs_f64() * 1e3,
            order_ms,
            seams_ms,
            seam_faces: self.seams.face_count() as u64,
            seam_area: self.seams.area(),
            texture_bytes_read: self.images.bytes_read(),
            texture_resident_bytes: self.images.resident_bytes(),
            texture_levels: self.images.drawn().iter().map(|(&i, &(w, d))| [i, w, d]).collect(),
        };
        self.front.clone_from(&cut.shown);
        self.culled.clone_from(&cut.culled);
        self.faces = cut.faces;
        let report = FrameReport { frame: self.frame, front: cut.shown, order, added, removed, culled: cut.culled, stats };
        self.frame += 1;
        Ok(report)
    }

    /// Triangles that close the slivers between displayed nodes of adjacent levels (selection.md
    /// §8), to draw with the front.
    pub fn seams(&self) -> &seams::Seams {
        &self.seams
    }

    /// The seams between the nodes of `front`, from the borders of those that take part (each made
    /// once, kept while its node stays displayed); made again only when those nodes or their
    /// displayed neighbours change.
    fn update_seams(&mut self, front: &[u32]) {
        let shown: rustc_hash::FxHashSet<u32> = front.iter().copied().collect();
        self.borders.retain(|n, _| shown.contains(n));
        // Seams run between a node and the children of a neighbour, or the parent of one: only
        // nodes with a neighbour of their level not displayed take part, and an edge of theirs can
        // only meet theirs or their displayed neighbours'.
        let reader = &self.reader;
        let sealing: Vec<u32> = front.iter().copied().filter(|&n| reader.neighbors(n).iter().any(|m| !shown.contains(m))).collect();
        let mut near: Vec<u32> = sealing.iter().flat_map(|&n| reader.neighbors(n).iter().copied().filter(|m| shown.contains(m))).collect();
        near.sort_unstable();
        near.dedup();
        if sealing == self.seam_nodes.0 && near == self.seam_nodes.1 {
            return;
        }
        let records = reader.nodes();
        for &n in sealing.iter().chain(&near) {
            if !self.borders.contains_key(&n) {
                if let Some(g) = self.cache.get(n) {
                    let r = &records[n as usize];
                    self.borders.insert(n, seams::Border::of(r.level, r.error, g));
                }
            }
        }
        let nodes = (sealing, near);
        let borders = |nodes: &[u32]| -> Vec<&seams::Border> { nodes.iter().filter_map(|n| self.borders.get(n)).collect() };
        self.seams = seams::seams(&borders(&nodes.0), &borders(&nodes.1));
        self.seam_nodes = nodes;
    }

    /// The displayed front as one mesh, each node's vertices kept apart, with the file's materials
    /// and corner attributes; a textured file's images come along at full resolution (read here),
    /// so that an export stands alone.
    pub fn front_mesh(&self) -> Result<Mesh> {
        let mut m = Mesh::default();
        let geometries: Vec<&NodeGeometry> = self.front.iter().filter_map(|&i| self.geometry(i)).collect();
        let attrs = self.reader.header().attributes;
        for g in geometries {
            let base = m.positions.len() as u32;
            m.positions.extend(&g.positions);
            let vertex: Vec<u32> = (base..base + g.positions.len() as u32).collect();
            crate::assemble::append_faces(&mut m, g, &vertex, attrs);
        }
        m.materials = self.reader.materials().to_vec();
        if m.materials.is_empty() {
            m.materials.push(Material::default());
        }
        m.images = crate::assemble::images(&self.reader)?;
        m.compute_face_geometry();
        Ok(m)
    }

    /// Nodes of the front the renderer found hidden behind what it drew (occlusion culling): the
    /// next [`Streamer::update`] does not refine them, so their children are neither read nor
    /// drawn. Not conservative while the camera moves: a node that comes into view is shown at its
    /// held level for one frame, then refined.
    pub fn hold_hidden(&mut self, nodes: &[u32]) {
        self.hidden.clear();
        self.hidden.extend_from_slice(nodes);
        self.hidden.sort_unstable();
    }

    /// The mark node `i` got in the last frame.
    pub fn mark(&self, i: u32) -> Mark {
        self.refiner.mark(i)
    }
}

/// Elements only in `new` and only in `old`, both ascending.
fn diff(old: &[u32], new: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let (mut added, mut removed) = (Vec::new(), Vec::new());
    let (mut i, mut j) = (0, 0);
    loop {
        match (old.get(i), new.get(j)) {
            (Some(a), Some(b)) if a == b => {
                i += 1;
                j += 1;
            }
            (Some(a), Some(b)) if a > b => {
                added.push(*b);
                j += 1;
            }
            (Some(a), _) => {
                removed.push(*a);
                i += 1;
            }
            (None, Some(b)) => {
                added.push(*b);
                j += 1;
            }
            (None, None) => return (added, removed),
        }
    }
}
