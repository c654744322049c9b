//! The barrier potential of IPC (Li et al. 2020, Eq. 7–8) over an active set:
//!
//! `B(x) = κ · ( Σ_{point–triangle} b(d²(x), d̂²) + Σ_{edge–edge} m(x)·b(d²(x), d̂²) )`
//!
//! with `b` the clamped log barrier on squared distances, `m` the edge–edge mollifier, `d̂`
//! in cm and `κ` the barrier stiffness (units: energy per cm⁴). The value, the interleaved
//! gradient (`3n`) and the Hessian as a list of 12×12 stencil blocks (optionally each projected
//! to PSD) are summed in the active set's fixed order, so the result is bitwise
//! reproducible whatever the thread count. The closest-feature type of each pair is
//! classified again at the positions given (the set's stored type is only a record of the
//! build), so the potential is the exact piecewise function at any `x`; rebuild the set when
//! `x` moves enough for new pairs to come within d̂.

mod local;
pub mod psd;

use rayon::prelude::*;

use super::ContactError;
use super::collisions::{Collision, Collisions};
use super::math::{Matrix12, Vector12, stencil};

/// `κ·Σ m·b(d², d̂²)` with its activation distance and stiffness.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BarrierPotential {
    /// Activation distance d̂ (cm): pairs farther apart contribute nothing.
    pub dhat: f64,
    /// Barrier stiffness κ.
    pub stiffness: f64,
}

/// One collision's Hessian: rows/columns `3i..3i+3` belong to simulation vertex `vertices[i]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HessianBlock {
    pub vertices: [u32; 4],
    pub matrix: Matrix12,
}

/// The blocks summed into a dense row-major `dim × dim` matrix (`dim` = 3 × vertices): for
/// checks and small problems (tests compare it with finite differences and ipctk).
pub fn assemble_dense(blocks: &[HessianBlock], dim: usize) -> Vec<f64> {
    let mut h = vec![0.0; dim * dim];
    for b in blocks {
        for (i, &vi) in b.vertices.iter().enumerate() {
            for (j, &vj) in b.vertices.iter().enumerate() {
                for r in 0..3 {
                    for c in 0..3 {
                        h[(3 * vi as usize + r) * dim + 3 * vj as usize + c] +=
                            b.matrix[(3 * i + r, 3 * j + c)];
                    }
                }
            }
        }
    }
    h
}

impl HessianBlock {
    /// `out += H·v` for interleaved vectors `v`, `out` of the simulation's size.
    pub fn add_product(&self, v: &[f64], out: &mut [f64]) {
        let mut local = [0.0; 12];
        for (i, &vi) in self.vertices.iter().enumerate() {
            local[3 * i..3 * i + 3].copy_from_slice(&v[3 * vi as usize..3 * vi as usize + 3]);
        }
        let local = nalgebra::SVector::<f64, 12>::from(local);
        let hv = self.matrix * local;
        for (i, &vi) in self.vertices.iter().enumerate() {
            for k in 0..3 {
                out[3 * vi as usize + k] += hv[3 * i + k];
            }
        }
    }
}

/// `out += Σ_blocks H·v`, in block order.
pub fn add_hessian_product(blocks: &[HessianBlock], v: &[f64], out: &mut [f64]) {
    for b in blocks {
        b.add_product(v, out);
    }
}

/// Whether to project each stencil block onto the PSD cone.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Projection {
    /// The exact Hessian.
    None,
    /// Each block `Q·max(Λ, 0)·Qᵀ` ([`psd::project_to_psd`]).
    ClampEigenvalues,
}

impl BarrierPotential {
    /// Fails unless `dhat > 0` and `stiffness ≥ 0`, both finite.
    pub fn new(dhat: f64, stiffness: f64) -> Result<Self, ContactError> {
        if !(dhat > 0.0) || !dhat.is_finite() || !(stiffness >= 0.0) || !stiffness.is_finite() {
            return Err(ContactError::InvalidParameter(format!(
                "barrier needs finite d̂ > 0 and κ ≥ 0, got d̂ = {dhat}, κ = {stiffness}"
            )));
        }
        Ok(Self { dhat, stiffness })
    }

    fn check(&self, collisions: &Collisions, x: &[f64]) -> Result<(), ContactError> {
        if collisions.dhat != self.dhat {
            return Err(ContactError::InvalidParameter(format!(
                "active set built with d̂ = {} used with a barrier of d̂ = {}",
                collisions.dhat, self.dhat
            )));
        }
        if let Some(v) = collisions
            .collisions
            .iter()
            .flat_map(|c| c.vertices)
            .find(|&v| 3 * v as usize + 2 >= x.len())
        {
            return Err(ContactError::PositionsLength {
                expected: 3 * (v as usize + 1),
                got: x.len(),
            });
        }
        if let Some(v) = collisions
            .collisions
            .iter()
            .flat_map(|c| c.vertices)
            .find(|&v| {
                !x[3 * v as usize..3 * v as usize + 3]
                    .iter()
                    .all(|c| c.is_finite())
            })
        {
            return Err(ContactError::NonFinite(v as usize));
        }
        Ok(())
    }

