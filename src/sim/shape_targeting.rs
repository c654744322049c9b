//! Shape-targeting energy of one element (Klár et al. 2020; the paper's Eq. 3 discretized):
//!
//! `E = (w·V/2)·‖F − R*·A‖²_F`,  `R* = argmax_{R ∈ SO(3)} tr(Rᵀ·F·A)`,
//!
//! where `V` is the rest volume, `w` the element's stiffness and `A` its symmetric actuation.
//! Because `R*` minimizes the energy over rotations, `∂E/∂F = w·V·(F − R*·A)` (envelope
//! theorem); the second derivatives go through `dR*` from [`PolarDerivative`].
//!
//! Shape targeting alone lets an element fold (det F < 0) when its neighbours, the bones or
//! contact demand it. A volume barrier keeps every element unfolded: below `J = det F = Ĵ`
//! the energy gains `w·V·μ·b(J)`, IPC's clamped log barrier `b(J) = −(J − Ĵ)²·ln(J/Ĵ)` (C²
//! at Ĵ, infinite at 0), so a solve from an unfolded state never accepts a folding step
//! (its energy is infinite) and the gradient turns the solver away before it gets there.
//!
//! Before the barrier is reached, a volume floor resists squeezing: below half its target
//! volume an element gains `κ·w·V·(J_f − J)³/(3·J_f)`, `J_f = ½·min(det A, 1)`
//! ([`VOLUME_FLOOR`]), so squeezed tissue bulges instead of crushing its smallest elements
//! into the barrier.

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
    /// `F` itself, kept for the step limit and the barrier's curvature at this state.
    pub deformation: Matrix3<f64>,
}

/// Volume ratio below which the barrier acts (`Ĵ`): 90 % compression. (0.05 converges
/// 143 of the 161 frames of [`BARRIER_WEIGHT`]'s measurement against 0.1's 145.)
pub const BARRIER_VOLUME: f64 = 0.1;
/// Barrier weight `μ`, relative to the element's stiffness. Measured on the extremes
/// sweep (`facesim bench extremes --face identity001 --contact false`, interactive): with
/// half the volume kept per step, μ = 1 converges 145 of 161 slider-end frames, μ = 10
/// 144, μ = 0.1 142; with a fifth kept, μ = 10 and 100 converge only 107 (a stiff wall
/// reached in long steps stalls the search). No setting folds an element.
pub const BARRIER_WEIGHT: f64 = 1.0;

/// Volume floor: an element squeezed below `c = VOLUME_FLOOR` times its target volume
/// (`J_f = c·min(det A, 1)`) pays `κ·w·V·(J_f − J)³/(3·J_f)`, `κ = VOLUME_WEIGHT`: C² at
/// the floor (a quadratic's curvature jump there kept L-BFGS from the 10⁻¹¹ residual the
/// stage-2 gradient check solves to), with the same force at `J = 0` as
/// `(κ·w·V/2)·(J_f − J)²`. Shape targeting alone resists compression only linearly (collapsing an element costs `w·V·‖A‖²/2`), so
/// where the bones and neighbours squeeze the tissue (the lips' corners as the jaw opens)
/// small elements were crushed into the barrier (`J` of 10⁻³…10⁻⁵), every step was then cut
/// to 10⁻³…10⁻⁸ by [`STEP_VOLUME_KEPT`], and the solve stalled. The floor makes the tissue
/// bulge instead, as real (nearly incompressible) tissue does. One-sided, so an element at
/// its target (or stretched) is untouched: the basis shapes' equilibria do not move.
///
/// Measured (`facesim bench shapes --contact off`, 5 sample faces × 19 shapes, final): without
/// the floor 90 of 95 converge; with it (κ = 30) 95, the same median iteration count (largest
/// ratio 1.65) and 18 s of solves against 29. A quadratic floor with κ = 10 converged 94, κ =
/// 100 91 (too stiff for the PD matrix, which lacks this curvature).
pub const VOLUME_WEIGHT: f64 = 30.0;
pub const VOLUME_FLOOR: f64 = 0.5;

/// `J_f = c·min(det A, 1)`, the volume ratio below which the floor acts. A target that
/// grows the element keeps the floor at `c` of the rest volume: the floor is against
/// crushing, not a demand to grow (with `c·det A` an actuation of 5·I, `det A` = 125, asked
/// for a 62-fold volume and found no equilibrium).
#[inline]
fn floor_volume(a: &Matrix3<f64>) -> f64 {
    VOLUME_FLOOR * a.determinant().min(1.0)
}

