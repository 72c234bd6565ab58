//! Shape retention of a face-budgeted front over 8 views around the model (512², pixel error 0,
//! the front refined until it stops), shared by the stream and partition benches.

use glam::Vec3;
use std::path::Path;
use strata::camera::Camera;
use strata::format::Reader;
use strata::render::Image;
use strata::stream::retention::retention;
use strata::stream::{Budgets, Priority, Streamer};

pub const SIZE: u32 = 512;
const FOV: f32 = 0.8;

/// The 8 cameras around a model of bounds `min`..`max`, a little above it, each framing it.
pub fn cameras(min: Vec3, max: Vec3) -> Vec<Camera> {
    let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
    (0..8)
        .map(|k| {
            let a = k as f32 * std::f32::consts::TAU / 8.0;
            Camera::framing(center, radius, Vec3::new(a.sin(), 0.3, a.cos()), FOV, SIZE, SIZE)
        })
        .collect()
}

/// The 8 cameras and the full-detail reference image of each.
pub struct Views {
    cameras: Vec<Camera>,
    references: Vec<Image>,
}

impl Views {
    pub fn of(file: &Path) -> strata::error::Result<Views> {
        let rd = Reader::open_path(file)?;
        let h = rd.header().clone();
        let full: Vec<_> = rd.level_nodes(0).map(|i| rd.read_node(i)).collect::<strata::error::Result<_>>()?;
        let cameras = cameras(h.min, h.max);
        let references = cameras
            .iter()
            .map(|cam| {
                let mut img = Image::new(SIZE, SIZE);
                for g in &full {
                    img.draw(cam, &g.positions, &g.normals, &g.indices, [200, 200, 200, 255]);
                }
                img
            })
            .collect();
        Ok(Views { cameras, references })
    }

    /// Mean shaded retention and coverage over the views of `file`'s front under `faces` faces,
    /// refined in `priority` order; `None` when the top level alone exceeds the budget.
    pub fn retention(&self, file: &Path, faces: u64, priority: Priority) -> strata::error::Result<Option<(f64, f64)>> {
        let budgets = Budgets { faces: Some(faces), pixel_error: 0.0, priority, ..Budgets::default() };
        let Ok(mut s) = Streamer::new(Reader::open_path(file)?, budgets) else { return Ok(None) };
        let (mut shaded, mut coverage) = (0.0, 0.0);
        let mut img = Image::new(SIZE, SIZE);
        let n = self.cameras.len() as f64;
        for (cam, reference) in self.cameras.iter().zip(&self.references) {
            let mut rep = s.update(cam, None)?;
            while !rep.added.is_empty() {
                rep = s.update(cam, None)?;
            }
            img.clear();
            for &i in &rep.front {
                if let Some(g) = s.geometry(i) {
                    img.draw(cam, &g.positions, &g.normals, &g.indices, [200, 200, 200, 255]);
                }
            }
            let r = retention(&img, reference);
            shaded += r.shaded / n;
            coverage += r.coverage / n;
        }
        Ok(Some((shaded, coverage)))
    }
}
