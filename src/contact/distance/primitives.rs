//! Squared distances between the flat features that the closest-feature types reduce to.
//! Each is the formula ipc-toolkit evaluates, so both libraries round alike. Units: cm².

use crate::contact::math::Vec3;

/// `d = ‖p − q‖²`.
#[inline]
pub fn point_point_distance(p: &Vec3, q: &Vec3) -> f64 {
    (p - q).norm_squared()
}

/// Squared distance from `p` to the infinite line through `e0`, `e1`:
/// `d = ‖(e0 − p) × (e1 − p)‖² / ‖e1 − e0‖²`. A zero-length edge gives `‖p − e0‖²`.
#[inline]
pub fn point_line_distance(p: &Vec3, e0: &Vec3, e1: &Vec3) -> f64 {
    let ee = (e1 - e0).norm_squared();
    if ee == 0.0 {
        return point_point_distance(p, e0);
    }
    (e0 - p).cross(&(e1 - p)).norm_squared() / ee
}

/// Squared distance from `p` to the plane through `t0, t1, t2`:
/// `d = ((p − t0)·n)² / ‖n‖²`, `n = (t1 − t0) × (t2 − t0)`. Requires a non-degenerate triangle.
#[inline]
pub fn point_plane_distance(p: &Vec3, t0: &Vec3, t1: &Vec3, t2: &Vec3) -> f64 {
    let n = (t1 - t0).cross(&(t2 - t0));
    let pn = (p - t0).dot(&n);
    pn * pn / n.norm_squared()
}

/// Squared distance between the infinite lines through `ea0, ea1` and `eb0, eb1`:
/// `d = ((ea0 − eb0)·n)² / ‖n‖²`, `n = (ea1 − ea0) × (eb1 − eb0)`. Requires non-parallel lines.
#[inline]
pub fn line_line_distance(ea0: &Vec3, ea1: &Vec3, eb0: &Vec3, eb1: &Vec3) -> f64 {
    let n = (ea1 - ea0).cross(&(eb1 - eb0));
    let wn = (ea0 - eb0).dot(&n);
    wn * wn / n.norm_squared()
}
