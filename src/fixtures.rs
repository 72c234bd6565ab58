//! Procedural meshes for fixtures, tests and benchmarks.
//!
//! Every mesh is deterministic across runs and platforms: only IEEE-exact arithmetic (+ − × ÷, sqrt,
//! floor), no sin/cos/exp whose last bit depends on the platform's math library, a self-contained
//! PRNG, and no hash-map iteration order in any output. Every mesh has already passed
//! [`Mesh::clean`] unchanged, so it has face normals, areas, materials and a material per face.

use crate::mesh::{triangle_cross, Material, Mesh};
use glam::{DVec2, DVec3, Vec2, Vec3};
use std::collections::HashMap;

/// A unit cube centred on the origin: 12 faces, closed, per-corner normals (hard edges).
pub fn cube() -> Mesh {
    let mut m = box_mesh(DVec3::splat(-0.5), DVec3::splat(0.5));
    m.uvs.clear();
    finish(m)
}

/// A box 2 × 1 × 0.5 on the z = 0 plane whose top face uses material `top` and the rest `sides`;
/// per-corner normals, and UVs mapping each face onto the unit square.
pub fn two_material_box() -> Mesh {
    let mut m = box_mesh(DVec3::new(-1.0, -0.5, 0.0), DVec3::new(1.0, 0.5, 0.5));
    m.face_materials = m.face_normals.iter().map(|n| u32::from(n.z > 0.5)).collect();
    m.materials = vec![
        Material { name: "sides".into(), base_color: [0.6, 0.6, 0.65, 1.0], texture: None, ..Material::default() },
        Material { name: "top".into(), base_color: [0.8, 0.25, 0.1, 1.0], texture: None, ..Material::default() },
    ];
    finish(m)
}

/// A unit sphere subdivided from an icosahedron: `20 · 4^subdivisions` faces, closed, smooth
/// per-corner normals.
pub fn icosphere(subdivisions: u32) -> Mesh {
    let (dirs, triangles) = icosphere_directions(subdivisions);
    let positions: Vec<Vec3> = dirs.iter().map(|d| d.as_vec3()).collect();
    let normals = triangles.iter().flatten().map(|&v| positions[v as usize]).collect();
    finish(Mesh { positions, triangles, normals, ..Mesh::default() })
}

/// An icosphere with per-corner RGBA colors taken from the normal (`rgb = (n + 1) / 2`), opaque.
pub fn colored_sphere(subdivisions: u32) -> Mesh {
    let mut m = icosphere(subdivisions);
    let channel = |x: f32| ((x * 0.5 + 0.5) * 255.0).round().clamp(0.0, 255.0) as u8;
    m.colors = m.normals.iter().map(|n| [channel(n.x), channel(n.y), channel(n.z), 255]).collect();
    m
}

/// A scan-like closed surface: a unit cube-sphere with `12 · n²` faces, displaced along the normal
/// by smooth multi-octave noise of height `amplitude` plus a small per-vertex jitter (a tenth of
/// it), with smooth per-corner normals. `n = 91` gives 99,372 faces.
pub fn noisy_sphere(n: u32, amplitude: f32, seed: u64) -> Mesh {
    displaced_sphere(n, f64::from(amplitude), 1.5, 6, 0.1 * f64::from(amplitude), seed)
}

/// A closed manifold random-ish blob for property tests: a cube-sphere whose radius varies
/// between about 0.6 and 1.4, with smooth per-corner normals. It has `12 · n²` faces for the `n`
/// that comes closest to `faces` (at least 12); the same seed always gives the same mesh.
pub fn random_blob(seed: u64, faces: usize) -> Mesh {
    let n = ((faces as f64 / 12.0).sqrt().round() as u32).max(1);
    displaced_sphere(n, 0.3, 1.2, 3, 0.1, seed)
}

/// An open height field over the unit square: `n × n` quads (`2n²` faces), smooth per-corner
/// normals, UVs equal to x and y, and a border of `4n` boundary edges.
pub fn open_grid(n: u32) -> Mesh {
    let n = n.max(1);
    let side = n + 1;
    let positions: Vec<Vec3> = (0..side * side)
        .map(|i| {
            let (x, y) = (f64::from(i % side) / f64::from(n), f64::from(i / side) / f64::from(n));
            let z = 0.15 * fbm(DVec3::new(3.0 * x, 3.0 * y, 0.5), 4, 7) + 0.2 * x * (1.0 - x) * y;
            DVec3::new(x, y, z).as_vec3()
        })
        .collect();
    let mut triangles = Vec::with_capacity(2 * (n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            let v = j * side + i;
            triangles.push([v, v + 1, v + side + 1]);
            triangles.push([v, v + side + 1, v + side]);
        }
    }
    let uvs = triangles.iter().flatten().map(|&v| Vec2::new(positions[v as usize].x, positions[v as usize].y)).collect();
    let normals = smooth_normals(&positions, &triangles);
    finish(Mesh { positions, triangles, normals, uvs, ..Mesh::default() })
}

/// A small non-manifold mesh: a fin of three quads sharing one edge (one edge used by three faces)
/// and, beside it, a bowtie (two triangles meeting at a single vertex).
pub fn nonmanifold() -> Mesh {
    let mut positions = vec![Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 1.0)];
    let mut triangles = Vec::new();
    for (x, y) in [(1.0, 0.0), (-0.5, 0.8), (-0.5, -0.8)] {
        let t = positions.len() as u32;
        positions.push(Vec3::new(x, y, 0.0));
        positions.push(Vec3::new(x, y, 1.0));
        triangles.push([0, t, t + 1]);
        triangles.push([0, t + 1, 1]);
    }
    let k = positions.len() as u32;
    positions.extend([[3.0, 0.0, 0.5], [2.0, 0.0, 1.0], [2.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 0.0, 1.0]].map(Vec3::from));
    triangles.push([k, k + 1, k + 2]);
    triangles.push([k, k + 3, k + 4]);
    finish(Mesh { positions, triangles, ..Mesh::default() })
}

