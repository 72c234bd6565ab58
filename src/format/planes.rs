//! `ORDR` (spec §7.6, format 2.3): separating planes between sibling nodes, from which a viewer
//! orders a front front to back for any eye without sorting faces (`selection.md` §5).
//!
//! A plane entry says that the subtree of one sibling (its geometry and every descendant's) lies
//! in `n·g ≤ first_max` and the other's in `n·g ≥ second_min`, `g` in grid coordinates. Where the
//! two bounds overlap (siblings sharing a border), ordering by the plane can only go wrong for
//! surface points inside that slab. The writer derives the planes from the stored grid points
//! ([`Support`]), like the bounds; nothing else in the file depends on them.

use super::chunk::Fields;
use super::octa;
use crate::error::Result;
use glam::{DVec3, Vec3};

/// Bytes of an entry besides its two indices: the normal's octahedral code and two f32 bounds.
pub const ENTRY_FIXED_BYTES: u64 = 12;

/// One separating plane between two children of the same parent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneEntry {
    /// The child on the low side, relative to the parent's first child.
    pub first: u32,
    /// The child on the high side, relative to the parent's first child.
    pub second: u32,
    /// The plane's normal, octahedral (§8.2).
    pub normal: [i16; 2],
    /// Every point of `first`'s subtree has `n·g ≤ first_max`.
    pub first_max: f32,
    /// Every point of `second`'s subtree has `n·g ≥ second_min`.
    pub second_min: f32,
}

/// Which of the two children of an entry is drawn first for an eye, if the plane decides.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decision {
    FirstBeforeSecond,
    SecondBeforeFirst,
    Undecided,
}

/// The file's planes, grouped by parent: the virtual root (the top level's nodes) first, then
/// every node in node order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Planes {
    /// `starts[p]..starts[p + 1]` are the entries of parent `p`, `p = 0` the virtual root and
    /// `p = i + 1` node `i`. Empty when the file has no `ORDR`.
    pub starts: Vec<u32>,
    pub entries: Vec<PlaneEntry>,
}

impl Planes {
    /// Whether the file carries planes at all.
    pub fn is_empty(&self) -> bool {
        self.starts.is_empty()
    }

    /// The entries between children of `parent` (`None` for the virtual root).
    pub fn of(&self, parent: Option<u32>) -> &[PlaneEntry] {
        &self.entries[self.range(parent)]
    }

    /// Where [`Planes::of`]'s entries lie in `entries` (empty for a parent without any).
    pub fn range(&self, parent: Option<u32>) -> std::ops::Range<usize> {
        let p = parent.map_or(0, |i| i as usize + 1);
        match (self.starts.get(p), self.starts.get(p + 1)) {
            (Some(&a), Some(&b)) => a as usize..b as usize,
            _ => 0..0,
        }
    }
}

/// Where the eye is, in grid coordinates, for the plane tests: a point, or a direction of view
/// for an orthographic camera (the eye infinitely far back along it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Eye {
    At(DVec3),
    Along(DVec3),
}

impl PlaneEntry {
    /// The rule of `selection.md` §5: the eye strictly below `second_min` sees `first` first,
    /// strictly above `first_max` sees `second` first; between, the plane decides nothing.
    pub fn decide(&self, eye: Eye) -> Decision {
        self.decide_with(self.unit_normal(), eye)
    }

    /// The entry's direction, decoded (f32, as the writer measured along it).
    pub fn unit_normal(&self) -> DVec3 {
        octa::decode(self.normal).as_dvec3()
    }

