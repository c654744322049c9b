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

use super::attachment::{BonePose, RigidMotion};
use super::contact::{ContactModel, ContactSolve, ContactStats, ContactStep};
use super::contact_gate::{Attempt, ContactGate, GateOutcome, note_refusal};
use super::low_rank::StepInverse;
use super::shape_targeting::LocalStep;
use super::simulator::{SimError, SimState, Simulator};
use super::staging::StageStart;
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
                contact: true,
                audit_crossings: false,
            },
            Quality::Preview => SolveSettings {
                tolerance: 1e-4,
                max_iterations: 100,
                history: 8,
                contact: true,
                audit_crossings: false,
            },
            Quality::Final => SolveSettings {
                tolerance: 1e-6,
                max_iterations: 1000,
                history: 8,
                contact: true,
                audit_crossings: true,
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
    /// Contact on or off (a no-op for a simulator without contact surfaces, see
    /// [`Simulator::set_contact`]).
    #[serde(default = "contact_on")]
    pub contact: bool,
    /// Whether a contact solve ends with the whole contact surface checked for crossings
    /// (`ContactStats::new_crossings`; a crossing found is [`SimError::Intersecting`]). A
    /// debug audit, not a guard: every line-search step and every pose stage is certified
    /// free of crossings over a complete candidate set, so the check finds nothing a correct
    /// solve can leave (the 1,008-code sweep never did). On at the final preset, where its
    /// ~9 ms is a few percent of a frame; off where a frame's budget is tens of ms.
    #[serde(default)]
    pub audit_crossings: bool,
}

fn contact_on() -> bool {
    true
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
    /// Most elements near folding (`det F` below the volume barrier's threshold, where its
    /// curvature enters the steps) at any accepted iterate.
    #[serde(default)]
    pub near_folding: usize,
    /// What contact did (`None` when contact was off or not set up).
    #[serde(default)]
    pub contact: Option<ContactStats>,
    /// The solve from the given state failed ([`FAILED_FACTOR`]) and this is the solve
    /// from rest that replaced it.
    #[serde(default)]
    pub from_rest: bool,
}

impl SolveStats {
    pub fn converged(&self) -> bool {
        self.termination == Termination::Converged
    }

    /// Whether the solve was given the iterations to converge ([`CONVERGING_BUDGET`]) and ran
    /// out of them far from any equilibrium: its residual above [`FAILED_FACTOR`] times its
    /// tolerance.
    pub fn failed(&self, settings: &SolveSettings) -> bool {
        settings.max_iterations >= CONVERGING_BUDGET
            && self.termination == Termination::IterationCap
            && !(self.residual <= FAILED_FACTOR * settings.tolerance)
    }
}

/// A solve given at least this many iterations (the final preset's 1,000) is asked for an
/// equilibrium, not for a step toward one: the interactive and preview presets (30 and 100)
/// show a capped frame as far as the solver got, marked unconverged, and refine it.
pub const CONVERGING_BUDGET: usize = 500;

/// A solve asked for an equilibrium ([`CONVERGING_BUDGET`]) that runs out of iterations with
/// its residual still this many times its tolerance has found none, only a crumpled face: it
/// is not a frame of the preset. [`Simulator::solve`] solves it again from rest, and reports
/// [`SimError::NoEquilibrium`] if that fails too. At the final preset that is a residual above
/// 10⁻² after 1,000 iterations (mouthClose alone without contact ends at 2.1).
pub const FAILED_FACTOR: f64 = 1e4;

