//! What `strata inspect` shows of a file: header, chunk tree, a summary per level, and on request
//! node rows (a level, one node, or the tree from the top down to a depth). Built from the
//! skeleton alone, except for one node's sub-chunks when a single node is asked for.

use super::skeleton::ChunkInfo;
use super::{ByteSource, Reader, NO_PARENT};
use crate::error::{Error, Result};

/// Which nodes to list.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Selection {
    /// The node tree from the top level down this many levels.
    pub depth: Option<u32>,
    /// Every node of this level.
    pub level: Option<u32>,
    /// This node, with its geometry's sub-chunks.
    pub node: Option<u32>,
}

/// The `HEAD` chunk, for display.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct HeaderView {
    pub file_size: u64,
    pub metres_per_unit: f64,
    pub min: [f32; 3],
    pub max: [f32; 3],
    pub attributes: super::Attributes,
    pub levels: u32,
    pub nodes: u32,
    pub materials: Vec<String>,
    pub input_vertices: u64,
    pub input_faces: u64,
    pub clusters: u32,
    pub params: super::HierarchyParams,
    /// The position grid: origin, step and bits per axis.
    pub grid: super::Grid,
    pub level_ratio: f32,
    pub tool: String,
}

/// One level's totals.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LevelView {
    pub level: u32,
    pub nodes: u32,
    pub faces: u64,
    pub vertices: u64,
    pub bytes: u64,
    /// Offsets of the level's first `GEOM` chunk and of the byte after its last.
    pub start: u64,
    pub end: u64,
    pub cone_deg_max: f32,
    pub error_max: f32,
}

/// One node.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct NodeView {
    pub node: u32,
    /// Depth in the listed tree (0 = top level); 0 for other listings.
    pub depth: u32,
    pub level: u32,
    pub parent: Option<u32>,
    pub children: Vec<u32>,
    pub neighbors: usize,
    pub faces: u32,
    pub vertices: u32,
    pub cone_deg: f32,
    pub radius: f32,
    pub error: f32,
    pub offset: u64,
    pub bytes: u32,
    /// The geometry's sub-chunks, when one node is asked for.
    pub chunks: Vec<ChunkInfo>,
}

/// Everything `inspect` shows.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Inspection {
    pub version: String,
    pub header: HeaderView,
    /// Where the model sits on Earth (`GEOR`), for terrain.
    pub georef: Option<super::Georef>,
    /// Chunks read at open (`HEAD`, `SKEL` and its sub-chunks); geometry chunks are summarized per
    /// level in `levels`.
    pub chunks: Vec<ChunkInfo>,
    /// Finest level first.
    pub levels: Vec<LevelView>,
    pub nodes: Vec<NodeView>,
    /// The images materials use (`TEXR`, `TEXL`), empty without.
    pub images: Vec<ImageView>,
    /// The separating planes (`ORDR`, 2.3), absent without.
    pub planes: Option<PlanesView>,
}

/// Where the separating planes lie and how many there are.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PlanesView {
    /// File offset of the `ORDR` chunk, and the bytes from there to the end of the file (the chunk
    /// and any a newer minor appends).
    pub offset: u64,
    pub bytes: u64,
    pub entries: u64,
    /// Parents (the virtual root included) with at least one entry.
    pub parents: u64,
}

/// One image and its levels.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ImageView {
    pub image: u32,
    pub name: String,
    pub codec: super::ImageCodec,
    /// Width, height and chunk bytes (ID through CRC) of each level, finest first.
    pub levels: Vec<[u64; 3]>,
    /// Where its `TEXL` chunks lie: the first offset and the byte after the last.
    pub start: u64,
    pub end: u64,
    /// `material: map` for every material slot that samples it.
    pub uses: Vec<String>,
}

