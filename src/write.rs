//! Write a group hierarchy and its level meshes as a strata file (format-spec/strata-v2.md): each
//! group of each level becomes a node whose geometry is the level mesh's faces in that group, its
//! positions on the file's grid ([`crate::quantize`]) and its bounds rounded outward
//! ([`crate::bounds`]); nodes go, finest level first, to the format's [`Writer`], which assembles
//! the file coarsest level first.

use crate::atomic::AtomicFile;
use crate::bounds;
use crate::derived_normals::DerivedNormals;
use crate::error::{Error, Result};
use crate::format::geom::v2::{base_and_span, cluster_shift, GeometryCodes};
use crate::format::geom::v3::Lattice;
use crate::format::texture::ImageIn;
use crate::format::{
    octa, Attributes, Georef, Grid, MaterialRange, NodeIn, Prepared, Preparer, WriteSummary, Writer, WriterOptions, GRID_BITS,
    MAX_GRID_BITS, MAX_TOOL_BYTES, NO_PARENT,
};
use crate::hierarchy::{self, Hierarchy, HierarchyParams, Lists};
use crate::levels::{pinned_flags, LevelMeshes};
use crate::mesh::{Material, Mesh};
use crate::quantize::{auto_grid_bits, model_grid, Quantized};
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};
use std::io::Write;
use std::path::Path;
use std::sync::Arc;

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
    /// Where the model sits on Earth, for terrain (a `GEOR` chunk, format 2.1).
    pub georef: Option<Georef>,
    /// How node geometry is stored.
    pub encoding: Encoding,
    /// Store each level's normals as readers derive them from its geometry
    /// ([`crate::derived_normals`]) rather than the normals the mesh carries.
    pub derive_normals: bool,
    /// The images level 0's materials index, each with its levels ([`crate::texture::pyramid`]);
    /// shared, so that options are cheap to copy however large the images.
    pub images: Arc<Vec<ImageIn>>,
}

/// How node geometry is stored: format 3's compressed payloads at a chosen precision (the default;
/// format-spec/strata-v3.md), or format 2's fixed-width arrays on a 20-bit grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Encoding {
    V2,
    V3(Precision),
}

/// Format 3's quantization (strata-v3.md §6): level 0 on the grid, coarser levels' inner vertices
/// on lattices tied to their error and edges, normals, colours and UVs to stated bits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Precision {
    /// Grid bits per axis over the model's largest extent (level 0's precision), 1..=21; 0 picks
    /// them from the mesh ([`crate::quantize::auto_grid_bits`]: a 64th of the median edge).
    pub grid_bits: u32,
    /// A node's lattice is the largest power-of-two number of grid steps not above this fraction of
    /// its error before quantization (or of its median edge, if smaller), so quantization adds at
    /// most `√3/2` of the fraction to its error.
    pub lattice: f32,
    /// Bits of each octahedral normal coordinate, 2..=16.
    pub normal_bits: u32,
    /// UVs are multiples of `2^−uv_bits` (fewer where a node's UVs are too large for f32 to hold
    /// them exactly), 1..=24.
    pub uv_bits: u32,
    /// Bits of each colour channel, 1..=8 (8 keeps colours exactly).
    pub color_bits: u32,
}

impl Default for Precision {
    fn default() -> Self {
        Precision { grid_bits: 0, lattice: 0.25, normal_bits: 8, uv_bits: 16, color_bits: 8 }
    }
}

impl Encoding {
    fn major(&self) -> u16 {
        match self {
            Encoding::V2 => 2,
            Encoding::V3(_) => 3,
        }
    }
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            metres_per_unit: 0.0,
            params: HierarchyParams::default(),
            level_ratio: 0.5,
            tool: format!("strata {}", env!("CARGO_PKG_VERSION")),
            georef: None,
            encoding: Encoding::V3(Precision::default()),
            derive_normals: false,
            images: Arc::default(),
        }
    }
}

/// Write the file for hierarchy `h` and level meshes `lv` to `path`, all or nothing (a temporary
/// file renamed on success; encoded nodes wait in unlinked temporary files beside it). Inconsistent
/// inputs are an error naming the level and group.
pub fn write(path: &Path, h: &Hierarchy, lv: &LevelMeshes, opts: &WriteOptions) -> Result<WriteSummary> {
    let mut file = AtomicFile::create(path)?;
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let summary = write_named(file.writer(), path, h, lv, opts, Some(dir))?;
    file.commit()?;
    Ok(summary)
}

