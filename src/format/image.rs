//! The image files inside `TEXL` chunks (spec §7.5) decoded into pixels: a reader's last check
//! that a level is usable, and what renderers sample. PNG through the `png` crate, JPEG through
//! `zune-jpeg`, both bounded by the size the file's header states.

use super::texture::{image_size, MAX_PIXELS, MAX_SIDE};
use super::ImageCodec;

/// Most decoded bytes per byte of an image file.
const EXPANSION: u64 = 33_024;

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
            return Err(format!("a {w} × {h} image (at most {MAX_SIDE} a side and {MAX_PIXELS} pixels)"));
        }
        // No PNG or JPEG packs more than this many decoded bytes into one of its own (a 1-bit PNG
        // of one flat color, deflate's 1032:1 times 32): a header claiming more is refused before
        // its pixels are allocated.
        let decoded = 4 * w as u64 * h as u64;
        if decoded > EXPANSION * bytes.len() as u64 + (1 << 20) {
            return Err(format!("a {w} × {h} image in {} bytes: more than its bytes can hold", bytes.len()));
        }
        Ok(())
    };
    match codec {
        ImageCodec::Png => {
            // The header's size bounds what decoding may allocate (16-bit RGBA rows plus filter bytes,
            // and a margin for the decoder's own buffers); profiles and text, which could inflate to
            // far more than the pixels, are skipped unread.
            let (w, h) = image_size(ImageCodec::Png, bytes)?;
            check(w, h)?;
            let limit = 8 * w as usize * h as usize + h as usize + (1 << 20);
            let mut d = png::Decoder::new_with_limits(std::io::Cursor::new(bytes), png::Limits { bytes: limit });
            d.set_ignore_iccp_chunk(true);
            d.set_ignore_text_chunk(true);
            d.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16 | png::Transformations::ALPHA);
            let mut r = d.read_info().map_err(|e| format!("not a readable PNG: {e}"))?;
            if (r.info().width, r.info().height) != (w, h) {
                return Err("PNG header read two ways disagrees".into());
            }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A PNG signature and IHDR claiming `w` × `h`, then nothing useful.
    fn claiming(w: u32, h: u32) -> Vec<u8> {
        let mut b = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        b.extend_from_slice(&w.to_be_bytes());
        b.extend_from_slice(&h.to_be_bytes());
        b.extend_from_slice(&[8, 6, 0, 0, 0, 0, 0, 0, 0]);
        b
    }

    #[test]
    fn a_header_claiming_more_than_its_bytes_hold_is_refused_before_decoding() {
        let e = decode(ImageCodec::Png, &claiming(16384, 16384)).unwrap_err();
        assert!(e.contains("more than its bytes can hold"), "{e}");
        let e = decode(ImageCodec::Png, &claiming(70000, 4)).unwrap_err();
        assert!(e.contains("at most 65536 a side"), "{e}");
        // A small claim passes the bound and fails as the truncated file it is.
        let e = decode(ImageCodec::Png, &claiming(64, 64)).unwrap_err();
        assert!(e.contains("not a readable PNG"), "{e}");
        // JPEG: a start-of-frame claiming 16384² in a few bytes.
        let jpeg = [0xFF, 0xD8, 0xFF, 0xC0, 0, 11, 8, 0x40, 0, 0x40, 0, 3, 1, 0x11, 0];
        let e = decode(ImageCodec::Jpeg, &jpeg).unwrap_err();
        assert!(e.contains("more than its bytes can hold") || e.contains("not a readable JPEG"), "{e}");
    }
}
