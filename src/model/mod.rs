//! Face models: built from a rig by the importer, stored in versioned files.

pub mod audit;
pub mod bindings;
mod bone_motion;
pub mod build;
pub mod contact_region;
pub mod creases;
pub mod deep_lining;
pub mod face;
pub mod file;
pub mod fit;
pub mod report;
pub mod targets;

pub use build::{BuildError, BuildSettings, Lod, build_face};
pub use face::{Binding, FaceModel, Part, RenderSurface, UvLayout};
pub use report::{BindingReport, BuildReport};
pub use targets::{Target, TargetError, shape_target, target};

#[cfg(test)]
pub(crate) mod test_support {
    //! Coarse face models built from the ICT rig once per test binary.

    use std::sync::OnceLock;

    use super::{FaceModel, Lod, build_face};
    use crate::rig::test_support::rig;

    /// The coarse model of `identity` (`None`: the template), built on first use.
    pub fn coarse_face(identity: Option<usize>) -> &'static FaceModel {
        static FACES: [OnceLock<FaceModel>; 11] = [const { OnceLock::new() }; 11];
        let slot = identity.map_or(0, |i| i + 1);
        FACES[slot].get_or_init(|| build_face(rig(), identity, &Lod::Coarse.settings()).unwrap())
    }
}
