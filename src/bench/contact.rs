//! `facesim bench contact`: per-frame time with contact on and off at each quality preset on
//! a face, where the contact time goes (broad phase, barrier, CCD, contact-aware linear
//! algebra), and the low-rank contact step against refactoring `L + K` every step.
//!
//! The frames are a slider drag: a sequence of mouth poses (lips pressing, pursing and
//! rolling in while the jaw opens a little and closes again), each frame warm-started from
//! the last, as in the editor.

use std::time::Duration;

use serde::Serialize;

use crate::contact::drive::{LipField, MouthPose, run_sequence};
use crate::contact::face::{FaceContact, FaceContactSettings};
use crate::model::FaceModel;
use crate::sim::{ContactStep, Quality, SimError, Simulator, SolveStats};

/// One configuration's frames, summarized by medians over frames.
#[derive(Clone, Debug, Serialize)]
pub struct ContactBenchRow {
    pub quality: Quality,
    pub contact: bool,
    pub step: Option<ContactStep>,
    pub frames: usize,
    /// Frames whose solve returned an error (inverted elements, crossings, …).
    pub failures: usize,
    pub converged: usize,
    pub frame_ms: f64,
    pub iterations: f64,
    pub broad_phase_ms: f64,
    pub barrier_ms: f64,
    pub ccd_ms: f64,
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

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Runs the drag of `frames` frames under every preset with contact on and off, and the
/// interactive preset with the refactoring contact step.
pub fn bench(model: &FaceModel, frames: usize) -> Result<Vec<ContactBenchRow>, SimError> {
    let face = FaceContact::new(model, &FaceContactSettings::default())?;
    let field = LipField::new(model, &face, 1.5);
    let mut sim = model.simulator()?;
    sim.set_contact(face)?;
    let mut rows = Vec::new();
    let run = |sim: &Simulator, quality: Quality, contact: bool, step: Option<ContactStep>| {
        let settings = crate::sim::SolveSettings {
            contact,
            ..quality.settings()
        };
        let outcomes = run_sequence(sim, frames, &settings, |k| {
            let pose = drag_pose(k, frames);
            (field.actuations(&pose), pose.bones())
        });
        let solved: Vec<&SolveStats> = outcomes
            .iter()
            .filter_map(|o| o.result.as_ref().ok())
            .collect();
        let per = |f: &dyn Fn(&SolveStats) -> f64| median(solved.iter().map(|s| f(s)).collect());
        let contact_ms = |f: &dyn Fn(&crate::sim::ContactStats) -> Duration| {
            per(&|s| s.contact.as_ref().map_or(0.0, |c| ms(f(c))))
        };
        ContactBenchRow {
            quality,
            contact,
            step,
            frames,
            failures: outcomes.len() - solved.len(),
            converged: solved.iter().filter(|s| s.converged()).count(),
            frame_ms: per(&|s| ms(s.wall_time)),
            iterations: per(&|s| s.iterations as f64),
            broad_phase_ms: contact_ms(&|c| c.broad_phase_time),
            barrier_ms: contact_ms(&|c| c.barrier_time),
            ccd_ms: contact_ms(&|c| c.ccd_time),
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
    for quality in Quality::ALL {
        rows.push(run(&sim, quality, false, None));
        rows.push(run(&sim, quality, true, Some(ContactStep::LowRankUpdate)));
    }
    sim.set_contact_step(ContactStep::Refactor);
    rows.push(run(
        &sim,
        Quality::Interactive,
        true,
        Some(ContactStep::Refactor),
    ));
    sim.set_contact_step(ContactStep::LowRankUpdate);
    Ok(rows)
}

/// The rows as a Markdown table.
pub fn table(rows: &[ContactBenchRow]) -> String {
    let mut out = String::from(
        "| preset | contact | step | frames ok | converged | frame ms | iterations | broad phase ms | barrier ms | CCD ms | linear ms | active pairs | lists built | pairs per step |\n|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        out += &format!(
            "| {} | {} | {} | {}/{} | {} | {:.1} | {:.0} | {:.1} | {:.1} | {:.1} | {:.1} | {:.0} | {:.0} | {:.0} |\n",
            r.quality,
            if r.contact { "on" } else { "off" },
            r.step.map_or("-".to_string(), |s| format!("{s:?}")),
            r.frames - r.failures,
            r.frames,
            r.converged,
            r.frame_ms,
            r.iterations,
            r.broad_phase_ms,
            r.barrier_ms,
            r.ccd_ms,
            r.linear_ms,
            r.active_pairs,
            r.candidate_builds,
            r.near_pairs,
        );
    }
    for q in Quality::ALL {
        let find = |c: bool| {
            rows.iter()
                .find(|r| r.quality == q && r.contact == c && r.step != Some(ContactStep::Refactor))
        };
        if let (Some(off), Some(on)) = (find(false), find(true)) {
            out += &format!(
                "\n{q}: contact on / off = {:.2}× per frame",
                on.frame_ms / off.frame_ms
            );
        }
    }
    out.push('\n');
    out
}
