//! Write a group hierarchy and its level meshes as a strata file (format-spec/strata-v2.md).
//!
//! Nodes are numbered breadth-first from the top level, children of a node consecutive, and their
//! geometry chunks follow the skeleton in that order, so a prefix of the file is a coarse model.
//! Bounds and cones are the hierarchy's, widened to cover each node's own (simplified) geometry and
//! its descendants, so that culling a node by them is safe for everything below it. Positions are
//! stored on one global grid; bounds, cones and errors are computed on the quantized positions and
//! rounded outward when stored.

use super::chunk;
use super::{
    angle_code, angle_decode, id, octa, pack, radius_code, radius_decode, Attributes, Grid, Header, LevelRecord, NodeRecord, GRID_BITS, MAGIC,
    MAJOR, MAX_TOOL_BYTES, MINOR, NO_PARENT,
};
use crate::atomic::AtomicFile;
use crate::cone::Cone;
use crate::error::{Error, Result};
use crate::hierarchy::{self, Hierarchy, HierarchyParams, Lists};
use crate::levels::LevelMeshes;
use crate::mesh::{triangle_cross, Material, Mesh};
use glam::Vec3;
use rustc_hash::FxHashMap;
use std::collections::HashMap;
use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

/// What the writer records besides the hierarchy and the meshes.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteOptions {
    /// Metres per model unit, 0 when unknown (glTF is in metres; OBJ and PLY do not say).
    pub metres_per_unit: f64,
    /// Parameters the hierarchy was built with.
    pub params: HierarchyParams,
    /// Target ratio of faces between a level and the one below.
    pub level_ratio: f32,
    /// Name and version of the writing program, at most 1024 bytes.
    pub tool: String,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            metres_per_unit: 0.0,
            params: HierarchyParams::default(),
            level_ratio: 0.5,
            tool: format!("strata {}", env!("CARGO_PKG_VERSION")),
        }
    }
}

/// What one level of the written file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct LevelSummary {
    pub level: u32,
    pub nodes: u32,
    pub faces: u64,
    pub vertices: u64,
    /// Bytes of the level's geometry chunks.
    pub bytes: u64,
}

/// What was written.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct WriteSummary {
    pub file_bytes: u64,
    /// Bytes a reader reads to open the file: prologue, `HEAD` and `SKEL`.
    pub skeleton_bytes: u64,
    pub input_faces: u64,
    pub nodes: u32,
    pub clusters: u32,
    /// Finest level first.
    pub levels: Vec<LevelSummary>,
}

impl WriteSummary {
    /// File bytes per face of the input mesh.
    pub fn bytes_per_face(&self) -> f64 {
        self.file_bytes as f64 / self.input_faces.max(1) as f64
    }
}

/// Write the file for hierarchy `h` and level meshes `lv` to `path`, all or nothing (a temporary
/// file renamed on success). Inconsistent inputs are an error naming the level and group.
pub fn write(path: &Path, h: &Hierarchy, lv: &LevelMeshes, opts: &WriteOptions) -> Result<WriteSummary> {
    let mut file = AtomicFile::create(path)?;
    let summary = write_named(file.writer(), path, h, lv, opts)?;
    file.commit()?;
    Ok(summary)
}

/// [`write`] into any seekable writer, from its current position (which becomes file offset 0).
pub fn write_to<W: Write + Seek>(w: &mut W, h: &Hierarchy, lv: &LevelMeshes, opts: &WriteOptions) -> Result<WriteSummary> {
    write_named(w, Path::new("<output>"), h, lv, opts)
}

