//! GeoTIFF elevation grids, read with the `tiff` crate (image-rs: strips and tiles; uncompressed,
//! LZW, Deflate and PackBits): one band of integer or floating-point samples. Where the grid lies
//! comes from the GeoTIFF tags (ModelPixelScale with ModelTiepoint, or a ModelTransformation
//! without rotation; GeoKeys for geographic or projected, the EPSG code, linear and vertical
//! units, pixel-is-area or point); no data from GDAL's GDAL_NODATA tag and NaN. Read one band of
//! strips or tiles at a time.

use super::heightfield::{self, Grid, Placement};
use super::{open_regular, ImportOptions, Raw};
use crate::error::{Error, Result};
use std::path::Path;
use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::ColorType;

/// GeoKey ids (GeoTIFF 1.1, §7).
mod key {
    pub const MODEL_TYPE: u16 = 1024;
    pub const RASTER_TYPE: u16 = 1025;
    pub const CITATION: u16 = 1026;
    pub const GEOGRAPHIC_TYPE: u16 = 2048;
    pub const PROJECTED_TYPE: u16 = 3072;
    pub const LINEAR_UNITS: u16 = 3076;
    pub const VERTICAL_UNITS: u16 = 4099;
}

pub fn read(path: &Path, options: &ImportOptions, warnings: &mut Vec<String>) -> Result<Raw> {
    let (file, file_len) = open_regular(path)?;
    let tiff_err = |e: tiff::TiffError| Error::invalid(path, None, format!("TIFF: {e}"));
    // What the decoder may allocate follows from the file's size: stored data cannot exceed it, and
    // decodes to at most MAX_EXPANSION times as much (and at most the crate's default 256 MiB a chunk).
    let mut limits = tiff::decoder::Limits::default();
    let decoded = usize::try_from(file_len.saturating_mul(heightfield::MAX_EXPANSION)).unwrap_or(usize::MAX);
    limits.decoding_buffer_size = decoded.min(limits.decoding_buffer_size);
    limits.intermediate_buffer_size = usize::try_from(file_len).unwrap_or(usize::MAX).min(limits.intermediate_buffer_size);
    limits.ifd_value_size = usize::try_from(file_len).unwrap_or(usize::MAX).min(limits.ifd_value_size);
    let mut dec = Decoder::new(std::io::BufReader::new(file)).map_err(tiff_err)?.with_limits(limits);
    let (w, h) = dec.dimensions().map_err(tiff_err)?;
    let (cols, rows) = (w as usize, h as usize);
    let format = dec.find_tag_unsigned::<u16>(Tag::SampleFormat).map_err(tiff_err)?.unwrap_or(1);
    let bits = match dec.colortype().map_err(tiff_err)? {
        ColorType::Gray(bits) => bits,
        ColorType::Multiband { num_samples, .. } => {
            return Err(Error::invalid(path, None, format!("{num_samples} samples per pixel: strata reads one band of elevations")))
        }
        other => return Err(Error::invalid(path, None, format!("a {other:?} image: strata reads one band of elevations"))),
    };
    let supported = matches!((format, bits), (1 | 2, 8 | 16 | 32 | 64) | (3, 32 | 64));
    if !supported {
        let kind = match format {
            1 => "unsigned integer",
            2 => "signed integer",
            3 => "floating-point",
            4 => "undefined",
            5 => "complex integer",
            6 => "complex floating-point",
            _ => "unknown",
        };
        return Err(Error::invalid(
            path,
            None,
            format!("{bits}-bit {kind} samples (SampleFormat {format}) are not supported: strata reads 8- to 64-bit integers and 32- or 64-bit floats"),
        ));
    }
    let nodata = match dec.find_tag(Tag::GdalNodata).map_err(tiff_err)? {
        Some(v) => {
            let text = v.into_string().map_err(tiff_err)?;
            let text = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
            Some(text.parse::<f64>().map_err(|_| Error::invalid(path, None, format!("GDAL_NODATA {text:?} is not a number")))?)
        }
        None => None,
    };
    let geo = GeoKeys::read(&mut dec).map_err(tiff_err)?;
    let placement = placement(path, &mut dec, &geo, cols, rows, options, warnings)?;
    let grid = Grid {
        cols,
        rows,
        placement,
        metres_per_height_unit: geo.units(key::VERTICAL_UNITS, "vertical", warnings),
        z_scale: options.dem.z_scale,
    };

    let counts = match dec.get_chunk_type() {
        ChunkType::Strip => Tag::StripByteCounts,
        ChunkType::Tile => Tag::TileByteCounts,
    };
    let stored: u64 =
        dec.find_tag_unsigned_vec::<u64>(counts).map_err(tiff_err)?.unwrap_or_default().iter().fold(0, |a, &b| a.saturating_add(b));
    heightfield::check_claim(path, cols, rows, u64::from(bits / 8).max(1), stored.min(file_len), heightfield::MAX_EXPANSION)?;
    let (cw, ch) = dec.chunk_dimensions();
    // A strip or tile taller than the image holds no more rows than the image.
    let (cw, ch) = (cw as usize, (ch as usize).min(rows));
    let across = match dec.get_chunk_type() {
        ChunkType::Strip => 1,
        ChunkType::Tile => cols.div_ceil(cw.max(1)),
    };
    if cw == 0 || ch == 0 {
        return Err(Error::invalid(path, None, "chunks of zero size"));
    }
    let mut band = vec![f64::NAN; cols * ch];
    let mut loaded = usize::MAX;
    heightfield::triangulate(path, &grid, warnings, |i, out| {
        let b = i / ch;
        if b != loaded {
            band.fill(f64::NAN);
            for c in 0..across {
                let index = (b * across + c) as u32;
                let at = format!("{} {index}", if across == 1 { "strip" } else { "tile" });
                let data = dec.read_chunk(index).map_err(|e| Error::at_element(path, at.clone(), format!("TIFF: {e}")))?;
                let values = to_f64(data);
                let (dw, dh) = dec.chunk_data_dimensions(index);
                let (dw, dh) = (dw as usize, dh as usize);
                let stride = values.len().checked_div(dh).unwrap_or(0);
                if stride < dw || dh > ch {
                    return Err(Error::at_element(path, at, format!("{} values for {dw} × {dh} samples", values.len())));
                }
                for r in 0..dh {
                    let dst = &mut band[r * cols + c * cw..r * cols + (c * cw + dw).min(cols)];
                    let n = dst.len();
                    dst.copy_from_slice(&values[r * stride..r * stride + n]);
                }
            }
            loaded = b;
        }
        out.copy_from_slice(&band[(i - b * ch) * cols..(i - b * ch + 1) * cols]);
        if let Some(nd) = nodata {
            out.iter_mut().filter(|h| **h == nd).for_each(|h| *h = f64::NAN);
        }
        Ok(())
    })
}

