//! The records of a strata file as a reader holds them (spec §5–§8): plain data, decoded.

use super::Grid;
use glam::{Vec2, Vec3};

/// A cone of directions: every direction within `half_angle` radians of the unit `axis`. Node and
/// cluster records bound their faces' normals with one (spec §6); `crate::cone` builds them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone {
    pub axis: Vec3,
    /// In [0, π]; π (as f32, a hair above π) means every direction.
    pub half_angle: f32,
}

/// A material (spec §7.4): enough to draw it and to keep material borders apart.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    /// Linear RGBA base color.
    pub base_color: [f32; 4],
    /// Path or URI of the base color texture, as written in the source file.
    pub texture: Option<String>,
    /// The images the material's maps sample, by [`MapKind`] (spec §7.5, `TEXR`).
    pub maps: [Option<TextureSlot>; MAP_KINDS],
}

impl Default for Material {
    fn default() -> Self {
        Material { name: "default".into(), base_color: [0.8, 0.8, 0.8, 1.0], texture: None, maps: [None; MAP_KINDS] }
    }
}

impl Material {
    /// The image map `kind` samples, if any.
    pub fn map(&self, kind: MapKind) -> Option<TextureSlot> {
        self.maps[kind as usize]
    }
}

/// Kinds of image map a material can have, in the order of `TEXR`'s slots (spec §7.5); glTF's
/// metallic-roughness model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub enum MapKind {
    /// sRGB color (and alpha), multiplied by the base color.
    BaseColor = 0,
    /// Tangent-space normals, linear.
    Normal = 1,
    /// Roughness in green, metalness in blue, linear.
    MetallicRoughness = 2,
    /// Ambient occlusion in red, linear.
    Occlusion = 3,
    /// sRGB emitted color.
    Emissive = 4,
}

/// Slots of map kinds per material.
pub const MAP_KINDS: usize = 5;

impl MapKind {
    pub const ALL: [MapKind; MAP_KINDS] =
        [MapKind::BaseColor, MapKind::Normal, MapKind::MetallicRoughness, MapKind::Occlusion, MapKind::Emissive];

    /// Whether texels are sRGB-encoded colors (filtered in linear light), else linear data.
    pub fn is_srgb(self) -> bool {
        matches!(self, MapKind::BaseColor | MapKind::Emissive)
    }

    pub fn name(self) -> &'static str {
        ["base color", "normal", "metallic-roughness", "occlusion", "emissive"][self as usize]
    }
}

/// How UVs outside [0, 1] sample an image, per axis (glTF's sampler wrap modes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
pub enum Wrap {
    #[default]
    Repeat = 0,
    Clamp = 1,
    Mirror = 2,
}

impl Wrap {
    pub fn from_code(c: u8) -> Option<Wrap> {
        [Wrap::Repeat, Wrap::Clamp, Wrap::Mirror].get(c as usize).copied()
    }
}

/// A material's map: which image (an index into the file's images) and how it wraps in u and v.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TextureSlot {
    pub image: u32,
    pub wrap: [Wrap; 2],
}

/// How an image's levels are compressed: each level is a complete file of that kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub enum ImageCodec {
    Png = 1,
    Jpeg = 2,
}

impl ImageCodec {
    pub fn from_code(c: u8) -> Option<ImageCodec> {
        match c {
            1 => Some(ImageCodec::Png),
            2 => Some(ImageCodec::Jpeg),
            _ => None,
        }
    }

    /// The media type of the level files (for glTF's `mimeType` and HTTP).
    pub fn mime(self) -> &'static str {
        match self {
            ImageCodec::Png => "image/png",
            ImageCodec::Jpeg => "image/jpeg",
        }
    }

    /// File name extension of a level file, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            ImageCodec::Png => "png",
            ImageCodec::Jpeg => "jpg",
        }
    }
}

