//! Writing a DAG as format 4 (format-spec/strata-v4.md): node geometry as format 3 stores it, the
//! node pages with the DAG's groups.
//!
//! Quantization keeps the DAG crack-free: a vertex a level kept from the level below (a group's
//! outer border) takes that level's grid point, and lies on the border of two nodes at both
//! levels, where format 3 keeps vertices on the grid; so both levels decode it to the same
//! position.

use super::{Dag, NONE};
use crate::atomic::AtomicFile;
use crate::bounds;
use crate::derived_normals::DerivedNormals;
use crate::error::{Error, Result};
use crate::format::codes::store_radius;
use crate::format::geom::v3::Lattice;
use crate::format::{Attributes, Grid, GroupIn, NodeIn, Prepared, Preparer, WriteSummary, Writer, MAJOR4, MAX_TOOL_BYTES, NO_PARENT};
use crate::hierarchy;
use crate::levels::{pinned_flags, position_key};
use crate::quantize::{auto_grid_bits, model_grid, Quantized};
use crate::write::{
    attributes_of, check_precision, in_order, lattice_shift, median_edge, node_geometry, uv_density, Encoding, Precision, WriteOptions,
};
use glam::Vec3;
use rustc_hash::{FxHashMap, FxHashSet};
use std::path::Path;

/// Write `dag` to `path` as format 4, atomically (a temporary file renamed when complete).
/// `clusters` is the grouping's culling clusters over the input's faces (level 0's, in input
/// order); `opts` as for the tree's writer, whose encoding must be format 3's.
pub fn write(path: &Path, dag: &Dag, clusters: &hierarchy::Level, opts: &WriteOptions) -> Result<WriteSummary> {
    let mut file = AtomicFile::create(path)?;
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let summary = write_named(file.writer(), path, dag, clusters, opts, Some(dir))?;
    file.commit()?;
    Ok(summary)
}

/// [`write`] into any writer, from its current position; encoded nodes wait in memory.
pub fn write_to<W: std::io::Write>(out: W, dag: &Dag, clusters: &hierarchy::Level, opts: &WriteOptions) -> Result<WriteSummary> {
    write_named(out, Path::new("<output>"), dag, clusters, opts, None)
}

fn write_named<W: std::io::Write>(
    out: W,
    path: &Path,
    dag: &Dag,
    clusters: &hierarchy::Level,
    opts: &WriteOptions,
    spill: Option<&Path>,
) -> Result<WriteSummary> {
    let bad = |msg: String| Error::invalid(path, None, msg);
    let Encoding::V3(precision) = opts.encoding else {
        return Err(bad("format 4 stores node geometry as format 3 does; format 2's encoding cannot be asked for".into()));
    };
    let precision = check_precision(precision).map_err(bad)?;
    if opts.tool.len() as u64 > MAX_TOOL_BYTES {
        return Err(bad(format!("tool string of {} bytes exceeds {MAX_TOOL_BYTES}", opts.tool.len())));
    }
    let Some(m0) = dag.levels.first().filter(|m| m.face_count() > 0) else {
        return Err(bad("nothing to write: level 0 has no faces".into()));
    };
    let attributes = attributes_of(m0);
    let bits = if precision.grid_bits == 0 { auto_grid_bits(m0) } else { precision.grid_bits };
    let grid = model_grid(&dag.levels, bits);
    let writer_opts = opts.writer_options(grid, attributes, m0, dag.levels.len() as u32, MAJOR4);
    let mut writer = Writer::new(out, path, writer_opts, spill)?;
    let place = Place {
        grid,
        precision,
        attributes,
        derive_normals: opts.derive_normals,
        textured: !opts.images.is_empty(),
        first: 0,
        node_key: &|n| n,
        group_key: &|g| g,
        base: Base::Input { clusters, pinned: None },
        preparer: &writer.preparer(),
    };
    write_levels(dag, &place, &mut |r| r.add_to(&mut writer), &bad)?;
    writer.finish()
}

/// Where a DAG's levels go in a file, and what its level 0 is.
pub struct Place<'a> {
    pub grid: Grid,
    pub precision: Precision,
    /// The file's corner attributes, which every level must carry.
    pub attributes: Attributes,
    /// Whether nodes store normals derived from each level's geometry.
    pub derive_normals: bool,
    /// Whether the file has images (then nodes get their UV density).
    pub textured: bool,
    /// The file level of the DAG's level 0.
    pub first: u32,
    /// The key of node `n` and of group `g` (their indices in the DAG) among their file level's.
    pub node_key: &'a (dyn Fn(u32) -> u32 + Sync),
    pub group_key: &'a (dyn Fn(u32) -> u32 + Sync),
    pub base: Base<'a>,
    /// The file's [`Writer::preparer`]: nodes are prepared on every core.
    pub preparer: &'a Preparer,
}

