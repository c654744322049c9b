//! Projection of a symmetric block onto the positive semi-definite cone: `H = QΛQᵀ ↦
//! Q·max(Λ, 0)·Qᵀ` (the nearest PSD matrix in the Frobenius norm), as IPC does per contact
//! stencil so that Newton / PCG see a convex model.

use nalgebra::{SMatrix, SymmetricEigen};

use crate::contact::math::{Matrix12, Vector12};

/// `Q·max(Λ, 0)·Qᵀ` of a symmetric 12×12 matrix. Vertices whose rows and columns are all
/// zero (a point–point or point–edge closest pair uses 2 or 3 of the 4 stencil vertices) are
/// left out of the eigendecomposition, which then runs on 6×6 or 9×9. A block that is already
/// PSD is returned unchanged, so PSD inputs round-trip bitwise.
pub fn project_to_psd(h: &Matrix12) -> Matrix12 {
    let (slots, count) = nonzero_slots(h);
    let slots = &slots[..count];
    match count {
        0 => *h,
        1 => project_slots_3(h, slots),
        2 => project_slots_6(h, slots),
        3 => project_slots_9(h, slots),
        _ => project_slots_12(h, slots),
    }
}

/// The positive part of a symmetric 12×12 `h` in factored form: vectors `gₖ = √λₖ·qₖ` over
/// its eigenpairs with `λₖ > keep·λ_max` (and `λₖ > 0`), so with `keep = 0`
/// `Σ gₖgₖᵀ = Q·max(Λ, 0)·Qᵀ` ([`project_to_psd`]). A larger `keep` keeps only the dominant
/// curvature: `Σ gₖgₖᵀ` is then a PSD lower bound of the projection, differing from it by at
/// most `keep·λ_max` in the spectral norm. The contact step's low-rank update takes the
/// barrier's curvature this way, one column per kept eigenvalue, not a dense block.
pub fn positive_part_factors(h: &Matrix12, keep: f64) -> Vec<Vector12> {
    let (slots, count) = nonzero_slots(h);
    let slots = &slots[..count];
    match count {
        0 => Vec::new(),
        1 => factors_slots_3(h, slots, keep),
        2 => factors_slots_6(h, slots, keep),
        3 => factors_slots_9(h, slots, keep),
        _ => factors_slots_12(h, slots, keep),
    }
}

/// The vertex slots (of 4) whose rows of `h` are not all zero, and their count.
fn nonzero_slots(h: &Matrix12) -> ([usize; 4], usize) {
    let mut slots = [0usize; 4];
    let mut count = 0;
    for i in 0..4 {
        if (0..12).any(|c| (0..3).any(|r| h[(3 * i + r, c)] != 0.0)) {
            slots[count] = i;
            count += 1;
        }
    }
    (slots, count)
}

macro_rules! factors_slots {
    ($name:ident, $n:literal) => {
        fn $name(h: &Matrix12, slots: &[usize], keep: f64) -> Vec<Vector12> {
            let index = |k: usize| 3 * slots[k / 3] + k % 3;
            let sub = SMatrix::<f64, $n, $n>::from_fn(|r, c| h[(index(r), index(c))]);
            let eig = SymmetricEigen::new(sub);
            let floor = keep * eig.eigenvalues.max();
            let mut out = Vec::new();
            for (k, &l) in eig.eigenvalues.iter().enumerate() {
                if l > 0.0 && l > floor {
                    let mut g = Vector12::zeros();
                    for r in 0..$n {
                        g[index(r)] = l.sqrt() * eig.eigenvectors[(r, k)];
                    }
                    out.push(g);
                }
            }
            out
        }
    };
}

factors_slots!(factors_slots_3, 3);
factors_slots!(factors_slots_6, 6);
factors_slots!(factors_slots_9, 9);
factors_slots!(factors_slots_12, 12);

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

    #[test]
    fn the_factors_rebuild_the_projection() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for zero_slot in [None, Some(1), Some(3)] {
            let a = Matrix12::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let mut h = a + a.transpose();
            if let Some(s) = zero_slot {
                for k in 0..12 {
                    for j in 3 * s..3 * s + 3 {
                        h[(k, j)] = 0.0;
                        h[(j, k)] = 0.0;
                    }
                }
            }
            let factors = positive_part_factors(&h, 0.0);
            let rebuild = |factors: &[Vector12]| {
                factors
                    .iter()
                    .fold(Matrix12::zeros(), |m, g| m + g * g.transpose())
            };
            let rebuilt = rebuild(&factors);
            let scale = h.norm();
            assert!((rebuilt - project_to_psd(&h)).norm() <= 1e-12 * scale);
            // One factor per positive eigenvalue, none for the zero slot.
            let positive = SymmetricEigen::new(project_to_psd(&h))
                .eigenvalues
                .iter()
                .filter(|&&l| l > 1e-10 * scale)
                .count();
            assert_eq!(factors.len(), positive);
            // The dominant part: fewer factors, PSD, below the projection by at most
            // keep·λ_max.
            let keep = 0.5;
            let dominant = positive_part_factors(&h, keep);
            assert!(!dominant.is_empty() && dominant.len() < factors.len());
            let gap = SymmetricEigen::new(project_to_psd(&h) - rebuild(&dominant)).eigenvalues;
            let largest = factors.iter().map(|g| g.norm_squared()).fold(0.0, f64::max);
            assert!(gap.min() >= -1e-12 * scale && gap.max() <= keep * largest + 1e-12 * scale);
        }
        assert!(positive_part_factors(&Matrix12::zeros(), 0.0).is_empty());
        assert!(positive_part_factors(&-Matrix12::identity(), 0.0).is_empty());
    }
}
