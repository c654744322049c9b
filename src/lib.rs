//! facesim: a physics-based face model (Yang et al., "An Implicit Physical Face Model Driven
//! by Expression and Style", SIGGRAPH Asia 2023).
//!
//! See ARCHITECTURE.md for how the modules fit together.

pub mod bench;
pub mod geometry;
pub mod nn;
pub mod scene;
pub mod sim;
