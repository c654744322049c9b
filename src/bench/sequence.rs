//! The frame loop the measurements share: codes in order → actuation → warm-started solve,
//! as the editor's session runs them (a failed frame is reported and the next one starts
//! from the last good state).

use std::time::Instant;

use crate::drive::{ActuationModel, Codes};
use crate::sim::{BonePose, SimState, Simulator, SolveSettings, SolveStats};

/// One frame's outcome.
pub struct FrameResult {
    pub index: usize,
    /// Wall time of actuation and solve.
    pub ms: f64,
    pub bones: BonePose,
    /// The solve's stats, or why the frame failed (actuation or solve error).
    pub outcome: Result<SolveStats, String>,
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
            .map_err(|e| e.to_string())
            .and_then(|a| {
                bones = a.bones();
                sim.solve(&a.tensors, &bones, &mut state, settings)
                    .map_err(|e| e.to_string())
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
