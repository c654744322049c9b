//! The `export` subcommand's arguments and runner, shared by the `facesim` CLI and the editor
//! binary (which adds `rrd` through a [`SinkFactory`]); progress is an indicatif bar with ETA
//! (drawn only on a terminal).

use std::path::{Path, PathBuf};

use facesim::export::{
    ExportError, ExportJob, ExportSummary, Format, FrameRange, SinkFactory, choose_face, export,
    render_settings,
};
use facesim::sample::Sample;
use facesim::session::track::Track;
use facesim::sim::Quality;

use crate::actuation::{Actuation, sample_faces};

/// `export TRACK.json --out DIR --format usd,pc2,obj,gltf [--fps 30] [--face NAME|INDEX]
/// [--contact on|off] [--frames A..B [--lead-in 10]]` (`--sample`, `--quality` and
/// `--actuation` come from the binary).
#[derive(Clone, Debug, clap::Args)]
pub struct ExportArgs {
    /// The animation track (facesim-track JSON, e.g. saved by the editor's timeline).
    pub track: PathBuf,
    /// Output folder (created if missing); files are named after the track.
    #[arg(long)]
    pub out: PathBuf,
    /// Formats: usd (.usda), pc2 (+ topology .obj), obj (one OBJ per frame), gltf (.glb),
    /// rrd (editor binary only).
    #[arg(long, value_delimiter = ',', required = true)]
    pub format: Vec<Format>,
    /// Frames per second.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// The sample face to animate, by name or index (default: the face the track names).
    #[arg(long)]
    pub face: Option<String>,
    /// Lip and teeth contact in every frame: on or off (default: the track's, else on).
    #[arg(long, value_parser = clap::builder::BoolishValueParser::new())]
    pub contact: Option<bool>,
    /// Only frames A..B of the track (B excluded; `A..` to the end), numbered as in the whole
    /// track, to split a long shot.
    #[arg(long, value_parser = parse_frames)]
    pub frames: Option<(usize, usize)>,
    /// Frames solved before A, not written, so the range starts from the state the whole
    /// export has there (warm starts).
    #[arg(long, default_value_t = 10, requires = "frames")]
    pub lead_in: usize,
}

/// `A..B`, `A..` or `..B` (frame numbers; B excluded).
fn parse_frames(s: &str) -> Result<(usize, usize), String> {
    let (a, b) = s
        .split_once("..")
        .ok_or_else(|| format!("'{s}' is not a frame range A..B (e.g. 0..300, 300..)"))?;
    let number = |t: &str, default: usize| {
        if t.is_empty() {
            Ok(default)
        } else {
            t.parse::<usize>()
                .map_err(|_| format!("'{t}' in '{s}' is not a frame number"))
        }
    };
    let (first, end) = (number(a, 0)?, number(b, usize::MAX)?);
    if first >= end {
        return Err(format!("the range {s} is empty"));
    }
    Ok((first, end))
}

/// Runs an export as the CLI does: loads the sample and track, shows a progress bar, prints
/// a summary. `quality` is the command line's `--quality`, if given; `actuation` what drives
/// the face.
pub fn run(
    args: &ExportArgs,
    sample_dir: &Path,
    quality: Option<Quality>,
    actuation: Actuation,
    extra: Option<&dyn SinkFactory>,
) -> anyhow::Result<ExportSummary> {
    use anyhow::Context as _;
    if args.format.contains(&Format::Rrd) && extra.is_none() {
        return Err(ExportError::RrdNeedsEditor.into());
    }
    let track = Track::load(&args.track)
        .with_context(|| format!("loading the track {}", args.track.display()))?;
    let sample = Sample::load(sample_dir)
        .with_context(|| format!("loading the sample from {}", sample_dir.display()))?;
    let face = choose_face(
        sample_faces(&sample, actuation)?,
        args.face.as_deref(),
        &track,
    )?;
    let (quality, contact) = render_settings(quality, args.contact, &track);
    let name = args
        .track
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "track".into());
    let job = ExportJob {
        name,
        out_dir: args.out.clone(),
        formats: args.format.clone(),
        fps: args.fps,
        quality,
        contact,
        actuation: actuation.to_string(),
        range: args.frames.map(|(first, end)| FrameRange {
            first,
            end,
            lead_in: args.lead_in,
        }),
    };
    let total = facesim::export::frame_count(track.duration(), args.fps);
    let (frames, which) = match args.frames {
        Some((first, end)) => (
            end.min(total).saturating_sub(first),
            format!("frames {first}..{} of {total}", end.min(total)),
        ),
        None => (total, format!("{total} frames")),
    };
    eprintln!(
        "exporting {} ({:.2} s, {which} at {} fps) on {} at the {quality} preset, \
         contact {}, actuation {actuation} → {}",
        args.track.display(),
        track.duration(),
        args.fps,
        face.name,
        if contact { "on" } else { "off" },
        args.out.display()
    );
    let bar = crate::progress::bar(
        frames as u64,
        "{bar:40} {pos}/{len} frames [{elapsed_precise}, ETA {eta_precise}] {per_sec}",
    );
    let summary = export(face, &track, &job, extra, &mut |done, _| {
        bar.set_position(done as u64)
    });
    bar.finish_and_clear();
    let summary = summary.context("export failed (no output was written under its final name)")?;
    eprintln!(
        "{} frames in {:.1} s (solver {:.1} s, median {} iterations, {} at the iteration cap); \
         {} vertices, {} triangles",
        summary.frames,
        summary.wall.as_secs_f64(),
        summary.solve.as_secs_f64(),
        summary.median_iterations,
        summary.capped,
        summary.vertices,
        summary.triangles
    );
    eprintln!(
        "{} of {} frames unconverged, {} with crossings (every frame: {})",
        summary.unconverged,
        summary.frames,
        summary.crossing_frames,
        summary.report.display()
    );
    for (path, bytes) in &summary.outputs {
        println!("{:>10.1} MB  {}", *bytes as f64 / 1e6, path.display());
    }
    Ok(summary)
}
