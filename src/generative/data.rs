//! Stage-1 data: poses of the rig turned into per-element actuations and jaw motions.
//!
//! For every training pose of a face (an expression code in a style), the rig's target skin
//! ([`crate::model::target`]) is fitted by a passive simulation ([`ActuationFitter`]); the
//! element actuations `A = sym(RᵀF)` (stored as `log A`, material space) and the jaw's rigid
//! fit to the lower teeth are the pose's labels (and, for the displacement baseline, where the
//! fit put every simulation vertex). A face's poses are cached in one versioned
//! file (`<face>.poses`) and regenerated only when it is missing or was made with other
//! settings or another mesh.
//!
//! Poses per face ([`training_codes`]): the rest, each of the 19 shapes alone at the
//! [`PoseSettings::single_weights`], random combinations of 2–4 shapes (weights in
//! [0.2, 0.9]) in the face's default style or a variation of it (±0.5 per entry, clamped to
//! [−1, 1]), and single shapes in random styles. Held-out codes ([`held_out_codes`]) are
//! further random combinations from their own stream, evaluated in each face's default style.

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::GenerativeError;
use crate::drive::Codes;
use crate::drive::basis::log_tensor;
use crate::model::FaceModel;
use crate::model::file::{self, Format};
use crate::model::fit::{ActuationFitter, FitSettings};
use crate::rig::{ExpressionCode, FaceRig, StyleCode};

/// The file format of cached poses; bump `version` when [`FacePoses`] changes shape or the
/// way poses are made changes.
pub const POSES_FORMAT: Format = Format {
    kind: "poses",
    version: 3,
};

/// A content hash of a face's simulation mesh and render rest (the poses are stale when the
/// face is rebuilt, even with the same element count).
pub fn face_hash(face: &FaceModel) -> u64 {
    let mut bytes = Vec::new();
    for p in face.mesh.vertices.iter().chain(&face.render.rest) {
        for k in 0..3 {
            bytes.extend_from_slice(&p[k].to_le_bytes());
        }
    }
    for t in &face.mesh.tets {
        for v in t {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    xxhash_rust::xxh3::xxh3_64(&bytes)
}

/// Which poses a face gets (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseSettings {
    /// Each code shape alone at each of these weights.
    pub single_weights: Vec<f64>,
    /// Random combinations per face.
    pub combinations: usize,
    /// Single shapes (weight 1) in random styles, per face.
    pub styled_singles: usize,
    pub seed: u64,
}

impl Default for PoseSettings {
    fn default() -> Self {
        PoseSettings {
            single_weights: vec![0.5, 1.0],
            combinations: 24,
            styled_singles: 8,
            seed: 1,
        }
    }
}

/// A random combination of 2–4 distinct code shapes with weights in [0.2, 0.9].
fn combination(rng: &mut ChaCha8Rng) -> ExpressionCode {
    let k = rng.random_range(2..=4);
    let mut code = ExpressionCode::NEUTRAL;
    for i in rand::seq::index::sample(rng, ExpressionCode::LEN, k) {
        code.0[i] = rng.random_range(0.2..0.9);
    }
    code
}

/// The training codes of a face whose default style is `style`; `face_index` picks the
/// face's own random stream.
pub fn training_codes(style: StyleCode, settings: &PoseSettings, face_index: u64) -> Vec<Codes> {
    let mut rng = ChaCha8Rng::seed_from_u64(
        settings.seed ^ 0x7a11_da7a ^ face_index.wrapping_mul(0x9e37_79b9_7f4a_7c15),
    );
    let mut out = vec![Codes {
        expression: ExpressionCode::NEUTRAL,
        style,
    }];
    for &w in &settings.single_weights {
        for name in ExpressionCode::NAMES {
            out.push(Codes {
                expression: ExpressionCode::single(name, w).expect("a code shape"),
                style,
            });
        }
    }
    for c in 0..settings.combinations {
        let expression = combination(&mut rng);
        let style = if c % 2 == 0 {
            style
        } else {
            StyleCode(
                style
                    .0
                    .map(|s| (s + rng.random_range(-0.5..0.5)).clamp(-1.0, 1.0)),
            )
        };
        out.push(Codes { expression, style });
    }
    for _ in 0..settings.styled_singles {
        let k = rng.random_range(0..ExpressionCode::LEN);
        let mut expression = ExpressionCode::NEUTRAL;
        expression.0[k] = 1.0;
        let style = StyleCode([0; 4].map(|_| rng.random_range(-1.0..1.0)));
        out.push(Codes { expression, style });
    }
    out
}

/// `count` held-out expression codes (random combinations from a stream no training pose
/// uses).
pub fn held_out_codes(count: usize, seed: u64) -> Vec<ExpressionCode> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0004_e1d0_u64);
    (0..count).map(|_| combination(&mut rng)).collect()
}

