//! Benchmarks run by `facesim bench`.
pub mod contact;
pub mod contact_sweep;
pub mod editor;
pub mod extremes;
pub mod mouth_poses;
pub mod nets;
pub mod remote;
pub mod shapes;
pub mod solver;
pub mod tradeoff;

pub use crate::stats::{median, percentile};
