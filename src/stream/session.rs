//! Viewing sessions to play through a [`Streamer`](super::Streamer): an orbit that moves in from
//! far to near, or a camera path given as text.

use crate::camera::{Camera, Projection};
use crate::error::{Error, Result};
use glam::Vec3;
use std::path::Path;

/// Vertical field of view of session cameras.
pub const FOV_Y: f32 = std::f32::consts::FRAC_PI_3;
/// Fraction of the view height the model spans at the start of an orbit.
pub const FAR_FRACTION: f32 = 0.05;
/// Eye distance from the center at the end of the approach, in model radii: a close-up.
pub const NEAR_RADII: f32 = 1.3;

/// Camera `i` of an `n`-frame orbit around the sphere (center, radius), as in the paper's
/// experiments: one turn around the vertical axis, moving over the first half from far (the model
/// spans 5% of the view) to a close-up, then staying close.
pub fn orbit(center: Vec3, radius: f32, i: usize, n: usize, width: u32, height: u32) -> Camera {
    orbit_at(center, radius, i, n, width, height, 0.3)
}

/// [`orbit`] for terrain: from 45° above the horizon, so that the surface is seen rather than its
/// edge.
pub fn terrain_orbit(center: Vec3, radius: f32, i: usize, n: usize, width: u32, height: u32) -> Camera {
    orbit_at(center, radius, i, n, width, height, 1.0)
}

/// Camera `i` of an orbit whose eye direction rises `lift` per unit of horizontal distance.
fn orbit_at(center: Vec3, radius: f32, i: usize, n: usize, width: u32, height: u32, lift: f32) -> Camera {
    let radius = radius.max(f32::MIN_POSITIVE);
    let far = radius / (FAR_FRACTION * (0.5 * FOV_Y).tan());
    let near = NEAR_RADII * radius;
    let half = (n / 2).max(2);
    let t = (i as f32 / (half - 1) as f32).min(1.0);
    let distance = far * (near / far).powf(t);
    let angle = std::f32::consts::TAU * i as f32 / n.max(1) as f32;
    let dir = Vec3::new(angle.sin(), lift, angle.cos()).normalize();
    looking(center + dir * distance, center, center, radius, width, height)
}

/// Camera `i` of an `n`-frame flight over terrain with bounds `min..max` (y up), along the middle
/// at a tenth of the width above the highest point, looking north and down at the ground a quarter
/// of the width ahead: from where that point is the south edge to where it is the north edge.
pub fn flyover(min: Vec3, max: Vec3, i: usize, n: usize, width: u32, height: u32) -> Camera {
    let extent = (max.x - min.x).max(max.z - min.z).max(f32::MIN_POSITIVE);
    let t = i as f32 / (n.max(2) - 1) as f32;
    let x = 0.5 * (min.x + max.x);
    let z = max.z + 0.25 * extent - t * (max.z - min.z);
    let eye = Vec3::new(x, max.y + 0.1 * extent, z);
    let target = Vec3::new(x, 0.5 * (min.y + max.y), z - 0.25 * extent);
    let (center, radius) = (0.5 * (min + max), 0.5 * (max - min).length());
    looking(eye, target, center, radius, width, height)
}

/// A perspective camera from `eye` toward `target` whose depth range holds the model's bounding
/// sphere (center, radius).
fn looking(eye: Vec3, target: Vec3, center: Vec3, radius: f32, width: u32, height: u32) -> Camera {
    let forward = target - eye;
    let up = if forward.cross(Vec3::Y).length_squared() < 1e-12 * forward.length_squared() { Vec3::Z } else { Vec3::Y };
    let d = eye.distance(center);
    Camera {
        eye,
        target,
        up,
        projection: Projection::Perspective { fov_y: FOV_Y },
        width,
        height,
        near: (d - radius).max(radius * 1e-3),
        far: d + radius,
    }
}

/// Parse a camera path: one camera per line, `ex ey ez tx ty tz` (eye, then target, model units,
/// whitespace-separated); blank lines and lines starting with `#` are skipped. The model's bounding
/// sphere (center, radius) sets the depth range; errors name `path` and the line.
pub fn parse_path(text: &str, path: &Path, center: Vec3, radius: f32, width: u32, height: u32) -> Result<Vec<Camera>> {
    let mut cameras = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let values: Vec<f32> = line
            .split_whitespace()
            .map(|w| w.parse::<f32>().ok().filter(|v| v.is_finite()))
            .collect::<Option<_>>()
            .ok_or_else(|| Error::at_line(path, k + 1, "expected six finite numbers: ex ey ez tx ty tz"))?;
        let [ex, ey, ez, tx, ty, tz] = values[..] else {
            return Err(Error::at_line(path, k + 1, format!("expected six numbers (ex ey ez tx ty tz), found {}", values.len())));
        };
        let (eye, target) = (Vec3::new(ex, ey, ez), Vec3::new(tx, ty, tz));
        if eye.distance(target) <= 0.0 {
            return Err(Error::at_line(path, k + 1, "the eye and the target coincide"));
        }
        cameras.push(looking(eye, target, center, radius, width, height));
    }
    Ok(cameras)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_moves_from_far_to_close_and_sees_the_model() {
        let n = 20;
        let cams: Vec<Camera> = (0..n).map(|i| orbit(Vec3::ONE, 2.0, i, n, 64, 64)).collect();
        let d: Vec<f32> = cams.iter().map(|c| c.eye.distance(Vec3::ONE)).collect();
        assert!(d.windows(2).take(n / 2 - 1).all(|w| w[1] < w[0]));
        assert!((d[n - 1] - NEAR_RADII * 2.0).abs() < 1e-3);
        let spans = 2.0 * cams[0].pixels_per_unit(d[0]) * 2.0 / 64.0;
        assert!((spans - FAR_FRACTION).abs() < 1e-3, "{spans}");
        assert!(cams.iter().all(|c| c.sees_sphere(Vec3::ONE, 2.0)));
    }

    #[test]
    fn path_lines_parse_and_errors_name_the_line() {
        let p = Path::new("cams.txt");
        let cams = parse_path("# eye target\n0 0 5 0 0 0\n\n1 2 3  0 0 0\n", p, Vec3::ZERO, 1.0, 8, 8).unwrap();
        assert_eq!(cams.len(), 2);
        assert_eq!(cams[1].eye, Vec3::new(1.0, 2.0, 3.0));
        let e = parse_path("0 0 5 0 0 0\n0 0 5 0 0\n", p, Vec3::ZERO, 1.0, 8, 8).unwrap_err().to_string();
        assert!(e.contains("cams.txt") && e.contains('2'), "{e}");
        assert!(parse_path("0 0 x 0 0 0", p, Vec3::ZERO, 1.0, 8, 8).is_err());
        assert!(parse_path("1 1 1 1 1 1", p, Vec3::ZERO, 1.0, 8, 8).is_err());
    }
}
