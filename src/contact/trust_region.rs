//! Certified per-vertex motion bounds: the trust region of Offset Geometric Contact (Chen et
//! al. 2025; ipc-toolkit's `ogc::TrustRegion`, which the tests compare against).
//!
//! At the centres `c` (positions where the region was last updated) each vertex `i` gets a
//! radius `rᵢ = (γ/2)·min(R, min_{pairs ∋ i} d_pair)`, with `d_pair` the distance of every
//! point–triangle and edge–edge pair it belongs to (incident pairs excluded), `R` the
//! inflation radius the pairs were gathered within (2·d̂) and `γ` = [`RELAXED_RADIUS_SCALING`]
//! < 1. A step is filtered so that every vertex stays in its ball, `‖xᵢ + Δxᵢ − cᵢ‖ ≤ rᵢ`.
//!
//! **Why no pair can cross (nor even touch) while every vertex stays in its ball.** A point of
//! a primitive is a convex combination of its vertices, so it moves by at most the largest
//! move of those vertices, `< (γ/2)·d_pair` for a pair found within `R`, and `< (γ/2)·R` for
//! any other. The distance between two primitives is 1-Lipschitz in the motion of each, so a
//! pair at distance `d` stays at distance `> d − 2·(γ/2)·d = (1 − γ)·d > 0`, and a pair
//! beyond `R` stays beyond `(1 − γ)·R > 0`. Inside the balls no continuous collision check is
//! needed: the step is collision free by construction.

use super::candidates::Candidates;
use super::math::stencil;
use super::mesh::ContactMesh;
use super::{CollisionKind, ContactError};

/// `γ` above (ipc-toolkit's `relaxed_radius_scaling`, its `2·γ_p`): each side of a pair moves
/// less than `γ/2` of their distance.
pub const RELAXED_RADIUS_SCALING: f64 = 0.9;
/// A filtered step that clamps more than this share of the vertices asks for a new region.
pub const UPDATE_THRESHOLD: f64 = 0.01;

/// Per-vertex balls in which a vertex may move without any pair coming into contact.
#[derive(Clone, Debug)]
pub struct TrustRegion {
    /// Positions the balls are centred on (interleaved, cm).
    pub centers: Vec<f64>,
    /// Per-vertex radii (cm).
    pub radii: Vec<f64>,
    /// The distance within which pairs bound a vertex (cm; 2·d̂).
    pub inflation: f64,
    /// Set when a filtered step clamped more than [`UPDATE_THRESHOLD`] of the vertices: the
    /// region should be rebuilt at the new positions.
    pub should_update: bool,
}

impl TrustRegion {
    /// The region for barrier distance `dhat` (cm); [`TrustRegion::update`] centres it.
    pub fn new(dhat: f64) -> Result<Self, ContactError> {
        if !(dhat > 0.0 && dhat.is_finite()) {
            return Err(ContactError::InvalidParameter(format!(
                "d̂ must be finite and positive, got {dhat}"
            )));
        }
        Ok(TrustRegion {
            centers: Vec::new(),
            radii: Vec::new(),
            inflation: 2.0 * dhat,
            should_update: true,
        })
    }

    /// Centres the balls at `x` and sizes them from the pairs within the inflation radius.
    pub fn update(&mut self, mesh: &ContactMesh, x: &[f64]) -> Result<(), ContactError> {
        let candidates = Candidates::build(mesh, x, self.inflation)?;
        let mut nearest = vec![self.inflation; mesh.vertex_count()];
        let mut bound = |ids: [u32; 4], kind: CollisionKind| {
            let d = kind.distance_squared(&stencil(x, ids)).sqrt();
            for v in ids {
                let slot = &mut nearest[v as usize];
                *slot = slot.min(d);
            }
        };
        for c in &candidates.point_triangle {
            let f = mesh.faces()[c.face as usize];
            bound([c.vertex, f[0], f[1], f[2]], CollisionKind::PointTriangle);
        }
        for c in &candidates.edge_edge {
            let [a0, a1] = mesh.edges()[c.edge_a as usize];
            let [b0, b1] = mesh.edges()[c.edge_b as usize];
            bound([a0, a1, b0, b1], CollisionKind::EdgeEdge);
        }
        self.radii = nearest
            .into_iter()
            .map(|d| 0.5 * RELAXED_RADIUS_SCALING * d)
            .collect();
        self.centers = x.to_vec();
        self.should_update = false;
        Ok(())
    }