/// A CAD-like part: an L-shaped bracket (an upright with a 45° chamfer on top and a foot with a
/// fillet in the inner corner), a through-hole in the upright and one in the foot, extruded 2 units.
/// Large flat faces, sharp 90° edges, long thin strips on the walls (triangle areas differ by
/// orders of magnitude), per-corner normals split where faces meet at more than 30°. Closed and
/// manifold, 3,256 faces.
pub fn cad_part() -> Mesh {
    let mut p = Profile::default();
    let extra = [DVec2::new(2.0, 1.0), DVec2::new(2.0, 1.3)];
    p.holed_square(DVec2::new(1.0, 1.0), 1.0, 0.6, 7, &extra);
    p.holed_square(DVec2::new(6.5, 0.5), 0.5, 0.25, 6, &[]);
    p.fan(&[[2.0, 0.0], [6.0, 0.0], [6.0, 1.0], [2.3, 1.0], [2.0, 1.0]]);
    p.fan(&[[0.0, 2.0], [2.0, 2.0], [2.0, 2.2], [1.8, 2.4], [0.0, 2.4]]);
    // Fillet between foot and upright: a quarter circle around (2.3, 1.3), fanned from the corner.
    let mut fillet = vec![[2.0, 1.0], [2.3, 1.0]];
    let quarter = arc(DVec2::new(0.0, -1.0), DVec2::new(-1.0, 0.0), 5);
    fillet.extend(quarter[1..quarter.len() - 1].iter().map(|d| (DVec2::new(2.3, 1.3) + 0.3 * *d).to_array()));
    fillet.push([2.0, 1.3]);
    p.fan(&fillet);
    finish(p.extrude(2.0, 3f64.sqrt() / 2.0))
}

/// A textured globe: a latitude-longitude sphere of `segments` × `segments / 2` quads (poles as
/// fans) with an equirectangular map, UV seam at longitude 180°, and its base color image, a
/// `width` × `width / 2` PNG: a checker of 16 × 8 cells whose hue runs with longitude and
/// brightness with latitude, under one-texel grid lines every 8 texels, so that each image level
/// looks different and a wrong UV or a wrong level shows.
pub fn textured_globe(segments: u32, width: u32) -> Mesh {
    use crate::format::{MapKind, TextureSlot, Wrap};
    let (nu, nv) = (segments.max(4), (segments / 2).max(2));
    let mut m = Mesh::default();
    let point = |i: u32, j: u32| {
        let (lon, lat) = (std::f64::consts::TAU * i as f64 / nu as f64, std::f64::consts::PI * (0.5 - j as f64 / nv as f64));
        DVec3::new(lat.cos() * lon.cos(), lat.sin(), -lat.cos() * lon.sin())
    };
    // Vertices by (i, j) with i = nu the seam's copy of i = 0: positions shared by the weld below.
    for j in 0..=nv {
        for i in 0..=nu {
            m.positions.push(point(i % nu, j).as_vec3());
        }
    }
    let at = |i: u32, j: u32| j * (nu + 1) + i;
    let uv = |i: u32, j: u32| Vec2::new(i as f32 / nu as f32, j as f32 / nv as f32);
    for j in 0..nv {
        for i in 0..nu {
            let quad = [(i, j), (i, j + 1), (i + 1, j + 1), (i + 1, j)];
            let tris: &[[usize; 3]] = if j == 0 {
                &[[0, 1, 2]]
            } else if j + 1 == nv {
                &[[0, 2, 3]]
            } else {
                &[[0, 1, 2], [0, 2, 3]]
            };
            for t in tris {
                let c = t.map(|k| quad[k]);
                m.triangles.push(c.map(|(a, b)| at(a, b)));
                for (a, b) in c {
                    m.uvs.push(uv(a, b));
                    m.normals.push(point(a % nu, b).as_vec3());
                }
            }
        }
    }
    m.face_materials = vec![0; m.triangles.len()];
    m.materials = vec![crate::mesh::Material { name: "globe".into(), base_color: [1.0; 4], ..crate::mesh::Material::default() }];
    m.materials[0].maps[MapKind::BaseColor as usize] = Some(TextureSlot { image: 0, wrap: [Wrap::Repeat, Wrap::Clamp] });
    let (w, h) = (width.max(16), (width / 2).max(8));
    let mut im = crate::texture::Rgba8::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let (cx, cy) = (16 * x / w, 8 * y / h);
            let hue = x as f32 / w as f32 * 6.0;
            let rgb = [(hue - 3.0).abs() - 1.0, 2.0 - (hue - 2.0).abs(), 2.0 - (hue - 4.0).abs()].map(|c| c.clamp(0.0, 1.0));
            let light = if (cx + cy) % 2 == 0 { 0.95 } else { 0.45 } * (0.4 + 0.6 * (1.0 - (2.0 * y as f32 / h as f32 - 1.0).abs()));
            let line = x % 8 == 0 || y % 8 == 0;
            let px = rgb.map(|c| if line { 20 } else { (255.0 * (0.15 + 0.85 * c) * light) as u8 });
            im.pixels[4 * (y * w + x) as usize..][..4].copy_from_slice(&[px[0], px[1], px[2], 255]);
        }
    }
    let png = crate::texture::encode(crate::texture::ImageCodec::Png, &im, 90).expect("a fixture image encodes");
    m.images = vec![crate::texture::SourceImage::new("globe.png".into(), png).expect("a PNG")];
    finish(m)
}

