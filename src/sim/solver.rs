//! The quasistatic solve: Projective Dynamics accelerated by L-BFGS (Liu, Bouaziz & Kavan
//! 2017, "Quasi-Newton methods for real-time simulation of hyperelastic materials").
//!
//! Each iteration is one local sweep (rotations, energy and stress for every element, in
//! parallel), one gradient gather and one solve with the prefactored PD matrix `L`, which is
//! the L-BFGS initial inverse Hessian `H₀ = L⁻¹`. With an empty history the step is exactly
//! the PD global step, so this is PD plus curvature from the last `m` steps. A backtracking
//! (Armijo) line search makes the energy non-increasing, which plain PD guarantees too.

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::attachment::BonePose;
use super::shape_targeting::LocalStep;
use super::simulator::{SimError, SimState, Simulator};
use super::tensor::SymTensor;
use super::vector::{axpy, dot, norm};

/// Accuracy/speed presets for a solve.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    /// For dragging sliders: a few iterations, visually settled.
    Interactive,
    /// For a paused preview: close to converged.
    Preview,
    /// For exported frames: converged to tight tolerance.
    Final,
}

impl std::str::FromStr for Quality {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Quality::ALL
            .into_iter()
            .find(|q| q.name() == s)
            .ok_or_else(|| {
                format!("unknown quality '{s}' (expected interactive, preview or final)")
            })
    }
}

impl std::fmt::Display for Quality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl Quality {
    pub fn name(self) -> &'static str {
        match self {
            Quality::Interactive => "interactive",
            Quality::Preview => "preview",
            Quality::Final => "final",
        }
    }

    pub const ALL: [Quality; 3] = [Quality::Interactive, Quality::Preview, Quality::Final];

    pub fn settings(self) -> SolveSettings {
        match self {
            Quality::Interactive => SolveSettings {
                tolerance: 1e-3,
                max_iterations: 30,
                history: 5,
            },
            Quality::Preview => SolveSettings {
                tolerance: 1e-4,
                max_iterations: 100,
                history: 8,
            },
            Quality::Final => SolveSettings {
                tolerance: 1e-6,
                max_iterations: 1000,
                history: 8,
            },
        }
    }
}

/// When a solve stops.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveSettings {
    /// Stop when `‖∇E‖ / force scale` falls below this (see [`SolveStats::residual`]).
    pub tolerance: f64,
    /// Stop after this many iterations even if not converged.
    pub max_iterations: usize,
    /// L-BFGS history length `m` (0 = plain Projective Dynamics).
    pub history: usize,
}

impl Default for SolveSettings {
    fn default() -> Self {
        Quality::Preview.settings()
    }
}

/// Why a solve stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Termination {
    /// Reached the tolerance.
    Converged,
    /// Hit `max_iterations` first.
    IterationCap,
    /// No step decreases the energy any more: the residual is at the floating-point floor.
    Stalled,
}

/// What a solve did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveStats {
    pub iterations: usize,
    /// Local sweeps (energy evaluations) done, line-search trials included.
    pub evaluations: usize,
    /// Relative residual at the start: `‖∇E‖` over the element force scale.
    pub initial_residual: f64,
    /// Relative residual at the end: `‖∇E(x)‖ / sqrt(Σₑ Σᵢ ‖wVₑ·Aₑ·gᵢ‖²)`, the net force
    /// against the size of the element forces in play. Invariant to rigid motions and to
    /// where the solve started.
    pub residual: f64,
    pub energy: f64,
    /// Energy after each accepted iteration, starting with the initial energy.
    pub energy_history: Vec<f64>,
    pub termination: Termination,
    pub wall_time: Duration,
    /// Time in local sweeps (rotations, energy, stress) and in solves with the PD factor;
    /// the rest of `wall_time` is gradients, L-BFGS vector work and setup.
    pub local_time: Duration,
    pub global_time: Duration,
    /// Time in the iteration loop (no setup or final checks): `iteration_time / iterations`
    /// is the cost of one iteration.
    pub iteration_time: Duration,
}

impl SolveStats {
    pub fn converged(&self) -> bool {
        self.termination == Termination::Converged
    }
}

