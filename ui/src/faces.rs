//! The faces the editor opens: the bundled sample (`sample_models/ict/`).

use std::path::Path;

use anyhow::{Context, Result};
use facesim::session::{Session, SessionFace};
use facesim::sim::Quality;

/// The bundled sample, relative to the repository root.
pub const SAMPLE_DIR: &str = facesim::sample::SAMPLE_DIR;

/// What turns the sliders into actuations.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Actuation {
    /// Each face's fitted per-shape basis (the per-identity model; the more accurate today).
    #[default]
    Basis,
    /// The trained expression/style networks through each identity's φ (the implicit model,
    /// `generative.nn` of the sample: stage 1).
    Networks,
    /// The same networks fine-tuned through the simulator (`generative-stage2.nn`): closer to
    /// the rig's skin, lips pressed harder into each other (contact keeps them apart).
    NetworksStage2,
}

impl Actuation {
    /// The sample's network file it drives with, if any.
    fn network_file(self) -> Option<&'static str> {
        match self {
            Actuation::Basis => None,
            Actuation::Networks => Some(facesim::generative::SAMPLE_NETWORKS),
            Actuation::NetworksStage2 => Some(facesim::generative::stage2::SAMPLE_STAGE2_NETWORKS),
        }
    }
}

/// A session on every face of the sample at `dir`, driven by `actuation`, with φ's heatmaps
/// next to the built-in ones.
pub fn open_sample_session(dir: &Path, quality: Quality, actuation: Actuation) -> Result<Session> {
    let sample = facesim::sample::Sample::load(dir)
        .with_context(|| format!("opening the sample at {}", dir.display()))?;
    let sources = sample
        .field_sources()
        .context("computing the mapping heatmaps")?;
    let mut faces = sample.session_faces();
    if let Some(file) = actuation.network_file() {
        let models = facesim::generative::generative_face::load_sample_networks(&sample, file)
            .context("loading the sample's networks")?
            .with_context(|| {
                format!(
                    "{} has no trained networks ({file}); train them with `facesim train`",
                    dir.display()
                )
            })?;
        for (face, model) in faces.iter_mut().zip(models) {
            face.actuation = model;
        }
    }
    Ok(Session::with_field_sources(faces, quality, sources)?)
}

/// Every face of the sample at `dir`, with its fitted actuation model.
pub fn load_sample(dir: &Path) -> Result<Vec<SessionFace>> {
    let sample = facesim::sample::Sample::load(dir)
        .with_context(|| format!("opening the sample at {}", dir.display()))?;
    Ok(sample.session_faces())
}