/// The meshes behind the files in `fixtures/`, written by `examples/make_fixtures.rs`.
pub struct Fixture {
    /// File name under `fixtures/`; its extension picks the format.
    pub file: &'static str,
    /// What the file is for.
    pub exercises: &'static str,
    pub mesh: Mesh,
}

/// Every committed fixture, in the order the README lists them.
pub fn committed() -> Vec<Fixture> {
    let f = |file, exercises, mesh| Fixture { file, exercises, mesh };
    vec![
        f("cube.obj", "smallest closed mesh; hard edges as per-corner normals (`f v//vn`)", cube()),
        f("icosphere.obj", "closed smooth sphere (subdivision 3); shared normals", icosphere(3)),
        f(
            "noisy_sphere.ply",
            "scan-like surface at ~100k faces, binary PLY with normals; import speed, grouping, simplification",
            noisy_sphere(91, 0.08, 1),
        ),
        f("cad_part.obj", "CAD-like part: through-holes, chamfer, fillet, sharp edges, large flat faces, thin strips", cad_part()),
        f("open_grid.obj", "open height field with a border (32 × 32 quads), normals and UVs", open_grid(32)),
        f("nonmanifold.obj", "an edge shared by three faces and a bowtie vertex", nonmanifold()),
        f("two_materials.glb", "two materials (two primitives), UVs and normals in glTF", two_material_box()),
        f("colored_sphere.ply", "per-vertex RGBA colors (uchar) and normals in binary PLY", colored_sphere(4)),
        f(
            "textured_globe.glb",
            "a base color image embedded in GLB (512 × 256 PNG), equirectangular UVs with a seam, clamped along v",
            textured_globe(96, 512),
        ),
    ]
}

/// An isosurface the way a CT scan's is made, by marching tetrahedra over an `n`³ lattice of the
/// unit cube, of a blobby field whose samples are whole multiples of 1/64 (as a scanner's integer
/// densities are) and an iso-value just off one of them (2⁻²² above 0). Wherever a sample equals that
/// multiple, the surface passes within ~10⁻⁷ of the lattice point and the vertices on its edges are
/// distinct positions closer together than a millionth of the model: the mesh that a position
/// grid of 20 bits cannot keep apart. Closed and manifold; no normals.
pub fn isosurface(n: u32, seed: u64) -> Mesh {
    let n = n.max(2) as usize;
    let h = 1.0 / (n - 1) as f64;
    let at = |i: usize, j: usize, k: usize| DVec3::new(i as f64, j as f64, k as f64) * h;
    let border = |i: usize| i == 0 || i == n - 1;
    let mut field = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = at(i, j, k);
                let d = p - DVec3::splat(0.5);
                let v =
                    if border(i) || border(j) || border(k) { -1.0 } else { 1.0 - d.length_squared() / 0.16 + 0.6 * fbm(3.0 * p, 3, seed) };
                field.push((v * 64.0).floor() / 64.0);
            }
        }
    }
    const ISO: f64 = 1.0 / (1u64 << 22) as f64;
    let index = |i: usize, j: usize, k: usize| (k * n + j) * n + i;
    let mut vertex_of: HashMap<(usize, usize), u32> = HashMap::new();
    let mut positions: Vec<Vec3> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    // Kuhn's six tetrahedra of a cube, each a path from corner 0 to corner 7 along the axes.
    const PATHS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    for k in 0..n - 1 {
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                for path in PATHS {
                    let mut c = [i, j, k];
                    let mut tet = [index(c[0], c[1], c[2]); 4];
                    for (s, &axis) in path.iter().enumerate() {
                        c[axis] += 1;
                        tet[s + 1] = index(c[0], c[1], c[2]);
                    }
                    let inside: Vec<usize> = tet.iter().copied().filter(|&v| field[v] > ISO).collect();
                    let outside: Vec<usize> = tet.iter().copied().filter(|&v| field[v] <= ISO).collect();
                    if inside.is_empty() || outside.is_empty() {
                        continue;
                    }
                    let mut cross = |a: usize, b: usize| -> u32 {
                        *vertex_of.entry((a.min(b), a.max(b))).or_insert_with(|| {
                            let lattice = |v: usize| at(v % n, v / n % n, v / (n * n));
                            let t = (ISO - field[a]) / (field[b] - field[a]);
                            positions.push((lattice(a) + (lattice(b) - lattice(a)) * t).as_vec3());
                            positions.len() as u32 - 1
                        })
                    };
                    let polygon: Vec<u32> = match (inside.len(), outside.len()) {
                        (1, _) => outside.iter().map(|&o| cross(inside[0], o)).collect(),
                        (_, 1) => inside.iter().map(|&v| cross(v, outside[0])).collect(),
                        _ => vec![
                            cross(inside[0], outside[0]),
                            cross(inside[0], outside[1]),
                            cross(inside[1], outside[1]),
                            cross(inside[1], outside[0]),
                        ],
                    };
                    let mean = |vs: &[usize]| vs.iter().fold(DVec3::ZERO, |s, &v| s + at(v % n, v / n % n, v / (n * n))) / vs.len() as f64;
                    let out_dir = mean(&outside) - mean(&inside);
                    for w in 1..polygon.len() - 1 {
                        let mut t = [polygon[0], polygon[w], polygon[w + 1]];
                        if triangle_cross(&positions, &t).dot(out_dir) < 0.0 {
                            t.swap(1, 2);
                        }
                        triangles.push(t);
                    }
                }
            }
        }
    }
    finish(Mesh { positions, triangles, ..Mesh::default() })
}

