//! Positions on the file's grid (spec §5.1): the grid that spans the model, every position on its
//! nearest grid point, and at level 0 distinct input positions kept distinct.

use crate::format::Grid;
use crate::mesh::{box_of, Mesh};
use glam::Vec3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// The grid of the file, `bits` bits per axis ([`GRID_BITS`] in format 2; format 3's precision):
/// its step spans the bounds of every level mesh's positions (level 0 first), and its origin is
/// level 0's minimum lowered on each axis by whole steps to below the other levels' (the step
/// doubled once, the origin recomputed, where the grid would then fall short of their maximum).
/// Input coordinates on a lattice (a scanner's, a voxel grid's, an elevation grid's) then keep
/// their alignment on the grid, whatever the simplified levels' extent.
pub fn model_grid<'a>(levels: impl IntoIterator<Item = &'a Mesh>, bits: u32) -> Grid {
    let mut levels = levels.into_iter();
    let first = levels.next().and_then(Mesh::bounds);
    let (lo, hi) = box_of(first.into_iter().chain(levels.filter_map(Mesh::bounds)).flat_map(|(l, h)| [l, h])).unwrap_or_default();
    let anchor = first.map_or(lo, |b| b.0);
    let fit = Grid::fit(lo, hi, bits);
    if !(lo.is_finite() && hi.is_finite()) {
        return fit;
    }
    // With 2 or more steps per axis one doubling always suffices; a grid of one step (1 bit) may
    // never reach both ends from a lowered origin, and keeps the bounds' own.
    let mut grid = fit;
    for _ in 0..2 {
        let origin: [f64; 3] = std::array::from_fn(|k| {
            let below = (anchor[k] as f64 - lo[k] as f64) / grid.step;
            anchor[k] as f64 - below.ceil() * grid.step
        });
        let covers = (0..3).all(|k| origin[k] + grid.last() as f64 * grid.step >= hi[k] as f64);
        if covers {
            return Grid { origin, ..grid };
        }
        grid.step *= 2.0;
    }
    fit
}

/// Grid steps per median edge that [`auto_grid_bits`] keeps.
pub const STEPS_PER_EDGE: f64 = 64.0;

/// Format 3's default precision: the fewest grid bits (8..=21) whose step is at most
/// 1/[`STEPS_PER_EDGE`] of the median edge of `mesh` (sampled over up to 65,536 faces), so that
/// quantization moves a vertex by a small fraction of its edges whatever the model's size.
pub fn auto_grid_bits(mesh: &Mesh) -> u32 {
    let Some((lo, hi)) = mesh.bounds() else { return 14 };
    let extent = (hi - lo).as_dvec3().max_element();
    let stride = (mesh.face_count() / 65_536).max(1);
    let mut edges: Vec<f64> = mesh
        .triangles
        .iter()
        .step_by(stride)
        .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
        .map(|(a, b)| mesh.positions[a as usize].as_dvec3().distance(mesh.positions[b as usize].as_dvec3()))
        .filter(|d| *d > 0.0 && d.is_finite())
        .collect();
    grid_bits_for(extent, &mut edges)
}

/// The grid bits of [`auto_grid_bits`] for a model whose largest side is `extent`, from a sample
/// of its edges' lengths (positive and finite; reordered); 14 without any.
pub fn grid_bits_for(extent: f64, edges: &mut [f64]) -> u32 {
    if edges.is_empty() || extent.is_nan() || extent <= 0.0 {
        return 14;
    }
    let mid = edges.len() / 2;
    let median = *edges.select_nth_unstable_by(mid, f64::total_cmp).1;
    ((extent * STEPS_PER_EDGE / median).log2().ceil() as u32).clamp(8, crate::format::MAX_GRID_BITS)
}

/// A level mesh's positions on the grid: grid points and the positions they decode to.
pub struct Quantized {
    pub points: Vec<[u32; 3]>,
    pub positions: Vec<Vec3>,
    /// Vertices moved off their nearest grid point to stay distinct, and how far each now lies from
    /// its input position (model units); empty for most meshes.
    pub moved: FxHashMap<u32, f32>,
    /// Format 3: how far each vertex snapped to its node's lattice now lies from its input
    /// position (model units, 0 for vertices left on the grid); empty when nothing snapped.
    pub snapped: Vec<f32>,
}

/// Largest cube radius, in grid steps, searched for a free grid point for a vertex whose nearest
/// one is taken.
const MAX_NUDGE_STEPS: i64 = 8;

