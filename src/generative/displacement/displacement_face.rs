//! The displacement baseline bound to one face: simulation positions and a jaw pose (for the
//! rigid teeth) for a code, with no solve.

use std::sync::Arc;

use faer::Mat;
use nalgebra::Point3;

use super::DisplacementNets;
use crate::drive::{Codes, DriveError};
use crate::generative::GenerativeError;
use crate::generative::generative_face::FaceWarp;
use crate::mapping::Mapping;
use crate::model::FaceModel;
use crate::nn::CodeBatch;
use crate::sim::{BonePose, RigidMotion};

/// The baseline's networks on one face.
pub struct DisplacementFace {
    nets: Arc<DisplacementNets>,
    warp: FaceWarp,
    /// N_D's input rows (canonical normalized vertex positions).
    input: Mat<f64>,
    rest: Vec<Point3<f64>>,
}

/// The baseline's output for one code.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplacedPose {
    /// Simulation vertex positions, interleaved (cm).
    pub positions: Vec<f64>,
    /// The jaw from N_B (for the rigid teeth).
    pub bones: BonePose,
}

impl DisplacementFace {
    /// Binds `nets` to `face` (its φ: `mapping`, `None` for the template face).
    pub fn new(
        nets: Arc<DisplacementNets>,
        face: &FaceModel,
        mapping: Option<&Mapping>,
    ) -> Result<Self, GenerativeError> {
        let warp = FaceWarp::vertices(face, mapping, &nets.frame)?;
        Ok(DisplacementFace {
            input: warp.input::<f64>(),
            nets,
            warp,
            rest: face.mesh.vertices.clone(),
        })
    }

    pub fn vertex_count(&self) -> usize {
        self.rest.len()
    }

    /// `x = X + R_φᵀ N_D(φ̂(X), tanh z)` for every simulation vertex, and the jaw `N_B(tanh z)`.
    /// Fails on invalid codes or a non-finite output.
    pub fn pose(&self, codes: &Codes) -> Result<DisplacedPose, GenerativeError> {
        codes.validate().map_err(DriveError::from)?;
        let u = self.nets.modulation(std::slice::from_ref(codes))?;
        let u: Vec<f64> = (0..u.ncols()).map(|k| u[(0, k)]).collect();
        let d = self
            .nets
            .displacement
            .eval(self.input.as_ref(), Some(&CodeBatch::shared(&u)))?;
        let mut positions = Vec::with_capacity(3 * self.rest.len());
        for (v, rest) in self.rest.iter().enumerate() {
            let m = self
                .warp
                .vector_to_material(v, &[d[(v, 0)], d[(v, 1)], d[(v, 2)]]);
            positions.extend((0..3).map(|k| rest[k] + m[k]));
        }
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(GenerativeError::NonFinite(format!(
                "displacement of vertex {} for {codes:?}",
                i / 3
            )));
        }
        let jaw = self.nets.jaw_params(&u)?;
        if jaw.iter().any(|v| !v.is_finite()) {
            return Err(GenerativeError::NonFinite(format!("jaw {jaw:?}")));
        }
        Ok(DisplacedPose {
            positions,
            bones: BonePose {
                skull: RigidMotion::IDENTITY,
                jaw: RigidMotion::from_params(jaw),
            },
        })
    }
}
