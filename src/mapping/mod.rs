//! The mapping function φ: D_M → D_C (the paper's canonical space, supplemental Sec. 1): one
//! small SIREN per identity from its material space (its own rest face and simulation mesh) to
//! the canonical (neutral) face, the actuation warp Ã = R_φᵀ A(φ(x)) R_φ, and φ's statistics.
//!
//! Data flow: `FaceModel` (identity) + `FaceModel` (neutral) → [`samples`] (surface
//! correspondences by rig vertex, elastic points) → [`train`] → [`Mapping`] (saved as
//! `<identity>.mapping`) → [`ElementWarp`] (per element φ(centroid) and R_φ, evaluated once)
//! → N_A evaluated at canonical positions and warped per element → solver. [`stats`] and
//! [`plot`] give the Fig. 3 heatmaps and per-vertex values for the viewer.

pub mod folder;
pub mod network;
pub mod plot;
pub mod samples;
pub mod stats;
pub mod train;
pub mod warp;

pub use network::{Architecture, MappedPoint, Mapping, Normalization, TrainingRecord, rotation_of};
pub use samples::{Correspondences, elastic_points, volume_points};
pub use stats::{HeatmapKind, IdentityStats, Summary, vertex_values};
pub use train::{LossRow, TrainConfig, loss_csv, train};
pub use warp::{ElementWarp, RingField, WarpComparison, warp};

use std::path::PathBuf;

use crate::model::file::FileError;
use crate::nn::NnError;

/// Why a mapping cannot be trained, loaded or used.
#[derive(Debug, thiserror::Error)]
pub enum MappingError {
    #[error(transparent)]
    File(#[from] FileError),
    #[error("network: {0}")]
    Nn(#[from] NnError),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    #[error("training settings: {0}")]
    Config(String),
    #[error("the canonical face must be the rig's neutral, got {0}")]
    CanonicalIsNotNeutral(String),
    #[error("{identity} and {canonical} share no embedded render vertex")]
    NoCorrespondences { identity: String, canonical: String },
    #[error("the canonical face has no rest position for rig vertex {0}")]
    NoCounterpart(u32),
    #[error("{0} has no embedded lip vertices")]
    NoLips(String),
    #[error(
        "the mapping was trained for {mapping} ({vertices} vertices, {elements} elements), not for {face} ({face_vertices} vertices, {face_elements} elements)"
    )]
    WrongFace {
        mapping: String,
        vertices: usize,
        elements: usize,
        face: String,
        face_vertices: usize,
        face_elements: usize,
    },
    #[error("point {0} is not finite")]
    NonFinitePoint(usize),
    #[error("the network produced a non-finite value")]
    NonFiniteOutput,
    #[error("the normalization scale {0} is not positive")]
    BadFrame(f64),
    #[error("training diverged at iteration {0} (non-finite loss or gradient)")]
    Diverged(u64),
    #[error("the mapping has not been trained")]
    Untrained,
    #[error("simulation: {0}")]
    Sim(String),
}

#[cfg(test)]
mod tests;
