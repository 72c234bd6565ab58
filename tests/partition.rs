//! The partitioned build (`strata convert --partitioned`, `--memory`): cells built apart meet
//! exactly, the file verifies and streams, neighbours are linked across cells, and bad input ends
//! in a clear error that leaves no output and no work files.

mod common;

use common::{edge, Edge};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use strata::format::Reader;
use strata::pipeline::{convert, Build, ConvertOptions, Silent};
use strata::stream::{session, Budgets, Streamer};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("strata-partition-{}-{name}", std::process::id()))
}

/// An empty folder for a test's work files.
fn work_dir(name: &str) -> PathBuf {
    let work = temp(name);
    std::fs::create_dir_all(&work).unwrap();
    work
}

/// Remove a test's outputs and its (by then empty) work folder.
fn clean_up<const N: usize>(files: [PathBuf; N], work: &Path) {
    for p in files {
        let _ = std::fs::remove_file(p);
    }
    let _ = std::fs::remove_dir(work);
}

/// Options that make the noisy sphere (99k faces) about ten cells.
fn partitioned(work: &Path) -> ConvertOptions {
    ConvertOptions { build: Build::Partitioned, memory: 16 << 20, temp: Some(work.to_path_buf()), ..ConvertOptions::default() }
}

/// Per level: how many faces use each edge (by decoded positions), and which nodes do.
fn level_edges(rd: &Reader<std::fs::File>, level: u32) -> HashMap<Edge, Vec<u32>> {
    let mut out: HashMap<Edge, Vec<u32>> = HashMap::new();
    for n in rd.level_nodes(level) {
        let g = rd.read_node(n).expect("node");
        for t in g.indices.chunks_exact(3) {
            for k in 0..3 {
                out.entry(edge(g.positions[t[k] as usize], g.positions[t[(k + 1) % 3] as usize])).or_default().push(n);
            }
        }
    }
    out
}

#[test]
fn cells_meet_exactly_and_are_linked_as_neighbours() {
    let work = work_dir("work");
    let input = fixture("noisy_sphere.ply");
    let out = temp("sphere.strata");
    let incore = temp("sphere-incore.strata");
    convert(&input, &Default::default(), &out, &partitioned(&work), &mut Silent).expect("partitioned convert");
    convert(&input, &Default::default(), &incore, &ConvertOptions { build: Build::InCore, ..ConvertOptions::default() }, &mut Silent)
        .expect("in-core convert");
    assert!(strata::format::verify_path(&out).is_sound(), "the partitioned file does not verify");
    assert_eq!(std::fs::read_dir(&work).unwrap().count(), 0, "work files left behind");

    let rd = Reader::open_path(&out).unwrap();
    let core = Reader::open_path(&incore).unwrap();
    assert_eq!(rd.levels()[0].faces, core.levels()[0].faces, "level 0 must hold every input face");
    assert_eq!(rd.header().input_vertices, core.header().input_vertices, "vertices welded across cells");
    // The sphere is closed: in every level of both files, every edge has two faces. Across cells
    // that holds only if their borders were kept exactly.
    let mut linked_across = 0;
    for (name, file) in [("in-core", &core), ("partitioned", &rd)] {
        for l in 0..file.levels().len() as u32 {
            let edges = level_edges(file, l);
            let open = edges.values().filter(|n| n.len() != 2).count();
            for (e, n) in edges.iter().filter(|(_, n)| n.len() != 2) {
                eprintln!("{name} level {l}: edge {:?} {:?} faces in nodes {n:?}", e.0.map(f32::from_bits), e.1.map(f32::from_bits));
            }
            assert_eq!(open, 0, "{name} level {l}: {open} edges without exactly two faces (a crack)");
            // Nodes that share an edge are neighbours in the skeleton.
            let mut pairs = HashSet::new();
            for n in edges.values() {
                if n[0] != n[1] {
                    pairs.insert((n[0].min(n[1]), n[0].max(n[1])));
                }
            }
            for &(a, b) in &pairs {
                assert!(file.neighbors(a).contains(&b), "{name} level {l}: nodes {a} and {b} share an edge but are not neighbours");
            }
            linked_across += pairs.len();
        }
    }
    assert!(linked_across > 0);
    assert!(rd.levels().len() >= 4, "{} levels", rd.levels().len());

    // It streams: the top level at once, then refinement along an orbit.
    let (min, max) = (rd.header().min, rd.header().max);
    let (center, radius) = ((min + max) * 0.5, (max - min).length() * 0.5);
    let top = rd.levels().len() as u32 - 1;
    let mut s = Streamer::new(rd, Budgets::default()).unwrap();
    let first = s.update(&session::orbit(center, radius, 0, 8, 160, 120), None).unwrap();
    assert!(first.front.iter().all(|&n| s.reader().nodes()[n as usize].level <= top));
    let mut finest = u32::MAX;
    for i in 0..8 {
        let f = s.update(&session::orbit(center, radius, i, 8, 160, 120), None).unwrap();
        finest = finest.min(f.front.iter().map(|&n| s.reader().nodes()[n as usize].level).min().unwrap_or(u32::MAX));
    }
    assert!(finest < top, "refinement never went below the top level");
    clean_up([out, incore], &work);
}

