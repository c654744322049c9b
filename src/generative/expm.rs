//! The exponential of a symmetric 3×3 matrix by scaling and squaring (N_A's `log A` → `A`).
//!
//! An eigendecomposition per element (what [`crate::drive::basis`] uses) costs more than
//! N_A itself on a full face; this is about ten 3×3 products. With `X = L / 2ˢ`, `‖X‖_F ≤ ¼`,
//! the degree-10 Taylor polynomial is exact to about 1e-14 relative, and every eigenvalue of
//! the result, `p(λ/2ˢ)^(2ˢ)`, is positive (p > 0 on [−¼, ¼]): symmetric positive definite
//! whenever the result is finite.

use nalgebra::Matrix3;

use crate::sim::SymTensor;

/// Degree of the Taylor polynomial.
const DEGREE: i32 = 10;

/// `exp L` of a symmetric `L` (stored `[xx, yy, zz, xy, xz, yz]`); exactly `I` for `L = 0`.
pub fn exp_sym(log: &[f64; 6]) -> SymTensor {
    if log.iter().all(|&v| v == 0.0) {
        return SymTensor::IDENTITY;
    }
    let l = SymTensor(*log).to_matrix();
    let norm = l.norm();
    let s = if norm > 0.25 {
        (norm / 0.25).log2().ceil().min(1023.0) as i32
    } else {
        0
    };
    let x = l * 0.5f64.powi(s);
    // Horner: I + X(I + X/2(I + X/3(… (I + X/10)))).
    let mut p = Matrix3::identity();
    for k in (1..=DEGREE).rev() {
        p = Matrix3::identity() + x * p / f64::from(k);
    }
    for _ in 0..s {
        p = p * p;
    }
    SymTensor::from_matrix(&p)
}

/// The adjoint of `L ↦ exp L` at a symmetric `L` (stored `[xx, yy, zz, xy, xz, yz]`): for
/// `G = ∂ℓ/∂(exp L)` as a symmetric matrix, `∂ℓ/∂L` as a symmetric matrix. Stage 2 needs it to
/// carry the simulator's `dℓ/dA` back to N_A's `log A`. Daleckii–Krein with `L = QΛQᵀ`:
/// `Q (Γ ∘ QᵀGQ) Qᵀ`, `Γᵢⱼ = (e^λᵢ − e^λⱼ)/(λᵢ − λⱼ)` (`e^λᵢ` where they meet), written as
/// `e^λⱼ·expm1(d)/d`, `d = λᵢ − λⱼ`, so close eigenvalues lose no digits. Self-adjoint, so
/// the same map is the derivative and its adjoint.
pub fn exp_sym_adjoint(log: &[f64; 6], grad: &Matrix3<f64>) -> Matrix3<f64> {
    let eig = nalgebra::SymmetricEigen::new(SymTensor(*log).to_matrix());
    let (q, lambda) = (eig.eigenvectors, eig.eigenvalues);
    let mut inner = q.transpose() * grad * q;
    for i in 0..3 {
        for j in 0..3 {
            let d = lambda[i] - lambda[j];
            let ratio = if d.abs() < 1e-8 {
                1.0 + 0.5 * d
            } else {
                d.exp_m1() / d
            };
            inner[(i, j)] *= lambda[j].exp() * ratio;
        }
    }
    q * inner * q.transpose()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::basis::exp_tensor;
    use rand::{Rng, SeedableRng};

    #[test]
    fn matches_the_eigendecomposition() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for i in 0..2000 {
            let scale = [0.01, 0.3, 1.0, 4.0][i % 4];
            let l: [f64; 6] = [0; 6].map(|_| scale * (2.0 * rng.random::<f64>() - 1.0));
            let (a, b) = (exp_sym(&l), exp_tensor(&l));
            let tol = 1e-12 * b.to_matrix().norm();
            for (x, y) in a.0.iter().zip(b.0) {
                assert!((x - y).abs() <= tol, "{l:?}: {a:?} vs {b:?}");
            }
            a.validate().unwrap();
        }
        assert_eq!(exp_sym(&[0.0; 6]), SymTensor::IDENTITY);
        // Beyond f64: not finite (the caller reports it), never NaN-free garbage.
        assert!(exp_sym(&[1e6, 0.0, 0.0, 0.0, 0.0, 0.0]).validate().is_err());
    }

    /// `⟨G, d exp(L)[H]⟩ = ⟨exp_sym_adjoint(L, G), H⟩` against central differences of
    /// `exp_sym`, also with repeated eigenvalues.
    #[test]
    fn adjoint_matches_central_differences() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut r = |s: f64| [0; 6].map(|_| s * (2.0 * rng.random::<f64>() - 1.0));
        let cases = [r(0.4), r(1.5), [0.2, 0.2, 0.2, 0.0, 0.0, 0.0], [0.0; 6]];
        for l in cases {
            let g = SymTensor(r(1.0)).to_matrix();
            let h = SymTensor(r(1.0)).to_matrix();
            let adj = exp_sym_adjoint(&l, &g);
            let eps = 1e-6;
            let at = |t: f64| {
                let m = SymTensor(l).to_matrix() + h * t;
                exp_sym(&SymTensor::from_matrix(&m).0).to_matrix()
            };
            let fd = (g.component_mul(&(at(eps) - at(-eps)))).sum() / (2.0 * eps);
            let an = adj.component_mul(&h).sum();
            assert!(
                (fd - an).abs() < 1e-8 * (1.0 + fd.abs()),
                "{l:?}: {an} vs {fd}"
            );
            assert!((adj - adj.transpose()).norm() < 1e-12);
        }
    }
}
