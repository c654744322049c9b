//! The actuation warp Ã(x) = R_φᵀ A(φ(x)) R_φ (supplemental, Sec. 1) and its comparison with
//! the naive warp A(φ(x)) (the paper's Figs. 1–2).
//!
//! R_φ takes material directions to canonical ones, so a canonical contraction direction v
//! is the material direction R_φᵀ v: the warp turns the principal directions with the face
//! and keeps the magnitudes (identity actuations stay identities, so every identity stays at
//! rest). The naive warp keeps the canonical directions as they are in world space.

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use super::MappingError;
use super::network::Mapping;
use crate::geometry::TetMesh;
use crate::model::{Binding, FaceModel};
use crate::rig::Region;
use crate::sim::{BonePose, Quality, SymTensor};

/// Ã = Rᵀ A R.
pub fn warp(r: &Matrix3<f64>, a: &SymTensor) -> SymTensor {
    SymTensor::from_matrix(&(r.transpose() * a.to_matrix() * r))
}

/// What the warp needs per element of an identity's mesh, evaluated once: the canonical
/// position φ(centroid) (where N_A is evaluated) and R_φ at the centroid.
#[derive(Clone, Debug, PartialEq)]
pub struct ElementWarp {
    pub canonical: Vec<Point3<f64>>,
    pub rotations: Vec<Matrix3<f64>>,
}

/// Element centroids of a mesh.
pub fn centroids(mesh: &TetMesh) -> Vec<Point3<f64>> {
    mesh.tets
        .iter()
        .map(|tet| {
            Point3::from(
                tet.iter()
                    .map(|&v| mesh.vertices[v as usize].coords)
                    .sum::<Vector3<f64>>()
                    / 4.0,
            )
        })
        .collect()
}

impl ElementWarp {
    /// φ(centroid) and R_φ for every element of `face` (the face φ was trained for).
    pub fn new(face: &FaceModel, mapping: &Mapping) -> Result<Self, MappingError> {
        mapping.check_face(face)?;
        let mapped = mapping.evaluate(&centroids(&face.mesh))?;
        Ok(ElementWarp {
            canonical: mapped.iter().map(|m| m.canonical).collect(),
            rotations: mapped.iter().map(|m| m.rotation()).collect(),
        })
    }

    /// Per element, R_φᵀ A(φ(x)) R_φ for a canonical field A.
    pub fn warped(&self, field: impl Fn(&Point3<f64>) -> SymTensor) -> Vec<SymTensor> {
        self.canonical
            .iter()
            .zip(&self.rotations)
            .map(|(x, r)| warp(r, &field(x)))
            .collect()
    }

    /// Per element, A(φ(x)) (the naive alternative).
    pub fn naive(&self, field: impl Fn(&Point3<f64>) -> SymTensor) -> Vec<SymTensor> {
        self.canonical.iter().map(field).collect()
    }

    /// The warp data of the same face rigidly rotated by `q` about `center`: φ′(x) =
    /// φ(qᵀ(x − c) + c), so ∂φ′/∂x = ∂φ/∂x·qᵀ and R_φ′ = R_φ·qᵀ.
    pub fn rotated(&self, q: &Matrix3<f64>) -> ElementWarp {
        ElementWarp {
            canonical: self.canonical.clone(),
            rotations: self.rotations.iter().map(|r| r * q.transpose()).collect(),
        }
    }
}

/// A canonical test field like the orbicularis oris: contraction (stretch 1 − strength at the
/// centre, Gaussian fall-off of `radius` cm) along circles about `axis` through `center`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RingField {
    pub center: [f64; 3],
    pub axis: [f64; 3],
    pub strength: f64,
    pub radius: f64,
}

impl RingField {
    /// Centred on the canonical face's lips (the embedded mouth-socket render vertices),
    /// about the face's forward axis (+z in the rig).
    pub fn around_mouth(
        canonical: &FaceModel,
        strength: f64,
        radius: f64,
    ) -> Result<Self, MappingError> {
        let lips: Vec<Point3<f64>> = canonical
            .render
            .rig_vertices
            .iter()
            .zip(&canonical.render.bindings)
            .zip(&canonical.render.rest)
            .filter(|((rig, b), _)| {
                Region::of_vertex(**rig as usize) == Some(Region::MouthSocket)
                    && matches!(b, Binding::Embedded { .. })
            })
            .map(|(_, p)| *p)
            .collect();
        if lips.is_empty() {
            return Err(MappingError::NoLips(canonical.name.clone()));
        }
        let c = lips.iter().map(|p| p.coords).sum::<Vector3<f64>>() / lips.len() as f64;
        Ok(RingField {
            center: [c.x, c.y, c.z],
            axis: [0.0, 0.0, 1.0],
            strength,
            radius,
        })
    }

