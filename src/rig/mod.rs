//! The face rig: importing ICT-FaceKit's blendshape rig (SPEC.md §3) and the checks the
//! simulation needs from it.
//!
//! Data flows `OBJ files → obj::ObjMesh → FaceRig (validated) → poses → jaw fit / surface
//! checks (self-intersection, gaps) → repair`.
//!
//! - [`obj`]: OBJ reading (file vertex order kept, quads kept) and writing.
//! - [`regions`]: the rig's named pieces (skin, mouth socket, teeth, …) as index ranges.
//! - [`expression`]: shape names and the default 19-d [`ExpressionCode`].
//! - [`codes`]: [`Codes`], an expression and a style code: the model's inputs.
//! - [`face_rig`]: [`FaceRig::load`], validation, [`FaceRig::pose`].
//! - [`jaw`]: rigid fit of the lower teeth (the jaw transform of a pose) and the jaw pivot.
//! - [`surface`]: triangle surfaces made of rig regions (pose-independent topology).
//! - [`intersect`], [`gap`]: edge–triangle self-intersections and the minimum gap between non-adjacent parts of a surface.
//! - [`style`]: the 4-d style code and each identity's default style.
//! - [`repair`]: removing the rest-pose self-intersections with the smallest vertex motion.
//!
//! Units are centimetres throughout; +y up, +z out of the face.

pub mod codes;
pub mod expression;
pub mod face_rig;
pub mod gap;
pub mod intersect;
pub mod jaw;
pub mod obj;
pub mod regions;
pub mod repair;
pub mod style;
pub mod surface;

pub use codes::Codes;
pub use expression::ExpressionCode;
pub use face_rig::{FaceRig, LoadProgress, RigError, RigIndices};
pub use obj::{ObjError, ObjMesh, Polygons};
pub use regions::Region;
pub use style::StyleCode;

/// Where the tools look for the rig by default (relative to the working directory: the
/// repository's root in this project's layout).
pub const DEFAULT_RIG_DIR: &str = "../shared/data/ict-facekit";

#[cfg(test)]
pub(crate) mod test_support {
    //! Shared test fixtures: the ICT rig (loaded once per test binary) and temp dirs.

    use std::path::PathBuf;
    use std::sync::OnceLock;

    use super::FaceRig;

    /// The rig directory: `$FACESIM_RIG_DIR`, else `../shared/data/ict-facekit` beside the
    /// crate.
    pub fn rig_dir() -> PathBuf {
        match std::env::var_os("FACESIM_RIG_DIR") {
            Some(d) => PathBuf::from(d),
            None => PathBuf::from(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../shared/data/ict-facekit"
            )),
        }
    }

    /// The ICT rig, loaded once and shared by every test in this binary.
    pub fn rig() -> &'static FaceRig {
        static RIG: OnceLock<FaceRig> = OnceLock::new();
        RIG.get_or_init(|| {
            let dir = rig_dir();
            match FaceRig::load(&dir) {
                Ok(rig) => rig,
                Err(e) => panic!(
                    "the ICT-FaceKit rig is needed by these tests (set FACESIM_RIG_DIR or put \
                     it at {}): {e}",
                    dir.display()
                ),
            }
        })
    }

    /// A fresh, empty directory under the system temp dir, unique per call.
    pub fn temp_dir(name: &str) -> PathBuf {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!(
            "facesim-{name}-{}-{n}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }
}
