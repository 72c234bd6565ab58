//! The level meshes M0 … ML: M0 is the input; Mℓ is Mℓ−1 simplified while every group of level ℓ
//! stays a non-empty patch (METHOD.md §4), minus the small components that leave it
//! ([`crate::small_components`]); connected too, except where a level cuts a handle or neck
//! inside a group ([`crate::simplify::SimplifyOptions::topology`]).
//! A node — group g of level ℓ — owns the faces of Mℓ labelled g.
//!
//! A node's geometric error bounds, in model units, how far its surface may lie from the input:
//! each level adds the simplifier's estimate for the group (an RMS distance to the planes the
//! group's vertices replaced, see [`crate::simplify`]) to the largest error of its children (an
//! absorber's errors cover the components it took in). The estimate is area-weighted, not a
//! Hausdorff bound; [`crate::distance`] measures the real thing.

use crate::hierarchy::Hierarchy;
use crate::mesh::Mesh;
use crate::simplify::{simplify_pinned, SimplifyOptions};
use rustc_hash::FxHashSet;

/// One level's mesh and what each of its faces belongs to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelMesh {
    pub mesh: Mesh,
    /// Group of level ℓ of each face of `mesh`.
    pub face_group: Vec<u32>,
    /// Per group of level ℓ: geometric error in model units, never smaller than its children's.
    pub group_error: Vec<f32>,
}

/// Level meshes, finest (the input, level 0) first.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LevelMeshes {
    pub levels: Vec<LevelMesh>,
}

/// How the level meshes are made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelParams {
    /// Target ratio of faces between a level mesh and the one below.
    pub ratio: f32,
    /// The top level mesh should have at most this many faces: a viewer shows it at once. While it
    /// has more, levels with the top's partition again are added (see [`Hierarchy::repeat_top`]),
    /// as long as each gets most of the way to its ratio.
    pub top_faces: usize,
}

impl Default for LevelParams {
    fn default() -> Self {
        LevelParams { ratio: 0.5, top_faces: 2048 }
    }
}

/// Degrees. Corner normals of one vertex closer than this are one normal at levels 1 and up
/// ([`SimplifyOptions::normal_seam_angle`]). A scan's input carries such near-equal normals where
/// its writer split a vertex (the CT head: 418 vertices, half of them under 13° apart); as seams
/// they would lock those vertices at every level, and at coarse levels, where little else is left,
/// stop the simplification (its top level 2,777 faces instead of 674). Creases strata computes
/// are sharper than `--crease-angle` (60°) between faces.
const NORMAL_SEAM_ANGLE: f32 = 30.0;

/// At most this many levels are added above the grouping's top.
const MAX_ADDED: usize = 32;

/// Fewest faces per node, on average, of an added level: below this the per-node overhead (about
/// 5 faces' worth of bytes) is more than a sixth of the node's own faces.
const MIN_ADDED_NODE_FACES: usize = 32;

/// Build every level mesh of `h` from `mesh`, each aiming at `p.ratio` of the faces of the level
/// below, and add levels on top of `h` while the top mesh has more than `p.top_faces` faces.
/// `mesh` becomes level 0 (taken, not copied: it is the largest of them). `on_level` is called
/// after each level with its index, for progress reports.
pub fn build(mesh: Mesh, h: &mut Hierarchy, p: &LevelParams, on_level: &mut dyn FnMut(usize)) -> LevelMeshes {
    let first = LevelMesh { mesh, face_group: h.levels[0].face_group.clone(), group_error: vec![0.0; h.levels[0].groups.len()] };
    build_from(first, h, p, None, on_level)
}