    /// A(X) = I + (λ − 1) d dᵀ, d the unit tangent of the circle through X.
    pub fn at(&self, x: &Point3<f64>) -> SymTensor {
        let axis = Vector3::from(self.axis).normalize();
        let r = x.coords - Vector3::from(self.center);
        let radial = r - axis * axis.dot(&r);
        let tangent = axis.cross(&radial);
        if tangent.norm() < 1e-9 {
            return SymTensor::IDENTITY;
        }
        let d = tangent.normalize();
        let bump = (-radial.norm_squared() / (self.radius * self.radius)).exp();
        let lambda = 1.0 - self.strength * bump;
        SymTensor::from_matrix(&(Matrix3::identity() + d * d.transpose() * (lambda - 1.0)))
    }
}

/// The unit eigenvector of a symmetric tensor's smallest eigenvalue (its contraction
/// direction), and the gap to the next eigenvalue (0: no defined direction).
pub fn contraction_direction(a: &SymTensor) -> (Vector3<f64>, f64) {
    let eig = a.to_matrix().symmetric_eigen();
    let mut order = [0, 1, 2];
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let v = eig.eigenvectors.column(order[0]).into_owned();
    (v, eig.eigenvalues[order[1]] - eig.eigenvalues[order[0]])
}

/// The angle between two directions (sign-free), degrees.
pub fn direction_angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    (a.dot(b).abs() / (a.norm() * b.norm()))
        .clamp(0.0, 1.0)
        .acos()
        .to_degrees()
}

/// Quantiles of a sample (sorted copy; nearest rank).
pub fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let i = ((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1);
    v[i]
}

/// How the warp and the naive warp differ on one face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WarpComparison {
    pub face: String,
    /// Rigid rotation applied to the face before warping (degrees about the vertical axis).
    pub rotation_deg: f64,
    /// Elements where the field contracts (eigenvalue gap ≥ 0.05).
    pub actuated_elements: usize,
    /// Angle between the warped and the naive contraction directions over those elements.
    pub angle_median_deg: f64,
    pub angle_p95_deg: f64,
    pub angle_max_deg: f64,
    /// Largest displacement from rest of the warp-driven and naive-driven faces, mm.
    pub warp_max_displacement_mm: f64,
    pub naive_max_displacement_mm: f64,
    /// ‖x_warp − x_naive‖ over the mesh vertices, mm (in the unrotated frame).
    pub difference_mean_mm: f64,
    pub difference_max_mm: f64,
    /// For a rotated face: ‖qᵀ x′ − x‖ of its warp-driven (naive-driven) result against the
    /// unrotated face's warp-driven result, mm — 0 means the actuation turned with the face.
    pub warp_equivariance_max_mm: f64,
    pub naive_equivariance_max_mm: f64,
    /// Identity actuations: the largest displacement from rest, mm (must be ~0).
    pub identity_actuation_max_displacement_mm: f64,
}

/// A copy of `face` rigidly rotated by `q` about `center` (mesh, pivot, render rest).
pub fn rotated_face(
    face: &FaceModel,
    q: &Matrix3<f64>,
    center: &Point3<f64>,
) -> Result<FaceModel, MappingError> {
    let rot = |p: &Point3<f64>| center + q * (p - center);
    let mut out = face.clone();
    out.mesh = TetMesh::new(
        face.mesh.vertices.iter().map(rot).collect(),
        face.mesh.tets.clone(),
    )
    .map_err(|e| MappingError::Sim(e.to_string()))?;
    out.jaw_pivot = rot(&face.jaw_pivot);
    out.render.rest = face.render.rest.iter().map(rot).collect();
    Ok(out)
}

/// Solves `face` from rest with per-element actuations (bones at rest, final quality) and
/// returns the vertex positions.
fn simulate(face: &FaceModel, actuations: &[SymTensor]) -> Result<Vec<f64>, MappingError> {
    let sim = face
        .simulator()
        .map_err(|e| MappingError::Sim(e.to_string()))?;
    let mut state = sim.rest_state();
    sim.solve(
        actuations,
        &BonePose::default(),
        &mut state,
        &Quality::Final.settings(),
    )
    .map_err(|e| MappingError::Sim(e.to_string()))?;
    Ok(state.flat_positions().to_vec())
}

fn max_displacement_mm(x: &[f64], rest: &[Point3<f64>]) -> f64 {
    rest.iter()
        .enumerate()
        .map(|(i, p)| (Vector3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]) - p.coords).norm())
        .fold(0.0, f64::max)
        * super::train::MM_PER_CM
}