/// Clean a freshly built mesh (adds the default material and face geometry).
fn finish(mesh: Mesh) -> Mesh {
    mesh.clean().expect("procedural positions are finite").0
}

/// An axis-aligned box, faces in the order −x, +x, −y, +y, −z, +z, with per-corner normals and
/// unmirrored per-face UVs over the unit square.
fn box_mesh(lo: DVec3, hi: DVec3) -> Mesh {
    let corner = |bits: [usize; 3]| -> u32 { (bits[0] | bits[1] << 1 | bits[2] << 2) as u32 };
    let positions = (0..8).map(|i| DVec3::select(glam::BVec3::new(i & 1 != 0, i & 2 != 0, i & 4 != 0), hi, lo).as_vec3()).collect();
    let mut m = Mesh { positions, ..Mesh::default() };
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in 0..2 {
            // Corners as (u, v) bits, counter-clockwise seen from outside.
            let quad: [(usize, usize); 4] = if side == 1 { [(0, 0), (1, 0), (1, 1), (0, 1)] } else { [(0, 0), (0, 1), (1, 1), (1, 0)] };
            let ids = quad.map(|(a, b)| {
                let mut bits = [0; 3];
                bits[axis] = side;
                bits[u] = a;
                bits[v] = b;
                corner(bits)
            });
            let uv = quad.map(|(a, b)| if side == 1 { Vec2::new(a as f32, b as f32) } else { Vec2::new(b as f32, a as f32) });
            let mut normal = Vec3::ZERO;
            normal[axis] = if side == 1 { 1.0 } else { -1.0 };
            for k in [[0, 1, 2], [0, 2, 3]] {
                m.triangles.push(k.map(|i| ids[i]));
                m.uvs.extend(k.map(|i| uv[i]));
                m.normals.extend([normal; 3]);
            }
        }
    }
    m.compute_face_geometry();
    m
}

/// Unit directions and faces of an icosahedron subdivided `subdivisions` times, faces outward.
fn icosphere_directions(subdivisions: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut dirs: Vec<DVec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|&p| DVec3::from(p).normalize())
    .collect();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut midpoint_of: HashMap<(u32, u32), u32> = HashMap::new();
        let mut midpoint = |a: u32, b: u32, dirs: &mut Vec<DVec3>| {
            *midpoint_of.entry((a.min(b), a.max(b))).or_insert_with(|| {
                dirs.push((dirs[a as usize] + dirs[b as usize]).normalize());
                (dirs.len() - 1) as u32
            })
        };
        triangles = triangles
            .iter()
            .flat_map(|&[a, b, c]| {
                let (ab, bc, ca) = (midpoint(a, b, &mut dirs), midpoint(b, c, &mut dirs), midpoint(c, a, &mut dirs));
                [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
            })
            .collect();
    }
    (dirs, triangles)
}

/// Unit directions and faces of a cube whose six faces are split into `n × n` quads and projected
/// onto the sphere (with the mapping that keeps cells near even size), faces outward.
fn cube_sphere(n: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let n = n.max(1) as i64;
    let mut index: HashMap<[i64; 3], u32> = HashMap::new();
    let mut dirs = Vec::new();
    let mut vertex = |g: [i64; 3], dirs: &mut Vec<DVec3>| {
        *index.entry(g).or_insert_with(|| {
            let [x, y, z] = g.map(|c| 2.0 * c as f64 / n as f64 - 1.0);
            let (x2, y2, z2) = (x * x, y * y, z * z);
            dirs.push(DVec3::new(
                x * (1.0 - y2 / 2.0 - z2 / 2.0 + y2 * z2 / 3.0).sqrt(),
                y * (1.0 - z2 / 2.0 - x2 / 2.0 + z2 * x2 / 3.0).sqrt(),
                z * (1.0 - x2 / 2.0 - y2 / 2.0 + x2 * y2 / 3.0).sqrt(),
            ));
            (dirs.len() - 1) as u32
        })
    };
    let mut triangles = Vec::with_capacity(12 * (n * n) as usize);
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in [0, n] {
            for j in 0..n {
                for i in 0..n {
                    let mut cell = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
                    if side == 0 {
                        cell.reverse();
                    }
                    let ids = cell.map(|(a, b)| {
                        let mut g = [0; 3];
                        g[axis] = side;
                        g[u] = a;
                        g[v] = b;
                        vertex(g, &mut dirs)
                    });
                    triangles.push([ids[0], ids[1], ids[2]]);
                    triangles.push([ids[0], ids[2], ids[3]]);
                }
            }
        }
    }
    (dirs, triangles)
}

/// A cube-sphere with radius `1 + amplitude · fbm(frequency · p) + jitter · uniform(−1, 1)` per
/// vertex and smooth normals. Star-shaped around the origin, so it stays closed and free of
/// self-intersections whatever the seed, as long as the radius stays positive.
fn displaced_sphere(n: u32, amplitude: f64, frequency: f64, octaves: u32, jitter: f64, seed: u64) -> Mesh {
    let (dirs, triangles) = cube_sphere(n);
    let mut rng = Rng(seed);
    let positions: Vec<Vec3> = dirs
        .iter()
        .map(|&d| {
            let r = 1.0 + amplitude * fbm(frequency * d, octaves, seed) + jitter * (2.0 * rng.unit() - 1.0);
            (r * d).as_vec3()
        })
        .collect();
    let normals = smooth_normals(&positions, &triangles);
    finish(Mesh { positions, triangles, normals, ..Mesh::default() })
}

