//! Actuation crosses: per element, the principal directions along which the actuation
//! contracts the tissue, drawn at the element's deformed centroid with lengths proportional
//! to the contraction `1 − λ` (λ: eigenvalue of the symmetric actuation `A`, 1 = at rest).

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::geometry::TetMesh;
use crate::sim::SymTensor;

/// Contractions smaller than this are not drawn.
pub const MIN_CONTRACTION: f64 = 0.02;

/// One arm of a cross: a segment centred at the element, and its contraction `1 − λ`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CrossArm {
    pub from: [f32; 3],
    pub to: [f32; 3],
    pub contraction: f32,
}

/// Arms of every element whose actuation contracts by at least [`MIN_CONTRACTION`], in
/// element order (deterministic).
pub fn actuation_crosses(mesh: &TetMesh, x: &[f64], tensors: &[SymTensor]) -> Vec<CrossArm> {
    let rest_volumes = mesh.volumes();
    let per_element: Vec<Vec<CrossArm>> = (0..mesh.tets.len())
        .into_par_iter()
        .map(|e| {
            let a = tensors[e].to_matrix();
            if (a - Matrix3::identity()).abs().max() < MIN_CONTRACTION {
                return Vec::new();
            }
            let t = mesh.tets[e];
            let p = |i: usize| {
                let v = t[i] as usize;
                Vector3::new(x[3 * v], x[3 * v + 1], x[3 * v + 2])
            };
            let center = (p(0) + p(1) + p(2) + p(3)) / 4.0;
            // The deformation gradient carries rest directions to the deformed element.
            let rest = |i: usize| mesh.vertices[t[i] as usize].coords;
            let dm =
                Matrix3::from_columns(&[rest(1) - rest(0), rest(2) - rest(0), rest(3) - rest(0)]);
            let ds = Matrix3::from_columns(&[p(1) - p(0), p(2) - p(0), p(3) - p(0)]);
            let f = dm.try_inverse().map_or(Matrix3::identity(), |inv| ds * inv);
            let size = rest_volumes[e].abs().cbrt();
            let eig = SymmetricEigen::new(a);
            (0..3)
                .filter_map(|k| {
                    let contraction = 1.0 - eig.eigenvalues[k];
                    if contraction < MIN_CONTRACTION {
                        return None;
                    }
                    let dir = f * eig.eigenvectors.column(k).into_owned();
                    let n = dir.norm();
                    if !(n > 0.0) || !contraction.is_finite() {
                        return None;
                    }
                    let half = dir / n * (0.5 * size * contraction.min(1.0) * 2.0);
                    let to32 = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
                    Some(CrossArm {
                        from: to32(center - half),
                        to: to32(center + half),
                        contraction: contraction as f32,
                    })
                })
                .collect()
        })
        .collect();
    per_element.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn unit_tet() -> TetMesh {
        TetMesh::new(
            vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
                Point3::new(0.0, 0.0, 1.0),
            ],
            vec![[0, 1, 2, 3]],
        )
        .unwrap()
    }

    #[test]
    fn a_contraction_along_x_gives_one_arm_along_x() {
        let mesh = unit_tet();
        let x: Vec<f64> = mesh.vertices.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        let arms = actuation_crosses(&mesh, &x, &[SymTensor([0.7, 1.0, 1.0, 0.0, 0.0, 0.0])]);
        assert_eq!(arms.len(), 1);
        let d: Vec<f32> = (0..3).map(|k| arms[0].to[k] - arms[0].from[k]).collect();
        assert!(
            d[0].abs() > 0.1 && d[1].abs() < 1e-6 && d[2].abs() < 1e-6,
            "{d:?}"
        );
        assert!((arms[0].contraction - 0.3).abs() < 1e-6);
        // Stretch and identity give no arms.
        assert!(
            actuation_crosses(&mesh, &x, &[SymTensor([1.2, 1.0, 1.0, 0.0, 0.0, 0.0])]).is_empty()
        );
        assert!(actuation_crosses(&mesh, &x, &[SymTensor::IDENTITY]).is_empty());
    }
}
