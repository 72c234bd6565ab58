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

/// Convert the noisy sphere with `opts`, check the file, and return its size.
fn check(name: &str, opts: &ConvertOptions) -> u64 {
    let out = temp(name);
    convert(&fixture("noisy_sphere.ply"), &Default::default(), &out, opts, &mut Silent).expect("convert");
    assert!(strata::format::verify_path(&out).is_sound(), "{name}: the file does not verify");
    let size = std::fs::metadata(&out).unwrap().len();
    if matches!(opts.normals, Normals::Geometry { .. }) {
        let rd = Reader::open_path(&out).unwrap();
        let mut shared = 0;
        for level in 0..rd.levels().len() as u32 {
            let (normals, sums) = level_normals(&rd, level);
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
                if level == 0 {
                    let surface = sums[p].normalize().as_vec3();
                    let angle = surface.angle_between(seen[0].1).to_degrees();
                    assert!(angle < 3.0, "{name}: level 0, the normal at {p:?} is {angle:.2}° from the surface's");
                }
            }
        }
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
    let input_normals = check("input-normals.strata", &in_core);
    let derived = check("derived.strata", &ConvertOptions { normals: geometry, ..in_core.clone() });
    let derived_partitioned = check("derived-partitioned.strata", &ConvertOptions { normals: geometry, ..partitioned });
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
