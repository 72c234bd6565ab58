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
}

impl Default for Material {
    fn default() -> Self {
        Material { name: "default".into(), base_color: [0.8, 0.8, 0.8, 1.0], texture: None }
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
            growth: 4,
            kc: 1.0,
            ks: 0.1,
            kn: 0.05,
            top_groups: 8,
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
