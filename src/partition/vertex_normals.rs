//! Computed vertex normals of the partitioned build, with no normal sum held per input vertex. A
//! vertex's normal is the sum of its faces' area-weighted normals. A vertex only one cell uses
//! has all its faces in that cell, which sums them when it loads ([`smooth`]); a vertex that
//! faces of several cells use (a bit in `shared`) takes its sum from [`SharedSums`], gathered
//! from every cell file in one pass once the input has streamed: such vertices lie where cells
//! meet, a few per thousand in a large mesh.

use super::cells::{scan_cell, Layout};
use super::is_shared;
use crate::error::Result;
use crate::mesh::triangle_cross;
use glam::Vec3;
use rustc_hash::FxHashMap;
use std::path::PathBuf;

/// The area-weighted normal sums of the shared vertices, over every face of the input.
#[derive(Debug, Default)]
pub struct SharedSums(FxHashMap<u32, Vec3>);

impl SharedSums {
    /// Sum the faces of every cell file in `spooled` (file, faces; vertex ids below `vertices`)
    /// at their shared corners, `threads` cells at a time, their sums added in cell order (so
    /// the result does not depend on the thread count). Nothing to read when no vertex is shared.
    pub fn gather(spooled: &[(PathBuf, u64)], layout: Layout, vertices: u64, shared: &[u64], threads: usize) -> Result<SharedSums> {
        use rayon::prelude::*;
        let mut all = FxHashMap::default();
        if shared.iter().all(|&w| w == 0) {
            return Ok(SharedSums(all));
        }
        for batch in spooled.chunks(threads.max(1)) {
            let per_cell: Vec<FxHashMap<u32, Vec3>> =
                batch.par_iter().map(|(path, faces)| cell_sums(path, *faces, layout, vertices, shared)).collect::<Result<_>>()?;
            for sums in per_cell {
                for (i, s) in sums {
                    *all.entry(i).or_insert(Vec3::ZERO) += s;
                }
            }
        }
        Ok(SharedSums(all))
    }
}

/// One cell file's sums at its shared corners.
fn cell_sums(path: &std::path::Path, faces: u64, layout: Layout, vertices: u64, shared: &[u64]) -> Result<FxHashMap<u32, Vec3>> {
    let mut sums = FxHashMap::default();
    scan_cell(path, faces, layout, vertices, |ids, positions| {
        if ids.iter().any(|&i| is_shared(shared, i)) {
            let cross = face_cross(&positions);
            if cross.is_finite() {
                for &i in ids.iter().filter(|&&i| is_shared(shared, i)) {
                    *sums.entry(i).or_insert(Vec3::ZERO) += cross;
                }
            }
        }
    })?;
    Ok(sums)
}

/// A face's area-weighted normal (twice its area long), as the whole-file import sums it.
fn face_cross(p: &[Vec3; 3]) -> Vec3 {
    triangle_cross(p, &[0, 1, 2]).as_vec3()
}

/// The smooth normals of a cell's vertices: `positions` and `triangles` are the cell's mesh as
/// read, `ids` its vertices' welded input ids. Vertices in `shared` take their sums from `sums`;
/// the others sum the cell's faces, which are all of theirs. A zero sum gives +Z.
pub fn smooth(positions: &[Vec3], triangles: &[[u32; 3]], ids: &[u32], shared: &[u64], sums: &SharedSums) -> Vec<Vec3> {
    let mut out = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let cross = face_cross(&t.map(|v| positions[v as usize]));
        if cross.is_finite() {
            for &v in t {
                out[v as usize] += cross;
            }
        }
    }
    for (n, &id) in out.iter_mut().zip(ids) {
        if is_shared(shared, id) {
            *n = sums.0.get(&id).copied().unwrap_or(Vec3::ZERO);
        }
    }
    out.iter().map(|n| n.normalize_or(Vec3::Z)).collect()
}

#[cfg(test)]
mod tests {
    use super::super::cells::{FaceRecord, Spool};
    use super::*;

    /// A strip of faces over two cells: the shared vertices' normals, gathered from both files,
    /// equal the whole mesh's; the others', summed by their own cell, too.
    #[test]
    fn sums_over_two_cells_give_the_whole_meshs_normals() {
        let dir = tempfile::tempdir().unwrap();
        let layout = Layout { normals: false, uvs: false, colors: false, materials: false };
        let grid = |i: u32| Vec3::new((i % 4) as f32, (i / 4) as f32, ((i * 7) % 5) as f32 * 0.3);
        let positions: Vec<Vec3> = (0..16).map(grid).collect();
        let mut triangles = Vec::new();
        for y in 0..3 {
            for x in 0..3 {
                let a = y * 4 + x;
                triangles.push([a, a + 1, a + 5]);
                triangles.push([a, a + 5, a + 4]);
            }
        }
        let cell = |t: &[u32; 3]| usize::from(t.iter().map(|&v| positions[v as usize].x).sum::<f32>() > 4.5);
        let mut spool = Spool::create(dir.path(), 2, layout).unwrap();
        let mut owner = [0u8; 16];
        for t in &triangles {
            let c = cell(t);
            for &v in t {
                owner[v as usize] |= 1 << c;
            }
            let record = FaceRecord {
                ids: *t,
                positions: t.map(|v| positions[v as usize]),
                normals: [Vec3::ZERO; 3],
                uvs: Default::default(),
                colors: Default::default(),
                material: 0,
            };
            spool.push(c, &record).unwrap();
        }
        let spooled = spool.finish().unwrap();
        let mut shared = vec![0u64];
        for (v, _) in owner.iter().enumerate().filter(|(_, &o)| o == 3) {
            shared[0] |= 1 << v;
        }
        assert!(shared[0].count_ones() >= 3, "the strip crosses the cells");
        let sums = SharedSums::gather(&spooled, layout, 16, &shared, 2).unwrap();
        let e = SharedSums::gather(&spooled, layout, 15, &shared, 1).unwrap_err().to_string();
        assert!(e.contains("cell-") && e.contains("vertex 15 of 15"), "{e}");
        assert_eq!(sums.0.len(), shared[0].count_ones() as usize);

        let whole = smooth(&positions, &triangles, &(0..16).collect::<Vec<_>>(), &[0], &SharedSums::default());
        for c in 0..2 {
            let mine: Vec<[u32; 3]> = triangles.iter().filter(|t| cell(t) == c).copied().collect();
            let mut ids: Vec<u32> = mine.iter().flatten().copied().collect();
            ids.sort_unstable();
            ids.dedup();
            let local: Vec<[u32; 3]> = mine.iter().map(|t| t.map(|v| ids.binary_search(&v).unwrap() as u32)).collect();
            let at: Vec<Vec3> = ids.iter().map(|&i| positions[i as usize]).collect();
            let normals = smooth(&at, &local, &ids, &shared, &sums);
            for (&id, n) in ids.iter().zip(&normals) {
                assert!(n.distance(whole[id as usize]) < 1e-6, "cell {c}, vertex {id}: {n} against {}", whole[id as usize]);
            }
        }
    }
}
