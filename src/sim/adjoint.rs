//! Sensitivities by implicit differentiation (the paper's supplemental Eq. 6).
//!
//! At an equilibrium `∇E(u; θ) = 0`, so `du/dθ = −(∇²E)⁻¹·∂∇E/∂θ`. For a loss `ℓ(u)` the
//! adjoint form needs one linear solve whatever the number of parameters:
//! `H·λ = ∂ℓ/∂u`, then `dℓ/dθ = −λᵀ·∂∇E/∂θ`. `H` is the exact Hessian (it includes the
//! rotation derivatives, so it is not the PD matrix); the solve is conjugate gradients
//! preconditioned by the prefactored PD matrix, which reuses its Cholesky factor.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::attachment::{Bone, BonePose};
use super::simulator::{SimError, SimState, Simulator};
use super::tensor::SymTensor;
use super::vector::{dot, norm};

/// Gradients of a loss with respect to the simulator's inputs.
#[derive(Clone, Debug)]
pub struct Sensitivities {
    /// `dℓ/dA` per element, over the 6 stored values `[xx, yy, zz, xy, xz, yz]` (each
    /// off-diagonal value counts for both of its matrix entries).
    pub actuation: Vec<[f64; 6]>,
    /// `dℓ/d[θx, θy, θz, tx, ty, tz]` of the jaw motion.
    pub jaw: [f64; 6],
    /// Conjugate-gradient iterations of the adjoint solve.
    pub iterations: usize,
    /// Its final relative residual `‖Hλ − ∂ℓ/∂u‖ / ‖∂ℓ/∂u‖`.
    pub residual: f64,
}

/// Relative residual at which the adjoint solve stops.
const ADJOINT_TOLERANCE: f64 = 1e-10;
const ADJOINT_MAX_ITERATIONS: usize = 1000;

/// The barrier's part of the Hessian at a state: exact (unprojected) 12×12 blocks in contact
/// space, `∇²(κB)`, applied as `Wᵀ·H·W` (implicit differentiation needs the true Hessian).
struct BarrierHessian<'a> {
    face: &'a crate::contact::surface::FaceContact,
    blocks: Vec<crate::contact::HessianBlock>,
}

impl BarrierHessian<'_> {
    /// `H_y·(W·v)` in contact space.
    fn contact_product(&self, v: &[f64]) -> Vec<f64> {
        let m = 3 * self.face.vertex_count();
        let mut u = vec![0.0; m];
        self.face.displacement(v, &mut u);
        let mut hu = vec![0.0; m];
        crate::contact::add_hessian_product(&self.blocks, &u, &mut hu);
        hu
    }

    /// `out += Wᵀ·H_y·W·v`.
    fn add_product(&self, v: &[f64], out: &mut [f64]) {
        let hu = self.contact_product(v);
        self.face.add_pulled_back(&hu, out);
    }
}

