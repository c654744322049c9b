//! The active set: candidate pairs closer than d̂, with their closest-feature type and (edge
//! pairs) their mollifier threshold. The original IPC formulation: every active
//! point–triangle pair and every active edge–edge pair contributes one barrier term, whatever
//! sub-feature realizes its distance (ipc-toolkit's `NormalCollisions` with the `IPC` set type
//! and no area weighting gives the same sum by merging duplicate sub-feature pairs).

use rayon::prelude::*;

use super::ContactError;
use super::candidates::Candidates;
use super::distance::{
    EdgeEdgeDistanceType, PointTriangleDistanceType, edge_edge_distance_type,
    edge_edge_distance_typed, point_triangle_distance_type, point_triangle_distance_typed,
};
use super::math::{Vec3, stencil};
use super::mesh::ContactMesh;

/// Which primitives a collision pairs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum CollisionKind {
    /// Stencil `[p, t0, t1, t2]`.
    PointTriangle,
    /// Stencil `[ea0, ea1, eb0, eb1]`.
    EdgeEdge,
}

impl CollisionKind {
    /// The squared distance (cm²) of a stencil, its closest-feature type classified anew.
    pub fn distance_squared(self, p: &[Vec3; 4]) -> f64 {
        match self {
            CollisionKind::PointTriangle => {
                let t = point_triangle_distance_type(&p[0], &p[1], &p[2], &p[3]);
                point_triangle_distance_typed(&p[0], &p[1], &p[2], &p[3], t)
            }
            CollisionKind::EdgeEdge => {
                let t = edge_edge_distance_type(&p[0], &p[1], &p[2], &p[3]);
                edge_edge_distance_typed(&p[0], &p[1], &p[2], &p[3], t)
            }
        }
    }
}

/// The closest-feature type of a collision.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CollisionType {
    PointTriangle(PointTriangleDistanceType),
    EdgeEdge(EdgeEdgeDistanceType),
}

/// One active pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Collision {
    pub kind: CollisionKind,
    /// Simulation vertex indices of the stencil (see [`CollisionKind`]).
    pub vertices: [u32; 4],
    /// Closest-feature type at the positions the set was built from.
    pub dtype: CollisionType,
    /// Squared distance at those positions (cm²), `0 < d² < activation²`.
    pub distance_squared: f64,
    /// The squared distance (cm²) below which the barrier acts on this pair: d̂², or less for
    /// a pair already close at rest ([`ContactMesh::with_close_pairs`]).
    pub activation2: f64,
    /// The barrier's weight, `(d̂²/activation²)²`: 1, but for a pair close at rest, whose
    /// barrier is then the plain one in units of its own activation distance
    /// (`b(d², a²)·(d̂²/a²)² = b(s²d̂², d̂²)` with `s = d/a`, `b` quartic in the scale). Unweighted,
    /// a pair activated at 0.06 d̂ would push back 10⁻⁵ as hard at the same relative gap,
    /// and be squeezed to 10⁻⁶ cm, where every step that moves it is cut to a sliver.
    pub weight: f64,
    /// Edge–edge mollifier threshold `ε_x` (cm⁴); 0 for point–triangle pairs.
    pub eps_x: f64,
}

impl Collision {
    /// The stencil's positions.
    pub fn positions(&self, x: &[f64]) -> [Vec3; 4] {
        stencil(x, self.vertices)
    }

    /// The squared distance (cm²) at positions `x`, the closest-feature type classified anew.
    pub fn distance_squared_at(&self, x: &[f64]) -> f64 {
        self.kind.distance_squared(&self.positions(x))
    }
}

/// The active set, in a fixed order: point–triangle pairs by (vertex, face), then edge–edge
/// pairs by (edge a, edge b).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Collisions {
    pub collisions: Vec<Collision>,
    /// The activation distance d̂ (cm) the set was built with.
    pub dhat: f64,
}

