//! Stability at the extremes (`facesim bench extremes`): sequences that push every input past
//! its range, solved as the editor's session solves them (warm-started, a failed frame
//! reported and the next one started from the last good state):
//!
//! - `slider ends`: every expression slider alone dragged 0 → 1 → 3 → 0 → −1 → −3 → 0
//!   (3× its range past both ends), then every style slider the same way (range [−1, 1]);
//! - `far styles`: style codes uniform in [−3, 3]⁴, far from every identity's, with random
//!   expressions in [0, 1];
//! - `jumps`: abrupt switches between distant codes (rest, everything at 1, random corners);
//! - `long`: a random walk of the sliders over many frames.
//!
//! Per sequence it counts frames that solved, converged, hit the iteration cap, folded
//! elements, crossed a contact surface, failed otherwise, and any non-finite position (which
//! must never happen), with the largest iteration count.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::contact::surface::FaceContact;
use crate::drive::{ActuationModel, Codes};
use crate::model::FaceModel;
use crate::model::contact_region::FaceContactSettings;
use crate::rig::ExpressionCode;
use crate::rig::style::StyleCode;
use crate::sim::{SimError, SolveSettings};
use crate::table::Table;

use crate::sequence::{FrameFailure, solve_codes};

/// The drag each slider makes, in units of its range: 0 → 1 → 3 → 0 → −1 → −3 → 0.
const DRAG: [f64; 7] = [0.0, 1.0, 3.0, 0.0, -1.0, -3.0, 0.0];

/// A named sequence of codes.
pub struct Case {
    pub name: &'static str,
    pub codes: Vec<Codes>,
}

/// The sequences (module doc); `long` frames for the random walk, seeded.
pub fn cases(long: usize, seed: u64) -> Vec<Case> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut slider_ends = Vec::new();
    for i in 0..ExpressionCode::LEN {
        for w in DRAG {
            let mut c = Codes::default();
            c.expression.0[i] = w;
            slider_ends.push(c);
        }
    }
    for i in 0..StyleCode::NAMES.len() {
        for w in DRAG {
            // Style acts on expressions: drive a smile with the jaw open meanwhile.
            let mut c = Codes::default();
            c.expression.0[ExpressionCode::index_of("jawOpen").expect("a slider")] = 0.5;
            c.expression.0[ExpressionCode::index_of("mouthSmile_L").expect("a slider")] = 0.7;
            c.style.0[i] = w;
            slider_ends.push(c);
        }
    }
    let random_expression = |rng: &mut ChaCha8Rng| {
        let mut c = Codes::default();
        for w in c.expression.0.iter_mut() {
            *w = rng.random_range(0.0..=1.0);
        }
        c
    };
    let far_styles = (0..20)
        .map(|_| {
            let mut c = random_expression(&mut rng);
            for s in c.style.0.iter_mut() {
                *s = rng.random_range(-3.0..=3.0);
            }
            c
        })
        .collect();
    let all_ones = Codes {
        expression: ExpressionCode([1.0; ExpressionCode::LEN]),
        ..Codes::default()
    };
    let mut jumps = Vec::new();
    for _ in 0..5 {
        let mut corner = Codes::default();
        for w in corner.expression.0.iter_mut() {
            *w = if rng.random_bool(0.5) { 1.0 } else { 0.0 };
        }
        jumps.extend([Codes::default(), all_ones, corner, Codes::default()]);
    }
    let mut walk = Vec::with_capacity(long);
    let mut c = Codes::default();
    for _ in 0..long {
        for w in c.expression.0.iter_mut() {
            *w = (*w + rng.random_range(-0.08..=0.08)).clamp(-0.2, 1.2);
        }
        for s in c.style.0.iter_mut() {
            *s = (*s + rng.random_range(-0.05..=0.05)).clamp(-1.2, 1.2);
        }
        walk.push(c);
    }
    vec![
        Case {
            name: "slider ends",
            codes: slider_ends,
        },
        Case {
            name: "far styles",
            codes: far_styles,
        },
        Case {
            name: "jumps",
            codes: jumps,
        },
        Case {
            name: "long",
            codes: walk,
        },
    ]
}

/// What one sequence did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CaseReport {
    pub name: String,
    pub frames: usize,
    pub converged: usize,
    /// Solved to a valid frame but stopped at the iteration cap or stalled above the
    /// tolerance (the frame is shown; its stats say so).
    pub unconverged: usize,
    pub inverted: usize,
    pub intersecting: usize,
    pub other_errors: usize,
    /// Frames whose state had a non-finite position (must be 0).
    pub non_finite: usize,
    pub max_iterations: usize,
    pub median_ms: f64,
    /// The first few error messages, verbatim.
    pub examples: Vec<String>,
}

