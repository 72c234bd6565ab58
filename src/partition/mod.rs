//! The partitioned build, for meshes larger than memory (and for large ones that fit, where it is
//! faster on several cores), top-down: stream the input into spatial cells on disk → build each
//! cell's finest levels alone, several at once, with the cell's border locked → merge the cells'
//! tops into one mesh, where the old cell borders are interior, and build the coarse levels there
//! → write. The file is the same format as the in-core build's; only how its levels were made
//! differs (notes/partition.md says what that costs).
//!
//! Memory: the cells in flight (each an in-core build of [`cell_faces`] faces), the vertex arrays
//! while streaming (positions, and colors, normals and texture coordinates when the input has
//! them), the images' levels, and what is held for later (the writer's node records, the pieces'
//! open edges); the tops waiting for the next round wait in temporary files, and computed normals
//! are summed by each cell from its own faces, save where cells meet ([`vertex_normals`]).
//! It stays within the budget
//! as long as the mesh simplifies where its cells meet; one that does not (a soup of separate
//! triangles) leaves large tops, and the final merge, which holds them all, is said to exceed it.
//! Cells meet exactly: the vertices faces of two cells use are pinned at every level a cell
//! builds, so the border edges of level ℓ nodes of two cells are the same edges, and the pieces
//! that weld the tops by position link such nodes as neighbours (a tree's), or gather them into
//! one group (a DAG's, [`dag`]).

mod cells;
mod dag;
mod tops;
mod vertex_normals;
mod work;

use crate::error::{Error, Result};
use crate::format::{Attributes, Grid, Writer, WriterOptions, GRID_BITS};
use crate::import::stream::{Declared, Faces, Streaming, Vertices};
use crate::import::{Format, ImportOptions};
use crate::mesh::Material;
use crate::pipeline::{ConvertOptions, Converted, Normals, Progress, StageTimes};
use crate::write::Encoding;
use cells::{Cells, Layout, Spool};
use glam::Vec3;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Bytes the in-core build holds per input face at its peak (measured: 406–420 on 0.5–5M-face
/// meshes, notes/levels.md), with room for the allocator.
pub const IN_CORE_BYTES_PER_FACE: u64 = 450;

/// Fewest and most faces per cell.
const MIN_CELL_FACES: u64 = 4096;
const MAX_CELL_FACES: u64 = 2_000_000;

/// Most faces per cell when memory allows more: larger cells are no faster to build per face,
/// and fewer of them keep cores idle while the last ones finish (notes/partition.md).
const FAST_CELL_FACES: u64 = 500_000;

/// Fewest input faces for which the automatic choice builds partitioned even when the in-core
/// build would fit: from there, cells built on every core at once beat one in-core build
/// (notes/partition.md).
pub const PARALLEL_FACES: u64 = 1_000_000;

/// What the partitioned build may use.
#[derive(Clone, Debug, PartialEq)]
pub struct Budget {
    /// Bytes of memory to stay within.
    pub memory: u64,
    /// Folder for the cell files (the system's temporary folder if none).
    pub temp: Option<PathBuf>,
    /// Cells built at once.
    pub threads: usize,
    /// Faces per cell; 0 derives it from `memory` and `threads` ([`cell_faces`]).
    pub cell_faces: u64,
    /// Whether memory matters more than time: then big allocations go to and from the system
    /// directly for the rest of the process ([`frugal_allocation`]), at the price of page faults
    /// (10–20 % more time, notes/partition.md).
    pub frugal: bool,
}

impl Budget {
    /// A budget of `memory` bytes on every core, frugal: memory matters more than time.
    pub fn new(memory: u64) -> Budget {
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        Budget { memory, temp: None, threads, cell_faces: 0, frugal: true }
    }

    /// A budget for an input of `faces` faces that the in-core build would fit in `memory`,
    /// partitioned for speed: cells of a size that depends on the input alone, so that every
    /// machine writes the same file, and no more of them at once than `memory` holds. The even
    /// number of cells nearest to cells of [`FAST_CELL_FACES`] (so at most 1.5 times that), so
    /// that two or four cores finish together.
    pub fn for_speed(memory: u64, faces: u64) -> Budget {
        let pairs = (faces + FAST_CELL_FACES) / (2 * FAST_CELL_FACES);
        let cells = (2 * pairs).clamp(2, MAX_CELLS - MAX_CELLS % 2);
        let cell_faces = faces.div_ceil(cells).max(MIN_CELL_FACES);
        let per_cell = cell_faces.saturating_mul(IN_CORE_BYTES_PER_FACE) * 10 / 6;
        let room = memory.saturating_sub(faces.saturating_mul(HELD_BYTES_PER_FACE));
        let b = Budget::new(memory);
        let threads = b.threads.min((room / per_cell.max(1)) as usize).max(1);
        Budget { threads, cell_faces, frugal: false, ..b }
    }
}

/// A sensible default memory budget: half of the machine's memory, at least 256 MiB.
pub fn default_memory() -> u64 {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("MemTotal:")).and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok()))
        .map_or(8 << 30, |kib| kib * 1024);
    (total / 2).max(256 << 20)
}

