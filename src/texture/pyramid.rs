//! The resolutions of an image a chunk file stores (spec §7.5): level 0 is the source file itself,
//! byte for byte; each next level halves the one before (rounding up) with a 2 × 2 box filter,
//! until the larger side is at most [`COARSEST_SIDE`]. Colors are averaged in linear light, normal
//! maps as unit vectors renormalized, other data linearly; levels keep the source's codec.

use super::{decode, encode, MapKind, Rgba8, SourceImage};
use crate::format::texture::{half, ImageIn, LevelIn};
use crate::format::ImageCodec;
use rayon::prelude::*;
use std::sync::OnceLock;

/// The coarsest level's larger side, at most: small enough that a viewer's first frame costs a
/// few kilobytes per image.
pub const COARSEST_SIDE: u32 = 64;
/// JPEG quality of the levels made from a JPEG source.
pub const JPEG_QUALITY: u8 = 90;

/// How texels are averaged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    /// sRGB colors: averaged in linear light, alpha linearly.
    Srgb,
    /// Data: averaged as stored.
    Linear,
    /// Tangent-space normals: averaged as vectors and renormalized.
    Normal,
}

impl Filter {
    pub fn for_map(kind: MapKind) -> Filter {
        match kind {
            MapKind::BaseColor | MapKind::Emissive => Filter::Srgb,
            MapKind::Normal => Filter::Normal,
            MapKind::MetallicRoughness | MapKind::Occlusion => Filter::Linear,
        }
    }
}

/// The sides of every level of a `width` × `height` image, finest first.
pub fn level_sizes(width: u32, height: u32) -> Vec<(u32, u32)> {
    let mut out = vec![(width, height)];
    let (mut w, mut h) = (width, height);
    while w.max(h) > COARSEST_SIDE {
        (w, h) = (half(w), half(h));
        out.push((w, h));
    }
    out
}

/// Every level of `image`, finest first: the source's own bytes, then the halvings encoded with its
/// codec. An image that cannot be decoded is an error naming why.
pub fn build(image: &SourceImage, filter: Filter) -> Result<Vec<LevelIn>, String> {
    let full = decode(image.codec, &image.bytes)?;
    let sizes = level_sizes(full.width, full.height);
    let mut levels = vec![LevelIn { width: full.width, height: full.height, bytes: image.bytes.to_vec() }];
    let mut current = full;
    let mut halvings = Vec::with_capacity(sizes.len());
    for _ in 1..sizes.len() {
        current = downsample(&current, filter);
        halvings.push(current.clone());
    }
    let encoded: Vec<Result<LevelIn, String>> = halvings
        .par_iter()
        .map(|im| Ok(LevelIn { width: im.width, height: im.height, bytes: encode(image.codec, im, JPEG_QUALITY)? }))
        .collect();
    for e in encoded {
        levels.push(e?);
    }
    Ok(levels)
}

fn srgb_to_linear_table() -> &'static [f32; 256] {
    static T: OnceLock<[f32; 256]> = OnceLock::new();
    T.get_or_init(|| {
        std::array::from_fn(|i| {
            let c = i as f32 / 255.0;
            if c <= 0.04045 {
                c / 12.92
            } else {
                ((c + 0.055) / 1.055).powf(2.4)
            }
        })
    })
}

