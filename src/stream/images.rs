//! Image levels for a streamed front (format-spec/selection.md §4): which level of each base color
//! image the displayed nodes need, and the levels held in memory, read on demand and counted
//! against the memory budget as decoded RGBA8.
//!
//! A node needs the coarsest level whose texels, at the node's nearest point, are no larger than a
//! pixel, from its UV density; an image's wanted level is the finest any displayed node using it
//! needs. An image is first drawn at its coarsest level, read alone, and refined from the next
//! frame on; its coarsest level stays resident once read, so a view never goes untextured; where
//! the budget has no room for a wanted level the finest coarser one that fits is drawn.

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::format::skeleton::Skeleton;
use crate::format::{ByteSource, MapKind, Material, NodeGeometry, Reader, Textures};
use crate::texture::sample::MipChain;
use crate::texture::{decode, Rgba8};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::sync::Arc;

/// The level of `image` a node with UV density `density` needs where a model unit spans
/// `pixels_per_unit` pixels: the largest level whose geometric-mean side reaches `pixels_per_unit
/// / density` texels per UV unit, or 0.
pub fn needed_level(t: &Textures, image: u32, pixels_per_unit: f32, density: f32) -> u32 {
    let want = pixels_per_unit as f64 / density as f64;
    let count = t.level_count(image);
    (0..count).rev().find(|&l| t.level(image, l).is_some_and(|v| ((v.width as f64) * (v.height as f64)).sqrt() >= want)).unwrap_or(0)
}

/// Images a node's geometry samples as base color: its material ranges' materials' maps, each once.
pub fn base_color_images(g: &NodeGeometry, materials: &[Material]) -> Vec<u32> {
    let mut v: Vec<u32> =
        g.material_ranges.iter().filter_map(|r| materials.get(r.material as usize)?.map(MapKind::BaseColor).map(|s| s.image)).collect();
    v.sort_unstable();
    v.dedup();
    v
}

/// Each used image's wanted level for the displayed nodes `front` (whose geometry `geometry`
/// gives): the finest level any of them needs.
pub fn wanted(skeleton: &Skeleton, camera: &Camera, front: &[u32], geometry: &dyn Fn(u32) -> Option<Vec<u32>>) -> BTreeMap<u32, u32> {
    let t = &skeleton.textures;
    let mut out: BTreeMap<u32, u32> = BTreeMap::new();
    for &i in front {
        let (Some(n), Some(&d)) = (skeleton.nodes.get(i as usize), t.uv_density.get(i as usize)) else { continue };
        if d <= 0.0 {
            continue;
        }
        let s = camera.pixels_per_unit((camera.eye.distance(n.center) - n.radius).max(0.0));
        for image in geometry(i).unwrap_or_default() {
            let l = needed_level(t, image, s, d);
            out.entry(image).and_modify(|w| *w = (*w).min(l)).or_insert(l);
        }
    }
    out
}

/// Image levels in memory.
#[derive(Default)]
pub struct ImageCache {
    held: HashMap<(u32, u32), Arc<Rgba8>>,
    /// Levels that could not be read or decoded: never tried again, a coarser one is drawn.
    failed: HashSet<(u32, u32)>,
    warnings: Vec<String>,
    resident: u64,
    read: u64,
    requests: u64,
    /// Per image the front uses: its wanted level and the one drawn, the finest held at or above it.
    drawn: BTreeMap<u32, (u32, u32)>,
    chains: HashMap<u32, MipChain>,
}

impl ImageCache {
    /// Bytes of the held levels as RGBA8.
    pub fn resident_bytes(&self) -> u64 {
        self.resident
    }

    /// Bytes of image files read so far.
    pub fn bytes_read(&self) -> u64 {
        self.read
    }

    /// Image levels read so far.
    pub fn requests(&self) -> u64 {
        self.requests
    }

    /// Per image used by the front: the wanted level and the one drawn.
    pub fn drawn(&self) -> &BTreeMap<u32, (u32, u32)> {
        &self.drawn
    }

    /// Levels that could not be read or decoded, each said once; taken by the caller.
    pub fn take_warnings(&mut self) -> Vec<String> {
        std::mem::take(&mut self.warnings)
    }

    /// What the renderer samples for `image`: its drawn level.
    pub fn chain(&self, image: u32) -> Option<&MipChain> {
        self.chains.get(&image)
    }

    /// Decoded bytes of the coarsest level of every image the materials sample as base color: what
    /// stays resident once the front has used them.
    pub fn pinned_bytes(t: &Textures, materials: &[Material]) -> u64 {
        let mut images: Vec<u32> = materials.iter().filter_map(|m| m.map(MapKind::BaseColor).map(|s| s.image)).collect();
        images.sort_unstable();
        images.dedup();
        images.iter().filter_map(|&i| t.level(i, t.level_count(i).checked_sub(1)?)).map(|l| l.decoded_bytes()).sum()
    }

