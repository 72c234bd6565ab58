//! Normal cones: the smallest cone enclosing a set of unit normals, the cone of two cones, and the
//! back-facing tests that let a viewer cull a whole group at once.
//!
//! Every cone this module returns contains what it claims to contain when measured in f64 from its
//! own f32 fields: rounding the axis to f32 is paid for by rounding the half-angle up. The facing
//! tests then keep a further [`FACING_MARGIN`] on the safe side, so a group is called Back or Front
//! only when every face it bounds is.

pub use crate::format::Cone;
use glam::{DVec3, Vec3};
use std::f64::consts::{FRAC_PI_2, PI};

/// Angle (radians) the facing tests keep between their decision and the 90° boundary, covering the
/// f32 rounding of normals, positions and eyes that a caller feeds them.
pub const FACING_MARGIN: f64 = 1e-5;

/// Margin added to computed half-angles before rounding them up to f32, so that re-measuring a
/// bounded direction in f64 never lands outside.
const ANGLE_SLACK: f64 = 1e-12;

/// The incremental search gives up (the set needs 90° or more) when a candidate cap's cosine falls
/// below this.
const MIN_CAP_COS: f64 = 1e-7;

/// Chord slack when testing a point against a candidate cap; absorbs the rounding of the cap
/// through its own defining points.
const CHORD_SLACK: f64 = 1e-12;

/// How much smaller than its predecessor a cap may come out through rounding before the search
/// concludes it has left the hemisphere where it is valid.
const SHRINK_SLACK: f64 = 1e-9;

/// Containment tests per point after which the search gives up; the expected count is about 10.
const WORK_PER_POINT: usize = 64;

/// Chord slack when checking the whole input against a sample's cap: wider than [`CHORD_SLACK`], so
/// that a normal the cap was built to contain is never reported outside it again.
const SCAN_SLACK: f64 = 1e-10;

/// Passes over the input after which the search settles for the current axis, widened to every
/// normal. Exact arithmetic needs at most four (one per normal pinning the answer, then a check).
const MAX_ROUNDS: usize = 8;

/// Inputs up to this size are searched whole; larger ones start from a sample of at least this size.
const FULL_SEARCH: usize = 4096;

impl Cone {
    /// The cone of a single normal: axis `n` normalized, half-angle 0 up to the f32 rounding of the
    /// axis. A zero or non-finite `n` gives the full cone (a face without a normal may face anywhere).
    pub fn from_normal(n: Vec3) -> Cone {
        match unit(n) {
            Some(p) => around(std::slice::from_ref(&n), p),
            None => full(Vec3::Z),
        }
    }

    /// The smallest cone enclosing both cones (exact up to rounding, and always enclosing), in O(1).
    /// A cone with a zero or non-finite axis makes the result the full cone.
    pub fn merge(&self, other: &Cone) -> Cone {
        if self.contains_cone(other, 0.0) {
            return *self;
        }
        if other.contains_cone(self, 0.0) {
            return *other;
        }
        let (Some(a), Some(b)) = (unit(self.axis), unit(other.axis)) else {
            return full(Vec3::Z);
        };
        let (ca, cb) = (self.half_angle as f64, other.half_angle as f64);
        let c = 0.5 * (angle(a, b) + ca + cb);
        if c >= PI || c.is_nan() {
            return full(self.axis);
        }
        // Turn a toward b until the far edges of both cones are equally far from the axis.
        let phi = c - ca;
        let u = a.cross(b).cross(a).try_normalize().unwrap_or_else(|| a.any_orthonormal_vector());
        let axis = (a * phi.cos() + u * phi.sin()).normalize().as_vec3();
        let axis64 = axis.as_dvec3();
        let needed = (angle(axis64, a) + ca).max(angle(axis64, b) + cb);
        Cone { axis, half_angle: round_up(needed) }
    }

    /// Whether `dir` (any length; zero counts as inside) is within `half_angle + tol` of the axis.
    pub fn contains(&self, dir: Vec3, tol: f32) -> bool {
        angle(self.axis.as_dvec3(), dir.as_dvec3()) <= self.half_angle as f64 + tol as f64
    }

    /// Whether every direction of `other` is within `half_angle + tol` of the axis.
    pub fn contains_cone(&self, other: &Cone, tol: f32) -> bool {
        let reach = self.half_angle as f64 + tol as f64;
        reach >= PI || angle(self.axis.as_dvec3(), other.axis.as_dvec3()) + other.half_angle as f64 <= reach
    }
}

