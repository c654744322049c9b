//! The faces the editor opens: the bundled sample (`sample_models/ict/`).

use std::path::Path;

use anyhow::{Context, Result};
use facesim::session::SessionFace;

/// The bundled sample, relative to the repository root.
pub const SAMPLE_DIR: &str = facesim::sample::SAMPLE_DIR;

/// Every face of the sample at `dir`, with its fitted actuation model.
pub fn load_sample(dir: &Path) -> Result<Vec<SessionFace>> {
    let sample = facesim::sample::Sample::load(dir)
        .with_context(|| format!("opening the sample at {}", dir.display()))?;
    Ok(sample.session_faces())
}