/// Armijo sufficient-decrease constant.
const ARMIJO: f64 = 1e-4;
/// Halvings of the step before the line search gives up.
const MAX_BACKTRACKS: usize = 40;
/// Below this relative size the energy change of a step is round-off; the step is taken on
/// the strength of its gradient alone.
const ROUND_OFF: f64 = 1e-13;

/// Ring buffer of the last `m` curvature pairs `(s, y)`. It lives in the [`SimState`], so the
/// next frame's solve starts with the curvature learned on this one: after a small input
/// change the Hessian has barely moved, and the first steps are already quasi-Newton steps.
#[derive(Clone, Debug)]
pub(crate) struct History {
    s: Vec<Vec<f64>>,
    y: Vec<Vec<f64>>,
    rho: Vec<f64>,
    alpha: Vec<f64>,
    len: usize,
    next: usize,
}

impl History {
    fn new(m: usize, dim: usize) -> Self {
        Self {
            s: vec![vec![0.0; dim]; m],
            y: vec![vec![0.0; dim]; m],
            rho: vec![0.0; m],
            alpha: vec![0.0; m],
            len: 0,
            next: 0,
        }
    }

    fn capacity(&self) -> usize {
        self.s.len()
    }

    fn dimension(&self) -> usize {
        self.s.first().map_or(0, Vec::len)
    }

    fn clear(&mut self) {
        self.len = 0;
        self.next = 0;
    }

    /// Stores `s = x₊ − x`, `y = g₊ − g` if the curvature `sᵀy` is positive.
    fn push(&mut self, x_new: &[f64], x: &[f64], g_new: &[f64], g: &[f64]) {
        let m = self.capacity();
        if m == 0 {
            return;
        }
        let slot = self.next;
        for i in 0..x.len() {
            self.s[slot][i] = x_new[i] - x[i];
            self.y[slot][i] = g_new[i] - g[i];
        }
        let sy = dot(&self.s[slot], &self.y[slot]);
        let yy = dot(&self.y[slot], &self.y[slot]);
        if !(sy > 1e-12 * yy.sqrt() * dot(&self.s[slot], &self.s[slot]).sqrt()) {
            return;
        }
        self.rho[slot] = 1.0 / sy;
        self.next = (slot + 1) % m;
        self.len = (self.len + 1).min(m);
    }

    /// `d = −H·g` by the two-loop recursion with `H₀ = L⁻¹`.
    fn direction(
        &mut self,
        sim: &Simulator,
        g: &[f64],
        d: &mut [f64],
        scratch: &mut super::global_matrix::SolveScratch,
    ) -> Duration {
        let m = self.capacity();
        d.copy_from_slice(g);
        let newest_first: Vec<usize> = (0..self.len).map(|k| (self.next + m - 1 - k) % m).collect();
        for &i in &newest_first {
            self.alpha[i] = self.rho[i] * dot(&self.s[i], d);
            axpy(-self.alpha[i], &self.y[i], d);
        }
        let solve_start = Instant::now();
        sim.global.solve_in_place(d, scratch);
        let solve_time = solve_start.elapsed();
        for &i in newest_first.iter().rev() {
            let beta = self.rho[i] * dot(&self.y[i], d);
            axpy(self.alpha[i] - beta, &self.s[i], d);
        }
        for v in d.iter_mut() {
            *v = -*v;
        }
        solve_time
    }
}