/// Smallest cone enclosing the normals: exact (to well within 1e-5 rad) when that cone is under 90°,
/// and otherwise a conservative cone around the better of the normals' mean and the last axis
/// tried. Zero-length and non-finite inputs are ignored; an empty input gives
/// `Cone { axis: Vec3::Z, half_angle: 0.0 }`.
///
/// The exact cone is the smallest enclosing circle on the sphere, found by a randomized incremental
/// search in a deterministic order on a sample of the normals; passes over the input add the
/// normals left outside until none is (Clarkson's scheme: a few passes, since each adds a normal
/// that pins the final cone). Expected linear time, sequential reads, memory for the sample only.
pub fn smallest_enclosing(normals: &[Vec3]) -> Cone {
    let mut rng = XorShift(0x9E37_79B9_7F4A_7C15 ^ normals.len() as u64);
    let mut sample: Vec<DVec3> = if normals.len() <= FULL_SEARCH {
        normals.iter().filter_map(|&n| unit(n)).collect()
    } else {
        let size = FULL_SEARCH.max(3 * (normals.len() as f64).sqrt() as usize);
        (0..size).filter_map(|_| unit(normals[rng.below(normals.len())])).collect()
    };
    if sample.is_empty() {
        match normals.iter().find_map(|&n| unit(n)) {
            Some(p) => sample.push(p),
            None => return Cone { axis: Vec3::Z, half_angle: 0.0 },
        }
    }
    let mut outside = Vec::new();
    let mut rounds = 0;
    loop {
        rounds += 1;
        rng.shuffle(&mut sample);
        let cap = match incremental(&sample) {
            Ok(cap) => cap,
            Err(last) => return conservative(normals, last),
        };
        let axis = cap.axis.as_vec3();
        let a = axis.as_dvec3().normalize();
        // Points of the exact cap stay within its chord plus the shift of rounding its axis.
        let limit = cap.chord + (a - cap.axis).length() + SCAN_SLACK;
        let widest = scan(normals, a, limit, &mut outside);
        if outside.is_empty() || rounds == MAX_ROUNDS {
            return Cone { axis, half_angle: chord_angle(widest) };
        }
        sample.append(&mut outside);
    }
}

/// Whether a group's faces all face away from the viewer, all toward it, or neither (or unknown).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Facing {
    Back,
    Front,
    Mixed,
}

/// Facing of a cone of normals under an orthographic view; `to_viewer` is the direction toward the
/// viewer. A face with normal n is front-facing iff n·to_viewer > 0. Back iff every direction of the
/// cone makes more than 90° with `to_viewer`, Front iff every one makes less, both with
/// [`FACING_MARGIN`] to spare; a zero or non-finite direction gives Mixed.
pub fn facing_orthographic(cone: &Cone, to_viewer: Vec3) -> Facing {
    match (unit(cone.axis), unit(to_viewer)) {
        (Some(a), Some(v)) => classify(angle(a, v), cone.half_angle as f64, 0.0),
        _ => Facing::Mixed,
    }
}

/// Facing of a group under a perspective view from `eye`, for a group whose faces all lie in the
/// sphere (`center`, `radius`). A face with normal n at p is front-facing iff n·(eye − p) > 0. The
/// directions from the sphere's points to the eye lie within β = asin(radius / |eye − center|) of
/// eye − center, so with α the angle between the cone axis and eye − center: Back iff
/// α − c − β > 90°, Front iff α + c + β < 90°, both with [`FACING_MARGIN`] to spare. Mixed when the
/// eye is inside or on the sphere, or an input is degenerate.
pub fn facing_perspective(cone: &Cone, center: Vec3, radius: f32, eye: Vec3) -> Facing {
    let to_eye = eye.as_dvec3() - center.as_dvec3();
    let (d, r) = (to_eye.length(), radius as f64);
    match unit(cone.axis) {
        Some(a) if r >= 0.0 && d > r && d.is_finite() => classify(angle(a, to_eye), cone.half_angle as f64, (r / d).asin()),
        _ => Facing::Mixed,
    }
}

fn classify(alpha: f64, c: f64, beta: f64) -> Facing {
    if alpha - c - beta > FRAC_PI_2 + FACING_MARGIN {
        Facing::Back
    } else if alpha + c + beta < FRAC_PI_2 - FACING_MARGIN {
        Facing::Front
    } else {
        Facing::Mixed
    }
}

/// A candidate cap of the incremental search: the points within `chord` (straight-line distance on
/// the unit sphere) of the unit `axis`.
struct Cap {
    axis: DVec3,
    chord: f64,
}

