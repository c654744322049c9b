//! facesim: a physics-based face model (Yang et al., "An Implicit Physical Face Model Driven
//! by Expression and Style", SIGGRAPH Asia 2023).
//!
//! See ARCHITECTURE.md for how the modules fit together.

// `!(x > 0.0)` is deliberate throughout: it rejects NaN together with non-positive values.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod bench;
pub mod contact;
pub mod drive;
pub mod export;
pub mod generative;
pub mod geometry;
pub mod mapping;
pub mod model;
pub mod nn;
pub mod plot;
pub mod rig;
pub mod sample;
pub mod sequence;
pub mod session;
pub mod sim;
pub mod slab;
pub mod stats;
pub mod table;
