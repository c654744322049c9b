//! Point–triangle squared distance, its gradient and Hessian (12 dofs ordered `p, t0, t1, t2`).

use super::distance_type::{PointTriangleDistanceType, is_degenerate_triangle};
use super::envelope::Envelope;
use super::primitives::{point_line_distance, point_plane_distance, point_point_distance};
use crate::contact::math::{Matrix12, Vec3, Vector12};

/// `dtype` made safe for the geometry: `Face` on a degenerate triangle, or an edge type on a
/// zero-length edge, is replaced by the automatic type (finite in every case).
fn feasible(
    p: &Vec3,
    t: [&Vec3; 3],
    dtype: PointTriangleDistanceType,
) -> PointTriangleDistanceType {
    use PointTriangleDistanceType as T;
    let edge_is_point = |i: usize, j: usize| t[i] == t[j];
    let ok = match dtype {
        T::Face => !is_degenerate_triangle(t[0], t[1], t[2]),
        T::Edge0 => !edge_is_point(0, 1),
        T::Edge1 => !edge_is_point(1, 2),
        T::Edge2 => !edge_is_point(2, 0),
        _ => true,
    };
    if ok {
        dtype
    } else {
        super::point_triangle_distance_type(p, t[0], t[1], t[2])
    }
}

/// Squared distance (cm²) from `p` to the triangle `(t0, t1, t2)` computed for the given
/// closest-feature type: `‖p − tᵢ‖²` for a vertex, the point–line distance for an edge, the
/// point–plane distance `((p − t0)·n)²/‖n‖²` for the face. An infeasible type (the face of a
/// degenerate triangle, a zero-length edge) falls back to the automatic type.
pub fn point_triangle_distance_typed(
    p: &Vec3,
    t0: &Vec3,
    t1: &Vec3,
    t2: &Vec3,
    dtype: PointTriangleDistanceType,
) -> f64 {
    use PointTriangleDistanceType as T;
    match feasible(p, [t0, t1, t2], dtype) {
        T::Vertex0 => point_point_distance(p, t0),
        T::Vertex1 => point_point_distance(p, t1),
        T::Vertex2 => point_point_distance(p, t2),
        T::Edge0 => point_line_distance(p, t0, t1),
        T::Edge1 => point_line_distance(p, t1, t2),
        T::Edge2 => point_line_distance(p, t2, t0),
        T::Face => point_plane_distance(p, t0, t1, t2),
    }
}

/// Squared distance (cm²) from `p` to the triangle `(t0, t1, t2)`, with the automatic type.
pub fn point_triangle_distance(p: &Vec3, t0: &Vec3, t1: &Vec3, t2: &Vec3) -> f64 {
    let dtype = super::point_triangle_distance_type(p, t0, t1, t2);
    point_triangle_distance_typed(p, t0, t1, t2, dtype)
}

/// The closest-point parametrization of the type on the stencil `[p, t0, t1, t2]`.
fn envelope(x: &[Vec3; 4], dtype: PointTriangleDistanceType) -> Envelope {
    use PointTriangleDistanceType as T;
    match feasible(&x[0], [&x[1], &x[2], &x[3]], dtype) {
        T::Vertex0 => Envelope::point_point(0, 1, x),
        T::Vertex1 => Envelope::point_point(0, 2, x),
        T::Vertex2 => Envelope::point_point(0, 3, x),
        T::Edge0 => Envelope::point_line(0, 1, 2, x),
        T::Edge1 => Envelope::point_line(0, 2, 3, x),
        T::Edge2 => Envelope::point_line(0, 3, 1, x),
        T::Face => Envelope::point_plane(0, [1, 2, 3], x),
    }
}

/// Gradient of the squared distance for the given type (cm), ordered `p, t0, t1, t2`:
/// `∂d/∂xᵢ = 2·aᵢ·v` where `v` is the vector from the triangle's closest point to `p` and
/// `aᵢ` the closest point's affine coefficients (see [`super::envelope`]).
pub fn point_triangle_distance_gradient(
    p: &Vec3,
    t0: &Vec3,
    t1: &Vec3,
    t2: &Vec3,
    dtype: PointTriangleDistanceType,
) -> Vector12 {
    envelope(&[*p, *t0, *t1, *t2], dtype).gradient()
}

/// Hessian of the squared distance for the given type (dimensionless), 12×12, ordered
/// `p, t0, t1, t2`; closed form of [`super::envelope`]. For the face type
/// `∂²d/∂p² = 2·n̂n̂ᵀ`; for a vertex type it is the constant point–point Hessian.
pub fn point_triangle_distance_hessian(
    p: &Vec3,
    t0: &Vec3,
    t1: &Vec3,
    t2: &Vec3,
    dtype: PointTriangleDistanceType,
) -> Matrix12 {
    envelope(&[*p, *t0, *t1, *t2], dtype).hessian()
}

/// Value, gradient and Hessian together (one envelope evaluation).
pub fn point_triangle_distance_derivatives(
    x: &[Vec3; 4],
    dtype: PointTriangleDistanceType,
) -> (f64, Vector12, Matrix12) {
    let d = point_triangle_distance_typed(&x[0], &x[1], &x[2], &x[3], dtype);
    let env = envelope(x, dtype);
    (d, env.gradient(), env.hessian())
}

/// Value and gradient together.
pub fn point_triangle_distance_and_gradient(
    x: &[Vec3; 4],
    dtype: PointTriangleDistanceType,
) -> (f64, Vector12) {
    let d = point_triangle_distance_typed(&x[0], &x[1], &x[2], &x[3], dtype);
    (d, envelope(x, dtype).gradient())
}