impl Simulator {
    /// The barrier Hessian at `state` if contact is on for it (the state carries the κ its
    /// solve ended with).
    fn barrier_hessian(
        &self,
        bones: &BonePose,
        state: &SimState,
    ) -> Result<Option<BarrierHessian<'_>>, SimError> {
        let (Some(model), Some(kappa)) = (self.contact.as_ref(), state.contact_stiffness) else {
            return Ok(None);
        };
        let face = &model.face;
        let mut y = vec![0.0; 3 * face.vertex_count()];
        face.positions(&state.x, bones, &mut y);
        let collisions = face.collisions(&y)?;
        let potential = crate::contact::BarrierPotential::new(face.dhat(), kappa)?;
        let blocks = potential.hessian(&collisions, &y, crate::contact::Projection::None)?;
        Ok(Some(BarrierHessian { face, blocks }))
    }

    /// `κ·B` and `κ·Wᵀ∇B` at `state` (zero without contact for it).
    fn barrier_gradient(
        &self,
        bones: &BonePose,
        state: &SimState,
        g: &mut [f64],
    ) -> Result<f64, SimError> {
        let (Some(model), Some(kappa)) = (self.contact.as_ref(), state.contact_stiffness) else {
            return Ok(0.0);
        };
        let face = &model.face;
        let mut y = vec![0.0; 3 * face.vertex_count()];
        face.positions(&state.x, bones, &mut y);
        let collisions = face.collisions(&y)?;
        let potential = crate::contact::BarrierPotential::new(face.dhat(), kappa)?;
        let gy = potential.gradient(&collisions, &y)?;
        face.add_pulled_back(&gy, g);
        Ok(potential.value(&collisions, &y)?)
    }

    /// `H·v` at `state` for the given inputs (exact Hessian of the total energy, the
    /// barrier's included when the state was solved with contact).
    pub fn hessian_vector_product(
        &self,
        actuations: &[SymTensor],
        bones: &BonePose,
        state: &SimState,
        v: &[f64],
    ) -> Result<Vec<f64>, SimError> {
        self.check_state(state)?;
        let frame = self.frame(actuations, bones)?;
        let lin = self.linearize(&frame, state);
        let barrier = self.barrier_hessian(bones, state)?;
        let mut out = vec![0.0; v.len()];
        self.hessian_product(&lin, v, &mut out);
        if let Some(b) = &barrier {
            b.add_product(v, &mut out);
        }
        Ok(out)
    }

    /// `∇E` at `state` (interleaved), for checks and for callers composing energies.
    pub fn energy_gradient(
        &self,
        actuations: &[SymTensor],
        bones: &BonePose,
        state: &SimState,
    ) -> Result<(f64, Vec<f64>), SimError> {
        self.check_state(state)?;
        let frame = self.frame(actuations, bones)?;
        let mut steps = state.steps.clone();
        let energy = self.local_sweep(&frame, &state.x, None, &mut steps);
        let mut g = vec![0.0; state.x.len()];
        self.gradient(&frame, &state.x, &steps, &mut g);
        let barrier = self.barrier_gradient(bones, state, &mut g)?;
        Ok((energy + barrier, g))
    }

    /// Gradients of a loss `ℓ(u)` with respect to every element's actuation and to the jaw
    /// motion, at the equilibrium `state` (solve to a tight tolerance first: the result is as
    /// accurate as the equilibrium). `loss_gradient` is `∂ℓ/∂u`, interleaved.
    pub fn sensitivities(
        &self,
        actuations: &[SymTensor],
        bones: &BonePose,
        state: &SimState,
        loss_gradient: &[f64],
    ) -> Result<Sensitivities, SimError> {
        self.check_state(state)?;
        if loss_gradient.len() != state.x.len() {
            return Err(SimError::LossGradientSize {
                expected: state.x.len(),
                got: loss_gradient.len(),
            });
        }
        let frame = self.frame(actuations, bones)?;
        let lin = self.linearize(&frame, state);
        let barrier = self.barrier_hessian(bones, state)?;
        let (lambda, iterations, residual) =
            self.adjoint_solve(&lin, barrier.as_ref(), loss_gradient)?;

        let actuation = (0..self.element_count())
            .into_par_iter()
            .with_min_len(512)
            .map(|e| {
                let tet = &self.mesh.tets[e];
                let mut big_lambda = Matrix3::zeros();
                for (corner, &v) in tet.iter().enumerate() {
                    let i = 3 * v as usize;
                    big_lambda += Vector3::new(lambda[i], lambda[i + 1], lambda[i + 2])
                        * self.ops[e].grads[corner].transpose();
                }
                lin[e].actuation_adjoint(&big_lambda)
            })
            .collect();

        // ∇ₓE has k·(x − T(p)) at jaw vertices, so −λᵀ∂∇E/∂θ = Σ k·λᵀ·∂T(p)/∂θ.
        let mut jaw = [0.0; 6];
        for v in self.attached_to(Bone::Jaw) {
            let jac = bones.jaw_target_jacobian(&self.config.jaw_pivot, &self.mesh.vertices[v]);
            let l = Vector3::new(lambda[3 * v], lambda[3 * v + 1], lambda[3 * v + 2])
                * self.stiffness[v];
            let contribution = jac.transpose() * l;
            for k in 0..6 {
                jaw[k] += contribution[k];
            }
        }
        // The teeth on the jaw are barrier obstacles: ∇ₓ(κB) = Wᵀ∇_y(κB)(W·x, T(p)), so
        // ∂∇ₓ(κB)/∂θ = Wᵀ·H_{y,r}·∂T(p_r)/∂θ and −λᵀ of it is −Σ_r (H·W·λ)_rᵀ·∂T(p_r)/∂θ;
        // an obstacle between the bones moves by its jaw share β of the jaw's motion.
        if let Some(b) = &barrier {
            let h_lambda = b.contact_product(&lambda);
            for (i, binding) in b.face.bindings().iter().enumerate() {
                let factor = binding.jaw_factor(bones);
                if let crate::contact::surface::ContactBinding::Rigid { rest, .. }
                | crate::contact::surface::ContactBinding::Bones { rest, .. } = binding
                    && factor != nalgebra::Matrix3::zeros()
                {
                    let jac = factor * bones.jaw_target_jacobian(&self.config.jaw_pivot, rest);
                    let hl =
                        Vector3::new(h_lambda[3 * i], h_lambda[3 * i + 1], h_lambda[3 * i + 2]);
                    let contribution = jac.transpose() * hl;
                    for k in 0..6 {
                        jaw[k] -= contribution[k];
                    }
                }
            }
        }
        Ok(Sensitivities {
            actuation,
            jaw,
            iterations,
            residual,
        })
    }

    /// Preconditioned conjugate gradients for `H·λ = b` with `M⁻¹ = L⁻¹`.
    fn adjoint_solve(
        &self,
        lin: &[super::shape_targeting::Linearized],
        barrier: Option<&BarrierHessian<'_>>,
        b: &[f64],
    ) -> Result<(Vec<f64>, usize, f64), SimError> {
        let dim = b.len();
        let b_norm = norm(b);
        let mut x = vec![0.0; dim];
        if b_norm == 0.0 {
            return Ok((x, 0, 0.0));
        }
        let mut scratch = self.solve_scratch();
        let mut r = b.to_vec();
        let mut z = r.clone();
        self.global.solve_in_place(&mut z, &mut scratch);
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let mut hp = vec![0.0; dim];
        let mut residual = 1.0;
        for iteration in 1..=ADJOINT_MAX_ITERATIONS {
            self.hessian_product(lin, &p, &mut hp);
            if let Some(bh) = barrier {
                bh.add_product(&p, &mut hp);
            }
            let curvature = dot(&p, &hp);
            if !(curvature > 0.0) {
                return Err(SimError::IndefiniteHessian(curvature / dot(&p, &p)));
            }
            let alpha = rz / curvature;
            for i in 0..dim {
                x[i] += alpha * p[i];
                r[i] -= alpha * hp[i];
            }
            residual = norm(&r) / b_norm;
            if residual <= ADJOINT_TOLERANCE {
                return Ok((x, iteration, residual));
            }
            z.copy_from_slice(&r);
            self.global.solve_in_place(&mut z, &mut scratch);
            let rz_new = dot(&r, &z);
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..dim {
                p[i] = z[i] + beta * p[i];
            }
        }
        Ok((x, ADJOINT_MAX_ITERATIONS, residual))
    }
}
