//! `GEOR` (spec §5.2, format 2.1): where an elevation grid's model sits on Earth. Optional; a file
//! with it is written as version 2.1, and 2.0 readers skip it as an unknown chunk.

use super::chunk::{self, Fields, HEADER_BYTES};
use super::{id, MAX_TOOL_BYTES, MINOR};
use crate::error::Result;
use std::path::Path;

/// Bytes of the fixed part of the `GEOR` payload (the CRS string follows).
pub const GEOR_FIXED_BYTES: usize = 52;

/// How model coordinates map to the Earth. In every frame the model's axes are x east, y up and
/// z south (glTF's y-up, right-handed), in metres.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GeoFrame {
    /// An elevation grid whose place is unknown (no georeference in its source).
    Unplaced = 0,
    /// A local tangent plane on the WGS 84 ellipsoid: origin is (longitude°, latitude°,
    /// ellipsoidal height in metres) of model point (0, 0, 0); east, north, up = x, −z, y.
    LocalTangent = 1,
    /// A projected CRS: easting = origin.x + x / k, northing = origin.y − z / k, height = origin.z
    /// + y metres, where k is metres per CRS unit.
    Projected = 2,
}

/// The `GEOR` record.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Georef {
    pub frame: GeoFrame,
    pub origin: [f64; 3],
    /// Metres per horizontal CRS unit (frame [`GeoFrame::Projected`]); 1 otherwise.
    pub metres_per_crs_unit: f64,
    /// Heights were multiplied by this before placing (1 = true relief).
    pub z_scale: f64,
    /// The source's coordinate reference system as it named it (`EPSG:4326`, ...); may be empty.
    pub crs: String,
}

/// The `GEOR` chunk.
pub fn encode(g: &Georef) -> Vec<u8> {
    let mut p = Vec::with_capacity(GEOR_FIXED_BYTES + g.crs.len());
    p.extend_from_slice(&(g.frame as u32).to_le_bytes());
    p.extend_from_slice(&0u32.to_le_bytes());
    for x in g.origin.into_iter().chain([g.metres_per_crs_unit, g.z_scale]) {
        p.extend_from_slice(&x.to_le_bytes());
    }
    p.extend_from_slice(&(g.crs.len() as u32).to_le_bytes());
    p.extend_from_slice(g.crs.as_bytes());
    let mut out = Vec::with_capacity(p.len() + 32);
    chunk::put(&mut out, id::GEOR, 0, &p);
    out
}

/// Decode the `GEOR` payload of the chunk at `pos` in a file of version `major.minor`.
pub fn decode(path: &Path, major: u16, minor: u16, payload: &[u8], pos: u64) -> Result<Georef> {
    let mut f = Fields::new(path, &id::GEOR, pos, payload, pos + HEADER_BYTES);
    if payload.len() < GEOR_FIXED_BYTES {
        return Err(f.error(format!("{} bytes, fewer than the {GEOR_FIXED_BYTES} of its fixed fields", payload.len())));
    }
    let newer = minor > super::known_minor(major);
    let at = f.offset();
    let frame = match f.u32()? {
        0 => GeoFrame::Unplaced,
        1 => GeoFrame::LocalTangent,
        2 => GeoFrame::Projected,
        k if newer => return Err(f.error_at(at, format!("frame {k} is newer than this reader (format 2.{MINOR})"))),
        k => return Err(f.error_at(at, format!("unknown frame {k}"))),
    };
    let at = f.offset();
    if f.u32()? != 0 && !newer {
        return Err(f.error_at(at, "reserved field is not 0"));
    }
    let at = f.offset();
    let origin = [f.f64()?, f.f64()?, f.f64()?];
    if !origin.iter().all(|x| x.is_finite()) {
        return Err(f.error_at(at, format!("origin {origin:?} is not finite")));
    }
    if frame == GeoFrame::LocalTangent && !(origin[0].abs() <= 180.0 && origin[1].abs() <= 90.0) {
        return Err(f.error_at(at, format!("longitude {} or latitude {} out of range", origin[0], origin[1])));
    }
    let at = f.offset();
    let metres_per_crs_unit = f.f64()?;
    if !(metres_per_crs_unit.is_finite() && metres_per_crs_unit > 0.0) {
        return Err(f.error_at(at, format!("metres per CRS unit {metres_per_crs_unit}")));
    }
    let at = f.offset();
    let z_scale = f.f64()?;
    if !(z_scale.is_finite() && z_scale > 0.0) {
        return Err(f.error_at(at, format!("z scale {z_scale}")));
    }
    let at = f.offset();
    let len = f.u32()?;
    if len as u64 > MAX_TOOL_BYTES {
        return Err(f.error_at(at, format!("CRS string of {len} bytes exceeds {MAX_TOOL_BYTES}")));
    }
    let crs = f.string(len)?;
    if f.remaining() > 0 && !newer {
        return Err(f.error(format!("{} bytes after the CRS string", f.remaining())));
    }
    Ok(Georef { frame, origin, metres_per_crs_unit, z_scale, crs })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn payload(g: &Georef) -> Vec<u8> {
        let c = encode(g);
        let size = u64::from_le_bytes(c[8..16].try_into().unwrap()) as usize;
        c[16..16 + size].to_vec()
    }

    #[test]
    fn round_trips_and_refuses_what_the_spec_refuses() {
        let g = Georef {
            frame: GeoFrame::LocalTangent,
            origin: [-105.5, 40.15, 0.0],
            metres_per_crs_unit: 1.0,
            z_scale: 1.0,
            crs: "EPSG:4326".into(),
        };
        let p = payload(&g);
        assert_eq!(p.len(), GEOR_FIXED_BYTES + 9);
        assert_eq!(decode(Path::new("t"), 2, 1, &p, 0).unwrap(), g);
        let refuse = |p: &[u8], minor: u16, words: &str| {
            let e = decode(Path::new("t"), 2, minor, p, 0).unwrap_err().to_string();
            assert!(e.contains(words), "{e}");
        };
        let mut bad = p.clone();
        bad[0] = 7;
        refuse(&bad, 1, "unknown frame 7");
        refuse(&bad, MINOR + 1, "newer than this reader");
        let mut bad = p.clone();
        bad[8..16].copy_from_slice(&200f64.to_le_bytes());
        refuse(&bad, 1, "out of range");
        let mut bad = p.clone();
        bad[40..48].copy_from_slice(&0f64.to_le_bytes());
        refuse(&bad, 1, "z scale 0");
        let mut longer = p.clone();
        longer.push(0);
        refuse(&longer, 1, "1 bytes after the CRS string");
        assert_eq!(decode(Path::new("t"), 2, MINOR + 1, &longer, 0).unwrap(), g);
        refuse(&p[..GEOR_FIXED_BYTES - 1], 1, "fewer than");
        refuse(&p[..p.len() - 1], 1, "needs 9 more bytes");
    }
}
