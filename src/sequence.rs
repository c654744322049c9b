//! The frame loop: frames solved one after another, each warm-started from the last good one.
//! The editor's session, the export (through the session), the benchmarks, the contact sweep
//! and the evaluation all solve through a [`Sequence`], so they share its rules:
//! - a frame that fails (actuation error, solve error, non-finite positions) never becomes the
//!   next frame's start: the state goes back to the last good frame (or to rest, with
//!   [`Recovery::Rest`]);
//! - a contact solve starts from a state without crossings: from the last frame solved with
//!   contact, else from rest (a contact-free solve may leave the lips crossed, and the
//!   barrier cannot undo a crossing).

use std::borrow::Borrow;
use std::time::Instant;

use crate::drive::{ActuationModel, Codes, DriveError};
use crate::sim::{BonePose, SimError, SimState, Simulator, SolveSettings, SolveStats, SymTensor};

/// Why a frame failed.
#[derive(Debug, thiserror::Error)]
pub enum FrameFailure {
    #[error(transparent)]
    Actuation(#[from] DriveError),
    #[error(transparent)]
    Solve(#[from] SimError),
    #[error("the solve left non-finite positions")]
    NonFinite,
}

impl FrameFailure {
    /// The solve ended with inverted elements.
    pub fn inverted(&self) -> bool {
        matches!(self, FrameFailure::Solve(SimError::Inverted { .. }))
    }

    /// The contact surfaces crossed after the solve.
    pub fn intersecting(&self) -> bool {
        matches!(self, FrameFailure::Solve(SimError::Intersecting { .. }))
    }
}

/// Where the next frame starts after a failed one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Recovery {
    /// From the last frame that solved.
    #[default]
    LastGood,
    /// From rest (the contact sweep measures every frame from a known start).
    Rest,
}

/// The warm-start state of a run of frames on one simulator (owned, or borrowed: `S` is a
/// [`Simulator`] or a reference to one).
pub struct Sequence<S: Borrow<Simulator>> {
    sim: S,
    /// The last good frame's state: where the next solve starts.
    state: SimState,
    /// The last good frame's positions, what a failure restores (only the positions: copying
    /// the whole state, with its solver memory and contact cache, at every frame would cost
    /// the editor more than a fresh memory costs the one frame after a failure).
    good: Vec<f64>,
    /// `state` holds no crossings: rest, or solved with contact.
    crossing_free: bool,
    recovery: Recovery,
}

impl<S: Borrow<Simulator>> Sequence<S> {
    /// A sequence that starts at rest and recovers from failures at the last good frame.
    pub fn new(sim: S) -> Self {
        let state = sim.borrow().rest_state();
        Sequence {
            good: state.flat_positions().to_vec(),
            state,
            sim,
            crossing_free: true,
            recovery: Recovery::LastGood,
        }
    }

    /// The same sequence, recovering from failures as `recovery` says.
    pub fn with_recovery(mut self, recovery: Recovery) -> Self {
        self.recovery = recovery;
        self
    }

    pub fn simulator(&self) -> &Simulator {
        self.sim.borrow()
    }

    /// The last good frame's state (the rest state before the first frame).
    pub fn state(&self) -> &SimState {
        &self.state
    }

    /// Starts the next frame from rest.
    pub fn restart(&mut self) {
        self.state = self.simulator().rest_state();
        self.keep_good();
        self.crossing_free = true;
    }

    fn keep_good(&mut self) {
        self.good.clear();
        self.good.extend_from_slice(self.state.flat_positions());
    }

    /// Solves one frame under `actuations` (one per element) and `bones`, from the last good
    /// frame; on success that frame is the next one's start, on failure the state recovers
    /// (see [`Recovery`]) and the error says why.
    pub fn solve(
        &mut self,
        actuations: &[SymTensor],
        bones: &BonePose,
        settings: &SolveSettings,
    ) -> Result<SolveStats, FrameFailure> {
        if settings.contact && !self.crossing_free {
            self.restart();
        }
        let result = solve_in(
            self.sim.borrow(),
            &mut self.state,
            actuations,
            bones,
            settings,
        );
        match &result {
            Ok(_) => {
                self.crossing_free = settings.contact;
                self.keep_good();
            }
            // The last good frame was as free of crossings as the start was.
            Err(_) => match self.recovery {
                Recovery::LastGood => {
                    let good: Vec<_> = self
                        .good
                        .chunks_exact(3)
                        .map(|p| nalgebra::Point3::new(p[0], p[1], p[2]))
                        .collect();
                    self.state = self
                        .simulator()
                        .state_at(&good)
                        .expect("the last good frame is a state of this simulator");
                }
                Recovery::Rest => self.restart(),
            },
        }
        result
    }

