//! The DAG's cuts are crack-free by construction (issue 14; notes/dag.md): along the orbit the
//! streamer tests, moving in from far, the cut at 1 px mixes levels and, drawn with the software
//! renderer, leaves no pixel the full model covers to an enclosed background
//! (`render::crack_pixels`), with no seams drawn. Shown without the DAG's rule, a coarse group
//! beside level 0 does crack, so the measure can fail.

use glam::Vec3;
use std::path::Path;
use strata::camera::Camera;
use strata::dag::{self, cut::cut, Dag, DagParams};
use strata::hierarchy::{self, HierarchyParams};
use strata::mesh::Adjacency;
use strata::render::{crack_pixels, Image};
use strata::stream::session;

const W: u32 = 640;
const H: u32 = 480;
const FRAMES: usize = 32;

fn draw(dag: &Dag, camera: &Camera, nodes: &[u32]) -> Image {
    let mut img = Image::new(W, H);
    for &n in nodes {
        let level = &dag.levels[dag.nodes[n as usize].level as usize];
        let indices: Vec<u32> = dag.indices(n as usize).collect();
        img.draw(camera, &level.positions, &[], &indices, [200, 200, 200, 255]);
    }
    img
}

#[test]
fn cuts_of_the_dag_leave_no_crack() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/noisy_sphere.ply");
    let mesh = strata::import::import(&path, None).expect("import").mesh;
    let adj = Adjacency::build(&mesh);
    let h = hierarchy::build(&mesh, &adj, &HierarchyParams::default());
    drop(adj);
    let dag = dag::build(mesh, &h.levels[0].face_group, &DagParams::default(), &mut |_, _| {});
    let full: Vec<u32> = (0..dag.level_nodes(0).end).collect();
    let (lo, hi) = dag.levels[0].bounds().expect("bounds");
    let (center, radius) = (0.5 * (lo + hi), 0.5 * (hi - lo).length());

    let (mut cracks, mut mixed) = (0, 0);
    for i in 0..FRAMES {
        let camera = session::orbit(center, radius, i, FRAMES, W, H);
        let shown = cut(&dag, &camera, 1.0).nodes;
        let levels: std::collections::BTreeSet<u32> = shown.iter().map(|&n| dag.nodes[n as usize].level).collect();
        mixed += (levels.len() > 1) as usize;
        cracks += crack_pixels(&draw(&dag, &camera, &shown), &draw(&dag, &camera, &full));
    }
    eprintln!("noisy sphere: {mixed} of {FRAMES} cuts mix levels, {cracks} crack pixels");
    assert!(mixed >= FRAMES / 2, "{mixed} cuts of several levels: the orbit should mostly show mixed cuts");
    assert_eq!(cracks, 0);

    // The control: the outputs of a group two levels up drawn directly beside level 0.
    let (g, group) = dag.groups.iter().enumerate().find(|(_, g)| g.level == 2).expect("a group of level 2");
    let replaced: Vec<u32> =
        dag.children.get(g).iter().flat_map(|&c| dag.children.get(dag.nodes[c as usize].source as usize).iter().copied()).collect();
    let mut wrong: Vec<u32> = full.iter().copied().filter(|n| !replaced.contains(n)).collect();
    wrong.extend(group.outputs.clone());
    let camera = Camera::framing(group.center, group.radius, group.center - center + Vec3::splat(1e-3), 50f32.to_radians(), W, H);
    let control = crack_pixels(&draw(&dag, &camera, &wrong), &draw(&dag, &camera, &full));
    eprintln!("control: {control} crack pixels");
    assert!(control > 0, "a coarse group beside level 0 should crack");
}
