//! Contact: the Incremental Potential Contact (IPC) barrier of Li et al. 2020 ("Incremental
//! Potential Contact: Intersection- and Inversion-free, Large-Deformation Dynamics", SIGGRAPH
//! 2020) for the lips, mouth and teeth surfaces, with additive continuous collision detection
//! (Li et al. 2021, "Codimensional Incremental Potential Contact", §5).
//!
//! Laid out like ipc-toolkit, one concept per module, data flowing in this order:
//!
//! ```text
//! ContactMesh + positions ──► broad phase (candidates::tree over d̂-inflated or swept boxes)
//!     ──► candidates (point–triangle and edge–edge pairs)
//!     ──► collisions (the active set: pairs with d < d̂, their distance type, mollifier)
//!     ──► potential (κ Σ m·b(d², d̂²): value, gradient, Hessian blocks, PSD-projected blocks)
//!     ──► ccd (a collision-free step fraction t ∈ [0, 1] for the line search)
//! ```
//!
//! `distance` holds the exact squared distances and their derivatives, `barrier` the scalar
//! barrier and the adaptive stiffness. Units: positions in centimetres, so squared distances
//! are cm², d̂ is cm, and the barrier value is κ·cm⁴ (κ carries whatever makes it an energy).
//! Positions everywhere are the solver's interleaved `[x0, y0, z0, x1, …]`.

pub mod barrier;
pub mod candidates;
pub mod ccd;
pub mod collisions;
pub mod distance;
mod math;
pub mod mesh;
pub mod planar;
pub mod potential;
pub mod refined;
pub mod surface;
#[cfg(test)]
mod test_scenes;
pub mod trust_region;
pub mod verlet;

pub use barrier::{barrier, barrier_first_derivative, barrier_second_derivative};
pub use candidates::{Candidates, EdgeEdgeCandidate, FixedPrimitives, PointTriangleCandidate};
pub use ccd::{CcdOptions, CcdOutcome, StepReport, collision_free_step, collision_free_step_over};
pub use collisions::CollisionType;
pub use collisions::{Collision, CollisionKind, Collisions};
pub use distance::{EdgeEdgeDistanceType, PointEdgeDistanceType, PointTriangleDistanceType};
pub use math::{Matrix12, Vector12};
pub use mesh::ContactMesh;
pub use planar::{PlanarReport, planar_step_over};
pub use potential::{
    BarrierPotential, HessianBlock, HessianFactors, Projection, add_hessian_product, assemble_dense,
};
pub use refined::{RefinedReport, refined_step_over};
pub use trust_region::TrustRegion;
pub use verlet::VerletList;

/// Errors at the contact module's boundary.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ContactError {
    #[error("invalid contact mesh: {0}")]
    InvalidMesh(String),
    #[error("got {got} position values, expected {expected} (3 per vertex)")]
    PositionsLength { expected: usize, got: usize },
    #[error("non-finite position or displacement at vertex {0}")]
    NonFinite(usize),
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    #[error(
        "surfaces touch or intersect: {kind:?} pair with vertices {vertices:?} has squared distance {distance_squared:e}"
    )]
    Touching {
        kind: CollisionKind,
        vertices: [u32; 4],
        distance_squared: f64,
    },
}