impl Simulator {
    /// Solves for the equilibrium under `actuations` (one per element) and `bones`, starting
    /// from `state` (the previous frame, or [`Simulator::rest_state`]) and leaving the result
    /// in it.
    ///
    /// Errors are loud: bad inputs are rejected before anything changes; a result with
    /// inverted elements is returned as [`SimError::Inverted`] (the state then holds it, for
    /// inspection). Non-finite trial states are never accepted, so the state stays finite.
    pub fn solve(
        &self,
        actuations: &[SymTensor],
        bones: &BonePose,
        state: &mut SimState,
        settings: &SolveSettings,
    ) -> Result<SolveStats, SimError> {
        let start = Instant::now();
        self.check_state(state)?;
        if !(settings.tolerance >= 0.0) {
            return Err(SimError::Setup(format!(
                "tolerance must be non-negative, got {}",
                settings.tolerance
            )));
        }
        let frame = self.frame(actuations, bones)?;
        let dim = state.x.len();
        let scale = self.force_scale(&frame);

        // Per-element buffers live in the state: the current one is updated in place (its
        // rotations are the warm start), the spare one takes line-search trials.
        let mut steps = std::mem::take(&mut state.steps);
        let mut trial_steps = std::mem::take(&mut state.spare);
        trial_steps.resize(steps.len(), LocalStep::default());
        let mut energy = self.local_sweep(&frame, &state.x, None, &mut steps);
        let mut g = vec![0.0; dim];
        self.gradient(&frame, &state.x, &steps, &mut g);
        let mut residual = norm(&g) / scale;
        if !energy.is_finite() || !residual.is_finite() {
            state.steps = steps;
            state.spare = trial_steps;
            return Err(SimError::NonFiniteState(0));
        }
        let initial_residual = residual;
        let mut energy_history = vec![energy];

        let mut history = match state.history.take() {
            Some(h) if h.capacity() == settings.history && h.dimension() == dim => h,
            _ => History::new(settings.history, dim),
        };
        let mut scratch = self.solve_scratch();
        let mut d = vec![0.0; dim];
        let mut x_trial = vec![0.0; dim];
        let mut g_trial = vec![0.0; dim];
        let mut iterations = 0;
        let mut evaluations = 1;
        let mut local_time = Duration::ZERO;
        let mut global_time = Duration::ZERO;
        let mut termination = Termination::IterationCap;

        let loop_start = Instant::now();
        while residual > settings.tolerance {
            if iterations == settings.max_iterations {
                break;
            }
            global_time += history.direction(self, &g, &mut d, &mut scratch);
            let mut slope = dot(&g, &d);
            if !(slope < 0.0) {
                // Not a descent direction (lost curvature information): restart as plain PD.
                history.clear();
                global_time += history.direction(self, &g, &mut d, &mut scratch);
                slope = dot(&g, &d);
            }
            let mut alpha = 1.0;
            let mut accepted = None;
            for _ in 0..MAX_BACKTRACKS {
                for i in 0..dim {
                    x_trial[i] = state.x[i] + alpha * d[i];
                }
                let sweep_start = Instant::now();
                let e = self.local_sweep(&frame, &x_trial, Some(&steps), &mut trial_steps);
                local_time += sweep_start.elapsed();
                evaluations += 1;
                if e.is_finite() {
                    if e <= energy + ARMIJO * alpha * slope {
                        accepted = Some(e);
                        break;
                    }
                    if (alpha * slope).abs() <= ROUND_OFF * energy.abs()
                        && e <= energy * (1.0 + ROUND_OFF)
                    {
                        // The energy cannot resolve this step; take it if it reduces the gradient.
                        self.gradient(&frame, &x_trial, &trial_steps, &mut g_trial);
                        if norm(&g_trial) < norm(&g) {
                            accepted = Some(e);
                            break;
                        }
                    }
                }
                alpha *= 0.5;
            }
            let Some(e) = accepted else {
                termination = Termination::Stalled;
                break;
            };
            self.gradient(&frame, &x_trial, &trial_steps, &mut g_trial);
            history.push(&x_trial, &state.x, &g_trial, &g);
            std::mem::swap(&mut state.x, &mut x_trial);
            std::mem::swap(&mut g, &mut g_trial);
            std::mem::swap(&mut steps, &mut trial_steps);
            energy = e;
            residual = norm(&g) / scale;
            iterations += 1;
            energy_history.push(energy);
        }
        let iteration_time = loop_start.elapsed();
        if residual <= settings.tolerance {
            termination = Termination::Converged;
        }
        let inverted: Vec<usize> = (0..steps.len())
            .filter(|&e| !(steps[e].volume_ratio > 0.0))
            .collect();
        state.steps = steps;
        state.spare = trial_steps;
        state.history = Some(history);
        let stats = SolveStats {
            iterations,
            evaluations,
            initial_residual,
            residual,
            energy,
            energy_history,
            termination,
            wall_time: start.elapsed(),
            local_time,
            global_time,
            iteration_time,
        };
        if let Some(&first) = inverted.first() {
            return Err(SimError::Inverted {
                count: inverted.len(),
                first,
                stats: Box::new(stats),
            });
        }
        Ok(stats)
    }
}