fn write_named<W: Write + Seek>(
    w: &mut W,
    path: &Path,
    h: &Hierarchy,
    lv: &LevelMeshes,
    opts: &WriteOptions,
) -> Result<WriteSummary> {
    let io = |e: std::io::Error| Error::io(path, e);
    let bad = |msg: String| Error::invalid(path, None, msg);
    let attributes = check_inputs(h, lv, opts).map_err(bad)?;
    let materials = material_table(&lv.levels[0].mesh);
    let plan = plan(h, lv);
    let grid = model_grid(lv);
    let mut quant = Vec::with_capacity(lv.levels.len());
    quant.push(Quantized::distinct(&grid, &lv.levels[0].mesh).map_err(bad)?);
    quant.extend(lv.levels[1..].iter().map(|l| Quantized::new(&grid, &l.mesh)));
    let (mut records, codes) = bounds(h, lv, &plan, &grid, &quant).map_err(bad)?;
    let (neighbor_counts, neighbors) = neighbor_lists(h, &plan);
    for (n, (r, &c)) in records.iter_mut().zip(&neighbor_counts).enumerate() {
        r.neighbor_count = c;
        if c > u16::MAX as u32 || r.child_count > u16::MAX as u32 {
            let (l, g) = plan.nodes[n];
            return Err(bad(format!("level {l} group {g}: {c} neighbours and {} children; at most {} each", r.child_count, u16::MAX)));
        }
    }

    let nl = plan.level_first.len();
    let mut header = Header {
        major: MAJOR,
        minor: MINOR,
        file_size: 0,
        metres_per_unit: opts.metres_per_unit,
        min: Vec3::ZERO,
        max: Vec3::ZERO,
        attributes,
        levels: nl as u32,
        nodes: records.len() as u32,
        materials: materials.len() as u32,
        input_vertices: lv.levels[0].mesh.vertex_count() as u64,
        input_faces: lv.levels[0].mesh.face_count() as u64,
        clusters: 0,
        params: opts.params,
        grid,
        level_ratio: opts.level_ratio,
        tool: opts.tool.clone(),
    };
    let mut levels = vec![LevelRecord::default(); nl];
    for (l, rec) in levels.iter_mut().enumerate() {
        rec.first_node = plan.level_first[l];
        rec.nodes = plan.level_nodes[l];
    }

    let base = w.stream_position().map_err(io)?;
    let mut prologue = Vec::with_capacity(16);
    prologue.extend_from_slice(&MAGIC);
    prologue.extend_from_slice(&MAJOR.to_le_bytes());
    prologue.extend_from_slice(&MINOR.to_le_bytes());
    let crc = chunk::crc32(&prologue);
    prologue.extend_from_slice(&crc.to_le_bytes());
    w.write_all(&prologue).map_err(io)?;
    let reserved = head_chunk(&header).len() + skel_chunk(&levels, &records, &codes, &neighbors, &materials).len();
    w.write_all(&vec![0u8; reserved]).map_err(io)?;

    let mut pos = prologue.len() as u64 + reserved as u64;
    let mut buf = Vec::new();
    for (n, &(l, g)) in plan.nodes.iter().enumerate() {
        let mesh = &lv.levels[l as usize].mesh;
        let faces = plan.faces[l as usize].get(g as usize);
        if faces.len() > (u32::MAX / 3) as usize {
            return Err(bad(format!("level {l} group {g}: {} faces in one node", faces.len())));
        }
        let clusters = (l == 0).then_some(&h.clusters);
        buf.clear();
        let enc = encode_node(mesh, &quant[l as usize], &grid, faces, clusters, attributes, &mut buf).map_err(bad)?;
        let span = enc.span;
        let rec = &mut records[n];
        rec.offset = pos;
        rec.size = u32::try_from(span).map_err(|_| bad(format!("level {l} group {g}: geometry of {span} bytes exceeds 4 GiB")))?;
        rec.crc = chunk::crc32(&buf[16..span as usize - 4]);
        rec.vertices = enc.vertices;
        rec.faces = faces.len() as u32;
        header.clusters += enc.clusters;
        let level = &mut levels[l as usize];
        level.faces += faces.len() as u64;
        level.vertices += enc.vertices as u64;
        level.bytes += buf.len() as u64;
        w.write_all(&buf).map_err(io)?;
        pos += buf.len() as u64;
    }

    header.file_size = pos;
    let top = &codes[..plan.level_nodes[nl - 1] as usize];
    header.min = top.iter().fold(Vec3::splat(f32::MAX), |m, c| m.min(grid.decode(c.min)));
    header.max = top.iter().fold(Vec3::splat(f32::MIN), |m, c| m.max(grid.decode(c.max)));
    let mut skeleton = head_chunk(&header);
    skeleton.extend(skel_chunk(&levels, &records, &codes, &neighbors, &materials));
    if skeleton.len() != reserved {
        return Err(bad(format!("internal error: skeleton of {} bytes in {reserved} reserved", skeleton.len())));
    }
    w.seek(SeekFrom::Start(base + prologue.len() as u64)).map_err(io)?;
    w.write_all(&skeleton).map_err(io)?;
    w.seek(SeekFrom::Start(base + pos)).map_err(io)?;
    w.flush().map_err(io)?;

    Ok(WriteSummary {
        file_bytes: pos,
        skeleton_bytes: prologue.len() as u64 + reserved as u64,
        input_faces: header.input_faces,
        nodes: header.nodes,
        clusters: header.clusters,
        levels: levels
            .iter()
            .enumerate()
            .map(|(l, r)| LevelSummary { level: l as u32, nodes: r.nodes, faces: r.faces, vertices: r.vertices, bytes: r.bytes })
            .collect(),
    })
}

/// The material table: level 0's, or one default material if it has none.
fn material_table(mesh: &Mesh) -> Vec<Material> {
    if mesh.materials.is_empty() {
        vec![Material::default()]
    } else {
        mesh.materials.clone()
    }
}

fn material_of(mesh: &Mesh, f: usize) -> u32 {
    mesh.face_materials.get(f).copied().unwrap_or(0)
}

