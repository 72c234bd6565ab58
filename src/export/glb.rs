//! Write binary glTF 2.0 (GLB): one mesh with one triangle primitive per used material.
//!
//! Each primitive has its own vertices, one per distinct (position, normal, UV, color) among its
//! corners, and u32 indices. Attributes: POSITION (with the min/max the spec requires) and, when the
//! mesh has them, NORMAL, TEXCOORD_0 and COLOR_0 (normalized unsigned bytes, RGBA). Materials keep
//! name and base color, and their maps (base color, normal, metallic-roughness, occlusion,
//! emissive) when the mesh has UVs: the images they sample are embedded in the binary chunk with
//! their media type, so the file stands alone; each map's wrap modes become a sampler.

use super::{check, invalid_mesh, split_vertices, Split};
use crate::atomic::write_file;
use crate::error::Result;
use crate::format::{MapKind, Wrap, MAP_KINDS};
use crate::mesh::Mesh;
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::{self, Write};
use std::path::Path;

/// Write `mesh` to `path` as GLB.
pub fn write(path: &Path, mesh: &Mesh) -> Result<()> {
    write_file(path, |w| write_glb(w, mesh))
}

/// Write the GLB bytes of `mesh`. A mesh without faces is refused: glTF has no empty primitive.
pub fn write_glb<W: Write>(mut out: W, mesh: &Mesh) -> io::Result<()> {
    check(mesh)?;
    if mesh.triangles.is_empty() {
        return Err(invalid_mesh("a GLB needs at least one face".into()));
    }
    let mut faces_of: Vec<Vec<usize>> = vec![Vec::new(); mesh.materials.len()];
    for (f, &m) in mesh.face_materials.iter().enumerate() {
        faces_of[m as usize].push(f);
    }
    let mut bin = Bin::default();
    let primitives = faces_of
        .iter()
        .enumerate()
        .filter(|(_, faces)| !faces.is_empty())
        .map(|(m, faces)| primitive(&mut bin, mesh, m as u32, &split_vertices(mesh, faces.iter().copied())))
        .collect();

    let t = textures(&mut bin, mesh);
    let materials = mesh
        .materials
        .iter()
        .zip(&t.maps)
        .map(|(m, maps)| {
            let r = |k: MapKind| maps[k as usize].map(|index| TextureRef { index });
            let metal_rough = r(MapKind::MetallicRoughness);
            MaterialJson {
                name: m.name.clone(),
                pbr_metallic_roughness: Pbr {
                    base_color_factor: m.base_color.map(|c| c.clamp(0.0, 1.0)),
                    base_color_texture: r(MapKind::BaseColor),
                    // With a metallic-roughness map its texels decide; without, a dull dielectric.
                    metallic_factor: if metal_rough.is_some() { 1.0 } else { 0.0 },
                    roughness_factor: 1.0,
                    metallic_roughness_texture: metal_rough,
                },
                normal_texture: r(MapKind::Normal),
                occlusion_texture: r(MapKind::Occlusion),
                emissive_factor: r(MapKind::Emissive).map(|_| [1.0; 3]),
                emissive_texture: r(MapKind::Emissive),
                alpha_mode: (m.base_color[3] < 1.0).then_some("BLEND"),
            }
        })
        .collect();
    while bin.data.len() % 4 != 0 {
        bin.data.push(0);
    }
    let root = Root {
        asset: Asset { version: "2.0", generator: "strata" },
        scene: 0,
        scenes: vec![Scene { nodes: vec![0] }],
        nodes: vec![Node { mesh: 0 }],
        meshes: vec![MeshJson { primitives }],
        materials,
        textures: t.textures,
        images: t.images,
        samplers: t.samplers,
        accessors: bin.accessors,
        buffer_views: bin.views,
        buffers: vec![Buffer { byte_length: bin.data.len() }],
    };
    let mut json = serde_json::to_vec(&root).map_err(io::Error::other)?;
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.data.len();
    let total = u32::try_from(total).map_err(|_| invalid_mesh(format!("{total} bytes exceed GLB's 4 GiB limit")))?;
    out.write_all(b"glTF")?;
    out.write_all(&2u32.to_le_bytes())?;
    out.write_all(&total.to_le_bytes())?;
    out.write_all(&(json.len() as u32).to_le_bytes())?;
    out.write_all(b"JSON")?;
    out.write_all(&json)?;
    out.write_all(&(bin.data.len() as u32).to_le_bytes())?;
    out.write_all(b"BIN\0")?;
    out.write_all(&bin.data)?;
    out.flush()
}

