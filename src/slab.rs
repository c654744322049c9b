//! A generated face-like slab scene: the controlled stand-in for a face model in solver tests
//! and benchmarks (exact element counts, known attachments, smooth "muscle" actuations).

use nalgebra::{Point3, Vector3};

use crate::geometry::generate::{box_mesh, slab_cells_for};
use crate::geometry::{MeshError, TetMesh};
use crate::sim::{Attachments, Bone, SymTensor};

/// Slab dimensions in centimetres: about a face's width and height, 2 cm of tissue.
pub const SLAB_SIZE: Vector3<f64> = Vector3::new(8.0, 8.0, 2.0);

/// A slab of about `elements` tetrahedra. Its back (z = 0) is bone: the upper 60% skull,
/// the lower 40% jaw, which pivots about a point behind the slab.
pub struct SlabScene {
    pub mesh: TetMesh,
    pub attachments: Attachments,
    pub jaw_pivot: Point3<f64>,
}

impl SlabScene {
    pub fn new(elements: usize, jitter: f64, seed: u64) -> Result<Self, MeshError> {
        Self::with_cells(slab_cells_for(elements), jitter, seed)
    }

    pub fn with_cells(cells: [usize; 3], jitter: f64, seed: u64) -> Result<Self, MeshError> {
        let mesh = box_mesh(cells, SLAB_SIZE, jitter, seed)?;
        let mut attachments = Attachments::default();
        for (v, p) in mesh.vertices.iter().enumerate() {
            if p.z.abs() < 1e-9 {
                attachments.vertices.push(v as u32);
                attachments.bones.push(if p.y > 0.4 * SLAB_SIZE.y {
                    Bone::Skull
                } else {
                    Bone::Jaw
                });
            }
        }
        Ok(Self {
            mesh,
            attachments,
            jaw_pivot: Point3::new(0.5 * SLAB_SIZE.x, 0.5 * SLAB_SIZE.y, -4.0),
        })
    }

    /// A smooth "orbicularis" field: contraction by up to `strength` along circles around a
    /// mouth-like centre, fading with distance (`A = I + (λ − 1)·d·dᵀ`, `λ = 1 − strength·bump`).
    pub fn actuations(&self, strength: f64) -> Vec<SymTensor> {
        self.mesh
            .tets
            .iter()
            .map(|tet| {
                let c = tet
                    .iter()
                    .map(|&v| self.mesh.vertices[v as usize].coords)
                    .sum::<Vector3<f64>>()
                    / 4.0;
                let (u, v) = (c.x / SLAB_SIZE.x - 0.5, c.y / SLAB_SIZE.y - 0.4);
                let d = Vector3::new(-v, u, 0.2 * c.z / SLAB_SIZE.z).normalize();
                let bump = (-(u * u + v * v) / 0.08).exp();
                let lambda = 1.0 - strength * bump;
                let m = nalgebra::Matrix3::identity() + d * d.transpose() * (lambda - 1.0);
                SymTensor::from_matrix(&m)
            })
            .collect()
    }
}
