//! Barycentric embedding of points (the artist's full-resolution surface) in a tetrahedral mesh
//! (the coarser simulation mesh), so the real skin follows the physics.
//!
//! Each point gets the tetrahedron that contains it, or the nearest one if it lies outside the
//! mesh, and its barycentric coordinates there: `p = Σᵢ wᵢ·xᵢ` with `Σᵢ wᵢ = 1`. The coordinates
//! are not clamped, so every point is reproduced exactly at rest and points slightly outside
//! the mesh follow it by extrapolation.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::bvh::{Box3, BoxTree};
use super::distance::closest_point_on_triangle;
use super::tet_mesh::TetMesh;

/// Where each embedded point lives.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Embedding {
    pub elements: Vec<u32>,
    pub weights: Vec<[f64; 4]>,
    /// Distance of each point from its element (0 inside), cm.
    pub outside_distance: Vec<f64>,
}

impl Embedding {
    /// Embeds `points` in `mesh`.
    pub fn new(mesh: &TetMesh, points: &[Point3<f64>]) -> Self {
        Self::among(mesh, points, &|_, _| true)
    }

    /// Embeds each point `i` in the containing or nearest element `e` with `accept(i, e)`
    /// (e.g. only the tissue on the point's side of the mouth slit); a point no element
    /// accepts gets element 0 at infinite distance.
    pub fn among(
        mesh: &TetMesh,
        points: &[Point3<f64>],
        accept: &(dyn Fn(usize, u32) -> bool + Sync),
    ) -> Self {
        let tree = element_tree(mesh);
        let start_radius = 0.1 * mesh.diameter() / (mesh.element_count() as f64).cbrt().max(1.0);
        let located: Vec<(u32, [f64; 4], f64)> = points
            .par_iter()
            .enumerate()
            .map(|(i, p)| locate(mesh, &tree, p, start_radius, &|e| accept(i, e)))
            .collect();
        Self {
            elements: located.iter().map(|l| l.0).collect(),
            weights: located.iter().map(|l| l.1).collect(),
            outside_distance: located.iter().map(|l| l.2).collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.elements.len()
    }

    pub fn is_empty(&self) -> bool {
        self.elements.is_empty()
    }

    /// The embedded points for mesh positions `x` (interleaved `[x0, y0, z0, …]`).
    pub fn apply(&self, tets: &[[u32; 4]], x: &[f64]) -> Vec<Point3<f64>> {
        self.elements
            .iter()
            .zip(&self.weights)
            .map(|(&e, w)| interpolate(&tets[e as usize], w, x))
            .collect()
    }
}

/// A box tree over `mesh`'s elements at rest (element `e` is leaf `e`).
pub fn element_tree(mesh: &TetMesh) -> BoxTree {
    let boxes: Vec<Box3> = mesh
        .tets
        .iter()
        .map(|t| Box3::around(&t.map(|v| mesh.vertices[v as usize]), 0.0))
        .collect();
    BoxTree::new(&boxes)
}

/// `Σᵢ wᵢ·xᵢ` over a tetrahedron's vertices, for interleaved mesh positions `x`.
pub fn interpolate(tet: &[u32; 4], weights: &[f64; 4], x: &[f64]) -> Point3<f64> {
    let mut p = Vector3::zeros();
    for (&v, w) in tet.iter().zip(weights) {
        let i = 3 * v as usize;
        p += Vector3::new(x[i], x[i + 1], x[i + 2]) * *w;
    }
    Point3::from(p)
}

/// Barycentric coordinates of `p` in tetrahedron `t` (unclamped).
pub fn barycentric(mesh: &TetMesh, t: usize, p: &Point3<f64>) -> [f64; 4] {
    let x0 = mesh.vertices[mesh.tets[t][0] as usize];
    let l = mesh
        .edge_matrix(t)
        .try_inverse()
        .map(|inv| inv * (p - x0))
        .unwrap_or_else(Vector3::zeros);
    [1.0 - l.x - l.y - l.z, l.x, l.y, l.z]
}

/// Distance from `p` to tetrahedron `t` (0 inside).
pub fn distance_to_tet(mesh: &TetMesh, t: usize, p: &Point3<f64>) -> f64 {
    let w = barycentric(mesh, t, p);
    if w.iter().all(|&c| c >= 0.0) {
        return 0.0;
    }
    let q = mesh.tets[t].map(|v| mesh.vertices[v as usize]);
    [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]
        .iter()
        .map(|f| (p - closest_point_on_triangle(p, &q[f[0]], &q[f[1]], &q[f[2]])).norm())
        .fold(f64::INFINITY, f64::min)
}

/// The containing (or else nearest) accepted element of `p`: searches boxes of growing
/// radius until a candidate is found, then once more out to that candidate's distance so none
/// closer is missed.
fn locate(
    mesh: &TetMesh,
    tree: &BoxTree,
    p: &Point3<f64>,
    start_radius: f64,
    accept: &dyn Fn(u32) -> bool,
) -> (u32, [f64; 4], f64) {
    let mut radius = start_radius;
    let mut candidates = Vec::new();
    let limit = mesh.diameter() * 4.0 + start_radius;
    loop {
        tree.overlapping(&Box3::around(&[*p], radius), &mut candidates);
        candidates.retain(|&e| accept(e));
        if !candidates.is_empty() || radius > limit {
            break;
        }
        radius *= 2.0;
    }
    let nearest = |candidates: &[u32]| {
        candidates
            .iter()
            .map(|&t| (distance_to_tet(mesh, t as usize, p), t))
            .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
            .unwrap_or((f64::INFINITY, 0))
    };
    if candidates.is_empty() {
        // Nothing accepted within reach of the growing boxes: every accepted element.
        candidates = (0..mesh.element_count() as u32)
            .filter(|&e| accept(e))
            .collect();
    }
    let (mut distance, mut element) = nearest(&candidates);
    if distance.is_finite() && distance > radius {
        tree.overlapping(&Box3::around(&[*p], distance), &mut candidates);
        candidates.retain(|&e| accept(e));
        (distance, element) = nearest(&candidates);
    }
    (element, barycentric(mesh, element as usize, p), distance)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::generate::box_mesh;

    #[test]
    fn points_are_reproduced_at_rest_and_follow_an_affine_motion() {
        let mesh = box_mesh([3, 3, 2], Vector3::new(3.0, 3.0, 2.0), 0.2, 4).unwrap();
        let points = vec![
            Point3::new(1.2, 0.7, 0.4),    // inside
            Point3::new(2.999, 1.5, 1.0),  // on the boundary
            Point3::new(1.5, 1.5, 2.3),    // 0.3 above the top
            Point3::new(-0.5, -0.5, -0.5), // outside a corner
        ];
        let embedding = Embedding::new(&mesh, &points);
        assert_eq!(embedding.outside_distance[0], 0.0);
        assert!((embedding.outside_distance[2] - 0.3).abs() < 1e-9);
        assert!((embedding.outside_distance[3] - 0.75f64.sqrt()).abs() < 1e-9);
        let rest: Vec<f64> = mesh.vertices.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        for (p, q) in points.iter().zip(embedding.apply(&mesh.tets, &rest)) {
            assert!((p - q).norm() < 1e-12);
        }
        // Any affine motion of the mesh moves embedded points by the same motion, exactly.
        let a = nalgebra::Matrix3::new(1.1, 0.2, 0.0, -0.1, 0.9, 0.3, 0.0, 0.1, 1.2);
        let t = Vector3::new(0.5, -1.0, 2.0);
        let moved: Vec<f64> = mesh
            .vertices
            .iter()
            .flat_map(|p| {
                let q = a * p.coords + t;
                [q.x, q.y, q.z]
            })
            .collect();
        for (p, q) in points.iter().zip(embedding.apply(&mesh.tets, &moved)) {
            assert!((a * p.coords + t - q.coords).norm() < 1e-12);
        }
    }

    #[test]
    fn the_nearest_element_is_found_however_far() {
        let mesh = box_mesh([2, 2, 2], Vector3::new(1.0, 1.0, 1.0), 0.0, 0).unwrap();
        let far = Point3::new(0.5, 0.5, 40.0);
        let e = Embedding::new(&mesh, &[far]);
        assert!((e.outside_distance[0] - 39.0).abs() < 1e-9);
    }
}
