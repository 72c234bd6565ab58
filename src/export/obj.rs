//! Write Wavefront OBJ, plus a sibling .mtl when the mesh has materials beyond a single default,
//! and the images its materials' base color, normal and emissive maps sample (`map_Kd`, `norm`,
//! `map_Ke`) as files beside it, named after the OBJ; an image file already there with other
//! contents is refused, never replaced. OBJ's UVs count v up from the bottom of the image: v is
//! flipped on the way out.
//!
//! Numbers are printed in the shortest form that parses back to the same f32, so positions survive
//! exactly. Identical normals and UVs are written once. Per-corner colors use the common
//! `v x y z r g b` extension (alpha is dropped); a position whose corners carry different colors gets
//! one `v` line per color. Face order is kept, with a `usemtl` at the start of every material run.

use super::check;
use crate::atomic::AtomicFile;
use crate::error::{Error, Result};
use crate::format::MapKind;
use crate::mesh::{Material, Mesh};
use std::collections::{HashMap, HashSet};
use std::fmt;
use std::hash::Hash;
use std::io::{self, Write};
use std::path::Path;

/// Write `mesh` to `path` and, when [`needs_mtl`], its materials to `path` with extension `.mtl`
/// and the images their maps use beside it ([`image_files`]).
pub fn write(path: &Path, mesh: &Mesh) -> Result<()> {
    let mtl_path = needs_mtl(mesh).then(|| path.with_extension("mtl"));
    let mtllib = mtl_path.as_ref().and_then(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned());
    let stem = path.file_stem().map_or("mesh".into(), |s| s.to_string_lossy().into_owned());
    let files = if mtl_path.is_some() { image_files(mesh, &stem) } else { Vec::new() };
    let dir = path.parent().unwrap_or(Path::new(""));
    // Every file is written under a temporary name first and all are renamed at the end, so a
    // failure leaves none of them. An image file already there is kept when it holds the same
    // bytes and refused otherwise: it may be another model's texture.
    let mut staged = Vec::new();
    for (image, name) in mesh.images.iter().zip(&files) {
        let Some(name) = name else { continue };
        let dest = dir.join(name);
        match std::fs::read(&dest) {
            Ok(existing) if existing == *image.bytes => continue,
            Ok(_) => {
                return Err(Error::invalid(
                    &dest,
                    None,
                    "exists with other contents; an OBJ export does not replace it (remove it, or export under another name)",
                ))
            }
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(Error::io(&dest, e)),
        }
        let mut f = AtomicFile::create(&dest)?;
        f.writer().write_all(&image.bytes).map_err(|e| Error::io(&dest, e))?;
        staged.push(f);
    }
    if let Some(mtl_path) = &mtl_path {
        let mut f = AtomicFile::create(mtl_path)?;
        write_mtl(f.writer(), mesh, &files).map_err(|e| Error::io(mtl_path, e))?;
        staged.push(f);
    }
    let mut file = AtomicFile::create(path)?;
    write_obj(file.writer(), mesh, mtllib.as_deref()).map_err(|e| Error::io(path, e))?;
    for f in staged {
        f.commit()?;
    }
    file.commit()
}

/// Maps an OBJ material library can name, with their statements.
const OBJ_MAPS: [(MapKind, &str); 3] = [(MapKind::BaseColor, "map_Kd"), (MapKind::Normal, "norm"), (MapKind::Emissive, "map_Ke")];

