//! Small components leave coarse levels (issue 14): a scan or an isosurface carries hundreds of
//! specks (noise, fragments, the scanner table's screws), and since a group never spans two
//! components each speck would stay a node of its own at every level, holding up the top level's
//! size and the skeleton's.
//!
//! A whole component — a group of level ℓ that shares no edge with another: a component, or a
//! piece joined to the rest only at vertices or non-manifold edges, whose removal opens no hole —
//! leaves level ℓ when a group of that level near it already has an error of at least the
//! component's size (the diagonal of its faces' box in Mℓ): its faces are dropped from Mℓ and
//! that group takes it in (its bounds, cone and children, [`Hierarchy::absorb`]), so
//! the component's finer node is reached by refining the absorber. What the front loses by drawing
//! the absorber instead is within the error the absorber already claims; its error is raised only
//! where the component's own error is larger (its children's, which any parent covers). "Near"
//! means inside the absorber's sphere grown to twice its radius (a chain of absorbers in one call
//! can reach further); among the groups that qualify, the one whose sphere grows least, then
//! whose cone widens least, is chosen (an absorber's sphere and cone decide when it is refined and
//! culled).

use crate::hierarchy::{GroupInfo, Hierarchy};
use crate::levels::LevelMesh;
use glam::Vec3;
use rustc_hash::FxHashMap;

/// Drop the components of level mesh `level` (level `l` of `h`, `l ≥ 1`) that may leave it, and
/// give them to their absorbers in `h`; returns how many left.
pub fn leave(level: &mut LevelMesh, h: &mut Hierarchy, l: usize) -> usize {
    let hl = &h.levels[l];
    let n = hl.groups.len();
    let errors = &level.group_error;
    let largest = errors.iter().copied().fold(0.0f32, f32::max);
    let size = own_sizes(level, n);
    let mut candidates: Vec<u32> =
        (0..n as u32).filter(|&g| hl.neighbors.get(g as usize).is_empty() && size[g as usize] <= largest).collect();
    if candidates.is_empty() || n < 2 {
        return 0;
    }
    candidates.sort_by(|&a, &b| size[a as usize].total_cmp(&size[b as usize]).then(a.cmp(&b)));

    let smallest = size[candidates[0] as usize];
    let grid = Reach::new(&hl.groups, |g| errors[g] >= smallest && hl.groups[g].radius > 0.0);
    let mut into: Vec<u32> = (0..n as u32).collect();
    let mut absorbed_size = vec![0.0f32; n];
    let mut left = Vec::new();
    for &c in &candidates {
        let info = &hl.groups[c as usize];
        let d = size[c as usize];
        let mut best: Option<(f32, f32, u32)> = None;
        let mut examined = 0;
        grid.around(info.center, |p| {
            examined += 1;
            if examined > MAX_EXAMINED || best.is_some_and(|b| b.0 <= 1.0 && b.1 <= 0.0) {
                return false;
            }
            if p == c || into[p as usize] != p || errors[p as usize] < d {
                return true;
            }
            let pi = &hl.groups[p as usize];
            let dist = pi.center.distance(info.center);
            if dist + info.radius > 2.0 * pi.radius {
                return true;
            }
            let widening = pi.cone.merge(&info.cone).half_angle - pi.cone.half_angle;
            let growth = (dist + info.radius).max(pi.radius) / pi.radius;
            let key = (growth, widening, p);
            if best.is_none_or(|b| key < b) {
                best = Some(key);
            }
            true
        });
        if let Some((_, _, p)) = best {
            into[c as usize] = p;
            absorbed_size[p as usize] = absorbed_size[p as usize].max(d);
            left.push(c);
        }
    }
    if left.is_empty() {
        return 0;
    }
    // A group that took others in and left later hands them on. Its absorber was still there
    // when it left, so going back from the last to leave, each absorber's own is already final.
    for &c in left.iter().rev() {
        into[c as usize] = into[into[c as usize] as usize];
    }
    let renumber = h.absorb(l, &into);
    let mut group_error = vec![0.0f32; h.levels[l].groups.len()];
    for g in 0..n {
        let r = renumber[g] as usize;
        group_error[r] = group_error[r].max(level.group_error[g]).max(absorbed_size[g]);
    }
    let keep: Vec<usize> = (0..level.face_group.len()).filter(|&f| into[level.face_group[f] as usize] == level.face_group[f]).collect();
    level.mesh = std::mem::take(&mut level.mesh).subset(&keep);
    level.face_group = keep.iter().map(|&f| renumber[level.face_group[f] as usize]).collect();
    level.group_error = group_error;
    left.len()
}

