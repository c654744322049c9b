//! The faces the editor opens: the bundled sample (`sample_models/ict/`).

use std::path::Path;

use anyhow::{Context, Result};
use facesim::session::{Session, SessionFace};
use facesim::sim::Quality;

/// The bundled sample, relative to the repository root.
pub const SAMPLE_DIR: &str = facesim::sample::SAMPLE_DIR;

pub use facesim_cli::actuation::Actuation;

/// A session on every face of the sample at `dir`, driven by `actuation`, with φ's heatmaps
/// next to the built-in ones.
pub fn open_sample_session(dir: &Path, quality: Quality, actuation: Actuation) -> Result<Session> {
    let sample = facesim::sample::Sample::load(dir)
        .with_context(|| format!("opening the sample at {}", dir.display()))?;
    let sources = sample
        .field_sources()
        .context("computing the mapping heatmaps")?;
    let faces = facesim_cli::actuation::sample_faces(&sample, actuation)?;
    Ok(Session::with_field_sources(faces, quality, sources)?)
}

/// Every face of the sample at `dir`, with its fitted actuation model.
pub fn load_sample(dir: &Path) -> Result<Vec<SessionFace>> {
    let sample = facesim::sample::Sample::load(dir)
        .with_context(|| format!("opening the sample at {}", dir.display()))?;
    Ok(sample.session_faces())
}
