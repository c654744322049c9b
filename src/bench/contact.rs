//! `facesim bench contact`: per-frame time with contact on and off at each quality preset on
//! a face, where the contact time goes (broad phase, barrier, CCD, contact-aware linear
//! algebra), and the low-rank contact step against refactoring `L + K` every step.
//!
//! Two sequences, each frame warm-started from the last as in the editor: a slider drag
//! (lips pressing, pursing and rolling in while the jaw opens a little and closes again),
//! and subtle lip motion (a light purse and press, the jaw clenched a hair: the closed lips
//! graze d̂ with negligible force, where the contact gate skips the contact machinery).
//! Contact rows run with the gate off ("always") and on ("when needed"), so the table shows
//! what skipping saves and what the refused attempts cost. (Opening the jaw is no case for
//! skipping on the sample: contact-free, the mouth's lining moves into the upper teeth from
//! 0.02 rad on.)

use std::time::Duration;

use serde::Serialize;

use super::median;
use super::mouth_poses::{FrameOutcome, LipField, MouthPose, run_sequence};
use crate::contact::surface::FaceContact;
use crate::model::FaceModel;
use crate::model::contact_region::FaceContactSettings;
use crate::sim::{
    ContactGate, ContactStep, Quality, SimError, Simulator, SolveSettings, SolveStats,
};
use crate::table::Table;

/// The frame sequences the benchmark drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Sequence {
    /// [`drag_pose`]: the lips press together, contact active in most frames.
    Drag,
    /// [`subtle_pose`]: small lip motion, the closed lips grazing d̂.
    Subtle,
}

impl Sequence {
    pub fn name(self) -> &'static str {
        match self {
            Sequence::Drag => "drag",
            Sequence::Subtle => "subtle",
        }
    }

    pub fn pose(self, k: usize, count: usize) -> MouthPose {
        match self {
            Sequence::Drag => drag_pose(k, count),
            Sequence::Subtle => subtle_pose(k, count),
        }
    }
}

/// One configuration's frames, summarized by medians over frames.
#[derive(Clone, Debug, Serialize)]
pub struct ContactBenchRow {
    pub sequence: Sequence,
    pub quality: Quality,
    pub contact: bool,
    pub step: Option<ContactStep>,
    /// The contact gate (`None` with contact off).
    pub gate: Option<ContactGate>,
    /// Frames whose contact solve the gate skipped (certified contact-free).
    pub skipped: usize,
    /// Frames where the gate tried contact-free and refused the result (the attempt's time
    /// wasted before the full solve).
    pub refused: usize,
    /// Median time in the gate per frame (its attempt and checks; the whole solve for a
    /// skipped frame).
    pub gate_ms: f64,
    pub frames: usize,
    /// Frames whose solve returned an error (inverted elements, crossings, …).
    pub failures: usize,
    pub converged: usize,
    pub frame_ms: f64,
    pub iterations: f64,
    pub broad_phase_ms: f64,
    /// Moving the bones: the carried starts' linearizations and the stages' certificates.
    pub staging_ms: f64,
    /// The after-solve crossing check.
    pub check_ms: f64,
    pub barrier_ms: f64,
    pub filter_ms: f64,
    pub linear_ms: f64,
    pub active_pairs: f64,
    /// Candidate lists built per frame (broad-phase runs).
    pub candidate_builds: f64,
    /// Pairs CCD and the line-search barrier checked per step.
    pub near_pairs: f64,
}

/// The drag's pose at frame `k` of `count`.
pub fn drag_pose(k: usize, count: usize) -> MouthPose {
    let t = (k + 1) as f64 / count as f64;
    MouthPose {
        jaw_open: 0.04 * (std::f64::consts::PI * t).sin(),
        purse: 0.6 * t,
        press: 0.8 * t,
        roll: 0.4 * t,
    }
}

