//! What the `facesim` and `facesim-editor` binaries share: the `export` command's arguments
//! and runner, and progress output on standard error. Arguments, printing and progress live
//! here and in the binaries; everything they run is in the `facesim` library.

pub mod export;
pub mod progress;
