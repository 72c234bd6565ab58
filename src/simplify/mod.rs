//! Quadric-error edge collapse, optionally keeping every group of a face partition a connected,
//! non-empty patch (METHOD.md §4; with topology changes, non-empty only).
//!
//! Garland–Heckbert: each vertex carries a quadric (f64), the area-weighted sum of the squared
//! distances to the planes of its input faces, plus planes perpendicular to the surface through open
//! border and seam edges (weighted by the squared edge length) so those lines keep their shape. A
//! collapse is ranked by the larger of its two ends' mean squared distances at the new position
//! (each end's quadric over its own face area, so that a small spike is not hidden by a large
//! neighbour).
//!
//! Collapses run cheapest first, in passes over a sorted queue with lazy invalidation: a collapse
//! bumps the version counters of its two vertices, which makes their other queued edges stale, and
//! the survivor's edges are ranked again for the next pass (see `State::run`). Data are flat arrays:
//! per-vertex records and quadrics, vertex ids per face, and per-vertex face lists in one arena.
//!
//! Every edge end is classified from its current faces. An edge is a *feature edge* when it is an
//! open border, or when its two faces differ in material, group, or the normal/UV/color of a shared
//! corner. A vertex with no feature edge is *free*; one with exactly two is on a *feature line* (a
//! border, a UV seam, a hard edge, a material or group border); any other vertex is a *corner* and
//! never moves. Vertices on non-manifold edges and non-manifold (bow-tie) vertices are never touched.
//! - Free–free collapses place the survivor at the quadric optimum (solved in f64; when the system
//!   is ill-conditioned or the optimum is far from the edge, the cheapest of the two ends and the
//!   midpoint), and its corner attributes are interpolated along the edge at the projection of the
//!   new position.
//! - Otherwise the collapse is a half-edge collapse onto an existing vertex, which keeps its place
//!   and its corner attributes: a free vertex onto a feature-line vertex, or a feature-line vertex
//!   along one of its own two feature edges onto the next vertex of the same line. Corners that
//!   follow the removed vertex take the survivor's corner values on their side of the line, so
//!   seams and material borders keep their topology and borders stay where they were.
//!
//! A collapse is also rejected when it breaks the link condition (the mesh stays manifold and no
//! face is duplicated), turns a face normal by more than `max_normal_turn` from its input normal, or
//! creates a degenerate or sliver face.
//!
//! Topology (opt-in; with groups only inside one group): a noisy scan has many
//! tiny handles and components, each of which keeps a dozen faces that no collapse may remove. When the target is not reached, the
//! simplification runs again, and where a collapse is blocked by the link condition alone the
//! mesh is cut along the triangle of edges that blocks it (a handle or neck) and both sides are
//! capped, or a closed tetrahedron is dropped: genus and components change, manifoldness not.
//!
//! Groups: group borders are feature lines, so a group's outline moves only along itself and the
//! removed vertex of any collapse touches at most two groups (the method's condition 2). The
//! method's condition 1 is applied in the form that is sufficient for connectivity: when both
//! removed faces lie in one group, the removed vertex is free or on an attribute seam, so its
//! closed one-group fan keeps the group connected; when they lie in different groups (a collapse
//! along a group border or an open border), each removed face must keep an edge neighbour in its
//! own group. Removing a face f from its group can only split the group through f, and the faces
//! across f's two other edges become edge neighbours after the collapse, so the group neither
//! splits nor vanishes. This also lets group outlines simplify, as the method asks.
//!
//! Where each part lives:
//! - `mod.rs`: the public API ([`SimplifyOptions`], [`Simplified`], [`simplify()`]);
//! - `quadric.rs`: the quadric error metric;
//! - `state.rs`: the collapse state (`State`): vertex and face records, their construction from
//!   the input (quadrics, locks, vertex kinds), the queries the other parts share, and the output;
//! - `collapse.rs`: the candidates of an edge, the checks (link condition, group survival, face
//!   shape) and the collapse itself;
//! - `queue.rs`: queue entries, ranking, and the pass loop (`State::run`);
//! - `topology.rs`: the changes of topology that [`SimplifyOptions::topology`] allows (cutting
//!   handles and necks, dropping closed tetrahedra);
//! - `prefetch.rs`: x86_64 prefetching for the pass loop and ranking;
//! - `tests.rs`: unit tests.
//!
//! Alternatives that were measured and lost are in `notes/simplify.md`.

mod collapse;
mod prefetch;
mod quadric;
mod queue;
mod state;
#[cfg(test)]
mod tests;
mod topology;

use crate::mesh::Mesh;
use state::State;

