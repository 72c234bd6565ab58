//! Node geometry of format 2 (spec §8): sub-chunks of fixed-width arrays. Positions are grid
//! offsets from a node base (u16 or u24), normals octahedral i16 pairs, UVs f32 pairs, colors RGBA
//! bytes, indices u16 or u32, then material ranges and, at level 0, culling clusters.

use super::NodeContext;
use crate::error::{Error, Result};
use crate::format::chunk::{self, Sub};
use crate::format::{
    angle_decode, id, octa, radius_decode, Cluster, Cone, MaterialRange, NodeGeometry, CLUSTER_RECORD_BYTES, RANGE_RECORD_BYTES,
};
use byteorder::{ByteOrder, LittleEndian as LE};
use glam::Vec2;

/// One node's geometry as format 2 stores it, before framing: what [`encode`] turns into a `GEOM`
/// payload. Corner attributes are empty when the file has none.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GeometryCodes {
    /// Grid point of each vertex.
    pub points: Vec<[u32; 3]>,
    /// Octahedral code of each vertex normal.
    pub normals: Vec<[i16; 2]>,
    /// Bit patterns of each vertex's f32 UV.
    pub uvs: Vec<[u32; 2]>,
    pub colors: Vec<[u8; 4]>,
    /// Three per face.
    pub indices: Vec<u32>,
    pub material_ranges: Vec<MaterialRange>,
    /// Level-0 nodes: the clusters' shift and records, tiling the faces.
    pub clusters: Option<(u32, Vec<ClusterCodes>)>,
    /// Format 3: the precision the codes were quantized to (normals at `normal_bits`, UVs on
    /// multiples of `2^−uv_bits`); format 2 ignores it (its normals are 16-bit, its UVs f32).
    pub lattice: super::v3::Lattice,
}

/// A cluster record as stored (spec §8.7).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClusterCodes {
    pub axis: [i16; 2],
    pub half_angle: u16,
    pub faces: u16,
    /// Sphere center: grid point `base + center·2^shift`.
    pub center: [u16; 3],
    pub radius: u16,
}

/// The node base (component-wise minimum of its grid points) and the largest offset from it.
pub fn base_and_span(points: &[[u32; 3]]) -> ([u32; 3], u32) {
    let base =
        points.iter().fold(if points.is_empty() { [0; 3] } else { [u32::MAX; 3] }, |b, p| [b[0].min(p[0]), b[1].min(p[1]), b[2].min(p[2])]);
    let span = points.iter().flat_map(|p| (0..3).map(move |k| p[k] - base[k])).max().unwrap_or(0);
    (base, span)
}

/// The writer's cluster shift: the smallest `t ≤ bits` with `span >> t` below 65536.
pub fn cluster_shift(span: u32, bits: u32) -> u32 {
    (0..=bits).find(|&s| span >> s <= u16::MAX as u32).unwrap_or(bits)
}

/// The `GEOM` payload of a node: its sub-chunks, in the order of the spec.
pub fn encode(g: &GeometryCodes) -> Vec<u8> {
    let (base, span) = base_and_span(&g.points);
    let width: u32 = if span <= u16::MAX as u32 { 2 } else { 3 };
    let mut pos: Vec<u8> = base.iter().flat_map(|x| x.to_le_bytes()).collect();
    for p in &g.points {
        for k in 0..3 {
            pos.extend_from_slice(&(p[k] - base[k]).to_le_bytes()[..width as usize]);
        }
    }
    let mut payload = Vec::new();
    chunk::put(&mut payload, id::VPOS, width, &pos);
    if !g.normals.is_empty() {
        let b: Vec<u8> = g.normals.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        chunk::put(&mut payload, id::VNRM, 0, &b);
    }
    if !g.uvs.is_empty() {
        let b: Vec<u8> = g.uvs.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        chunk::put(&mut payload, id::VTEX, 0, &b);
    }
    if !g.colors.is_empty() {
        chunk::put(&mut payload, id::VCOL, 0, g.colors.as_flattened());
    }
    let vertices = g.points.len();
    let index_bytes: Vec<u8> = if vertices <= 1 << 16 {
        g.indices.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect()
    } else {
        g.indices.iter().flat_map(|&i| i.to_le_bytes()).collect()
    };
    chunk::put(&mut payload, id::INDX, if vertices <= 1 << 16 { 2 } else { 4 }, &index_bytes);
    let mut ranges = Vec::with_capacity(12 * g.material_ranges.len());
    for r in &g.material_ranges {
        for x in [r.material, r.first_index, r.index_count] {
            ranges.extend_from_slice(&x.to_le_bytes());
        }
    }
    chunk::put(&mut payload, id::MATR, 0, &ranges);
    if let Some((shift, clusters)) = &g.clusters {
        let mut table = Vec::with_capacity(16 * clusters.len());
        for c in clusters {
            table.extend(c.axis.iter().flat_map(|x| x.to_le_bytes()));
            table.extend_from_slice(&c.half_angle.to_le_bytes());
            table.extend_from_slice(&c.faces.to_le_bytes());
            table.extend(c.center.iter().flat_map(|x| x.to_le_bytes()));
            table.extend_from_slice(&c.radius.to_le_bytes());
        }
        chunk::put(&mut payload, id::CLUS, *shift, &table);
    }
    payload
}

