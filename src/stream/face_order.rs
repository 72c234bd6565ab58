//! Faces of a decoded node put along a Morton curve of their centroids, within each culling cluster
//! and material range: runs of consecutive faces then cover compact patches of the surface, which
//! is what the software renderer's occlusion test tests as one (`render::BLOCK_FACES` faces).
//!
//! Format 2 writers store faces so already (strata-v2.md §8.6); a format-3 payload decodes its faces
//! in the order its traversal reaches them (rings around a start triangle), so the streamer puts a
//! format-3 node in this order once, when it reads it.

use crate::format::NodeGeometry;

/// Reorder `g`'s faces: within each run of faces that lies in one cluster and one material range,
/// by the Morton code of their centroids on a 2^21 grid over the node's positions (ties keep their
/// order). Vertices, ranges and clusters stay as they are.
pub fn morton(g: &mut NodeGeometry) {
    let faces = g.indices.len() / 3;
    if faces < 2 || g.positions.is_empty() {
        return;
    }
    let (lo, hi) = g.positions.iter().fold((g.positions[0], g.positions[0]), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    let extent = (hi - lo).max_element();
    let scale = if extent > 0.0 && extent.is_finite() { ((1u32 << 21) - 1) as f32 / extent } else { 0.0 };
    let key = |f: usize| -> u64 {
        let t = &g.indices[3 * f..3 * f + 3];
        let c = (g.positions[t[0] as usize] + g.positions[t[1] as usize] + g.positions[t[2] as usize]) / 3.0;
        let q = ((c - lo) * scale).to_array().map(|x| if x.is_finite() { x.clamp(0.0, ((1u32 << 21) - 1) as f32) as u64 } else { 0 });
        spread(q[0]) | spread(q[1]) << 1 | spread(q[2]) << 2
    };
    let keys: Vec<u64> = (0..faces).map(key).collect();
    // Runs: faces between consecutive starts of a cluster or a material range.
    let mut starts: Vec<usize> = g.clusters.iter().map(|c| c.first_face as usize).collect();
    starts.extend(g.material_ranges.iter().map(|r| r.first_index as usize / 3));
    starts.extend([0, faces]);
    starts.retain(|&s| s <= faces);
    starts.sort_unstable();
    starts.dedup();
    let mut order: Vec<(u64, u32)> = Vec::new();
    let mut moved = vec![0u32; 0];
    for run in starts.windows(2) {
        let (a, b) = (run[0], run[1]);
        if b - a < 2 {
            continue;
        }
        order.clear();
        order.extend((a..b).map(|f| (keys[f], f as u32)));
        order.sort_unstable();
        moved.clear();
        moved.extend(order.iter().flat_map(|&(_, f)| g.indices[3 * f as usize..3 * f as usize + 3].iter().copied()));
        g.indices[3 * a..3 * b].copy_from_slice(&moved);
    }
}

/// The 21 low bits of `x` spread three apart.
fn spread(x: u64) -> u64 {
    let mut v = x & 0x1f_ffff;
    v = (v | v << 32) & 0x1f_0000_0000_ffff;
    v = (v | v << 16) & 0x1f_0000_ff00_00ff;
    v = (v | v << 8) & 0x100f_00f0_0f00_f00f;
    v = (v | v << 4) & 0x10c3_0c30_c30c_30c3;
    (v | v << 2) & 0x1249_2492_4924_9249
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::{Cluster, MaterialRange};
    use glam::Vec3;

    fn interleave(x: u64, y: u64, z: u64) -> u64 {
        (0..21).fold(0, |m, b| m | ((x >> b) & 1) << (3 * b) | ((y >> b) & 1) << (3 * b + 1) | ((z >> b) & 1) << (3 * b + 2))
    }

    #[test]
    fn spread_interleaves_21_bits() {
        for (x, y, z) in [(0, 0, 0), (1, 2, 3), (0x1f_ffff, 0, 0x15_5555), (12345, 678_901, 1_999_999)] {
            assert_eq!(spread(x) | spread(y) << 1 | spread(z) << 2, interleave(x, y, z));
        }
    }

    /// A strip of quads along x, faces shuffled; two clusters and two materials.
    fn strip() -> NodeGeometry {
        let n = 16;
        let positions: Vec<Vec3> = (0..=n).flat_map(|i| [Vec3::new(i as f32, 0.0, 0.0), Vec3::new(i as f32, 1.0, 0.0)]).collect();
        let strip: Vec<[u32; 3]> = (0..n as u32).flat_map(|i| [[2 * i, 2 * i + 2, 2 * i + 1], [2 * i + 1, 2 * i + 2, 2 * i + 3]]).collect();
        let faces: Vec<[u32; 3]> = (0..strip.len()).map(|k| strip[k * 7 % strip.len()]).collect();
        let c = |first_face, face_count| Cluster {
            cone: crate::format::Cone { axis: Vec3::Z, half_angle: 3.2 },
            center: Vec3::ZERO,
            radius: 1.0,
            first_face,
            face_count,
        };
        NodeGeometry {
            positions,
            indices: faces.concat(),
            material_ranges: vec![
                MaterialRange { material: 0, first_index: 0, index_count: 3 * 10 },
                MaterialRange { material: 1, first_index: 30, index_count: 3 * 22 },
            ],
            clusters: vec![c(0, 20), c(20, 12)],
            ..Default::default()
        }
    }

    #[test]
    fn faces_move_within_their_cluster_and_material_only() {
        let before = strip();
        let mut g = before.clone();
        morton(&mut g);
        let faces = |g: &NodeGeometry, r: std::ops::Range<usize>| {
            let mut f: Vec<&[u32]> = g.indices[3 * r.start..3 * r.end].chunks(3).collect();
            f.sort();
            f.into_iter().map(|x| x.to_vec()).collect::<Vec<_>>()
        };
        for r in [0..10, 10..20, 20..32] {
            assert_eq!(faces(&g, r.clone()), faces(&before, r));
        }
        assert_ne!(g.indices, before.indices);
        // Within a run, consecutive faces are near each other: the steps between centroids add up
        // to about each run's extent along the strip.
        let cx = |g: &NodeGeometry, f: usize| (0..3).map(|k| g.positions[g.indices[3 * f + k] as usize].x).sum::<f32>() / 3.0;
        let walk = |g: &NodeGeometry| -> f32 {
            [0..10, 10..20, 20..32].into_iter().flat_map(|r| r.clone().zip(r.skip(1))).map(|(a, b)| (cx(g, a) - cx(g, b)).abs()).sum()
        };
        // The least walk covers each run's span once.
        let span: f32 = [0..10, 10..20, 20..32]
            .into_iter()
            .map(|r| {
                let x: Vec<f32> = r.map(|f| cx(&g, f)).collect();
                x.iter().fold(f32::MIN, |m, &v| m.max(v)) - x.iter().fold(f32::MAX, |m, &v| m.min(v))
            })
            .sum();
        assert!(walk(&g) <= span + 1.0 && walk(&g) < 0.5 * walk(&before), "{} against {} (spans {span})", walk(&g), walk(&before));
        let (mut again, mut once) = (g.clone(), g);
        morton(&mut again);
        morton(&mut once);
        assert_eq!(again, once, "the order is a fixed point");
    }

    #[test]
    fn degenerate_nodes_are_left_alone() {
        let mut g = NodeGeometry { positions: vec![Vec3::splat(f32::NAN); 3], indices: vec![0, 1, 2, 2, 1, 0], ..Default::default() };
        morton(&mut g);
        assert_eq!(g.indices.len(), 6);
        let mut empty = NodeGeometry::default();
        morton(&mut empty);
    }
}