impl Quantized {
    /// Every position on its nearest grid point.
    pub fn new(grid: &Grid, mesh: &Mesh) -> Quantized {
        let points: Vec<[u32; 3]> = mesh.positions.iter().map(|&p| grid.encode(p)).collect();
        let positions = points.iter().map(|&g| grid.decode(g)).collect();
        Quantized { points, positions, moved: FxHashMap::default(), snapped: Vec::new() }
    }

    /// Level 0 (spec §5.1): distinct input positions decode to distinct positions, so that the input's
    /// faces stay distinct. A vertex whose nearest grid point decodes to a position an earlier
    /// vertex (in vertex order) already holds goes to the free grid point nearest its input position
    /// in the smallest cube around its nearest grid point that has one.
    pub fn distinct(grid: &Grid, mesh: &Mesh) -> std::result::Result<Quantized, String> {
        Quantized::distinct_keeping(grid, mesh, &[])
    }

    /// [`Quantized::distinct`], the vertices `kept[v]` on their nearest grid point whatever the
    /// others do (taken first, never moved): a piece of a partitioned build keeps the vertices it
    /// shares with other pieces where every piece puts them. Two kept vertices nearer than a grid
    /// step may share a point.
    pub fn distinct_keeping(grid: &Grid, mesh: &Mesh, kept: &[bool]) -> std::result::Result<Quantized, String> {
        let mut q = Quantized::new(grid, mesh);
        let key = |p: Vec3| (p + Vec3::ZERO).to_array().map(f32::to_bits);
        let mut holder: FxHashMap<[u32; 3], u32> = FxHashMap::with_capacity_and_hasher(q.points.len(), Default::default());
        let is_kept = |v: usize| kept.get(v).copied().unwrap_or(false);
        for v in (0..q.points.len()).filter(|&v| is_kept(v)) {
            holder.entry(key(q.positions[v])).or_insert(v as u32);
        }
        for v in (0..q.points.len()).filter(|&v| !is_kept(v)) {
            let first = *holder.entry(key(q.positions[v])).or_insert(v as u32);
            if first == v as u32 || mesh.positions[first as usize] == mesh.positions[v] {
                continue;
            }
            let input = mesh.positions[v].as_dvec3();
            let mut best: Option<(f64, [u32; 3], Vec3)> = None;
            for r in 1..=MAX_NUDGE_STEPS {
                for d in (-r..=r).flat_map(|x| (-r..=r).flat_map(move |y| (-r..=r).map(move |z| [x, y, z]))) {
                    if d.iter().all(|c| c.abs() < r) {
                        continue;
                    }
                    let g: [i64; 3] = std::array::from_fn(|a| q.points[v][a] as i64 + d[a]);
                    if g.iter().any(|&c| c < 0 || c > grid.last() as i64) {
                        continue;
                    }
                    let g = g.map(|c| c as u32);
                    let p = grid.decode(g);
                    let distance = p.as_dvec3().distance(input);
                    if !holder.contains_key(&key(p)) && best.is_none_or(|b| distance < b.0) {
                        best = Some((distance, g, p));
                    }
                }
                if best.is_some() {
                    break;
                }
            }
            let Some((distance, g, p)) = best else {
                return Err(format!(
                    "level 0 vertex {v}: no free grid point within {MAX_NUDGE_STEPS} steps keeps it apart from vertex {first}"
                ));
            };
            holder.insert(key(p), v as u32);
            q.points[v] = g;
            q.positions[v] = p;
            q.moved.insert(v as u32, round_up(distance));
        }
        Ok(q)
    }