/// Runs every case on `model` (contact on or off as `settings` says).
pub fn run(
    model: &FaceModel,
    actuation: &dyn ActuationModel,
    cases: &[Case],
    settings: &SolveSettings,
    progress: &dyn Fn(&str, usize, usize),
) -> Result<Vec<CaseReport>, SimError> {
    let mut sim = model.simulator()?;
    if settings.contact {
        sim.set_contact(
            FaceContact::new(model, &FaceContactSettings::default())
                .map_err(|e| SimError::Setup(format!("contact surfaces: {e}")))?,
        )?;
    }
    let mut reports = Vec::new();
    for case in cases {
        let mut r = CaseReport {
            name: case.name.to_string(),
            frames: case.codes.len(),
            ..CaseReport::default()
        };
        let mut ms = Vec::new();
        solve_codes(&sim, actuation, &case.codes, settings, |frame, _| {
            progress(case.name, frame.index + 1, case.codes.len());
            ms.push(frame.ms);
            match &frame.outcome {
                Ok(stats) => {
                    r.max_iterations = r.max_iterations.max(stats.iterations);
                    if stats.converged() {
                        r.converged += 1;
                    } else {
                        r.unconverged += 1;
                    }
                }
                Err(FrameFailure::NonFinite) => r.non_finite += 1,
                Err(e) => {
                    if e.inverted() {
                        r.inverted += 1;
                    } else if e.intersecting() {
                        r.intersecting += 1;
                    } else {
                        r.other_errors += 1;
                    }
                    if r.examples.len() < 3 {
                        r.examples.push(format!("frame {}: {e}", frame.index));
                    }
                }
            }
        });
        ms.sort_by(f64::total_cmp);
        r.median_ms = ms.get(ms.len() / 2).copied().unwrap_or(0.0);
        reports.push(r);
    }
    Ok(reports)
}

/// The reports in markdown.
pub fn table(reports: &[CaseReport]) -> String {
    let mut t = Table::new(
        &[
            "sequence",
            "frames",
            "converged",
            "unconverged (shown)",
            "inverted",
            "intersecting",
            "other errors",
            "non-finite",
            "max iterations",
            "median ms",
        ],
        "lrrrrrrrrr",
    );
    for r in reports {
        t.row([
            r.name.clone(),
            r.frames.to_string(),
            r.converged.to_string(),
            r.unconverged.to_string(),
            r.inverted.to_string(),
            r.intersecting.to_string(),
            r.other_errors.to_string(),
            r.non_finite.to_string(),
            r.max_iterations.to_string(),
            format!("{:.1}", r.median_ms),
        ]);
    }
    t.to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::Quality;

    #[test]
    fn the_cases_reach_three_times_past_every_range() {
        let all = cases(10, 1);
        let ends = &all[0].codes;
        assert_eq!(
            ends.len(),
            7 * (ExpressionCode::LEN + StyleCode::NAMES.len())
        );
        for i in 0..ExpressionCode::LEN {
            let values: Vec<f64> = ends.iter().map(|c| c.expression.0[i]).collect();
            assert!(values.contains(&3.0) && values.contains(&-3.0));
        }
        for i in 0..StyleCode::NAMES.len() {
            let values: Vec<f64> = ends.iter().map(|c| c.style.0[i]).collect();
            assert!(values.contains(&3.0) && values.contains(&-3.0));
        }
        assert_eq!(all[3].codes.len(), 10);
        // Seeded: the same cases again.
        assert_eq!(cases(10, 1)[1].codes, all[1].codes);
    }

    /// The reduced sweep CI runs (contact off, so it stays fast): every frame gives a valid
    /// face (converged, or shown as unconverged) with no folded element and no non-finite
    /// position, within the iteration cap. The counts are the README's; a change in them is
    /// a change in behaviour worth a look.
    #[test]
    fn extreme_inputs_never_give_folded_or_non_finite_faces() {
        let sample = crate::sample::Sample::load(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::sample::SAMPLE_DIR),
        )
        .unwrap();
        let face = sample.face("identity001").unwrap();
        let settings = SolveSettings {
            contact: false,
            ..Quality::Interactive.settings()
        };
        let reports = run(
            &face.model,
            face.actuation.as_ref(),
            &cases(30, 1),
            &settings,
            &|_, _, _| {},
        )
        .unwrap();
        for r in &reports {
            eprintln!("{r:?}");
            assert_eq!(r.non_finite, 0, "{r:?}");
            assert_eq!(r.other_errors, 0, "{r:?}");
            assert_eq!(
                r.inverted, 0,
                "the volume barrier lets no element fold: {r:?}"
            );
            assert!(r.max_iterations <= settings.max_iterations);
            assert_eq!(
                r.converged + r.unconverged + r.inverted + r.intersecting,
                r.frames
            );
        }
    }
}