    /// Solves one frame as [`Sequence::solve`] would, from the same start, into a state of
    /// its own; the sequence does not move (to compare settings from one start).
    pub fn solve_aside(
        &self,
        actuations: &[SymTensor],
        bones: &BonePose,
        settings: &SolveSettings,
    ) -> (Result<SolveStats, FrameFailure>, SimState) {
        let mut state = if settings.contact && !self.crossing_free {
            self.simulator().rest_state()
        } else {
            self.state.clone()
        };
        let result = solve_in(self.simulator(), &mut state, actuations, bones, settings);
        (result, state)
    }
}

/// One solve from `state`, into it; a result with a non-finite position is a failure.
fn solve_in(
    sim: &Simulator,
    state: &mut SimState,
    actuations: &[SymTensor],
    bones: &BonePose,
    settings: &SolveSettings,
) -> Result<SolveStats, FrameFailure> {
    let stats = sim.solve(actuations, bones, state, settings)?;
    if state.flat_positions().iter().all(|v| v.is_finite()) {
        Ok(stats)
    } else {
        Err(FrameFailure::NonFinite)
    }
}

/// One frame of [`solve_codes`].
pub struct FrameResult {
    pub index: usize,
    /// Wall time of actuation and solve.
    pub ms: f64,
    pub bones: BonePose,
    /// The solve's stats, or why the frame failed.
    pub outcome: Result<SolveStats, FrameFailure>,
}

/// Solves `codes` in order on `sim`, driven by `actuation`, as the editor's session does;
/// `each(result, state)` sees every frame with the state it left (after a failure, the
/// last good frame's).
pub fn solve_codes(
    sim: &Simulator,
    actuation: &dyn ActuationModel,
    codes: &[Codes],
    settings: &SolveSettings,
    mut each: impl FnMut(&FrameResult, &SimState),
) {
    let mut sequence = Sequence::new(sim);
    for (index, c) in codes.iter().enumerate() {
        let start = Instant::now();
        let mut bones = BonePose::default();
        let outcome = actuation
            .actuate(c)
            .map_err(FrameFailure::from)
            .and_then(|a| {
                bones = a.bones();
                sequence.solve(&a.tensors, &bones, settings)
            });
        let result = FrameResult {
            index,
            ms: start.elapsed().as_secs_f64() * 1e3,
            bones,
            outcome,
        };
        each(&result, sequence.state());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{Quality, SimConfig};
    use crate::slab::SlabScene;
    use nalgebra::Matrix3;

    /// A small slab attached at its base.
    fn slab() -> Simulator {
        let scene = SlabScene::with_cells([4, 4, 2], 0.25, 3).unwrap();
        let config = SimConfig {
            jaw_pivot: scene.jaw_pivot,
            ..SimConfig::default()
        };
        Simulator::new(scene.mesh.clone(), scene.attachments.clone(), config).unwrap()
    }

    /// Every element stretched by `s` along z.
    fn stretch(sim: &Simulator, s: f64) -> Vec<SymTensor> {
        let m = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, s));
        vec![SymTensor::from_matrix(&m); sim.element_count()]
    }

    #[test]
    fn a_failed_frame_never_becomes_the_next_start() {
        let sim = slab();
        let settings = Quality::Final.settings();
        let mut seq = Sequence::new(&sim);
        seq.solve(&stretch(&sim, 1.2), &BonePose::default(), &settings)
            .unwrap();
        let good = seq.state().flat_positions().to_vec();
        let mut bad = stretch(&sim, 1.0);
        bad[0] = SymTensor::from_matrix(&Matrix3::from_diagonal_element(f64::NAN));
        assert!(seq.solve(&bad, &BonePose::default(), &settings).is_err());
        assert_eq!(
            seq.state().flat_positions(),
            &good[..],
            "back at the last good frame"
        );

        let mut from_rest = Sequence::new(&sim).with_recovery(Recovery::Rest);
        from_rest
            .solve(&stretch(&sim, 1.2), &BonePose::default(), &settings)
            .unwrap();
        assert!(
            from_rest
                .solve(&bad, &BonePose::default(), &settings)
                .is_err()
        );
        assert_eq!(
            from_rest.state().flat_positions(),
            sim.rest_state().flat_positions(),
            "back at rest"
        );
    }

    #[test]
    fn solving_aside_leaves_the_sequence_where_it_was() {
        let sim = slab();
        let settings = Quality::Final.settings();
        let mut seq = Sequence::new(&sim);
        seq.solve(&stretch(&sim, 1.1), &BonePose::default(), &settings)
            .unwrap();
        let before = seq.state().flat_positions().to_vec();
        let (result, aside) = seq.solve_aside(&stretch(&sim, 1.3), &BonePose::default(), &settings);
        result.unwrap();
        assert_eq!(seq.state().flat_positions(), &before[..]);
        assert_ne!(aside.flat_positions(), &before[..]);
        // The same frame solved in the sequence lands where the aside solve did.
        seq.solve(&stretch(&sim, 1.3), &BonePose::default(), &settings)
            .unwrap();
        assert_eq!(seq.state().flat_positions(), aside.flat_positions());
    }
}
