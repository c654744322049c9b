//! The per-element linear operator from vertex positions to the deformation gradient.

use nalgebra::{Matrix3, Vector3};

use crate::geometry::TetMesh;

/// Linear tetrahedron: `F = Σᵢ xᵢ ⊗ gᵢ`, where `gᵢ` is the (constant) gradient of vertex `i`'s
/// barycentric coordinate in the rest configuration, so `F = I` at rest. Rows `1..4` of
/// `Dm⁻¹` give `g₁..g₃` and `g₀ = −(g₁ + g₂ + g₃)`.
#[derive(Clone, Copy, Debug)]
pub struct ElementOperator {
    pub grads: [Vector3<f64>; 4],
    pub rest_volume: f64,
}

impl ElementOperator {
    pub fn for_mesh(mesh: &TetMesh) -> Vec<Self> {
        (0..mesh.element_count())
            .map(|e| {
                let dm = mesh.edge_matrix(e);
                // TetMesh::new guarantees positive, non-flat elements, so Dm is invertible.
                let inv = dm
                    .try_inverse()
                    .expect("validated mesh has invertible rest elements");
                let g1: Vector3<f64> = inv.row(0).transpose();
                let g2: Vector3<f64> = inv.row(1).transpose();
                let g3: Vector3<f64> = inv.row(2).transpose();
                Self {
                    grads: [-(g1 + g2 + g3), g1, g2, g3],
                    rest_volume: dm.determinant() / 6.0,
                }
            })
            .collect()
    }

    /// `F = Σᵢ xᵢ gᵢᵀ` for the element's 4 vertex positions (or position changes).
    #[inline]
    pub fn deformation_gradient(&self, x: &[Vector3<f64>; 4]) -> Matrix3<f64> {
        x[0] * self.grads[0].transpose()
            + x[1] * self.grads[1].transpose()
            + x[2] * self.grads[2].transpose()
            + x[3] * self.grads[3].transpose()
    }

    /// The vertex forces of a first Piola–Kirchhoff-like stress `P = ∂E/∂F`:
    /// `∂E/∂xᵢ = P gᵢ`.
    #[inline]
    pub fn vertex_gradients(&self, p: &Matrix3<f64>) -> [Vector3<f64>; 4] {
        self.grads.map(|g| p * g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::generate::box_mesh;

    #[test]
    fn rest_gives_identity_and_affine_maps_give_their_matrix() {
        let mesh = box_mesh([2, 2, 2], Vector3::new(1.0, 2.0, 3.0), 0.3, 3).unwrap();
        let ops = ElementOperator::for_mesh(&mesh);
        let affine = Matrix3::new(1.1, 0.2, -0.3, 0.0, 0.9, 0.4, 0.5, -0.1, 1.3);
        let shift = Vector3::new(3.0, -1.0, 2.0);
        for (e, op) in ops.iter().enumerate() {
            let rest = mesh.tets[e].map(|v| mesh.vertices[v as usize].coords);
            assert!((op.deformation_gradient(&rest) - Matrix3::identity()).norm() < 1e-12);
            let moved = rest.map(|p| affine * p + shift);
            assert!((op.deformation_gradient(&moved) - affine).norm() < 1e-12);
            assert!((op.rest_volume - mesh.signed_volume(e)).abs() < 1e-15);
        }
    }
}
