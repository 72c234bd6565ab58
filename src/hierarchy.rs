//! The group hierarchy: grouping rounds ([`crate::group`]) run again and again on their own output
//! with relaxing thresholds and growing caps (METHOD.md §2–3).
//!
//! Two kinds of partition come out, both as plain arrays:
//! - **clusters**: small groups of tens of faces with tight cones, for back-face culling inside a
//!   streamed node (a chunk wants hundreds of faces, tight cones want few);
//! - **levels** 0 (finest node level, the streamed leaves) … L (top): each level-ℓ group is a union of
//!   level-(ℓ−1) groups (of clusters for level 0); a virtual root holds the top groups.
//!
//! Groups only grow across edges shared by two faces, so no group spans disconnected parts, with one
//! exception made after grouping: a small component that leaves a coarse level is taken in by a
//! group of that level near it ([`Hierarchy::absorb`], [`crate::small_components`]).

use crate::cone::{smallest_enclosing, Cone};
use crate::group::{group_round, RoundParams, Unit};
use crate::mesh::{box_of, Adjacency, Mesh, NO_FACE};
use glam::Vec3;
use rayon::prelude::*;

/// Marks "no parent": the group is a top group, a child of the virtual root.
pub use crate::format::NO_PARENT;

pub use crate::format::HierarchyParams;

/// What the hierarchy records of each group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupInfo {
    /// Contains every face normal of the group and every cone of its children.
    pub cone: Cone,
    /// Bounding sphere of the group's vertices.
    pub center: Vec3,
    pub radius: f32,
    /// Bounding box of the group's vertices.
    pub min: Vec3,
    pub max: Vec3,
    /// Faces of the input mesh in the group.
    pub faces: u32,
    pub area: f32,
    /// Sum of face area × unit face normal.
    pub area_normal: Vec3,
}

/// A list of lists as offsets into one array: list `i` is `items[offsets[i]..offsets[i + 1]]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lists {
    pub offsets: Vec<u32>,
    pub items: Vec<u32>,
}

