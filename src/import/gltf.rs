//! glTF 2.0 import: `.gltf` (JSON with external or `data:` buffers) and `.glb`.
//!
//! Every triangle primitive of the default scene (scene 0 when none is marked default; every mesh
//! once, untransformed, when the file has no scenes) lands in one raw mesh under its node's world
//! transform: normals by the inverse transpose, winding flipped under a mirroring transform, strips
//! and fans expanded. Point and line primitives are skipped with a warning. Skins, morph targets
//! and EXT_mesh_gpu_instancing are not applied (meshes keep their bind pose; an instanced mesh is
//! imported once, with a warning).
//!
//! Corner attributes come from NORMAL, TEXCOORD_0 (with the base color texture's
//! KHR_texture_transform applied) and COLOR_0. When only some primitives have one of them, the
//! others are filled so the corner array stays complete: face normals, UV (0, 0), opaque white.
//!
//! Accessors are read by one bounds-checked reader here rather than the gltf crate's iterators:
//! those read POSITION and NORMAL as f32 whatever the component type (KHR_mesh_quantization
//! stores them as integers) and index out of bounds on empty or short accessors. The reader also
//! checks strides and offsets against element sizes, so that no element is read from bytes that
//! belong to another.
//!
//! The partitioned build streams a file ([`stream`]): its buffers read whole, as here, the vertex
//! attributes of all primitives held, and each primitive's triangles handed on in batches.
//!
//! External buffers are read only from the glTF file's folder, unless
//! [`ImportOptions::allow_outside_files`]; so are images (files, `data:` URIs or buffer views, PNG
//! or JPEG), which become the materials' maps (base color, normal, metallic-roughness, occlusion,
//! emissive) on TEXCOORD_0. An image that cannot be read is a warning, and its maps are left out.

use super::{ImportOptions, Raw};
use crate::error::{Error, Result};
use crate::format::{TextureSlot, Wrap, MAP_KINDS};
use crate::mesh::{coordinate_problem, Material, Mesh};
use crate::texture::SourceImage;
use base64::Engine;
use glam::{Affine2, Mat3, Mat4, Vec2, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::json;
use gltf::mesh::{Mode, Semantic};
use std::borrow::Cow;
use std::ops::Range;
use std::path::Path;

/// Required extensions whose data strata cannot decode.
const UNDECODABLE: &[&str] = &["KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_meshopt_compression"];
/// Required extensions this reader implements.
const HANDLED: &[&str] = &["KHR_mesh_quantization", "KHR_texture_transform"];
/// Required extensions that change only shading, which strata does not keep.
const APPEARANCE_ONLY: &[&str] = &["KHR_texture_basisu", "EXT_texture_webp", "EXT_texture_avif", "KHR_lights_punctual"];

/// Read a glTF or GLB file into a raw, uncleaned mesh. External buffers must lie in the file's
/// folder unless `options.allow_outside_files`.
pub fn read(path: &Path, options: &ImportOptions, warnings: &mut Vec<String>) -> Result<Raw> {
    // glTF's unit is the metre (glTF 2.0 §3.4).
    read_mesh(path, options, warnings).map(|mesh| Raw { mesh, metres_per_unit: Some(1.0), georef: None, grid: None })
}

fn read_mesh(path: &Path, options: &ImportOptions, warnings: &mut Vec<String>) -> Result<Mesh> {
    with_scene(path, options, warnings, |scene, warnings| {
        let mut builder = Builder::new(scene.doc);
        for (mesh_index, prim, world) in scene.primitives {
            builder.add(scene.buffers, *mesh_index, prim, *world)?;
        }
        if builder.mesh.triangles.is_empty() {
            return Err(Error::invalid(path, None, "no triangles in the imported scene"));
        }
        let mut mesh = builder.finish(warnings);
        load_images(path, scene.doc, scene.buffers, &scene.maps, options.allow_outside_files, &mut mesh, warnings);
        Ok(mesh)
    })
}

/// A file's scene as the readers take it: the document, the triangle primitives of its scene
/// with their meshes and world transforms, the materials' maps and the buffers those use.
struct Scene<'a> {
    doc: &'a gltf::Document,
    primitives: &'a [(usize, gltf::Primitive<'a>, Mat4)],
    maps: Vec<GltfMaps>,
    buffers: &'a Buffers<'a>,
}

/// Read, check and open `path`'s scene, and hand it to `f`.
fn with_scene<R>(
    path: &Path,
    options: &ImportOptions,
    warnings: &mut Vec<String>,
    f: impl FnOnce(&Scene, &mut Vec<String>) -> Result<R>,
) -> Result<R> {
    let bytes = super::read_file(path)?;
    let glb = bytes.starts_with(b"glTF");
    let (json_bytes, bin) = if glb { split_glb(path, &bytes)? } else { (&bytes[..], None) };
    let doc = document(path, json_bytes, glb, warnings)?;
    let (primitives, skipped) = triangle_primitives(path, &doc, warnings)?;
    if skipped > 0 {
        warnings.push(format!("{skipped} point or line primitives skipped"));
    }
    let used = primitives.iter().map(|(_, p, _)| p);
    let maps = material_maps(&doc, warnings);
    let image_buffers: Vec<usize> = maps
        .iter()
        .flatten()
        .flatten()
        .filter_map(|(image, _)| doc.as_json().images.get(*image as usize)?.buffer_view)
        .filter_map(|view| Some(doc.views().nth(view.value())?.buffer().index()))
        .collect();
    let buffers = Buffers::load(path, &doc, bin, bytes.len(), used, &image_buffers, options.allow_outside_files)?;
    f(&Scene { doc: &doc, primitives: &primitives, maps, buffers: &buffers }, warnings)
}

/// The document of a glTF JSON text, its extensions and indices checked.
fn document(path: &Path, json_bytes: &[u8], glb: bool, warnings: &mut Vec<String>) -> Result<gltf::Document> {
    let root = parse_json(path, json_bytes, glb)?;
    check_extensions(path, &root, warnings)?;
    validate(path, &root)?;
    Ok(gltf::Document::from_json_without_validation(root))
}

/// The scene's triangle primitives (mesh index, primitive, world transform), and how many point
/// or line primitives were left out.
type Primitives<'a> = Vec<(usize, gltf::Primitive<'a>, Mat4)>;
fn triangle_primitives<'a>(path: &Path, doc: &'a gltf::Document, warnings: &mut Vec<String>) -> Result<(Primitives<'a>, usize)> {
    let mut skipped = 0;
    let mut primitives = Vec::new();
    for (mesh, world) in scene_meshes(path, doc, warnings)? {
        for prim in mesh.primitives() {
            if matches!(prim.mode(), Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                primitives.push((mesh.index(), prim, world));
            } else {
                skipped += 1;
            }
        }
    }
    Ok((primitives, skipped))
}

/// The triangles the primitives of `path` make, from its JSON alone (a GLB's binary chunk is
/// not read): what the partitioned build plans its cells by.
pub fn streaming_declared(path: &Path) -> Result<super::stream::Declared> {
    use std::io::Read as _;
    let (file, len) = super::open_regular(path)?;
    let mut file = std::io::BufReader::new(file);
    let mut head = [0u8; 20];
    let n = (&mut file).take(20).read(&mut head).map_err(|e| Error::io(path, e))?;
    let glb = head[..n].starts_with(b"glTF");
    let json = if glb {
        let chunk = u32_at(&head, 12)
            .filter(|_| n == 20 && &head[16..20] == b"JSON")
            .ok_or_else(|| Error::at_byte(path, 12, "a GLB whose first chunk is not a JSON chunk"))? as u64;
        if chunk > len.saturating_sub(20) {
            return Err(Error::at_byte(path, 12, format!("GLB JSON chunk of {chunk} bytes runs past the end of the file ({len} bytes)")));
        }
        let mut json = Vec::with_capacity(chunk as usize);
        (&mut file).take(chunk).read_to_end(&mut json).map_err(|e| Error::io(path, e))?;
        json
    } else {
        let mut json = head[..n].to_vec();
        file.read_to_end(&mut json).map_err(|e| Error::io(path, e))?;
        json
    };
    let doc = document(path, &json, glb, &mut Vec::new())?;
    let (primitives, _) = triangle_primitives(path, &doc, &mut Vec::new())?;
    let triangles = primitives
        .iter()
        .map(|(_, p, _)| {
            let count = p.indices().or_else(|| p.get(&Semantic::Positions)).map_or(0, |a| a.count() as u64);
            match p.mode() {
                Mode::Triangles => count / 3,
                _ => count.saturating_sub(2),
            }
        })
        .sum();
    Ok(super::stream::Declared { triangles, refused: None })
}

