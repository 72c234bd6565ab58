//! Heightmap PNGs: 16-bit greyscale values (times a scale, plus an offset), Mapbox Terrain-RGB or
//! Mapzen Terrarium colours (`--dem-encoding`). Read row by row.
//!
//! Where the grid lies comes from a JSON sidecar with the same name (`boulder.png` →
//! `boulder.json`), or, for a Web Mercator tile, from `--dem-tile z/x/y`. Sidecar keys, all
//! optional:
//!
//! - `xllcorner`, `yllcorner` (the grid's lower-left corner) or `xllcenter`, `yllcenter` (the
//!   lower-left sample's centre), and `cellsize`; with a `_deg` suffix (`xllcorner_deg`, ...) they
//!   are degrees;
//! - `crs`: a name such as `EPSG:4326` (degrees when it names 4326 and no `_deg` key says so);
//! - `row0`: `north` (default) or `south`, the edge of the image's first row;
//! - `units`: of the heights, metres unless it names feet;
//! - `scale`, `offset`: height = value × scale + offset (16-bit greyscale only; 1 and 0);
//! - `nodata`: a stored 16-bit value that means no data.

use super::heightfield::{self, axis, DemCrs, DemEncoding, Grid, Placement};
use super::{open_regular, read_regular_file, ImportOptions, Raw};
use crate::error::{Error, Result};
use crate::geodesy::{mercator_lat, mercator_lon};
use png::{BitDepth, ColorType};
use std::path::Path;

pub fn read(path: &Path, options: &ImportOptions, warnings: &mut Vec<String>) -> Result<Raw> {
    let (file, stored) = open_regular(path)?;
    let png_err = |e: png::DecodingError| Error::invalid(path, None, format!("not a readable PNG: {e}"));
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(png_err)?;
    let info = reader.info();
    let (cols, rows, interlaced) = (info.width as usize, info.height as usize, info.interlaced);
    let (color, depth) = (info.color_type, info.bit_depth);
    let encoding = options.dem.encoding.unwrap_or(DemEncoding::Grey16);
    let channels = match (encoding, color, depth) {
        (DemEncoding::Grey16, ColorType::Grayscale, BitDepth::Sixteen) => 1,
        (DemEncoding::TerrainRgb | DemEncoding::Terrarium, ColorType::Rgb, BitDepth::Eight) => 3,
        (DemEncoding::TerrainRgb | DemEncoding::Terrarium, ColorType::Rgba, BitDepth::Eight) => 4,
        (DemEncoding::Grey16, ColorType::Rgb | ColorType::Rgba, BitDepth::Eight) => {
            return Err(Error::invalid(
                path,
                None,
                "an 8-bit colour PNG: if it encodes heights in its colours, say how with --dem-encoding terrain-rgb or terrarium; heightmaps in grey need 16 bits",
            ))
        }
        (DemEncoding::Grey16, ..) => {
            return Err(Error::invalid(
                path,
                None,
                format!("a {color:?} PNG of {} bits per sample: a heightmap PNG is 16-bit greyscale (8 bits would quantize heights to 256 steps)", depth as u8),
            ))
        }
        _ => {
            return Err(Error::invalid(
                path,
                None,
                format!("a {color:?} PNG of {} bits per sample: {encoding:?} heights are 8-bit RGB or RGBA", depth as u8),
            ))
        }
    };
    let bytes_per_sample = if channels == 1 { 2 } else { channels as u64 };
    heightfield::check_claim(path, cols, rows, bytes_per_sample, stored, heightfield::MAX_EXPANSION)?;
    let sidecar = Sidecar::read(path)?;
    let placement = placement(path, options, sidecar.as_ref(), cols, rows, warnings)?;
    let (scale, offset, nodata, feet) = sidecar.as_ref().map_or((1.0, 0.0, None, false), |s| (s.scale, s.offset, s.nodata, s.feet));
    let grid = Grid { cols, rows, placement, metres_per_height_unit: if feet { 0.3048 } else { 1.0 }, z_scale: options.dem.z_scale };
    let whole = if interlaced {
        let mut buf = vec![0; reader.output_buffer_size().ok_or_else(|| Error::invalid(path, None, "the image is too large"))?];
        reader.next_frame(&mut buf).map_err(png_err)?;
        Some(buf)
    } else {
        None
    };
    let line = cols * channels * if channels == 1 { 2 } else { 1 };
    heightfield::triangulate(path, &grid, warnings, |i, out| {
        let data = match &whole {
            Some(buf) => &buf[i * line..(i + 1) * line],
            None => reader
                .next_row()
                .map_err(|e| Error::at_element(path, format!("row {i}"), format!("PNG data: {e}")))?
                .ok_or_else(|| Error::at_element(path, format!("row {i}"), "the image data ends early"))?
                .data(),
        };
        for (h, px) in out.iter_mut().zip(data.chunks_exact(line / cols)) {
            *h = match encoding {
                DemEncoding::Grey16 => {
                    let v = u16::from_be_bytes([px[0], px[1]]);
                    if Some(v) == nodata {
                        f64::NAN
                    } else {
                        f64::from(v) * scale + offset
                    }
                }
                _ if channels == 4 && px[3] == 0 => f64::NAN,
                DemEncoding::TerrainRgb => -10_000.0 + f64::from(u32::from(px[0]) << 16 | u32::from(px[1]) << 8 | u32::from(px[2])) * 0.1,
                DemEncoding::Terrarium => f64::from(px[0]) * 256.0 + f64::from(px[1]) + f64::from(px[2]) / 256.0 - 32_768.0,
            };
        }
        Ok(())
    })
}

