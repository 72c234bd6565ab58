//! Elevation grid to triangle mesh, shared by the DEM readers ([`super::asc`], [`super::geotiff`],
//! [`super::hgt`], [`super::heightmap_png`]).
//!
//! A reader says where the grid's samples lie ([`Placement`]) and hands over its heights one row
//! at a time, north to south as files store them; [`triangulate`] turns each row into vertices at
//! once and joins it to the row before, so a grid is never held twice: what stays in memory is the
//! mesh being built and two rows.
//!
//! - Two triangles per cell, split along the diagonal whose ends differ less in height: a ridge or
//!   valley running diagonally through a cell stays a ridge or valley instead of being cut across.
//! - A void (no data: NaN from the reader) has no vertex. A cell with one void corner keeps the
//!   triangle of its other three; cells with more have none: voids are holes, never spikes.
//! - Model axes are x east, y up, z south, in metres, as glTF has them. Grids in degrees go to the
//!   local tangent plane at their centre ([`crate::geodesy`]); projected grids are offset to their
//!   centre; grids that say nothing of their place are laid out on cells of a given size. Where the
//!   model sits is the [`Georef`] the chunk file keeps (spec §5.2).

use super::Raw;
use crate::error::{Error, Result};
use crate::format::{GeoFrame, Georef};
use crate::geodesy::{self, LocalFrame, Meridian, Parallel};
use crate::mesh::{Material, Mesh};
use glam::{DVec3, Vec3};
use std::path::Path;

/// Where a grid's sample centres are: a coordinate per column and one per row.
#[derive(Clone, Debug, PartialEq)]
pub enum Placement {
    /// Degrees on WGS 84: longitude per column, latitude per row.
    Geographic { lon: Vec<f64>, lat: Vec<f64>, crs: String },
    /// A projected CRS: easting per column, northing per row, in CRS units of `metres_per_unit`.
    Projected { x: Vec<f64>, y: Vec<f64>, metres_per_unit: f64, crs: String },
    /// Nowhere known: samples `cell` metres apart, row 0 the northernmost.
    Unplaced { cell: f64 },
}

/// A grid of `cols` × `rows` heights.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    pub cols: usize,
    pub rows: usize,
    pub placement: Placement,
    /// Metres per unit of the heights the reader gives.
    pub metres_per_height_unit: f64,
    /// Exaggeration applied on top (1 = true relief).
    pub z_scale: f64,
}

/// What an elevation grid held, as read: its size, voids and height range (metres, before
/// `z_scale`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GridSummary {
    pub cols: usize,
    pub rows: usize,
    /// Samples without data.
    pub voids: u64,
    pub min_height: f64,
    pub max_height: f64,
}

/// How a DEM is read, beyond what its file says.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DemOptions {
    /// How a PNG stores heights; `None`: 16-bit greyscale values.
    pub encoding: Option<DemEncoding>,
    /// Whether the grid's coordinates are degrees, when the file does not say.
    pub crs: DemCrs,
    /// Multiplies heights (vertical exaggeration).
    pub z_scale: f64,
    /// Metres between samples of a grid that says nothing of its place.
    pub cell_size: Option<f64>,
    /// A PNG that is the Web Mercator tile `[z, x, y]`.
    pub tile: Option<[u32; 3]>,
}

impl Default for DemOptions {
    fn default() -> Self {
        DemOptions { encoding: None, crs: DemCrs::Auto, z_scale: 1.0, cell_size: None, tile: None }
    }
}

/// How a PNG encodes heights in its colours.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DemEncoding {
    /// 16-bit greyscale: the value, times the sidecar's scale plus its offset.
    Grey16,
    /// Mapbox Terrain-RGB: h = −10000 + (R·65536 + G·256 + B) · 0.1 metres.
    TerrainRgb,
    /// Mapzen Terrarium: h = R·256 + G + B/256 − 32768 metres.
    Terrarium,
}

/// What a grid's horizontal coordinates are when its file does not say.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DemCrs {
    /// Degrees when they fit longitude and latitude with cells under 0.1, else projected; said in
    /// a warning.
    #[default]
    Auto,
    /// Longitude and latitude on WGS 84.
    Degrees,
    /// Linear units of a projected CRS (metres unless the file says).
    Projected,
}