    /// [`PlaneEntry::decide`] with the direction already decoded ([`PlaneEntry::unit_normal`]).
    pub fn decide_with(&self, n: DVec3, eye: Eye) -> Decision {
        match eye {
            Eye::At(g) => {
                let s = (n.x * g.x + n.y * g.y) + n.z * g.z;
                if s < self.second_min as f64 {
                    Decision::FirstBeforeSecond
                } else if s > self.first_max as f64 {
                    Decision::SecondBeforeFirst
                } else {
                    Decision::Undecided
                }
            }
            Eye::Along(d) => {
                let s = (n.x * d.x + n.y * d.y) + n.z * d.z;
                if s > 0.0 {
                    Decision::FirstBeforeSecond
                } else if s < 0.0 {
                    Decision::SecondBeforeFirst
                } else {
                    Decision::Undecided
                }
            }
        }
    }
}

/// Decode the `ORDR` payload: `nodes + 1` u32 entry counts, then the entries; `child_counts(p)`
/// gives the number of children of parent `p` (0 = virtual root). Every count and index is checked
/// before anything is allocated from it.
pub fn decode_ordr(f: &mut Fields, width: u64, nodes: u32, child_counts: impl Fn(usize) -> u32) -> Result<Planes> {
    if width != 2 && width != 4 {
        return Err(f.error_at(f.offset(), format!("entry index width {width}; must be 2 or 4")));
    }
    let parents = nodes as u64 + 1;
    if (f.remaining() as u64) < parents * 4 {
        return Err(f.error(format!("holds {} bytes; the counts of {parents} parents need {}", f.remaining(), parents * 4)));
    }
    let mut starts = Vec::with_capacity(parents as usize + 1);
    let mut total = 0u64;
    starts.push(0);
    for _ in 0..parents {
        total += f.u32()? as u64;
        if total > u32::MAX as u64 {
            return Err(f.error(format!("counts sum to more than {} entries", u32::MAX)));
        }
        starts.push(total as u32);
    }
    let entry = 2 * width + ENTRY_FIXED_BYTES;
    if f.remaining() as u64 != total * entry {
        return Err(f.error(format!("{total} entries of {entry} bytes need {}; {} follow the counts", total * entry, f.remaining())));
    }
    let mut entries = Vec::with_capacity(total as usize);
    for p in 0..parents as usize {
        let children = child_counts(p);
        let mut last: Option<(u32, u32)> = None;
        for _ in starts[p]..starts[p + 1] {
            let at = f.offset();
            let index = |f: &mut Fields| if width == 2 { f.u16().map(u32::from) } else { f.u32() };
            let (first, second) = (index(f)?, index(f)?);
            let normal = [f.u16()? as i16, f.u16()? as i16];
            let (first_max, second_min) = (f.f32()?, f.f32()?);
            let who = || if p == 0 { "the top level".to_string() } else { format!("node {}", p - 1) };
            let pair = (first.min(second), first.max(second));
            if first == second || pair.1 >= children {
                return Err(f.error_at(at, format!("{}: a plane between children {first} and {second} of {children}", who())));
            }
            if last.is_some_and(|l| l >= pair) {
                return Err(
                    f.error_at(at, format!("{}: the plane between children {} and {} is out of order or repeated", who(), pair.0, pair.1))
                );
            }
            if !(first_max.is_finite() && second_min.is_finite()) {
                return Err(f.error_at(at, format!("{}: plane bounds {first_max} and {second_min} must be finite", who())));
            }
            last = Some(pair);
            entries.push(PlaneEntry { first, second, normal, first_max, second_min });
        }
    }
    Ok(Planes { starts, entries })
}

/// The `ORDR` payload and its flags (the index width).
pub fn encode_ordr(planes: &Planes) -> (u32, Vec<u8>) {
    let width = if planes.entries.iter().all(|e| e.first.max(e.second) <= u16::MAX as u32) { 2 } else { 4 };
    let mut p = Vec::with_capacity(planes.starts.len() * 4 + planes.entries.len() * (2 * width + 12));
    for w in planes.starts.windows(2) {
        p.extend_from_slice(&(w[1] - w[0]).to_le_bytes());
    }
    for e in &planes.entries {
        for x in [e.first, e.second] {
            p.extend_from_slice(&x.to_le_bytes()[..width]);
        }
        p.extend(e.normal.iter().flat_map(|x| x.to_le_bytes()));
        p.extend_from_slice(&e.first_max.to_le_bytes());
        p.extend_from_slice(&e.second_min.to_le_bytes());
    }
    (width as u32, p)
}