/// Per-corner normals averaged over the faces around each vertex, weighted by face area.
fn smooth_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut sum = vec![DVec3::ZERO; positions.len()];
    for t in triangles {
        let c = triangle_cross(positions, t);
        for &v in t {
            sum[v as usize] += c;
        }
    }
    triangles.iter().flatten().map(|&v| sum[v as usize].normalize_or_zero().as_vec3()).collect()
}

/// Unit directions from `from` to `to` (less than 180° apart), counter-clockwise if `to` lies
/// counter-clockwise of `from`, by `levels` rounds of bisection: `2^levels + 1` directions, ends
/// included. Bisection needs only sqrt, so the points are the same on every platform.
fn arc(from: DVec2, to: DVec2, levels: u32) -> Vec<DVec2> {
    let mut dirs = vec![from, to];
    for _ in 0..levels {
        let mut finer = Vec::with_capacity(2 * dirs.len() - 1);
        for w in dirs.windows(2) {
            finer.push(w[0]);
            finer.push((w[0] + w[1]).normalize());
        }
        finer.push(to);
        dirs = finer;
    }
    dirs
}

/// A planar profile in the (x, z) plane, triangulated counter-clockwise, to extrude along y.
/// Points are shared by exact coordinates, so cells that share an edge share its vertices.
#[derive(Default)]
struct Profile {
    points: Vec<DVec2>,
    index: HashMap<[u64; 2], u32>,
    triangles: Vec<[u32; 3]>,
}

impl Profile {
    fn point(&mut self, p: DVec2) -> u32 {
        let points = &mut self.points;
        *self.index.entry([p.x.to_bits(), p.y.to_bits()]).or_insert_with(|| {
            points.push(p);
            (points.len() - 1) as u32
        })
    }

    /// A convex polygon, counter-clockwise, fanned from its first point.
    fn fan(&mut self, polygon: &[[f64; 2]]) {
        let ids: Vec<u32> = polygon.iter().map(|&p| self.point(DVec2::from(p))).collect();
        for w in ids[1..].windows(2) {
            self.triangles.push([ids[0], w[0], w[1]]);
        }
    }

    /// A square of half-size `half` around `center` with a round hole of radius `radius`
    /// (`4 · 2^levels` segments). Each square corner fans to the quarter of the hole facing it;
    /// each side, split at the `extra` points that lie on it, fans from the hole point facing it.
    fn holed_square(&mut self, center: DVec2, half: f64, radius: f64, levels: u32, extra: &[DVec2]) {
        let axes = [DVec2::X, DVec2::Y, DVec2::NEG_X, DVec2::NEG_Y];
        let mut hole = Vec::new();
        for q in 0..4 {
            let quarter = arc(axes[q], axes[(q + 1) % 4], levels);
            hole.extend(quarter[..quarter.len() - 1].iter().map(|d| center + radius * *d));
        }
        let hole: Vec<u32> = hole.into_iter().map(|p| self.point(p)).collect();
        let quarter = hole.len() / 4;
        // Corner k sits at 45° + k·90°, counter-clockwise from the top right.
        let corners =
            [DVec2::new(1.0, 1.0), DVec2::new(-1.0, 1.0), DVec2::new(-1.0, -1.0), DVec2::new(1.0, -1.0)].map(|c| center + half * c);
        for k in 0..4 {
            let c = self.point(corners[k]);
            for j in k * quarter..(k + 1) * quarter {
                self.triangles.push([c, hole[(j + 1) % hole.len()], hole[j]]);
            }
            let (a, b) = (corners[k], corners[(k + 1) % 4]);
            let mut side: Vec<DVec2> = extra.iter().copied().filter(|&p| on_segment(p, a, b)).collect();
            side.sort_by(|p, q| (*p - a).length_squared().total_cmp(&(*q - a).length_squared()));
            let side: Vec<u32> = [a].into_iter().chain(side).chain([b]).map(|p| self.point(p)).collect();
            let facing = hole[((k + 1) * quarter) % hole.len()];
            for w in side.windows(2) {
                self.triangles.push([facing, w[0], w[1]]);
            }
        }
    }