/// Whether a grid's corner coordinates `x0..x1`, `y0..y1` with cells of `cell` units are degrees
/// (given `crs`), with a warning when that was guessed.
pub fn is_geographic(crs: DemCrs, x: [f64; 2], y: [f64; 2], cell: f64, warnings: &mut Vec<String>) -> bool {
    match crs {
        DemCrs::Degrees => true,
        DemCrs::Projected => false,
        DemCrs::Auto => {
            let fits = x.iter().all(|v| v.abs() <= 180.0) && y.iter().all(|v| v.abs() <= 90.0) && cell.abs() < 0.1;
            let what = if fits { "longitude and latitude in degrees" } else { "metres of a projected CRS" };
            warnings.push(format!(
                "the file does not say what its coordinates are; read as {what} (x {:.6}..{:.6}, y {:.6}..{:.6}, cell {cell}); --dem-crs says otherwise",
                x[0], x[1], y[0], y[1]
            ));
            fits
        }
    }
}

/// Most decoded bytes per stored byte that a reader expects of compressed data (deflate's limit
/// is 1032:1): a file whose header claims more samples than that is refused before anything is
/// allocated for them.
pub const MAX_EXPANSION: u64 = 1100;

/// Refuse a grid of `cols` × `rows` samples of `bytes_per_sample` that `stored` bytes cannot hold
/// when each stored byte decodes to at most `expansion` bytes ([`MAX_EXPANSION`] for compressed
/// data, 1 for text).
pub fn check_claim(path: &Path, cols: usize, rows: usize, bytes_per_sample: u64, stored: u64, expansion: u64) -> Result<()> {
    let claimed = (cols as u64).saturating_mul(rows as u64).saturating_mul(bytes_per_sample);
    if claimed > stored.saturating_mul(expansion) {
        return Err(Error::invalid(
            path,
            None,
            format!("the header claims {cols} × {rows} samples, more than the file's {stored} bytes of data can hold: it lies about the size or the file is cut"),
        ));
    }
    Ok(())
}

/// Sample centres along an axis: `first`, `first + step`, ...
pub fn axis(first: f64, step: f64, n: usize) -> Vec<f64> {
    (0..n).map(|k| first + step * k as f64).collect()
}

/// Marks a void sample in a row.
const NONE: u32 = u32::MAX;

/// Build the mesh of `grid`, whose row `i` (0 = north) `read_row(i, heights)` fills with heights
/// in the grid's units, NaN where there is no data. Rows are asked for in order, each once.
pub fn triangulate(
    path: &Path,
    grid: &Grid,
    warnings: &mut Vec<String>,
    mut read_row: impl FnMut(usize, &mut [f64]) -> Result<()>,
) -> Result<Raw> {
    let (cols, rows) = (grid.cols, grid.rows);
    if cols < 2 || rows < 2 {
        return Err(Error::invalid(path, None, format!("a {cols} × {rows} grid has no cells: at least 2 × 2 samples are needed")));
    }
    if (cols as u64) * (rows as u64) >= u64::from(NONE) {
        return Err(Error::invalid(path, None, format!("a {cols} × {rows} grid has more samples than strata's 2^32 − 1 vertices")));
    }
    let vertical = grid.metres_per_height_unit * grid.z_scale;
    let (place, georef, flip) = place(grid);

    let mut mesh = Mesh { materials: vec![Material { name: "terrain".into(), ..Material::default() }], ..Mesh::default() };
    // Reserved up to a bound: the rows, not the header, prove how large the grid is.
    mesh.positions.reserve((cols * rows).min(1 << 20));
    mesh.triangles.reserve((2 * (cols - 1) * (rows - 1)).min(2 << 20));
    // The last four rows read: heights (scaled, NaN = void) and vertex ids; row k in slot k % 4.
    let mut h = [(); 4].map(|_| vec![f64::NAN; cols]);
    let mut ids = [(); 4].map(|_| vec![NONE; cols]);
    let (mut voids, mut lo, mut hi) = (0u64, f64::INFINITY, f64::NEG_INFINITY);
    for k in 0..rows {
        let (hk, ik) = (&mut h[k % 4], &mut ids[k % 4]);
        hk.fill(f64::NAN);
        read_row(k, hk)?;
        for j in 0..cols {
            if hk[j].is_finite() {
                (lo, hi) = (lo.min(hk[j]), hi.max(hk[j]));
            }
            hk[j] *= vertical;
            if hk[j].is_finite() {
                ik[j] = mesh.positions.len() as u32;
                mesh.positions.push(place(k, j, hk[j]));
            } else {
                hk[j] = f64::NAN;
                ik[j] = NONE;
                voids += 1;
            }
        }
        // The cells between rows k − 2 and k − 1 now have a row on each side to look at.
        if k >= 2 {
            join(&mut mesh.triangles, &ids, &h, k - 2, k >= 3, true, flip);
        }
    }
    join(&mut mesh.triangles, &ids, &h, rows - 2, rows >= 3, false, flip);
    mesh.face_materials = vec![0; mesh.triangles.len()];
    if voids > 0 {
        let total = cols as u64 * rows as u64;
        warnings.push(format!("{voids} of {total} samples ({:.2}%) have no data: left as holes", 100.0 * voids as f64 / total as f64));
    }
    if mesh.triangles.is_empty() {
        return Err(Error::invalid(path, None, "no cell has three samples with data: the grid is all voids"));
    }
    let unit = grid.metres_per_height_unit;
    let summary = GridSummary { cols, rows, voids, min_height: lo * unit, max_height: hi * unit };
    Ok(Raw { mesh, metres_per_unit: Some(1.0), georef: Some(georef), grid: Some(summary) })
}

