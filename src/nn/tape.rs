//! The workspace of a batched forward/backward pass: what the forward pass records for the
//! backward pass, and the backward pass's results. Reuse one tape across iterations: its
//! buffers only grow, so a training loop does not allocate once shapes are stable.
//!
//! Memory per point (scalars), for layer widths wₗ and d tangents (Jacobian pass):
//! `Value` only the output (it runs in cache-sized chunks); `Gradient` 2 Σ wₗ;
//! `Jacobian` (3 + 2d) Σ wₗ. Split large batches into
//! chunks and accumulate: [`super::Mlp::backward`] adds into the parameter gradient.

use faer::MatRef;
use serde::{Deserialize, Serialize};

use super::matrix::Buf;
use super::real::Real;

/// What a forward pass computes and records.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Pass {
    /// Outputs only (inference).
    Value,
    /// Outputs, plus σ′ per layer for a backward pass of a loss on the outputs.
    Gradient,
    /// Outputs and the spatial Jacobian ∂y/∂x by forward-mode tangents (one per input
    /// dimension), plus σ′, σ″ and the tangents for a backward pass of a loss on both.
    Jacobian,
}

impl Pass {
    pub(crate) fn tangents(self) -> bool {
        matches!(self, Pass::Jacobian)
    }
}

/// Per-layer records.
#[derive(Clone, Debug, Default)]
pub(crate) struct LayerTape<T> {
    /// Output h = σ(z) (N × out).
    pub h: Buf<T>,
    /// σ′(z) (N × out); `Gradient` and `Jacobian` passes.
    pub d1: Buf<T>,
    /// σ″(z) (N × out); `Jacobian` pass.
    pub d2: Buf<T>,
    /// Pre-activation tangents ż = ȧ W̃_hᵀ (dN × out, tangent k in rows kN..(k+1)N).
    pub zt: Buf<T>,
    /// Output tangents ḣ = σ′(z) ⊙ ż (dN × out).
    pub ht: Buf<T>,
    /// Effective (Lipschitz-normalized) weight W̃ (out × fan_in); Lipschitz layers only.
    pub w_eff: Buf<T>,
    /// Absolute row sums of the raw W; Lipschitz layers only.
    pub row_sums: Vec<T>,
    /// Bias per code run, b + W̃_z z_g (G × out, row-major).
    pub bias: Vec<T>,
}

/// Per-task buffers of the chunked `Value` pass: activations of the current chunk (ping-pong)
/// and the outputs of the task's chunks, in chunk order.
#[derive(Clone, Debug, Default)]
pub(crate) struct ChunkScratch<T> {
    pub cur: Buf<T>,
    pub next: Buf<T>,
    pub out: Vec<T>,
}

/// Forward records and backward results of one batch. See the module docs.
#[derive(Clone, Debug)]
pub struct Tape<T> {
    pub(crate) pass: Option<Pass>,
    pub(crate) n: usize,
    /// Number of tangents d (the input dimension) in a `Jacobian` pass, else 0.
    pub(crate) d: usize,
    /// The network input (N × in).
    pub(crate) x: Buf<T>,
    /// Tangent seeds: the identity, tangent k = e_k at every point (dN × in).
    pub(crate) xt: Buf<T>,
    /// Codes (G × code_dim, row-major) and their point ranges.
    pub(crate) codes: Vec<T>,
    pub(crate) code_dim: usize,
    pub(crate) ranges: Vec<std::ops::Range<usize>>,
    pub(crate) layers: Vec<LayerTape<T>>,
    // Backward scratch and results.
    pub(crate) gh: Buf<T>,
    pub(crate) gh2: Buf<T>,
    pub(crate) gt: Buf<T>,
    pub(crate) gt2: Buf<T>,
    pub(crate) gw: Buf<T>,
    pub(crate) scratch: Vec<ChunkScratch<T>>,
    pub(crate) seg_sums: Vec<T>,
    pub(crate) input_grad: Buf<T>,
    pub(crate) code_grad: Vec<T>,
    pub(crate) has_backward: bool,
}