impl Cap {
    fn one(p: DVec3) -> Cap {
        Cap { axis: p, chord: 0.0 }
    }

    /// The cap with p and q diametrically on its rim; None when it is not under 90°.
    fn two(p: DVec3, q: DVec3) -> Option<Cap> {
        let axis = (p + q).try_normalize()?;
        Cap::checked(axis, p)
    }

    /// The cap under 90° with p, q and s on its rim: its axis is the normal of their plane, on
    /// their side. None when that plane passes (nearly) through the origin.
    fn three(p: DVec3, q: DVec3, s: DVec3) -> Option<Cap> {
        let w = (q - p).cross(s - p).try_normalize()?;
        Cap::checked(if w.dot(p) < 0.0 { -w } else { w }, p)
    }

    fn checked(axis: DVec3, rim: DVec3) -> Option<Cap> {
        (axis.dot(rim) > MIN_CAP_COS).then(|| Cap { axis, chord: (rim - axis).length() })
    }

    /// Each cap of the search encloses a superset of its predecessor's points, so it is no smaller;
    /// a smaller one means the search has left the hemisphere where it is valid.
    fn grew_from(&self, chord: f64) -> Result<(), DVec3> {
        if self.chord >= chord - SHRINK_SLACK {
            Ok(())
        } else {
            Err(self.axis)
        }
    }

    fn contains(&self, p: DVec3) -> bool {
        let limit = self.chord + CHORD_SLACK;
        (p - self.axis).length_squared() <= limit * limit
    }
}

/// Randomized incremental smallest enclosing cap of non-empty `points` (the sphere version of
/// Welzl's circle): every cap it builds is the smallest cap of a subset, so none reaches 90° unless
/// the answer does. Gives up, returning the last axis under 90°, when a cap would reach 90°, comes
/// out smaller than its predecessor (both only happen when the answer needs 90° or more) or the
/// work exceeds [`WORK_PER_POINT`] per point.
fn incremental(points: &[DVec3]) -> Result<Cap, DVec3> {
    let mut budget = WORK_PER_POINT * points.len() + 1024;
    let mut cap = Cap::one(points[0]);
    for i in 1..points.len() {
        if cap.contains(points[i]) {
            continue;
        }
        let before_i = cap.chord;
        budget = budget.checked_sub(i).ok_or(cap.axis)?;
        cap = Cap::one(points[i]);
        for j in 0..i {
            if cap.contains(points[j]) {
                continue;
            }
            let before_j = cap.chord;
            budget = budget.checked_sub(j).ok_or(cap.axis)?;
            cap = Cap::two(points[i], points[j]).ok_or(cap.axis)?;
            for k in 0..j {
                if !cap.contains(points[k]) {
                    let before_k = cap.chord;
                    cap = Cap::three(points[i], points[j], points[k]).ok_or(cap.axis)?;
                    cap.grew_from(before_k)?;
                }
            }
            cap.grew_from(before_j)?;
        }
        cap.grew_from(before_i)?;
    }
    Ok(cap)
}

/// One pass over the normals: the widest chord from unit `a`, with the unit normals farther than
/// `limit` appended to `outside`.
fn scan(normals: &[Vec3], a: DVec3, limit: f64, outside: &mut Vec<DVec3>) -> f64 {
    let mut widest = 0.0f64;
    for p in normals.iter().filter_map(|&n| unit(n)) {
        let chord_sq = (p - a).length_squared();
        widest = widest.max(chord_sq);
        if chord_sq > limit * limit {
            outside.push(p);
        }
    }
    widest.sqrt()
}

/// The cone for normals that need 90° or more: around their mean or around `last`, whichever is
/// narrower.
fn conservative(normals: &[Vec3], last: DVec3) -> Cone {
    let by_last = around(normals, last);
    match normals.iter().filter_map(|&n| unit(n)).sum::<DVec3>().try_normalize() {
        Some(mean) => {
            let by_mean = around(normals, mean);
            if by_mean.half_angle < by_last.half_angle {
                by_mean
            } else {
                by_last
            }
        }
        None => by_last,
    }
}

/// The cone around `axis` (rounded to f32) just wide enough for every normal.
fn around(normals: &[Vec3], axis: DVec3) -> Cone {
    let axis = axis.as_vec3();
    let widest = scan(normals, axis.as_dvec3().normalize(), f64::INFINITY, &mut Vec::new());
    Cone { axis, half_angle: chord_angle(widest) }
}

