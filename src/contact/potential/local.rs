//! One collision's barrier term and its derivatives on its 12-dof stencil.
//!
//! Point–triangle: `B = κ·b(d(x), d̂²)`. Edge–edge: `B = κ·m(c(x))·b(d(x), d̂²)` with the
//! mollifier `m` of [`crate::contact::distance::mollifier`] (`m = 1` once `c ≥ ε_x`); `d̂²` is
//! the collision's own `activation2` (d̂² but for pairs close at rest).
//! Derivatives by the chain and product rules:
//! - `∇B = κ·(m·b'·∇d + b·∇m)`,
//! - `∇²B = κ·(m·(b''·∇d∇dᵀ + b'·∇²d) + b'·(∇m∇dᵀ + ∇d∇mᵀ) + b·∇²m)`.

use crate::contact::barrier::{barrier, barrier_first_derivative, barrier_second_derivative};
use crate::contact::collisions::{Collision, CollisionKind};
use crate::contact::distance::mollifier::{
    edge_edge_cross_squarednorm, edge_edge_cross_squarednorm_gradient,
    edge_edge_cross_squarednorm_hessian, mollifier, mollifier_derivative,
    mollifier_second_derivative,
};
use crate::contact::distance::{
    edge_edge_distance_and_gradient, edge_edge_distance_derivatives, edge_edge_distance_type,
    point_triangle_distance_and_gradient, point_triangle_distance_derivatives,
    point_triangle_distance_type,
};
use crate::contact::math::{Matrix12, Vec3, Vector12};

fn distance_gradient(kind: CollisionKind, p: &[Vec3; 4]) -> (f64, Vector12) {
    match kind {
        CollisionKind::PointTriangle => {
            let t = point_triangle_distance_type(&p[0], &p[1], &p[2], &p[3]);
            point_triangle_distance_and_gradient(p, t)
        }
        CollisionKind::EdgeEdge => {
            let t = edge_edge_distance_type(&p[0], &p[1], &p[2], &p[3]);
            edge_edge_distance_and_gradient(p, t)
        }
    }
}

fn distance_derivatives(kind: CollisionKind, p: &[Vec3; 4]) -> (f64, Vector12, Matrix12) {
    match kind {
        CollisionKind::PointTriangle => {
            let t = point_triangle_distance_type(&p[0], &p[1], &p[2], &p[3]);
            point_triangle_distance_derivatives(p, t)
        }
        CollisionKind::EdgeEdge => {
            let t = edge_edge_distance_type(&p[0], &p[1], &p[2], &p[3]);
            edge_edge_distance_derivatives(p, t)
        }
    }
}

/// `c` and whether the edge pair is mollified (`c < ε_x`).
fn mollified(c: &Collision, p: &[Vec3; 4]) -> Option<f64> {
    if c.kind != CollisionKind::EdgeEdge {
        return None;
    }
    let cross = edge_edge_cross_squarednorm(&p[0], &p[1], &p[2], &p[3]);
    (cross < c.eps_x).then_some(cross)
}

/// `m·b(d, d̂²)` (unit stiffness), `+∞` at `d ≤ 0`.
pub fn value(c: &Collision, p: &[Vec3; 4]) -> f64 {
    let dhat2 = c.activation2;
    let b = c.weight * barrier(c.kind.distance_squared(p), dhat2);
    match mollified(c, p) {
        Some(cross) if b != 0.0 => mollifier(cross, c.eps_x) * b,
        _ => b,
    }
}

/// `∇(m·b)` (unit stiffness).
pub fn gradient(c: &Collision, p: &[Vec3; 4]) -> Vector12 {
    let dhat2 = c.activation2;
    let (d, gd) = distance_gradient(c.kind, p);
    let b1 = c.weight * barrier_first_derivative(d, dhat2);
    match mollified(c, p) {
        None => b1 * gd,
        Some(cross) => {
            let m = mollifier(cross, c.eps_x);
            let gm = mollifier_derivative(cross, c.eps_x)
                * edge_edge_cross_squarednorm_gradient(&p[0], &p[1], &p[2], &p[3]);
            (m * b1) * gd + c.weight * barrier(d, dhat2) * gm
        }
    }
}

/// `∇²(m·b)` (unit stiffness), dense 12×12 and exactly symmetric.
pub fn hessian(c: &Collision, p: &[Vec3; 4]) -> Matrix12 {
    let h = hessian_unsymmetrized(c, p);
    0.5 * (h + h.transpose())
}

fn hessian_unsymmetrized(c: &Collision, p: &[Vec3; 4]) -> Matrix12 {
    let dhat2 = c.activation2;
    let (d, gd, hd) = distance_derivatives(c.kind, p);
    let b1 = c.weight * barrier_first_derivative(d, dhat2);
    let b2 = c.weight * barrier_second_derivative(d, dhat2);
    let plain = b2 * (gd * gd.transpose()) + b1 * hd;
    match mollified(c, p) {
        None => plain,
        Some(cross) => {
            let m = mollifier(cross, c.eps_x);
            let m1 = mollifier_derivative(cross, c.eps_x);
            let m2 = mollifier_second_derivative(cross, c.eps_x);
            let gc = edge_edge_cross_squarednorm_gradient(&p[0], &p[1], &p[2], &p[3]);
            let hc = edge_edge_cross_squarednorm_hessian(&p[0], &p[1], &p[2], &p[3]);
            let gm = m1 * gc;
            let hm = m2 * (gc * gc.transpose()) + m1 * hc;
            let cross_terms = gm * gd.transpose();
            m * plain
                + b1 * (cross_terms + cross_terms.transpose())
                + c.weight * barrier(d, dhat2) * hm
        }
    }
}