/// [`write`] into any writer, from its current position; encoded nodes wait in memory.
pub fn write_to<W: Write>(w: &mut W, h: &Hierarchy, lv: &LevelMeshes, opts: &WriteOptions) -> Result<WriteSummary> {
    write_named(w, Path::new("<output>"), h, lv, opts, None)
}

fn write_named<W: Write>(
    w: W,
    path: &Path,
    h: &Hierarchy,
    lv: &LevelMeshes,
    opts: &WriteOptions,
    spill: Option<&Path>,
) -> Result<WriteSummary> {
    let bad = |msg: String| Error::invalid(path, None, msg);
    let attributes = check_inputs(h, lv, opts).map_err(bad)?;
    let precision = match opts.encoding {
        Encoding::V2 => None,
        Encoding::V3(p) => Some(check_precision(p).map_err(bad)?),
    };
    let bits = match precision {
        None => GRID_BITS,
        Some(p) if p.grid_bits == 0 => auto_grid_bits(&lv.levels[0].mesh),
        Some(p) => p.grid_bits,
    };
    let grid = model_grid(lv.levels.iter().map(|l| &l.mesh), bits);
    let piece = Piece::new(h, lv, &grid, precision, None, &[], lv.levels.len()).map_err(bad)?;
    let writer_opts = opts.writer_options(grid, attributes, &lv.levels[0].mesh, h.levels.len() as u32, opts.encoding.major());
    let mut writer = Writer::new(w, path, writer_opts, spill)?;
    let place = Place { offset: 0, levels: 0..h.levels.len(), file_levels: h.levels.len(), key: &|_, g| g, shared: None };
    let textured = !opts.images.is_empty();
    let looks = Looks { attributes, precision, textured, derive_normals: opts.derive_normals };
    let preparer = writer.preparer();
    piece.add(&preparer, &mut |node| writer.add_prepared(node), &bad, h, lv, &grid, looks, &place)?;
    writer.finish()
}

impl WriteOptions {
    /// What the format's writer records besides the nodes, for a file of `levels` levels of format
    /// `major` whose level 0 is `level0`.
    pub(crate) fn writer_options(&self, grid: Grid, attributes: Attributes, level0: &Mesh, levels: u32, major: u16) -> WriterOptions {
        WriterOptions {
            metres_per_unit: self.metres_per_unit,
            params: self.params,
            level_ratio: self.level_ratio,
            tool: self.tool.clone(),
            grid,
            attributes,
            materials: material_table(level0),
            input_vertices: level0.vertex_count() as u64,
            levels,
            georef: self.georef.clone(),
            major,
            images: self.images.clone(),
        }
    }
}

/// The corner attributes `mesh` carries.
pub(crate) fn attributes_of(mesh: &Mesh) -> Attributes {
    Attributes { normals: !mesh.normals.is_empty(), uvs: !mesh.uvs.is_empty(), colors: !mesh.colors.is_empty() }
}

/// Where a piece's nodes go in the file: piece level `l` is file level `l + offset`; the levels in
/// `levels` are written, group `g` of piece level `l` under key `key(l, g)` (its parent's key
/// likewise, one level up). `file_levels` is the file's number of levels, which tells the top
/// level's nodes (no parent); `usize::MAX` when the piece writes no top node (its top goes to
/// the piece that merges it). The in-core build is one piece; the partitioned build writes each
/// cell and the merge of their tops as pieces of one file.
pub(crate) struct Place<'a> {
    pub offset: usize,
    pub levels: std::ops::Range<usize>,
    pub file_levels: usize,
    pub key: &'a (dyn Fn(usize, u32) -> u32 + Sync),
    /// The positions ([`crate::levels::position_key`]) of the vertices the piece shares with pieces
    /// written apart: their faces on the other side are not in this piece, so their normals stay
    /// the carried ones.
    pub shared: Option<&'a FxHashSet<[u32; 3]>>,
}

/// What a piece's nodes store besides positions and faces: the attributes, format 3's precision
/// (`None`: format 2), whether materials have images, and whether normals are derived from each
/// level's geometry ([`crate::derived_normals`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Looks {
    pub attributes: Attributes,
    pub precision: Option<Precision>,
    pub textured: bool,
    pub derive_normals: bool,
}

/// A hierarchy and its level meshes made ready to write: positions on the file's grid, node
/// faces and bounds.
pub(crate) struct Piece {
    pub quant: Vec<Quantized>,
    pub shifts: Vec<Vec<u32>>,
    pub faces: Vec<Lists>,
    pub bounds: Vec<Vec<bounds::NodeBounds>>,
}

