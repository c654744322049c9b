//! The export loop: a track's codes at every frame time → the editor's [`Session`] (actuation,
//! warm-started solve at the chosen preset, with or without contact, render positions and
//! normals) → every format's writer and the report ([`super::report`]); then the outputs are
//! renamed into place.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::atomic::Staging;
use super::report::ReportBuilder;
use super::{ExportError, ExportMesh, Format, FrameSink, frame_count};
use crate::session::session_face::FaceTopology;
use crate::session::track::Track;
use crate::session::{Display, Request, Session, SessionFace};
use crate::sim::{Quality, Termination};

/// What to export.
#[derive(Clone, Debug)]
pub struct ExportJob {
    /// The output base name (files are `NAME.usda`, `NAME.pc2`, …).
    pub name: String,
    pub out_dir: PathBuf,
    pub formats: Vec<Format>,
    pub fps: f64,
    pub quality: Quality,
    /// Lip and teeth contact in every solve.
    pub contact: bool,
    /// What drove the face (`basis`, `networks`, …), as the report records it.
    pub actuation: String,
    /// The frames to write (`None`: all of the track's).
    pub range: Option<FrameRange>,
}

/// A range of a track's frames, `first..end` (frame `k` at `t = k/fps`; `end` past the last
/// frame means to the end), written after solving up to `lead_in` frames before `first`
/// without writing them. Every solve warm-starts from the last, so a range that starts cold
/// would differ from the same frames of the whole export; the lead-in brings the solver's
/// state to where the whole export has it (the difference is measured in the export guide).
/// Frames keep their numbers: time codes, PC2's start frame, OBJ names and glTF times are
/// those of the whole track, so ranges of one shot line up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRange {
    pub first: usize,
    pub end: usize,
    pub lead_in: usize,
}

impl FrameRange {
    /// What an export of a track of `total` frames solves and writes for `range`.
    fn resolve(range: Option<FrameRange>, total: usize) -> Result<Span, ExportError> {
        let Some(r) = range else {
            return Ok(Span {
                lead_start: 0,
                first: 0,
                end: total,
                total,
            });
        };
        let end = r.end.min(total);
        if r.first >= end {
            return Err(ExportError::EmptyRange {
                first: r.first,
                end: r.end,
                total,
            });
        }
        Ok(Span {
            lead_start: r.first.saturating_sub(r.lead_in),
            first: r.first,
            end,
            total,
        })
    }
}

/// Makes the writer of a format the core library does not write (the editor's `.rrd`).
pub trait SinkFactory {
    /// `temp` is where to write; the export renames it into place at the end.
    fn create(
        &self,
        format: Format,
        temp: &Path,
        topology: &FaceTopology,
        frames: usize,
        fps: f64,
    ) -> Result<Option<Box<dyn FrameSink>>, ExportError>;
}

/// What an export did.
#[derive(Clone, Debug)]
pub struct ExportSummary {
    pub face: String,
    /// The first frame written (0 unless a range was asked for).
    pub first: usize,
    pub frames: usize,
    pub vertices: usize,
    pub triangles: usize,
    /// Final paths and sizes in bytes (a folder's size is the sum of its files).
    pub outputs: Vec<(PathBuf, u64)>,
    pub wall: Duration,
    /// Time in the solver, summed over frames.
    pub solve: Duration,
    /// Frames that hit the preset's iteration cap before its tolerance.
    pub capped: usize,
    /// Frames that did not reach the preset's tolerance (capped or stalled above it).
    pub unconverged: usize,
    /// Frames in which the crossing audit found crossings.
    pub crossing_frames: usize,
    pub median_iterations: usize,
    /// The report's final path.
    pub report: PathBuf,
}

/// Progress after each frame: `(frames done, frames in all)`.
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize);

fn size_of(path: &Path) -> u64 {
    if path.is_dir() {
        std::fs::read_dir(path)
            .map(|d| d.flatten().map(|e| size_of(&e.path())).sum())
            .unwrap_or(0)
    } else {
        std::fs::metadata(path).map_or(0, |m| m.len())
    }
}