/// An image a material uses, stored as a pyramid of resolutions (spec §7.5): level 0 is the full
/// image, each next level half the size (rounded up) of the one before.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ImageRecord {
    /// As the source named it (a file name or URI, or "embedded image 3").
    pub name: String,
    pub codec: ImageCodec,
    /// Index into [`Textures::levels`] of each level, finest (the full image) first.
    pub levels: Vec<u32>,
}

/// One resolution of an image: a `TEXL` chunk after the geometry (spec §7.5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageLevel {
    pub image: u32,
    /// 0 = the full image.
    pub level: u32,
    pub width: u32,
    pub height: u32,
    /// Where its `TEXL` chunk starts (not stored: the chunks follow the last `GEOM` in table
    /// order), its bytes from ID through CRC (padding excluded), and the CRC of its payload.
    pub offset: u64,
    pub size: u32,
    pub crc: u32,
}

impl ImageLevel {
    /// Bytes of its pixels decoded as RGBA8, what a renderer holds.
    pub fn decoded_bytes(&self) -> u64 {
        4 * self.width as u64 * self.height as u64
    }
}

/// The images of a file and what selects their levels: the `TEXR` chunk decoded. Empty for a
/// file without images.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Textures {
    pub images: Vec<ImageRecord>,
    /// Every level of every image, in file order (coarsest first as writers lay them out).
    pub levels: Vec<ImageLevel>,
    /// Per node: UV units per model unit over its textured faces (0 for a node without), rounded
    /// up, so that a level fine enough for it can be chosen from its projected size (selection.md).
    pub uv_density: Vec<f32>,
}

impl Textures {
    pub fn is_empty(&self) -> bool {
        self.images.is_empty()
    }

    /// Level `level` of image `image` (0 = full), if it exists.
    pub fn level(&self, image: u32, level: u32) -> Option<&ImageLevel> {
        let i = *self.images.get(image as usize)?.levels.get(level as usize)?;
        self.levels.get(i as usize)
    }

    /// Levels of image `image` (0 when there is no such image).
    pub fn level_count(&self, image: u32) -> u32 {
        self.images.get(image as usize).map_or(0, |i| i.levels.len() as u32)
    }

    /// Bytes of the `TEXL` chunks, padding included.
    pub fn stored_bytes(&self) -> u64 {
        self.levels.iter().map(|l| l.size as u64 + super::chunk::padding(l.offset + l.size as u64)).sum()
    }
}

/// Parameters of the group hierarchy (`crate::hierarchy`), recorded in `HEAD` (spec §5) and not
/// interpreted by readers. Angles are cone half-angles in radians; sizes count faces of the input
/// mesh.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct HierarchyParams {
    /// Size cap of a culling cluster.
    pub cluster_faces: u32,
    /// Cone threshold of a culling cluster.
    pub cluster_angle: f32,
    /// Size cap of a level-0 group (a streamed leaf node): a few hundred faces make a worthwhile
    /// chunk and draw call.
    pub leaf_faces: u32,
    /// Cone threshold of a level-0 group.
    pub leaf_angle: f32,
    /// How much the threshold relaxes from one level to the next.
    pub angle_step: f32,
    /// How much the size cap grows from one level to the next.
    pub growth: u32,
    /// Weights of the evaluation function (cone tightness, compactness, size balance); the method's
    /// source found the cone term decisive.
    pub kc: f32,
    pub ks: f32,
    pub kn: f32,
    /// Stop adding levels once at most this many groups remain.
    pub top_groups: usize,
}

impl Default for HierarchyParams {
    fn default() -> Self {
        HierarchyParams {
            cluster_faces: 32,
            cluster_angle: 35f32.to_radians(),
            leaf_faces: 512,
            leaf_angle: 120f32.to_radians(),
            angle_step: 30f32.to_radians(),
            growth: 2,
            kc: 1.0,
            ks: 0.1,
            kn: 0.05,
            top_groups: 8,
        }
    }
}

