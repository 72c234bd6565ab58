//! Images in the file (spec §7.5, format 2.2): the `TEXR` sub-chunk of `SKEL` (the image table,
//! each material's maps, each node's UV density) and the `TEXL` chunks after the last `GEOM`, one
//! per level of each image, each a complete PNG or JPEG file. Pure functions over byte slices.

use super::chunk::{self, Fields, HEADER_BYTES, TRAILER_BYTES};
use super::id;
use super::records::{ImageCodec, ImageLevel, ImageRecord, Material, TextureSlot, Textures, Wrap, MAP_KINDS};
use crate::error::Result;
use std::collections::HashSet;

/// Bytes of one level entry of `TEXR`.
pub const LEVEL_ENTRY_BYTES: u64 = 24;
/// Bytes of one material's slots in `TEXR`: five of (image u32, wrap u8 ×2, reserved u16).
pub const MATERIAL_SLOTS_BYTES: u64 = 8 * MAP_KINDS as u64;
/// Most levels one image may have.
pub const MAX_LEVELS: u32 = 32;
/// Largest image side.
pub const MAX_SIDE: u32 = 1 << 16;
/// Most pixels of one level: 16384², a GiB as RGBA8.
pub const MAX_PIXELS: u64 = 1 << 28;
/// Longest image name, in bytes.
pub const MAX_NAME_BYTES: u32 = 4096;
/// Marks an empty material slot.
pub const NO_IMAGE: u32 = u32::MAX;

/// The side of the next level: half, rounded up.
pub fn half(side: u32) -> u32 {
    side.div_ceil(2)
}

/// The u16 code of a UV density (UV units per model unit): 0 for none, else
/// `32768 + ⌈256·log2 d⌉` clamped to 1..=65535, so that the decoded density is never below `d`.
pub fn density_code(d: f32) -> u16 {
    if d.is_nan() || d <= 0.0 || !d.is_finite() {
        return 0;
    }
    let c = (256.0 * (d as f64).log2()).ceil() + 32768.0;
    c.clamp(1.0, 65535.0) as u16
}

/// The density a code stands for.
pub fn density_decode(code: u16) -> f32 {
    if code == 0 {
        0.0
    } else {
        (2f64).powf((code as f64 - 32768.0) / 256.0) as f32
    }
}

/// One level to write: its size and its file bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LevelIn {
    pub width: u32,
    pub height: u32,
    pub bytes: Vec<u8>,
}

/// One image to write: its levels, finest (the full image) first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ImageIn {
    pub name: String,
    pub codec: ImageCodec,
    pub levels: Vec<LevelIn>,
}

/// The order in which levels are laid out: by pixel count, then image, so that the coarsest level
/// of every image comes first and a viewer fetches them in one range. Pairs (image, level).
pub fn layout_order(images: &[ImageIn]) -> Vec<(u32, u32)> {
    let mut all: Vec<(u64, u32, u32)> = images
        .iter()
        .enumerate()
        .flat_map(|(i, im)| im.levels.iter().enumerate().map(move |(l, v)| (v.width as u64 * v.height as u64, i as u32, l as u32)))
        .collect();
    all.sort_unstable();
    all.into_iter().map(|(_, i, l)| (i, l)).collect()
}

/// The `TEXR` payload: images, level entries in `order`, material slots, node density codes.
pub fn encode_texr(images: &[ImageIn], order: &[(u32, u32)], materials: &[Material], density: &[u16]) -> Vec<u8> {
    let mut p = Vec::new();
    p.extend_from_slice(&(images.len() as u32).to_le_bytes());
    p.extend_from_slice(&(order.len() as u32).to_le_bytes());
    for im in images {
        p.extend_from_slice(&(im.name.len() as u32).to_le_bytes());
        p.extend_from_slice(im.name.as_bytes());
        p.extend_from_slice(&[im.codec as u8, im.levels.len() as u8, 0, 0]);
    }
    for &(i, l) in order {
        let v = &images[i as usize].levels[l as usize];
        let span = v.bytes.len() as u64 + HEADER_BYTES + TRAILER_BYTES;
        for x in [i, l, v.width, v.height, span as u32, chunk::crc32(&v.bytes)] {
            p.extend_from_slice(&x.to_le_bytes());
        }
    }
    for m in materials {
        for slot in m.maps {
            let (image, wrap) = slot.map_or((NO_IMAGE, [Wrap::Repeat; 2]), |s| (s.image, s.wrap));
            p.extend_from_slice(&image.to_le_bytes());
            p.extend_from_slice(&[wrap[0] as u8, wrap[1] as u8, 0, 0]);
        }
    }
    for &c in density {
        p.extend_from_slice(&c.to_le_bytes());
    }
    p
}