#[test]
fn bad_input_ends_in_a_clear_error_without_output_or_work_files() {
    let work = work_dir("bad-work");
    let out = temp("bad.strata");

    // A format without a streaming reader: an elevation grid.
    let grid = temp("grid.asc");
    std::fs::write(&grid, "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 4\n").unwrap();
    let e = convert(&grid, &Default::default(), &out, &partitioned(&work), &mut Silent).unwrap_err().to_string();
    assert!(e.contains("reads OBJ, GLTF and PLY"), "{e}");

    // A GLB cut inside its binary chunk.
    let glb = std::fs::read(fixture("two_materials.glb")).unwrap();
    let cut_glb = temp("cut.glb");
    std::fs::write(&cut_glb, &glb[..glb.len() - 100]).unwrap();
    let e = convert(&cut_glb, &Default::default(), &out, &partitioned(&work), &mut Silent).unwrap_err().to_string();
    assert!(e.contains("cut.glb") && e.contains("truncated GLB"), "{e}");

    // A binary PLY cut inside its faces.
    let bytes = std::fs::read(fixture("noisy_sphere.ply")).unwrap();
    let cut = temp("cut.ply");
    std::fs::write(&cut, &bytes[..bytes.len() - 1000]).unwrap();
    let e = convert(&cut, &Default::default(), &out, &partitioned(&work), &mut Silent).unwrap_err().to_string();
    assert!(e.contains("cut.ply") && e.contains("byte"), "{e}");

    // An index past the vertices, in the last face.
    let mut bad = bytes.clone();
    let n = bad.len();
    bad[n - 4..].copy_from_slice(&u32::MAX.to_le_bytes());
    let wild = temp("wild.ply");
    std::fs::write(&wild, &bad).unwrap();
    let e = convert(&wild, &Default::default(), &out, &partitioned(&work), &mut Silent).unwrap_err().to_string();
    assert!(e.contains("out of range"), "{e}");

    assert!(!out.exists(), "an output was left");
    assert_eq!(std::fs::read_dir(&work).unwrap().count(), 0, "work files left behind");
    clean_up([grid, cut_glb, cut, wild], &work);
}

/// The noisy sphere written as OBJ (positions, per-corner normals).
fn sphere_obj(name: &str) -> PathBuf {
    let mesh = strata::import(&fixture("noisy_sphere.ply"), None).expect("import").mesh;
    let obj = temp(name);
    strata::export::obj::write(&obj, &mesh).expect("write OBJ");
    obj
}