impl Lists {
    pub fn get(&self, i: usize) -> &[u32] {
        &self.items[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Lists `0..n` where list `k` holds, in increasing order, every `i` with `labels[i] == k`.
    pub fn from_labels(labels: &[u32], n: usize) -> Lists {
        let mut offsets = vec![0u32; n + 1];
        for &k in labels {
            offsets[k as usize + 1] += 1;
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut items = vec![0u32; labels.len()];
        for (i, &k) in labels.iter().enumerate() {
            items[fill[k as usize] as usize] = i as u32;
            fill[k as usize] += 1;
        }
        Lists { offsets, items }
    }

    /// Symmetric adjacency lists of `n` nodes from unordered pairs.
    fn from_pairs(pairs: &[[u32; 2]], n: usize) -> Lists {
        let mut offsets = vec![0u32; n + 1];
        for &[a, b] in pairs {
            offsets[a as usize + 1] += 1;
            offsets[b as usize + 1] += 1;
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut items = vec![0u32; 2 * pairs.len()];
        for &[a, b] in pairs {
            items[fill[a as usize] as usize] = b;
            fill[a as usize] += 1;
            items[fill[b as usize] as usize] = a;
            fill[b as usize] += 1;
        }
        let mut lists = Lists { offsets, items };
        for i in 0..n {
            let (s, e) = (lists.offsets[i] as usize, lists.offsets[i + 1] as usize);
            lists.items[s..e].sort_unstable();
        }
        lists
    }
}

/// One partition of the mesh's faces.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Level {
    /// Group of each face of the input mesh.
    pub face_group: Vec<u32>,
    pub groups: Vec<GroupInfo>,
    /// Children of each group: groups of the level below (clusters, for level 0; none for clusters).
    pub children: Lists,
    /// Parent of each group in the level above, or [`NO_PARENT`].
    pub parent: Vec<u32>,
    /// Groups of the same level that share an edge with each group.
    pub neighbors: Lists,
    /// Cone threshold and size cap this level was grouped with.
    pub max_angle: f32,
    pub max_faces: u32,
}

/// Culling clusters and node levels, finest first.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Hierarchy {
    pub clusters: Level,
    pub levels: Vec<Level>,
}

impl Hierarchy {
    /// The partition below level `l`: the clusters for level 0, else level `l − 1`.
    pub fn below(&self, l: usize) -> &Level {
        if l == 0 {
            &self.clusters
        } else {
            &self.levels[l - 1]
        }
    }

    /// Add a level above the top with the top's partition again, each top group the one child of
    /// its copy: level meshes can then coarsen further than the grouping alone allows, so the level
    /// a viewer shows first stays small.
    pub fn repeat_top(&mut self) {
        let Some(top) = self.levels.last_mut() else { return };
        let n = top.groups.len() as u32;
        top.parent = (0..n).collect();
        let mut level = top.clone();
        level.children = Lists { offsets: (0..=n).collect(), items: (0..n).collect() };
        level.parent = vec![NO_PARENT; n as usize];
        self.levels.push(level);
    }

    /// Move whole groups of level `l` into others: group `g` goes into `into[g]` (itself when it
    /// stays), which must stay; `l ≥ 1`. A moved group has no neighbours (it shares no edge with
    /// another); its faces, children and bounds become its absorber's, and the groups above it
    /// that held nothing else go the same way, level by level up to the top. Groups are
    /// renumbered in order; returns, per old group of level `l`, its new number (for a moved
    /// group, its absorber's).
    pub fn absorb(&mut self, l: usize, into: &[u32]) -> Vec<u32> {
        assert!(l >= 1, "level 0's groups hold the clusters; they never move");
        debug_assert!((0..into.len()).all(|g| into[g] as usize == g || self.levels[l].neighbors.get(g).is_empty()));
        let mut fate = into.to_vec();
        let mut first_renumber = Vec::new();
        for k in l..self.levels.len() {
            let n = self.levels[k].groups.len();
            debug_assert_eq!(fate.len(), n);
            let mut renumber = vec![u32::MAX; n];
            let mut kept = 0u32;
            for g in 0..n {
                if fate[g] as usize == g {
                    renumber[g] = kept;
                    kept += 1;
                }
            }
            for g in 0..n {
                let target = fate[g] as usize;
                debug_assert_eq!(fate[target] as usize, target, "an absorber must stay");
                renumber[g] = renumber[target];
            }
            let old_parent = std::mem::take(&mut self.levels[k].parent);
            let level = &mut self.levels[k];
            let mut groups: Vec<GroupInfo> = (0..n).filter(|&g| fate[g] as usize == g).map(|g| level.groups[g]).collect();
            for g in (0..n).filter(|&g| fate[g] as usize != g) {
                let r = renumber[g] as usize;
                groups[r] = groups[r].union(&level.groups[g]);
            }
            level.groups = groups;
            for g in &mut level.face_group {
                *g = renumber[*g as usize];
            }
            let mut offsets = vec![0u32];
            let mut items = Vec::with_capacity(level.neighbors.items.len());
            for g in (0..n).filter(|&g| fate[g] as usize == g) {
                items.extend(level.neighbors.get(g).iter().map(|&x| renumber[x as usize]));
                offsets.push(items.len() as u32);
            }
            level.neighbors = Lists { offsets, items };
            let kept = kept as usize;
            // The level below points at the new numbers; children follow from it.
            for p in &mut self.levels[k - 1].parent {
                *p = renumber[*p as usize];
            }
            self.levels[k].children = Lists::from_labels(&self.levels[k - 1].parent, kept);
            // Above: a group goes when all its children went, into the parent of their absorber.
            let parent: Vec<u32> = (0..n).filter(|&g| fate[g] as usize == g).map(|g| old_parent[g]).collect();
            if k + 1 < self.levels.len() {
                let above = self.levels[k + 1].groups.len();
                let mut stays = vec![false; above];
                let mut next: Vec<u32> = (0..above as u32).collect();
                for g in 0..n {
                    if fate[g] as usize == g {
                        stays[old_parent[g] as usize] = true;
                    }
                }
                for g in 0..n {
                    let p = old_parent[g] as usize;
                    if !stays[p] {
                        // Its one child: groups merge across shared edges, which a moved one lacks.
                        debug_assert_eq!(self.levels[k + 1].children.get(p).len(), 1);
                        next[p] = old_parent[fate[g] as usize];
                    }
                }
                fate = next;
            }
            self.levels[k].parent = parent;
            if k == l {
                first_renumber = renumber;
            }
        }
        first_renumber
    }

    /// Remove the top level (never the last one); its children become the top.
    pub fn pop_top(&mut self) {
        if self.levels.len() > 1 {
            self.levels.pop();
            if let Some(top) = self.levels.last_mut() {
                top.parent = vec![NO_PARENT; top.groups.len()];
            }
        }
    }
}

impl GroupInfo {
    /// Bounds, cone and counts that cover both groups.
    pub fn union(&self, other: &GroupInfo) -> GroupInfo {
        let (min, max) = (self.min.min(other.min), self.max.max(other.max));
        let center = 0.5 * (min + max);
        let radius = (center.distance(self.center) + self.radius).max(center.distance(other.center) + other.radius) * (1.0 + 1e-6);
        GroupInfo {
            cone: self.cone.merge(&other.cone),
            center,
            radius,
            min,
            max,
            faces: self.faces + other.faces,
            area: self.area + other.area,
            area_normal: self.area_normal + other.area_normal,
        }
    }
}

/// Build the hierarchy of `mesh` (whose edge adjacency is `adj`).
pub fn build(mesh: &Mesh, adj: &Adjacency, p: &HierarchyParams) -> Hierarchy {
    build_levels(mesh, adj, p, None)
}

/// [`build`] with exactly `levels` node levels when given: grouping stops there, and a grouping
/// that ends lower is topped up with [`Hierarchy::repeat_top`]. The partitioned build gives every
/// cell the same number of levels this way, so that cells meet level by level.
pub fn build_levels(mesh: &Mesh, adj: &Adjacency, p: &HierarchyParams, levels: Option<usize>) -> Hierarchy {
    let nf = mesh.face_count();
    let total = nf.max(1) as u32;
    let round = RoundParams { max_angle: p.cluster_angle, max_faces: p.cluster_faces.min(total), kc: p.kc, ks: p.ks, kn: p.kn };

    // Clusters, from faces.
    let face_units: Vec<Unit> = (0..nf).into_par_iter().map(|f| face_unit(mesh, f)).collect();
    let face_pairs = face_pairs(adj);
    let cluster_labels = cluster_round(&face_units, &face_pairs, &round);
    let mut clusters = make_level(mesh, cluster_labels, None, &[], p.cluster_angle, p.cluster_faces);
    let pairs = group_pairs(&face_pairs, &clusters.face_group);
    clusters.neighbors = Lists::from_pairs(&pairs, clusters.groups.len());
    let mut h = Hierarchy { clusters, levels: Vec::new() };
    grow(mesh, &mut h, pairs, p, (p.leaf_angle, p.leaf_faces), levels.unwrap_or(usize::MAX));
    while levels.is_some_and(|n| h.levels.len() < n) {
        h.repeat_top();
    }
    h
}

/// Levels above `base`, a partition of `mesh`'s faces whose groups' summaries are given (the top
/// groups of cells built apart, for the partitioned build): grouping rounds go on from `base`'s
/// threshold and cap. The result's level 0 is `base` (with its neighbours from `adj`); it has no
/// clusters. With `levels`, it has exactly that many (as [`build_levels`]).
pub fn extend(mesh: &Mesh, adj: &Adjacency, mut base: Level, p: &HierarchyParams, levels: Option<usize>) -> Hierarchy {
    let pairs = group_pairs(&face_pairs(adj), &base.face_group);
    base.neighbors = Lists::from_pairs(&pairs, base.groups.len());
    let next = ((base.max_angle + p.angle_step).min(std::f32::consts::PI), base.max_faces.saturating_mul(p.growth.max(2)));
    let mut h = Hierarchy { clusters: Level::default(), levels: vec![base] };
    grow(mesh, &mut h, pairs, p, next, levels.unwrap_or(usize::MAX));
    while levels.is_some_and(|n| h.levels.len() < n) {
        h.repeat_top();
    }
    h
}

/// Each pair of edge-adjacent faces once.
fn face_pairs(adj: &Adjacency) -> Vec<[u32; 2]> {
    adj.face_neighbors
        .iter()
        .enumerate()
        .flat_map(|(f, n)| n.iter().filter(move |&&g| g != NO_FACE && (f as u32) < g).map(move |&g| [f as u32, g]))
        .collect()
}

/// Grouping rounds on the top of `h` (its clusters while it has no level), whose groups are joined
/// by `pairs`, from threshold and cap `start`, until the top has at most `p.top_groups` groups, no
/// round merges any more, or `h` has `max_levels` levels.
fn grow(mesh: &Mesh, h: &mut Hierarchy, mut pairs: Vec<[u32; 2]>, p: &HierarchyParams, start: (f32, u32), max_levels: usize) {
    // Caps count faces of the input, which the groups record (the mesh may be a coarse level).
    let below = h.levels.last().unwrap_or(&h.clusters);
    let total = below.groups.iter().map(|g| g.faces as u64).sum::<u64>().clamp(1, u32::MAX as u64) as u32;
    let round = |max_angle: f32, max_faces: u32| RoundParams { max_angle, max_faces, kc: p.kc, ks: p.ks, kn: p.kn };
    let (mut angle, mut cap) = start;
    while h.levels.len() < max_levels {
        let below = h.levels.last().unwrap_or(&h.clusters);
        let units: Vec<Unit> = below.groups.iter().map(group_unit).collect();
        let labels = group_round(&units, &pairs, &round(angle, cap.min(total)));
        let count = labels.iter().max().map_or(0, |&m| m as usize + 1);
        let progressed = count < below.groups.len();
        let saturated = angle >= std::f32::consts::PI && cap >= total;
        if progressed || h.levels.is_empty() {
            let face_group: Vec<u32> = below.face_group.iter().map(|&g| labels[g as usize]).collect();
            let mut level = make_level(mesh, face_group, Some(&labels), &below.groups, angle, cap);
            pairs = group_pairs(&pairs, &labels);
            level.neighbors = Lists::from_pairs(&pairs, level.groups.len());
            h.levels.last_mut().unwrap_or(&mut h.clusters).parent = labels;
            h.levels.push(level);
        }
        let done = h.levels.last().map_or(0, |l| l.groups.len()) <= p.top_groups;
        if done || (saturated && !progressed) {
            break;
        }
        angle = (angle + p.angle_step).min(std::f32::consts::PI);
        cap = cap.saturating_mul(p.growth.max(2));
    }
    if let Some(top) = h.levels.last_mut() {
        top.parent = vec![NO_PARENT; top.groups.len()];
    }
}

/// Faces per independent piece of the cluster round.
const CLUSTER_PIECE: usize = 16384;

/// The cluster round, run in parallel on pieces of about [`CLUSTER_PIECE`] faces that are
/// contiguous in Morton order of their centroids: clusters never cross a piece's border, which
/// costs little (clusters are small) and keeps every heap small and cache-resident. The pieces
/// depend only on the mesh, so the result does not depend on the number of threads.
fn cluster_round(units: &[Unit], pairs: &[[u32; 2]], p: &RoundParams) -> Vec<u32> {
    let n = units.len();
    if n <= CLUSTER_PIECE {
        return group_round(units, pairs, p);
    }
    let (lo, hi) = box_of(units.iter().map(|u| u.center)).unwrap_or_default();
    let scale = 1023.0 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let mut order: Vec<(u32, u32)> = units.iter().enumerate().map(|(i, u)| (morton((u.center - lo) * scale), i as u32)).collect();
    order.par_sort_unstable();
    let mut rank = vec![0u32; n];
    for (r, &(_, i)) in order.iter().enumerate() {
        rank[i as usize] = r as u32;
    }
    let pieces = n.div_ceil(CLUSTER_PIECE);
    let mut piece_pairs: Vec<Vec<[u32; 2]>> = vec![Vec::new(); pieces];
    for &[a, b] in pairs {
        let (ra, rb) = (rank[a as usize] as usize, rank[b as usize] as usize);
        if ra / CLUSTER_PIECE == rb / CLUSTER_PIECE {
            piece_pairs[ra / CLUSTER_PIECE].push([(ra % CLUSTER_PIECE) as u32, (rb % CLUSTER_PIECE) as u32]);
        }
    }
    let local: Vec<Vec<u32>> = order
        .par_chunks(CLUSTER_PIECE)
        .zip(piece_pairs.par_iter())
        .map(|(chunk, pp)| {
            let piece_units: Vec<Unit> = chunk.iter().map(|&(_, i)| units[i as usize]).collect();
            group_round(&piece_units, pp, p)
        })
        .collect();
    let mut labels = vec![0u32; n];
    let mut base = 0u32;
    for (c, piece) in local.iter().enumerate() {
        for (k, &l) in piece.iter().enumerate() {
            labels[order[c * CLUSTER_PIECE + k].1 as usize] = base + l;
        }
        base += piece.iter().max().map_or(0, |&m| m + 1);
    }
    labels
}

/// Interleave the bits of three 10-bit coordinates.
fn morton(q: Vec3) -> u32 {
    fn spread(x: f32) -> u32 {
        let mut v = (x.max(0.0) as u32).min(1023);
        v = (v | (v << 16)) & 0x0300_00FF;
        v = (v | (v << 8)) & 0x0300_F00F;
        v = (v | (v << 4)) & 0x030C_30C3;
        (v | (v << 2)) & 0x0924_9249
    }
    spread(q.x) | (spread(q.y) << 1) | (spread(q.z) << 2)
}

fn face_unit(mesh: &Mesh, f: usize) -> Unit {
    let [a, b, c] = mesh.triangles[f].map(|v| mesh.positions[v as usize]);
    let center = (a + b + c) / 3.0;
    let radius = center.distance(a).max(center.distance(b)).max(center.distance(c)) * (1.0 + 1e-6);
    let n = mesh.face_normals[f];
    Unit { cone: Cone::from_normal(n), area_normal: n * mesh.face_areas[f], center, radius, faces: 1 }
}

fn group_unit(g: &GroupInfo) -> Unit {
    Unit { cone: g.cone, area_normal: g.area_normal, center: g.center, radius: g.radius, faces: g.faces }
}

/// Distinct unordered pairs of different groups joined by an item pair.
fn group_pairs(item_pairs: &[[u32; 2]], label: &[u32]) -> Vec<[u32; 2]> {
    let mut out: Vec<[u32; 2]> = item_pairs
        .iter()
        .map(|&[a, b]| (label[a as usize], label[b as usize]))
        .filter(|(a, b)| a != b)
        .map(|(a, b)| [a.min(b), a.max(b)])
        .collect();
    out.par_sort_unstable();
    out.dedup();
    out
}

/// Group summaries of a partition. `labels` maps the groups `below` to the new groups (None for
/// clusters, built from faces); cones then also enclose the children's cones.
fn make_level(mesh: &Mesh, face_group: Vec<u32>, labels: Option<&[u32]>, below: &[GroupInfo], max_angle: f32, max_faces: u32) -> Level {
    let ng = face_group.iter().max().map_or(0, |&m| m as usize + 1);
    let faces_of = Lists::from_labels(&face_group, ng);
    let children = labels.map(|l| Lists::from_labels(l, ng)).unwrap_or_default();
    let groups: Vec<GroupInfo> = (0..ng)
        .into_par_iter()
        .map(|g| {
            let faces = faces_of.get(g);
            let normals: Vec<Vec3> = faces.iter().map(|&f| mesh.face_normals[f as usize]).collect();
            let mut cone = smallest_enclosing(&normals);
            if labels.is_some() {
                for &c in children.get(g) {
                    let child = &below[c as usize].cone;
                    let reach = cone.axis.dot(child.axis).clamp(-1.0, 1.0).acos() + child.half_angle;
                    cone.half_angle = cone.half_angle.max(reach).min(std::f32::consts::PI);
                }
            }
            let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
            let (mut area, mut area_normal) = (0.0f32, Vec3::ZERO);
            for &f in faces {
                for &v in &mesh.triangles[f as usize] {
                    let p = mesh.positions[v as usize];
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
                area += mesh.face_areas[f as usize];
                area_normal += mesh.face_normals[f as usize] * mesh.face_areas[f as usize];
            }
            let center = 0.5 * (lo + hi);
            let radius = faces
                .iter()
                .flat_map(|&f| mesh.triangles[f as usize])
                .map(|v| center.distance(mesh.positions[v as usize]))
                .fold(0.0f32, f32::max)
                * (1.0 + 1e-6);
            // Faces of the input: the children's (the partitioned build's merge groups a coarse
            // level mesh, whose faces are not the input's), else this mesh's own.
            let input_faces = match labels {
                Some(_) => children.get(g).iter().map(|&c| below[c as usize].faces).sum(),
                None => faces.len() as u32,
            };
            GroupInfo { cone, center, radius, min: lo, max: hi, faces: input_faces, area, area_normal }
        })
        .collect();
    Level { face_group, parent: Vec::new(), children, neighbors: Lists::default(), groups, max_angle, max_faces }
}
