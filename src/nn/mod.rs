//! A small CPU neural-network kit for the paper's networks: the per-identity mapping network φ
//! (SIREN, trained with an elastic regularizer on ∂φ/∂x), the actuation network N_A (SIREN
//! positional layer, then GeLU layers with Lipschitz weight normalization, modulated by a
//! code), the jaw network N_B and the code encoders (small MLPs).
//!
//! Data flows `x (N × in) [+ codes] → Mlp::forward → Tape (outputs, Jacobian) → loss
//! gradients → Mlp::backward → ∂L/∂θ (+ ∂L/∂x, ∂L/∂z) → Adam::step`.
//!
//! - [`MlpSpec`]/[`LayerSpec`] describe a network; [`Mlp`] holds its flat parameter vector,
//!   initialized deterministically from a seed (SIREN or PyTorch-default init).
//! - [`Mlp::forward`] evaluates a batch as dense products (faer) with fused bias+activation
//!   kernels; [`Pass::Jacobian`] also propagates one forward-mode tangent per input dimension
//!   to get ∂y/∂x at every point.
//! - [`Mlp::backward`] is hand-written reverse mode through the primal and tangent
//!   computation, so losses on both the outputs and the Jacobian get exact parameter, input
//!   and code gradients. All of it is checked against central differences in the tests.
//! - [`Mlp::gradient_chunked`] ([`ChunkedGradient`]) is the data-parallel way to train on
//!   large batches: fixed-size chunks, per-lane accumulation, thread-count-independent bits,
//!   bounded memory. Prefer it to `Par::rayon` on a whole-batch tape, whose fine-grained
//!   fork/join scales poorly on a busy machine.
//! - [`Mlp::cache_points`] ([`PointCache`]) precomputes the code-independent layers for a
//!   fixed point set, so a new code (a slider change) costs only the remaining layers.
//! - [`lipschitz`]: Liu et al. 2022 normalization and the λ Π softplus(cᵢ) loss.
//! - [`Adam`], [`LrSchedule`], and [`Checkpoint`] (versioned, bit-exact parameter files).
//!
//! Scalars are `f32` or `f64` ([`Real`]). Results are deterministic: same seed, same inputs,
//! same thread count → same bits (element-wise kernels are partition independent and
//! reductions have a fixed order).
//!
//! ```
//! use facesim::nn::{CodeBatch, LayerSpec, Mlp, MlpSpec, Pass, Tape};
//! use faer::{Mat, Par};
//!
//! // N_A-like: position (3) → SIREN 32 → 2 GeLU 32 with Lipschitz and an 8-d code → 6.
//! let spec = MlpSpec::new(3)
//!     .with_code_dim(8)
//!     .layer(LayerSpec::siren_first(32, 5.0))
//!     .layer(LayerSpec::gelu(32).lipschitz().with_code())
//!     .layer(LayerSpec::gelu(32).lipschitz().with_code())
//!     .layer(LayerSpec::linear(6));
//! let net = Mlp::<f64>::new(spec, 42)?;
//! let x = Mat::from_fn(100, 3, |i, j| (i * 3 + j) as f64 * 0.01);
//! let code = CodeBatch::shared(&[0.1; 8]);
//! let mut tape = Tape::new();
//! net.forward(x.as_ref(), Some(&code), Pass::Gradient, &mut tape, Par::Seq)?;
//! let y = tape.output().unwrap().to_owned(); // 100 × 6
//! // L = ½‖y‖²: ∂L/∂y = y.
//! let mut grad = vec![0.0; net.num_params()];
//! net.backward(&mut tape, Some(y.as_ref()), None, &mut grad, Par::Seq)?;
//! net.lipschitz_loss(1e-6, Some(&mut grad))?;
//! # Ok::<(), facesim::nn::NnError>(())
//! ```

pub mod activation;
pub mod adam;
pub mod bench;
pub mod code;
pub mod error;
pub mod layer;
pub mod lipschitz;
mod matrix;
pub mod mlp;
pub mod params;
pub mod real;
pub mod schedule;
pub mod tape;

#[cfg(test)]
mod gradcheck;

pub use activation::Activation;
pub use adam::{Adam, AdamConfig};
pub use code::CodeBatch;
pub use error::NnError;
pub use layer::{Init, LayerSpec, MlpSpec};
pub use mlp::{ChunkedGradient, Mlp, PointCache};
pub use params::Checkpoint;
pub use real::Real;
pub use schedule::LrSchedule;
pub use tape::{Pass, Tape};
