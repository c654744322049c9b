//! Contact only when the surfaces can meet: a contact solve first tries the cheap
//! contact-free solve from the same start and keeps its result when it is certified to be
//! an equilibrium with contact too, by the same stopping rule a contact solve ends with.
//!
//! Why this is sound: the barrier `κ·B(y)` is zero, with zero gradient, wherever every pair
//! of contact primitives is at least d̂ apart, and its force falls off quadratically as a
//! pair's distance approaches d̂ from below. So a contact-free result `x*` is accepted when
//! (a) the residual of the energy *with* contact at `x*` (κ chosen by the rule a contact
//! solve starting at `x*` uses) passes the tolerance — exactly zero barrier when no pair is
//! within d̂; on the closed mouth of the sample, whose rest lips are repaired to exactly d̂
//! apart, small expressions bring lip pairs a hair inside d̂ with negligible force. Two more
//! checks make it a *valid* result: (b) no edge crosses a triangle at `x*` (the after-solve
//! check every contact solve ends with), and (c) the straight-line motion of the contact
//! surfaces (teeth included) from the start state to `x*` is collision-free (the solver's step
//! filter, `contact::refined`), so the lips did not pass through each other or the teeth on
//! the way (a lip pushed entirely through the other ends with no crossing and no close pair,
//! and is still wrong). When any
//! check fails the attempt is discarded — it ran on a copy of the state, so nothing of it
//! (positions, L-BFGS history, rotations, bones) leaks — and the full contact solve runs
//! from the original state.
//!
//! The attempt costs a contact-free solve (tens of ms on the coarse sample) plus the checks;
//! a full contact solve costs hundreds. To not pay the attempt on every frame where it is
//! bound to be refused (lips pressed stay pressed from one frame of a drag to the next), the
//! state keeps a backoff: after `n` refusals in a row the next `2ⁿ − 1` frames (at most 15)
//! go straight to the full solve; an accepted attempt resets it.

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::attachment::BonePose;
use super::contact::{ContactModel, ContactStats};
use super::simulator::{Frame, SimError, SimState, Simulator};
use super::solver::{SolveSettings, SolveStats};
use super::vector::{axpy, norm};
use crate::contact::barrier::initial_barrier_stiffness;
use crate::contact::{BarrierPotential, Candidates, Collisions, ContactError, refined_step_over};

/// The share of each pair's gap the path check keeps (see (c) in `attempt_contact_free`).
const GATE_KEEP: f64 = 0.01;

/// Whether a contact solve may keep a verified contact-free result.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ContactGate {
    /// Every contact solve runs the full IPC machinery (broad phase, step filter, barrier, pose
    /// stages), even when the surfaces are far apart.
    Always,
    /// Try contact-free first and keep the result when it is certified (module doc).
    #[default]
    WhenNeeded,
}

/// What the gate decided for one contact solve ([`ContactStats::gate`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GateOutcome {
    /// The gate was off ([`ContactGate::Always`]): the full contact solve ran.
    #[default]
    Off,
    /// The contact-free result was certified and kept: no contact machinery ran.
    Skipped,
    /// Not tried: the last attempts on this state's sequence were refused, and the gate
    /// waits a few frames before trying again ([`Backoff`]). The full solve ran.
    Backoff,
    /// The contact-free solve itself failed (e.g. folded elements). The full solve ran.
    ContactFreeFailed,
    /// Refused: pairs within d̂ at the contact-free result push hard enough that the
    /// residual with contact fails the stopping rule. The full solve ran.
    Near,
    /// Refused: the contact-free result has crossings (or touching surfaces). The full
    /// solve ran.
    Crossing,
    /// Refused: the straight-line motion to the contact-free result passes through a
    /// surface. The full solve ran.
    PathCrosses,
}

impl GateOutcome {
    pub fn skipped(self) -> bool {
        self == GateOutcome::Skipped
    }

    /// The contact-free attempt ran and its result was refused (its time was wasted).
    pub fn refused(self) -> bool {
        matches!(
            self,
            GateOutcome::ContactFreeFailed
                | GateOutcome::Near
                | GateOutcome::Crossing
                | GateOutcome::PathCrosses
        )
    }
}

/// The attempt's result: a certified solve, or why not.
pub(crate) enum Attempt {
    Accepted(Box<SolveStats>),
    Refused(GateOutcome),
}

impl Simulator {
    /// Chooses whether contact solves may keep a certified contact-free result (the
    /// default, [`ContactGate::WhenNeeded`]) or always run the full contact solve.
    pub fn set_contact_gate(&mut self, gate: ContactGate) {
        if let Some(c) = self.contact.as_mut() {
            c.gate = gate;
        }
    }