/// What decoding `TEXR` needs of the rest of the skeleton.
pub struct TexrContext {
    pub nodes: u32,
    /// Where the first `TEXL` chunk starts: after the last `GEOM` chunk and its padding.
    pub levels_start: u64,
    pub file_size: u64,
}

/// Decode `TEXR` from its fields, filling each material's maps; checks every value (spec §7.5).
pub fn decode_texr(f: &mut Fields, cx: &TexrContext, materials: &mut [Material]) -> Result<Textures> {
    let (count, entries) = (f.u32()?, f.u32()?);
    if count == 0 {
        return Err(f.error("holds no image; a file without images has no TEXR chunk"));
    }
    // Every image record takes at least 8 bytes and every entry 24: counts the payload cannot hold
    // are refused before anything is allocated for them.
    let least = count as u64 * 8 + entries as u64 * LEVEL_ENTRY_BYTES;
    if least > f.remaining() as u64 {
        return Err(f.error(format!("{count} images and {entries} level entries need at least {least} bytes, {} left", f.remaining())));
    }
    let mut images = Vec::new();
    let mut total = 0u64;
    for i in 0..count {
        let at = f.offset();
        let len = f.u32()?;
        if len > MAX_NAME_BYTES {
            return Err(f.error_at(at, format!("image {i}: a name of {len} bytes (at most {MAX_NAME_BYTES})")));
        }
        let name =
            f.string(len).map_err(|_| f.error_at(at, format!("image {i}: name of {len} bytes runs past the chunk or is not UTF-8")))?;
        let at = f.offset();
        let b = f.bytes(4)?;
        let codec = ImageCodec::from_code(b[0]).ok_or_else(|| f.error_at(at, format!("image {i}: unknown codec {}", b[0])))?;
        let levels = b[1] as u32;
        if levels == 0 || levels > MAX_LEVELS || b[2] != 0 || b[3] != 0 {
            return Err(f.error_at(at, format!("image {i}: {levels} levels (1..={MAX_LEVELS}) or non-zero reserved bytes")));
        }
        total += levels as u64;
        if total > entries as u64 {
            return Err(f.error_at(at, format!("image {i}: images with more levels than the {entries} level entries")));
        }
        images.push(ImageRecord { name, codec, levels: vec![u32::MAX; levels as usize] });
    }
    if entries as u64 != total {
        return Err(f.error(format!("{entries} level entries for images with {total} levels")));
    }
    if (f.remaining() as u64) < entries as u64 * LEVEL_ENTRY_BYTES {
        return Err(f.error(format!("{entries} level entries run past the chunk")));
    }
    let mut levels = Vec::with_capacity(entries as usize);
    let mut offset = cx.levels_start;
    for e in 0..entries {
        let at = f.offset();
        let [image, level, width, height, size, crc] = [f.u32()?, f.u32()?, f.u32()?, f.u32()?, f.u32()?, f.u32()?];
        let bad = |msg: String| f.error_at(at, format!("level entry {e}: {msg}"));
        let Some(rec) = images.get_mut(image as usize) else {
            return Err(bad(format!("image {image} of {count}")));
        };
        let Some(slot) = rec.levels.get_mut(level as usize) else {
            return Err(bad(format!("level {level} of image {image}'s {}", rec.levels.len())));
        };
        if *slot != u32::MAX {
            return Err(bad(format!("level {level} of image {image} a second time")));
        }
        *slot = e;
        if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE || width as u64 * height as u64 > MAX_PIXELS {
            return Err(bad(format!("{width} × {height} pixels (1..={MAX_SIDE} a side, at most {MAX_PIXELS} in all)")));
        }
        if (size as u64) < HEADER_BYTES + TRAILER_BYTES + 1 {
            return Err(bad(format!("a chunk of {size} bytes")));
        }
        let end = offset.checked_add(size as u64).filter(|&e| e <= cx.file_size);
        let Some(end) = end else {
            return Err(bad(format!("its chunk at offset {offset} ({size} bytes) runs past the end of the file ({} bytes)", cx.file_size)));
        };
        levels.push(ImageLevel { image, level, width, height, offset, size, crc });
        offset = end + chunk::padding(end);
    }
    for (i, rec) in images.iter().enumerate() {
        for w in rec.levels.windows(2) {
            let (a, b) = (&levels[w[0] as usize], &levels[w[1] as usize]);
            if b.width != half(a.width) || b.height != half(a.height) || (a.width == 1 && a.height == 1) {
                return Err(f.error(format!(
                    "image {i}: level {} is {} × {}, level {} {} × {}; each level must halve the one before, rounding up",
                    a.level, a.width, a.height, b.level, b.width, b.height
                )));
            }
        }
    }
    for (m, mat) in materials.iter_mut().enumerate() {
        for k in 0..MAP_KINDS {
            let at = f.offset();
            let image = f.u32()?;
            let b = f.bytes(4)?;
            let wrap = [Wrap::from_code(b[0]), Wrap::from_code(b[1])];
            let bad = |msg: String| f.error_at(at, format!("material {m} slot {k}: {msg}"));
            if b[2] != 0 || b[3] != 0 {
                return Err(bad("non-zero reserved bytes".into()));
            }
            let [Some(s), Some(t)] = wrap else {
                return Err(bad(format!("unknown wrap modes {} {}", b[0], b[1])));
            };
            mat.maps[k] = match image {
                NO_IMAGE => None,
                i if i < count => Some(TextureSlot { image: i, wrap: [s, t] }),
                i => return Err(bad(format!("image {i} of {count}"))),
            };
        }
    }
    let mut uv_density = Vec::with_capacity(cx.nodes as usize);
    for _ in 0..cx.nodes {
        uv_density.push(density_decode(f.u16()?));
    }
    if f.remaining() > 0 {
        return Err(f.error(format!("{} bytes after the node densities", f.remaining())));
    }
    Ok(Textures { images, levels, uv_density })
}