/// `b(J)`, `b′(J)`, `b″(J)` of the volume barrier (module doc); `b = ∞` for `J ≤ 0`.
#[inline]
fn barrier(j: f64) -> (f64, f64, f64) {
    let jh = BARRIER_VOLUME;
    if j >= jh {
        return (0.0, 0.0, 0.0);
    }
    if !(j > 0.0) {
        return (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY);
    }
    let (d, l) = (j - jh, (j / jh).ln());
    (
        -d * d * l,
        -2.0 * d * l - d * d / j,
        -2.0 * l - 4.0 * d / j + d * d / (j * j),
    )
}

/// `cof(F) = ∂ det F / ∂F`, column by column `[c₁×c₂, c₂×c₀, c₀×c₁]`.
#[inline]
fn cofactor(f: &Matrix3<f64>) -> Matrix3<f64> {
    let (c0, c1, c2) = (f.column(0), f.column(1), f.column(2));
    Matrix3::from_columns(&[c1.cross(&c2), c2.cross(&c0), c0.cross(&c1)])
}

/// The differential of [`cofactor`] for a change `dF`.
#[inline]
fn cofactor_differential(f: &Matrix3<f64>, df: &Matrix3<f64>) -> Matrix3<f64> {
    let (c0, c1, c2) = (f.column(0), f.column(1), f.column(2));
    let (d0, d1, d2) = (df.column(0), df.column(1), df.column(2));
    Matrix3::from_columns(&[
        d1.cross(&c2) + c1.cross(&d2),
        d2.cross(&c0) + c2.cross(&d0),
        d0.cross(&c1) + c0.cross(&d1),
    ])
}

/// The volume barrier's curvature along `∇J`, for steps: `(w·V·μ·b″(J), cof F)` when the
/// element is near folding (`0 < J < Ĵ`). The element's barrier Hessian is
/// `w·V·μ·(b″·∇J·∇Jᵀ + b′·∇²J)`; the first (rank-one, PSD) term dominates as `J → 0`
/// (`b″ ~ Ĵ²/J²` against `b′ ~ Ĵ²/J`) and is what the step needs to stop short of the wall.
/// `∇J` with respect to corner `i` is `cof F · gᵢ`.
#[inline]
pub fn barrier_curvature(f: &Matrix3<f64>, wv: f64) -> Option<(f64, Matrix3<f64>)> {
    let j = f.determinant();
    if !(j > 0.0 && j < BARRIER_VOLUME) {
        return None;
    }
    let (_, _, ddb) = barrier(j);
    Some((wv * BARRIER_WEIGHT * ddb, cofactor(f)))
}

/// Share of an element's volume one line-search step may take away (the rest is the
/// most a step may squeeze): the step is shortened so that `det F` keeps at least this
/// fraction of its value, so a step never jumps into the barrier (where its energy is
/// infinite and the search would halve it a dozen times) and approaches it gradually.
///
/// Measured like [`BARRIER_WEIGHT`] (μ = 1): keeping 0.5 converges 145 of 161 slider-end
/// frames, 0.7 140, 0.2 145 (but 107 at μ = 10); without the limit (μ = 10) 2 (almost every step
/// jumped into the barrier and was halved a dozen times).
pub const STEP_VOLUME_KEPT: f64 = 0.5;

