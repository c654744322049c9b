//! Symmetric 3×3 actuation tensors stored as their 6 independent entries.

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

/// A symmetric 3×3 tensor `[[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]` stored as
/// `[xx, yy, zz, xy, xz, yz]`. Each off-diagonal value stands for two matrix entries, so a
/// derivative with respect to it is the sum of the derivatives with respect to both.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SymTensor(pub [f64; 6]);

/// Why an actuation tensor is rejected.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum TensorError {
    #[error("has a non-finite entry")]
    NonFinite,
    #[error("is not positive definite (leading minors {0:e}, {1:e}, {2:e})")]
    NotPositiveDefinite(f64, f64, f64),
}

impl SymTensor {
    pub const IDENTITY: SymTensor = SymTensor([1.0, 1.0, 1.0, 0.0, 0.0, 0.0]);

    pub fn to_matrix(&self) -> Matrix3<f64> {
        let [xx, yy, zz, xy, xz, yz] = self.0;
        Matrix3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz)
    }

    /// The symmetric part of `m`.
    pub fn from_matrix(m: &Matrix3<f64>) -> Self {
        let s = |i: usize, j: usize| 0.5 * (m[(i, j)] + m[(j, i)]);
        SymTensor([m[(0, 0)], m[(1, 1)], m[(2, 2)], s(0, 1), s(0, 2), s(1, 2)])
    }

    /// The matrix that a unit change of stored value `k` adds (two entries for off-diagonals).
    pub fn basis(k: usize) -> Matrix3<f64> {
        let mut v = [0.0; 6];
        v[k] = 1.0;
        SymTensor(v).to_matrix()
    }

    /// Reduces a full-matrix gradient `G = ∂f/∂A` to the gradient with respect to the 6 stored
    /// values: diagonal entries once, off-diagonal entries `G_ij + G_ji`.
    pub fn gradient_from_matrix(g: &Matrix3<f64>) -> [f64; 6] {
        [
            g[(0, 0)],
            g[(1, 1)],
            g[(2, 2)],
            g[(0, 1)] + g[(1, 0)],
            g[(0, 2)] + g[(2, 0)],
            g[(1, 2)] + g[(2, 1)],
        ]
    }

    /// Checks the tensor is usable as an actuation: finite and positive definite
    /// (Sylvester's criterion). Near-singular tensors pass; they are valid, if extreme, targets.
    pub fn validate(&self) -> Result<(), TensorError> {
        if !self.0.iter().all(|v| v.is_finite()) {
            return Err(TensorError::NonFinite);
        }
        let m = self.to_matrix();
        let m1 = m[(0, 0)];
        let m2 = m[(0, 0)] * m[(1, 1)] - m[(0, 1)] * m[(1, 0)];
        let m3 = m.determinant();
        if m1 > 0.0 && m2 > 0.0 && m3 > 0.0 {
            Ok(())
        } else {
            Err(TensorError::NotPositiveDefinite(m1, m2, m3))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_counts_off_diagonals_twice() {
        let t = SymTensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]);
        assert_eq!(SymTensor::from_matrix(&t.to_matrix()), t);
        // f(A) = <G, A> changes by G_01 + G_10 when the stored xy value grows by one.
        let g = Matrix3::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0);
        let grad = SymTensor::gradient_from_matrix(&g);
        for (k, value) in grad.iter().enumerate() {
            assert_eq!(*value, g.component_mul(&SymTensor::basis(k)).sum());
        }
    }

    #[test]
    fn validation_rejects_indefinite_and_non_finite_tensors() {
        assert!(SymTensor::IDENTITY.validate().is_ok());
        assert!(
            SymTensor([1e-9, 1.0, 1.0, 0.0, 0.0, 0.0])
                .validate()
                .is_ok()
        );
        assert!(
            SymTensor([1.0, 1.0, -0.5, 0.0, 0.0, 0.0])
                .validate()
                .is_err()
        );
        assert!(
            SymTensor([1.0, 1.0, 1.0, 2.0, 0.0, 0.0])
                .validate()
                .is_err()
        );
        assert_eq!(
            SymTensor([f64::NAN, 1.0, 1.0, 0.0, 0.0, 0.0]).validate(),
            Err(TensorError::NonFinite)
        );
    }
}
