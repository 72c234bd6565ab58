//! Play a viewing session: per camera, update the [`Streamer`], draw its front with the software
//! renderer strip by strip, and hand the frame's report, timings and (on request) pixels and shape
//! retention to the caller, which prints or saves them.

use super::retention::{retention, Retention};
use super::{FrameReport, Streamer};
use crate::camera::Camera;
use crate::error::Result;
use crate::format::{ByteSource, NodeGeometry};
use crate::render::{palette, Image, Part, Strips};
use crate::texture::draw::node_parts;
use std::time::Instant;

/// What to produce per frame besides the report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlayOptions {
    pub width: u32,
    pub height: u32,
    /// Keep each whole frame's pixels (RGBA, rows top down): nodes colored by id, or for a textured
    /// model its materials with the image levels held.
    pub pixels: bool,
    /// Also draw the front and the full-detail model in one plain color and measure the retention.
    pub compare_full: bool,
}

/// One played frame.
pub struct Frame<'a> {
    pub report: FrameReport,
    /// Time to draw the front.
    pub draw_ms: f64,
    /// Time since the file was opened, when this frame was ready.
    pub since_open_ms: f64,
    /// The frame's pixels, with [`PlayOptions::pixels`].
    pub rgba: Option<&'a [u8]>,
    /// With [`PlayOptions::compare_full`].
    pub retained: Option<Retention>,
}

/// Play `cameras` through `streamer`, calling `each` with every frame. The frame-time controller
/// (if the budgets ask for one) is fed the last frame's refine and draw time. `full` is the
/// full-detail geometry for [`PlayOptions::compare_full`], read apart from the streamer's budgets;
/// `opened` is when the file was opened.
pub fn play<S: ByteSource>(
    streamer: &mut Streamer<S>,
    cameras: &[Camera],
    opts: PlayOptions,
    full: &[NodeGeometry],
    opened: Instant,
    mut each: impl FnMut(Frame<'_>) -> Result<()>,
) -> Result<()> {
    let (width, height) = (opts.width.max(1), opts.height.max(1));
    // Frames are drawn strip by strip; a whole one is kept only when asked for.
    let mut strips = Strips::new(width, height);
    let row_bytes = 4 * width as usize;
    let mut rgba = if opts.pixels { vec![0u8; row_bytes * height as usize] } else { Vec::new() };
    let mut plain = opts.compare_full.then(|| (Image::new(width, height), Image::new(width, height)));
    let mut last_ms = None;
    // A textured model is drawn in its materials with the image levels the streamer holds; others
    // with a color per node.
    let textured = !streamer.reader().textures().is_empty();
    for camera in cameras {
        let report = streamer.update(camera, last_ms)?;
        let start = Instant::now();
        let s = &*streamer;
        let parts: Vec<Part> = report
            .front
            .iter()
            .filter_map(|&i| s.geometry(i).map(|g| (i, g)))
            .flat_map(|(i, g)| {
                if textured {
                    node_parts(g, s.reader().materials(), &|image| s.image(image))
                } else {
                    vec![Part::new(&g.positions, &g.normals, &g.indices, palette(i))]
                }
            })
            .collect();
        strips.draw(camera, &parts, |row, line| {
            if let Some(out) = rgba.get_mut(row as usize * row_bytes..row as usize * row_bytes + line.len()) {
                out.copy_from_slice(line);
            }
        });
        let draw_ms = start.elapsed().as_secs_f64() * 1e3;
        last_ms = Some((report.stats.refine_ms + draw_ms) as f32);
        let since_open_ms = opened.elapsed().as_secs_f64() * 1e3;
        let retained = plain.as_mut().map(|(front, whole)| {
            const PLAIN: [u8; 4] = [200, 200, 200, 255];
            front.clear();
            whole.clear();
            for &i in &report.front {
                if let Some(g) = streamer.geometry(i) {
                    front.draw(camera, &g.positions, &g.normals, &g.indices, PLAIN);
                }
            }
            for g in full {
                whole.draw(camera, &g.positions, &g.normals, &g.indices, PLAIN);
            }
            retention(front, whole)
        });
        each(Frame { report, draw_ms, since_open_ms, rgba: opts.pixels.then_some(&rgba[..]), retained })?;
    }
    Ok(())
}
