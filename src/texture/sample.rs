//! Sampling for the software renderer: a chain of an image's levels, bilinear within the level
//! a face's texel-to-pixel ratio chooses.

use super::Rgba8;
use crate::format::Wrap;
use std::sync::Arc;

/// An image's levels as pixels, finest first, each half the one before (rounded up), shared with
/// whoever holds them. A chain may start below the full image (the finest level a streamed front
/// has read); `full_width` and `full_height` are then still the full image's, so that level choice
/// does not depend on which levels are present. How UVs wrap belongs to the map sampling it, not to
/// the image ([`MipChain::sample`]).
#[derive(Clone, Debug, Default)]
pub struct MipChain {
    /// Level index (0 = full) of `levels[0]`.
    pub first_level: u32,
    pub levels: Vec<Arc<Rgba8>>,
    pub full_width: u32,
    pub full_height: u32,
}

impl MipChain {
    /// Levels `first_level ..` of an image whose full size is `full_width` × `full_height`.
    pub fn new(first_level: u32, levels: Vec<Arc<Rgba8>>, full_width: u32, full_height: u32) -> MipChain {
        MipChain { first_level, levels, full_width, full_height }
    }

    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Texels of the full image per unit of UV area: what a face's UV area is scaled by to choose
    /// its level.
    pub fn full_texels(&self) -> f64 {
        self.full_width as f64 * self.full_height as f64
    }

    /// The level (index into `levels`) for a face covering `texels` texels of the full image over
    /// `pixels` pixels of the screen: the level where a texel is about a pixel, clamped to those held.
    pub fn choose(&self, texels: f64, pixels: f64) -> usize {
        if self.levels.is_empty() {
            return 0;
        }
        let lod = if pixels > 0.0 && texels > 0.0 { 0.5 * (texels / pixels).log2() } else { 0.0 };
        let lod = if lod.is_finite() { lod.max(0.0).round() as i64 } else { 0 };
        (lod - self.first_level as i64).clamp(0, self.levels.len() as i64 - 1) as usize
    }

    /// The texel color at `(u, v)` of level `level` (index into `levels`), bilinear with wrap
    /// modes `wrap` along u and v; UV (0, 0) is the image's top-left corner, as in glTF.
    pub fn sample(&self, level: usize, u: f32, v: f32, wrap: [Wrap; 2]) -> [u8; 4] {
        let Some(im) = self.levels.get(level) else { return [255; 4] };
        let (w, h) = (im.width as i64, im.height as i64);
        // Far outside [0, 1] the wrap modes repeat with a period of a side or two: clamping there
        // keeps the texel arithmetic in range without changing what repeats.
        let x = (u * w as f32 - 0.5).clamp(-1e9, 1e9);
        let y = (v * h as f32 - 0.5).clamp(-1e9, 1e9);
        if !(x.is_finite() && y.is_finite()) {
            return im.get(0, 0);
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let xs = [wrap_index(x0, w, wrap[0]), wrap_index(x0 + 1, w, wrap[0])];
        let ys = [wrap_index(y0, h, wrap[1]), wrap_index(y0 + 1, h, wrap[1])];
        let t = [im.get(xs[0], ys[0]), im.get(xs[1], ys[0]), im.get(xs[0], ys[1]), im.get(xs[1], ys[1])];
        let weights = [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy];
        std::array::from_fn(|c| {
            let s: f32 = t.iter().zip(weights).map(|(t, w)| t[c] as f32 * w).sum();
            (s + 0.5).clamp(0.0, 255.0) as u8
        })
    }
}

/// Texel index `i` of a side of `n` texels under `mode`.
fn wrap_index(i: i64, n: i64, mode: Wrap) -> u32 {
    let r = match mode {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::Clamp => i.clamp(0, n - 1),
        Wrap::Mirror => {
            let m = i.rem_euclid(2 * n);
            if m < n {
                m
            } else {
                2 * n - 1 - m
            }
        }
    };
    r as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_by_two() -> Rgba8 {
        let mut im = Rgba8::new(2, 2);
        im.pixels.copy_from_slice(&[0, 0, 0, 255, 200, 0, 0, 255, 0, 200, 0, 255, 0, 0, 200, 255]);
        im
    }

    #[test]
    fn texel_centers_sample_exactly_and_between_blends() {
        let chain = MipChain::new(0, vec![Arc::new(two_by_two())], 2, 2);
        let r = [Wrap::Repeat; 2];
        assert_eq!(chain.sample(0, 0.25, 0.25, r), [0, 0, 0, 255]);
        assert_eq!(chain.sample(0, 0.75, 0.25, r), [200, 0, 0, 255]);
        assert_eq!(chain.sample(0, 0.25, 0.75, r), [0, 200, 0, 255]);
        assert_eq!(chain.sample(0, 0.5, 0.25, r), [100, 0, 0, 255]);
        // At a texel's edge repeat blends with the far side, clamp with itself.
        assert_eq!(chain.sample(0, 0.0, 0.25, r), [100, 0, 0, 255]);
        assert_eq!(chain.sample(0, 0.0, 0.25, [Wrap::Clamp; 2]), [0, 0, 0, 255]);
        // Huge UVs neither panic nor leave the image.
        for big in [1e30, -1e30, 3e9, f32::MAX] {
            let _ = chain.sample(0, big, -big, r);
            let _ = chain.sample(0, big, big, [Wrap::Mirror; 2]);
        }
    }

    #[test]
    fn wrap_modes() {
        assert_eq!(wrap_index(-1, 4, Wrap::Repeat), 3);
        assert_eq!(wrap_index(5, 4, Wrap::Clamp), 3);
        assert_eq!(wrap_index(-1, 4, Wrap::Mirror), 0);
        assert_eq!(wrap_index(4, 4, Wrap::Mirror), 3);
        assert_eq!(wrap_index(9, 4, Wrap::Mirror), 1);
    }

    #[test]
    fn level_choice_follows_texels_per_pixel() {
        let chain = MipChain::new(0, [8, 4, 2].map(|s| Arc::new(Rgba8::new(s, s))).to_vec(), 8, 8);
        assert_eq!(chain.choose(64.0, 64.0), 0);
        assert_eq!(chain.choose(64.0, 16.0), 1);
        assert_eq!(chain.choose(64.0, 1.0), 2);
        assert_eq!(chain.choose(64.0, 0.0), 0);
        let coarse = MipChain::new(1, vec![Arc::new(Rgba8::new(4, 4))], 8, 8);
        assert_eq!(coarse.choose(64.0, 64.0), 0);
    }
}
