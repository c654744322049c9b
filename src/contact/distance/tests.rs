//! Distances against an independent brute-force reference, gradients and Hessians against
//! finite differences for every distance type, and degenerate inputs.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::mollifier::*;
use super::*;
use crate::contact::math::{Matrix12, Vec3, Vector12};

const PT_TYPES: [PointTriangleDistanceType; 7] = [
    PointTriangleDistanceType::Vertex0,
    PointTriangleDistanceType::Vertex1,
    PointTriangleDistanceType::Vertex2,
    PointTriangleDistanceType::Edge0,
    PointTriangleDistanceType::Edge1,
    PointTriangleDistanceType::Edge2,
    PointTriangleDistanceType::Face,
];

const EE_TYPES: [EdgeEdgeDistanceType; 9] = [
    EdgeEdgeDistanceType::Ea0Eb0,
    EdgeEdgeDistanceType::Ea0Eb1,
    EdgeEdgeDistanceType::Ea1Eb0,
    EdgeEdgeDistanceType::Ea1Eb1,
    EdgeEdgeDistanceType::EaEb0,
    EdgeEdgeDistanceType::EaEb1,
    EdgeEdgeDistanceType::Ea0Eb,
    EdgeEdgeDistanceType::Ea1Eb,
    EdgeEdgeDistanceType::EaEb,
];

fn rand_vec(rng: &mut ChaCha8Rng, s: f64) -> Vec3 {
    Vec3::new(
        rng.random_range(-s..s),
        rng.random_range(-s..s),
        rng.random_range(-s..s),
    )
}

fn random_stencil(rng: &mut ChaCha8Rng) -> [Vec3; 4] {
    std::array::from_fn(|_| rand_vec(rng, 1.0))
}

fn flat(x: &[Vec3; 4]) -> Vector12 {
    Vector12::from_fn(|i, _| x[i / 3][i % 3])
}

fn unflat(v: &Vector12) -> [Vec3; 4] {
    std::array::from_fn(|i| Vec3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]))
}

/// Central differences of `f` (scalar) and `g` (gradient) at `x`.
fn fd_check(
    x: &[Vec3; 4],
    f: impl Fn(&[Vec3; 4]) -> f64,
    g: impl Fn(&[Vec3; 4]) -> Vector12,
    h: impl Fn(&[Vec3; 4]) -> Matrix12,
    what: &str,
) {
    let step = 1e-6;
    let x0 = flat(x);
    let grad = g(x);
    let hess = h(x);
    let mut fd_grad = Vector12::zeros();
    let mut fd_hess = Matrix12::zeros();
    for i in 0..12 {
        let mut xp = x0;
        let mut xm = x0;
        xp[i] += step;
        xm[i] -= step;
        fd_grad[i] = (f(&unflat(&xp)) - f(&unflat(&xm))) / (2.0 * step);
        fd_hess.set_column(i, &((g(&unflat(&xp)) - g(&unflat(&xm))) / (2.0 * step)));
    }
    let gscale = grad.amax().max(1e-3);
    let hscale = hess.amax().max(1e-3);
    assert!(
        (fd_grad - grad).amax() <= 1e-6 * gscale,
        "{what}: gradient {grad:?} vs FD {fd_grad:?}"
    );
    assert!(
        (fd_hess - hess).amax() <= 1e-5 * hscale,
        "{what}: Hessian off by {:e} (scale {hscale:e})",
        (fd_hess - hess).amax()
    );
    assert_eq!(hess, hess.transpose(), "{what}: Hessian not symmetric");
}

#[test]
fn point_triangle_derivatives_match_finite_differences_for_every_type() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for _ in 0..40 {
        let x = random_stencil(&mut rng);
        for t in PT_TYPES {
            fd_check(
                &x,
                |y| point_triangle_distance_typed(&y[0], &y[1], &y[2], &y[3], t),
                |y| point_triangle_distance_gradient(&y[0], &y[1], &y[2], &y[3], t),
                |y| point_triangle_distance_hessian(&y[0], &y[1], &y[2], &y[3], t),
                &format!("PT {t:?}"),
            );
        }
    }
}

