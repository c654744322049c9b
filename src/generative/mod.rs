//! The expression/style networks (the paper's multi-identity model, Fig. 4 of the
//! supplemental) and their stage-1 training.
//!
//! `codes → encoders → z → tanh → N_A(X, tanh z) = log A (canonical), N_B(tanh z) = jaw [θ; t]`,
//! then per identity the canonical field is warped by φ (`Ã = R_φᵀ A(φ(x)) R_φ`).
//!
//! - [`nets`]: the four networks ([`GenerativeNets`]), the canonical frame, saving/loading.
//! - [`face`]: [`GenerativeFace`], the [`crate::drive::ActuationModel`] the editor and
//!   session drive (N_A's code-independent first layer cached per face, f32 inference).
//! - [`data`]: stage-1 data: training and held-out codes, per-element actuations from
//!   [`crate::model::fit`] on the rig's targets, cached on disk.
//! - [`loss`]: the stage-1 loss and its gradient through all four networks.
//! - [`train`]: the stage-1 training loop (Adam, linear decay, checkpoints, resume).
//! - [`stage2`]: stage 2, fine-tuning through the simulator (surface loss, sensitivities).
//! - [`displacement`]: the paper's baseline, a displacement network of N_A's shape trained
//!   on the same poses (no physics).
//! - [`transfer`]: style transfer without canonical space (A's actuations on B's elements).
//! - [`eval`]: held-out codes simulated with the networks and with the actuation basis, and
//!   the baseline's displacements, on the same poses.

pub mod data;
pub mod displacement;
pub mod eval;
pub mod expm;
pub mod generative_face;
pub mod loss;
pub mod metrics;
pub mod nets;
pub mod pipeline;
pub mod run;
pub mod stage2;
pub mod train;
pub mod transfer;

#[cfg(test)]
mod stage2_tests;
#[cfg(test)]
pub(crate) mod tests;

pub use data::{FacePoses, PoseData, PoseSettings, held_out_codes, training_codes};
pub use displacement::{DisplacementData, DisplacementFace, DisplacementNets};
pub use eval::{EvalReport, EvalRow, evaluate};
pub use generative_face::{
    GenerativeFace, SAMPLE_NETWORKS, load_sample_networks, sample_actuations,
};
pub use nets::{Architecture, CanonicalFrame, GenerativeNets};
pub use stage2::{Stage2Data, Stage2Face, Stage2Settings, Stage2Trainer};
pub use train::{
    LossRow, ModelTrainer, NetworkSet, Stage1Config, Stage1Data, TrainingData, train_model,
    train_stage1,
};

use crate::drive::DriveError;
use crate::mapping::MappingError;
use crate::model::TargetError;
use crate::model::file::FileError;
use crate::model::fit::FitError;
use crate::nn::NnError;
use crate::sim::SimError;

/// Why building, training, loading or evaluating the networks failed.
#[derive(Debug, thiserror::Error)]
pub enum GenerativeError {
    #[error(transparent)]
    Nn(#[from] NnError),
    #[error(transparent)]
    Mapping(#[from] MappingError),
    #[error(transparent)]
    File(#[from] FileError),
    #[error(transparent)]
    Drive(#[from] DriveError),
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error("target of face {face}: {source}")]
    Target { face: String, source: TargetError },
    #[error("fitting face {face}: {source}")]
    Fit { face: String, source: FitError },
    #[error("face {face} has no mapping φ into the canonical face (train it with train-mapping)")]
    NoMapping { face: String },
    #[error("invalid setting: {0}")]
    Config(String),
    #[error("non-finite output: {0}")]
    NonFinite(String),
    #[error("training diverged at iteration {0} (non-finite loss or gradient)")]
    Diverged(u64),
    #[error("{0}")]
    Checkpoint(String),
    #[error("file i/o: {0}")]
    Io(#[from] std::io::Error),
}
