//! Shape retention (seed 000's measure): how much of the full-detail model's image a streamed front
//! keeps, both drawn in one plain color with the same camera. Pixels covered in neither image do
//! not count; the rest are retained when both images agree there.

use crate::render::{changed_share, Image};

/// Largest per-channel difference (of 255) still counted as the same pixel: shading that moved by
/// a few levels because coarser normals are slightly different is not a change of shape.
pub const TOLERANCE: u8 = 8;

/// Retention of one image against its full-detail reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Retention {
    /// 1 − changed share over pixels covered in either image, colors within [`TOLERANCE`].
    pub shaded: f64,
    /// Share of pixels covered in either image that are covered in both: the silhouette alone.
    pub coverage: f64,
}

/// Shape retention of `front` against `full`, both of the same size (else nothing is retained).
pub fn retention(front: &Image, full: &Image) -> Retention {
    let shaded = 1.0 - changed_share(front, full, TOLERANCE);
    if front.depth.len() != full.depth.len() || front.width != full.width {
        return Retention { shaded, coverage: 0.0 };
    }
    let (mut either, mut both) = (0usize, 0usize);
    for (a, b) in front.depth.iter().zip(&full.depth) {
        either += (a.is_finite() || b.is_finite()) as usize;
        both += (a.is_finite() && b.is_finite()) as usize;
    }
    let coverage = if either == 0 { 1.0 } else { both as f64 / either as f64 };
    Retention { shaded, coverage }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use glam::Vec3;

    fn square(image: &mut Image, half: f32) {
        let cam = Camera::framing(Vec3::ZERO, 1.0, Vec3::Z, 1.0, image.width, image.height);
        let p = [Vec3::new(-half, -half, 0.0), Vec3::new(half, -half, 0.0), Vec3::new(half, half, 0.0), Vec3::new(-half, half, 0.0)];
        image.draw(&cam, &p, &[], &[0, 1, 2, 0, 2, 3], [200, 200, 200, 255]);
    }

    #[test]
    fn identical_images_retain_everything_and_a_smaller_shape_retains_its_share() {
        let (mut full, mut front) = (Image::new(64, 64), Image::new(64, 64));
        square(&mut full, 0.5);
        assert_eq!(retention(&full, &full), Retention { shaded: 1.0, coverage: 1.0 });
        square(&mut front, 0.25);
        let r = retention(&front, &full);
        assert!((r.coverage - 0.25).abs() < 0.05, "{r:?}");
        assert!((r.shaded - r.coverage).abs() < 1e-9, "same color where both cover: {r:?}");
        let empty = Image::new(64, 64);
        assert_eq!(retention(&empty, &full).coverage, 0.0);
        assert_eq!(retention(&empty, &empty), Retention { shaded: 1.0, coverage: 1.0 });
        assert_eq!(retention(&Image::new(8, 8), &full).coverage, 0.0);
    }
}
