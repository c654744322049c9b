//! The displacement baseline's training data: per face, its simulation vertices in canonical
//! space (φ, normalized; R_φ), and per pose the fitted displacement of every vertex rotated
//! into canonical space (`R_φ d`). Batches are drawn exactly like stage 1's
//! ([`crate::generative::train::batch_picks`]: same poses per iteration for a seed), with
//! vertices in place of elements.

use faer::Mat;

use crate::drive::Codes;
use crate::generative::GenerativeError;
use crate::generative::data::FacePoses;
use crate::generative::generative_face::FaceWarp;
use crate::generative::train::{Stage1Config, batch_picks, pose_index};

/// One pose: codes and canonical displacement per vertex (cm).
#[derive(Clone, Debug)]
pub struct DisplacementPose {
    pub codes: Codes,
    /// The fitted jaw `[θ; t]`.
    pub jaw: [f64; 6],
    pub displacements: Vec<[f32; 3]>,
}

/// One face's vertices and poses.
#[derive(Clone, Debug)]
pub struct DisplacementFaceData {
    pub name: String,
    /// Per simulation vertex ([`FaceWarp::vertices`]).
    pub warp: FaceWarp,
    pub poses: Vec<DisplacementPose>,
}

/// Everything the baseline trains on.
#[derive(Clone, Debug)]
pub struct DisplacementData {
    pub faces: Vec<DisplacementFaceData>,
    index: Vec<(usize, usize)>,
}

/// A batch: codes, canonical positions (rows of pose b after those of poses < b), rows per
/// pose, canonical target displacement per row.
#[derive(Clone, Debug)]
pub struct DisplacementBatch {
    pub codes: Vec<Codes>,
    pub x: Mat<f64>,
    pub counts: Vec<usize>,
    pub targets: Vec<[f64; 3]>,
    /// Fitted jaw per pose.
    pub jaw: Vec<[f64; 6]>,
}

impl DisplacementData {
    /// Rotates each face's material-space displacements into canonical space; `warp` must be
    /// the face's vertex warp.
    pub fn new(faces: Vec<(FaceWarp, FacePoses)>) -> Result<Self, GenerativeError> {
        let mut out = Vec::with_capacity(faces.len());
        for (warp, poses) in faces {
            if let Some(p) = poses
                .poses
                .iter()
                .find(|p| p.displacements.len() != warp.len())
            {
                return Err(GenerativeError::Config(format!(
                    "a pose of {} has {} vertex displacements, its vertex warp {} vertices",
                    poses.face,
                    p.displacements.len(),
                    warp.len()
                )));
            }
            let samples = poses
                .poses
                .iter()
                .map(|p| DisplacementPose {
                    codes: p.codes,
                    jaw: p.jaw,
                    displacements: p
                        .displacements
                        .iter()
                        .enumerate()
                        .map(|(v, d)| {
                            warp.vector_to_canonical(v, &d.map(f64::from))
                                .map(|c| c as f32)
                        })
                        .collect(),
                })
                .collect();
            out.push(DisplacementFaceData {
                name: poses.face,
                warp,
                poses: samples,
            });
        }
        let index = pose_index(out.iter().map(|d| d.poses.len()))?;
        Ok(DisplacementData { faces: out, index })
    }

    pub fn pose_count(&self) -> usize {
        self.index.len()
    }

    /// The batch of iteration `it`: `config.batch_poses` poses × `config.elements_per_pose`
    /// vertices each.
    pub fn batch(&self, config: &Stage1Config, it: u64) -> DisplacementBatch {
        let (mut codes, mut counts, mut targets, mut rows, mut jaw) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (f, p, vertices) in batch_picks(config, it, &self.index, |f| self.faces[f].warp.len()) {
            let face = &self.faces[f];
            let pose = &face.poses[p];
            codes.push(pose.codes);
            jaw.push(pose.jaw);
            counts.push(vertices.len());
            for v in vertices {
                targets.push(pose.displacements[v].map(f64::from));
                rows.push(face.warp.canonical[v]);
            }
        }
        DisplacementBatch {
            codes,
            x: Mat::from_fn(rows.len(), 3, |i, k| rows[i][k]),
            counts,
            targets,
            jaw,
        }
    }
}