/// The angle subtended by a chord of the unit sphere, rounded up to f32.
fn chord_angle(chord: f64) -> f32 {
    round_up(2.0 * (0.5 * chord).min(1.0).asin())
}

fn full(axis: Vec3) -> Cone {
    Cone { axis, half_angle: std::f32::consts::PI }
}

/// `x + ANGLE_SLACK` rounded up to f32, at most π (as f32); an exact 0 stays 0.
fn round_up(x: f64) -> f32 {
    if x == 0.0 {
        return 0.0;
    }
    let x = x + ANGLE_SLACK;
    let f = x as f32;
    let f = if (f as f64) < x { f32::from_bits(f.to_bits() + 1) } else { f };
    f.min(std::f32::consts::PI)
}

/// The angle between two directions, accurate near 0 and π; 0 if either is zero.
fn angle(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}

fn unit(v: Vec3) -> Option<DVec3> {
    v.as_dvec3().try_normalize()
}

/// Deterministic xorshift generator: sampling and shuffling in an order no input is likely to
/// defeat, with the same result on every run.
struct XorShift(u64);

impl XorShift {
    fn below(&mut self, n: usize) -> usize {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 as u128 * n as u128) >> 64) as usize
    }

    fn shuffle(&mut self, points: &mut [DVec3]) {
        for i in (1..points.len()).rev() {
            points.swap(i, self.below(i + 1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const PI32: f32 = std::f32::consts::PI;

    /// SplitMix64: many samples per proptest case from one generated seed.
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        fn unit_f64(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
        fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.unit_f64()
        }
        fn chance(&mut self, p: f64) -> bool {
            self.unit_f64() < p
        }
        fn direction(&mut self) -> DVec3 {
            let z = self.range(-1.0, 1.0);
            let phi = self.range(0.0, 2.0 * PI);
            let s = (1.0 - z * z).sqrt();
            DVec3::new(s * phi.cos(), s * phi.sin(), z)
        }
        /// Uniform on the cap of half-angle `cap` around unit `axis`.
        fn in_cap(&mut self, axis: DVec3, cap: f64) -> DVec3 {
            let cos_t = self.range(cap.cos(), 1.0);
            let phi = self.range(0.0, 2.0 * PI);
            let (u, v) = axis.any_orthonormal_pair();
            let s = (1.0 - cos_t * cos_t).max(0.0).sqrt();
            axis * cos_t + (u * phi.cos() + v * phi.sin()) * s
        }
        /// A random f32 unit-ish axis, exactly as a caller would hold it.
        fn axis(&mut self) -> Vec3 {
            self.direction().as_vec3()
        }
    }

    /// `a` turned by `t` radians toward `toward` (any direction if they are parallel).
    fn rotate(a: DVec3, toward: DVec3, t: f64) -> DVec3 {
        let u = a.cross(toward).cross(a).try_normalize().unwrap_or_else(|| a.any_orthonormal_vector());
        a * t.cos() + u * t.sin()
    }

    fn normalized(v: Vec3) -> DVec3 {
        v.as_dvec3().normalize()
    }

    /// The smallest enclosing cap by trying every axis determined by 1, 2 or 3 points (both sides of
    /// each triple's plane), each widened to reach every point.
    fn brute_force(points: &[DVec3]) -> f64 {
        let mut axes: Vec<DVec3> = points.to_vec();
        for (i, &p) in points.iter().enumerate() {
            for (j, &q) in points.iter().enumerate().skip(i + 1) {
                axes.extend((p + q).try_normalize());
                for &s in &points[j + 1..] {
                    if let Some(w) = (q - p).cross(s - p).try_normalize() {
                        axes.extend([w, -w]);
                    }
                }
            }
        }
        axes.iter().map(|&a| points.iter().map(|&p| angle(a, p)).fold(0.0, f64::max)).fold(PI, f64::min)
    }

    fn sample_normals(rng: &mut Rng, count: usize, cap: f64) -> Vec<Vec3> {
        let axis = rng.direction();
        (0..count).map(|_| rng.in_cap(axis, cap).as_vec3()).collect()
    }

    fn assert_encloses(cone: &Cone, normals: &[Vec3], tol: f32) {
        assert!((0.0..=PI32).contains(&cone.half_angle), "{cone:?}");
        assert!((cone.axis.length() - 1.0).abs() < 1e-6, "{cone:?}");
        for &n in normals {
            assert!(n == Vec3::ZERO || cone.contains(n, tol), "{cone:?} misses {n:?}");
        }
    }

    proptest! {
        #[test]
        fn matches_brute_force_under_85_degrees(seed: u64, count in 1usize..=12, scale in 0.0f64..1.0) {
            let mut rng = Rng(seed);
            // Log-uniform cap sizes from ~1.5e-6 rad up to 85°.
            let cap = 85f64.to_radians() * 10f64.powf(-6.0 * scale);
            let normals = sample_normals(&mut rng, count, cap);
            let cone = smallest_enclosing(&normals);
            assert_encloses(&cone, &normals, 0.0);
            let best = brute_force(&normals.iter().map(|&n| normalized(n)).collect::<Vec<_>>());
            prop_assert!((cone.half_angle as f64 - best).abs() <= 1e-5, "{cone:?} vs {best}");
        }

        #[test]
        fn exact_under_90_and_enclosing_for_any_cap(seed: u64, count in 1usize..=12, cap in 0.0f64..=PI) {
            let mut rng = Rng(seed);
            let normals = sample_normals(&mut rng, count, cap);
            let cone = smallest_enclosing(&normals);
            assert_encloses(&cone, &normals, 0.0);
            let best = brute_force(&normals.iter().map(|&n| normalized(n)).collect::<Vec<_>>());
            prop_assert!(cone.half_angle as f64 >= best - 1e-6, "{cone:?} below optimum {best}");
            if best < 89.9f64.to_radians() {
                prop_assert!((cone.half_angle as f64 - best).abs() <= 1e-5, "{cone:?} vs {best}");
            }
        }

        #[test]
        fn encloses_large_sets_of_any_spread(seed: u64, count in 1usize..12_000, cap in 0.0f64..=PI) {
            let mut rng = Rng(seed);
            let mut normals = sample_normals(&mut rng, count, cap);
            // Zero-length normals are ignored; scaled ones count by direction.
            normals[0] = Vec3::ZERO;
            normals[count / 2] *= 1e-3;
            let cone = smallest_enclosing(&normals);
            assert_encloses(&cone, &normals, 0.0);
            if cap < 85f64.to_radians() {
                prop_assert!(cone.half_angle as f64 <= cap + 1e-5, "{cone:?} wider than the {cap} cap");
            }
        }

        #[test]
        fn sampled_search_matches_whole_search(seed: u64, count in FULL_SEARCH + 1..40_000, cap in 0.0f64..1.48) {
            let mut rng = Rng(seed);
            let axis = rng.direction();
            let mut normals: Vec<Vec3> = (0..count).map(|_| rng.in_cap(axis, cap).as_vec3()).collect();
            // Three normals on the rim, 120° apart, pin the answer to the cap itself.
            let (u, v) = axis.any_orthonormal_pair();
            for (k, n) in normals[..3].iter_mut().enumerate() {
                let phi = k as f64 * 2.0 * PI / 3.0;
                *n = (axis * cap.cos() + (u * phi.cos() + v * phi.sin()) * cap.sin()).as_vec3();
            }
            // A coherent order, as a mesh would give: sorted around the axis.
            normals.sort_by(|a, b| {
                let key = |n: &Vec3| n.as_dvec3().dot(v).atan2(n.as_dvec3().dot(u));
                key(a).total_cmp(&key(b))
            });
            let cone = smallest_enclosing(&normals);
            assert_encloses(&cone, &normals, 0.0);
            prop_assert!((cone.half_angle as f64 - cap).abs() <= 1e-5, "{cone:?} vs {cap}");
            let mut all: Vec<DVec3> = normals.iter().map(|&n| normalized(n)).collect();
            XorShift(seed).shuffle(&mut all);
            let whole = incremental(&all).map_err(|_| "whole search gave up").unwrap();
            let whole_angle = 2.0 * (0.5 * whole.chord).asin();
            prop_assert!((cone.half_angle as f64 - whole_angle).abs() <= 1e-5, "{cone:?} vs {whole_angle}");
        }

        #[test]
        fn merge_encloses_both_and_is_smallest(seed: u64) {
            let mut rng = Rng(seed);
            let a = Cone { axis: rng.axis(), half_angle: rng.range(0.0, PI) as f32 };
            let b = Cone { axis: rng.axis(), half_angle: rng.range(0.0, PI) as f32 };
            let m = a.merge(&b);
            prop_assert!(m.contains_cone(&a, 0.0) && m.contains_cone(&b, 0.0), "{a:?} {b:?} -> {m:?}");
            prop_assert!((m.axis.length() - 1.0).abs() < 1e-6);
            let (ca, cb) = (a.half_angle as f64, b.half_angle as f64);
            let theta = angle(a.axis.as_dvec3(), b.axis.as_dvec3());
            let optimum = (0.5 * (theta + ca + cb)).max(ca).max(cb).min(PI);
            prop_assert!((m.half_angle as f64 - optimum).abs() <= 1e-5, "{m:?} vs {optimum}");
            prop_assert!((b.merge(&a).half_angle - m.half_angle).abs() <= 1e-5);
        }

        #[test]
        fn merge_matches_enclosing_cone_of_rims(seed: u64) {
            let mut rng = Rng(seed);
            let a_axis = rng.direction();
            let b_axis = rng.in_cap(a_axis, 40f64.to_radians());
            let [a, b] = [a_axis, b_axis]
                .map(|axis| Cone { axis: axis.as_vec3(), half_angle: rng.range(0.0, 40f64.to_radians()) as f32 });
            let rims: Vec<Vec3> = [a, b]
                .iter()
                .map(|cone| (normalized(cone.axis), cone.half_angle as f64))
                .flat_map(|(axis, c)| {
                    let (u, v) = axis.any_orthonormal_pair();
                    (0..360).map(move |k| {
                        let phi = k as f64 * PI / 180.0;
                        (axis * c.cos() + (u * phi.cos() + v * phi.sin()) * c.sin()).as_vec3()
                    })
                })
                .collect();
            let m = a.merge(&b);
            let exact = smallest_enclosing(&rims);
            // Rim directions rounded to f32 may poke out of their own cone by ~1e-7 rad.
            assert_encloses(&m, &rims, 1e-6);
            // The rims are sampled every degree: their cone falls short of the true one by < 1e-4 rad.
            prop_assert!(exact.half_angle <= m.half_angle + 1e-5, "{exact:?} vs {m:?}");
            prop_assert!(exact.half_angle >= m.half_angle - 1e-4, "{exact:?} vs {m:?}");
        }

        #[test]
        fn merged_face_cones_enclose_the_faces(seed: u64, count in 1usize..40, cap in 0.0f64..=PI) {
            let mut rng = Rng(seed);
            let normals = sample_normals(&mut rng, count, cap);
            let merged = normals.iter().map(|&n| Cone::from_normal(n)).reduce(|a, b| a.merge(&b)).unwrap();
            assert_encloses(&merged, &normals, 0.0);
            let smallest = smallest_enclosing(&normals);
            if smallest.half_angle < 1.5 {
                prop_assert!(merged.half_angle >= smallest.half_angle - 1e-5);
            }
        }

        #[test]
        fn merge_of_nested_cones_is_the_outer(seed: u64) {
            let mut rng = Rng(seed);
            let outer_c = rng.range(1e-3, PI - 1e-3);
            let inner_c = rng.range(0.0, outer_c);
            let outer = Cone { axis: rng.axis(), half_angle: outer_c as f32 };
            let inner_axis = rotate(normalized(outer.axis), rng.direction(), rng.range(0.0, 0.9 * (outer_c - inner_c)));
            let inner = Cone { axis: inner_axis.as_vec3(), half_angle: inner_c as f32 };
            prop_assert_eq!(outer.merge(&inner), outer);
            prop_assert_eq!(inner.merge(&outer), outer);
            prop_assert_eq!(outer.merge(&outer), outer);
        }

        #[test]
        fn merge_of_opposite_cones(seed: u64) {
            let mut rng = Rng(seed);
            let axis = rng.axis();
            let a = Cone { axis, half_angle: rng.range(0.0, PI) as f32 };
            let b = Cone { axis: -axis, half_angle: rng.range(0.0, PI) as f32 };
            let m = a.merge(&b);
            prop_assert!(m.contains_cone(&a, 0.0) && m.contains_cone(&b, 0.0), "{a:?} {b:?} -> {m:?}");
            let sum = a.half_angle as f64 + b.half_angle as f64;
            if sum >= PI {
                prop_assert_eq!(m.half_angle, PI32);
            } else {
                prop_assert!((m.half_angle as f64 - (FRAC_PI_2 + 0.5 * sum)).abs() <= 1e-5, "{m:?}");
            }
        }

        #[test]
        fn orthographic_facing_is_never_wrong(seed: u64) {
            let mut rng = Rng(seed);
            let cone = random_cone(&mut rng);
            let a = normalized(cone.axis);
            let c = cone.half_angle as f64;
            let alpha = near_threshold(&mut rng, c).clamp(0.0, PI);
            let view = rotate(a, rng.direction(), alpha).as_vec3();
            let v = normalized(view);
            let normals = cone_normals(&mut rng, &cone, &[v]);
            let facing = facing_orthographic(&cone, view);
            for &n in &normals {
                let d = n.as_dvec3().dot(v);
                prop_assert!(facing != Facing::Back || d <= 0.0, "{cone:?} {view:?} {n:?}: Back but {d}");
                prop_assert!(facing != Facing::Front || d > 0.0, "{cone:?} {view:?} {n:?}: Front but {d}");
            }
            let alpha = angle(a, v);
            if alpha - c > FRAC_PI_2 + 1e-4 {
                prop_assert_eq!(facing, Facing::Back);
            } else if alpha + c < FRAC_PI_2 - 1e-4 {
                prop_assert_eq!(facing, Facing::Front);
            }
        }

        #[test]
        fn perspective_facing_is_never_wrong(seed: u64) {
            let mut rng = Rng(seed);
            let cone = random_cone(&mut rng);
            let a = normalized(cone.axis);
            let c = cone.half_angle as f64;
            let center = DVec3::new(rng.range(-100.0, 100.0), rng.range(-100.0, 100.0), rng.range(-100.0, 100.0)).as_vec3();
            let radius = 10f64.powf(rng.range(-2.0, 1.0)) as f32;
            let (o, r) = (center.as_dvec3(), radius as f64);
            let inside = rng.chance(0.15);
            let dist = if inside { r * rng.unit_f64() } else { r * (1.0 + 10f64.powf(rng.range(-6.0, 2.0))) };
            let beta = if inside { FRAC_PI_2 } else { (r / dist).asin() };
            let alpha = near_threshold(&mut rng, c + beta).clamp(0.0, PI);
            let eye = (o + rotate(a, rng.direction(), alpha) * dist).as_vec3();
            let e = eye.as_dvec3();
            let to_eye = (e - o).normalize();
            // The tangent points where the sphere's directions to the eye turn furthest toward and away
            // from the axis, then random points of the ball.
            let mut points = Vec::new();
            if !inside {
                let tangent = (dist * dist - r * r).max(0.0).sqrt();
                for turn in [beta, -beta] {
                    points.push(e - rotate(to_eye, a, turn) * tangent);
                }
            }
            points.extend((0..30).map(|_| o + rng.direction() * r * rng.unit_f64().cbrt()));
            let points: Vec<DVec3> = points
                .into_iter()
                .map(|p| (o + (p - o) * (1.0 - 1e-6)).as_vec3().as_dvec3())
                .filter(|p| (*p - o).length() <= r)
                .collect();
            let views: Vec<DVec3> = points.iter().map(|&p| (e - p).normalize()).collect();
            let normals = cone_normals(&mut rng, &cone, &views);
            let facing = facing_perspective(&cone, center, radius, eye);
            for &p in &points {
                for &n in &normals {
                    let d = n.as_dvec3().dot(e - p);
                    prop_assert!(facing != Facing::Back || d <= 0.0, "{cone:?} {eye:?} {p:?} {n:?}: Back but {d}");
                    prop_assert!(facing != Facing::Front || d > 0.0, "{cone:?} {eye:?} {p:?} {n:?}: Front but {d}");
                }
            }
            let d = (e - o).length();
            if d <= r {
                prop_assert_eq!(facing, Facing::Mixed);
            } else {
                let (alpha, beta) = (angle(a, e - o), (r / d).asin());
                if alpha - c - beta > FRAC_PI_2 + 1e-4 {
                    prop_assert_eq!(facing, Facing::Back);
                } else if alpha + c + beta < FRAC_PI_2 - 1e-4 {
                    prop_assert_eq!(facing, Facing::Front);
                }
            }
        }
    }

    fn random_cone(rng: &mut Rng) -> Cone {
        let half_angle = if rng.chance(0.1) { 0.0 } else { PI * rng.unit_f64().powi(2) };
        Cone { axis: rng.axis(), half_angle: half_angle as f32 }
    }

    /// An axis-to-viewer angle near the Back threshold (π/2 + spread) or the Front one (π/2 − spread),
    /// or anywhere.
    fn near_threshold(rng: &mut Rng, spread: f64) -> f64 {
        let delta = 10f64.powf(rng.range(-7.0, -1.0)) * if rng.chance(0.5) { 1.0 } else { -1.0 };
        match rng.next() % 3 {
            0 => FRAC_PI_2 + spread + delta,
            1 => FRAC_PI_2 - spread + delta,
            _ => rng.range(0.0, PI),
        }
    }

    /// Normals inside the cone: for each view direction, the rim normals turned furthest toward and
    /// away from it, then random ones; only those the cone contains as stored in f32.
    fn cone_normals(rng: &mut Rng, cone: &Cone, views: &[DVec3]) -> Vec<Vec3> {
        let a = normalized(cone.axis);
        let c = cone.half_angle as f64;
        let rim = (c - 1e-7).max(0.0);
        let mut normals: Vec<Vec3> = views.iter().flat_map(|&v| [rotate(a, v, rim), rotate(a, v, -rim)]).map(DVec3::as_vec3).collect();
        normals.extend((0..30).map(|_| rng.in_cap(a, c).as_vec3()));
        normals.retain(|&n| cone.contains(n, 0.0));
        normals
    }

    #[test]
    fn degenerate_inputs() {
        let empty = Cone { axis: Vec3::Z, half_angle: 0.0 };
        assert_eq!(smallest_enclosing(&[]), empty);
        assert_eq!(smallest_enclosing(&[Vec3::ZERO, Vec3::splat(f32::NAN)]), empty);
        let n = Vec3::new(0.3, -0.4, 0.5);
        let same = smallest_enclosing(&[n, n * 2.0, Vec3::ZERO, n]);
        assert!(same.half_angle < 1e-6 && same.contains(n, 0.0), "{same:?}");
        assert_eq!(Cone::from_normal(Vec3::X), Cone { axis: Vec3::X, half_angle: 0.0 });
        assert_eq!(Cone::from_normal(Vec3::ZERO).half_angle, PI32);
        let opposite = smallest_enclosing(&[Vec3::X, -Vec3::X]);
        assert_encloses(&opposite, &[Vec3::X, -Vec3::X], 0.0);
        let both = Cone::from_normal(Vec3::Y).merge(&Cone::from_normal(-Vec3::Y));
        assert!((both.half_angle as f64 - FRAC_PI_2).abs() < 1e-6 && both.axis.y.abs() < 1e-6, "{both:?}");
        let octahedron = [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z];
        assert_encloses(&smallest_enclosing(&octahedron), &octahedron, 0.0);
    }

    #[test]
    fn known_cones() {
        // Three normals 30° from +Z, evenly around it: the cone is exactly 30° around +Z.
        let t = 30f64.to_radians();
        let normals: Vec<Vec3> = (0..3)
            .map(|k| {
                let phi = k as f64 * 2.0 * PI / 3.0;
                DVec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), t.cos()).as_vec3()
            })
            .collect();
        let cone = smallest_enclosing(&normals);
        assert!((cone.half_angle as f64 - t).abs() < 1e-6 && cone.axis.z > 1.0 - 1e-6, "{cone:?}");
        // Adding a normal inside changes nothing; the diametral pair of an obtuse triple decides.
        let pair = smallest_enclosing(&[Vec3::X, Vec3::Y, Vec3::new(1.0, 1.0, 0.1)]);
        assert!((pair.half_angle as f64 - PI / 4.0).abs() < 1e-6, "{pair:?}");
    }

    #[test]
    fn clear_views_are_decided() {
        let cone = Cone { axis: Vec3::Z, half_angle: 0.5 };
        assert_eq!(facing_orthographic(&cone, Vec3::Z), Facing::Front);
        assert_eq!(facing_orthographic(&cone, -Vec3::Z), Facing::Back);
        assert_eq!(facing_orthographic(&cone, Vec3::X), Facing::Mixed);
        assert_eq!(facing_orthographic(&cone, Vec3::ZERO), Facing::Mixed);
        assert_eq!(facing_perspective(&cone, Vec3::ZERO, 1.0, Vec3::new(0.0, 0.0, 10.0)), Facing::Front);
        assert_eq!(facing_perspective(&cone, Vec3::ZERO, 1.0, Vec3::new(0.0, 0.0, -10.0)), Facing::Back);
        assert_eq!(facing_perspective(&cone, Vec3::ZERO, 1.0, Vec3::new(0.0, 0.0, -1.1)), Facing::Mixed);
        assert_eq!(facing_perspective(&cone, Vec3::ZERO, 1.0, Vec3::new(0.0, 0.0, 0.5)), Facing::Mixed);
        let full = Cone { axis: Vec3::Z, half_angle: PI32 };
        assert_eq!(facing_orthographic(&full, -Vec3::Z), Facing::Mixed);
    }
}