impl Piece {
    /// `base`: the bounds of level 0 when they are known already (the partitioned build's merge,
    /// whose level 0 is the cells' tops); level 0 is then not the input and its positions are
    /// rounded to the grid like any coarser level's. Otherwise level 0 is the input, its vertices
    /// kept apart on the grid, those of `kept` on their nearest point
    /// ([`Quantized::distinct_keeping`]). With `precision` (format 3), the inner vertices of levels
    /// `1..snapped` move to their nodes' lattices; a level passed on to be written by another piece
    /// (a cell's top) must stay unsnapped, as that piece will see it.
    pub fn new(
        h: &Hierarchy,
        lv: &LevelMeshes,
        grid: &Grid,
        precision: Option<Precision>,
        base: Option<Vec<bounds::NodeBounds>>,
        kept: &[bool],
        snapped: usize,
    ) -> std::result::Result<Piece, String> {
        let mut quant = Vec::with_capacity(lv.levels.len());
        quant.push(match base {
            None => Quantized::distinct_keeping(grid, &lv.levels[0].mesh, kept)?,
            Some(_) => Quantized::new(grid, &lv.levels[0].mesh),
        });
        quant.par_extend(lv.levels[1..].par_iter().map(|l| Quantized::new(grid, &l.mesh)));
        let faces: Vec<Lists> = lv.levels.iter().zip(&h.levels).map(|(m, hl)| Lists::from_labels(&m.face_group, hl.groups.len())).collect();
        let mut shifts: Vec<Vec<u32>> = lv.levels.iter().map(|l| vec![0; l.group_error.len()]).collect();
        if let Some(p) = precision {
            let snapped = snapped.min(lv.levels.len()).max(1);
            // Levels apart, on every core.
            (
                quant[1..snapped].par_iter_mut(),
                shifts[1..snapped].par_iter_mut(),
                lv.levels[1..snapped].par_iter(),
                faces[1..snapped].par_iter(),
            )
                .into_par_iter()
                .for_each(|(q, shift, level, faces)| {
                    *shift = (0..level.group_error.len())
                        .map(|g| lattice_shift(level.group_error[g].min(median_edge(&level.mesh, faces.get(g))), p.lattice, grid))
                        .collect();
                    q.snap_inner(grid, &level.mesh, &level.face_group, shift);
                });
        }
        let bounds = bounds::nodes(h, lv, &faces, grid, &quant, base)?;
        Ok(Piece { quant, shifts, faces, bounds })
    }

    /// Hand the nodes of `place.levels` to `add` (a [`Writer::add_prepared`]) in order, each with
    /// its geometry, prepared by `preparer` a batch at a time on every core; geometry that cannot
    /// be stored is an error made by `bad`.
    #[allow(clippy::too_many_arguments)]
    pub fn add(
        &self,
        preparer: &Preparer,
        add: &mut dyn FnMut(Prepared) -> Result<()>,
        bad: &(dyn Fn(String) -> Error + Sync),
        h: &Hierarchy,
        lv: &LevelMeshes,
        grid: &Grid,
        looks: Looks,
        place: &Place,
    ) -> Result<()> {
        let Looks { attributes, precision, textured, derive_normals } = looks;
        let normal_bits = precision.map_or(octa::BITS, |p| p.normal_bits);
        for l in place.levels.clone() {
            let hl = &h.levels[l];
            let mesh = &lv.levels[l].mesh;
            let file_level = l + place.offset;
            let derived = (derive_normals && attributes.normals).then(|| {
                let shared = place.shared.map(|s| pinned_flags(mesh, s));
                DerivedNormals::new(mesh, &self.quant[l].points, normal_bits, |v| shared.as_ref().is_some_and(|f| f[v as usize]))
            });
            let node = |g: usize| -> Result<Prepared> {
                let b = &self.bounds[l][g];
                let clusters = (file_level == 0).then_some(&h.clusters);
                let lattice = precision.map_or(Lattice::default(), |p| Lattice {
                    shift: self.shifts[l][g],
                    normal_bits: if attributes.normals { p.normal_bits } else { 0 },
                    uv_bits: if attributes.uvs { p.uv_bits } else { 0 },
                    color_bits: if attributes.colors { p.color_bits } else { 0 },
                });
                let geometry =
                    node_geometry(mesh, &self.quant[l], grid, self.faces[l].get(g), clusters, attributes, lattice, derived.as_ref())
                        .map_err(bad)?;
                let uv_density = if textured { uv_density(mesh, self.faces[l].get(g)) } else { 0.0 };
                let top = file_level + 1 == place.file_levels;
                preparer.prepare(NodeIn {
                    level: file_level as u32,
                    key: (place.key)(l, g as u32),
                    parent: if top { NO_PARENT } else { (place.key)(l + 1, hl.parent[g]) },
                    source: NO_PARENT,
                    neighbors: hl.neighbors.get(g).iter().map(|&n| (place.key)(l, n)).collect(),
                    codes: b.codes,
                    error: b.error,
                    uv_density,
                    geometry,
                })
            };
            in_order(0..self.bounds[l].len(), &node, &mut |_, prepared| add(prepared))?;
        }
        Ok(())
    }
}