#[test]
fn an_obj_file_streams_to_the_same_file_as_its_ply() {
    let work = work_dir("obj-work");
    let obj = sphere_obj("sphere.obj");
    let (from_obj, from_ply) = (temp("from-obj.strata"), temp("from-ply.strata"));
    convert(&obj, &Default::default(), &from_obj, &partitioned(&work), &mut Silent).expect("partitioned OBJ");
    convert(&fixture("noisy_sphere.ply"), &Default::default(), &from_ply, &partitioned(&work), &mut Silent).expect("partitioned PLY");
    assert!(strata::format::verify_path(&from_obj).is_sound(), "the file from OBJ does not verify");
    assert_eq!(std::fs::read_dir(&work).unwrap().count(), 0, "work files left behind");
    let rd = Reader::open_path(&from_obj).unwrap();
    assert!(rd.header().attributes.normals, "the OBJ's normals are carried");
    assert!(rd.levels().len() >= 4 && rd.levels()[0].faces == 99_372, "{} levels", rd.levels().len());
    // The same positions, normals and faces in the same order: the same build, byte for byte.
    assert!(std::fs::read(&from_obj).unwrap() == std::fs::read(&from_ply).unwrap(), "OBJ and PLY streams built different files");
    clean_up([obj, from_obj, from_ply], &work);
}

#[test]
fn obj_streams_resolve_relative_and_forward_indices_and_polygons() {
    let work = work_dir("objidx-work");
    // A 40 × 40 grid of quads, faces written between the vertices they use: every other row
    // by negative indices, and the last row's faces before the vertices they name.
    let n = 40;
    let mut text = String::from("# grid\n");
    let id = |i: usize, j: usize| i * (n + 1) + j + 1;
    for i in 0..=n {
        for j in 0..=n {
            text += &format!("v {} {} {}\n", j as f32 / n as f32, i as f32 / n as f32, ((i * j) as f32 * 0.01).sin() * 0.05);
        }
        if i == n - 1 {
            // Forward: row n - 1's faces use row n's vertices, defined below.
            for j in 0..n {
                text += &format!("f {} {} {} {}\n", id(i, j), id(i, j + 1), id(i + 1, j + 1), id(i + 1, j));
            }
        }
        if i > 0 && i < n {
            let seen = (i + 1) * (n + 1);
            for j in 0..n {
                let rel = |v: usize| v as i64 - seen as i64 - 1;
                let q = [id(i - 1, j), id(i - 1, j + 1), id(i, j + 1), id(i, j)];
                if i % 2 == 0 {
                    text += &format!("f {} {} {} {}\n", rel(q[0]), rel(q[1]), rel(q[2]), rel(q[3]));
                } else {
                    text += &format!("f {} {} {} {}\n", q[0], q[1], q[2], q[3]);
                }
            }
        }
    }
    let obj = temp("grid.obj");
    std::fs::write(&obj, &text).unwrap();
    let (part, core) = (temp("grid-part.strata"), temp("grid-core.strata"));
    let opts = ConvertOptions { build: Build::Partitioned, memory: 16 << 20, temp: Some(work.clone()), ..ConvertOptions::default() };
    convert(&obj, &Default::default(), &part, &opts, &mut Silent).expect("partitioned OBJ");
    convert(&obj, &Default::default(), &core, &ConvertOptions { build: Build::InCore, ..ConvertOptions::default() }, &mut Silent)
        .expect("in-core OBJ");
    let (rp, rc) = (Reader::open_path(&part).unwrap(), Reader::open_path(&core).unwrap());
    assert_eq!(rp.levels()[0].faces, 2 * (n * n) as u64);
    assert_eq!(rp.levels()[0].faces, rc.levels()[0].faces);
    assert_eq!(rp.header().input_vertices, rc.header().input_vertices);
    // The same level-0 surface: every edge of the grid's interior has two faces, its border one.
    let edges = level_edges(&rp, 0);
    assert_eq!(edges.values().filter(|f| f.len() == 1).count(), 4 * n, "the grid's border");
    assert!(edges.values().all(|f| f.len() <= 2), "a non-manifold edge");

    // Bad lines are named, and leave no output.
    std::fs::remove_file(&part).unwrap();
    for (body, want) in [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "line 4: face vertex index 4 out of range: the file has 3 vertices"),
        ("v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n", "line 3: relative vertex index -3 reaches before the first of 2 so far"),
        ("v 0 0 0\nv 1 zero 0\n", "line 2: v: 'zero' is not a number"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 zero\nf 1/1 2 3\n", "line 4: vt: 'zero' is not a number"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/2 2 3\n", "line 5: face texture coordinate index 2 out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl\nf 1 2 3\n", "line 4: usemtl without a material name"),
        ("v 0 0 0\nv 1000000010 0 0\nv 0 1 0\nf 1 2 3\n", "line 2: coordinate 1.00000001e9 exceeds"),
        ("v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r", "line 1: v has 15 numbers"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf //1 2 3\n", "line 4: face vertex '//1' has no position index"),
        ("", "the file is empty"),
    ] {
        std::fs::write(&obj, body).unwrap();
        let e = convert(&obj, &Default::default(), &part, &opts, &mut Silent).unwrap_err().to_string();
        assert!(e.contains("grid.obj") && e.contains(want), "{e}");
    }
    assert!(!part.exists(), "a bad input left an output");
    assert_eq!(std::fs::read_dir(&work).unwrap().count(), 0, "work files left behind");
    clean_up([obj, part, core], &work);
}