/// Bytes held per input face besides the cells: while the input streams, its vertex arrays
/// (positions, weld, owner: 18 bytes a vertex, about 9 a face; 30 and 15 with the input's
/// normals); while cells are built, the writer's node records and the pieces' open edges, a few
/// bytes a face, as tops and node supports wait in temporary files.
pub const HELD_BYTES_PER_FACE: u64 = 16;

/// Faces per cell for a budget and an input of `faces` faces: the cells in flight at once take
/// 60 % of what the held state ([`HELD_BYTES_PER_FACE`]) leaves, the rest is for the merge and
/// the allocator. So the peak stays near the budget whatever the input's size. Cells hold at most
/// [`FAST_CELL_FACES`] unless [`MAX_CELLS`] cells need more.
pub fn cell_faces(b: &Budget, faces: u64) -> u64 {
    if b.cell_faces > 0 {
        return b.cell_faces;
    }
    let free = b.memory.saturating_sub(faces.saturating_mul(HELD_BYTES_PER_FACE));
    let fits = (free / 10 * 6 / b.threads.max(1) as u64 / IN_CORE_BYTES_PER_FACE).clamp(MIN_CELL_FACES, MAX_CELL_FACES);
    fits.min(FAST_CELL_FACES.max(faces.div_ceil(MAX_CELLS)))
}

/// The streaming reader for `input`: its `format`'s, else its extension's, if that has one.
pub fn streaming(input: &Path, format: Option<Format>) -> Option<&'static Streaming> {
    format.or_else(|| Format::from_path(input))?.streaming()
}

/// Most cells: node keys give a piece 12 bits, and each cell holds a file open while the input
/// is streamed (systems allow about a thousand open files by default).
pub const MAX_CELLS: u64 = 960;

/// Node levels each cell builds for cells of `faces` faces (at least one): while the cell's top
/// keeps at least 64·√faces faces. Its locked border stays at full detail and grows as √faces, so
/// it stays a small part of the top. With 24·√faces, the CT head's partitioned DAG read 1.24
/// times the in-core DAG's distance to the input at level 4, its cells' top; with 64 (two levels
/// in the cells instead of four), 1.07 there (notes/dag.md).
pub fn cell_levels(faces: u64) -> usize {
    (((faces as f64).sqrt() / 64.0).log2().floor() as i64).clamp(1, 12) as usize
}

/// What a partitioned build reads: the input file, the options it is read with, its format's
/// streaming reader ([`streaming`]) and what `reader.declared` said of it.
pub struct Input<'a> {
    pub path: &'a Path,
    pub import: &'a ImportOptions,
    pub reader: &'a Streaming,
    pub declared: Declared,
}

