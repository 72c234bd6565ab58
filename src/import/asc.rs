//! ESRI ASCII grid (`.asc`): a header of `key value` lines (`ncols`, `nrows`, `xllcorner` or
//! `xllcenter`, `yllcorner` or `yllcenter`, `cellsize` — or GDAL's `dx` and `dy` — and optionally
//! `NODATA_value`, in any order, any case), then `nrows` rows of `ncols` heights, north first,
//! separated by any whitespace. Read row by row. A `.prj` beside the file says whether the
//! coordinates are degrees (`GEOGCS`) or a projection (`PROJCS`); without one, see
//! [`heightfield::is_geographic`].

use super::heightfield::{self, axis, Grid, Placement};
use super::{open_regular, read_regular_file, ImportOptions, Raw};
use crate::error::{Error, Result};
use std::io::BufRead;
use std::path::Path;

/// Lines a header may have before the data starts.
const MAX_HEADER_LINES: usize = 16;

pub fn read(path: &Path, options: &ImportOptions, warnings: &mut Vec<String>) -> Result<Raw> {
    let (file, len) = open_regular(path)?;
    let mut tokens = Tokens { reader: std::io::BufReader::with_capacity(1 << 16, file), line: String::new(), pos: 0, line_no: 0, path };
    let header = read_header(&mut tokens)?;
    let (cols, rows, cell) = (header.cols, header.rows, header.cell);
    // Each value takes a digit and a separator at least: 2 bytes per sample, uncompressed.
    heightfield::check_claim(path, cols, rows, 2, len, 1)?;
    // Sample centres: row 0 is the north edge.
    let (x0, y_south) =
        (header.x + if header.center { 0.0 } else { 0.5 * cell.0 }, header.y + if header.center { 0.0 } else { 0.5 * cell.1 });
    let x = axis(x0, cell.0, cols);
    let y = axis(y_south + cell.1 * (rows - 1) as f64, -cell.1, rows);
    let prj = read_prj(path, warnings);
    let geographic = match &prj {
        Some(p) => p.geographic,
        None => heightfield::is_geographic(options.dem.crs, [x[0], x[cols - 1]], [y[rows - 1], y[0]], cell.0, warnings),
    };
    let crs = prj.as_ref().map(|p| p.name.clone()).unwrap_or_default();
    let placement = if geographic {
        Placement::Geographic { lon: x, lat: y, crs: if crs.is_empty() { "degrees (WGS 84 assumed)".into() } else { crs } }
    } else {
        Placement::Projected { x, y, metres_per_unit: prj.map_or(1.0, |p| p.metres_per_unit), crs }
    };
    let grid = Grid { cols, rows, placement, metres_per_height_unit: 1.0, z_scale: options.dem.z_scale };
    let nodata = header.nodata;
    let raw = heightfield::triangulate(path, &grid, warnings, |i, row| {
        for (j, h) in row.iter_mut().enumerate() {
            let Some((token, line)) = tokens.next()? else {
                return Err(Error::at_line(
                    path,
                    tokens.line_no,
                    format!("the data ends at value {} of row {} of the header's {rows} rows of {cols}: truncated, or the header is wrong about the size", j + 1, i + 1),
                ));
            };
            let v = parse_number(token).ok_or_else(|| Error::at_line(path, line, format!("expected a height, found {token:?}")))?;
            *h = if Some(v) == nodata { f64::NAN } else { v };
        }
        Ok(())
    })?;
    if let Some((token, line)) = tokens.next()? {
        return Err(Error::at_line(
            path,
            line,
            format!("{token:?} follows the header's {rows} rows of {cols} values: the header is wrong about the size"),
        ));
    }
    Ok(raw)
}

/// What the header says.
struct Header {
    cols: usize,
    rows: usize,
    /// Lower-left corner of the grid, or centre of its lower-left cell when `center`.
    x: f64,
    y: f64,
    center: bool,
    /// Cell width and height.
    cell: (f64, f64),
    nodata: Option<f64>,
}

