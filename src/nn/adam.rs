//! Adam (Kingma & Ba 2015), as in PyTorch `torch.optim.Adam` without weight decay.
//!
//! At step t (from 1), for gradient g:
//!   m ← β₁m + (1 − β₁)g,   v ← β₂v + (1 − β₂)g²,
//!   θ ← θ − lr · (m / (1 − β₁ᵗ)) / (√(v / (1 − β₂ᵗ)) + ε).
//! Defaults β₁ = 0.9, β₂ = 0.999, ε = 1e-8. Moments are kept in f64 whatever the parameter
//! type, so f32 training does not lose small updates in the moments.

use serde::{Deserialize, Serialize};

use super::error::NnError;
use super::real::Real;

/// Adam's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdamConfig {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
}

impl Default for AdamConfig {
    fn default() -> Self {
        AdamConfig {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// Adam's state for one parameter vector (serializable, to resume training).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adam {
    config: AdamConfig,
    m: Vec<f64>,
    v: Vec<f64>,
    t: u64,
}

impl Adam {
    /// Fresh state for `n` parameters.
    pub fn new(n: usize, config: AdamConfig) -> Result<Self, NnError> {
        let AdamConfig { beta1, beta2, eps } = config;
        if !((0.0..1.0).contains(&beta1) && (0.0..1.0).contains(&beta2)) {
            return Err(NnError::Optimizer(format!(
                "β1 = {beta1}, β2 = {beta2} must lie in [0, 1)"
            )));
        }
        if !(eps.is_finite() && eps > 0.0) {
            return Err(NnError::Optimizer(format!("ε = {eps} must be positive")));
        }
        Ok(Adam {
            config,
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        })
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.t
    }

    pub fn config(&self) -> AdamConfig {
        self.config
    }

    /// One update of `params` with gradient `grad` and learning rate `lr`.
    pub fn step<T: Real>(&mut self, params: &mut [T], grad: &[T], lr: f64) -> Result<(), NnError> {
        if params.len() != self.m.len() || grad.len() != self.m.len() {
            return Err(NnError::ParamCount {
                expected: self.m.len(),
                found: if params.len() != self.m.len() {
                    params.len()
                } else {
                    grad.len()
                },
            });
        }
        if !(lr.is_finite() && lr >= 0.0) {
            return Err(NnError::Optimizer(format!(
                "learning rate {lr} must be ≥ 0"
            )));
        }
        let AdamConfig { beta1, beta2, eps } = self.config;
        self.t += 1;
        let t = i32::try_from(self.t).unwrap_or(i32::MAX);
        let c1 = 1.0 - beta1.powi(t);
        let c2 = 1.0 - beta2.powi(t);
        let step = lr / c1;
        let inv_sqrt_c2 = 1.0 / c2.sqrt();
        for (((p, &g), m), v) in params
            .iter_mut()
            .zip(grad)
            .zip(self.m.iter_mut())
            .zip(self.v.iter_mut())
        {
            let g = g.to_f64();
            *m = beta1 * *m + (1.0 - beta1) * g;
            *v = beta2 * *v + (1.0 - beta2) * g * g;
            let update = step * *m / (v.sqrt() * inv_sqrt_c2 + eps);
            *p = T::of(p.to_f64() - update);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_step_moves_each_parameter_by_lr_against_the_gradient_sign() {
        let mut adam = Adam::new(3, AdamConfig::default()).unwrap();
        let mut p = vec![1.0f64, 2.0, 3.0];
        adam.step(&mut p, &[0.5, -2.0, 0.0], 0.1).unwrap();
        // m̂ = g, v̂ = g²: the update is lr·g/(|g| + ε).
        assert!((p[0] - 0.9).abs() < 1e-7 && (p[1] - 2.1).abs() < 1e-7 && p[2] == 3.0);
        assert_eq!(adam.steps(), 1);
    }

    #[test]
    fn minimizes_a_quadratic() {
        let target = [3.0f64, -1.0, 0.5];
        let mut p = vec![0.0f64; 3];
        let mut adam = Adam::new(3, AdamConfig::default()).unwrap();
        for _ in 0..2000 {
            let g: Vec<f64> = p.iter().zip(&target).map(|(a, b)| 2.0 * (a - b)).collect();
            adam.step(&mut p, &g, 0.05).unwrap();
        }
        for (a, b) in p.iter().zip(&target) {
            assert!((a - b).abs() < 1e-3, "{p:?}");
        }
    }

    #[test]
    fn rejects_bad_settings_and_lengths() {
        assert!(
            Adam::new(
                2,
                AdamConfig {
                    beta1: 1.0,
                    ..Default::default()
                }
            )
            .is_err()
        );
        assert!(
            Adam::new(
                2,
                AdamConfig {
                    eps: 0.0,
                    ..Default::default()
                }
            )
            .is_err()
        );
        let mut adam = Adam::new(2, AdamConfig::default()).unwrap();
        let mut p = vec![0.0f32; 3];
        assert!(adam.step(&mut p, &[0.0; 3], 0.1).is_err());
        let mut p = vec![0.0f32; 2];
        assert!(adam.step(&mut p, &[0.0; 2], f64::NAN).is_err());
    }
}
