//! Activation functions σ with their first and second derivatives, applied column by column
//! (one feature of every point) with the layer bias fused in: h = σ(z + b).
//!
//! | activation | σ(x) | σ′(x) | σ″(x) |
//! |---|---|---|---|
//! | `Identity` | x | 1 | 0 |
//! | `Sine { omega0: ω }` (SIREN) | sin(ωx) | ω cos(ωx) | −ω² sin(ωx) |
//! | `Tanh` | tanh x | 1 − tanh²x | −2 tanh x (1 − tanh²x) |
//! | `Gelu` (tanh form) | x·s(v) | s + x s′ v′ | s′ (2v′ + x((1 − 2s) v′² + v″)) |
//!
//! GeLU uses the tanh approximation (Hendrycks & Gimpel 2016; PyTorch `approximate="tanh"`):
//! ½x(1 + tanh(√(2/π)(x + 0.044715x³))) = x·s(v) with the logistic s(v) = 1/(1 + e^(−v)),
//! v = 2√(2/π)(x + 0.044715x³), s′ = s(1 − s), v′ = 2√(2/π)(1 + 3·0.044715x²),
//! v″ = 2√(2/π)·6·0.044715x. It differs from the erf form x·Φ(x) by at most ~5e-4 and is
//! used consistently (forward, tangents, both derivatives) so all gradients are exact for it.
//!
//! `Sine` and `Gelu` use the vectorizable kernels of [`Real`]; `Tanh` calls `std` (it is
//! meant for small layers such as code bounding).

use serde::{Deserialize, Serialize};

use super::real::Real;

/// The non-linearity of a layer.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Activation {
    /// σ(x) = x (a linear / affine layer).
    Identity,
    /// SIREN: σ(x) = sin(ω₀x) (Sitzmann et al. 2020).
    Sine { omega0: f64 },
    /// GeLU, tanh form (see the module docs).
    Gelu,
    /// σ(x) = tanh x.
    Tanh,
}

const GELU_A: f64 = 0.044715;
/// 2·√(2/π).
const GELU_K2: f64 = 2.0 * 0.797_884_560_802_865_4;

impl Activation {
    /// σ(x), σ′(x), σ″(x) at one point (the scalar reference the batched kernels follow).
    #[inline(always)]
    pub fn eval<T: Real>(self, x: T) -> (T, T, T) {
        match self {
            Activation::Identity => (x, T::ONE, T::ZERO),
            Activation::Sine { omega0 } => {
                let w = T::of(omega0);
                let (s, c) = if (w * x).abs() <= T::SIN_COS_LIMIT {
                    (w * x).sin_cos_fast()
                } else {
                    ((w * x).sin(), (w * x).cos())
                };
                (s, w * c, -(w * w) * s)
            }
            Activation::Gelu => gelu(x),
            Activation::Tanh => tanh_all(x),
        }
    }

    /// True when σ″ ≡ 0 (the tangent back-propagation can skip the σ″ term).
    pub fn is_linear(self) -> bool {
        matches!(self, Activation::Identity)
    }

    /// Checks parameters (ω₀ finite and positive).
    pub fn validate(self) -> Result<(), String> {
        match self {
            Activation::Sine { omega0 } if !(omega0.is_finite() && omega0 > 0.0) => Err(format!(
                "SIREN ω0 must be finite and positive, got {omega0}"
            )),
            _ => Ok(()),
        }
    }

    /// In place over one column: `col[i] ← σ(col[i] + bias)`, and when given,
    /// `d1[i] ← σ′(·)`, `d2[i] ← σ″(·)`. Runs with the CPU's widest SIMD (see [`ApplyKernel`]).
    pub(crate) fn apply<T: Real>(
        self,
        col: &mut [T],
        bias: T,
        d1: Option<&mut [T]>,
        d2: Option<&mut [T]>,
    ) {
        pulp::Arch::new().dispatch(ApplyKernel {
            act: self,
            col,
            bias,
            d1,
            d2,
        });
    }
}

/// `col[i] ← f(col[i]).0`, `d1[i] ← .1`, `d2[i] ← .2` (derivative slices optional), with
/// the element expression expanded in place (no closure call), so the loops vectorize.
macro_rules! map3 {
    ($col:expr, $d1:expr, $d2:expr, |$x:ident| $f:expr) => {
        match ($d1, $d2) {
            (None, None) => {
                for v in $col.iter_mut() {
                    let $x = *v;
                    *v = $f.0;
                }
            }
            (Some(d1), None) => {
                for (v, a) in $col.iter_mut().zip(d1.iter_mut()) {
                    let $x = *v;
                    let (h, g1, _) = $f;
                    *v = h;
                    *a = g1;
                }
            }
            (Some(d1), Some(d2)) => {
                for ((v, a), b) in $col.iter_mut().zip(d1.iter_mut()).zip(d2.iter_mut()) {
                    let $x = *v;
                    let (h, g1, g2) = $f;
                    *v = h;
                    *a = g1;
                    *b = g2;
                }
            }
            (None, Some(d2)) => {
                for (v, b) in $col.iter_mut().zip(d2.iter_mut()) {
                    let $x = *v;
                    let (h, _, g2) = $f;
                    *v = h;
                    *b = g2;
                }
            }
        }
    };
}

/// The column kernel of [`Activation::apply`], run through `pulp` so that its loops are
/// compiled for (and dispatched to) AVX2+FMA when the CPU has it; everything it calls is
/// `#[inline(always)]`, so the whole loop body is vectorized.
struct ApplyKernel<'a, T> {
    act: Activation,
    col: &'a mut [T],
    bias: T,
    d1: Option<&'a mut [T]>,
    d2: Option<&'a mut [T]>,
}

