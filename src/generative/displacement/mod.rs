//! The paper's baseline: a displacement network of N_A's shape that regresses where the
//! tissue goes, with no physics in between.
//!
//! `codes → encoders → z → tanh → N_D(X̂, tanh z) = d` (cm, canonical frame), then per identity
//! `x = X + R_φᵀ d(φ(X))` for every simulation vertex X. N_D is N_A with 3 outputs (SIREN first
//! layer on the canonical position, Lipschitz GeLU layers modulated by tanh z); everything
//! else is the physics model's architecture, trained anew: its own encoders and its own N_B
//! for the jaw (the supplemental: "simply adjusting the dimension of the final layer to
//! three").
//!
//! **What it predicts, and why that is the fair comparison.** Its labels are the
//! displacements of every simulation vertex in the *same fitted states* whose element
//! stretches are the physics model's stage-1 labels ([`super::data::PoseData`]): both models
//! learn one description of the same poses from the same codes, with the same batches, seed
//! and schedule ([`super::train::ModelTrainer`]). Predicting simulation vertices (not render
//! vertices straight from the rig) means the baseline is read out exactly like the physics:
//! the render skin is embedded in the tet mesh, the volume is that of the tet mesh, and the
//! lips that may cross are the same embedded lips. Displacements are carried between canonical
//! and material space by R_φ like the actuation warp (`d_canonical = R_φ d_material`); φ's
//! stretch is not applied (identities differ from the template by a few per cent in size).
//!
//! The jaw: N_B, trained with the same jaw term as the physics model's, places the rigid teeth
//! (the tissue, including the part attached to the jaw, comes from N_D alone). A rigid fit to
//! N_D's jaw-attached vertices was tried first and is ill-conditioned: on the 13–18 clustered
//! vertices a rotation about the pivot trades against a translation, and the teeth landed
//! several millimetres off.
//!
//! - [`data`]: per face, φ and R_φ at the vertices and the canonical displacement labels.
//! - [`face`]: the networks bound to one face: positions and jaw for a code.

pub mod data;
pub mod displacement_face;

#[cfg(test)]
mod tests;

use std::sync::Mutex;

use faer::{Mat, Par};

use super::GenerativeError;
use super::loss::{LossParts, LossWeights, LossWorkspace, encode, encode_backward, jaw_term};
use super::nets::{Architecture, CanonicalFrame, GenerativeNets, NetFile, jaw_params, modulation};
use super::train::{NetworkSet, Stage1Config, TrainingData};
use crate::drive::Codes;
use crate::nn::{Checkpoint, Mlp, Pass};

pub use data::DisplacementData;
pub use displacement_face::DisplacementFace;

/// The baseline's file name next to the physics networks (`sample_models/ict/displacement.nn`).
pub const SAMPLE_DISPLACEMENT: &str = "displacement.nn";

/// Names of the networks in a [`Checkpoint`].
pub const DISPLACEMENT_NET_NAMES: [&str; 4] = ["expression", "style", "displacement", "jaw"];
const DISPLACEMENT_FILE: NetFile = NetFile {
    kind: "facesim-displacement",
    what: "displacement-baseline",
    version_key: "displacement_version",
    version: DISPLACEMENT_VERSION,
    names: DISPLACEMENT_NET_NAMES,
};
/// Bump when the meaning of the stored networks changes.
pub const DISPLACEMENT_VERSION: u32 = 1;

/// The baseline's networks (module docs), in f64.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplacementNets {
    pub architecture: Architecture,
    pub frame: CanonicalFrame,
    pub expression: Mlp<f64>,
    pub style: Mlp<f64>,
    pub displacement: Mlp<f64>,
    /// N_B (as in [`GenerativeNets`]).
    pub jaw: Mlp<f64>,
}