    /// The contact gate in use (`None` without contact surfaces).
    pub fn contact_gate(&self) -> Option<ContactGate> {
        self.contact.as_ref().map(|c| c.gate)
    }

    /// The contact-free solve from `state`, certified against `model` (module doc). On
    /// acceptance `state` holds the result; otherwise it is untouched. Errors only for
    /// contact-geometry failures of the checks themselves.
    pub(crate) fn try_contact_free(
        &self,
        model: &ContactModel,
        frame: &Frame,
        bones: &BonePose,
        state: &mut SimState,
        settings: &SolveSettings,
    ) -> Result<Attempt, SimError> {
        if state.gate_backoff.wait > 0 {
            state.gate_backoff.wait -= 1;
            return Ok(Attempt::Refused(GateOutcome::Backoff));
        }
        let attempt = self.attempt_contact_free(model, frame, bones, state, settings)?;
        match &attempt {
            Attempt::Accepted(_) => state.gate_backoff = Backoff::default(),
            Attempt::Refused(_) => state.gate_backoff.refused(),
        }
        Ok(attempt)
    }

    /// The attempt itself: `state` holds the result if it is accepted, else is untouched.
    fn attempt_contact_free(
        &self,
        model: &ContactModel,
        frame: &Frame,
        bones: &BonePose,
        state: &mut SimState,
        settings: &SolveSettings,
    ) -> Result<Attempt, SimError> {
        let start = Instant::now();
        let face = &model.face;
        let mut trial = state.clone();
        let Ok(mut stats) = self.solve_contact_free(frame, bones, &mut trial, settings) else {
            return Ok(Attempt::Refused(GateOutcome::ContactFreeFailed));
        };
        let m = 3 * face.vertex_count();
        let (mut y0, mut y1) = (vec![0.0; m], vec![0.0; m]);
        face.positions(&state.x, &state.bones, &mut y0);
        face.positions(&trial.x, bones, &mut y1);
        let dy: Vec<f64> = y1.iter().zip(&y0).map(|(b, a)| b - a).collect();
        // One broad phase serves (a) and (c): boxes swept along the motion and grown by d̂
        // hold every pair within d̂ at the result and every pair that can meet on the way.
        let candidates = Candidates::build_swept(face.mesh(), &y0, &dy, face.dhat())?;
        // (a) The barrier changes nothing the stopping rule can see: with the stiffness a
        // contact solve would start with here, the residual of the energy with contact is
        // within the tolerance (or, for a result the iteration cap stopped, no larger than
        // the contact-free one). With no pair within d̂ the barrier is exactly zero.
        let collisions =
            match Collisions::from_candidates(face.mesh(), &candidates, &y1, face.dhat()) {
                Ok(c) => c,
                // Surfaces touching (distance 0) at the result: certainly not contact-free.
                Err(ContactError::Touching { .. }) => {
                    return Ok(Attempt::Refused(GateOutcome::Crossing));
                }
                Err(e) => return Err(e.into()),
            };
        let dim = trial.x.len();
        let scale = self.force_scale(frame);
        let mut g = vec![0.0; dim];
        self.gradient(frame, &trial.x, &trial.steps, &mut g);
        let elastic_residual = norm(&g) / scale;
        let unit = BarrierPotential::new(face.dhat(), 1.0)?;
        let mut gb = vec![0.0; dim];
        if !collisions.is_empty() {
            let mut gb_y = vec![0.0; m];
            unit.add_gradient(&collisions, &y1, &mut gb_y)?;
            face.add_pulled_back(&gb_y, &mut gb);
        }
        let (kappa, _) = initial_barrier_stiffness(
            face.mesh().bbox_diagonal(&y1),
            face.dhat(),
            model.stiffness_scale,
            &g,
            &gb,
            1e11,
        );
        axpy(kappa, &gb, &mut g);
        let residual = norm(&g) / scale;
        if !(residual <= settings.tolerance.max(elastic_residual)) {
            return Ok(Attempt::Refused(GateOutcome::Near));
        }
        // (c) Nothing passed through on the way (teeth included: the bones moved too): every
        // pair keeps part of its gap along the whole path (`contact::refined`; sufficient, not
        // necessary, so a refusal only costs the full solve). (a) already refused results
        // with pairs pressed close, so keeping a hundredth of each gap is enough here.
        let path = refined_step_over(face.mesh(), &candidates, &y0, &dy, GATE_KEEP)?;
        if path.step < 1.0 {
            return Ok(Attempt::Refused(GateOutcome::PathCrosses));
        }
        // (b) Nothing crosses at the result (pairs the barrier leaves out included: the
        // check every contact solve ends with).
        if !face.new_crossings(&y1).is_empty() {
            return Ok(Attempt::Refused(GateOutcome::Crossing));
        }
        let barrier = kappa * unit.value(&collisions, &y1)?;
        *state = trial;
        state.bones = *bones;
        state.contact_stiffness = Some(kappa);
        stats.energy += barrier;
        stats.residual = residual;
        if let Some(last) = stats.energy_history.last_mut() {
            *last += barrier;
        }
        stats.contact = Some(ContactStats {
            active_pairs: collisions.len(),
            min_distance: collisions.min_distance_squared().sqrt(),
            stiffness: kappa,
            pose_stages: 1,
            new_crossings: Some(0),
            gate: GateOutcome::Skipped,
            gate_time: start.elapsed(),
            ..ContactStats::default()
        });
        Ok(Attempt::Accepted(Box::new(stats)))
    }
}