/// Check what the writer relies on; return the corner attributes every level carries.
fn check_inputs(h: &Hierarchy, lv: &LevelMeshes, opts: &WriteOptions) -> std::result::Result<Attributes, String> {
    if opts.tool.len() as u64 > MAX_TOOL_BYTES {
        return Err(format!("tool string of {} bytes exceeds {MAX_TOOL_BYTES}", opts.tool.len()));
    }
    let nl = h.levels.len();
    if nl == 0 || lv.levels.len() != nl {
        return Err(format!("{nl} hierarchy levels but {} level meshes; need the same number, at least 1", lv.levels.len()));
    }
    if nl >= u32::MAX as usize {
        return Err(format!("{nl} levels"));
    }
    let m0 = &lv.levels[0].mesh;
    if m0.face_count() == 0 {
        return Err("nothing to write: level 0 has no faces".into());
    }
    if h.clusters.face_group.len() != m0.face_count() {
        return Err(format!("clusters label {} faces but level 0 has {}", h.clusters.face_group.len(), m0.face_count()));
    }
    if let Some(f) = h.clusters.face_group.iter().position(|&c| c as usize >= h.clusters.groups.len()) {
        return Err(format!("face {f} is in cluster {} of {}", h.clusters.face_group[f], h.clusters.groups.len()));
    }
    let has = |m: &Mesh| Attributes { normals: !m.normals.is_empty(), uvs: !m.uvs.is_empty(), colors: !m.colors.is_empty() };
    let attributes = has(m0);
    let materials = material_table(m0).len();
    let mut total_nodes = 0usize;
    for (l, (hl, ml)) in h.levels.iter().zip(&lv.levels).enumerate() {
        let m = &ml.mesh;
        let nf = m.face_count();
        let ng = hl.groups.len();
        total_nodes += ng;
        let ctx = |msg: String| format!("level {l}: {msg}");
        if has(m) != attributes {
            return Err(ctx(format!("corner attributes {:?} differ from level 0's {attributes:?}", has(m))));
        }
        for (name, len) in [("normals", m.normals.len()), ("uvs", m.uvs.len()), ("colors", m.colors.len())] {
            if len != 0 && len != 3 * nf {
                return Err(ctx(format!("{len} {name} for {nf} faces")));
            }
        }
        if !m.face_materials.is_empty() && m.face_materials.len() != nf {
            return Err(ctx(format!("{} face materials for {nf} faces", m.face_materials.len())));
        }
        if let Some(f) = (0..nf).find(|&f| material_of(m, f) as usize >= materials) {
            return Err(ctx(format!("face {f} has material {} of {materials}", material_of(m, f))));
        }
        if let Some(f) = m.triangles.iter().position(|t| t.iter().any(|&v| v as usize >= m.vertex_count())) {
            return Err(ctx(format!("face {f} indexes past {} vertices", m.vertex_count())));
        }
        if ml.face_group.len() != nf {
            return Err(ctx(format!("{} face groups for {nf} faces", ml.face_group.len())));
        }
        if let Some(f) = ml.face_group.iter().position(|&g| g as usize >= ng) {
            return Err(ctx(format!("face {f} is in group {} of {ng}", ml.face_group[f])));
        }
        if ml.group_error.len() != ng {
            return Err(ctx(format!("{} group errors for {ng} groups", ml.group_error.len())));
        }
        if let Some(g) = ml.group_error.iter().position(|e| !e.is_finite()) {
            return Err(ctx(format!("group {g} has error {}", ml.group_error[g])));
        }
        if hl.parent.len() != ng {
            return Err(ctx(format!("{} parents for {ng} groups", hl.parent.len())));
        }
        let above = h.levels.get(l + 1).map(|a| a.groups.len());
        for (g, &p) in hl.parent.iter().enumerate() {
            let ok = match above {
                Some(na) => (p as usize) < na,
                None => p == hierarchy::NO_PARENT,
            };
            if !ok {
                return Err(ctx(format!("group {g} has parent {p}")));
            }
        }
        if hl.neighbors.len() != ng || hl.neighbors.items.iter().any(|&x| x as usize >= ng) {
            return Err(ctx("neighbour lists do not match the groups".into()));
        }
        if let Some(g) = hl.groups.iter().position(|gi| !(gi.center.is_finite() && gi.radius.is_finite() && gi.cone.axis.is_finite())) {
            return Err(ctx(format!("group {g} has non-finite bounds or cone")));
        }
    }
    if total_nodes >= NO_PARENT as usize {
        return Err(format!("{total_nodes} nodes"));
    }
    Ok(attributes)
}

/// The node numbering and each group's faces.
struct Plan {
    /// (level, group) of each node, in file order.
    nodes: Vec<(u32, u32)>,
    /// Node of each group, per level.
    node_of: Vec<Vec<u32>>,
    /// Per level (finest first): first node and node count.
    level_first: Vec<u32>,
    level_nodes: Vec<u32>,
    /// Per level: faces of the level mesh in each group.
    faces: Vec<Lists>,
    /// Per node: first child and child count.
    children: Vec<(u32, u32)>,
}

