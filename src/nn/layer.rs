//! Layer and network architecture descriptions, the flat parameter layout, and the
//! deterministic initialization.
//!
//! A layer maps its input `a` (the previous layer's output, or the network input), optionally
//! concatenated with the network's code `z`, through an affine map and an activation:
//!
//!   h = σ(W̃ [a; z] + b),   W̃ = W, or its Lipschitz normalization (see [`super::lipschitz`]).
//!
//! Parameters of layer l live in one flat vector, in this order: W (out × (in + code),
//! column-major, the code columns last), b (out), and c (one value, Lipschitz layers only).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::activation::Activation;
use super::error::NnError;
use super::lipschitz::softplus_inverse;
use super::real::Real;

/// How a layer's weights are drawn. Biases are always U(−1/√fan_in, 1/√fan_in) (the PyTorch
/// `nn.Linear` default, which the SIREN reference code keeps).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Init {
    /// W ~ U(−1/√fan_in, 1/√fan_in) (PyTorch `nn.Linear` default).
    Uniform,
    /// First SIREN layer: W ~ U(−1/fan_in, 1/fan_in) (Sitzmann et al. 2020, Sec. 3.2).
    SirenFirst,
    /// Later SIREN layers (and the linear layer after them):
    /// W ~ U(−√(6/fan_in)/ω₀, √(6/fan_in)/ω₀).
    SirenHidden { omega0: f64 },
}

impl Init {
    /// The half-width of the uniform weight distribution for a fan-in.
    pub fn weight_bound(self, fan_in: usize) -> f64 {
        let n = fan_in as f64;
        match self {
            Init::Uniform => 1.0 / n.sqrt(),
            Init::SirenFirst => 1.0 / n,
            Init::SirenHidden { omega0 } => (6.0 / n).sqrt() / omega0,
        }
    }
}

/// One layer of an [`MlpSpec`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayerSpec {
    /// Output width.
    pub width: usize,
    pub activation: Activation,
    pub init: Init,
    /// Lipschitz weight normalization with a trainable bound c.
    pub lipschitz: bool,
    /// Concatenate the network code z to this layer's input (modulation).
    pub takes_code: bool,
}

impl LayerSpec {
    /// A layer with the given activation, `Init::Uniform`, no normalization, no code.
    pub fn new(width: usize, activation: Activation) -> Self {
        LayerSpec {
            width,
            activation,
            init: Init::Uniform,
            lipschitz: false,
            takes_code: false,
        }
    }

    /// First SIREN layer: sin(ω₀(Wx + b)) with `Init::SirenFirst`.
    pub fn siren_first(width: usize, omega0: f64) -> Self {
        LayerSpec::new(width, Activation::Sine { omega0 }).with_init(Init::SirenFirst)
    }

    /// Hidden SIREN layer: sin(ω₀(Wx + b)) with `Init::SirenHidden`.
    pub fn siren(width: usize, omega0: f64) -> Self {
        LayerSpec::new(width, Activation::Sine { omega0 }).with_init(Init::SirenHidden { omega0 })
    }

    /// GeLU layer (tanh form), `Init::Uniform`.
    pub fn gelu(width: usize) -> Self {
        LayerSpec::new(width, Activation::Gelu)
    }

    /// tanh layer, `Init::Uniform`.
    pub fn tanh(width: usize) -> Self {
        LayerSpec::new(width, Activation::Tanh)
    }

    /// Affine layer (identity activation), `Init::Uniform`.
    pub fn linear(width: usize) -> Self {
        LayerSpec::new(width, Activation::Identity)
    }

    pub fn with_init(mut self, init: Init) -> Self {
        self.init = init;
        self
    }

    /// Adds Lipschitz weight normalization with a trainable bound.
    pub fn lipschitz(mut self) -> Self {
        self.lipschitz = true;
        self
    }

    /// Concatenates the network code to this layer's input.
    pub fn with_code(mut self) -> Self {
        self.takes_code = true;
        self
    }
}

/// A multilayer perceptron: input dimension, optional code dimension, and layers in order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MlpSpec {
    pub input_dim: usize,
    /// Dimension of the code z concatenated to the layers with `takes_code` (0: none).
    pub code_dim: usize,
    pub layers: Vec<LayerSpec>,
}

impl MlpSpec {
    /// An empty network on `input_dim` inputs; add layers with [`MlpSpec::layer`].
    pub fn new(input_dim: usize) -> Self {
        MlpSpec {
            input_dim,
            code_dim: 0,
            layers: Vec::new(),
        }
    }

    /// Sets the code dimension.
    pub fn with_code_dim(mut self, code_dim: usize) -> Self {
        self.code_dim = code_dim;
        self
    }