/// Convert `input` into `output` by the partitioned build.
pub fn convert(
    Input { path: input, import, reader, declared }: Input,
    output: &Path,
    opts: &ConvertOptions,
    budget: &Budget,
    progress: &mut dyn Progress,
) -> Result<Converted> {
    let mut times = StageTimes::default();
    let mut clock = Instant::now();
    let mut lap = |slot: &mut f64| {
        *slot = clock.elapsed().as_secs_f64() * 1e3;
        clock = Instant::now();
    };
    crate::atomic::protect(input);
    crate::atomic::check_output(output)?;
    let temp = crate::atomic::TempDir::create(budget.temp.as_deref())?;
    let mut warnings = Vec::new();
    if let Some(why) = declared.refused {
        return Err(Error::invalid(input, None, why));
    }
    let triangles = declared.triangles.max(1);
    let cell_faces = cell_faces(budget, triangles);
    let cells = triangles.div_ceil(cell_faces);
    let held = triangles.saturating_mul(HELD_BYTES_PER_FACE);
    let wanted = held + budget.threads as u64 * MIN_CELL_FACES * IN_CORE_BYTES_PER_FACE * 10 / 6;
    let starved = budget.cell_faces == 0 && cells > 1 && wanted > budget.memory;
    if starved || cells > MAX_CELLS {
        let need = held + budget.threads as u64 * (triangles / MAX_CELLS).max(MIN_CELL_FACES) * IN_CORE_BYTES_PER_FACE * 10 / 6;
        return Err(Error::invalid(
            input,
            None,
            format!(
                "about {triangles} triangles need about {} MiB for the partitioned build; --memory gives {} MiB",
                need.max(wanted) >> 20,
                budget.memory >> 20
            ),
        ));
    }

    if budget.frugal {
        frugal_allocation();
    }
    // Distribute: faces to cells by centroid, noting which vertices faces of several cells use.
    progress.stage("distribute", 0);
    let mut state: Option<Distribute> = None;
    let looks = (reader.stream)(
        input,
        import,
        &mut |v, faces| {
            let d = match &mut state {
                Some(d) => d,
                None => state.insert(Distribute::new(v, faces, triangles, cell_faces, opts.normals, temp.path())?),
            };
            d.push(v, faces)
        },
        &mut warnings,
    )?;
    let Some(d) = state else {
        return Err(Error::invalid(input, None, "nothing to convert: no faces"));
    };
    crate::import::replaced_corners_warnings(d.replaced_normals, d.replaced_uvs, &mut warnings);
    let precision = match opts.encoding {
        Encoding::V3(p) => Some(p),
        Encoding::V2 => None,
    };
    let compute_normals = d.compute_normals;
    let Distributed { grid, layout, vertices, shared, spooled } = d.finish(precision.map_or(GRID_BITS, |p| p.grid_bits))?;
    // Computed normals need every face of a vertex: cells sum their own vertices' faces, and the
    // vertices several cells use are summed here from every cell file.
    let shared_sums =
        compute_normals.then(|| vertex_normals::SharedSums::gather(&spooled, layout, vertices, &shared, budget.threads)).transpose()?;
    lap(&mut times.import_ms);

    // The images' levels, made while no cell is in memory; maps without UVs are dropped.
    let mut materials = if looks.materials.is_empty() { vec![Material::default()] } else { looks.materials };
    if !looks.images.is_empty() {
        progress.stage("textures", looks.images.len() as u64);
    }
    let images = crate::texture::pyramid::prepare(&mut materials, &looks.images, layout.uvs, &mut warnings, &mut || progress.step());
    drop(looks.images);
    let textured = !images.is_empty();
    lap(&mut times.texture_ms);
    let attributes = Attributes { normals: layout.normals || compute_normals, uvs: layout.uvs, colors: layout.colors };
    // The crease angle of computed normals (unused where the input's are kept).
    let crease = opts.normals.computed(false).unwrap_or(0.0);
    let k = cell_levels(cell_faces);
    let writer_opts = WriterOptions {
        metres_per_unit: 0.0,
        params: opts.hierarchy,
        level_ratio: opts.levels.ratio,
        tool: format!("strata {}", env!("CARGO_PKG_VERSION")),
        grid,
        attributes,
        materials: materials.clone(),
        input_vertices: 0,
        levels: k as u32 + 1,
        georef: None,
        major: match precision {
            Some(_) if opts.dag => crate::format::MAJOR4,
            Some(_) => 3,
            None if opts.dag => return Err(Error::invalid(input, None, "a DAG (format 4) stores node geometry as format 3 does")),
            None => 2,
        },
        images: images.into(),
    };
    let mut file = crate::atomic::AtomicFile::create(output)?;
    let dir = output.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let writer = Writer::new(file.writer(), output, writer_opts, Some(dir))?;
    let job = work::Job {
        input,
        hierarchy: opts.hierarchy,
        levels: opts.levels,
        grid,
        attributes,
        cell_levels: k,
        cell_faces,
        layout,
        shared_sums: shared_sums.as_ref(),
        shared: &shared,
        vertices,
        crease,
        precision,
        materials: &materials,
        textured,
        derive_normals: compute_normals,
        temp: temp.path(),
    };
    let (summary, cell_warnings) = if opts.dag {
        dag::build(&job, &spooled, writer, budget.threads, progress)?
    } else {
        work::build(&job, &spooled, writer, budget.threads, progress)?
    };
    warnings.extend(cell_warnings);
    drop(shared_sums);
    drop(temp);
    lap(&mut times.simplify_ms);
    file.commit()?;
    lap(&mut times.write_ms);
    Ok(Converted { summary, times, warnings, cells: Some(spooled.iter().filter(|(_, faces)| *faces > 0).count()) })
}

