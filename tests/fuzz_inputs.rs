//! The fuzz targets' code paths (`fuzz/`), bounded so that `cargo test --release` can afford them:
//! the same seed files, mutated by proptest (bits flipped, bytes set to 0, 0xFF, 0x7F or 0x80,
//! truncation, ranges duplicated or deleted, two seeds spliced, numbers in text replaced by huge,
//! negative, NaN or infinite ones; chunk files and GLB containers made consistent again half the
//! time, so that the damage gets past checksums and lengths), fed to the chunk-file reader and to
//! the OBJ, PLY and glTF importers. No input may panic, allocate more than [`ALLOCATION_LIMIT`] at
//! once, or take more than [`SLOW_CASE`].
//!
//! Also runs every input kept under `fuzz/regressions/<target>/`. Inputs under
//! `fuzz/regressions/<target>/unfixed/` reproduce known, not yet fixed bugs: they run only with
//! `cargo test --release --test fuzz_inputs -- --ignored`, and a panic at one of the places listed
//! in [`KNOWN_UNFIXED`] is counted and printed but does not fail the mutation tests.
//!
//! `PROPTEST_CASES` overrides the number of cases per code path.

use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::{Config, TestCaseError, TestRunner};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::Write;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::{Duration, Instant};
use strata::fuzzing::{import_gltf, read_everything, ImportDir};

/// No single allocation for inputs of these sizes (at most ~170 kB) may be larger.
const ALLOCATION_LIMIT: usize = 64 << 20;
/// Allocations larger than this are refused outright (the process aborts, naming the input):
/// letting them through could take the machine's memory before the case ends.
const REFUSED: usize = 1 << 30;
/// No case may take longer (release build; a debug build is slower but well within it).
const SLOW_CASE: Duration = Duration::from_secs(10);

/// Panics that mutated inputs may reach and that are known and not fixed yet: what, and where the
/// panic is raised (none now). Remove an entry once its bug is fixed;
/// its inputs in `fuzz/regressions/<target>/unfixed/` then move up a folder.
const KNOWN_UNFIXED: &[(&str, &str)] = &[];

thread_local! {
    /// Where this thread's last panic was raised.
    static PANICKED_AT: std::cell::RefCell<String> = const { std::cell::RefCell::new(String::new()) };
    /// The largest single allocation of this thread since the case began.
    static LARGEST: Cell<usize> = const { Cell::new(0) };
    /// The description of the case this thread runs, for an allocation refused outright.
    static CASE: Cell<(*const u8, usize)> = const { Cell::new((std::ptr::null(), 0)) };
}

/// Records each thread's largest allocation; refuses (and names the case of) huge ones.
struct Watch;

fn note(size: usize) -> bool {
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
    if size <= REFUSED {
        return true;
    }
    let _ = CASE.try_with(|c| {
        let (p, n) = c.get();
        if !p.is_null() {
            // SAFETY: `run_case` keeps the description alive while it is set here.
            let desc = unsafe { std::slice::from_raw_parts(p, n) };
            let mut err = std::io::stderr();
            let _ = err.write_all(b"allocation of more than 1 GiB refused; input: ");
            let _ = err.write_all(desc);
            let _ = err.write_all(b"\n");
        }
    });
    false
}

unsafe impl GlobalAlloc for Watch {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if !note(l.size()) {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        if !note(l.size()) {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        if !note(new_size) {
            return std::ptr::null_mut();
        }
        unsafe { System.realloc(p, l, new_size) }
    }
}

#[global_allocator]
static WATCH: Watch = Watch;

/// The four code paths, as the fuzz targets name them.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Target {
    Reader,
    Obj,
    Ply,
    Gltf,
    /// Elevation grids: each seed's name gives its extension.
    Dem,
}

impl Target {
    fn name(self) -> &'static str {
        match self {
            Target::Reader => "reader",
            Target::Obj => "obj",
            Target::Ply => "ply",
            Target::Gltf => "gltf",
            Target::Dem => "dem",
        }
    }
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A seed: a name for descriptions and its bytes.
type Seed = (String, Vec<u8>);

