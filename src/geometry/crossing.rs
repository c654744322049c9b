//! Whether a segment crosses a triangle, decided by orientation tests.
//!
//! The segment `pq` crosses triangle `abc` iff `p` and `q` lie on opposite sides
//! of the triangle's plane and the line `pq` passes inside the triangle:
//!
//! `sign O(a,b,c,p) ≠ sign O(a,b,c,q)` and `sign O(p,q,a,b) = sign O(p,q,b,c) = sign O(p,q,c,a)`,
//!
//! with `O(a,b,c,d) = (a − d)·((b − d) × (c − d))` (six times the signed volume of `abcd`),
//! evaluated in f64 — not exact arithmetic, but "exact enough": the rounding error is ~1e-16
//! of the products of coordinate differences (≲ 1e-18 cm³ for the rig's millimetre-scale lip
//! elements), far below the volumes that decide real crossings; exact zeros are handled by
//! the tie rules below.
//!
//! Ties (a determinant exactly 0, e.g. mirror-symmetric vertices on the x = 0 plane) are
//! decided by a fixed rule, equivalent to an infinitesimal perturbation:
//! - a point exactly on the triangle's plane counts as lying just behind it (opposite its
//!   normal `(b − a) × (c − a)`, as if the triangle were pushed forward infinitesimally): a
//!   segment touching the triangle at an endpoint crosses iff its other endpoint is in front,
//!   and a segment lying in the plane never crosses;
//! - a line exactly through the triangle's edge `(u, v)` (in the triangle's vertex order)
//!   counts as inside that edge iff `u < v` (vertex ids). Two consistently oriented
//!   triangles traverse their shared edge in opposite directions, so a segment through the
//!   shared edge is counted exactly once, not twice or zero times.

use nalgebra::Point3;

/// `O(a,b,c,d) = (a − d)·((b − d) × (c − d))`: six times the signed volume of the
/// tetrahedron `abcd` (cm³); positive when `d` lies on the side of plane `abc` opposite to its
/// normal `(b − a) × (c − a)`.
pub fn orient3d(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>, d: &Point3<f64>) -> f64 {
    (a - d).dot(&(b - d).cross(&(c - d)))
}

/// Whether segment `pq` crosses triangle `t` (positions) with vertex ids `ids`, under the
/// module's tie rules.
pub fn segment_crosses_triangle(
    p: &Point3<f64>,
    q: &Point3<f64>,
    t: [&Point3<f64>; 3],
    ids: [u32; 3],
) -> bool {
    let side_p = orient3d(t[0], t[1], t[2], p) >= 0.0;
    let side_q = orient3d(t[0], t[1], t[2], q) >= 0.0;
    if side_p == side_q {
        return false;
    }
    let mut sign = None;
    for k in 0..3 {
        let (u, v) = (k, (k + 1) % 3);
        let o = orient3d(p, q, t[u], t[v]);
        let positive = if o == 0.0 { ids[u] < ids[v] } else { o > 0.0 };
        match sign {
            None => sign = Some(positive),
            Some(s) if s != positive => return false,
            Some(_) => {}
        }
    }
    true
}
