//! Codes → per-element actuations and the jaw pose: the front of the data flow
//! (`codes → networks → actuations → solver → frame`).
//!
//! An [`ActuationModel`] is bound to one face (one identity's simulation mesh): it turns an
//! expression and style code into one actuation tensor per element of that mesh and the
//! jaw's rigid motion. The editor, the server and the exporter only see this trait, so the
//! model behind it (the per-shape actuation basis, or the trained networks) can change
//! without them changing.

pub mod basis;

use crate::rig::codes::CodeError;
pub use crate::rig::codes::Codes;
use crate::sim::{BonePose, RigidMotion, SymTensor};

/// One frame's inputs to the simulator.
#[derive(Clone, Debug, PartialEq)]
pub struct Actuation {
    /// One per element of the face's mesh, symmetric positive definite.
    pub tensors: Vec<SymTensor>,
    /// The jaw's motion relative to the skull, about the face's jaw pivot.
    pub jaw: RigidMotion,
}

impl Actuation {
    /// The bone pose of this frame (the head does not move).
    pub fn bones(&self) -> BonePose {
        BonePose {
            skull: RigidMotion::IDENTITY,
            jaw: self.jaw,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum DriveError {
    #[error("code entry {name} is {value}; codes must be finite")]
    NonFiniteCode { name: &'static str, value: f64 },
    #[error("the actuation model drives {expected} elements, the face has {got}")]
    ElementCount { expected: usize, got: usize },
    #[error("the actuation model produced an unusable tensor at element {element}: {reason}")]
    BadTensor { element: usize, reason: String },
}

impl From<CodeError> for DriveError {
    fn from(e: CodeError) -> Self {
        match e {
            CodeError::NonFinite { name, value } => DriveError::NonFiniteCode { name, value },
        }
    }
}

/// Codes → actuations for one face (module doc).
pub trait ActuationModel: Send + Sync {
    /// Elements of the face's mesh this model drives.
    fn element_count(&self) -> usize;

    /// The actuations and jaw pose for `codes`. Every finite code gives a usable frame
    /// (positive definite tensors), also beyond the sliders' ranges.
    fn actuate(&self, codes: &Codes) -> Result<Actuation, DriveError>;
}