    /// Appends a layer.
    pub fn layer(mut self, layer: LayerSpec) -> Self {
        self.layers.push(layer);
        self
    }

    /// A SIREN (the mapping network φ's shape): `hidden_layers` sine layers of `width`
    /// (the first with `SirenFirst` init) and a final linear layer with `SirenHidden` init.
    pub fn siren(
        input_dim: usize,
        width: usize,
        hidden_layers: usize,
        omega0: f64,
        output_dim: usize,
    ) -> Self {
        let mut spec = MlpSpec::new(input_dim);
        for l in 0..hidden_layers {
            spec = spec.layer(if l == 0 {
                LayerSpec::siren_first(width, omega0)
            } else {
                LayerSpec::siren(width, omega0)
            });
        }
        spec.layer(LayerSpec::linear(output_dim).with_init(Init::SirenHidden { omega0 }))
    }

    /// Output dimension (the last layer's width; the input dimension if there are no layers).
    pub fn output_dim(&self) -> usize {
        self.layers.last().map_or(self.input_dim, |l| l.width)
    }

    /// Checks the architecture is well formed.
    pub fn validate(&self) -> Result<(), NnError> {
        let bad = |msg: String| Err(NnError::InvalidSpec(msg));
        if self.input_dim == 0 {
            return bad("input dimension is 0".into());
        }
        if self.layers.is_empty() {
            return bad("no layers".into());
        }
        for (l, layer) in self.layers.iter().enumerate() {
            if layer.width == 0 {
                return bad(format!("layer {l} has width 0"));
            }
            layer
                .activation
                .validate()
                .or_else(|m| bad(format!("layer {l}: {m}")))?;
            if let Init::SirenHidden { omega0 } = layer.init
                && !(omega0.is_finite() && omega0 > 0.0)
            {
                return bad(format!("layer {l}: init ω0 must be finite and positive"));
            }
            if layer.takes_code && self.code_dim == 0 {
                return bad(format!("layer {l} takes a code but code_dim is 0"));
            }
        }
        if self.code_dim > 0 && !self.layers.iter().any(|l| l.takes_code) {
            return bad("code_dim > 0 but no layer takes the code".into());
        }
        Ok(())
    }

    /// The parameter layout (offsets into the flat vector) of every layer.
    pub(crate) fn layout(&self) -> Vec<LayerLayout> {
        let mut offset = 0;
        let mut in_dim = self.input_dim;
        self.layers
            .iter()
            .map(|l| {
                let code = if l.takes_code { self.code_dim } else { 0 };
                let fan_in = in_dim + code;
                let lay = LayerLayout {
                    in_dim,
                    code_dim: code,
                    out_dim: l.width,
                    w: offset,
                    b: offset + l.width * fan_in,
                    c: l.lipschitz.then_some(offset + l.width * fan_in + l.width),
                };
                offset += l.width * fan_in + l.width + usize::from(l.lipschitz);
                in_dim = l.width;
                lay
            })
            .collect()
    }

    /// Total number of scalar parameters.
    pub fn num_params(&self) -> usize {
        self.layout().last().map_or(0, |l| l.end())
    }

    /// Initial parameters drawn from ChaCha8 seeded with `seed`: per layer in order, W in its
    /// storage order, then b (see [`Init`]); c = softplus⁻¹(maxᵢ Σⱼ|Wᵢⱼ|) so that the
    /// normalization starts inactive (Liu et al. initialize c to the largest row sum).
    /// Drawn in f64 and rounded, so f32 and f64 networks from one seed agree.
    pub fn init_params<T: Real>(&self, seed: u64) -> Result<Vec<T>, NnError> {
        self.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut params = vec![0.0f64; self.num_params()];
        for (spec, lay) in self.layers.iter().zip(self.layout()) {
            let fan_in = lay.fan_in();
            let wb = spec.init.weight_bound(fan_in);
            for p in &mut params[lay.w..lay.b] {
                *p = wb * (2.0 * rng.random::<f64>() - 1.0);
            }
            let bb = 1.0 / (fan_in as f64).sqrt();
            for p in &mut params[lay.b..lay.b + lay.out_dim] {
                *p = bb * (2.0 * rng.random::<f64>() - 1.0);
            }
            if let Some(c) = lay.c {
                let w = &params[lay.w..lay.b];
                let mut max_row = 0.0f64;
                for i in 0..lay.out_dim {
                    let r: f64 = (0..fan_in).map(|j| w[j * lay.out_dim + i].abs()).sum();
                    max_row = max_row.max(r);
                }
                params[c] = softplus_inverse(max_row.max(1e-6));
            }
        }
        Ok(params.into_iter().map(T::of).collect())
    }
}