/// How far to simplify and which collapses to allow.
///
/// The default bounds on face turn and shape were chosen by measurement (`cargo bench --bench
/// simplify`; the settings measured against them are in `notes/simplify.md`).
#[derive(Clone, Debug, PartialEq)]
pub struct SimplifyOptions {
    /// Stop once at most this many faces remain, as far as the rules allow. Default 0: only
    /// `max_error` (or running out of legal collapses) stops.
    pub target_faces: usize,
    /// Make no collapse whose error estimate (model units) exceeds this. Default none.
    pub max_error: Option<f32>,
    /// Radians. A collapse that leaves any face normal turned by more than this from that face's
    /// normal in the input is rejected. Measured from the input, turns cannot add up over many
    /// collapses into folds. Default 75°.
    pub max_normal_turn: f32,
    /// Reject a collapse that leaves a face with quality below this and worse than before. Quality
    /// is 4√3·area / (sum of squared edge lengths): 1 for an equilateral triangle, 0 for a
    /// degenerate one. Default 0.02 (a triangle about 90× longer than wide).
    pub min_face_quality: f32,
    /// Weight of the border planes (perpendicular to the face through each open-border edge,
    /// weighted by the squared edge length) against the area-weighted face planes. Default 10:
    /// heavy, so border collapses come late and only where the border is straight.
    pub border_weight: f32,
    /// The same for seam edges (attribute, material and group borders). Default 1.
    pub seam_weight: f32,
    /// When the face target cannot be reached otherwise (not when only `max_error` bounds the
    /// simplification, with `target_faces` 0), simplify again allowing changes of topology that
    /// keep the mesh manifold wherever the link condition blocks a collapse: a handle or neck
    /// whose cross-section is a triangle of edges that is not a face is cut there and both sides
    /// capped, and a closed tetrahedron is dropped, each only if it moves the surface by less
    /// than `max_error`; without groups, collapses may also remove a component's last faces. The
    /// copies of cut vertices come after the others in the output; they start where their
    /// originals are, and where no later collapse moves them, a reader that welds vertices by
    /// position (the chunk file's writer does, by grid point) sees the two caps as one doubled
    /// face and the cut's edges as edges of four faces. Without it a mesh of many handles and
    /// components (a noisy scan) stops at a few faces per handle and component. With groups, a cut
    /// only where the faces along its cycle are of one group, which the caps take (other groups'
    /// faces around its vertices keep their edges, so no group gains or loses a neighbour), and a
    /// tetrahedron dropped only where every face around it is of one group; no group loses its
    /// last faces (a tetrahedron is dropped only from a group that keeps others), but a cut
    /// through a neck leaves its group in two pieces, and the cap's move and a dropped
    /// tetrahedron (its spread and its vertices' errors) count in the group's error. Default false.
    pub topology: bool,
    /// Radians. Corners of one vertex whose normals lie within this angle of the first normal of a
    /// set become one: each gets the set's normalized sum, and no seam runs between them (a set
    /// spans at most twice the angle). Level meshes set it so that a scanner's near-equal normals at welded vertices
    /// do not lock those vertices at every level. Default 0: any difference is a seam.
    pub normal_seam_angle: f32,
}

impl Default for SimplifyOptions {
    fn default() -> Self {
        SimplifyOptions {
            target_faces: 0,
            max_error: None,
            max_normal_turn: 75f32.to_radians(),
            min_face_quality: 0.02,
            border_weight: 10.0,
            seam_weight: 1.0,
            topology: false,
            normal_seam_angle: 0.0,
        }
    }
}

/// A simplified mesh and how far it may be from its input.
#[derive(Clone, Debug, PartialEq)]
pub struct Simplified {
    /// Compacted (no unused vertices, which keep their input order), faces in input order,
    /// face normals and areas recomputed.
    pub mesh: Mesh,
    /// Input face of each output face: output faces are the surviving input faces, in order,
    /// then the caps of topology changes, each with the input face it took its material from.
    pub source_faces: Vec<u32>,
    /// Group label of each output face, copied from the input labels; empty without groups.
    pub face_groups: Vec<u32>,
    /// Per group label, the largest error estimate of a vertex of its faces (0 if untouched);
    /// empty without groups.
    pub group_error: Vec<f32>,
    /// The largest error estimate of any collapse made.
    pub error: f32,
}

/// Simplify `mesh` by quadric-error edge collapses until `opts.target_faces` or `opts.max_error`.
///
/// `groups`: optional face partition (a label per input face, labels `0..n_groups`). When given,
/// every group stays a connected, non-empty patch (non-empty only, with [`SimplifyOptions::topology`]).
///
/// Error estimates are in model units. A collapse's error is the larger of its two ends'
/// sqrt(quadric cost / accumulated weight): the weighted RMS distance of the new position to the
/// planes (face, border and seam planes) merged into each end. A vertex's error is its own such
/// distance, or the largest error of the collapses merged into it if larger. These are estimates,
/// not bounds on the Hausdorff distance to the input.
///
/// # Panics
/// If `groups` is given with a length other than the face count.
pub fn simplify(mesh: &Mesh, groups: Option<&[u32]>, opts: &SimplifyOptions) -> Simplified {
    simplify_pinned(mesh, groups, &[], opts)
}

/// [`simplify`] with the vertices `pinned[v]` kept: they never move or go (collapses may end on
/// them), and no collapse joins two of them by a new edge. A piece of a larger mesh simplified
/// alone, its vertices shared with other pieces pinned, then still meets them exactly: every edge
/// between two pinned vertices stays, and none appears that another piece could make too. An
/// empty `pinned` pins nothing. Topology changes, when asked for, leave pinned vertices alone: no
/// cut runs through one, no closed tetrahedron with one goes.
///
/// # Panics
/// If `groups` is given with a length other than the face count, or `pinned` is neither empty
/// nor one flag per vertex.
pub fn simplify_pinned(mesh: &Mesh, groups: Option<&[u32]>, pinned: &[bool], opts: &SimplifyOptions) -> Simplified {
    if let Some(g) = groups {
        assert_eq!(g.len(), mesh.triangles.len(), "simplify: one group label per face");
    }
    assert!(pinned.is_empty() || pinned.len() == mesh.positions.len(), "simplify: one pin flag per vertex");
    let mut s = State::new(mesh, groups);
    s.merge_normal_seams(opts.normal_seam_angle);
    s.pinned = pinned.to_vec();
    if mesh.triangles.len() > opts.target_faces {
        s.init(opts, false);
        s.run(opts);
        let face_target = opts.target_faces > 0 || opts.max_error.is_none();
        if opts.topology && face_target && s.faces_left > opts.target_faces {
            s = State::new(mesh, groups);
            s.merge_normal_seams(opts.normal_seam_angle);
            s.pinned = pinned.to_vec();
            s.init(opts, true);
            s.run(opts);
        }
    }
    s.finish(mesh, groups.is_some())
}
