//! Play a viewing session: per camera, update the [`Streamer`], draw its front with the software
//! renderer strip by strip, and hand the frame's report, timings and (on request) pixels and shape
//! retention to the caller, which prints or saves them.

use super::retention::{retention, Retention};
use super::{FrameReport, Streamer};
use crate::camera::Camera;
use crate::error::Result;
use crate::format::{ByteSource, NodeGeometry};
use crate::render::{palette, DrawStats, Image, Part, Strips};
use crate::texture::draw::node_parts;
use std::time::Instant;

/// The color of the seams between levels in a frame whose nodes are drawn in a color each.
const SEAM_COLOR: [u8; 4] = [200, 200, 200, 255];

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
    /// Draw the front in the streamer's front-to-back order (else in node order).
    pub ordered: bool,
    /// Skip nodes whose box lies behind what is already drawn ([`Strips::set_occlusion`]); the
    /// pixels are the same either way.
    pub occlusion: bool,
    /// With `occlusion`, also keep the nodes found hidden from being refined in the next frame
    /// ([`Streamer::hold_hidden`]): fewer reads, at the price of a frame's lag where they come into view.
    pub hold_hidden: bool,
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
    /// Faces drawn, overdraw and what occlusion culling skipped.
    pub draw: DrawStats,
    /// Nodes of the front the occlusion test skipped entirely.
    pub nodes_hidden: usize,
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
    strips.set_occlusion(opts.occlusion);
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
        let nodes = if opts.ordered { &report.order } else { &report.front };
        // Each part's node, for counting the nodes occlusion culling skipped.
        let mut owner = Vec::new();
        let mut parts: Vec<Part> = nodes
            .iter()
            .filter_map(|&i| s.geometry(i).map(|g| (i, g)))
            .flat_map(|(i, g)| {
                let (lo, hi) = s.reader().node_box(i);
                let parts = if textured {
                    node_parts(g, s.reader().materials(), &|image| s.image(image))
                } else {
                    vec![Part::new(&g.positions, &g.normals, &g.indices, palette(i))]
                };
                owner.extend(parts.iter().map(|_| i));
                parts.into_iter().map(move |p| p.with_bounds(lo, hi))
            })
            .collect();
        // The seams between levels, last: they fill slivers behind nothing.
        let seams = s.seams();
        if !seams.indices.is_empty() {
            parts.push(Part::new(&seams.positions, &seams.normals, &seams.indices, SEAM_COLOR));
        }
        strips.draw(camera, &parts, |row, line| {
            if let Some(out) = rgba.get_mut(row as usize * row_bytes..row as usize * row_bytes + line.len()) {
                out.copy_from_slice(line);
            }
        });
        let draw_ms = start.elapsed().as_secs_f64() * 1e3;
        let draw = strips.stats();
        // A node is hidden when all its parts are (the seams' part, last, belongs to none).
        let hidden: Vec<u32> = if opts.occlusion {
            let mut shown: Vec<(u32, bool)> = owner.iter().enumerate().map(|(k, &i)| (i, !strips.part_hidden(k))).collect();
            shown.sort_unstable();
            shown.dedup_by(|b, a| {
                a.0 == b.0 && {
                    a.1 |= b.1;
                    true
                }
            });
            shown.iter().filter(|s| !s.1).map(|s| s.0).collect()
        } else {
            Vec::new()
        };
        let nodes_hidden = hidden.len();
        if opts.hold_hidden {
            streamer.hold_hidden(&hidden);
        }
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
            let seams = streamer.seams();
            front.draw(camera, &seams.positions, &seams.normals, &seams.indices, PLAIN);
            for g in full {
                whole.draw(camera, &g.positions, &g.normals, &g.indices, PLAIN);
            }
            retention(front, whole)
        });
        each(Frame { report, draw_ms, since_open_ms, rgba: opts.pixels.then_some(&rgba[..]), retained, draw, nodes_hidden })?;
    }
    Ok(())
}