    /// Shortens each vertex's step `dx` from `x` so that it ends in its ball (the largest
    /// `β ∈ [0, 1]` with `‖xᵢ + β·Δxᵢ − cᵢ‖ ≤ rᵢ`); returns how many vertices were clamped.
    pub fn filter_step(&mut self, x: &[f64], dx: &mut [f64]) -> Result<usize, ContactError> {
        let n = self.radii.len();
        if let Some(&got) = [x.len(), dx.len()].iter().find(|&&len| len != 3 * n) {
            return Err(ContactError::PositionsLength {
                expected: 3 * n,
                got,
            });
        }
        let mut clamped = 0;
        for i in 0..n {
            let at = |v: &[f64]| nalgebra::Vector3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
            let beta = truncation(at(x), at(dx), at(&self.centers), self.radii[i]);
            if beta < 1.0 {
                dx[3 * i..3 * i + 3].iter_mut().for_each(|d| *d *= beta);
                clamped += 1;
            }
        }
        if clamped as f64 > UPDATE_THRESHOLD * n as f64 {
            self.should_update = true;
        }
        Ok(clamped)
    }
}

/// The largest `β ∈ [0, 1]` with `‖x + β·dx − c‖ ≤ r`, for `x` inside the ball: the positive
/// root of `‖dx‖²·β² + 2·dx·(x − c)·β + ‖x − c‖² − r² = 0`, in the form without cancellation.
/// A ball of radius 0 (a vertex touching another primitive) allows no motion.
fn truncation(
    x: nalgebra::Vector3<f64>,
    dx: nalgebra::Vector3<f64>,
    c: nalgebra::Vector3<f64>,
    r: f64,
) -> f64 {
    if (x + dx - c).norm() <= r {
        return 1.0;
    }
    let a = dx.norm_squared();
    let b = 2.0 * dx.dot(&(x - c));
    let k = ((x - c).norm_squared() - r * r).min(0.0);
    let root = (b * b - 4.0 * a * k).max(0.0).sqrt();
    let beta = if b >= 0.0 {
        -2.0 * k / (b + root)
    } else {
        (root - b) / (2.0 * a)
    };
    if beta.is_finite() {
        beta.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A triangle, a second one whose corner (vertex 3) is 0.3 cm above the first and whose
    /// edges from it pass 0.36 cm from the first's edges, and a far triangle; d̂ = 0.2 (pairs
    /// within 0.4 count).
    fn point_over_triangle() -> (ContactMesh, Vec<f64>) {
        let x = vec![
            0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, // the first triangle
            0.2, 0.2, 0.3, 0.2, 0.2, 3.3, 3.2, 0.2, 3.3, // the corner over it
            0.0, 0.0, 10.0, 1.0, 0.0, 10.0, 0.0, 1.0, 10.0, // far away
        ];
        let mesh = ContactMesh::new(&x, vec![[0, 1, 2], [3, 4, 5], [6, 7, 8]]).unwrap();
        (mesh, x)
    }

    #[test]
    fn radii_are_half_the_relaxed_distance_and_steps_end_on_the_ball() {
        let (mesh, x) = point_over_triangle();
        let mut region = TrustRegion::new(0.2).unwrap();
        region.update(&mesh, &x).unwrap();
        let r = 0.5 * RELAXED_RADIUS_SCALING * 0.3;
        for v in 0..4 {
            assert!((region.radii[v] - r).abs() < 1e-12, "{:?}", region.radii);
        }
        // The corner's edges bound their far ends by the edge–edge distance √0.13.
        let edge = 0.5 * RELAXED_RADIUS_SCALING * 0.13f64.sqrt();
        for v in 4..6 {
            assert!((region.radii[v] - edge).abs() < 1e-12, "{:?}", region.radii);
        }
        // The far triangle's vertices see nothing within 0.4 but each other (incident): the
        // inflation radius bounds them.
        for v in 6..9 {
            assert!((region.radii[v] - 0.5 * RELAXED_RADIUS_SCALING * 0.4).abs() < 1e-12);
        }
        let mut dx = vec![0.0; x.len()];
        dx[11] = -1.0; // the point dives through the triangle
        assert_eq!(region.filter_step(&x, &mut dx).unwrap(), 1);
        assert!((dx[11] + r).abs() < 1e-12, "ends on its ball: {}", dx[11]);
        assert!(dx.iter().enumerate().all(|(k, &d)| k == 11 || d == 0.0));
        // 1 of 9 vertices clamped is past the update threshold.
        assert!(region.should_update);
    }

    #[test]
    fn a_touching_vertex_may_not_move_and_bad_input_is_refused() {
        let (mesh, mut x) = point_over_triangle();
        x[11] = 0.0; // the point on the triangle
        let mut region = TrustRegion::new(0.2).unwrap();
        region.update(&mesh, &x).unwrap();
        assert_eq!(region.radii[3], 0.0);
        let mut dx = vec![0.01; x.len()];
        region.filter_step(&x, &mut dx).unwrap();
        assert!(dx.iter().all(|d| d.is_finite()));
        assert_eq!(&dx[9..12], &[0.0, 0.0, 0.0]);
        assert!(region.filter_step(&x, &mut dx[..3]).is_err());
        assert!(TrustRegion::new(0.0).is_err());
        assert!(TrustRegion::new(f64::NAN).is_err());
    }
}
