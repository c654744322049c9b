//! Shape-targeting energy of one element (Klár et al. 2020; the paper's Eq. 3 discretized):
//!
//! `E = (w·V/2)·‖F − R*·A‖²_F`,  `R* = argmax_{R ∈ SO(3)} tr(Rᵀ·F·A)`,
//!
//! where `V` is the rest volume, `w` the element's stiffness and `A` its symmetric actuation.
//! Because `R*` minimizes the energy over rotations, `∂E/∂F = w·V·(F − R*·A)` (envelope
//! theorem); the second derivatives go through `dR*` from [`PolarDerivative`].

use nalgebra::{Matrix3, UnitQuaternion};

use super::polar::{PolarDerivative, closest_rotation};
use super::tensor::SymTensor;

/// Value and stress of one element after its local (rotation) step.
#[derive(Clone, Copy, Debug, Default)]
pub struct LocalStep {
    pub rotation: UnitQuaternion<f64>,
    /// `∂E/∂F = w·V·(F − R*·A)`.
    pub stress: Matrix3<f64>,
    pub energy: f64,
    /// `det F`: the element's volume ratio (≤ 0 means inverted).
    pub volume_ratio: f64,
}

/// The local step: best rotation (warm-started from `guess`), energy and stress.
#[inline]
pub fn local_step(
    f: &Matrix3<f64>,
    a: &Matrix3<f64>,
    wv: f64,
    guess: &UnitQuaternion<f64>,
) -> LocalStep {
    let rotation = closest_rotation(&(f * a), guess);
    let diff = f - rotation.to_rotation_matrix().matrix() * a;
    LocalStep {
        rotation,
        stress: diff * wv,
        energy: 0.5 * wv * diff.norm_squared(),
        volume_ratio: f.determinant(),
    }
}

/// The linearized element at a solved state, for Hessian products and sensitivities.
#[derive(Clone, Copy, Debug)]
pub struct Linearized {
    f: Matrix3<f64>,
    a: Matrix3<f64>,
    wv: f64,
    polar: PolarDerivative,
}

impl Linearized {
    pub fn new(
        f: &Matrix3<f64>,
        a: &Matrix3<f64>,
        wv: f64,
        rotation: &UnitQuaternion<f64>,
    ) -> Self {
        let r = rotation.to_rotation_matrix().into_inner();
        Self {
            f: *f,
            a: *a,
            wv,
            polar: PolarDerivative::new(&r, &(f * a)),
        }
    }

    /// `d(∂E/∂F) = w·V·(dF − dR*·A)` for a change `dF`: the element Hessian applied to `dF`.
    #[inline]
    pub fn stress_differential(&self, df: &Matrix3<f64>) -> Matrix3<f64> {
        let dr = self.polar.d_rotation(&(df * self.a));
        (df - dr * self.a) * self.wv
    }

    /// `∂/∂A ⟨Λ, ∂E/∂F⟩` with respect to the 6 stored actuation values, for a fixed `Λ`.
    ///
    /// `∂(∂E/∂F)/∂A[dA] = −w·V·(dR*·A + R*·dA)`, `dR* = dR*(F·dA)`. The adjoint method needs
    /// `−⟨Λ, ·⟩` of this, which is returned.
    pub fn actuation_adjoint(&self, lambda: &Matrix3<f64>) -> [f64; 6] {
        let r = self.polar.r;
        // ⟨Λ, R·dA⟩ = ⟨RᵀΛ, dA⟩ is linear in dA directly.
        let direct = SymTensor::gradient_from_matrix(&(r.transpose() * lambda));
        let mut out = [0.0; 6];
        for (k, value) in out.iter_mut().enumerate() {
            let da = SymTensor::basis(k);
            let dr = self.polar.d_rotation(&(self.f * da));
            *value = self.wv * (lambda.component_mul(&(dr * self.a)).sum() + direct[k]);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn energy(f: &Matrix3<f64>, a: &Matrix3<f64>) -> f64 {
        local_step(f, a, 1.7, &UnitQuaternion::identity()).energy
    }

    fn random_spd(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
        let b = Matrix3::from_fn(|_, _| rng.random_range(-0.5..0.5));
        Matrix3::identity() + b * b.transpose()
    }

    #[test]
    fn energy_is_zero_exactly_at_a_rotated_target() {
        let a = Matrix3::new(1.2, 0.1, 0.0, 0.1, 0.8, 0.05, 0.0, 0.05, 1.0);
        let r = UnitQuaternion::from_scaled_axis(nalgebra::Vector3::new(0.4, 0.1, -0.7));
        let f = r.to_rotation_matrix().matrix() * a;
        assert!(energy(&f, &a) < 1e-28);
    }

    #[test]
    fn stress_and_its_differential_match_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let h = 1e-6;
        for _ in 0..100 {
            let a = random_spd(&mut rng);
            let f = Matrix3::identity() + Matrix3::from_fn(|_, _| rng.random_range(-0.6..0.6));
            let df = Matrix3::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let step = local_step(&f, &a, 1.7, &UnitQuaternion::identity());
            let fd = (energy(&(f + df * h), &a) - energy(&(f - df * h), &a)) / (2.0 * h);
            assert!((fd - step.stress.component_mul(&df).sum()).abs() < 1e-7 * (1.0 + fd.abs()));

            let lin = Linearized::new(&f, &a, 1.7, &step.rotation);
            let sp = local_step(&(f + df * h), &a, 1.7, &step.rotation).stress;
            let sm = local_step(&(f - df * h), &a, 1.7, &step.rotation).stress;
            let fd = (sp - sm) / (2.0 * h);
            assert!((fd - lin.stress_differential(&df)).norm() < 1e-6 * (1.0 + fd.norm()));
        }
    }

    #[test]
    fn actuation_adjoint_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let h = 1e-6;
        for _ in 0..100 {
            let a = SymTensor::from_matrix(&random_spd(&mut rng));
            let f = Matrix3::identity() + Matrix3::from_fn(|_, _| rng.random_range(-0.6..0.6));
            let lambda = Matrix3::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let step = local_step(&f, &a.to_matrix(), 1.7, &UnitQuaternion::identity());
            let got =
                Linearized::new(&f, &a.to_matrix(), 1.7, &step.rotation).actuation_adjoint(&lambda);
            for (k, got_k) in got.iter().enumerate() {
                let mut plus = a;
                plus.0[k] += h;
                let mut minus = a;
                minus.0[k] -= h;
                let stress =
                    |t: &SymTensor| local_step(&f, &t.to_matrix(), 1.7, &step.rotation).stress;
                // −⟨Λ, ∂stress/∂a_k⟩
                let fd = -lambda
                    .component_mul(&((stress(&plus) - stress(&minus)) / (2.0 * h)))
                    .sum();
                assert!(
                    (fd - got_k).abs() < 1e-6 * (1.0 + fd.abs()),
                    "k={k}: fd {fd} vs {got_k}"
                );
            }
        }
    }
}
