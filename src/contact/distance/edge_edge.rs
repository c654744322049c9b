//! Edge–edge squared distance, its gradient and Hessian (12 dofs ordered `ea0, ea1, eb0, eb1`).

use super::distance_type::EdgeEdgeDistanceType;
use super::envelope::Envelope;
use super::primitives::{line_line_distance, point_line_distance, point_point_distance};
use crate::contact::math::{Matrix12, Vec3, Vector12};

/// `dtype` made safe for the geometry: `EaEb` on exactly parallel edges, or a type using the
/// line of a zero-length edge, is replaced by the automatic type.
fn feasible(x: [&Vec3; 4], dtype: EdgeEdgeDistanceType) -> EdgeEdgeDistanceType {
    use EdgeEdgeDistanceType as T;
    let a_is_point = x[0] == x[1];
    let b_is_point = x[2] == x[3];
    let ok = match dtype {
        T::EaEb => (x[1] - x[0]).cross(&(x[3] - x[2])).norm_squared() > 0.0,
        T::EaEb0 | T::EaEb1 => !a_is_point,
        T::Ea0Eb | T::Ea1Eb => !b_is_point,
        _ => true,
    };
    if ok {
        dtype
    } else {
        super::edge_edge_distance_type(x[0], x[1], x[2], x[3])
    }
}

/// Squared distance (cm²) between edges `(ea0, ea1)` and `(eb0, eb1)` for the given type:
/// point–point for two end points, point–line for an end point and an interior, line–line
/// `((ea0 − eb0)·n)²/‖n‖²` (`n = (ea1 − ea0) × (eb1 − eb0)`) for two interiors. An infeasible
/// type falls back to the automatic type.
pub fn edge_edge_distance_typed(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
    dtype: EdgeEdgeDistanceType,
) -> f64 {
    use EdgeEdgeDistanceType as T;
    match feasible([ea0, ea1, eb0, eb1], dtype) {
        T::Ea0Eb0 => point_point_distance(ea0, eb0),
        T::Ea0Eb1 => point_point_distance(ea0, eb1),
        T::Ea1Eb0 => point_point_distance(ea1, eb0),
        T::Ea1Eb1 => point_point_distance(ea1, eb1),
        T::EaEb0 => point_line_distance(eb0, ea0, ea1),
        T::EaEb1 => point_line_distance(eb1, ea0, ea1),
        T::Ea0Eb => point_line_distance(ea0, eb0, eb1),
        T::Ea1Eb => point_line_distance(ea1, eb0, eb1),
        T::EaEb => line_line_distance(ea0, ea1, eb0, eb1),
    }
}

/// Squared distance (cm²) between two edges, with the automatic type.
pub fn edge_edge_distance(ea0: &Vec3, ea1: &Vec3, eb0: &Vec3, eb1: &Vec3) -> f64 {
    let dtype = super::edge_edge_distance_type(ea0, ea1, eb0, eb1);
    edge_edge_distance_typed(ea0, ea1, eb0, eb1, dtype)
}

fn envelope(x: &[Vec3; 4], dtype: EdgeEdgeDistanceType) -> Envelope {
    use EdgeEdgeDistanceType as T;
    match feasible([&x[0], &x[1], &x[2], &x[3]], dtype) {
        T::Ea0Eb0 => Envelope::point_point(0, 2, x),
        T::Ea0Eb1 => Envelope::point_point(0, 3, x),
        T::Ea1Eb0 => Envelope::point_point(1, 2, x),
        T::Ea1Eb1 => Envelope::point_point(1, 3, x),
        T::EaEb0 => Envelope::point_line(2, 0, 1, x),
        T::EaEb1 => Envelope::point_line(3, 0, 1, x),
        T::Ea0Eb => Envelope::point_line(0, 2, 3, x),
        T::Ea1Eb => Envelope::point_line(1, 2, 3, x),
        T::EaEb => Envelope::line_line([0, 1], [2, 3], x),
    }
}

/// Gradient of the squared edge–edge distance for the given type (cm), ordered
/// `ea0, ea1, eb0, eb1`: `∂d/∂xᵢ = 2·aᵢ·v`, `v` the vector between the closest points
/// (see [`super::envelope`]).
pub fn edge_edge_distance_gradient(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
    dtype: EdgeEdgeDistanceType,
) -> Vector12 {
    envelope(&[*ea0, *ea1, *eb0, *eb1], dtype).gradient()
}

/// Hessian of the squared edge–edge distance for the given type (dimensionless), 12×12,
/// closed form of [`super::envelope`]; for `EaEb` the `p`-independent part is `2·aaᵀ ⊗ n̂n̂ᵀ`.
pub fn edge_edge_distance_hessian(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
    dtype: EdgeEdgeDistanceType,
) -> Matrix12 {
    envelope(&[*ea0, *ea1, *eb0, *eb1], dtype).hessian()
}

/// Value, gradient and Hessian together (one envelope evaluation).
pub fn edge_edge_distance_derivatives(
    x: &[Vec3; 4],
    dtype: EdgeEdgeDistanceType,
) -> (f64, Vector12, Matrix12) {
    let d = edge_edge_distance_typed(&x[0], &x[1], &x[2], &x[3], dtype);
    let env = envelope(x, dtype);
    (d, env.gradient(), env.hessian())
}

/// Value and gradient together.
pub fn edge_edge_distance_and_gradient(
    x: &[Vec3; 4],
    dtype: EdgeEdgeDistanceType,
) -> (f64, Vector12) {
    let d = edge_edge_distance_typed(&x[0], &x[1], &x[2], &x[3], dtype);
    (d, envelope(x, dtype).gradient())
}
