//! Textures: the images a mesh's materials use, from import to the file and back to pixels.
//!
//! - [`SourceImage`]: an image as an importer found it (its file's bytes, PNG or JPEG), which
//!   [`crate::mesh::Mesh::images`] holds and materials' maps index;
//! - [`decode`]: PNG or JPEG bytes into RGBA8 pixels, within size limits;
//! - [`pyramid`]: the resolutions a chunk file stores (spec §7.5), halving down to a small level,
//!   filtered in linear light for colors and renormalized for normal maps;
//! - [`sample`]: bilinear sampling from a chain of levels, for the software renderer;
//! - [`draw`]: what the renderer draws of textured geometry, and the chains it samples.

pub mod draw;
pub mod pyramid;
pub mod sample;

pub use crate::format::{ImageCodec, MapKind};
use std::sync::Arc;

/// Largest side of an image strata decodes (the format's limit, spec §7.5).
pub const MAX_SIDE: u32 = crate::format::texture::MAX_SIDE;
/// Most pixels of an image strata decodes: 16384², 1 GiB as RGBA8.
pub const MAX_PIXELS: u64 = 1 << 28;

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

/// Pixels as RGBA8, rows top first.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Rgba8 {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

impl Rgba8 {
    pub fn new(width: u32, height: u32) -> Rgba8 {
        Rgba8 { width, height, pixels: vec![0; 4 * width as usize * height as usize] }
    }

    #[inline]
    pub fn get(&self, x: u32, y: u32) -> [u8; 4] {
        let i = 4 * (y as usize * self.width as usize + x as usize);
        [self.pixels[i], self.pixels[i + 1], self.pixels[i + 2], self.pixels[i + 3]]
    }
}

/// Decode a PNG or JPEG file into RGBA8 (grey, palette, 16-bit and alpha-less images expanded),
/// refusing images beyond [`MAX_SIDE`] a side or [`MAX_PIXELS`] before allocating their pixels.
pub fn decode(codec: ImageCodec, bytes: &[u8]) -> Result<Rgba8, String> {
    let check = |w: u32, h: u32| {
        if w == 0 || h == 0 || w > MAX_SIDE || h > MAX_SIDE || w as u64 * h as u64 > MAX_PIXELS {
            Err(format!("a {w} × {h} image (at most {MAX_SIDE} a side and {MAX_PIXELS} pixels)"))
        } else {
            Ok(())
        }
    };
    match codec {
        ImageCodec::Png => {
            let mut d = png::Decoder::new_with_limits(std::io::Cursor::new(bytes), png::Limits { bytes: 4 * MAX_PIXELS as usize });
            d.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16 | png::Transformations::ALPHA);
            let mut r = d.read_info().map_err(|e| format!("not a readable PNG: {e}"))?;
            let (w, h) = (r.info().width, r.info().height);
            check(w, h)?;
            let size = r.output_buffer_size().ok_or("PNG too large")?;
            let mut buf = vec![0; size];
            let info = r.next_frame(&mut buf).map_err(|e| format!("not a readable PNG: {e}"))?;
            buf.truncate(info.buffer_size());
            let n = w as usize * h as usize;
            let pixels = match info.color_type {
                png::ColorType::Rgba => buf,
                png::ColorType::Rgb => buf.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
                png::ColorType::GrayscaleAlpha => buf.chunks_exact(2).flat_map(|p| [p[0], p[0], p[0], p[1]]).collect(),
                png::ColorType::Grayscale => buf.iter().flat_map(|&g| [g, g, g, 255]).collect(),
                png::ColorType::Indexed => return Err("an indexed PNG left unexpanded".into()),
            };
            if pixels.len() != 4 * n {
                return Err(format!("PNG decoded to {} bytes for {w} × {h} pixels", pixels.len()));
            }
            Ok(Rgba8 { width: w, height: h, pixels })
        }
        ImageCodec::Jpeg => {
            use zune_core::bytestream::ZCursor;
            use zune_core::colorspace::ColorSpace;
            use zune_core::options::DecoderOptions;
            let options = DecoderOptions::default()
                .jpeg_set_out_colorspace(ColorSpace::RGBA)
                .set_max_width(MAX_SIDE as usize)
                .set_max_height(MAX_SIDE as usize);
            let mut d = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), options);
            d.decode_headers().map_err(|e| format!("not a readable JPEG: {e:?}"))?;
            let info = d.info().ok_or("not a readable JPEG: no frame header")?;
            let (w, h) = (info.width as u32, info.height as u32);
            check(w, h)?;
            let pixels = d.decode().map_err(|e| format!("not a readable JPEG: {e:?}"))?;
            if pixels.len() != 4 * w as usize * h as usize {
                return Err(format!("JPEG decoded to {} bytes for {w} × {h} pixels", pixels.len()));
            }
            Ok(Rgba8 { width: w, height: h, pixels })
        }
    }
}

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