    /// Hold each image's `wanted` level (and its coarsest), reading what is missing, within `room`
    /// bytes for all image levels if given: where the wanted level does not fit, the finest coarser
    /// one that does is held instead. Levels neither wanted, drawn nor coarsest are dropped, and
    /// finer held levels too while the held ones exceed `room`. An image first used is drawn at its
    /// coarsest level this frame. A level that cannot be read or decoded is a warning
    /// ([`ImageCache::take_warnings`]) and a coarser one is drawn; an image with no readable level is
    /// drawn untextured.
    pub fn update<S: ByteSource>(&mut self, reader: &Reader<S>, wanted: &BTreeMap<u32, u32>, room: Option<u64>) -> Result<()> {
        let t = reader.textures();
        let coarsest = |i: u32| t.level_count(i).saturating_sub(1);
        let keep = |&(i, l): &(u32, u32)| l == coarsest(i) || wanted.get(&i).is_some_and(|&w| l >= w);
        let dropped: Vec<(u32, u32)> = self.held.keys().copied().filter(|k| !keep(k)).collect();
        for k in dropped {
            self.release(k);
        }
        // Room shrinks when the displayed geometry grows: give back the finest levels first.
        if let Some(r) = room {
            let mut finer: Vec<(u32, u32)> = self.held.keys().copied().filter(|&(i, l)| l != coarsest(i)).collect();
            finer.sort_by_key(|&(i, l)| (l, i));
            for k in finer {
                if self.resident <= r {
                    break;
                }
                self.release(k);
            }
        }
        let mut drawn = BTreeMap::new();
        for (&image, &want) in wanted {
            let Some(full) = t.level(image, 0) else { continue };
            let (full_w, full_h) = (full.width, full.height);
            let first_use = !self.held.contains_key(&(image, coarsest(image)));
            self.load(reader, image, coarsest(image));
            let mut level = None;
            if !first_use {
                for l in want..coarsest(image) {
                    if self.held.contains_key(&(image, l)) {
                        level = Some(l);
                        break;
                    }
                    let bytes = t.level(image, l).map_or(0, |v| v.decoded_bytes());
                    if room.is_none_or(|r| self.resident + bytes <= r) && self.load(reader, image, l) {
                        level = Some(l);
                        break;
                    }
                }
            }
            let level = level.unwrap_or(coarsest(image));
            let Some(pixels) = self.held.get(&(image, level)).cloned() else { continue };
            // Coarser held levels than the drawn one, other than the coarsest, are of no use now.
            let spare: Vec<(u32, u32)> =
                self.held.keys().copied().filter(|&(i, l)| i == image && l > level && l != coarsest(image)).collect();
            for k in spare {
                self.release(k);
            }
            if self.chains.get(&image).is_none_or(|c| c.first_level != level) {
                self.chains.insert(image, MipChain::new(level, vec![pixels], full_w, full_h));
            }
            drawn.insert(image, (want, level));
        }
        self.chains.retain(|i, _| drawn.contains_key(i));
        self.drawn = drawn;
        Ok(())
    }

    /// Read and decode a level unless held; false when it is not held after (it failed).
    fn load<S: ByteSource>(&mut self, reader: &Reader<S>, image: u32, level: u32) -> bool {
        if self.held.contains_key(&(image, level)) {
            return true;
        }
        if self.failed.contains(&(image, level)) {
            return false;
        }
        let t = reader.textures();
        let result = t
            .images
            .get(image as usize)
            .ok_or_else(|| Error::at_element(reader.path(), format!("image {image}"), "no such image"))
            .and_then(|rec| {
                let bytes = reader.read_image_level(image, level)?;
                let pixels =
                    decode(rec.codec, &bytes).map_err(|e| Error::at_element(reader.path(), format!("image {image} level {level}"), e))?;
                Ok((bytes.len(), pixels))
            });
        match result {
            Ok((len, pixels)) => {
                self.read += len as u64;
                self.requests += 1;
                self.resident += 4 * pixels.width as u64 * pixels.height as u64;
                self.held.insert((image, level), Arc::new(pixels));
                true
            }
            Err(e) => {
                self.failed.insert((image, level));
                self.warnings.push(format!("image level left undrawn: {e}"));
                false
            }
        }
    }

    fn release(&mut self, key: (u32, u32)) {
        if let Some(p) = self.held.remove(&key) {
            self.resident -= 4 * p.width as u64 * p.height as u64;
        }
    }
}
