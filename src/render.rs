//! A software rasterizer for looking at meshes and measuring what streaming changes on screen:
//! triangles seen by a [`Camera`] are drawn with a headlight into an RGBA8 image with a depth buffer.
//!
//! Faces are transformed to clip space and clipped (near and far planes, and a guard band around
//! the sides so screen coordinates stay small), then snapped to a fixed-point sub-pixel grid and
//! filled with exact integer edge functions under the top-left rule: faces sharing an edge neither
//! overlap nor leave cracks. Depth is z/w, interpolated linearly in screen space. Faces are set up
//! in parallel, then filled in parallel by horizontal bands, each band drawing its faces in input
//! order, so the image does not depend on the thread count.
//!
//! [`Strips`] draws the same image without ever holding all of it (for streaming, where memory is
//! what is measured): a few horizontal strips at a time, each with its own small color and depth
//! buffers, handed over row by row when done.

use crate::atomic::write_file;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::format::Wrap;
use crate::texture::sample::MipChain;
use glam::{Vec2, Vec3, Vec4};
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicU8, Ordering};

/// Color of pixels no face covers.
pub const BACKGROUND: [u8; 4] = [28, 30, 36, 255];
/// Share of the color lit regardless of the light direction.
const AMBIENT: f32 = 0.18;

/// Brightness of a surface with normal `n` (any length) lit head-on from `light` (unit).
fn lit(n: Vec3, light: Vec3) -> f32 {
    AMBIENT + (1.0 - AMBIENT) * n.normalize_or_zero().dot(light).max(0.0)
}
/// Sub-pixel bits of the fixed-point vertex grid.
const SUBPIXEL_BITS: u32 = 8;
const SUBPIXEL: f32 = (1 << SUBPIXEL_BITS) as f32;
/// Faces are clipped to |x|, |y| ≤ GUARD · w, so screen coordinates stay within a few viewports.
const GUARD: f32 = 2.0;
/// Rows per band of the parallel fill.
const BAND_ROWS: u32 = 32;
/// Faces per parallel setup task.
const SETUP_CHUNK: usize = 4096;

/// An RGBA8 color buffer with a depth buffer.
pub struct Image {
    pub width: u32,
    pub height: u32,
    /// Row-major, top row first, 4 bytes per pixel.
    pub rgba: Vec<u8>,
    /// Normalized device depth (z/w, -1 near to 1 far) per pixel; +inf where nothing was drawn.
    pub depth: Vec<f32>,
}

/// Faces per batch of [`Image::draw_parts`]: large enough to amortize the parallel passes, small
/// enough that the per-face setup records stay around a megabyte.
pub const BATCH_FACES: usize = 8192;

/// One mesh to draw: triangles (3 indices per face) over positions, optional per-vertex normals,
/// one color, and optionally a texture over per-vertex UVs (texel × color, each channel over 255).
#[derive(Clone, Copy, Debug)]
pub struct Part<'a> {
    pub positions: &'a [Vec3],
    pub normals: &'a [Vec3],
    pub indices: &'a [u32],
    pub color: [u8; 4],
    /// Per vertex, as positions; empty without a texture.
    pub uvs: &'a [Vec2],
    pub texture: Option<&'a MipChain>,
    /// How UVs outside [0, 1] wrap, along u and v.
    pub wrap: [Wrap; 2],
    /// Draw face ids instead of colors: face k's pixels get `first + k` as little-endian RGBA
    /// bytes, unshaded (an id buffer, for measuring what is visible). [`Image::draw_parts`] only.
    pub ids: Option<u32>,
    /// A box holding every position (its node's box), for [`Strips`]'s occlusion test.
    pub bounds: Option<(Vec3, Vec3)>,
}

impl<'a> Part<'a> {
    /// An untextured part.
    pub fn new(positions: &'a [Vec3], normals: &'a [Vec3], indices: &'a [u32], color: [u8; 4]) -> Part<'a> {
        Part { positions, normals, indices, color, uvs: &[], texture: None, wrap: [Wrap::Repeat; 2], ids: None, bounds: None }
    }

    /// This part drawn as face ids from `first` on ([`Part::ids`]).
    pub fn with_ids(self, first: u32) -> Part<'a> {
        Part { ids: Some(first), texture: None, ..self }
    }

    /// This part with a box that holds all its positions: with occlusion culling on, [`Strips`]
    /// skips it wherever the box lies behind what is already drawn.
    pub fn with_bounds(self, lo: Vec3, hi: Vec3) -> Part<'a> {
        Part { bounds: Some((lo, hi)), ..self }
    }

    /// This part with `texture` sampled at `uvs` (one per position; otherwise drawn untextured),
    /// wrapping as `wrap` says.
    pub fn textured(self, uvs: &'a [Vec2], texture: &'a MipChain, wrap: [Wrap; 2]) -> Part<'a> {
        Part { uvs, texture: (uvs.len() == self.positions.len() && !texture.is_empty()).then_some(texture), wrap, ..self }
    }
}

/// A face ready to fill: fixed-point screen vertices with positive area, and linear depth and
/// shade over the screen.
struct Setup {
    x: [i64; 3],
    y: [i64; 3],
    /// Pixel bounds, inclusive.
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
    /// `value(px, py) = v + dx·(px − ox) + dy·(py − oy)` in pixels, for depth and shade, with the
    /// origin at vertex 0.
    origin: [f32; 2],
    z: [f32; 3],
    shade: [f32; 3],
    color: [u8; 4],
    /// Textured faces: u/w, v/w and 1/w over the screen (perspective-correct UVs), the part
    /// (index in the batch) whose texture it samples, and the level chosen for the face.
    tex: Option<TexSetup>,
}

#[derive(Clone, Copy)]
struct TexSetup {
    uw: [f32; 3],
    vw: [f32; 3],
    iw: [f32; 3],
    part: u32,
    level: u32,
}

/// A clip-space vertex with its shade and UV.
#[derive(Clone, Copy)]
struct ClipVertex {
    p: Vec4,
    shade: f32,
    uv: Vec2,
}

/// What a face's setup needs of its part's texture: the part's index in the batch and the chain.
#[derive(Clone, Copy)]
struct FaceTexture<'a> {
    part: u32,
    chain: &'a MipChain,
}

impl Image {
    /// An image cleared to [`BACKGROUND`] with depth +inf; at least 1 × 1.
    pub fn new(width: u32, height: u32) -> Image {
        let (width, height) = (width.max(1), height.max(1));
        let n = width as usize * height as usize;
        let mut image = Image { width, height, rgba: vec![0; 4 * n], depth: vec![f32::INFINITY; n] };
        image.clear();
        image
    }

    /// Back to [`BACKGROUND`] and depth +inf.
    pub fn clear(&mut self) {
        for px in self.rgba.chunks_exact_mut(4) {
            px.copy_from_slice(&BACKGROUND);
        }
        self.depth.fill(f32::INFINITY);
    }

    /// Rasterize triangles (indices into positions, 3 per face) seen by `camera`, with simple
    /// shading (Lambert from a headlight along the view direction + ambient) of `color`. Per-vertex
    /// `normals` (same length as positions) give smooth shading; empty (or any other length) →
    /// flat face normals. Back faces are culled (counter-clockwise front faces). Faces with an
    /// index out of range or a non-finite position are skipped. The viewport is this image; the
    /// camera's own size only sets its aspect ratio. Returns the number of faces drawn (not
    /// culled/clipped away, and reaching at least one pixel center within their bounds).
    pub fn draw(&mut self, camera: &Camera, positions: &[Vec3], normals: &[Vec3], indices: &[u32], color: [u8; 4]) -> usize {
        self.draw_parts(camera, &[Part::new(positions, normals, indices, color)])
    }