/// Compares the warp with the naive warp on `face` for the canonical `field`: principal
/// directions, simulated faces, and — on a copy rotated by `rotation_deg` about the vertical
/// (y) axis — whether the actuation turns with the face.
pub fn compare(
    face: &FaceModel,
    mapping: &Mapping,
    field: &RingField,
    rotation_deg: f64,
) -> Result<WarpComparison, MappingError> {
    let ew = ElementWarp::new(face, mapping)?;
    let warped = ew.warped(|x| field.at(x));
    let naive = ew.naive(|x| field.at(x));
    let mut angles = Vec::new();
    for (w, n) in warped.iter().zip(&naive) {
        let (dn, gap) = contraction_direction(n);
        if gap >= 0.05 {
            let (dw, _) = contraction_direction(w);
            angles.push(direction_angle_deg(&dw, &dn));
        }
    }
    let rest = &face.mesh.vertices;
    let x_id = simulate(face, &ew.warped(|_| SymTensor::IDENTITY))?;
    let x_warp = simulate(face, &warped)?;
    let x_naive = simulate(face, &naive)?;
    let diffs: Vec<f64> = (0..rest.len())
        .map(|i| {
            (0..3)
                .map(|k| (x_warp[3 * i + k] - x_naive[3 * i + k]).powi(2))
                .sum::<f64>()
                .sqrt()
                * super::train::MM_PER_CM
        })
        .collect();

    // The same face rotated: the warp must give the rotated result, the naive warp does not.
    let q: Matrix3<f64> =
        Rotation3::from_axis_angle(&Vector3::y_axis(), rotation_deg.to_radians()).into_inner();
    let (lo, hi) = face.mesh.bounds();
    let center = nalgebra::center(&lo, &hi);
    let turned = rotated_face(face, &q, &center)?;
    let ew_turned = ew.rotated(&q);
    let back = |x: &[f64]| -> Vec<f64> {
        let mut out = vec![0.0; x.len()];
        for i in 0..x.len() / 3 {
            let p = Point3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
            let b = center + q.transpose() * (p - center);
            out[3 * i..3 * i + 3].copy_from_slice(&[b.x, b.y, b.z]);
        }
        out
    };
    let gap_to = |x: &[f64]| -> f64 {
        x.iter()
            .zip(&x_warp)
            .collect::<Vec<_>>()
            .chunks(3)
            .map(|c| c.iter().map(|(a, b)| (*a - *b).powi(2)).sum::<f64>().sqrt())
            .fold(0.0, f64::max)
            * super::train::MM_PER_CM
    };
    let turned_warp = back(&simulate(&turned, &ew_turned.warped(|x| field.at(x)))?);
    let turned_naive = back(&simulate(&turned, &ew_turned.naive(|x| field.at(x)))?);

    Ok(WarpComparison {
        face: face.name.clone(),
        rotation_deg,
        actuated_elements: angles.len(),
        angle_median_deg: quantile(&angles, 0.5),
        angle_p95_deg: quantile(&angles, 0.95),
        angle_max_deg: angles.iter().copied().fold(0.0, f64::max),
        warp_max_displacement_mm: max_displacement_mm(&x_warp, rest),
        naive_max_displacement_mm: max_displacement_mm(&x_naive, rest),
        difference_mean_mm: diffs.iter().sum::<f64>() / diffs.len().max(1) as f64,
        difference_max_mm: diffs.iter().copied().fold(0.0, f64::max),
        warp_equivariance_max_mm: gap_to(&turned_warp),
        naive_equivariance_max_mm: gap_to(&turned_naive),
        identity_actuation_max_displacement_mm: max_displacement_mm(&x_id, rest),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_warp_conjugates_by_the_rotation_and_keeps_identities() {
        let r: Matrix3<f64> = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.4).into_inner();
        assert_eq!(
            warp(&r, &SymTensor::IDENTITY).0.map(|v| (v * 1e12).round()),
            SymTensor::IDENTITY.0.map(|v| (v * 1e12).round())
        );
        let d = Vector3::new(0.0, 1.0, 0.0);
        let a = SymTensor::from_matrix(&(Matrix3::identity() - 0.3 * d * d.transpose()));
        let (v, gap) = contraction_direction(&warp(&r, &a));
        assert!((gap - 0.3).abs() < 1e-12);
        // The contraction direction is Rᵀ d.
        assert!(direction_angle_deg(&v, &(r.transpose() * d)) < 1e-6);
        assert!((direction_angle_deg(&v, &d) - 0.4f64.to_degrees()).abs() < 1e-6);
    }

    #[test]
    fn the_ring_field_contracts_along_circles_about_its_axis() {
        let f = RingField {
            center: [0.0, 0.0, 0.0],
            axis: [0.0, 0.0, 1.0],
            strength: 0.3,
            radius: 2.0,
        };
        let a = f.at(&Point3::new(1.0, 0.0, 0.5));
        let (v, gap) = contraction_direction(&a);
        assert!(direction_angle_deg(&v, &Vector3::y()) < 1e-9);
        assert!((gap - 0.3 * (-0.25f64).exp()).abs() < 1e-12);
        assert!(a.validate().is_ok());
        assert_eq!(f.at(&Point3::new(0.0, 0.0, 3.0)), SymTensor::IDENTITY);
    }
}
