//! CCD never returns a step that passes through: randomized pairs checked by brute force
//! along the path, known impact times, degenerate steps, and whole surfaces.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::contact::distance::{edge_edge_distance, point_triangle_distance};
use crate::contact::math::Vec3;
use crate::contact::test_scenes::{two_sheet_mesh, two_sheets};

fn rand_vec(rng: &mut ChaCha8Rng, s: f64) -> Vec3 {
    Vec3::new(
        rng.random_range(-s..s),
        rng.random_range(-s..s),
        rng.random_range(-s..s),
    )
}

fn at(x0: &[Vec3; 4], dx: &[Vec3; 4], t: f64) -> [Vec3; 4] {
    std::array::from_fn(|i| x0[i] + t * dx[i])
}

fn pt_dist(x: &[Vec3; 4]) -> f64 {
    point_triangle_distance(&x[0], &x[1], &x[2], &x[3]).sqrt()
}

fn ee_dist(x: &[Vec3; 4]) -> f64 {
    edge_edge_distance(&x[0], &x[1], &x[2], &x[3]).sqrt()
}

/// Brute force: the distance along `[0, t1]`, sampled at `samples` points, stays positive, and
/// so does a certified lower bound between samples (the distance is `rate`-Lipschitz in t:
/// `min over [a, b] ≥ (d(a) + d(b) − rate·(b − a))/2`), bisecting where the bound is not
/// conclusive. Also counts sign changes of the orientation (signed volume of the stencil),
/// which a crossing would produce while the distance passes through 0.
fn assert_no_contact(
    x0: &[Vec3; 4],
    dx: &[Vec3; 4],
    t1: f64,
    dist: &impl Fn(&[Vec3; 4]) -> f64,
    rate: f64,
    what: &str,
) {
    let samples = 2000;
    let mut prev = (0.0, dist(x0));
    let orient = |x: &[Vec3; 4]| (x[1] - x[0]).cross(&(x[2] - x[0])).dot(&(x[3] - x[0]));
    let mut prev_sign = orient(x0).signum();
    for k in 1..=samples {
        let t = t1 * k as f64 / samples as f64;
        let x = at(x0, dx, t);
        let d = dist(&x);
        assert!(d > 0.0, "{what}: distance 0 at t = {t} ≤ {t1}");
        let s = orient(&x).signum();
        if s != prev_sign && s != 0.0 {
            // An orientation flip is fine only away from contact: the distance is positive on
            // both sides and (certified below) in between.
            assert!(
                d > 0.0 && prev.1 > 0.0,
                "{what}: flip through contact at t = {t}"
            );
            prev_sign = s;
        }
        certify(x0, dx, prev, (t, d), dist, rate, 0, what);
        prev = (t, d);
    }
}

#[allow(clippy::too_many_arguments)]
fn certify(
    x0: &[Vec3; 4],
    dx: &[Vec3; 4],
    (a, da): (f64, f64),
    (b, db): (f64, f64),
    dist: &impl Fn(&[Vec3; 4]) -> f64,
    rate: f64,
    depth: u32,
    what: &str,
) {
    if (da + db - rate * (b - a)) / 2.0 > 0.0 {
        return;
    }
    assert!(
        depth < 40,
        "{what}: cannot certify [{a}, {b}] (d = {da:e}, {db:e})"
    );
    let m = 0.5 * (a + b);
    let dm = dist(&at(x0, dx, m));
    assert!(dm > 0.0, "{what}: distance 0 at t = {m}");
    certify(x0, dx, (a, da), (m, dm), dist, rate, depth + 1, what);
    certify(x0, dx, (m, dm), (b, db), dist, rate, depth + 1, what);
}

/// Relative speed bound used by the certificate (mean removed, as in the CCD).
fn rate(dx: &[Vec3; 4], edge_edge: bool) -> f64 {
    let mean = (dx[0] + dx[1] + dx[2] + dx[3]) / 4.0;
    let d: [Vec3; 4] = std::array::from_fn(|i| dx[i] - mean);
    if edge_edge {
        d[0].norm().max(d[1].norm()) + d[2].norm().max(d[3].norm())
    } else {
        d[0].norm() + d[1].norm().max(d[2].norm()).max(d[3].norm())
    }
}