/// The seeds of `fuzz/seed.sh`, read from `fixtures/` and `fuzz/seeds/`; the chunk files are
/// converted here with the library, with the same options as the script gives the CLI.
fn seeds(target: Target) -> &'static [Seed] {
    static SEEDS: OnceLock<[Vec<Seed>; 5]> = OnceLock::new();
    let all = SEEDS.get_or_init(|| {
        let fixture = |name: &str| (name.to_string(), read(&root().join("fixtures").join(name)));
        let own = |name: &str| (name.to_string(), read(&root().join("fuzz/seeds").join(name)));
        let obj = ["cube.obj", "icosphere.obj", "nonmanifold.obj", "open_grid.obj", "cad_part.obj"].map(fixture).to_vec();
        let ply = vec![fixture("colored_sphere.ply"), own("quad_ascii.ply"), own("tetra_strips_be.ply")];
        let gltf = vec![fixture("two_materials.glb"), own("tetra_datauri.gltf")];
        let reader = chunk_files();
        [reader, obj, ply, gltf, dem_seeds()]
    });
    &all[target as usize]
}

/// Small elevation grids with voids: an ESRI ASCII grid, an SRTM tile and a 16-bit PNG. The GeoTIFF
/// ([`geotiff_seed`]) is left out of mutation: the `tiff` crate (0.11) allocates a tag's declared
/// count while opening, before a caller's limits apply, so a flipped count in a 433-byte file makes
/// it allocate 64 to 224 MB at once (bounded by the crate, but past this test's limit).
fn dem_seeds() -> Vec<Seed> {
    let h = |i: usize, j: usize| 100.0 + 30.0 * ((i as f64) * 0.8).sin() + 20.0 * ((j as f64) * 0.6).cos();
    let (cols, rows) = (7usize, 6usize);
    let mut asc = format!("ncols {cols}\nnrows {rows}\nxllcorner 500000\nyllcorner 4000000\ncellsize 30\nNODATA_value -9999\n");
    for i in 0..rows {
        let row: Vec<String> = (0..cols).map(|j| if (i, j) == (2, 3) { "-9999".into() } else { format!("{:.1}", h(i, j)) }).collect();
        asc += &(row.join(" ") + "\n");
    }
    let n = 6;
    let hgt: Vec<u8> = (0..n * n).flat_map(|k| if k == 14 { i16::MIN } else { h(k / n, k % n) as i16 }.to_be_bytes()).collect();
    let mut png_bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png_bytes, cols as u32, rows as u32);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let data: Vec<u8> = (0..cols * rows).flat_map(|k| (h(k / cols, k % cols) as u16).to_be_bytes()).collect();
        enc.write_header().unwrap().write_image_data(&data).unwrap();
    }
    vec![("hill.asc".into(), asc.into_bytes()), ("N46E007.hgt".into(), hgt), ("hill.png".into(), png_bytes)]
}

/// A small GeoTIFF in degrees with one void.
fn geotiff_seed() -> Seed {
    let h = |i: usize, j: usize| 100.0 + 30.0 * ((i as f64) * 0.8).sin() + 20.0 * ((j as f64) * 0.6).cos();
    let (cols, rows) = (7usize, 6usize);
    let mut tif = std::io::Cursor::new(Vec::new());
    {
        use tiff::encoder::{colortype, TiffEncoder};
        let mut enc = TiffEncoder::new(&mut tif).unwrap();
        let mut img = enc.new_image::<colortype::GrayI16>(cols as u32, rows as u32).unwrap();
        let dir = img.encoder();
        dir.write_tag(tiff::tags::Tag::ModelPixelScaleTag, &[0.001f64, 0.001, 0.0][..]).unwrap();
        dir.write_tag(tiff::tags::Tag::ModelTiepointTag, &[0.0f64, 0.0, 0.0, 7.0, 46.0, 0.0][..]).unwrap();
        dir.write_tag(tiff::tags::Tag::GeoKeyDirectoryTag, &[1u16, 1, 0, 2, 1024, 0, 1, 2, 2048, 0, 1, 4326][..]).unwrap();
        dir.write_tag(tiff::tags::Tag::GdalNodata, "-32768").unwrap();
        let data: Vec<i16> = (0..cols * rows).map(|k| if k == 9 { i16::MIN } else { h(k / cols, k % cols) as i16 }).collect();
        img.write_data(&data).unwrap();
    }
    ("hill.tif".into(), tif.into_inner())
}

/// The extension of the seed a case description starts with (`hill.asc with [...]`).
fn seed_ext(desc: &str) -> &str {
    desc.split_whitespace().next().and_then(|n| n.rsplit_once('.')).map_or("", |(_, e)| e)
}