impl Collisions {
    /// Broad phase (boxes inflated by d̂) and narrow phase at positions `x`.
    pub fn build(mesh: &ContactMesh, x: &[f64], dhat: f64) -> Result<Self, ContactError> {
        check_dhat(dhat)?;
        let candidates = Candidates::build(mesh, x, dhat)?;
        Self::from_candidates(mesh, &candidates, x, dhat)
    }

    /// The candidates with `0 < d² < d̂²` at `x` (below their own activation distance for
    /// the mesh's close pairs). A pair at distance 0 (touching or intersecting surfaces) is
    /// an error: the barrier is infinite there.
    pub fn from_candidates(
        mesh: &ContactMesh,
        candidates: &Candidates,
        x: &[f64],
        dhat: f64,
    ) -> Result<Self, ContactError> {
        check_dhat(dhat)?;
        mesh.check_positions(x)?;
        // (activation², weight) of a pair with its own activation distance, or of a plain one.
        let scale = |own: Option<f64>| {
            own.map_or((dhat * dhat, 1.0), |a| {
                (a * a, (dhat * dhat / (a * a)).powi(2))
            })
        };
        let faces = mesh.faces();
        let edges = mesh.edges();
        let pt = candidates.point_triangle.par_iter().map(|c| {
            let f = faces[c.face as usize];
            let vertices = [c.vertex, f[0], f[1], f[2]];
            let p = stencil(x, vertices);
            let t = point_triangle_distance_type(&p[0], &p[1], &p[2], &p[3]);
            let d = point_triangle_distance_typed(&p[0], &p[1], &p[2], &p[3], t);
            let (activation2, weight) = scale(mesh.point_triangle_activation(c.vertex, c.face));
            (d < activation2).then_some(Collision {
                kind: CollisionKind::PointTriangle,
                vertices,
                dtype: CollisionType::PointTriangle(t),
                distance_squared: d,
                activation2,
                weight,
                eps_x: 0.0,
            })
        });
        let ee = candidates.edge_edge.par_iter().map(|c| {
            let [a0, a1] = edges[c.edge_a as usize];
            let [b0, b1] = edges[c.edge_b as usize];
            let vertices = [a0, a1, b0, b1];
            let p = stencil(x, vertices);
            let t = edge_edge_distance_type(&p[0], &p[1], &p[2], &p[3]);
            let d = edge_edge_distance_typed(&p[0], &p[1], &p[2], &p[3], t);
            let (activation2, weight) = scale(mesh.edge_edge_activation(c.edge_a, c.edge_b));
            (d < activation2).then_some(Collision {
                kind: CollisionKind::EdgeEdge,
                vertices,
                dtype: CollisionType::EdgeEdge(t),
                distance_squared: d,
                activation2,
                weight,
                eps_x: mesh.mollifier_threshold(c.edge_a as usize, c.edge_b as usize),
            })
        });
        let mut collisions: Vec<Collision> = pt.flatten().collect();
        collisions.extend(ee.flatten().collect::<Vec<_>>());
        if let Some(c) = collisions.iter().find(|c| !(c.distance_squared > 0.0)) {
            return Err(ContactError::Touching {
                kind: c.kind,
                vertices: c.vertices,
                distance_squared: c.distance_squared,
            });
        }
        Ok(Self { collisions, dhat })
    }

    pub fn len(&self) -> usize {
        self.collisions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.collisions.is_empty()
    }

    /// The smallest squared distance in the set (cm²), `d̂²` when empty (for the κ update).
    pub fn min_distance_squared(&self) -> f64 {
        self.collisions
            .iter()
            .map(|c| c.distance_squared)
            .fold(self.dhat * self.dhat, f64::min)
    }
}

fn check_dhat(dhat: f64) -> Result<(), ContactError> {
    if !(dhat > 0.0) || !dhat.is_finite() {
        return Err(ContactError::InvalidParameter(format!(
            "d̂ must be finite and > 0, got {dhat}"
        )));
    }
    Ok(())
}