/// Directions the writer tries for planes: the three axes and 61 more spread over a hemisphere
/// (a Fibonacci lattice), each as its octahedral code.
pub const DIRECTIONS: usize = 64;

/// The writer's directions as codes and their decoded normals.
pub fn directions() -> &'static [([i16; 2], DVec3); DIRECTIONS] {
    static DIRS: std::sync::OnceLock<[([i16; 2], DVec3); DIRECTIONS]> = std::sync::OnceLock::new();
    DIRS.get_or_init(|| {
        let mut out = [([0i16; 2], DVec3::ZERO); DIRECTIONS];
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        for (k, slot) in out.iter_mut().enumerate() {
            let dir = match k {
                0 => Vec3::X,
                1 => Vec3::Y,
                2 => Vec3::Z,
                _ => {
                    let j = (k - 3) as f64;
                    let z = 1.0 - (j + 0.5) / (DIRECTIONS - 3) as f64;
                    let r = (1.0 - z * z).sqrt();
                    let a = golden * j;
                    Vec3::new((r * a.cos()) as f32, (r * a.sin()) as f32, z as f32)
                }
            };
            let code = octa::encode(dir);
            *slot = (code, octa::decode(code).as_dvec3());
        }
        out
    })
}

/// The extent of a set of grid points along each of [`directions`]: per direction the least and
/// the greatest `n·g`, rounded outward to f32 (`[min, max]`). Unions of subtrees take the least of
/// the mins and the greatest of the maxes.
#[derive(Clone, Debug, PartialEq)]
pub struct Support(pub Box<[[f32; 2]; DIRECTIONS]>);

impl Default for Support {
    fn default() -> Self {
        Support(Box::new([[f32::INFINITY, f32::NEG_INFINITY]; DIRECTIONS]))
    }
}

fn down(x: f64) -> f32 {
    let f = x as f32;
    // One step further than the rounding needs, so that the bound holds whatever f64 rounding a
    // reader's own arithmetic adds.
    if (f as f64) <= x {
        f.next_down()
    } else {
        f.next_down().next_down()
    }
}

fn up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) >= x {
        f.next_up()
    } else {
        f.next_up().next_up()
    }
}

impl Support {
    /// Bytes of [`Support::to_bytes`].
    pub const BYTES: usize = DIRECTIONS * 8;

    /// The extents as little-endian f32s, min then max per direction.
    pub fn to_bytes(&self, out: &mut Vec<u8>) {
        out.extend(self.0.iter().flatten().flat_map(|x| x.to_le_bytes()));
    }