/// File names, beside an OBJ named `stem`, for the images the materials' [`OBJ_MAPS`] use (when
/// the mesh has UVs): `<stem>_<image name's file name>`, made safe for a file system and unique,
/// with the codec's extension; `None` for images not written.
pub fn image_files(mesh: &Mesh, stem: &str) -> Vec<Option<String>> {
    let mut used = vec![false; mesh.images.len()];
    if !mesh.uvs.is_empty() {
        for m in &mesh.materials {
            for (kind, _) in OBJ_MAPS {
                if let Some(u) = m.map(kind).and_then(|s| used.get_mut(s.image as usize)) {
                    *u = true;
                }
            }
        }
    }
    let mut taken = HashSet::new();
    mesh.images
        .iter()
        .zip(used)
        .enumerate()
        .map(|(i, (image, used))| {
            if !used {
                return None;
            }
            let base = image.name.rsplit(['/', '\\']).next().unwrap_or("");
            let base = base.rsplit_once('.').map_or(base, |(b, _)| b);
            let safe: String = base.chars().map(|c| if c.is_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect();
            let safe = if safe.is_empty() { format!("image{i}") } else { safe };
            let ext = image.codec.extension();
            let mut name = format!("{stem}_{safe}.{ext}");
            let mut k = 1;
            while !taken.insert(name.clone()) {
                name = format!("{stem}_{safe}_{k}.{ext}");
                k += 1;
            }
            Some(name)
        })
        .collect()
}

/// Whether the mesh carries materials worth a .mtl file: anything but none or one default material.
pub fn needs_mtl(mesh: &Mesh) -> bool {
    !(mesh.materials.is_empty() || (mesh.materials.len() == 1 && mesh.materials[0] == Material::default()))
}

/// Write the OBJ text of `mesh`, naming `mtllib` as its material library when given.
pub fn write_obj<W: Write>(mut out: W, mesh: &Mesh, mtllib: Option<&str>) -> io::Result<()> {
    check(mesh)?;
    let corners = 3 * mesh.face_count();
    writeln!(out, "# written by strata: {} faces", mesh.face_count())?;
    if let Some(lib) = mtllib {
        writeln!(out, "mtllib {lib}")?;
    }

    let vertex_of_corner: Vec<u32> = if mesh.colors.is_empty() {
        for p in &mesh.positions {
            writeln!(out, "v {} {} {}", Num(p.x), Num(p.y), Num(p.z))?;
        }
        mesh.triangles.iter().flatten().copied().collect()
    } else {
        let (index, firsts) = dedup((0..corners).map(|c| (mesh.triangles[c / 3][c % 3], mesh.colors[c])));
        for c in firsts {
            let p = mesh.positions[mesh.triangles[c / 3][c % 3] as usize];
            let [r, g, b, _] = mesh.colors[c].map(|x| Num(f32::from(x) / 255.0));
            writeln!(out, "v {} {} {} {r} {g} {b}", Num(p.x), Num(p.y), Num(p.z))?;
        }
        index
    };
    let (uv_of_corner, firsts) = dedup(mesh.uvs.iter().map(|t| t.to_array().map(f32::to_bits)));
    for c in firsts {
        writeln!(out, "vt {} {}", Num(mesh.uvs[c].x), Num(1.0 - mesh.uvs[c].y))?;
    }
    let (normal_of_corner, firsts) = dedup(mesh.normals.iter().map(|n| n.to_array().map(f32::to_bits)));
    for c in firsts {
        let n = mesh.normals[c];
        writeln!(out, "vn {} {} {}", Num(n.x), Num(n.y), Num(n.z))?;
    }

    let names = needs_mtl(mesh).then(|| material_names(&mesh.materials));
    let mut current = None;
    for (f, face) in vertex_of_corner.chunks_exact(3).enumerate() {
        if let Some(names) = &names {
            let m = mesh.face_materials[f];
            if current != Some(m) {
                writeln!(out, "usemtl {}", names[m as usize])?;
                current = Some(m);
            }
        }
        out.write_all(b"f")?;
        for (k, v) in face.iter().enumerate() {
            let c = 3 * f + k;
            write!(out, " {}", v + 1)?;
            match (uv_of_corner.get(c), normal_of_corner.get(c)) {
                (Some(t), Some(n)) => write!(out, "/{}/{}", t + 1, n + 1)?,
                (Some(t), None) => write!(out, "/{}", t + 1)?,
                (None, Some(n)) => write!(out, "//{}", n + 1)?,
                (None, None) => {}
            }
        }
        out.write_all(b"\n")?;
    }
    out.flush()
}

/// Write the .mtl text for the materials of `mesh`: diffuse color, opacity, and its maps: those
/// whose image is written as `image_files[image]`, else the base color texture's path as the source
/// named it.
pub fn write_mtl<W: Write>(mut out: W, mesh: &Mesh, image_files: &[Option<String>]) -> io::Result<()> {
    writeln!(out, "# written by strata: {} materials", mesh.materials.len())?;
    for (m, name) in mesh.materials.iter().zip(material_names(&mesh.materials)) {
        let [r, g, b, a] = m.base_color.map(Num);
        writeln!(out, "\nnewmtl {name}\nKd {r} {g} {b}\nd {a}")?;
        let file = |kind: MapKind| m.map(kind).and_then(|s| image_files.get(s.image as usize)?.clone());
        for (kind, statement) in OBJ_MAPS {
            match (file(kind), kind) {
                (Some(f), _) => {
                    let clamp = m.map(kind).is_some_and(|s| s.wrap.contains(&crate::format::Wrap::Clamp));
                    writeln!(out, "{statement} {}{f}", if clamp { "-clamp on " } else { "" })?;
                }
                (None, MapKind::BaseColor) => {
                    if let Some(texture) = &m.texture {
                        writeln!(out, "map_Kd {texture}")?;
                    }
                }
                _ => {}
            }
        }
    }
    out.flush()
}

/// Material names usable in `newmtl`/`usemtl`: whitespace becomes `_`, an empty name becomes
/// `material`, and a name already taken gets the material's index appended.
fn material_names(materials: &[Material]) -> Vec<String> {
    let mut taken = HashSet::new();
    materials
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let mut name: String = m.name.chars().map(|c| if c.is_whitespace() { '_' } else { c }).collect();
            if name.is_empty() {
                name = "material".into();
            }
            while !taken.insert(name.clone()) {
                name = format!("{name}_{i}");
            }
            name
        })
        .collect()
}