    /// [`Image::draw`] for many meshes at once (a streamed front's nodes): parts are gathered into
    /// batches of about [`BATCH_FACES`] faces, each set up and filled in one pass, so that many
    /// small parts cost little more than one large one while temporary memory stays bounded.
    /// Parts are drawn in order; returns the faces drawn over all parts.
    pub fn draw_parts(&mut self, camera: &Camera, parts: &[Part<'_>]) -> usize {
        let mut drawn = 0;
        let mut start = 0;
        while start < parts.len() {
            let (mut end, mut faces) = (start + 1, parts[start].indices.len() / 3);
            while end < parts.len() && faces + parts[end].indices.len() / 3 <= BATCH_FACES {
                faces += parts[end].indices.len() / 3;
                end += 1;
            }
            drawn += self.draw_batch(camera, &parts[start..end]);
            start = end;
        }
        drawn
    }

    fn draw_batch(&mut self, camera: &Camera, parts: &[Part<'_>]) -> usize {
        if self.rgba.len() != 4 * self.depth.len() || self.depth.len() != self.width as usize * self.height as usize {
            return 0;
        }
        let view_projection = camera.view_projection();
        let light = -camera.forward();
        let vertex_shades: Vec<Vec<f32>> = parts
            .par_iter()
            .map(|p| if p.normals.len() == p.positions.len() { p.normals.iter().map(|&n| lit(n, light)).collect() } else { Vec::new() })
            .collect();
        let (width, height) = (self.width, self.height);
        let work: Vec<(usize, usize)> =
            parts.iter().enumerate().flat_map(|(k, p)| (0..(p.indices.len() / 3).div_ceil(SETUP_CHUNK)).map(move |c| (k, c))).collect();
        let chunks: Vec<(Vec<Setup>, usize)> = work
            .par_iter()
            .map_init(Clip::default, |clip, &(k, c)| {
                let Part { positions, indices, color, uvs, texture, ids, .. } = parts[k];
                let tex = texture.map(|chain| FaceTexture { part: k as u32, chain });
                let vertex_shade = &vertex_shades[k];
                let face_count = indices.len() / 3;
                let mut out = Vec::new();
                let mut drawn = 0;
                for f in c * SETUP_CHUNK..((c + 1) * SETUP_CHUNK).min(face_count) {
                    let tri = [indices[3 * f], indices[3 * f + 1], indices[3 * f + 2]];
                    if tri.iter().any(|&i| i as usize >= positions.len()) {
                        continue;
                    }
                    let p = tri.map(|i| positions[i as usize]);
                    if !p.iter().all(|v| v.is_finite()) {
                        continue;
                    }
                    let shade = if ids.is_some() {
                        [1.0; 3]
                    } else if vertex_shade.is_empty() {
                        [lit((p[1] - p[0]).cross(p[2] - p[0]), light); 3]
                    } else {
                        tri.map(|i| vertex_shade[i as usize])
                    };
                    let color = ids.map_or(color, |first| first.wrapping_add(f as u32).to_le_bytes());
                    let uv = |k: usize| if tex.is_some() { uvs[tri[k] as usize] } else { Vec2::ZERO };
                    let corners: [ClipVertex; 3] =
                        std::array::from_fn(|k| ClipVertex { p: view_projection * p[k].extend(1.0), shade: shade[k], uv: uv(k) });
                    let before = out.len();
                    setup_face(corners, width, height, color, tex, &mut out, clip);
                    drawn += (out.len() > before) as usize;
                }
                (out, drawn)
            })
            .collect();
        let drawn = chunks.iter().map(|c| c.1).sum();
        let faces: Vec<Setup> = chunks.into_iter().flat_map(|c| c.0).collect();

        let bands = height.div_ceil(BAND_ROWS) as usize;
        let mut binned: Vec<Vec<u32>> = vec![Vec::new(); bands];
        for (i, s) in faces.iter().enumerate() {
            for band in &mut binned[(s.y0 / BAND_ROWS) as usize..=(s.y1 / BAND_ROWS) as usize] {
                band.push(i as u32);
            }
        }
        let row_pixels = width as usize * BAND_ROWS as usize;
        self.rgba.par_chunks_mut(4 * row_pixels).zip(self.depth.par_chunks_mut(row_pixels)).zip(binned.par_iter()).enumerate().for_each(
            |(band, ((rgba, depth), list))| {
                let first_row = band as u32 * BAND_ROWS;
                let last_row = (first_row + BAND_ROWS).min(height) - 1;
                for &i in list {
                    fill(&faces[i as usize], width, first_row, last_row, rgba, depth, parts);
                }
            },
        );
        drawn
    }

    /// Pixels covered by the model (depth written), for comparisons.
    pub fn coverage(&self) -> Vec<bool> {
        self.depth.iter().map(|d| d.is_finite()).collect()
    }

    /// Write the image as an RGBA PNG, all or nothing.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        write_rgba_png(path, self.width, self.height, &self.rgba)
    }

    /// The image as an RGBA PNG file's bytes; empty if the fields disagree on the size.
    pub fn encode_png(&self) -> Vec<u8> {
        encode(self.width, self.height, &self.rgba).unwrap_or_default()
    }
}

/// Write `width` × `height` RGBA8 pixels (top row first) as a PNG, all or nothing.
pub fn write_rgba_png(path: &Path, width: u32, height: u32, rgba: &[u8]) -> Result<()> {
    let bytes = encode(width, height, rgba).map_err(|e| Error::invalid(path, None, format!("cannot encode PNG: {e}")))?;
    write_file(path, |w| w.write_all(&bytes))
}

fn encode(width: u32, height: u32, rgba: &[u8]) -> std::result::Result<Vec<u8>, png::EncodingError> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(rgba)?;
    writer.finish()?;
    Ok(bytes)
}

/// Rows per strip of [`Strips`].
pub const STRIP_ROWS: u32 = 32;
/// Faces per block of a part: the unit of the per-strip tests.
pub const BLOCK_FACES: usize = 16;
// A block's faces found hidden are bits of a u32.
const _: () = assert!(BLOCK_FACES <= 32);
/// Rows a face's pixels may reach beyond the rows of its corners' projections (rounding and
/// clipping error), for the strip test.
const ROW_MARGIN: i32 = 2;
/// Row of a vertex whose faces are skipped (non-finite in clip space).
const BAD_ROW: i32 = i32::MIN;
/// Row of a vertex with no usable screen row (at or behind the eye plane): its faces are set up
/// in every strip.
const NO_ROW: i32 = i32::MIN + 1;
/// Rows of a block no strip test can rule out.
const ALL_ROWS: (i32, i32) = (i32::MIN, i32::MAX);

/// Where the faces of a block of [`BLOCK_FACES`] may reach on screen, found once per frame from
/// their corners: rows and columns (conservatively: a few pixels more each way) and the least
/// depth of a corner; `z` is −∞ where a corner lies before the near plane or behind the eye (no
/// occlusion test then).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Block {
    rows: (i32, i32),
    cols: (i32, i32),
    z: f32,
}

/// A block no test can rule out.
const ANYWHERE: Block = Block { rows: ALL_ROWS, cols: ALL_ROWS, z: f32::NEG_INFINITY };
/// Bounds that hold nothing yet (rows empty).
const NOWHERE: Block = Block { rows: (i32::MAX, i32::MIN), cols: (i32::MAX, i32::MIN), z: f32::INFINITY };

/// What occlusion culling found of a block or part this frame: not tested, hidden in some strip
/// and drawn in none, or drawn.
const UNTESTED: u8 = 0;
const HIDDEN: u8 = 1;
const DRAWN: u8 = 2;

/// Whether every pixel of `rows` × `cols` (clamped to the strip `first..=last` and the image) holds
/// a depth below `z`; None when no pixel of the strip is in the region.
fn behind(rows: (i32, i32), cols: (i32, i32), z: f32, first: u32, last: u32, width: u32, depth: &[f32]) -> Option<bool> {
    let (a, b) = (rows.0.max(first as i32), rows.1.min(last as i32));
    let (x0, x1) = (cols.0.max(0), cols.1.min(width as i32 - 1));
    if a > b || x0 > x1 {
        return None;
    }
    // The middle pixel first: where something shows, it most often shows there.
    let middle = ((a + b) / 2 - first as i32) as usize * width as usize + ((x0 + x1) / 2) as usize;
    if depth[middle] >= z {
        return Some(false);
    }
    Some((a..=b).all(|row| {
        let line = (row as u32 - first) as usize * width as usize;
        depth[line + x0 as usize..=line + x1 as usize].iter().all(|&d| d < z)
    }))
}

/// Per-frame constants of a strip draw.
struct StripFrame<'a> {
    parts: &'a [Part<'a>],
    view_projection: glam::Mat4,
    light: Vec3,
    width: u32,
    height: u32,
    /// Per part, with occlusion culling on: where its box projects ([`Hull`]).
    hulls: &'a [Hull],
    /// Per part, and per face ([`BLOCK_FACES`] entries per block, parts one after the other):
    /// [`UNTESTED`], [`HIDDEN`] or [`DRAWN`].
    drawn: &'a [AtomicU8],
    face_state: &'a [AtomicU8],
    /// Per block, [`BLOCK_FACES`] entries: each face's bounds.
    face_bounds: &'a [Block],
}

/// A part's box on screen, for the occlusion test: pixels `x0..=x1` × `y0..=y1` (a pixel wider
/// than the corners' projections each way) and the nearest depth any of its points can have.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Hull {
    /// No box, or one reaching to or behind the near plane: always drawn.
    Unknown,
    /// The box projects outside the image: nothing of the part can be drawn.
    Outside,
    Rect {
        x0: u32,
        x1: u32,
        y0: u32,
        y1: u32,
        z: f32,
    },
}

/// Depth below a box's least corner depth that a fragment of a face inside it can still reach
/// through rounding; the occlusion test leaves this much to spare.
const HULL_DEPTH_MARGIN: f32 = 1e-5;

impl Hull {
    fn of(part: &Part<'_>, view_projection: &glam::Mat4, width: u32, height: u32) -> Hull {
        let Some((lo, hi)) = part.bounds else { return Hull::Unknown };
        let (mut x0, mut x1, mut y0, mut y1, mut z) = (f32::INFINITY, f32::NEG_INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::INFINITY);
        for k in 0..8 {
            let c =
                Vec3::new(if k & 1 == 0 { lo.x } else { hi.x }, if k & 2 == 0 { lo.y } else { hi.y }, if k & 4 == 0 { lo.z } else { hi.z });
            let clip = *view_projection * c.extend(1.0);
            // Depth along the view is linear over the box, so its least value is at a corner; a
            // corner at or before the near plane leaves the box's depth unbounded below.
            if !clip.is_finite() || clip.w <= 0.0 || clip.z < -clip.w {
                return Hull::Unknown;
            }
            let n = clip.truncate() / clip.w;
            let (px, py) = ((n.x + 1.0) * 0.5 * width as f32, (1.0 - n.y) * 0.5 * height as f32);
            (x0, x1, y0, y1, z) = (x0.min(px), x1.max(px), y0.min(py), y1.max(py), z.min(n.z));
        }
        if !(x0.is_finite() && x1.is_finite() && y0.is_finite() && y1.is_finite() && z.is_finite()) {
            return Hull::Unknown;
        }
        let (x0, y0) = ((x0.floor() - 1.0).max(0.0), (y0.floor() - 1.0).max(0.0));
        let (x1, y1) = ((x1.ceil() + 1.0).min(width as f32 - 1.0), (y1.ceil() + 1.0).min(height as f32 - 1.0));
        if x0 > x1 || y0 > y1 {
            return Hull::Outside;
        }
        Hull::Rect { x0: x0 as u32, x1: x1 as u32, y0: y0 as u32, y1: y1 as u32, z: z - HULL_DEPTH_MARGIN }
    }

    /// Whether nothing of the part can show in the strip whose rows `first..=last` have `depth`:
    /// every pixel its box reaches there already holds something nearer than the box. A part
    /// whose box misses these rows is hidden here too (it has no pixels in them).
    fn hidden(&self, first: u32, last: u32, width: u32, depth: &[f32]) -> bool {
        match *self {
            Hull::Unknown => false,
            Hull::Outside => true,
            Hull::Rect { x0, x1, y0, y1, z } => {
                behind((y0 as i32, y1 as i32), (x0 as i32, x1 as i32), z, first, last, width, depth) != Some(false)
            }
        }
    }

    fn reaches(&self, first: u32, last: u32) -> bool {
        match *self {
            Hull::Unknown => true,
            Hull::Outside => false,
            Hull::Rect { y0, y1, .. } => y0 <= last && y1 >= first,
        }
    }
}

