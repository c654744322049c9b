//! The mapping network φ: D_M → D_C of one identity, its Jacobian ∂φ/∂x and the rotation R_φ,
//! and its file.
//!
//! φ is a SIREN (Sitzmann et al. 2020) — 4 sine layers with ω₀ = 5 and a linear layer, SIREN
//! initialization — between fixed normalizations of the two spaces, with an identity skip:
//!
//!   x̂ = (x − c_M)/s,   φ(x) = c_C + s·(x̂ + y(x̂)),   ∂φ/∂x = I + ∂y/∂x̂,
//!
//! where y is the network, c_M and c_C are the bounding-box centres of the identity's and the
//! canonical face's tissue and s is half the canonical face's largest extent (cm). The
//! normalization puts the inputs in [−1, 1]³, the range SIREN's initialization is designed for;
//! the skip makes the untrained φ a translation that lines the two faces up (det ∂φ/∂x near 1
//! from the start), so the network only learns the difference between the faces.

use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use faer::{Mat, Par};

use super::MappingError;
use crate::model::FaceModel;
use crate::model::file::{self, Format};
use crate::nn::{Mlp, MlpSpec, Pass, Tape};
use crate::sim::polar::svd_rotation;

/// The file format of trained mapping networks.
pub const MAPPING_FORMAT: Format = Format {
    kind: "mapping",
    version: 1,
};

/// The paper's architecture: hidden SIREN layers, their width and ω₀.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Architecture {
    pub hidden_layers: usize,
    pub width: usize,
    pub omega0: f64,
}

impl Default for Architecture {
    /// 4 SIREN layers with ω₀ = 5 (the paper) of width 64 (a CPU-sized width).
    fn default() -> Self {
        Architecture {
            hidden_layers: 4,
            width: 64,
            omega0: 5.0,
        }
    }
}

impl Architecture {
    /// The network y: 3 → SIREN × hidden_layers → linear 3.
    pub fn spec(&self) -> MlpSpec {
        MlpSpec::siren(3, self.width, self.hidden_layers, self.omega0, 3)
    }
}

/// The fixed normalization around the network (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    /// c_M: centre of the identity's tissue bounding box, cm.
    pub material_center: [f64; 3],
    /// c_C: centre of the canonical face's tissue bounding box, cm.
    pub canonical_center: [f64; 3],
    /// s: half the canonical face's largest bounding-box extent, cm.
    pub scale: f64,
}

impl Normalization {
    /// The frame between an identity's face and the canonical face.
    pub fn between(identity: &FaceModel, canonical: &FaceModel) -> Self {
        let center = |m: &FaceModel| {
            let (lo, hi) = m.mesh.bounds();
            let c = nalgebra::center(&lo, &hi);
            [c.x, c.y, c.z]
        };
        let (lo, hi) = canonical.mesh.bounds();
        let scale = 0.5 * (hi - lo).max();
        Normalization {
            material_center: center(identity),
            canonical_center: center(canonical),
            scale,
        }
    }

    /// x̂ = (x − c_M)/s.
    pub fn normalize_material(&self, p: &Point3<f64>) -> [f64; 3] {
        let c = self.material_center;
        [0, 1, 2].map(|k| (p[k] - c[k]) / self.scale)
    }

    /// X̂ = (X − c_C)/s.
    pub fn normalize_canonical(&self, p: &Point3<f64>) -> [f64; 3] {
        let c = self.canonical_center;
        [0, 1, 2].map(|k| (p[k] - c[k]) / self.scale)
    }
}

/// What training recorded (kept in the file, shown by `facesim stats`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainingRecord {
    pub seed: u64,
    pub iterations: u64,
    pub learning_rate: f64,
    pub lambda_elastic: f64,
    pub surface_batch: usize,
    pub elastic_batch: usize,
    pub surface_points: usize,
    pub elastic_points: usize,
    /// Loss terms over all points after training: mean squared vertex error (mm²) and mean
    /// elastic residual ‖J − R‖²_F.
    pub final_vertex_mse_mm2: f64,
    pub final_elastic: f64,
}

/// The stored form of a trained φ (postcard cannot carry the spec's tagged enums, so the
/// architecture is stored as plain numbers and the spec rebuilt from it).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct MappingFile {
    identity_name: String,
    canonical_name: String,
    mesh_vertices: usize,
    mesh_elements: usize,
    architecture: Architecture,
    frame: Normalization,
    params: Vec<f64>,
    record: TrainingRecord,
}

/// φ at one point: the canonical position and the Jacobian ∂φ/∂x (row i, column k = ∂φᵢ/∂x_k).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MappedPoint {
    pub canonical: Point3<f64>,
    pub jacobian: Matrix3<f64>,
}

impl MappedPoint {
    /// R_φ: the reflection-safe rotation of the polar decomposition of ∂φ/∂x.
    pub fn rotation(&self) -> Matrix3<f64> {
        rotation_of(&self.jacobian)
    }
}

/// The reflection-safe closest rotation of a Jacobian (an SVD: exact, no warm start needed).
pub fn rotation_of(j: &Matrix3<f64>) -> Matrix3<f64> {
    let q: UnitQuaternion<f64> = svd_rotation(j);
    q.to_rotation_matrix().into_inner()
}

/// A trained (or freshly initialized) mapping network of one identity.
#[derive(Clone, Debug, PartialEq)]
pub struct Mapping {
    pub identity_name: String,
    pub canonical_name: String,
    mesh_vertices: usize,
    mesh_elements: usize,
    pub architecture: Architecture,
    pub frame: Normalization,
    net: Mlp<f64>,
    pub record: Option<TrainingRecord>,
}