    /// The support [`Support::to_bytes`] wrote to `bytes` ([`Support::BYTES`] long).
    pub fn from_bytes(bytes: &[u8]) -> Support {
        debug_assert_eq!(bytes.len(), Support::BYTES);
        let mut s = Support::default();
        for (x, b) in s.0.iter_mut().flatten().zip(bytes.chunks_exact(4)) {
            *x = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        s
    }

    /// The support of `points` (grid coordinates).
    pub fn of(points: &[[u32; 3]]) -> Support {
        let mut s = Support::default();
        for (slot, (_, n)) in s.0.iter_mut().zip(directions()) {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for p in points {
                let v = (n.x * p[0] as f64 + n.y * p[1] as f64) + n.z * p[2] as f64;
                lo = lo.min(v);
                hi = hi.max(v);
            }
            if lo <= hi {
                *slot = [down(lo), up(hi)];
            }
        }
        s
    }

    /// Grow to hold `other` too.
    pub fn union(&mut self, other: &Support) {
        for (a, b) in self.0.iter_mut().zip(other.0.iter()) {
            a[0] = a[0].min(b[0]);
            a[1] = a[1].max(b[1]);
        }
    }

    fn is_empty(&self) -> bool {
        self.0[0][0] > self.0[0][1]
    }
}

/// The best plane the writer's directions give between two subtrees, if its slab is thin: the
/// direction and side whose overlap `first_max − second_min` is least, kept when that is at most
/// `slack` grid units.
pub fn separate(a: &Support, b: &Support, slack: f64) -> Option<PlaneEntry> {
    if a.is_empty() || b.is_empty() {
        return None;
    }
    let mut best: Option<(f64, PlaneEntry)> = None;
    for (k, (code, _)) in directions().iter().enumerate() {
        let (sa, sb) = (a.0[k], b.0[k]);
        for (first, second, first_max, second_min) in [(0, 1, sa[1], sb[0]), (1, 0, sb[1], sa[0])] {
            let overlap = first_max as f64 - second_min as f64;
            if best.as_ref().is_none_or(|(o, _)| overlap < *o) {
                best = Some((overlap, PlaneEntry { first, second, normal: *code, first_max, second_min }));
            }
        }
    }
    best.filter(|(o, _)| *o <= slack).map(|(_, e)| e)
}

/// Eye position `eye` (model units) in grid coordinates.
pub fn grid_eye(grid: &super::Grid, eye: Vec3) -> DVec3 {
    let o = DVec3::from_array(grid.origin);
    (eye.as_dvec3() - o) / grid.step
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_support_reads_back_from_its_bytes() {
        let s = Support::of(&[[0, 7, 3], [1000, 20, 65_535], [5, 5, 1 << 20]]);
        let mut bytes = vec![1, 2];
        s.to_bytes(&mut bytes);
        assert_eq!(bytes.len(), 2 + Support::BYTES);
        assert_eq!(Support::from_bytes(&bytes[2..]), s);
        assert_eq!(
            Support::from_bytes(&{
                let mut b = Vec::new();
                Support::default().to_bytes(&mut b);
                b
            }),
            Support::default()
        );
    }

    #[test]
    fn separated_boxes_get_a_plane_with_a_gap_and_the_eye_decides() {
        let a = Support::of(&[[0, 0, 0], [10, 10, 10]]);
        let b = Support::of(&[[20, 0, 0], [30, 10, 10]]);
        let e = separate(&a, &b, 0.0).expect("a gap along x");
        assert!(e.first_max < e.second_min);
        let (low, high) = if e.first == 0 { (-5.0, 40.0) } else { (40.0, -5.0) };
        assert_eq!(e.decide(Eye::At(DVec3::new(low, 5.0, 5.0))), Decision::FirstBeforeSecond);
        assert_eq!(e.decide(Eye::At(DVec3::new(high, 5.0, 5.0))), Decision::SecondBeforeFirst);
    }

    #[test]
    fn interleaved_sets_get_no_plane() {
        let corners =
            |lo: u32, hi: u32| -> Vec<[u32; 3]> { (0..8).map(|k| [0, 1, 2].map(|a| if k >> a & 1 == 1 { hi } else { lo })).collect() };
        let a = Support::of(&corners(0, 30));
        let b = Support::of(&corners(10, 20));
        assert!(separate(&a, &b, 1.0).is_none());
    }

    #[test]
    fn bounds_hold_every_point() {
        let pts: Vec<[u32; 3]> = (0..200u32).map(|i| [i * 7919 % 2_000_003, i * 104_729 % 1_048_573, i * 31 % 999_983]).collect();
        let s = Support::of(&pts);
        for (k, (_, n)) in directions().iter().enumerate() {
            for p in &pts {
                let v = (n.x * p[0] as f64 + n.y * p[1] as f64) + n.z * p[2] as f64;
                assert!(s.0[k][0] as f64 <= v && v <= s.0[k][1] as f64);
            }
        }
    }
}