fn to_f64(data: DecodingResult) -> Vec<f64> {
    fn conv<T: Copy>(v: Vec<T>, f: impl Fn(T) -> f64) -> Vec<f64> {
        v.into_iter().map(f).collect()
    }
    match data {
        DecodingResult::U8(v) => conv(v, f64::from),
        DecodingResult::U16(v) => conv(v, f64::from),
        DecodingResult::U32(v) => conv(v, f64::from),
        DecodingResult::U64(v) => conv(v, |x| x as f64),
        DecodingResult::I8(v) => conv(v, f64::from),
        DecodingResult::I16(v) => conv(v, f64::from),
        DecodingResult::I32(v) => conv(v, f64::from),
        DecodingResult::I64(v) => conv(v, |x| x as f64),
        DecodingResult::F16(v) => conv(v, |x| f64::from(f32::from(x))),
        DecodingResult::F32(v) => conv(v, f64::from),
        DecodingResult::F64(v) => v,
    }
}

/// The GeoKey directory: short values and the citation strings it points at.
#[derive(Default)]
struct GeoKeys {
    shorts: Vec<(u16, u16)>,
    texts: Vec<(u16, String)>,
    doubles: Vec<(u16, f64)>,
}

impl GeoKeys {
    fn read<R: std::io::Read + std::io::Seek>(dec: &mut Decoder<R>) -> tiff::TiffResult<GeoKeys> {
        let mut keys = GeoKeys::default();
        let Some(dir) = dec.find_tag(Tag::GeoKeyDirectoryTag)? else {
            return Ok(keys);
        };
        let dir = dir.into_u16_vec()?;
        let ascii = dec.find_tag(Tag::GeoAsciiParamsTag)?.map(|v| v.into_string()).transpose()?.unwrap_or_default();
        let doubles = dec.find_tag(Tag::GeoDoubleParamsTag)?.map(|v| v.into_f64_vec()).transpose()?.unwrap_or_default();
        for e in dir.get(4..).unwrap_or(&[]).chunks_exact(4) {
            let (id, location, count, value) = (e[0], e[1], e[2] as usize, e[3] as usize);
            match location {
                0 => keys.shorts.push((id, e[3])),
                34737 => {
                    if let Some(s) = ascii.get(value..value + count) {
                        keys.texts.push((id, s.trim_end_matches(['|', '\0']).to_string()));
                    }
                }
                34736 => {
                    if let Some(&d) = doubles.get(value) {
                        keys.doubles.push((id, d));
                    }
                }
                _ => {}
            }
        }
        Ok(keys)
    }