impl DisplacementNets {
    /// Fresh networks from `seed`; the encoders and N_B start like the physics model's for
    /// the same seed (same streams), N_D from N_A's stream.
    pub fn new(
        architecture: Architecture,
        frame: CanonicalFrame,
        seed: u64,
    ) -> Result<Self, GenerativeError> {
        // The physics model's constructor validates the frame and seeds the encoders.
        let g = GenerativeNets::new(architecture, frame, seed)?;
        let s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15).wrapping_add(3);
        Ok(DisplacementNets {
            displacement: Mlp::new(architecture.displacement_spec(), s)?,
            expression: g.expression,
            style: g.style,
            jaw: g.jaw,
            architecture,
            frame,
        })
    }

    pub fn nets(&self) -> [&Mlp<f64>; 4] {
        [&self.expression, &self.style, &self.displacement, &self.jaw]
    }

    pub fn nets_mut(&mut self) -> [&mut Mlp<f64>; 4] {
        [
            &mut self.expression,
            &mut self.style,
            &mut self.displacement,
            &mut self.jaw,
        ]
    }

    /// The jaw `[θ; t]` for a modulation row.
    pub fn jaw_params(&self, u: &[f64]) -> Result<[f64; 6], GenerativeError> {
        jaw_params(&self.jaw, u)
    }

    /// The modulation tanh(z) of each code (B × code_dim).
    pub fn modulation(&self, codes: &[Codes]) -> Result<Mat<f64>, GenerativeError> {
        modulation(&self.expression, &self.style, &self.architecture, codes)
    }

    pub fn to_checkpoint(&self) -> Checkpoint {
        DISPLACEMENT_FILE.write(self.nets(), &self.architecture, &self.frame)
    }

    /// The networks of a checkpoint written by [`DisplacementNets::to_checkpoint`]; checks
    /// the kind (a physics `generative.nn` is refused), version and shapes.
    pub fn from_checkpoint(ck: &Checkpoint) -> Result<Self, GenerativeError> {
        let ([expression, style, displacement, jaw], architecture, frame) =
            DISPLACEMENT_FILE.read(ck, Architecture::displacement_spec)?;
        Ok(DisplacementNets {
            expression,
            style,
            displacement,
            jaw,
            architecture,
            frame,
        })
    }

    /// The loss of one batch (module [`data`] makes them) and its gradient, **added** into
    /// `grads` (in [`DISPLACEMENT_NET_NAMES`] order):
    ///
    ///   L = (1/R) Σ_rows ‖N_D(X̂; u_b) − d*‖² + L_jaw + λ_lip Π softplus(cᵢ)
    ///
    /// (cm²; `fit` in [`LossParts`]; `L_jaw` the physics model's jaw term; `act` is 0: there is
    /// no actuation).
    pub fn batch_loss(
        &self,
        batch: &data::DisplacementBatch,
        w: &LossWeights,
        ws: &mut LossWorkspace,
        grads: &mut [Vec<f64>],
        par: Par,
    ) -> Result<LossParts, GenerativeError> {
        let b_count = batch.codes.len();
        let rows: usize = batch.counts.iter().sum();
        if b_count == 0
            || rows == 0
            || batch.counts.len() != b_count
            || batch.x.nrows() != rows
            || batch.targets.len() != rows
            || batch.jaw.len() != b_count
            || grads.len() != 4
        {
            return Err(GenerativeError::Config(format!(
                "inconsistent displacement batch: {b_count} poses, {} counts, {} rows, {} targets, {} gradients",
                batch.counts.len(),
                batch.x.nrows(),
                batch.targets.len(),
                grads.len()
            )));
        }
        let lambda_lip = w.lambda_lip;
        let [tape_e, tape_s, _] = ws.tapes_mut();
        let (u, codes) = encode(
            &self.expression,
            &self.style,
            &self.architecture,
            &batch.codes,
            &batch.counts,
            tape_e,
            tape_s,
        )?;

        let inv_r = 1.0 / rows as f64;
        let parts: Mutex<Vec<(usize, f64)>> = Mutex::new(Vec::new());
        let [grad_e, grad_s, grad_d, grad_b] = grads else {
            unreachable!("four gradients checked above")
        };
        self.displacement.gradient_chunked(
            batch.x.as_ref(),
            Some(&codes),
            Pass::Gradient,
            ws.chunked_mut(),
            grad_d,
            par,
            |range, tape, mut dy, _| {
                let y = tape.output().expect("outputs");
                let mut fit = 0.0;
                for (i, g) in range.clone().enumerate() {
                    for k in 0..3 {
                        let r = y[(i, k)] - batch.targets[g][k];
                        fit += r * r;
                        dy[(i, k)] = 2.0 * r * inv_r;
                    }
                }
                parts
                    .lock()
                    .expect("no panics while held")
                    .push((range.start, fit * inv_r));
                fit * inv_r
            },
        )?;
        let mut parts = parts.into_inner().expect("no panics while held");
        parts.sort_by_key(|p| p.0);
        let fit: f64 = parts.iter().map(|p| p.1).sum();
        let mut du = ws.chunked_mut().code_grad().to_vec();
        let [tape_e, tape_s, tape_b] = ws.tapes_mut();
        let jaw = jaw_term(
            &self.jaw,
            &u,
            &batch.jaw,
            w.jaw_lever_cm,
            tape_b,
            grad_b,
            &mut du,
        )?;
        encode_backward(
            &self.expression,
            &self.style,
            &self.architecture,
            &u,
            &du,
            [tape_e, tape_s],
            [grad_e, grad_s],
        )?;
        let lip_weighted = self
            .displacement
            .lipschitz_loss(lambda_lip, Some(grad_d.as_mut_slice()))?;
        let lip = self.displacement.lipschitz_loss(1.0, None)?;
        Ok(LossParts {
            fit,
            jaw,
            act: 0.0,
            lip,
            total: fit + jaw + lip_weighted,
            skipped: 0,
        })
    }
}

impl NetworkSet for DisplacementNets {
    fn names() -> &'static [&'static str] {
        &DISPLACEMENT_NET_NAMES
    }

    fn init(
        architecture: Architecture,
        frame: CanonicalFrame,
        seed: u64,
    ) -> Result<Self, GenerativeError> {
        DisplacementNets::new(architecture, frame, seed)
    }

    fn networks(&self) -> Vec<&Mlp<f64>> {
        self.nets().to_vec()
    }

    fn networks_mut(&mut self) -> Vec<&mut Mlp<f64>> {
        self.nets_mut().into_iter().collect()
    }

    fn to_checkpoint(&self) -> Checkpoint {
        DisplacementNets::to_checkpoint(self)
    }

    fn from_checkpoint(ck: &Checkpoint) -> Result<Self, GenerativeError> {
        DisplacementNets::from_checkpoint(ck)
    }
}

impl TrainingData for DisplacementData {
    type Nets = DisplacementNets;

    fn batch_loss(
        &self,
        nets: &DisplacementNets,
        config: &Stage1Config,
        it: u64,
        ws: &mut LossWorkspace,
        grads: &mut [Vec<f64>],
    ) -> Result<LossParts, GenerativeError> {
        let batch = self.batch(config, it);
        nets.batch_loss(&batch, &config.weights, ws, grads, Par::rayon(0))
    }
}