    /// Extrude the profile from y = 0 to y = `depth`: two caps and a wall on every boundary edge.
    /// Wall normals are smoothed across boundary vertices where the cosine of the angle between
    /// neighbouring walls is at least `crease_cos`, and split otherwise.
    fn extrude(&self, depth: f64, crease_cos: f64) -> Mesh {
        let np = self.points.len() as u32;
        let lift = |p: DVec2, y: f64| DVec3::new(p.x, y, p.y).as_vec3();
        let mut positions: Vec<Vec3> = self.points.iter().map(|&p| lift(p, 0.0)).collect();
        positions.extend(self.points.iter().map(|&p| lift(p, depth)));
        let mut triangles = Vec::new();
        let mut normals = Vec::new();
        // Counter-clockwise in (x, z) faces −y: the near cap as is, the far cap reversed.
        for t in &self.triangles {
            triangles.push(*t);
            normals.extend([Vec3::NEG_Y; 3]);
        }
        for &[a, b, c] in &self.triangles {
            triangles.push([a + np, c + np, b + np]);
            normals.extend([Vec3::Y; 3]);
        }

        // Boundary edges, directed as in their triangle (material on the left).
        let mut uses: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &self.triangles {
            for k in 0..3 {
                *uses.entry((t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))).or_default() += 1;
            }
        }
        let edges: Vec<(u32, u32)> = self
            .triangles
            .iter()
            .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
            .filter(|&(a, b)| uses[&(a.min(b), a.max(b))] == 1)
            .collect();
        let outward = |(a, b): (u32, u32)| {
            let d = self.points[b as usize] - self.points[a as usize];
            DVec2::new(d.y, -d.x).normalize()
        };
        let mut into = vec![u32::MAX; self.points.len()];
        let mut out_of = vec![u32::MAX; self.points.len()];
        for (e, &(a, b)) in edges.iter().enumerate() {
            out_of[a as usize] = e as u32;
            into[b as usize] = e as u32;
        }
        let blend = |own: DVec2, other: u32| {
            let n = outward(edges[other as usize]);
            let m = if own.dot(n) >= crease_cos { (own + n).normalize() } else { own };
            DVec3::new(m.x, 0.0, m.y).as_vec3()
        };
        for &(a, b) in &edges {
            let own = outward((a, b));
            let (na, nb) = (blend(own, into[a as usize]), blend(own, out_of[b as usize]));
            let (a0, b0, a1, b1) = (a, b, a + np, b + np);
            triangles.push([b0, a0, a1]);
            normals.extend([nb, na, na]);
            triangles.push([b0, a1, b1]);
            normals.extend([nb, na, nb]);
        }
        Mesh { positions, triangles, normals, ..Mesh::default() }
    }
}

/// Whether `p` lies on segment a–b strictly between its ends (axis-aligned segments, exact).
fn on_segment(p: DVec2, a: DVec2, b: DVec2) -> bool {
    let between = |x: f64, lo: f64, hi: f64| x > lo.min(hi) && x < lo.max(hi);
    (a.x == b.x && p.x == a.x && between(p.y, a.y, b.y)) || (a.y == b.y && p.y == a.y && between(p.x, a.x, b.x))
}

