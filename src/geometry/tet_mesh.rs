//! Tetrahedral meshes: rest positions, elements and the checks every simulation mesh must pass.

use nalgebra::{Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// Errors found when a tetrahedral mesh is not fit for simulation.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MeshError {
    #[error("mesh has no vertices or no elements")]
    Empty,
    #[error("vertex {vertex} has a non-finite coordinate")]
    NonFiniteVertex { vertex: usize },
    #[error(
        "element {element} references vertex {vertex}, but the mesh has {vertex_count} vertices"
    )]
    IndexOutOfRange {
        element: usize,
        vertex: usize,
        vertex_count: usize,
    },
    #[error("element {element} repeats a vertex")]
    RepeatedVertex { element: usize },
    #[error("element {element} is inverted or flat at rest (signed volume {volume:e})")]
    InvertedOrFlat { element: usize, volume: f64 },
}

/// A tetrahedral mesh in its rest configuration.
///
/// Elements are positively oriented: `(x1 - x0) · ((x2 - x0) × (x3 - x0)) > 0`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TetMesh {
    pub vertices: Vec<Point3<f64>>,
    pub tets: Vec<[u32; 4]>,
}

impl TetMesh {
    /// Builds a mesh and checks it: indices in range, finite coordinates, no inverted or flat
    /// element (relative to the mesh's own scale).
    pub fn new(vertices: Vec<Point3<f64>>, tets: Vec<[u32; 4]>) -> Result<Self, MeshError> {
        let mesh = Self { vertices, tets };
        mesh.validate()?;
        Ok(mesh)
    }

    pub fn vertex_count(&self) -> usize {
        self.vertices.len()
    }

    pub fn element_count(&self) -> usize {
        self.tets.len()
    }

    fn validate(&self) -> Result<(), MeshError> {
        if self.vertices.is_empty() || self.tets.is_empty() {
            return Err(MeshError::Empty);
        }
        if let Some(vertex) = self
            .vertices
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(MeshError::NonFiniteVertex { vertex });
        }
        let n = self.vertices.len();
        // A flat element is one whose volume is tiny next to the cube of its longest edge.
        const MIN_SHAPE_RATIO: f64 = 1e-12;
        for (element, tet) in self.tets.iter().enumerate() {
            for &v in tet {
                if v as usize >= n {
                    return Err(MeshError::IndexOutOfRange {
                        element,
                        vertex: v as usize,
                        vertex_count: n,
                    });
                }
            }
            for i in 0..4 {
                for j in i + 1..4 {
                    if tet[i] == tet[j] {
                        return Err(MeshError::RepeatedVertex { element });
                    }
                }
            }
            let volume = self.signed_volume(element);
            let longest = self.longest_edge(element);
            if !(volume > MIN_SHAPE_RATIO * longest.powi(3)) {
                return Err(MeshError::InvertedOrFlat { element, volume });
            }
        }
        Ok(())
    }

    /// The element's edge matrix `[x1 - x0, x2 - x0, x3 - x0]` (columns).
    pub fn edge_matrix(&self, element: usize) -> Matrix3<f64> {
        let [a, b, c, d] = self.tets[element].map(|v| self.vertices[v as usize]);
        Matrix3::from_columns(&[b - a, c - a, d - a])
    }

    /// Signed volume: det(edge matrix) / 6.
    pub fn signed_volume(&self, element: usize) -> f64 {
        self.edge_matrix(element).determinant() / 6.0
    }

    pub fn volumes(&self) -> Vec<f64> {
        (0..self.tets.len())
            .map(|e| self.signed_volume(e))
            .collect()
    }

    fn longest_edge(&self, element: usize) -> f64 {
        let p = self.tets[element].map(|v| self.vertices[v as usize]);
        let mut longest = 0.0f64;
        for i in 0..4 {
            for j in i + 1..4 {
                longest = longest.max((p[i] - p[j]).norm());
            }
        }
        longest
    }

    /// Axis-aligned bounding box (min, max).
    pub fn bounds(&self) -> (Point3<f64>, Point3<f64>) {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        for p in &self.vertices {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        (Point3::from(lo), Point3::from(hi))
    }

    /// Length of the bounding-box diagonal: the mesh's "diameter" used to scale tolerances.
    pub fn diameter(&self) -> f64 {
        let (lo, hi) = self.bounds();
        (hi - lo).norm()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_tet() -> (Vec<Point3<f64>>, Vec<[u32; 4]>) {
        let v = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
        ];
        (v, vec![[0, 1, 2, 3]])
    }

    #[test]
    fn accepts_a_positive_tet_and_reports_its_volume() {
        let (v, t) = unit_tet();
        let mesh = TetMesh::new(v, t).unwrap();
        assert!((mesh.volumes()[0] - 1.0 / 6.0).abs() < 1e-15);
    }

    #[test]
    fn rejects_bad_meshes_with_the_reason() {
        let (v, _) = unit_tet();
        assert_eq!(
            TetMesh::new(v.clone(), vec![[0, 2, 1, 3]]),
            Err(MeshError::InvertedOrFlat {
                element: 0,
                volume: -1.0 / 6.0
            })
        );
        assert!(matches!(
            TetMesh::new(v.clone(), vec![[0, 1, 2, 7]]),
            Err(MeshError::IndexOutOfRange {
                element: 0,
                vertex: 7,
                ..
            })
        ));
        assert_eq!(
            TetMesh::new(v.clone(), vec![[0, 1, 1, 3]]),
            Err(MeshError::RepeatedVertex { element: 0 })
        );
        let mut nan = v.clone();
        nan[2].y = f64::NAN;
        assert_eq!(
            TetMesh::new(nan, vec![[0, 1, 2, 3]]),
            Err(MeshError::NonFiniteVertex { vertex: 2 })
        );
        let mut flat = v;
        flat[3] = Point3::new(0.3, 0.3, 0.0);
        assert!(matches!(
            TetMesh::new(flat, vec![[0, 1, 2, 3]]),
            Err(MeshError::InvertedOrFlat { .. })
        ));
    }
}
