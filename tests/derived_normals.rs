//! `--normals geometry` (`strata::derived_normals`): each level's normals derived from its own
//! geometry as format 3's readers predict them. The file is smaller than with the input's normals;
//! a vertex that nodes of a level share decodes to the same normal in each of them, in the
//! in-core build and in the partitioned one (whose cells see only their side of their borders);
//! level 0's normals follow its surface.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use strata::format::Reader;
use strata::pipeline::{convert, Build, ConvertOptions, Normals, Silent};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("strata-derived-normals-{}-{name}", std::process::id()))
}

type Key = [u32; 3];
/// Per position, the nodes it decodes in and its normal there.
type Seen = HashMap<Key, Vec<(u32, glam::Vec3)>>;

fn key(p: glam::Vec3) -> Key {
    p.to_array().map(f32::to_bits)
}

/// Per decoded position of `level`: the normals its vertices decode to in each node, and the sum of
/// the cross products of the level's faces around it.
fn level_normals(rd: &Reader<std::fs::File>, level: u32) -> (Seen, HashMap<Key, glam::DVec3>) {
    let (mut normals, mut sums) = (Seen::new(), HashMap::<Key, glam::DVec3>::new());
    for n in rd.level_nodes(level) {
        let g = rd.read_node(n).expect("node");
        for (p, nrm) in g.positions.iter().zip(&g.normals) {
            normals.entry(key(*p)).or_default().push((n, *nrm));
        }
        for t in g.indices.chunks_exact(3) {
            let [a, b, c] = [0, 1, 2].map(|k| g.positions[t[k] as usize].as_dvec3());
            let cross = (b - a).cross(c - a);
            for &v in t {
                *sums.entry(key(g.positions[v as usize])).or_default() += cross;
            }
        }
    }
    (normals, sums)
}

/// Check that every vertex nodes of `level` share decodes to the same normal in each; return how
/// many are shared. With `surface`, also that each normal is within 3° of the level's own surface.
fn shared_vertices_agree(name: &str, rd: &Reader<std::fs::File>, level: u32, surface: bool) -> usize {
    let (normals, sums) = level_normals(rd, level);
    let mut shared = 0;
    for (p, seen) in &normals {
        let nodes: std::collections::HashSet<u32> = seen.iter().map(|s| s.0).collect();
        if nodes.len() > 1 {
            shared += 1;
            let first = seen[0].1;
            assert!(
                seen.iter().all(|s| s.1 == first),
                "{name}: level {level}, the vertex at {p:?} decodes to different normals in nodes {seen:?}"
            );
        }
        if surface {
            let angle = sums[p].normalize().as_vec3().angle_between(seen[0].1).to_degrees();
            assert!(angle < 3.0, "{name}: level {level}, the normal at {p:?} is {angle:.2}° from the surface's");
        }
    }
    shared
}

/// Convert `input` with `opts`, check the file, and return its size; with `--normals geometry`,
/// check that shared vertices agree at every level and that level 0 follows its surface.
fn check(name: &str, input: &Path, opts: &ConvertOptions) -> u64 {
    let out = temp(name);
    convert(input, &Default::default(), &out, opts, &mut Silent).expect("convert");
    assert!(strata::format::verify_path(&out).is_sound(), "{name}: the file does not verify");
    let size = std::fs::metadata(&out).unwrap().len();
    if matches!(opts.normals, Normals::Geometry { .. }) {
        let rd = Reader::open_path(&out).unwrap();
        let shared: usize = (0..rd.levels().len() as u32).map(|l| shared_vertices_agree(name, &rd, l, l == 0)).sum();
        assert!(shared > 1000, "{name}: only {shared} vertices shared between nodes: the test checks little");
    }
    let _ = std::fs::remove_file(&out);
    size
}

#[test]
fn derived_normals_agree_across_nodes_follow_the_surface_and_cost_less() {
    let work = temp("work");
    std::fs::create_dir_all(&work).unwrap();
    // One normal per vertex, so that every vertex shared by two nodes must decode alike.
    let geometry = Normals::Geometry { crease_angle: std::f32::consts::PI };
    let in_core = ConvertOptions { build: Build::InCore, ..ConvertOptions::default() };
    let partitioned = ConvertOptions { build: Build::Partitioned, memory: 16 << 20, temp: Some(work.clone()), ..ConvertOptions::default() };
    let sphere = fixture("noisy_sphere.ply");
    let input_normals = check("input-normals.strata", &sphere, &in_core);
    let derived = check("derived.strata", &sphere, &ConvertOptions { normals: geometry, ..in_core.clone() });
    let derived_partitioned = check("derived-partitioned.strata", &sphere, &ConvertOptions { normals: geometry, ..partitioned });
    // The sphere's noise makes its borders' normals costly: 5 % smaller when this test was written.
    assert!(
        derived * 100 < input_normals * 97,
        "derived normals should make the file at least 3 % smaller: {derived} bytes against {input_normals}"
    );
    assert!(derived_partitioned * 100 < input_normals * 97, "partitioned: {derived_partitioned} bytes against {input_normals}");
    let _ = std::fs::remove_dir(&work);
}