/// Points per chunk when evaluating φ (bounded tape memory, parallel over chunks).
const EVAL_CHUNK: usize = 512;

impl Mapping {
    /// An untrained φ between `identity` and `canonical`, initialized from `seed`.
    pub fn new(
        identity: &FaceModel,
        canonical: &FaceModel,
        architecture: Architecture,
        seed: u64,
    ) -> Result<Self, MappingError> {
        let net = Mlp::new(architecture.spec(), seed)?;
        Ok(Mapping {
            identity_name: identity.name.clone(),
            canonical_name: canonical.name.clone(),
            mesh_vertices: identity.mesh.vertex_count(),
            mesh_elements: identity.mesh.element_count(),
            architecture,
            frame: Normalization::between(identity, canonical),
            net,
            record: None,
        })
    }

    pub fn network(&self) -> &Mlp<f64> {
        &self.net
    }

    pub(crate) fn network_mut(&mut self) -> &mut Mlp<f64> {
        &mut self.net
    }

    /// Fails unless this φ was trained for `face` (same name and mesh size).
    pub fn check_face(&self, face: &FaceModel) -> Result<(), MappingError> {
        if face.name != self.identity_name
            || face.mesh.vertex_count() != self.mesh_vertices
            || face.mesh.element_count() != self.mesh_elements
        {
            return Err(MappingError::WrongFace {
                mapping: self.identity_name.clone(),
                vertices: self.mesh_vertices,
                elements: self.mesh_elements,
                face: face.name.clone(),
                face_vertices: face.mesh.vertex_count(),
                face_elements: face.mesh.element_count(),
            });
        }
        Ok(())
    }

    /// φ and ∂φ/∂x at each point (material space, cm), in parallel over fixed chunks (each
    /// point's result is independent of the others, so the output is deterministic).
    pub fn evaluate(&self, points: &[Point3<f64>]) -> Result<Vec<MappedPoint>, MappingError> {
        if let Some(i) = points
            .iter()
            .position(|p| !p.coords.iter().all(|v| v.is_finite()))
        {
            return Err(MappingError::NonFinitePoint(i));
        }
        let chunks: Vec<Result<Vec<MappedPoint>, MappingError>> = points
            .par_chunks(EVAL_CHUNK)
            .map(|chunk| self.evaluate_chunk(chunk))
            .collect();
        let mut out = Vec::with_capacity(points.len());
        for c in chunks {
            out.extend(c?);
        }
        Ok(out)
    }

    fn evaluate_chunk(&self, points: &[Point3<f64>]) -> Result<Vec<MappedPoint>, MappingError> {
        let n = points.len();
        let xs: Vec<[f64; 3]> = points
            .iter()
            .map(|p| self.frame.normalize_material(p))
            .collect();
        let x = Mat::from_fn(n, 3, |i, k| xs[i][k]);
        let mut tape = Tape::new();
        self.net
            .forward(x.as_ref(), None, Pass::Jacobian, &mut tape, Par::Seq)?;
        let (y, jac) = match (tape.output(), tape.jacobian()) {
            (Some(y), Some(j)) => (y, j),
            _ => unreachable!("a Jacobian pass records outputs and Jacobians"),
        };
        let (s, c) = (self.frame.scale, self.frame.canonical_center);
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            let canonical =
                Point3::from(Vector3::from_fn(|r, _| c[r] + s * (xs[i][r] + y[(i, r)])));
            let jacobian = Matrix3::from_fn(|r, k| {
                let skip = if r == k { 1.0 } else { 0.0 };
                skip + jac[(k * n + i, r)]
            });
            if !(canonical.coords.iter().all(|v| v.is_finite())
                && jacobian.iter().all(|v| v.is_finite()))
            {
                return Err(MappingError::NonFiniteOutput);
            }
            out.push(MappedPoint {
                canonical,
                jacobian,
            });
        }
        Ok(out)
    }

    /// Writes the trained φ (versioned, checksummed, atomic).
    pub fn save(&self, path: &std::path::Path) -> Result<(), MappingError> {
        let record = self.record.clone().ok_or(MappingError::Untrained)?;
        let stored = MappingFile {
            identity_name: self.identity_name.clone(),
            canonical_name: self.canonical_name.clone(),
            mesh_vertices: self.mesh_vertices,
            mesh_elements: self.mesh_elements,
            architecture: self.architecture,
            frame: self.frame,
            params: self.net.params().to_vec(),
            record,
        };
        Ok(file::write(path, MAPPING_FORMAT, &stored)?)
    }

    /// Reads a φ written by [`Mapping::save`] (checks the container, the parameter count and
    /// their finiteness).
    pub fn load(path: &std::path::Path) -> Result<Self, MappingError> {
        let stored: MappingFile = file::read(path, MAPPING_FORMAT)?;
        if !(stored.frame.scale.is_finite() && stored.frame.scale > 0.0) {
            return Err(MappingError::BadFrame(stored.frame.scale));
        }
        let net = Mlp::from_params(stored.architecture.spec(), stored.params)?;
        Ok(Mapping {
            identity_name: stored.identity_name,
            canonical_name: stored.canonical_name,
            mesh_vertices: stored.mesh_vertices,
            mesh_elements: stored.mesh_elements,
            architecture: stored.architecture,
            frame: stored.frame,
            net,
            record: Some(stored.record),
        })
    }
}
