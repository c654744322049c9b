//! A seeded random-code sweep: expression sliders drawn uniformly from `[-0.5, 1.5]` (past
//! both ends of their range), one frame per code, warm-started from the previous frame, as a
//! user dragging sliders at random would drive the solver. The acceptance run is 1000
//! codes with zero intersections (`facesim bench contact --sweep`).
//!
//! [`SweepMode::Compare`] solves every frame twice from the same start, without and with
//! contact, so that a failure can be put on its cause: a frame that inverts without contact
//! too is asked too much by its codes (the actuation model's business), one that inverts only
//! with contact is contact's.

use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::contact::surface::FaceContact;
use crate::drive::{ActuationModel, Codes};
use crate::model::FaceModel;
use crate::model::contact_region::FaceContactSettings;
use crate::rig::ExpressionCode;
use crate::sequence::{FrameFailure, Recovery, Sequence};
use crate::sim::{Quality, SimError, SolveSettings, SolveStats};

/// Which solves a sweep runs per code.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SweepMode {
    /// Contact on (the acceptance run).
    #[default]
    Contact,
    /// Contact off: what the codes alone do to the tissue.
    NoContact,
    /// Both, each frame from the same start (the contact-on chain is the one carried on).
    Compare,
}

/// How one solve of a frame ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FrameOutcome {
    Converged,
    /// Valid, intersection-free, but not within the tolerance (iteration cap or stall).
    Unconverged,
    Inverted,
    Intersecting,
    Error,
}

/// Counts over the solves of one kind (contact on or off).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SweepCounts {
    pub frames: usize,
    /// Frames that solved to a valid (and, with contact, intersection-free) result.
    pub ok: usize,
    /// Of those, frames within the tolerance (the rest hit the iteration cap or stalled).
    pub converged: usize,
    /// Of those, frames whose bone pose could not be reached from the last frame and that
    /// were solved from rest ([`crate::sim::ContactStats::from_rest`]).
    #[serde(default)]
    pub from_rest: usize,
    /// Frames whose result had inverted elements ([`SimError::Inverted`]).
    pub inverted: usize,
    /// Frames whose result crossed a contact surface ([`SimError::Intersecting`]).
    pub intersecting: usize,
    /// Any other error, as text (first few).
    pub other_errors: Vec<String>,
    /// Median wall time per frame.
    pub median_frame: Duration,
    /// Every frame's wall time (ms), in frame order: what a sweep split into shards merges
    /// (`tools/ray/contact_sweep.py`).
    #[serde(default)]
    pub frame_ms: Vec<f64>,
    /// Longest frame.
    pub max_frame: Duration,
    /// Median and largest inverted-element count over the inverted frames.
    pub median_inverted_elements: usize,
    pub max_inverted_elements: usize,
}

/// What the sweep found.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SweepReport {
    pub mode: SweepMode,
    /// Contact on (`None` in [`SweepMode::NoContact`]).
    pub contact: Option<SweepCounts>,
    /// Contact off (`None` in [`SweepMode::Contact`]).
    pub no_contact: Option<SweepCounts>,
    /// [`SweepMode::Compare`]: frames inverted with contact on that are valid without it
    /// (contact's doing), and frames inverted both ways (the codes' doing).
    pub inverted_only_with_contact: usize,
    pub inverted_both: usize,
    /// Per frame: (contact on, contact off) outcomes, `None` for a solve not run.
    pub outcomes: Vec<(Option<FrameOutcome>, Option<FrameOutcome>)>,
    /// Wall time of the whole sweep.
    pub total: Duration,
}

impl SweepReport {
    /// The counts and the comparison as text (the per-frame outcomes are in the JSON).
    pub fn summary(&self) -> String {
        let mut out = format!(
            "mode {:?}, total {:.1} s\n",
            self.mode,
            self.total.as_secs_f64()
        );
        for (name, c) in [
            ("contact on", &self.contact),
            ("contact off", &self.no_contact),
        ] {
            if let Some(c) = c {
                out += &format!(
                    "{name}: {} frames, {} ok ({} converged, {} from rest), {} inverted (elements median {}, max {}), \
                     {} intersecting, {} other errors {:?}; frame median {:.1} ms, max {:.1} ms\n",
                    c.frames,
                    c.ok,
                    c.converged,
                    c.from_rest,
                    c.inverted,
                    c.median_inverted_elements,
                    c.max_inverted_elements,
                    c.intersecting,
                    c.other_errors.len(),
                    c.other_errors,
                    c.median_frame.as_secs_f64() * 1e3,
                    c.max_frame.as_secs_f64() * 1e3,
                );
            }
        }
        if self.mode == SweepMode::Compare {
            out += &format!(
                "inverted with contact only: {}, inverted with and without contact: {}\n",
                self.inverted_only_with_contact, self.inverted_both
            );
        }
        out
    }
}