fn read_header<R: BufRead>(t: &mut Tokens<R>) -> Result<Header> {
    let path = t.path;
    let (mut cols, mut rows, mut x, mut y, mut cell, mut dx, mut dy, mut nodata) = (None, None, None, None, None, None, None, None);
    let mut center = (None, None);
    for _ in 0..MAX_HEADER_LINES {
        t.fill()?;
        let line = t.line.trim();
        let Some((key, value)) = line.split_once(char::is_whitespace) else {
            if line.is_empty() {
                t.line.clear();
                continue;
            }
            break;
        };
        if parse_number(key).is_some() {
            break;
        }
        let value = value.trim();
        let at = t.line_no;
        let number = || parse_number(value).ok_or_else(|| Error::at_line(path, at, format!("{key}: expected a number, found {value:?}")));
        let count = || {
            value
                .parse::<usize>()
                .ok()
                .filter(|&n| n > 0)
                .ok_or_else(|| Error::at_line(path, at, format!("{key}: expected a positive whole number, found {value:?}")))
        };
        match key.to_ascii_lowercase().as_str() {
            "ncols" => cols = Some(count()?),
            "nrows" => rows = Some(count()?),
            "xllcorner" => (x, center.0) = (Some(number()?), Some(false)),
            "xllcenter" => (x, center.0) = (Some(number()?), Some(true)),
            "yllcorner" => (y, center.1) = (Some(number()?), Some(false)),
            "yllcenter" => (y, center.1) = (Some(number()?), Some(true)),
            "cellsize" => cell = Some(number()?),
            "dx" => dx = Some(number()?),
            "dy" => dy = Some(number()?),
            "nodata_value" => nodata = Some(number()?),
            _ => return Err(Error::at_line(path, at, format!("unknown header key {key:?} of an ESRI ASCII grid"))),
        }
        t.line.clear();
    }
    let need = |v: Option<f64>, what: &str| v.ok_or_else(|| Error::invalid(path, None, format!("the header has no {what}")));
    let cols = cols.ok_or_else(|| Error::invalid(path, None, "the header has no ncols"))?;
    let rows = rows.ok_or_else(|| Error::invalid(path, None, "the header has no nrows"))?;
    let cell = match (cell, dx, dy) {
        (Some(c), _, _) => (c, c),
        (None, Some(dx), Some(dy)) => (dx, dy),
        _ => return Err(Error::invalid(path, None, "the header has no cellsize (nor dx and dy)")),
    };
    if !(cell.0 > 0.0 && cell.1 > 0.0 && cell.0.is_finite() && cell.1.is_finite()) {
        return Err(Error::invalid(path, None, format!("cell size {} × {} is not positive", cell.0, cell.1)));
    }
    let (x, y) = (need(x, "xllcorner or xllcenter")?, need(y, "yllcorner or yllcenter")?);
    if center.0 != center.1 {
        return Err(Error::invalid(path, None, "the header mixes a corner (xllcorner/yllcorner) with a centre (xllcenter/yllcenter)"));
    }
    Ok(Header { cols, rows, x, y, center: center.0 == Some(true), cell, nodata })
}

/// A number as grids write them; `nan` too (a void).
fn parse_number(s: &str) -> Option<f64> {
    let v = s.parse::<f64>().ok()?;
    (v.is_finite() || v.is_nan()).then_some(v)
}

/// Whitespace-separated tokens of a text file with their line numbers, one line in memory.
struct Tokens<'a, R> {
    reader: R,
    line: String,
    pos: usize,
    line_no: usize,
    path: &'a Path,
}

impl<R: BufRead> Tokens<'_, R> {
    /// Make sure a line is loaded (possibly empty at the end of the file).
    fn fill(&mut self) -> Result<()> {
        if self.line.is_empty() {
            self.pos = 0;
            let n = self.reader.read_line(&mut self.line).map_err(|e| match e.kind() {
                std::io::ErrorKind::InvalidData => Error::at_line(self.path, self.line_no + 1, "the line is not UTF-8 text"),
                _ => Error::io(self.path, e),
            })?;
            if n > 0 {
                self.line_no += 1;
            }
        }
        Ok(())
    }

    /// The next token and its line, or `None` at the end of the file.
    fn next(&mut self) -> Result<Option<(&str, usize)>> {
        loop {
            self.fill()?;
            if self.line.is_empty() {
                return Ok(None);
            }
            let rest = &self.line[self.pos..];
            let start = rest.len() - rest.trim_start().len();
            if start == rest.len() {
                self.line.clear();
                continue;
            }
            let len = rest[start..].find(char::is_whitespace).unwrap_or(rest.len() - start);
            let (a, b) = (self.pos + start, self.pos + start + len);
            self.pos = b;
            return Ok(Some((&self.line[a..b], self.line_no)));
        }
    }
}

