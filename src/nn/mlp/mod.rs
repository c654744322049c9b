//! The multilayer perceptron: batched forward pass (values, optionally forward-mode tangents
//! for the spatial Jacobian) and the hand-written backward pass through both.
//!
//! Per layer l, with input a (N × in, points as rows), code z_g on the run of points g,
//! effective weight W̃ = [W̃_h W̃_z] (Lipschitz-normalized when enabled):
//!
//!   z = a W̃_hᵀ + 1 (b + W̃_z z_g)ᵀ,   h = σ(z)
//!
//! and with the `Jacobian` pass, for each input dimension k (tangent seeds ȧ₀ = e_k):
//!
//!   ż_k = ȧ_k W̃_hᵀ,   ḣ_k = σ′(z) ⊙ ż_k           (so ḣ_k of the last layer = ∂y/∂x_k)
//!
//! Backward (reverse mode through the primal and the tangent computation — the "double
//! backward" a loss on ∂y/∂x needs), with adjoints h̄ = ∂L/∂h and ḣ̄_k = ∂L/∂ḣ_k:
//!
//!   ż̄_k = σ′(z) ⊙ ḣ̄_k,         z̄ = σ′(z) ⊙ h̄ + σ″(z) ⊙ Σ_k ż_k ⊙ ḣ̄_k,
//!   ∂L/∂W̃_h = z̄ᵀ a + Σ_k ż̄_kᵀ ȧ_k,   ∂L/∂b = Σ_n z̄_n,   ∂L/∂W̃_z = Σ_g (Σ_{n∈g} z̄_n) z_gᵀ,
//!   ā = z̄ W̃_h,   ǡ_k = ż̄_k W̃_h,   ∂L/∂z_g = W̃_zᵀ Σ_{n∈g} z̄_n,
//!
//! then ∂L/∂W̃ → (∂L/∂W, ∂L/∂c) through the normalization ([`crate::nn::lipschitz`]).
//! At the input, ā₀ = ∂L/∂x (through both paths when a Jacobian loss is given).

use faer::{Mat, MatRef, Par};

mod backward;
mod chunked;
mod forward;
mod infer;

pub use chunked::ChunkedGradient;
pub use infer::PointCache;

use super::code::CodeBatch;
use super::error::NnError;
use super::layer::{LayerLayout, MlpSpec};
use super::lipschitz::{lipschitz_loss, softplus};
use super::real::Real;
use super::tape::{LayerTape, Pass, Tape};

/// A multilayer perceptron with its parameters in one flat vector (layout in
/// [`crate::nn::layer`]), generic over `f32`/`f64`.
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp<T> {
    spec: MlpSpec,
    layout: Vec<LayerLayout>,
    params: Vec<T>,
}

impl<T: Real> Mlp<T> {
    /// A network with parameters initialized deterministically from `seed`
    /// ([`MlpSpec::init_params`]).
    pub fn new(spec: MlpSpec, seed: u64) -> Result<Self, NnError> {
        let params = spec.init_params(seed)?;
        Ok(Mlp {
            layout: spec.layout(),
            spec,
            params,
        })
    }

    /// A network with the given parameters (checked for count and finiteness).
    pub fn from_params(spec: MlpSpec, params: Vec<T>) -> Result<Self, NnError> {
        spec.validate()?;
        let expected = spec.num_params();
        if params.len() != expected {
            return Err(NnError::ParamCount {
                expected,
                found: params.len(),
            });
        }
        if let Some(i) = params.iter().position(|p| !p.is_finite()) {
            return Err(NnError::NonFiniteParam(i));
        }
        Ok(Mlp {
            layout: spec.layout(),
            spec,
            params,
        })
    }

    /// The same network in another scalar type.
    pub fn cast<U: Real>(&self) -> Mlp<U> {
        Mlp {
            spec: self.spec.clone(),
            layout: self.layout.clone(),
            params: self.params.iter().map(|p| U::of(p.to_f64())).collect(),
        }
    }

    pub fn spec(&self) -> &MlpSpec {
        &self.spec
    }

    pub fn params(&self) -> &[T] {
        &self.params
    }

    /// Mutable parameters (for the optimizer). Do not change them between a forward pass and
    /// its backward pass.
    pub fn params_mut(&mut self) -> &mut [T] {
        &mut self.params
    }

    pub fn num_params(&self) -> usize {
        self.params.len()
    }

    pub fn input_dim(&self) -> usize {
        self.spec.input_dim
    }

    pub fn output_dim(&self) -> usize {
        self.spec.output_dim()
    }

    pub fn code_dim(&self) -> usize {
        self.spec.code_dim
    }

    /// Offsets of the Lipschitz bound parameters cᵢ in the parameter vector, in layer order.
    pub fn lipschitz_param_indices(&self) -> Vec<usize> {
        self.layout.iter().filter_map(|l| l.c).collect()
    }

    /// The current per-layer Lipschitz bounds softplus(cᵢ).
    pub fn lipschitz_bounds(&self) -> Vec<T> {
        self.lipschitz_param_indices()
            .into_iter()
            .map(|i| softplus(self.params[i]))
            .collect()
    }

    /// L_lip = λ Πᵢ softplus(cᵢ) over this network's Lipschitz layers (1·λ if it has none);
    /// when `grad` is given, **adds** ∂L_lip/∂θ into it.
    pub fn lipschitz_loss(&self, lambda: T, grad: Option<&mut [T]>) -> Result<T, NnError> {
        let idx = self.lipschitz_param_indices();
        let cs: Vec<T> = idx.iter().map(|&i| self.params[i]).collect();
        match grad {
            None => Ok(lipschitz_loss(&cs, lambda, None)),
            Some(grad) => {
                self.check_grad_len(grad)?;
                let mut g = vec![T::ZERO; cs.len()];
                let loss = lipschitz_loss(&cs, lambda, Some(&mut g));
                for (&i, gi) in idx.iter().zip(g) {
                    grad[i] += gi;
                }
                Ok(loss)
            }
        }
    }

    /// Convenience inference on a fresh tape, sequentially: y = f(x) (N × out).
    pub fn eval(&self, x: MatRef<'_, T>, codes: Option<&CodeBatch<T>>) -> Result<Mat<T>, NnError> {
        let mut tape = Tape::new();
        self.forward(x, codes, Pass::Value, &mut tape, Par::Seq)?;
        Ok(tape.output().map_or_else(
            || Mat::zeros(x.nrows(), self.output_dim()),
            |y| y.to_owned(),
        ))
    }

    fn check_grad_len(&self, grad: &[T]) -> Result<(), NnError> {
        if grad.len() != self.params.len() {
            return Err(NnError::ParamCount {
                expected: self.params.len(),
                found: grad.len(),
            });
        }
        Ok(())
    }

    /// The effective weight W̃ (out × fan_in) of layer `l`: the raw parameters, or the
    /// normalized copy the forward pass left on the tape.
    fn weight<'a>(&'a self, l: usize, lt: &'a LayerTape<T>) -> MatRef<'a, T> {
        let lay = &self.layout[l];
        if lay.c.is_some() {
            lt.w_eff.view()
        } else {
            MatRef::from_column_major_slice(&self.params[lay.w..lay.b], lay.out_dim, lay.fan_in())
        }
    }
}
