//! Unit normals in 4 bytes: the octahedral map (Meyer et al. 2010; Cigolle et al. 2014) projects
//! the sphere onto the octahedron |x|+|y|+|z| = 1 and unfolds it onto the square [-1, 1]², stored as
//! two i16 in steps of 1/32767. Encoding picks, of the four neighbouring grid points, the one whose
//! decoded normal is closest, which bounds the angular error by [`MAX_ERROR`].

use glam::{Vec2, Vec3};

/// Bits per coordinate of full-precision codes (format 2's, and [`encode`]'s).
pub const BITS: u32 = 16;
/// Grid steps per unit of the unfolded square at [`BITS`].
pub const SCALE: f32 = 32767.0;
/// Largest angle, in radians, between a unit normal and its decoded code (checked in the tests).
pub const MAX_ERROR: f32 = 5e-5;

fn sign(v: f32) -> f32 {
    if v >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

/// The octahedral square coordinates of a direction; zero or non-finite vectors map to +Z.
fn unfold(n: Vec3) -> Vec2 {
    let l1 = n.x.abs() + n.y.abs() + n.z.abs();
    if l1.is_nan() || l1 <= 0.0 || l1.is_infinite() {
        return Vec2::ZERO;
    }
    let p = Vec2::new(n.x, n.y) / l1;
    if n.z < 0.0 {
        Vec2::new((1.0 - p.y.abs()) * sign(p.x), (1.0 - p.x.abs()) * sign(p.y))
    } else {
        p
    }
}

/// Decode a stored pair into a unit normal.
pub fn decode(q: [i16; 2]) -> Vec3 {
    decode_at([q[0] as i32, q[1] as i32], SCALE)
}

/// Steps per unit of the unfolded square for `bits` (2..=16) per coordinate: `2^(bits−1) − 1`
/// ([`SCALE`] at 16).
pub fn scale(bits: u32) -> i32 {
    (1 << (bits - 1)) - 1
}

/// Decode a pair at `scale` steps per unit of the unfolded square (format 3: `2^(bits−1) − 1`).
pub fn decode_at(q: [i32; 2], scale: f32) -> Vec3 {
    let x = (q[0] as f32 / scale).clamp(-1.0, 1.0);
    let y = (q[1] as f32 / scale).clamp(-1.0, 1.0);
    let z = 1.0 - x.abs() - y.abs();
    let (x, y) = if z < 0.0 { ((1.0 - y.abs()) * sign(x), (1.0 - x.abs()) * sign(y)) } else { (x, y) };
    Vec3::new(x, y, z).normalize()
}

/// Encode a normal (any length; zero or non-finite becomes +Z).
pub fn encode(n: Vec3) -> [i16; 2] {
    encode_bits(n, BITS)
}

/// Encode a normal with `bits` (2..=16) per coordinate, scale `2^(bits−1) − 1` (format 3).
pub fn encode_bits(n: Vec3, bits: u32) -> [i16; 2] {
    let scale = scale(bits) as f32;
    let p = unfold(n) * scale;
    let target = n.normalize_or(Vec3::Z);
    let mut best = [0i16; 2];
    let mut best_gap = f32::INFINITY;
    for x in [p.x.floor(), p.x.ceil()] {
        for y in [p.y.floor(), p.y.ceil()] {
            let q = [x.clamp(-scale, scale) as i16, y.clamp(-scale, scale) as i16];
            let gap = decode_at([q[0] as i32, q[1] as i32], scale).distance_squared(target);
            if gap < best_gap {
                best_gap = gap;
                best = q;
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_is_within_the_bound() {
        let mut worst = 0f32;
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        let mut check = |n: Vec3| {
            let (a, b) = (n.normalize().as_dvec3(), decode(encode(n)).as_dvec3());
            worst = worst.max(a.cross(b).length().atan2(a.dot(b)) as f32);
        };
        for _ in 0..200_000 {
            let v = Vec3::new(next(), next(), next());
            if v.length_squared() > 1e-6 {
                check(v);
            }
        }
        for v in [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z, Vec3::ONE, -Vec3::ONE] {
            check(v);
        }
        assert!(worst <= MAX_ERROR, "worst error {worst} rad");
        assert_eq!(decode(encode(Vec3::ZERO)), Vec3::Z);
    }
}