    /// Format 3 (spec §8.1 of strata-v3.md): move every vertex that lies inside its node (no edge
    /// on the node's border or the mesh's) to the nearest point of its node's lattice,
    /// `2^shift[g]` grid steps, where `face_group` gives each face's node. Border vertices stay on
    /// the grid, so that neighbouring nodes still share them exactly.
    pub fn snap_inner(&mut self, grid: &Grid, mesh: &Mesh, face_group: &[u32], shift: &[u32]) {
        let n = self.points.len();
        let mut edges: Vec<(u32, u32, bool, u32)> = Vec::with_capacity(3 * mesh.face_count());
        for (f, t) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                edges.push((a.min(b), a.max(b), a < b, face_group[f]));
            }
        }
        edges.par_sort_unstable();
        let mut node = vec![u32::MAX; n];
        let mut border = vec![false; n];
        for run in edges.chunk_by(|x, y| (x.0, x.1) == (y.0, y.1)) {
            let inner = run.len() == 2 && run[0].2 != run[1].2 && run[0].3 == run[1].3;
            for v in [run[0].0, run[0].1] {
                let v = v as usize;
                border[v] |= !inner || (node[v] != u32::MAX && node[v] != run[0].3);
                node[v] = run[0].3;
            }
        }
        self.snapped = vec![0.0; n];
        for v in 0..n {
            if border[v] || node[v] == u32::MAX {
                continue;
            }
            let s = shift[node[v] as usize];
            if s == 0 {
                continue;
            }
            let g = self.points[v].map(|x| crate::format::geom::v3::snap(x, s, grid.bits));
            let p = grid.decode(g);
            self.points[v] = g;
            self.positions[v] = p;
            self.snapped[v] = round_up(p.as_dvec3().distance(mesh.positions[v].as_dvec3()));
        }
    }

    /// The quantization bound of `faces` of `mesh`: [`Grid::error`], or the distance of a moved or
    /// snapped vertex from its input position where larger.
    pub fn error(&self, grid: &Grid, mesh: &Mesh, faces: &[u32]) -> f32 {
        let mut e = grid.error();
        if !self.moved.is_empty() || !self.snapped.is_empty() {
            for &f in faces {
                for v in mesh.triangles[f as usize] {
                    e = e.max(self.moved.get(&v).copied().unwrap_or(0.0));
                    e = e.max(self.snapped.get(v as usize).copied().unwrap_or(0.0));
                }
            }
        }
        e
    }
}

/// `x` as the smallest f32 not below it.
fn round_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x {
        f.next_up()
    } else {
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_keeps_level_zero_lattice_points_whatever_the_other_levels_span() {
        // Level 0 on a lattice of step 1/8 from (1, 1, 1); a coarser level strays below and
        // above it by amounts that are no multiple of any step.
        let level0 = Mesh {
            positions: (0..64)
                .map(|i| Vec3::new(1.0 + (i % 4) as f32 / 8.0, 1.0 + (i / 4 % 4) as f32 / 8.0, 1.0 + (i / 16) as f32 / 8.0))
                .collect(),
            ..Mesh::default()
        };
        let level1 = Mesh { positions: vec![Vec3::splat(0.93), Vec3::new(1.5, 1.2, 1.7)], ..Mesh::default() };
        let grid = model_grid([&level0, &level1], 8);
        for &p in level0.positions.iter().chain(&level1.positions) {
            let g = grid.encode(p);
            assert!(g.iter().all(|&c| c < grid.last()), "{p} off the grid");
        }
        for &p in &level0.positions {
            assert_eq!(grid.decode(grid.encode(p)), p, "{p} moved");
        }
        // A grid of one step per axis cannot lower its origin and still reach the top: the
        // bounds' own.
        let one = model_grid([&level0, &level1], 1);
        assert_eq!(one, Grid::fit(Vec3::splat(0.93), Vec3::new(1.5, 1.2, 1.7), 1));
        let plain = Grid::fit(Vec3::splat(0.93), Vec3::new(1.5, 1.2, 1.7), 8);
        assert!(level0.positions.iter().any(|&p| plain.decode(plain.encode(p)) != p), "the bounds' own origin would move them");
    }

    #[test]
    fn level_zero_positions_stay_distinct_within_their_stated_bound() {
        let mesh = crate::fixtures::isosurface(24, 3);
        let (lo, hi) = mesh.bounds().unwrap();
        let grid = Grid::fit(lo, hi, crate::format::GRID_BITS);
        let plain = Quantized::new(&grid, &mesh);
        let q = Quantized::distinct(&grid, &mesh).unwrap();
        let keys =
            |q: &Quantized| q.positions.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<std::collections::HashSet<_>>().len();
        assert!(keys(&plain) < mesh.vertex_count(), "the fixture crowds vertices");
        assert_eq!(keys(&q), mesh.vertex_count());
        assert!(!q.moved.is_empty());
        for (v, (&p, &input)) in q.positions.iter().zip(&mesh.positions).enumerate() {
            let bound = q.moved.get(&(v as u32)).map_or(grid.error(), |&d| d.max(grid.error()));
            assert!(p.as_dvec3().distance(input.as_dvec3()) <= bound as f64, "vertex {v}");
            if !q.moved.contains_key(&(v as u32)) {
                assert_eq!(q.points[v], plain.points[v]);
            }
        }
        let all: Vec<u32> = (0..mesh.face_count() as u32).collect();
        assert!(q.error(&grid, &mesh, &all) > grid.error());
    }
}