/// Where one layer's parameters are in the flat vector, and its shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct LayerLayout {
    /// Width of the previous layer's output (or the network input).
    pub in_dim: usize,
    /// Code columns of W (0 when the layer takes no code).
    pub code_dim: usize,
    pub out_dim: usize,
    /// Offset of W (out × (in + code), column-major).
    pub w: usize,
    /// Offset of b (out).
    pub b: usize,
    /// Offset of c (Lipschitz layers).
    pub c: Option<usize>,
}

impl LayerLayout {
    pub fn fan_in(&self) -> usize {
        self.in_dim + self.code_dim
    }

    /// One past the layer's last parameter.
    pub fn end(&self) -> usize {
        self.b + self.out_dim + usize::from(self.c.is_some())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_is_contiguous_and_counts_match() {
        let spec = MlpSpec::new(3)
            .with_code_dim(4)
            .layer(LayerSpec::siren_first(8, 5.0))
            .layer(LayerSpec::gelu(7).lipschitz().with_code())
            .layer(LayerSpec::linear(2));
        spec.validate().unwrap();
        let lay = spec.layout();
        assert_eq!(lay[0].w, 0);
        assert_eq!(lay[1].w, lay[0].end());
        assert_eq!(lay[1].fan_in(), 8 + 4);
        assert_eq!(lay[1].c, Some(lay[1].b + 7));
        assert_eq!(
            spec.num_params(),
            (8 * 3 + 8) + (7 * 12 + 7 + 1) + (2 * 7 + 2)
        );
    }

    #[test]
    fn invalid_specs_are_rejected() {
        assert!(MlpSpec::new(3).validate().is_err());
        assert!(
            MlpSpec::new(0)
                .layer(LayerSpec::linear(1))
                .validate()
                .is_err()
        );
        assert!(
            MlpSpec::new(3)
                .layer(LayerSpec::linear(0))
                .validate()
                .is_err()
        );
        assert!(
            MlpSpec::new(3)
                .layer(LayerSpec::siren(4, -1.0))
                .validate()
                .is_err()
        );
        assert!(
            MlpSpec::new(3)
                .layer(LayerSpec::linear(2).with_code())
                .validate()
                .is_err()
        );
        assert!(
            MlpSpec::new(3)
                .with_code_dim(2)
                .layer(LayerSpec::linear(2))
                .validate()
                .is_err()
        );
    }

    /// Weight bounds, mean and variance of the SIREN initialization (U(−a, a) has variance
    /// a²/3), and the deterministic stream.
    #[test]
    fn siren_init_statistics() {
        let (n_in, width, omega0) = (256usize, 256usize, 30.0);
        let spec = MlpSpec::new(n_in)
            .layer(LayerSpec::siren_first(width, omega0))
            .layer(LayerSpec::siren(width, omega0));
        let p: Vec<f64> = spec.init_params(11).unwrap();
        let lay = spec.layout();
        for (l, init) in [(0, Init::SirenFirst), (1, Init::SirenHidden { omega0 })] {
            let a = init.weight_bound(n_in);
            let w = &p[lay[l].w..lay[l].b];
            assert!(w.iter().all(|v| v.abs() <= a));
            let n = w.len() as f64;
            let mean = w.iter().sum::<f64>() / n;
            let var = w.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
            // n = 65536 samples: the mean's std is a/√(3n) ≈ 0.0023a, the variance's ≈ 0.3%.
            assert!(mean.abs() < 0.01 * a, "layer {l}: mean {mean}");
            assert!(
                (var / (a * a / 3.0) - 1.0).abs() < 0.02,
                "layer {l}: var {var}"
            );
        }
        assert_eq!(Init::SirenFirst.weight_bound(4), 0.25);
        assert!((Init::SirenHidden { omega0: 5.0 }.weight_bound(6) - 0.2).abs() < 1e-15);
        let q: Vec<f64> = spec.init_params(11).unwrap();
        assert!(p.iter().zip(&q).all(|(a, b)| a.to_bits() == b.to_bits()));
        let r: Vec<f64> = spec.init_params(12).unwrap();
        assert!(p != r);
    }

    #[test]
    fn lipschitz_bound_starts_at_the_largest_row_sum() {
        let spec = MlpSpec::new(5).layer(LayerSpec::gelu(4).lipschitz());
        let p: Vec<f64> = spec.init_params(3).unwrap();
        let lay = spec.layout()[0];
        let max_row = (0..4)
            .map(|i| (0..5).map(|j| p[lay.w + j * 4 + i].abs()).sum::<f64>())
            .fold(0.0, f64::max);
        let s = super::super::lipschitz::softplus(p[lay.c.unwrap()]);
        assert!((s - max_row).abs() < 1e-12);
    }
}