#[test]
fn edge_edge_derivatives_match_finite_differences_for_every_type() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for _ in 0..40 {
        let x = random_stencil(&mut rng);
        for t in EE_TYPES {
            fd_check(
                &x,
                |y| edge_edge_distance_typed(&y[0], &y[1], &y[2], &y[3], t),
                |y| edge_edge_distance_gradient(&y[0], &y[1], &y[2], &y[3], t),
                |y| edge_edge_distance_hessian(&y[0], &y[1], &y[2], &y[3], t),
                &format!("EE {t:?}"),
            );
        }
    }
}

#[test]
fn mollifier_derivatives_match_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut mollified = 0;
    for _ in 0..60 {
        // Nearly parallel edges, so that c < ε_x for many of them.
        let a0 = rand_vec(&mut rng, 1.0);
        let u = rand_vec(&mut rng, 1.0);
        let b0 = rand_vec(&mut rng, 1.0);
        let w = u * rng.random_range(0.5..1.5) + rand_vec(&mut rng, 0.05);
        let x = [a0, a0 + u, b0, b0 + w];
        let eps = 1e-3 * u.norm_squared() * (u.norm_squared() * 1.2);
        if edge_edge_cross_squarednorm(&x[0], &x[1], &x[2], &x[3]) < eps {
            mollified += 1;
        }
        fd_check(
            &x,
            |y| edge_edge_cross_squarednorm(&y[0], &y[1], &y[2], &y[3]),
            |y| edge_edge_cross_squarednorm_gradient(&y[0], &y[1], &y[2], &y[3]),
            |y| edge_edge_cross_squarednorm_hessian(&y[0], &y[1], &y[2], &y[3]),
            "cross",
        );
        fd_check(
            &x,
            |y| edge_edge_mollifier(&y[0], &y[1], &y[2], &y[3], eps),
            |y| edge_edge_mollifier_gradient(&y[0], &y[1], &y[2], &y[3], eps),
            |y| edge_edge_mollifier_hessian(&y[0], &y[1], &y[2], &y[3], eps),
            "mollifier",
        );
    }
    assert!(mollified > 10, "only {mollified} mollified samples");
    // C¹ at the threshold, 0 at parallel.
    assert_eq!(mollifier(1.0, 1.0), 1.0);
    assert_eq!(mollifier_derivative(1.0, 1.0), 0.0);
    assert_eq!(mollifier(0.0, 1.0), 0.0);
    assert!((mollifier(1.0 - 1e-9, 1.0) - 1.0).abs() < 1e-15);
}

/// Squared distance from `p` to the segment, by clamped projection.
fn seg_dist(p: &Vec3, a: &Vec3, b: &Vec3) -> f64 {
    let e = b - a;
    let s = ((p - a).dot(&e) / e.norm_squared()).clamp(0.0, 1.0);
    (p - (a + s * e)).norm_squared()
}

/// Independent reference: the point–triangle distance as the minimum over the face (when the
/// projection is inside) and the three segments.
fn reference_pt(x: &[Vec3; 4]) -> f64 {
    let [p, a, b, c] = x;
    let mut best = seg_dist(p, a, b)
        .min(seg_dist(p, b, c))
        .min(seg_dist(p, c, a));
    let n = (b - a).cross(&(c - a));
    let q = p - n * ((p - a).dot(&n) / n.norm_squared());
    let inside = [(a, b), (b, c), (c, a)]
        .iter()
        .all(|(u, v)| (*v - *u).cross(&(q - *u)).dot(&n) >= 0.0);
    if inside {
        best = best.min((p - q).norm_squared());
    }
    best
}

