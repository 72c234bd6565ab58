//! Textures: the images a mesh's materials use, from import to the file and back to pixels.
//!
//! - [`SourceImage`]: an image as an importer found it (its file's bytes, PNG or JPEG), which
//!   [`crate::mesh::Mesh::images`] holds and materials' maps index;
//! - [`decode`] (from the format layer, which checks that image levels decode): PNG or JPEG bytes
//!   into RGBA8 pixels, within size limits;
//! - [`pyramid`]: the resolutions a chunk file stores (spec §7.5), halving down to a small level,
//!   filtered in linear light for colors and renormalized for normal maps;
//! - [`sample`]: bilinear sampling from a chain of levels, for the software renderer;
//! - [`draw`]: what the renderer draws of textured geometry, and the chains it samples.

pub mod draw;
pub mod pyramid;
pub mod sample;

pub use crate::format::{ImageCodec, MapKind};
use std::sync::Arc;

pub use crate::format::texture::{MAX_PIXELS, MAX_SIDE};

/// An image as a source file holds it: one PNG or JPEG file's bytes.
#[derive(Clone, PartialEq, Eq)]
pub struct SourceImage {
    /// As the source named it: a file name or URI as written, or "embedded image N".
    pub name: String,
    pub codec: ImageCodec,
    pub bytes: Arc<[u8]>,
}

impl std::fmt::Debug for SourceImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SourceImage({:?}, {:?}, {} bytes)", self.name, self.codec, self.bytes.len())
    }
}

impl SourceImage {
    /// An image from its file's bytes; the codec from the bytes' signature, or why it is neither
    /// a PNG nor a JPEG.
    pub fn new(name: String, bytes: Vec<u8>) -> Result<SourceImage, String> {
        let codec = sniff(&bytes).ok_or_else(|| "neither a PNG nor a JPEG file".to_string())?;
        Ok(SourceImage { name, codec, bytes: bytes.into() })
    }
}

/// PNG or JPEG, from a file's first bytes.
pub fn sniff(bytes: &[u8]) -> Option<ImageCodec> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some(ImageCodec::Png)
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some(ImageCodec::Jpeg)
    } else {
        None
    }
}

pub use crate::format::image::{decode, Rgba8};

/// Encode RGBA8 pixels as `codec`: PNG keeps alpha (and drops it when every pixel is opaque);
/// JPEG at `quality` (1..=100), without alpha.
pub fn encode(codec: ImageCodec, image: &Rgba8, quality: u8) -> Result<Vec<u8>, String> {
    let opaque = image.pixels.chunks_exact(4).all(|p| p[3] == 255);
    match codec {
        ImageCodec::Png => {
            let mut out = Vec::new();
            let mut e = png::Encoder::new(&mut out, image.width, image.height);
            e.set_depth(png::BitDepth::Eight);
            let rgb: Vec<u8>;
            let data = if opaque {
                e.set_color(png::ColorType::Rgb);
                rgb = image.pixels.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
                &rgb[..]
            } else {
                e.set_color(png::ColorType::Rgba);
                &image.pixels[..]
            };
            e.set_compression(png::Compression::Balanced);
            let mut w = e.write_header().map_err(|e| e.to_string())?;
            w.write_image_data(data).map_err(|e| e.to_string())?;
            w.finish().map_err(|e| e.to_string())?;
            Ok(out)
        }
        ImageCodec::Jpeg => {
            let (w, h) = (u16::try_from(image.width), u16::try_from(image.height));
            let (Ok(w), Ok(h)) = (w, h) else {
                return Err(format!("a {} × {} JPEG (at most 65535 a side)", image.width, image.height));
            };
            let mut out = Vec::new();
            let e = jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100));
            e.encode(&image.pixels, w, h, jpeg_encoder::ColorType::Rgba).map_err(|e| e.to_string())?;
            Ok(out)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker(w: u32, h: u32, alpha: u8) -> Rgba8 {
        let mut im = Rgba8::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let on = (x / 4 + y / 4) % 2 == 0;
                let i = 4 * (y * w + x) as usize;
                im.pixels[i..i + 4].copy_from_slice(&if on { [230, 40, 20, alpha] } else { [20, 60, 200, alpha] });
            }
        }
        im
    }

    #[test]
    fn png_round_trips_with_and_without_alpha() {
        for alpha in [255, 128] {
            let im = checker(37, 20, alpha);
            let bytes = encode(ImageCodec::Png, &im, 90).unwrap();
            assert_eq!(sniff(&bytes), Some(ImageCodec::Png));
            assert_eq!(decode(ImageCodec::Png, &bytes).unwrap(), im);
            assert_eq!(crate::format::texture::image_size(ImageCodec::Png, &bytes), Ok((37, 20)));
        }
    }

    #[test]
    fn jpeg_round_trips_within_its_loss() {
        let im = checker(40, 24, 255);
        let bytes = encode(ImageCodec::Jpeg, &im, 95).unwrap();
        assert_eq!(sniff(&bytes), Some(ImageCodec::Jpeg));
        assert_eq!(crate::format::texture::image_size(ImageCodec::Jpeg, &bytes), Ok((40, 24)));
        let back = decode(ImageCodec::Jpeg, &bytes).unwrap();
        assert_eq!((back.width, back.height), (40, 24));
        let err: f64 = im.pixels.iter().zip(&back.pixels).map(|(&a, &b)| (a as f64 - b as f64).abs()).sum::<f64>() / im.pixels.len() as f64;
        assert!(err < 12.0, "mean error {err}");
    }

    #[test]
    fn garbage_is_an_error_not_a_panic() {
        assert!(SourceImage::new("x".into(), b"GIF89a....".to_vec()).is_err());
        let png = encode(ImageCodec::Png, &checker(8, 8, 255), 90).unwrap();
        for cut in [9, 20, 33, png.len() - 5] {
            assert!(decode(ImageCodec::Png, &png[..cut]).is_err());
        }
        let jpeg = encode(ImageCodec::Jpeg, &checker(8, 8, 255), 90).unwrap();
        for cut in [3, 20, 100] {
            assert!(decode(ImageCodec::Jpeg, &jpeg[..cut.min(jpeg.len() - 1)]).is_err());
        }
    }
}