/// Armijo sufficient-decrease constant.
const ARMIJO: f64 = 1e-4;
/// Halvings of the step before the line search gives up.
const MAX_BACKTRACKS: usize = 40;
/// A step the contact filter cuts below this share of the L-BFGS direction restarts the
/// direction as plain PD (not the volume limit's: there the restart lost the neutral's
/// mouthClose without contact). Measured on the neutral's jawOpen at the
/// final preset with contact: the quasi-Newton direction had grown to 150–1,150 (PD's ~50)
/// and was cut to 10⁻⁷…10⁻¹³ for 900 iterations (no equilibrium); with the restart the
/// solve converges in 485 iterations.
const SHORT_STEP: f64 = 1e-3;
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

    fn is_empty(&self) -> bool {
        self.len == 0
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

    /// `d = −H·g` by the two-loop recursion with `H₀` applied by `h0` (`L⁻¹`, or
    /// `(L + K)⁻¹` with contact).
    fn direction(&mut self, h0: &mut dyn FnMut(&mut [f64]), g: &[f64], d: &mut [f64]) -> Duration {
        let m = self.capacity();
        d.copy_from_slice(g);
        let newest_first: Vec<usize> = (0..self.len).map(|k| (self.next + m - 1 - k) % m).collect();
        for &i in &newest_first {
            self.alpha[i] = self.rho[i] * dot(&self.s[i], d);
            axpy(-self.alpha[i], &self.y[i], d);
        }
        let solve_start = Instant::now();
        h0(d);
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

/// Most bone-pose stages a contact solve may split a pose change into.
pub(crate) const MAX_POSE_STAGES: usize = 64;

/// Shortest pose stage (fraction of the whole swing) a solve from rest tries before the pose
/// is unreachable.
const SHORTEST_STAGE: f64 = 1e-9;

/// Shortest pose stage a warm-started solve tries before it gives the warm path up and the
/// frame is solved from rest. Pressed pairs can stall the stages of a warm start: seed 118's
/// frame 12 of the 1,008-code run crept through ~10⁻⁴ of its swing per stage after 40–55 s
/// of bisection each (2,039 s for the frame); with this floor it is solved from rest (134 s).
pub(crate) const SHORTEST_WARM_STAGE: f64 = 1e-3;

/// Iteration cap of an intermediate pose stage (the last one gets the preset's): it only has
/// to end valid, and the next stage's carry starts from wherever it got. Measured on random
/// codes (`sweep_stages` example, seed 101, frames 0–12, interactive, one thread): 10
/// iterations took 228 s, 3 took 105 s and 1 took 99 s, in about as many stages; with 1,
/// frame 15 then started from an element crushed to `det F` ~10⁻¹⁴ (see
/// `Simulator::starts_unfolded`).
const STAGE_ITERATIONS: usize = 3;

/// Whether the bone pose `to` lies nearer the rest pose than `from` does: the largest move of
/// a contact vertex the bones carry (the teeth) from rest to `to` is shorter than from `from`.
fn nearer_rest(model: &ContactModel, from: &BonePose, to: &BonePose) -> bool {
    let face = &model.face;
    // Any tissue positions: the tissue's vertices land alike under the three poses.
    let x = vec![0.0; 3 * face.sim_vertex_count()];
    let place = |pose: &BonePose| {
        let mut y = vec![0.0; 3 * face.vertex_count()];
        face.positions(&x, pose, &mut y);
        y
    };
    let (at_to, at_from, at_rest) = (place(to), place(from), place(&BonePose::default()));
    let farthest = |a: &[f64], b: &[f64]| {
        a.chunks_exact(3)
            .zip(b.chunks_exact(3))
            .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>())
            .fold(0.0, f64::max)
    };
    farthest(&at_to, &at_rest) < farthest(&at_to, &at_from)
}

/// The pose a fraction `s` of the way from `a` to `b` (parameters interpolated linearly);
/// exactly `b` at `s = 1` (so a solved state records the very pose it was asked for, and the
/// next solve at that pose moves nothing).
fn lerp_pose(a: &BonePose, b: &BonePose, s: f64) -> BonePose {
    if s == 1.0 {
        return *b;
    }
    let mix = |p: &RigidMotion, q: &RigidMotion| {
        let (p, q) = (p.params(), q.params());
        RigidMotion::from_params(std::array::from_fn(|k| p[k] + s * (q[k] - p[k])))
    };
    BonePose {
        skull: mix(&a.skull, &b.skull),
        jaw: mix(&a.jaw, &b.jaw),
    }
}

/// Runs `work` on a thread of rayon's pool. A solve runs thousands of parallel loops; started
/// from a thread outside the pool, each is handed over to the pool and waited for (a futex
/// wake-up and sleep apiece: a fifth of a one-thread contact frame's time, ~0.4 s of system
/// time in `contact_drag`), while from a worker it simply runs there. [`Simulator::solve`]
/// does this itself; a caller that follows a solve with more work on the same simulator
/// (e.g. [`Simulator::sensitivities`]) should wrap both, so that they share one core's
/// cache: stage-2 training's adjoint took ~2.7× as long in its triangular solves when the
/// solve had run on a worker and the adjoint on the caller's thread.
pub fn on_worker<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    if rayon::current_thread_index().is_some() {
        work()
    } else {
        rayon::join(work, || ()).0
    }
}