#[test]
fn randomized_steps_never_pass_through() {
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let opts = CcdOptions::default();
    let mut hits = 0;
    for trial in 0..300 {
        let x0: [Vec3; 4] = std::array::from_fn(|_| rand_vec(&mut rng, 1.0));
        // Some steps are large enough to cross, some tiny, some pure sliding.
        let scale = [0.01, 0.5, 2.0, 4.0][trial % 4];
        let dx: [Vec3; 4] = std::array::from_fn(|_| rand_vec(&mut rng, scale));
        for edge_edge in [false, true] {
            let r = if edge_edge {
                edge_edge_ccd(&x0, &dx, 1.0, &opts)
            } else {
                point_triangle_ccd(&x0, &dx, 1.0, &opts)
            };
            assert!((0.0..=1.0).contains(&r.toi));
            if r.outcome == CcdOutcome::Hit {
                hits += 1;
                assert!(r.toi < 1.0);
            }
            let dist = |x: &[Vec3; 4]| if edge_edge { ee_dist(x) } else { pt_dist(x) };
            // The returned state keeps the gap (1 − η)·d₀.
            let d0 = dist(&x0);
            assert!(
                dist(&at(&x0, &dx, r.toi))
                    >= (1.0 - opts.conservative_rescaling) * d0 * (1.0 - 1e-9)
            );
            assert_no_contact(
                &x0,
                &dx,
                r.toi,
                &dist,
                rate(&dx, edge_edge),
                &format!("trial {trial} ee={edge_edge}"),
            );
        }
    }
    assert!(hits > 50, "only {hits} impacts in the randomized set");
}