/// What the distribution pass leaves: the file's grid, the cell files' layout, which welded
/// vertices more than one cell uses (a bit each) and each cell's file and face count.
struct Distributed {
    grid: Grid,
    layout: Layout,
    vertices: u64,
    shared: Vec<u64>,
    spooled: Vec<(PathBuf, u64)>,
}

/// Whether the bit of welded vertex `id` is set in `shared` ([`Distributed::shared`]): faces of
/// more than one cell use it.
fn is_shared(shared: &[u64], id: u32) -> bool {
    shared.get(id as usize / 64).is_some_and(|w| w >> (id % 64) & 1 == 1)
}

/// Marks a vertex used by faces of more than one cell in [`Distribute::owner`] (cells number at
/// most [`MAX_CELLS`]).
const SHARED: u16 = u16::MAX;
const _: () = assert!(MAX_CELLS < SHARED as u64);

/// The distribution pass's state, made when the vertices are known.
struct Distribute {
    cells: Cells,
    spool: Spool,
    layout: Layout,
    /// Per input vertex, the first vertex at the same position (+0 = −0): vertices are welded by
    /// position as the in-core build welds them, before normals are summed or cells compared.
    weld: Vec<u32>,
    /// Per welded vertex: 0 unused so far, `c + 1` used by cell `c` alone, or [`SHARED`].
    owner: Vec<u16>,
    /// Whether normals are computed (from the faces around each vertex, once cells are known).
    compute_normals: bool,
    lo: Vec3,
    hi: Vec3,
    /// Lengths of the edges of every `stride`-th face (format 3's automatic grid bits).
    edges: Vec<f64>,
    stride: u64,
    seen: u64,
    /// Corner normals that were NaN or infinite and corner UVs that were unusable, replaced as
    /// the whole-file import replaces them.
    replaced_normals: u64,
    replaced_uvs: u64,
}

impl Distribute {
    /// The state for the vertices `v` and a first batch like `first`, of `faces` faces in all.
    fn new(v: &Vertices, first: &Faces, faces: u64, cell_faces: u64, normals: Normals, temp: &Path) -> Result<Distribute> {
        let cells = Cells::split(v.positions, faces, cell_faces);
        let given = !v.normals.is_empty() || !first.normals.is_empty();
        let compute = normals.computed(given).is_some();
        let layout = Layout {
            normals: given && !compute && normals != Normals::None,
            uvs: !first.uvs.is_empty(),
            colors: !v.colors.is_empty(),
            materials: !first.materials.is_empty(),
        };
        let spool = Spool::create(temp, cells.count, layout)?;
        let n = v.positions.len();
        Ok(Distribute {
            cells,
            spool,
            layout,
            weld: weld(v.positions),
            owner: vec![0; n],
            compute_normals: compute,
            lo: Vec3::splat(f32::MAX),
            hi: Vec3::splat(f32::MIN),
            edges: Vec::new(),
            stride: (faces / 65_536).max(1),
            seen: 0,
            replaced_normals: 0,
            replaced_uvs: 0,
        })
    }

    fn push(&mut self, v: &Vertices, faces: &Faces) -> Result<()> {
        for (f, t) in faces.triangles.iter().enumerate() {
            let p = t.map(|i| v.positions[i as usize]);
            for q in p {
                self.lo = self.lo.min(q);
                self.hi = self.hi.max(q);
            }
            if self.seen % self.stride == 0 {
                let lengths = (0..3).map(|k| p[k].as_dvec3().distance(p[(k + 1) % 3].as_dvec3()));
                self.edges.extend(lengths.filter(|d| *d > 0.0 && d.is_finite()));
            }
            self.seen += 1;
            let cell = self.cells.of((p[0] + p[1] + p[2]) / 3.0);
            let mut n = match faces.normals.get(f) {
                _ if !self.layout.normals => [Vec3::ZERO; 3],
                Some(&corners) => corners,
                None => t.map(|i| v.normals[i as usize]),
            };
            let c = if self.layout.colors { t.map(|i| v.colors[i as usize]) } else { [[0; 4]; 3] };
            let mut uvs = faces.uvs.get(f).copied().unwrap_or([glam::Vec2::ZERO; 3]);
            let (normals, uv_count) = crate::import::replace_unusable_face_corners(v.positions, t, &mut n, &mut uvs);
            self.replaced_normals += normals;
            self.replaced_uvs += uv_count;
            let material = faces.materials.get(f).copied().unwrap_or(0);
            let welded = t.map(|i| self.weld[i as usize]);
            for &i in &welded {
                let o = &mut self.owner[i as usize];
                *o = match *o {
                    0 => cell as u16 + 1,
                    x if x == cell as u16 + 1 => x,
                    _ => SHARED,
                };
            }
            self.spool.push(cell, &cells::FaceRecord { ids: welded, positions: p, normals: n, uvs, colors: c, material })?;
        }
        Ok(())
    }