#[test]
fn a_mesh_without_normals_gets_them_derived_from_each_level_by_default() {
    let work = temp("work-auto");
    std::fs::create_dir_all(&work).unwrap();
    // The CAD part without its normals (its creases make smooth classes at 60°).
    let text = std::fs::read_to_string(fixture("cad_part.obj")).unwrap();
    let stripped: Vec<String> = text
        .lines()
        .filter(|l| !l.starts_with("vn "))
        .map(|l| match l.strip_prefix("f ") {
            Some(rest) => format!("f {}", rest.split_whitespace().map(|c| c.split('/').next().unwrap()).collect::<Vec<_>>().join(" ")),
            None => l.to_string(),
        })
        .collect();
    let input = temp("no-normals.obj");
    std::fs::write(&input, stripped.join("\n")).unwrap();
    let geometry = Normals::Geometry { crease_angle: 60f32.to_radians() };
    for build in [Build::InCore, Build::Partitioned] {
        let base = ConvertOptions { build, memory: 16 << 20, temp: Some(work.clone()), ..ConvertOptions::default() };
        let (auto, derived) = (temp("auto.strata"), temp("geometry.strata"));
        convert(&input, &Default::default(), &auto, &base, &mut Silent).expect("default convert");
        convert(&input, &Default::default(), &derived, &ConvertOptions { normals: geometry, ..base.clone() }, &mut Silent)
            .expect("convert with --normals geometry");
        assert!(
            std::fs::read(&auto).unwrap() == std::fs::read(&derived).unwrap(),
            "{build:?}: a mesh without normals should be written as with --normals geometry"
        );
        let _ = (std::fs::remove_file(&auto), std::fs::remove_file(&derived));
    }
    let _ = (std::fs::remove_file(&input), std::fs::remove_dir(&work));
}

#[test]
fn vertices_of_edges_with_more_than_two_faces_agree_across_cells() {
    // The noisy sphere with a fin standing on every 30th face's first edge: edges of three faces,
    // which a cell of the partitioned build may hold two of (and then sees no open edge there).
    let sphere = strata::import(&fixture("noisy_sphere.ply"), None).unwrap().mesh;
    let mut obj = String::new();
    for p in &sphere.positions {
        obj += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    let mut extra = Vec::new();
    for (f, t) in sphere.triangles.iter().enumerate() {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
        if f % 30 == 0 {
            let (a, b) = (sphere.positions[t[0] as usize], sphere.positions[t[1] as usize]);
            let tip = (a + b) * 0.5 * 1.02;
            extra.push((t[0], t[1], tip));
        }
    }
    let n = sphere.positions.len() as u32;
    for (k, (a, b, tip)) in extra.iter().enumerate() {
        obj += &format!("v {} {} {}\nf {} {} {}\n", tip.x, tip.y, tip.z, b + 1, a + 1, n + k as u32 + 1);
    }
    let input = temp("fins.obj");
    std::fs::write(&input, obj).unwrap();
    let work = temp("work-fins");
    std::fs::create_dir_all(&work).unwrap();
    let geometry = Normals::Geometry { crease_angle: std::f32::consts::PI };
    for (name, opts) in [
        ("fins-in-core.strata", ConvertOptions { build: Build::InCore, normals: geometry, ..ConvertOptions::default() }),
        (
            "fins-partitioned.strata",
            ConvertOptions {
                build: Build::Partitioned,
                memory: 16 << 20,
                temp: Some(work.clone()),
                normals: geometry,
                ..ConvertOptions::default()
            },
        ),
    ] {
        let out = temp(name);
        convert(&input, &Default::default(), &out, &opts, &mut Silent).expect("convert");
        let rd = Reader::open_path(&out).unwrap();
        // Level 0 keeps its vertices apart on the grid: one position, one vertex.
        assert!(shared_vertices_agree(name, &rd, 0, false) > 1000, "{name}: too few shared vertices");
        let _ = std::fs::remove_file(&out);
    }
    let _ = (std::fs::remove_file(&input), std::fs::remove_dir(&work));
}