    /// An error for the first collision at distance 0 (infinite barrier), if any.
    fn touching(&self, collisions: &Collisions, x: &[f64]) -> Result<(), ContactError> {
        if let Some((c, d)) = collisions
            .collisions
            .iter()
            .map(|c| (c, c.distance_squared_at(x)))
            .find(|(_, d)| !(*d > 0.0))
        {
            return Err(ContactError::Touching {
                kind: c.kind,
                vertices: c.vertices,
                distance_squared: d,
            });
        }
        Ok(())
    }

    /// `B(x) = κ·Σ m·b(d², d̂ₚ²)` (`d̂ₚ` each pair's activation distance, d̂ but for close
    /// pairs); `+∞` if a pair touches (`d = 0`).
    pub fn value(&self, collisions: &Collisions, x: &[f64]) -> Result<f64, ContactError> {
        self.check(collisions, x)?;
        let terms: Vec<f64> = collisions
            .collisions
            .par_iter()
            .map(|c| local::value(c, &stencil(x, c.vertices)))
            .collect();
        Ok(self.stiffness * terms.iter().sum::<f64>())
    }

    /// `out += ∇B(x)` (interleaved, `out.len() ≥ 3·(max vertex + 1)`). Fails on a touching pair.
    pub fn add_gradient(
        &self,
        collisions: &Collisions,
        x: &[f64],
        out: &mut [f64],
    ) -> Result<(), ContactError> {
        self.check(collisions, x)?;
        self.touching(collisions, x)?;
        if out.len() != x.len() {
            return Err(ContactError::PositionsLength {
                expected: x.len(),
                got: out.len(),
            });
        }
        let locals: Vec<_> = collisions
            .collisions
            .par_iter()
            .map(|c| local::gradient(c, &stencil(x, c.vertices)))
            .collect();
        for (c, g) in collisions.collisions.iter().zip(&locals) {
            for (i, &v) in c.vertices.iter().enumerate() {
                for k in 0..3 {
                    out[3 * v as usize + k] += self.stiffness * g[3 * i + k];
                }
            }
        }
        Ok(())
    }

    /// `∇B(x)`, interleaved, the length of `x`.
    pub fn gradient(&self, collisions: &Collisions, x: &[f64]) -> Result<Vec<f64>, ContactError> {
        let mut g = vec![0.0; x.len()];
        self.add_gradient(collisions, x, &mut g)?;
        Ok(g)
    }

    /// `∇²B(x)` as one 12×12 block per collision (in the set's order), each optionally
    /// projected to PSD. The global Hessian is `Σ Pᵢᵀ Hᵢ Pᵢ` with `Pᵢ` the stencil's scatter.
    pub fn hessian(
        &self,
        collisions: &Collisions,
        x: &[f64],
        projection: Projection,
    ) -> Result<Vec<HessianBlock>, ContactError> {
        self.stencil_hessians(collisions, x, |vertices, h| HessianBlock {
            vertices,
            matrix: match projection {
                Projection::None => h,
                Projection::ClampEigenvalues => psd::project_to_psd(&h),
            },
        })
    }

    /// `each(stencil, κ·∇²bᵢ)` for every collision (in the set's order), after checking the
    /// positions and that no pair touches.
    fn stencil_hessians<T: Send>(
        &self,
        collisions: &Collisions,
        x: &[f64],
        each: impl Fn([u32; 4], Matrix12) -> T + Sync,
    ) -> Result<Vec<T>, ContactError> {
        self.check(collisions, x)?;
        self.touching(collisions, x)?;
        let kappa = self.stiffness;
        Ok(collisions
            .collisions
            .par_iter()
            .map(|c: &Collision| {
                each(
                    c.vertices,
                    kappa * local::hessian(c, &stencil(x, c.vertices)),
                )
            })
            .collect())
    }
}

/// One stencil's PSD-projected Hessian in factored form, `Σ gₖgₖᵀ` ([`psd::positive_part_factors`]).
#[derive(Clone, Debug, PartialEq)]
pub struct HessianFactors {
    pub vertices: [u32; 4],
    pub factors: Vec<Vector12>,
}

impl BarrierPotential {
    /// The PSD-projected Hessian of [`BarrierPotential::hessian`], each stencil as the
    /// factors of its positive part (κ included) with eigenvalues above `keep·λ_max`
    /// ([`psd::positive_part_factors`]), for low-rank updates.
    pub fn hessian_factors(
        &self,
        collisions: &Collisions,
        x: &[f64],
        keep: f64,
    ) -> Result<Vec<HessianFactors>, ContactError> {
        self.stencil_hessians(collisions, x, |vertices, h| HessianFactors {
            vertices,
            factors: psd::positive_part_factors(&h, keep),
        })
    }
}

#[cfg(test)]
mod tests;