/// How many frames the gate waits before trying again: after `n` refusals in a row it
/// goes straight to the full solve for `2ⁿ − 1` frames (1, 3, 7, then 15 at most), so a
/// sequence in persistent contact (a drag with the lips pressed) wastes a few attempts, not
/// one per frame, while one that separates is tried again soon.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Backoff {
    refusals: u32,
    pub(crate) wait: u32,
}

impl Backoff {
    fn refused(&mut self) {
        self.refusals = (self.refusals + 1).min(MAX_BACKOFF);
        self.wait = (1 << self.refusals) - 1;
    }
}

/// Refusals in a row beyond which the wait stops growing (15 frames).
const MAX_BACKOFF: u32 = 4;

/// Records in a full solve's stats why the gate let it run and the time the attempt
/// before it took (wasted).
pub(crate) fn note_refusal(stats: &mut SolveStats, outcome: GateOutcome, attempt: Duration) {
    if let Some(c) = stats.contact.as_mut() {
        c.gate = outcome;
        c.gate_time = attempt;
    }
}

#[cfg(test)]
mod tests {
    use super::{ContactGate, GateOutcome};
    use crate::bench::mouth_poses::{LipField, MouthPose};
    use crate::contact::surface::FaceContact;
    use crate::model::contact_region::FaceContactSettings;
    use crate::sim::{BonePose, Quality, SimState, Simulator, SolveSettings, SolveStats};

    /// The coarse neutral with contact surfaces and its lip field.
    fn setup() -> (Simulator, LipField) {
        let model = crate::model::test_support::coarse_face(None);
        let face = FaceContact::new(model, &FaceContactSettings::default()).unwrap();
        let field = LipField::new(model, &face, 1.5);
        let mut sim = model.simulator().unwrap();
        sim.set_contact(face).unwrap();
        (sim, field)
    }

    fn solve(
        sim: &Simulator,
        field: &LipField,
        pose: &MouthPose,
        state: &mut SimState,
        settings: &SolveSettings,
    ) -> SolveStats {
        sim.solve(&field.actuations(pose), &pose.bones(), state, settings)
            .unwrap_or_else(|e| panic!("{pose:?}: {e}"))
    }

    /// Independent checks of a returned contact result: no pair closer than the barrier
    /// allows and no crossing.
    fn assert_valid(sim: &Simulator, state: &SimState, bones: &BonePose) {
        let face = sim.contact().unwrap();
        let mut y = vec![0.0; 3 * face.vertex_count()];
        face.positions(state.flat_positions(), bones, &mut y);
        assert!(face.new_crossings(&y).is_empty());
        assert!(state.flat_positions().iter().all(|v| v.is_finite()));
    }