/// The expression codes of the sweep: `count` codes, each slider uniform in `[-0.5, 1.5]`.
pub fn random_codes(count: usize, seed: u64) -> Vec<Codes> {
    random_codes_in(count, seed, -0.5, 1.5)
}

/// `count` codes, each slider uniform in `[low, high]` (`low ≤ high`).
pub fn random_codes_in(count: usize, seed: u64, low: f64, high: f64) -> Vec<Codes> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            let mut codes = Codes::default();
            for w in codes.expression.0.iter_mut().take(ExpressionCode::LEN) {
                *w = rng.random_range(low..=high);
            }
            codes
        })
        .collect()
}

/// Running tallies of one kind of solve.
#[derive(Default)]
struct Tally {
    counts: SweepCounts,
    times: Vec<Duration>,
    inverted_elements: Vec<usize>,
}

impl Tally {
    fn record(
        &mut self,
        result: &Result<SolveStats, FrameFailure>,
        time: Duration,
    ) -> FrameOutcome {
        let c = &mut self.counts;
        c.frames += 1;
        self.times.push(time);
        match result {
            Ok(stats) => {
                c.ok += 1;
                c.from_rest += usize::from(from_rest(stats));
                if stats.termination == crate::sim::Termination::Converged {
                    c.converged += 1;
                    FrameOutcome::Converged
                } else {
                    FrameOutcome::Unconverged
                }
            }
            Err(FrameFailure::Solve(SimError::Inverted { count, .. })) => {
                c.inverted += 1;
                self.inverted_elements.push(*count);
                FrameOutcome::Inverted
            }
            Err(FrameFailure::Solve(SimError::Intersecting { .. })) => {
                c.intersecting += 1;
                FrameOutcome::Intersecting
            }
            Err(e) => {
                if c.other_errors.len() < 8 {
                    c.other_errors.push(e.to_string());
                }
                FrameOutcome::Error
            }
        }
    }

    fn finish(mut self) -> SweepCounts {
        self.counts.frame_ms = self.times.iter().map(|t| t.as_secs_f64() * 1e3).collect();
        self.times.sort_unstable();
        self.inverted_elements.sort_unstable();
        let c = &mut self.counts;
        c.median_frame = self
            .times
            .get(self.times.len() / 2)
            .copied()
            .unwrap_or_default();
        c.max_frame = self.times.last().copied().unwrap_or_default();
        c.median_inverted_elements = self
            .inverted_elements
            .get(self.inverted_elements.len() / 2)
            .copied()
            .unwrap_or(0);
        c.max_inverted_elements = self.inverted_elements.last().copied().unwrap_or(0);
        self.counts
    }
}

/// One solve of a swept frame, as it finishes (for progress reports: a long sweep that is
/// stopped keeps what it printed).
#[derive(Clone, Debug)]
pub struct SolveReport {
    /// Contact on for this solve.
    pub contact: bool,
    pub outcome: FrameOutcome,
    pub time: Duration,
    /// The solver's message for a failed solve.
    pub error: Option<String>,
    /// The frame was solved from rest (its pose unreachable from the last frame).
    pub from_rest: bool,
}

fn from_rest(stats: &SolveStats) -> bool {
    stats.contact.as_ref().is_some_and(|c| c.from_rest)
}

