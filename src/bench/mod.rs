//! Benchmarks run by `facesim bench`.
pub mod solver;
