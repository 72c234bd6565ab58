//! What the software renderer draws of textured geometry: one part per material range, colored by
//! the material's base color and sampling its base color image where it has one, and the chains of
//! levels those parts sample, read from a chunk file or made from a source image.

use super::pyramid::{build, Filter};
use super::sample::MipChain;
use super::{decode, SourceImage};
use crate::error::{Error, Result};
use crate::format::{ByteSource, MapKind, Material, NodeGeometry, Reader};
use crate::render::Part;
use std::sync::Arc;

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
/// node has UVs), wrapping as the map says.
pub fn node_parts<'a>(g: &'a NodeGeometry, materials: &[Material], chain: &dyn Fn(u32) -> Option<&'a MipChain>) -> Vec<Part<'a>> {
    g.material_ranges
        .iter()
        .filter_map(|r| {
            let indices = g.indices.get(r.first_index as usize..(r.first_index + r.index_count) as usize)?;
            let m = materials.get(r.material as usize);
            let color = m.map_or([200, 200, 200, 255], |m| srgb_color(m.base_color));
            let part = Part::new(&g.positions, &g.normals, indices, color);
            let slot = m.and_then(|m| m.map(MapKind::BaseColor));
            Some(match slot.and_then(|s| Some((s, chain(s.image)?))) {
                Some((s, c)) => part.textured(&g.uvs, c, s.wrap),
                None => part,
            })
        })
        .collect()
}

/// Decoded bytes one image may take in a render: 4096² RGBA8. Finer levels are left out.
pub const IMAGE_BYTES: u64 = 64 << 20;
/// Decoded bytes all images of a render may take together; past it, the largest images start at a
/// coarser level.
pub const TOTAL_BYTES: u64 = 512 << 20;

/// Levels `from..` of image `image` of a chunk file, decoded into a chain.
pub fn read_chain<S: ByteSource>(rd: &Reader<S>, image: u32, from: u32) -> Result<MipChain> {
    let t = rd.textures();
    let rec = t.images.get(image as usize).ok_or_else(|| Error::at_element(rd.path(), format!("image {image}"), "no such image"))?;
    let full = t.level(image, 0).ok_or_else(|| Error::at_element(rd.path(), format!("image {image}"), "no levels"))?;
    let mut levels = Vec::new();
    for l in from..t.level_count(image) {
        let bytes = rd.read_image_level(image, l)?;
        let pixels = decode(rec.codec, &bytes).map_err(|e| Error::at_element(rd.path(), format!("image {image} level {l}"), e))?;
        levels.push(Arc::new(pixels));
    }
    Ok(MipChain::new(from, levels, full.width, full.height))
}

/// The chains of images `used` (indices into the file's images) for a render: each from its
/// finest level within [`IMAGE_BYTES`], all within [`TOTAL_BYTES`]. An image that cannot be read
/// or decoded is a warning (its parts are drawn in their material's color); `chains[image]` is
/// `None` for it and for images not used.
pub fn read_chains<S: ByteSource>(rd: &Reader<S>, used: &[u32], warnings: &mut Vec<String>) -> Vec<Option<MipChain>> {
    let t = rd.textures();
    let bytes = |i: u32, l: u32| t.level(i, l).map_or(0, |v| v.decoded_bytes() * 4 / 3);
    let mut from: Vec<(u32, u32)> = Vec::new();
    for &i in used {
        match (0..t.level_count(i)).find(|&l| bytes(i, l) <= IMAGE_BYTES) {
            Some(l) => from.push((i, l)),
            None => warnings.push(format!("image {i} drawn untextured: no level within {} MiB decoded", IMAGE_BYTES >> 20)),
        }
    }
    while from.iter().map(|&(i, l)| bytes(i, l)).sum::<u64>() > TOTAL_BYTES {
        let Some(k) = (0..from.len()).filter(|&k| from[k].1 + 1 < t.level_count(from[k].0)).max_by_key(|&k| bytes(from[k].0, from[k].1))
        else {
            break;
        };
        from[k].1 += 1;
    }
    let mut chains: Vec<Option<MipChain>> = vec![None; t.images.len()];
    for (i, l) in from {
        match read_chain(rd, i, l) {
            Ok(c) => chains[i as usize] = Some(c),
            Err(e) => warnings.push(format!("image {i} drawn untextured: {e}")),
        }
    }
    chains
}

/// A source image's levels as a chain (as a chunk file would store them).
pub fn source_chain(image: &SourceImage, kind: MapKind) -> std::result::Result<MipChain, String> {
    let levels = build(image, Filter::for_map(kind))?;
    let decoded = levels.iter().map(|l| decode(image.codec, &l.bytes).map(Arc::new)).collect::<std::result::Result<Vec<_>, _>>()?;
    let (w, h) = (levels[0].width, levels[0].height);
    Ok(MipChain::new(0, decoded, w, h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::{MaterialRange, TextureSlot, Wrap};

    #[test]
    fn each_part_wraps_as_its_material_map_says() {
        let g = NodeGeometry {
            positions: vec![glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::Y],
            uvs: vec![glam::Vec2::ZERO; 3],
            indices: vec![0, 1, 2, 0, 1, 2],
            material_ranges: vec![
                MaterialRange { material: 0, first_index: 0, index_count: 3 },
                MaterialRange { material: 1, first_index: 3, index_count: 3 },
            ],
            ..NodeGeometry::default()
        };
        let slot = |w| Some(TextureSlot { image: 0, wrap: [w; 2] });
        let mut materials = vec![Material::default(), Material::default()];
        materials[0].maps[MapKind::BaseColor as usize] = slot(Wrap::Clamp);
        materials[1].maps[MapKind::BaseColor as usize] = slot(Wrap::Mirror);
        let chain = MipChain::new(0, vec![Arc::new(crate::texture::Rgba8::new(2, 2))], 2, 2);
        let parts = node_parts(&g, &materials, &|_| Some(&chain));
        assert_eq!(parts.iter().map(|p| p.wrap).collect::<Vec<_>>(), [[Wrap::Clamp; 2], [Wrap::Mirror; 2]]);
        assert!(parts.iter().all(|p| p.texture.is_some()));
    }
}
