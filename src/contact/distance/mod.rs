//! Exact squared distances between contact primitives (point–triangle, edge–edge and the
//! point–point / point–edge / parallel sub-cases they reduce to), the closest-feature
//! classification, and closed-form gradients and dense 12×12 Hessians for every type.
//!
//! All distances are **squared** (cm²), as in IPC: the barrier acts on `d²` against `d̂²`,
//! which keeps every distance polynomial-rational and smooth within a type.

mod distance_type;
mod edge_edge;
pub(crate) mod envelope;
pub mod mollifier;
mod point_triangle;
mod primitives;

pub use distance_type::{
    DEGENERATE_TRIANGLE, EdgeEdgeDistanceType, PARALLEL_THRESHOLD, PointEdgeDistanceType,
    PointTriangleDistanceType, edge_edge_distance_type, edge_edge_parallel_distance_type,
    is_degenerate_triangle, point_edge_distance_type, point_triangle_distance_type,
};
pub use edge_edge::{
    edge_edge_distance, edge_edge_distance_and_gradient, edge_edge_distance_derivatives,
    edge_edge_distance_gradient, edge_edge_distance_hessian, edge_edge_distance_typed,
};
pub use point_triangle::{
    point_triangle_distance, point_triangle_distance_and_gradient,
    point_triangle_distance_derivatives, point_triangle_distance_gradient,
    point_triangle_distance_hessian, point_triangle_distance_typed,
};
pub use primitives::{
    line_line_distance, point_line_distance, point_plane_distance, point_point_distance,
};

use crate::contact::math::Vec3;

/// Squared distance (cm²) from `p` to the segment `(e0, e1)` with the automatic type: to an
/// end point, or to the line when `p` projects inside.
pub fn point_edge_distance(p: &Vec3, e0: &Vec3, e1: &Vec3) -> f64 {
    match point_edge_distance_type(p, e0, e1) {
        PointEdgeDistanceType::Vertex0 => point_point_distance(p, e0),
        PointEdgeDistanceType::Vertex1 => point_point_distance(p, e1),
        PointEdgeDistanceType::Edge => point_line_distance(p, e0, e1),
    }
}

#[cfg(test)]
mod tests;
