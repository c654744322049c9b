//! Errors of the neural-network kit.

use super::tape::Pass;

/// Why a network operation, a file, or a training setting is rejected.
#[derive(Debug, thiserror::Error)]
pub enum NnError {
    #[error("invalid network: {0}")]
    InvalidSpec(String),
    #[error("{what} has shape {found:?}, expected {expected:?}")]
    Shape {
        what: &'static str,
        expected: (usize, usize),
        found: (usize, usize),
    },
    #[error("the network takes a {0}-d code but none was given")]
    MissingCode(usize),
    #[error("the network takes no code but one was given")]
    UnexpectedCode,
    #[error("the code has dimension {found}, the network expects {expected}")]
    CodeDim { expected: usize, found: usize },
    #[error("invalid code batch: {0}")]
    CodeBatch(String),
    #[error("backward needs a forward pass of kind {needed:?} on the tape, found {found:?}")]
    Pass { needed: Pass, found: Option<Pass> },
    #[error("the point cache was made with other parameters")]
    StaleCache,
    #[error("the parameter vector has {found} values, the network has {expected}")]
    ParamCount { expected: usize, found: usize },
    #[error("parameter {0} is not finite")]
    NonFiniteParam(usize),
    #[error("invalid learning-rate schedule: {0}")]
    Schedule(String),
    #[error("invalid optimizer setting: {0}")]
    Optimizer(String),
    #[error("not a facesim network file (format {0:?})")]
    Format(String),
    #[error("network file has version {found}, this build reads version {expected}")]
    Version { expected: u32, found: u32 },
    #[error("network file is corrupt: {0}")]
    Corrupt(String),
    #[error("no network named {0:?} in the file")]
    UnknownNetwork(String),
    #[error("reading or writing JSON: {0}")]
    Json(#[from] serde_json::Error),
    #[error("file i/o: {0}")]
    Io(#[from] std::io::Error),
}