const FLOAT: u32 = 5126;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// Append a primitive's vertex attributes and indices to `bin`.
fn primitive(bin: &mut Bin, mesh: &Mesh, material: u32, split: &Split) -> Primitive {
    let corners = || split.vertex_corner.iter().map(|&c| c as usize);
    let positions: Vec<[f32; 3]> = corners().map(|c| mesh.positions[mesh.triangles[c / 3][c % 3] as usize].to_array()).collect();
    let (mut min, mut max) = (positions[0], positions[0]);
    for p in &positions {
        for i in 0..3 {
            min[i] = min[i].min(p[i]);
            max[i] = max[i].max(p[i]);
        }
    }
    let mut attributes = BTreeMap::new();
    let floats = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let position_bytes = floats(positions.as_flattened());
    attributes.insert("POSITION", bin.push(&position_bytes, ARRAY_BUFFER, FLOAT, positions.len(), "VEC3", Some((min, max))));
    if !mesh.normals.is_empty() {
        let normals: Vec<f32> = corners().flat_map(|c| mesh.normals[c].to_array()).collect();
        attributes.insert("NORMAL", bin.push(&floats(&normals), ARRAY_BUFFER, FLOAT, positions.len(), "VEC3", None));
    }
    if !mesh.uvs.is_empty() {
        let uvs: Vec<f32> = corners().flat_map(|c| mesh.uvs[c].to_array()).collect();
        attributes.insert("TEXCOORD_0", bin.push(&floats(&uvs), ARRAY_BUFFER, FLOAT, positions.len(), "VEC2", None));
    }
    if !mesh.colors.is_empty() {
        let colors: Vec<u8> = corners().flat_map(|c| mesh.colors[c]).collect();
        let accessor = bin.push(&colors, ARRAY_BUFFER, UNSIGNED_BYTE, positions.len(), "VEC4", None);
        bin.accessors[accessor as usize].normalized = true;
        attributes.insert("COLOR_0", accessor);
    }
    let index_bytes: Vec<u8> = split.corner_vertex.iter().flat_map(|v| v.to_le_bytes()).collect();
    let indices = bin.push(&index_bytes, ELEMENT_ARRAY_BUFFER, UNSIGNED_INT, split.corner_vertex.len(), "SCALAR", None);
    Primitive { attributes, indices, material, mode: 4 }
}

/// The texture, image and sampler arrays of the materials' maps, when the mesh has UVs, and each
/// material's texture index per map kind. Each image used is embedded once (a buffer view with its
/// media type); each distinct (image, wrap modes) is one texture.
struct Textures {
    textures: Vec<Texture>,
    images: Vec<Image>,
    samplers: Vec<Sampler>,
    maps: Vec<[Option<u32>; MAP_KINDS]>,
}

fn textures(bin: &mut Bin, mesh: &Mesh) -> Textures {
    let mut t = Textures { textures: Vec::new(), images: Vec::new(), samplers: Vec::new(), maps: Vec::new() };
    let mut image_of: BTreeMap<u32, u32> = BTreeMap::new();
    let mut sampler_of: BTreeMap<[Wrap; 2], u32> = BTreeMap::new();
    let mut texture_of: BTreeMap<(u32, u32), u32> = BTreeMap::new();
    let gl = |w: Wrap| match w {
        Wrap::Repeat => 10497,
        Wrap::Clamp => 33071,
        Wrap::Mirror => 33648,
    };
    for m in &mesh.materials {
        let slots = m.maps.map(|slot| {
            let slot = slot.filter(|_| !mesh.uvs.is_empty())?;
            let source = mesh.images.get(slot.image as usize)?;
            let image = *image_of.entry(slot.image).or_insert_with(|| {
                let view = bin.view(&source.bytes);
                t.images.push(Image { name: source.name.clone(), buffer_view: view, mime_type: source.codec.mime() });
                t.images.len() as u32 - 1
            });
            let sampler = *sampler_of.entry(slot.wrap).or_insert_with(|| {
                t.samplers.push(Sampler { mag_filter: 9729, min_filter: 9987, wrap_s: gl(slot.wrap[0]), wrap_t: gl(slot.wrap[1]) });
                t.samplers.len() as u32 - 1
            });
            Some(*texture_of.entry((image, sampler)).or_insert_with(|| {
                t.textures.push(Texture { sampler, source: image });
                t.textures.len() as u32 - 1
            }))
        });
        t.maps.push(slots);
    }
    t
}