/// What a DAG's level 0 is.
pub enum Base<'a> {
    /// The input, written with the grouping's culling `clusters` (over the input's faces, in the
    /// input's order). Vertices at `pinned` positions (where a piece meets others) take their
    /// nearest grid point whatever the others do, as every piece puts them.
    Input { clusters: &'a hierarchy::Level, pinned: Option<&'a FxHashSet<[u32; 3]>> },
    /// Nodes written already, the tops of earlier pieces: their vertices' grid points by position
    /// and, per node, what it was stored with. Not written again; their consumers are.
    Tops { points: &'a FxHashMap<[u32; 3], [u32; 3]>, stored: &'a [Stored] },
}

/// A node's or group's error and sphere as stored (decoded).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stored {
    pub error: f32,
    pub center: Vec3,
    pub radius: f32,
}

/// What [`write_levels`] gives the file.
pub enum Record {
    Node(Box<Prepared>),
    Group(GroupIn),
    /// Node `key` of `level`, added earlier, is a child of `group`.
    Consumer {
        level: u32,
        key: u32,
        group: u32,
    },
}

impl Record {
    /// Give it to `writer`.
    pub fn add_to<W: std::io::Write>(self, writer: &mut Writer<W>) -> Result<()> {
        match self {
            Record::Node(n) => writer.add_prepared(*n),
            Record::Group(g) => writer.add_group(g),
            Record::Consumer { level, key, group } => {
                writer.set_parent(level, key, group);
                Ok(())
            }
        }
    }
}

/// How a DAG's top level was written: its vertices' grid points as a next level inherits them
/// (before inner vertices snap to their node's lattice: every vertex at one position has the same
/// one), and what its nodes and groups were stored with: per top node; per group, for the groups
/// of levels above level 0 and the stand-ins ([`Stored::default`] for none else).
pub struct Written {
    pub points: Vec<[u32; 3]>,
    pub nodes: Vec<Stored>,
    pub groups: Vec<Stored>,
}

