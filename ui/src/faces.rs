//! The faces the editor opens: the bundled sample (`sample_models/ict/`).

use std::path::Path;

use anyhow::{Result, bail};
use facesim::session::SessionFace;

/// The bundled sample, relative to the repository root.
pub const SAMPLE_DIR: &str = "sample_models/ict";

/// Every face of the sample at `dir`, with its fitted actuation model.
///
/// The sample and its loader (`facesim::model::sample`) are not in this branch yet; until
/// they are, this fails loudly rather than opening a face without a real actuation model.
pub fn load_sample(dir: &Path) -> Result<Vec<SessionFace>> {
    bail!(
        "cannot open the sample at {}: the bundled sample and its loader are not in this build yet",
        dir.display()
    )
}