impl HierarchyParams {
    /// The size cap growth that keeps nodes of one size when each level has `level_ratio` of the
    /// faces of the one below (groups then merge about `1 / level_ratio` to one): round(1 /
    /// ratio), from 2 to 64; the default's for a ratio that is not a positive number.
    pub fn growth_for(level_ratio: f32) -> u32 {
        if level_ratio > 0.0 && level_ratio.is_finite() {
            (1.0 / level_ratio).round().clamp(2.0, 64.0) as u32
        } else {
            HierarchyParams::default().growth
        }
    }
}

/// Which corner attributes every vertex of the file carries besides its position.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Attributes {
    pub normals: bool,
    pub uvs: bool,
    pub colors: bool,
}

impl Attributes {
    /// The `HEAD` attribute bits: 1 normals, 2 UVs, 4 colors.
    pub fn bits(self) -> u32 {
        self.normals as u32 | (self.uvs as u32) << 1 | (self.colors as u32) << 2
    }

    pub fn from_bits(bits: u32) -> Attributes {
        Attributes { normals: bits & 1 != 0, uvs: bits & 2 != 0, colors: bits & 4 != 0 }
    }
}

/// The `HEAD` chunk: what the file holds and how it was built.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    pub major: u16,
    pub minor: u16,
    /// Size of the whole file in bytes.
    pub file_size: u64,
    /// Metres per model unit; 0 when the unit is unknown.
    pub metres_per_unit: f64,
    /// Bounds of every level's geometry.
    pub min: Vec3,
    pub max: Vec3,
    pub attributes: Attributes,
    pub levels: u32,
    pub nodes: u32,
    pub materials: u32,
    /// Vertices and faces of the input mesh (level 0).
    pub input_vertices: u64,
    pub input_faces: u64,
    /// Culling clusters over all level-0 nodes.
    pub clusters: u32,
    /// Parameters the hierarchy was built with.
    pub params: HierarchyParams,
    /// The grid every position, box and sphere center lies on.
    pub grid: Grid,
    /// Target ratio of faces between a level and the one below.
    pub level_ratio: f32,
    /// Name and version of the program that wrote the file.
    pub tool: String,
}

impl Header {
    /// Whether this reader knows every field and chunk of the file's version.
    pub fn minor_known(&self) -> bool {
        self.minor <= super::known_minor(self.major)
    }

    /// Whether the file's version carries separating planes (`ORDR`): 2.3 and format 3; format 4,
    /// whose nodes are not a tree, has none.
    pub fn has_planes_version(&self) -> bool {
        self.major == 3 || (self.major == 2 && self.minor >= 3)
    }

    /// Whether the file's node table is a DAG of nodes and groups (format 4).
    pub fn is_dag(&self) -> bool {
        self.major == super::MAJOR4
    }
}

/// One entry of the `LEVL` chunk: level ℓ's nodes are `first_node .. first_node + nodes`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LevelRecord {
    pub first_node: u32,
    pub nodes: u32,
    /// Faces and vertices over the level's nodes.
    pub faces: u64,
    pub vertices: u64,
    /// Bytes of the level's `GEOM` chunks, padding included.
    pub bytes: u64,
}

/// One entry of the node table. Nodes are numbered in file order: top level first, and within a
/// level by parent, so a node's children are consecutive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodeRecord {
    /// Level ℓ (0 = full detail); not stored, implied by the `LEVL` ranges.
    pub level: u32,
    /// Parent node, or [`NO_PARENT`] for a top-level node.
    pub parent: u32,
    /// Children are nodes `first_child .. first_child + child_count` of level ℓ − 1.
    pub first_child: u32,
    pub child_count: u32,
    /// Neighbours are `neighbors[neighbor_first .. neighbor_first + neighbor_count]`; `neighbor_first`
    /// is not stored, the lists follow one another in node order.
    pub neighbor_first: u32,
    pub neighbor_count: u32,
    /// Contains every face normal of this node and every cone of its descendants.
    pub cone: Cone,
    /// Bounding sphere of this node's vertices and of its descendants' spheres. The node's box is
    /// kept apart, packed, since only the checks of its geometry need it
    /// ([`Reader::node_box`](super::Reader::node_box)).
    pub center: Vec3,
    pub radius: f32,
    /// Geometric error in model units, never smaller than a child's; includes the position
    /// quantization bound [`Grid::error`].
    pub error: f32,
    pub faces: u32,
    pub vertices: u32,
    /// Where the node's `GEOM` chunk starts (not stored: chunks follow the skeleton in node order),
    /// its bytes from ID to CRC (padding excluded), and the CRC-32 of its payload.
    pub offset: u64,
    pub size: u32,
    pub crc: u32,
}