/// A textured globe of 65k faces whose southern half has a second, untextured material, written
/// in `dir` as `name` (OBJ with its MTL and image, or GLB).
fn textured_globe(dir: &Path, name: &str) -> PathBuf {
    let mut mesh = strata::fixtures::textured_globe(256, 256);
    let red = strata::mesh::Material { name: "red".into(), base_color: [0.8, 0.1, 0.1, 1.0], ..Default::default() };
    mesh.materials.push(red);
    for (f, t) in mesh.triangles.iter().enumerate() {
        if t.iter().map(|&v| mesh.positions[v as usize].y).sum::<f32>() < 0.0 {
            mesh.face_materials[f] = 1;
        }
    }
    let path = dir.join(name);
    if name.ends_with(".ply") {
        write_meshlab_ply(&path, &mesh);
    } else {
        strata::export::write(&path, &mesh).expect("write the globe");
    }
    path
}

/// `mesh` as a binary PLY in MeshLab's convention for textures, as photogrammetry tools write it:
/// a `TextureFile` comment per material (the image of the first, written beside the file, stands
/// for every one), each face's corners' UVs in a `texcoord` list and its material as `texnumber`.
fn write_meshlab_ply(path: &Path, mesh: &strata::mesh::Mesh) {
    let image = &mesh.images[0];
    let names: Vec<String> = (0..mesh.materials.len()).map(|k| format!("texture{k}.png")).collect();
    for n in &names {
        std::fs::write(path.with_file_name(n), &image.bytes[..]).unwrap();
    }
    let mut out: Vec<u8> = b"ply\nformat binary_little_endian 1.0\n".to_vec();
    for n in &names {
        out.extend(format!("comment TextureFile {n}\n").bytes());
    }
    out.extend(
        format!(
            "element vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\n\
             property list uchar int vertex_indices\nproperty list uchar float texcoord\nproperty int texnumber\nend_header\n",
            mesh.positions.len(),
            mesh.triangles.len()
        )
        .bytes(),
    );
    for p in &mesh.positions {
        out.extend(p.to_array().iter().flat_map(|x| x.to_le_bytes()));
    }
    for (f, t) in mesh.triangles.iter().enumerate() {
        out.push(3);
        out.extend(t.iter().flat_map(|&v| (v as i32).to_le_bytes()));
        out.push(6);
        for c in 0..3 {
            let uv = mesh.uvs[3 * f + c];
            out.extend([uv.x, 1.0 - uv.y].iter().flat_map(|x| x.to_le_bytes()));
        }
        out.extend((mesh.face_materials[f] as i32).to_le_bytes());
    }
    std::fs::write(path, out).unwrap();
}

