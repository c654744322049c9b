//! The networks bound to one face: the [`ActuationModel`] the editor, session and exporter
//! drive.
//!
//! Per face, once: each element centroid's canonical position φ(x) (the template face's own
//! centroids; φ for the identities), normalized, and R_φ; N_A's code-independent first layer
//! over those points is cached ([`crate::nn::PointCache`]). Per frame: the encoders and N_B
//! (a few thousand flops), N_A's remaining layers over the elements in f32, then per element
//! `Ã = exp(R_φᵀ log A R_φ) = R_φᵀ A R_φ` (the warp commutes with exp; [`super::expm`]).

use crate::generative::NetworkSet;
use std::sync::Arc;

use faer::{Mat, Par};
use nalgebra::Matrix3;
use rayon::prelude::*;

use super::GenerativeError;
use super::expm::exp_sym;
use super::nets::{CanonicalFrame, GenerativeNets};
use crate::drive::{Actuation, ActuationModel, Codes, DriveError};
use crate::mapping::Mapping;
use crate::mapping::warp::{ElementWarp, centroids, warp};
use crate::model::FaceModel;
use crate::nn::{CodeBatch, Mlp, PointCache, Tape};
use crate::sample::Sample;
use crate::sim::{RigidMotion, SymTensor};

/// Where a face's elements are in canonical space (normalized) and how their frames turn.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceWarp {
    /// X̂ per element (rows of N_A's input).
    pub canonical: Vec<[f64; 3]>,
    /// R_φ per element; `None` on the template face (φ is the identity).
    pub rotations: Option<Vec<Matrix3<f64>>>,
}

impl FaceWarp {
    /// The template face (`mapping` = `None`, identity `None`) or an identity with its φ.
    pub fn new(
        face: &FaceModel,
        mapping: Option<&Mapping>,
        frame: &CanonicalFrame,
    ) -> Result<Self, GenerativeError> {
        match (face.identity, mapping) {
            (None, _) => Ok(FaceWarp {
                canonical: centroids(&face.mesh)
                    .iter()
                    .map(|p| frame.normalize(p))
                    .collect(),
                rotations: None,
            }),
            (Some(_), None) => Err(GenerativeError::NoMapping {
                face: face.name.clone(),
            }),
            (Some(_), Some(m)) => {
                let w = ElementWarp::new(face, m)?;
                Ok(FaceWarp {
                    canonical: w.canonical.iter().map(|p| frame.normalize(p)).collect(),
                    rotations: Some(w.rotations),
                })
            }
        }
    }

    /// The same for the face's simulation *vertices* (the displacement baseline's points):
    /// φ(vertex) and R_φ at the vertex.
    pub fn vertices(
        face: &FaceModel,
        mapping: Option<&Mapping>,
        frame: &CanonicalFrame,
    ) -> Result<Self, GenerativeError> {
        match (face.identity, mapping) {
            (None, _) => Ok(FaceWarp {
                canonical: face
                    .mesh
                    .vertices
                    .iter()
                    .map(|p| frame.normalize(p))
                    .collect(),
                rotations: None,
            }),
            (Some(_), None) => Err(GenerativeError::NoMapping {
                face: face.name.clone(),
            }),
            (Some(_), Some(m)) => {
                m.check_face(face)?;
                let mapped = m.evaluate(&face.mesh.vertices)?;
                Ok(FaceWarp {
                    canonical: mapped
                        .iter()
                        .map(|p| frame.normalize(&p.canonical))
                        .collect(),
                    rotations: Some(mapped.iter().map(|p| p.rotation()).collect()),
                })
            }
        }
    }

    pub fn len(&self) -> usize {
        self.canonical.len()
    }

    /// A material-space vector at point `i` in canonical space: `R_φ v`.
    pub fn vector_to_canonical(&self, i: usize, v: &[f64; 3]) -> [f64; 3] {
        match &self.rotations {
            None => *v,
            Some(r) => (r[i] * nalgebra::Vector3::from(*v)).into(),
        }
    }