/// glTF as a stream, for the partitioned build: the buffers are read as the whole-file reader
/// reads them, every primitive's vertex attributes are held (transformed, in one array each),
/// and each primitive's triangles are handed on in batches, their corners' normals and UVs and
/// their materials with them, filled where a primitive lacks what others have, as [`read`] fills
/// them. Its materials and images come after.
pub fn stream(
    path: &Path,
    options: &ImportOptions,
    sink: &mut super::stream::FaceSink,
    warnings: &mut Vec<String>,
) -> Result<super::stream::Looks> {
    use super::stream::{Faces, Looks, Vertices, BATCH};
    with_scene(path, options, warnings, |scene, warnings| {
        let mut builder = Builder::new(scene.doc);
        let (mut positions, mut normals, mut uvs, mut colors) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        // Per primitive: its first vertex, vertex count, what it has, its material, whether it mirrors.
        let mut held = Vec::with_capacity(scene.primitives.len());
        for (mesh_index, prim, world) in scene.primitives {
            let v = builder.vertices(scene.buffers, *mesh_index, prim, *world)?;
            let (base, n) = (positions.len(), v.positions.len());
            if base + n > u32::MAX as usize {
                return Err(Error::at_element(
                    path,
                    format!("mesh {mesh_index} primitive {}", prim.index()),
                    "more than 2^32 vertices in total",
                ));
            }
            let has = [v.normals.is_some(), v.uvs.is_some(), v.colors.is_some()];
            positions.extend(v.positions);
            normals.extend(v.normals.unwrap_or_else(|| vec![Vec3::ZERO; n]));
            uvs.extend(v.uvs.unwrap_or_else(|| vec![Vec2::ZERO; n]));
            colors.extend(v.colors.unwrap_or_else(|| vec![[255; 4]; n]));
            for (present, has) in builder.present.iter_mut().zip(has) {
                *present |= has;
            }
            held.push((base as u32, n, has, v.material, v.flip));
        }
        let [with_normals, with_uvs, with_colors] = builder.present;
        if !with_normals {
            normals = Vec::new();
        }
        if !with_uvs {
            uvs = Vec::new();
        }
        if !with_colors {
            colors = Vec::new();
        }
        let vertices = Vertices { positions: &positions, normals: &[], colors: &colors };
        let (mut tris, mut corner_normals, mut corner_uvs, mut materials) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut faces = 0usize;
        for ((mesh_index, prim, _), &(base, n, has, material, flip)) in scene.primitives.iter().zip(&held) {
            let triangles = builder.triangles(scene.buffers, *mesh_index, prim, n, flip)?;
            builder.note(faces..faces + triangles.len(), has);
            faces += triangles.len();
            for t in triangles {
                let t = t.map(|v| base + v);
                tris.push(t);
                if with_normals {
                    corner_normals.push(if has[0] {
                        t.map(|v| normals[v as usize])
                    } else {
                        let [a, b, c] = t.map(|v| positions[v as usize]);
                        [(b - a).cross(c - a).normalize_or_zero(); 3]
                    });
                }
                if with_uvs {
                    corner_uvs.push(t.map(|v| uvs[v as usize]));
                }
                materials.push(material);
                if tris.len() >= BATCH {
                    sink(&vertices, &Faces { triangles: &tris, normals: &corner_normals, uvs: &corner_uvs, materials: &materials })?;
                    tris.clear();
                    corner_normals.clear();
                    corner_uvs.clear();
                    materials.clear();
                }
            }
        }
        if faces == 0 {
            return Err(Error::invalid(path, None, "no triangles in the imported scene"));
        }
        if !tris.is_empty() {
            sink(&vertices, &Faces { triangles: &tris, normals: &corner_normals, uvs: &corner_uvs, materials: &materials })?;
        }
        builder.warn(warnings);
        let mut looks = Mesh { materials: std::mem::take(&mut builder.mesh.materials), ..Mesh::default() };
        load_images(path, scene.doc, scene.buffers, &scene.maps, options.allow_outside_files, &mut looks, warnings);
        Ok(Looks { materials: looks.materials, images: looks.images })
    })
}

/// A material's maps as glTF names them: per [`MapKind`] slot, the glTF image and the wrap modes.
type GltfMaps = [Option<(u32, [Wrap; 2])>; MAP_KINDS];

/// Each glTF material's maps that use TEXCOORD_0 (strata keeps one UV set); maps on other sets are
/// left out with a warning.
fn material_maps(doc: &gltf::Document, warnings: &mut Vec<String>) -> Vec<GltfMaps> {
    let wrap = |m: gltf::texture::WrappingMode| match m {
        gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
        gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
        gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
    };
    let mut other_sets = 0;
    let out = doc
        .materials()
        .map(|m| {
            let pbr = m.pbr_metallic_roughness();
            let slots: [Option<(gltf::Texture, u32)>; MAP_KINDS] = [
                pbr.base_color_texture().map(|i| (i.texture(), i.tex_coord())),
                m.normal_texture().map(|i| (i.texture(), i.tex_coord())),
                pbr.metallic_roughness_texture().map(|i| (i.texture(), i.tex_coord())),
                m.occlusion_texture().map(|i| (i.texture(), i.tex_coord())),
                m.emissive_texture().map(|i| (i.texture(), i.tex_coord())),
            ];
            slots.map(|slot| {
                let (t, set) = slot?;
                if set != 0 {
                    other_sets += 1;
                    return None;
                }
                let s = t.sampler();
                Some((t.source().index() as u32, [wrap(s.wrap_s()), wrap(s.wrap_t())]))
            })
        })
        .collect();
    if other_sets > 0 {
        warnings.push(format!("{other_sets} material maps on a UV set other than TEXCOORD_0 left out (strata keeps one UV set)"));
    }
    out
}

/// Read the images the materials' maps use (files beside the model, `data:` URIs, buffer views)
/// into `mesh.images` and set each material's maps. An image that cannot be read or is neither PNG
/// nor JPEG is a warning naming it; the maps using it are left out.
fn load_images(
    path: &Path,
    doc: &gltf::Document,
    buffers: &Buffers,
    maps: &[GltfMaps],
    allow_outside: bool,
    mesh: &mut Mesh,
    warnings: &mut Vec<String>,
) {
    let json = doc.as_json();
    let mut loaded: Vec<Option<Option<u32>>> = vec![None; json.images.len()];
    for (m, slots) in maps.iter().enumerate() {
        for (k, slot) in slots.iter().enumerate() {
            let Some((image, wrap)) = *slot else { continue };
            let index = *loaded.get_mut(image as usize).expect("validated image index").get_or_insert_with(|| {
                let element = format!("image {image}");
                let im = &json.images[image as usize];
                let name = match (im.uri.as_deref(), im.name.as_deref()) {
                    (Some(uri), _) if !uri.starts_with("data:") => uri.to_string(),
                    (_, Some(name)) if !name.is_empty() => name.to_string(),
                    _ => format!("embedded image {image}"),
                };
                let bytes = match (&im.uri, im.buffer_view) {
                    (Some(uri), _) => load_uri(path, &element, uri, allow_outside, MAX_IMAGE_FILE).map_err(|e| e.to_string()),
                    (None, Some(view)) => match doc.views().nth(view.value()) {
                        Some(v) => buffers.view(&v).map(<[u8]>::to_vec).map_err(|e| e.to_string()),
                        None => Err(format!("{element}: no buffer view {}", view.value())),
                    },
                    (None, None) => Err(format!("{element}: neither a uri nor a bufferView")),
                };
                match bytes.and_then(|b| SourceImage::new(name.clone(), b).map_err(|e| format!("{element} ({name}): {e}"))) {
                    Ok(source) => {
                        mesh.images.push(source);
                        Some(mesh.images.len() as u32 - 1)
                    }
                    Err(e) => {
                        warnings.push(format!("texture left out: {e}"));
                        None
                    }
                }
            });
            if let (Some(index), Some(mat)) = (index, mesh.materials.get_mut(m)) {
                mat.maps[k] = Some(TextureSlot { image: index, wrap });
            }
        }
    }
}

/// Largest image file read.
const MAX_IMAGE_FILE: u64 = 1 << 30;

fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(bytes.get(at..at.checked_add(4)?)?.try_into().ok()?))
}

/// Split a GLB container into its JSON chunk and its first BIN chunk, if any.
fn split_glb<'a>(path: &Path, bytes: &'a [u8]) -> Result<(&'a [u8], Option<&'a [u8]>)> {
    let (Some(version), Some(length)) = (u32_at(bytes, 4), u32_at(bytes, 8)) else {
        return Err(Error::at_byte(path, 0, "truncated GLB header (needs 12 bytes)"));
    };
    if version != 2 {
        return Err(Error::at_byte(path, 4, format!("GLB version {version}; only version 2 is supported")));
    }
    let length = length as usize;
    if length > bytes.len() {
        return Err(Error::at_byte(path, 8, format!("truncated GLB: the header declares {length} bytes but the file has {}", bytes.len())));
    }
    let data = &bytes[..length];
    let (mut json, mut bin) = (None, None);
    let mut at = 12;
    while at < data.len() {
        let (Some(chunk_length), Some(kind)) = (u32_at(data, at), data.get(at + 4..at + 8)) else {
            return Err(Error::at_byte(path, at as u64, "truncated GLB chunk header"));
        };
        let start = at + 8;
        let end = start + chunk_length as usize;
        let Some(chunk) = data.get(start..end) else {
            return Err(Error::at_byte(
                path,
                at as u64,
                format!("GLB chunk of {chunk_length} bytes runs past the end of the data ({length} bytes)"),
            ));
        };
        match kind {
            b"JSON" if json.is_none() => json = Some(chunk),
            b"BIN\0" if bin.is_none() => bin = Some(chunk),
            _ if json.is_none() => return Err(Error::at_byte(path, at as u64, "the first GLB chunk is not JSON")),
            _ => {}
        }
        at = end;
    }
    match json {
        Some(json) => Ok((json, bin)),
        None => Err(Error::at_byte(path, 12, "GLB without a JSON chunk")),
    }
}

