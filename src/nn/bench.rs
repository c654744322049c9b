//! Micro-benchmarks of batched passes (`cargo run --release -p facesim --example nn_bench`).

use std::time::Instant;

use faer::{Mat, Par};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::code::CodeBatch;
use super::error::NnError;
use super::layer::{LayerSpec, MlpSpec};
use super::mlp::Mlp;
use super::real::Real;
use super::tape::{Pass, Tape};

/// An N_A-shaped network: 3 → SIREN(`width`, ω₀ = 5) → `gelu_layers` × GeLU(`width`,
/// Lipschitz, code concatenated) → linear 6, with a `code_dim`-d code.
pub fn actuation_like_spec(width: usize, gelu_layers: usize, code_dim: usize) -> MlpSpec {
    let mut spec = MlpSpec::new(3)
        .with_code_dim(code_dim)
        .layer(LayerSpec::siren_first(width, 5.0));
    for _ in 0..gelu_layers {
        spec = spec.layer(LayerSpec::gelu(width).lipschitz().with_code());
    }
    spec.layer(LayerSpec::linear(6))
}

/// Timing of repeated passes over one batch.
#[derive(Clone, Debug)]
pub struct Timing {
    pub points: usize,
    pub pass: Pass,
    /// Through a [`super::PointCache`] (the code-independent layers precomputed).
    pub cached: bool,
    pub threads: usize,
    pub dtype: &'static str,
    pub min_ms: f64,
    pub median_ms: f64,
    /// Including a backward pass (∂L/∂θ for a loss on the outputs, and on the Jacobian
    /// after a `Jacobian` pass).
    pub with_backward: bool,
}

/// Times `runs` forward passes (after one warm-up) of `net` on `points` random positions in
/// [−1, 1]³ with one shared random code (if the network has one), optionally followed by a
/// backward pass.
pub fn time_passes<T: Real>(
    net: &Mlp<T>,
    points: usize,
    pass: Pass,
    backward: bool,
    par: Par,
    runs: usize,
) -> Result<Timing, NnError> {
    let (x, codes) = inputs(net, points);
    let mut tape = Tape::new();
    let mut grad = vec![T::ZERO; net.num_params()];
    let dy = Mat::from_fn(points, net.output_dim(), |i, j| {
        T::of(((i + j) % 7) as f64 * 0.1)
    });
    let dj = Mat::from_fn(points * net.input_dim(), net.output_dim(), |i, j| {
        T::of(((i * 3 + j) % 5) as f64 * 0.1)
    });
    let mut times = Vec::with_capacity(runs);
    for r in 0..=runs {
        let t0 = Instant::now();
        net.forward(x.as_ref(), codes.as_ref(), pass, &mut tape, par)?;
        if backward {
            let dj = (pass == Pass::Jacobian).then(|| dj.as_ref());
            net.backward(&mut tape, Some(dy.as_ref()), dj, &mut grad, par)?;
        }
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        if r > 0 {
            times.push(ms);
        }
    }
    Ok(summary::<T>(points, pass, false, backward, par, times))
}

/// Times `runs` value passes through a [`super::PointCache`] of the same random points (the
/// cache is built once, outside the timing).
pub fn time_cached<T: Real>(
    net: &Mlp<T>,
    points: usize,
    par: Par,
    runs: usize,
) -> Result<Timing, NnError> {
    let (x, codes) = inputs(net, points);
    let cache = net.cache_points(x.as_ref(), par)?;
    let mut tape = Tape::new();
    let mut times = Vec::with_capacity(runs);
    for r in 0..=runs {
        let t0 = Instant::now();
        net.forward_cached(&cache, codes.as_ref(), &mut tape, par)?;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        if r > 0 {
            times.push(ms);
        }
    }
    Ok(summary::<T>(points, Pass::Value, true, false, par, times))
}

/// Times `runs` calls of [`Mlp::gradient_chunked`] (chunks of `chunk_rows`, 8 lanes) for a
/// linear loss on the outputs (and on the Jacobian after a `Jacobian` pass).
pub fn time_chunked<T: Real>(
    net: &Mlp<T>,
    points: usize,
    pass: Pass,
    chunk_rows: usize,
    par: Par,
    runs: usize,
) -> Result<Timing, NnError> {
    let (x, codes) = inputs(net, points);
    let mut ws = super::ChunkedGradient::new(chunk_rows, 8)?;
    let mut grad = vec![T::ZERO; net.num_params()];
    let loss = |_: std::ops::Range<usize>,
                _: &Tape<T>,
                mut dy: faer::MatMut<'_, T>,
                dj: Option<faer::MatMut<'_, T>>| {
        dy.fill(T::of(0.1));
        if let Some(mut dj) = dj {
            dj.fill(T::of(0.1));
        }
        T::ZERO
    };
    let mut times = Vec::with_capacity(runs);
    for r in 0..=runs {
        let t0 = Instant::now();
        net.gradient_chunked(
            x.as_ref(),
            codes.as_ref(),
            pass,
            &mut ws,
            &mut grad,
            par,
            loss,
        )?;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        if r > 0 {
            times.push(ms);
        }
    }
    Ok(summary::<T>(points, pass, false, true, par, times))
}

/// `points` random positions in [−1, 1]^in and one shared random tanh-bounded code.
fn inputs<T: Real>(net: &Mlp<T>, points: usize) -> (Mat<T>, Option<CodeBatch<T>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let x = Mat::from_fn(points, net.input_dim(), |_, _| {
        T::of(rng.random_range(-1.0..1.0))
    });
    let code: Vec<T> = (0..net.code_dim())
        .map(|_| T::of(rng.random_range(-1.0..1.0f64).tanh()))
        .collect();
    let codes = (net.code_dim() > 0).then(|| CodeBatch::shared(&code));
    (x, codes)
}

fn summary<T: Real>(
    points: usize,
    pass: Pass,
    cached: bool,
    with_backward: bool,
    par: Par,
    mut times: Vec<f64>,
) -> Timing {
    times.sort_by(f64::total_cmp);
    Timing {
        points,
        pass,
        cached,
        threads: super::matrix::n_tasks(par),
        dtype: T::NAME,
        min_ms: times.first().copied().unwrap_or(0.0),
        median_ms: times.get(times.len() / 2).copied().unwrap_or(0.0),
        with_backward,
    }
}
