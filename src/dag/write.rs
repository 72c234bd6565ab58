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
use crate::format::{GroupIn, NodeIn, WriteSummary, Writer, MAJOR4, MAX_TOOL_BYTES, NO_PARENT};
use crate::hierarchy;
use crate::levels::position_key;
use crate::quantize::{auto_grid_bits, model_grid, Quantized};
use crate::write::{attributes_of, check_precision, lattice_shift, median_edge, node_geometry, uv_density, Encoding, WriteOptions};
use glam::Vec3;
use rustc_hash::FxHashMap;
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
    if clusters.face_group.len() != m0.face_count() || dag.input_faces.len() != m0.face_count() {
        return Err(bad(format!("clusters label {} faces but level 0 has {}", clusters.face_group.len(), m0.face_count())));
    }
    let attributes = attributes_of(m0);
    if let Some(l) = dag.levels.iter().position(|m| attributes_of(m) != attributes) {
        return Err(bad(format!("level {l}: corner attributes differ from level 0's {attributes:?}")));
    }
    // Level 0's clusters in level 0's face order.
    let mut clusters = clusters.clone();
    clusters.face_group = dag.input_faces.iter().map(|&f| clusters.face_group[f as usize]).collect();

    let bits = if precision.grid_bits == 0 { auto_grid_bits(m0) } else { precision.grid_bits };
    let grid = model_grid(&dag.levels, bits);
    let writer_opts = opts.writer_options(grid, attributes, m0, dag.levels.len() as u32, MAJOR4);
    let mut writer = Writer::new(out, path, writer_opts, spill)?;
    let textured = !opts.images.is_empty();

    // Per group, its stored error and sphere (decoded), filled level by level from the bottom.
    let mut group_error = vec![0f32; dag.groups.len()];
    let mut group_sphere = vec![(Vec3::ZERO, 0f32); dag.groups.len()];
    let mut node_error = vec![0f32; dag.nodes.len()];
    let mut node_sphere = vec![(Vec3::ZERO, 0f32); dag.nodes.len()];
    // Grid points of the level below, by position, before its lattices.
    let mut below: FxHashMap<[u32; 3], [u32; 3]> = FxHashMap::default();
    for (l, mesh) in dag.levels.iter().enumerate() {
        let nodes = dag.level_nodes(l);
        let first = nodes.start;
        let mut q = if l == 0 { Quantized::distinct(&grid, mesh).map_err(bad)? } else { Quantized::new(&grid, mesh) };
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
        // Each node's faces, as the codec and the measures take them.
        let faces: Vec<Vec<u32>> = nodes.clone().map(|n| dag.nodes[n as usize].faces.clone().collect()).collect();
        let faces = |n: u32| faces[(n - first) as usize].as_slice();
        // Lattices of the inner vertices, from each node's error as built and its edges.
        let shifts: Vec<u32> = nodes
            .clone()
            .map(|n| match dag.nodes[n as usize].source {
                NONE => 0,
                s => lattice_shift(dag.groups[s as usize].error.min(median_edge(mesh, faces(n))), precision.lattice, &grid),
            })
            .collect();
        if l > 0 {
            q.snap_inner(&grid, mesh, &node_of_face, &shifts);
        }
        // This level's groups: error and sphere over their children (one level down, stored).
        for g in dag.groups.iter().enumerate().filter(|(_, g)| g.level as usize == l).map(|(g, _)| g) {
            let group = &dag.groups[g];
            let quantization = group.outputs.clone().map(|n| q.error(&grid, mesh, faces(n))).fold(0.0, f32::max);
            let children = dag.children.get(g);
            let mut error = group.error + quantization;
            let center = grid.encode(group.center);
            let dc = grid.decode(center).as_dvec3();
            let mut needed = 0f64;
            for &c in children {
                error = error.max(node_error[c as usize]);
                let (cc, cr) = node_sphere[c as usize];
                needed = needed.max(dc.distance(cc.as_dvec3()) + cr as f64);
                let s = dag.nodes[c as usize].source;
                if s != NONE {
                    let (sc, sr) = group_sphere[s as usize];
                    needed = needed.max(dc.distance(sc.as_dvec3()) + sr as f64);
                }
            }
            let (radius_code, radius) = store_radius(&grid, needed);
            group_error[g] = error;
            group_sphere[g] = (grid.decode(center), radius);
            writer.add_group(GroupIn { level: l as u32, key: g as u32, error, center, radius: radius_code })?;
        }
        let derived =
            (opts.derive_normals && attributes.normals).then(|| DerivedNormals::new(mesh, &q.points, precision.normal_bits, |_| false));
        for n in nodes {
            let node = &dag.nodes[n as usize];
            let own = faces(n);
            let error = if l == 0 { q.error(&grid, mesh, own) } else { group_error[node.source as usize] };
            let (codes, center, radius) = bounds::of_faces(mesh, &q, &grid, own, node.center, node.cone.axis);
            node_error[n as usize] = error;
            node_sphere[n as usize] = (center, radius);
            let lattice = Lattice {
                shift: shifts[(n - first) as usize],
                normal_bits: if attributes.normals { precision.normal_bits } else { 0 },
                uv_bits: if attributes.uvs { precision.uv_bits } else { 0 },
                color_bits: if attributes.colors { precision.color_bits } else { 0 },
            };
            let geometry = node_geometry(mesh, &q, &grid, own, (l == 0).then_some(&clusters), attributes, lattice, derived.as_ref())
                .map_err(|m| bad(format!("level {l} node {n}: {m}")))?;
            writer.add(NodeIn {
                level: l as u32,
                key: n,
                parent: if node.consumer == NONE { NO_PARENT } else { node.consumer },
                source: if node.source == NONE { NO_PARENT } else { node.source },
                neighbors: Vec::new(),
                codes,
                error,
                uv_density: if textured { uv_density(mesh, own) } else { 0.0 },
                geometry,
            })?;
        }
    }
    writer.finish()
}