/// sRGB-encoded u8 of a linear value in [0, 1], from a 4096-entry table.
fn linear_to_srgb(v: f32) -> u8 {
    static T: OnceLock<Vec<u8>> = OnceLock::new();
    let t = T.get_or_init(|| {
        (0..4096)
            .map(|i| {
                let l = i as f32 / 4095.0;
                let s = if l <= 0.003_130_8 { l * 12.92 } else { 1.055 * l.powf(1.0 / 2.4) - 0.055 };
                (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8
            })
            .collect()
    });
    t[(v.clamp(0.0, 1.0) * 4095.0 + 0.5) as usize]
}

/// `image` at half the size, rounded up: each texel the mean of the (up to) 2 × 2 texels it covers.
pub fn downsample(image: &Rgba8, filter: Filter) -> Rgba8 {
    let (w, h) = (half(image.width), half(image.height));
    let mut out = Rgba8::new(w, h);
    let lin = srgb_to_linear_table();
    out.pixels.par_chunks_mut(4 * w as usize).enumerate().for_each(|(y, row)| {
        let y = y as u32;
        let ys = [2 * y, (2 * y + 1).min(image.height - 1)];
        for x in 0..w {
            let xs = [2 * x, (2 * x + 1).min(image.width - 1)];
            let texels = [image.get(xs[0], ys[0]), image.get(xs[1], ys[0]), image.get(xs[0], ys[1]), image.get(xs[1], ys[1])];
            let px = match filter {
                Filter::Linear => std::array::from_fn(|c| ((texels.iter().map(|t| t[c] as u32).sum::<u32>() + 2) / 4) as u8),
                Filter::Srgb => {
                    // Weighted by alpha, so that transparent texels (whose color is often junk) do not
                    // bleed into the visible ones; all transparent: a plain mean.
                    let weight: u32 = texels.iter().map(|t| t[3] as u32).sum();
                    let mean = |c: usize| match weight {
                        0 => texels.iter().map(|t| lin[t[c] as usize]).sum::<f32>() / 4.0,
                        w => texels.iter().map(|t| lin[t[c] as usize] * t[3] as f32).sum::<f32>() / w as f32,
                    };
                    let alpha = ((weight + 2) / 4) as u8;
                    [linear_to_srgb(mean(0)), linear_to_srgb(mean(1)), linear_to_srgb(mean(2)), alpha]
                }
                Filter::Normal => {
                    let v = texels.iter().fold(glam::Vec3::ZERO, |s, t| {
                        s + glam::Vec3::new(t[0] as f32, t[1] as f32, t[2] as f32) / 127.5 - glam::Vec3::ONE
                    });
                    let n = v.try_normalize().unwrap_or(glam::Vec3::Z);
                    let q = |c: f32| ((c + 1.0) * 127.5 + 0.5).clamp(0.0, 255.0) as u8;
                    let alpha = ((texels.iter().map(|t| t[3] as u32).sum::<u32>() + 2) / 4) as u8;
                    [q(n.x), q(n.y), q(n.z), alpha]
                }
            };
            row[4 * x as usize..4 * x as usize + 4].copy_from_slice(&px);
        }
    });
    out
}

/// The `images` that `materials` use, each with its levels for the file, in a new order that the
/// materials' maps are renumbered to. An image no map uses is dropped; one that cannot be decoded
/// is a warning naming it, and the maps using it are cleared; without UVs (`has_uvs` false) every
/// map is. `progress` is called once per image.
pub fn prepare(
    materials: &mut [crate::mesh::Material],
    images: &[SourceImage],
    has_uvs: bool,
    warnings: &mut Vec<String>,
    progress: &mut dyn FnMut(),
) -> Vec<ImageIn> {
    let used = materials.iter().any(|m| m.maps.iter().any(Option::is_some));
    if used && !has_uvs {
        warnings.push("textures left out: the mesh has no UVs to map them".into());
    }
    let mut out = Vec::new();
    let mut renumber: Vec<Option<u32>> = vec![None; images.len()];
    for (i, image) in images.iter().enumerate() {
        let first_use =
            materials.iter().flat_map(|m| MapKind::ALL.into_iter().filter(|&k| m.map(k).is_some_and(|s| s.image == i as u32))).next();
        let Some(kind) = first_use.filter(|_| has_uvs) else { continue };
        progress();
        // What the file's image table holds must pass the writer's checks: the header's size is
        // the decoded one (a JPEG the decoder forgives but whose markers do not state it is left
        // out), and the name fits (cut at a character boundary).
        let checked = build(image, Filter::for_map(kind)).and_then(|levels| {
            let stated = crate::format::texture::image_size(image.codec, &levels[0].bytes)?;
            if stated != (levels[0].width, levels[0].height) {
                return Err(format!(
                    "its header states {} × {}, it decodes to {} × {}",
                    stated.0, stated.1, levels[0].width, levels[0].height
                ));
            }
            Ok(levels)
        });
        match checked {
            Ok(levels) => {
                let mut name = image.name.clone();
                let max = crate::format::texture::MAX_NAME_BYTES as usize;
                if name.len() > max {
                    let cut = (0..=max).rev().find(|&k| name.is_char_boundary(k)).unwrap_or(0);
                    name.truncate(cut);
                }
                renumber[i] = Some(out.len() as u32);
                out.push(ImageIn { name, codec: image.codec, levels });
            }
            Err(e) => warnings.push(format!("texture left out: {}: {e}", image.name)),
        }
    }
    for m in materials.iter_mut() {
        for slot in &mut m.maps {
            *slot = slot.and_then(|s| Some(crate::format::TextureSlot { image: (*renumber.get(s.image as usize)?)?, ..s }));
        }
    }
    out
}

/// Levels decoded: every level of a pyramid as pixels, finest first (for renderers).
pub fn decode_levels(codec: ImageCodec, levels: &[Vec<u8>]) -> Result<Vec<Rgba8>, String> {
    levels.iter().map(|b| decode(codec, b)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_halve_rounding_up_to_the_coarsest_side() {
        assert_eq!(level_sizes(64, 10), vec![(64, 10)]);
        assert_eq!(level_sizes(300, 65), vec![(300, 65), (150, 33), (75, 17), (38, 9)]);
        assert_eq!(level_sizes(1, 1000).last(), Some(&(1, 63)));
    }

    #[test]
    fn srgb_averaging_is_in_linear_light() {
        let mut im = Rgba8::new(2, 2);
        for (i, v) in [0u8, 255, 0, 255].iter().enumerate() {
            im.pixels[4 * i..4 * i + 4].copy_from_slice(&[*v, *v, *v, 255]);
        }
        let half = downsample(&im, Filter::Srgb);
        // Half of full intensity in linear light is sRGB 188, not 128.
        assert_eq!(half.get(0, 0), [188, 188, 188, 255]);
        assert_eq!(downsample(&im, Filter::Linear).get(0, 0)[0], 128);
        // A transparent texel's color does not bleed into an opaque one's.
        let mut cut = Rgba8::new(2, 1);
        cut.pixels.copy_from_slice(&[255, 0, 0, 255, 0, 255, 0, 0]);
        assert_eq!(downsample(&cut, Filter::Srgb).get(0, 0), [255, 0, 0, 128]);
    }

    #[test]
    fn normals_stay_unit() {
        let mut im = Rgba8::new(2, 1);
        im.pixels.copy_from_slice(&[255, 128, 128, 255, 128, 128, 255, 255]);
        let p = downsample(&im, Filter::Normal).get(0, 0);
        let n = glam::Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) / 127.5 - glam::Vec3::ONE;
        assert!((n.length() - 1.0).abs() < 0.02 && (n.x - n.z).abs() < 0.02, "{p:?}");
    }

    #[test]
    fn build_keeps_the_source_and_halves() {
        let mut im = Rgba8::new(130, 70);
        for (i, p) in im.pixels.chunks_exact_mut(4).enumerate() {
            p.copy_from_slice(&[(i % 251) as u8, (i % 13) as u8 * 19, 77, 255]);
        }
        let bytes = encode(ImageCodec::Png, &im, 90).unwrap();
        let src = SourceImage::new("a.png".into(), bytes.clone()).unwrap();
        let levels = build(&src, Filter::Srgb).unwrap();
        assert_eq!(levels.iter().map(|l| (l.width, l.height)).collect::<Vec<_>>(), vec![(130, 70), (65, 35), (33, 18)]);
        assert_eq!(levels[0].bytes, bytes);
        for l in &levels {
            assert_eq!(crate::format::texture::image_size(ImageCodec::Png, &l.bytes), Ok((l.width, l.height)));
        }
    }
}
