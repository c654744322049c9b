//! Lipschitz weight normalization (Liu et al. 2022, "Learning Smooth Neural Functions via
//! Lipschitz Regularization"), used by every GeLU layer of N_A with its own trainable bound cᵢ.
//!
//! Per layer with raw weight W (out × in) and bound parameter c, the effective weight is
//!
//!   W̃ᵢⱼ = Wᵢⱼ · αᵢ,   αᵢ = min(1, softplus(c) / rᵢ),   rᵢ = Σⱼ |Wᵢⱼ|,
//!
//! so every row's absolute sum (the layer's ∞-norm Lipschitz bound) is at most softplus(c).
//! The regularizer on a network is  L_lip = λ_lip · Πᵢ softplus(cᵢ)  (an upper bound of the
//! network's Lipschitz constant, given 1-Lipschitz activations).
//!
//! Backward, with G = ∂L/∂W̃, s = softplus(c), tᵢ = Σⱼ Gᵢⱼ Wᵢⱼ, for a clipped row (s < rᵢ):
//!
//!   ∂L/∂Wᵢₖ = αᵢ Gᵢₖ − (s / rᵢ²) sign(Wᵢₖ) tᵢ,      ∂L/∂c += sigmoid(c) tᵢ / rᵢ,
//!
//! and for an unclipped row (s ≥ rᵢ) ∂L/∂Wᵢₖ = Gᵢₖ with no c term. The kink at s = rᵢ and
//! at Wᵢₖ = 0 take the one-sided values above (subgradient).

use super::real::Real;

/// softplus(c) = ln(1 + eᶜ), computed as max(c, 0) + ln(1 + e^(−|c|)) (no overflow).
pub fn softplus<T: Real>(c: T) -> T {
    c.max(T::ZERO) + (-c.abs()).exp().ln_1p()
}

/// The logistic sigmoid(c) = 1/(1 + e^(−c)) = softplus′(c), without overflow.
pub fn sigmoid<T: Real>(c: T) -> T {
    if c >= T::ZERO {
        T::ONE / (T::ONE + (-c).exp())
    } else {
        let e = c.exp();
        e / (T::ONE + e)
    }
}

/// The c with softplus(c) = s, for s > 0: c = s + ln(1 − e^(−s)).
pub fn softplus_inverse<T: Real>(s: T) -> T {
    s + (-(-s).exp_m1()).ln()
}

/// Writes W̃ = diag(α)·W into `w_eff` and the row sums rᵢ into `row_sums`.
/// `w` and `w_eff` are column-major `rows × cols`.
pub(crate) fn normalize<T: Real>(
    w: &[T],
    rows: usize,
    cols: usize,
    c: T,
    w_eff: &mut [T],
    row_sums: &mut [T],
) {
    debug_assert_eq!(w.len(), rows * cols);
    row_sums.fill(T::ZERO);
    for col in w.chunks_exact(rows) {
        for (r, &v) in row_sums.iter_mut().zip(col) {
            *r += v.abs();
        }
    }
    let s = softplus(c);
    let alpha: Vec<T> = row_sums.iter().map(|&r| scale(s, r)).collect();
    for (out, col) in w_eff.chunks_exact_mut(rows).zip(w.chunks_exact(rows)) {
        for ((o, &v), &a) in out.iter_mut().zip(col).zip(&alpha) {
            *o = v * a;
        }
    }
}

/// αᵢ = min(1, s/rᵢ) (1 for an all-zero row).
#[inline]
fn scale<T: Real>(s: T, r: T) -> T {
    if s < r { s / r } else { T::ONE }
}

/// Given G = ∂L/∂W̃ (`g`, column-major like `w`), **adds** ∂L/∂W into `grad_w` and returns
/// ∂L/∂c (formulas in the module docs). `row_sums` are those written by [`normalize`].
pub(crate) fn normalize_backward<T: Real>(
    w: &[T],
    rows: usize,
    c: T,
    row_sums: &[T],
    g: &[T],
    grad_w: &mut [T],
) -> T {
    let s = softplus(c);
    let mut t = vec![T::ZERO; rows];
    for (gc, wc) in g.chunks_exact(rows).zip(w.chunks_exact(rows)) {
        for ((ti, &gv), &wv) in t.iter_mut().zip(gc).zip(wc) {
            *ti += gv * wv;
        }
    }
    let clipped: Vec<bool> = row_sums.iter().map(|&r| s < r).collect();
    for ((gw, gc), wc) in grad_w
        .chunks_exact_mut(rows)
        .zip(g.chunks_exact(rows))
        .zip(w.chunks_exact(rows))
    {
        for i in 0..rows {
            gw[i] += if clipped[i] {
                let r = row_sums[i];
                (s / r) * gc[i] - (s / (r * r)) * wc[i].sign() * t[i]
            } else {
                gc[i]
            };
        }
    }
    let sig = sigmoid(c);
    let mut gc = T::ZERO;
    for i in 0..rows {
        if clipped[i] {
            gc += sig * t[i] / row_sums[i];
        }
    }
    gc
}

