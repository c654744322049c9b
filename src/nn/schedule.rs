//! Learning-rate schedules.
//!
//! The paper's schedule: constant lr₀ for the first fraction f of the T iterations, then a
//! linear decay reaching 0 at iteration T:
//!
//!   lr(i) = lr₀                                  for i < s,   s = ⌊f·T⌋
//!   lr(i) = lr₀ · (T − i) / (T − s)              for s ≤ i < T
//!   lr(i) = 0                                    for i ≥ T.
//!
//! φ: lr₀ = 1e-4, T = 100k, f = 0.5. N_A/N_B stage 1: 1e-4, 400 epochs, f = 0.5; stage 2:
//! 5e-5, f = 0 (decay from the start).

use serde::{Deserialize, Serialize};

use super::error::NnError;

/// A learning rate as a function of the iteration index (from 0).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LrSchedule {
    /// lr(i) = lr.
    Constant { lr: f64 },
    /// Constant, then linear decay to 0 (module docs).
    LinearDecay {
        lr: f64,
        total_iters: u64,
        decay_start_fraction: f64,
    },
}

impl LrSchedule {
    /// Constant `lr`.
    pub fn constant(lr: f64) -> Result<Self, NnError> {
        let s = LrSchedule::Constant { lr };
        s.validate()?;
        Ok(s)
    }

    /// Constant `lr` until `decay_start_fraction · total_iters`, then linear decay to 0 at
    /// `total_iters`.
    pub fn linear_decay(
        lr: f64,
        total_iters: u64,
        decay_start_fraction: f64,
    ) -> Result<Self, NnError> {
        let s = LrSchedule::LinearDecay {
            lr,
            total_iters,
            decay_start_fraction,
        };
        s.validate()?;
        Ok(s)
    }

    /// Checks the settings (lr finite and ≥ 0, fraction in [0, 1], T > 0).
    pub fn validate(&self) -> Result<(), NnError> {
        let lr = match *self {
            LrSchedule::Constant { lr } => lr,
            LrSchedule::LinearDecay {
                lr,
                total_iters,
                decay_start_fraction: f,
            } => {
                if total_iters == 0 {
                    return Err(NnError::Schedule("total iterations must be > 0".into()));
                }
                if !(0.0..=1.0).contains(&f) {
                    return Err(NnError::Schedule(format!(
                        "decay start fraction {f} must lie in [0, 1]"
                    )));
                }
                lr
            }
        };
        if !(lr.is_finite() && lr >= 0.0) {
            return Err(NnError::Schedule(format!("learning rate {lr} must be ≥ 0")));
        }
        Ok(())
    }

    /// The learning rate at iteration `iter` (0-based).
    pub fn lr_at(&self, iter: u64) -> f64 {
        match *self {
            LrSchedule::Constant { lr } => lr,
            LrSchedule::LinearDecay {
                lr,
                total_iters: t,
                decay_start_fraction: f,
            } => {
                let s = ((f * t as f64).floor() as u64).min(t);
                if iter < s {
                    lr
                } else if iter >= t {
                    0.0
                } else {
                    lr * (t - iter) as f64 / (t - s) as f64
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_schedule_values() {
        let s = LrSchedule::linear_decay(1e-4, 100_000, 0.5).unwrap();
        assert_eq!(s.lr_at(0), 1e-4);
        assert_eq!(s.lr_at(49_999), 1e-4);
        assert_eq!(s.lr_at(50_000), 1e-4);
        assert!((s.lr_at(75_000) - 0.5e-4).abs() < 1e-18);
        assert!((s.lr_at(99_999) - 1e-4 / 50_000.0).abs() < 1e-18);
        assert_eq!(s.lr_at(100_000), 0.0);
        assert_eq!(s.lr_at(1 << 40), 0.0);
        // Monotone non-increasing.
        let mut prev = f64::INFINITY;
        for i in (0..100_100).step_by(97) {
            let v = s.lr_at(i);
            assert!(v <= prev);
            prev = v;
        }
    }

    #[test]
    fn decay_from_the_start_and_constant() {
        let s = LrSchedule::linear_decay(5e-5, 20, 0.0).unwrap();
        assert_eq!(s.lr_at(0), 5e-5);
        assert!((s.lr_at(10) - 2.5e-5).abs() < 1e-18);
        assert_eq!(LrSchedule::constant(0.1).unwrap().lr_at(12345), 0.1);
    }

    #[test]
    fn invalid_schedules_are_rejected() {
        assert!(LrSchedule::linear_decay(1e-4, 0, 0.5).is_err());
        assert!(LrSchedule::linear_decay(1e-4, 10, 1.5).is_err());
        assert!(LrSchedule::linear_decay(-1.0, 10, 0.5).is_err());
        assert!(LrSchedule::constant(f64::NAN).is_err());
    }
}