/// Where the samples are: a Web Mercator tile, the sidecar's grid, or nowhere.
fn placement(
    path: &Path,
    options: &ImportOptions,
    sidecar: Option<&Sidecar>,
    cols: usize,
    rows: usize,
    warnings: &mut Vec<String>,
) -> Result<Placement> {
    if let Some([z, x, y]) = options.dem.tile {
        if z > 30 || x >= 1 << z || y >= 1 << z {
            return Err(Error::invalid(path, None, format!("--dem-tile {z}/{x}/{y} is not a tile: x and y run from 0 to 2^z − 1")));
        }
        let lon = (0..cols).map(|j| mercator_lon(f64::from(x) + (j as f64 + 0.5) / cols as f64, z)).collect();
        let lat = (0..rows).map(|i| mercator_lat(f64::from(y) + (i as f64 + 0.5) / rows as f64, z)).collect();
        return Ok(Placement::Geographic { lon, lat, crs: format!("EPSG:3857 tile {z}/{x}/{y}") });
    }
    let Some(s) = sidecar.filter(|s| s.cell.is_some()) else {
        let cell = options.dem.cell_size.unwrap_or(1.0);
        warnings.push(format!(
            "no georeference (no {} beside it, no --dem-tile): placed nowhere, samples {cell} m apart (--dem-cell-size)",
            path.with_extension("json").file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
        ));
        return Ok(Placement::Unplaced { cell });
    };
    let cell = s.cell.unwrap_or(1.0);
    let (x0, y0) = (s.x.unwrap_or(0.0), s.y.unwrap_or(0.0));
    let half = if s.center { 0.0 } else { 0.5 * cell };
    let x = axis(x0 + half, cell, cols);
    let south = y0 + half;
    let y = if s.row0_south { axis(south, cell, rows) } else { axis(south + cell * (rows - 1) as f64, -cell, rows) };
    let geographic = match (options.dem.crs, s.degrees) {
        (DemCrs::Auto, Some(d)) => d,
        (crs, _) => heightfield::is_geographic(crs, [x[0], x[cols - 1]], [south, south + cell * (rows - 1) as f64], cell, warnings),
    };
    let crs = s.crs.clone();
    Ok(if geographic { Placement::Geographic { lon: x, lat: y, crs } } else { Placement::Projected { x, y, metres_per_unit: 1.0, crs } })
}

/// What a JSON sidecar says.
#[derive(Debug, Default)]
struct Sidecar {
    x: Option<f64>,
    y: Option<f64>,
    cell: Option<f64>,
    center: bool,
    /// Whether the coordinates are degrees, when the sidecar says.
    degrees: Option<bool>,
    crs: String,
    row0_south: bool,
    feet: bool,
    scale: f64,
    offset: f64,
    nodata: Option<u16>,
}

