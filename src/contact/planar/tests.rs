use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;

fn v(x: f64, y: f64, z: f64) -> Vec3 {
    Vector3::new(x, y, z)
}

fn distance(kind: CollisionKind, x: &[Vec3; 4]) -> f64 {
    kind.distance_squared(x).sqrt()
}

fn moved(x: &[Vec3; 4], dx: &[Vec3; 4], t: f64) -> [Vec3; 4] {
    std::array::from_fn(|i| x[i] + dx[i] * t)
}

/// A point falling onto a triangle covers 90 % of the gap and stops a tenth of it short; a
/// point sliding along it, however close, is not held back; a pair that starts touching
/// allows no step.
#[test]
fn a_falling_point_stops_short_and_a_sliding_one_moves_freely() {
    let tri = [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)];
    let x = [v(0.2, 0.3, 1.0), tri[0], tri[1], tri[2]];
    let fall = [
        v(0.0, 0.0, -2.0),
        Vec3::zeros(),
        Vec3::zeros(),
        Vec3::zeros(),
    ];
    let t = pair_step(CollisionKind::PointTriangle, &x, &fall, DEFAULT_KEEP);
    assert!((t - 0.45).abs() < 1e-12, "{t}");
    let end = moved(&x, &fall, t);
    assert!((distance(CollisionKind::PointTriangle, &end) - 0.1).abs() < 1e-12);

    // Both sides approach: the plane sits where they would meet.
    let both = [
        v(0.0, 0.0, -1.0),
        v(0.0, 0.0, 1.0),
        v(0.0, 0.0, 1.0),
        v(0.0, 0.0, 1.0),
    ];
    let t = pair_step(CollisionKind::PointTriangle, &x, &both, DEFAULT_KEEP);
    assert!((t - 0.45).abs() < 1e-12, "{t}");

    let close = [v(0.2, 0.3, 1e-9), tri[0], tri[1], tri[2]];
    let slide = [
        v(0.3, 0.2, 0.0),
        Vec3::zeros(),
        Vec3::zeros(),
        Vec3::zeros(),
    ];
    assert_eq!(
        pair_step(CollisionKind::PointTriangle, &close, &slide, DEFAULT_KEEP),
        1.0
    );

    let touching = [v(0.2, 0.3, 0.0), tri[0], tri[1], tri[2]];
    assert_eq!(
        pair_step(
            CollisionKind::PointTriangle,
            &touching,
            &slide,
            DEFAULT_KEEP
        ),
        0.0
    );
}

/// `|p − s|` for the closest point `s` of segment `(a, b)`, by its clamped parameter.
fn point_segment_distance(p: &Vec3, a: &Vec3, b: &Vec3) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (p - (a + ab * t)).norm()
}

/// The closest points agree with the contact kit's exact distance on every closest-feature
/// region, for points and for edges (parallel and degenerate ones included).
#[test]
fn closest_points_give_the_exact_distance() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut r = |s: f64| {
        v(
            rng.random_range(-s..s),
            rng.random_range(-s..s),
            rng.random_range(-s..s),
        )
    };
    for k in 0..20_000 {
        let mut x = [r(1.0), r(1.0), r(1.0), r(1.0)];
        match k % 5 {
            // Parallel edges, a degenerate edge, a degenerate triangle.
            1 => x[3] = x[2] + (x[1] - x[0]) * 0.7,
            2 => x[1] = x[0],
            3 => x[3] = x[1] + (x[2] - x[1]) * 0.3,
            _ => {}
        }
        for kind in [CollisionKind::PointTriangle, CollisionKind::EdgeEdge] {
            let (a, b) = closest_points(kind, &x);
            // The kit's edge–edge distance assumes proper edges: a degenerate one is a point,
            // whose distance to the other edge is the reference.
            let exact = if kind == CollisionKind::EdgeEdge && k % 5 == 2 {
                point_segment_distance(&x[0], &x[2], &x[3])
            } else {
                distance(kind, &x)
            };
            assert!(
                ((a - b).norm() - exact).abs() <= 1e-9 * (1.0 + exact),
                "{kind:?} {x:?}: {} vs {exact}",
                (a - b).norm()
            );
        }
    }
}

/// The guarantee of the module doc, sampled: along any step the filter allows, every pair
/// stays at least `keep` of its starting distance apart, for random pairs and motions (both
/// sides moving, rotating, sliding, nearly touching, parallel edges).
#[test]
fn a_filtered_step_keeps_every_pair_apart() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut limited = 0;
    for k in 0..20_000 {
        let mut r = |s: f64| {
            v(
                rng.random_range(-s..s),
                rng.random_range(-s..s),
                rng.random_range(-s..s),
            )
        };
        let mut x = [r(1.0), r(1.0), r(1.0), r(1.0)];
        if k % 4 == 1 {
            x[3] = x[2] + (x[1] - x[0]) * 0.5;
        }
        let dx = [r(3.0), r(3.0), r(3.0), r(3.0)];
        for kind in [CollisionKind::PointTriangle, CollisionKind::EdgeEdge] {
            let d0 = distance(kind, &x);
            if !(d0 > 1e-6) {
                continue;
            }
            for keep in [DEFAULT_KEEP, 0.5] {
                let t = pair_step(kind, &x, &dx, keep);
                limited += usize::from(t < 1.0);
                for s in 0..=32 {
                    let d = distance(kind, &moved(&x, &dx, t * s as f64 / 32.0));
                    assert!(
                        d >= keep * d0 * (1.0 - 1e-9) - 1e-12,
                        "{kind:?} keep {keep}: {d} < {} at {s}/32 of t = {t}",
                        keep * d0
                    );
                }
            }
        }
    }
    assert!(
        limited > 10_000,
        "the motions must approach often: {limited}"
    );
}

/// A whole surface: the step is the smallest pair's, the limiting pair is named, and the
/// per-vertex bounds reduce to it.
#[test]
fn the_surface_step_is_the_smallest_pair_step() {
    use crate::contact::test_scenes::two_sheets;
    let (x, faces) = two_sheets(6, 0.05, [0.03, 0.02], 0.3, 0.0, 1);
    let mesh = ContactMesh::new(&x, faces).unwrap();
    let n = x.len() / 3;
    // The upper sheet falls through the lower one.
    let dx: Vec<f64> = (0..n)
        .flat_map(|i| {
            if x[3 * i + 2] > 0.0 {
                [0.0, 0.0, -0.2]
            } else {
                [0.0; 3]
            }
        })
        .collect();
    let candidates = Candidates::build_swept(&mesh, &x, &dx, 0.0).unwrap();
    let report = planar_step_over(&mesh, &candidates, &x, &dx, DEFAULT_KEEP).unwrap();
    assert!(report.step > 0.0 && report.step < 0.25, "{report:?}");
    assert!(report.limiting.is_some());
    let per_vertex = vertex_steps(&mesh, &candidates, &x, &dx, DEFAULT_KEEP).unwrap();
    let smallest = per_vertex.iter().copied().fold(1.0, f64::min);
    assert_eq!(smallest, report.step);
    let y: Vec<f64> = x
        .iter()
        .zip(&dx)
        .map(|(p, d)| p + report.step * d)
        .collect();
    assert!(
        crate::contact::Collisions::build(&mesh, &y, 1e-9).is_ok(),
        "no pair touches"
    );
    assert!(planar_step_over(&mesh, &candidates, &x, &dx, 1.5).is_err());
}