/// Simulates `track` on `face` and writes `job`'s formats (module doc). Nothing appears under
/// a final name unless every frame solved and every writer finished.
pub fn export(
    face: SessionFace,
    track: &Track,
    job: &ExportJob,
    extra: Option<&dyn SinkFactory>,
    progress: Progress<'_>,
) -> Result<ExportSummary, ExportError> {
    if job.formats.is_empty() {
        return Err(ExportError::NoFormats);
    }
    if !(job.fps > 0.0 && job.fps <= 1000.0) {
        return Err(ExportError::BadFps(job.fps));
    }
    if track.keys.is_empty() {
        return Err(ExportError::EmptyTrack);
    }
    if job.formats.contains(&Format::Rrd) && extra.is_none() {
        return Err(ExportError::RrdNeedsEditor);
    }
    let start = Instant::now();
    let span = FrameRange::resolve(job.range, frame_count(track.duration(), job.fps))?;
    let (first, frames) = (span.first, span.frames());
    let mesh = ExportMesh::of(&face.model);
    let topology = FaceTopology::of(&face.name, &face.model);
    std::fs::create_dir_all(&job.out_dir).map_err(|e| ExportError::io(&job.out_dir, e))?;
    let mut staging = Staging::default();
    let report_path = job.out_dir.join(format!("{}.report.json", job.name));
    let mut report = ReportBuilder::new(
        &face.model,
        &job.name,
        job.fps,
        job.quality,
        job.contact,
        &job.actuation,
    );
    let result = (|| {
        let sinks = open_sinks(
            &mut staging,
            job,
            &mesh,
            &topology,
            &span,
            extra,
            &face.name,
        )?;
        let run = run_frames(
            face.clone(),
            track,
            job,
            &span,
            sinks,
            &mut report,
            progress,
        )?;
        report.write(&staging.output(report_path.clone())?)?;
        Ok(run)
    })();
    match result {
        Ok((solve, capped, median_iterations)) => {
            let outputs = staging.commit()?;
            Ok(ExportSummary {
                face: face.name,
                first,
                frames,
                vertices: mesh.vertex_count(),
                triangles: mesh.triangles.len(),
                outputs: outputs
                    .into_iter()
                    .map(|p| {
                        let s = size_of(&p);
                        (p, s)
                    })
                    .collect(),
                wall: start.elapsed(),
                solve,
                capped,
                unconverged: report.report().unconverged,
                crossing_frames: report.report().crossing_frames,
                median_iterations,
                report: report_path,
            })
        }
        Err(e) => {
            staging.abandon();
            Err(e)
        }
    }
}