/// Independent reference: edge–edge distance as the minimum over the four end-point–segment
/// distances and, when the lines' closest points are inside both segments, the line distance.
fn reference_ee(x: &[Vec3; 4]) -> f64 {
    let [a0, a1, b0, b1] = x;
    let mut best = seg_dist(a0, b0, b1)
        .min(seg_dist(a1, b0, b1))
        .min(seg_dist(b0, a0, a1))
        .min(seg_dist(b1, a0, a1));
    let (u, v, w) = (a1 - a0, b1 - b0, a0 - b0);
    let (a, b, c, d, e) = (u.dot(&u), u.dot(&v), v.dot(&v), u.dot(&w), v.dot(&w));
    let den = a * c - b * b;
    if den > 1e-12 * a * c {
        let s = (b * e - c * d) / den;
        let t = (a * e - b * d) / den;
        if (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&t) {
            best = best.min(((a0 + s * u) - (b0 + t * v)).norm_squared());
        }
    }
    best
}

#[test]
fn automatic_types_give_the_true_distance() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut seen_pt = std::collections::HashSet::new();
    let mut seen_ee = std::collections::HashSet::new();
    for _ in 0..4000 {
        let x = random_stencil(&mut rng);
        let d = point_triangle_distance(&x[0], &x[1], &x[2], &x[3]);
        let r = reference_pt(&x);
        assert!((d - r).abs() <= 1e-12 * (1.0 + r), "PT {x:?}: {d} vs {r}");
        seen_pt.insert(point_triangle_distance_type(&x[0], &x[1], &x[2], &x[3]));
        let d = edge_edge_distance(&x[0], &x[1], &x[2], &x[3]);
        let r = reference_ee(&x);
        assert!((d - r).abs() <= 1e-12 * (1.0 + r), "EE {x:?}: {d} vs {r}");
        seen_ee.insert(edge_edge_distance_type(&x[0], &x[1], &x[2], &x[3]));
    }
    assert_eq!(seen_pt.len(), 7, "{seen_pt:?}");
    assert_eq!(seen_ee.len(), 9, "{seen_ee:?}");
}