    /// A canonical vector at point `i` in material space: `R_φᵀ v`.
    pub fn vector_to_material(&self, i: usize, v: &[f64; 3]) -> [f64; 3] {
        match &self.rotations {
            None => *v,
            Some(r) => (r[i].transpose() * nalgebra::Vector3::from(*v)).into(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.canonical.is_empty()
    }

    /// N_A's input rows (N × 3).
    pub fn input<T: crate::nn::Real>(&self) -> Mat<T> {
        Mat::from_fn(self.len(), 3, |i, k| T::of(self.canonical[i][k]))
    }

    /// A material-space log actuation of element `e` in canonical space: `R_φ L R_φᵀ`.
    pub fn to_canonical(&self, e: usize, log: &[f64; 6]) -> [f64; 6] {
        match &self.rotations {
            None => *log,
            Some(r) => warp(&r[e].transpose(), &SymTensor(*log)).0,
        }
    }

    /// A canonical log actuation of element `e` in material space: `R_φᵀ L R_φ`.
    pub fn to_material(&self, e: usize, log: &[f64; 6]) -> [f64; 6] {
        match &self.rotations {
            None => *log,
            Some(r) => warp(&r[e], &SymTensor(*log)).0,
        }
    }
}

/// The networks driving one face (module docs).
pub struct GenerativeFace {
    nets: Arc<GenerativeNets>,
    actuation: Mlp<f32>,
    cache: PointCache<f32>,
    warp: FaceWarp,
}

impl GenerativeFace {
    /// Binds `nets` to `face` (its φ: `mapping`, `None` for the template face).
    pub fn new(
        nets: Arc<GenerativeNets>,
        face: &FaceModel,
        mapping: Option<&Mapping>,
    ) -> Result<Self, GenerativeError> {
        let warp = FaceWarp::new(face, mapping, &nets.frame)?;
        let actuation: Mlp<f32> = nets.actuation.cast();
        let cache = actuation.cache_points(warp.input::<f32>().as_ref(), Par::Seq)?;
        Ok(GenerativeFace {
            nets,
            actuation,
            cache,
            warp,
        })
    }

    pub fn nets(&self) -> &Arc<GenerativeNets> {
        &self.nets
    }

    /// N_A over every element for one modulation row (the cached pass): canonical log A per
    /// element. What the inference benchmark times.
    pub fn canonical_logs(&self, u: &[f64], tape: &mut Tape<f32>) -> Result<(), DriveError> {
        let u32: Vec<f32> = u.iter().map(|&v| v as f32).collect();
        self.actuation
            .forward_cached(&self.cache, Some(&CodeBatch::shared(&u32)), tape, Par::Seq)
            .map_err(|e| DriveError::BadTensor {
                element: 0,
                reason: format!("actuation network: {e}"),
            })
    }
}

fn net_error(e: GenerativeError) -> DriveError {
    DriveError::BadTensor {
        element: 0,
        reason: format!("networks: {e}"),
    }
}

impl ActuationModel for GenerativeFace {
    fn element_count(&self) -> usize {
        self.warp.len()
    }

    fn actuate(&self, codes: &Codes) -> Result<Actuation, DriveError> {
        codes.validate()?;
        let u = self
            .nets
            .modulation(std::slice::from_ref(codes))
            .map_err(net_error)?;
        let u: Vec<f64> = (0..u.ncols()).map(|k| u[(0, k)]).collect();
        let mut tape = Tape::new();
        self.canonical_logs(&u, &mut tape)?;
        let y = tape.output().expect("a value pass has outputs");
        let logs: Vec<[f64; 6]> = (0..y.nrows())
            .map(|e| [0, 1, 2, 3, 4, 5].map(|k| y[(e, k)] as f64))
            .collect();
        let tensors: Vec<SymTensor> = logs
            .par_iter()
            .enumerate()
            .with_min_len(256)
            .map(|(e, l)| exp_sym(&self.warp.to_material(e, l)))
            .collect();
        if let Some(e) = tensors.iter().position(|t| t.validate().is_err()) {
            return Err(DriveError::BadTensor {
                element: e,
                reason: format!("{:?} from log {:?}", tensors[e], logs[e]),
            });
        }
        let jaw = self.nets.jaw_params(&u).map_err(net_error)?;
        if jaw.iter().any(|v| !v.is_finite()) {
            return Err(DriveError::BadTensor {
                element: 0,
                reason: format!("non-finite jaw {jaw:?}"),
            });
        }
        Ok(Actuation {
            tensors,
            jaw: RigidMotion::from_params(jaw),
        })
    }
}

/// The networks driving every face of a sample, in the sample's order (what the session
/// takes in place of the actuation bases). Identities need their mappings.
pub fn sample_actuations(
    sample: &Sample,
    nets: Arc<GenerativeNets>,
) -> Result<Vec<Arc<dyn ActuationModel>>, GenerativeError> {
    sample
        .faces
        .iter()
        .map(|f| {
            let g = GenerativeFace::new(nets.clone(), &f.model, f.mapping.as_ref())?;
            Ok(Arc::new(g) as Arc<dyn ActuationModel>)
        })
        .collect()
}

/// The trained networks' file name in a sample folder (`sample_models/ict/generative.nn`).
pub const SAMPLE_NETWORKS: &str = "generative.nn";

/// The sample's trained networks in its file `file` ([`SAMPLE_NETWORKS`], or
/// [`super::stage2::SAMPLE_STAGE2_NETWORKS`] for the stage-2 weights) driving each of its
/// faces, in the sample's order; `None` when the sample has no such file. What the session
/// loads to drive the faces with the networks instead of the actuation bases.
pub fn load_sample_networks(
    sample: &Sample,
    file: &str,
) -> Result<Option<Vec<Arc<dyn ActuationModel>>>, GenerativeError> {
    let path = sample.dir.join(file);
    if !path.exists() {
        return Ok(None);
    }
    let nets = Arc::new(GenerativeNets::load(&path)?);
    sample_actuations(sample, nets).map(Some)
}