/// Number the nodes breadth-first: the top groups in order, then level by level the children of
/// each node in turn.
fn plan(h: &Hierarchy, lv: &LevelMeshes) -> Plan {
    let nl = h.levels.len();
    let mut nodes: Vec<(u32, u32)> = Vec::new();
    let mut node_of: Vec<Vec<u32>> = h.levels.iter().map(|l| vec![u32::MAX; l.groups.len()]).collect();
    let mut level_first = vec![0u32; nl];
    let mut level_nodes = vec![0u32; nl];
    let mut children: Vec<(u32, u32)> = Vec::new();
    for l in (0..nl).rev() {
        let ng = h.levels[l].groups.len();
        level_first[l] = nodes.len() as u32;
        level_nodes[l] = ng as u32;
        let mut order: Vec<u32> = (0..ng as u32).collect();
        if l + 1 < nl {
            let parent_node = |g: u32| node_of[l + 1][h.levels[l].parent[g as usize] as usize];
            order.sort_by_key(|&g| (parent_node(g), g));
        }
        for &g in &order {
            node_of[l][g as usize] = nodes.len() as u32;
            nodes.push((l as u32, g));
        }
        if l + 1 < nl {
            let above = level_first[l + 1] as usize..(level_first[l + 1] + level_nodes[l + 1]) as usize;
            let mut ranges = vec![(0u32, 0u32); above.len()];
            for (i, &g) in order.iter().enumerate() {
                let p = node_of[l + 1][h.levels[l].parent[g as usize] as usize] as usize - above.start;
                if ranges[p].1 == 0 {
                    ranges[p].0 = level_first[l] + i as u32;
                }
                ranges[p].1 += 1;
            }
            children[above].copy_from_slice(&ranges);
        }
        children.resize(nodes.len(), (0, 0));
    }
    let faces = lv.levels.iter().zip(&h.levels).map(|(m, hl)| Lists::from_labels(&m.face_group, hl.groups.len())).collect();
    Plan { nodes, node_of, level_first, level_nodes, faces, children }
}

/// Angle between two directions, in f64.
fn angle(a: Vec3, b: Vec3) -> f64 {
    let (a, b) = (a.as_dvec3(), b.as_dvec3());
    a.cross(b).length().atan2(a.dot(b))
}