/// Encode `dag`'s levels (all but level 0 when it holds [`Base::Tops`]) and their groups into
/// records for the file, level 0 first. A top node's consumer is left for whoever builds on it.
pub fn write_levels(
    dag: &Dag,
    place: &Place,
    emit: &mut dyn FnMut(Record) -> Result<()>,
    bad: &(dyn Fn(String) -> Error + Sync),
) -> Result<Written> {
    let Place { grid, precision, attributes, .. } = *place;
    if let Some(l) = dag.levels.iter().position(|m| attributes_of(m) != attributes) {
        return Err(bad(format!("level {l}: corner attributes differ from the file's {attributes:?}")));
    }
    // Per group, its stored error and sphere, filled level by level from the bottom; the
    // stand-ins for earlier pieces' groups hold what those were stored with.
    let mut group_stored = vec![Stored::default(); dag.groups.len()];
    for (g, group) in dag.groups.iter().enumerate().filter(|(_, g)| g.level == 0) {
        group_stored[g] = Stored { error: group.error, center: group.center, radius: group.radius };
    }
    let mut node_stored = vec![Stored::default(); dag.nodes.len()];
    // Grid points of the level below, by position, before its lattices.
    let mut below: FxHashMap<[u32; 3], [u32; 3]> = FxHashMap::default();
    let mut top_points = Vec::new();
    for (l, mesh) in dag.levels.iter().enumerate() {
        let file_level = place.first + l as u32;
        let nodes = dag.level_nodes(l);
        let first = nodes.start;
        let node_key = |n: u32| (place.node_key)(n);
        if let (Base::Tops { points, stored }, 0) = (&place.base, l) {
            // Written already: what the next level inherits, and the nodes' consumers.
            if stored.len() != nodes.len() {
                return Err(bad(format!("{} stored nodes for {} at level 0", stored.len(), nodes.len())));
            }
            let grid_points = (mesh.positions.iter().enumerate())
                .map(|(v, x)| points.get(&position_key(*x)).copied().ok_or_else(|| bad(format!("level 0 vertex {v} has no grid point"))))
                .collect::<Result<Vec<[u32; 3]>>>()?;
            below = mesh.positions.iter().zip(&grid_points).map(|(p, &g)| (position_key(*p), g)).collect();
            for n in nodes.clone() {
                node_stored[n as usize] = stored[(n - first) as usize];
                let consumer = dag.nodes[n as usize].consumer;
                if consumer != NONE {
                    emit(Record::Consumer { level: file_level, key: node_key(n), group: (place.group_key)(consumer) })?;
                }
            }
            top_points = grid_points;
            continue;
        }
        // Each node's faces, as the codec and the measures take them.
        let faces: Vec<Vec<u32>> = nodes.clone().map(|n| dag.nodes[n as usize].faces.clone().collect()).collect();
        let faces = |n: u32| faces[(n - first) as usize].as_slice();
        let mut clusters = None;
        let mut q = match (&place.base, l) {
            (Base::Input { clusters: c, pinned }, 0) => {
                if c.face_group.len() != mesh.face_count() || dag.input_faces.len() != mesh.face_count() {
                    return Err(bad(format!("clusters label {} faces but level 0 has {}", c.face_group.len(), mesh.face_count())));
                }
                // Level 0's clusters in level 0's face order.
                let mut c = (*c).clone();
                c.face_group = dag.input_faces.iter().map(|&f| c.face_group[f as usize]).collect();
                clusters = Some(c);
                let kept = pinned.map_or_else(Vec::new, |p| pinned_flags(mesh, p));
                Quantized::distinct_keeping(&grid, mesh, &kept).map_err(bad)?
            }
            _ => Quantized::new(&grid, mesh),
        };
        for (v, p) in mesh.positions.iter().enumerate() {
            if let Some(&g) = below.get(&position_key(*p)) {
                q.points[v] = g;
                q.positions[v] = grid.decode(g);
            }
        }
        below = mesh.positions.iter().zip(&q.points).map(|(p, &g)| (position_key(*p), g)).collect();
        let mut node_of_face = vec![0u32; mesh.face_count()];
        for (k, n) in dag.nodes[nodes.start as usize..nodes.end as usize].iter().enumerate() {
            node_of_face[n.faces.start as usize..n.faces.end as usize].fill(k as u32);
        }
        // Lattices of the inner vertices, from each node's error as built and its edges.
        let shifts: Vec<u32> = nodes
            .clone()
            .map(|n| match dag.nodes[n as usize].source {
                NONE => 0,
                s => lattice_shift(dag.groups[s as usize].error.min(median_edge(mesh, faces(n))), precision.lattice, &grid),
            })
            .collect();
        if l + 1 == dag.levels.len() {
            top_points = q.points.clone();
        }
        if l > 0 {
            q.snap_inner(&grid, mesh, &node_of_face, &shifts);
        }
        // This level's groups: error and sphere over their children (one level down, stored).
        for g in dag.groups.iter().enumerate().filter(|(_, g)| g.level as usize == l && l > 0).map(|(g, _)| g) {
            let group = &dag.groups[g];
            let quantization = group.outputs.clone().map(|n| q.error(&grid, mesh, faces(n))).fold(0.0, f32::max);
            let children = dag.children.get(g);
            let mut error = group.error + quantization;
            let center = grid.encode(group.center);
            let dc = grid.decode(center).as_dvec3();
            let mut needed = 0f64;
            for &c in children {
                let child = node_stored[c as usize];
                error = error.max(child.error);
                needed = needed.max(dc.distance(child.center.as_dvec3()) + child.radius as f64);
                let s = dag.nodes[c as usize].source;
                if s != NONE {
                    let source = group_stored[s as usize];
                    needed = needed.max(dc.distance(source.center.as_dvec3()) + source.radius as f64);
                }
            }
            let (radius_code, radius) = store_radius(&grid, needed);
            group_stored[g] = Stored { error, center: grid.decode(center), radius };
            emit(Record::Group(GroupIn { level: file_level, key: (place.group_key)(g as u32), error, center, radius: radius_code }))?;
        }
        let derived =
            (place.derive_normals && attributes.normals).then(|| DerivedNormals::new(mesh, &q.points, precision.normal_bits, |_| false));
        let node = |n: u32| -> Result<(Stored, Prepared)> {
            let node = &dag.nodes[n as usize];
            let own = faces(n);
            let error = if l == 0 { q.error(&grid, mesh, own) } else { group_stored[node.source as usize].error };
            let (codes, center, radius) = bounds::of_faces(mesh, &q, &grid, own, node.center, node.cone.axis);
            let lattice = Lattice {
                shift: shifts[(n - first) as usize],
                normal_bits: if attributes.normals { precision.normal_bits } else { 0 },
                uv_bits: if attributes.uvs { precision.uv_bits } else { 0 },
                color_bits: if attributes.colors { precision.color_bits } else { 0 },
            };
            let geometry = node_geometry(mesh, &q, &grid, own, clusters.as_ref(), attributes, lattice, derived.as_ref())
                .map_err(|m| bad(format!("level {file_level} node {}: {m}", node_key(n))))?;
            let key = |g: u32| if g == NONE { NO_PARENT } else { (place.group_key)(g) };
            let prepared = place.preparer.prepare(NodeIn {
                level: file_level,
                key: node_key(n),
                parent: key(node.consumer),
                source: key(node.source),
                neighbors: Vec::new(),
                codes,
                error,
                uv_density: if place.textured { uv_density(mesh, own) } else { 0.0 },
                geometry,
            })?;
            Ok((Stored { error, center, radius }, prepared))
        };
        in_order(nodes.start as usize..nodes.end as usize, &|n| node(n as u32), &mut |n, (stored, prepared)| {
            node_stored[n] = stored;
            emit(Record::Node(Box::new(prepared)))
        })?;
    }
    let top = dag.level_nodes(dag.levels.len().saturating_sub(1));
    let nodes = node_stored[top.start as usize..top.end as usize].to_vec();
    Ok(Written { points: top_points, nodes, groups: group_stored })
}
