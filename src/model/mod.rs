//! Face models and the files they live in.

pub mod file;