/// The largest `α ∈ (0, 1]` with `det(F + t·dF) > keep·det F` for every `t ∈ [0, α]`
/// (`det F > 0`): the first root of a cubic in `t`, bracketed between its critical points
/// (where it is monotone) and bisected; 1 when there is none.
pub fn volume_step_limit(f: &Matrix3<f64>, df: &Matrix3<f64>, keep: f64) -> f64 {
    let j = f.determinant();
    // det(F + t·dF) = J + t·⟨cof F, dF⟩ + t²·⟨F, cof dF⟩ + t³·det dF.
    let c = [
        (1.0 - keep) * j,
        cofactor(f).component_mul(df).sum(),
        cofactor(df).component_mul(f).sum(),
        df.determinant(),
    ];
    let q = |t: f64| c[0] + t * (c[1] + t * (c[2] + t * c[3]));
    if !(c[0] > 0.0) {
        return 0.0;
    }
    // Critical points: roots of 3c₃t² + 2c₂t + c₁ inside (0, 1).
    let mut breaks = vec![0.0];
    let (a, b, cc) = (3.0 * c[3], 2.0 * c[2], c[1]);
    let mut roots = Vec::with_capacity(2);
    if a.abs() <= 1e-14 * (b.abs() + cc.abs()) {
        if b != 0.0 {
            roots.push(-cc / b);
        }
    } else {
        let disc = b * b - 4.0 * a * cc;
        if disc >= 0.0 {
            // The cancellation-free pair of roots.
            let m = -0.5 * (b + b.signum() * disc.sqrt());
            if m != 0.0 {
                roots.push(m / a);
                roots.push(cc / m);
            } else {
                roots.push(0.0);
            }
        }
    }
    roots.retain(|t| *t > 0.0 && *t < 1.0);
    roots.sort_by(f64::total_cmp);
    breaks.extend(roots);
    breaks.push(1.0);
    for w in breaks.windows(2) {
        let (mut lo, mut hi) = (w[0], w[1]);
        if q(hi) > 0.0 {
            continue;
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if q(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        return lo;
    }
    1.0
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
    let j = f.determinant();
    let (mut energy, mut stress) = (0.5 * wv * diff.norm_squared(), diff * wv);
    let jf = floor_volume(a);
    let dv = j - jf;
    if dv < 0.0 {
        // E = κ·w·V·(−d)³/(3·J_f), C² at the floor (d = 0); ∂E/∂J = −κ·w·V·d²/J_f.
        let kv = wv * VOLUME_WEIGHT;
        energy -= kv * dv * dv * dv / (3.0 * jf);
        stress -= cofactor(f) * (kv * dv * dv / jf);
    }
    if j < BARRIER_VOLUME {
        let (b, db, _) = barrier(j);
        energy += wv * BARRIER_WEIGHT * b;
        if db.is_finite() {
            stress += cofactor(f) * (wv * BARRIER_WEIGHT * db);
        }
    }
    LocalStep {
        rotation,
        stress,
        energy,
        volume_ratio: j,
        deformation: *f,
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
        let mut shape = (df - dr * self.a) * self.wv;
        let j = self.f.determinant();
        let jf = floor_volume(&self.a);
        let dv = j - jf;
        if dv < 0.0 {
            // d(−κwV·d²/J_f·cof F) = −κwV/J_f·(2d·⟨cof F, dF⟩·cof F + d²·d cof F).
            let (cof, kv) = (cofactor(&self.f), self.wv * VOLUME_WEIGHT);
            shape -= (cof * (2.0 * dv * cof.component_mul(df).sum())
                + cofactor_differential(&self.f, df) * (dv * dv))
                * (kv / jf);
        }
        if !(j < BARRIER_VOLUME && j > 0.0) {
            return shape;
        }
        // d(b′(J)·cof F) = b″(J)·⟨cof F, dF⟩·cof F + b′(J)·d cof F.
        let (_, db, ddb) = barrier(j);
        let cof = cofactor(&self.f);
        let dj = cof.component_mul(df).sum();
        shape
            + (cof * (ddb * dj) + cofactor_differential(&self.f, df) * db)
                * (self.wv * BARRIER_WEIGHT)
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
        let jf = floor_volume(&self.a);
        let dv = self.f.determinant() - jf;
        if dv < 0.0 {
            // The stress −κwV·d²/J_f·cof F moves with J_f = c·det A (d = J − J_f):
            // ∂/∂J_f = κwV·(2d/J_f + d²/J_f²)·cof F, and ∂J_f/∂A = c·cof A.
            let along = -lambda.component_mul(&cofactor(&self.f)).sum()
                * (self.wv * VOLUME_WEIGHT * VOLUME_FLOOR)
                * (2.0 * dv / jf + dv * dv / (jf * jf));
            // The floor does not move with A once det A ≥ 1.
            let cof_a = if jf < VOLUME_FLOOR {
                cofactor(&self.a)
            } else {
                Matrix3::zeros()
            };
            for (k, value) in out.iter_mut().enumerate() {
                *value += along * cof_a.component_mul(&SymTensor::basis(k)).sum();
            }
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
            // Away from the volume barrier (tested on its own below).
            let f = loop {
                let f = Matrix3::identity() + Matrix3::from_fn(|_, _| rng.random_range(-0.6..0.6));
                if f.determinant() > 2.0 * BARRIER_VOLUME {
                    break f;
                }
            };
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

    /// The volume barrier: zero above Ĵ, growing without bound toward J = 0, infinite when
    /// folded; its stress and Hessian (inside the element's) match finite differences.
    #[test]
    fn the_volume_barrier_and_its_derivatives_match_finite_differences() {
        let a = Matrix3::identity();
        let squash = |j: f64| Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, j));
        let floor = |j: f64| {
            1.7 * VOLUME_WEIGHT * (VOLUME_FLOOR - j).max(0.0).powi(3) / (3.0 * VOLUME_FLOOR)
        };
        assert!((energy(&squash(0.2), &a) - floor(0.2) - 0.5 * 1.7 * 0.64).abs() < 1e-12);
        assert!(energy(&squash(0.05), &a) > 0.5 * 1.7 * 0.95f64.powi(2));
        assert!(energy(&squash(1e-6), &a) > energy(&squash(1e-3), &a));
        assert_eq!(energy(&squash(-0.1), &a), f64::INFINITY);
        let (b, db, ddb) = barrier(BARRIER_VOLUME);
        assert_eq!((b, db, ddb), (0.0, 0.0, 0.0));
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let h = 1e-7;
        for _ in 0..100 {
            let a = random_spd(&mut rng);
            // Nearly flat elements: J in (0, Ĵ).
            let mut f = Matrix3::identity() + Matrix3::from_fn(|_, _| rng.random_range(-0.2..0.2));
            let j0 = f.determinant();
            let target = rng.random_range(0.01..0.09);
            f.set_column(2, &(f.column(2) * (target / j0)));
            let df = Matrix3::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let step = local_step(&f, &a, 1.7, &UnitQuaternion::identity());
            let fd = (energy(&(f + df * h), &a) - energy(&(f - df * h), &a)) / (2.0 * h);
            let got = step.stress.component_mul(&df).sum();
            assert!((fd - got).abs() < 1e-5 * (1.0 + fd.abs()), "{fd} vs {got}");
            let lin = Linearized::new(&f, &a, 1.7, &step.rotation);
            let sp = local_step(&(f + df * h), &a, 1.7, &step.rotation).stress;
            let sm = local_step(&(f - df * h), &a, 1.7, &step.rotation).stress;
            let fd = (sp - sm) / (2.0 * h);
            let got = lin.stress_differential(&df);
            assert!(
                (fd - got).norm() < 1e-4 * (1.0 + fd.norm()),
                "{fd} vs {got}"
            );
        }
    }

    /// The volume floor: nothing at or above half the target volume, a cubic cost below
    /// it, which the barrier's log adds to only below `Ĵ`.
    #[test]
    fn squeezing_below_the_volume_floor_costs_cubically() {
        let a = Matrix3::identity() * 0.9; // det A = 0.729, floor 0.3645
        let squash = |j: f64| Matrix3::from_diagonal(&nalgebra::Vector3::new(0.9, 0.9, j / 0.81));
        let shape_only = |j: f64| {
            let f = squash(j);
            let r = closest_rotation(&(f * a), &UnitQuaternion::identity());
            0.5 * 1.7 * (f - r.to_rotation_matrix().matrix() * a).norm_squared()
        };
        for j in [0.5, 0.37, 1.2] {
            assert!((energy(&squash(j), &a) - shape_only(j)).abs() < 1e-12);
        }
        let floor = VOLUME_FLOOR * a.determinant();
        for j in [0.3, 0.2, 0.11] {
            let extra = energy(&squash(j), &a) - shape_only(j);
            let expected = 1.7 * VOLUME_WEIGHT * (floor - j).powi(3) / (3.0 * floor);
            assert!(
                (extra - expected).abs() < 1e-9 * expected,
                "{extra} vs {expected}"
            );
        }
    }

    /// The step limit keeps `keep·det F` exactly at its root and never skips a dip of the
    /// cubic (checked on a fine grid of `t`).
    #[test]
    fn the_volume_step_limit_stops_at_the_first_loss_of_volume() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let mut limited = 0;
        for _ in 0..2000 {
            let f = loop {
                let f = Matrix3::identity() + Matrix3::from_fn(|_, _| rng.random_range(-0.5..0.5));
                if f.determinant() > 0.05 {
                    break f;
                }
            };
            let df = Matrix3::from_fn(|_, _| rng.random_range(-2.0..2.0));
            let keep = 0.2;
            let floor = keep * f.determinant();
            let alpha = volume_step_limit(&f, &df, keep);
            assert!(alpha > 0.0 && alpha <= 1.0);
            for k in 0..=1000 {
                let t = alpha * k as f64 / 1000.0;
                assert!(
                    (f + df * t).determinant() > floor * (1.0 - 1e-9),
                    "t {t} of {alpha}"
                );
            }
            if alpha < 1.0 {
                limited += 1;
                let at = (f + df * alpha).determinant();
                assert!((at - floor).abs() < 1e-9 * (1.0 + floor), "{at} vs {floor}");
            }
        }
        assert!(limited > 200, "the cases exercise the limit ({limited})");
    }

    #[test]
    fn actuation_adjoint_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let h = 1e-6;
        for _ in 0..100 {
            // Half of them shrink (det A < 1), where the volume floor moves with A.
            let shrink = if rng.random_bool(0.5) { 0.6 } else { 1.0 };
            let a = SymTensor::from_matrix(&(random_spd(&mut rng) * shrink));
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
