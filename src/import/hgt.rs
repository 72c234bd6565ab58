//! SRTM `.hgt` tiles: n × n big-endian signed 16-bit heights in metres, no header, north row
//! first; n follows from the length (1201 for 3″ tiles, 3601 for 1″). The name says where the
//! tile is: `N40W074.hgt` has its south-west sample at 40° N, 74° W and spans one degree, samples
//! lying on the degree lines. −32768 marks a void. Read row by row.

use super::heightfield::{self, axis, Grid, Placement};
use super::{open_regular, ImportOptions, Raw};
use crate::error::{Error, Result};
use std::io::Read;
use std::path::Path;

/// A void.
const VOID: i16 = i16::MIN;

pub fn read(path: &Path, options: &ImportOptions, warnings: &mut Vec<String>) -> Result<Raw> {
    let (file, len) = open_regular(path)?;
    let n = (len / 2).isqrt();
    if len == 0 || len % 2 != 0 || n * n * 2 != len || n < 2 {
        return Err(Error::invalid(
            path,
            None,
            format!("{len} bytes is not a tile of n × n 16-bit heights (2·n² bytes: 2,884,802 for a 3″ tile, 25,934,402 for a 1″ tile): truncated or not a .hgt file"),
        ));
    }
    let n = n as usize;
    let placement = match corner(path) {
        Some((lon, lat)) => {
            let step = 1.0 / (n - 1) as f64;
            Placement::Geographic { lon: axis(lon, step, n), lat: axis(lat + 1.0, -step, n), crs: "EPSG:4326 (SRTM, EGM96 heights)".into() }
        }
        None => {
            let cell = options.dem.cell_size.unwrap_or(1.0);
            warnings.push(format!(
                "the name does not say where the tile is (as N40W074.hgt does): placed nowhere, samples {cell} m apart (--dem-cell-size)"
            ));
            Placement::Unplaced { cell }
        }
    };
    let grid = Grid { cols: n, rows: n, placement, metres_per_height_unit: 1.0, z_scale: options.dem.z_scale };
    let mut reader = std::io::BufReader::with_capacity(1 << 16, file);
    let mut bytes = vec![0u8; 2 * n];
    heightfield::triangulate(path, &grid, warnings, |i, row| {
        reader.read_exact(&mut bytes).map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => Error::at_byte(path, (2 * n * i) as u64, "the file ended early (changed while read?)"),
            _ => Error::io(path, e),
        })?;
        for (h, b) in row.iter_mut().zip(bytes.chunks_exact(2)) {
            let v = i16::from_be_bytes([b[0], b[1]]);
            *h = if v == VOID { f64::NAN } else { f64::from(v) };
        }
        Ok(())
    })
}

/// Longitude and latitude of the south-west sample from the first part of the file name like
/// `N40W074` or `s01e120` (`N40W074.hgt`, `srtm_N40W074.hgt`, `N40W074.SRTMGL3.hgt`).
fn corner(path: &Path) -> Option<(f64, f64)> {
    let name = path.file_name()?.to_str()?.to_ascii_uppercase();
    let b = name.as_bytes();
    let digits = |s: &[u8]| s.iter().all(u8::is_ascii_digit).then(|| s.iter().fold(0.0, |v, &d| 10.0 * v + f64::from(d - b'0')));
    b.windows(7).find_map(|w| {
        let lat = match w[0] {
            b'N' => digits(&w[1..3])?,
            b'S' => -digits(&w[1..3])?,
            _ => return None,
        };
        let lon = match w[3] {
            b'E' => digits(&w[4..7])?,
            b'W' => -digits(&w[4..7])?,
            _ => return None,
        };
        (lat.abs() < 90.0 && lon.abs() < 180.0).then_some((lon, lat))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_name_places_the_tile() {
        assert_eq!(corner(Path::new("N40W074.hgt")), Some((-74.0, 40.0)));
        assert_eq!(corner(Path::new("/x/s01e120.hgt")), Some((120.0, -1.0)));
        assert_eq!(corner(Path::new("tile.hgt")), None);
        assert_eq!(corner(Path::new("N95W074.hgt")), None);
        assert_eq!(corner(Path::new("riptide_N40W074.hgt")), Some((-74.0, 40.0)));
    }

    #[test]
    fn reads_a_small_tile_and_refuses_a_cut_one() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("N10E020.hgt");
        let values: [i16; 9] = [1, 2, 3, 4, VOID, 6, 7, 8, 9];
        std::fs::write(&p, values.iter().flat_map(|v| v.to_be_bytes()).collect::<Vec<u8>>()).unwrap();
        let raw = read(&p, &ImportOptions::default(), &mut Vec::new()).unwrap();
        assert_eq!(raw.mesh.positions.len(), 8);
        assert_eq!(raw.georef.unwrap().origin, [20.5, 10.5, 0.0]);
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..17]).unwrap();
        let e = read(&p, &ImportOptions::default(), &mut Vec::new()).unwrap_err().to_string();
        assert!(e.contains("17 bytes is not a tile"), "{e}");
    }
}
