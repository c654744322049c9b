//! What drives a sample's faces (`--actuation`, shared by the editor, `serve` and `export`):
//! each face's fitted basis or the sample's trained networks through each face's φ.

use anyhow::{Context, Result};
use facesim::sample::Sample;
use facesim::session::SessionFace;

/// What turns the codes into actuations.
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
    pub fn network_file(self) -> Option<&'static str> {
        match self {
            Actuation::Basis => None,
            Actuation::Networks => Some(facesim::generative::SAMPLE_NETWORKS),
            Actuation::NetworksStage2 => Some(facesim::generative::stage2::SAMPLE_STAGE2_NETWORKS),
        }
    }
}

impl std::fmt::Display for Actuation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use clap::ValueEnum as _;
        let value = self.to_possible_value().expect("every variant is a value");
        f.write_str(value.get_name())
    }
}

/// Every face of `sample` as a session takes it, driven by `actuation`.
pub fn sample_faces(sample: &Sample, actuation: Actuation) -> Result<Vec<SessionFace>> {
    let mut faces = sample.session_faces();
    if let Some(file) = actuation.network_file() {
        let models = facesim::generative::generative_face::load_sample_networks(sample, file)
            .context("loading the sample's networks")?
            .with_context(|| {
                format!(
                    "{} has no trained networks ({file}); train them with `facesim train`",
                    sample.dir.display()
                )
            })?;
        for (face, model) in faces.iter_mut().zip(models) {
            face.actuation = model;
        }
    }
    Ok(faces)
}
