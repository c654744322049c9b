//! The total potential: gradient and Hessian against finite differences (with mollified edge
//! pairs), PSD projection, determinism across thread counts, errors.

use super::*;
use crate::contact::collisions::{CollisionKind, CollisionType};
use crate::contact::distance::PointTriangleDistanceType;
use crate::contact::distance::mollifier::edge_edge_cross_squarednorm;
use crate::contact::math::Vec3;
use crate::contact::test_scenes::{two_sheet_mesh, two_sheets};

/// Sheets at about d̂/2 with jitter: every distance type, and (aligned grids) mollified pairs.
fn scene() -> (crate::contact::ContactMesh, Vec<f64>, f64) {
    let (x, faces) = two_sheets(6, 0.006, [0.031, 0.017], 0.0, 0.002, 21);
    let mesh = two_sheet_mesh(&x, &faces);
    (mesh, x, 0.01)
}

#[test]
fn gradient_and_hessian_match_finite_differences() {
    let (mesh, x, dhat) = scene();
    let set = Collisions::build(&mesh, &x, dhat).unwrap();
    let pot = BarrierPotential::new(dhat, 1e3).unwrap();
    let kinds = |k| set.collisions.iter().filter(|c| c.kind == k).count();
    assert!(kinds(CollisionKind::PointTriangle) > 10 && kinds(CollisionKind::EdgeEdge) > 10);
    let mollified = set
        .collisions
        .iter()
        .filter(|c| {
            let p = c.positions(&x);
            c.kind == CollisionKind::EdgeEdge
                && edge_edge_cross_squarednorm(&p[0], &p[1], &p[2], &p[3]) < c.eps_x
        })
        .count();
    assert!(mollified > 0, "no mollified edge pair in the scene");
    assert!(set.collisions.iter().any(|c| matches!(
        c.dtype,
        CollisionType::PointTriangle(crate::contact::PointTriangleDistanceType::Face)
    )));

    let n = x.len();
    let g = pot.gradient(&set, &x).unwrap();
    let blocks = pot.hessian(&set, &x, Projection::None).unwrap();
    let h = assemble_dense(&blocks, n);
    let step = 1e-8;
    let gscale = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let hscale = h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for i in (0..n).filter(|&i| g[i] != 0.0) {
        let mut xp = x.clone();
        let mut xm = x.clone();
        xp[i] += step;
        xm[i] -= step;
        let fd = (pot.value(&set, &xp).unwrap() - pot.value(&set, &xm).unwrap()) / (2.0 * step);
        assert!(
            (fd - g[i]).abs() <= 1e-5 * gscale,
            "dof {i}: {fd} vs {}",
            g[i]
        );
        let gp = pot.gradient(&set, &xp).unwrap();
        let gm = pot.gradient(&set, &xm).unwrap();
        for j in 0..n {
            let fd = (gp[j] - gm[j]) / (2.0 * step);
            assert!(
                (fd - h[j * n + i]).abs() <= 1e-5 * hscale,
                "H[{j}, {i}]: {fd} vs {}",
                h[j * n + i]
            );
        }
    }
    // Hessian-vector products from the blocks agree with the dense matrix.
    let v: Vec<f64> = (0..n).map(|i| ((i * 7919) % 13) as f64 - 6.0).collect();
    let mut hv = vec![0.0; n];
    add_hessian_product(&blocks, &v, &mut hv);
    for r in 0..n {
        let dense: f64 = (0..n).map(|c| h[r * n + c] * v[c]).sum();
        assert!((dense - hv[r]).abs() <= 1e-9 * hscale);
    }
}

#[test]
fn projected_blocks_are_psd_and_keep_psd_blocks() {
    let (mesh, x, dhat) = scene();
    let set = Collisions::build(&mesh, &x, dhat).unwrap();
    let pot = BarrierPotential::new(dhat, 1.0).unwrap();
    let exact = pot.hessian(&set, &x, Projection::None).unwrap();
    let proj = pot.hessian(&set, &x, Projection::ClampEigenvalues).unwrap();
    let mut changed = 0;
    for (e, p) in exact.iter().zip(&proj) {
        let eig = nalgebra::SymmetricEigen::new(p.matrix);
        let scale = e.matrix.amax();
        assert!(eig.eigenvalues.iter().all(|&l| l >= -1e-10 * scale));
        if e.matrix != p.matrix {
            changed += 1;
        }
    }
    assert!(changed > 0, "expected some indefinite blocks");
}

