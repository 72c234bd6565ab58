//! What the software renderer draws of textured geometry: one part per material range, colored by
//! the material's base color and sampling its base color image where it has one, and the chains of
//! levels those parts sample, read from a chunk file or made from a source image.

use super::pyramid::{build, Filter};
use super::sample::MipChain;
use super::{decode, SourceImage};
use crate::error::{Error, Result};
use crate::format::{ByteSource, MapKind, Material, NodeGeometry, Reader};
use crate::render::Part;

/// The sRGB bytes of a linear RGBA color (alpha kept linear).
pub fn srgb_color(linear: [f32; 4]) -> [u8; 4] {
    let e = |c: f32| {
        let c = c.clamp(0.0, 1.0);
        let s = if c <= 0.003_130_8 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
        (s * 255.0 + 0.5) as u8
    };
    [e(linear[0]), e(linear[1]), e(linear[2]), (linear[3].clamp(0.0, 1.0) * 255.0 + 0.5) as u8]
}

/// The parts of one node's geometry: one per material range, in the material's color, textured
/// with `chain(image)` where the material's base color map names an image that has one (and the
/// node has UVs).
pub fn node_parts<'a>(g: &'a NodeGeometry, materials: &[Material], chain: &dyn Fn(u32) -> Option<&'a MipChain>) -> Vec<Part<'a>> {
    g.material_ranges
        .iter()
        .filter_map(|r| {
            let indices = g.indices.get(r.first_index as usize..(r.first_index + r.index_count) as usize)?;
            let m = materials.get(r.material as usize);
            let color = m.map_or([200, 200, 200, 255], |m| srgb_color(m.base_color));
            let part = Part::new(&g.positions, &g.normals, indices, color);
            let chain = m.and_then(|m| m.map(MapKind::BaseColor)).and_then(|s| chain(s.image));
            Some(match chain {
                Some(c) => part.textured(&g.uvs, c),
                None => part,
            })
        })
        .collect()
}

/// Levels `from..` of image `image` of a chunk file, decoded into a chain with the wrap modes of
/// `wrap_of`'s slot.
pub fn read_chain<S: ByteSource>(rd: &Reader<S>, image: u32, from: u32, wrap: [crate::format::Wrap; 2]) -> Result<MipChain> {
    let t = rd.textures();
    let rec = t.images.get(image as usize).ok_or_else(|| Error::at_element(rd.path(), format!("image {image}"), "no such image"))?;
    let full = t.level(image, 0).ok_or_else(|| Error::at_element(rd.path(), format!("image {image}"), "no levels"))?;
    let mut levels = Vec::new();
    for l in from..t.level_count(image) {
        let bytes = rd.read_image_level(image, l)?;
        levels.push(decode(rec.codec, &bytes).map_err(|e| Error::at_element(rd.path(), format!("image {image} level {l}"), e))?);
    }
    let mut chain = MipChain::new(from, levels, full.width, full.height);
    chain.wrap = wrap;
    Ok(chain)
}

/// Every base color image of a chunk file's materials as a chain of all its levels (`None` for
/// images no material samples as base color).
pub fn read_base_color_chains<S: ByteSource>(rd: &Reader<S>) -> Result<Vec<Option<MipChain>>> {
    let mut chains: Vec<Option<MipChain>> = vec![None; rd.textures().images.len()];
    for m in rd.materials() {
        if let Some(s) = m.map(MapKind::BaseColor) {
            if chains[s.image as usize].is_none() {
                chains[s.image as usize] = Some(read_chain(rd, s.image, 0, s.wrap)?);
            }
        }
    }
    Ok(chains)
}

/// A source image's levels as a chain (as a chunk file would store them).
pub fn source_chain(image: &SourceImage, kind: MapKind) -> std::result::Result<MipChain, String> {
    let levels = build(image, Filter::for_map(kind))?;
    let decoded = levels.iter().map(|l| decode(image.codec, &l.bytes)).collect::<std::result::Result<Vec<_>, _>>()?;
    let (w, h) = (levels[0].width, levels[0].height);
    Ok(MipChain::new(0, decoded, w, h))
}
