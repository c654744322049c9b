//! What the `facesim` and `facesim-editor` binaries share: what drives a sample's faces
//! (`--actuation`), the `export` command's arguments and runner, and progress output on
//! standard error. Arguments, printing and progress live here and in the binaries; everything
//! they run is in the `facesim` library.

pub mod actuation;
pub mod export;
pub mod progress;