#[test]
fn head_on_impacts_stop_before_the_known_time() {
    let opts = CcdOptions::default();
    // A point falling onto the interior of a triangle from height h at speed v: TOI = h/v.
    for (h, v) in [(1.0, 2.0), (1e-3, 1.0), (1e-6, 3.0), (0.5, 0.5000001)] {
        let x0 = [
            Vec3::new(0.2, 0.2, h),
            Vec3::zeros(),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let dx = [
            Vec3::new(0.0, 0.0, -v),
            Vec3::zeros(),
            Vec3::zeros(),
            Vec3::zeros(),
        ];
        let toi_true = h / v;
        let r = point_triangle_ccd(&x0, &dx, 1.0, &opts);
        assert_eq!(r.outcome, CcdOutcome::Hit);
        assert!(
            r.toi < toi_true && r.toi >= 0.8 * toi_true,
            "h={h} v={v}: {} vs {toi_true}",
            r.toi
        );
    }
    // Crossing edges: ea along x at z = h, eb along y at z = 0, ea moving down.
    let h = 0.3;
    let x0 = [
        Vec3::new(-1.0, 0.1, h),
        Vec3::new(1.0, 0.1, h),
        Vec3::new(0.2, -1.0, 0.0),
        Vec3::new(0.2, 1.0, 0.0),
    ];
    let dx = [
        Vec3::new(0.0, 0.0, -1.0),
        Vec3::new(0.0, 0.0, -1.0),
        Vec3::zeros(),
        Vec3::zeros(),
    ];
    let r = edge_edge_ccd(&x0, &dx, 1.0, &opts);
    assert_eq!(r.outcome, CcdOutcome::Hit);
    assert!(r.toi < h && r.toi >= 0.8 * h);
    // The same impact after t_max is not reported.
    let r = edge_edge_ccd(&x0, &dx, 0.2, &opts);
    assert_eq!((r.outcome, r.toi), (CcdOutcome::Clear, 0.2));
}

#[test]
fn zero_steps_rigid_motion_and_close_pairs() {
    let opts = CcdOptions::default();
    let x0 = [
        Vec3::new(0.2, 0.2, 0.1),
        Vec3::zeros(),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    let zero = [Vec3::zeros(); 4];
    assert_eq!(
        point_triangle_ccd(&x0, &zero, 1.0, &opts).outcome,
        CcdOutcome::Clear
    );
    assert_eq!(point_triangle_ccd(&x0, &zero, 1.0, &opts).toi, 1.0);
    let shift = [Vec3::new(5.0, -3.0, 100.0); 4];
    let r = edge_edge_ccd(&x0, &shift, 1.0, &opts);
    assert_eq!(
        (r.outcome, r.toi, r.iterations),
        (CcdOutcome::Clear, 1.0, 0)
    );
    // Touching at the start: no step can be certified.
    let touching = [Vec3::new(0.2, 0.2, 0.0), x0[1], x0[2], x0[3]];
    let up = [
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::zeros(),
        Vec3::zeros(),
        Vec3::zeros(),
    ];
    let r = point_triangle_ccd(&touching, &up, 1.0, &opts);
    assert_eq!((r.outcome, r.toi), (CcdOutcome::TooClose, 0.0));
    // Already within min_distance.
    let near = CcdOptions {
        min_distance: 0.2,
        ..opts
    };
    assert_eq!(
        point_triangle_ccd(&x0, &up, 1.0, &near).outcome,
        CcdOutcome::TooClose
    );
    // Very close and sliding sideways: safe, possibly capped; moving away: clear.
    let close = [Vec3::new(0.2, 0.2, 1e-7), x0[1], x0[2], x0[3]];
    let slide = [
        Vec3::new(0.3, 0.3, 0.0),
        Vec3::zeros(),
        Vec3::zeros(),
        Vec3::zeros(),
    ];
    let capped = CcdOptions {
        max_iterations: 1000,
        ..opts
    };
    let r = point_triangle_ccd(&close, &slide, 1.0, &capped);
    assert_eq!(r.outcome, CcdOutcome::IterationCap);
    assert!(r.toi > 0.0 && r.toi < 1.0);
    assert_no_contact(
        &close,
        &slide,
        r.toi,
        &pt_dist,
        rate(&slide, false),
        "sliding",
    );
    let away = [
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::zeros(),
        Vec3::zeros(),
        Vec3::zeros(),
    ];
    assert_eq!(
        point_triangle_ccd(&close, &away, 1.0, &opts).outcome,
        CcdOutcome::Clear
    );
    // Invalid options.
    assert!(
        CcdOptions {
            conservative_rescaling: 1.0,
            ..opts
        }
        .validate()
        .is_err()
    );
    assert!(
        CcdOptions {
            min_distance: -1.0,
            ..opts
        }
        .validate()
        .is_err()
    );
}

#[test]
fn surfaces_pressed_together_stop_before_contact() {
    let (x, faces) = two_sheets(8, 0.05, [0.021, 0.013], 0.2, 0.003, 41);
    let mesh = two_sheet_mesh(&x, &faces);
    let n = x.len() / 3;
    let mut dx = vec![0.0; x.len()];
    for v in n / 2..n {
        dx[3 * v + 2] = -0.2; // would pass 0.15 cm through the lower sheet
        dx[3 * v] = 0.03;
    }
    let opts = CcdOptions::default();
    let report = collision_free_step(&mesh, &x, &dx, &opts).unwrap();
    assert!(report.step > 0.05 && report.step < 0.25, "{report:?}");
    assert!(report.limiting.is_some());
    // After the step every pair is still apart: check with a fine static active set.
    let xt: Vec<f64> = x
        .iter()
        .zip(&dx)
        .map(|(a, b)| a + report.step * b)
        .collect();
    let set = crate::contact::Collisions::build(&mesh, &xt, 0.05).unwrap();
    assert!(set.min_distance_squared() > 0.0);
    // Moving apart: the full step.
    let away: Vec<f64> = dx.iter().map(|v| -v).collect();
    assert_eq!(
        collision_free_step(&mesh, &x, &away, &opts).unwrap().step,
        1.0
    );
    // Deterministic.
    assert_eq!(collision_free_step(&mesh, &x, &dx, &opts).unwrap(), report);
}
