//! Exact distance primitives between points, segments and triangles (cm), shared by the rig
//! checks, the embedding and contact.

use nalgebra::{Point3, Vector3};

/// Distance from `p` to triangle `abc` (cm), by the closest point on the triangle (Ericson,
/// *Real-Time Collision Detection*, §5.1.5).
pub fn point_triangle_distance(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> f64 {
    (p - closest_point_on_triangle(p, a, b, c)).norm()
}

/// The point of triangle `abc` closest to `p`.
pub fn closest_point_on_triangle(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> Point3<f64> {
    let ab = b - a;
    let ac = c - a;
    if !(ab.cross(&ac).norm_squared() > 1e-14 * ab.norm_squared() * ac.norm_squared()) {
        // Degenerate (zero-area, to rounding) triangle: the closest of its edges. The Voronoi
        // tests below divide by its area.
        return [(a, b), (b, c), (c, a)]
            .into_iter()
            .map(|(s, e)| closest_point_on_segment(p, s, e))
            .min_by(|x, y| (p - x).norm_squared().total_cmp(&(p - y).norm_squared()))
            .unwrap_or(*a);
    }
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    a + ab * (vb / denom) + ac * (vc / denom)
}

fn closest_point_on_segment(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> Point3<f64> {
    let ab = b - a;
    let l2 = ab.norm_squared();
    if l2 == 0.0 {
        return *a;
    }
    a + ab * ((p - a).dot(&ab) / l2).clamp(0.0, 1.0)
}

/// Distance between segments `p1q1` and `p2q2` (cm): `‖(p1 + s·d1) − (p2 + t·d2)‖` at the
/// parameters of [`segment_segment_params`].
pub fn segment_segment_distance(
    p1: &Point3<f64>,
    q1: &Point3<f64>,
    p2: &Point3<f64>,
    q2: &Point3<f64>,
) -> f64 {
    let (s, t) = segment_segment_params(p1, q1, p2, q2);
    ((p1 + (q1 - p1) * s) - (p2 + (q2 - p2) * t)).norm()
}

/// Parameters `(s, t) ∈ [0, 1]²` of the closest points `p1 + s·(q1 − p1)` and
/// `p2 + t·(q2 − p2)` of two segments (Ericson, *Real-Time Collision Detection*, §5.1.9;
/// parallel segments take `s = 0` and degenerate ones their single point).
pub fn segment_segment_params(
    p1: &Point3<f64>,
    q1: &Point3<f64>,
    p2: &Point3<f64>,
    q2: &Point3<f64>,
) -> (f64, f64) {
    let d1: Vector3<f64> = q1 - p1;
    let d2: Vector3<f64> = q2 - p2;
    let r = p1 - p2;
    let a = d1.norm_squared();
    let e = d2.norm_squared();
    let f = d2.dot(&r);
    if a == 0.0 && e == 0.0 {
        return (0.0, 0.0);
    }
    if a == 0.0 {
        return (0.0, (f / e).clamp(0.0, 1.0));
    }
    let c = d1.dot(&r);
    if e == 0.0 {
        return ((-c / a).clamp(0.0, 1.0), 0.0);
    }
    let b = d1.dot(&d2);
    let denom = a * e - b * b;
    let s0 = if denom > 1e-14 * a * e {
        ((b * f - c * e) / denom).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let t0 = (b * s0 + f) / e;
    if t0 < 0.0 {
        ((-c / a).clamp(0.0, 1.0), 0.0)
    } else if t0 > 1.0 {
        (((b - c) / a).clamp(0.0, 1.0), 1.0)
    } else {
        (s0, t0)
    }
}
