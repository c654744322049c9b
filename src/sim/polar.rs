//! The rotation of a polar decomposition, reflection-safe, and its derivative.
//!
//! For a 3×3 matrix `M`, `R* = argmax_{R ∈ SO(3)} tr(Rᵀ M)` is the rotation closest to `M`.
//! When `det M < 0` (an inverted element) this is *not* the orthogonal polar factor, which
//! would be a reflection: the sign flip goes to the smallest singular value instead, so `R*`
//! is always a proper rotation.

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

/// Newton iterations on SO(3) before falling back to an SVD; warm starts need one or two.
const MAX_NEWTON_STEPS: usize = 12;

/// The vector of the skew part of `K`: `axial(K) = w` with `[w]× = (K − Kᵀ)/2`.
#[inline]
pub fn axial(k: &Matrix3<f64>) -> Vector3<f64> {
    0.5 * Vector3::new(
        k[(2, 1)] - k[(1, 2)],
        k[(0, 2)] - k[(2, 0)],
        k[(1, 0)] - k[(0, 1)],
    )
}

/// `[w]×`, the cross-product matrix.
#[inline]
pub fn skew(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// `R* = argmax_{R ∈ SO(3)} tr(Rᵀ M)`, warm-started from `guess` (the previous rotation).
///
/// Newton's method on `R·exp([w]×)`: the objective's gradient is `a = axial(S − Sᵀ)` and its
/// Hessian `−K`, `K = tr(S)·I − sym(S)`, with `S = Rᵀ M`. A stationary point with `K ⪰ 0` is
/// the global maximum (Wahba's problem has no other local maxima); anything else, including
/// non-convergence, falls back to an exact SVD, so the result never depends on the guess.
pub fn closest_rotation(m: &Matrix3<f64>, guess: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    let scale = m.abs().max();
    if scale == 0.0 || !scale.is_finite() {
        return if scale == 0.0 {
            *guess
        } else {
            UnitQuaternion::identity()
        };
    }
    newton_rotation(m, guess).map_or_else(|| svd_rotation(m), |(q, _)| q)
}

/// The Newton iteration of [`closest_rotation`]: the rotation and the steps it took, or `None`
/// where only the SVD can be trusted.
pub fn newton_rotation(
    m: &Matrix3<f64>,
    guess: &UnitQuaternion<f64>,
) -> Option<(UnitQuaternion<f64>, usize)> {
    let mut q = *guess;
    for step in 0..MAX_NEWTON_STEPS {
        let s = q.to_rotation_matrix().into_inner().transpose() * m;
        // a = axial(S − Sᵀ); K = tr(S)·I − sym(S).
        let a = Vector3::new(
            s[(2, 1)] - s[(1, 2)],
            s[(0, 2)] - s[(2, 0)],
            s[(1, 0)] - s[(0, 1)],
        );
        let t = s.trace();
        let k = [
            t - s[(0, 0)],
            t - s[(1, 1)],
            t - s[(2, 2)],
            -0.5 * (s[(0, 1)] + s[(1, 0)]),
            -0.5 * (s[(0, 2)] + s[(2, 0)]),
            -0.5 * (s[(1, 2)] + s[(2, 1)]),
        ];
        let w = solve_spd3(k, a)?;
        let angle = w.norm();
        if angle <= 1e-15 {
            return Some((q, step));
        }
        if angle > 1.0 {
            // Far from the optimum: Newton's quadratic model is not to be trusted.
            return None;
        }
        q *= exp_map(&w);
        if angle <= NEWTON_LAST_STEP {
            // Quadratic convergence: what is left after this step is about angle² (round-off).
            return Some((q, step + 1));
        }
    }
    None
}

/// A Newton step this small leaves an error of about its square: the iteration stops there.
const NEWTON_LAST_STEP: f64 = 1e-7;

/// Solves `K·w = b` for a symmetric 3×3 `K = [[k0, k3, k4], [k3, k1, k5], [k4, k5, k2]]` by
/// LDLᵀ, or `None` unless `K` is positive definite.
#[inline]
fn solve_spd3(k: [f64; 6], b: Vector3<f64>) -> Option<Vector3<f64>> {
    let [k00, k11, k22, k10, k20, k21] = k;
    let d0 = k00;
    if !(d0 > 0.0) {
        return None;
    }
    let l10 = k10 / d0;
    let l20 = k20 / d0;
    let d1 = k11 - l10 * k10;
    if !(d1 > 0.0) {
        return None;
    }
    let l21 = (k21 - l20 * k10) / d1;
    let d2 = k22 - l20 * k20 - l21 * l21 * d1;
    if !(d2 > 0.0) {
        return None;
    }
    let y0 = b.x;
    let y1 = b.y - l10 * y0;
    let y2 = b.z - l20 * y0 - l21 * y1;
    let z2 = y2 / d2;
    let z1 = y1 / d1 - l21 * z2;
    let z0 = y0 / d0 - l10 * z1 - l20 * z2;
    Some(Vector3::new(z0, z1, z2))
}

/// Exact reflection-safe rotation from an SVD: `R = U·diag(1, 1, det(UVᵀ))·Vᵀ`, with the sign
/// on the smallest singular value.
pub fn svd_rotation(m: &Matrix3<f64>) -> UnitQuaternion<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return UnitQuaternion::identity();
    };
    let mut u = u;
    if (u * v_t).determinant() < 0.0 {
        let smallest = svd.singular_values.imin();
        u.column_mut(smallest).neg_mut();
    }
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(u * v_t))
}