/// Per material, how many faces a level has, and every corner's UV (as bits, sorted).
fn level_looks(rd: &Reader<std::fs::File>, level: u32) -> (Vec<u64>, Vec<[u32; 2]>) {
    let mut faces = vec![0u64; rd.materials().len()];
    let mut uvs = Vec::new();
    for n in rd.level_nodes(level) {
        let g = rd.read_node(n).expect("node");
        for r in &g.material_ranges {
            faces[r.material as usize] += r.index_count as u64 / 3;
        }
        uvs.extend(g.indices.iter().map(|&i| g.uvs[i as usize].to_array().map(f32::to_bits)));
    }
    uvs.sort_unstable();
    (faces, uvs)
}

#[test]
fn a_textured_obj_glb_or_ply_of_two_materials_builds_partitioned_with_its_uvs_materials_and_images() {
    for name in ["globe.obj", "globe.glb", "globe.ply"] {
        textured_builds_partitioned_as_in_core(name, false);
    }
}

#[test]
fn a_textured_glb_of_two_materials_builds_partitioned_as_a_dag_with_its_uvs_materials_and_images() {
    textured_builds_partitioned_as_in_core("globe.glb", true);
}

/// The textured globe written as `name`, converted partitioned and in memory, as trees or as
/// DAGs (`dag`), holds the same materials, images, UVs at level 0, and materials at every level.
fn textured_builds_partitioned_as_in_core(name: &str, dag: bool) {
    let tag = if dag { format!("dag-{name}") } else { name.to_string() };
    let work = work_dir(&format!("textured-work-{tag}"));
    let dir = work_dir(&format!("textured-input-{tag}"));
    let obj = textured_globe(&dir, name);
    let (part, core) = (temp(&format!("textured-part-{tag}.strata")), temp(&format!("textured-core-{tag}.strata")));
    let c = convert(&obj, &Default::default(), &part, &ConvertOptions { dag, ..partitioned(&work) }, &mut Silent).expect("partitioned");
    assert!(c.cells.is_some_and(|n| n > 1), "{:?} cells", c.cells);
    convert(&obj, &Default::default(), &core, &ConvertOptions { build: Build::InCore, dag, ..ConvertOptions::default() }, &mut Silent)
        .expect("in core");
    assert_eq!(Reader::open_path(&part).unwrap().header().major, if dag { 4 } else { 3 });
    assert!(strata::format::verify_path(&part).is_sound(), "the partitioned file does not verify");
    assert_eq!(std::fs::read_dir(&work).unwrap().count(), 0, "work files left behind");
    let (rp, rc) = (Reader::open_path(&part).unwrap(), Reader::open_path(&core).unwrap());
    assert!(rp.header().attributes.uvs, "UVs carried");
    assert_eq!(rp.materials(), rc.materials());
    assert_eq!(rp.materials().len(), 2);
    // The same images (a PLY names one per material), with the same levels.
    let (tp, tc) = (rp.textures(), rc.textures());
    let ply = name.ends_with(".ply");
    assert_eq!(tp.images.len(), if ply { 2 } else { 1 });
    assert_eq!(tp.images, tc.images);
    assert_eq!(tp.levels.len(), tc.levels.len());
    for image in 0..tp.images.len() as u32 {
        for level in 0..tp.level_count(image) {
            assert!(
                rp.read_image_level(image, level).unwrap() == rc.read_image_level(image, level).unwrap(),
                "image {image} level {level}"
            );
        }
    }
    // Level 0: each material's faces, and every corner's UV, as in the in-core build; every level
    // keeps both materials, and every node that has textured faces a UV density.
    let (faces, uvs) = level_looks(&rp, 0);
    assert_eq!((&faces, &uvs), (&level_looks(&rc, 0).0, &level_looks(&rc, 0).1));
    assert!(faces.iter().all(|&n| n > 20_000), "{faces:?}");
    for level in 1..rp.levels().len() as u32 {
        let (faces, _) = level_looks(&rp, level);
        assert!(faces.iter().all(|&n| n > 0), "level {level}: {faces:?}");
    }
    for n in 0..rp.nodes().len() {
        let g = rp.read_node(n as u32).unwrap();
        let textured = g.material_ranges.iter().any(|r| (r.material == 0 || ply) && r.index_count > 0);
        assert_eq!(textured, tp.uv_density[n] > 0.0, "node {n}");
    }
    for f in std::fs::read_dir(&dir).unwrap().flatten() {
        let _ = std::fs::remove_file(f.path());
    }
    clean_up([part, core], &dir);
    let _ = std::fs::remove_dir(&work);
}

