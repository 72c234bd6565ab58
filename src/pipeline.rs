//! The conversion, top-down in one place: import → normals (if missing) → texture levels → group →
//! simplify per level → write.

use crate::dag::{self, DagParams};
use crate::error::Result;
use crate::format::WriteSummary;
use crate::hierarchy::{self, HierarchyParams};
use crate::import::{import_with, ImportOptions};
use crate::levels::{self, LevelParams};
use crate::mesh::Adjacency;
use crate::normals::smooth_normals;
use crate::write::{self, Encoding, Precision, WriteOptions};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// What a conversion is built with.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvertOptions {
    pub hierarchy: HierarchyParams,
    pub levels: LevelParams,
    pub normals: Normals,
    /// How node geometry is stored (format 2 or 3).
    pub encoding: Encoding,
    /// In memory, or partitioned into cells on disk ([`crate::partition`]).
    pub build: Build,
    /// Bytes of memory the partitioned build stays within; 0: half the machine's
    /// ([`crate::partition::default_memory`]).
    pub memory: u64,
    /// Folder for the partitioned build's cell files (the system's temporary folder if none).
    pub temp: Option<std::path::PathBuf>,
    /// Build a DAG of nodes ([`crate::dag`]) and write format 4 (strata-v4.md), in memory.
    pub dag: bool,
}

/// Which build makes the levels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Build {
    /// Partitioned when the input is a file the partitioned build streams (PLY, OBJ, glTF, GLB)
    /// and either an in-core build would not fit in `memory`
    /// ([`crate::partition::IN_CORE_BYTES_PER_FACE`]) or, on a machine of several cores, it has at
    /// least [`crate::partition::PARALLEL_FACES`] faces and memory for two cells at once (there
    /// the partitioned build is faster); else in memory.
    Auto,
    /// Always in memory.
    InCore,
    /// Always partitioned (a file the partitioned build streams).
    Partitioned,
}

impl Default for ConvertOptions {
    fn default() -> Self {
        ConvertOptions {
            hierarchy: HierarchyParams::default(),
            levels: LevelParams::default(),
            normals: Normals::Auto { crease_angle: 60f32.to_radians() },
            encoding: Encoding::V3(Precision::default()),
            build: Build::Auto,
            memory: 0,
            temp: None,
            dag: false,
        }
    }
}

/// Which normals the chunk file stores.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Normals {
    /// The input's normals; when it has none, smooth ones as [`Normals::Geometry`] makes them.
    Auto { crease_angle: f32 },
    /// The input's normals, if any.
    Input,
    /// None: the smallest file, drawn flat-shaded.
    None,
    /// Smooth normals of each level's own geometry, split at edges sharper than `crease_angle`
    /// radians ([`crate::normals::smooth_normals`] decides the splits), the input's dropped:
    /// stored as format 3's readers predict them ([`crate::derived_normals`]), at a few
    /// hundredths of a bit where a node holds all of a vertex's faces.
    Geometry { crease_angle: f32 },
}

impl Normals {
    /// The crease angle of the smooth normals strata computes for an input with or without normals
    /// of its own, which the file then stores as each level's own ([`crate::derived_normals`]);
    /// `None` where it stores the input's normals, or none.
    pub fn computed(self, input_has_normals: bool) -> Option<f32> {
        match self {
            Normals::Geometry { crease_angle } => Some(crease_angle),
            Normals::Auto { crease_angle } if !input_has_normals => Some(crease_angle),
            _ => None,
        }
    }
}

/// Progress of a long conversion, reported stage by stage.
pub trait Progress {
    /// A stage begins; `steps` is how many [`Progress::step`] calls it will make (0 if unknown).
    fn stage(&mut self, name: &str, steps: u64);
    fn step(&mut self);
}

/// Progress that reports nothing.
pub struct Silent;

impl Progress for Silent {
    fn stage(&mut self, _: &str, _: u64) {}
    fn step(&mut self) {}
}