/// The binary chunk under construction, with one buffer view and one accessor per array.
#[derive(Default)]
struct Bin {
    data: Vec<u8>,
    views: Vec<BufferView>,
    accessors: Vec<Accessor>,
}

impl Bin {
    /// Append `bytes` as a buffer view without target (an image's); returns the view's index.
    fn view(&mut self, bytes: &[u8]) -> u32 {
        while self.data.len() % 4 != 0 {
            self.data.push(0);
        }
        self.views.push(BufferView { buffer: 0, byte_offset: self.data.len(), byte_length: bytes.len(), target: None });
        self.data.extend_from_slice(bytes);
        (self.views.len() - 1) as u32
    }

    /// Append `bytes` as a new buffer view and accessor; returns the accessor index.
    fn push(
        &mut self,
        bytes: &[u8],
        target: u32,
        component_type: u32,
        count: usize,
        kind: &'static str,
        bounds: Option<([f32; 3], [f32; 3])>,
    ) -> u32 {
        while self.data.len() % 4 != 0 {
            self.data.push(0);
        }
        self.views.push(BufferView { buffer: 0, byte_offset: self.data.len(), byte_length: bytes.len(), target: Some(target) });
        self.data.extend_from_slice(bytes);
        self.accessors.push(Accessor {
            buffer_view: (self.views.len() - 1) as u32,
            component_type,
            normalized: false,
            count,
            kind,
            min: bounds.map(|b| b.0),
            max: bounds.map(|b| b.1),
        });
        (self.accessors.len() - 1) as u32
    }
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Root {
    asset: Asset,
    scene: u32,
    scenes: Vec<Scene>,
    nodes: Vec<Node>,
    meshes: Vec<MeshJson>,
    materials: Vec<MaterialJson>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    textures: Vec<Texture>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    images: Vec<Image>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    samplers: Vec<Sampler>,
    accessors: Vec<Accessor>,
    buffer_views: Vec<BufferView>,
    buffers: Vec<Buffer>,
}

#[derive(Serialize)]
struct Asset {
    version: &'static str,
    generator: &'static str,
}

#[derive(Serialize)]
struct Scene {
    nodes: Vec<u32>,
}

#[derive(Serialize)]
struct Node {
    mesh: u32,
}

#[derive(Serialize)]
struct MeshJson {
    primitives: Vec<Primitive>,
}

#[derive(Serialize)]
struct Primitive {
    attributes: BTreeMap<&'static str, u32>,
    indices: u32,
    material: u32,
    mode: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct MaterialJson {
    name: String,
    pbr_metallic_roughness: Pbr,
    #[serde(skip_serializing_if = "Option::is_none")]
    normal_texture: Option<TextureRef>,
    #[serde(skip_serializing_if = "Option::is_none")]
    occlusion_texture: Option<TextureRef>,
    #[serde(skip_serializing_if = "Option::is_none")]
    emissive_texture: Option<TextureRef>,
    #[serde(skip_serializing_if = "Option::is_none")]
    emissive_factor: Option<[f32; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    alpha_mode: Option<&'static str>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Pbr {
    base_color_factor: [f32; 4],
    #[serde(skip_serializing_if = "Option::is_none")]
    base_color_texture: Option<TextureRef>,
    metallic_factor: f32,
    roughness_factor: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    metallic_roughness_texture: Option<TextureRef>,
}

#[derive(Serialize)]
struct TextureRef {
    index: u32,
}

#[derive(Serialize)]
struct Texture {
    sampler: u32,
    source: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Image {
    name: String,
    buffer_view: u32,
    mime_type: &'static str,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Sampler {
    mag_filter: u32,
    min_filter: u32,
    wrap_s: u32,
    wrap_t: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Accessor {
    buffer_view: u32,
    component_type: u32,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    normalized: bool,
    count: usize,
    #[serde(rename = "type")]
    kind: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    min: Option<[f32; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    max: Option<[f32; 3]>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct BufferView {
    buffer: u32,
    byte_offset: usize,
    byte_length: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    target: Option<u32>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Buffer {
    byte_length: usize,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures;
    use serde_json::Value;

    fn u32_at(b: &[u8], at: usize) -> u32 {
        u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
    }

    /// Check the GLB framing and return the parsed JSON and the binary chunk.
    fn parse(glb: &[u8]) -> (Value, &[u8]) {
        assert_eq!(&glb[..4], b"glTF");
        assert_eq!(u32_at(glb, 4), 2);
        assert_eq!(u32_at(glb, 8) as usize, glb.len());
        let json_len = u32_at(glb, 12) as usize;
        assert_eq!(&glb[16..20], b"JSON");
        assert_eq!(json_len % 4, 0);
        let json = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
        let b = 20 + json_len;
        let bin_len = u32_at(glb, b) as usize;
        assert_eq!(&glb[b + 4..b + 8], b"BIN\0");
        assert_eq!(bin_len % 4, 0);
        assert_eq!(b + 8 + bin_len, glb.len());
        (json, &glb[b + 8..])
    }

    fn f32s(v: &Value) -> Vec<f32> {
        v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect()
    }

    fn glb(mesh: &Mesh) -> Vec<u8> {
        let mut out = Vec::new();
        write_glb(&mut out, mesh).unwrap();
        out
    }

    /// Accessor `a` checked against its buffer view; returns (count, view bytes).
    fn accessor<'a>(json: &Value, bin: &'a [u8], a: &Value, elem_size: usize) -> (usize, &'a [u8]) {
        let acc = &json["accessors"][a.as_u64().unwrap() as usize];
        let view = &json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let (off, len) = (view["byteOffset"].as_u64().unwrap() as usize, view["byteLength"].as_u64().unwrap() as usize);
        let count = acc["count"].as_u64().unwrap() as usize;
        assert_eq!(off % 4, 0);
        assert_eq!(len, count * elem_size);
        assert!(off + len <= json["buffers"][0]["byteLength"].as_u64().unwrap() as usize);
        (count, &bin[off..off + len])
    }

    #[test]
    fn two_materials_make_two_primitives() {
        let m = fixtures::two_material_box();
        let bytes = glb(&m);
        let (json, bin) = parse(&bytes);
        assert_eq!(json["buffers"][0]["byteLength"].as_u64().unwrap() as usize, bin.len());
        let prims = json["meshes"][0]["primitives"].as_array().unwrap();
        assert_eq!(prims.len(), 2);
        let mut indices_total = 0;
        let (mut lo, mut hi) = (Vec::new(), Vec::new());
        for (i, p) in prims.iter().enumerate() {
            assert_eq!(p["material"], i);
            assert_eq!(p["mode"], 4);
            let (nv, _) = accessor(&json, bin, &p["attributes"]["POSITION"], 12);
            assert_eq!(accessor(&json, bin, &p["attributes"]["NORMAL"], 12).0, nv);
            assert_eq!(accessor(&json, bin, &p["attributes"]["TEXCOORD_0"], 8).0, nv);
            let (ni, idx) = accessor(&json, bin, &p["indices"], 4);
            assert_eq!(ni, 3 * m.face_materials.iter().filter(|&&fm| fm == i as u32).count());
            assert!((0..ni).all(|k| (u32_at(idx, 4 * k) as usize) < nv));
            indices_total += ni;
            let pos = &json["accessors"][p["attributes"]["POSITION"].as_u64().unwrap() as usize];
            lo.push(pos["min"].clone());
            hi.push(pos["max"].clone());
        }
        assert_eq!(indices_total, 3 * m.face_count());
        // The sides reach every corner of the box; the top lies at its top.
        let (blo, bhi) = m.bounds().unwrap();
        assert_eq!(f32s(&lo[0]), blo.to_array());
        assert_eq!(f32s(&hi[0]), bhi.to_array());
        assert_eq!(f32s(&lo[1])[2], bhi.z);
        let mats = json["materials"].as_array().unwrap();
        assert_eq!(mats.iter().map(|x| x["name"].as_str().unwrap()).collect::<Vec<_>>(), ["sides", "top"]);
        assert_eq!(f32s(&mats[1]["pbrMetallicRoughness"]["baseColorFactor"]), m.materials[1].base_color);
        assert!(json.get("images").is_none());
    }

    #[test]
    fn positions_and_colors_land_in_the_buffer() {
        let m = fixtures::colored_sphere(1);
        let bytes = glb(&m);
        let (json, bin) = parse(&bytes);
        let p = &json["meshes"][0]["primitives"][0];
        let color = &json["accessors"][p["attributes"]["COLOR_0"].as_u64().unwrap() as usize];
        assert_eq!(
            (color["componentType"].as_u64(), color["normalized"].as_bool(), color["type"].as_str()),
            (Some(5121), Some(true), Some("VEC4"))
        );
        let (_, pos) = accessor(&json, bin, &p["attributes"]["POSITION"], 12);
        let (_, colors) = accessor(&json, bin, &p["attributes"]["COLOR_0"], 4);
        let (ni, idx) = accessor(&json, bin, &p["indices"], 4);
        assert_eq!(ni, 3 * m.face_count());
        for c in 0..ni {
            let v = u32_at(idx, 4 * c) as usize;
            let xyz = [0, 1, 2].map(|i| u32_at(pos, 12 * v + 4 * i));
            assert_eq!(xyz, m.positions[m.triangles[c / 3][c % 3] as usize].to_array().map(f32::to_bits));
            assert_eq!(colors[4 * v..4 * v + 4], m.colors[c]);
        }
    }

    /// A box whose two materials share one embedded image as base color, the second also with it
    /// as emissive map clamped along v.
    fn textured_box() -> (Mesh, Vec<u8>) {
        let mut m = fixtures::two_material_box();
        let png = crate::texture::encode(crate::texture::ImageCodec::Png, &crate::texture::Rgba8::new(4, 4), 90).unwrap();
        m.images = vec![crate::texture::SourceImage::new("maps/side wall.png".into(), png.clone()).unwrap()];
        let slot = crate::format::TextureSlot { image: 0, wrap: [Wrap::Repeat; 2] };
        m.materials[0].maps[MapKind::BaseColor as usize] = Some(slot);
        m.materials[1].maps[MapKind::BaseColor as usize] = Some(slot);
        m.materials[1].maps[MapKind::Emissive as usize] = Some(crate::format::TextureSlot { wrap: [Wrap::Repeat, Wrap::Clamp], ..slot });
        m.materials[1].texture = Some("a path that is not written.png".into());
        (m, png)
    }

    #[test]
    fn maps_embed_their_images() {
        let (mut m, png) = textured_box();
        let bytes = glb(&m);
        let (json, bin) = parse(&bytes);
        let view = json["images"][0]["bufferView"].clone();
        assert_eq!(json["images"], serde_json::json!([{ "name": "maps/side wall.png", "bufferView": view, "mimeType": "image/png" }]));
        let view = &json["bufferViews"][json["images"][0]["bufferView"].as_u64().unwrap() as usize];
        assert!(view.get("target").is_none(), "an image's view has no target");
        let at = view["byteOffset"].as_u64().unwrap() as usize;
        assert_eq!(&bin[at..at + view["byteLength"].as_u64().unwrap() as usize], &png[..]);
        assert_eq!(json["textures"], serde_json::json!([{ "sampler": 0, "source": 0 }, { "sampler": 1, "source": 0 }]));
        assert_eq!(json["samplers"][1]["wrapT"], 33071);
        for mat in json["materials"].as_array().unwrap() {
            assert_eq!(mat["pbrMetallicRoughness"]["baseColorTexture"]["index"], 0);
        }
        assert_eq!(json["materials"][1]["emissiveTexture"]["index"], 1);
        assert_eq!(json["materials"][1]["emissiveFactor"], serde_json::json!([1.0, 1.0, 1.0]));
        assert!(!String::from_utf8_lossy(&glb(&m)).contains("not written"), "no reference to files beside it");
        m.uvs.clear();
        let (json, _) = parse(&glb(&m));
        assert!(json.get("images").is_none() && json.get("textures").is_none());
    }

    #[test]
    fn gltf_crate_reads_it_back() {
        let (mut m, png) = textured_box();
        m.colors = vec![[10, 20, 30, 255]; 3 * m.face_count()];
        let bytes = glb(&m);
        let doc = gltf::Gltf::from_slice(&bytes).unwrap();
        let blob = doc.blob.as_deref().unwrap();
        let mut corners = 0;
        for p in doc.meshes().next().unwrap().primitives() {
            let reader = p.reader(|_| Some(blob));
            let positions: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
            assert_eq!(reader.read_normals().unwrap().count(), positions.len());
            assert_eq!(reader.read_tex_coords(0).unwrap().into_f32().count(), positions.len());
            assert!(reader.read_colors(0).unwrap().into_rgba_u8().all(|c| c == [10, 20, 30, 255]));
            let indices: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
            assert!(indices.iter().all(|&i| (i as usize) < positions.len()));
            corners += indices.len();
        }
        assert_eq!(corners, 3 * m.face_count());
        let top = doc.materials().nth(1).unwrap();
        let texture = top.pbr_metallic_roughness().base_color_texture().unwrap().texture();
        let gltf::image::Source::View { view, mime_type } = texture.source().source() else { panic!("an embedded image") };
        assert_eq!(mime_type, "image/png");
        assert_eq!(&blob[view.offset()..view.offset() + view.length()], &png[..]);
    }

    #[test]
    fn empty_mesh_is_refused() {
        let err = write_glb(Vec::new(), &Mesh::default()).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
    }
}