/// Chunk files converted from small fixtures, as `fuzz/seed.sh` makes them.
fn chunk_files() -> Vec<Seed> {
    use strata::hierarchy::HierarchyParams;
    use strata::levels::LevelParams;
    use strata::pipeline::{convert, ConvertOptions, Normals, Silent};
    use strata::write::{Encoding, Precision};
    let dir = ImportDir::new().expect("a scratch folder");
    let tiny = ConvertOptions {
        hierarchy: HierarchyParams { cluster_faces: 2, leaf_faces: 4, growth: 2, top_groups: 1, ..HierarchyParams::default() },
        levels: LevelParams { top_faces: 2, ..LevelParams::default() },
        ..ConvertOptions::default()
    };
    let plain = ConvertOptions::default();
    let no_normals = ConvertOptions { normals: Normals::None, ..ConvertOptions::default() };
    let v2 = |o: &ConvertOptions| ConvertOptions { encoding: Encoding::V2, ..o.clone() };
    let v3 = |o: &ConvertOptions| ConvertOptions { encoding: Encoding::V3(Precision::default()), ..o.clone() };
    let inputs = [
        ("fixtures/cube.obj", "cube", v2(&plain)),
        ("fixtures/cube.obj", "cube_levels", v2(&tiny)),
        ("fixtures/nonmanifold.obj", "nonmanifold", v2(&no_normals)),
        ("fixtures/two_materials.glb", "two_materials", v2(&tiny)),
        ("fuzz/seeds/quad_ascii.ply", "quad_colors_uvs", v2(&plain)),
        ("fuzz/seeds/tetra_datauri.gltf", "tetra_all_attributes", v2(&tiny)),
        ("fixtures/cube.obj", "cube_levels_v3", v3(&tiny)),
        ("fixtures/nonmanifold.obj", "nonmanifold_v3", v3(&no_normals)),
        ("fixtures/two_materials.glb", "two_materials_v3", v3(&tiny)),
        ("fuzz/seeds/quad_ascii.ply", "quad_colors_uvs_v3", v3(&plain)),
        ("fuzz/seeds/tetra_datauri.gltf", "tetra_all_attributes_v3", v3(&tiny)),
    ];
    let mut files: Vec<Seed> = inputs
        .iter()
        .map(|(input, name, opts)| {
            let input = root().join(input);
            let name = format!("{name}.strata");
            let out = dir.path().join(&name);
            convert(&input, &Default::default(), &out, opts, &mut Silent).unwrap_or_else(|e| panic!("{}: {e}", input.display()));
            (name, read(&out))
        })
        .collect();
    // Images (format 2.2): the textured golden vector.
    files.push(("textured.strata".into(), read(&root().join("format-spec/vectors/textured.strata"))));
    files
}

/// Numbers that text formats should refuse or survive (and a few ordinary ones, which keep the
/// file readable so that the code behind the first checks runs too).
const NUMBERS: &[&str] = &[
    "0.5",
    "2",
    "-3.25",
    "1e3",
    "7",
    "0",
    "-0",
    "-1",
    "-2",
    "1e39",
    "-1e39",
    "3.4028236e38",
    "1e-45",
    "1e308",
    "1e309",
    "NaN",
    "nan",
    "-nan",
    "inf",
    "-inf",
    "infinity",
    "65535",
    "65536",
    "2147483647",
    "2147483648",
    "-2147483649",
    "4294967295",
    "4294967296",
    "18446744073709551616",
    "99999999999999999999999999",
    "0x10",
    "1.",
    ".",
    "-",
    "1e",
    "",
];

/// A byte position: within the first KiB (headers, the chunk file's skeleton) or anywhere.
#[derive(Clone, Copy, Debug)]
struct Pos {
    head: bool,
    at: Index,
}

impl Pos {
    fn of(self, len: usize) -> usize {
        self.at.index(if self.head { len.min(1024) } else { len })
    }
}

fn pos() -> impl Strategy<Value = Pos> {
    (any::<bool>(), any::<Index>()).prop_map(|(head, at)| Pos { head, at })
}