/// One fitted pose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseData {
    pub codes: Codes,
    /// The jaw's `[θ; t]` fitted to the lower teeth.
    pub jaw: [f64; 6],
    /// `log A` per element, material space (`[xx, yy, zz, xy, xz, yz]`).
    pub logs: Vec<[f32; 6]>,
    /// Per simulation vertex, where the fit put it minus its rest position (cm, material
    /// space): the labels of the displacement baseline ([`super::displacement`]), from the
    /// same fitted state the actuations describe.
    pub displacements: Vec<[f32; 3]>,
    /// Fitted skin against the target, RMS (cm).
    pub skin_rms: f64,
    /// Elements whose stretch the fit clamped.
    pub clamped: usize,
}

/// A face's cached poses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FacePoses {
    pub face: String,
    /// [`face_hash`] of the face the poses were fitted on.
    pub face_hash: u64,
    pub element_count: usize,
    pub settings: PoseSettings,
    pub poses: Vec<PoseData>,
}

impl FacePoses {
    /// Fits every training pose of `face` (its default style `style`, index `face_index` in
    /// the sample); `progress(done, total)`.
    pub fn generate(
        rig: &FaceRig,
        face: &FaceModel,
        style: StyleCode,
        face_index: u64,
        settings: &PoseSettings,
        progress: &dyn Fn(usize, usize),
    ) -> Result<Self, GenerativeError> {
        let all = training_codes(style, settings, face_index);
        let fitter = ActuationFitter::new(face, FitSettings::default()).map_err(|source| {
            GenerativeError::Fit {
                face: face.name.clone(),
                source,
            }
        })?;
        let mut poses = Vec::with_capacity(all.len());
        for (i, codes) in all.iter().enumerate() {
            progress(i, all.len());
            let target = crate::model::target(rig, face, codes).map_err(|source| {
                GenerativeError::Target {
                    face: face.name.clone(),
                    source,
                }
            })?;
            let fit = fitter
                .fit(&target, None)
                .map_err(|source| GenerativeError::Fit {
                    face: face.name.clone(),
                    source,
                })?;
            poses.push(PoseData {
                codes: *codes,
                jaw: target.jaw.motion.params(),
                logs: fit.tensors.iter().map(log_tensor).collect(),
                displacements: face
                    .mesh
                    .vertices
                    .iter()
                    .zip(fit.positions.chunks_exact(3))
                    .map(|(rest, x)| [0, 1, 2].map(|k| (x[k] - rest[k]) as f32))
                    .collect(),
                skin_rms: fit.skin_rms,
                clamped: fit.clamped,
            });
        }
        progress(poses.len(), poses.len());
        Ok(FacePoses {
            face: face.name.clone(),
            face_hash: face_hash(face),
            element_count: face.mesh.element_count(),
            settings: settings.clone(),
            poses,
        })
    }

    /// The cached poses at `path` if they exist and were made for `face` with `settings`;
    /// `None` when they must be (re)generated (missing, an older format, other settings, another
    /// or rebuilt face). A corrupt file is an error.
    pub fn load_matching(
        path: &Path,
        face: &FaceModel,
        settings: &PoseSettings,
    ) -> Result<Option<Self>, GenerativeError> {
        if !path.exists() {
            return Ok(None);
        }
        let poses: FacePoses = match file::read(path, POSES_FORMAT) {
            Ok(p) => p,
            // An older format version is regenerated, anything else is reported.
            Err(file::FileError::Version { .. }) => return Ok(None),
            Err(e) => return Err(e.into()),
        };
        let matches = poses.face == face.name
            && poses.face_hash == face_hash(face)
            && poses.element_count == face.mesh.element_count()
            && poses.settings == *settings
            && poses.poses.iter().all(|p| {
                p.logs.len() == poses.element_count
                    && p.displacements.len() == face.mesh.vertex_count()
            });
        Ok(matches.then_some(poses))
    }

    pub fn save(&self, path: &Path) -> Result<(), GenerativeError> {
        Ok(file::write(path, POSES_FORMAT, self)?)
    }
}
