//! Synthetic lower-face inputs for contact tests and the contact benchmark, until the
//! expression-code driver exists: a jaw rotation and lip actuation fields (purse, press,
//! roll) localized around the mouth, with amplitudes that may go beyond the usual range.
//!
//! Everything downstream takes `(actuations, bone pose)` from a closure
//! ([`run_sequence`]), so the expression-code sweep plugs in by passing a closure that asks
//! the actuation model for a code's per-element tensors and jaw motion.

use nalgebra::{Matrix3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::contact::surface::FaceContact;
use crate::model::FaceModel;
use crate::sequence::{Recovery, Sequence};
use crate::sim::{BonePose, RigidMotion, Simulator, SolveSettings, SolveStats, SymTensor};

/// A synthetic mouth pose. `0` everywhere is the rest face; the usual range of each value is
/// `[0, 1]` (`[−1, 1]` for `roll` and `jaw_open`), and tests go past it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MouthPose {
    /// Jaw rotation about the pivot's x axis (rad; positive opens, negative clenches).
    pub jaw_open: f64,
    /// Orbicularis purse: contraction across the mouth (x), extension outwards (z).
    pub purse: f64,
    /// Lips pressed together: contraction in height (y) of both lips.
    pub press: f64,
    /// Lips rolled in (positive) or out (negative): a y–z shear, opposite for the two lips.
    pub roll: f64,
}

impl MouthPose {
    /// A random pose, each value uniform in its range scaled by `reach` (1: the usual range,
    /// more: beyond it). The jaw stays within `±max_jaw` rad.
    pub fn random(rng: &mut impl Rng, reach: f64, max_jaw: f64) -> Self {
        Self {
            jaw_open: rng.random_range(-max_jaw..=max_jaw),
            purse: reach * rng.random_range(0.0..=1.0),
            press: reach * rng.random_range(0.0..=1.0),
            roll: reach * rng.random_range(-1.0..=1.0),
        }
    }

    /// The jaw's bone pose.
    pub fn bones(&self) -> BonePose {
        BonePose {
            jaw: RigidMotion::from_params([self.jaw_open, 0.0, 0.0, 0.0, 0.0, 0.0]),
            ..BonePose::default()
        }
    }
}

/// Per-element weights in `[0, 1]`: 1 at the lip line, falling linearly to 0 at `radius` cm,
/// and the height of each element's centroid relative to the lip line (upper lip > 0).
#[derive(Clone, Debug)]
pub struct LipField {
    weight: Vec<f64>,
    side: Vec<f64>,
}

impl LipField {
    pub fn new(model: &FaceModel, contact: &FaceContact, radius: f64) -> Self {
        let line = contact.lip_line();
        let mouth_y = line.iter().map(|p| p.y).sum::<f64>() / line.len().max(1) as f64;
        let (weight, side) = model
            .mesh
            .tets
            .iter()
            .map(|t| {
                let c = t
                    .iter()
                    .map(|&v| model.mesh.vertices[v as usize].coords)
                    .sum::<Vector3<f64>>()
                    / 4.0;
                let c = Point3::from(c);
                let d = line
                    .iter()
                    .map(|p| (p - c).norm())
                    .fold(f64::INFINITY, f64::min);
                ((1.0 - d / radius).max(0.0), (c.y - mouth_y).signum())
            })
            .unzip();
        Self { weight, side }
    }

    /// The actuation of every element for `pose` (symmetric positive definite by
    /// construction: a rotation-free stretch `diag(sx, sy, sz)` sheared in y–z by less than
    /// its determinant allows).
    pub fn actuations(&self, pose: &MouthPose) -> Vec<SymTensor> {
        self.weight
            .iter()
            .zip(&self.side)
            .map(|(&w, &side)| {
                let sx = (1.0 - 0.45 * w * pose.purse).max(0.25);
                let sy = (1.0 - 0.4 * w * pose.press).max(0.25);
                let sz = (1.0 / (sx * sy)).min(4.0);
                let shear = 0.3 * w * pose.roll * side;
                let limit = 0.9 * (sy * sz).sqrt();
                let shear = shear.clamp(-limit, limit);
                SymTensor::from_matrix(&Matrix3::new(sx, 0.0, 0.0, 0.0, sy, shear, 0.0, shear, sz))
            })
            .collect()
    }
}

/// One frame of a sequence.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FrameOutcome {
    pub frame: usize,
    /// The solve's statistics, or the error it returned.
    pub result: Result<SolveStats, String>,
}

/// Solves `count` frames in order, each warm-started from the last, with inputs from
/// `inputs(frame)`; every error is recorded (a failed frame restarts the next one from
/// rest). Returns the outcome of every frame.
pub fn run_sequence(
    sim: &Simulator,
    count: usize,
    settings: &SolveSettings,
    mut inputs: impl FnMut(usize) -> (Vec<SymTensor>, BonePose),
) -> Vec<FrameOutcome> {
    let mut sequence = Sequence::new(sim).with_recovery(Recovery::Rest);
    (0..count)
        .map(|frame| {
            let (actuations, bones) = inputs(frame);
            FrameOutcome {
                frame,
                result: sequence
                    .solve(&actuations, &bones, settings)
                    .map_err(|e| e.to_string()),
            }
        })
        .collect()
}

/// `count` random mouth poses from `seed` (see [`MouthPose::random`]).
pub fn random_poses(seed: u64, count: usize, reach: f64, max_jaw: f64) -> Vec<MouthPose> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|_| MouthPose::random(&mut rng, reach, max_jaw))
        .collect()
}