/// Triangles of the cells between rows `r` (north) and `r + 1` of the ring `ids`/`h` (row k in
/// slot k % 4), with rows `r − 1` and `r + 2` there when `before` and `after` say so.
fn join(out: &mut Vec<[u32; 3]>, ids: &[Vec<u32>; 4], h: &[Vec<f64>; 4], r: usize, before: bool, after: bool, flip: bool) {
    let (a, b) = (&ids[r % 4], &ids[(r + 1) % 4]);
    let (ha, hb) = (&h[r % 4], &h[(r + 1) % 4]);
    let (h0, h3) = (before.then(|| &h[(r + 3) % 4]), after.then(|| &h[(r + 2) % 4]));
    let mut push = |t: [u32; 3]| out.push(if flip { [t[0], t[2], t[1]] } else { t });
    for j in 0..a.len() - 1 {
        // nw ne / sw se; (nw, sw, ne) winds counter-clockwise seen from above.
        let (nw, ne, sw, se) = (a[j], a[j + 1], b[j], b[j + 1]);
        match [nw, ne, sw, se].iter().filter(|&&v| v == NONE).count() {
            0 => {
                if split_nw_se([ha[j], ha[j + 1], hb[j], hb[j + 1]], h0, h3, j) {
                    push([nw, sw, se]);
                    push([nw, se, ne]);
                } else {
                    push([nw, sw, ne]);
                    push([ne, sw, se]);
                }
            }
            1 if nw == NONE => push([ne, sw, se]),
            1 if ne == NONE => push([nw, sw, se]),
            1 if sw == NONE => push([nw, se, ne]),
            1 => push([nw, sw, ne]),
            _ => {}
        }
    }
}

/// Whether the cell with corner heights `[nw, ne, sw, se]` at column `j` splits along nw–se: the
/// diagonal whose midpoint lies closer to the surface at the cell's centre, estimated by cubic
/// (Catmull–Rom) interpolation along both diagonals through the samples beyond the corners (rows
/// `north` and `south`). A ridge or valley crossing the cell diagonally is kept whichever it is,
/// which the four corners alone cannot tell. Without those samples (edges, voids) the diagonal
/// whose ends differ less in height.
fn split_nw_se(c: [f64; 4], north: Option<&Vec<f64>>, south: Option<&Vec<f64>>, j: usize) -> bool {
    let [nw, ne, sw, se] = c;
    let sample = |row: Option<&Vec<f64>>, col: Option<usize>| row.zip(col).and_then(|(r, c)| r.get(c).copied()).filter(|v| v.is_finite());
    let cubic = |p0: Option<f64>, p1: f64, p2: f64, p3: Option<f64>| Some((9.0 * (p1 + p2) - p0? - p3?) / 16.0);
    let along = cubic(sample(north, j.checked_sub(1)), nw, se, sample(south, Some(j + 2)));
    let across = cubic(sample(north, Some(j + 2)), ne, sw, sample(south, j.checked_sub(1)));
    match along.zip(across) {
        Some((p, q)) => {
            let centre = 0.5 * (p + q);
            (0.5 * (nw + se) - centre).abs() <= (0.5 * (ne + sw) - centre).abs()
        }
        None => (nw - se).abs() <= (ne - sw).abs(),
    }
}