/// What a `.prj` (WKT) beside the grid says.
struct Prj {
    geographic: bool,
    name: String,
    metres_per_unit: f64,
}

fn read_prj(path: &Path, warnings: &mut Vec<String>) -> Option<Prj> {
    let prj = path.with_extension("prj");
    let bytes = read_regular_file(&prj, 1 << 16).ok()?;
    let text = String::from_utf8_lossy(&bytes);
    let upper = text.to_ascii_uppercase();
    let kind = ["PROJCS[", "PROJCRS[", "GEOGCS[", "GEOGCRS["].into_iter().filter_map(|k| upper.find(k).map(|at| (at, k))).min()?;
    let name = text[kind.0 + kind.1.len()..].split('"').nth(1).unwrap_or("").to_string();
    let geographic = kind.1.starts_with("GEOG");
    let metres_per_unit = if geographic {
        1.0
    } else if upper.contains("US SURVEY FOOT") || upper.contains("FOOT_US") {
        1200.0 / 3937.0
    } else if upper.contains("UNIT[\"FOOT") {
        0.3048
    } else {
        1.0
    };
    warnings.push(format!("{}: {} {name:?}", prj.display(), if geographic { "geographic" } else { "projected" }));
    Some(Prj { geographic, name, metres_per_unit })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::GeoFrame;

    fn import(text: &str) -> Result<Raw> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.asc");
        std::fs::write(&p, text).unwrap();
        read(&p, &ImportOptions::default(), &mut Vec::new())
    }

    #[test]
    fn header_in_any_order_values_across_lines_and_nodata() {
        let raw = import("NROWS 3\nncols 2\ncellsize 10\nyllcorner 1000\nxllcorner 5000\nnodata_value -9999\n1 2 3\n4 -9999\n5\n").unwrap();
        assert_eq!(raw.mesh.positions.len(), 5);
        assert_eq!(raw.mesh.triangles.len(), 3, "the void takes one triangle of the lower cell");
        let g = raw.georef.unwrap();
        assert_eq!((g.frame, g.origin), (GeoFrame::Projected, [5010.0, 1015.0, 0.0]));
        assert_eq!(raw.mesh.positions[0], glam::Vec3::new(-5.0, 1.0, -10.0));
    }

    #[test]
    fn a_header_that_lies_about_the_size_is_refused_with_the_line() {
        let e = import("ncols 2\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 4\n").unwrap_err();
        assert!(e.to_string().contains("the data ends at value 1 of row 3"), "{e}");
        let e = import("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 4\n5 6\n").unwrap_err();
        assert_eq!(e.location(), Some(&crate::Location::Line(8)), "{e}");
        assert!(e.to_string().contains("the header is wrong about the size"), "{e}");
        let e = import("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 x\n3 4\n").unwrap_err();
        assert_eq!(e.to_string().split(": ").nth(1), Some("line 6"));
        let e = import("ncols 2\nnrows 2\nxllcorner 0\ncellsize 1\n1 2\n3 4\n").unwrap_err();
        assert!(e.to_string().contains("no yllcorner"), "{e}");
        let e = import("ncols 2\nnrows -2\n").unwrap_err();
        assert!(e.to_string().contains("positive whole number"), "{e}");
    }

    #[test]
    fn degrees_are_recognised_or_said() {
        let raw = import("ncols 2\nnrows 2\nxllcorner -105\nyllcorner 40\ncellsize 0.001\n1 2\n3 4\n").unwrap();
        assert_eq!(raw.georef.unwrap().frame, GeoFrame::LocalTangent);
    }
}