impl StripFrame<'_> {
    fn lit(&self, n: Vec3) -> f32 {
        lit(n, self.light)
    }

    /// A position in clip space and its screen row: the floor of its screen y, clamped to a few
    /// rows around the image; or [`BAD_ROW`], [`NO_ROW`].
    fn transform(&self, p: Vec3) -> (Vec4, i32) {
        let clip = self.view_projection * p.extend(1.0);
        let row = if !clip.is_finite() {
            BAD_ROW
        } else if clip.w > 0.0 {
            // With w > 0 at all three corners, every clipped point projects between them: the
            // face's rows lie within its corners' rows.
            let y = (1.0 - clip.y / clip.w) * 0.5 * self.height as f32;
            if y.is_finite() {
                y.floor().clamp(-16.0, self.height as f32 + 16.0) as i32
            } else {
                NO_ROW
            }
        } else {
            NO_ROW
        };
        (clip, row)
    }

    /// Corner `i` of `part` from the cache, transformed (and shaded when `smooth`) on a miss.
    fn corner(&self, part: &Part<'_>, i: u32, smooth: bool, cache: &mut VertexCache) -> Corner {
        let slot = &mut cache.entries[i as usize % CACHE_SIZE];
        if slot.index != i || slot.generation != cache.generation {
            let (p, row) = self.transform(part.positions[i as usize]);
            let shade = if smooth { self.lit(part.normals[i as usize]) } else { 0.0 };
            let uv = if part.texture.is_some() { part.uvs[i as usize] } else { Vec2::ZERO };
            *slot = Corner { clip: ClipVertex { p, shade, uv }, row, index: i, generation: cache.generation };
        }
        *slot
    }

    /// Where the faces of each block of `part` may reach ([`Block`]; rows empty when
    /// first > last), into `out` (one per [`BLOCK_FACES`] faces).
    /// With `faces` (occlusion culling), also each face's own ([`NOWHERE`] for a face not drawn),
    /// [`BLOCK_FACES`] entries per block.
    fn block_bounds(&self, part: &Part<'_>, cache: &mut VertexCache, out: &mut [Block], mut faces: Option<&mut [Block]>) {
        cache.next_generation();
        let n = part.positions.len();
        for (k, (block, bounds)) in part.indices.chunks(3 * BLOCK_FACES).zip(out).enumerate() {
            let mut b = NOWHERE;
            for (j, tri) in block.chunks_exact(3).enumerate() {
                let f = self.face_bounds(part, [tri[0], tri[1], tri[2]], n, false, cache);
                if let Some(faces) = faces.as_deref_mut() {
                    faces[k * BLOCK_FACES + j] = f.unwrap_or(NOWHERE);
                }
                match f {
                    None => continue,
                    Some(_) if b.rows == ALL_ROWS => {}
                    Some(f) if f.rows == ALL_ROWS => b = ANYWHERE,
                    Some(f) => {
                        b.rows = (b.rows.0.min(f.rows.0), b.rows.1.max(f.rows.1));
                        b.cols = (b.cols.0.min(f.cols.0), b.cols.1.max(f.cols.1));
                        b.z = b.z.min(f.z);
                    }
                }
            }
            if !b.z.is_finite() {
                b.z = f32::NEG_INFINITY;
            }
            *bounds = b;
        }
    }

    /// Where face `tri` of `part` may reach ([`Block`] of one face; [`ANYWHERE`] when a corner
    /// has no screen row), or None when it is not drawn at all (an index past `n` vertices, a
    /// corner not finite). `smooth` as the strip draws the part, for the cache's sake.
    fn face_bounds(&self, part: &Part<'_>, tri: [u32; 3], n: usize, smooth: bool, cache: &mut VertexCache) -> Option<Block> {
        if tri.iter().any(|&i| i as usize >= n) {
            return None;
        }
        let c = tri.map(|i| self.corner(part, i, smooth, cache));
        let r = c.map(|c| c.row);
        if r.contains(&BAD_ROW) {
            return None;
        }
        if r.contains(&NO_ROW) {
            return Some(ANYWHERE);
        }
        let edge = self.width as f32 + 16.0;
        let mut b = Block {
            rows: (r[0].min(r[1]).min(r[2]) - ROW_MARGIN, r[0].max(r[1]).max(r[2]) + ROW_MARGIN),
            cols: (i32::MAX, i32::MIN),
            z: f32::INFINITY,
        };
        for p in c.map(|c| c.clip.p) {
            // w > 0 here (the row is usable); a corner before the near plane has a depth below
            // -1 that clipping replaces: no depth bound then.
            let x = ((p.x / p.w + 1.0) * 0.5 * self.width as f32).clamp(-16.0, edge).floor() as i32;
            b.cols = (b.cols.0.min(x - ROW_MARGIN), b.cols.1.max(x + ROW_MARGIN));
            b.z = if p.z < -p.w { f32::NEG_INFINITY } else { b.z.min(p.z / p.w) };
        }
        Some(b)
    }

    /// Which faces of a block (bit j: face j; `faces`, their bounds from [`Strips::face_bounds`])
    /// lie behind the depths of the strip of `rows` by their own rectangle and least corner depth,
    /// or have no pixel there: the block test made tight where one rectangle for the block reaches
    /// pixels none of its faces covers, and face by face where some of its faces show. Faces in
    /// curve order are hidden in runs: where the first and the last face both show, the others are
    /// taken to show too, untested (testing every face of every block that shows cost more than
    /// drawing what it finds).
    fn faces_behind(&self, faces: &[Block], rows: (u32, u32), depth: &[f32]) -> u32 {
        let test = |f: &Block| {
            if f.rows.0 > f.rows.1 {
                true
            } else if f.rows == ALL_ROWS || !f.z.is_finite() {
                false
            } else {
                behind(f.rows, f.cols, f.z - HULL_DEPTH_MARGIN, rows.0, rows.1, self.width, depth) != Some(false)
            }
        };
        let last = faces.len() - 1;
        if !test(&faces[0]) && !test(&faces[last]) {
            return 0;
        }
        faces.iter().enumerate().fold(0, |hidden, (j, f)| hidden | (test(f) as u32) << j)
    }

    /// Draw every face reaching strip `strip` (rows `strip · STRIP_ROWS ..`) into its buffers, in
    /// input order, as [`Image::draw_parts`] draws them into the whole image. `blocks` are the
    /// parts' block rows, one after the other. Counts the faces whose topmost pixel row lies in
    /// this strip, so that each drawn face counts once.
    fn draw_strip(&self, strip: u32, blocks: &[Block], rgba: &mut [u8], depth: &mut [f32], s: &mut StripScratch) -> DrawStats {
        let (width, height) = (self.width, self.height);
        let first = strip * STRIP_ROWS;
        let last = (first + STRIP_ROWS).min(height) - 1;
        let (lo, hi) = (first as i32, last as i32);
        let mut stats = DrawStats::default();
        let mut block = 0;
        for (part_index, part) in self.parts.iter().enumerate() {
            let tex = part.texture.map(|chain| FaceTexture { part: part_index as u32, chain });
            let count = (part.indices.len() / 3).div_ceil(BLOCK_FACES);
            let first_block = block;
            let ranges = &blocks[block..block + count];
            block += count;
            if ranges.iter().all(|b| b.rows.1 < lo || b.rows.0 > hi) {
                continue;
            }
            let occlusion = !self.hulls.is_empty();
            if let Some(h) = self.hulls.get(part_index) {
                if !h.reaches(first, last) {
                    continue;
                }
                if h.hidden(first, last, width, depth) {
                    self.drawn[part_index].fetch_max(HIDDEN, Ordering::Relaxed);
                    continue;
                }
            }
            let n = part.positions.len();
            let smooth = part.normals.len() == n;
            s.cache.next_generation();
            for (b, bounds) in ranges.iter().enumerate() {
                if bounds.rows.1 < lo || bounds.rows.0 > hi {
                    continue;
                }
                let end = (3 * (b + 1) * BLOCK_FACES).min(part.indices.len() / 3 * 3);
                let faces = &part.indices[3 * b * BLOCK_FACES..end];
                // The block's faces' entries in `face_state` and `face_bounds`.
                let at = (first_block + b) * BLOCK_FACES;
                let slots = at..at + faces.len() / 3;
                // Faces of the block found hidden here, one bit each.
                let mut hidden = 0u32;
                if occlusion {
                    if bounds.z > f32::NEG_INFINITY {
                        let all = u32::MAX >> (32 - slots.len());
                        match behind(bounds.rows, bounds.cols, bounds.z - HULL_DEPTH_MARGIN, first, last, width, depth) {
                            // Outside the image: its faces have no pixel here.
                            None => continue,
                            Some(true) => hidden = all,
                            Some(false) => hidden = self.faces_behind(&self.face_bounds[slots.clone()], (first, last), depth),
                        }
                        if hidden == all {
                            self.drawn[part_index].fetch_max(HIDDEN, Ordering::Relaxed);
                            for f in &self.face_state[slots] {
                                f.fetch_max(HIDDEN, Ordering::Relaxed);
                            }
                            continue;
                        }
                    }
                    self.drawn[part_index].store(DRAWN, Ordering::Relaxed);
                }
                for (j, tri) in faces.chunks_exact(3).enumerate() {
                    let face = occlusion.then(|| &self.face_state[at + j]);
                    if hidden >> j & 1 == 1 {
                        if let Some(f) = face {
                            f.fetch_max(HIDDEN, Ordering::Relaxed);
                        }
                        continue;
                    }
                    let tri = [tri[0], tri[1], tri[2]];
                    if tri.iter().any(|&i| i as usize >= n) {
                        continue;
                    }
                    let v = tri.map(|i| self.corner(part, i, smooth, &mut s.cache));
                    if v.iter().any(|v| v.row == BAD_ROW) {
                        continue;
                    }
                    if v.iter().all(|v| v.row != NO_ROW) {
                        let rows = v.map(|v| v.row);
                        let (a, b) = (rows[0].min(rows[1]).min(rows[2]) - ROW_MARGIN, rows[0].max(rows[1]).max(rows[2]) + ROW_MARGIN);
                        if b < lo || a > hi {
                            continue;
                        }
                    }
                    // Drawn here: a face hidden in another strip is not hidden.
                    if let Some(f) = face {
                        f.store(DRAWN, Ordering::Relaxed);
                    }
                    let mut corners = v.map(|v| v.clip);
                    if !smooth {
                        let p = tri.map(|i| part.positions[i as usize]);
                        let shade = self.lit((p[1] - p[0]).cross(p[2] - p[0]));
                        for c in &mut corners {
                            c.shade = shade;
                        }
                    }
                    s.setups.clear();
                    setup_face(corners, width, height, part.color, tex, &mut s.setups, &mut s.clip);
                    if s.setups.iter().map(|f| f.y0).min().is_some_and(|top| top / STRIP_ROWS == strip) {
                        stats.faces += 1;
                    }
                    for f in &s.setups {
                        if f.y1 >= first && f.y0 <= last {
                            let (fragments, writes) = fill(f, width, first, last, rgba, depth, self.parts);
                            stats.fragments += fragments;
                            stats.writes += writes;
                        }
                    }
                }
            }
        }
        stats.covered = depth.iter().filter(|d| d.is_finite()).count() as u64;
        stats
    }
}