/// Nodes prepared at once on every core before they are handed over in order: enough to keep the
/// cores busy, few enough that their encoded bytes stay small beside the level meshes.
const PREPARE_BATCH: usize = 64;

/// Run `prepare(i)` for each `i` of `items`, [`PREPARE_BATCH`] at a time on every core, and hand
/// each result to `add` in order; the first error in that order stops.
pub(crate) fn in_order<T: Send>(
    items: std::ops::Range<usize>,
    prepare: &(dyn Fn(usize) -> Result<T> + Sync),
    add: &mut dyn FnMut(usize, T) -> Result<()>,
) -> Result<()> {
    for start in items.clone().step_by(PREPARE_BATCH) {
        let batch: Vec<Result<T>> = (start..(start + PREPARE_BATCH).min(items.end)).into_par_iter().map(prepare).collect();
        for (i, done) in (start..).zip(batch) {
            add(i, done?)?;
        }
    }
    Ok(())
}

pub(crate) fn check_precision(p: Precision) -> std::result::Result<Precision, String> {
    let valid = (0..=MAX_GRID_BITS).contains(&p.grid_bits)
        && (2..=16).contains(&p.normal_bits)
        && (1..=24).contains(&p.uv_bits)
        && (1..=8).contains(&p.color_bits)
        && p.lattice.is_finite()
        && p.lattice >= 0.0;
    if !valid {
        return Err(format!(
            "precision {p:?}: grid bits must be 0 (automatic) or 1..={MAX_GRID_BITS}, normal bits 2..=16, UV bits 1..=24, colour bits 1..=8, the lattice fraction finite and ≥ 0"
        ));
    }
    Ok(p)
}

