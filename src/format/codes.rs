//! The quantized codes of the format (spec §5.1, §7.2): the position grid, packed grid points,
//! cone half-angles and radii as u16 codes, and the writer's rules for rounding bounds outward.

use super::{octa, Cone};
use glam::{DVec3, Vec3};

/// Largest number of grid bits per axis: three coordinates pack into the low 63 bits of a u64.
pub const MAX_GRID_BITS: u32 = 21;
/// Grid bits the writer uses: a millionth of the model's extent, and most nodes' offsets fit u16.
pub const GRID_BITS: u32 = 20;

/// The global position grid (spec §5.1): grid point `g` is at `origin + g·step` per axis,
/// `0 ≤ g < 2^bits`, computed in f64 and rounded to f32 once, so that a grid point decodes to the
/// same f32 everywhere.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Grid {
    pub origin: [f64; 3],
    pub step: f64,
    pub bits: u32,
}

impl Grid {
    /// The writer's grid for a model with bounds `min..max`: origin `min`, step the smallest power
    /// of two that spans the largest extent with `2^bits − 1` steps (1 for a flat point).
    pub fn fit(min: Vec3, max: Vec3, bits: u32) -> Grid {
        let extent = (max - min).as_dvec3().max_element();
        let cells = ((1u64 << bits) - 1) as f64;
        let mut step = 1.0f64;
        if extent > 0.0 {
            while extent / step > cells {
                step *= 2.0;
            }
            while extent / (step / 2.0) <= cells {
                step /= 2.0;
            }
        }
        Grid { origin: min.as_dvec3().to_array(), step, bits }
    }

    /// Largest grid coordinate.
    pub fn last(&self) -> u32 {
        ((1u64 << self.bits) - 1) as u32
    }

    /// The grid point nearest `p`, clamped to the grid.
    pub fn encode(&self, p: Vec3) -> [u32; 3] {
        let g = ((p.as_dvec3() - DVec3::from(self.origin)) / self.step).round();
        g.to_array().map(|x| x.clamp(0.0, self.last() as f64) as u32)
    }

    /// Grid coordinates of the cell corner at or below (`up` false) or at or above (`up` true) `p`.
    pub fn bound(&self, p: Vec3, up: bool) -> [u32; 3] {
        let g = (p.as_dvec3() - DVec3::from(self.origin)) / self.step;
        let g = if up { g.ceil() } else { g.floor() };
        g.to_array().map(|x| x.clamp(0.0, self.last() as f64) as u32)
    }

    /// The position of grid point `g`.
    pub fn decode(&self, g: [u32; 3]) -> Vec3 {
        (DVec3::from(self.origin) + DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64) * self.step).as_vec3()
    }

    /// A length of `steps` grid steps, in model units.
    pub fn length(&self, steps: f64) -> f32 {
        (steps * self.step) as f32
    }

    /// The distance bound between a position and its grid point that every node's geometric error
    /// includes: half a step per axis, √3/2 steps in all.
    pub fn error(&self) -> f32 {
        (self.step * 3f64.sqrt() / 2.0) as f32
    }
}

/// Three grid coordinates in one u64: x in bits 0..21, y in 21..42, z in 42..63.
pub fn pack(g: [u32; 3]) -> u64 {
    g[0] as u64 | (g[1] as u64) << 21 | (g[2] as u64) << 42
}

/// The inverse of [`pack`]; `None` when bit 63 is set.
pub fn unpack(v: u64) -> Option<[u32; 3]> {
    let m = (1u64 << 21) - 1;
    (v >> 63 == 0).then_some([(v & m) as u32, (v >> 21 & m) as u32, (v >> 42 & m) as u32])
}

/// A cone half-angle as a u16: `k·π/65535`, rounded up from `angle` radians (π and above: 65535).
pub fn angle_code(angle: f64) -> u16 {
    let mut k = (angle / std::f64::consts::PI * 65535.0).ceil().clamp(0.0, 65535.0) as u16;
    while k < u16::MAX && (angle_decode(k) as f64) < angle {
        k += 1;
    }
    k
}