/// The width and height a PNG or JPEG file's header states, or why it cannot be read. Reads the
/// header only (PNG's IHDR, JPEG's first start-of-frame marker).
pub fn image_size(codec: ImageCodec, b: &[u8]) -> std::result::Result<(u32, u32), String> {
    match codec {
        ImageCodec::Png => {
            if b.len() < 24 || b[..8] != *b"\x89PNG\r\n\x1a\n" || b[12..16] != *b"IHDR" {
                return Err("not a PNG file (no signature and IHDR)".into());
            }
            let be = |o: usize| u32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
            Ok((be(16), be(20)))
        }
        ImageCodec::Jpeg => {
            if b.len() < 4 || b[0] != 0xFF || b[1] != 0xD8 {
                return Err("not a JPEG file (no start-of-image marker)".into());
            }
            let mut at = 2usize;
            while at + 4 <= b.len() {
                if b[at] != 0xFF {
                    return Err(format!("no JPEG marker at byte {at}"));
                }
                let marker = b[at + 1];
                if marker == 0xFF {
                    at += 1;
                    continue;
                }
                let len = u16::from_be_bytes([b[at + 2], b[at + 3]]) as usize;
                // SOF0..SOF15 but DHT (C4), JPG (C8) and DAC (CC).
                if (0xC0..=0xCF).contains(&marker) && ![0xC4, 0xC8, 0xCC].contains(&marker) {
                    if at + 9 > b.len() {
                        break;
                    }
                    let h = u16::from_be_bytes([b[at + 5], b[at + 6]]) as u32;
                    let w = u16::from_be_bytes([b[at + 7], b[at + 8]]) as u32;
                    return Ok((w, h));
                }
                if marker == 0xDA || len < 2 {
                    break;
                }
                at += 2 + len;
            }
            Err("no JPEG start-of-frame marker before the image data".into())
        }
    }
}