/// Format 4: a group of the DAG, which made a run of nodes of its level (its outputs) from nodes
/// of the level below (its children) whose outer border it kept (strata-v4.md §1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupRecord {
    /// The level of its outputs, at least 1.
    pub level: u32,
    /// Its outputs are nodes `first_output .. first_output + outputs`.
    pub first_output: u32,
    pub outputs: u32,
    /// How many nodes of the level below name it as their consumer.
    pub children: u32,
    /// Geometric error in model units, never below its children's.
    pub error: f32,
    /// A sphere holding its children's spheres and their source groups' spheres.
    pub center: Vec3,
    pub radius: f32,
}

/// Format 4: the DAG's groups and how nodes refer to them. Groups are numbered in file order (the
/// top level's first); [`NO_PARENT`] marks "none".
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DagTable {
    pub groups: Vec<GroupRecord>,
    /// Per level (finest first), its groups.
    pub level_groups: Vec<std::ops::Range<u32>>,
    /// Per node: the group it is a child of (none at the top), and the group that made it (none at
    /// level 0).
    pub consumer: Vec<u32>,
    pub source: Vec<u32>,
    /// Group `g`'s children are `child_items[child_offsets[g] .. child_offsets[g + 1]]`, in node
    /// order.
    pub child_offsets: Vec<u32>,
    pub child_items: Vec<u32>,
}

impl DagTable {
    /// The children of group `g` (nodes of the level below its outputs).
    pub fn children(&self, g: u32) -> &[u32] {
        match (self.child_offsets.get(g as usize), self.child_offsets.get(g as usize + 1)) {
            (Some(&a), Some(&b)) => &self.child_items[a as usize..b as usize],
            _ => &[],
        }
    }

    /// The outputs of group `g`.
    pub fn outputs(&self, g: u32) -> std::ops::Range<u32> {
        self.groups.get(g as usize).map_or(0..0, |r| r.first_output..r.first_output + r.outputs)
    }
}

/// A run of indices drawn with one material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaterialRange {
    pub material: u32,
    pub first_index: u32,
    pub index_count: u32,
}

/// A culling cluster inside a level-0 node: faces `first_face .. first_face + face_count` of the
/// node (`first_face` is not stored: clusters follow one another), all facing within `cone`, all
/// inside the sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cluster {
    pub cone: Cone,
    pub center: Vec3,
    pub radius: f32,
    pub first_face: u32,
    pub face_count: u32,
}

/// One node's geometry, decoded: node-local vertices and triangles over them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeGeometry {
    pub positions: Vec<Vec3>,
    /// Unit normals per vertex, or empty when the file has none.
    pub normals: Vec<Vec3>,
    pub uvs: Vec<Vec2>,
    pub colors: Vec<[u8; 4]>,
    /// Three per face, each below `positions.len()`.
    pub indices: Vec<u32>,
    /// Consecutive runs covering `indices`.
    pub material_ranges: Vec<MaterialRange>,
    /// Level-0 nodes only: consecutive runs covering the faces.
    pub clusters: Vec<Cluster>,
}

impl NodeGeometry {
    pub fn face_count(&self) -> usize {
        self.indices.len() / 3
    }
}