/// [`build`] from a given first level (`h`'s level 0, with its errors: the partitioned build's
/// merged cell tops). Vertices at the positions `pinned` holds (as [`position_key`]s) never move
/// ([`crate::simplify::simplify_pinned`]): a piece's levels then meet its neighbours' exactly.
pub fn build_from(
    first: LevelMesh,
    h: &mut Hierarchy,
    p: &LevelParams,
    pinned: Option<&FxHashSet<[u32; 3]>>,
    on_level: &mut dyn FnMut(usize),
) -> LevelMeshes {
    let ratio = p.ratio.clamp(0.0, 1.0);
    // A piece with pinned vertices is part of a larger mesh: a component it sees whole may not be.
    let coarsen = |below: &LevelMesh, h: &mut Hierarchy, l: usize| {
        let mut level = coarsen(below, h, l, ratio, pinned);
        if pinned.is_none() {
            crate::small_components::leave(&mut level, h, l);
        }
        level
    };
    let mut levels = vec![first];
    on_level(0);
    for l in 1..h.levels.len() {
        levels.push(coarsen(&levels[l - 1], h, l));
        on_level(l);
    }
    // An added level costs a node per top group in the skeleton every reader loads (a record,
    // neighbours and a chunk frame: about as many bytes as 5 faces of geometry). It must get most
    // of the way to its target, and keep nodes of MIN_ADDED_NODE_FACES faces on average.
    let worthwhile = ratio as f64 + (1.0 - ratio as f64) / 4.0;
    for _ in 0..MAX_ADDED {
        let below = levels.last().map_or(0, |t| t.mesh.face_count());
        if below <= p.top_faces {
            break;
        }
        let nodes = h.levels[levels.len() - 1].groups.len().max(1);
        if (below as f64 * ratio as f64) < (MIN_ADDED_NODE_FACES * nodes) as f64 {
            break;
        }
        h.repeat_top();
        let next = coarsen(&levels[levels.len() - 1], h, levels.len());
        let nodes = h.levels[levels.len()].groups.len();
        if next.mesh.face_count() as f64 > below as f64 * worthwhile || next.mesh.face_count() < MIN_ADDED_NODE_FACES * nodes {
            h.pop_top();
            break;
        }
        levels.push(next);
        on_level(levels.len() - 1);
    }
    LevelMeshes { levels }
}

/// How many levels [`build`] is expected to make for `faces` input faces and a grouping of
/// `grouped` levels: exact unless the simplifier stops short of its targets or the added levels'
/// nodes would be too small, when fewer are made.
pub fn expected_levels(faces: usize, grouped: usize, p: &LevelParams) -> usize {
    let ratio = p.ratio.clamp(0.0, 1.0) as f64;
    let mut top = faces as f64 * ratio.powi(grouped.saturating_sub(1) as i32);
    let mut n = grouped;
    while top > p.top_faces as f64 && n < grouped + MAX_ADDED && ratio < 1.0 {
        top *= ratio;
        n += 1;
    }
    n
}

/// Per vertex of `mesh`, whether its position ([`position_key`]) is in `set`: the vertices a piece
/// of a partitioned build shares with other pieces.
pub fn pinned_flags(mesh: &Mesh, set: &FxHashSet<[u32; 3]>) -> Vec<bool> {
    mesh.positions.iter().map(|&p| set.contains(&position_key(p))).collect()
}

/// A position as the key welding compares: its coordinates' bits, −0 as +0.
pub fn position_key(p: glam::Vec3) -> [u32; 3] {
    (p + glam::Vec3::ZERO).to_array().map(f32::to_bits)
}

/// Level `l` made from the level mesh `below` of level `l − 1`.
fn coarsen(below: &LevelMesh, h: &Hierarchy, l: usize, ratio: f32, pinned: Option<&FxHashSet<[u32; 3]>>) -> LevelMesh {
    let parent = &h.levels[l - 1].parent;
    let labels: Vec<u32> = below.face_group.iter().map(|&g| parent[g as usize]).collect();
    let target = ((below.mesh.face_count() as f64) * ratio as f64).round() as usize;
    // Topology changes apply where the simplification would stop at handles (coarse levels of a
    // scan); not in a piece of a partitioned build, whose top is welded by position to its
    // neighbours (which would join a cut's copies back to their originals).
    let opts = SimplifyOptions {
        target_faces: target,
        topology: pinned.is_none(),
        normal_seam_angle: NORMAL_SEAM_ANGLE.to_radians(),
        ..SimplifyOptions::default()
    };
    let pins: Vec<bool> = pinned.map_or(Vec::new(), |set| pinned_flags(&below.mesh, set));
    let s = simplify_pinned(&below.mesh, Some(&labels), &pins, &opts);
    let groups = &h.levels[l];
    let group_error = (0..groups.groups.len())
        .map(|g| {
            let children = groups.children.get(g).iter().map(|&c| below.group_error[c as usize]).fold(0.0, f32::max);
            children + s.group_error.get(g).copied().unwrap_or(0.0)
        })
        .collect();
    LevelMesh { mesh: s.mesh, face_group: s.face_groups, group_error }
}