impl<T: Real> pulp::WithSimd for ApplyKernel<'_, T> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let ApplyKernel {
            act,
            col,
            bias,
            d1,
            d2,
        } = self;
        match act {
            Activation::Identity => {
                for v in col.iter_mut() {
                    *v += bias;
                }
                if let Some(d1) = d1 {
                    d1.fill(T::ONE);
                }
                if let Some(d2) = d2 {
                    d2.fill(T::ZERO);
                }
            }
            Activation::Sine { omega0 } => {
                let w = T::of(omega0);
                let ww = w * w;
                // The fast kernel is accurate for |ω(z + b)| ≤ SIN_COS_LIMIT; otherwise (or on
                // NaN) the whole column takes the std path.
                let mut out_of_range = 0u8;
                // `!(a <= b)` on purpose: NaN counts as out of range.
                #[allow(clippy::neg_cmp_op_on_partial_ord)]
                for &v in col.iter() {
                    out_of_range |= u8::from(!((w * (v + bias)).abs() <= T::SIN_COS_LIMIT));
                }
                if out_of_range != 0 {
                    map3!(col, d1, d2, |x| {
                        let y = w * (x + bias);
                        let s = y.sin();
                        (s, w * y.cos(), -ww * s)
                    });
                } else {
                    map3!(col, d1, d2, |x| {
                        let (s, c) = (w * (x + bias)).sin_cos_fast();
                        (s, w * c, -ww * s)
                    });
                }
            }
            Activation::Gelu => map3!(col, d1, d2, |x| gelu(x + bias)),
            Activation::Tanh => map3!(col, d1, d2, |x| tanh_all(x + bias)),
        }
    }
}

/// GeLU (tanh form) with both derivatives; see the module docs.
#[inline(always)]
fn gelu<T: Real>(x: T) -> (T, T, T) {
    let (a, k2) = (T::of(GELU_A), T::of(GELU_K2));
    let x2 = x * x;
    let v = x * (k2 + k2 * a * x2);
    let e = (-v).exp_fast();
    let s = T::ONE / (T::ONE + e);
    // s′ = s(1 − s) = s²e (no cancellation when s → 1).
    let sp = s * s * e;
    let vp = k2 + T::of(3.0) * k2 * a * x2;
    let vpp = T::of(6.0) * k2 * a * x;
    let h = x * s;
    let d1 = s + x * sp * vp;
    let d2 = sp * (T::of(2.0) * vp + x * ((T::ONE - T::of(2.0) * s) * vp * vp + vpp));
    (h, d1, d2)
}

#[inline(always)]
fn tanh_all<T: Real>(x: T) -> (T, T, T) {
    let t = x.tanh();
    let d = T::ONE - t * t;
    (t, d, T::of(-2.0) * t * d)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [Activation; 4] = [
        Activation::Identity,
        Activation::Sine { omega0: 5.0 },
        Activation::Gelu,
        Activation::Tanh,
    ];

    /// σ′ and σ″ against central differences of σ and σ′.
    #[test]
    fn derivatives_match_finite_differences() {
        let h = 1e-5;
        for act in ALL {
            for i in 0..81 {
                let x = -4.0 + 0.1 * i as f64 + 0.0123;
                let (_, d1, d2) = act.eval(x);
                let fd1 = (act.eval(x + h).0 - act.eval(x - h).0) / (2.0 * h);
                let fd2 = (act.eval(x + h).1 - act.eval(x - h).1) / (2.0 * h);
                let s1 = 1.0 + d1.abs();
                let s2 = 1.0 + d2.abs();
                assert!(
                    (d1 - fd1).abs() < 1e-7 * s1,
                    "{act:?} σ′({x}): {d1} vs {fd1}"
                );
                assert!(
                    (d2 - fd2).abs() < 1e-7 * s2,
                    "{act:?} σ″({x}): {d2} vs {fd2}"
                );
            }
        }
    }

    #[test]
    fn gelu_is_the_tanh_form_and_close_to_erf_form() {
        for i in 0..101 {
            let x = -5.0 + 0.1 * i as f64;
            let u = (2.0 / std::f64::consts::PI).sqrt() * (x + GELU_A * x * x * x);
            let reference = 0.5 * x * (1.0 + u.tanh());
            let (g, _, _) = Activation::Gelu.eval(x);
            assert!((g - reference).abs() < 1e-14 * (1.0 + x.abs()), "x = {x}");
        }
        // Saturation: no NaN/inf for huge inputs.
        for x in [-1e30, -1e3, 1e3, 1e30] {
            let (g, d1, d2) = Activation::Gelu.eval(x);
            assert!(g.is_finite() && d1.is_finite() && d2.is_finite(), "x = {x}");
        }
    }

    #[test]
    fn batched_apply_matches_scalar_eval_including_std_fallback() {
        for act in ALL {
            // The last value puts ω(x + b) beyond the fast kernel's range for Sine.
            let xs: Vec<f64> = (0..37)
                .map(|i| -3.0 + 0.17 * i as f64)
                .chain([3.0e4])
                .collect();
            let bias = 0.25;
            let mut col = xs.clone();
            let mut d1 = vec![0.0; xs.len()];
            let mut d2 = vec![0.0; xs.len()];
            act.apply(&mut col, bias, Some(&mut d1), Some(&mut d2));
            for (i, &x) in xs.iter().enumerate() {
                let (h, g1, g2) = act.eval(x + bias);
                let tol = 1e-12 * (1.0 + h.abs() + g1.abs() + g2.abs());
                assert!((col[i] - h).abs() < tol, "{act:?} at {x}");
                assert!(
                    (d1[i] - g1).abs() < tol && (d2[i] - g2).abs() < tol,
                    "{act:?} at {x}"
                );
            }
        }
    }
}