fn open_sinks(
    staging: &mut Staging,
    job: &ExportJob,
    mesh: &ExportMesh,
    topology: &FaceTopology,
    span: &Span,
    extra: Option<&dyn SinkFactory>,
    face: &str,
) -> Result<Vec<Box<dyn FrameSink>>, ExportError> {
    let (dir, name) = (&job.out_dir, &job.name);
    let (first, frames) = (span.first, span.frames());
    let comment = format!(
        "facesim export of track '{name}' on face '{face}', frames {first}..{} of {} at {} fps, \
         {} preset, contact {}",
        span.end,
        span.total,
        job.fps,
        job.quality,
        if job.contact { "on" } else { "off" }
    );
    let mut formats: Vec<Format> = Vec::new();
    for f in &job.formats {
        if !formats.contains(f) {
            formats.push(*f);
        }
    }
    let mut sinks: Vec<Box<dyn FrameSink>> = Vec::new();
    for format in formats {
        let sink: Box<dyn FrameSink> = match format {
            Format::Usd => {
                let target = dir.join(format!("{name}.usda"));
                let normals = staging.scratch(&target, "normals")?;
                let temp = staging.output(target)?;
                Box::new(super::usd::UsdWriter::create(
                    &temp, &normals, mesh, first, frames, job.fps, &comment,
                )?)
            }
            Format::Pc2 => {
                let cache = staging.output(dir.join(format!("{name}.pc2")))?;
                let obj = staging.output(dir.join(format!("{name}.obj")))?;
                Box::new(super::pc2::Pc2Sink::create(
                    &cache, &obj, mesh, first, frames,
                )?)
            }
            Format::Obj => {
                let temp = staging.output(dir.join(format!("{name}_obj")))?;
                Box::new(super::obj::ObjSequenceSink::create(
                    &temp, name, mesh, span.total, job.fps,
                )?)
            }
            Format::Gltf => {
                let target = dir.join(format!("{name}.glb"));
                let targets = staging.scratch(&target, "targets")?;
                let temp = staging.output(target)?;
                Box::new(super::gltf::GltfWriter::create(
                    &temp, &targets, mesh, first, frames, job.fps, &comment,
                )?)
            }
            Format::Rrd => {
                let temp = staging.output(dir.join(format!("{name}.rrd")))?;
                extra
                    .and_then(|f| {
                        f.create(format, &temp, topology, frames, job.fps)
                            .transpose()
                    })
                    .ok_or(ExportError::RrdNeedsEditor)??
            }
        };
        sinks.push(sink);
    }
    Ok(sinks)
}

/// The frames an export solves: `lead_start..first` only to warm up, `first..end` written;
/// `total` is the track's frame count.
struct Span {
    lead_start: usize,
    first: usize,
    end: usize,
    total: usize,
}

impl Span {
    /// The frames written.
    fn frames(&self) -> usize {
        self.end - self.first
    }
}

/// Solves every frame in order through the session (the lead-in too) and hands the range's
/// frames to the sinks.
fn run_frames(
    face: SessionFace,
    track: &Track,
    job: &ExportJob,
    span: &Span,
    mut sinks: Vec<Box<dyn FrameSink>>,
    report: &mut ReportBuilder,
    progress: Progress<'_>,
) -> Result<(Duration, usize, usize), ExportError> {
    let model = face.model.clone();
    let session = Session::new(vec![face], job.quality)?;
    session.submit_all(&[
        Request::Refine(false),
        Request::Contact(job.contact),
        Request::Display(Display {
            crosses: false,
            heatmaps: false,
        }),
    ])?;
    // A frame can take long at the final preset on a fine face; a stopped worker cannot.
    let timeout = Duration::from_secs(3600);
    let frames = span.frames();
    let (mut solve, mut capped, mut iterations) = (Duration::ZERO, 0, Vec::with_capacity(frames));
    let mut last_index = None;
    for k in span.lead_start..span.end {
        let time = k as f64 / job.fps;
        let codes = track.sample(time).expect("the track has keys");
        let fail = |reason: String| ExportError::Frame {
            frame: k,
            time,
            reason,
        };
        let generation = session
            .submit(Request::Codes(codes))
            .map_err(|e| fail(e.to_string()))?;
        let frame = session
            .wait_generation(generation, timeout)
            .ok_or_else(|| fail("the session published no frame within an hour".into()))?;
        if let Some(error) = &frame.error {
            return Err(fail(error.clone()));
        }
        if k < span.first {
            continue;
        }
        // Held codes (equal to the last frame's) publish no new frame: the same geometry.
        if last_index != Some(frame.index) {
            solve += Duration::from_secs_f64(frame.stats.solve_ms / 1e3);
            capped += (frame.stats.termination == Termination::IterationCap) as usize;
            iterations.push(frame.stats.iterations);
        }
        last_index = Some(frame.index);
        report.record(&model, k, time, &frame);
        for sink in &mut sinks {
            sink.frame(k, &frame)?;
        }
        progress(k + 1 - span.first, frames);
    }
    for sink in sinks {
        sink.finish()?;
    }
    iterations.sort_unstable();
    let median = iterations.get(iterations.len() / 2).copied().unwrap_or(0);
    Ok((solve, capped, median))
}