#[test]
fn parallel_edges_use_point_edge_types_with_the_right_distance() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for _ in 0..500 {
        let a0 = rand_vec(&mut rng, 1.0);
        let u = rand_vec(&mut rng, 1.0);
        let b0 = rand_vec(&mut rng, 1.0);
        let k = rng.random_range(-2.0..2.0);
        let x = [a0, a0 + u, b0, b0 + k * u];
        let t = edge_edge_distance_type(&x[0], &x[1], &x[2], &x[3]);
        assert_ne!(t, EdgeEdgeDistanceType::EaEb);
        let d = edge_edge_distance(&x[0], &x[1], &x[2], &x[3]);
        assert!((d - reference_ee(&x)).abs() <= 1e-12 * (1.0 + d));
        let g = edge_edge_distance_gradient(&x[0], &x[1], &x[2], &x[3], t);
        let h = edge_edge_distance_hessian(&x[0], &x[1], &x[2], &x[3], t);
        assert!(g.iter().chain(h.iter()).all(|v| v.is_finite()));
        // Asking for the line–line type on exactly parallel edges falls back, finite.
        let tt = EdgeEdgeDistanceType::EaEb;
        let h = edge_edge_distance_hessian(&x[0], &x[1], &x[2], &x[3], tt);
        assert!(h.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn degenerate_inputs_stay_finite() {
    let o = Vec3::zeros();
    let ex = Vec3::new(1.0, 0.0, 0.0);
    let cases: Vec<[Vec3; 4]> = vec![
        // Collinear triangles, point off and on the line.
        [Vec3::new(0.3, 0.5, 0.2), o, ex, 2.0 * ex],
        [Vec3::new(1.0, 0.5, 0.2), o, ex, 0.5 * ex],
        [Vec3::new(0.5, 0.0, 0.0), o, ex, 0.5 * ex],
        [Vec3::new(0.3, 0.7, 0.1), o, ex, 0.37 * ex],
        // A triangle collapsed to a point.
        [Vec3::new(0.3, 0.7, 0.1), o, o, o],
        // Two coincident corners.
        [Vec3::new(0.3, 0.7, 0.1), o, o, Vec3::new(0.0, 1.0, 0.0)],
        // Point exactly on an edge's line, outside the edge.
        [Vec3::new(2.0, 0.0, 0.0), o, ex, Vec3::new(0.0, 1.0, 0.0)],
        // Point on the triangle (distance 0).
        [Vec3::new(0.2, 0.2, 0.0), o, ex, Vec3::new(0.0, 1.0, 0.0)],
        // Point on an edge.
        [Vec3::new(0.5, 0.0, 0.0), o, ex, Vec3::new(0.0, 1.0, 0.0)],
    ];
    for x in &cases {
        let t = point_triangle_distance_type(&x[0], &x[1], &x[2], &x[3]);
        let d = point_triangle_distance(&x[0], &x[1], &x[2], &x[3]);
        assert!(
            (d - reference_pt_degenerate(x)).abs() < 1e-12,
            "{x:?}: {t:?} {d}"
        );
        for tt in PT_TYPES {
            let (d, g, h) = point_triangle_distance_derivatives(x, tt);
            assert!(
                d.is_finite() && g.iter().chain(h.iter()).all(|v| v.is_finite()),
                "{x:?} {tt:?}"
            );
        }
        // The same points as edges: zero-length and collinear edges.
        let t = edge_edge_distance_type(&x[0], &x[1], &x[2], &x[3]);
        for tt in EE_TYPES.into_iter().chain([t]) {
            let (d, g, h) = edge_edge_distance_derivatives(x, tt);
            assert!(
                d.is_finite() && g.iter().chain(h.iter()).all(|v| v.is_finite()),
                "{x:?} {tt:?}"
            );
        }
    }
    // Both edges points; one edge a point.
    let p = Vec3::new(0.0, 0.5, 0.2);
    assert_eq!(
        edge_edge_distance_type(&p, &p, &o, &o),
        EdgeEdgeDistanceType::Ea0Eb0
    );
    assert_eq!(
        edge_edge_distance_type(&p, &p, &o, &ex),
        EdgeEdgeDistanceType::Ea0Eb
    );
    assert_eq!(
        edge_edge_distance_type(&o, &ex, &p, &p),
        EdgeEdgeDistanceType::EaEb0
    );
    assert_eq!(
        point_edge_distance_type(&p, &o, &o),
        PointEdgeDistanceType::Vertex0
    );
    assert!((point_edge_distance(&p, &o, &ex) - 0.29).abs() < 1e-15);
}

/// Brute force over the segments only (a degenerate triangle has no face).
fn reference_pt_degenerate(x: &[Vec3; 4]) -> f64 {
    let seg = |p: &Vec3, a: &Vec3, b: &Vec3| {
        if a == b {
            (p - a).norm_squared()
        } else {
            seg_dist(p, a, b)
        }
    };
    let [p, a, b, c] = x;
    let segs = seg(p, a, b).min(seg(p, b, c)).min(seg(p, c, a));
    if is_degenerate_triangle(a, b, c) {
        segs
    } else {
        reference_pt(x)
    }
}

#[test]
fn face_hessian_of_the_point_is_twice_the_normal_projector() {
    let x = [
        Vec3::new(0.2, 0.3, 0.4),
        Vec3::zeros(),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    let h = point_triangle_distance_hessian(
        &x[0],
        &x[1],
        &x[2],
        &x[3],
        PointTriangleDistanceType::Face,
    );
    let hpp = h.fixed_view::<3, 3>(0, 0);
    let expected = nalgebra::Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0);
    assert!((hpp - expected).amax() < 1e-15);
    let g = point_triangle_distance_gradient(
        &x[0],
        &x[1],
        &x[2],
        &x[3],
        PointTriangleDistanceType::Face,
    );
    assert!((g.fixed_rows::<3>(0) - Vec3::new(0.0, 0.0, 0.8)).amax() < 1e-15);
    // Translation invariance: the gradient sums to zero over the stencil.
    let sum: Vec3 = (0..4).map(|i| g.fixed_rows::<3>(3 * i).into_owned()).sum();
    assert!(sum.amax() < 1e-15);
}