/// Describe an open file; nodes as `select` asks.
pub fn inspect<S: ByteSource>(rd: &Reader<S>, select: Selection) -> Result<Inspection> {
    let h = rd.header().clone();
    let header = HeaderView {
        file_size: h.file_size,
        metres_per_unit: h.metres_per_unit,
        min: h.min.to_array(),
        max: h.max.to_array(),
        attributes: h.attributes,
        levels: h.levels,
        nodes: h.nodes,
        materials: rd.materials().iter().map(|m| m.name.clone()).collect(),
        input_vertices: h.input_vertices,
        input_faces: h.input_faces,
        clusters: h.clusters,
        params: h.params,
        grid: h.grid,
        level_ratio: h.level_ratio,
        tool: h.tool.clone(),
    };
    let levels = rd
        .levels()
        .iter()
        .enumerate()
        .map(|(l, r)| {
            let nodes = &rd.nodes()[r.first_node as usize..(r.first_node + r.nodes) as usize];
            LevelView {
                level: l as u32,
                nodes: r.nodes,
                faces: r.faces,
                vertices: r.vertices,
                bytes: r.bytes,
                start: nodes.first().map_or(0, |n| n.offset),
                end: nodes.first().map_or(0, |n| n.offset) + r.bytes,
                cone_deg_max: nodes.iter().map(|n| n.cone.half_angle.to_degrees()).fold(0.0, f32::max),
                error_max: nodes.iter().map(|n| n.error).fold(0.0, f32::max),
            }
        })
        .collect();
    let mut nodes = Vec::new();
    if let Some(l) = select.level {
        if l >= h.levels {
            return Err(Error::invalid(rd.path(), None, format!("level {l} does not exist (the file has levels 0..{})", h.levels - 1)));
        }
        nodes.extend(rd.level_nodes(l).map(|i| view(rd, i, 0)));
    }
    if let Some(depth) = select.depth.filter(|&d| d > 0) {
        let mut stack: Vec<(u32, u32)> = rd.level_nodes(h.levels - 1).rev().map(|i| (i, 0)).collect();
        while let Some((i, d)) = stack.pop() {
            nodes.push(view(rd, i, d));
            if d + 1 < depth {
                stack.extend(rd.children(i).rev().map(|c| (c, d + 1)));
            }
        }
    }
    if let Some(i) = select.node {
        if i >= h.nodes {
            return Err(Error::invalid(rd.path(), None, format!("node {i} does not exist (the file has {} nodes)", h.nodes)));
        }
        let mut v = view(rd, i, 0);
        v.chunks = rd.node_chunks(i)?;
        nodes.push(v);
    }
    let t = rd.textures();
    let images = t
        .images
        .iter()
        .enumerate()
        .map(|(i, im)| {
            let lv: Vec<&super::ImageLevel> = im.levels.iter().map(|&e| &t.levels[e as usize]).collect();
            let uses = rd
                .materials()
                .iter()
                .flat_map(|m| {
                    super::MapKind::ALL
                        .into_iter()
                        .filter(|&k| m.map(k).is_some_and(|s| s.image == i as u32))
                        .map(|k| format!("{}: {}", m.name, k.name()))
                })
                .collect();
            ImageView {
                image: i as u32,
                name: im.name.clone(),
                codec: im.codec,
                levels: lv.iter().map(|l| [l.width as u64, l.height as u64, l.size as u64]).collect(),
                start: lv.iter().map(|l| l.offset).min().unwrap_or(0),
                end: lv.iter().map(|l| l.offset + l.size as u64).max().unwrap_or(0),
                uses,
            }
        })
        .collect();
    Ok(Inspection {
        version: format!("{}.{}", h.major, h.minor),
        header,
        georef: rd.georef().cloned(),
        chunks: rd.skeleton_chunks().to_vec(),
        levels,
        nodes,
        images,
        planes: {
            let p = rd.read_planes()?;
            (!p.is_empty()).then(|| PlanesView {
                offset: rd.planes_offset(),
                bytes: rd.file_size() - rd.planes_offset(),
                entries: p.entries.len() as u64,
                parents: p.starts.windows(2).filter(|w| w[1] > w[0]).count() as u64,
            })
        },
    })
}

