//! Benchmarks run by `facesim bench`.
pub mod editor;
pub mod solver;
