//! Places on the WGS 84 ellipsoid as metres in a local frame, for elevation grids given in degrees.
//!
//! A grid in longitude and latitude is placed in the **local tangent plane** (east, north, up) at
//! an origin: each sample goes to Earth-centred coordinates (ECEF) on the ellipsoid and from there
//! into the frame. This is exact, not a map projection: distances and angles between samples are
//! the true ones in 3D, and the surface curves away from the origin's plane as the Earth does (by
//! d²/2R, about 200 m at 50 km). The only approximation is the height: grids give heights above
//! the geoid (SRTM: EGM96), taken here as heights above the ellipsoid, which moves the whole model
//! by the geoid undulation (tens of metres) along the vertical and tilts it by the geoid's slope
//! (a few metres over a 1° tile).

use glam::DVec3;

/// WGS 84 semi-major axis, metres.
pub const A: f64 = 6_378_137.0;
/// WGS 84 flattening.
pub const F: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared.
pub const E2: f64 = F * (2.0 - F);

/// What ECEF needs of a latitude: the prime-vertical radius N, sin φ and cos φ.
#[derive(Clone, Copy, Debug)]
pub struct Parallel {
    n: f64,
    sin: f64,
    cos: f64,
}

impl Parallel {
    pub fn new(lat_deg: f64) -> Parallel {
        let (sin, cos) = lat_deg.to_radians().sin_cos();
        Parallel { n: A / (1.0 - E2 * sin * sin).sqrt(), sin, cos }
    }
}

/// What ECEF needs of a longitude: sin λ and cos λ.
#[derive(Clone, Copy, Debug)]
pub struct Meridian {
    sin: f64,
    cos: f64,
}

impl Meridian {
    pub fn new(lon_deg: f64) -> Meridian {
        let (sin, cos) = lon_deg.to_radians().sin_cos();
        Meridian { sin, cos }
    }
}

/// Earth-centred, Earth-fixed coordinates of a point `h` metres above the ellipsoid.
pub fn ecef(lat: &Parallel, lon: &Meridian, h: f64) -> DVec3 {
    let r = (lat.n + h) * lat.cos;
    DVec3::new(r * lon.cos, r * lon.sin, (lat.n * (1.0 - E2) + h) * lat.sin)
}

/// The local tangent plane at a point of the ellipsoid: east, north and up unit vectors.
#[derive(Clone, Copy, Debug)]
pub struct LocalFrame {
    origin: DVec3,
    east: DVec3,
    north: DVec3,
    up: DVec3,
}

impl LocalFrame {
    /// The frame at longitude `lon_deg`, latitude `lat_deg`, `h` metres above the ellipsoid.
    pub fn new(lon_deg: f64, lat_deg: f64, h: f64) -> LocalFrame {
        let (lat, lon) = (Parallel::new(lat_deg), Meridian::new(lon_deg));
        LocalFrame {
            origin: ecef(&lat, &lon, h),
            east: DVec3::new(-lon.sin, lon.cos, 0.0),
            north: DVec3::new(-lat.sin * lon.cos, -lat.sin * lon.sin, lat.cos),
            up: DVec3::new(lat.cos * lon.cos, lat.cos * lon.sin, lat.sin),
        }
    }

    /// East, north, up of an ECEF point, in metres.
    pub fn enu(&self, p: DVec3) -> DVec3 {
        let d = p - self.origin;
        DVec3::new(d.dot(self.east), d.dot(self.north), d.dot(self.up))
    }
}

/// Longitude in degrees of `x` tiles from the left of the Web Mercator world at zoom `z`
/// (fractional: a pixel's centre is `x + (col + 0.5) / width`).
pub fn mercator_lon(x: f64, z: u32) -> f64 {
    x / f64::from(1u32 << z.min(31)) * 360.0 - 180.0
}

/// Latitude in degrees of `y` tiles down from the top of the Web Mercator world at zoom `z`.
pub fn mercator_lat(y: f64, z: u32) -> f64 {
    let t = std::f64::consts::PI * (1.0 - 2.0 * y / f64::from(1u32 << z.min(31)));
    t.sinh().atan().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ecef_matches_known_points() {
        let p = ecef(&Parallel::new(0.0), &Meridian::new(0.0), 0.0);
        assert!((p - DVec3::new(A, 0.0, 0.0)).length() < 1e-6);
        let pole = ecef(&Parallel::new(90.0), &Meridian::new(0.0), 0.0);
        // The polar radius b = a (1 − f).
        assert!((pole.z - A * (1.0 - F)).abs() < 1e-6 && pole.x.abs() < 1e-6);
    }

    #[test]
    fn local_frame_gives_true_distances_and_curvature() {
        let frame = LocalFrame::new(-105.5, 40.0, 0.0);
        let at = |lon: f64, lat: f64, h: f64| frame.enu(ecef(&Parallel::new(lat), &Meridian::new(lon), h));
        assert!(at(-105.5, 40.0, 0.0).length() < 1e-6);
        assert!((at(-105.5, 40.0, 1000.0) - DVec3::new(0.0, 0.0, 1000.0)).length() < 1e-6);
        // One minute of latitude at 40° N is 1850.6 m of meridian arc.
        let north = at(-105.5, 40.0 + 1.0 / 60.0, 0.0);
        assert!((north.y - 1850.6).abs() < 0.5 && north.x.abs() < 1e-6, "{north}");
        // 50 km east the ellipsoid has fallen about d²/2R below the plane.
        let east = at(-105.5 + 50_000.0 / (111_320.0 * 40f64.to_radians().cos()), 40.0, 0.0);
        assert!((east.x - 50_000.0).abs() < 150.0 && (-east.z - 196.0).abs() < 5.0, "{east}");
    }

    #[test]
    fn mercator_tiles_cover_the_world() {
        assert_eq!(mercator_lon(0.0, 0), -180.0);
        assert_eq!(mercator_lon(1.0, 0), 180.0);
        assert!((mercator_lat(0.0, 0) - 85.051_128_78).abs() < 1e-6);
        assert!(mercator_lat(1.0, 1).abs() < 1e-9);
    }
}