/// The grid of the file: the bounds of every level's positions, [`GRID_BITS`] bits.
fn model_grid(lv: &LevelMeshes) -> Grid {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for l in &lv.levels {
        for p in &l.mesh.positions {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    if lo.cmpgt(hi).any() {
        (lo, hi) = (Vec3::ZERO, Vec3::ZERO);
    }
    Grid::fit(lo, hi, GRID_BITS)
}

/// A level mesh's positions on the grid: grid points and the positions they decode to.
struct Quantized {
    points: Vec<[u32; 3]>,
    positions: Vec<Vec3>,
    /// Vertices moved off their nearest grid point to stay distinct, and how far each now lies from
    /// its input position (model units); empty for most meshes.
    moved: FxHashMap<u32, f32>,
}

/// Largest cube radius, in grid steps, searched for a free grid point for a vertex whose nearest
/// one is taken.
const MAX_NUDGE_STEPS: i64 = 8;

impl Quantized {
    /// Every position on its nearest grid point.
    fn new(grid: &Grid, mesh: &Mesh) -> Quantized {
        let points: Vec<[u32; 3]> = mesh.positions.iter().map(|&p| grid.encode(p)).collect();
        let positions = points.iter().map(|&g| grid.decode(g)).collect();
        Quantized { points, positions, moved: FxHashMap::default() }
    }

    /// Level 0 (spec §5.1): distinct input positions decode to distinct positions, so that the input's
    /// faces stay distinct. A vertex whose nearest grid point decodes to a position an earlier
    /// vertex (in vertex order) already holds goes to the free grid point nearest its input position
    /// in the smallest cube around its nearest grid point that has one.
    fn distinct(grid: &Grid, mesh: &Mesh) -> std::result::Result<Quantized, String> {
        let mut q = Quantized::new(grid, mesh);
        let key = |p: Vec3| (p + Vec3::ZERO).to_array().map(f32::to_bits);
        let mut holder: FxHashMap<[u32; 3], u32> = FxHashMap::with_capacity_and_hasher(q.points.len(), Default::default());
        for v in 0..q.points.len() {
            let first = *holder.entry(key(q.positions[v])).or_insert(v as u32);
            if first == v as u32 || mesh.positions[first as usize] == mesh.positions[v] {
                continue;
            }
            let input = mesh.positions[v].as_dvec3();
            let mut best: Option<(f64, [u32; 3], Vec3)> = None;
            for r in 1..=MAX_NUDGE_STEPS {
                for d in (-r..=r).flat_map(|x| (-r..=r).flat_map(move |y| (-r..=r).map(move |z| [x, y, z]))) {
                    if d.iter().all(|c| c.abs() < r) {
                        continue;
                    }
                    let g: [i64; 3] = std::array::from_fn(|a| q.points[v][a] as i64 + d[a]);
                    if g.iter().any(|&c| c < 0 || c > grid.last() as i64) {
                        continue;
                    }
                    let g = g.map(|c| c as u32);
                    let p = grid.decode(g);
                    let distance = p.as_dvec3().distance(input);
                    if !holder.contains_key(&key(p)) && best.is_none_or(|b| distance < b.0) {
                        best = Some((distance, g, p));
                    }
                }
                if best.is_some() {
                    break;
                }
            }
            let Some((distance, g, p)) = best else {
                return Err(format!("level 0 vertex {v}: no free grid point within {MAX_NUDGE_STEPS} steps keeps it apart from vertex {first}"));
            };
            holder.insert(key(p), v as u32);
            q.points[v] = g;
            q.positions[v] = p;
            q.moved.insert(v as u32, round_up(distance));
        }
        Ok(q)
    }

    /// The quantization bound of `faces` of `mesh`: [`Grid::error`], or the distance of a moved
    /// vertex from its input position where larger.
    fn error(&self, grid: &Grid, mesh: &Mesh, faces: &[u32]) -> f32 {
        let mut e = grid.error();
        if !self.moved.is_empty() {
            for &f in faces {
                for v in mesh.triangles[f as usize] {
                    e = e.max(self.moved.get(&v).copied().unwrap_or(0.0));
                }
            }
        }
        e
    }
}

/// `x` as the smallest f32 not below it.
fn round_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x {
        f.next_up()
    } else {
        f
    }
}

/// A node's stored codes: box corners and sphere center on the grid, cone and radius codes.
#[derive(Clone, Copy, Default)]
struct Codes {
    min: [u32; 3],
    max: [u32; 3],
    center: [u32; 3],
    axis: [i16; 2],
    half_angle: u16,
    radius: u16,
}

/// The cone stored for a cone around `axis` that must reach `need(decoded axis)` radians: the axis
/// quantized, the angle rounded up.
fn store_cone(axis: Vec3, need: impl Fn(Vec3) -> f64) -> ([i16; 2], u16, Cone) {
    let code = octa::encode(axis);
    let decoded = octa::decode(code);
    let k = angle_code(need(decoded));
    (code, k, Cone { axis: decoded, half_angle: angle_decode(k) })
}

/// The radius code covering `needed` model units, and its decoded radius.
fn store_radius(grid: &Grid, needed: f64) -> (u16, f32) {
    let k = radius_code(needed / grid.step * (1.0 + 1e-6));
    (k, grid.length(radius_decode(k)))
}

/// Node records with structure, bounds, cones and errors, and their stored codes; geometry fields
/// are filled while writing. Bottom-up, so each node's cone and bounds cover its descendants', all
/// computed on the quantized positions and rounded outward.
fn bounds(h: &Hierarchy, lv: &LevelMeshes, plan: &Plan, grid: &Grid, quant: &[Quantized]) -> std::result::Result<(Vec<NodeRecord>, Vec<Codes>), String> {
    let mut records: Vec<NodeRecord> = Vec::with_capacity(plan.nodes.len());
    for (n, &(l, _)) in plan.nodes.iter().enumerate() {
        let (first_child, child_count) = plan.children[n];
        records.push(NodeRecord {
            level: l,
            parent: NO_PARENT,
            first_child,
            child_count,
            neighbor_first: 0,
            neighbor_count: 0,
            cone: Cone { axis: Vec3::Z, half_angle: 0.0 },
            center: Vec3::ZERO,
            radius: 0.0,
            error: 0.0,
            faces: 0,
            vertices: 0,
            offset: 0,
            size: 0,
            crc: 0,
        });
    }
    let mut codes = vec![Codes::default(); plan.nodes.len()];
    for (l, (hl, q)) in h.levels.iter().zip(quant).enumerate() {
        let mesh = &lv.levels[l].mesh;
        for (g, info) in hl.groups.iter().enumerate() {
            let n = plan.node_of[l][g] as usize;
            if !(info.min.is_finite() && info.max.is_finite() && info.center.is_finite() && info.radius.is_finite()) {
                return Err(format!("level {l} group {g}: bounds are not finite"));
            }
            let (first, count) = plan.children[n];
            let faces = plan.faces[l].get(g);
            let (mut lo, mut hi) = (grid.bound(info.min, false), grid.bound(info.max, true));
            let mut grow = |p: [u32; 3]| {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            };
            for &f in faces {
                for &v in &mesh.triangles[f as usize] {
                    grow(q.points[v as usize]);
                }
            }
            for c in first..first + count {
                grow(codes[c as usize].min);
                grow(codes[c as usize].max);
            }

            let center = grid.encode(info.center);
            let dc = grid.decode(center).as_dvec3();
            let mut needed = info.radius as f64 + dc.distance(info.center.as_dvec3());
            for &f in faces {
                for &v in &mesh.triangles[f as usize] {
                    needed = needed.max(dc.distance(q.positions[v as usize].as_dvec3()));
                }
            }
            let mut error = lv.levels[l].group_error[g] + q.error(grid, mesh, faces);
            for c in first..first + count {
                let child = records[c as usize];
                needed = needed.max(dc.distance(child.center.as_dvec3()) + child.radius as f64);
                error = error.max(child.error);
                records[c as usize].parent = n as u32;
            }
            let (radius_code, radius) = store_radius(grid, needed);

            let normals: Vec<Vec3> = faces
                .iter()
                .map(|&f| triangle_cross(&q.positions, &mesh.triangles[f as usize]))
                .filter(|c| c.length_squared() > 0.0)
                .map(|c| c.normalize().as_vec3())
                .collect();
            let axis = info.cone.axis.normalize_or(Vec3::Z);
            let (axis_code, angle, cone) = store_cone(axis, |d| {
                let mut need = info.cone.half_angle as f64 + angle(axis, d);
                for &nrm in &normals {
                    need = need.max(angle(d, nrm));
                }
                for c in first..first + count {
                    let ch = records[c as usize].cone;
                    need = need.max(angle(d, ch.axis) + ch.half_angle as f64);
                }
                need
            });
            codes[n] = Codes { min: lo, max: hi, center, axis: axis_code, half_angle: angle, radius: radius_code };
            let r = &mut records[n];
            r.cone = cone;
            r.center = grid.decode(center);
            r.radius = radius;
            r.error = error;
        }
    }
    Ok((records, codes))
}

/// Per node, its same-level neighbours as node numbers, ascending; and all lists end to end.
fn neighbor_lists(h: &Hierarchy, plan: &Plan) -> (Vec<u32>, Vec<u32>) {
    let mut counts = Vec::with_capacity(plan.nodes.len());
    let mut items = Vec::new();
    for &(l, g) in &plan.nodes {
        let l = l as usize;
        let start = items.len();
        let list = h.levels[l].neighbors.get(g as usize);
        items.extend(list.iter().filter(|&&x| x != g).map(|&x| plan.node_of[l][x as usize]));
        items[start..].sort_unstable();
        let mut kept = start;
        for i in start..items.len() {
            if kept == start || items[i] != items[kept - 1] {
                items[kept] = items[i];
                kept += 1;
            }
        }
        items.truncate(kept);
        counts.push((items.len() - start) as u32);
    }
    (counts, items)
}

/// What encoding a node produced.
struct Encoded {
    /// Bytes of the chunk from ID to CRC.
    span: u64,
    vertices: u32,
    clusters: u32,
}

/// Append the `GEOM` chunk of `faces` of `mesh` to `out` (at an aligned position). Faces are
/// ordered by culling cluster (level 0), then material; vertices are deduplicated corners (grid
/// point and attributes) in order of first use. Cluster cones and spheres are the hierarchy's,
/// widened to cover the quantized faces and rounded outward.
fn encode_node(
    mesh: &Mesh,
    q: &Quantized,
    grid: &Grid,
    faces: &[u32],
    clusters: Option<&hierarchy::Level>,
    attrs: Attributes,
    out: &mut Vec<u8>,
) -> std::result::Result<Encoded, String> {
    let cluster_of = |f: u32| clusters.map_or(0, |c| c.face_group[f as usize]);
    let mut order: Vec<u32> = faces.to_vec();
    order.sort_by_key(|&f| (cluster_of(f), material_of(mesh, f as usize), f));

    type Key = ([u32; 3], [i16; 2], [u32; 2], [u8; 4]);
    let mut index_of: HashMap<Key, u32> = HashMap::with_capacity(order.len());
    let (mut points, mut nrm, mut tex, mut col) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut indices: Vec<u32> = Vec::with_capacity(order.len() * 3);
    for &f in &order {
        for k in 0..3 {
            let corner = 3 * f as usize + k;
            let g = q.points[mesh.triangles[f as usize][k] as usize];
            let n = if attrs.normals { octa::encode(mesh.normals[corner]) } else { [0; 2] };
            let uv = if attrs.uvs { mesh.uvs[corner].to_array().map(f32::to_bits) } else { [0; 2] };
            let c = if attrs.colors { mesh.colors[corner] } else { [0; 4] };
            let next = index_of.len() as u32;
            let i = *index_of.entry((g, n, uv, c)).or_insert_with(|| {
                points.push(g);
                nrm.extend(n.iter().flat_map(|x| x.to_le_bytes()));
                tex.extend(uv.iter().flat_map(|x| x.to_le_bytes()));
                col.extend_from_slice(&c);
                next
            });
            indices.push(i);
        }
    }
    let vertices = index_of.len() as u32;

    let base = points.iter().fold(if points.is_empty() { [0; 3] } else { [u32::MAX; 3] }, |b, p| [b[0].min(p[0]), b[1].min(p[1]), b[2].min(p[2])]);
    let span = points.iter().flat_map(|p| (0..3).map(move |k| p[k] - base[k])).max().unwrap_or(0);
    let width: u32 = if span <= u16::MAX as u32 { 2 } else { 3 };
    let mut pos: Vec<u8> = base.iter().flat_map(|x| x.to_le_bytes()).collect();
    for p in &points {
        for k in 0..3 {
            pos.extend_from_slice(&(p[k] - base[k]).to_le_bytes()[..width as usize]);
        }
    }

    let mut payload = Vec::new();
    chunk::put(&mut payload, id::VPOS, width, &pos);
    if attrs.normals {
        chunk::put(&mut payload, id::VNRM, 0, &nrm);
    }
    if attrs.uvs {
        chunk::put(&mut payload, id::VTEX, 0, &tex);
    }
    if attrs.colors {
        chunk::put(&mut payload, id::VCOL, 0, &col);
    }
    let index_bytes: Vec<u8> = if vertices <= 1 << 16 {
        indices.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect()
    } else {
        indices.iter().flat_map(|&i| i.to_le_bytes()).collect()
    };
    chunk::put(&mut payload, id::INDX, if vertices <= 1 << 16 { 2 } else { 4 }, &index_bytes);

    let mut ranges = Vec::new();
    let mut first = 0u32;
    for run in order.chunk_by(|&a, &b| material_of(mesh, a as usize) == material_of(mesh, b as usize)) {
        ranges.extend_from_slice(&material_of(mesh, run[0] as usize).to_le_bytes());
        ranges.extend_from_slice(&(3 * first).to_le_bytes());
        ranges.extend_from_slice(&(3 * run.len() as u32).to_le_bytes());
        first += run.len() as u32;
    }
    chunk::put(&mut payload, id::MATR, 0, &ranges);

    let mut cluster_count = 0;
    if let Some(cl) = clusters {
        let shift = (0..=grid.bits).find(|&s| span >> s <= u16::MAX as u32).unwrap_or(grid.bits);
        let mut table = Vec::new();
        for run in order.chunk_by(|&a, &b| cluster_of(a) == cluster_of(b)) {
            let g = &cl.groups[cluster_of(run[0]) as usize];
            if !(g.center.is_finite() && g.radius.is_finite()) {
                return Err(format!("cluster {}: bounds are not finite", cluster_of(run[0])));
            }
            let target = grid.encode(g.center);
            let c: [u32; 3] = std::array::from_fn(|k| (target[k].saturating_sub(base[k]).min(span) >> shift).min(u16::MAX as u32));
            let dc = grid.decode(std::array::from_fn(|k| base[k] + (c[k] << shift))).as_dvec3();
            let mut needed = g.radius as f64 + dc.distance(g.center.as_dvec3());
            let mut normals = Vec::new();
            for &f in run {
                let t = &mesh.triangles[f as usize];
                for &v in t {
                    needed = needed.max(dc.distance(q.positions[v as usize].as_dvec3()));
                }
                let n = triangle_cross(&q.positions, t);
                if n.length_squared() > 0.0 {
                    normals.push(n.normalize().as_vec3());
                }
            }
            let (radius, _) = store_radius(grid, needed);
            let axis = g.cone.axis.normalize_or(Vec3::Z);
            let (axis_code, half, _) = store_cone(axis, |d| normals.iter().fold(g.cone.half_angle as f64 + angle(axis, d), |m, &n| m.max(angle(d, n))));
            for piece in run.chunks(u16::MAX as usize) {
                table.extend(axis_code.iter().flat_map(|x| x.to_le_bytes()));
                table.extend_from_slice(&half.to_le_bytes());
                table.extend_from_slice(&(piece.len() as u16).to_le_bytes());
                table.extend(c.iter().flat_map(|&x| (x as u16).to_le_bytes()));
                table.extend_from_slice(&radius.to_le_bytes());
                cluster_count += 1;
            }
        }
        chunk::put(&mut payload, id::CLUS, shift, &table);
    }
    chunk::put(out, id::GEOM, 0, &payload);
    Ok(Encoded { span: payload.len() as u64 + chunk::HEADER_BYTES + chunk::TRAILER_BYTES, vertices, clusters: cluster_count })
}

/// The `HEAD` chunk.
fn head_chunk(h: &Header) -> Vec<u8> {
    let mut p = Vec::with_capacity(160);
    p.extend_from_slice(&h.file_size.to_le_bytes());
    p.extend_from_slice(&h.metres_per_unit.to_le_bytes());
    for x in h.min.to_array().into_iter().chain(h.max.to_array()) {
        p.extend_from_slice(&x.to_le_bytes());
    }
    for x in [h.attributes.bits(), h.levels, h.nodes, h.materials] {
        p.extend_from_slice(&x.to_le_bytes());
    }
    p.extend_from_slice(&h.input_vertices.to_le_bytes());
    p.extend_from_slice(&h.input_faces.to_le_bytes());
    p.extend_from_slice(&h.clusters.to_le_bytes());
    let q = &h.params;
    p.extend_from_slice(&q.cluster_faces.to_le_bytes());
    p.extend_from_slice(&q.cluster_angle.to_le_bytes());
    p.extend_from_slice(&q.leaf_faces.to_le_bytes());
    p.extend_from_slice(&q.leaf_angle.to_le_bytes());
    p.extend_from_slice(&q.angle_step.to_le_bytes());
    p.extend_from_slice(&q.growth.to_le_bytes());
    for x in [q.kc, q.ks, q.kn] {
        p.extend_from_slice(&x.to_le_bytes());
    }
    p.extend_from_slice(&(q.top_groups.min(u32::MAX as usize) as u32).to_le_bytes());
    p.extend_from_slice(&h.level_ratio.to_le_bytes());
    for x in h.grid.origin.into_iter().chain([h.grid.step]) {
        p.extend_from_slice(&x.to_le_bytes());
    }
    p.extend_from_slice(&h.grid.bits.to_le_bytes());
    p.extend_from_slice(&(h.tool.len() as u32).to_le_bytes());
    p.extend_from_slice(h.tool.as_bytes());
    let mut out = Vec::with_capacity(p.len() + 32);
    chunk::put(&mut out, id::HEAD, 0, &p);
    out
}

/// The `SKEL` chunk: `LEVL`, `NODE`, `NBRS`, `MATL`.
fn skel_chunk(levels: &[LevelRecord], records: &[NodeRecord], codes: &[Codes], neighbors: &[u32], materials: &[Material]) -> Vec<u8> {
    let mut payload = Vec::new();
    let mut p = Vec::with_capacity(levels.len() * 32);
    for l in levels {
        p.extend_from_slice(&l.first_node.to_le_bytes());
        p.extend_from_slice(&l.nodes.to_le_bytes());
        p.extend_from_slice(&l.faces.to_le_bytes());
        p.extend_from_slice(&l.vertices.to_le_bytes());
        p.extend_from_slice(&l.bytes.to_le_bytes());
    }
    chunk::put(&mut payload, id::LEVL, 0, &p);

    p.clear();
    for (r, c) in records.iter().zip(codes) {
        p.extend_from_slice(&(r.child_count as u16).to_le_bytes());
        p.extend_from_slice(&(r.neighbor_count as u16).to_le_bytes());
        p.extend(c.axis.iter().flat_map(|x| x.to_le_bytes()));
        p.extend_from_slice(&c.half_angle.to_le_bytes());
        p.extend_from_slice(&c.radius.to_le_bytes());
        for g in [c.min, c.max, c.center] {
            p.extend_from_slice(&pack(g).to_le_bytes());
        }
        p.extend_from_slice(&r.error.to_le_bytes());
        for x in [r.faces, r.vertices, r.size, r.crc] {
            p.extend_from_slice(&x.to_le_bytes());
        }
    }
    chunk::put(&mut payload, id::NODE, 0, &p);

    p.clear();
    let width = if levels.iter().all(|l| l.nodes <= 1 << 16) { 2 } else { 4 };
    let mut next = neighbors.iter();
    for r in records {
        let first = levels[r.level as usize].first_node;
        for &x in next.by_ref().take(r.neighbor_count as usize) {
            p.extend_from_slice(&(x - first).to_le_bytes()[..width as usize]);
        }
    }
    chunk::put(&mut payload, id::NBRS, width, &p);

    p.clear();
    for m in materials {
        p.extend_from_slice(&(m.name.len() as u32).to_le_bytes());
        p.extend_from_slice(m.name.as_bytes());
        for x in m.base_color {
            p.extend_from_slice(&x.to_le_bytes());
        }
        let tex = m.texture.as_deref().unwrap_or("");
        p.extend_from_slice(&(tex.len() as u32).to_le_bytes());
        p.extend_from_slice(tex.as_bytes());
    }
    chunk::put(&mut payload, id::MATL, 0, &p);

    let mut out = Vec::with_capacity(payload.len() + 24);
    chunk::put(&mut out, id::SKEL, 0, &payload);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_zero_positions_stay_distinct_within_their_stated_bound() {
        let mesh = crate::fixtures::isosurface(24, 3);
        let (lo, hi) = mesh.bounds().unwrap();
        let grid = Grid::fit(lo, hi, GRID_BITS);
        let plain = Quantized::new(&grid, &mesh);
        let q = Quantized::distinct(&grid, &mesh).unwrap();
        let keys = |q: &Quantized| q.positions.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<std::collections::HashSet<_>>().len();
        assert!(keys(&plain) < mesh.vertex_count(), "the fixture crowds vertices");
        assert_eq!(keys(&q), mesh.vertex_count());
        assert!(!q.moved.is_empty());
        for (v, (&p, &input)) in q.positions.iter().zip(&mesh.positions).enumerate() {
            let bound = q.moved.get(&(v as u32)).map_or(grid.error(), |&d| d.max(grid.error()));
            assert!(p.as_dvec3().distance(input.as_dvec3()) <= bound as f64, "vertex {v}");
            if !q.moved.contains_key(&(v as u32)) {
                assert_eq!(q.points[v], plain.points[v]);
            }
        }
        let all: Vec<u32> = (0..mesh.face_count() as u32).collect();
        assert!(q.error(&grid, &mesh, &all) > grid.error());
    }
}
