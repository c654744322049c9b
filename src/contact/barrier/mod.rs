//! The clamped log barrier of IPC (Li et al. 2020, Eq. 6) and its adaptive stiffness.
//!
//! IPC applies the barrier to **squared** distances: callers pass `d = dist²` (cm²) and
//! `d̂ = dist_hat²` (cm²) consistently, as ipc-toolkit does, so `b` has units of cm⁴.

mod stiffness;

pub use stiffness::{initial_barrier_stiffness, update_barrier_stiffness};

/// `ln(d/d̂)`, accurate at both ends: `ln_1p((d − d̂)/d̂)` near `d̂` (where `d/d̂ − 1` is
/// small and exact), `ln(d/d̂)` otherwise.
fn log_ratio(d: f64, dhat: f64) -> f64 {
    if d >= 0.5 * dhat {
        ((d - dhat) / dhat).ln_1p()
    } else {
        (d / dhat).ln()
    }
}

/// `b(d) = −(d − d̂)² ln(d/d̂)` for `0 < d < d̂`, `0` for `d ≥ d̂`, `+∞` for `d ≤ 0`.
///
/// `b(d̂) = b'(d̂) = b''(d̂) = 0`, so the clamped barrier is C² across `d̂`; `b → ∞` as
/// `d → 0⁺`.
pub fn barrier(d: f64, dhat: f64) -> f64 {
    if d <= 0.0 {
        f64::INFINITY
    } else if d >= dhat {
        0.0
    } else {
        let t = d - dhat;
        -t * t * log_ratio(d, dhat)
    }
}

/// `b'(d) = (d̂ − d)·(2 ln(d/d̂) − d̂/d + 1)` for `0 < d < d̂`, `0` for `d ≥ d̂`, `−∞` for
/// `d ≤ 0` (units cm² when `d` is a squared distance).
///
/// Evaluated as `(d̂ − d)·(2 ln(d/d̂) − (d̂ − d)/d)`: both terms are negative, so nothing
/// cancels as `d → d̂` (the textbook form loses `log₁₀(d̂/(d̂ − d))` digits there).
pub fn barrier_first_derivative(d: f64, dhat: f64) -> f64 {
    if d <= 0.0 {
        f64::NEG_INFINITY
    } else if d >= dhat {
        0.0
    } else {
        let gap = dhat - d;
        gap * (2.0 * log_ratio(d, dhat) - gap / d)
    }
}

/// `b''(d) = (d̂/d + 2)·d̂/d − 2 ln(d/d̂) − 3` for `0 < d < d̂`, `0` for `d ≥ d̂`, `+∞` for
/// `d ≤ 0` (dimensionless). Positive on `(0, d̂)`: the barrier is convex in `d`.
///
/// Evaluated as `(d̂ − d)(d̂ + 3d)/d² − 2 ln(d/d̂)`, a sum of two positive terms (no
/// cancellation as `d → d̂`, where `b'' ≈ 6(d̂ − d)/d̂`).
pub fn barrier_second_derivative(d: f64, dhat: f64) -> f64 {
    if d <= 0.0 {
        f64::INFINITY
    } else if d >= dhat {
        0.0
    } else {
        (dhat - d) * (dhat + 3.0 * d) / (d * d) - 2.0 * log_ratio(d, dhat)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn barrier_derivatives_match_finite_differences() {
        let dhat = 1e-4;
        for &d in &[1e-9, 1e-7, 3e-6, 2e-5, 5e-5, 9.9e-5] {
            let h = 1e-6 * d;
            let fd1 = (barrier(d + h, dhat) - barrier(d - h, dhat)) / (2.0 * h);
            let fd2 = (barrier_first_derivative(d + h, dhat)
                - barrier_first_derivative(d - h, dhat))
                / (2.0 * h);
            let b1 = barrier_first_derivative(d, dhat);
            let b2 = barrier_second_derivative(d, dhat);
            assert!(
                (fd1 - b1).abs() <= 1e-6 * b1.abs(),
                "b' at {d}: {fd1} vs {b1}"
            );
            assert!(
                (fd2 - b2).abs() <= 1e-6 * b2.abs(),
                "b'' at {d}: {fd2} vs {b2}"
            );
            assert!(barrier(d, dhat) > 0.0 && b1 < 0.0 && b2 > 0.0);
        }
    }

    #[test]
    fn barrier_is_clamped_and_smooth_at_dhat() {
        let dhat = 2.0;
        assert_eq!(barrier(2.0, dhat), 0.0);
        assert_eq!(barrier(3.0, dhat), 0.0);
        assert_eq!(barrier_first_derivative(3.0, dhat), 0.0);
        assert_eq!(barrier(0.0, dhat), f64::INFINITY);
        assert_eq!(barrier(-1.0, dhat), f64::INFINITY);
        // Continuity of b, b', b'' at d̂ from below.
        let d = dhat * (1.0 - 1e-7);
        assert!(barrier(d, dhat).abs() < 1e-18);
        assert!(barrier_first_derivative(d, dhat).abs() < 1e-12);
        assert!(barrier_second_derivative(d, dhat).abs() < 1e-5);
        // Near d̂ the stable forms keep full relative accuracy: b'' ≈ 6δ, b' ≈ −3δ·(d̂ − d).
        let d = dhat * (1.0 - 1e-9);
        let delta = (dhat - d) / dhat; // exact (Sterbenz), unlike 1e-9 itself
        let b2 = barrier_second_derivative(d, dhat);
        assert!((b2 / (6.0 * delta) - 1.0).abs() < 1e-8, "{b2}");
        let b1 = barrier_first_derivative(d, dhat);
        assert!(
            (b1 / (-3.0 * delta * dhat * delta) - 1.0).abs() < 1e-8,
            "{b1}"
        );
    }
}
