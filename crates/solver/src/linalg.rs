//! Small dense linear algebra for the active-set step: the eigen-decomposition of a symmetric 3x3 matrix
//! (cyclic Jacobi rotations), from which the solver builds pseudo-inverses and null-space projectors.
//!
//! Jacobi is chosen over a closed-form cubic because it stays accurate for nearly repeated eigenvalues,
//! which is exactly the case of near-parallel planes (a 1 degree wedge gives eigenvalues about 2 and 1.5e-4).

use crate::math::sqrt;
use glam::{DMat3, DVec3};

/// Eigenvalues and orthonormal eigenvectors (the columns of `vectors`) of a symmetric matrix.
#[derive(Debug, Clone, Copy)]
pub struct SymmetricEigen3 {
    pub values: DVec3,
    pub vectors: DMat3,
}

/// Eigen-decomposition of the symmetric matrix `m` (only its upper triangle is read).
pub fn symmetric_eigen3(m: DMat3) -> SymmetricEigen3 {
    // a[row][col]
    let mut a = [
        [m.x_axis.x, m.y_axis.x, m.z_axis.x],
        [m.x_axis.y, m.y_axis.y, m.z_axis.y],
        [m.x_axis.z, m.y_axis.z, m.z_axis.z],
    ];
    // Symmetrise from the upper triangle.
    for (r, c) in [(1usize, 0usize), (2, 0), (2, 1)] {
        a[r][c] = a[c][r];
    }
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..32 {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        let diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
        if off <= 1e-36 * diag || off == 0.0 {
            break;
        }
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            let apq = a[p][q];
            if apq == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
            // f64::signum(+0.0) is 1.0, so theta == 0 gives t = 1 (a 45 degree rotation), as it should.
            let t = theta.signum() / (theta.abs() + sqrt(theta * theta + 1.0));
            let c = 1.0 / sqrt(t * t + 1.0);
            let s = t * c;
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (row_p, row_q) = (a[p], a[q]);
            for col in 0..3 {
                a[p][col] = c * row_p[col] - s * row_q[col];
                a[q][col] = s * row_p[col] + c * row_q[col];
            }
            for row in v.iter_mut() {
                let (vkp, vkq) = (row[p], row[q]);
                row[p] = c * vkp - s * vkq;
                row[q] = s * vkp + c * vkq;
            }
        }
    }
    SymmetricEigen3 {
        values: DVec3::new(a[0][0], a[1][1], a[2][2]),
        vectors: DMat3::from_cols(
            DVec3::new(v[0][0], v[1][0], v[2][0]),
            DVec3::new(v[0][1], v[1][1], v[2][1]),
            DVec3::new(v[0][2], v[1][2], v[2][2]),
        ),
    }
}

/// The pseudo-inverse of a symmetric positive semi-definite matrix and the projector onto its null space,
/// treating eigenvalues below `relative_tolerance * max eigenvalue` as zero. Returns `(pinv, null_projector, rank)`.
pub fn psd_pseudo_inverse(m: DMat3, relative_tolerance: f64) -> (DMat3, DMat3, usize) {
    let eig = symmetric_eigen3(m);
    let (pinv, range, rank) = pseudo_inverse_parts(&eig, relative_tolerance);
    (pinv, DMat3::IDENTITY - range, rank)
}

/// The pseudo-inverse of a symmetric positive semi-definite matrix from its eigen-decomposition (eigenvalues
/// below `relative_tolerance * max eigenvalue` taken as zero).
pub fn pseudo_inverse_from(eig: &SymmetricEigen3, relative_tolerance: f64) -> DMat3 {
    pseudo_inverse_parts(eig, relative_tolerance).0
}

/// `(pinv, projector onto the range, rank)` from an eigen-decomposition.
fn pseudo_inverse_parts(eig: &SymmetricEigen3, relative_tolerance: f64) -> (DMat3, DMat3, usize) {
    let max = eig.values.max_element().max(0.0);
    let mut pinv = DMat3::ZERO;
    let mut range = DMat3::ZERO;
    let mut rank = 0;
    if max > 0.0 {
        for i in 0..3 {
            let lambda = eig.values[i];
            if lambda > relative_tolerance * max {
                let e = eig.vectors.col(i);
                let outer = outer(e, e);
                pinv += outer * (1.0 / lambda);
                range += outer;
                rank += 1;
            }
        }
    }
    (pinv, range, rank)
}