#[test]
fn auto_builds_a_small_obj_partitioned_only_when_it_would_not_fit() {
    let work = work_dir("auto-work");
    let obj = sphere_obj("auto.obj");
    let (auto_small, forced, auto_large) = (temp("auto-small.strata"), temp("auto-forced.strata"), temp("auto-large.strata"));
    let with = |build: Build, memory: u64| ConvertOptions { build, memory, temp: Some(work.clone()), ..ConvertOptions::default() };
    // 99k faces need about 45 MB in core: 16 MB sends the file to the partitioned build.
    convert(&obj, &Default::default(), &auto_small, &with(Build::Auto, 16 << 20), &mut Silent).expect("auto, 16 MB");
    convert(&obj, &Default::default(), &forced, &with(Build::Partitioned, 16 << 20), &mut Silent).expect("partitioned");
    convert(&obj, &Default::default(), &auto_large, &with(Build::Auto, 1 << 30), &mut Silent).expect("auto, 1 GB");
    let bytes = |p: &Path| std::fs::read(p).unwrap();
    assert!(bytes(&auto_small) == bytes(&forced), "Auto under 16 MB did not build partitioned");
    assert!(bytes(&auto_large) != bytes(&forced), "Auto under 1 GB built partitioned");
    assert_eq!(Reader::open_path(&auto_large).unwrap().levels()[0].faces, 99_372);
    clean_up([obj, auto_small, forced, auto_large], &work);
}

#[test]
fn auto_builds_a_mesh_of_a_million_faces_partitioned_even_when_it_fits() {
    let work = work_dir("auto-parallel-work");
    let (ply, out) = (temp("auto-parallel.ply"), temp("auto-parallel.strata"));
    let mut file = std::io::BufWriter::new(std::fs::File::create(&ply).unwrap());
    let (faces, _) = strata::fixtures::write_bumpy_sphere_ply(&mut file, strata::partition::PARALLEL_FACES, 7, &mut |_| {}).unwrap();
    drop(file);
    assert!(faces >= strata::partition::PARALLEL_FACES, "{faces} faces");
    let opts = ConvertOptions { memory: 4 << 30, temp: Some(work.clone()), ..ConvertOptions::default() };
    let c = convert(&ply, &Default::default(), &out, &opts, &mut Silent).expect("auto");
    if std::thread::available_parallelism().map_or(1, |n| n.get()) > 1 {
        let cells = c.cells.expect("built in memory");
        assert!(cells >= 2, "{cells} cells: no parallel work");
    } else {
        assert_eq!(c.cells, None, "partitioned on one core");
    }
    assert_eq!(Reader::open_path(&out).unwrap().levels()[0].faces, faces);
    clean_up([ply, out], &work);
}
