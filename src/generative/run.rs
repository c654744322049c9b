//! A training run kept in a folder: the loop every model's trainer runs (stage 1, stage 2,
//! the displacement baseline) and the files it keeps, so that an interrupted run resumes
//! from its last checkpoint and ends bit for bit where an uninterrupted one would:
//! - the checkpoint (parameters, Adam moments, iteration), every `checkpoint_every`
//!   iterations and at the end;
//! - the loss curve as CSV ([`LOSS_CSV_HEADER`]), the rows past a resumed iteration dropped;
//! - the trained networks;
//! - a JSON summary: settings, timing, the last batch's loss.
//!
//! Files are replaced atomically (written beside, then renamed), so a run killed mid-write
//! leaves the last complete file. A caller can also stop a run between iterations (its
//! progress callback breaks): the checkpoint is saved there, and no model is written.

use std::io::Write;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::train::{LOSS_CSV_HEADER, LossRow, ModelTrainer, Stage1Config, TrainingData};
use super::{CanonicalFrame, GenerativeError, NetworkSet};
use crate::nn::{Checkpoint, NnError};

/// The names of the files one kind of run keeps in its folder.
#[derive(Clone, Copy, Debug)]
pub struct RunFiles {
    /// What the run trains, for messages and the summary.
    pub label: &'static str,
    pub model: &'static str,
    pub checkpoint: &'static str,
    pub loss: &'static str,
    pub summary: &'static str,
    /// What a pose's sampled rows are (elements, vertices), for messages.
    pub rows: &'static str,
}

/// Stage 1 (`facesim train --stage 1`).
pub const STAGE1_FILES: RunFiles = RunFiles {
    label: "stage 1",
    model: "generative.nn",
    checkpoint: "checkpoint.nn",
    loss: "loss.csv",
    summary: "train.json",
    rows: "elements",
};

/// Stage 2, through the simulator.
pub const STAGE2_FILES: RunFiles = RunFiles {
    label: "stage 2",
    model: "generative-stage2.nn",
    checkpoint: "stage2-checkpoint.nn",
    loss: "stage2-loss.csv",
    summary: "stage2-train.json",
    rows: "elements (all)",
};

/// The displacement baseline.
pub const DISPLACEMENT_FILES: RunFiles = RunFiles {
    label: "displacement baseline",
    model: super::displacement::SAMPLE_DISPLACEMENT,
    checkpoint: "displacement-checkpoint.nn",
    loss: "displacement-loss.csv",
    summary: "displacement-train.json",
    rows: "vertices",
};

/// One run: where, what and how.
pub struct RunPlan<'a> {
    /// The run's folder (it must exist).
    pub out: &'a Path,
    /// Continue the run whose checkpoint is in `out` (else there must be none).
    pub resume: bool,
    pub config: Stage1Config,
    /// The canonical frame of fresh networks.
    pub frame: CanonicalFrame,
    pub files: &'a RunFiles,
    pub checkpoint_every: u64,
    /// The pose data's settings, recorded in the summary.
    pub pose_settings: serde_json::Value,
}

/// What the loop reports as it goes (for a progress bar).
pub enum RunEvent<'a> {
    /// The loop starts at iteration `from` (0, or where a resumed run stopped).
    Started { from: u64 },
    /// One iteration done; `skipped` counts the poses skipped so far in this process.
    Step { row: &'a LossRow, skipped: usize },
}

