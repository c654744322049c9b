//! Projection of a symmetric block onto the positive semi-definite cone: `H = QΛQᵀ ↦
//! Q·max(Λ, 0)·Qᵀ` (the nearest PSD matrix in the Frobenius norm), as IPC does per contact
//! stencil so that Newton / PCG see a convex model.

use nalgebra::SymmetricEigen;

use crate::contact::math::Matrix12;

/// `Q·max(Λ, 0)·Qᵀ` of a symmetric 12×12 matrix. A block that is already PSD is returned
/// unchanged (not re-assembled), so PSD inputs round-trip bitwise.
pub fn project_to_psd(h: &Matrix12) -> Matrix12 {
    let eig = SymmetricEigen::new(*h);
    if eig.eigenvalues.iter().all(|&l| l >= 0.0) {
        return *h;
    }
    let clamped = eig.eigenvalues.map(|l| l.max(0.0));
    let q = &eig.eigenvectors;
    let mut out = q * nalgebra::SMatrix::<f64, 12, 12>::from_diagonal(&clamped) * q.transpose();
    // Exact symmetry.
    out = 0.5 * (out + out.transpose());
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn projection_clamps_negative_eigenvalues() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let a = Matrix12::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let h = a + a.transpose();
        let p = project_to_psd(&h);
        let eig = SymmetricEigen::new(p);
        let scale = h.norm();
        assert!(eig.eigenvalues.iter().all(|&l| l >= -1e-12 * scale));
        // Idempotent, and the positive part is kept: ⟨H − P, P⟩ = 0.
        let pp = project_to_psd(&p);
        assert!((pp - p).norm() <= 1e-12 * scale);
        assert!(((h - p).component_mul(&p)).sum().abs() <= 1e-10 * scale * scale);
        let psd = a * a.transpose();
        assert_eq!(project_to_psd(&psd), psd);
    }
}