#[test]
fn results_are_bitwise_identical_across_thread_counts() {
    let (mesh, x, dhat) = scene();
    let run = || {
        let set = Collisions::build(&mesh, &x, dhat).unwrap();
        let pot = BarrierPotential::new(dhat, 3.0).unwrap();
        (
            pot.value(&set, &x).unwrap().to_bits(),
            pot.gradient(&set, &x)
                .unwrap()
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>(),
            pot.hessian(&set, &x, Projection::ClampEigenvalues).unwrap(),
        )
    };
    let many = run();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(run);
    assert!(many == one);
}

#[test]
fn touching_pairs_and_mismatches_are_errors() {
    let (x, faces) = two_sheets(3, 0.0, [0.0, 0.0], 0.0, 0.0, 1);
    let mesh = two_sheet_mesh(&x, &faces);
    assert!(matches!(
        Collisions::build(&mesh, &x, 0.01),
        Err(ContactError::Touching { .. })
    ));
    let (mesh, x, dhat) = scene();
    let set = Collisions::build(&mesh, &x, dhat).unwrap();
    let other = BarrierPotential::new(2.0 * dhat, 1.0).unwrap();
    assert!(matches!(
        other.value(&set, &x),
        Err(ContactError::InvalidParameter(_))
    ));
    assert!(BarrierPotential::new(0.0, 1.0).is_err());
    let v = set.collisions[0].vertices[1];
    let mut bad = x.clone();
    bad[3 * v as usize] = f64::INFINITY;
    let pot = BarrierPotential::new(dhat, 1.0).unwrap();
    assert_eq!(
        pot.gradient(&set, &bad),
        Err(ContactError::NonFinite(v as usize))
    );
    assert!(matches!(
        pot.value(&set, &x[..6]),
        Err(ContactError::PositionsLength { .. })
    ));
    // The scene is about 1 cm wide and 0.006 cm thick.
    let diag = mesh.bbox_diagonal(&x);
    assert!(diag > 1.4 && diag < 1.6, "{diag}");
    assert!(BarrierPotential::new(1.0, f64::NAN).is_err());
    // Far apart: empty set, zero potential.
    let (x, faces) = two_sheets(3, 1.0, [0.0, 0.0], 0.0, 0.0, 1);
    let mesh = two_sheet_mesh(&x, &faces);
    let set = Collisions::build(&mesh, &x, 0.01).unwrap();
    assert!(set.is_empty());
    let pot = BarrierPotential::new(0.01, 1.0).unwrap();
    assert_eq!(pot.value(&set, &x).unwrap(), 0.0);
    assert_eq!(set.min_distance_squared(), 1e-4);
}

/// A pair close at rest, activated at `a < d̂` and weighted `(d̂²/a²)²`, is the plain pair in
/// units of its own activation distance: at the gap `s·a` its barrier equals the plain pair's
/// at `s·d̂`, and its push is `d̂/a` times as strong. Unweighted it would be `(a/d̂)⁴` as weak.
#[test]
fn a_close_pairs_barrier_is_the_plain_one_at_its_own_scale() {
    let (dhat, a) = (0.03, 0.004);
    let pair = |gap: f64, activation: f64| {
        let p = [
            Vec3::new(0.2, 0.3, gap),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let c = Collision {
            kind: CollisionKind::PointTriangle,
            vertices: [0, 1, 2, 3],
            dtype: CollisionType::PointTriangle(PointTriangleDistanceType::Face),
            distance_squared: gap * gap,
            activation2: activation * activation,
            weight: (dhat / activation).powi(4),
            eps_x: 0.0,
        };
        (local::value(&c, &p), local::gradient(&c, &p)[2])
    };
    for s in [0.05, 0.3, 0.7, 0.95] {
        let (close, plain) = (pair(s * a, a), pair(s * dhat, dhat));
        assert!(plain.0 > 0.0);
        assert!(
            (close.0 / plain.0 - 1.0).abs() < 1e-12,
            "s = {s}: {close:?} vs {plain:?}"
        );
        assert!((close.1 / plain.1 - dhat / a).abs() < 1e-9 * dhat / a);
    }
}