impl<T: Real> Default for Tape<T> {
    fn default() -> Self {
        Tape::new()
    }
}

impl<T: Real> Tape<T> {
    pub fn new() -> Self {
        Tape {
            pass: None,
            n: 0,
            d: 0,
            x: Buf::default(),
            xt: Buf::default(),
            codes: Vec::new(),
            code_dim: 0,
            ranges: Vec::new(),
            layers: Vec::new(),
            gh: Buf::default(),
            gh2: Buf::default(),
            gt: Buf::default(),
            gt2: Buf::default(),
            gw: Buf::default(),
            scratch: Vec::new(),
            seg_sums: Vec::new(),
            input_grad: Buf::default(),
            code_grad: Vec::new(),
            has_backward: false,
        }
    }

    /// The kind of the last forward pass, if any.
    pub fn pass(&self) -> Option<Pass> {
        self.pass
    }

    /// Number of points N in the last forward pass.
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// The outputs y (N × out) of the last forward pass.
    pub fn output(&self) -> Option<MatRef<'_, T>> {
        self.pass?;
        self.layers.last().map(|l| l.h.view())
    }

    /// The Jacobian of the last `Jacobian` pass, stacked by input dimension: a (d·N × out)
    /// matrix whose row k·N + n, column i is ∂yᵢ/∂x_k at point n.
    pub fn jacobian(&self) -> Option<MatRef<'_, T>> {
        if self.pass != Some(Pass::Jacobian) {
            return None;
        }
        self.layers.last().map(|l| l.ht.view())
    }

    /// ∂y/∂x_k at every point (N × out), from the last `Jacobian` pass.
    pub fn jacobian_column(&self, k: usize) -> Option<MatRef<'_, T>> {
        let j = self.jacobian()?;
        (k < self.d).then(|| j.subrows(k * self.n, self.n))
    }

    /// The Jacobian at point `n` as an (out × d) row-major array: entry (i, k) = ∂yᵢ/∂x_k.
    pub fn jacobian_at(&self, n: usize) -> Option<Vec<T>> {
        let j = self.jacobian()?;
        if n >= self.n {
            return None;
        }
        let out = j.ncols();
        let mut m = vec![T::ZERO; out * self.d];
        for i in 0..out {
            for k in 0..self.d {
                m[i * self.d + k] = j[(k * self.n + n, i)];
            }
        }
        Some(m)
    }

    /// ∂L/∂x (N × in) from the last backward pass (through the outputs and, when a Jacobian
    /// loss was given, through the Jacobian).
    pub fn input_grad(&self) -> Option<MatRef<'_, T>> {
        self.has_backward.then(|| self.input_grad.view())
    }

    /// ∂L/∂z for each code of the batch (G × code_dim, row-major) from the last backward pass;
    /// `None` when the network takes no code.
    pub fn code_grad(&self) -> Option<&[T]> {
        (self.has_backward && self.code_dim > 0).then_some(self.code_grad.as_slice())
    }

    /// Bytes held by the tape's buffers.
    pub fn memory_bytes(&self) -> usize {
        let s = std::mem::size_of::<T>();
        let layers: usize = self
            .layers
            .iter()
            .map(|l| {
                l.h.bytes()
                    + l.d1.bytes()
                    + l.d2.bytes()
                    + l.zt.bytes()
                    + l.ht.bytes()
                    + l.w_eff.bytes()
                    + (l.row_sums.capacity() + l.bias.capacity()) * s
            })
            .sum();
        layers
            + [
                &self.x,
                &self.xt,
                &self.gh,
                &self.gh2,
                &self.gt,
                &self.gt2,
                &self.gw,
                &self.input_grad,
            ]
            .iter()
            .map(|b| b.bytes())
            .sum::<usize>()
            + self
                .scratch
                .iter()
                .map(|c| c.cur.bytes() + c.next.bytes() + c.out.capacity() * s)
                .sum::<usize>()
            + (self.codes.capacity() + self.seg_sums.capacity() + self.code_grad.capacity()) * s
    }
}
