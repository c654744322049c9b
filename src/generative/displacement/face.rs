//! The displacement baseline bound to one face: simulation positions (and a jaw pose for the
//! rigid teeth) for a code, with no solve.

use std::sync::Arc;

use faer::Mat;
use nalgebra::{Point3, Vector3};

use super::DisplacementNets;
use crate::drive::Codes;
use crate::generative::GenerativeError;
use crate::generative::face::FaceWarp;
use crate::mapping::Mapping;
use crate::model::FaceModel;
use crate::nn::CodeBatch;
use crate::rig::jaw::fit_rigid;
use crate::sim::{Bone, BonePose, RigidMotion};

/// The baseline's networks on one face.
pub struct DisplacementFace {
    nets: Arc<DisplacementNets>,
    warp: FaceWarp,
    /// N_D's input rows (canonical normalized vertex positions).
    input: Mat<f64>,
    rest: Vec<Point3<f64>>,
    /// Simulation vertices attached to the jaw, and the face's jaw pivot.
    jaw_vertices: Vec<u32>,
    jaw_pivot: Point3<f64>,
}

/// The baseline's output for one code.
#[derive(Clone, Debug, PartialEq)]
pub struct DisplacedPose {
    /// Simulation vertex positions, interleaved (cm).
    pub positions: Vec<f64>,
    /// The jaw fitted to the predicted jaw-attached vertices (for the rigid teeth).
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
        let jaw_vertices: Vec<u32> = face
            .attachments
            .vertices
            .iter()
            .zip(&face.attachments.bones)
            .filter(|(_, b)| **b == Bone::Jaw)
            .map(|(&v, _)| v)
            .collect();
        Ok(DisplacementFace {
            input: warp.input::<f64>(),
            nets,
            warp,
            rest: face.mesh.vertices.clone(),
            jaw_vertices,
            jaw_pivot: face.jaw_pivot,
        })
    }

    pub fn vertex_count(&self) -> usize {
        self.rest.len()
    }

    /// `x = X + R_φᵀ N_D(φ̂(X), tanh z)` for every simulation vertex, and the jaw: the rigid
    /// motion (about the pivot) best fitting the jaw-attached vertices' predicted positions
    /// (the identity when the face has fewer than 3 of them). Fails on invalid codes or a
    /// non-finite output.
    pub fn pose(&self, codes: &Codes) -> Result<DisplacedPose, GenerativeError> {
        codes.validate()?;
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
        let jaw = if self.jaw_vertices.len() >= 3 {
            let rest: Vec<Point3<f64>> = self
                .jaw_vertices
                .iter()
                .map(|&v| self.rest[v as usize])
                .collect();
            let posed: Vec<Point3<f64>> = self
                .jaw_vertices
                .iter()
                .map(|&v| {
                    let i = 3 * v as usize;
                    Point3::from(Vector3::new(
                        positions[i],
                        positions[i + 1],
                        positions[i + 2],
                    ))
                })
                .collect();
            fit_rigid(&rest, &posed, &self.jaw_pivot)
                .map_err(|e| GenerativeError::NonFinite(format!("jaw fit: {e}")))?
                .motion
        } else {
            RigidMotion::IDENTITY
        };
        Ok(DisplacedPose {
            positions,
            bones: BonePose {
                skull: RigidMotion::IDENTITY,
                jaw,
            },
        })
    }
}