    /// The grid: the step the input's bounds need (as the in-core build's), the origin lowered on
    /// each axis by whole steps to centre the bounds in the grid's span, so that a simplified
    /// vertex straying outside the input's bounds (pieces do not know the coarse levels' bounds
    /// beforehand) stays on the grid where it can.
    /// `bits`: the grid's bits, 0 for format 3's automatic choice from the sampled edges.
    fn finish(mut self, bits: u32) -> Result<Distributed> {
        let extent = (self.hi - self.lo).as_dvec3().max_element();
        let bits = if bits == 0 { crate::quantize::grid_bits_for(extent, &mut self.edges) } else { bits };
        let mut grid = Grid::fit(self.lo, self.hi, bits);
        let span = grid.step * grid.last() as f64;
        for k in 0..3 {
            let extent = (self.hi[k] as f64 - self.lo[k] as f64).max(0.0);
            grid.origin[k] -= ((span - extent) / 2.0 / grid.step).floor() * grid.step;
        }
        let mut shared = vec![0u64; self.owner.len().div_ceil(64)];
        for (i, _) in self.owner.iter().enumerate().filter(|(_, &o)| o == SHARED) {
            shared[i / 64] |= 1 << (i % 64);
        }
        Ok(Distributed { grid, layout: self.layout, vertices: self.owner.len() as u64, shared, spooled: self.spool.finish()? })
    }
}

/// Per vertex, the first vertex at the same position (+0 = −0), found by sorting.
fn weld(positions: &[Vec3]) -> Vec<u32> {
    use rayon::prelude::*;
    let key = |i: u32| crate::levels::position_key(positions[i as usize]);
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.par_sort_unstable_by_key(|&i| (key(i), i));
    let mut weld = vec![0u32; positions.len()];
    for run in order.chunk_by(|&a, &b| key(a) == key(b)) {
        for &i in run {
            weld[i as usize] = run[0];
        }
    }
    weld
}

/// Give freed heap memory back to the system (glibc keeps it otherwise, and the next cell or the
/// merge would then count against the budget twice).
pub(crate) fn release_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages of the allocator's own heap to the system.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Have glibc serve allocations of 256 KiB or more by mappings of their own, which go back to the
/// system when freed. By default it raises that threshold whenever such a block is freed, after
/// which the pieces' big arrays come from the heap, which `malloc_trim` returns only in part
/// where allocations that outlive a piece (node records, open edges) lie among them: the peak
/// then grows with the number of pieces (notes/partition.md). This lasts for the whole process.
fn frugal_allocation() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes a tunable of the allocator, under the allocator's own lock.
    // Should it refuse (it returns 0), the build goes on with the default.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 256 << 10);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_capped_for_speed_unless_there_would_be_too_many() {
        let b = Budget { memory: 64 << 30, temp: None, threads: 2, cell_faces: 0, frugal: true };
        assert_eq!(cell_faces(&b, 5_000_000), FAST_CELL_FACES);
        assert_eq!(cell_faces(&b, 1_000_000_000), 1_000_000_000u64.div_ceil(MAX_CELLS));
        let tight = Budget { memory: 256 << 20, ..b.clone() };
        assert!(cell_faces(&tight, 5_000_000) < FAST_CELL_FACES);
    }

    #[test]
    fn a_budget_for_speed_depends_on_the_input_alone_and_fits_its_cells_in_memory() {
        let (a, b) = (Budget::for_speed(2 << 30, 3_000_000), Budget::for_speed(64 << 30, 3_000_000));
        assert_eq!(a.cell_faces, FAST_CELL_FACES);
        assert_eq!(a.cell_faces, b.cell_faces);
        assert_eq!(Budget::for_speed(64 << 30, 1_002_252).cell_faces, 501_126, "two cells, not three");
        assert_eq!(Budget::for_speed(64 << 30, 2_600_000).cell_faces, 433_334, "six cells");
        let per_cell = FAST_CELL_FACES * IN_CORE_BYTES_PER_FACE * 10 / 6;
        assert!(a.threads as u64 * per_cell + 3_000_000 * HELD_BYTES_PER_FACE <= 2 << 30 || a.threads == 1);
        assert_eq!(Budget::for_speed(512 << 20, 1_000_000).threads, 1);
    }
}