/// Wall-clock milliseconds per stage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StageTimes {
    pub import_ms: f64,
    /// Decoding the images and making their levels.
    pub texture_ms: f64,
    pub group_ms: f64,
    pub simplify_ms: f64,
    pub write_ms: f64,
}

/// What a conversion did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Converted {
    pub summary: WriteSummary,
    pub times: StageTimes,
    pub warnings: Vec<String>,
    /// The cells of a partitioned build; `None` when built in memory.
    pub cells: Option<usize>,
}

/// What the partitioned build needs when it is the one to run: its budget, the input's streaming
/// reader and what that says of the file.
type Partitioned = (crate::partition::Budget, &'static crate::import::stream::Streaming, crate::import::stream::Declared);

/// Which build runs (see [`Build`]): `None` for the in-core build, with a warning in `warnings`
/// when that is chosen for a file the partitioned build cannot take and memory may not hold.
fn partitioned(input: &Path, import: &ImportOptions, opts: &ConvertOptions, warnings: &mut Vec<String>) -> Result<Option<Partitioned>> {
    use crate::error::Error;
    use crate::partition::{Budget, IN_CORE_BYTES_PER_FACE, PARALLEL_FACES};
    let memory = if opts.memory > 0 { opts.memory } else { crate::partition::default_memory() };
    let with_temp = |mut b: Budget| {
        b.temp = opts.temp.clone();
        b
    };
    let reader = crate::partition::streaming(input, import.format);
    match opts.build {
        Build::InCore => Ok(None),
        Build::Auto => {
            let Some(reader) = reader else { return Ok(None) };
            // Asked of every file, small ones too: a .gltf's buffers may lie in other files.
            let fits = |faces: u64| faces.saturating_mul(IN_CORE_BYTES_PER_FACE) <= memory;
            Ok(match (reader.declared)(input) {
                Ok(d) if fits(d.triangles) => {
                    // Cells built for speed must run at least two at once to beat the in-core build.
                    let fast = (d.triangles >= PARALLEL_FACES && d.refused.is_none())
                        .then(|| Budget::for_speed(memory, d.triangles))
                        .filter(|b| b.threads > 1);
                    fast.map(|b| (with_temp(b), reader, d))
                }
                Ok(crate::import::stream::Declared { triangles, refused: Some(why) }) => {
                    warnings.push(format!(
                        "about {triangles} triangles need about {} MiB in memory, more than the {} MiB of --memory, but {why}; built in memory",
                        triangles.saturating_mul(IN_CORE_BYTES_PER_FACE) >> 20,
                        memory >> 20
                    ));
                    None
                }
                Ok(d) => Some((with_temp(Budget::new(memory)), reader, d)),
                Err(_) => None,
            })
        }
        Build::Partitioned => {
            let Some(reader) = reader else {
                return Err(Error::invalid(
                    input,
                    None,
                    format!(
                        "the partitioned build reads {} files; convert this one in memory (without --partitioned)",
                        crate::import::Format::streaming_list()
                    ),
                ));
            };
            let d = (reader.declared)(input)?;
            match d.refused {
                Some(why) => Err(Error::invalid(input, None, format!("{why}; convert it in memory (without --partitioned)"))),
                None => Ok(Some((with_temp(Budget::new(memory)), reader, d))),
            }
        }
    }
}

/// Convert the mesh file `input`, read with `import`, into the chunk file `output`, which appears
/// only when complete. An output that is a directory or the input itself is refused before any work.
pub fn convert(
    input: &Path,
    import: &ImportOptions,
    output: &Path,
    opts: &ConvertOptions,
    progress: &mut dyn Progress,
) -> Result<Converted> {
    let mut times = StageTimes::default();
    let mut clock = Instant::now();
    let mut lap = |slot: &mut f64| {
        *slot = clock.elapsed().as_secs_f64() * 1e3;
        clock = Instant::now();
    };

    let mut choice_warnings = Vec::new();
    if let Some((budget, reader, declared)) = partitioned(input, import, opts, &mut choice_warnings)? {
        let input = crate::partition::Input { path: input, import, reader, declared };
        let mut converted = crate::partition::convert(input, output, opts, &budget, progress)?;
        converted.warnings.extend(top_warning(&converted.summary, opts));
        return Ok(converted);
    }
    crate::atomic::protect(input);
    crate::atomic::check_output(output)?;
    progress.stage("import", 0);
    let mut imported = import_with(input, import)?;
    let computed = opts.normals.computed(!imported.mesh.normals.is_empty());
    match computed {
        Some(crease_angle) => imported.mesh.normals = smooth_normals(&imported.mesh, crease_angle),
        None if opts.normals == Normals::None => imported.mesh.normals.clear(),
        None => {}
    }
    lap(&mut times.import_ms);

    let textured = imported.mesh.images.len() as u64;
    progress.stage("textures", textured);
    let m = &mut imported.mesh;
    let images =
        crate::texture::pyramid::prepare(&mut m.materials, &m.images, !m.uvs.is_empty(), &mut imported.warnings, &mut || progress.step());
    // The levels hold the images from here on.
    imported.mesh.images.clear();
    lap(&mut times.texture_ms);

    let mesh = &imported.mesh;
    progress.stage("group", 0);
    let adjacency = Adjacency::build(mesh);
    // A DAG takes only level 0's groups (and the culling clusters) from the grouping.
    let mut h = hierarchy::build_levels(mesh, &adjacency, &opts.hierarchy, opts.dag.then_some(1));
    drop(adjacency);
    lap(&mut times.group_ms);

    progress.stage("simplify", levels::expected_levels(mesh.face_count(), h.levels.len(), &opts.levels) as u64);
    let (metres_per_unit, georef) = (imported.metres_per_unit, imported.georef.take());
    let built = if opts.dag {
        let params = DagParams { ratio: opts.levels.ratio, top_faces: opts.levels.top_faces };
        let level0 = h.levels[0].face_group.clone();
        Err(dag::build(imported.mesh, &level0, &params, &mut |_, _| progress.step()))
    } else {
        Ok(levels::build(imported.mesh, &mut h, &opts.levels, &mut |_| progress.step()))
    };
    lap(&mut times.simplify_ms);

    progress.stage("write", 0);
    let write_opts = WriteOptions {
        metres_per_unit: metres_per_unit.unwrap_or(0.0),
        params: opts.hierarchy,
        level_ratio: opts.levels.ratio,
        georef,
        encoding: opts.encoding,
        derive_normals: computed.is_some(),
        images: images.into(),
        ..WriteOptions::default()
    };
    // The tree's levels, or the DAG.
    let summary = match &built {
        Ok(lv) => write::write(output, &h, lv, &write_opts)?,
        Err(d) => dag::write::write(output, d, &h.clusters, &write_opts)?,
    };
    lap(&mut times.write_ms);

    choice_warnings.extend(imported.warnings);
    choice_warnings.extend(top_warning(&summary, opts));
    Ok(Converted { summary, times, warnings: choice_warnings, cells: None })
}

/// A warning when the top level kept more faces than `--top-faces`: the levels stopped shrinking
/// (a viewer then opens the file with all of the top level at once).
fn top_warning(summary: &crate::format::WriteSummary, opts: &ConvertOptions) -> Option<String> {
    let top = summary.levels.last()?.faces;
    (top > opts.levels.top_faces as u64).then(|| {
        let hint = if opts.dag { "" } else { "; --dag lets small separate pieces leave coarse levels" };
        format!(
            "the top level holds {top} faces, more than --top-faces {}: the levels stopped shrinking (many separate pieces?){hint}",
            opts.levels.top_faces
        )
    })
}
