//! `strata render`: draw a mesh, or one level of a chunk file, to a PNG with the software
//! rasterizer.

use super::{load, open_chunk_file, MeshInput};
use anyhow::{Context, Result};
use clap::ValueEnum;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args)]
pub struct Args {
    /// A .strata file, or an OBJ, glTF/GLB or PLY mesh.
    input: PathBuf,
    /// The PNG to write.
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long, default_value_t = 512)]
    width: u32,
    #[arg(long, default_value_t = 512)]
    height: u32,
    /// Eye and target as "ex,ey,ez:tx,ty,tz"; default: framing the model from --view-dir.
    #[arg(long, allow_hyphen_values = true)]
    camera: Option<String>,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 45.0)]
    fov: f32,
    /// Direction from the model toward the eye for the default camera, as "x,y,z"; default
    /// "0.3,0.4,1.0", and for terrain (y up) "0,1,0.8": from the south, 50° above the horizon.
    #[arg(long, allow_hyphen_values = true)]
    view_dir: Option<String>,
    /// Color by: materials (base color and base color texture; the default for textured models),
    /// one plain color (the default otherwise), each node (strata files), or the level (strata files).
    #[arg(long, value_enum, default_value_t = RenderColor::Auto)]
    color: RenderColor,
    /// Level of a strata file to draw (0 = full detail).
    #[arg(long, default_value_t = 0)]
    level: u32,
    #[command(flatten)]
    dem: super::DemArgs,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum RenderColor {
    Auto,
    Materials,
    Plain,
    Groups,
    Levels,
}

pub fn run(a: Args) -> Result<()> {
    use strata::format::MapKind;
    use strata::render::{palette, Image, Part};
    use strata::stream::images::base_color_images;
    use strata::texture::draw::{node_parts, read_chains, source_chain, srgb_color};
    anyhow::ensure!(a.width > 0 && a.height > 0, "--width and --height must be positive");
    strata::atomic::protect(&a.input);
    strata::atomic::check_output(&a.output)?;
    let plain = [200, 200, 200, 255];
    let mut image = Image::new(a.width, a.height);
    let (mut drawn, mut faces, mut draw_ms) = (0, 0, 0.0);
    let is_strata = a.input.extension().is_some_and(|e| e.eq_ignore_ascii_case("strata"));
    if is_strata {
        let rd = open_chunk_file(&a.input)?;
        let levels = rd.header().levels;
        anyhow::ensure!(a.level < levels, "--level {}: {} has levels 0..{}", a.level, a.input.display(), levels.saturating_sub(1));
        let camera = render_camera(&a, rd.header().min, rd.header().max, rd.georef().is_some())?;
        let color = match a.color {
            RenderColor::Auto if !rd.textures().is_empty() => RenderColor::Materials,
            RenderColor::Auto => RenderColor::Plain,
            c => c,
        };
        // The images the level's geometry samples: a first pass over its nodes finds them.
        let mut chains = Vec::new();
        if color == RenderColor::Materials && !rd.textures().is_empty() {
            let mut used = Vec::new();
            for node in rd.level_nodes(a.level) {
                used.extend(base_color_images(&rd.read_node(node)?, rd.materials()));
            }
            used.sort_unstable();
            used.dedup();
            let mut warnings = Vec::new();
            chains = read_chains(&rd, &used, &mut warnings);
            for w in warnings {
                eprintln!("warning: {}: {w}", a.input.display());
            }
        }
        for node in rd.level_nodes(a.level) {
            let g = rd.read_node(node)?;
            let parts = match color {
                RenderColor::Materials => node_parts(&g, rd.materials(), &|i| chains.get(i as usize)?.as_ref()),
                c => {
                    let color = match c {
                        RenderColor::Groups => palette(node),
                        RenderColor::Levels => palette(a.level),
                        _ => plain,
                    };
                    vec![Part::new(&g.positions, &g.normals, &g.indices, color)]
                }
            };
            let start = Instant::now();
            drawn += image.draw_parts(&camera, &parts);
            draw_ms += start.elapsed().as_secs_f64() * 1e3;
            faces += g.face_count();
        }
    } else {
        anyhow::ensure!(
            matches!(a.color, RenderColor::Plain | RenderColor::Auto | RenderColor::Materials),
            "--color groups and levels need a .strata file"
        );
        let imported = load(&MeshInput { mesh: a.input.clone(), format: None, allow_outside_files: false, dem: a.dem.clone() })?;
        let m = imported.mesh;
        let (min, max) = m.bounds().context("empty mesh")?;
        let camera = render_camera(&a, min, max, imported.georef.is_some())?;
        let textured = !m.uvs.is_empty() && m.materials.iter().any(|x| x.map(MapKind::BaseColor).is_some());
        if a.color == RenderColor::Materials || (a.color == RenderColor::Auto && textured) {
            let corners: Vec<glam::Vec3> =
                m.triangles.iter().flatten().map(|&v| m.positions.get(v as usize).copied().unwrap_or(glam::Vec3::NAN)).collect();
            let mut chains: Vec<Option<strata::texture::sample::MipChain>> = vec![None; m.images.len()];
            for mat in &m.materials {
                if let Some(slot) = mat.map(MapKind::BaseColor) {
                    if chains[slot.image as usize].is_none() {
                        match source_chain(&m.images[slot.image as usize], MapKind::BaseColor) {
                            Ok(c) => chains[slot.image as usize] = Some(c),
                            Err(e) => eprintln!("warning: {}: {}: {e}", a.input.display(), m.images[slot.image as usize].name),
                        }
                    }
                }
            }
            let mut by_material: Vec<Vec<u32>> = vec![Vec::new(); m.materials.len().max(1)];
            for f in 0..m.face_count() {
                let id = m.face_materials.get(f).copied().unwrap_or(0) as usize;
                let last = by_material.len() - 1;
                by_material[id.min(last)].extend([3 * f as u32, 3 * f as u32 + 1, 3 * f as u32 + 2]);
            }
            let parts: Vec<Part> = by_material
                .iter()
                .enumerate()
                .filter(|(_, i)| !i.is_empty())
                .map(|(id, indices)| {
                    let mat = m.materials.get(id);
                    let part = Part::new(&corners, &m.normals, indices, mat.map_or(plain, |x| srgb_color(x.base_color)));
                    let slot = mat.and_then(|x| x.map(MapKind::BaseColor));
                    match slot.and_then(|s| Some((s, chains[s.image as usize].as_ref()?))) {
                        Some((s, c)) => part.textured(&m.uvs, c, s.wrap),
                        None => part,
                    }
                })
                .collect();
            let start = Instant::now();
            drawn = image.draw_parts(&camera, &parts);
            draw_ms = start.elapsed().as_secs_f64() * 1e3;
            image.write_png(&a.output)?;
            println!(
                "drew {drawn} of {} faces at {}x{} in {draw_ms:.1} ms, wrote {}",
                m.face_count(),
                a.width,
                a.height,
                a.output.display()
            );
            return Ok(());
        }
        // Corner normals become vertices of their own; without them, faces are flat.
        let (positions, normals, indices): (Vec<_>, Vec<_>, Vec<u32>) = if m.normals.is_empty() {
            (m.positions.clone(), Vec::new(), m.triangles.iter().flatten().copied().collect())
        } else {
            let corners = m.triangles.iter().flatten().map(|&v| m.positions.get(v as usize).copied().unwrap_or(glam::Vec3::NAN)).collect();
            (corners, m.normals.clone(), (0..3 * m.triangles.len() as u32).collect())
        };
        let start = Instant::now();
        drawn = image.draw(&camera, &positions, &normals, &indices, plain);
        draw_ms = start.elapsed().as_secs_f64() * 1e3;
        faces = m.face_count();
    }
    image.write_png(&a.output)?;
    println!("drew {drawn} of {faces} faces at {}x{} in {draw_ms:.1} ms, wrote {}", a.width, a.height, a.output.display());
    Ok(())
}

