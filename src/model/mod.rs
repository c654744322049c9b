//! Face models: built from a rig by the importer, stored in versioned files.

pub mod build;
pub mod face;
pub mod file;

pub use build::{BuildError, BuildReport, BuildSettings, Lod, build_face};
pub use face::{Binding, FaceModel, RenderSurface};