fn parse_json(path: &Path, bytes: &[u8], glb: bool) -> Result<json::Root> {
    let bytes = bytes.strip_prefix("\u{feff}".as_bytes()).unwrap_or(bytes);
    json::Root::from_slice(bytes).map_err(|e| {
        if let Some(why) = super::utf16_hint(bytes) {
            return Error::invalid(path, None, why);
        }
        let text = e.to_string();
        let message = format!("invalid glTF JSON: {}", text.rsplit_once(" at line ").map_or(text.as_str(), |(m, _)| m));
        match (e.line(), glb) {
            (0, _) => Error::invalid(path, None, message),
            (line, false) => Error::at_line(path, line, format!("column {}: {message}", e.column())),
            (line, true) => Error::at_element(path, format!("JSON chunk line {line} column {}", e.column()), message),
        }
    })
}

fn check_extensions(path: &Path, root: &json::Root, warnings: &mut Vec<String>) -> Result<()> {
    for ext in &root.extensions_required {
        let ext = ext.as_str();
        if UNDECODABLE.contains(&ext) {
            return Err(Error::at_element(
                path,
                "extensionsRequired",
                format!(
                    "the file requires {ext}: compressed geometry strata cannot decode \
                     (decompress it first, e.g. with gltf-transform)"
                ),
            ));
        }
        if ext.starts_with("KHR_materials_") || APPEARANCE_ONLY.contains(&ext) {
            warnings.push(format!("required extension {ext} ignored: it changes only appearance"));
        } else if !HANDLED.contains(&ext) {
            return Err(Error::at_element(path, "extensionsRequired", format!("the file requires {ext}, which strata does not support")));
        }
    }
    if root.extensions_used.iter().any(|e| e == "EXT_mesh_gpu_instancing") {
        warnings.push("EXT_mesh_gpu_instancing ignored: each instanced mesh is imported once, at its node".into());
    }
    Ok(())
}

/// The gltf crate's validation, minus what this reader handles itself (required extensions,
/// byteStride) or does not need (POSITION min/max).
fn validate(path: &Path, root: &json::Root) -> Result<()> {
    use json::validation::{Error as Problem, Validate};
    // The validator indexes the POSITION accessor unchecked: check attribute references first.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(bad) = prim.attributes.values().find(|a| a.value() >= root.accessors.len()) {
                return Err(Error::at_element(
                    path,
                    format!("mesh {m} primitive {p}"),
                    format!("attribute refers to accessor {} but the file has {}", bad.value(), root.accessors.len()),
                ));
            }
        }
    }
    let mut problems = Vec::new();
    root.validate(root, json::Path::new, &mut |at: &dyn Fn() -> json::Path, problem| {
        let at = at().to_string();
        let ignored = (problem == Problem::Unsupported && at.starts_with("extensionsRequired"))
            || (at.contains("\"POSITION\"") && (at.ends_with(".min") || at.ends_with(".max")))
            || at.ends_with(".byteStride");
        if !ignored {
            problems.push((at, problem));
        }
    });
    match problems.first() {
        None => Ok(()),
        Some((at, problem)) => {
            let more = if problems.len() > 1 { format!(" (and {} more problems)", problems.len() - 1) } else { String::new() };
            Err(Error::at_element(path, at.clone(), format!("{problem}{more}")))
        }
    }
}

/// Meshes to import with their world transforms, in scene order.
fn scene_meshes<'a>(path: &Path, doc: &'a gltf::Document, warnings: &mut Vec<String>) -> Result<Vec<(gltf::Mesh<'a>, Mat4)>> {
    let Some(scene) = doc.default_scene().or_else(|| doc.scenes().next()) else {
        return Ok(doc.meshes().map(|m| (m, Mat4::IDENTITY)).collect());
    };
    let scenes = doc.scenes().count();
    if scenes > 1 {
        warnings.push(format!("the file has {scenes} scenes; imported scene {}", scene.index()));
    }
    let mut seen = vec![false; doc.nodes().count()];
    let mut out = Vec::new();
    let mut stack: Vec<(gltf::Node, Mat4)> = scene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
    stack.reverse();
    while let Some((node, parent)) = stack.pop() {
        if seen.get_mut(node.index()).is_none_or(|s| std::mem::replace(s, true)) {
            return Err(Error::at_element(
                path,
                format!("node {}", node.index()),
                format!("appears twice in scene {}'s hierarchy (a cycle or a shared child)", scene.index()),
            ));
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            out.push((mesh, world));
        }
        let first_child = stack.len();
        stack.extend(node.children().map(|c| (c, world)));
        stack[first_child..].reverse();
    }
    Ok(out)
}

/// Buffer contents, loaded for the buffers the imported primitives use.
struct Buffers<'a> {
    path: &'a Path,
    data: Vec<Option<Cow<'a, [u8]>>>,
    /// Bytes in the file and all loaded buffers: an upper bound on elements an accessor without a
    /// buffer view may declare.
    total: usize,
}

impl<'a> Buffers<'a> {
    fn load<'d>(
        path: &'a Path,
        doc: &'d gltf::Document,
        bin: Option<&'a [u8]>,
        file_size: usize,
        primitives: impl Iterator<Item = &'d gltf::Primitive<'d>>,
        also: &[usize],
        allow_outside: bool,
    ) -> Result<Self> {
        let mut needed = vec![false; doc.buffers().count()];
        for &b in also {
            if let Some(n) = needed.get_mut(b) {
                *n = true;
            }
        }
        for prim in primitives {
            let semantics = [Semantic::Positions, Semantic::Normals, Semantic::TexCoords(0), Semantic::Colors(0)];
            for a in semantics.iter().filter_map(|s| prim.get(s)).chain(prim.indices()) {
                let views = a.view().into_iter().chain(a.sparse().into_iter().flat_map(|s| [s.indices().view(), s.values().view()]));
                for view in views {
                    if let Some(n) = needed.get_mut(view.buffer().index()) {
                        *n = true;
                    }
                }
            }
        }
        let mut data = Vec::with_capacity(needed.len());
        let mut total = file_size;
        for (buffer, needed) in doc.buffers().zip(needed) {
            if !needed {
                data.push(None);
                continue;
            }
            let element = format!("buffer {}", buffer.index());
            let bytes: Cow<[u8]> = match buffer.source() {
                gltf::buffer::Source::Bin => Cow::Borrowed(
                    bin.ok_or_else(|| Error::at_element(path, &element, "refers to the GLB binary chunk, but there is none"))?,
                ),
                gltf::buffer::Source::Uri(uri) => Cow::Owned(load_uri(path, &element, uri, allow_outside, buffer.length() as u64)?),
            };
            if bytes.len() < buffer.length() {
                return Err(Error::at_element(
                    path,
                    element,
                    format!("holds {} bytes, fewer than its byteLength {}", bytes.len(), buffer.length()),
                ));
            }
            total = total.saturating_add(bytes.len());
            data.push(Some(bytes));
        }
        Ok(Buffers { path, data, total })
    }

    /// The bytes of a buffer view, checked against its buffer.
    fn view(&self, view: &gltf::buffer::View) -> Result<&[u8]> {
        let b = view.buffer().index();
        let range = view.offset()..view.offset().saturating_add(view.length());
        let data = self.data.get(b).and_then(Option::as_deref).unwrap_or_default();
        data.get(range.clone()).ok_or_else(|| {
            Error::at_element(
                self.path,
                format!("buffer view {}", view.index()),
                format!("bytes {}..{} lie outside buffer {b} ({} bytes)", range.start, range.end, data.len()),
            )
        })
    }

    /// Decode every element of an accessor (sparse substitutions applied); `decode` gets exactly
    /// one element's bytes. Vertex attributes (`packed` None) step by their view's byteStride;
    /// data glTF stores tightly packed is named by `packed` (e.g. "indices").
    fn read<T>(&self, a: &gltf::Accessor, packed: Option<&str>, decode: impl Fn(&[u8]) -> T) -> Result<Vec<T>> {
        let err = |message: String| Error::at_element(self.path, format!("accessor {}", a.index()), message);
        let (count, size) = (a.count(), a.size());
        let mut out = Vec::new();
        match a.view() {
            Some(view) => {
                let bytes = self.view(&view)?;
                let stride = stride(a, &view, packed).map_err(err)?;
                let end = count.checked_sub(1).map_or(Some(0), |last| last.checked_mul(stride)?.checked_add(a.offset())?.checked_add(size));
                if end.is_none_or(|end| end > bytes.len()) {
                    return Err(err(format!(
                        "{count} elements of {size} bytes (offset {}, stride {stride}) \
                         overrun buffer view {} of {} bytes",
                        a.offset(),
                        view.index(),
                        bytes.len()
                    )));
                }
                out.reserve_exact(count);
                out.extend((0..count).map(|i| decode(&bytes[a.offset() + i * stride..][..size])));
            }
            None => {
                if count > self.total {
                    return Err(err(format!("{count} elements without a buffer view: more than the file could hold")));
                }
                let zero = vec![0u8; size];
                out.extend((0..count).map(|_| decode(&zero)));
            }
        }
        if let Some(sparse) = a.sparse() {
            let k = sparse.count();
            let (indices, values) = (sparse.indices(), sparse.values());
            let index_size = indices.index_type().size();
            check_packed(&indices.view(), index_size, "sparse indices").map_err(err)?;
            check_packed(&values.view(), size, "sparse values").map_err(err)?;
            let index_bytes = slice(self.view(&indices.view())?, indices.offset(), k, index_size)
                .ok_or_else(|| err(format!("{k} sparse indices overrun their buffer view")))?;
            let value_bytes = slice(self.view(&values.view())?, values.offset(), k, size)
                .ok_or_else(|| err(format!("{k} sparse values overrun their buffer view")))?;
            for (i, value) in index_bytes.chunks_exact(index_size).zip(value_bytes.chunks_exact(size)) {
                let i = uint(i) as usize;
                let slot = out.get_mut(i).ok_or_else(|| err(format!("sparse index {i} out of range for {count} elements")))?;
                *slot = decode(value);
            }
        }
        Ok(out)
    }

    /// An attribute as `N` floats per element: normalized integers map to [0, 1] or [-1, 1],
    /// other integers keep their value (KHR_mesh_quantization).
    fn floats<const N: usize>(&self, a: &gltf::Accessor, semantic: &str) -> Result<Vec<[f32; N]>> {
        if a.dimensions().multiplicity() != N || matches!(a.dimensions(), Dimensions::Mat2) {
            return Err(Error::at_element(
                self.path,
                format!("accessor {}", a.index()),
                format!("{semantic} must have {N} components, has type {:?}", a.dimensions()),
            ));
        }
        let (ty, normalized) = (a.data_type(), a.normalized());
        self.read(a, None, |b| std::array::from_fn(|c| component(b, c, ty, normalized)))
    }

    fn indices(&self, a: &gltf::Accessor) -> Result<Vec<u32>> {
        if a.dimensions() != Dimensions::Scalar || !matches!(a.data_type(), DataType::U8 | DataType::U16 | DataType::U32) {
            return Err(Error::at_element(
                self.path,
                format!("accessor {}", a.index()),
                format!("indices must be unsigned integer scalars, are {:?} {:?}", a.data_type(), a.dimensions()),
            ));
        }
        self.read(a, Some("indices"), uint)
    }

    fn colors(&self, a: &gltf::Accessor) -> Result<Vec<[u8; 4]>> {
        let to_u8 = |c: f32| (c.clamp(0.0, 1.0) * 255.0).round() as u8;
        if a.dimensions() == Dimensions::Vec3 {
            Ok(self.floats::<3>(a, "COLOR_0")?.into_iter().map(|c| [to_u8(c[0]), to_u8(c[1]), to_u8(c[2]), 255]).collect())
        } else {
            Ok(self.floats::<4>(a, "COLOR_0")?.into_iter().map(|c| c.map(to_u8)).collect())
        }
    }
}