    fn short(&self, id: u16) -> Option<u16> {
        self.shorts.iter().find(|k| k.0 == id).map(|k| k.1)
    }

    fn text(&self, id: u16) -> Option<&str> {
        self.texts.iter().find(|k| k.0 == id).map(|k| k.1.as_str())
    }

    /// Metres per unit of the EPSG unit code in key `id` (metres when absent).
    fn units(&self, id: u16, what: &str, warnings: &mut Vec<String>) -> f64 {
        match self.short(id) {
            None | Some(9001) => 1.0,
            Some(9002) => 0.3048,
            Some(9003) => 1200.0 / 3937.0,
            Some(code) => {
                warnings.push(format!("{what} unit code {code} is not one strata knows: read as metres"));
                1.0
            }
        }
    }

    /// The CRS as a name: the EPSG code, else the citation.
    fn crs(&self) -> String {
        let code = self.short(key::PROJECTED_TYPE).or(self.short(key::GEOGRAPHIC_TYPE)).filter(|&c| c != 32767 && c != 0);
        match code {
            Some(c) => format!("EPSG:{c}"),
            None => self.text(key::CITATION).unwrap_or("").to_string(),
        }
    }
}

/// Where the samples are, from the model tags.
fn placement<R: std::io::Read + std::io::Seek>(
    path: &Path,
    dec: &mut Decoder<R>,
    geo: &GeoKeys,
    cols: usize,
    rows: usize,
    options: &ImportOptions,
    warnings: &mut Vec<String>,
) -> Result<Placement> {
    let tiff_err = |e: tiff::TiffError| Error::invalid(path, None, format!("TIFF: {e}"));
    let get = |dec: &mut Decoder<R>, tag| dec.find_tag(tag).map_err(tiff_err)?.map(|v| v.into_f64_vec().map_err(tiff_err)).transpose();
    // X = x0 + sx · column, Y = y0 + sy · row, at pixel corners.
    let (x0, sx, y0, sy) = if let Some(m) = get(dec, Tag::ModelTransformationTag)? {
        if m.len() < 8 {
            return Err(Error::invalid(path, None, format!("ModelTransformation has {} values, not 16", m.len())));
        }
        if m[1] != 0.0 || m[4] != 0.0 {
            return Err(Error::invalid(path, None, "the grid is rotated or sheared (ModelTransformation): strata reads north-up grids"));
        }
        (m[3], m[0], m[7], m[5])
    } else {
        match (get(dec, Tag::ModelTiepointTag)?, get(dec, Tag::ModelPixelScaleTag)?) {
            (Some(t), Some(s)) if t.len() >= 6 && s.len() >= 2 => (t[3] - t[0] * s[0], s[0], t[4] + t[1] * s[1], -s[1]),
            _ => {
                let cell = options.dem.cell_size.unwrap_or(1.0);
                warnings.push(format!("no GeoTIFF georeference: placed nowhere, samples {cell} m apart (--dem-cell-size)"));
                return Ok(Placement::Unplaced { cell });
            }
        }
    };
    if !(x0.is_finite() && y0.is_finite() && sx.is_finite() && sy.is_finite() && sx != 0.0 && sy != 0.0) {
        return Err(Error::invalid(path, None, format!("georeference origin ({x0}, {y0}), pixel size ({sx}, {sy}) is unusable")));
    }
    let half = if geo.short(key::RASTER_TYPE) == Some(2) { 0.0 } else { 0.5 };
    let x: Vec<f64> = (0..cols).map(|c| x0 + sx * (c as f64 + half)).collect();
    let y: Vec<f64> = (0..rows).map(|r| y0 + sy * (r as f64 + half)).collect();
    let geographic = match geo.short(key::MODEL_TYPE) {
        Some(2) => true,
        Some(1) => false,
        _ => {
            let (xs, ys) = ([x[0], x[cols - 1]], [y[0].min(y[rows - 1]), y[0].max(y[rows - 1])]);
            heightfield::is_geographic(options.dem.crs, xs, ys, sx.abs(), warnings)
        }
    };
    let crs = geo.crs();
    Ok(if geographic {
        Placement::Geographic { lon: x, lat: y, crs }
    } else {
        Placement::Projected { x, y, metres_per_unit: geo.units(key::LINEAR_UNITS, "linear", warnings), crs }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::GeoFrame;
    use tiff::encoder::{colortype, TiffEncoder};

    /// A 3 × 2 float GeoTIFF in UTM metres, one sample no data.
    fn write_geotiff(path: &Path) {
        let file = std::fs::File::create(path).unwrap();
        let mut enc = TiffEncoder::new(file).unwrap();
        let mut img = enc.new_image::<colortype::Gray32Float>(3, 2).unwrap();
        let dir = img.encoder();
        dir.write_tag(Tag::ModelPixelScaleTag, &[30.0f64, 30.0, 0.0][..]).unwrap();
        dir.write_tag(Tag::ModelTiepointTag, &[0.0f64, 0.0, 0.0, 480_000.0, 4_400_000.0, 0.0][..]).unwrap();
        dir.write_tag(Tag::GeoKeyDirectoryTag, &[1u16, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32613][..]).unwrap();
        dir.write_tag(Tag::GdalNodata, "-9999").unwrap();
        img.write_data(&[1.0f32, 2.0, 3.0, 4.0, -9999.0, 6.0]).unwrap();
    }

    #[test]
    fn reads_a_projected_float_grid_with_nodata() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.tif");
        write_geotiff(&p);
        let raw = read(&p, &ImportOptions::default(), &mut Vec::new()).unwrap();
        assert_eq!(raw.mesh.positions.len(), 5);
        let g = raw.georef.unwrap();
        assert_eq!((g.frame, g.origin, g.crs.as_str()), (GeoFrame::Projected, [480_045.0, 4_399_970.0, 0.0], "EPSG:32613"));
        assert_eq!(raw.mesh.positions[0], glam::Vec3::new(-30.0, 1.0, -15.0));
        // The same file claiming complex floats (SampleFormat 6).
        let mut bytes = std::fs::read(&p).unwrap();
        let entry = [0x53, 0x01, 3, 0, 1, 0, 0, 0, 3, 0];
        let at = bytes.windows(10).position(|w| w == entry).expect("the SampleFormat entry");
        bytes[at + 8] = 6;
        std::fs::write(&p, bytes).unwrap();
        let e = read(&p, &ImportOptions::default(), &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("complex floating-point samples (SampleFormat 6) are not supported"), "{e}");
    }
}