/// The subtle sequence's pose at frame `k` of `count`: a purse rising to 0.3 and back, a
/// press growing to 0.1, the jaw clenching to 0.01 rad.
pub fn subtle_pose(k: usize, count: usize) -> MouthPose {
    let t = (k + 1) as f64 / count as f64;
    MouthPose {
        jaw_open: -0.01 * t,
        purse: 0.3 * (std::f64::consts::PI * t).sin(),
        press: 0.1 * t,
        ..MouthPose::default()
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The face the benchmark drives: its simulator with contact set up (gate and step as the
/// caller sets them) and the lip field the sequences' poses go through.
pub struct ContactScene {
    pub sim: Simulator,
    field: LipField,
}

impl ContactScene {
    pub fn new(model: &FaceModel) -> Result<Self, SimError> {
        let face = FaceContact::new(model, &FaceContactSettings::default())?;
        let field = LipField::new(model, &face, 1.5);
        let mut sim = model.simulator()?;
        sim.set_contact(face)?;
        Ok(Self { sim, field })
    }

    /// Solves `frames` frames of `sequence` in order, each warm-started from the last.
    pub fn run(
        &self,
        sequence: Sequence,
        frames: usize,
        settings: &SolveSettings,
    ) -> Vec<FrameOutcome> {
        run(&self.sim, &self.field, sequence, frames, settings)
    }
}

fn run(
    sim: &Simulator,
    field: &LipField,
    sequence: Sequence,
    frames: usize,
    settings: &SolveSettings,
) -> Vec<FrameOutcome> {
    run_sequence(sim, frames, settings, |k| {
        let pose = sequence.pose(k, frames);
        (field.actuations(&pose), pose.bones())
    })
}

/// Runs both sequences of `frames` frames under every preset with contact off, on with the
/// gate off and on with the gate on, and the drag at the interactive preset with the
/// refactoring contact step (gate off).
pub fn bench(model: &FaceModel, frames: usize) -> Result<Vec<ContactBenchRow>, SimError> {
    let ContactScene { mut sim, field } = ContactScene::new(model)?;
    let mut rows = Vec::new();
    let row = |sim: &Simulator,
               sequence: Sequence,
               quality: Quality,
               contact: bool,
               step: ContactStep| {
        let settings = SolveSettings {
            contact,
            ..quality.settings()
        };
        let outcomes = run(sim, &field, sequence, frames, &settings);
        let solved: Vec<&SolveStats> = outcomes
            .iter()
            .filter_map(|o| o.result.as_ref().ok())
            .collect();
        let per = |f: &dyn Fn(&SolveStats) -> f64| {
            median(&solved.iter().map(|s| f(s)).collect::<Vec<_>>())
        };
        let contact_ms = |f: &dyn Fn(&crate::sim::ContactStats) -> Duration| {
            per(&|s| s.contact.as_ref().map_or(0.0, |c| ms(f(c))))
        };
        let in_contact = contact && sim.contact().is_some();
        ContactBenchRow {
            sequence,
            quality,
            contact,
            step: in_contact.then_some(step),
            gate: in_contact.then(|| sim.contact_gate()).flatten(),
            skipped: solved
                .iter()
                .filter(|s| s.contact.as_ref().is_some_and(|c| c.gate.skipped()))
                .count(),
            refused: solved
                .iter()
                .filter(|s| s.contact.as_ref().is_some_and(|c| c.gate.refused()))
                .count(),
            gate_ms: contact_ms(&|c| c.gate_time),
            frames,
            failures: outcomes.len() - solved.len(),
            converged: solved.iter().filter(|s| s.converged()).count(),
            frame_ms: per(&|s| ms(s.wall_time)),
            iterations: per(&|s| s.iterations as f64),
            broad_phase_ms: contact_ms(&|c| c.broad_phase_time),
            staging_ms: contact_ms(&|c| c.staging_time),
            check_ms: contact_ms(&|c| c.check_time),
            barrier_ms: contact_ms(&|c| c.barrier_time),
            filter_ms: contact_ms(&|c| c.filter_time),
            linear_ms: contact_ms(&|c| c.linear_time),
            active_pairs: per(&|s| s.contact.as_ref().map_or(0.0, |c| c.active_pairs as f64)),
            candidate_builds: per(&|s| {
                s.contact
                    .as_ref()
                    .map_or(0.0, |c| c.candidate_builds as f64)
            }),
            near_pairs: per(&|s| {
                s.contact.as_ref().map_or(0.0, |c| {
                    c.candidate_pairs as f64 / (s.iterations.max(1) as f64)
                })
            }),
        }
    };
    for sequence in [Sequence::Drag, Sequence::Subtle] {
        for quality in Quality::ALL {
            rows.push(row(
                &sim,
                sequence,
                quality,
                false,
                ContactStep::LowRankUpdate,
            ));
            for gate in [ContactGate::Always, ContactGate::WhenNeeded] {
                sim.set_contact_gate(gate);
                rows.push(row(
                    &sim,
                    sequence,
                    quality,
                    true,
                    ContactStep::LowRankUpdate,
                ));
            }
        }
    }
    sim.set_contact_gate(ContactGate::Always);
    sim.set_contact_step(ContactStep::Refactor);
    rows.push(row(
        &sim,
        Sequence::Drag,
        Quality::Interactive,
        true,
        ContactStep::Refactor,
    ));
    sim.set_contact_step(ContactStep::LowRankUpdate);
    sim.set_contact_gate(ContactGate::default());
    Ok(rows)
}

/// "off", "on (always)" or "on (when needed)".
pub fn contact_label(r: &ContactBenchRow) -> &'static str {
    match (r.contact, r.gate) {
        (false, _) => "off",
        (true, Some(ContactGate::WhenNeeded)) => "on (when needed)",
        (true, _) => "on (always)",
    }
}

/// The rows as a Markdown table.
pub fn table(rows: &[ContactBenchRow]) -> String {
    let mut t = Table::new(
        &[
            "sequence",
            "preset",
            "contact",
            "step",
            "frames ok",
            "skipped",
            "refused",
            "gate ms",
            "converged",
            "frame ms",
            "iterations",
            "broad phase ms",
            "barrier ms",
            "filter ms",
            "linear ms",
            "staging ms",
            "check ms",
            "active pairs",
            "lists built",
            "pairs per step",
        ],
        "llllrrrrrrrrrrrrrrrr",
    );
    let ms = |v: f64| format!("{v:.1}");
    let count = |v: f64| format!("{v:.0}");
    for r in rows {
        t.row([
            r.sequence.name().to_string(),
            r.quality.to_string(),
            contact_label(r).to_string(),
            r.step.map_or("-".to_string(), |s| format!("{s:?}")),
            format!("{}/{}", r.frames - r.failures, r.frames),
            r.skipped.to_string(),
            r.refused.to_string(),
            ms(r.gate_ms),
            r.converged.to_string(),
            ms(r.frame_ms),
            count(r.iterations),
            ms(r.broad_phase_ms),
            ms(r.barrier_ms),
            ms(r.filter_ms),
            ms(r.linear_ms),
            ms(r.staging_ms),
            ms(r.check_ms),
            count(r.active_pairs),
            count(r.candidate_builds),
            count(r.near_pairs),
        ]);
    }
    let mut out = t.to_string();
    for sequence in [Sequence::Drag, Sequence::Subtle] {
        for q in Quality::ALL {
            let find = |c: bool, gate: Option<ContactGate>| {
                rows.iter().find(|r| {
                    r.sequence == sequence
                        && r.quality == q
                        && r.contact == c
                        && r.gate == gate
                        && r.step != Some(ContactStep::Refactor)
                })
            };
            let off = find(false, None);
            let always = find(true, Some(ContactGate::Always));
            let needed = find(true, Some(ContactGate::WhenNeeded));
            if let (Some(off), Some(always), Some(needed)) = (off, always, needed) {
                out += &format!(
                    "\n{}, {q}: contact on (always) / off = {:.2}×, on (when needed) / off = {:.2}× per frame",
                    sequence.name(),
                    always.frame_ms / off.frame_ms,
                    needed.frame_ms / off.frame_ms
                );
            }
        }
    }
    out.push('\n');
    out
}