fn view<S: ByteSource>(rd: &Reader<S>, i: u32, depth: u32) -> NodeView {
    let n = rd.nodes()[i as usize];
    NodeView {
        node: i,
        depth,
        level: n.level,
        parent: (n.parent != NO_PARENT).then_some(n.parent),
        children: rd.children(i).collect(),
        neighbors: rd.neighbors(i).len(),
        faces: n.faces,
        vertices: n.vertices,
        cone_deg: n.cone.half_angle.to_degrees(),
        radius: n.radius,
        error: n.error,
        offset: n.offset,
        bytes: n.size,
        chunks: Vec::new(),
    }
}

/// Everything a file holds, decoded, as one JSON value: the header, levels, materials, and every
/// node's record, neighbours, box and geometry. The form of the golden vectors in
/// `format-spec/vectors/` that every reader of the format checks itself against. Floats are the
/// decoded f32 values, exactly (as f64 numbers).
pub fn dump<S: ByteSource>(rd: &Reader<S>) -> Result<serde_json::Value> {
    use serde_json::json;
    let f = |x: f32| json!(x as f64);
    let v3 = |v: glam::Vec3| json!([v.x as f64, v.y as f64, v.z as f64]);
    let h = rd.header();
    let p = &h.params;
    let cone = |c: &super::Cone| json!({ "axis": v3(c.axis), "half_angle": f(c.half_angle) });
    let mut nodes = Vec::with_capacity(rd.nodes().len());
    for (i, n) in rd.nodes().iter().enumerate() {
        let g = rd.read_node(i as u32)?;
        let (min, max) = rd.node_box(i as u32);
        nodes.push(json!({
            "level": n.level,
            "parent": (n.parent != NO_PARENT).then_some(n.parent),
            "first_child": n.first_child,
            "child_count": n.child_count,
            "neighbors": rd.neighbors(i as u32),
            "cone": cone(&n.cone),
            "center": v3(n.center),
            "radius": f(n.radius),
            "box": { "min": v3(min), "max": v3(max) },
            "error": f(n.error),
            "faces": n.faces,
            "vertices": n.vertices,
            "offset": n.offset,
            "size": n.size,
            "crc": n.crc,
            "geometry": {
                "positions": g.positions.iter().map(|&p| v3(p)).collect::<Vec<_>>(),
                "normals": g.normals.iter().map(|&p| v3(p)).collect::<Vec<_>>(),
                "uvs": g.uvs.iter().map(|uv| json!([uv.x as f64, uv.y as f64])).collect::<Vec<_>>(),
                "colors": g.colors,
                "indices": g.indices,
                "material_ranges": g.material_ranges.iter().map(|r| json!([r.material, r.first_index, r.index_count])).collect::<Vec<_>>(),
                // Format 3 stores a cluster's faces only; its bounds are the reader's to compute.
                "clusters": g.clusters.iter().map(|c| if h.major >= 3 {
                    json!({ "first_face": c.first_face, "face_count": c.face_count })
                } else {
                    json!({
                        "cone": cone(&c.cone), "center": v3(c.center), "radius": f(c.radius),
                        "first_face": c.first_face, "face_count": c.face_count,
                    })
                }).collect::<Vec<_>>(),
            },
        }));
    }
    let mut out = json!({
        "version": format!("{}.{}", h.major, h.minor),
        "header": {
            "file_size": h.file_size,
            "metres_per_unit": h.metres_per_unit,
            "min": v3(h.min),
            "max": v3(h.max),
            "attributes": h.attributes,
            "levels": h.levels,
            "nodes": h.nodes,
            "materials": h.materials,
            "input_vertices": h.input_vertices,
            "input_faces": h.input_faces,
            "clusters": h.clusters,
            "params": {
                "cluster_faces": p.cluster_faces, "cluster_angle": f(p.cluster_angle), "leaf_faces": p.leaf_faces,
                "leaf_angle": f(p.leaf_angle), "angle_step": f(p.angle_step), "growth": p.growth,
                "kc": f(p.kc), "ks": f(p.ks), "kn": f(p.kn), "top_groups": p.top_groups,
            },
            "grid": { "origin": h.grid.origin, "step": h.grid.step, "bits": h.grid.bits },
            "level_ratio": f(h.level_ratio),
            "tool": h.tool,
        },
        "georef": rd.georef(),
        "levels": rd.levels().iter().map(|l| json!({
            "first_node": l.first_node, "nodes": l.nodes, "faces": l.faces, "vertices": l.vertices, "bytes": l.bytes,
        })).collect::<Vec<_>>(),
        "materials": rd.materials().iter().map(|m| json!({
            "name": m.name, "base_color": m.base_color.map(|x| x as f64), "texture": m.texture,
        })).collect::<Vec<_>>(),
        "nodes": nodes,
    });
    if let Some(d) = rd.dag() {
        // Format 4: the groups in file order, and each node's consumer and source (null: none).
        let none = |x: u32| (x != NO_PARENT).then_some(x);
        out["dag"] = json!({
            "groups": d.groups.iter().map(|g| json!({
                "level": g.level, "first_output": g.first_output, "outputs": g.outputs, "children": g.children,
                "error": f(g.error), "center": v3(g.center), "radius": f(g.radius),
            })).collect::<Vec<_>>(),
            "consumer": d.consumer.iter().map(|&x| none(x)).collect::<Vec<_>>(),
            "source": d.source.iter().map(|&x| none(x)).collect::<Vec<_>>(),
        });
    }
    let planes = rd.read_planes()?;
    if !planes.is_empty() {
        // Files with separating planes (2.3): per parent (-1 = the virtual root), its entries.
        let mut list = Vec::with_capacity(planes.entries.len());
        for (p, w) in planes.starts.windows(2).enumerate() {
            for e in &planes.entries[w[0] as usize..w[1] as usize] {
                list.push(json!({
                    "parent": p as i64 - 1, "first": e.first, "second": e.second, "normal": e.normal,
                    "first_max": f(e.first_max), "second_min": f(e.second_min),
                }));
            }
        }
        out["planes"] = json!(list);
    }
    if let Some(code) = &rd.skeleton().code {
        let t = &code.tables;
        out["code"] =
            json!({ "normal_bits": t.normal_bits, "color_bits": t.color_bits, "freqs": t.freqs.iter().map(|f| &f.0).collect::<Vec<_>>() });
    }
    let t = rd.textures();
    if !t.is_empty() {
        // Files with images (2.2) also list them; the level files' bytes by length and CRC-32.
        let slot = |s: Option<super::TextureSlot>| s.map(|s| json!({ "image": s.image, "wrap": [s.wrap[0] as u8, s.wrap[1] as u8] }));
        let mut levels = Vec::with_capacity(t.levels.len());
        for l in &t.levels {
            let bytes = rd.read_image_level(l.image, l.level)?;
            levels.push(json!({
                "image": l.image, "level": l.level, "width": l.width, "height": l.height,
                "offset": l.offset, "size": l.size, "crc": l.crc,
                "file_bytes": bytes.len(), "file_crc": super::chunk::crc32(&bytes),
            }));
        }
        out["textures"] = json!({
            "images": t.images.iter().map(|i| json!({ "name": i.name, "codec": i.codec as u8, "levels": i.levels })).collect::<Vec<_>>(),
            "levels": levels,
            "maps": rd.materials().iter().map(|m| m.maps.map(slot)).collect::<Vec<_>>(),
            "uv_density": t.uv_density.iter().map(|&d| f(d)).collect::<Vec<_>>(),
        });
    }
    Ok(out)
}