impl Simulator {
    /// Solves for the equilibrium under `actuations` (one per element) and `bones`, starting
    /// from `state` (the previous frame, or [`Simulator::rest_state`]) and leaving the result
    /// in it.
    ///
    /// With contact set up ([`Simulator::set_contact`]) and `settings.contact` on, the barrier
    /// is part of the energy, every line-search step is collision-checked, rigid contact
    /// surfaces (teeth) are moved to the new pose in collision-free stages with the tissue
    /// carried along, and the result is checked for crossings ([`SimError::Intersecting`]).
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
        on_worker(|| {
            let warm = !self.at_rest(state);
            let stats = self.solve_on_worker(actuations, bones, state, settings)?;
            if !stats.failed(settings) {
                return Ok(stats);
            }
            let retry = if warm {
                *state = SimState {
                    gate_backoff: state.gate_backoff,
                    ..self.rest_state()
                };
                let mut again = self.solve_on_worker(actuations, bones, state, settings)?;
                again.from_rest = true;
                again.wall_time += stats.wall_time;
                again
            } else {
                stats
            };
            if retry.failed(settings) {
                Err(SimError::NoEquilibrium {
                    residual: retry.residual,
                    stats: Box::new(retry),
                })
            } else {
                Ok(retry)
            }
        })
    }

    fn solve_on_worker(
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
        let model = if settings.contact {
            self.contact.as_ref()
        } else {
            None
        };
        let Some(model) = model else {
            let mut stats = self.solve_stage(&frame, None, bones, state, settings)?;
            state.bones = *bones;
            state.contact_stiffness = None;
            stats.wall_time = start.elapsed();
            return Ok(stats);
        };
        let toward_rest = !self.at_rest(state) && nearer_rest(model, &state.bones, bones);
        if toward_rest {
            // A jump back toward rest (the editor's reset, a slider released from far) starts
            // there: its pose stages from the last frame close the jaw onto the lips, which
            // certifies only in short stages at seconds apiece (the neutral's jump from
            // jawOpen 1 back to rest took 52 s that way), and from rest the solve is short.
            *state = SimState {
                gate_backoff: state.gate_backoff,
                ..self.rest_state()
            };
        }
        // Contact only when the surfaces can meet: a certified contact-free result is the
        // equilibrium with contact too (see `contact_gate`).
        let (gate, attempt_time) = match model.gate {
            ContactGate::Always => (GateOutcome::Off, Duration::ZERO),
            ContactGate::WhenNeeded => {
                match self.try_contact_free(model, &frame, bones, state, settings)? {
                    Attempt::Accepted(stats) => {
                        let mut stats = *stats;
                        if let Some(c) = stats.contact.as_mut() {
                            c.from_rest |= toward_rest;
                        }
                        stats.wall_time = start.elapsed();
                        return Ok(stats);
                    }
                    Attempt::Refused(why) => (why, start.elapsed()),
                }
            }
        };
        let warm = !self.at_rest(state);
        let result =
            match self.solve_with_contact(model, &frame, actuations, bones, state, settings) {
                // The path from the last frame can be blocked where rest's is not (seed 122's
                // frame 15 of the 1,008-code run: from frame 14, pairs pressed ~4·10⁻⁵ cm
                // apart let each stage past 95 % of the swing cover only 10⁻⁴ of it, and 64
                // stages ran out; from rest it takes one), so such a frame is solved from
                // rest instead; the state then holds that solve.
                Err(SimError::PoseUnreachable(_)) if warm => {
                    *state = SimState {
                        gate_backoff: state.gate_backoff,
                        ..self.rest_state()
                    };
                    self.solve_with_contact(model, &frame, actuations, bones, state, settings)
                        .map(|mut stats| {
                            if let Some(c) = stats.contact.as_mut() {
                                c.from_rest = true;
                            }
                            stats
                        })
                }
                result => result,
            };
        match result {
            Ok(mut stats) => {
                if let Some(c) = stats.contact.as_mut() {
                    c.from_rest |= toward_rest;
                }
                note_refusal(&mut stats, gate, attempt_time);
                stats.wall_time = start.elapsed();
                Ok(stats)
            }
            Err(SimError::Inverted {
                count,
                first,
                mut stats,
            }) => {
                note_refusal(&mut stats, gate, attempt_time);
                stats.wall_time = start.elapsed();
                Err(SimError::Inverted {
                    count,
                    first,
                    stats,
                })
            }
            Err(SimError::Intersecting { count, mut stats }) => {
                note_refusal(&mut stats, gate, attempt_time);
                stats.wall_time = start.elapsed();
                Err(SimError::Intersecting { count, stats })
            }
            Err(e) => Err(e),
        }
    }

    /// One contact-free solve at `bones` (the contact gate's attempt).
    pub(super) fn solve_contact_free(
        &self,
        frame: &super::simulator::Frame,
        bones: &BonePose,
        state: &mut SimState,
        settings: &SolveSettings,
    ) -> Result<SolveStats, SimError> {
        self.solve_stage(frame, None, bones, state, settings)
    }

    /// The full contact solve: the bones moved to the new pose in collision-free stages
    /// (the tissue carried along with them where that is certified, see `staging`), the
    /// barrier in every stage, and the crossing audit at the end when the settings ask for it.
    fn solve_with_contact(
        &self,
        model: &ContactModel,
        frame: &super::simulator::Frame,
        actuations: &[SymTensor],
        bones: &BonePose,
        state: &mut SimState,
        settings: &SolveSettings,
    ) -> Result<SolveStats, SimError> {
        let start = Instant::now();

        // Reach the new pose in stages the step filter certifies free of crossings, each starting
        // with the tissue carried along with the bones when that is certified too (see
        // `staging`), solving after each.
        let from = state.bones;
        // From a warm start, a stage shorter than this (of the whole swing) gives the warm
        // path up: the frame is solved from rest instead (see `Simulator::solve`).
        let shortest = if self.at_rest(state) {
            SHORTEST_STAGE
        } else {
            model.shortest_warm_stage
        };
        let mut reached = 0.0;
        let mut total: Option<SolveStats> = None;
        let mut stages = 0;
        let mut carried_stages = 0;
        let mut staging = Duration::ZERO;
        // The next stage's first try: the rest of the swing, or twice the last stage when
        // that had to be shortened (a refused try costs the CCD of its whole path: on the
        // neutral's jump from jawOpen 1 back to rest, the tries of the whole remainder after
        // each shortened stage took 1–15 s apiece).
        let mut span: f64 = 1.0;
        loop {
            let mut s = (reached + span).min(1.0);
            let here = lerp_pose(&from, bones, reached);
            // Only a pose change moves anything (an unchanged jaw needs no broad phase here).
            let staging_start = Instant::now();
            let carry = if here == *bones {
                None
            } else {
                let carrier = self.carrier(
                    model,
                    actuations,
                    &state.x,
                    &state.steps,
                    &here,
                    state.contact_cache.as_ref(),
                )?;
                let gap = carrier.closest_gap();
                loop {
                    let pose = lerp_pose(&from, bones, s);
                    if let Some(start) = self.stage_start(&carrier, &state.x, &pose, gap)? {
                        break Some(start);
                    }
                    // Bisection: jumping to the fraction a certificate allows (it keeps part of
                    // every gap) made more, shorter stages (measured with CCD: a random code
                    // then exceeded the stage limit).
                    s = reached + 0.5 * (s - reached);
                    if s - reached < shortest {
                        return Err(SimError::PoseUnreachable(
                            "the teeth cannot move toward the new pose without crossing the \
                             lips (the tissue is pinned against them)"
                                .into(),
                        ));
                    }
                }
            };
            staging += staging_start.elapsed();
            stages += 1;
            if stages > model.stage_limit {
                return Err(SimError::PoseUnreachable(format!(
                    "reaching it needed more than {} collision-free stages",
                    model.stage_limit
                )));
            }
            if let Some(StageStart::Carried(dx)) = carry {
                axpy(1.0, &dx, &mut state.x);
                carried_stages += 1;
            }
            let pose = lerp_pose(&from, bones, s);
            let stage_frame;
            let f = if s == 1.0 {
                frame
            } else {
                stage_frame = self.frame(actuations, &pose)?;
                &stage_frame
            };
            // An intermediate stage only has to end valid (the next one starts from it), not
            // converged.
            let stage_settings = SolveSettings {
                max_iterations: if s == 1.0 {
                    settings.max_iterations
                } else {
                    settings.max_iterations.min(STAGE_ITERATIONS)
                },
                ..*settings
            };
            let result = self.solve_stage(f, Some(model), &pose, state, &stage_settings);
            state.bones = pose;
            let stats = match result {
                Ok(stats) => stats,
                Err(SimError::Inverted {
                    count,
                    first,
                    mut stats,
                }) if s == 1.0 => {
                    merge_stages(&mut stats, total, stages, carried_stages);
                    return Err(SimError::Inverted {
                        count,
                        first,
                        stats,
                    });
                }
                Err(e) => return Err(e),
            };
            let mut stats = stats;
            merge_stages(&mut stats, total.take(), stages, carried_stages);
            total = Some(stats);
            if s == 1.0 {
                break;
            }
            span = 2.0 * (s - reached);
            reached = s;
        }
        let mut stats = total.expect("at least one stage ran");
        state.contact_stiffness = stats.contact.as_ref().map(|c| c.stiffness);
        if let Some(c) = stats.contact.as_mut() {
            c.staging_time = staging;
        }
        // The intersection-free guarantee, audited on what the artist sees.
        let crossings = settings
            .audit_crossings
            .then(|| self.audit_crossings(model, &state.x, bones, &mut stats));
        stats.wall_time = start.elapsed();
        if let Some(count @ 1..) = crossings {
            return Err(SimError::Intersecting {
                count,
                stats: Box::new(stats),
            });
        }
        Ok(stats)
    }

    /// The contact surface's crossings at `x` that were not there at rest, recorded in the
    /// contact stats with the check's time.
    fn audit_crossings(
        &self,
        model: &ContactModel,
        x: &[f64],
        bones: &BonePose,
        stats: &mut SolveStats,
    ) -> usize {
        let check_start = Instant::now();
        let mut y = vec![0.0; 3 * model.face.vertex_count()];
        model.face.positions(x, bones, &mut y);
        let count = model.face.new_crossings_of_solve(&y).len();
        if let Some(c) = stats.contact.as_mut() {
            c.check_time = check_start.elapsed();
            c.new_crossings = Some(count);
        }
        count
    }

    /// One solve at fixed bones (with the rigid contact surfaces already there).
    fn solve_stage(
        &self,
        frame: &super::simulator::Frame,
        model: Option<&ContactModel>,
        bones: &BonePose,
        state: &mut SimState,
        settings: &SolveSettings,
    ) -> Result<SolveStats, SimError> {
        let start = Instant::now();
        let dim = state.x.len();
        let scale = self.force_scale(frame);

        // Per-element buffers live in the state: the current one is updated in place (its
        // rotations are the warm start), the spare one takes line-search trials.
        let mut steps = std::mem::take(&mut state.steps);
        let mut trial_steps = std::mem::take(&mut state.spare);
        trial_steps.resize(steps.len(), LocalStep::default());
        let restore = |state: &mut SimState, steps, trial_steps| {
            state.steps = steps;
            state.spare = trial_steps;
        };
        let mut energy = self.local_sweep(frame, &state.x, None, &mut steps);
        let mut g = vec![0.0; dim];
        self.gradient(frame, &state.x, &steps, &mut g);
        let mut contact = match model {
            Some(m) => match ContactSolve::start_solve(
                m,
                &state.x,
                bones,
                &g,
                state.contact_cache.as_ref(),
            ) {
                Ok(c) => Some(c),
                Err(e) => {
                    restore(state, steps, trial_steps);
                    return Err(e.into());
                }
            },
            None => None,
        };
        if let Some(c) = contact.as_mut() {
            energy += c.energy();
            if let Err(e) = c.add_gradient(&mut g) {
                restore(state, steps, trial_steps);
                return Err(e.into());
            }
        }
        let mut residual = norm(&g) / scale;
        let folded = steps.iter().filter(|s| !(s.volume_ratio > 0.0)).count();
        if folded > 0 {
            restore(state, steps, trial_steps);
            return Err(SimError::FoldedStart(folded));
        }
        if !energy.is_finite() || !residual.is_finite() {
            restore(state, steps, trial_steps);
            return Err(SimError::NonFiniteState(0));
        }
        let initial_residual = residual;
        let mut energy_history = vec![energy];

        let mut history = match state.history.take() {
            Some(h) if h.capacity() == settings.history && h.dimension() == dim => h,
            _ => History::new(settings.history, dim),
        };
        let mut scratch = self.solve_scratch();
        // H₀ with the curvature L lacks (contact's barrier, the volume barrier), rebuilt at
        // every accepted point.
        let (mut step_inverse, mut near_folding) = match self.step_inverse(&steps, contact.as_mut())
        {
            Ok(built) => built,
            Err(e) => {
                restore(state, steps, trial_steps);
                return Err(e);
            }
        };
        let mut d = vec![0.0; dim];
        let mut x_trial = vec![0.0; dim];
        let mut g_trial = vec![0.0; dim];
        let mut iterations = 0;
        let mut evaluations = 1;
        let mut local_time = Duration::ZERO;
        let mut global_time = Duration::ZERO;
        let mut termination = Termination::IterationCap;

        let loop_start = Instant::now();
        let outcome: Result<(), SimError> = (|| {
            while residual > settings.tolerance {
                if iterations == settings.max_iterations {
                    break;
                }
                let mut h0 = |v: &mut [f64]| step_inverse.apply(&self.global, v, &mut scratch);
                // The L-BFGS direction, restarted as plain PD when the curvature pairs fail
                // it: it is not a descent direction (lost curvature information), or the
                // contact filter allows almost nothing of it (the pairs' own steps were that
                // short too, so they say little; PD's step the filter lets through).
                // And when the last step changed which contact pairs are active (K, in H₀, is
                // refreshed at every step): pairs from steps where other contact pairs were
                // active point the step far past the barrier, and the filter then cuts it
                // to a sliver. Measured (`bench editor --contact`, one thread, one run):
                // keeping the pairs across such changes, every interactive frame hit the
                // 30-iteration cap (785 ms median); clearing them at every contact step,
                // 177 ms but 143 final iterations (1.6 s); clearing them only when the
                // active set changes, 189 ms and 46 final iterations (0.66 s).
                if contact.as_ref().is_some_and(|c| c.contact_changed()) {
                    history.clear();
                }
                let (slope, mut alpha) = loop {
                    global_time += history.direction(&mut h0, &g, &mut d);
                    let slope = dot(&g, &d);
                    if !(slope < 0.0) && !history.is_empty() {
                        history.clear();
                        continue;
                    }
                    let alpha = match contact.as_mut() {
                        Some(c) => c.max_step(&d)?,
                        None => 1.0,
                    };
                    if alpha < SHORT_STEP && !history.is_empty() {
                        history.clear();
                        continue;
                    }
                    break (slope, alpha);
                };
                alpha = alpha.min(self.volume_step_limit(&steps, &d));
                let mut accepted = None;
                if alpha > 0.0 {
                    for _ in 0..MAX_BACKTRACKS {
                        for i in 0..dim {
                            x_trial[i] = state.x[i] + alpha * d[i];
                        }
                        let sweep_start = Instant::now();
                        let mut e =
                            self.local_sweep(frame, &x_trial, Some(&steps), &mut trial_steps);
                        local_time += sweep_start.elapsed();
                        if let Some(c) = contact.as_mut() {
                            e += c.trial_energy(alpha)?;
                        }
                        evaluations += 1;
                        if e.is_finite() {
                            if e <= energy + ARMIJO * alpha * slope {
                                accepted = Some(e);
                                break;
                            }
                            if (alpha * slope).abs() <= ROUND_OFF * energy.abs()
                                && e <= energy * (1.0 + ROUND_OFF)
                            {
                                // The energy cannot resolve this step; take it if it reduces
                                // the gradient.
                                self.gradient(frame, &x_trial, &trial_steps, &mut g_trial);
                                if let Some(c) = contact.as_mut() {
                                    c.add_trial_gradient(&mut g_trial)?;
                                }
                                if norm(&g_trial) < norm(&g) {
                                    accepted = Some(e);
                                    break;
                                }
                            }
                        }
                        alpha *= 0.5;
                    }
                }
                let Some(e) = accepted else {
                    termination = Termination::Stalled;
                    break;
                };
                self.gradient(frame, &x_trial, &trial_steps, &mut g_trial);
                let mut e = e;
                if let Some(c) = contact.as_mut() {
                    // Move the contact state along; κ may change, so the energy and the
                    // gradient are taken with the new κ.
                    let e_el = e - c.trial_energy_value();
                    e = e_el + c.accept()?;
                    c.add_gradient(&mut g_trial)?;
                }
                history.push(&x_trial, &state.x, &g_trial, &g);
                std::mem::swap(&mut state.x, &mut x_trial);
                std::mem::swap(&mut g, &mut g_trial);
                std::mem::swap(&mut steps, &mut trial_steps);
                // The preconditioner is rebuilt when its contact curvature is (see
                // `ContactSolve::accept`); in between, L-BFGS's pairs follow the change, and
                // only the count of elements near folding is taken.
                let near = if contact.as_ref().is_none_or(|c| c.curvature_refreshed()) {
                    let (inverse, near) = self.step_inverse(&steps, contact.as_mut())?;
                    step_inverse = inverse;
                    near
                } else {
                    self.volume_barrier_curvature(&steps).columns.len()
                };
                near_folding = near_folding.max(near);
                energy = e;
                residual = norm(&g) / scale;
                iterations += 1;
                energy_history.push(energy);
            }
            Ok(())
        })();
        let iteration_time = loop_start.elapsed();
        state.history = Some(history);
        if let Err(e) = outcome {
            restore(state, steps, trial_steps);
            return Err(e);
        }
        if residual <= settings.tolerance {
            termination = Termination::Converged;
        }
        let contact = contact.map(|c| {
            let (stats, cache) = c.finish();
            state.contact_cache = cache;
            stats
        });
        let inverted: Vec<usize> = (0..steps.len())
            .filter(|&e| !(steps[e].volume_ratio > 0.0))
            .collect();
        restore(state, steps, trial_steps);
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
            near_folding,
            contact,
            from_rest: false,
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

/// Factor columns of `K` per simulation vertex above which a step's `(L + K)⁻¹` is factored
/// afresh rather than updated: Woodbury's `r × r` Cholesky grows as `r³`, a sparse
/// factorization of `L⊗I₃ + K` costs about the same whatever `r`. Measured on a random jump
/// from rest with the lips pressed (seed 102's frame 0, 2,625 vertices, one thread; columns:
/// Woodbury against refactoring, ms per step): ~1,000: 28 / 41, ~1,250: 53 / 49, ~1,500:
/// 78 / 54. Where the factorization fails (a non-positive pivot), the step falls back to
/// Woodbury.
const REFACTOR_COLUMNS_PER_VERTEX: f64 = 0.5;

impl Simulator {
    /// `H₀` at the state of the local `steps`: `L⁻¹` plus, by a low-rank update, the
    /// curvature of the contact barrier and of the volume barrier; and how many elements are
    /// near folding.
    pub(super) fn step_inverse(
        &self,
        steps: &[LocalStep],
        contact: Option<&mut ContactSolve>,
    ) -> Result<(StepInverse, usize), SimError> {
        let start = Instant::now();
        let barrier = self.volume_barrier_curvature(steps);
        let near = barrier.columns.len();
        let (curvature, mode) = match &contact {
            Some(c) => (c.curvature().clone().plus(barrier), c.step_mode()),
            None => (barrier, ContactStep::LowRankUpdate),
        };
        let refactor = mode == ContactStep::LowRankUpdate
            && curvature.columns.len() as f64
                > REFACTOR_COLUMNS_PER_VERTEX * self.vertex_count() as f64;
        let inverse = if refactor {
            // The sparse factorization can meet a non-positive pivot where the barrier's
            // curvature dwarfs `L` (seed 105's frame 3); Woodbury's `I + UᵀL⁻¹U` cannot.
            StepInverse::new(
                &self.global,
                &self.inverse_columns,
                curvature.clone(),
                ContactStep::Refactor,
            )
            .or_else(|_| StepInverse::new(&self.global, &self.inverse_columns, curvature, mode))
        } else {
            StepInverse::new(&self.global, &self.inverse_columns, curvature, mode)
        }
        .map_err(SimError::Setup)?;
        if let Some(c) = contact {
            c.stats.linear_time += start.elapsed();
        }
        Ok((inverse, near))
    }
}

/// Folds the statistics of earlier pose stages into the last one's.
fn merge_stages(
    last: &mut SolveStats,
    earlier: Option<SolveStats>,
    stages: usize,
    carried_stages: usize,
) {
    if let Some(c) = last.contact.as_mut() {
        c.pose_stages = stages;
        c.carried_stages = carried_stages;
    }
    let Some(e) = earlier else {
        return;
    };
    last.iterations += e.iterations;
    last.evaluations += e.evaluations;
    last.initial_residual = e.initial_residual;
    last.local_time += e.local_time;
    last.global_time += e.global_time;
    last.iteration_time += e.iteration_time;
    last.near_folding = last.near_folding.max(e.near_folding);
    let mut history = e.energy_history;
    history.extend_from_slice(&last.energy_history);
    last.energy_history = history;
    if let (Some(c), Some(ec)) = (last.contact.as_mut(), e.contact) {
        c.filter_limited_steps += ec.filter_limited_steps;
        c.candidate_builds += ec.candidate_builds;
        c.candidate_pairs += ec.candidate_pairs;
        c.broad_phase_time += ec.broad_phase_time;
        c.barrier_time += ec.barrier_time;
        c.filter_time += ec.filter_time;
        c.linear_time += ec.linear_time;
    }
}