/// The step between elements of accessor `a` in `view`, checked so that elements neither overlap
/// nor straddle a stride: the view's byteStride for a vertex attribute, the element size for data
/// glTF stores tightly packed (`packed` names it, e.g. "indices").
///
/// glTF also wants a byteStride that is a multiple of 4 within 4..=252, and offsets that are
/// multiples of the component size: alignment and limits for GPU vertex fetch. Files that break
/// only those rules are accepted (a byteStride of 0 meaning tightly packed, as the gltf crate reads
/// it), because this reader decodes every component from bytes: they read exactly as their writer
/// meant, and refusing them would only lose a model whose data is clear.
fn stride(a: &gltf::Accessor, view: &gltf::buffer::View, packed: Option<&str>) -> std::result::Result<usize, String> {
    let (offset, size) = (a.offset(), a.size());
    if let Some(what) = packed {
        check_packed(view, size, what)?;
        return Ok(size);
    }
    let Some(stride) = view.stride() else { return Ok(size) };
    let (dims, ty) = (dimensions_name(a.dimensions()), component_name(a.data_type()));
    let element = format!("{size}-byte elements ({dims} of {ty})");
    if stride < size {
        return Err(format!(
            "buffer view {} has byteStride {stride}, less than the accessor's {element}: elements would overlap",
            view.index()
        ));
    }
    // An offset past a whole stride starts at a later element; one that leaves less than an
    // element before the next stride would read each element across two.
    if offset % stride + size > stride {
        return Err(format!(
            "byteOffset {offset} puts the accessor's {element} across the byteStride {stride} of buffer view {}: \
             each would run into the next",
            view.index()
        ));
    }
    Ok(stride)
}

/// Check that `view` does not give tightly packed data (`what`) a byteStride other than its
/// element size, which glTF forbids and which would read differently with and without it.
fn check_packed(view: &gltf::buffer::View, size: usize, what: &str) -> std::result::Result<(), String> {
    match view.stride() {
        Some(stride) if stride != size => Err(format!(
            "{what}: buffer view {} has byteStride {stride}, but glTF stores {what} tightly packed \
             ({size}-byte elements); the view must not set byteStride",
            view.index()
        )),
        _ => Ok(()),
    }
}

fn component_name(ty: DataType) -> &'static str {
    match ty {
        DataType::I8 => "byte",
        DataType::U8 => "unsigned byte",
        DataType::I16 => "short",
        DataType::U16 => "unsigned short",
        DataType::U32 => "unsigned int",
        DataType::F32 => "float",
    }
}

fn dimensions_name(d: Dimensions) -> &'static str {
    match d {
        Dimensions::Scalar => "SCALAR",
        Dimensions::Vec2 => "VEC2",
        Dimensions::Vec3 => "VEC3",
        Dimensions::Vec4 => "VEC4",
        Dimensions::Mat2 => "MAT2",
        Dimensions::Mat3 => "MAT3",
        Dimensions::Mat4 => "MAT4",
    }
}

/// `k` elements of `size` bytes from `offset` on, if the bytes hold them.
fn slice(bytes: &[u8], offset: usize, k: usize, size: usize) -> Option<&[u8]> {
    bytes.get(offset..)?.get(..k.checked_mul(size)?)
}

/// A little-endian unsigned integer of 1, 2 or 4 bytes.
fn uint(b: &[u8]) -> u32 {
    b.iter().rev().fold(0, |v, &byte| (v << 8) | u32::from(byte))
}

/// Component `c` of an element's bytes, as glTF defines normalized integer conversion.
fn component(b: &[u8], c: usize, ty: DataType, normalized: bool) -> f32 {
    let bytes = &b[c * ty.size()..(c + 1) * ty.size()];
    let (value, max) = match ty {
        DataType::F32 => return f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]),
        DataType::I8 => (f32::from(bytes[0] as i8), 127.0),
        DataType::U8 => (f32::from(bytes[0]), 255.0),
        DataType::I16 => (f32::from(i16::from_le_bytes([bytes[0], bytes[1]])), 32767.0),
        DataType::U16 => (f32::from(u16::from_le_bytes([bytes[0], bytes[1]])), 65535.0),
        DataType::U32 => (uint(bytes) as f32, u32::MAX as f32),
    };
    if normalized {
        (value / max).max(-1.0)
    } else {
        value
    }
}

/// Read an external or `data:` URI, relative to the glTF file. A file name must stay inside the
/// glTF file's folder unless `allow_outside`.
/// The bytes of a buffer's `uri` (a data: URI or a file in the model's folder), at most `max_len`
/// of them (its byteLength: a file may be longer).
fn load_uri(path: &Path, element: &str, uri: &str, allow_outside: bool, max_len: u64) -> Result<Vec<u8>> {
    if let Some(data) = uri.strip_prefix("data:") {
        let Some((header, payload)) = data.split_once(',') else {
            return Err(Error::at_element(path, element, "malformed data URI (no comma)"));
        };
        if !header.ends_with(";base64") {
            return Ok(percent_decode(payload));
        }
        let engine = base64::engine::GeneralPurpose::new(
            &base64::alphabet::STANDARD,
            base64::engine::GeneralPurposeConfig::new().with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
        );
        return engine.decode(payload.trim()).map_err(|e| Error::at_element(path, element, format!("bad base64 in data URI: {e}")));
    }
    if uri.split_once(':').is_some_and(|(scheme, _)| scheme.len() > 1 && !scheme.contains('/')) {
        return Err(Error::at_element(path, element, format!("unsupported URI '{uri}' (only relative file names and data: URIs)")));
    }
    let name = String::from_utf8(percent_decode(uri)).unwrap_or_else(|_| uri.to_string());
    let folder = path.parent().unwrap_or(Path::new(""));
    if !allow_outside && !super::stays_inside(Path::new(&name)) {
        let decoded = if name == uri { String::new() } else { format!(" ({name})") };
        let shown = if folder.as_os_str().is_empty() { Path::new(".") } else { folder };
        return Err(Error::at_element(
            path,
            element,
            format!(
                "uri '{uri}'{decoded} points outside the model's folder {}; strata reads only files \
                 inside it unless given --allow-outside-files",
                shown.display()
            ),
        ));
    }
    let file = folder.join(name);
    crate::atomic::protect(&file);
    let cannot = |e: &dyn std::fmt::Display| Error::at_element(path, element, format!("cannot read {}: {e}", file.display()));
    super::read_regular_file(&file, max_len).map_err(|e| cannot(&e))
}