/// splitmix64: a tiny, well-mixed PRNG that is the same everywhere.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix(self.0)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Smooth value noise in [−1, 1]: random values on the integer lattice, blended with a quintic fade.
fn value_noise(p: DVec3, seed: u64) -> f64 {
    let cell = p.floor();
    let f = p - cell;
    let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (u, v, w) = (fade(f.x), fade(f.y), fade(f.z));
    let lattice = |dx: i64, dy: i64, dz: i64| {
        let [x, y, z] = [cell.x as i64 + dx, cell.y as i64 + dy, cell.z as i64 + dz].map(|c| c as u64);
        let h = mix(seed ^ mix(x ^ mix(y ^ mix(z))));
        (h >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    };
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let plane = |dz| lerp(lerp(lattice(0, 0, dz), lattice(1, 0, dz), u), lerp(lattice(0, 1, dz), lattice(1, 1, dz), u), v);
    lerp(plane(0), plane(1), w)
}

/// Fractal noise in [−1, 1]: `octaves` layers of value noise, each twice the frequency and half
/// the weight of the last.
/// Write a detailed closed mesh of about `faces` faces (at least 12) straight to a binary PLY,
/// holding none of it in memory: a sphere displaced by ten octaves of noise (large bumps down to
/// wrinkles a few cells wide), made as the six faces of a cube, each an `n` × `n` grid of quads
/// (12·n² faces), pushed out to the sphere. Vertices on the cube's edges are written once per face
/// they belong to, at bit-identical positions (every coordinate is a whole number over `n`, divided
/// once), so importing welds them into one closed, manifold surface. For tests and benchmarks at
/// sizes that are not committed (5M, 20M faces); `progress` is called with the fraction written.
/// Returns the faces and vertices written.
pub fn write_bumpy_sphere_ply(
    out: &mut impl std::io::Write,
    faces: u64,
    seed: u64,
    progress: &mut dyn FnMut(f64),
) -> std::io::Result<(u64, u64)> {
    let n = ((faces.max(12) as f64 / 12.0).sqrt().round() as u64).max(1);
    let (face_count, vertex_count) = (12 * n * n, 6 * (n + 1) * (n + 1));
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment strata fixtures::write_bumpy_sphere_ply n={n} seed={seed}\n\
         element vertex {vertex_count}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {face_count}\nproperty list uchar uint vertex_indices\nend_header\n"
    )?;
    // Each cube face: its outward axis and two in-plane axes with u × v outward.
    const FACES: [([i64; 3], [i64; 3], [i64; 3]); 6] = [
        ([1, 0, 0], [0, 1, 0], [0, 0, 1]),
        ([-1, 0, 0], [0, 0, 1], [0, 1, 0]),
        ([0, 1, 0], [0, 0, 1], [1, 0, 0]),
        ([0, -1, 0], [1, 0, 0], [0, 0, 1]),
        ([0, 0, 1], [1, 0, 0], [0, 1, 0]),
        ([0, 0, -1], [0, 1, 0], [1, 0, 0]),
    ];
    let ni = n as i64;
    let steps = (12 * n + 6) as f64;
    let mut buf = Vec::with_capacity(1 << 16);
    for (f, (normal, u, v)) in FACES.iter().enumerate() {
        for j in 0..=ni {
            for i in 0..=ni {
                // Whole numbers m in [−n, n], each coordinate m / n: the same on every face it is on.
                let m = |k: usize| normal[k] * ni + u[k] * (2 * i - ni) + v[k] * (2 * j - ni);
                let cube = DVec3::new(m(0) as f64, m(1) as f64, m(2) as f64) / ni as f64;
                let dir = cube / cube.length();
                let r = 1.0 + 0.08 * (fbm(2.0 * dir, 4, seed) - 0.5) + 0.015 * (fbm(24.0 * dir, 6, seed ^ 0x9E37) - 0.5);
                for c in (dir * r).as_vec3().to_array() {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
            }
            if buf.len() > (1 << 16) - 64 {
                out.write_all(&buf)?;
                buf.clear();
            }
            progress((f as u64 * (n + 1) + j as u64 + 1) as f64 / steps);
        }
    }
    for f in 0..6u64 {
        let base = f * (n + 1) * (n + 1);
        for j in 0..n {
            for i in 0..n {
                let at = |i: u64, j: u64| (base + j * (n + 1) + i) as u32;
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                for t in [[a, b, c], [a, c, d]] {
                    buf.push(3);
                    for x in t {
                        buf.extend_from_slice(&x.to_le_bytes());
                    }
                }
            }
            if buf.len() > (1 << 16) - 64 {
                out.write_all(&buf)?;
                buf.clear();
            }
            progress((6 * (n + 1) + f * n + j + 1) as f64 / steps);
        }
    }
    out.write_all(&buf)?;
    Ok((face_count, vertex_count))
}

fn fbm(p: DVec3, octaves: u32, seed: u64) -> f64 {
    let (mut sum, mut weight, mut total, mut scale) = (0.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        sum += weight * value_noise(scale * p, seed.wrapping_add(u64::from(o)));
        total += weight;
        weight *= 0.5;
        scale *= 2.0;
    }
    sum / total
}

/// `n` separate triangles of about unit size scattered in a 100-unit cube, as an OBJ file: a soup
/// (specks, fragments, an unwelded export), whose levels shrink only where small components may
/// leave. For tests and benchmarks.
pub fn write_soup_obj(w: &mut impl std::io::Write, n: usize) -> std::io::Result<()> {
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    for _ in 0..n {
        let c = [rng.unit() * 100.0, rng.unit() * 100.0, rng.unit() * 100.0];
        for _ in 0..3 {
            writeln!(w, "v {:.4} {:.4} {:.4}", c[0] + rng.unit() - 0.5, c[1] + rng.unit() - 0.5, c[2] + rng.unit() - 0.5)?;
        }
    }
    for t in 0..n {
        writeln!(w, "f {} {} {}", 3 * t + 1, 3 * t + 2, 3 * t + 3)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Adjacency, CleanReport, VertexFaces};
    use std::collections::HashSet;

    /// Every directed edge used once and its reverse used once: closed, manifold, consistently oriented.
    fn closed_and_oriented(m: &Mesh) -> bool {
        let directed: Vec<(u32, u32)> = m.triangles.iter().flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3]))).collect();
        let set: HashSet<(u32, u32)> = directed.iter().copied().collect();
        set.len() == directed.len() && directed.iter().all(|&(a, b)| set.contains(&(b, a)))
    }

    #[test]
    fn bumpy_sphere_streams_to_a_closed_ply() {
        let mut bytes = Vec::new();
        let mut last = 0.0;
        let (faces, vertices) = write_bumpy_sphere_ply(&mut bytes, 10_000, 3, &mut |f| last = f).unwrap();
        assert_eq!((faces, last), (12 * 29 * 29, 1.0));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("b.ply");
        std::fs::write(&p, &bytes).unwrap();
        let imported = crate::import::import(&p, None).unwrap();
        let m = imported.mesh;
        assert_eq!(m.face_count() as u64, faces);
        // The cube's edges weld: 6 (n+1)² written, 6n² + 2 distinct on a closed genus-0 surface.
        assert_eq!((vertices, m.vertex_count()), (6 * 30 * 30, 6 * 29 * 29 + 2));
        assert!(closed_and_oriented(&m) && volume(&m) > 3.5, "closed and outward: volume {}", volume(&m));
    }

    fn volume(m: &Mesh) -> f64 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|v| m.positions[v as usize].as_dvec3());
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Cleaning again changes nothing, the arrays are consistent and normals are unit length.
    fn assert_clean(m: &Mesh) {
        assert_eq!(m.validate(), Ok(()));
        let (again, report) = m.clone().clean().unwrap();
        assert_eq!(report, CleanReport::default());
        assert_eq!(&again, m);
        assert!(m.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-5));
    }

    #[test]
    fn every_fixture_is_clean() {
        for f in committed() {
            assert_clean(&f.mesh);
        }
        assert_clean(&random_blob(3, 500));
    }

    #[test]
    fn cube_has_hard_edges() {
        let m = cube();
        assert_eq!((m.face_count(), m.vertex_count()), (12, 8));
        assert!(closed_and_oriented(&m));
        assert!((volume(&m) - 1.0).abs() < 1e-9);
        for (c, n) in m.normals.iter().enumerate() {
            assert_eq!(*n, m.face_normals[c / 3]);
        }
    }

    #[test]
    fn icosphere_is_a_closed_unit_sphere() {
        for s in 0..4 {
            let m = icosphere(s);
            assert_eq!(m.face_count(), 20 * 4usize.pow(s));
            assert_eq!(m.vertex_count(), 10 * 4usize.pow(s) + 2);
            assert!(closed_and_oriented(&m));
            assert!(m.positions.iter().all(|p| (p.length() - 1.0).abs() < 1e-6));
            assert!(volume(&m) > 0.0);
        }
        let v = volume(&icosphere(4));
        assert!((v - 4.0 / 3.0 * std::f64::consts::PI).abs() < 0.01, "{v}");
    }

    #[test]
    fn noisy_sphere_is_closed_bumpy_and_seeded() {
        let m = noisy_sphere(20, 0.1, 5);
        assert_eq!(m.face_count(), 12 * 400);
        assert!(closed_and_oriented(&m));
        let radii: Vec<f32> = m.positions.iter().map(|p| p.length()).collect();
        let (lo, hi) = radii.iter().fold((f32::MAX, 0f32), |(lo, hi), &r| (lo.min(r), hi.max(r)));
        assert!(lo > 1.0 - 0.11 && hi < 1.0 + 0.11 && hi - lo > 0.05, "{lo} {hi}");
        assert!(m.normals.iter().zip(m.triangles.iter().flatten()).all(|(n, &v)| n.dot(m.positions[v as usize]) > 0.5));
        assert_eq!(m, noisy_sphere(20, 0.1, 5));
        assert_ne!(m.positions, noisy_sphere(20, 0.1, 6).positions);
        assert_eq!(noisy_sphere(91, 0.08, 1).face_count(), 99_372);
    }

    #[test]
    fn random_blob_is_closed_and_deterministic() {
        for (seed, faces, expect) in [(1, 10, 12), (2, 1000, 972), (3, 5000, 4800)] {
            let m = random_blob(seed, faces);
            assert_eq!(m.face_count(), expect);
            assert!(closed_and_oriented(&m));
            assert!(volume(&m) > 0.5);
            assert_eq!(m, random_blob(seed, faces));
        }
        assert_ne!(random_blob(1, 1000).positions, random_blob(2, 1000).positions);
    }

    #[test]
    fn cad_part_is_a_closed_part_with_sharp_edges() {
        let m = cad_part();
        assert_eq!(m.face_count(), 3256);
        assert!(closed_and_oriented(&m));
        let adj = Adjacency::build(&m);
        assert_eq!((adj.boundary_edges, adj.nonmanifold_edges.len()), (0, 0));
        // Profile area (upright, chamfered top, foot, fillet corner, foot block, minus holes) × depth.
        let pi = std::f64::consts::PI;
        let area = 4.0 + 0.78 + 4.0 + (0.09 - 0.0225 * pi) + 1.0 - pi * (0.36 + 0.0625);
        assert!((volume(&m) - 2.0 * area).abs() < 1e-3 * area, "{} vs {}", volume(&m), 2.0 * area);
        let (small, large) = m.face_areas.iter().fold((f32::MAX, 0f32), |(s, l), &a| (s.min(a), l.max(a)));
        assert!(large > 1000.0 * small, "{small} {large}");
        // Normals split at sharp edges: a box corner carries three different normals.
        let corner = m.positions.iter().position(|p| *p == Vec3::new(0.0, 0.0, 0.0)).unwrap() as u32;
        let at_corner: HashSet<[u32; 3]> = (0..3 * m.face_count())
            .filter(|&c| m.triangles[c / 3][c % 3] == corner)
            .map(|c| m.normals[c].to_array().map(f32::to_bits))
            .collect();
        assert_eq!(at_corner.len(), 3);
        // Along a hole, normals are smooth: each hole vertex has one normal on the wall.
        assert!(m.normals.iter().all(|n| n.length() > 0.99));
    }

    #[test]
    fn open_grid_has_a_border() {
        let m = open_grid(8);
        assert_eq!(m.face_count(), 128);
        let adj = Adjacency::build(&m);
        assert_eq!((adj.boundary_edges, adj.nonmanifold_edges.len()), (32, 0));
        assert_eq!(m.uvs.len(), 3 * 128);
        assert!(m.face_normals.iter().all(|n| n.z > 0.5));
    }

    #[test]
    fn nonmanifold_has_a_fin_and_a_bowtie() {
        let m = nonmanifold();
        assert_eq!(m.face_count(), 8);
        let adj = Adjacency::build(&m);
        assert_eq!(adj.nonmanifold_edges.len(), 1);
        let vf = VertexFaces::build(&m);
        let k = m.positions.iter().position(|p| *p == Vec3::new(3.0, 0.0, 0.5)).unwrap() as u32;
        let faces = vf.of(k);
        assert_eq!(faces.len(), 2);
        let shared: Vec<u32> =
            m.triangles[faces[0] as usize].iter().filter(|v| m.triangles[faces[1] as usize].contains(v)).copied().collect();
        assert_eq!(shared, [k]);
    }

    #[test]
    fn two_material_box_maps_top_and_sides() {
        let m = two_material_box();
        assert_eq!(m.materials.iter().map(|x| x.name.as_str()).collect::<Vec<_>>(), ["sides", "top"]);
        assert!(closed_and_oriented(&m));
        let top: Vec<usize> = (0..12).filter(|&f| m.face_materials[f] == 1).collect();
        assert_eq!(top.len(), 2);
        assert!(top.iter().all(|&f| m.face_normals[f] == Vec3::Z));
        assert!(m.uvs.iter().all(|t| (t.x == 0.0 || t.x == 1.0) && (t.y == 0.0 || t.y == 1.0)));
        // UVs are not mirrored: the UV triangle winds the same way as the face seen from outside.
        for f in 0..12 {
            let [a, b, c] = [0, 1, 2].map(|k| m.uvs[3 * f + k]);
            assert!((b - a).perp_dot(c - a) > 0.0, "face {f}");
        }
    }

    #[test]
    fn colored_sphere_colors_follow_normals() {
        let m = colored_sphere(2);
        assert_eq!(m.colors.len(), m.normals.len());
        for (c, n) in m.colors.iter().zip(&m.normals) {
            assert_eq!(c[3], 255);
            assert!((f32::from(c[0]) / 255.0 * 2.0 - 1.0 - n.x).abs() < 0.01);
        }
    }
}