#[derive(Clone, Debug)]
enum Mutation {
    FlipBit {
        at: Pos,
        bit: u8,
    },
    Set {
        at: Pos,
        value: u8,
    },
    Truncate {
        at: Pos,
    },
    Duplicate {
        at: Pos,
        len: usize,
        to: Pos,
    },
    Delete {
        at: Pos,
        len: usize,
    },
    /// This seed up to `at`, then another seed of the same code path from `from` on.
    Splice {
        other: Index,
        at: Pos,
        from: Pos,
    },
    /// The `nth` number of the text replaced.
    Number {
        nth: Index,
        to: &'static str,
    },
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        3 => (pos(), 0u8..8).prop_map(|(at, bit)| Mutation::FlipBit { at, bit }),
        3 => (pos(), prop::sample::select(vec![0u8, 0xFF, 0x7F, 0x80])).prop_map(|(at, value)| Mutation::Set { at, value }),
        1 => pos().prop_map(|at| Mutation::Truncate { at }),
        1 => (pos(), 1usize..300, pos()).prop_map(|(at, len, to)| Mutation::Duplicate { at, len, to }),
        1 => (pos(), 1usize..300).prop_map(|(at, len)| Mutation::Delete { at, len }),
        1 => (any::<Index>(), pos(), pos()).prop_map(|(other, at, from)| Mutation::Splice { other, at, from }),
        3 => (any::<Index>(), prop::sample::select(NUMBERS)).prop_map(|(nth, to)| Mutation::Number { nth, to }),
    ]
}

/// A case: a seed, what happens to it, and whether the container is made consistent again (chunk
/// files: every checksum and the file size recomputed afterwards; GLB files: the mutations applied
/// to the JSON chunk and the lengths recomputed).
#[derive(Clone, Debug)]
struct Case {
    seed: Index,
    mutations: Vec<Mutation>,
    reseal: bool,
}

fn case() -> impl Strategy<Value = Case> {
    (any::<Index>(), prop::collection::vec(mutation(), 1..4), any::<bool>()).prop_map(|(seed, mutations, reseal)| Case {
        seed,
        mutations,
        reseal,
    })
}

/// Byte ranges of the numbers in `bytes` (runs of digits, signs, dots and exponents that hold a
/// digit and start a word), in the first 256 KiB.
fn numbers(bytes: &[u8]) -> Vec<(usize, usize)> {
    let part = |b: u8| b.is_ascii_digit() || matches!(b, b'-' | b'+' | b'.' | b'e' | b'E');
    let bytes = &bytes[..bytes.len().min(256 << 10)];
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let starts = part(bytes[i]) && (i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || part(bytes[i - 1])));
        if !starts {
            i += 1;
            continue;
        }
        let end = bytes[i..].iter().position(|&b| !part(b)).map_or(bytes.len(), |k| i + k);
        if bytes[i..end].iter().any(u8::is_ascii_digit) {
            out.push((i, end));
        }
        i = end;
    }
    out
}

fn apply(m: &Mutation, b: &mut Vec<u8>, seeds: &[Seed]) {
    let len = b.len();
    match *m {
        _ if len == 0 => {}
        Mutation::FlipBit { at, bit } => b[at.of(len)] ^= 1 << bit,
        Mutation::Set { at, value } => b[at.of(len)] = value,
        Mutation::Truncate { at } => b.truncate(at.of(len)),
        Mutation::Duplicate { at, len: n, to } => {
            let start = at.of(len);
            let piece = b[start..(start + n).min(len)].to_vec();
            let to = to.of(len);
            b.splice(to..to, piece);
        }
        Mutation::Delete { at, len: n } => {
            let start = at.of(len);
            b.drain(start..(start + n).min(len));
        }
        Mutation::Splice { other, at, from } => {
            let other = &seeds[other.index(seeds.len())].1;
            b.truncate(at.of(len));
            if !other.is_empty() {
                b.extend_from_slice(&other[from.of(other.len())..]);
            }
        }
        Mutation::Number { nth, to } => {
            let found = numbers(b);
            if !found.is_empty() {
                let (s, e) = found[nth.index(found.len())];
                b.splice(s..e, to.bytes());
            }
        }
    }
}

/// Record where each panic is raised, then report it as usual.
fn watch_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let report = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let at = info.location().map_or(String::new(), |l| format!("{}:{}", l.file(), l.line()));
            let _ = PANICKED_AT.try_with(|p| *p.borrow_mut() = at);
            report(info);
        }));
    });
}

/// The known, unfixed bug a panic raised at `at` is, if any.
fn known_unfixed(at: &str) -> Option<&'static str> {
    KNOWN_UNFIXED.iter().find(|(_, place)| at.contains(place)).map(|(what, _)| *what)
}

/// What one case did.
struct Outcome {
    /// It returned (rather than panicked).
    returned: bool,
    /// Where it panicked, if it did.
    panicked_at: String,
    /// The reader opened the bytes and decoded a node, or the importer imported them.
    deep: bool,
    largest: usize,
    took: Duration,
}

