//! Projection of a symmetric block onto the positive semi-definite cone: `H = QΛQᵀ ↦
//! Q·max(Λ, 0)·Qᵀ` (the nearest PSD matrix in the Frobenius norm), as IPC does per contact
//! stencil so that Newton / PCG see a convex model.

use nalgebra::{SMatrix, SymmetricEigen};

use crate::contact::math::Matrix12;

/// `Q·max(Λ, 0)·Qᵀ` of a symmetric 12×12 matrix. Vertices whose rows and columns are all
/// zero (a point–point or point–edge closest pair uses 2 or 3 of the 4 stencil vertices) are
/// left out of the eigendecomposition, which then runs on 6×6 or 9×9. A block that is already
/// PSD is returned unchanged, so PSD inputs round-trip bitwise.
pub fn project_to_psd(h: &Matrix12) -> Matrix12 {
    let mut slots = [0usize; 4];
    let mut count = 0;
    for i in 0..4 {
        if (0..12).any(|c| (0..3).any(|r| h[(3 * i + r, c)] != 0.0)) {
            slots[count] = i;
            count += 1;
        }
    }
    let slots = &slots[..count];
    match count {
        0 => *h,
        1 => project_slots_3(h, slots),
        2 => project_slots_6(h, slots),
        3 => project_slots_9(h, slots),
        _ => project_slots_12(h, slots),
    }
}

/// Projects the `N×N` sub-matrix of the given vertex slots (`N = 3·slots.len()`); one
/// function per size, so the eigendecomposition runs on fixed-size matrices.
macro_rules! project_slots {
    ($name:ident, $n:literal) => {
        fn $name(h: &Matrix12, slots: &[usize]) -> Matrix12 {
            let index = |k: usize| 3 * slots[k / 3] + k % 3;
            let sub = SMatrix::<f64, $n, $n>::from_fn(|r, c| h[(index(r), index(c))]);
            let eig = SymmetricEigen::new(sub);
            if eig.eigenvalues.iter().all(|&l| l >= 0.0) {
                return *h;
            }
            let q = &eig.eigenvectors;
            let clamped =
                SMatrix::<f64, $n, $n>::from_diagonal(&eig.eigenvalues.map(|l| l.max(0.0)));
            let p = q * clamped * q.transpose();
            let mut out = Matrix12::zeros();
            for r in 0..$n {
                for c in 0..$n {
                    // Exact symmetry.
                    out[(index(r), index(c))] = 0.5 * (p[(r, c)] + p[(c, r)]);
                }
            }
            out
        }
    };
}

project_slots!(project_slots_3, 3);
project_slots!(project_slots_6, 6);
project_slots!(project_slots_9, 9);
project_slots!(project_slots_12, 12);

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
        // Zero vertex slots stay zero and the rest is projected as a smaller matrix.
        let mut partial = h;
        for k in 0..12 {
            for j in 3..6 {
                partial[(k, j)] = 0.0;
                partial[(j, k)] = 0.0;
            }
        }
        let p = project_to_psd(&partial);
        assert!((0..12).all(|k| (3..6).all(|j| p[(k, j)] == 0.0 && p[(j, k)] == 0.0)));
        let eig = SymmetricEigen::new(p);
        assert!(eig.eigenvalues.iter().all(|&l| l >= -1e-12 * scale));
        assert!(((partial - p).component_mul(&p)).sum().abs() <= 1e-10 * scale * scale);
    }
}
