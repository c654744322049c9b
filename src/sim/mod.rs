//! The quasistatic soft-tissue simulator.
//!
//! Data flows `actuations + bone pose → Simulator::solve (local sweep ⇄ global solve) → SimState`,
//! and back through `Simulator::sensitivities` for training.

pub mod adjoint;
pub mod attachment;
pub mod contact;
pub mod contact_gate;
pub mod deformation;
pub mod global_matrix;
mod low_rank;
pub mod polar;
pub mod shape_targeting;
pub mod simulator;
pub mod solver;
mod staging;
pub mod tensor;
mod vector;

pub use adjoint::Sensitivities;
pub use attachment::{Attachments, Bone, BonePose, RigidFit, RigidMotion};
pub use contact::{ContactStats, ContactStep};
pub use contact_gate::{ContactGate, GateOutcome};
pub use simulator::{SimConfig, SimError, SimState, Simulator};
pub use solver::{Quality, SolveSettings, SolveStats, Termination, on_worker};
pub use tensor::SymTensor;

#[cfg(test)]
mod tests;
