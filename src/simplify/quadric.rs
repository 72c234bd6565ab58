//! The quadric error metric: a weighted sum of squared distances to planes, its value at a point
//! and its minimiser.

use glam::DVec3;

/// A symmetric quadric pᵀAp + 2bᵀp + c with its accumulated weights.
/// 96 bytes aligned to 32, so that a vertex's quadric spans two cache lines, never three.
#[derive(Clone, Copy, Debug, Default)]
#[repr(align(32))]
pub(super) struct Quadric {
    /// xx, xy, xz, yy, yz, zz.
    pub(super) a: [f64; 6],
    pub(super) b: [f64; 3],
    pub(super) c: f64,
    /// Sum of the weights of all planes: Q(p) / w is a mean squared distance (the error estimate).
    pub(super) w: f64,
    /// Sum of the face areas only: Q(p) / area ranks collapses, so that heavily weighted border
    /// and seam planes make those collapses come late.
    pub(super) area: f64,
    /// Not a sum (`add` leaves it): in a vertex's quadric, the largest squared error estimate of
    /// the collapses merged into it, kept here because every read of it also reads the quadric.
    pub(super) err_sq: f64,
}

impl Quadric {
    /// weight · (distance to the plane through `p` with unit normal `n`)².
    pub(super) fn plane(n: DVec3, p: DVec3, weight: f64) -> Quadric {
        Quadric::with_offset(n, -n.dot(p), weight)
    }

    /// `plane` given the plane's offset `d = -n·p`.
    pub(super) fn with_offset(n: DVec3, d: f64, weight: f64) -> Quadric {
        let wn = n * weight;
        Quadric {
            a: [wn.x * n.x, wn.x * n.y, wn.x * n.z, wn.y * n.y, wn.y * n.z, wn.z * n.z],
            b: [wn.x * d, wn.y * d, wn.z * d],
            c: weight * d * d,
            w: weight,
            area: 0.0,
            err_sq: 0.0,
        }
    }

    pub(super) fn add(&mut self, o: &Quadric) {
        for i in 0..6 {
            self.a[i] += o.a[i];
        }
        for i in 0..3 {
            self.b[i] += o.b[i];
        }
        self.c += o.c;
        self.w += o.w;
        self.area += o.area;
    }

    pub(super) fn eval(&self, p: DVec3) -> f64 {
        let [xx, xy, xz, yy, yz, zz] = self.a;
        let ap = DVec3::new(xx * p.x + xy * p.y + xz * p.z, xy * p.x + yy * p.y + yz * p.z, xz * p.x + yz * p.y + zz * p.z);
        (p.dot(ap) + 2.0 * (self.b[0] * p.x + self.b[1] * p.y + self.b[2] * p.z) + self.c).max(0.0)
    }

    /// The minimiser, if A is well conditioned: det(A / trace A) above 1e-9.
    pub(super) fn optimum(&self) -> Option<DVec3> {
        let [xx, xy, xz, yy, yz, zz] = self.a;
        let (c00, c01, c02) = (yy * zz - yz * yz, xz * yz - xy * zz, xy * yz - xz * yy);
        let det = xx * c00 + xy * c01 + xz * c02;
        let trace = xx + yy + zz;
        // Also when the trace is NaN.
        if trace.is_nan() || trace <= 0.0 || det <= 1e-9 * trace * trace * trace {
            return None;
        }
        let (c11, c12, c22) = (xx * zz - xz * xz, xy * xz - xx * yz, xx * yy - xy * xy);
        let [bx, by, bz] = self.b;
        let inv = -1.0 / det;
        Some(DVec3::new(
            (c00 * bx + c01 * by + c02 * bz) * inv,
            (c01 * bx + c11 * by + c12 * bz) * inv,
            (c02 * bx + c12 * by + c22 * bz) * inv,
        ))
    }
}