/// The rotation `normalize(1, w/2)`: `exp([w]×)` up to `O(‖w‖³)`, which keeps Newton's
/// quadratic convergence without a sine or cosine.
#[inline]
fn exp_map(w: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::new_normalize(Quaternion::new(1.0, 0.5 * w.x, 0.5 * w.y, 0.5 * w.z))
}

/// Linearization of `M ↦ R*(M)` at one point: `dR = R·[w]×` with
/// `(tr(S)·I − S)·w = axial(Rᵀ dM − dMᵀ R)` and `S = Rᵀ M` (from differentiating `M = R S`).
#[derive(Clone, Copy, Debug)]
pub struct PolarDerivative {
    pub r: Matrix3<f64>,
    k_inv: Matrix3<f64>,
}

impl PolarDerivative {
    pub fn new(r: &Matrix3<f64>, m: &Matrix3<f64>) -> Self {
        let s = r.transpose() * m;
        let sym = 0.5 * (s + s.transpose());
        let k = Matrix3::identity() * sym.trace() - sym;
        // K is singular only when two singular values cancel (a fully flattened element); the
        // derivative is unbounded there, so regularize at round-off scale.
        let k_inv = k
            .try_inverse()
            .filter(|inv| inv.iter().all(|v| v.is_finite()))
            .unwrap_or_else(|| {
                let eps = 1e-12 * (1.0 + sym.abs().max());
                (k + Matrix3::identity() * eps)
                    .try_inverse()
                    .unwrap_or_else(Matrix3::zeros)
            });
        Self { r: *r, k_inv }
    }

    /// The rotation's change `dR` for a change `dM` of the decomposed matrix.
    #[inline]
    pub fn d_rotation(&self, dm: &Matrix3<f64>) -> Matrix3<f64> {
        let rt_dm = self.r.transpose() * dm;
        let w = self.k_inv * axial(&(rt_dm - rt_dm.transpose()));
        self.r * skew(&w)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_matrix(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
        Matrix3::from_fn(|_, _| rng.random_range(-1.0..1.0))
    }

    fn objective(r: &UnitQuaternion<f64>, m: &Matrix3<f64>) -> f64 {
        r.to_rotation_matrix().matrix().component_mul(m).sum()
    }

    #[test]
    fn matches_the_svd_from_any_guess_and_is_never_a_reflection() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for case in 0..2000 {
            let mut m = random_matrix(&mut rng);
            if case % 3 == 0 {
                // Inverted: flip a column so det < 0.
                m.column_mut(0).neg_mut();
            }
            let guess = UnitQuaternion::from_scaled_axis(Vector3::from_fn(|_, _| {
                rng.random_range(-3.0..3.0)
            }));
            let r = closest_rotation(&m, &guess);
            let exact = svd_rotation(&m);
            assert!((r.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-12);
            assert!(
                (objective(&r, &m) - objective(&exact, &m)).abs() < 1e-12,
                "case {case}: {} vs {}",
                objective(&r, &m),
                objective(&exact, &m)
            );
            // No rotation does better than the result (sampled check of global optimality).
            for _ in 0..4 {
                let other = UnitQuaternion::from_scaled_axis(Vector3::from_fn(|_, _| {
                    rng.random_range(-3.0..3.0)
                }));
                assert!(objective(&other, &m) <= objective(&r, &m) + 1e-12);
            }
        }
    }

    #[test]
    fn keeps_a_pure_rotation_and_handles_zero_and_rank_deficient_input() {
        let rot = UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.2, 0.5));
        let m = rot.to_rotation_matrix().into_inner() * 2.5;
        assert!(closest_rotation(&m, &UnitQuaternion::identity()).angle_to(&rot) < 1e-12);
        let zero = closest_rotation(&Matrix3::zeros(), &rot);
        assert!(zero.angle_to(&rot) < 1e-15);
        let flat = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0);
        let r = closest_rotation(&flat, &rot);
        assert!((objective(&r, &flat) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn derivative_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..200 {
            let m = random_matrix(&mut rng) + Matrix3::identity() * 1.5;
            let dm = random_matrix(&mut rng);
            let r = closest_rotation(&m, &UnitQuaternion::identity());
            let d = PolarDerivative::new(&r.to_rotation_matrix().into_inner(), &m);
            let h = 1e-6;
            let rp = closest_rotation(&(m + dm * h), &r)
                .to_rotation_matrix()
                .into_inner();
            let rm = closest_rotation(&(m - dm * h), &r)
                .to_rotation_matrix()
                .into_inner();
            let fd = (rp - rm) / (2.0 * h);
            let err = (fd - d.d_rotation(&dm)).norm();
            assert!(err < 1e-6 * (1.0 + fd.norm()), "err {err}");
        }
    }
}
