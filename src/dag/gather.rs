//! Gathering a level's nodes into groups of about [`PER_GROUP`] adjacent nodes: the units the next
//! level simplifies, each with its outer border pinned.
//!
//! Seeds are taken in node order; a group grows by the free neighbour that shares the most edges
//! with its members, so group borders run short. Groups left smaller (no free neighbour: separate
//! components, corners between full groups) are merged in the Morton order of their centers, so
//! small components of the model gather with their near ones rather than staying apart at every
//! level.

use crate::mesh::{box_of, Mesh};
use glam::Vec3;
use rustc_hash::FxHashMap;

/// Nodes per group: eight halve to four nodes of the same size at the next level. Fewer pin more
/// of each level (notes/dag.md: 4 kept less of the bunny at 10 % of its faces, 16 too).
pub const PER_GROUP: usize = 8;

/// The group of each node, given the node of each face of `mesh` (labels `0..nodes`, each used),
/// and how many groups.
pub fn gather(mesh: &Mesh, node_of_face: &[u32], nodes: usize) -> (Vec<u32>, usize) {
    let mut center = vec![Vec3::ZERO; nodes];
    let mut count = vec![0u32; nodes];
    let mut owner: FxHashMap<u64, u32> = FxHashMap::default();
    let mut shared: FxHashMap<u64, u32> = FxHashMap::default();
    for (f, t) in mesh.triangles.iter().enumerate() {
        let n = node_of_face[f];
        center[n as usize] += t.iter().map(|&v| mesh.positions[v as usize]).sum::<Vec3>() / 3.0;
        count[n as usize] += 1;
        for k in 0..3 {
            let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
            match owner.entry(pair(a, b)) {
                std::collections::hash_map::Entry::Occupied(m) if *m.get() != n => {
                    let m = *m.get();
                    *shared.entry(pair(m.min(n), m.max(n))).or_default() += 1;
                }
                std::collections::hash_map::Entry::Occupied(_) => {}
                std::collections::hash_map::Entry::Vacant(e) => {
                    e.insert(n);
                }
            }
        }
    }
    for (c, &k) in center.iter_mut().zip(&count) {
        *c /= k.max(1) as f32;
    }
    let mut neighbours: Vec<Vec<(u32, u32)>> = vec![Vec::new(); nodes];
    for (&key, &w) in &shared {
        let (a, b) = ((key >> 32) as u32, key as u32);
        neighbours[a as usize].push((b, w));
        neighbours[b as usize].push((a, w));
    }
    for l in &mut neighbours {
        l.sort_unstable();
    }

    let mut group = vec![u32::MAX; nodes];
    let mut members_of: Vec<Vec<u32>> = Vec::new();
    for seed in 0..nodes {
        if group[seed] != u32::MAX {
            continue;
        }
        let g = members_of.len() as u32;
        group[seed] = g;
        let mut members = vec![seed as u32];
        while members.len() < PER_GROUP {
            let best = members
                .iter()
                .flat_map(|&x| neighbours[x as usize].iter())
                .filter(|&&(y, _)| group[y as usize] == u32::MAX)
                .fold(None, |best: Option<(u32, u32)>, &(y, w)| if best.is_none_or(|b| w > b.1) { Some((y, w)) } else { best });
            let Some((y, _)) = best else { break };
            group[y as usize] = g;
            members.push(y);
        }
        members_of.push(members);
    }

    // Small groups merge along the Morton order of their centers.
    let bounds = box_of(center.iter().copied()).unwrap_or_default();
    let small: Vec<u32> = (0..members_of.len() as u32).filter(|&g| members_of[g as usize].len() < PER_GROUP).collect();
    let items: Vec<(Vec3, usize)> = small
        .iter()
        .map(|&g| {
            let m = &members_of[g as usize];
            (m.iter().map(|&n| center[n as usize]).sum::<Vec3>() / m.len() as f32, m.len())
        })
        .collect();
    let mut merged_into = (0..members_of.len() as u32).collect::<Vec<u32>>();
    for run in morton_runs(&items, bounds, PER_GROUP) {
        for &i in &run {
            merged_into[small[i] as usize] = small[run[0]];
        }
    }
    let mut renumber = vec![u32::MAX; members_of.len()];
    let mut groups = 0u32;
    for g in 0..members_of.len() {
        let root = merged_into[g] as usize;
        if renumber[root] == u32::MAX {
            renumber[root] = groups;
            groups += 1;
        }
        renumber[g] = renumber[root];
    }
    (group.iter().map(|&g| renumber[g as usize]).collect(), groups as usize)
}

fn pair(a: u32, b: u32) -> u64 {
    (a as u64) << 32 | b as u64
}

/// The mean of the corners of `faces` of `mesh` (the origin for none): where a group of faces
/// stands in the Morton order of [`morton_runs`].
pub(super) fn centre(mesh: &Mesh, faces: &[u32]) -> Vec3 {
    let sum: Vec3 = faces.iter().flat_map(|&f| mesh.triangles[f as usize]).map(|v| mesh.positions[v as usize]).sum();
    sum / (3 * faces.len().max(1)) as f32
}

/// Items `(centre, weight)` taken in the Morton order of their centres within `bounds` (equal
/// codes by index) and joined into runs, each closed once its weight reaches `target` (the last
/// may fall short): indices into `items`, run by run.
pub(super) fn morton_runs(items: &[(Vec3, usize)], (lo, hi): (Vec3, Vec3), target: usize) -> Vec<Vec<usize>> {
    let scale = 1023.0 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let mut order: Vec<(u32, usize)> = items
        .iter()
        .enumerate()
        .map(|(i, &(c, _))| (morton(((c - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(1023.0)).as_uvec3().to_array()), i))
        .collect();
    order.sort_unstable();
    let mut runs = Vec::new();
    let (mut run, mut weight) = (Vec::new(), 0);
    for (_, i) in order {
        run.push(i);
        weight += items[i].1;
        if weight >= target {
            runs.push(std::mem::take(&mut run));
            weight = 0;
        }
    }
    if !run.is_empty() {
        runs.push(run);
    }
    runs
}

/// Interleaved bits of three 10-bit coordinates.
fn morton(c: [u32; 3]) -> u32 {
    let spread = |mut x: u32| {
        x &= 0x3ff;
        x = (x | x << 16) & 0x0300_00ff;
        x = (x | x << 8) & 0x0300_f00f;
        x = (x | x << 4) & 0x030c_30c3;
        (x | x << 2) & 0x0924_9249
    };
    spread(c[0]) | spread(c[1]) << 1 | spread(c[2]) << 2
}