/// The half-angle, in radians, of code `k`.
pub fn angle_decode(k: u16) -> f32 {
    (k as f64 * std::f64::consts::PI / 65535.0) as f32
}

/// A radius in grid steps as a u16 float, rounded up: mantissa `k & 0x7FF`, exponent `k >> 11`,
/// value `mantissa · 2^exponent` steps.
pub fn radius_code(steps: f64) -> u16 {
    let mut e = 0u32;
    while e < 31 && (steps / (1u64 << e) as f64).ceil() > 2047.0 {
        e += 1;
    }
    let m = (steps / (1u64 << e) as f64).ceil().clamp(0.0, 2047.0) as u16;
    m | (e as u16) << 11
}

/// The radius in grid steps of code `k`.
pub fn radius_decode(k: u16) -> f64 {
    ((k & 0x7FF) as u64) as f64 * (1u64 << (k >> 11)) as f64
}

/// Angle between two directions, in f64.
pub fn angle(a: Vec3, b: Vec3) -> f64 {
    let (a, b) = (a.as_dvec3(), b.as_dvec3());
    a.cross(b).length().atan2(a.dot(b))
}

/// The stored cone for a cone around `axis` that must reach `need(decoded axis)` radians: the axis
/// quantized, the angle rounded up (spec §11).
pub fn store_cone(axis: Vec3, need: impl Fn(Vec3) -> f64) -> ([i16; 2], u16, Cone) {
    let code = octa::encode(axis);
    let decoded = octa::decode(code);
    let k = angle_code(need(decoded));
    (code, k, Cone { axis: decoded, half_angle: angle_decode(k) })
}

/// The radius code covering `needed` model units, with the writer's margin of 10⁻⁶, and its
/// decoded radius (spec §11).
pub fn store_radius(grid: &Grid, needed: f64) -> (u16, f32) {
    let k = radius_code(needed / grid.step * (1.0 + 1e-6));
    (k, grid.length(radius_decode(k)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::GRID_BITS;

    #[test]
    fn codes_round_up_and_stay_close() {
        for i in 0..=2000 {
            let a = i as f64 * std::f64::consts::PI / 2000.0;
            let k = angle_code(a);
            assert!(angle_decode(k) as f64 >= a || k == u16::MAX, "angle {a} coded as {k}");
            assert!((angle_decode(k) as f64) < a + 1e-4, "angle {a} widened to {}", angle_decode(k));
        }
        assert_eq!(angle_code(10.0), u16::MAX);
        for steps in [0.0, 0.5, 1.0, 2047.0, 2047.5, 2048.0, 123_456.7, 3e6, 1e12] {
            let r = radius_decode(radius_code(steps));
            assert!(r >= steps && r <= steps * (1.0 + 1.0 / 1024.0) + 1.0, "{steps} steps coded as {r}");
        }
    }

    #[test]
    fn grid_points_pack_and_decode_within_half_a_step() {
        let g = [(1 << 21) - 1, 12345, 0];
        assert_eq!(unpack(pack(g)), Some(g));
        assert_eq!(unpack(1 << 63), None);
        let (min, max) = (Vec3::new(-3.0, 1000.0, 0.25), Vec3::new(5.0, 1001.0, 0.5));
        let grid = Grid::fit(min, max, GRID_BITS);
        assert!(8.0 / grid.step <= grid.last() as f64 && 8.0 / (grid.step / 2.0) > grid.last() as f64);
        for k in 0..1000 {
            let t = k as f32 / 999.0;
            let p = min + (max - min) * Vec3::new(t, t * t, 1.0 - t);
            let q = grid.decode(grid.encode(p));
            for a in 0..3 {
                let ulp = (p[a].abs().max(q[a].abs()) * f32::EPSILON) as f64;
                assert!(((q[a] - p[a]) as f64).abs() <= grid.step / 2.0 + ulp / 2.0, "{p} → {q}");
            }
            assert!(grid.decode(grid.bound(p, false)).cmple(p).all() && p.cmple(grid.decode(grid.bound(p, true))).all());
        }
    }
}