/// The median edge length of `faces` of `mesh` (each face's three edges), infinite for none.
pub(crate) fn median_edge(mesh: &Mesh, faces: &[u32]) -> f32 {
    let mut lengths: Vec<f32> = faces
        .iter()
        .flat_map(|&f| {
            let p = mesh.triangles[f as usize].map(|v| mesh.positions[v as usize]);
            [p[0].distance(p[1]), p[1].distance(p[2]), p[2].distance(p[0])]
        })
        .collect();
    if lengths.is_empty() {
        return f32::INFINITY;
    }
    let mid = lengths.len() / 2;
    *lengths.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// The lattice shift of a node whose error before quantization, or the median length of its
/// edges if smaller, is `error`: the largest `s` with `2^s` grid steps at most `fraction · error`,
/// below the grid's bits. The edges bound it where a level's error outgrows its faces (a handle
/// cut at a coarse level): a lattice a quarter of the error would fold most of those faces flat.
pub(crate) fn lattice_shift(error: f32, fraction: f32, grid: &Grid) -> u32 {
    let steps = (fraction as f64 * error as f64) / grid.step;
    if steps.is_nan() || steps < 2.0 {
        return 0;
    }
    (steps.log2().floor() as u32).min(grid.bits - 1)
}

/// UV units per model unit over the faces of `faces` whose material has an image map: the square
/// root of their UV area over their area; 0 when there are none (or no UVs). Mapped faces whose
/// UVs have no extent (a palette texture: a texel per face) give the smallest density, so that they
/// get the full image, where each texel keeps its color.
pub(crate) fn uv_density(mesh: &Mesh, faces: &[u32]) -> f32 {
    if mesh.uvs.is_empty() {
        return 0.0;
    }
    let (mut uv_area, mut area, mut mapped) = (0f64, 0f64, false);
    for &f in faces {
        let f = f as usize;
        let textured = mesh.materials.get(material_of(mesh, f) as usize).is_some_and(|m| m.maps.iter().any(Option::is_some));
        if !textured {
            continue;
        }
        mapped = true;
        let [a, b, c] = [0, 1, 2].map(|k| mesh.uvs[3 * f + k].as_dvec2());
        uv_area += 0.5 * (b - a).perp_dot(c - a).abs();
        area += mesh.face_areas.get(f).copied().unwrap_or(0.0) as f64;
    }
    let d = if area > 0.0 && uv_area.is_finite() { (uv_area / area).sqrt() as f32 } else { 0.0 };
    match mapped {
        false => 0.0,
        true if d > f32::MIN_POSITIVE => d,
        true => f32::MIN_POSITIVE,
    }
}

/// The material table: level 0's, or one default material if it has none.
pub(crate) fn material_table(mesh: &Mesh) -> Vec<Material> {
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
    let has = attributes_of;
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

/// The UV bits a node's faces `order` can keep: at most `bits`, and few enough that every UV's
/// multiple of `2^−bits` is an exact f32 (below 2^24 steps).
fn uv_bits(mesh: &Mesh, order: &[u32], bits: u32) -> u32 {
    let largest = order.iter().flat_map(|&f| (0..3).map(move |k| 3 * f as usize + k)).fold(0f32, |m, c| {
        let uv = mesh.uvs[c];
        if uv.is_finite() {
            m.max(uv.x.abs()).max(uv.y.abs())
        } else {
            m
        }
    });
    let mut b = bits;
    while b > 1 && (largest as f64) * (1u64 << b) as f64 >= (1u64 << 23) as f64 {
        b -= 1;
    }
    b
}

/// The geometry of `faces` of `mesh`, as the format stores it. Faces are ordered by culling cluster
/// (level 0), then material, then along a Morton curve; vertices are deduplicated corners (grid point and attributes) in
/// order of first use. Cluster records start from the hierarchy's cones and spheres
/// ([`bounds::cluster`]). With `derived`, format 3's normals are those of the level's geometry.
#[allow(clippy::too_many_arguments)]
pub(crate) fn node_geometry(
    mesh: &Mesh,
    q: &Quantized,
    grid: &Grid,
    faces: &[u32],
    clusters: Option<&hierarchy::Level>,
    attrs: Attributes,
    lattice: Lattice,
    derived: Option<&DerivedNormals>,
) -> std::result::Result<GeometryCodes, String> {
    let cluster_of = |f: u32| clusters.map_or(0, |c| c.face_group[f as usize]);
    // Within a cluster and material, faces go along a Morton curve of their centroids, so that
    // consecutive faces are near each other (compact blocks for a renderer's occlusion test).
    let morton = |f: u32| {
        let t = mesh.triangles[f as usize].map(|v| q.points[v as usize]);
        let c = [0, 1, 2].map(|k| ((t[0][k] as u64 + t[1][k] as u64 + t[2][k] as u64) / 3) as u32);
        (0..21).fold(0u64, |m, bit| m | (0..3).fold(0u64, |b, k| b | (((c[k] >> bit) & 1) as u64) << (3 * bit + k)))
    };
    let mut order: Vec<u32> = faces.to_vec();
    order.sort_by_cached_key(|&f| (cluster_of(f), material_of(mesh, f as usize), morton(f), f));

    type Key = ([u32; 3], [i16; 2], [u32; 2], [u8; 4]);
    let mut index_of: FxHashMap<Key, u32> = FxHashMap::with_capacity_and_hasher(order.len(), Default::default());
    // Corners of a mesh vertex often repeat its attributes: the output index per vertex and raw
    // attributes, so that each is quantized and encoded once.
    type Raw = (u32, [u32; 3], [u32; 2], [u8; 4]);
    let mut seen: FxHashMap<Raw, u32> = FxHashMap::with_capacity_and_hasher(order.len(), Default::default());
    let mut lattice = lattice;
    if lattice.uv_bits > 0 {
        lattice.uv_bits = uv_bits(mesh, &order, lattice.uv_bits);
    }
    let uv_scale = (1u64 << lattice.uv_bits) as f64;
    let mut out = GeometryCodes { indices: Vec::with_capacity(order.len() * 3), lattice, ..GeometryCodes::default() };
    for &f in &order {
        for k in 0..3 {
            let corner = 3 * f as usize + k;
            let v = mesh.triangles[f as usize][k];
            let raw = (
                v,
                if attrs.normals { mesh.normals[corner].to_array().map(f32::to_bits) } else { [0; 3] },
                if attrs.uvs { mesh.uvs[corner].to_array().map(f32::to_bits) } else { [0; 2] },
                if attrs.colors { mesh.colors[corner] } else { [0; 4] },
            );
            if let Some(&i) = seen.get(&raw) {
                out.indices.push(i);
                continue;
            }
            let g = q.points[v as usize];
            let n = match (attrs.normals, lattice.normal_bits) {
                (false, _) => [0; 2],
                // Format 2 (bits 0) stores full-precision codes.
                (true, bits) => derived
                    .and_then(|d| d.code(corner))
                    .unwrap_or_else(|| octa::encode_bits(mesh.normals[corner], if bits == 0 { octa::BITS } else { bits })),
            };
            let uv = match (attrs.uvs, lattice.uv_bits) {
                (false, _) => [0; 2],
                (true, 0) => mesh.uvs[corner].to_array().map(f32::to_bits),
                (true, _) => mesh.uvs[corner].to_array().map(|u| (((u as f64 * uv_scale).round() / uv_scale) as f32).to_bits()),
            };
            let c = if attrs.colors { mesh.colors[corner] } else { [0; 4] };
            let next = index_of.len() as u32;
            let i = *index_of.entry((g, n, uv, c)).or_insert_with(|| {
                out.points.push(g);
                if attrs.normals {
                    out.normals.push(n);
                }
                if attrs.uvs {
                    out.uvs.push(uv);
                }
                if attrs.colors {
                    out.colors.push(c);
                }
                next
            });
            seen.insert(raw, i);
            out.indices.push(i);
        }
    }

    let mut first = 0u32;
    for run in order.chunk_by(|&a, &b| material_of(mesh, a as usize) == material_of(mesh, b as usize)) {
        out.material_ranges.push(MaterialRange {
            material: material_of(mesh, run[0] as usize),
            first_index: 3 * first,
            index_count: 3 * run.len() as u32,
        });
        first += run.len() as u32;
    }

    if let Some(cl) = clusters {
        let (base, span) = base_and_span(&out.points);
        let shift = cluster_shift(span, grid.bits);
        let mut records = Vec::new();
        for run in order.chunk_by(|&a, &b| cluster_of(a) == cluster_of(b)) {
            let g = &cl.groups[cluster_of(run[0]) as usize];
            if !(g.center.is_finite() && g.radius.is_finite()) {
                return Err(format!("cluster {}: bounds are not finite", cluster_of(run[0])));
            }
            let record = bounds::cluster(mesh, q, grid, run, (g.center, g.radius, g.cone), (base, span, shift));
            for piece in run.chunks(u16::MAX as usize) {
                records.push(crate::format::geom::v2::ClusterCodes { faces: piece.len() as u16, ..record });
            }
        }
        out.clusters = Some((shift, records));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A coarse level whose error outgrows its faces (a handle cut there counts in the whole
    /// node's error) gets its lattice from its edges, so its faces stay faces.
    #[test]
    fn lattice_is_bounded_by_the_nodes_edges() {
        let mesh = crate::fixtures::icosphere(5);
        let adjacency = crate::mesh::Adjacency::build(&mesh);
        let mut h = hierarchy::build(&mesh, &adjacency, &HierarchyParams::default());
        let mut lv = crate::levels::build(mesh, &mut h, &crate::levels::LevelParams::default(), &mut |_| {});
        assert!(lv.levels.len() >= 3);
        for level in &mut lv.levels[1..] {
            level.group_error.iter_mut().for_each(|e| *e = 1e3);
        }
        let grid = Grid::fit(glam::Vec3::splat(-1.0), glam::Vec3::splat(1.0), 16);
        let n = lv.levels.len();
        let piece = Piece::new(&h, &lv, &grid, Some(Precision::default()), None, &[], n).expect("piece");
        for l in 1..n {
            let level = &lv.levels[l];
            for g in 0..level.group_error.len() {
                let edge = median_edge(&level.mesh, piece.faces[l].get(g));
                let step = (1u64 << piece.shifts[l][g]) as f64 * grid.step;
                assert!(piece.shifts[l][g] > 0 && step <= 0.25 * edge as f64, "level {l} node {g}: lattice {step} for edges of {edge}");
            }
            let points = &piece.quant[l].points;
            let folded = level.mesh.triangles.iter().filter(|t| {
                let p = t.map(|v| points[v as usize]);
                p[0] == p[1] || p[1] == p[2] || p[2] == p[0]
            });
            assert_eq!(folded.count(), 0, "level {l}");
        }
    }
}