type Place = Box<dyn Fn(usize, usize, f64) -> Vec3>;

/// The model position of sample (row, column) at height `h` metres, the georeference, and
/// whether the grid's rows and columns wind the other way (row 0 south, or columns running west).
fn place(grid: &Grid) -> (Place, Georef, bool) {
    let model = |enu: DVec3| Vec3::new(enu.x as f32, enu.z as f32, -enu.y as f32);
    let mid = |v: &[f64]| 0.5 * (v[0] + v[v.len() - 1]);
    let increasing = |v: &[f64]| v[v.len() - 1] >= v[0];
    let georef = |frame, origin, metres_per_crs_unit, crs: &str| Georef {
        frame,
        origin,
        metres_per_crs_unit,
        z_scale: grid.z_scale,
        crs: crs.chars().take(256).collect(),
    };
    match &grid.placement {
        Placement::Geographic { lon, lat, crs } => {
            let (lon0, lat0) = (mid(lon), mid(lat));
            let frame = LocalFrame::new(lon0, lat0, 0.0);
            let (parallels, meridians): (Vec<Parallel>, Vec<Meridian>) =
                (lat.iter().map(|&l| Parallel::new(l)).collect(), lon.iter().map(|&l| Meridian::new(l)).collect());
            let flip = increasing(lon) == increasing(lat);
            let f = move |i: usize, j: usize, h: f64| model(frame.enu(geodesy::ecef(&parallels[i], &meridians[j], h)));
            (Box::new(f), georef(GeoFrame::LocalTangent, [lon0, lat0, 0.0], 1.0, crs), flip)
        }
        Placement::Projected { x, y, metres_per_unit, crs } => {
            let (x0, y0, k) = (mid(x), mid(y), *metres_per_unit);
            let flip = increasing(x) == increasing(y);
            let (x, y) = (x.clone(), y.clone());
            let f = move |i: usize, j: usize, h: f64| model(DVec3::new((x[j] - x0) * k, (y[i] - y0) * k, h));
            (Box::new(f), georef(GeoFrame::Projected, [x0, y0, 0.0], k, crs), flip)
        }
        Placement::Unplaced { cell } => {
            let (cell, cx, cy) = (*cell, 0.5 * (grid.cols - 1) as f64, 0.5 * (grid.rows - 1) as f64);
            let f = move |i: usize, j: usize, h: f64| model(DVec3::new((j as f64 - cx) * cell, (cy - i as f64) * cell, h));
            (Box::new(f), georef(GeoFrame::Unplaced, [0.0; 3], 1.0, ""), false)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(cols: usize, rows: usize, placement: Placement) -> Grid {
        Grid { cols, rows, placement, metres_per_height_unit: 1.0, z_scale: 1.0 }
    }

    fn run(g: &Grid, heights: &[f64]) -> Raw {
        let mut w = Vec::new();
        triangulate(Path::new("t"), g, &mut w, |i, row| {
            row.copy_from_slice(&heights[i * g.cols..(i + 1) * g.cols]);
            Ok(())
        })
        .unwrap()
    }

    fn faces_up(m: &Mesh) -> bool {
        m.triangles.iter().all(|t| {
            let [a, b, c] = t.map(|v| m.positions[v as usize]);
            (b - a).cross(c - a).y > 0.0
        })
    }

    #[test]
    fn cells_become_two_upward_triangles_split_along_ridges_and_valleys() {
        let g = grid(2, 2, Placement::Unplaced { cell: 10.0 });
        let raw = run(&g, &[5.0, 0.0, 1.0, 5.0]);
        assert_eq!(raw.mesh.triangles, vec![[0, 2, 3], [0, 3, 1]], "the diagonal whose ends differ less");
        assert!(faces_up(&raw.mesh));
        assert_eq!(raw.mesh.positions[0], Vec3::new(-5.0, 5.0, -5.0), "north-west is -x, -z");
        assert_eq!(run(&g, &[0.0, 5.0, 5.0, 1.0]).mesh.triangles, vec![[0, 2, 1], [1, 2, 3]]);
        assert_eq!(raw.georef.unwrap().frame, GeoFrame::Unplaced);
        // The middle cell of a ridge and of a valley along the main diagonal: same corner
        // differences, and in both the split follows the line.
        let g = grid(4, 4, Placement::Unplaced { cell: 1.0 });
        let ridge: Vec<f64> = (0..16usize).map(|k| 10.0 - 5.0 * (k / 4).abs_diff(k % 4) as f64).collect();
        let valley: Vec<f64> = (0..16usize).map(|k| 5.0 * (k / 4).abs_diff(k % 4) as f64).collect();
        for heights in [ridge, valley] {
            let m = run(&g, &heights).mesh;
            assert!(faces_up(&m));
            let (nw, se) = (5, 10);
            assert!(m.triangles.iter().any(|t| t.contains(&nw) && t.contains(&se)), "{heights:?}");
        }
    }

    #[test]
    fn voids_are_holes_and_grids_stored_south_up_still_face_up() {
        let n = f64::NAN;
        let g = grid(
            3,
            3,
            Placement::Projected { x: axis(500.0, 30.0, 3), y: axis(100.0, -30.0, 3), metres_per_unit: 1.0, crs: String::new() },
        );
        let raw = run(&g, &[1.0, 2.0, 3.0, 4.0, n, 6.0, 7.0, 8.0, 9.0]);
        assert_eq!(raw.mesh.positions.len(), 8);
        assert_eq!(raw.mesh.triangles.len(), 4, "each cell keeps the triangle away from the void");
        let gr = raw.georef.unwrap();
        assert_eq!((gr.frame, gr.origin), (GeoFrame::Projected, [530.0, 70.0, 0.0]));
        assert_eq!(raw.mesh.positions[0], Vec3::new(-30.0, 1.0, -30.0));
        assert!(faces_up(&raw.mesh));
        // The same grid with row 0 in the south.
        let g =
            grid(3, 3, Placement::Projected { x: axis(500.0, 30.0, 3), y: axis(40.0, 30.0, 3), metres_per_unit: 1.0, crs: String::new() });
        assert!(faces_up(&run(&g, &[7.0, 8.0, 9.0, 4.0, n, 6.0, 1.0, 2.0, 3.0]).mesh));
    }

    #[test]
    fn degrees_go_to_the_local_tangent_plane() {
        let g = grid(3, 3, Placement::Geographic { lon: axis(-106.0, 0.5, 3), lat: axis(41.0, -0.5, 3), crs: "EPSG:4326".into() });
        let raw = run(&g, &[0.0; 9]);
        let gr = raw.georef.unwrap();
        assert_eq!((gr.frame, gr.origin), (GeoFrame::LocalTangent, [-105.5, 40.5, 0.0]));
        let p = raw.mesh.positions;
        assert!(p[4].length() < 1e-3, "the centre is the origin");
        // Half a degree of latitude is about 55.5 km; the plane's edge lies below the curved Earth's.
        assert!((p[1].z + 55_510.0).abs() < 100.0 && p[1].y < -200.0, "{}", p[1]);
        assert!(raw.mesh.triangles.len() == 8);
    }

    #[test]
    fn refuses_grids_without_cells_or_data() {
        let g = grid(1, 5, Placement::Unplaced { cell: 1.0 });
        let e = triangulate(Path::new("t"), &g, &mut Vec::new(), |_, _| Ok(())).unwrap_err().to_string();
        assert!(e.contains("no cells"), "{e}");
        let g = grid(2, 2, Placement::Unplaced { cell: 1.0 });
        let e = triangulate(Path::new("t"), &g, &mut Vec::new(), |_, _| Ok(())).unwrap_err().to_string();
        assert!(e.contains("all voids"), "{e}");
    }
}