    fn max_difference(a: &SimState, b: &SimState) -> f64 {
        a.flat_positions()
            .iter()
            .zip(b.flat_positions())
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max)
    }

    /// Lips pressed lightly (or pursed, or the jaw clenched a hair): pairs of the closed
    /// lips, repaired to d̂ apart at rest, come a little inside d̂ with negligible force, so the
    /// gate keeps the contact-free result without running the contact machinery. It is the
    /// equilibrium the full contact solve finds, to solver tolerance, intersection-free.
    /// (On this face opening the jaw is no such case: contact-free, the mouth's lining
    /// moves into the upper teeth.)
    #[test]
    fn negligible_contact_skips_the_machinery_and_matches_the_full_contact_solve() {
        let (mut sim, field) = setup();
        assert_eq!(sim.contact_gate(), Some(ContactGate::WhenNeeded));
        let settings = Quality::Preview.settings();
        for pose in [
            MouthPose {
                press: 0.02,
                ..MouthPose::default()
            },
            MouthPose {
                jaw_open: -0.001,
                ..MouthPose::default()
            },
        ] {
            sim.set_contact_gate(ContactGate::WhenNeeded);
            let mut skipped = sim.rest_state();
            let stats = solve(&sim, &field, &pose, &mut skipped, &settings);
            let c = stats.contact.as_ref().expect("contact was on");
            assert_eq!(c.gate, GateOutcome::Skipped, "{pose:?}: {c:?}");
            assert_eq!(c.candidate_builds, 0, "no contact machinery ran");
            assert!(c.min_distance > 0.0 && c.stiffness > 0.0);
            assert!(stats.converged() && stats.residual <= settings.tolerance);
            assert_valid(&sim, &skipped, &pose.bones());

            sim.set_contact_gate(ContactGate::Always);
            let mut full = sim.rest_state();
            let stats = solve(&sim, &field, &pose, &mut full, &settings);
            let f = stats.contact.as_ref().unwrap();
            assert_eq!(f.gate, GateOutcome::Off);
            assert!(f.candidate_builds > 0, "the full solve ran the broad phase");
            assert!(stats.converged());
            let diff = max_difference(&skipped, &full);
            // Both converged to 1e-6 of the force scale on a face a few cm across.
            assert!(
                diff < 1e-3,
                "{pose:?}: skipped vs full contact solve: {diff:e} cm"
            );
            eprintln!(
                "{pose:?}: skipped vs full: {diff:.1e} cm apart, {} vs {} active pairs",
                c.active_pairs, f.active_pairs
            );
        }
    }

    /// Lips pressed and rolled in at the ends of their ranges: the contact-free result brings
    /// them within d̂ (or through each other), so the gate refuses it and the full contact
    /// solve runs from the original state — bitwise the result of the gate being off, so the
    /// attempt left nothing behind (positions, history, rotations, bones). The next frame
    /// starts in contact and goes straight to the full solve.
    #[test]
    fn pressed_lips_refuse_the_skip_and_fall_back_to_the_full_contact_solve() {
        let (mut sim, field) = setup();
        let settings = Quality::Interactive.settings();
        let poses = [
            MouthPose {
                press: 1.0,
                purse: 0.5,
                ..MouthPose::default()
            },
            MouthPose {
                press: 1.0,
                roll: 1.0,
                ..MouthPose::default()
            },
        ];
        let mut gated = sim.rest_state();
        let mut outcomes = Vec::new();
        for pose in &poses {
            let stats = solve(&sim, &field, pose, &mut gated, &settings);
            let c = stats.contact.unwrap();
            assert!(c.active_pairs > 0, "{pose:?}: the lips must be in contact");
            assert_valid(&sim, &gated, &pose.bones());
            outcomes.push(c.gate);
        }
        let refused = |g: GateOutcome| {
            matches!(
                g,
                GateOutcome::Near | GateOutcome::Crossing | GateOutcome::PathCrosses
            )
        };
        assert!(refused(outcomes[0]), "{outcomes:?}");
        // Refused once: the next frame goes straight to the full solve.
        assert_eq!(outcomes[1], GateOutcome::Backoff, "{outcomes:?}");

        sim.set_contact_gate(ContactGate::Always);
        let mut always = sim.rest_state();
        for pose in &poses {
            solve(&sim, &field, pose, &mut always, &settings);
        }
        assert_eq!(gated.flat_positions(), always.flat_positions());
    }

    /// Refusals in a row wait 1, 3, 7, then 15 frames; an acceptance resets.
    #[test]
    fn the_backoff_doubles_up_to_fifteen_frames() {
        let mut b = super::Backoff::default();
        let waits: Vec<u32> = (0..6)
            .map(|_| {
                b.refused();
                b.wait
            })
            .collect();
        assert_eq!(waits, [1, 3, 7, 15, 15, 15]);
    }

    /// Same inputs from the same start give bitwise the same result, skipped or not.
    #[test]
    fn the_gate_is_deterministic() {
        let (sim, field) = setup();
        let settings = Quality::Interactive.settings();
        let poses = [
            MouthPose {
                purse: 0.05,
                ..MouthPose::default()
            },
            MouthPose {
                press: 1.0,
                purse: 0.5,
                ..MouthPose::default()
            },
        ];
        let run = || {
            let mut state = sim.rest_state();
            let gates: Vec<GateOutcome> = poses
                .iter()
                .map(|p| {
                    solve(&sim, &field, p, &mut state, &settings)
                        .contact
                        .unwrap()
                        .gate
                })
                .collect();
            (state, gates)
        };
        let (a, ga) = run();
        let (b, gb) = run();
        assert_eq!(ga, gb);
        assert_eq!(ga[0], GateOutcome::Skipped);
        assert_ne!(ga[1], GateOutcome::Skipped);
        assert_eq!(a.flat_positions(), b.flat_positions());
    }
}