/// The outer product `a b^T`.
pub fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Solves `H x = g` for a symmetric positive definite `H` (the primal method's Hessian with no kink: `k I` plus
/// positive semi-definite terms), by its cofactors: one division, and every cofactor independent of the others, so the
/// solve's chain of dependent operations is short (an LDL^T factorisation divides by each pivot in turn, three
/// divisions one after another, which on the primal method's path was a tenth of a 10-primitive solve). For
/// such an `H` every 2x2 minor is at least `k^2`, and the result is as accurate as the factorisation's (a
/// relative error of a few eps times the condition number); nothing needs more: the certificate checks
/// whatever point the steps reach.
///
/// Kept (the cofactors and the inverse of the determinant) to solve again with the same matrix without a second
/// division: the primal method's third-order correction uses the Newton step's Hessian.
#[derive(Debug, Clone, Copy)]
pub struct SpdCofactors {
    /// `c00, c01, c02, c11, c12, c22` (the cofactor matrix is symmetric).
    c: [f64; 6],
    inverse_det: f64,
}

impl SpdCofactors {
    #[inline]
    pub fn of(h: &DMat3) -> Self {
        let (a00, a10, a20) = (h.x_axis.x, h.x_axis.y, h.x_axis.z);
        let (a11, a21, a22) = (h.y_axis.y, h.y_axis.z, h.z_axis.z);
        let c00 = a11 * a22 - a21 * a21;
        let c01 = a20 * a21 - a10 * a22;
        let c02 = a10 * a21 - a11 * a20;
        let c11 = a00 * a22 - a20 * a20;
        let c12 = a10 * a20 - a00 * a21;
        let c22 = a00 * a11 - a10 * a10;
        Self {
            c: [c00, c01, c02, c11, c12, c22],
            inverse_det: 1.0 / (a00 * c00 + a10 * c01 + a20 * c02),
        }
    }

    /// `H^-1 g`: the cofactors' product with `g` (independent of the division), then the scale.
    #[inline]
    pub fn solve(&self, g: DVec3) -> DVec3 {
        let [c00, c01, c02, c11, c12, c22] = self.c;
        DVec3::new(
            c00 * g.x + c01 * g.y + c02 * g.z,
            c01 * g.x + c11 * g.y + c12 * g.z,
            c02 * g.x + c12 * g.y + c22 * g.z,
        ) * self.inverse_det
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spd_solve_matches_the_inverse() {
        // k I plus two weighted projectors, as the primal method's Hessian is.
        let n = DVec3::new(0.3, -0.5, 0.8).normalize();
        let q = DVec3::new(-0.7, 0.1, 0.2).normalize();
        let h =
            DMat3::IDENTITY * 500.0 + (DMat3::IDENTITY - outer(n, n)) * 80.0 + outer(q, q) * 3e4;
        let g = DVec3::new(1.5, -0.25, 4.0);
        let x = SpdCofactors::of(&h).solve(g);
        let expected = h.inverse() * g;
        assert!(
            (x - expected).length() <= 1e-14 * expected.length(),
            "{x} {expected}"
        );
        assert!((h * x - g).length() <= 1e-12 * g.length());
    }

    #[test]
    fn eigen_reconstructs_the_matrix() {
        let m = DMat3::from_cols(
            DVec3::new(4.0, 1.0, -2.0),
            DVec3::new(1.0, 3.0, 0.5),
            DVec3::new(-2.0, 0.5, 1.0),
        );
        let e = symmetric_eigen3(m);
        let d = DMat3::from_diagonal(e.values);
        let back = e.vectors * d * e.vectors.transpose();
        assert!(
            (back - m).to_cols_array().iter().all(|x| x.abs() < 1e-12),
            "{back:?}"
        );
        let vtv = e.vectors.transpose() * e.vectors;
        assert!((vtv - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|x| x.abs() < 1e-12));
    }

    #[test]
    fn near_parallel_planes_keep_their_small_eigenvalue() {
        let angle = 1f64.to_radians();
        let q1 = DVec3::Z;
        let q2 = DVec3::new(angle.sin(), 0.0, angle.cos());
        let m = outer(q1, q1) + outer(q2, q2);
        let e = symmetric_eigen3(m);
        let mut values = e.values.to_array();
        values.sort_by(f64::total_cmp);
        assert!(values[0].abs() < 1e-15);
        assert!(
            (values[1] - (1.0 - angle.cos())).abs() < 1e-12,
            "{values:?}"
        );
        assert!((values[2] - (1.0 + angle.cos())).abs() < 1e-12);
    }

    #[test]
    fn pseudo_inverse_of_a_rank_one_matrix() {
        let q = DVec3::new(1.0, 2.0, 2.0) / 3.0;
        let (pinv, null, rank) = psd_pseudo_inverse(outer(q, q), 1e-12);
        assert_eq!(rank, 1);
        assert!((pinv * q - q).length() < 1e-12);
        assert!((null * q).length() < 1e-12);
        let t = q.any_orthonormal_vector();
        assert!((null * t - t).length() < 1e-12);
    }
}