/// L_lip = λ · Πᵢ softplus(cᵢ); when `grad` is given, **adds**
/// ∂L/∂cₖ = λ · sigmoid(cₖ) · Π_{i≠k} softplus(cᵢ) into `grad[k]`.
pub fn lipschitz_loss<T: Real>(cs: &[T], lambda: T, grad: Option<&mut [T]>) -> T {
    let sp: Vec<T> = cs.iter().map(|&c| softplus(c)).collect();
    let loss = lambda * sp.iter().fold(T::ONE, |a, &b| a * b);
    if let Some(grad) = grad {
        for (k, g) in grad.iter_mut().enumerate() {
            let others = sp
                .iter()
                .enumerate()
                .filter(|&(i, _)| i != k)
                .fold(T::ONE, |a, (_, &b)| a * b);
            *g += lambda * sigmoid(cs[k]) * others;
        }
    }
    loss
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn softplus_helpers() {
        for c in [-50.0, -3.0, -0.1, 0.0, 0.7, 4.0, 60.0f64] {
            let s = softplus(c);
            assert!((s - (1.0 + c.exp()).ln()).abs() < 1e-14 * (1.0 + s));
            assert!(
                (softplus_inverse(s) - c).abs() < 1e-9 * (1.0 + c.abs()),
                "c = {c}"
            );
            let h = 1e-6;
            let fd = (softplus(c + h) - softplus(c - h)) / (2.0 * h);
            assert!((sigmoid(c) - fd).abs() < 1e-8);
        }
    }

    /// A loss L(W̃) = Σ Rᵢⱼ W̃ᵢⱼ + ½ΣW̃ᵢⱼ² checked through the normalization against central
    /// differences in W and c, with some rows clipped and some not.
    #[test]
    fn normalization_gradient_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (rows, cols) = (6, 5);
        let w: Vec<f64> = (0..rows * cols)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let r_mat: Vec<f64> = (0..rows * cols)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let mut sums = vec![0.0; rows];
        let mut we = vec![0.0; rows * cols];
        normalize(&w, rows, cols, 0.0, &mut we, &mut sums);
        let mut sorted = sums.clone();
        sorted.sort_by(f64::total_cmp);
        // softplus(c) between the 2nd and 3rd smallest row sums: rows of both kinds.
        let c = softplus_inverse(0.5 * (sorted[1] + sorted[2]));
        let loss = |w: &[f64], c: f64| {
            let mut we = vec![0.0; rows * cols];
            let mut sums = vec![0.0; rows];
            normalize(w, rows, cols, c, &mut we, &mut sums);
            we.iter()
                .zip(&r_mat)
                .map(|(a, b)| a * b + 0.5 * a * a)
                .sum::<f64>()
        };
        normalize(&w, rows, cols, c, &mut we, &mut sums);
        let clipped = sums.iter().filter(|&&r| softplus(c) < r).count();
        assert!(clipped > 0 && clipped < rows);
        for i in 0..rows {
            let r: f64 = (0..cols).map(|j| we[j * rows + i].abs()).sum();
            assert!(r <= softplus(c) * (1.0 + 1e-12) || r == sums[i]);
        }
        let g: Vec<f64> = we.iter().zip(&r_mat).map(|(a, b)| b + a).collect();
        let mut gw = vec![0.0; rows * cols];
        let gc = normalize_backward(&w, rows, c, &sums, &g, &mut gw);
        let h = 1e-6;
        for k in 0..rows * cols {
            let (mut wp, mut wm) = (w.clone(), w.clone());
            wp[k] += h;
            wm[k] -= h;
            let fd = (loss(&wp, c) - loss(&wm, c)) / (2.0 * h);
            assert!((fd - gw[k]).abs() < 1e-7, "W[{k}]: {} vs {fd}", gw[k]);
        }
        let fd = (loss(&w, c + h) - loss(&w, c - h)) / (2.0 * h);
        assert!((fd - gc).abs() < 1e-7, "c: {gc} vs {fd}");
    }

    #[test]
    fn lipschitz_loss_gradient_matches_finite_differences() {
        let cs = [0.3, -1.2, 2.5, 0.0];
        let lambda = 0.7;
        let mut grad = vec![0.0; cs.len()];
        let l = lipschitz_loss(&cs, lambda, Some(&mut grad));
        let expected: f64 = lambda * cs.iter().map(|&c| softplus(c)).product::<f64>();
        assert!((l - expected).abs() < 1e-15);
        let h = 1e-6;
        for k in 0..cs.len() {
            let (mut p, mut m) = (cs, cs);
            p[k] += h;
            m[k] -= h;
            let fd =
                (lipschitz_loss(&p, lambda, None) - lipschitz_loss(&m, lambda, None)) / (2.0 * h);
            assert!((fd - grad[k]).abs() < 1e-9, "c[{k}]: {} vs {fd}", grad[k]);
        }
    }
}
