//! The frame loop the measurements share: codes in order → actuation → warm-started solve,
//! as the editor's session runs them (a failed frame is reported and the next one starts
//! from the last good state).

use std::time::Instant;

use crate::drive::{ActuationModel, Codes, DriveError};
use crate::sim::{BonePose, SimError, SimState, Simulator, SolveSettings, SolveStats};

/// Why a frame failed.
#[derive(Debug, thiserror::Error)]
pub enum FrameFailure {
    #[error(transparent)]
    Actuation(#[from] DriveError),
    #[error(transparent)]
    Solve(#[from] SimError),
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

/// One frame's outcome.
pub struct FrameResult {
    pub index: usize,
    /// Wall time of actuation and solve.
    pub ms: f64,
    pub bones: BonePose,
    /// The solve's stats, or why the frame failed (actuation or solve error).
    pub outcome: Result<SolveStats, FrameFailure>,
    /// Every position of the state the solve left is finite (checked on failures too).
    pub finite: bool,
}

/// Solves `codes` in order on `sim`; `each(result, state)` sees every frame (on a failure,
/// the state the solve left, before the last good state is restored).
pub fn solve_codes(
    sim: &Simulator,
    actuation: &dyn ActuationModel,
    codes: &[Codes],
    settings: &SolveSettings,
    mut each: impl FnMut(&FrameResult, &SimState),
) {
    let mut state = sim.rest_state();
    let mut good = state.clone();
    for (index, c) in codes.iter().enumerate() {
        let start = Instant::now();
        let mut bones = BonePose::default();
        let outcome = actuation
            .actuate(c)
            .map_err(FrameFailure::from)
            .and_then(|a| {
                bones = a.bones();
                Ok(sim.solve(&a.tensors, &bones, &mut state, settings)?)
            });
        let result = FrameResult {
            index,
            ms: start.elapsed().as_secs_f64() * 1e3,
            bones,
            finite: state.flat_positions().iter().all(|v| v.is_finite()),
            outcome,
        };
        each(&result, &state);
        if result.outcome.is_ok() && result.finite {
            good.clone_from(&state);
        } else {
            state.clone_from(&good);
        }
    }
}
