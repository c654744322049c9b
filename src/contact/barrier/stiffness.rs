//! Adaptive barrier stiffness κ (Li et al. 2020, supplemental §C; ipc-toolkit's
//! `initial_barrier_stiffness` / `update_barrier_stiffness`).
//!
//! The contact energy is `κ·Σ b(d², d̂²)`. κ starts where the barrier's gradient balances the
//! elastic gradient, inside `[κ_min, κ_max = 100·κ_min]`, and doubles while the closest pair
//! keeps approaching at a tiny distance.

use super::barrier_second_derivative;

/// The initial κ and the cap `κ_max` it may later grow to.
///
/// - `κ_min = scale_factor·scale / (4·d₀·b''(d₀, d̂²))`, with the reference squared distance
///   `d₀ = (10⁻⁸·bbox_diagonal)²` (or `d̂²/2` if that is not below `d̂²`): the stiffness
///   at which the barrier's curvature along a distance direction, `4d₀·b''(d₀)`, outweighs
///   `scale_factor` times the elastic scale at a gap of 10⁻⁸ of the scene.
/// - `κ = −(∇B·∇E)/‖∇B‖²` (least-squares balance of `∇E + κ∇B`), or 1 when `∇B = 0`,
///   clamped to `[κ_min, 100·κ_min]`.
///
/// Parameters: `bbox_diagonal` (cm), `dhat` (cm, the unsquared activation distance), `scale`
/// (dynamics: the average vertex mass; our quasistatic solve: a characteristic stiffness such
/// as the mean diagonal entry of the elastic Hessian), `grad_energy` and `grad_barrier` (the
/// elastic gradient and the unit-stiffness barrier gradient, interleaved `3n`),
/// `scale_factor` (ipc-toolkit's `min_barrier_stiffness_scale`, default `1e11`). Returns
/// `(κ, κ_max)`.
pub fn initial_barrier_stiffness(
    bbox_diagonal: f64,
    dhat: f64,
    scale: f64,
    grad_energy: &[f64],
    grad_barrier: &[f64],
    scale_factor: f64,
) -> (f64, f64) {
    let dhat2 = dhat * dhat;
    let mut d0 = 1e-8 * bbox_diagonal;
    d0 *= d0;
    if d0 >= dhat2 {
        d0 = 0.5 * dhat2;
    }
    let kappa_min = scale_factor * scale / (4.0 * d0 * barrier_second_derivative(d0, dhat2));
    let kappa_max = 100.0 * kappa_min;
    let gb2: f64 = grad_barrier.iter().map(|g| g * g).sum();
    let kappa = if gb2 > 0.0 {
        let dot: f64 = grad_barrier
            .iter()
            .zip(grad_energy)
            .map(|(b, e)| b * e)
            .sum();
        -dot / gb2
    } else {
        1.0
    };
    (kappa.clamp(kappa_min, kappa_max), kappa_max)
}

/// κ after an iteration: doubled (capped at `kappa_max`) when the minimum squared distance was
/// and still is below `(dhat_epsilon_scale·bbox_diagonal)²` and decreased; unchanged otherwise.
/// `prev_min_distance` and `min_distance` are **squared** distances (cm²); ipc-toolkit's
/// default `dhat_epsilon_scale` is `1e-9`.
pub fn update_barrier_stiffness(
    prev_min_distance: f64,
    min_distance: f64,
    kappa_max: f64,
    kappa: f64,
    bbox_diagonal: f64,
    dhat_epsilon_scale: f64,
) -> f64 {
    let eps = dhat_epsilon_scale * bbox_diagonal;
    let eps2 = eps * eps;
    if prev_min_distance < eps2 && min_distance < eps2 && min_distance < prev_min_distance {
        kappa_max.min(2.0 * kappa)
    } else {
        kappa
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn initial_stiffness_balances_gradients_within_bounds() {
        let (kmin_probe, kmax) = initial_barrier_stiffness(10.0, 0.01, 1.0, &[0.0], &[0.0], 1e11);
        // ∇B = 0: κ = 1 clamped to κ_min.
        assert!((kmax / kmin_probe - 100.0).abs() < 1e-9);
        // ∇E = −3∇B balances at κ = 3 when 3 ∈ [κ_min, κ_max]: scale so that κ_min = 0.05.
        let d0: f64 = (1e-8 * 10.0f64).powi(2);
        let unit = 4.0 * d0 * barrier_second_derivative(d0, 1e-4);
        let (k, kmax) =
            initial_barrier_stiffness(10.0, 0.01, 0.05 * unit, &[-3.0, 6.0], &[1.0, -2.0], 1.0);
        assert!(
            (k - 3.0).abs() < 1e-12 && (kmax - 5.0).abs() < 1e-12,
            "{k} {kmax}"
        );
        // Outside the bounds it is clamped.
        let (k, _) =
            initial_barrier_stiffness(10.0, 0.01, 0.05 * unit, &[-300.0, 600.0], &[1.0, -2.0], 1.0);
        assert!((k - 5.0).abs() < 1e-12);
    }

    #[test]
    fn update_doubles_only_when_stuck_close() {
        let diag = 1.0;
        let tiny = 1e-20;
        assert_eq!(
            update_barrier_stiffness(2.0 * tiny, tiny, 100.0, 1.0, diag, 1e-9),
            2.0
        );
        assert_eq!(
            update_barrier_stiffness(2.0 * tiny, tiny, 1.5, 1.0, diag, 1e-9),
            1.5
        );
        assert_eq!(
            update_barrier_stiffness(tiny, 2.0 * tiny, 100.0, 1.0, diag, 1e-9),
            1.0
        );
        assert_eq!(
            update_barrier_stiffness(1.0, 0.5, 100.0, 1.0, diag, 1e-9),
            1.0
        );
    }
}