/// Decode the sub-chunks `subs` of a node's `GEOM` payload, checking presence, sizes, ranges and
/// tiling (spec §10).
pub fn decode(ctx: &NodeContext, payload: &[u8], subs: &[Sub]) -> Result<NodeGeometry> {
    let (i, rec) = (ctx.index, ctx.record);
    let at = rec.offset;
    let err = |off: u64, msg: String| Error::at_byte(ctx.path, off, format!("{}: node {i}: {msg}", chunk::name(&id::GEOM, at)));
    let mut found: [Option<&Sub>; 7] = [None; 7];
    let kinds = [id::VPOS, id::VNRM, id::VTEX, id::VCOL, id::INDX, id::MATR, id::CLUS];
    for s in subs {
        if let Some(k) = kinds.iter().position(|&x| x == s.frame.id) {
            if found[k].is_some() {
                return Err(err(s.offset, format!("a second {} chunk", chunk::id_str(&s.frame.id))));
            }
            found[k] = Some(s);
        }
    }
    let attrs = ctx.header.attributes;
    let wanted = [true, attrs.normals, attrs.uvs, attrs.colors, true, true, rec.level == 0];
    for k in 0..7 {
        if found[k].is_some() != wanted[k] {
            let what = if wanted[k] { "lacks" } else { "should not have" };
            return Err(err(at, format!("{what} a {} chunk", chunk::id_str(&kinds[k]))));
        }
    }
    let v = rec.vertices as u64;
    let data = |s: &Sub, per: u64, what: &str| -> Result<&[u8]> {
        if s.frame.size != v * per {
            return Err(err(
                s.offset + 8,
                format!("{} holds {} bytes; {v} vertices need {} for {what}", chunk::id_str(&s.frame.id), s.frame.size, v * per),
            ));
        }
        Ok(&payload[s.start..s.end])
    };
    let mut g = NodeGeometry::default();
    if let Some(s) = found[0] {
        let width = s.frame.flags as u64;
        if width != 2 && width != 3 {
            return Err(err(s.offset + 4, format!("position width {width}; must be 2 or 3")));
        }
        if s.frame.size != 12 + v * 3 * width {
            return Err(err(
                s.offset + 8,
                format!("VPOS holds {} bytes; {v} vertices need {} for positions", s.frame.size, 12 + v * 3 * width),
            ));
        }
        let b = &payload[s.start..s.end];
        let base = [LE::read_u32(&b[0..4]), LE::read_u32(&b[4..8]), LE::read_u32(&b[8..12])];
        let grid = ctx.header.grid;
        let offsets: Vec<u32> = b[12..].chunks_exact(width as usize).map(|c| LE::read_uint(c, c.len()) as u32).collect();
        g.positions.reserve(v as usize);
        for (k, q) in offsets.chunks_exact(3).enumerate() {
            let p: [u64; 3] = std::array::from_fn(|a| base[a] as u64 + q[a] as u64);
            if p.iter().any(|&x| x > grid.last() as u64) {
                return Err(err(s.payload_offset() + 12 + 3 * width * k as u64, format!("vertex {k} lies off the {}-bit grid", grid.bits)));
            }
            g.positions.push(grid.decode(p.map(|x| x as u32)));
        }
    }
    if let Some(s) = found[1] {
        g.normals =
            data(s, 4, "normals")?.chunks_exact(4).map(|c| octa::decode([LE::read_i16(&c[0..2]), LE::read_i16(&c[2..4])])).collect();
    }
    if let Some(s) = found[2] {
        g.uvs = data(s, 8, "UVs")?.chunks_exact(8).map(|c| Vec2::new(LE::read_f32(&c[0..4]), LE::read_f32(&c[4..8]))).collect();
    }
    if let Some(s) = found[3] {
        g.colors = data(s, 4, "colors")?.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
    }
    let n_idx = 3 * rec.faces as u64;
    if let Some(s) = found[4] {
        let width = s.frame.flags as u64;
        if width != 2 && width != 4 {
            return Err(err(s.offset + 4, format!("index width {width}; must be 2 or 4")));
        }
        if s.frame.size != n_idx * width {
            return Err(err(s.offset + 8, format!("INDX holds {} bytes; {} faces need {}", s.frame.size, rec.faces, n_idx * width)));
        }
        let b = &payload[s.start..s.end];
        g.indices = if width == 2 {
            b.chunks_exact(2).map(|c| LE::read_u16(c) as u32).collect()
        } else {
            b.chunks_exact(4).map(LE::read_u32).collect()
        };
        if let Some(k) = g.indices.iter().position(|&x| x as u64 >= v) {
            return Err(err(s.payload_offset() + width * k as u64, format!("index {k} is {} of {v} vertices", g.indices[k])));
        }
    }
    if let Some(s) = found[5] {
        if s.frame.size % RANGE_RECORD_BYTES != 0 {
            return Err(err(s.offset + 8, format!("MATR size {} is not a multiple of {RANGE_RECORD_BYTES}", s.frame.size)));
        }
        let mut next = 0u64;
        for (k, c) in payload[s.start..s.end].chunks_exact(12).enumerate() {
            let r = MaterialRange {
                material: LE::read_u32(&c[0..4]),
                first_index: LE::read_u32(&c[4..8]),
                index_count: LE::read_u32(&c[8..12]),
            };
            if r.first_index as u64 != next || r.index_count == 0 || r.index_count % 3 != 0 || r.material >= ctx.header.materials {
                return Err(err(
                    s.payload_offset() + 12 * k as u64,
                    format!("material range {k} ({}, {}, {}) does not continue at index {next} with a whole number of faces of a known material", r.material, r.first_index, r.index_count),
                ));
            }
            next += r.index_count as u64;
            g.material_ranges.push(r);
        }
        if next != n_idx {
            return Err(err(s.offset, format!("material ranges cover {next} of {n_idx} indices")));
        }
    }
    if let Some(s) = found[6] {
        if s.frame.size % CLUSTER_RECORD_BYTES != 0 {
            return Err(err(s.offset + 8, format!("CLUS size {} is not a multiple of {CLUSTER_RECORD_BYTES}", s.frame.size)));
        }
        let grid = ctx.header.grid;
        let shift = s.frame.flags;
        if shift > grid.bits {
            return Err(err(s.offset + 4, format!("CLUS shift {shift} exceeds the {} grid bits", grid.bits)));
        }
        let base = found[0].map_or([0; 3], |p| {
            let b = &payload[p.start..p.end];
            [LE::read_u32(&b[0..4]), LE::read_u32(&b[4..8]), LE::read_u32(&b[8..12])]
        });
        let mut next = 0u64;
        for (k, c) in payload[s.start..s.end].chunks_exact(16).enumerate() {
            let u = |o: usize| LE::read_u16(&c[o..o + 2]);
            let face_count = u(6) as u32;
            let center: [u64; 3] = std::array::from_fn(|a| base[a] as u64 + ((u(8 + 2 * a) as u64) << shift));
            let rec_at = s.payload_offset() + 16 * k as u64;
            if face_count == 0 {
                return Err(err(rec_at, format!("cluster {k} has no faces")));
            }
            if center.iter().any(|&x| x > grid.last() as u64) {
                return Err(err(rec_at, format!("cluster {k}'s center lies off the {}-bit grid", grid.bits)));
            }
            g.clusters.push(Cluster {
                cone: Cone { axis: octa::decode([u(0) as i16, u(2) as i16]), half_angle: angle_decode(u(4)) },
                center: grid.decode(center.map(|x| x as u32)),
                radius: grid.length(radius_decode(u(14))),
                first_face: next as u32,
                face_count,
            });
            next += face_count as u64;
        }
        if next != rec.faces as u64 {
            return Err(err(s.offset, format!("clusters cover {next} of {} faces", rec.faces)));
        }
    }
    Ok(g)
}