/// Check a `TEXL` chunk's bytes (`level.size` of them, ID through CRC) against its entry: ID,
/// size, CRC, and the image header's size. Returns the image file's bytes.
pub fn check_level<'b>(level: &ImageLevel, codec: ImageCodec, bytes: &'b [u8]) -> std::result::Result<&'b [u8], (u64, String)> {
    let at = level.offset;
    if bytes.len() as u64 != level.size as u64 || bytes.len() < 21 {
        return Err((at, format!("{} bytes, the entry says {}", bytes.len(), level.size)));
    }
    if bytes[..4] != id::TEXL {
        return Err((at, format!("{} where a TEXL chunk should be", chunk::id_str(&[bytes[0], bytes[1], bytes[2], bytes[3]]))));
    }
    let size = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes"));
    if size + HEADER_BYTES + TRAILER_BYTES != level.size as u64 {
        return Err((at + 8, format!("payload size {size} does not match the entry's {} bytes", level.size)));
    }
    let end = bytes.len() - 4;
    let payload = &bytes[16..end];
    let stored = u32::from_le_bytes(bytes[end..].try_into().expect("4 bytes"));
    let actual = chunk::crc32(payload);
    if stored != actual || stored != level.crc {
        return Err((at + end as u64, format!("CRC {actual:08x}, stored {stored:08x}, table {:08x}", level.crc)));
    }
    let (w, h) = image_size(codec, payload).map_err(|m| (at + 16, m))?;
    if (w, h) != (level.width, level.height) {
        return Err((at + 16, format!("the image is {w} × {h}, the entry says {} × {}", level.width, level.height)));
    }
    Ok(payload)
}

/// Image indices the materials use, each once, ascending.
pub fn used_images(materials: &[Material]) -> Vec<u32> {
    let set: HashSet<u32> = materials.iter().flat_map(|m| m.maps.iter().flatten().map(|s| s.image)).collect();
    let mut v: Vec<u32> = set.into_iter().collect();
    v.sort_unstable();
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn density_codes_round_up_and_round_trip() {
        for d in [1e-6f32, 0.01, 0.37, 1.0, 2.5, 1000.0, 3e5] {
            let c = density_code(d);
            let back = density_decode(c);
            assert!(back >= d && back <= d * 1.003, "{d} -> {c} -> {back}");
        }
        assert_eq!(density_code(0.0), 0);
        assert_eq!(density_code(f32::NAN), 0);
        assert_eq!(density_decode(0), 0.0);
    }

    #[test]
    fn headers_give_sizes() {
        let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        png.extend_from_slice(&300u32.to_be_bytes());
        png.extend_from_slice(&7u32.to_be_bytes());
        assert_eq!(image_size(ImageCodec::Png, &png), Ok((300, 7)));
        assert!(image_size(ImageCodec::Png, &png[..20]).is_err());
        // SOI, an APP0 of 4 bytes, SOF0 with 8-bit precision, height 5, width 9.
        let jpeg = [0xFF, 0xD8, 0xFF, 0xE0, 0, 4, 1, 2, 0xFF, 0xC0, 0, 11, 8, 0, 5, 0, 9, 3];
        assert_eq!(image_size(ImageCodec::Jpeg, &jpeg), Ok((9, 5)));
        assert!(image_size(ImageCodec::Jpeg, &jpeg[..10]).is_err());
        assert!(image_size(ImageCodec::Jpeg, b"GIF89a").is_err());
    }

    #[test]
    fn layout_puts_small_levels_first() {
        let lv = |w: u32| LevelIn { width: w, height: w, bytes: vec![1] };
        let images = vec![
            ImageIn { name: "a".into(), codec: ImageCodec::Png, levels: vec![lv(256), lv(128), lv(64)] },
            ImageIn { name: "b".into(), codec: ImageCodec::Png, levels: vec![lv(100), lv(50)] },
        ];
        assert_eq!(layout_order(&images), vec![(1, 1), (0, 2), (1, 0), (0, 1), (0, 0)]);
    }
}