/// A GLB file's JSON and first BIN chunk.
fn glb_parts(b: &[u8]) -> Option<(Vec<u8>, Vec<u8>)> {
    let u32_at = |at: usize| Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?) as usize);
    if !b.starts_with(b"glTF") || b.get(16..20)? != b"JSON" {
        return None;
    }
    let json_end = 20 + u32_at(12)?;
    let json = b.get(20..json_end)?.to_vec();
    let bin = match (u32_at(json_end), b.get(json_end + 4..json_end + 8)) {
        (Some(n), Some(b"BIN\0")) => b.get(json_end + 8..json_end + 8 + n)?.to_vec(),
        _ => Vec::new(),
    };
    Some((json, bin))
}

/// A GLB file of `json` (padded with spaces) and `bin` (with zeros), its lengths consistent.
fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let mut json = json.to_vec();
    json.resize(json.len().next_multiple_of(4), b' ');
    let mut bin = bin.to_vec();
    bin.resize(bin.len().next_multiple_of(4), 0);
    let total = 12 + 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    out
}

/// The code path of `target` on `bytes`. `desc` names the input should it allocate too much.
fn run_case(target: Target, dir: &ImportDir, bytes: &[u8], desc: &str) -> Outcome {
    CASE.with(|c| c.set((desc.as_ptr(), desc.len())));
    LARGEST.with(|l| l.set(0));
    let start = Instant::now();
    let result = catch_unwind(AssertUnwindSafe(|| match target {
        Target::Reader => read_everything(bytes).nodes_decoded > 0,
        Target::Obj => dir.import(bytes, "obj").is_ok(),
        Target::Ply => dir.import(bytes, "ply").is_ok(),
        Target::Gltf => import_gltf(dir, bytes).is_ok(),
        Target::Dem => dir.import(bytes, seed_ext(desc)).is_ok(),
    }));
    let took = start.elapsed();
    CASE.with(|c| c.set((std::ptr::null(), 0)));
    let panicked_at = if result.is_err() { PANICKED_AT.with(|p| p.borrow().clone()) } else { String::new() };
    Outcome { returned: result.is_ok(), panicked_at, deep: result.unwrap_or(false), largest: LARGEST.with(Cell::get), took }
}

/// How a case that did not fail ended.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Passed {
    /// Refused early, or got past the first checks (see [`Outcome::deep`]).
    Shallow,
    Deep,
    /// Panicked at a place [`KNOWN_UNFIXED`] lists (when `tolerate` is set).
    Known,
}

/// Run the case; an error names what went wrong.
fn check(target: Target, dir: &ImportDir, bytes: &[u8], desc: &str, tolerate: bool) -> Result<Passed, String> {
    watch_panics();
    let out = run_case(target, dir, bytes, desc);
    if !out.returned {
        return match known_unfixed(&out.panicked_at) {
            Some(_) if tolerate => Ok(Passed::Known),
            Some(what) => Err(format!("{} panicked at {} (known: {what}) on {desc}", target.name(), out.panicked_at)),
            None => Err(format!("{} panicked at {} on {desc}", target.name(), out.panicked_at)),
        };
    }
    if out.largest > ALLOCATION_LIMIT {
        return Err(format!("{} allocated {} bytes at once on {desc}", target.name(), out.largest));
    }
    if out.took > SLOW_CASE {
        return Err(format!("{} took {:?} on {desc}", target.name(), out.took));
    }
    Ok(if out.deep { Passed::Deep } else { Passed::Shallow })
}

