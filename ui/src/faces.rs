//! The faces the editor opens: the bundled sample (`sample_models/ict/`).

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result};
use facesim::model::sample::Sample;
use facesim::session::SessionFace;

/// The bundled sample, relative to the repository root.
pub const SAMPLE_DIR: &str = "sample_models/ict";

/// Every face of the sample at `dir`, with its fitted actuation model.
pub fn load_sample(dir: &Path) -> Result<Vec<SessionFace>> {
    let sample =
        Sample::load(dir).with_context(|| format!("loading the sample at {}", dir.display()))?;
    Ok(sample
        .faces
        .into_iter()
        .map(|f| SessionFace {
            name: f.name,
            identity: f.identity,
            default_style: f.style,
            model: Arc::new(f.model),
            actuation: f.actuation,
        })
        .collect())
}