/// Groups a query looks at, at most, for one candidate: coincident specks would otherwise make
/// each query scan them all. The first that grows no sphere and widens no cone also ends it.
const MAX_EXAMINED: usize = 4096;

/// Per group of `level`, the size of what leaving takes from the level's image: the diagonal of
/// the box of its own faces in that level (what it absorbed earlier is already gone from it).
fn own_sizes(level: &LevelMesh, n: usize) -> Vec<f32> {
    let mut boxes = vec![(Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)); n];
    for (t, &g) in level.mesh.triangles.iter().zip(&level.face_group) {
        let b = &mut boxes[g as usize];
        for &v in t {
            let p = level.mesh.positions[v as usize];
            (b.0, b.1) = (b.0.min(p), b.1.max(p));
        }
    }
    boxes.into_iter().map(|(lo, hi)| if lo.x <= hi.x { (hi - lo).length() } else { 0.0 }).collect()
}

/// The groups whose doubled spheres may hold a point: a hash grid per power-of-two radius class,
/// cells four class radii wide, so a query looks at 27 cells per class.
struct Reach {
    /// Per class: its cell size and its groups by cell.
    classes: Vec<(f32, Cells)>,
}

type Cells = FxHashMap<[i32; 3], Vec<u32>>;

impl Reach {
    /// The groups for which `may` holds.
    fn new(groups: &[GroupInfo], may: impl Fn(usize) -> bool) -> Reach {
        let mut by_class: FxHashMap<i32, Cells> = FxHashMap::default();
        for (g, info) in groups.iter().enumerate().filter(|&(g, _)| may(g)) {
            let class = class_of(info.radius);
            let cell = cell_of(info.center, cell_size(class));
            by_class.entry(class).or_default().entry(cell).or_default().push(g as u32);
        }
        let mut classes: Vec<(i32, Cells)> = by_class.into_iter().collect();
        classes.sort_by_key(|c| c.0);
        Reach { classes: classes.into_iter().map(|(c, m)| (cell_size(c), m)).collect() }
    }

    /// Call `f` with every group whose doubled sphere could hold `p` (and some that do not),
    /// until it returns false.
    fn around(&self, p: Vec3, mut f: impl FnMut(u32) -> bool) {
        for (size, cells) in &self.classes {
            let [x, y, z] = cell_of(p, *size);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        if let Some(list) = cells.get(&[x + dx, y + dy, z + dz]) {
                            if !list.iter().all(|&g| f(g)) {
                                return;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The power of two at or above a (positive) radius.
fn class_of(radius: f32) -> i32 {
    radius.max(f32::MIN_POSITIVE).log2().ceil().clamp(-126.0, 127.0) as i32
}

/// Four class radii: a doubled sphere (radius at most 2^(class+1)) around a center in one cell
/// reaches at most the next cell each way.
fn cell_size(class: i32) -> f32 {
    2f32.powi(class + 2)
}

/// The cell holding `p`, clamped one short of the i32 range so that neighbouring cells exist.
fn cell_of(p: Vec3, size: f32) -> [i32; 3] {
    const LIMIT: f32 = (1u32 << 30) as f32;
    (p / size).floor().to_array().map(|c| c.clamp(-LIMIT, LIMIT) as i32)
}