/// Entries of a [`VertexCache`]: faces of a block mostly share nearby vertices.
const CACHE_SIZE: usize = 1024;

/// A transformed corner, cached under its vertex index.
#[derive(Clone, Copy)]
struct Corner {
    clip: ClipVertex,
    row: i32,
    index: u32,
    generation: u32,
}

/// Recently transformed vertices of the current part, direct-mapped by index: a small fixed
/// buffer however large the part is.
struct VertexCache {
    entries: Vec<Corner>,
    generation: u32,
}

impl Default for VertexCache {
    fn default() -> Self {
        let none = Corner { clip: ClipVertex { p: Vec4::ZERO, shade: 0.0, uv: Vec2::ZERO }, row: BAD_ROW, index: 0, generation: 0 };
        VertexCache { entries: vec![none; CACHE_SIZE], generation: 0 }
    }
}

impl VertexCache {
    /// Forget every entry (a new part, or new shading).
    fn next_generation(&mut self) {
        if self.generation == u32::MAX {
            self.entries.iter_mut().for_each(|e| e.generation = 0);
            self.generation = 0;
        }
        self.generation += 1;
    }
}

/// Reusable buffers of one strip in flight.
#[derive(Default)]
struct StripScratch {
    cache: VertexCache,
    setups: Vec<Setup>,
    clip: Clip,
}

/// One strip in flight: its color and depth rows and scratch.
#[derive(Default)]
struct Slot {
    rgba: Vec<u8>,
    depth: Vec<f32>,
    scratch: StripScratch,
}

/// A renderer that never holds a whole frame: the image is drawn in horizontal strips of
/// [`STRIP_ROWS`] rows, a few strips at a time in parallel, each handed over as soon as it is
/// done. Only the strips in flight have color and depth buffers; faces are tested against a
/// strip by blocks, whose rows are found once per frame. Draws the same image as
/// [`Image::draw_parts`] on a cleared image, row for row. Buffers are kept between frames.
pub struct Strips {
    width: u32,
    height: u32,
    slots: Vec<Slot>,
    /// Where each block of [`BLOCK_FACES`] faces reaches, parts one after the other (this frame).
    blocks: Vec<Block>,
    /// Each part's first block, and one past the last part's.
    block_start: Vec<usize>,
    occlusion: bool,
    hulls: Vec<Hull>,
    drawn: Vec<AtomicU8>,
    /// With occlusion culling, [`BLOCK_FACES`] per block: each face's bounds and state (this frame).
    face_bounds: Vec<Block>,
    face_state: Vec<AtomicU8>,
    stats: DrawStats,
}

/// What a [`Strips::draw`] did: its faces, overdraw and what occlusion culling skipped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DrawStats {
    /// Faces set up and filled, each counted once.
    pub faces: usize,
    /// Pixels inside drawn faces, and those of them that passed the depth test (were shaded).
    pub fragments: u64,
    pub writes: u64,
    /// Pixels some face covers.
    pub covered: u64,
    /// Parts with bounds skipped by the occlusion test in every strip their box reaches; faces
    /// skipped by it (their part, their block or they alone) in every strip and drawn in none.
    pub parts_hidden: usize,
    pub faces_hidden: u64,
}

impl DrawStats {
    /// Depth-test failures per covered pixel.
    pub fn failures_per_pixel(&self) -> f64 {
        (self.fragments - self.writes) as f64 / self.covered.max(1) as f64
    }

    /// Shaded fragments per covered pixel (1 when every pixel is shaded once).
    pub fn writes_per_pixel(&self) -> f64 {
        self.writes as f64 / self.covered.max(1) as f64
    }
}

impl std::ops::Add for DrawStats {
    type Output = DrawStats;
    fn add(self, o: DrawStats) -> DrawStats {
        DrawStats {
            faces: self.faces + o.faces,
            fragments: self.fragments + o.fragments,
            writes: self.writes + o.writes,
            covered: self.covered + o.covered,
            parts_hidden: self.parts_hidden + o.parts_hidden,
            faces_hidden: self.faces_hidden + o.faces_hidden,
        }
    }
}

impl Strips {
    /// A renderer for `width` × `height` images (at least 1 × 1).
    pub fn new(width: u32, height: u32) -> Strips {
        let (width, height) = (width.max(1), height.max(1));
        let strips = height.div_ceil(STRIP_ROWS) as usize;
        let count = rayon::current_num_threads().clamp(1, strips);
        let n = width as usize * STRIP_ROWS as usize;
        let slots = (0..count).map(|_| Slot { rgba: vec![0; 4 * n], depth: vec![f32::INFINITY; n], ..Slot::default() }).collect();
        Strips {
            width,
            height,
            slots,
            blocks: Vec::new(),
            block_start: Vec::new(),
            occlusion: false,
            hulls: Vec::new(),
            drawn: Vec::new(),
            face_bounds: Vec::new(),
            face_state: Vec::new(),
            stats: DrawStats::default(),
        }
    }

    /// Occlusion culling: parts with [`Part::bounds`] are skipped in a strip where their box lies
    /// behind what the parts before them drew there, and so are blocks of [`BLOCK_FACES`] faces
    /// whose corners' screen rectangle does (at the corners' least depth), and failing that, the
    /// faces whose own rectangles do (at their own corners' least depth; all of a block's faces
    /// are tested when its first or last is found hidden, see `faces_behind`). Drawn front to back,
    /// this skips much of what is hidden; the image is the same pixel for pixel either way (the
    /// tests are conservative).
    pub fn set_occlusion(&mut self, on: bool) {
        self.occlusion = on;
    }

    /// What the last [`Strips::draw`] did.
    pub fn stats(&self) -> DrawStats {
        self.stats
    }

    /// Whether the last [`Strips::draw`] found part `k` hidden (its box or its blocks behind what
    /// was drawn) and drew nothing of it (only with occlusion culling on).
    pub fn part_hidden(&self, k: usize) -> bool {
        self.drawn.get(k).is_some_and(|d| d.load(Ordering::Relaxed) == HIDDEN)
    }

    /// Whether the last [`Strips::draw`] skipped face `f` of part `k` by occlusion, and drew it
    /// in no strip: its part, its block of [`BLOCK_FACES`], or the face itself.
    pub fn face_hidden(&self, k: usize, f: usize) -> bool {
        self.part_hidden(k)
            || self.block_start.get(k).zip(self.block_start.get(k + 1)).is_some_and(|(&b, &end)| {
                let block = b + f / BLOCK_FACES;
                block < end
                    && self.face_state.get(block * BLOCK_FACES + f % BLOCK_FACES).is_some_and(|s| s.load(Ordering::Relaxed) == HIDDEN)
            })
    }