/// Mutated seeds through `target`'s code path, `cases` of them unless `PROPTEST_CASES` says.
fn mutated(target: Target, cases: u32) {
    let seeds = seeds(target);
    let dir = ImportDir::new().expect("a scratch folder");
    let cases = if std::env::var_os("PROPTEST_CASES").is_some() { Config::default().cases } else { cases };
    let config = Config { cases, failure_persistence: None, ..Config::default() };
    let mut runner = TestRunner::new(config);
    let start = Instant::now();
    let deep = Cell::new(0u32);
    let known = Cell::new(0u32);
    let result = runner.run(&case(), |c| {
        let (name, seed) = &seeds[c.seed.index(seeds.len())];
        let mut bytes = seed.clone();
        let parts = glb_parts(seed).filter(|_| c.reseal && target == Target::Gltf);
        let reseal = c.reseal && (target == Target::Reader || parts.is_some());
        if let Some((mut json, bin)) = parts {
            // The mutations go to the JSON chunk, and the container is rebuilt around it.
            for m in &c.mutations {
                apply(m, &mut json, seeds);
            }
            bytes = glb(&json, &bin);
        } else {
            for m in &c.mutations {
                apply(m, &mut bytes, seeds);
            }
            if reseal {
                strata::fuzzing::reseal(&mut bytes);
            }
        }
        let resealed = match (target, reseal) {
            (Target::Gltf, true) => ", to the JSON chunk, GLB lengths recomputed",
            (_, true) => ", checksums and file size recomputed",
            _ => "",
        };
        let desc = format!("{name} with {:?}{resealed} ({} bytes)", c.mutations, bytes.len());
        match check(target, &dir, &bytes, &desc, true).map_err(TestCaseError::fail)? {
            Passed::Deep => deep.set(deep.get() + 1),
            Passed::Known => known.set(known.get() + 1),
            Passed::Shallow => {}
        }
        Ok(())
    });
    let what = if target == Target::Reader { "opened with a node decoded" } else { "imported" };
    let secs = start.elapsed().as_secs_f64();
    println!("{}: {cases} cases in {secs:.1} s, {} {what}, {} hit known unfixed bugs", target.name(), deep.get(), known.get());
    if let Err(e) = result {
        panic!("{e}");
    }
    // Mutations that leave the input readable are what reach the decoding: too few and the test
    // only exercises the first checks.
    assert!(deep.get() as f64 >= 0.03 * cases as f64, "only {} of {cases} cases got past the first checks", deep.get());
}

#[test]
fn seeds_are_read_whole() {
    let dir = ImportDir::new().expect("a scratch folder");
    for (name, bytes) in seeds(Target::Reader) {
        let rd = strata::format::Reader::open(std::io::Cursor::new(bytes)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!rd.nodes().is_empty());
        assert!(strata::format::verify(std::io::Cursor::new(bytes), Path::new(name)).is_sound(), "{name}");
    }
    assert!(seeds(Target::Reader)
        .iter()
        .any(|(_, b)| { strata::format::Reader::open(std::io::Cursor::new(b)).is_ok_and(|rd| rd.levels().len() >= 3) }));
    for (target, ext) in [(Target::Obj, "obj"), (Target::Ply, "ply")] {
        for (name, bytes) in seeds(target) {
            dir.import(bytes, ext).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
    }
    for (name, bytes) in seeds(Target::Gltf) {
        import_gltf(&dir, bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    for (name, bytes) in seeds(Target::Dem).iter().chain([&geotiff_seed()]) {
        let imported = dir.import(bytes, seed_ext(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let voids = u64::from(!name.ends_with(".png"));
        assert!(imported.georef.is_some() && imported.grid.is_some_and(|g| g.voids == voids), "{name}");
    }
}

#[test]
fn mutated_elevation_grids() {
    mutated(Target::Dem, 2000);
}

#[test]
fn mutated_chunk_files() {
    mutated(Target::Reader, 20000);
}

#[test]
fn mutated_obj_files() {
    mutated(Target::Obj, 1500);
}

#[test]
fn mutated_ply_files() {
    mutated(Target::Ply, 2000);
}

#[test]
fn mutated_gltf_files() {
    mutated(Target::Gltf, 5000);
}

/// Files in `fuzz/regressions/<target>/<sub>`.
fn regressions(target: Target, sub: &str) -> Vec<PathBuf> {
    let dir = root().join("fuzz/regressions").join(target.name()).join(sub);
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(&dir).map(|d| d.flatten().map(|e| e.path()).filter(|p| p.is_file()).collect()).unwrap_or_default();
    files.sort();
    files
}

fn run_regressions(sub: &str) -> usize {
    let dir = ImportDir::new().expect("a scratch folder");
    let mut failures = Vec::new();
    let mut count = 0;
    for target in [Target::Reader, Target::Obj, Target::Ply, Target::Gltf] {
        for file in regressions(target, sub) {
            count += 1;
            if let Err(e) = check(target, &dir, &read(&file), &file.display().to_string(), false) {
                failures.push(e);
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    count
}

/// Inputs the fuzzers once crashed on, kept after their fix.
#[test]
fn kept_fuzz_regressions() {
    println!("{} kept inputs", run_regressions(""));
}

/// Inputs that still crash, kept until their bug is fixed; run with `-- --ignored`.
#[test]
#[ignore]
fn unfixed_fuzz_findings() {
    println!("{} unfixed inputs", run_regressions("unfixed"));
}