/// Solves `codes` in order on `model` driven by `actuation`, at `quality`, in `mode`; a
/// failed frame restarts the next one from rest. `on_solve` hears of every solve (the
/// frame's index and how it went) as it finishes.
pub fn sweep(
    model: &FaceModel,
    actuation: &dyn ActuationModel,
    codes: &[Codes],
    quality: Quality,
    mode: SweepMode,
    on_solve: &mut dyn FnMut(usize, &SolveReport),
) -> Result<SweepReport, SimError> {
    let begin = std::time::Instant::now();
    let mut sim = model.simulator()?;
    sim.set_contact(FaceContact::new(model, &FaceContactSettings::default())?)?;
    // The sweep is where the crossing audit runs on every frame.
    let on = SolveSettings {
        audit_crossings: true,
        ..quality.settings()
    };
    let off = SolveSettings {
        contact: false,
        ..on
    };
    let mut sequence = Sequence::new(&sim).with_recovery(Recovery::Rest);
    let (mut with, mut without) = (Tally::default(), Tally::default());
    let mut report = SweepReport {
        mode,
        ..SweepReport::default()
    };
    let mut tell = |frame: usize,
                    contact: bool,
                    r: &Result<SolveStats, FrameFailure>,
                    time: Duration,
                    outcome: FrameOutcome| {
        on_solve(
            frame,
            &SolveReport {
                contact,
                outcome,
                time,
                error: r.as_ref().err().map(|e| e.to_string()),
                from_rest: r.as_ref().is_ok_and(from_rest),
            },
        );
        outcome
    };
    for (frame, c) in codes.iter().enumerate() {
        let a = actuation
            .actuate(c)
            .map_err(|e| SimError::Setup(format!("actuation: {e}")))?;
        let bones = a.bones();
        let off_outcome = (mode != SweepMode::Contact).then(|| {
            let start = Instant::now();
            let r = if mode == SweepMode::Compare {
                sequence.solve_aside(&a.tensors, &bones, &off).0
            } else {
                sequence.solve(&a.tensors, &bones, &off)
            };
            let t = start.elapsed();
            let outcome = without.record(&r, t);
            tell(frame, false, &r, t, outcome)
        });
        let on_outcome = (mode != SweepMode::NoContact).then(|| {
            let start = Instant::now();
            let r = sequence.solve(&a.tensors, &bones, &on);
            let t = start.elapsed();
            let outcome = with.record(&r, t);
            tell(frame, true, &r, t, outcome)
        });
        if on_outcome == Some(FrameOutcome::Inverted) {
            match off_outcome {
                Some(FrameOutcome::Inverted) => report.inverted_both += 1,
                Some(_) => report.inverted_only_with_contact += 1,
                None => {}
            }
        }
        report.outcomes.push((on_outcome, off_outcome));
    }
    report.contact = (mode != SweepMode::NoContact).then(|| with.finish());
    report.no_contact = (mode != SweepMode::Contact).then(|| without.finish());
    report.total = begin.elapsed();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A few random codes on the bundled sample's neutral face, solved with and without
    /// contact from the same starts: every frame solves or fails loudly, none crosses a
    /// surface (the full 1000-code run is the benchmark), and the comparison adds up.
    #[test]
    fn random_codes_with_contact_never_intersect() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let sample = crate::sample::Sample::load(root.join(crate::sample::SAMPLE_DIR)).unwrap();
        let face = sample.faces.iter().find(|f| f.identity.is_none()).unwrap();
        let codes = random_codes(4, 11);
        assert_eq!(codes, random_codes(4, 11), "the sweep is seeded");
        let narrow = random_codes_in(4, 11, 0.0, 0.5);
        assert!(
            narrow
                .iter()
                .all(|c| c.expression.0.iter().all(|w| (0.0..=0.5).contains(w)))
        );
        assert_ne!(narrow, codes);
        assert!(
            codes
                .iter()
                .all(|c| c.expression.0.iter().all(|w| (-0.5..=1.5).contains(w)))
        );
        let mut heard = Vec::new();
        let report = sweep(
            &face.model,
            face.actuation.as_ref(),
            // Weights up to 0.5: the full range costs minutes a frame with contact on the
            // format-3 face (docs/performance/contact.md); the 1,000-code run covers it.
            &narrow,
            Quality::Interactive,
            SweepMode::Compare,
            &mut |frame, r| heard.push((frame, r.contact, r.outcome)),
        )
        .unwrap();
        let on = report.contact.as_ref().unwrap();
        let off = report.no_contact.as_ref().unwrap();
        assert_eq!((on.frames, off.frames), (4, 4));
        assert_eq!((on.frame_ms.len(), off.frame_ms.len()), (4, 4));
        let slowest = on.frame_ms.iter().copied().fold(0.0, f64::max);
        assert_eq!(slowest, on.max_frame.as_secs_f64() * 1e3);
        assert_eq!(on.intersecting, 0, "{report:?}");
        assert!(on.other_errors.is_empty(), "{report:?}");
        assert!(on.ok >= 1, "{report:?}");
        assert_eq!(
            report.inverted_both + report.inverted_only_with_contact,
            on.inverted,
            "{report:?}"
        );
        assert_eq!(report.outcomes.len(), 4);
        // Every solve was reported as it finished, without contact first, in frame order.
        let told: Vec<_> = report
            .outcomes
            .iter()
            .enumerate()
            .flat_map(|(i, (on, off))| [(i, false, off.unwrap()), (i, true, on.unwrap())])
            .collect();
        assert_eq!(heard, told);
        assert!(
            report
                .outcomes
                .iter()
                .all(|(a, b)| a.is_some() && b.is_some())
        );
    }
}