/// Three comma-separated numbers.
fn parse_vec3(s: &str, what: &str) -> Result<glam::Vec3> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .with_context(|| format!("{what}: {s:?} is not three comma-separated numbers"))?;
    anyhow::ensure!(v.len() == 3 && v.iter().all(|x| x.is_finite()), "{what}: {s:?} is not three comma-separated numbers");
    Ok(glam::Vec3::new(v[0], v[1], v[2]))
}

/// The camera of `strata render`: framing the bounding sphere, or at --camera's eye and target.
fn render_camera(a: &Args, min: glam::Vec3, max: glam::Vec3, terrain: bool) -> Result<strata::camera::Camera> {
    anyhow::ensure!(a.fov > 0.0 && a.fov < 180.0, "--fov must be between 0 and 180 degrees, not {}", a.fov);
    let (center, radius) = ((min + max) * 0.5, ((max - min).length() * 0.5).max(f32::MIN_POSITIVE));
    let fov = a.fov.to_radians();
    let Some(spec) = &a.camera else {
        let dir = match &a.view_dir {
            Some(d) => parse_vec3(d, "--view-dir")?,
            None if terrain => glam::Vec3::new(0.0, 1.0, 0.8),
            None => glam::Vec3::new(0.3, 0.4, 1.0),
        };
        return Ok(strata::camera::Camera::framing(center, radius, dir, fov, a.width, a.height));
    };
    let (eye, target) = spec.split_once(':').with_context(|| format!("--camera: {spec:?} is not \"ex,ey,ez:tx,ty,tz\""))?;
    let (eye, target) = (parse_vec3(eye, "--camera eye")?, parse_vec3(target, "--camera target")?);
    anyhow::ensure!(eye != target, "--camera: the eye and the target are the same point");
    let mut camera = strata::camera::Camera::framing(center, radius, eye - target, fov, a.width, a.height);
    let distance = eye.distance(center);
    camera.eye = eye;
    camera.target = target;
    camera.near = (distance - radius).max(1e-4 * (distance + radius));
    camera.far = distance + radius;
    Ok(camera)
}
