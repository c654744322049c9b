//! Style transfer without a canonical space (the paper's "Model-N", supplemental Fig. 6):
//! identity A's per-identity actuations carried to identity B's mesh element by element.
//!
//! B's element e takes the actuation tensor of A's element whose rest centroid is nearest to
//! e's rest centroid (both faces sit in the rig's common frame), and A's jaw. Driving it with
//! A's style code is "B's face with A's style" for a model that only knows A's actuations per
//! element; the networks do the same through canonical space (φ and the warp), and the rig's
//! target for B in A's style is the reference both are measured against ([`super::evaluate`]
//! with B's face and A's style).

use std::sync::Arc;

use nalgebra::Point3;
use rayon::prelude::*;

use crate::drive::{Actuation, ActuationModel, Codes, DriveError};
use crate::mapping::warp::centroids;
use crate::model::FaceModel;

/// A's actuation model read out on B's elements (module docs).
pub struct NearestElementTransfer {
    source: Arc<dyn ActuationModel>,
    /// For each element of B, the element of A it copies.
    source_element: Vec<usize>,
}

impl NearestElementTransfer {
    /// `source` drives face `a`; the result drives face `b`.
    pub fn new(
        source: Arc<dyn ActuationModel>,
        a: &FaceModel,
        b: &FaceModel,
    ) -> Result<Self, DriveError> {
        let ca = centroids(&a.mesh);
        if source.element_count() != ca.len() {
            return Err(DriveError::BadTensor {
                element: 0,
                reason: format!(
                    "the source model drives {} elements, face {} has {}",
                    source.element_count(),
                    a.name,
                    ca.len()
                ),
            });
        }
        let nearest = |p: &Point3<f64>| {
            ca.iter()
                .enumerate()
                .map(|(i, q)| (i, (p - q).norm_squared()))
                .min_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)))
                .map_or(0, |(i, _)| i)
        };
        let source_element = centroids(&b.mesh).par_iter().map(nearest).collect();
        Ok(NearestElementTransfer {
            source,
            source_element,
        })
    }

    /// For each element of B, the element of A it copies.
    pub fn source_elements(&self) -> &[usize] {
        &self.source_element
    }
}

impl ActuationModel for NearestElementTransfer {
    fn element_count(&self) -> usize {
        self.source_element.len()
    }

    fn actuate(&self, codes: &Codes) -> Result<Actuation, DriveError> {
        let a = self.source.actuate(codes)?;
        Ok(Actuation {
            tensors: self.source_element.iter().map(|&e| a.tensors[e]).collect(),
            jaw: a.jaw,
        })
    }
}