/// Number distinct keys in order of first appearance: the number of every key, and the position
/// of the first occurrence of each distinct key.
fn dedup<K: Hash + Eq>(keys: impl Iterator<Item = K>) -> (Vec<u32>, Vec<usize>) {
    let mut seen = HashMap::new();
    let mut firsts = Vec::new();
    let index = keys
        .enumerate()
        .map(|(i, k)| {
            *seen.entry(k).or_insert_with(|| {
                firsts.push(i);
                (firsts.len() - 1) as u32
            })
        })
        .collect();
    (index, firsts)
}

/// An f32 printed in its shortest exact form, with an exponent when it is very small or large.
struct Num(f32);

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let a = self.0.abs();
        if a != 0.0 && !(1e-4..1e9).contains(&a) {
            write!(f, "{:e}", self.0)
        } else {
            write!(f, "{}", self.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures;

    fn obj_text(mesh: &Mesh, mtllib: Option<&str>) -> String {
        let mut out = Vec::new();
        write_obj(&mut out, mesh, mtllib).unwrap();
        String::from_utf8(out).unwrap()
    }

    fn lines<'a>(text: &'a str, tag: &str) -> Vec<&'a str> {
        text.lines().filter(|l| l.split_whitespace().next() == Some(tag)).collect()
    }

    #[test]
    fn numbers_round_trip_exactly() {
        for x in [0.1f32, -0.0, 1.0 / 3.0, 1e-7, -2.5e-30, f32::MAX, f32::MIN_POSITIVE, 1e-45, 123456.79, 7e9] {
            let s = Num(x).to_string();
            assert_eq!(s.parse::<f32>().unwrap().to_bits(), x.to_bits(), "{x} printed as {s}");
            assert!(s.len() <= 15, "{s}");
        }
        assert_eq!(Num(1.0).to_string(), "1");
        assert_eq!(Num(-0.25).to_string(), "-0.25");
    }

    #[test]
    fn cube_positions_exact_and_normals_deduplicated() {
        let cube = fixtures::cube();
        let text = obj_text(&cube, None);
        let v = lines(&text, "v");
        assert_eq!(v.len(), 8);
        for (line, p) in v.iter().zip(&cube.positions) {
            let xyz: Vec<f32> = line.split_whitespace().skip(1).map(|s| s.parse().unwrap()).collect();
            assert_eq!(xyz.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), p.to_array().map(f32::to_bits));
        }
        assert_eq!(lines(&text, "vn").len(), 6);
        assert!(lines(&text, "vt").is_empty());
        let f = lines(&text, "f");
        assert_eq!(f.len(), 12);
        assert!(f.iter().all(|l| l.split_whitespace().skip(1).all(|c| c.contains("//"))), "{f:?}");
        assert!(!text.contains("usemtl") && !text.contains("mtllib"));
        assert!(!needs_mtl(&cube));
    }

    #[test]
    fn faces_index_what_they_should() {
        let m = fixtures::two_material_box();
        let text = obj_text(&m, None);
        let v: Vec<Vec<f32>> =
            lines(&text, "v").iter().map(|l| l.split_whitespace().skip(1).map(|s| s.parse().unwrap()).collect()).collect();
        let vt: Vec<Vec<f32>> =
            lines(&text, "vt").iter().map(|l| l.split_whitespace().skip(1).map(|s| s.parse().unwrap()).collect()).collect();
        let vn: Vec<Vec<f32>> =
            lines(&text, "vn").iter().map(|l| l.split_whitespace().skip(1).map(|s| s.parse().unwrap()).collect()).collect();
        assert_eq!(vt.len(), 4, "the box maps every face to the unit square");
        for (f, line) in lines(&text, "f").iter().enumerate() {
            for (k, corner) in line.split_whitespace().skip(1).enumerate() {
                let idx: Vec<usize> = corner.split('/').map(|s| s.parse().unwrap()).collect();
                let c = 3 * f + k;
                assert_eq!(v[idx[0] - 1], m.positions[m.triangles[f][k] as usize].to_array());
                assert_eq!(vt[idx[1] - 1], [m.uvs[c].x, 1.0 - m.uvs[c].y], "OBJ's v runs up");
                assert_eq!(vn[idx[2] - 1], m.normals[c].to_array());
            }
        }
    }

    #[test]
    fn materials_get_runs_and_a_library() {
        let mut m = fixtures::two_material_box();
        m.materials[1].texture = Some("tex/top.png".into());
        assert!(needs_mtl(&m));
        let text = obj_text(&m, Some("box.mtl"));
        assert_eq!(text.lines().nth(1), Some("mtllib box.mtl"));
        let runs = 1 + m.face_materials.windows(2).filter(|w| w[0] != w[1]).count();
        assert_eq!(lines(&text, "usemtl").len(), runs);
        assert!(runs >= 2);
        let mut mtl = Vec::new();
        write_mtl(&mut mtl, &m, &[]).unwrap();
        let mtl = String::from_utf8(mtl).unwrap();
        assert_eq!(lines(&mtl, "newmtl"), ["newmtl sides", "newmtl top"]);
        assert_eq!(lines(&mtl, "Kd").len(), 2);
        assert_eq!(lines(&mtl, "map_Kd"), ["map_Kd tex/top.png"]);
        let c = m.materials[1].base_color;
        assert!(mtl.contains(&format!("Kd {} {} {}\nd {}", c[0], c[1], c[2], c[3])));
    }

    #[test]
    fn maps_write_their_images_beside_the_obj() {
        let mut m = fixtures::two_material_box();
        let png = crate::texture::encode(crate::texture::ImageCodec::Png, &crate::texture::Rgba8::new(2, 2), 90).unwrap();
        m.images = vec![
            crate::texture::SourceImage::new("maps\\wall paper.png".into(), png.clone()).unwrap(),
            crate::texture::SourceImage::new("unused.png".into(), png.clone()).unwrap(),
        ];
        let slot = crate::format::TextureSlot { image: 0, wrap: [crate::format::Wrap::Clamp; 2] };
        m.materials[0].maps[MapKind::BaseColor as usize] = Some(slot);
        m.materials[1].maps[MapKind::Normal as usize] = Some(slot);
        let dir = std::env::temp_dir().join(format!("strata-obj-export-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("box.obj");
        write(&path, &m).unwrap();
        let mtl = std::fs::read_to_string(dir.join("box.mtl")).unwrap();
        assert_eq!(lines(&mtl, "map_Kd"), ["map_Kd -clamp on box_wall_paper.png"]);
        assert_eq!(lines(&mtl, "norm"), ["norm -clamp on box_wall_paper.png"]);
        assert_eq!(std::fs::read(dir.join("box_wall_paper.png")).unwrap(), png);
        assert!(!dir.join("box_unused.png").exists(), "an image no map uses is not written");
        // Again: the same image is kept; another image of that name is not replaced.
        write(&path, &m).unwrap();
        let other = crate::texture::encode(crate::texture::ImageCodec::Png, &crate::texture::Rgba8::new(3, 3), 90).unwrap();
        let mut changed = m.clone();
        changed.images[0] = crate::texture::SourceImage::new("maps/wall paper.png".into(), other).unwrap();
        let e = write(&dir.join("box.obj"), &changed).unwrap_err().to_string();
        assert!(e.contains("box_wall_paper.png") && e.contains("does not replace it"), "{e}");
        assert_eq!(std::fs::read(dir.join("box_wall_paper.png")).unwrap(), png);
        // Names that collide get numbered until free.
        let mut many = m.clone();
        let named = |n: &str| crate::texture::SourceImage::new(n.into(), png.clone()).unwrap();
        many.images = vec![named("x_1.png"), named("x.png"), named("sub/x.png"), named("x.png")];
        for (k, mat) in many.materials.iter_mut().enumerate() {
            mat.maps[MapKind::BaseColor as usize] = Some(crate::format::TextureSlot { image: k as u32, ..slot });
            mat.maps[MapKind::Emissive as usize] = Some(crate::format::TextureSlot { image: 2 + k as u32, ..slot });
        }
        let names: Vec<String> = image_files(&many, "o").into_iter().flatten().collect();
        assert_eq!(names, ["o_x_1.png", "o_x.png", "o_x_2.png", "o_x_3.png"]);
        // Read back: the same image, the same maps, the same UVs.
        let back = crate::import::import(&path, None).unwrap().mesh;
        assert_eq!(&back.images[0].bytes[..], &png[..]);
        assert_eq!(back.materials.iter().filter_map(|x| x.map(MapKind::BaseColor)).count(), 1);
        assert_eq!(back.uvs.len(), m.uvs.len());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn material_names_are_usable_and_unique() {
        let named = |n: &str| Material { name: n.into(), ..Material::default() };
        let names = material_names(&[named("my mat"), named("my_mat"), named(""), named("my_mat")]);
        assert_eq!(names, ["my_mat", "my_mat_1", "material", "my_mat_3"]);
    }

    #[test]
    fn colors_extend_vertex_lines() {
        let m = fixtures::colored_sphere(1);
        let text = obj_text(&m, None);
        let v = lines(&text, "v");
        assert!(v.len() >= m.vertex_count());
        for (f, line) in lines(&text, "f").iter().enumerate() {
            for (k, corner) in line.split_whitespace().skip(1).enumerate() {
                let i: usize = corner.split('/').next().unwrap().parse().unwrap();
                let rgb: Vec<f32> = v[i - 1].split_whitespace().skip(4).map(|s| s.parse().unwrap()).collect();
                let expect = &m.colors[3 * f + k][..3];
                assert_eq!(rgb.iter().map(|x| (x * 255.0).round() as u8).collect::<Vec<_>>(), expect);
            }
        }
    }

    #[test]
    fn write_creates_obj_and_mtl() {
        let dir = std::env::temp_dir().join(format!("strata-obj-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write(&dir.join("box.obj"), &fixtures::two_material_box()).unwrap();
        let text = std::fs::read_to_string(dir.join("box.obj")).unwrap();
        assert!(text.contains("mtllib box.mtl\n"));
        assert!(std::fs::read_to_string(dir.join("box.mtl")).unwrap().contains("newmtl top"));
        write(&dir.join("cube.obj"), &fixtures::cube()).unwrap();
        assert!(!dir.join("cube.mtl").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
