//! A seeded random-code sweep with contact on: expression sliders drawn uniformly from
//! `[-0.5, 1.5]` (past both ends of their range), one frame per code, warm-started from the
//! previous frame, as a user dragging sliders at random would drive the solver. The issue's
//! acceptance run is 1000 codes with zero intersections (`facesim bench contact --sweep`).

use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::contact::face::{FaceContact, FaceContactSettings};
use crate::drive::{ActuationModel, Codes};
use crate::model::FaceModel;
use crate::rig::ExpressionCode;
use crate::sim::{Quality, SimError};

/// What the sweep found.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SweepReport {
    pub frames: usize,
    /// Frames that solved to a valid, intersection-free result.
    pub ok: usize,
    /// Of those, frames within the tolerance (the rest hit the iteration cap or stalled).
    pub converged: usize,
    /// Frames whose result had inverted elements ([`SimError::Inverted`]).
    pub inverted: usize,
    /// Frames whose result crossed a contact surface ([`SimError::Intersecting`]).
    pub intersecting: usize,
    /// Any other error, as text (first few).
    pub other_errors: Vec<String>,
    /// Median wall time per frame.
    pub median_frame: Duration,
}

/// The expression codes of the sweep: `count` codes, each slider uniform in `[-0.5, 1.5]`.
pub fn random_codes(count: usize, seed: u64) -> Vec<Codes> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            let mut codes = Codes::default();
            for w in codes.expression.0.iter_mut().take(ExpressionCode::LEN) {
                *w = rng.random_range(-0.5..=1.5);
            }
            codes
        })
        .collect()
}

/// Solves `codes` in order on `model` driven by `actuation`, contact on, at `quality`; a
/// failed frame restarts the next one from rest.
pub fn sweep(
    model: &FaceModel,
    actuation: &dyn ActuationModel,
    codes: &[Codes],
    quality: Quality,
) -> Result<SweepReport, SimError> {
    let mut sim = model.simulator()?;
    sim.set_contact(FaceContact::new(model, &FaceContactSettings::default())?)?;
    let settings = quality.settings();
    let mut state = sim.rest_state();
    let mut report = SweepReport::default();
    let mut times = Vec::with_capacity(codes.len());
    for c in codes {
        let a = actuation
            .actuate(c)
            .map_err(|e| SimError::Setup(format!("actuation: {e}")))?;
        let start = std::time::Instant::now();
        let result = sim.solve(&a.tensors, &a.bones(), &mut state, &settings);
        times.push(start.elapsed());
        report.frames += 1;
        match result {
            Ok(stats) => {
                report.ok += 1;
                if stats.termination == crate::sim::Termination::Converged {
                    report.converged += 1;
                }
                continue;
            }
            Err(SimError::Inverted { .. }) => report.inverted += 1,
            Err(SimError::Intersecting { .. }) => report.intersecting += 1,
            Err(e) => {
                if report.other_errors.len() < 8 {
                    report.other_errors.push(e.to_string());
                }
            }
        }
        state = sim.rest_state();
    }
    times.sort_unstable();
    report.median_frame = times.get(times.len() / 2).copied().unwrap_or_default();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A few random codes on the bundled sample's neutral face: every frame solves or fails
    /// loudly, and none crosses a surface (the full 1000-code run is the benchmark).
    #[test]
    fn random_codes_with_contact_never_intersect() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let sample = crate::sample::Sample::load(root.join(crate::sample::SAMPLE_DIR)).unwrap();
        let face = sample.faces.iter().find(|f| f.identity.is_none()).unwrap();
        let codes = random_codes(4, 11);
        assert_eq!(codes, random_codes(4, 11), "the sweep is seeded");
        assert!(
            codes
                .iter()
                .all(|c| c.expression.0.iter().all(|w| (-0.5..=1.5).contains(w)))
        );
        let report = sweep(
            &face.model,
            face.actuation.as_ref(),
            &codes,
            Quality::Interactive,
        )
        .unwrap();
        assert_eq!(report.frames, 4);
        assert_eq!(report.intersecting, 0, "{report:?}");
        assert!(report.other_errors.is_empty(), "{report:?}");
        assert!(report.ok >= 1, "{report:?}");
    }
}