/// How a run went.
#[derive(Clone, Debug)]
pub struct RunReport {
    /// All the config's iterations are done and the model is written (else the caller
    /// stopped the run: resume it from its checkpoint).
    pub finished: bool,
    /// Iterations run by this call (fewer than the config's when resumed).
    pub iterations_run: usize,
    pub seconds: f64,
    pub median_ms_per_iteration: f64,
    /// Poses skipped (stage 2: unconverged solves) over this call's iterations.
    pub skipped: usize,
    pub last: Option<LossRow>,
    /// The trained networks' file.
    pub model: PathBuf,
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{0} exists: resume that run, or remove it")]
    Exists(PathBuf),
    #[error("loading {path} to resume: {source}")]
    Resume { path: PathBuf, source: NnError },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("writing {path}: {source}")]
    Save { path: PathBuf, source: NnError },
    #[error("iteration {iteration}: {source}")]
    Step {
        iteration: u64,
        source: GenerativeError,
    },
    #[error(transparent)]
    Train(#[from] GenerativeError),
    #[error("{face}: {source}")]
    Face {
        face: String,
        source: Box<GenerativeError>,
    },
    #[error("loading the networks {path}: {source}")]
    Init {
        path: PathBuf,
        source: Box<GenerativeError>,
    },
    #[error("loading the rig: {0}")]
    Rig(#[from] crate::rig::RigError),
    #[error(transparent)]
    Sample(#[from] Box<crate::sample::SampleError>),
}

fn io_error(path: &Path) -> impl Fn(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `bytes` beside `path`, then renames it over `path` (a run's files, and `eval`'s).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), RunError> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).map_err(io_error(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io_error(path))
}

fn save_checkpoint(ck: &Checkpoint, path: &Path) -> Result<(), RunError> {
    let mut bytes = Vec::new();
    ck.to_writer(&mut bytes).map_err(|source| RunError::Save {
        path: path.to_path_buf(),
        source,
    })?;
    write_atomic(path, &bytes)
}

/// The loss curve kept from an earlier run: its rows before iteration `from`.
fn kept_rows(path: &Path, from: u64) -> Result<String, RunError> {
    let mut csv = format!("{LOSS_CSV_HEADER}\n");
    if from > 0 && path.exists() {
        let old = std::fs::read_to_string(path).map_err(io_error(path))?;
        for line in old.lines().skip(1) {
            let it: u64 = line
                .split(',')
                .next()
                .and_then(|s| s.parse().ok())
                .unwrap_or(u64::MAX);
            if it < from {
                csv.push_str(line);
                csv.push('\n');
            }
        }
    }
    Ok(csv)
}

/// Trains `data`'s networks (fresh, from `init`, or resumed) for the plan's iterations,
/// keeping the run's files in `plan.out` (module doc); `pose_count` goes into the summary.
/// `on_event` hears of the start and each iteration; breaking after an iteration stops the
/// run there.
pub fn run_training<D: TrainingData>(
    plan: &RunPlan<'_>,
    data: &D,
    pose_count: usize,
    init: Option<D::Nets>,
    on_event: &mut dyn FnMut(RunEvent<'_>) -> ControlFlow<()>,
) -> Result<RunReport, RunError> {
    let (config, files) = (plan.config, plan.files);
    let ck_path = plan.out.join(files.checkpoint);
    let csv_path = plan.out.join(files.loss);
    let mut trainer = if plan.resume {
        let ck = Checkpoint::load(&ck_path).map_err(|source| RunError::Resume {
            path: ck_path.clone(),
            source,
        })?;
        ModelTrainer::resume(data, config, &ck)?
    } else {
        if ck_path.exists() {
            return Err(RunError::Exists(ck_path));
        }
        match init {
            Some(nets) => ModelTrainer::from_nets(data, config, nets)?,
            None => ModelTrainer::new(data, config, plan.frame)?,
        }
    };
    write_atomic(
        &csv_path,
        kept_rows(&csv_path, trainer.iteration())?.as_bytes(),
    )?;
    let mut csv_file = std::fs::OpenOptions::new()
        .append(true)
        .open(&csv_path)
        .map_err(io_error(&csv_path))?;
    let mut stop = on_event(RunEvent::Started {
        from: trainer.iteration(),
    })
    .is_break();
    let start = Instant::now();
    let (mut step_ms, mut last, mut skipped) = (Vec::new(), None, 0);
    while !trainer.done() && !stop {
        let t = Instant::now();
        let iteration = trainer.iteration();
        let row = trainer
            .step()
            .map_err(|source| RunError::Step { iteration, source })?;
        step_ms.push(t.elapsed().as_secs_f64() * 1e3);
        writeln!(csv_file, "{}", row.csv()).map_err(io_error(&csv_path))?;
        skipped += row.parts.skipped;
        stop = on_event(RunEvent::Step { row: &row, skipped }).is_break();
        if trainer.iteration() % plan.checkpoint_every == 0 || trainer.done() || stop {
            csv_file.flush().map_err(io_error(&csv_path))?;
            save_checkpoint(&trainer.checkpoint(), &ck_path)?;
        }
        last = Some(row);
    }
    let seconds = start.elapsed().as_secs_f64();
    let median_ms_per_iteration = crate::stats::median(&step_ms);
    let model = plan.out.join(files.model);
    let report = RunReport {
        finished: trainer.done(),
        iterations_run: step_ms.len(),
        seconds,
        median_ms_per_iteration,
        skipped,
        last,
        model,
    };
    if !report.finished {
        return Ok(report);
    }
    trainer
        .nets()
        .to_checkpoint()
        .save(&report.model)
        .map_err(|source| RunError::Save {
            path: report.model.clone(),
            source,
        })?;
    let summary = serde_json::json!({
        "stage": files.label,
        "config": config,
        "data_settings": data.settings(),
        "pose_settings": plan.pose_settings,
        "skipped_poses": skipped,
        "poses": pose_count,
        "iterations_run": step_ms.len(),
        "seconds": seconds,
        "median_ms_per_iteration": median_ms_per_iteration,
        "last": report.last,
    });
    let text = serde_json::to_string_pretty(&summary).expect("the summary serializes");
    write_atomic(&plan.out.join(files.summary), text.as_bytes())?;
    Ok(report)
}
