//! Benchmarks run by `facesim bench`.
pub mod contact;
pub mod solver;
