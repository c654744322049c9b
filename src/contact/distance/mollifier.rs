//! The edge–edge mollifier of Li et al. 2020 (§4.3, Eq. 11): it fades the edge–edge barrier
//! out as two edges become parallel, where the edge–edge distance is not smooth.
//!
//! With `c(x) = ‖(ea1 − ea0) × (eb1 − eb0)‖²` (cm⁴) and the rest-shape threshold
//! `ε_x = 10⁻³·‖ea0 − ea1‖²·‖eb0 − eb1‖²` (cm⁴, at rest):
//! `m(c) = −c²/ε_x² + 2c/ε_x` for `c < ε_x`, else `1`. It is C¹ at `c = ε_x` and `m(0) = 0`.

use nalgebra::Matrix3;

use crate::contact::math::{Matrix12, Vec3, Vector12};

/// `ε_x = 10⁻³·‖ea0 − ea1‖²·‖eb0 − eb1‖²` from the rest positions (cm⁴).
pub fn edge_edge_mollifier_threshold(ea0: &Vec3, ea1: &Vec3, eb0: &Vec3, eb1: &Vec3) -> f64 {
    1e-3 * (ea0 - ea1).norm_squared() * (eb0 - eb1).norm_squared()
}

/// `c = ‖(ea1 − ea0) × (eb1 − eb0)‖²` (cm⁴).
pub fn edge_edge_cross_squarednorm(ea0: &Vec3, ea1: &Vec3, eb0: &Vec3, eb1: &Vec3) -> f64 {
    (ea1 - ea0).cross(&(eb1 - eb0)).norm_squared()
}

/// Gradient of `c` (cm³), ordered `ea0, ea1, eb0, eb1`. With `u = ea1 − ea0`, `w = eb1 − eb0`:
/// `∂c/∂u = 2‖w‖²u − 2(u·w)w`, `∂c/∂w = 2‖u‖²w − 2(u·w)u`, and `∂/∂ea0 = −∂/∂u` etc.
pub fn edge_edge_cross_squarednorm_gradient(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
) -> Vector12 {
    let u = ea1 - ea0;
    let w = eb1 - eb0;
    let uw = u.dot(&w);
    let gu = 2.0 * (w.norm_squared() * u - uw * w);
    let gw = 2.0 * (u.norm_squared() * w - uw * u);
    let mut g = Vector12::zeros();
    g.fixed_rows_mut::<3>(0).copy_from(&-gu);
    g.fixed_rows_mut::<3>(3).copy_from(&gu);
    g.fixed_rows_mut::<3>(6).copy_from(&-gw);
    g.fixed_rows_mut::<3>(9).copy_from(&gw);
    g
}

/// Hessian of `c` (cm²): `∂²c/∂u² = 2(‖w‖²I − wwᵀ)`, `∂²c/∂w² = 2(‖u‖²I − uuᵀ)`,
/// `∂²c/∂u∂w = 4uwᵀ − 2wuᵀ − 2(u·w)I`, mapped to the 4 vertices by `u = ea1 − ea0`,
/// `w = eb1 − eb0`.
pub fn edge_edge_cross_squarednorm_hessian(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
) -> Matrix12 {
    let u = ea1 - ea0;
    let w = eb1 - eb0;
    let uw = u.dot(&w);
    let id = Matrix3::identity();
    let huu = 2.0 * (w.norm_squared() * id - w * w.transpose());
    let hww = 2.0 * (u.norm_squared() * id - u * u.transpose());
    let huw = 4.0 * u * w.transpose() - 2.0 * w * u.transpose() - 2.0 * uw * id;
    // Vertex signs: ea0 = −u, ea1 = +u, eb0 = −w, eb1 = +w.
    let sign = [-1.0, 1.0, -1.0, 1.0];
    let mut h = Matrix12::zeros();
    for i in 0..4 {
        for j in 0..4 {
            let block = match (i < 2, j < 2) {
                (true, true) => huu,
                (false, false) => hww,
                (true, false) => huw,
                (false, true) => huw.transpose(),
            };
            h.fixed_view_mut::<3, 3>(3 * i, 3 * j)
                .copy_from(&(sign[i] * sign[j] * block));
        }
    }
    h
}

/// `m(c) = −c²/ε² + 2c/ε` for `c < ε`, else `1` (dimensionless).
pub fn mollifier(c: f64, eps_x: f64) -> f64 {
    if c < eps_x {
        let r = c / eps_x;
        (2.0 - r) * r
    } else {
        1.0
    }
}

/// `m'(c) = 2/ε − 2c/ε²` for `c < ε`, else `0` (1/cm⁴).
pub fn mollifier_derivative(c: f64, eps_x: f64) -> f64 {
    if c < eps_x {
        2.0 * (eps_x - c) / (eps_x * eps_x)
    } else {
        0.0
    }
}

/// `m''(c) = −2/ε²` for `c < ε`, else `0` (1/cm⁸).
pub fn mollifier_second_derivative(c: f64, eps_x: f64) -> f64 {
    if c < eps_x {
        -2.0 / (eps_x * eps_x)
    } else {
        0.0
    }
}

/// `m(c(x))` for the current edges.
pub fn edge_edge_mollifier(ea0: &Vec3, ea1: &Vec3, eb0: &Vec3, eb1: &Vec3, eps_x: f64) -> f64 {
    mollifier(edge_edge_cross_squarednorm(ea0, ea1, eb0, eb1), eps_x)
}

/// `∇m = m'(c)·∇c` (1/cm), ordered `ea0, ea1, eb0, eb1`.
pub fn edge_edge_mollifier_gradient(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
    eps_x: f64,
) -> Vector12 {
    let c = edge_edge_cross_squarednorm(ea0, ea1, eb0, eb1);
    if c >= eps_x {
        return Vector12::zeros();
    }
    mollifier_derivative(c, eps_x) * edge_edge_cross_squarednorm_gradient(ea0, ea1, eb0, eb1)
}

/// `∇²m = m''(c)·∇c∇cᵀ + m'(c)·∇²c` (1/cm²).
pub fn edge_edge_mollifier_hessian(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
    eps_x: f64,
) -> Matrix12 {
    let c = edge_edge_cross_squarednorm(ea0, ea1, eb0, eb1);
    if c >= eps_x {
        return Matrix12::zeros();
    }
    let g = edge_edge_cross_squarednorm_gradient(ea0, ea1, eb0, eb1);
    mollifier_second_derivative(c, eps_x) * (g * g.transpose())
        + mollifier_derivative(c, eps_x) * edge_edge_cross_squarednorm_hessian(ea0, ea1, eb0, eb1)
}
