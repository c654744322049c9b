//! The per-export report (`NAME.report.json`): how every frame came out, so an unconverged or
//! crossing frame is never passed on as a clean frame of the preset. Each frame carries the
//! solver's termination and residual and an independent crossing audit of what the artist
//! sees ([`CrossingAudit`]: every edge of the skin, mouth lining and teeth against every
//! triangle, crossings the rig already has at rest left out), and the creased edges of the
//! skin and lining ([`CreaseAudit`]: where the surface turned back on itself; the rig's own
//! shapes crease a few, so a count is read against the rig where it is at hand).

use std::path::Path;

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::{ExportError, Out};
use crate::model::FaceModel;
use crate::model::audit::CrossingAudit;
use crate::model::creases::CreaseAudit;
use crate::model::deep_lining::DeepLiningStats;
use crate::session::Frame;
use crate::sim::{Quality, Termination};

pub const REPORT_FORMAT: &str = "facesim-export-report";
pub const REPORT_VERSION: u32 = 1;

/// One frame of the export.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    pub frame: usize,
    /// Seconds into the track.
    pub time: f64,
    /// Reached the preset's tolerance.
    pub converged: bool,
    pub termination: Termination,
    pub iterations: usize,
    pub residual: f64,
    pub solve_ms: f64,
    /// Solved again from rest: the warm start from the last frame found no equilibrium.
    pub from_rest: bool,
    /// New edge–triangle crossings of skin, mouth lining and teeth (the audit).
    pub crossings: usize,
    /// Those crossings by pair of pieces (`"face skin / mouth socket"`).
    pub crossing_pieces: Vec<(String, usize)>,
    /// Creased skin and lining edges (the crease audit).
    #[serde(default)]
    pub creases: usize,
    /// The deep lining's contact pass, where it ran (final frames with contact).
    #[serde(default)]
    pub lining: Option<DeepLiningStats>,
}

/// The whole export (module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExportReport {
    pub format: String,
    pub version: u32,
    pub track: String,
    pub face: String,
    pub fps: f64,
    pub quality: Quality,
    pub contact: bool,
    /// What drove the face: its fitted `basis`, or the sample's `networks` through its φ
    /// (empty in reports written before it was recorded).
    #[serde(default)]
    pub actuation: String,
    /// Frames that did not reach the preset's tolerance.
    pub unconverged: usize,
    /// Frames with at least one crossing.
    pub crossing_frames: usize,
    pub frames: Vec<FrameRecord>,
}

/// Builds the report frame by frame.
pub struct ReportBuilder {
    audit: CrossingAudit,
    creases: CreaseAudit,
    report: ExportReport,
}

impl ReportBuilder {
    pub fn new(
        model: &FaceModel,
        track: &str,
        fps: f64,
        quality: Quality,
        contact: bool,
        actuation: &str,
    ) -> Self {
        ReportBuilder {
            audit: CrossingAudit::new(model),
            creases: CreaseAudit::new(model),
            report: ExportReport {
                format: REPORT_FORMAT.into(),
                version: REPORT_VERSION,
                track: track.into(),
                face: model.name.clone(),
                fps,
                quality,
                contact,
                actuation: actuation.into(),
                unconverged: 0,
                crossing_frames: 0,
                frames: Vec::new(),
            },
        }
    }

    /// Records frame `index` (at `time` s) of `model`.
    pub fn record(&mut self, model: &FaceModel, index: usize, time: f64, frame: &Frame) {
        let positions: Vec<Point3<f64>> = frame
            .positions
            .iter()
            .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        let crossings = self.audit.audit(model, &positions);
        let stats = &frame.stats;
        self.report.unconverged += usize::from(!stats.converged);
        self.report.crossing_frames += usize::from(crossings.pairs > 0);
        self.report.frames.push(FrameRecord {
            frame: index,
            time,
            converged: stats.converged,
            termination: stats.termination,
            iterations: stats.iterations,
            residual: stats.residual,
            solve_ms: stats.solve_ms,
            from_rest: stats.from_rest,
            crossings: crossings.pairs,
            crossing_pieces: crossings.by_pieces,
            creases: self.creases.audit(&positions).edges,
            lining: stats.lining.clone(),
        });
    }

    pub fn report(&self) -> &ExportReport {
        &self.report
    }

    /// Writes the report as pretty JSON to `path`.
    pub fn write(&self, path: &Path) -> Result<(), ExportError> {
        let mut out = Out::create(path)?;
        let text = serde_json::to_string_pretty(&self.report).expect("reports serialize");
        out.write_all(text.as_bytes())?;
        out.close()
    }
}