    /// Draw `parts` seen by `camera` over the background, as [`Image::draw_parts`] would on a
    /// cleared image; each strip's rows go to `put_rows(first_row, rgba)` (RGBA8, top row first),
    /// top strip first. Returns the faces drawn.
    pub fn draw(&mut self, camera: &Camera, parts: &[Part<'_>], mut put_rows: impl FnMut(u32, &[u8])) -> usize {
        let (width, height) = (self.width, self.height);
        let view_projection = camera.view_projection();
        let counts = parts.iter().map(|p| (p.indices.len() / 3).div_ceil(BLOCK_FACES));
        self.block_start.clear();
        self.block_start.push(0);
        for c in counts.clone() {
            self.block_start.push(self.block_start.last().unwrap_or(&0) + c);
        }
        let total = *self.block_start.last().unwrap_or(&0);
        self.hulls.clear();
        self.drawn.clear();
        self.face_state.clear();
        if self.occlusion {
            self.hulls.extend(parts.iter().map(|p| Hull::of(p, &view_projection, width, height)));
            self.drawn.extend(parts.iter().map(|_| AtomicU8::new(UNTESTED)));
            self.face_state.extend((0..total * BLOCK_FACES).map(|_| AtomicU8::new(UNTESTED)));
        }
        let frame = StripFrame {
            parts,
            view_projection,
            light: -camera.forward(),
            width,
            height,
            hulls: &self.hulls,
            drawn: &self.drawn,
            face_bounds: &[],
            face_state: &self.face_state,
        };
        // Scratch is sized here, so that the workers do not allocate (their arenas would keep
        // the memory).
        for slot in &mut self.slots {
            let s = &mut slot.scratch;
            s.setups.reserve(16);
            for v in [&mut s.clip.polygon, &mut s.clip.clipped] {
                v.reserve(16);
            }
            s.clip.d.reserve(16);
            s.clip.screen.reserve(16);
        }
        self.blocks.clear();
        self.blocks.resize(total, ANYWHERE);
        self.face_bounds.clear();
        if self.occlusion {
            self.face_bounds.resize(total * BLOCK_FACES, NOWHERE);
        }
        // Each slot finds the block bounds of every slots.len()-th part.
        let mut per_part: Vec<(&mut [Block], Option<&mut [Block]>)> = Vec::with_capacity(parts.len());
        let (mut rest, mut faces_rest) = (&mut self.blocks[..], &mut self.face_bounds[..]);
        for c in counts {
            let (head, tail) = rest.split_at_mut(c);
            rest = tail;
            let faces = if faces_rest.is_empty() {
                None
            } else {
                let (head, tail) = std::mem::take(&mut faces_rest).split_at_mut(c * BLOCK_FACES);
                faces_rest = tail;
                Some(head)
            };
            per_part.push((head, faces));
        }
        let stride = self.slots.len();
        type Lane<'p, 'b> = Vec<(&'p Part<'p>, (&'b mut [Block], Option<&'b mut [Block]>))>;
        let mut lanes: Vec<Lane> = (0..stride).map(|_| Vec::new()).collect();
        for (k, (part, out)) in parts.iter().zip(per_part).enumerate() {
            lanes[k % stride].push((part, out));
        }
        self.slots.par_iter_mut().zip(lanes).for_each(|(slot, lane)| {
            for (part, (out, faces)) in lane {
                frame.block_bounds(part, &mut slot.scratch.cache, out, faces);
            }
        });
        let frame = StripFrame { face_bounds: &self.face_bounds, ..frame };
        let strips = height.div_ceil(STRIP_ROWS);
        let blocks = &self.blocks;
        let mut stats = DrawStats::default();
        for wave in (0..strips).step_by(self.slots.len()) {
            let busy = (strips - wave).min(self.slots.len() as u32) as usize;
            stats = stats
                + self.slots[..busy]
                    .par_iter_mut()
                    .enumerate()
                    .map(|(k, slot)| {
                        let strip = wave + k as u32;
                        let n = (width * (((strip + 1) * STRIP_ROWS).min(height) - strip * STRIP_ROWS)) as usize;
                        for px in slot.rgba[..4 * n].chunks_exact_mut(4) {
                            px.copy_from_slice(&BACKGROUND);
                        }
                        slot.depth[..n].fill(f32::INFINITY);
                        frame.draw_strip(strip, blocks, &mut slot.rgba[..4 * n], &mut slot.depth[..n], &mut slot.scratch)
                    })
                    .reduce(DrawStats::default, |a, b| a + b);
            for (k, slot) in self.slots[..busy].iter().enumerate() {
                let strip = wave + k as u32;
                let n = (width * (((strip + 1) * STRIP_ROWS).min(height) - strip * STRIP_ROWS)) as usize;
                put_rows(strip * STRIP_ROWS, &slot.rgba[..4 * n]);
            }
        }
        self.stats = stats;
        for (k, part) in parts.iter().enumerate() {
            let faces = part.indices.len() / 3;
            if self.part_hidden(k) {
                self.stats.parts_hidden += 1;
                self.stats.faces_hidden += faces as u64;
            } else if self.occlusion {
                // A block skipped whole marks its faces too; entries past a part's last face stay untested.
                let states = &self.face_state[self.block_start[k] * BLOCK_FACES..self.block_start[k + 1] * BLOCK_FACES];
                self.stats.faces_hidden += states.iter().filter(|s| s.load(Ordering::Relaxed) == HIDDEN).count() as u64;
            }
        }
        self.stats.faces
    }
}

/// A screen vertex: x right and y down in pixels, depth z/w, shade, and u/w, v/w, 1/w.
type Screen = (f32, f32, f32, f32, [f32; 3]);

/// Reusable buffers of [`setup_face`]'s clipping, so that drawing allocates nothing per face.
#[derive(Default)]
struct Clip {
    polygon: Vec<ClipVertex>,
    clipped: Vec<ClipVertex>,
    d: Vec<f32>,
    screen: Vec<Screen>,
}

/// Clip a face, cull it if it faces away, and append its fill setups (none, or one per triangle of
/// the clipped polygon).
fn setup_face(
    corners: [ClipVertex; 3],
    width: u32,
    height: u32,
    color: [u8; 4],
    tex: Option<FaceTexture>,
    out: &mut Vec<Setup>,
    clip: &mut Clip,
) {
    if !corners.iter().all(|c| c.p.is_finite()) {
        return;
    }
    // Inside each plane where plane · p ≥ 0: near, far, left, right, bottom, top.
    const PLANES: [Vec4; 6] = [
        Vec4::new(0.0, 0.0, 1.0, 1.0),
        Vec4::new(0.0, 0.0, -1.0, 1.0),
        Vec4::new(1.0, 0.0, 0.0, GUARD),
        Vec4::new(-1.0, 0.0, 0.0, GUARD),
        Vec4::new(0.0, 1.0, 0.0, GUARD),
        Vec4::new(0.0, -1.0, 0.0, GUARD),
    ];
    let (w, h) = (width as f32, height as f32);
    // Screen space: x right, y down, pixel (i, j) covers [i, i+1) × [j, j+1); z is depth.
    let to_screen = |v: &ClipVertex| {
        let n = v.p.truncate() / v.p.w;
        let iw = 1.0 / v.p.w;
        ((n.x + 1.0) * 0.5 * w, (1.0 - n.y) * 0.5 * h, n.z, v.shade, [v.uv.x * iw, v.uv.y * iw, iw])
    };
    let finite = |s: &Screen| s.0.is_finite() && s.1.is_finite() && s.2.is_finite();
    if PLANES.iter().all(|plane| corners.iter().all(|c| plane.dot(c.p) >= 0.0)) {
        let screen = corners.map(|c| to_screen(&c));
        if screen.iter().all(finite) {
            out.extend(setup_triangle(screen, width, height, color, tex));
        }
        return;
    }
    let Clip { polygon, clipped, d, screen } = clip;
    polygon.clear();
    polygon.extend_from_slice(&corners);
    for plane in PLANES {
        d.clear();
        d.extend(polygon.iter().map(|v| plane.dot(v.p)));
        if d.iter().all(|&d| d >= 0.0) {
            continue;
        }
        if d.iter().all(|&d| d < 0.0) {
            return;
        }
        clipped.clear();
        for i in 0..polygon.len() {
            let j = (i + 1) % polygon.len();
            if d[i] >= 0.0 {
                clipped.push(polygon[i]);
            }
            if (d[i] >= 0.0) != (d[j] >= 0.0) {
                let t = d[i] / (d[i] - d[j]);
                clipped.push(ClipVertex {
                    p: polygon[i].p.lerp(polygon[j].p, t),
                    shade: polygon[i].shade + (polygon[j].shade - polygon[i].shade) * t,
                    uv: polygon[i].uv.lerp(polygon[j].uv, t),
                });
            }
        }
        std::mem::swap(polygon, clipped);
    }
    screen.clear();
    screen.extend(polygon.iter().map(to_screen));
    if !screen.iter().all(finite) {
        return;
    }
    for k in 1..screen.len().saturating_sub(1) {
        out.extend(setup_triangle([screen[0], screen[k], screen[k + 1]], width, height, color, tex));
    }
}

/// Snap a screen triangle to the fixed-point grid; `None` if it faces away, has no area, or lies
/// outside the image.
fn setup_triangle(v: [Screen; 3], width: u32, height: u32, color: [u8; 4], tex: Option<FaceTexture>) -> Option<Setup> {
    let mut x = v.map(|s| (s.0 * SUBPIXEL).round() as i64);
    let mut y = v.map(|s| (s.1 * SUBPIXEL).round() as i64);
    let mut z = v.map(|s| s.2);
    let mut shade = v.map(|s| s.3);
    let mut persp = v.map(|s| s.4);
    let area = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
    // Counter-clockwise with y up is negative area with y down; reorder it to positive.
    if area >= 0 {
        return None;
    }
    x.swap(1, 2);
    y.swap(1, 2);
    z.swap(1, 2);
    shade.swap(1, 2);
    persp.swap(1, 2);
    // Pixels whose centers (i + ½) lie within the vertices' bounds.
    let half = 1i64 << (SUBPIXEL_BITS - 1);
    let first = |lo: i64| (lo - half + (1 << SUBPIXEL_BITS) - 1).div_euclid(1 << SUBPIXEL_BITS).max(0);
    let last = |hi: i64, n: u32| (hi - half).div_euclid(1 << SUBPIXEL_BITS).min(n as i64 - 1);
    let (x0, x1) = (first(*x.iter().min()?), last(*x.iter().max()?, width));
    let (y0, y1) = (first(*y.iter().min()?), last(*y.iter().max()?, height));
    if x0 > x1 || y0 > y1 {
        return None;
    }
    // Depth and shade as `[value at vertex 0, d/dx, d/dy]` per pixel.
    let fx = x.map(|v| v as f32 / SUBPIXEL);
    let fy = y.map(|v| v as f32 / SUBPIXEL);
    let (ax, ay, bx, by) = (fx[1] - fx[0], fy[1] - fy[0], fx[2] - fx[0], fy[2] - fy[0]);
    let area = ax * by - ay * bx;
    let plane = |v: [f32; 3]| {
        let (d1, d2) = (v[1] - v[0], v[2] - v[0]);
        [v[0], (d1 * by - d2 * ay) / area, (d2 * ax - d1 * bx) / area]
    };
    let (x0, x1, y0, y1) = (x0 as u32, x1 as u32, y0 as u32, y1 as u32);
    let tex = tex.map(|t| {
        // The level where a texel is about a pixel: the face's full-resolution texels over its pixels.
        let uv = persp.map(|p| Vec2::new(p[0], p[1]) / p[2]);
        let texels = 0.5 * ((uv[1] - uv[0]).perp_dot(uv[2] - uv[0])).abs() as f64 * t.chain.full_texels();
        let pixels = 0.5 * area.abs() as f64;
        TexSetup {
            uw: plane(persp.map(|p| p[0])),
            vw: plane(persp.map(|p| p[1])),
            iw: plane(persp.map(|p| p[2])),
            part: t.part,
            level: t.chain.choose(texels, pixels) as u32,
        }
    });
    Some(Setup { x, y, x0, x1, y0, y1, origin: [fx[0], fy[0]], z: plane(z), shade: plane(shade), color, tex })
}

/// Fill the rows `first_row ..= last_row` of a face into a band of the image.
/// Returns the pixels inside the face (fragments) and those that passed the depth test.
fn fill(s: &Setup, width: u32, first_row: u32, last_row: u32, rgba: &mut [u8], depth: &mut [f32], parts: &[Part<'_>]) -> (u64, u64) {
    let texture = s.tex.and_then(|t| {
        let part = parts.get(t.part as usize)?;
        Some((t, part.texture?, part.wrap))
    });
    let (y0, y1) = (s.y0.max(first_row), s.y1.min(last_row));
    let step = 1i64 << SUBPIXEL_BITS;
    // Edge k runs from vertex k to k + 1; on a top edge (horizontal, going right) or a left edge
    // (going up), centers exactly on the edge are inside, elsewhere they are not.
    let mut edges = [(0i64, 0i64, 0i64); 3];
    for (k, e) in edges.iter_mut().enumerate() {
        let j = (k + 1) % 3;
        let (dx, dy) = (s.x[j] - s.x[k], s.y[j] - s.y[k]);
        let top_left = dy < 0 || (dy == 0 && dx > 0);
        // E(p) = dx·(py − yk) − dy·(px − xk), minus one where the edge itself is outside.
        let px = s.x0 as i64 * step + step / 2;
        let e0 = dx * (y0 as i64 * step + step / 2 - s.y[k]) - dy * (px - s.x[k]) - (!top_left) as i64;
        *e = (e0, -dy * step, dx * step);
    }
    let [r, g, b, a] = s.color.map(|c| c as f32);
    let (mut fragments, mut writes) = (0u64, 0u64);
    for (row, py) in (y0..=y1).enumerate() {
        let mut e = edges.map(|(e0, _, per_row)| e0 + per_row * row as i64);
        let cy = py as f32 + 0.5 - s.origin[1];
        let line = (py - first_row) as usize * width as usize;
        for px in s.x0..=s.x1 {
            if (e[0] | e[1] | e[2]) >= 0 {
                fragments += 1;
                let cx = px as f32 + 0.5 - s.origin[0];
                let z = s.z[0] + s.z[1] * cx + s.z[2] * cy;
                let i = line + px as usize;
                if z < depth[i] {
                    writes += 1;
                    depth[i] = z;
                    let l = (s.shade[0] + s.shade[1] * cx + s.shade[2] * cy).clamp(0.0, 1.0);
                    let px = match texture {
                        None => [(r * l) as u8, (g * l) as u8, (b * l) as u8, a as u8],
                        Some((t, chain, wrap)) => {
                            let at = |p: [f32; 3]| p[0] + p[1] * cx + p[2] * cy;
                            let iw = at(t.iw);
                            let texel = chain.sample(t.level as usize, at(t.uw) / iw, at(t.vw) / iw, wrap);
                            let k = l / 255.0;
                            [(texel[0] as f32 * r * k) as u8, (texel[1] as f32 * g * k) as u8, (texel[2] as f32 * b * k) as u8, a as u8]
                        }
                    };
                    rgba[4 * i..4 * i + 4].copy_from_slice(&px);
                }
            }
            for (k, ek) in e.iter_mut().enumerate() {
                *ek += edges[k].1;
            }
        }
    }
    (fragments, writes)
}

/// A stable, distinct color per id (for group and level colors): hues a golden angle apart, with
/// saturation and brightness varied so that ids a full turn apart still differ.
pub fn palette(id: u32) -> [u8; 4] {
    let hue = (id as f64 * 0.618_033_988_749_895).fract() * 6.0;
    let saturation = [0.65, 0.45, 0.8][(id / 7 % 3) as usize];
    let value = [0.95, 0.8][(id / 3 % 2) as usize];
    let c = value * saturation;
    let x = c * (1.0 - (hue % 2.0 - 1.0).abs());
    let (r, g, b) = match hue as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let byte = |v: f64| ((v + value - c) * 255.0).round() as u8;
    [byte(r), byte(g), byte(b), 255]
}

/// Share of covered pixels whose color differs by more than `tolerance` (max channel) between two
/// images of the same size, over pixels covered in either: the "shape retention" measure. Images
/// of different sizes differ entirely (1); two empty images not at all (0).
pub fn changed_share(a: &Image, b: &Image, tolerance: u8) -> f64 {
    if a.width != b.width || a.height != b.height || a.rgba.len() != b.rgba.len() || a.depth.len() != b.depth.len() {
        return 1.0;
    }
    let (mut covered, mut changed) = (0usize, 0usize);
    for (i, (da, db)) in a.depth.iter().zip(&b.depth).enumerate() {
        if !da.is_finite() && !db.is_finite() {
            continue;
        }
        covered += 1;
        let (pa, pb) = (&a.rgba[4 * i..4 * i + 4], &b.rgba[4 * i..4 * i + 4]);
        changed += pa.iter().zip(pb).any(|(x, y)| x.abs_diff(*y) > tolerance) as usize;
    }
    if covered == 0 {
        0.0
    } else {
        changed as f64 / covered as f64
    }
}

/// Crack pixels of a front's image against the full model's from the same camera: pixels the full
/// model covers that the front leaves to the background, where that background is enclosed by the
/// front (not reachable from the picture's edge through background). Silhouette differences reach
/// the edge and do not count; pinholes between nodes that do not meet do.
pub fn crack_pixels(front: &Image, full: &Image) -> u64 {
    crack_mask(front, full).iter().filter(|&&c| c).count() as u64
}

/// Per pixel, whether it is one of [`crack_pixels`] (all false for images of different sizes).
pub fn crack_mask(front: &Image, full: &Image) -> Vec<bool> {
    let (w, h) = (front.width as usize, front.height as usize);
    if front.width != full.width || front.height != full.height || front.depth.len() != w * h || full.depth.len() != w * h {
        return vec![false; front.depth.len()];
    }
    let bg: Vec<bool> = front.depth.iter().map(|d| !d.is_finite()).collect();
    let mut outside = vec![false; w * h];
    let mut stack: Vec<usize> = (0..w).flat_map(|x| [x, (h - 1) * w + x]).chain((0..h).flat_map(|y| [y * w, y * w + w - 1])).collect();
    while let Some(i) = stack.pop() {
        if outside[i] || !bg[i] {
            continue;
        }
        outside[i] = true;
        let (x, y) = (i % w, i / w);
        if x > 0 {
            stack.push(i - 1);
        }
        if x + 1 < w {
            stack.push(i + 1);
        }
        if y > 0 {
            stack.push(i - w);
        }
        if y + 1 < h {
            stack.push(i + w);
        }
    }
    (0..w * h).map(|i| bg[i] && !outside[i] && full.depth[i].is_finite()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Projection;

    /// Looking down −Z at the origin, 50 pixels per unit over a 100 × 100 image.
    fn ortho() -> Camera {
        Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            projection: Projection::Orthographic { height: 2.0 },
            width: 100,
            height: 100,
            near: 1.0,
            far: 10.0,
        }
    }

    fn covered(image: &Image) -> usize {
        image.coverage().iter().filter(|&&c| c).count()
    }

    fn pixel(image: &Image, x: u32, y: u32) -> [u8; 4] {
        let i = 4 * (y * image.width + x) as usize;
        [image.rgba[i], image.rgba[i + 1], image.rgba[i + 2], image.rgba[i + 3]]
    }

    /// A sphere of `radius` made of flat triangles, counter-clockwise seen from outside.
    fn sphere(radius: f32) -> (Vec<Vec3>, Vec<u32>) {
        let m = crate::fixtures::icosphere(3);
        (m.positions.iter().map(|p| *p * radius).collect(), m.triangles.iter().flatten().copied().collect())
    }

    #[test]
    fn triangle_covers_its_area_and_winding_decides_culling() {
        let tri = [Vec3::new(-0.5, -0.5, 0.0), Vec3::new(0.5, -0.5, 0.0), Vec3::new(0.0, 0.5, 0.0)];
        let mut image = Image::new(100, 100);
        assert_eq!(image.draw(&ortho(), &tri, &[], &[0, 1, 2], [255, 0, 0, 255]), 1);
        let expected = 0.5 * 50.0 * 50.0;
        let got = covered(&image) as f32;
        assert!((got - expected).abs() < 0.03 * expected, "{got} pixels, expected about {expected}");
        // Lit head-on: the full color.
        assert_eq!(pixel(&image, 50, 60), [255, 0, 0, 255]);
        let mut back = Image::new(100, 100);
        assert_eq!(back.draw(&ortho(), &tri, &[], &[0, 2, 1], [255, 0, 0, 255]), 0);
        assert_eq!(covered(&back), 0);
    }

    #[test]
    fn faces_sharing_an_edge_cover_each_pixel_once() {
        // A 50 × 50 pixel square split along a diagonal through pixel centers.
        let square = [Vec3::new(-0.5, -0.5, 0.0), Vec3::new(0.5, -0.5, 0.0), Vec3::new(0.5, 0.5, 0.0), Vec3::new(-0.5, 0.5, 0.0)];
        let (mut a, mut b) = (Image::new(100, 100), Image::new(100, 100));
        a.draw(&ortho(), &square, &[], &[0, 1, 2], [255; 4]);
        b.draw(&ortho(), &square, &[], &[0, 2, 3], [255; 4]);
        let both = a.coverage().iter().zip(b.coverage()).filter(|(x, y)| **x && *y).count();
        assert_eq!(both, 0);
        assert_eq!(covered(&a) + covered(&b), 2500);
    }

    #[test]
    fn nearer_face_wins_in_either_order() {
        let quad = |z: f32| [Vec3::new(-0.5, -0.5, z), Vec3::new(0.5, -0.5, z), Vec3::new(0.5, 0.5, z), Vec3::new(-0.5, 0.5, z)];
        let indices = [0, 1, 2, 0, 2, 3];
        let (near, far) = (quad(1.0), quad(0.0));
        for near_first in [true, false] {
            let mut image = Image::new(100, 100);
            for draw_near in [near_first, !near_first] {
                let (p, c) = if draw_near { (&near, [0, 255, 0, 255]) } else { (&far, [255, 0, 0, 255]) };
                assert_eq!(image.draw(&ortho(), p, &[], &indices, c), 2);
            }
            assert_eq!(pixel(&image, 50, 50), [0, 255, 0, 255], "near drawn first: {near_first}");
            assert_eq!(pixel(&image, 30, 70), [0, 255, 0, 255]);
        }
    }

    #[test]
    fn parts_draw_as_their_draws_in_sequence() {
        let (positions, indices) = sphere(0.6);
        let (left, right): (Vec<Vec3>, Vec<Vec3>) =
            (positions.iter().map(|p| *p - Vec3::X * 0.3).collect(), positions.iter().map(|p| *p + Vec3::X * 0.3).collect());
        let mut one_by_one = Image::new(100, 100);
        let drawn = one_by_one.draw(&ortho(), &left, &[], &indices, [255, 0, 0, 255])
            + one_by_one.draw(&ortho(), &right, &[], &indices, [0, 0, 255, 255]);
        let mut batched = Image::new(100, 100);
        let parts = [Part::new(&left, &[], &indices, [255, 0, 0, 255]), Part::new(&right, &[], &indices, [0, 0, 255, 255])];
        assert_eq!(batched.draw_parts(&ortho(), &parts), drawn);
        assert_eq!(batched.rgba, one_by_one.rgba);
        assert_eq!(batched.depth, one_by_one.depth);
        assert!(drawn > 0);
    }

    /// The strip renderer's rows, assembled into an image.
    fn draw_in_strips(camera: &Camera, parts: &[Part<'_>], width: u32, height: u32) -> (Vec<u8>, usize) {
        let mut rgba = vec![0; 4 * (width * height) as usize];
        let mut next = 0;
        let drawn = Strips::new(width, height).draw(camera, parts, |row, rows| {
            assert_eq!(row, next, "strips in order");
            let at = 4 * (row * width) as usize;
            rgba[at..at + rows.len()].copy_from_slice(rows);
            next += (rows.len() / 4) as u32 / width;
        });
        assert_eq!(next, height);
        (rgba, drawn)
    }

    #[test]
    fn strips_draw_what_the_whole_image_draws() {
        let (positions, indices) = sphere(0.7);
        let shifted = |d: Vec3| positions.iter().map(|p| *p + d).collect::<Vec<Vec3>>();
        let (left, right, far) =
            (shifted(Vec3::new(-0.4, 0.1, 0.0)), shifted(Vec3::new(0.4, -0.2, 0.3)), shifted(Vec3::new(0.0, 0.0, -2.0)));
        let normals: Vec<Vec3> = positions.iter().map(|p| p.normalize()).collect();
        let mut bad = indices.clone();
        bad.extend([0, 1, u32::MAX, 5]);
        let nan = [Vec3::NAN, Vec3::X, Vec3::Y, Vec3::new(0.0, 1.0, 0.1)];
        let parts = [
            Part::new(&left, &normals, &indices, palette(1)),
            Part::new(&right, &[], &bad, palette(2)),
            Part::new(&far, &normals, &indices, palette(3)),
            Part::new(&nan, &[], &[0, 1, 2, 1, 2, 3], palette(4)),
            Part::new(&[], &[], &[], palette(5)),
        ];
        let perspective = |eye: Vec3, target: Vec3, width, height| Camera {
            eye,
            target,
            up: Vec3::Y,
            projection: Projection::Perspective { fov_y: 70f32.to_radians() },
            width,
            height,
            near: 0.05,
            far: 20.0,
        };
        let cameras = [
            (ortho(), 100, 100),
            (perspective(Vec3::new(0.5, 0.8, 4.0), Vec3::ZERO, 97, 131), 97, 131),
            // Inside a sphere and grazing the others: faces cross the near plane and the guard band.
            (perspective(Vec3::new(-0.4, 0.1, 0.2), Vec3::new(1.0, -0.3, -1.0), 160, 90), 160, 90),
            (perspective(Vec3::new(0.0, 0.0, 0.75), Vec3::new(0.0, 0.0, -5.0), 64, 200), 64, 200),
            (ortho(), 1, 1),
        ];
        for (camera, width, height) in cameras {
            let mut whole = Image::new(width, height);
            let drawn = whole.draw_parts(&camera, &parts);
            let (rgba, strip_drawn) = draw_in_strips(&camera, &parts, width, height);
            assert!(rgba == whole.rgba, "{width}x{height} from {}: images differ", camera.eye);
            assert_eq!(strip_drawn, drawn, "{width}x{height} from {}", camera.eye);
            assert!(drawn > 0);
        }
    }

    /// The strip renderer's rows with occlusion culling on, and its stats.
    fn draw_occluded(camera: &Camera, parts: &[Part<'_>], width: u32, height: u32) -> (Vec<u8>, DrawStats) {
        let (rgba, strips) = occluded_strips(camera, parts, width, height);
        (rgba, strips.stats())
    }

    /// [`draw_occluded`], with the renderer kept to ask which faces it skipped.
    fn occluded_strips(camera: &Camera, parts: &[Part<'_>], width: u32, height: u32) -> (Vec<u8>, Strips) {
        let mut rgba = vec![0; 4 * (width * height) as usize];
        let mut strips = Strips::new(width, height);
        strips.set_occlusion(true);
        strips.draw(camera, parts, |row, rows| {
            let at = 4 * (row * width) as usize;
            rgba[at..at + rows.len()].copy_from_slice(rows);
        });
        (rgba, strips)
    }

    #[test]
    fn occlusion_culling_skips_what_is_behind_and_changes_no_pixel() {
        // A grid of small spheres behind a large one, with their boxes; drawn near first.
        let (unit, indices) = sphere(1.0);
        let moved = |r: f32, d: Vec3| unit.iter().map(|p| *p * r + d).collect::<Vec<Vec3>>();
        let mut meshes = vec![(moved(0.8, Vec3::new(0.0, 0.0, 1.0)), palette(0))];
        for k in 0..25 {
            let d = Vec3::new((k % 5) as f32 * 0.3 - 0.6, (k / 5) as f32 * 0.3 - 0.6, -1.0);
            meshes.push((moved(0.12, d), palette(k + 1)));
        }
        let boxes: Vec<(Vec3, Vec3)> = meshes
            .iter()
            .map(|(p, _)| p.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v))))
            .collect();
        let parts: Vec<Part> =
            meshes.iter().zip(&boxes).map(|((p, c), &(lo, hi))| Part::new(p, &[], &indices, *c).with_bounds(lo, hi)).collect();
        let perspective = Camera {
            eye: Vec3::new(0.3, 0.2, 4.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            projection: Projection::Perspective { fov_y: 50f32.to_radians() },
            width: 120,
            height: 90,
            near: 0.05,
            far: 20.0,
        };
        for camera in [ortho(), perspective] {
            let (width, height) = (120, 90);
            let (plain, faces) = draw_in_strips(&camera, &parts, width, height);
            let (culled, stats) = draw_occluded(&camera, &parts, width, height);
            assert!(culled == plain, "from {}: occlusion culling changed pixels", camera.eye);
            assert!(stats.parts_hidden >= 4, "from {}: {stats:?}", camera.eye);
            assert!(stats.faces < faces);
            assert!(stats.faces_hidden > 0);
            // Without boxes, the blocks of faces are still tested.
            let unboxed: Vec<Part> = parts.iter().map(|p| Part { bounds: None, ..*p }).collect();
            let (unboxed_image, unboxed_stats) = draw_occluded(&camera, &unboxed, width, height);
            assert!(unboxed_image == plain);
            assert!(unboxed_stats.faces_hidden > 0 && unboxed_stats.faces < faces, "{unboxed_stats:?}");
            // Drawn back to front, nothing is behind what is drawn before it.
            let reversed: Vec<Part> = parts.iter().rev().copied().collect();
            let (back_first, stats) = draw_occluded(&camera, &reversed, width, height);
            assert!(back_first == plain);
            assert_eq!(stats.parts_hidden, 0);
            assert!(stats.writes > stats.covered, "back to front shades pixels more than once");
        }
    }

    #[test]
    fn a_block_is_hidden_when_each_of_its_faces_is_though_its_rectangle_is_not() {
        // Two near squares with a gap between them; behind them one block of two small faces, one
        // behind each square: the block's rectangle spans the gap, each face's does not.
        let square =
            |x0: f32, x1: f32, z: f32| [Vec3::new(x0, -0.5, z), Vec3::new(x1, -0.5, z), Vec3::new(x1, 0.5, z), Vec3::new(x0, 0.5, z)];
        let (left, right) = (square(-0.9, -0.1, 1.0), square(0.1, 0.9, 1.0));
        let quad = [0, 1, 2, 0, 2, 3];
        let back = [
            Vec3::new(-0.7, -0.2, -1.0),
            Vec3::new(-0.3, -0.2, -1.0),
            Vec3::new(-0.5, 0.2, -1.0),
            Vec3::new(0.3, -0.2, -1.0),
            Vec3::new(0.7, -0.2, -1.0),
            Vec3::new(0.5, 0.2, -1.0),
        ];
        let back_faces = [0, 1, 2, 3, 4, 5];
        let camera = ortho();
        let (w, h) = (camera.width, camera.height);
        let alone = [Part::new(&back, &[], &back_faces, palette(3))];
        assert_eq!(draw_in_strips(&camera, &alone, w, h).1, 2, "both back faces face the camera");
        let parts = [Part::new(&left, &[], &quad, palette(1)), Part::new(&right, &[], &quad, palette(2)), alone[0]];
        let (plain, faces) = draw_in_strips(&camera, &parts, w, h);
        let (culled, stats) = draw_occluded(&camera, &parts, w, h);
        assert!(culled == plain, "occlusion culling changed pixels");
        assert_eq!(faces, 6);
        assert_eq!(stats.faces, 4, "{stats:?}");
        assert_eq!(stats.faces_hidden, 2, "{stats:?}");
    }

    #[test]
    fn faces_of_a_block_that_shows_are_skipped_one_by_one_where_hidden() {
        // A near square over the left half; behind it one block of four faces along x: the first
        // two behind the square, the last two beside it. The block shows; its first two faces do not.
        let near = [Vec3::new(-1.0, -0.5, 1.0), Vec3::new(0.0, -0.5, 1.0), Vec3::new(0.0, 0.5, 1.0), Vec3::new(-1.0, 0.5, 1.0)];
        let mut back = Vec::new();
        let mut faces = Vec::new();
        for x in [-0.8f32, -0.5, 0.3, 0.6] {
            let at = back.len() as u32;
            back.extend([Vec3::new(x, -0.2, -1.0), Vec3::new(x + 0.15, -0.2, -1.0), Vec3::new(x + 0.07, 0.2, -1.0)]);
            faces.extend([at, at + 1, at + 2]);
        }
        let camera = ortho();
        let (w, h) = (camera.width, camera.height);
        let parts = [Part::new(&near, &[], &[0, 1, 2, 0, 2, 3], palette(1)), Part::new(&back, &[], &faces, palette(2))];
        let (plain, all) = draw_in_strips(&camera, &parts, w, h);
        assert_eq!(all, 6);
        let (culled, strips) = occluded_strips(&camera, &parts, w, h);
        assert!(culled == plain, "occlusion culling changed pixels");
        let stats = strips.stats();
        assert_eq!((stats.faces, stats.faces_hidden), (4, 2), "{stats:?}");
        assert_eq!((0..4).map(|f| strips.face_hidden(1, f)).collect::<Vec<_>>(), [true, true, false, false]);
        assert!(!strips.part_hidden(1));
        assert!(!strips.face_hidden(2, 0), "no such part");
    }

    #[test]
    fn a_face_hidden_in_its_strip_is_hidden_though_its_block_shows_in_another() {
        // One block of three faces: the first and last high in the picture (strip 0), shown; the
        // middle one lower (strip 1), behind a near square.
        let near = [Vec3::new(-1.0, -0.5, 1.0), Vec3::new(1.0, -0.5, 1.0), Vec3::new(1.0, 0.2, 1.0), Vec3::new(-1.0, 0.2, 1.0)];
        let tri = |x: f32, y: f32| [Vec3::new(x - 0.1, y, -1.0), Vec3::new(x + 0.1, y, -1.0), Vec3::new(x, y + 0.2, -1.0)];
        let back: Vec<Vec3> = [tri(-0.5, 0.7), tri(0.0, -0.2), tri(0.5, 0.7)].concat();
        let camera = ortho();
        let (w, h) = (camera.width, camera.height);
        let parts =
            [Part::new(&near, &[], &[0, 1, 2, 0, 2, 3], palette(1)), Part::new(&back, &[], &[0, 1, 2, 3, 4, 5, 6, 7, 8], palette(2))];
        let (plain, all) = draw_in_strips(&camera, &parts, w, h);
        assert_eq!(all, 5);
        let (culled, strips) = occluded_strips(&camera, &parts, w, h);
        assert!(culled == plain, "occlusion culling changed pixels");
        let stats = strips.stats();
        assert_eq!((stats.faces, stats.faces_hidden), (4, 1), "{stats:?}");
        assert_eq!((0..3).map(|f| strips.face_hidden(1, f)).collect::<Vec<_>>(), [false, true, false]);
    }

    #[test]
    fn faces_crossing_the_near_plane_are_clipped_not_dropped() {
        let camera = Camera {
            eye: Vec3::ZERO,
            target: Vec3::NEG_Z,
            up: Vec3::Y,
            projection: Projection::Perspective { fov_y: 90f32.to_radians() },
            width: 64,
            height: 64,
            near: 0.1,
            far: 100.0,
        };
        // A floor below the eye, reaching behind it.
        let floor = [Vec3::new(-1.0, -1.0, -5.0), Vec3::new(0.0, -1.0, 1.0), Vec3::new(1.0, -1.0, -5.0)];
        let mut image = Image::new(64, 64);
        assert_eq!(image.draw(&camera, &floor, &[], &[0, 1, 2], [200; 4]), 1);
        let c = image.coverage();
        let bottom = c[32 * 64..].iter().filter(|&&c| c).count();
        assert!(bottom > 200, "{bottom} pixels below the horizon");
        assert!(c[..31 * 64].iter().all(|&c| !c), "nothing above the horizon");
        // Nearest rows are covered at the bottom center: the clipped part reaches the near plane.
        assert!(c[63 * 64 + 32]);
        let behind = floor.map(|p| Vec3::new(p.x, p.y, 10.0 + p.z.abs()));
        assert_eq!(Image::new(64, 64).draw(&camera, &behind, &[], &[0, 1, 2], [200; 4]), 0);
    }

    #[test]
    fn sphere_covers_its_disk_from_every_direction() {
        let (positions, indices) = sphere(1.0);
        let fov = 45f32.to_radians();
        for dir in [Vec3::Z, Vec3::Y, Vec3::NEG_X, Vec3::new(0.3, 0.4, 1.0), Vec3::new(-1.0, -2.0, 0.5)] {
            // Frame a larger sphere so the unit sphere has a margin.
            let camera = Camera::framing(Vec3::ZERO, 1.25, dir, fov, 256, 256);
            let mut image = Image::new(256, 256);
            let drawn = image.draw(&camera, &positions, &[], &indices, [200; 4]);
            assert!(drawn > indices.len() / 3 / 3 && drawn < indices.len() / 3 * 2 / 3, "{drawn} faces drawn");
            let half_angle = (1.0 / camera.eye.length()).asin();
            let radius = 128.0 * half_angle.tan() / (0.5 * fov).tan();
            let expected = std::f32::consts::PI * radius * radius;
            let got = covered(&image) as f32;
            assert!((got / expected - 0.985).abs() < 0.02, "from {dir}: {got} pixels, expected about {expected}");
            // Lit from the eye: brightest at the center, darker toward the rim.
            let center = pixel(&image, 128, 128)[0];
            let rim = pixel(&image, 128, 128 + radius as u32 - 3)[0];
            assert!(center > 190 && rim < center, "center {center}, rim {rim}");
        }
    }

    #[test]
    fn smooth_normals_shade_without_facets() {
        let (positions, indices) = sphere(1.0);
        let camera = Camera::framing(Vec3::ZERO, 1.25, Vec3::Z, 45f32.to_radians(), 128, 128);
        let mut flat = Image::new(128, 128);
        let mut smooth = Image::new(128, 128);
        flat.draw(&camera, &positions, &[], &indices, [200; 4]);
        smooth.draw(&camera, &positions, &positions, &indices, [200; 4]);
        assert_eq!(flat.coverage(), smooth.coverage());
        // Along a row, smooth shading changes by small steps only.
        let row: Vec<i32> = (40..88).map(|x| pixel(&smooth, x, 64)[0] as i32).collect();
        assert!(row.windows(2).all(|w| (w[0] - w[1]).abs() <= 4), "{row:?}");
        assert!(changed_share(&flat, &smooth, 2) > 0.1);
    }

    #[test]
    fn bad_input_draws_nothing() {
        let mut image = Image::new(100, 100);
        let nan = [Vec3::new(f32::NAN, 0.0, 0.0), Vec3::new(0.5, -0.5, 0.0), Vec3::new(0.0, 0.5, 0.0)];
        assert_eq!(image.draw(&ortho(), &nan, &[], &[0, 1, 2], [255; 4]), 0);
        let inf = [Vec3::new(f32::INFINITY, 0.0, 0.0), Vec3::new(0.5, -0.5, 0.0), Vec3::new(0.0, 0.5, 0.0)];
        assert_eq!(image.draw(&ortho(), &inf, &[], &[0, 1, 2], [255; 4]), 0);
        let ok = [Vec3::new(-0.5, -0.5, 0.0), Vec3::new(0.5, -0.5, 0.0), Vec3::new(0.0, 0.5, 0.0)];
        assert_eq!(image.draw(&ortho(), &ok, &[], &[0, 1, 3, 7, u32::MAX, 0], [255; 4]), 0);
        assert_eq!(image.draw(&ortho(), &ok, &[], &[0, 1, 1, 2, 2, 2], [255; 4]), 0);
        assert_eq!(image.draw(&ortho(), &[Vec3::splat(1e30); 3], &[], &[0, 1, 2], [255; 4]), 0);
        assert_eq!(image.draw(&ortho(), &[], &[], &[0, 1], [255; 4]), 0);
        let nan_normals = [Vec3::NAN; 3];
        assert_eq!(image.draw(&ortho(), &ok, &nan_normals, &[0, 1, 2, 0], [255; 4]), 1);
        assert!(covered(&image) > 1000);
        let mut degenerate_camera = ortho();
        degenerate_camera.target = degenerate_camera.eye;
        degenerate_camera.near = 0.0;
        degenerate_camera.projection = Projection::Perspective { fov_y: 0.0 };
        let mut other = Image::new(0, 0);
        other.draw(&degenerate_camera, &ok, &[], &[0, 1, 2], [255; 4]);
    }

    #[test]
    fn changed_share_is_zero_for_itself_and_positive_for_a_shift() {
        let (positions, indices) = sphere(1.0);
        let camera = Camera::framing(Vec3::ZERO, 1.25, Vec3::new(0.3, 0.4, 1.0), 45f32.to_radians(), 128, 128);
        let mut a = Image::new(128, 128);
        a.draw(&camera, &positions, &[], &indices, palette(3));
        assert_eq!(changed_share(&a, &a, 0), 0.0);
        let shift = Vec3::new(0.05, 0.0, 0.0);
        let moved = Camera { eye: camera.eye + shift, target: camera.target + shift, ..camera };
        let mut b = Image::new(128, 128);
        b.draw(&moved, &positions, &[], &indices, palette(3));
        let share = changed_share(&a, &b, 8);
        assert!(share > 0.01 && share < 1.0, "{share}");
        assert_eq!(changed_share(&Image::new(10, 10), &Image::new(10, 10), 0), 0.0);
        assert_eq!(changed_share(&a, &Image::new(10, 10), 0), 1.0);
    }

    #[test]
    fn palette_colors_are_distinct_and_stable() {
        let colors: Vec<[u8; 4]> = (0..64).map(palette).collect();
        assert_eq!(colors, (0..64).map(palette).collect::<Vec<_>>());
        for i in 0..colors.len() {
            for j in 0..i {
                let d = (0..3).map(|k| colors[i][k].abs_diff(colors[j][k])).max().unwrap_or(0);
                assert!(d >= 8, "palette({i}) = {:?} and palette({j}) = {:?}", colors[i], colors[j]);
            }
        }
    }

    #[test]
    fn id_parts_write_face_ids() {
        let (positions, indices) = sphere(1.0);
        let mut image = Image::new(64, 64);
        image.draw_parts(&ortho(), &[Part::new(&positions, &[], &indices, [9; 4]).with_ids(1000)]);
        let faces = indices.len() as u32 / 3;
        let mut seen = std::collections::BTreeSet::new();
        for px in image.rgba.chunks_exact(4) {
            let id = u32::from_le_bytes([px[0], px[1], px[2], px[3]]);
            if px != BACKGROUND {
                assert!((1000..1000 + faces).contains(&id), "{id}");
                seen.insert(id);
            }
        }
        assert!(seen.len() > 10);
    }

    #[test]
    fn png_round_trips() {
        let (positions, indices) = sphere(1.0);
        let camera = Camera::framing(Vec3::ZERO, 1.25, Vec3::Z, 45f32.to_radians(), 96, 64);
        let mut image = Image::new(96, 64);
        image.draw(&camera, &positions, &positions, &indices, palette(1));
        let bytes = image.encode_png();
        let decoder = png::Decoder::new(std::io::Cursor::new(&bytes));
        let mut reader = decoder.read_info().expect("decodes");
        let mut buf = vec![0; reader.output_buffer_size().expect("size")];
        let info = reader.next_frame(&mut buf).expect("frame");
        assert_eq!((info.width, info.height, info.color_type), (96, 64, png::ColorType::Rgba));
        assert_eq!(&buf[..info.buffer_size()], &image.rgba[..]);
        let path = std::env::temp_dir().join(format!("strata-render-test-{}.png", std::process::id()));
        image.write_png(&path).expect("writes");
        assert_eq!(std::fs::read(&path).expect("reads"), bytes);
        let _ = std::fs::remove_file(&path);
    }
}