/// Decode `%XX` escapes; anything else passes through.
fn percent_decode(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = b.get(i + 1..i + 3).and_then(|h| std::str::from_utf8(h).ok()).and_then(|h| u8::from_str_radix(h, 16).ok());
        match (b[i], hex) {
            (b'%', Some(byte)) => {
                out.push(byte);
                i += 3;
            }
            (c, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    out
}

/// Expand a primitive's index list into triangles, as the glTF spec orders strips and fans.
fn assemble(mode: Mode, idx: &[u32]) -> Vec<[u32; 3]> {
    match mode {
        Mode::TriangleStrip => {
            idx.windows(3).enumerate().map(|(i, w)| if i % 2 == 0 { [w[0], w[1], w[2]] } else { [w[0], w[2], w[1]] }).collect()
        }
        Mode::TriangleFan => idx.windows(2).skip(1).map(|w| [w[0], w[1], idx[0]]).collect(),
        _ => idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    }
}

/// The corner attributes, in `Builder::present` / `Builder::missing` order, with what fills the
/// corners of primitives that lack one.
const ATTRIBUTES: [(&str, &str); 3] = [("NORMAL", "face normals"), ("TEXCOORD_0", "UV (0, 0)"), ("COLOR_0", "white")];

/// Accumulates primitives into one raw mesh.
/// One primitive's vertex attributes, transformed, and what its faces take.
struct PrimitiveVertices {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    uvs: Option<Vec<Vec2>>,
    colors: Option<Vec<[u8; 4]>>,
    material: u32,
    flip: bool,
}

struct Builder {
    mesh: Mesh,
    /// Per material: the UV transform of its base color texture (KHR_texture_transform).
    uv_transforms: Vec<Option<Affine2>>,
    /// Id of the default material, once a primitive without material needed it.
    default_material: Option<u32>,
    /// Per attribute: whether any primitive had it, and the face ranges of primitives without it.
    present: [bool; 3],
    missing: [Vec<Range<usize>>; 3],
    trailing_indices: usize,
}

impl Builder {
    fn new(doc: &gltf::Document) -> Self {
        let mut materials = Vec::new();
        let mut uv_transforms = Vec::new();
        for m in doc.materials() {
            let pbr = m.pbr_metallic_roughness();
            let info = pbr.base_color_texture();
            // The image's JSON, not gltf's Image::source(), which unwraps what an invalid image lacks
            // (a uri or a bufferView, a bufferView's mimeType); images are only named, never read.
            let texture = info.as_ref().map(|info| {
                let image = info.texture().source().index();
                match doc.as_json().images.get(image).and_then(|i| i.uri.as_deref()) {
                    Some(uri) if !uri.starts_with("data:") => uri.to_string(),
                    _ => format!("embedded image {image}"),
                }
            });
            let transform = info.and_then(|info| {
                let t = info.texture_transform()?;
                (t.tex_coord().unwrap_or(info.tex_coord()) == 0)
                    .then(|| Affine2::from_scale_angle_translation(Vec2::from(t.scale()), t.rotation(), Vec2::from(t.offset())))
            });
            let name = m.name().map_or_else(|| format!("material {}", materials.len()), str::to_string);
            materials.push(Material { name, base_color: pbr.base_color_factor(), texture, ..Material::default() });
            uv_transforms.push(transform);
        }
        Builder {
            mesh: Mesh { materials, ..Mesh::default() },
            uv_transforms,
            default_material: None,
            present: [false; 3],
            missing: Default::default(),
            trailing_indices: 0,
        }
    }

    fn add(&mut self, buffers: &Buffers, mesh_index: usize, prim: &gltf::Primitive, world: Mat4) -> Result<()> {
        let v = self.vertices(buffers, mesh_index, prim, world)?;
        let n = v.positions.len();
        let base = self.mesh.positions.len();
        if base + n > u32::MAX as usize {
            return Err(Error::at_element(
                buffers.path,
                format!("mesh {mesh_index} primitive {}", prim.index()),
                "more than 2^32 vertices in total",
            ));
        }
        let triangles = self.triangles(buffers, mesh_index, prim, n, v.flip)?;
        let has = [v.normals.is_some(), v.uvs.is_some(), v.colors.is_some()];
        let m = &mut self.mesh;
        m.positions.extend(v.positions);
        let first_face = m.triangles.len();
        for t in triangles {
            m.triangles.push(t.map(|v| base as u32 + v));
            m.face_materials.push(v.material);
            for v2 in t.map(|v| v as usize) {
                m.normals.push(v.normals.as_ref().map_or(Vec3::ZERO, |a| a[v2]));
                m.uvs.push(v.uvs.as_ref().map_or(Vec2::ZERO, |a| a[v2]));
                m.colors.push(v.colors.as_ref().map_or([255; 4], |a| a[v2]));
            }
        }
        let faces = first_face..m.triangles.len();
        self.note(faces, has);
        Ok(())
    }

    /// A primitive's vertex attributes under `world`, its material (the default one for none)
    /// and whether `world` mirrors.
    fn vertices(&mut self, buffers: &Buffers, mesh_index: usize, prim: &gltf::Primitive, world: Mat4) -> Result<PrimitiveVertices> {
        let path = buffers.path;
        let element = format!("mesh {mesh_index} primitive {}", prim.index());
        let err = |message: String| Error::at_element(path, &element, message);

        let positions: Vec<Vec3> = match prim.get(&Semantic::Positions) {
            Some(a) => buffers.floats::<3>(&a, "POSITION")?.into_iter().map(|p| world.transform_point3(p.into())),
            None => return Err(err("no POSITION attribute".into())),
        }
        .collect();
        for (i, p) in positions.iter().enumerate() {
            if let Some(problem) = coordinate_problem(p.as_dvec3().to_array()) {
                return Err(err(format!("vertex {i}: {problem}")));
            }
        }
        let n = positions.len();
        let attribute = |semantic: Semantic, name: &str| -> Result<Option<gltf::Accessor>> {
            match prim.get(&semantic) {
                Some(a) if a.count() != n => Err(err(format!("{name} has {} elements but POSITION has {n}", a.count()))),
                a => Ok(a),
            }
        };
        let linear = Mat3::from_mat4(world);
        let normal_matrix = linear.inverse().transpose();
        let normals = match attribute(Semantic::Normals, "NORMAL")? {
            Some(a) => Some(
                buffers
                    .floats::<3>(&a, "NORMAL")?
                    .into_iter()
                    .map(Vec3::from)
                    // A NaN or infinite normal stays so, for the import to replace and report.
                    .map(|v| if v.is_finite() { (normal_matrix * v).normalize_or_zero() } else { v })
                    .collect::<Vec<_>>(),
            ),
            None => None,
        };
        let material = match prim.material().index() {
            Some(i) => i as u32,
            None => *self.default_material.get_or_insert_with(|| {
                self.mesh.materials.push(Material::default());
                self.uv_transforms.push(None);
                (self.mesh.materials.len() - 1) as u32
            }),
        };
        let uv_transform = self.uv_transforms.get(material as usize).copied().flatten().unwrap_or(Affine2::IDENTITY);
        let uvs = match attribute(Semantic::TexCoords(0), "TEXCOORD_0")? {
            Some(a) => Some(
                buffers.floats::<2>(&a, "TEXCOORD_0")?.into_iter().map(|uv| uv_transform.transform_point2(uv.into())).collect::<Vec<_>>(),
            ),
            None => None,
        };
        let colors = match attribute(Semantic::Colors(0), "COLOR_0")? {
            Some(a) => Some(buffers.colors(&a)?),
            None => None,
        };
        Ok(PrimitiveVertices { positions, normals, uvs, colors, material, flip: linear.determinant() < 0.0 })
    }

    /// A primitive's triangles over its `n` vertices (strips and fans expanded, wound the other
    /// way when its transform mirrors), indices checked.
    fn triangles(&mut self, buffers: &Buffers, mesh_index: usize, prim: &gltf::Primitive, n: usize, flip: bool) -> Result<Vec<[u32; 3]>> {
        let indices = match prim.indices() {
            Some(a) => buffers.indices(&a)?,
            None => (0..n as u32).collect(),
        };
        if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
            let element = format!("mesh {mesh_index} primitive {}", prim.index());
            return Err(Error::at_element(buffers.path, element, format!("index {bad} out of range for {n} vertices")));
        }
        if prim.mode() == Mode::Triangles {
            self.trailing_indices += indices.len() % 3;
        }
        let mut triangles = assemble(prim.mode(), &indices);
        if flip {
            for t in &mut triangles {
                t.swap(1, 2);
            }
        }
        Ok(triangles)
    }

    /// Faces `faces` came from a primitive that has (normals, UVs, colors) as `has` says.
    fn note(&mut self, faces: Range<usize>, has: [bool; 3]) {
        for (k, has) in has.into_iter().enumerate() {
            self.present[k] |= has;
            if !has {
                self.missing[k].push(faces.clone());
            }
        }
    }

    /// The warnings of the attributes some primitives lacked, and of trailing indices.
    fn warn(&self, warnings: &mut Vec<String>) {
        for (k, (name, fill)) in ATTRIBUTES.iter().enumerate() {
            if self.present[k] && !self.missing[k].is_empty() {
                let faces: usize = self.missing[k].iter().map(|r| r.len()).sum();
                warnings.push(format!("{faces} faces from primitives without {name} got {fill}"));
            }
        }
        if self.trailing_indices > 0 {
            warnings.push(format!("{} triangle-list indices past the last full triangle ignored", self.trailing_indices));
        }
    }

    /// Drop attributes no primitive had, fill the gaps of the others, and hand over the mesh.
    fn finish(mut self, warnings: &mut Vec<String>) -> Mesh {
        let m = &mut self.mesh;
        let [normals, uvs, colors] = self.present;
        if !normals {
            m.normals.clear();
        }
        if !uvs {
            m.uvs.clear();
        }
        if !colors {
            m.colors.clear();
        }
        if normals {
            for f in self.missing[0].iter().flat_map(|r| r.clone()) {
                let [a, b, c] = m.triangles[f].map(|v| m.positions[v as usize]);
                let normal = (b - a).cross(c - a).normalize_or_zero();
                m.normals[3 * f..3 * f + 3].fill(normal);
            }
        }
        self.warn(warnings);
        self.mesh
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Location;
    use serde_json::{json, Value};
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A fresh directory under the system temp dir, removed on drop.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new() -> Self {
            static NEXT: AtomicUsize = AtomicUsize::new(0);
            let dir =
                std::env::temp_dir().join(format!("strata-gltf-test-{}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)));
            std::fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }

        fn write(&self, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
            let path = self.0.join(name);
            std::fs::write(&path, bytes).unwrap();
            path
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    /// Builds a small glTF document: accessors packed into one buffer.
    #[derive(Default)]
    struct Doc {
        bin: Vec<u8>,
        views: Vec<Value>,
        accessors: Vec<Value>,
    }

    impl Doc {
        fn accessor(&mut self, bytes: &[u8], component_type: u32, count: usize, ty: &str, extra: Value) -> usize {
            while self.bin.len() % 4 != 0 {
                self.bin.push(0);
            }
            self.views.push(json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()}));
            self.bin.extend_from_slice(bytes);
            let view = self.views.len() - 1;
            let mut a = json!({"bufferView": view, "componentType": component_type, "count": count, "type": ty});
            if let (Value::Object(a), Value::Object(extra)) = (&mut a, extra) {
                a.extend(extra);
            }
            self.accessors.push(a);
            self.accessors.len() - 1
        }

        fn positions(&mut self, p: &[[f32; 3]]) -> usize {
            let bytes: Vec<u8> = p.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
            self.accessor(&bytes, 5126, p.len(), "VEC3", json!({"min": [-1e9, -1e9, -1e9], "max": [1e9, 1e9, 1e9]}))
        }

        fn vec3(&mut self, v: &[[f32; 3]]) -> usize {
            let bytes: Vec<u8> = v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
            self.accessor(&bytes, 5126, v.len(), "VEC3", json!({}))
        }

        fn indices(&mut self, i: &[u16]) -> usize {
            let bytes: Vec<u8> = i.iter().flat_map(|x| x.to_le_bytes()).collect();
            self.accessor(&bytes, 5123, i.len(), "SCALAR", json!({}))
        }

        /// The whole document with the buffer as a data URI; `extra` is merged into the root.
        fn json(&self, meshes: Value, nodes: Value, extra: Value) -> Value {
            let uri = format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(&self.bin));
            let mut root = json!({
                "asset": {"version": "2.0"},
                "buffers": [{"uri": uri, "byteLength": self.bin.len()}],
                "bufferViews": self.views,
                "accessors": self.accessors,
                "meshes": meshes,
                "nodes": nodes,
                "scenes": [{"nodes": [0]}],
                "scene": 0,
            });
            if let (Value::Object(r), Value::Object(extra)) = (&mut root, extra) {
                r.extend(extra);
            }
            root
        }
    }

    fn read_json(doc: &Value) -> (Result<Mesh>, Vec<String>) {
        let dir = TempDir::new();
        let path = dir.write("m.gltf", serde_json::to_vec_pretty(doc).unwrap());
        let mut warnings = Vec::new();
        let mesh = read_mesh(&path, &ImportOptions::default(), &mut warnings);
        if let Ok(m) = &mesh {
            m.validate().unwrap();
        }
        (mesh, warnings)
    }

    fn message(r: Result<Mesh>) -> String {
        r.unwrap_err().to_string()
    }

    const FIVE: [[f32; 3]; 5] = [[0., 0., 0.], [1., 0., 0.], [0., 1., 0.], [1., 1., 0.], [0., 2., 0.]];

    /// One node with one mesh of one primitive.
    fn single(doc: &Doc, primitive: Value) -> Value {
        doc.json(json!([{"primitives": [primitive]}]), json!([{"mesh": 0}]), json!({}))
    }

    #[test]
    fn strips_fans_lists_and_unindexed_primitives() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE);
        let i = d.indices(&[0, 1, 2, 3, 4]);
        let list = d.indices(&[0, 1, 2, 2, 1, 3, 4]);
        let cases = [
            (json!({"attributes": {"POSITION": p}, "indices": i, "mode": 5}), vec![[0, 1, 2], [1, 3, 2], [2, 3, 4]], 0),
            (json!({"attributes": {"POSITION": p}, "indices": i, "mode": 6}), vec![[1, 2, 0], [2, 3, 0], [3, 4, 0]], 0),
            (json!({"attributes": {"POSITION": p}, "indices": list}), vec![[0, 1, 2], [2, 1, 3]], 1),
            (json!({"attributes": {"POSITION": p}, "mode": 4}), vec![[0, 1, 2]], 1),
        ];
        for (primitive, triangles, warnings) in cases {
            let (mesh, w) = read_json(&single(&d, primitive));
            let mesh = mesh.unwrap();
            assert_eq!(mesh.triangles, triangles);
            assert_eq!(mesh.positions, FIVE.map(Vec3::from).to_vec());
            assert_eq!(w.len(), warnings, "{w:?}");
            assert_eq!(mesh.materials, vec![Material::default()]);
        }
    }

    #[test]
    fn points_and_lines_are_skipped_with_a_warning() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE);
        let prims = json!([
            {"attributes": {"POSITION": p}, "mode": 0},
            {"attributes": {"POSITION": p}, "mode": 3},
            {"attributes": {"POSITION": p}},
        ]);
        let (mesh, warnings) = read_json(&d.json(json!([{"primitives": prims}]), json!([{"mesh": 0}]), json!({})));
        assert_eq!(mesh.unwrap().face_count(), 1);
        assert_eq!(warnings[0], "2 point or line primitives skipped");
        let only_points = single(&d, json!({"attributes": {"POSITION": p}, "mode": 0}));
        assert!(message(read_json(&only_points).0).contains("no triangles"));
    }

    #[test]
    fn node_transforms_compose_and_mirroring_flips_winding() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        let n = d.vec3(&[[1., 0., 0.], [0., 0., 1.], [0., 0., 1.]]);
        let nodes = json!([{"translation": [10, 0, 0], "children": [1]}, {"scale": [-2, 1, 1], "mesh": 0}]);
        let doc = d.json(json!([{"primitives": [{"attributes": {"POSITION": p, "NORMAL": n}}]}]), nodes, json!({}));
        let mesh = read_json(&doc).0.unwrap();
        assert_eq!(mesh.positions, vec![Vec3::new(10., 0., 0.), Vec3::new(8., 0., 0.), Vec3::new(10., 1., 0.)]);
        assert_eq!(mesh.triangles, vec![[0, 2, 1]]);
        assert_eq!(mesh.normals, vec![-Vec3::X, Vec3::Z, Vec3::Z]);
        let [a, b, c] = mesh.triangles[0].map(|v| mesh.positions[v as usize]);
        assert!((b - a).cross(c - a).z > 0.0, "flipped winding keeps the face facing +z like its normals");
    }

    #[test]
    fn missing_corner_attributes_are_filled() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        let n = d.vec3(&[[1., 0., 0.]; 3]);
        let colors = d.accessor(&[255, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 128], 5121, 3, "VEC4", json!({"normalized": true}));
        let prims = json!([
            {"attributes": {"POSITION": p, "NORMAL": n, "COLOR_0": colors}},
            {"attributes": {"POSITION": p}},
        ]);
        let (mesh, warnings) = read_json(&d.json(json!([{"primitives": prims}]), json!([{"mesh": 0}]), json!({})));
        let mesh = mesh.unwrap();
        assert_eq!(mesh.normals, [[Vec3::X; 3], [Vec3::Z; 3]].concat());
        assert_eq!(mesh.colors, vec![[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 128], [255; 4], [255; 4], [255; 4]]);
        assert!(mesh.uvs.is_empty());
        assert_eq!(warnings.len(), 2, "{warnings:?}");
    }

    #[test]
    fn quantized_attributes_are_converted_by_component_type() {
        let mut d = Doc::default();
        let pos: Vec<u8> = [[0i16, 0, 0], [32767, 0, 0], [0, -32767, 0]].iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let p = d.accessor(&pos, 5122, 3, "VEC3", json!({"normalized": true, "min": [0, -32767, 0], "max": [32767, 0, 0]}));
        let plain: Vec<u8> = [[0u16, 0, 0], [300, 0, 0], [0, 7, 0]].iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let q = d.accessor(&plain, 5123, 3, "VEC3", json!({"min": [0, 0, 0], "max": [300, 7, 0]}));
        // i8 normals padded to a 4-byte stride; -128 clamps to -1.
        let n = d.accessor(&[0, 0, 127, 0, 127, 0, 0, 0, 0, 0, 128, 0], 5120, 3, "VEC3", json!({"normalized": true}));
        let view = d.accessors[n]["bufferView"].as_u64().unwrap() as usize;
        d.views[view]["byteStride"] = json!(4);
        let uv: Vec<u8> = [0u16, 65535, 65535, 0, 0, 0].iter().flat_map(|x| x.to_le_bytes()).collect();
        let t = d.accessor(&uv, 5123, 3, "VEC2", json!({"normalized": true}));
        let prims = json!([
            {"attributes": {"POSITION": p, "NORMAL": n, "TEXCOORD_0": t}},
            {"attributes": {"POSITION": q, "NORMAL": n, "TEXCOORD_0": t}},
        ]);
        let extra = json!({"extensionsUsed": ["KHR_mesh_quantization"], "extensionsRequired": ["KHR_mesh_quantization"]});
        let mesh = read_json(&d.json(json!([{"primitives": prims}]), json!([{"mesh": 0}]), extra)).0.unwrap();
        assert_eq!(&mesh.positions[..3], &[Vec3::ZERO, Vec3::X, -Vec3::Y]);
        assert_eq!(&mesh.positions[3..], &[Vec3::ZERO, Vec3::new(300., 0., 0.), Vec3::new(0., 7., 0.)]);
        assert_eq!(&mesh.normals[..3], &[Vec3::Z, Vec3::X, Vec3::new(0., 0., -1.)]);
        assert_eq!(&mesh.uvs[..3], &[Vec2::Y, Vec2::X, Vec2::ZERO]);
    }

    /// A document whose POSITION accessor holds `FIVE[..3]` at `offset + i * stride` in a view of
    /// that stride, the bytes between them 0xff.
    fn strided_positions(stride: usize, offset: usize) -> Value {
        let mut d = Doc::default();
        let mut bytes = vec![0xff; offset + 2 * stride.max(12) + 12];
        for (i, p) in FIVE[..3].iter().enumerate() {
            let at = offset + i * stride.max(12);
            bytes[at..at + 12].copy_from_slice(&p.map(f32::to_le_bytes).concat());
        }
        let p = d.accessor(&bytes, 5126, 3, "VEC3", json!({"byteOffset": offset}));
        d.views[0]["byteStride"] = json!(stride);
        single(&d, json!({"attributes": {"POSITION": p}}))
    }

    #[test]
    fn strides_must_keep_elements_apart_but_need_not_be_aligned() {
        for (stride, offset) in [(12, 0), (16, 4), (14, 2), (256, 0), (0, 0), (12, 24)] {
            let mesh = read_json(&strided_positions(stride, offset)).0.unwrap_or_else(|e| panic!("{stride}: {e}"));
            assert_eq!(mesh.positions, FIVE[..3].iter().map(|&p| Vec3::from(p)).collect::<Vec<_>>(), "{offset}");
        }
        let refused = [(4, 0, "byteStride 4, less"), (8, 0, "byteStride 8, less"), (16, 8, "byteOffset 8")];
        for (stride, offset, what) in refused {
            let e = message(read_json(&strided_positions(stride, offset)).0);
            assert!(e.contains("accessor 0") && e.contains("buffer view 0") && e.contains(what), "{e}");
        }
        // One-byte UVs two bytes apart read correctly, though glTF wants strides of 4 or more.
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        let uv = d.accessor(&[0, 255, 255, 0, 0, 0], 5121, 3, "VEC2", json!({"normalized": true}));
        d.views[1]["byteStride"] = json!(2);
        let mesh = read_json(&single(&d, json!({"attributes": {"POSITION": p, "TEXCOORD_0": uv}}))).0.unwrap();
        assert_eq!(&mesh.uvs[..3], &[Vec2::Y, Vec2::X, Vec2::ZERO]);
    }

    #[test]
    fn sparse_accessors_replace_base_values() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        let sparse_indices = d.indices(&[2]);
        let sparse_values = d.vec3(&[[0., 5., 0.]]);
        let (iv, vv) = (d.accessors[sparse_indices]["bufferView"].clone(), d.accessors[sparse_values]["bufferView"].clone());
        d.accessors[p]["sparse"] = json!({"count": 1, "indices": {"bufferView": iv, "componentType": 5123}, "values": {"bufferView": vv}});
        let mesh = read_json(&single(&d, json!({"attributes": {"POSITION": p}}))).0.unwrap();
        assert_eq!(mesh.positions[2], Vec3::new(0., 5., 0.));
        d.accessors[p]["sparse"]["count"] = json!(2);
        assert!(message(read_json(&single(&d, json!({"attributes": {"POSITION": p}}))).0).contains("sparse indices overrun"));
    }

    #[test]
    fn materials_and_texture_transforms() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        let uv = d.accessor(&[0f32, 0., 1., 0., 0., 1.].map(f32::to_le_bytes).concat(), 5126, 3, "VEC2", json!({}));
        let image_view = d.indices(&[0, 0]);
        let prims = json!([
            {"attributes": {"POSITION": p, "TEXCOORD_0": uv}, "material": 0},
            {"attributes": {"POSITION": p}, "material": 1},
            {"attributes": {"POSITION": p}},
        ]);
        let extra = json!({
            "extensionsUsed": ["KHR_texture_transform"],
            "materials": [
                {"name": "logo", "pbrMetallicRoughness": {
                    "baseColorFactor": [1, 0.5, 0.25, 1],
                    "baseColorTexture": {
                        "index": 0,
                        "extensions": {"KHR_texture_transform": {"offset": [0.5, 0], "scale": [2, 2]}},
                    },
                }},
                {"pbrMetallicRoughness": {"baseColorTexture": {"index": 1}}},
            ],
            "textures": [{"source": 0}, {"source": 1}],
            "images": [
                {"uri": "Logo%20Image.png"},
                {"bufferView": d.accessors[image_view]["bufferView"], "mimeType": "image/png"},
            ],
        });
        let mesh = read_json(&d.json(json!([{"primitives": prims}]), json!([{"mesh": 0}]), extra)).0.unwrap();
        assert_eq!(mesh.face_materials, vec![0, 1, 2]);
        assert_eq!(mesh.materials[0].name, "logo");
        assert_eq!(mesh.materials[0].base_color, [1.0, 0.5, 0.25, 1.0]);
        assert_eq!(mesh.materials[0].texture.as_deref(), Some("Logo%20Image.png"));
        assert_eq!(mesh.materials[1].name, "material 1");
        assert_eq!(mesh.materials[1].texture.as_deref(), Some("embedded image 1"));
        assert_eq!(mesh.materials[2], Material::default());
        assert_eq!(&mesh.uvs[..3], &[Vec2::new(0.5, 0.), Vec2::new(2.5, 0.), Vec2::new(0.5, 2.)]);
        assert_eq!(&mesh.uvs[3..], &[Vec2::ZERO; 6]);
    }

    #[test]
    fn external_buffers_resolve_percent_encoded_names() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        let mut doc = single(&d, json!({"attributes": {"POSITION": p}}));
        doc["buffers"][0]["uri"] = json!("my%20buffer.bin");
        let dir = TempDir::new();
        let gltf = dir.write("m.gltf", serde_json::to_vec(&doc).unwrap());
        let missing = message(read_mesh(&gltf, &ImportOptions::default(), &mut Vec::new()));
        assert!(missing.contains("buffer 0") && missing.contains("my buffer.bin"), "{missing}");
        dir.write("my buffer.bin", &d.bin[..d.bin.len() - 1]);
        let short = message(read_mesh(&gltf, &ImportOptions::default(), &mut Vec::new()));
        assert!(short.contains("fewer than its byteLength"), "{short}");
        dir.write("my buffer.bin", &d.bin);
        assert_eq!(read_mesh(&gltf, &ImportOptions::default(), &mut Vec::new()).unwrap().face_count(), 1);
    }

    #[test]
    fn file_names_climbing_out_of_the_folder_are_recognised_by_their_text() {
        for inside in ["a.bin", "./a.bin", "sub/a.bin", "sub/../a.bin", "sub/./../sub/a.bin", "..a.bin", "a..b"] {
            assert!(crate::import::stays_inside(Path::new(inside)), "{inside}");
        }
        for outside in ["../a.bin", "sub/../../a.bin", "./../a.bin", "/etc/hostname", "sub/../../sub/a.bin"] {
            assert!(!crate::import::stays_inside(Path::new(outside)), "{outside}");
        }
    }

    #[test]
    fn buffers_outside_the_folder_need_permission() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        let mut doc = single(&d, json!({"attributes": {"POSITION": p}}));
        doc["buffers"][0]["uri"] = json!("../m.bin");
        let dir = TempDir::new();
        dir.write("m.bin", &d.bin);
        std::fs::create_dir_all(dir.0.join("model")).unwrap();
        let gltf = dir.write("model/m.gltf", serde_json::to_vec(&doc).unwrap());
        let e = message(read_mesh(&gltf, &ImportOptions::default(), &mut Vec::new()));
        assert!(e.contains("buffer 0") && e.contains("'../m.bin'") && e.contains("outside"), "{e}");
        let allowed = ImportOptions { allow_outside_files: true, ..ImportOptions::default() };
        assert_eq!(read_mesh(&gltf, &allowed, &mut Vec::new()).unwrap().face_count(), 1);
    }

    #[test]
    fn required_extensions_strata_cannot_decode_are_named() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        for ext in ["KHR_draco_mesh_compression", "EXT_meshopt_compression", "EXT_something_new"] {
            let extra = json!({"extensionsUsed": [ext], "extensionsRequired": [ext]});
            let doc = d.json(json!([{"primitives": [{"attributes": {"POSITION": p}}]}]), json!([{"mesh": 0}]), extra);
            let e = message(read_json(&doc).0);
            assert!(e.contains(ext), "{e}");
        }
        let extra = json!({"extensionsUsed": ["EXT_mesh_gpu_instancing"]});
        let doc = d.json(json!([{"primitives": [{"attributes": {"POSITION": p}}]}]), json!([{"mesh": 0}]), extra);
        let (mesh, warnings) = read_json(&doc);
        assert_eq!(mesh.unwrap().face_count(), 1);
        assert!(warnings[0].contains("EXT_mesh_gpu_instancing"));
    }

    #[test]
    fn bad_references_are_errors_naming_the_element() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE[..3]);
        let i = d.indices(&[0, 1, 3]);
        let e = message(read_json(&single(&d, json!({"attributes": {"POSITION": p}, "indices": i}))).0);
        assert!(e.contains("mesh 0 primitive 0") && e.contains("index 3 out of range"), "{e}");

        let e = message(read_json(&single(&d, json!({"attributes": {"POSITION": 7}}))).0);
        assert!(e.contains("mesh 0 primitive 0") && e.contains("accessor 7"), "{e}");

        d.accessors[p]["count"] = json!(4);
        let e = message(read_json(&single(&d, json!({"attributes": {"POSITION": p}}))).0);
        assert!(e.contains("accessor 0") && e.contains("overrun"), "{e}");

        d.accessors[p]["count"] = json!(3);
        d.views[0]["byteLength"] = json!(1000);
        let e = message(read_json(&single(&d, json!({"attributes": {"POSITION": p}}))).0);
        assert!(e.contains("buffer view 0") && e.contains("outside buffer 0"), "{e}");

        d.views[0]["byteLength"] = json!(36);
        let cyclic = d.json(
            json!([{"primitives": [{"attributes": {"POSITION": p}}]}]),
            json!([{"children": [1]}, {"children": [0], "mesh": 0}]),
            json!({}),
        );
        let e = message(read_json(&cyclic).0);
        assert!(e.contains("node 0") && e.contains("appears twice"), "{e}");
    }

    #[test]
    fn bad_json_reports_line_and_column() {
        let dir = TempDir::new();
        let path = dir.write("m.gltf", "{\n  \"asset\": {\"version\": \"2.0\"},\n  \"meshes\": [,]\n}\n");
        let e = read_mesh(&path, &ImportOptions::default(), &mut Vec::new()).unwrap_err();
        assert_eq!(e.location(), Some(&Location::Line(3)));
        assert!(e.to_string().contains("column"), "{e}");
    }

    /// A GLB of `doc` with its buffer moved into the BIN chunk.
    fn glb(d: &Doc, mut doc: Value) -> Vec<u8> {
        doc["buffers"][0] = json!({"byteLength": d.bin.len()});
        let mut json = serde_json::to_vec(&doc).unwrap();
        while json.len() % 4 != 0 {
            json.push(b' ');
        }
        let mut bin = d.bin.clone();
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&json);
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
        out
    }

    #[test]
    fn glb_reads_and_every_truncation_is_an_error() {
        let mut d = Doc::default();
        let p = d.positions(&FIVE);
        let i = d.indices(&[0, 1, 2, 3, 4]);
        let bytes = glb(&d, single(&d, json!({"attributes": {"POSITION": p}, "indices": i, "mode": 5})));
        let dir = TempDir::new();
        let path = dir.write("m.glb", &bytes);
        assert_eq!(read_mesh(&path, &ImportOptions::default(), &mut Vec::new()).unwrap().face_count(), 3);
        for len in 0..bytes.len() {
            dir.write("m.glb", &bytes[..len]);
            assert!(read_mesh(&path, &ImportOptions::default(), &mut Vec::new()).is_err(), "prefix of {len} bytes");
        }
        let mut small_header = bytes.clone();
        small_header[8..12].copy_from_slice(&4u32.to_le_bytes());
        dir.write("m.glb", &small_header);
        assert!(message(read_mesh(&path, &ImportOptions::default(), &mut Vec::new())).contains("JSON"));
    }

    /// A document using most of what the reader handles: strips, sparse positions, normals,
    /// normalized colors, UVs, a material and a node hierarchy.
    fn rich_document() -> Value {
        let mut d = Doc::default();
        let p = d.positions(&FIVE);
        let n = d.vec3(&[[0., 0., 1.]; 5]);
        let c = d.accessor(&[255; 20], 5121, 5, "VEC4", json!({"normalized": true}));
        let t = d.accessor(&[0u16; 10].map(u16::to_le_bytes).concat(), 5123, 5, "VEC2", json!({"normalized": true}));
        let i = d.indices(&[0, 1, 2, 3, 4]);
        let si = d.indices(&[1]);
        let sv = d.vec3(&[[3., 0., 0.]]);
        let (iv, vv) = (d.accessors[si]["bufferView"].clone(), d.accessors[sv]["bufferView"].clone());
        d.accessors[p]["sparse"] = json!({"count": 1, "indices": {"bufferView": iv, "componentType": 5123}, "values": {"bufferView": vv}});
        let attributes = json!({"POSITION": p, "NORMAL": n, "COLOR_0": c, "TEXCOORD_0": t});
        let prim = json!({"attributes": attributes, "indices": i, "mode": 5, "material": 0});
        let nodes = json!([{"children": [1], "scale": [1, 1, -1]}, {"mesh": 0}]);
        d.json(json!([{"primitives": [prim]}]), nodes, json!({"materials": [{"name": "m"}]}))
    }

    /// JSON pointers to every number in `v`.
    fn number_pointers(v: &Value, at: String, out: &mut Vec<String>) {
        match v {
            Value::Number(_) => out.push(at),
            Value::Array(a) => a.iter().enumerate().for_each(|(i, x)| number_pointers(x, format!("{at}/{i}"), out)),
            Value::Object(o) => o.iter().for_each(|(k, x)| number_pointers(x, format!("{at}/{k}"), out)),
            _ => {}
        }
    }

    #[test]
    fn the_rich_document_imports() {
        let mesh = read_json(&rich_document()).0.unwrap();
        assert_eq!(mesh.face_count(), 3);
        assert_eq!(mesh.positions[1], Vec3::new(3., 0., 0.));
        assert!(mesh.normals.iter().all(|&n| n == -Vec3::Z));
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(400))]

        /// Any numbers written over any numbers of a valid document never panic the reader;
        /// what imports is a valid mesh.
        #[test]
        fn corrupted_numbers_never_panic(
            edits in proptest::collection::vec(
                (0..1000usize, proptest::sample::select(vec![
                    json!(0), json!(1), json!(2), json!(3), json!(4), json!(5), json!(7), json!(12), json!(64),
                    json!(255), json!(5121), json!(5123), json!(5125), json!(5126), json!(65535),
                    json!(4294967295u64), json!(1u64 << 40), json!(-1), json!(1.5),
                ])),
                1..4,
            )
        ) {
            let mut doc = rich_document();
            let mut pointers = Vec::new();
            number_pointers(&doc, String::new(), &mut pointers);
            for (k, value) in edits {
                if let Some(slot) = doc.pointer_mut(&pointers[k % pointers.len()]) {
                    *slot = value;
                }
            }
            if let (Ok(mesh), _) = read_json(&doc) {
                proptest::prop_assert!(mesh.validate().is_ok());
            }
        }
    }

    /// What [`stream`] hands on of `path`, as a mesh: positions, triangles, corner normals, UVs
    /// and colors, each face's material, the materials and images.
    fn streamed(path: &Path) -> Mesh {
        let mut m = Mesh::default();
        let looks = stream(
            path,
            &ImportOptions::default(),
            &mut |v, f| {
                m.positions = v.positions.to_vec();
                m.triangles.extend_from_slice(f.triangles);
                m.normals.extend(f.normals.iter().flatten());
                m.uvs.extend(f.uvs.iter().flatten());
                if !v.colors.is_empty() {
                    m.colors.extend(f.triangles.iter().flatten().map(|&i| v.colors[i as usize]));
                }
                m.face_materials.extend_from_slice(f.materials);
                Ok(())
            },
            &mut Vec::new(),
        )
        .unwrap();
        (m.materials, m.images) = (looks.materials, looks.images);
        m
    }

    /// The stream gives what the whole-file reader reads: the fixtures, and the shared glTF
    /// models when present (node transforms, mirrored nodes, primitives without some attributes,
    /// external buffers and images).
    #[test]
    fn streams_what_the_whole_file_reader_reads() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut paths = vec![root.join("fixtures/textured_globe.glb"), root.join("fixtures/two_materials.glb")];
        let shared = root.join("../shared/meshes/gltf");
        let mut stack = vec![shared];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else if p.extension().is_some_and(|x| x == "gltf" || x == "glb") {
                    paths.push(p);
                }
            }
        }
        let mut compared = 0;
        for path in &paths {
            let name = path.display();
            let Ok(whole) = read(path, &ImportOptions::default(), &mut Vec::new()).map(|r| r.mesh) else {
                let e = stream(path, &ImportOptions::default(), &mut |_, _| Ok(()), &mut Vec::new());
                assert!(e.is_err(), "{name}: the whole-file reader refuses it, the stream does not");
                continue;
            };
            let m = streamed(path);
            let declared = streaming_declared(path).unwrap();
            assert!(declared.triangles >= m.triangles.len() as u64, "{name}: declared {} < {}", declared.triangles, m.triangles.len());
            assert_eq!(m.positions, whole.positions, "{name}");
            assert_eq!(m.triangles, whole.triangles, "{name}");
            assert_eq!(m.normals, whole.normals, "{name}");
            assert_eq!(m.uvs, whole.uvs, "{name}");
            assert_eq!(m.colors, whole.colors, "{name}");
            assert_eq!(m.face_materials, whole.face_materials, "{name}");
            assert_eq!(m.materials, whole.materials, "{name}");
            assert_eq!(m.images.len(), whole.images.len(), "{name}");
            assert!(m.images.iter().zip(&whole.images).all(|(a, b)| a.name == b.name && a.bytes == b.bytes), "{name}");
            compared += 1;
        }
        println!("{compared} of {} files compared", paths.len());
        assert!(compared >= 2, "{compared} files compared");
    }
}
