//! Benchmarks run by `facesim bench`.
pub mod contact;
pub mod editor;
pub mod solver;
