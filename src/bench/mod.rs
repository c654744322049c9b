//! Benchmarks run by `facesim bench`.
pub mod contact;
pub mod contact_sweep;
pub mod editor;
pub mod extremes;
pub mod sequence;
pub mod solver;
pub mod tradeoff;