impl Sidecar {
    fn read(png: &Path) -> Result<Option<Sidecar>> {
        let path = png.with_extension("json");
        let Ok(bytes) = read_regular_file(&path, 1 << 20) else {
            return Ok(None);
        };
        let v: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| Error::at_line(&path, e.line(), format!("not JSON: {e}")))?;
        let bad = |key: &str, what: &str| Error::at_element(&path, key, format!("expected {what}"));
        let num = |key: &str| -> Result<Option<f64>> {
            match v.get(key) {
                None => Ok(None),
                Some(x) => x.as_f64().filter(|x| x.is_finite()).map(Some).ok_or_else(|| bad(key, "a number")),
            }
        };
        let text = |key: &str| -> Result<Option<String>> {
            match v.get(key) {
                None => Ok(None),
                Some(x) => x.as_str().map(|s| Some(s.to_string())).ok_or_else(|| bad(key, "a string")),
            }
        };
        let mut s = Sidecar { scale: 1.0, ..Sidecar::default() };
        for (suffix, degrees) in [("", None), ("_deg", Some(true))] {
            for (key, center) in [("xllcorner", false), ("xllcenter", true)] {
                if let Some(x) = num(&format!("{key}{suffix}"))? {
                    (s.x, s.center, s.degrees) = (Some(x), center, degrees.or(s.degrees));
                }
            }
            for key in ["yllcorner", "yllcenter"] {
                if let Some(y) = num(&format!("{key}{suffix}"))? {
                    s.y = Some(y);
                }
            }
            if let Some(c) = num(&format!("cellsize{suffix}"))? {
                if c <= 0.0 {
                    return Err(bad(&format!("cellsize{suffix}"), "a positive cell size"));
                }
                (s.cell, s.degrees) = (Some(c), degrees.or(s.degrees));
            }
        }
        s.crs = text("crs")?.unwrap_or_default();
        if s.degrees.is_none() && (s.crs.contains("4326") || s.crs.contains("4269")) {
            s.degrees = Some(true);
        }
        s.row0_south = match text("row0")?.as_deref() {
            None | Some("north") => false,
            Some("south") => true,
            Some(_) => return Err(bad("row0", "\"north\" or \"south\"")),
        };
        let units = text("units")?.unwrap_or_default().to_ascii_lowercase();
        s.feet = units.contains("feet") || units.contains("foot") || units.split(|c: char| !c.is_alphanumeric()).any(|w| w == "ft");
        s.scale = num("scale")?.unwrap_or(1.0);
        s.offset = num("offset")?.unwrap_or(0.0);
        s.nodata = match num("nodata")? {
            None => None,
            Some(n) if n.fract() == 0.0 && (0.0..=65535.0).contains(&n) => Some(n as u16),
            Some(_) => return Err(bad("nodata", "a 16-bit value (0..65535)")),
        };
        Ok(Some(s))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::GeoFrame;

    fn write_png(path: &Path, w: u32, h: u32, color: ColorType, depth: BitDepth, data: &[u8]) {
        let file = std::fs::File::create(path).unwrap();
        let mut enc = png::Encoder::new(file, w, h);
        enc.set_color(color);
        enc.set_depth(depth);
        enc.write_header().unwrap().write_image_data(data).unwrap();
    }

    #[test]
    fn grey16_with_a_sidecar_and_terrain_rgb_as_a_tile() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.png");
        let values: [u16; 4] = [100, 200, 65535, 400];
        write_png(&p, 2, 2, ColorType::Grayscale, BitDepth::Sixteen, &values.iter().flat_map(|v| v.to_be_bytes()).collect::<Vec<u8>>());
        std::fs::write(
            dir.path().join("h.json"),
            r#"{"xllcorner": 1000, "yllcorner": 2000, "cellsize": 30, "nodata": 65535, "scale": 0.5}"#,
        )
        .unwrap();
        let raw = read(&p, &ImportOptions::default(), &mut Vec::new()).unwrap();
        assert_eq!(raw.mesh.positions.len(), 3);
        assert_eq!(raw.mesh.positions[1].y, 100.0);
        let g = raw.georef.unwrap();
        assert_eq!((g.frame, g.origin), (GeoFrame::Projected, [1030.0, 2030.0, 0.0]));

        let rgb = dir.path().join("t.png");
        let px = |h: f64| {
            let v = ((h + 10_000.0) * 10.0).round() as u32;
            [(v >> 16) as u8, (v >> 8) as u8, v as u8]
        };
        let data: Vec<u8> = [0.0, 100.0, 2000.5, 3776.0].iter().flat_map(|&h| px(h)).collect();
        write_png(&rgb, 2, 2, ColorType::Rgb, BitDepth::Eight, &data);
        let e = read(&rgb, &ImportOptions::default(), &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("--dem-encoding"), "{e}");
        let mut o = ImportOptions::default();
        o.dem.encoding = Some(DemEncoding::TerrainRgb);
        o.dem.tile = Some([10, 906, 404]);
        let raw = read(&rgb, &o, &mut Vec::new()).unwrap();
        let s = raw.grid.unwrap();
        assert!(s.min_height.abs() < 0.05 && (s.max_height - 3776.0).abs() < 0.05, "{s:?}");
        let g = raw.georef.unwrap();
        assert!(g.frame == GeoFrame::LocalTangent && (g.origin[0] - 138.6).abs() < 0.2 && (g.origin[1] - 35.3).abs() < 0.3, "{g:?}");
    }

    #[test]
    fn a_png_of_the_wrong_depth_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g8.png");
        write_png(&p, 2, 2, ColorType::Grayscale, BitDepth::Eight, &[1, 2, 3, 4]);
        let e = read(&p, &ImportOptions::default(), &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("Grayscale PNG of 8 bits") && e.contains("16-bit greyscale"), "{e}");
    }
}
